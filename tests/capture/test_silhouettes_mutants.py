"""bodystudio.capture.silhouettes cases the accuracy tests do not pin (issue 17, mutation testing): the
session layer on a hand-made 2-camera, 48x32 session (report, per-camera IoU, parameters passed through,
messages naming the file), dark backgrounds where the |E/s| floors act, the 2-frame model, the
morphology kernels, 4- vs 8-connected holes, exact component-size thresholds and mask dtypes."""

import logging

import cv2
import numpy as np
import pytest

from bodystudio.capture import silhouettes as sil
from bodystudio.capture.session import SessionWriter, open_session
from bodystudio.capture.silhouettes import SegmentationParams
from bodystudio.errors import SessionError
from bodystudio.geometry.camera import ring_rig

W, H = 48, 32


def _plate(seed):
    rng = np.random.default_rng(seed)
    return np.kron(rng.uniform(70, 140, (4, 6, 3)), np.ones((8, 8, 1)))  # 32 x 48 blocky background


def _noisy(image, rng, sigma=2.0):
    return np.clip(np.round(image + rng.normal(0, sigma, image.shape)), 0, 255).astype(np.uint8)


def _truth(frame, cam):
    m = np.zeros((H, W), bool)
    m[6 + frame:26, 14 + 3 * cam:30 + 3 * cam] = True
    return m


def _write_session(path, n_backgrounds=(3, 3), rgb=True, gt=True, image_width=W, dark=False):
    """cam_00 and cam_01, frames 0 and 1: a subject darker than any shadow (0.3 x the background) or, with
    ``dark=False``, skin-coloured, on a blocky background."""
    rng = np.random.default_rng(0)
    rig = ring_rig(2, width=W, height=H)
    with SessionWriter(path, cameras=rig, source="synthetic") as w:
        for c, cam in enumerate(rig.names):
            plate = _plate(c)
            for i in range(n_backgrounds[c]):
                w.write_background(cam, i, _noisy(plate, rng))
            for f in (0, 1):
                t = _truth(f, c)
                image = plate.copy()
                image[t] = 0.3 * plate[t] if dark else (220, 60, 30)
                if rgb:
                    if image_width != W:
                        image = np.concatenate([image, image[:, :image_width - W]], axis=1)
                    w.write_image(cam, f, _noisy(image, rng))
                if gt:
                    w.write_mask(cam, f, t, ground_truth=True)
    return rig


def test_segment_session_reports_per_camera_iou_and_writes_the_masks(tmp_path, caplog):
    path = tmp_path / "s"
    rig = _write_session(path)
    with caplog.at_level(logging.INFO, logger="bodystudio.capture.silhouettes"):
        report = sil.segment_session(path)
    s = open_session(path)
    ious = {cam: [sil.mask_iou(s.frame(f).masks[cam], _truth(f, c)) for f in (0, 1)]
            for c, cam in enumerate(rig.names)}
    assert report.n_masks == 4
    assert report.iou_per_camera == pytest.approx({cam: np.mean(v) for cam, v in ious.items()}, rel=1e-12)
    assert report.iou_mean == pytest.approx(np.mean(list(ious.values())), rel=1e-12)
    assert report.iou_min == pytest.approx(np.min(list(ious.values())), rel=1e-12)
    assert report.iou_min > 0.95
    assert report.to_dict() == {"n_masks": 4, "iou_mean": report.iou_mean, "iou_min": report.iou_min,
                                "iou_per_camera": report.iou_per_camera}
    assert sil.silhouette_scores(s).to_dict() == report.to_dict()
    assert s.metadata["masks"] == "segmented (Horprasert)"
    assert f"segmented 4 masks in {s.path} (IoU mean {report.iou_mean})" in caplog.messages


def test_segment_session_passes_its_parameters_through(tmp_path):
    """A subject at 0.3 x the background is foreground only because shadows never go below 0.45 x:
    with a 0.2 floor it is a shadow, and every mask comes out empty."""
    path = tmp_path / "s"
    _write_session(path, dark=True)
    assert sil.segment_session(path).iou_min > 0.95
    report = sil.segment_session(path, SegmentationParams(shadow_floor=0.2))
    assert report.iou_mean == 0.0 and report.n_masks == 4
    s = open_session(path)
    assert not any(s.frame(f).masks[c].any() for f in (0, 1) for c in s.camera_names)


def test_session_background_models_use_the_params_floors(tmp_path):
    path = tmp_path / "s"
    _write_session(path, n_backgrounds=(1, 3))
    s = open_session(path)
    models = sil.session_background_models(s, SegmentationParams(single_frame_std=7.0, std_floor=20.0))
    assert models["cam_00"].n_frames == 1 and models["cam_01"].n_frames == 3
    np.testing.assert_array_equal(models["cam_00"].std, 7.0)
    np.testing.assert_array_equal(models["cam_01"].std, 20.0)


