"""viewer/arm.py on a stand-in arm sequence (mutOO; the method of mutMM's viewer files).

Five frames of a two-triangle arm numbered 10..14, a truth 1..4 mm off per vertex (the error colours by hand), a
stand-in session whose Kinect points are given (``views.kinect_points`` replaced, its stride recorded). The layers
are read back from the plotter's actors; the framing against :func:`scene.frame_front` called on its own; the
payload's frames picked by ``linspace`` written by hand; ``open_arm_view``'s sources by spies.
"""

from __future__ import annotations

import logging
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from bodystudio.errors import InputError, SessionError
from bodystudio.viewer import arm as va
from bodystudio.viewer import scene as sc

SIZE = (320, 240)
IDS = (10, 11, 12, 13, 14)
QUAD = np.array([[0.0, 0.0, 1.0], [0.1, 0.0, 1.0], [0.1, 0.3, 1.0], [0.0, 0.3, 1.0]])
F2 = np.array([[0, 1, 2], [0, 2, 3]])
OFF_MM = np.array([1.0, 2.0, 3.0, 4.0])


def _view(truth=True, session=None, arm_mask=None, ids=IDS, path="caps/armcap"):
    V = np.stack([QUAD + [0.01 * k, 0.0, 0.0] for k in range(len(ids))])
    T = V + np.array([0.0, 0.0, 1.0]) * OFF_MM[:, None] / 1000.0 if truth else None
    return va.ArmSequenceView(Path(path), tuple(ids), V, F2, T, session, arm_mask)


def _data(plotter, name):
    import pyvista as pv

    mapper = plotter.renderer.actors[name].GetMapper()
    mapper.Update()
    return pv.wrap(mapper.GetInput())


def _text(plotter, name):
    actor = plotter.renderer.actors.get(name)
    return None if actor is None else next(actor.GetText(k) for k in range(4) if actor.GetText(k))


def _kinect(monkeypatch):
    """``views.kinect_points`` replaced: the points of each frame, around the arm and beyond its 8 cm margin."""
    import bodystudio.viewer.views as vw

    calls = []

    def points(session, frame, stride=7):
        calls.append((session, frame, stride))
        x0 = 0.01 * (frame - 10)  # the frame's arm lies at x0 .. x0 + 0.1
        return np.array([[x0 + 0.05, 0.1, 1.0], [x0 - 0.079, 0.0, 1.0], [x0 - 0.081, 0.0, 1.0],
                         [x0 + 0.179, 0.3, 1.0], [x0 + 0.181, 0.3, 1.0], [x0, 0.38 + 0.001, 1.0],
                         [x0, -0.079, 1.079], [x0, 0.1, 0.921], [x0, 0.1, 0.92 - 0.001]])

    monkeypatch.setattr(vw, "kinect_points", points)
    session = SimpleNamespace(frame=lambda fid: int(fid))
    return session, calls


def test_index_errors_and_title():
    v = _view()
    assert v.index(None) == 0 and v.index(12) == 2 and v.index(np.int64(14)) == 4
    with pytest.raises(InputError) as e:
        v.index(15)
    assert str(e.value) == "caps/armcap: no frame 15; frames are 10..14"
    np.testing.assert_allclose(v.errors_mm(3), OFF_MM, rtol=1e-9)
    assert _view(truth=False).errors_mm(0) is None
    assert va._title(v, 2) == "armcap  frame 12  median error (all vertices) 2.5 mm"
    masked = _view(arm_mask=np.array([False, True, True, True]))
    assert va._title(masked, 1) == "armcap  frame 11  arm median error 3.0 mm"
    wrong = _view(arm_mask=np.array([True, False, False]))
    assert va._title(wrong, 1) == "armcap  frame 11  median error (all vertices) 2.5 mm"
    assert va._title(_view(truth=False, arm_mask=np.ones(4, bool)), 4) == "armcap  frame 14"


def test_depth_points_are_those_within_8_cm_of_the_arms_box(monkeypatch):
    kinect = _kinect(monkeypatch)
    session, calls = kinect
    assert va.arm_depth_points(_view(), 1).shape == (0, 3)
    v = _view(session=session)
    P = va.arm_depth_points(v, 2)
    assert calls == [(session, 12, 2)]
    x0 = 0.02
    want = np.array([[x0 + 0.05, 0.1, 1.0], [x0 - 0.079, 0.0, 1.0], [x0 + 0.179, 0.3, 1.0], [x0, -0.079, 1.079],
                     [x0, 0.1, 0.921]])
    np.testing.assert_allclose(P, want)
    va.arm_depth_points(v, 0, stride=5)
    assert calls[-1][1:] == (10, 5)


