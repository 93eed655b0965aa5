"""viewer/garment.py: what a fit folder opens as, the garment it is dressed in and its fitted scene (mutOO; < 1 s).

``open_garment_view`` on folders written here with the fit, render and session readers replaced by spies (each
part missing, damaged or present, its note whole); ``garment_choice``'s three sources; ``fitted_scene`` on a
stand-in fit and body (the pose of the frame's index, the albedo normalised by its 99th percentile by hand).
"""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from bodystudio.errors import FileFormatError, SessionError
from bodystudio.viewer import garment as vg


def _folder(tmp_path, render=True, eval_text=None, source="S"):
    fit = tmp_path / "fit"
    fit.mkdir()
    (fit / "fit.json").write_text(json.dumps({"format": "bodystudio-garment-fit"}))
    if render:
        (fit / "render").mkdir()
        (fit / "render" / "render.json").write_text(json.dumps({"format": "bodystudio-garment-render"}))
    if eval_text is not None:
        (fit / "eval.json").write_text(eval_text)
    return fit


def _readers(monkeypatch):
    import bodystudio.capture.session as cs
    import bodystudio.garment.composite as gc
    import bodystudio.garment.fitfile as gf

    seen = {}

    def fit(path):
        seen.setdefault("fit", []).append(Path(path))
        return SimpleNamespace(source=seen.get("source", "S"))

    def render(path):
        seen.setdefault("render", []).append(Path(path))
        if seen.get("render_error"):
            raise FileFormatError("render.json: damaged")
        return {"garment": "dress"}

    def session(path):
        seen.setdefault("session", []).append(Path(path))
        if seen.get("session_error"):
            raise SessionError("S: no session.json")
        return "the session"

    monkeypatch.setattr(gf, "load_garment_fit", fit)
    monkeypatch.setattr(gc, "load_render", render)
    monkeypatch.setattr(cs, "open_session", session)
    return seen


def test_open_garment_view_reads_every_part(tmp_path, monkeypatch):
    readers = _readers(monkeypatch)
    fit = _folder(tmp_path, eval_text='{"iou": 0.9}')
    (tmp_path / "S").mkdir()
    monkeypatch.chdir(tmp_path)
    v = vg.open_garment_view(fit / "render")  # the render folder opens its fit
    assert v.fit_dir == fit and readers["fit"] == [fit] and readers["render"] == [fit]
    assert v.render == {"garment": "dress"} and v.session == "the session" and readers["session"] == [Path("S")]
    assert v.saved_scores == {"iou": 0.9} and v.notes == ()
    assert v.render_dir == fit / "render" and v.name == "fit" and v.has_source


def test_open_garment_view_notes_what_is_missing(tmp_path, monkeypatch):
    readers = _readers(monkeypatch)
    monkeypatch.chdir(tmp_path)
    fit = _folder(tmp_path, render=False, eval_text="[1]")
    v = vg.open_garment_view(str(fit))
    assert v.render is None and v.session is None and v.saved_scores is None and not v.has_source
    assert v.notes == (f"no render yet: run 'bodystudio garment render {fit} --out OUT.mp4' for the composite",
                       f"the fit's source {fit / 'S'} is gone: no input frames or ground truth",
                       f"{fit / 'eval.json'}: not a JSON object; rerun 'bodystudio eval garment'")
    (fit / "render").mkdir()
    (fit / "eval.json").write_text("{bad")
    (tmp_path / "S").mkdir()
    readers.update(render_error=True, session_error=True)
    v = vg.open_garment_view(fit)
    assert v.render is None and v.session is None and v.saved_scores is None
    assert v.notes == ("render not shown: render.json: damaged",
                       "the fit's source session is unreadable, no input frames or truth: S: no session.json",
                       f"{fit / 'eval.json'}: not valid JSON (JSONDecodeError); rerun 'bodystudio eval garment'")
    (tmp_path / "S").rmdir()
    (tmp_path / "S").write_bytes(b"video")  # a video file: a source, no session
    (fit / "eval.json").unlink()
    v = vg.open_garment_view(fit)
    assert v.session is None and v.has_source and v.notes == ("render not shown: render.json: damaged",)


def test_open_garment_view_refuses_a_folder_without_a_fit(tmp_path, monkeypatch):
    _readers(monkeypatch)
    with pytest.raises(SessionError) as e:
        vg.open_garment_view(tmp_path)
    assert str(e.value) == (f"{tmp_path}: not a garment fit folder (no fit.json); run 'bodystudio garment fit VIDEO "
                            f"--stature S --out {tmp_path}' first")
    render = tmp_path / "x"
    render.mkdir()
    (render / "render.json").write_text(json.dumps({"format": "bodystudio-garment-render"}))
    with pytest.raises(SessionError, match=rf"^{tmp_path}: not a garment fit folder"):
        vg.open_garment_view(render)


