"""viewer/garment.py's before/after strip: its input, composite and truth panels (mutOO; < 1 s, no fit run).

A stand-in fit and session (images per camera, a target render), a composite PNG written with OpenCV and read back;
the strip's panels, their order and captions, the whole-factor enlargement to ``MIN_STRIP_HEIGHT`` rows and the
caption box drawn by OpenCV itself on a copy.
"""

from __future__ import annotations

from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from bodystudio.errors import FileFormatError, SessionError
from bodystudio.viewer import garment as vg


def _img(value, h=60, w=80):
    a = np.zeros((h, w, 3), np.uint8)
    a[..., 0], a[..., 1], a[..., 2] = value, value + 1, value + 2
    return a


def _session(gt=True, cams=("front", "side")):
    frames = {f: SimpleNamespace(images={c: _img(10 * f + k) for k, c in enumerate(cams)},
                                 gt_target={cams[0]: _img(100 + f)} if gt else {}) for f in (1, 2, 3)}
    return SimpleNamespace(camera_names=list(cams), frame=lambda f: frames[f], frame_ids=[1, 2, 3],
                           gt_garment={"target": {}} if gt else None)


def _view(tmp_path, session=None, render=None, camera="side", notes=()):
    fit = SimpleNamespace(frame_ids=[1, 2, 3], fitted=[True] * 3, camera=SimpleNamespace(name=camera),
                          source="video.mp4", body=lambda: "body")
    return vg.GarmentView(tmp_path, fit, render, session, None, tuple(notes))


def test_input_frames_from_the_session_camera_or_the_video(tmp_path, monkeypatch):
    import bodystudio.garment.composite as gc

    s = _session()
    got = vg.input_frames(_view(tmp_path, s, camera="side"), [np.int64(2), 3])
    assert list(got) == [2, 3] and (got[2] == _img(21)).all() and (got[3] == _img(31)).all()
    got = vg.input_frames(_view(tmp_path, s, camera="other"), [1])  # not a session camera: the first
    assert (got[1] == _img(10)).all()
    seen = []

    def source_frames(stub, fit_dir):
        seen.append((stub.source, stub.frame_ids.tolist(), stub.camera.name, fit_dir))
        return [_img(7), _img(8)]

    monkeypatch.setattr(gc, "source_frames", source_frames)
    got = vg.input_frames(_view(tmp_path), [2, 3])
    assert seen == [("video.mp4", [2, 3], "side", tmp_path)] and (got[3] == _img(8)).all()


def test_read_png_and_truth_frame(tmp_path):
    p = tmp_path / "a.png"
    bgr = _img(40)
    cv2.imwrite(str(p), bgr)
    np.testing.assert_array_equal(vg._read_png(p), bgr[..., ::-1])
    assert vg._read_png(tmp_path / "none.png") is None
    (tmp_path / "bad.png").write_bytes(b"not a png")
    assert vg._read_png(tmp_path / "bad.png") is None
    s = _session()
    np.testing.assert_array_equal(vg.truth_frame(_view(tmp_path, s), np.int64(2)), _img(102))
    assert vg.truth_frame(_view(tmp_path, s), 9) is None
    assert vg.truth_frame(_view(tmp_path, _session(gt=False)), 2) is None
    assert vg.truth_frame(_view(tmp_path, None), 2) is None
    broken = _session()
    broken.frame = lambda f: SimpleNamespace(gt_target={})  # no render of that camera
    assert vg.truth_frame(_view(tmp_path, broken), 2) is None

    def damaged(f):
        raise FileFormatError("gt: damaged")

    broken.frame = damaged  # an unreadable frame
    assert vg.truth_frame(_view(tmp_path, broken), 2) is None