def test_depth_points_on_the_box_are_kept(monkeypatch):
    import bodystudio.viewer.views as vw

    v = _view(session=SimpleNamespace(frame=lambda fid: fid))
    lo = v.vertices[1].min(0) - va.DEPTH_MARGIN_M
    hi = v.vertices[1].max(0) + va.DEPTH_MARGIN_M
    monkeypatch.setattr(vw, "kinect_points", lambda session, frame, stride=7: np.stack([lo, hi]))
    np.testing.assert_array_equal(va.arm_depth_points(v, 1), np.stack([lo, hi]))


def test_arm_frame_layers_error_colours_truth_and_depth(monkeypatch):
    kinect = _kinect(monkeypatch)
    session, _ = kinect
    v = _view(session=session)
    p = sc.make_plotter(window_size=SIZE)
    sc.add_point_cloud(p, np.zeros((1, 3)), name="other")
    assert va.scene_for_arm_frame(v, 3, p) is p
    np.testing.assert_allclose(_data(p, "arm").points, v.vertices[3])
    np.testing.assert_allclose(_data(p, "arm").point_data["error (mm)"], OFF_MM, rtol=1e-6)
    mapper = p.renderer.actors["arm"].GetMapper()
    assert tuple(mapper.GetScalarRange()) == (0.0, 10.0)
    np.testing.assert_allclose(_data(p, "truth-arm").points, v.truth[3])
    truth_prop = p.renderer.actors["truth-arm"].GetProperty()
    assert truth_prop.GetOpacity() == pytest.approx(0.2)
    np.testing.assert_allclose(truth_prop.GetColor(), sc.GT_COLOR, atol=1 / 255)
    np.testing.assert_allclose(_data(p, "depth").points, va.arm_depth_points(v, 3))
    depth_prop = p.renderer.actors["depth"].GetProperty()
    np.testing.assert_allclose(depth_prop.GetColor(), va.DEPTH_COLOR, atol=1 / 255)
    assert depth_prop.GetPointSize() == 3.0
    assert "error (mm)" in p.scalar_bars
    # frame 1 replaces the layers; another cloud stays
    va.scene_for_arm_frame(v, 1, p)
    np.testing.assert_allclose(_data(p, "arm").points, v.vertices[1])
    np.testing.assert_allclose(_data(p, "truth-arm").points, v.truth[1])
    assert "other" in p.renderer.actors
    # no truth, no cloud: the plain arm alone; the old truth, depth and bar gone, another bar kept
    from bodystudio.geometry.mesh import Mesh

    sc.add_error_map(p, Mesh(QUAD, F2), OFF_MM, title="other (mm)", name="other-map")
    va.scene_for_arm_frame(_view(truth=False, session=session), 0, p, cloud=False)
    assert {"truth-arm", "depth"}.isdisjoint(p.renderer.actors) and "error (mm)" not in p.scalar_bars
    assert "other (mm)" in p.scalar_bars
    np.testing.assert_allclose(_data(p, "arm").points, QUAD)
    np.testing.assert_allclose(p.renderer.actors["arm"].GetProperty().GetColor(), sc.MESH_COLOR, atol=1 / 255)
    p.close()


