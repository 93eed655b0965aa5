"""``bodystudio synth garment``, ``garment fit`` and ``garment render`` through typer's CliRunner with the API
replaced by spies (mutNN).

Each option must reach the API unchanged (the CLI's defaults equal the API's where both have one), the printed
line / JSON must hold the API's figures (read back with ``json.loads``, compared with hand-written values), and
each refusal must be an :class:`InputError` with its whole message before any work. No video is fitted: the file
runs in about a second.
"""

from __future__ import annotations

import inspect
import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from tests.reliability.cli_spies import Spy
from tests.reliability.cli_spies import invoke as _invoke
from tests.reliability.cli_spies import refused as _refused


def _help(args) -> str:
    res = _invoke([*args, "--help"])
    return " ".join(res.stdout.replace("│", " ").split())


# ------------------------------------------------------------------------------------------------ synth garment

class Session:
    streams = ["rgb", "mask", "gt"]

    def __len__(self):
        return 12


@pytest.fixture
def synth_spy(monkeypatch, tmp_path):
    import bodystudio.garment.synthetic as synthetic

    monkeypatch.chdir(tmp_path)
    spy = Spy(ret=Session())
    spy.real = synthetic.synth_garment_session
    monkeypatch.setattr(synthetic, "synth_garment_session", spy)
    return spy


def test_synth_garment_defaults(synth_spy):
    res = _invoke(["synth", "garment", "g", "--subject-seed", "5"])
    assert res.exit_code == 0, (res.output, res.exception)
    assert synth_spy.calls == [((Path("g"),), dict(subject_seed=5, n_frames=60, garment="tshirt", pattern="stripes",
                                                   motion="walk", resolution=(480, 640), seed=0, noise=True,
                                                   progress=True))]
    api = inspect.signature(synth_spy.real).parameters
    for cli, name in (("n_frames", "n_frames"), ("garment", "garment"), ("pattern", "pattern"), ("motion", "motion"),
                      ("seed", "seed"), ("noise", "noise")):
        assert synth_spy.calls[0][1][cli] == api[name].default, name
    assert res.stdout == ("wrote g: 12 frames of walk wearing a plain tshirt (target: stripes tshirt), streams rgb, "
                          "mask, gt\n")


def test_synth_garment_every_option(synth_spy):
    res = _invoke(["synth", "garment", "g", "--subject-seed", "0", "--frames", "9", "--garment", "skirt", "--pattern",
                   "checks", "--motion", "turn", "--resolution", "320X200", "--seed", "4", "--no-noise"])
    assert res.exit_code == 0, (res.output, res.exception)
    assert synth_spy.calls == [((Path("g"),), dict(subject_seed=0, n_frames=9, garment="skirt", pattern="checks",
                                                   motion="turn", resolution=(320, 200), seed=4, noise=False,
                                                   progress=True))]
    assert res.stdout.startswith("wrote g: 12 frames of turn wearing a plain skirt (target: checks skirt)")


def test_synth_garment_refusals(synth_spy):
    res = _invoke(["synth", "garment", "g"])
    assert res.exit_code == 2 and "--subject-seed" in res.output and not synth_spy.calls
    _refused(_invoke(["synth", "garment", "g", "--subject-seed", "1", "--resolution", "15x100"]),
             "--resolution '15x100' must be WIDTHxHEIGHT in pixels, e.g. 640x480")
    Path("full").mkdir()
    (Path("full") / "x").write_text("x")
    _refused(_invoke(["synth", "garment", "full", "--subject-seed", "1"]),
             "session folder full: exists and is not empty; choose a new folder")
    assert not synth_spy.calls
    Path("empty").mkdir()
    assert _invoke(["synth", "garment", "empty", "--subject-seed", "1"]).exit_code == 0


def test_synth_garment_help():
    text = _help(["synth", "garment"])
    for phrase in ("new session folder", "subject drawn from the population (seed)", "frames at 30 fps",
                   "target garment: tights | skirt | tshirt | longsleeve", "target cloth: stripes | checks | print | "
                   "plain", "walk | arm_flex | turn | arms_raise | a_pose", "camera image WIDTHxHEIGHT",
                   "light, colours, motion variation and sensor noise", "no sensor noise"):
        assert f" {phrase} " in f" {text} ", phrase