def test_garment_choice_render_then_target_then_default():
    def view(render=None, gt=None, session=True):
        return SimpleNamespace(render=render, session=SimpleNamespace(gt_garment=gt) if session else None)

    assert vg.garment_choice(view({"garment": "dress", "texture": "dots", "seed": "3", "texture_size": 128.0})) == (
        "dress", "dots", 3, 128)
    assert vg.garment_choice(view({"garment": "dress"})) == ("dress", "stripes", 0, 512)
    target = {"target": {"name": "skirt", "pattern": "checks", "seed": 2}, "texture_size": 64}
    assert vg.garment_choice(view({"garment": ""}, target)) == ("skirt", "checks", 2, 64)
    assert vg.garment_choice(view(None, {"target": {"name": "skirt", "pattern": "checks"}})) == (
        "skirt", "checks", 0, 256)
    assert vg.garment_choice(view(None, {"other": 1})) == vg.DEFAULT_GARMENT
    assert vg.garment_choice(view(None, None)) == vg.DEFAULT_GARMENT
    assert vg.garment_choice(view(None, session=False)) == vg.DEFAULT_GARMENT


def test_fitted_scene_poses_the_frames_body_and_garment(monkeypatch):
    import bodystudio.body.skinning as sk
    import bodystudio.garment.garments as gg

    V = np.arange(12.0).reshape(4, 3)
    body = SimpleNamespace(faces=[[0, 1, 2]], skeleton="skel", pose=lambda pose: (V + pose, None))
    albedo = np.linspace(0.0, 2.0, 4)
    fit = SimpleNamespace(frame_ids=[4, 6, 8], fitted=[True] * 3, pose=lambda i: 10.0 * i, albedo=albedo,
                          body=lambda: body)
    view = SimpleNamespace(fit=fit, fit_dir=Path("F"), render={"garment": "dress", "texture": "dots", "seed": 1,
                                                               "texture_size": 32}, session=None)
    calls = []
    monkeypatch.setattr(gg, "dress", lambda b, *a: calls.append(("dress", b, a)) or "garment")
    monkeypatch.setattr(gg, "pose_garment", lambda g, b, p: ("posed", g, b is body, p))
    monkeypatch.setattr(sk, "posed_joints", lambda skel, p: (("joints", skel, p), None))
    s = vg.fitted_scene(view, 8)
    np.testing.assert_array_equal(s.body_vertices, V + 20.0)
    np.testing.assert_array_equal(s.body_faces, [[0, 1, 2]])
    assert calls == [("dress", body, ("dress", "dots", 32, 1))] and s.garment == "garment"
    assert s.garment_vertices == ("posed", "garment", True, 20.0) and s.joints == ("joints", "skel", 20.0)
    top = np.percentile(albedo, 99)
    np.testing.assert_array_equal(s.body_colors, np.clip(np.round(255 * albedo / top), 0, 255).astype(np.uint8))
    assert s.body_colors.dtype == np.uint8 and s.body_colors.tolist() == [0, 86, 172, 255]
    other = SimpleNamespace(faces=[[0, 1, 2]], skeleton="s2", pose=lambda pose: (V, None))
    s = vg.fitted_scene(view, 4, body=other, garment="mine")
    assert s.garment == "mine" and len(calls) == 1 and s.garment_vertices[2] is False
    fit.albedo = np.ones(3)  # another size: no colours
    assert vg.fitted_scene(view, 6).body_colors is None
    fit.albedo = None
    assert vg.fitted_scene(view, 6).body_colors is None
    fit.albedo = np.zeros(4)  # all black: no division by zero
    assert vg.fitted_scene(view, 6).body_colors.tolist() == [0, 0, 0, 0]


def test_fitted_scene_colours_of_a_dim_albedo(monkeypatch):
    import bodystudio.body.skinning as sk
    import bodystudio.garment.garments as gg

    V = np.zeros((4, 3))
    body = SimpleNamespace(faces=[[0, 1, 2]], skeleton="s", pose=lambda pose: (V, None))
    fit = SimpleNamespace(frame_ids=[1], fitted=[True], pose=lambda i: 0.0, albedo=np.array([0.0, 0.15, 0.5, 0.5]),
                          body=lambda: body)
    view = SimpleNamespace(fit=fit, fit_dir=Path("F"), render=None, session=None)
    monkeypatch.setattr(gg, "pose_garment", lambda g, b, p: None)
    monkeypatch.setattr(sk, "posed_joints", lambda skel, p: (None, None))
    # the 99th percentile is 0.5, below 1: the brightest still white; 0.3 of it is 76.5 -> 76 (255, not 256, steps)
    assert vg.fitted_scene(view, 1, garment="g").body_colors.tolist() == [0, 76, 255, 255]
    fit.albedo = np.array([-0.25, 0.0, 0.5, 0.5])  # below zero: black, not wrapped round
    assert vg.fitted_scene(view, 1, garment="g").body_colors.tolist() == [0, 0, 255, 255]
