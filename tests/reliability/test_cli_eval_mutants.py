"""``bodystudio eval mirror / garment / reconstruct / rig`` through typer's CliRunner with the scorers replaced by
spies (mutNN): the figures users trust.

Each command must hand its arguments to the scorer unchanged (defaults as the help says), print the scorer's
figures as strict JSON (the printed text read back with ``json.loads`` and compared with hand-written values: the
rounding, the key order, NaN / inf refused rather than printed as non-JSON) and fail rather than print a partial
line. No session is read and nothing is scored: the file runs in about a second.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from types import SimpleNamespace

import pytest

from tests.reliability.cli_spies import invoke as _invoke
from tests.reliability.cli_spies import spy as _spy


def _help(args) -> str:
    res = _invoke([*args, "--help"])
    assert res.exit_code == 0, res.output
    return " ".join(res.stdout.replace("│", " ").split())


# ------------------------------------------------------------------------------------------------ eval mirror

def test_eval_mirror_prints_the_scores_as_indented_json(tmp_path, monkeypatch):
    scores = {"fg_iou": 0.912345, "psnr_person": None, "psnr_person_identical": True, "frames": [1, 2]}
    spy = _spy(monkeypatch, "bodystudio.mirror.evaluate.evaluate_mirror", ret=scores)
    res = _invoke(["eval", "mirror", tmp_path / "s"])
    assert res.exit_code == 0, (res.output, res.exception)
    assert spy.calls == [((tmp_path / "s", None), {})]
    assert res.stdout == json.dumps(scores, indent=2) + "\n"
    assert res.stdout.startswith('{\n  "fg_iou": 0.912345,\n  "psnr_person": null')
    res = _invoke(["eval", "mirror", tmp_path / "s", "--run", tmp_path / "r"])
    assert res.exit_code == 0 and spy.calls[1] == ((tmp_path / "s", tmp_path / "r"), {})


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_eval_mirror_never_prints_a_non_json_number(tmp_path, monkeypatch, bad):
    _spy(monkeypatch, "bodystudio.mirror.evaluate.evaluate_mirror", ret={"fg_iou": 0.9, "psnr_person": bad})
    res = _invoke(["eval", "mirror", tmp_path / "s"])
    assert res.exit_code != 0 and isinstance(res.exception, ValueError)
    assert res.stdout == ""


def test_eval_mirror_help():
    text = _help(["eval", "mirror"])
    for phrase in ("synthetic mirror session (bodystudio synth mirror)",
                   "run folder of `bodystudio mirror run` (default SESSION/mirror/run)",
                   "Score a mirror run against the session's ground truth: init, tracking, foreground, warp, "
                   "PSNR/SSIM, timings."):
        assert f" {phrase} " in f" {text} ", phrase


# ------------------------------------------------------------------------------------------------ eval garment

def test_eval_garment_prints_the_scores_as_indented_json(tmp_path, monkeypatch):
    scores = {"stature_err_mm": 4.5, "composite": {"psnr_person": 27.25}}
    spy = _spy(monkeypatch, "bodystudio.garment.evaluate.evaluate_garment", ret=scores)
    res = _invoke(["eval", "garment", tmp_path / "fit"])
    assert res.exit_code == 0, (res.output, res.exception)
    assert spy.calls == [((tmp_path / "fit", None), {})]
    assert res.stdout == ('{\n  "stature_err_mm": 4.5,\n  "composite": {\n    "psnr_person": 27.25\n  }\n}\n')
    res = _invoke(["eval", "garment", tmp_path / "fit", "--session", tmp_path / "s"])
    assert res.exit_code == 0 and spy.calls[1] == ((tmp_path / "fit", tmp_path / "s"), {})


@pytest.mark.parametrize("bad", [math.nan, math.inf])
def test_eval_garment_never_prints_a_non_json_number(tmp_path, monkeypatch, bad):
    _spy(monkeypatch, "bodystudio.garment.evaluate.evaluate_garment", ret={"psnr_person": bad})
    res = _invoke(["eval", "garment", tmp_path / "fit"])
    assert res.exit_code != 0 and isinstance(res.exception, ValueError) and res.stdout == ""


def test_eval_garment_help():
    text = _help(["eval", "garment"])
    for phrase in ("fit folder of `bodystudio garment fit`", "synthetic session (default: the fit's source)",
                   "Score a garment fit against the synthetic session's ground truth (JSON): stature, joints, "
                   "light, albedo, silhouette IoU, ms per frame; plus the composite's scores when "
                   "DIR/render/render.json exists."):
        assert f" {phrase} " in f" {text} ", phrase


def test_eval_group_lists_its_commands():
    text = _help(["eval"])
    for name in ("mirror", "garment", "reconstruct", "rig", "calib", "muscle"):
        assert f" {name} " in text, name
    res = _invoke(["eval"])
    assert res.exit_code != 0 and "Usage:" in res.output  # no_args_is_help


# ------------------------------------------------------------------------------------------------ eval reconstruct

def test_eval_reconstruct_rounds_and_orders_the_figures(tmp_path, monkeypatch):
    s = {"frames": 3, "iou_min": 0.9123456, "extra": 1.23456, "median_mm": 12.34567, "p90_mm": 20.0004,
         "hausdorff_mm": 40.12349, "pct_under_10mm": 55.55555, "ms_per_frame": 250.12345, "note": "x",
         "per_frame": [1.23456]}
    spy = _spy(monkeypatch, "bodystudio.reconstruct.sequence.evaluate_session", ret=dict(s))
    res = _invoke(["eval", "reconstruct", tmp_path / "sess"])
    assert res.exit_code == 0, (res.output, res.exception)
    assert spy.calls == [((tmp_path / "sess",), {})]
    out = json.loads(res.stdout)
    assert list(out.items()) == [("median_mm", 12.346), ("p90_mm", 20.0), ("hausdorff_mm", 40.123),
                                 ("pct_under_10mm", 55.556), ("iou_min", 0.912), ("ms_per_frame", 250.123),
                                 ("frames", 3), ("extra", 1.235), ("note", "x"), ("per_frame", [1.23456])]
    assert res.stdout.count("\n") == 1  # one line


def test_eval_reconstruct_without_some_figures(tmp_path, monkeypatch):
    _spy(monkeypatch, "bodystudio.reconstruct.sequence.evaluate_session",
         ret={"median_mm": 1.0, "frames": 2, "ms_per_frame": 3.00049})
    res = _invoke(["eval", "reconstruct", tmp_path / "sess"])
    assert list(json.loads(res.stdout).items()) == [("median_mm", 1.0), ("ms_per_frame", 3.0), ("frames", 2)]


def test_eval_reconstruct_help():
    text = _help(["eval", "reconstruct"])
    assert " session folder with a reconstruct/ result " in f" {text} "
    assert " Score SESSION/reconstruct/ meshes against ground truth; prints JSON. " in f" {text} "


# ------------------------------------------------------------------------------------------------ eval rig

def test_eval_rig_passes_the_scan_transform_and_adds_the_seconds(tmp_path, monkeypatch):
    av = SimpleNamespace(metadata={"scan": {"to_canonical": [[1, 0], [0, 1]]}, "seconds": 12.5})
    load = _spy(monkeypatch, "bodystudio.rig.evaluate.load_avatar", ret=av)
    gt = _spy(monkeypatch, "bodystudio.register.synthetic.load_ground_truth", ret="GT")
    evaluate = _spy(monkeypatch, "bodystudio.rig.evaluate.evaluate_rig", ret={"joint_err_mm_mean": 17.25})
    res = _invoke(["eval", "rig", tmp_path / "a.glb", "--gt", tmp_path / "a.gt"])
    assert res.exit_code == 0, (res.output, res.exception)
    assert load.calls == [((tmp_path / "a.glb",), {})]
    assert gt.calls == [((tmp_path / "a.gt",), {})]
    assert evaluate.calls == [((av, "GT", [[1, 0], [0, 1]]), {})]
    assert res.stdout == '{\n  "joint_err_mm_mean": 17.25,\n  "seconds": 12.5\n}\n'


def test_eval_rig_without_scan_metadata(tmp_path, monkeypatch):
    av = SimpleNamespace(metadata={})
    _spy(monkeypatch, "bodystudio.rig.evaluate.load_avatar", ret=av)
    _spy(monkeypatch, "bodystudio.register.synthetic.load_ground_truth", ret="GT")
    evaluate = _spy(monkeypatch, "bodystudio.rig.evaluate.evaluate_rig", ret={"x": 1})
    res = _invoke(["eval", "rig", tmp_path / "a.glb", "--gt", tmp_path / "a.gt"])
    assert res.exit_code == 0, (res.output, res.exception)
    assert evaluate.calls == [((av, "GT", None), {})]
    assert json.loads(res.stdout) == {"x": 1, "seconds": None}


def test_eval_rig_needs_gt(tmp_path, monkeypatch):
    load = _spy(monkeypatch, "bodystudio.rig.evaluate.load_avatar")
    res = _invoke(["eval", "rig", tmp_path / "a.glb"])
    assert res.exit_code == 2 and "--gt" in res.output and not load.calls


def test_eval_rig_help():
    text = _help(["eval", "rig"])
    for phrase in ("avatar .glb written by bodystudio rig", "ground-truth folder OUT.gt/ of the synthetic scan",
                   "Score a rigged avatar against its synthetic scan's ground truth; prints JSON."):
        assert f" {phrase} " in f" {text} ", phrase


def test_eval_commands_are_one_module_each():
    """The eval group's commands are the stage modules' functions (not copies)."""
    from bodystudio.cli import eval as eval_cli
    from bodystudio.cli import reconstruct, rig

    callbacks = {c.name: c.callback for c in eval_cli.app.registered_commands}
    assert callbacks["mirror"] is eval_cli.eval_mirror and callbacks["garment"] is eval_cli.eval_garment
    assert callbacks["reconstruct"] is reconstruct.eval_reconstruct and callbacks["rig"] is rig.eval_rig
    assert Path(eval_cli.__file__).name == "eval.py"