def test_session_errors_name_the_file(tmp_path):
    path = tmp_path / "nobg"
    _write_session(path, n_backgrounds=(2, 0))
    s = open_session(path)
    with pytest.raises(SessionError) as e:
        sil.segment_session(path)
    assert str(e.value) == (f"{s.path / 'cam_01' / 'background'}: no empty-studio frames for camera cam_01; "
                            "record a few frames without the subject (import them with --backgrounds)")
    path = tmp_path / "norgb"
    _write_session(path, rgb=False)
    s = open_session(path)
    with pytest.raises(SessionError) as e:
        sil.segment_session(path)
    assert str(e.value) == f"{s.path / 'session.json'}: the session has no RGB frames to segment"
    path = tmp_path / "wide"
    _write_session(path, image_width=W + 8)
    s = open_session(path)
    with pytest.raises(SessionError) as e:
        sil.segment_session(path)
    assert str(e.value) == (f"{s.path / 'cam_00' / 'rgb'}: frame 0 is {W + 8}x{H} but the background frames "
                            f"are {W}x{H}")
    path = tmp_path / "nogt"
    _write_session(path, gt=False)
    s = open_session(path)
    with pytest.raises(SessionError) as e:
        sil.silhouette_scores(s)
    assert str(e.value) == (f"{s.path / 'session.json'}: no ground-truth masks to score against "
                            "(only synthetic sessions have gt/masks)")
    report = sil.segment_session(path)  # segmenting needs no ground truth: no IoU then
    assert report.n_masks == 4 and report.iou_mean is None and report.iou_min is None
    assert report.iou_per_camera == {}


def test_report_averages_per_camera_and_skips_cameras_without_scores():
    r = sil._report(3, {"a": [0.5, 1.0], "b": [], "c": [0.9]})
    assert r.n_masks == 3 and r.iou_per_camera == {"a": 0.75, "c": 0.9}
    assert r.iou_mean == pytest.approx(0.8) and r.iou_min == 0.5
    r = sil._report(0, {"a": []})
    assert (r.iou_mean, r.iou_min, r.iou_per_camera) == (None, None, {})


# --- model and distortions ------------------------------------------------------------------------

def test_background_model_dtype_defaults_and_message():
    plate = _plate(3).astype(np.uint8)
    model = sil.background_model([plate, plate + 4])
    assert model.mean.dtype == np.float32 and model.std.dtype == np.float32
    one = sil.background_model([plate])
    np.testing.assert_array_equal(one.std, 3.0)  # the default single_frame_std
    assert one.mean.dtype == np.float32 and one.std.dtype == np.float32
    with pytest.raises(ValueError, match=r"^background_model needs at least one empty frame$"):
        sil.background_model([])


def test_a_two_frame_model_uses_the_sample_std_and_measured_rms():
    """Two frames a and a + d: the sample std is |d| / sqrt(2) per channel (floored by its median), the
    RMS distortions are measured on the two frames, not the single-frame guesses."""
    rng = np.random.default_rng(5)
    a = _plate(4)
    d = rng.uniform(-6.0, 6.0, a.shape)
    model = sil.background_model([a, a + d])
    raw = np.abs(d) / np.sqrt(2.0)
    np.testing.assert_allclose(model.std, np.maximum(raw, max(np.median(raw), 1.0)), rtol=1e-5)
    unit = sil.BackgroundModel(model.mean, model.std, 1.0, 1.0, 2)
    al, cd = zip(*(sil.brightness_chromaticity_distortion(f, unit) for f in (a, a + d)), strict=True)
    assert model.cd_rms == pytest.approx(max(np.sqrt(np.mean(np.square(cd))), 1.0), rel=1e-5)
    assert model.alpha_rms == pytest.approx(np.sqrt(np.mean((np.stack(al) - 1.0) ** 2)), rel=1e-5)
    assert model.cd_rms != pytest.approx(np.sqrt(2.0), rel=1e-3)


def test_dark_backgrounds_are_not_floored_as_if_bright():
    """A background of grey level 1 with std 3: sum (E/s)^2 = 1/3, above the 1e-6 guard, so a pixel twice
    as bright has alpha exactly 2 and the single-frame alpha RMS is sqrt(3)."""
    dark = np.ones((4, 5, 3))
    model = sil.background_model([dark])
    assert model.alpha_rms == pytest.approx(np.sqrt(3.0), rel=1e-6)
    alpha, cd = sil.brightness_chromaticity_distortion(2 * dark, model)
    np.testing.assert_allclose(alpha, 2.0, rtol=1e-6)
    np.testing.assert_allclose(cd, 0.0, atol=1e-5)