def test_before_after_panels_in_order_and_what_is_missing(tmp_path, monkeypatch):
    s = _session()
    render_dir = tmp_path / "render" / "frames"
    render_dir.mkdir(parents=True)
    cv2.imwrite(str(render_dir / "00002.png"), _img(60))
    v = _view(tmp_path, s, render={})
    panels = vg.before_after_panels(v, 2)
    assert [c for c, _ in panels] == ["input", "composite", "truth"]
    np.testing.assert_array_equal(panels[0][1], _img(21))
    np.testing.assert_array_equal(panels[1][1], _img(60)[..., ::-1])
    np.testing.assert_array_equal(panels[2][1], _img(102))
    given = {3: _img(5)}
    assert [c for c, _ in vg.before_after_panels(v, 3, given)] == ["input", "truth"]  # no composite of frame 3
    assert vg.before_after_panels(v, 3, given)[0][1] is given[3]
    assert [c for c, _ in vg.before_after_panels(v, 1, given)] == ["truth"]  # frames given without frame 1
    with pytest.raises(Exception, match="not a frame of the fit"):
        vg.before_after_panels(v, 9)
    import bodystudio.garment.composite as gc

    def gone(stub, fit_dir):
        raise SessionError("video.mp4: gone")

    monkeypatch.setattr(gc, "source_frames", gone)
    lone = _view(tmp_path, None, render=None, notes=("the source is gone", "no render yet"))
    with pytest.raises(SessionError) as e:
        vg.before_after_panels(lone, 2)
    assert str(e.value) == (f"{tmp_path}: frame 2 has no input frame, composite or truth to show (the source is "
                            "gone; no render yet)")
    with pytest.raises(SessionError, match=r"to show \(nothing found\)$"):
        vg.before_after_panels(_view(tmp_path), 2)


def test_before_after_strip_enlarges_by_a_whole_factor_and_captions_each_panel(tmp_path):
    s = _session()
    v = _view(tmp_path, s)
    frames = {2: _img(50, h=70, w=80)}  # the truth is 60 rows: both cut to 60, enlarged 4 x (240 rows)
    strip = vg.before_after_strip(v, 2, frames)
    assert strip.shape == (240, 2 * 320, 3) and strip.dtype == np.uint8
    want = [vg.caption_image(np.repeat(np.repeat(p[:60], 4, 0), 4, 1).copy(), c)
            for c, p in (("input", frames[2]), ("truth", _img(102)))]
    np.testing.assert_array_equal(strip, np.concatenate(want, axis=1))
    big = {2: _img(50, h=300, w=20)}
    s2 = _session(gt=False)
    assert vg.before_after_strip(_view(tmp_path, s2), 2, big).shape == (300, 20, 3)  # tall enough: as it is


def test_caption_image_draws_the_box_and_text_as_opencv_does():
    img = np.full((40, 200, 3), 90, np.uint8)
    out = vg.caption_image(img.copy(), "input")
    ref = img.copy()
    cv2.rectangle(ref, (0, 0), (8 + 9 * 5, 22), (0, 0, 0), -1)
    cv2.putText(ref, "input", (4, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
    np.testing.assert_array_equal(out, ref)
    assert (out[30:, :] == 90).all() and (out[:, 60:] == 90).all() and (out[0, 0] == 0).all()
    assert out.max() == 255


def test_dress_fitted_body_uses_the_garment_choice(tmp_path, monkeypatch):
    import bodystudio.garment.garments as gg

    monkeypatch.setattr(gg, "dress", lambda body, *a: (body, a))
    v = _view(tmp_path, None, render={"garment": "dress", "texture": "dots", "seed": 4, "texture_size": 16})
    assert vg.dress_fitted_body(v) == ("body", ("body", ("dress", "dots", 16, 4)))


def test_a_short_video_read_and_a_session_without_a_target(tmp_path, monkeypatch):
    import bodystudio.garment.composite as gc

    monkeypatch.setattr(gc, "source_frames", lambda stub, fit_dir: [_img(1)])
    with pytest.raises(ValueError):  # a frame the video did not give is never paired with another
        vg.input_frames(_view(tmp_path), [2, 3])
    s = _session()
    s.gt_garment = None  # frames with target renders, but not a garment session: no truth
    assert vg.truth_frame(_view(tmp_path, s), 2) is None
