"""Arm capture folders edited or damaged after ``muscle capture`` (adversarial pass): a NaN or unknown
fitted shape in params.json is refused with one line by ``muscle model extend`` / ``eval muscle`` instead of
being learnt into a model that ``muscle model info`` then refuses (exit 0 before), or a traceback."""

import json
import shutil

import pytest

from bodystudio.cli.main import main

from .conftest import run_bad


@pytest.fixture(scope="module")
def model_capture(tiny_arm_model_path, tmp_path_factory):
    root = tmp_path_factory.mktemp("advcap")
    session = root / "session"
    assert main(["synth", "arm", str(session), "--subject-seed", "5", "--frames", "2", "--resolution", "2k"]) == 0
    out = root / "cap"
    assert main(["muscle", "capture", str(session), "--out", str(out), "--model", str(tiny_arm_model_path)]) == 0
    return out


def edited_capture(capture, tmp_path, edit):
    """A copy of the capture whose params.json names no session (so extend takes the fitted shape) and is
    changed by ``edit(params)``."""
    copy = tmp_path / "edited"
    shutil.copytree(capture, copy)
    params = json.loads((copy / "params.json").read_text())
    params["session"] = None
    edit(params)
    (copy / "params.json").write_text(json.dumps(params))
    return copy


@pytest.mark.parametrize("edit, phrase", [
    (lambda p: p["shape"].update(bmi=float("nan")), "shape is NaN or infinite"),
    (lambda p: p["shape"].update(height_m=float("inf")), "shape is NaN or infinite"),
    (lambda p: p["shape"].update(weight=80.0), "unknown names ['weight']"),
    (lambda p: p["similarity"].update(scale=float("nan")), "similarity is NaN"),
])
def test_extend_refuses_a_capture_with_a_broken_fitted_shape(model_capture, tiny_arm_model_path, tmp_path, capsys,
                                                              edit, phrase):
    capture = edited_capture(model_capture, tmp_path, edit)
    out = tmp_path / "m2.npz"
    run_bad(["muscle", "model", "extend", tiny_arm_model_path, capture, "--out", out], capsys, phrase)
    assert not out.exists()
    run_bad(["eval", "muscle", capture, "--session", tmp_path / "none"], capsys, phrase)


def test_extend_of_the_unedited_capture_still_works(model_capture, tiny_arm_model_path, tmp_path, capsys):
    capture = edited_capture(model_capture, tmp_path, lambda p: None)
    out = tmp_path / "m2.npz"
    assert main(["muscle", "model", "extend", str(tiny_arm_model_path), str(capture), "--out", str(out)]) == 0
    assert main(["muscle", "model", "info", str(out)]) == 0
    assert '"n_subjects": 3' in capsys.readouterr().out


def test_extend_refuses_two_captures_of_one_recording(model_capture, tiny_arm_model_path, tmp_path, capsys):
    """A copied capture folder (another name) added beside the original: one subject learnt twice, exit 0
    before (the name check only sees folder names)."""
    copy = tmp_path / "copy_of_cap"
    shutil.copytree(model_capture, copy)
    out = tmp_path / "m2.npz"
    run_bad(["muscle", "model", "extend", tiny_arm_model_path, model_capture, copy, "--out", out], capsys,
            "a capture of the same recording as")
    assert not out.exists()


def test_eval_muscle_prints_strict_json_for_a_two_frame_capture(model_capture, capsys):
    """jitter_mm needs three frames: a 2-frame capture printed "jitter_mm": NaN (not JSON) with exit 0; now null."""
    capsys.readouterr()
    assert main(["eval", "muscle", str(model_capture)]) == 0
    scores = json.loads(capsys.readouterr().out, parse_constant=lambda c: pytest.fail(f"{c} in the JSON"))
    assert scores["jitter_mm"] is None and scores["median_mm"] > 0