def test_arm_sequence_title_key_help_and_framing(monkeypatch):
    kinect = _kinect(monkeypatch)
    session, _ = kinect
    v = _view(session=session)
    given = sc.make_plotter(window_size=SIZE)
    p = va.scene_for_arm_sequence(v, 13, plotter=given, cloud=False)
    assert p is given
    assert "depth" not in p.renderer.actors
    np.testing.assert_allclose(_data(p, "arm").points, v.vertices[3])
    assert _text(p, "title") == "armcap  frame 13  median error (all vertices) 2.5 mm"
    assert _text(p, "key-help") == sc.KEY_HELP + "\nslider or n / p: next / previous frame"
    ref = sc.make_plotter(window_size=SIZE)
    Vall = v.vertices.reshape(-1, 3)
    sc.frame_front(ref, np.stack([Vall.min(0), Vall.max(0)]), direction=(0.2, 0.1, 1.0), margin=1.2)
    np.testing.assert_allclose(p.camera.position, ref.camera.position, rtol=1e-9)
    np.testing.assert_allclose(p.camera.focal_point, ref.camera.focal_point, rtol=1e-9)
    np.testing.assert_allclose(p.camera.up, ref.camera.up, atol=1e-9)
    p.close()
    one = _view(ids=(7,), session=session)
    p = va.scene_for_arm_sequence(one, title="mine")
    assert _text(p, "title") == "mine" and _text(p, "key-help") == sc.KEY_HELP and "depth" in p.renderer.actors
    np.testing.assert_allclose(_data(p, "arm").points, QUAD)
    p.close()
    p = va.scene_for_arm_sequence(one, key_help=False, plotter=sc.make_plotter(window_size=SIZE))
    assert _text(p, "key-help") is None
    p.close()
    p = va.scene_for_arm_sequence(_view(ids=(7, 8), session=session), cloud=False)
    assert _text(p, "key-help") == sc.KEY_HELP + "\nslider or n / p: next / previous frame"
    p.close()


def test_time_slider_draws_the_chosen_frame(monkeypatch):
    kinect = _kinect(monkeypatch)
    session, _ = kinect
    seen = {}

    def slider(plotter, ids, start, show):
        seen.update(plotter=plotter, ids=list(ids), start=start, show=show)
        return "slid"

    monkeypatch.setattr(sc, "add_frame_slider", slider)
    p = sc.make_plotter(window_size=SIZE)
    assert va.add_arm_time_slider(p, _view(ids=(3,))) is p and not seen
    v = _view(session=session)
    assert va.add_arm_time_slider(p, v, frame_id=12) == "slid"
    assert seen["ids"] == list(IDS) and seen["start"] == 2 and seen["plotter"] is p
    seen["show"](4)
    np.testing.assert_allclose(_data(p, "arm").points, v.vertices[4])
    assert "depth" in p.renderer.actors
    assert _text(p, "title") == "armcap  frame 14  median error (all vertices) 2.5 mm"
    assert va.add_arm_time_slider(p, _view(ids=(7, 9))) == "slid" and seen["ids"] == [7, 9]
    va.add_arm_time_slider(p, v, cloud=False)
    assert seen["start"] == 0
    seen["show"](1)
    assert "depth" not in p.renderer.actors
    p.close()


def test_payload_frames_by_linspace_and_the_opening_frame(monkeypatch):
    kinect = _kinect(monkeypatch)
    import bodystudio.viewer.webgl as wg

    session, _ = kinect
    calls = []

    def payload(plotter, include=None, exclude=(), allow_empty=False):
        arm = _data(plotter, "arm").points.copy()
        calls.append((include, exclude, allow_empty, "depth" in plotter.renderer.actors))
        bars = [float(arm[0, 0])] if include is not None else "statics' own"
        return {"objects": [arm], "colorBars": bars, "camera": "cam"}

    monkeypatch.setattr(wg, "scene_payload", payload)
    v = _view(session=session)
    p = sc.make_plotter(window_size=SIZE)
    out = va.arm_payload(v, p, max_frames=3, start=13)
    assert [f["id"] for f in out["frames"]] == [10, 12, 14]
    for f, k in zip(out["frames"], (0, 2, 4), strict=True):
        np.testing.assert_allclose(f["objects"][0], v.vertices[k])
        assert f["colorBars"] == [pytest.approx(0.01 * k)]
    assert out["start"] == 1 and out["colorBars"] == out["frames"][1]["colorBars"]
    assert out["camera"] == "cam"
    np.testing.assert_allclose(out["objects"][0], v.vertices[2])  # the statics drawn at the opening frame
    names = set(va.ARM_LAYERS)
    assert calls[:3] == [(names, (), True, True)] * 3 and calls[3] == (None, names, True, True)
    calls.clear()
    out = va.arm_payload(v, p, cloud=False, max_frames=5)
    assert [f["id"] for f in out["frames"]] == list(IDS) and out["start"] == 0
    assert not any(c[3] for c in calls)
    out = va.arm_payload(v, p, max_frames=4, start=14)
    assert [f["id"] for f in out["frames"]] == [10, 11, 13, 14] and out["start"] == 3
    monkeypatch.setattr("bodystudio.viewer.views.MAX_HTML_FRAMES", 2)
    assert [f["id"] for f in va.arm_payload(v, p)["frames"]] == [10, 14]
    p.close()