def test_size_mismatch_message_names_both_sizes():
    model = sil.background_model([np.full((60, 80, 3), 100.0)])
    with pytest.raises(ValueError) as e:
        sil.brightness_chromaticity_distortion(np.zeros((40, 70, 3)), model)
    assert str(e.value) == "image is 70x40 but the background model is 80x60"


def test_strict_brightness_mode_keeps_chromatic_foreground_and_unchanged_background():
    """shadows_are_background=False adds |alpha - 1| beyond tau_brightness to the CD test, it does not
    replace it: an equally bright but differently coloured pixel stays foreground, the background stays."""
    rng = np.random.default_rng(6)
    plate = _plate(7)
    model = sil.background_model([_noisy(plate, rng) for _ in range(5)])
    image = plate.copy()
    image[10:20, 10:20] = plate[10:20, 10:20, ::-1]  # channels swapped: new colour, similar brightness
    image[0:5, 30:40] *= 0.8  # a soft shadow: background only when shadows are background
    strict = sil.foreground_pixels(image, model, SegmentationParams(shadows_are_background=False))
    loose = sil.foreground_pixels(image, model)
    swapped = np.zeros(plate.shape[:2], bool)
    swapped[10:20, 10:20] = True
    swapped &= np.abs(plate - plate[..., ::-1]).max(-1) > 20  # blocks whose colour really changes
    assert swapped.sum() > 20
    assert strict[swapped].all() and loose[swapped].all()
    untouched = np.ones(plate.shape[:2], bool)
    untouched[10:20, 10:20] = False
    untouched[0:5, 30:40] = False
    assert not strict[untouched].any() and not loose[untouched].any()
    assert strict[0:5, 30:40].all() and not loose[0:5, 30:40].any()


def test_segment_silhouette_is_clean_mask_of_foreground_pixels_with_the_same_params():
    rng = np.random.default_rng(8)
    plate = _plate(9)
    model = sil.background_model([_noisy(plate, rng) for _ in range(4)])
    image = plate.copy()
    image[8:24, 10:30] *= 0.3
    image[2, 2] = (250, 0, 0)
    image = _noisy(image, rng)
    params = SegmentationParams(shadow_floor=0.2, min_component_px=0, min_component_fraction=0.0)
    got = sil.segment_silhouette(image, model, params)
    np.testing.assert_array_equal(got, sil.clean_mask(sil.foreground_pixels(image, model, params), params))
    assert got[2, 2] and not got[8:24, 10:30].any()  # the speck kept, the dark block a shadow


# --- clean-up -----------------------------------------------------------------------------------

def _blob():
    mask = np.zeros((40, 40), np.uint8)
    cv2.circle(mask, (20, 20), 11, 1, -1)
    mask[20, 2:40] = 1  # a 1 px whisker
    mask[5:9, 30:34] = 1  # a 4 px square
    mask[24, 20] = 0  # a 1 px hole
    mask[17:19, 5:35] = 0  # a 2 px slit across the disc
    return mask.astype(bool)


