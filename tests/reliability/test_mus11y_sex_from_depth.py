"""``muscle capture`` without ``--shape``: the subject's sex from the depth when the model knows women
(``CaptureOptions.sex_from_depth``; docs/muscle.md, "The sex from the depth"). With a model of men only the capture is
today's (taken as male, with the warning); with a model of both sexes the chosen sex and its evidence (the two held-out
depth energies) are in params.json and plausibility.json (``sex_fit``) and on stdout; an ambiguous choice warns with
the figures; ``--shape`` with the sex runs no fit; a damaged ``sex_fit`` in params.json is refused naming the file."""

from __future__ import annotations

import json

import numpy as np
import pytest

from bodystudio.errors import FileFormatError, InputError
from tests.reliability.conftest import assert_clean_error, run_inprocess

FRAMES = 3  # the held-out depth energy takes every 4th frame from the third


@pytest.fixture(scope="module")
def models(tmp_path_factory):
    """2k left-arm models of three training men (one base-pose mesh, four poses each) alone and with two women."""
    from bodystudio.body import build_body
    from bodystudio.muscle.arm import arm_template
    from bodystudio.muscle.model import learn_arm_model, save_arm_model
    from bodystudio.muscle.synthetic import training_dataset

    template = arm_template(build_body(resolution="2k"), "left")
    men, _ = training_dataset("2k", n_subjects=3, n_shapes=1, n_poses=4)
    women, _ = training_dataset("2k", n_subjects=0, n_shapes=1, n_poses=4, n_women=2)
    root = tmp_path_factory.mktemp("sexmodels")
    out = {}
    for name, samples in (("men", men), ("mixed", men + women)):
        out[name] = root / f"{name}.npz"
        save_arm_model(out[name], learn_arm_model(samples, template, population_size=12))
    return out


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    from bodystudio.muscle.synthetic import synth_arm_session

    path = tmp_path_factory.mktemp("sexsession") / "S"
    synth_arm_session(path, subject_seed=518, n_frames=FRAMES, resolution="2k")
    return path


def _capture(session, model, out, capfd, *extra):
    return run_inprocess(["muscle", "capture", session, "--out", out, "--model", model, "--no-refine",
                          "--no-sequence-fit", *extra], capfd)


def test_a_model_of_men_takes_the_subject_as_male_and_says_so(session, models, tmp_path, capfd):
    out = tmp_path / "cap"
    result = _capture(session, models["men"], out, capfd)
    assert_clean_error(result, 0, "")
    params = json.loads((out / "params.json").read_text())
    assert params["sex_fit"] is None and params["shape"]["sex"] == 1.0
    verdict = json.loads((out / "plausibility.json").read_text())
    assert "sex_fit" not in verdict["figures"]
    assert any(w.startswith("the subject's sex was not given (--shape): assumed like every training subject of the "
                            "model (men only)") for w in verdict["warnings"]), verdict["warnings"]
    assert "sex from the depth" not in result.stdout


def test_a_model_of_both_sexes_records_the_sex_it_chose_and_why(session, models, tmp_path, capfd):
    out = tmp_path / "cap"
    result = _capture(session, models["mixed"], out, capfd)
    assert_clean_error(result, 0, "")
    params = json.loads((out / "params.json").read_text())
    fit = params["sex_fit"]
    assert set(fit) == {"sex", "chosen", "energy_mm", "margin_mm", "ambiguous"}, fit
    assert fit["chosen"] == ("female" if fit["sex"] == 0.0 else "male") and params["shape"]["sex"] == fit["sex"]
    male, female = fit["energy_mm"]["male"], fit["energy_mm"]["female"]
    assert 0 < min(male, female) < 50 and (fit["sex"] == 0.0) == (female < male)
    assert fit["ambiguous"] == (abs(male - female) <= fit["margin_mm"])
    verdict = json.loads((out / "plausibility.json").read_text())
    assert verdict["figures"]["sex_fit"] == fit
    assert f"the subject's sex from the depth: {fit['chosen']}" in result.stdout
    assert not any("taken as male" in w for w in verdict["warnings"]), verdict["warnings"]
    from bodystudio.muscle.capture import load_arm_capture

    assert load_arm_capture(out).sex_fit == fit


