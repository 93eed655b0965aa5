"""Bad input for the extension options (issue 11, sixth pass): ``muscle capture --for-extension`` and
``muscle model extend --centre`` / ``--captured-rest`` / ``--shape-form`` / ``--subject-rows``: one line, exit 2,
nothing written."""

import pytest

from .conftest import run_bad


@pytest.fixture(scope="module")
def arm_session(tmp_path_factory):
    from bodystudio.cli.main import main

    out = tmp_path_factory.mktemp("arm") / "session"
    assert main(["synth", "arm", str(out), "--subject-seed", "5", "--frames", "3", "--resolution", "2k"]) == 0
    return out


@pytest.mark.parametrize("args, phrase", [
    (["--no-model", "--for-extension"], "--for-extension with --no-model"),
    (["--model", "M", "--no-sequence-fit", "--for-extension"], "--for-extension with --no-sequence-fit"),
])
@pytest.mark.parametrize("batch", [False, True])
def test_capture_for_extension_conflicts(arm_session, tiny_arm_model_path, tmp_path, capsys, args, phrase, batch):
    args = [str(tiny_arm_model_path) if a == "M" else a for a in args]
    sessions = [arm_session, arm_session.parent] if batch else [arm_session]  # batch: refused before a cluster
    run_bad(["muscle", "capture", *sessions, "--out", tmp_path / "cap", *args], capsys, phrase)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("value", ["elbow", "", "SEX"])
def test_extend_refuses_an_unknown_centre(tiny_arm_model_path, tmp_path, capsys, value):
    run_bad(["muscle", "model", "extend", tiny_arm_model_path, tmp_path, "--out", tmp_path / "m2.npz",
             "--centre", value], capsys, f"--centre {value!r}: valid: sex, fitted, regressed")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("value", ["surface", "", "BODY"])
def test_extend_refuses_an_unknown_captured_rest(tiny_arm_model_path, tmp_path, capsys, value):
    run_bad(["muscle", "model", "extend", tiny_arm_model_path, tmp_path, "--out", tmp_path / "m2.npz",
             "--captured-rest", value], capsys, f"--captured-rest {value!r}: valid: body, mesh")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("value", ["kernel", "", "BODY"])
def test_extend_refuses_an_unknown_shape_form(tiny_arm_model_path, tmp_path, capsys, value):
    run_bad(["muscle", "model", "extend", tiny_arm_model_path, tmp_path, "--out", tmp_path / "m2.npz",
             "--shape-form", value], capsys, f"--shape-form {value!r}: valid: body, linear")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("value", ["one", "", "TRAINING"])
def test_extend_refuses_an_unknown_subject_rows(tiny_arm_model_path, tmp_path, capsys, value):
    run_bad(["muscle", "model", "extend", tiny_arm_model_path, tmp_path, "--out", tmp_path / "m2.npz",
             "--subject-rows", value], capsys, f"--subject-rows {value!r}: valid: own, training")
    assert list(tmp_path.iterdir()) == []


def test_extend_api_refuses_an_unknown_subject_rows(tiny_arm_model_path):
    from bodystudio.errors import InputError
    from bodystudio.muscle.model import ArmSample, ArmShapeParams, extend_arm_model, load_arm_model

    model = load_arm_model(tiny_arm_model_path)
    sample = ArmSample("x", ArmShapeParams(22.0, 0.5, 1.75, 0.5), model.base_vertices.copy(), None)
    with pytest.raises(InputError, match="subject_rows='each' must be one of own, training"):
        extend_arm_model(model, [sample], subject_rows="each")


def test_capture_module_refuses_an_extension_capture_without_the_sequence_fit(arm_session, tiny_arm_model_path):
    from bodystudio.errors import InputError
    from bodystudio.muscle.capture import capture_session_arm

    with pytest.raises(InputError, match="needs the model and the sequence fit"):
        capture_session_arm(arm_session, tiny_arm_model_path, sequence_fit=False, for_extension=True)
    with pytest.raises(InputError, match="needs the model and the sequence fit"):
        capture_session_arm(arm_session, None, mode="nicp", for_extension=True)


@pytest.mark.parametrize("value", [0.0, -1.0, float("nan"), float("inf")])
def test_extend_api_refuses_a_bad_weight_prior_weight(tiny_arm_model_path, value):
    from bodystudio.errors import InputError
    from bodystudio.muscle.model import ArmSample, ArmShapeParams, extend_arm_model, load_arm_model

    model = load_arm_model(tiny_arm_model_path)
    sample = ArmSample("x", ArmShapeParams(22.0, 0.5, 1.75, 0.5), model.base_vertices.copy(), None)
    with pytest.raises(InputError, match=r"^weight_prior_weight=.* must be > 0 \(or None: prior_weight's\)$"):
        extend_arm_model(model, [sample], captured_rest="body", weight_prior_weight=value)