@pytest.mark.parametrize("op, size", [("open", 2), ("open", 5), ("close", 2), ("close", 5)])
def test_morphology_uses_an_elliptic_kernel_of_the_given_size(op, size):
    mask = _blob()
    kw = {f"{op}_px": size, "min_component_px": 0, "min_component_fraction": 0.0, "max_hole_fraction": 0.0}
    got = sil.clean_mask(mask, SegmentationParams(**kw))
    cv_op = cv2.MORPH_OPEN if op == "open" else cv2.MORPH_CLOSE

    def ref(kernel):
        return cv2.morphologyEx(mask.astype(np.uint8), cv_op, kernel) > 0

    ellipse = ref(cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size)))
    if size % 2 == 0:  # morphologyEx shifts by a pixel for even sizes: the second pass by the reflected kernel
        k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))
        first, second = (cv2.erode, cv2.dilate) if op == "open" else (cv2.dilate, cv2.erode)
        ellipse = second(first(mask.astype(np.uint8), k, anchor=(size // 2,) * 2), np.ascontiguousarray(k[::-1, ::-1]),
                         anchor=(size - 1 - size // 2,) * 2) > 0
    np.testing.assert_array_equal(got, ellipse)
    assert not np.array_equal(ellipse, mask)
    if size == 5:  # distinguishable from a rectangle and from OpenCV's default 3x3
        assert not np.array_equal(ellipse, ref(cv2.getStructuringElement(cv2.MORPH_RECT, (5, 5))))
        assert not np.array_equal(ellipse, ref(None))


def test_holes_are_4_connected_and_every_enclosed_hole_counts():
    m = np.ones((10, 10), bool)
    m[0, 0] = False  # border background in the corner
    m[1, 1] = False  # touches it only diagonally: enclosed for 4-connectivity
    out = sil.fill_small_holes(m, 5)
    assert out[1, 1] and not out[0, 0]
    m = np.ones((10, 10), bool)
    m[4:6, 4:6] = False  # the only hole: label 1
    assert sil.fill_small_holes(m, 4).all()
    assert not sil.fill_small_holes(m, 3)[4:6, 4:6].any()
    m = np.ones((10, 10), bool)
    m[4:6, 0:2] = False  # a notch on the left border only
    assert not sil.fill_small_holes(m, 10)[4:6, 0:2].any()
    m = np.ones((10, 10), bool)
    m[0:2, 4:6] = False  # on the top border only
    assert not sil.fill_small_holes(m, 10)[0:2, 4:6].any()


def test_component_thresholds_are_inclusive_and_empty_masks_are_boolean():
    m = np.zeros((40, 40), bool)
    m[0:10, 0:10] = True  # 100 px
    m[20:22, 20:25] = True  # 10 px: exactly 0.1 of the largest
    m[30:35, 30:40] = True  # 50 px: exactly the default min_px
    out = sil.largest_components(m, 0.1, 0)
    assert out[20:22, 20:25].all()
    out = sil.largest_components(m)
    assert out[30:35, 30:40].all() and not out[20:22, 20:25].any()
    empty = sil.largest_components(np.zeros((5, 5), bool))
    assert empty.dtype == bool and not empty.any()
    assert sil.clean_mask(np.zeros((5, 5), bool)).dtype == bool


def test_mask_iou_reads_any_nonzero_value_as_inside():
    a = np.zeros((4, 4), np.uint8)
    a[0, :2] = 2
    b = np.zeros((4, 4), np.uint8)
    b[0, 1:3] = 2
    assert sil.mask_iou(a, b) == pytest.approx(1 / 3)
    assert sil.mask_iou(a, b > 0) == pytest.approx(1 / 3)
    assert sil.mask_iou(a > 0, b) == pytest.approx(1 / 3)


_RANGES = [("tau_cd", 0.1, 100.0, "--tau-cd"), ("tau_brightness", 0.1, 100.0, "tau_brightness"),
           ("shadow_floor", 0.0, 1.0, "shadow_floor"), ("highlight_ceiling", 1.0, 10.0, "highlight_ceiling"),
           ("std_floor", 0.0, 50.0, "std_floor"), ("single_frame_std", 0.0, 50.0, "single_frame_std"),
           ("close_px", 0, 100, "--close"), ("open_px", 0, 100, "--open"),
           ("min_component_fraction", 0.0, 1.0, "min_component_fraction"),
           ("min_component_px", 0, 10**6, "min_component_px"), ("max_hole_fraction", 0.0, 1.0, "max_hole_fraction")]


@pytest.mark.parametrize("name, lo, hi, flag", _RANGES)
def test_segmentation_params_accept_their_closed_range_and_name_the_option(name, lo, hi, flag):
    from bodystudio.errors import InputError

    for good in (lo, hi, (lo + hi) / 2 if isinstance(hi, float) else (lo + hi) // 2):
        assert getattr(SegmentationParams(**{name: good}), name) == good
    step = 0.5 if isinstance(hi, float) else 1
    for bad in (hi + step, lo - step, float("nan")):
        with pytest.raises(InputError) as e:
            SegmentationParams(**{name: bad})
        assert str(e.value) == f"{flag} {bad:g} is out of range; use a value in [{lo:g}, {hi:g}]"


def test_segment_session_builds_its_models_with_the_params_floors(tmp_path):
    """A 50-grey-level std floor makes the skin-coloured subject (100-150 levels from the background) fall
    inside the chromaticity threshold: the session's masks come out empty, as the params ask."""
    path = tmp_path / "s"
    _write_session(path)
    assert sil.segment_session(path, SegmentationParams(std_floor=50.0)).iou_mean < 0.2


def test_the_session_lock_names_the_silhouettes_command(tmp_path, monkeypatch):
    """While segmenting, the session's lock names the command (what a refused reader is told)."""
    from bodystudio.capture.session import session_layout
    from bodystudio.runfolder import read_lock

    path = tmp_path / "s"
    _write_session(path)
    real, seen = sil.segment_silhouette, []

    def probe(*args, **kwargs):
        if not seen:
            seen.append(read_lock(session_layout(path).lock))
        return real(*args, **kwargs)

    monkeypatch.setattr(sil, "segment_silhouette", probe)
    sil.segment_session(path)
    assert seen[0]["command"] == "bodystudio capture silhouettes"