def test_a_given_sex_is_not_fitted(session, models, tmp_path, capfd):
    out = tmp_path / "cap"
    shape = "bmi=20,muscularity=0.5,height_m=1.58,arm_length_m=0.45,sex=female"
    result = _capture(session, models["mixed"], out, capfd, "--shape", shape)
    assert_clean_error(result, 0, "")
    params = json.loads((out / "params.json").read_text())
    assert params["sex_fit"] is None and params["shape"]["sex"] == 0.0
    assert "sex from the depth" not in result.stdout and "sex" not in result.stderr


def test_an_ambiguous_sex_is_warned_with_its_figures():
    from bodystudio.muscle.capture import sex_from_depth_energies
    from bodystudio.muscle.plausibility import capture_verdict

    both = {"sex": {"value": 0.0, "range": [0.0, 1.0], "outside": 0.0}}
    clear = sex_from_depth_energies({1.0: 4.52, 0.0: 3.45}, 0.02)
    assert clear == {"sex": 0.0, "chosen": "female", "energy_mm": {"male": 4.52, "female": 3.45}, "margin_mm": 0.02,
                     "ambiguous": False}
    assert capture_verdict({"shape": both, "shape_given": False, "sex_fit": clear}, "left")["warnings"] == []
    close = sex_from_depth_energies({1.0: 3.911, 0.0: 3.902}, 0.02)
    assert close["chosen"] == "female" and close["ambiguous"]
    warnings = capture_verdict({"shape": both, "shape_given": False, "sex_fit": close}, "left")["warnings"]
    assert len(warnings) == 1 and "as a man the held-out depth energy is 3.911 mm, as a woman 3.902 mm" in \
        warnings[0] and "taken as female" in warnings[0] and "give --shape with the subject's sex" in warnings[0]
    # a tie is a man (the paper's subjects), and ambiguous
    assert sex_from_depth_energies({1.0: 3.9, 0.0: 3.9}, 0.0) == {
        "sex": 1.0, "chosen": "male", "energy_mm": {"male": 3.9, "female": 3.9}, "margin_mm": 0.0, "ambiguous": True}


def test_candidate_sexes():
    from types import SimpleNamespace

    from bodystudio.muscle.capture import CaptureOptions, candidate_sexes

    rows = lambda *sexes: SimpleNamespace(shape_rows=np.array([[22, 0.5, 1.7, 0.5, s] for s in sexes], float))  # noqa: E731
    o = CaptureOptions()
    assert candidate_sexes(rows(1.0, 1.0), o) == (1.0,)  # the paper's all-male model: as before
    assert candidate_sexes(rows(1.0, 0.0), o) == (1.0, 0.0)
    assert candidate_sexes(rows(1.0, 0.0), CaptureOptions(sex_from_depth=False)) == (1.0,)
    assert candidate_sexes(rows(1.0, 0.0), o, SimpleNamespace(sex=0.0)) == (0.0,)
    with pytest.raises(InputError, match="sex_margin_mm must be >= 0"):
        CaptureOptions(sex_margin_mm=-0.1)
    with pytest.raises(InputError, match="sex_margin_mm must be >= 0"):
        CaptureOptions(sex_margin_mm=float("nan"))


def test_a_damaged_sex_fit_is_refused_naming_the_folder(tmp_path):
    from bodystudio.muscle.capture import ArmCapture, load_arm_capture, write_arm_capture

    V = np.array([[[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0], [0, 0, 0.1]]], float)
    F = np.array([[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]])
    sex_fit = {"sex": 0.0, "chosen": "female", "energy_mm": {"male": 4.5, "female": 3.4}, "margin_mm": 0.02,
               "ambiguous": False}
    out = write_arm_capture(tmp_path / "cap", ArmCapture(V, F, [None], None, (1.0, np.eye(3), np.zeros(3)), "nicp",
                                                         "k", sex_fit=sex_fit))
    assert load_arm_capture(out).sex_fit == sex_fit
    params = json.loads((out / "params.json").read_text())
    (out / "params.json").write_text(json.dumps({**params, "sex_fit": "female"}))
    with pytest.raises(FileFormatError, match="not a readable arm capture folder.*sex_fit 'female' is not a record"):
        load_arm_capture(out)