# ------------------------------------------------------------------------------------------------ garment fit

@pytest.fixture
def fit_spy(monkeypatch, tmp_path):
    import bodystudio.garment.fit as fit_mod

    monkeypatch.chdir(tmp_path)
    fit = SimpleNamespace(frame_ids=[0, 1, 2, 3], stature_m=1.7523456, silhouette_iou=np.array([0.9, 0.95, 0.91234]),
                          timings_ms={"shape": 10.5}, warnings=("w1", "w2"))
    spy = Spy(ret=fit)
    spy.real = fit_mod.fit_garment_video
    monkeypatch.setattr(fit_mod, "fit_garment_video", spy)
    return spy


def test_garment_fit_defaults_and_output(fit_spy):
    res = _invoke(["garment", "fit", "v.mp4", "--stature", "1.75", "--out", "f"])
    assert res.exit_code == 0, (res.output, res.exception)
    assert fit_spy.calls == [((Path("v.mp4"), 1.75, Path("f")), dict(
        frames=None, template="2k", focal_px=None, keyframes=None, progress=True, background=None,
        shape_refinement=True, pose_refinement=True, clothing_allowance_m=None))]
    api = inspect.signature(fit_spy.real).parameters
    for name in ("frames", "template", "focal_px", "keyframes", "background", "shape_refinement", "pose_refinement",
                 "clothing_allowance_m"):
        assert fit_spy.calls[0][1][name] == api[name].default, name
    assert list(json.loads(res.stdout).items()) == [
        ("out", "f"), ("frames", 4), ("stature_m", 1.7523), ("silhouette_iou_mean", 0.9208),
        ("ms_per_frame", {"shape": 10.5}), ("warnings", ["w1", "w2"])]


def test_garment_fit_every_option(fit_spy):
    Path("k.json").write_text("{}")
    res = _invoke(["garment", "fit", "s", "--stature", "0.5", "--out", "f", "--frames", "2:9", "--template", "6k",
                   "--focal-px", "800", "--background", "bg.png", "--keyframes", "k.json", "--no-shape-refinement",
                   "--no-pose-refinement", "--clothing-mm", "12.5"])
    assert res.exit_code == 0, (res.output, res.exception)
    (args, kw), = fit_spy.calls
    assert args == (Path("s"), 0.5, Path("f"))
    assert kw == dict(frames="2:9", template="6k", focal_px=800.0, keyframes=Path("k.json"), progress=True,
                      background=Path("bg.png"), shape_refinement=False, pose_refinement=False,
                      clothing_allowance_m=pytest.approx(0.0125, abs=1e-15))
    res = _invoke(["garment", "fit", "s", "--stature", "2", "--out", "g", "--clothing-mm", "0"])
    assert fit_spy.calls[1][1]["clothing_allowance_m"] == 0.0


def test_garment_fit_refusals(fit_spy):
    _refused(_invoke(["garment", "fit", "v.mp4", "--out", "f"]),
             "--stature is required: give the actor's stature in metres (e.g. --stature 1.78)")
    _refused(_invoke(["garment", "fit", "v.mp4", "--stature", "1.7", "--out", "f", "--keyframes", "none.json"]),
             "--keyframes none.json: no such file")
    Path("kdir").mkdir()
    _refused(_invoke(["garment", "fit", "v.mp4", "--stature", "1.7", "--out", "f", "--keyframes", "kdir"]),
             "--keyframes kdir: no such file")
    Path("full").mkdir()
    (Path("full") / "x").write_text("x")
    _refused(_invoke(["garment", "fit", "v.mp4", "--stature", "1.7", "--out", "full"]),
             "fit folder full: exists and is not empty; choose a new folder")
    res = _invoke(["garment", "fit", "v.mp4", "--stature", "1.7"])
    assert res.exit_code == 2 and "--out" in res.output
    assert not fit_spy.calls