def test_is_arm_capture(tmp_path):
    assert not va.is_arm_capture(tmp_path)
    m = tmp_path / "manifest.json"
    m.write_text('{"format": "bodystudio-arm-capture"}')
    assert va.is_arm_capture(tmp_path) and va.is_arm_capture(str(tmp_path))
    m.write_text('{"format": "bodystudio-mirror-run"}')
    assert not va.is_arm_capture(tmp_path)
    m.write_text("[1, 2]")
    assert not va.is_arm_capture(tmp_path)
    m.write_text("{not json")
    assert not va.is_arm_capture(tmp_path)
    m.unlink()
    m.mkdir()
    assert not va.is_arm_capture(tmp_path)


def _capture(session_path="S", n=4):
    V = np.stack([QUAD, QUAD + 0.01])[:, :n]
    return SimpleNamespace(vertices=V, faces=F2, frame_ids=[np.int64(5), np.int64(6)], session_path=session_path)


def test_open_arm_view_reads_the_session_truth_and_mask(monkeypatch, caplog):
    import bodystudio.capture.session as cs
    import bodystudio.muscle.capture as mc
    import bodystudio.muscle.synthetic as ms
    from bodystudio.geometry.mesh import Mesh

    opened, templates = [], []
    gt = {5: Mesh(QUAD + 0.002, F2), 6: Mesh(QUAD + 0.012, F2)}

    def session(path):
        opened.append(str(path))
        if str(path) == "gone":
            raise SessionError("gone: no session.json")
        frames = {"S": (5, 6), "S1": (5,), "small": (5, 6)}[str(path)]
        mesh = (lambda f: Mesh(QUAD[:3] + 0.002, F2[:1])) if str(path) == "small" else gt.get
        return SimpleNamespace(frame_ids=frames, frame=lambda f: SimpleNamespace(gt_arm_mesh=mesh(f)), path=str(path))

    def template(s):
        templates.append(s.path)
        if s.path == "S1":
            raise SessionError("no template")
        return SimpleNamespace(arm_mask=np.array([True, True, False, True]))

    cap = {"c": _capture()}
    loaded = []
    monkeypatch.setattr(mc, "load_arm_capture", lambda p: loaded.append(p) or cap["c"])
    monkeypatch.setattr(cs, "open_session", session)
    monkeypatch.setattr(ms, "session_arm_template", template)
    v = va.open_arm_view("caps/a")
    assert v.path == Path("caps/a") and v.frame_ids == (5, 6) and all(type(f) is int for f in v.frame_ids)
    assert v.vertices is cap["c"].vertices and v.faces is F2 and v.session.path == "S"
    np.testing.assert_allclose(v.truth, np.stack([QUAD + 0.002, QUAD + 0.012]))
    np.testing.assert_array_equal(v.arm_mask, [True, True, False, True])
    assert opened == ["S"] and templates == ["S"] and loaded == [Path("caps/a")]
    v = va.open_arm_view("caps/a", session_path="S1")  # the given session over the recorded one; frame 6 not in it
    assert opened[-1] == "S1" and v.truth is None and v.arm_mask is None and v.session.path == "S1"
    v = va.open_arm_view("caps/a", session_path="small")  # ground truth of another topology
    assert v.truth is None and v.arm_mask is None and v.session is not None
    with caplog.at_level(logging.WARNING):
        v = va.open_arm_view("caps/a", session_path="gone")
    assert v.session is None and v.truth is None
    assert [r.name for r in caplog.records if r.levelno == logging.WARNING] == ["bodystudio.viewer.arm"]
    assert [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING] == [
        "caps/a: its session is not readable (gone: no session.json); showing the capture alone"]
    cap["c"] = _capture(session_path=None)
    n = len(opened)
    v = va.open_arm_view("caps/a")
    assert len(opened) == n and v.session is None and v.truth is None
    # a template that cannot be read: the truth without the mask
    gt_s1 = {5: Mesh(QUAD + 0.002, F2), 6: Mesh(QUAD + 0.012, F2)}

    def session_all(path):
        return SimpleNamespace(frame_ids=(5, 6), frame=lambda f: SimpleNamespace(gt_arm_mesh=gt_s1[f]), path="S1")

    monkeypatch.setattr(cs, "open_session", session_all)
    cap["c"] = _capture()
    v = va.open_arm_view("caps/a")
    assert v.truth is not None and v.arm_mask is None