def test_garment_fit_help():
    text = _help(["garment", "fit"])
    for phrase in ("video file (MP4, MOV, ...) or session folder (cam_00/rgb + mask)",
                   "the actor's stature in metres (0.5-2.5), required", "new fit folder",
                   "frame range START:END (default: all)", "body template: 2k | 6k | full",
                   "focal length in pixels (default: a 40 deg vertical field of view)",
                   "skip the final shape refinement against every frame's silhouette",
                   "thickness of the actor's worn clothes in mm (0-30; the shape refinement's allowance)"):
        assert f" {phrase} " in f" {text} ", phrase


# ------------------------------------------------------------------------------------------------ garment render

DOC = {"frame_ids": [1, 2, 3], "ms_per_frame": {"render": 12.4, "flow": 3.6}, "n_flow_applied": 2,
       "n_hem_applied": 1, "options": {"flow": True}}


@pytest.fixture
def render_spy(monkeypatch, tmp_path):
    import bodystudio.garment.composite as composite

    monkeypatch.chdir(tmp_path)
    Path("fit").mkdir()
    spy = Spy(fn=lambda *a, **k: json.loads(json.dumps(DOC)))
    spy.real = composite.render_garment_video
    monkeypatch.setattr(composite, "render_garment_video", spy)
    return spy


def test_garment_render_defaults_and_line(render_spy):
    res = _invoke(["garment", "render", "fit", "--out", "o.mp4"])
    assert res.exit_code == 0, (res.output, res.exception)
    assert render_spy.calls == [((Path("fit"), "tshirt", "stripes", Path("o.mp4")),
                                 dict(flow=True, rbf=True, depth=True, seed=0, progress=True, hem=True))]
    api = inspect.signature(render_spy.real).parameters
    for name in ("flow", "rbf", "depth", "seed", "hem", "garment", "texture"):
        value = render_spy.calls[0][1].get(name, {"garment": "tshirt", "texture": "stripes"}.get(name))
        assert value == api[name].default, name
    assert res.stdout == ("wrote fit/render and o.mp4: 3 frames of stripes tshirt (ms per frame: render 12, flow 4; "
                          "flow correction used in 2 of them, hem matte in 1)\n")


def test_garment_render_every_option(render_spy, monkeypatch):
    doc = dict(DOC, options={"flow": False})
    render_spy.fn = lambda *a, **k: doc
    res = _invoke(["garment", "render", "fit", "--out", "o.MP4", "--garment", "skirt", "--texture", "checks",
                   "--no-flow", "--no-rbf", "--no-depth", "--no-hem", "--seed", "7"])
    assert res.exit_code == 0, (res.output, res.exception)
    assert render_spy.calls == [((Path("fit"), "skirt", "checks", Path("o.MP4")),
                                 dict(flow=False, rbf=False, depth=False, seed=7, progress=True, hem=False))]
    assert res.stdout.endswith("flow correction used in 2 of them, hem matte in 1, --no-flow)\n")


def test_garment_render_refusals(render_spy):
    _refused(_invoke(["garment", "render", "fit", "--out", "o.mp4", "--garment", "cape"]),
             "--garment 'cape': valid: tights, skirt, tshirt, longsleeve")
    _refused(_invoke(["garment", "render", "fit", "--out", "o.avi"]), "--out o.avi: the video must be an .mp4 file")
    _refused(_invoke(["garment", "render", "nofit", "--out", "o.mp4"]),
             "nofit: no such fit folder; run 'bodystudio garment fit VIDEO --out nofit' first")
    Path("afile").write_text("x")
    _refused(_invoke(["garment", "render", "afile", "--out", "o.mp4"]),
             "afile: no such fit folder; run 'bodystudio garment fit VIDEO --out afile' first")
    # the options are checked before the folder
    _refused(_invoke(["garment", "render", "nofit", "--out", "o.mp4", "--seed", "-1"]),
             "--seed -1: must be in [0, 2^32)")
    assert not render_spy.calls


def test_garment_render_help():
    text = _help(["garment", "render"])
    for phrase in ("garment fit folder (from 'bodystudio garment fit')", "tights | skirt | tshirt | longsleeve",
                   "cloth pattern: stripes | checks | print | plain", "output video (.mp4)",
                   "skip the optical-flow motion correction (§7.1)", "skip the silhouette RBF warp (§7.2)",
                   "no depth compositing: the garment over everything", "cloth colours"):
        assert f" {phrase} " in f" {text} ", phrase
