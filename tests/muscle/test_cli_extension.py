"""Parity of the CLI with the benchmark's extension (issue 11, sixth pass): ``muscle capture --for-extension``
captures with the benchmark's setting and ``muscle model extend`` centres by sex by default, as the API does."""

import json

import numpy as np
import pytest

from bodystudio.cli.main import main

SHAPE = "bmi=22,muscularity=0.5,height_m=1.75,arm_length_m=0.5"


@pytest.fixture(scope="module")
def extension_capture(tmp_path_factory, tiny_arm_model_path):
    """A 4-frame 2k session captured with --for-extension and the tiny model (a man by --shape)."""
    root = tmp_path_factory.mktemp("ext")
    session, cap = root / "session", root / "cap"
    assert main(["synth", "arm", str(session), "--subject-seed", "3", "--frames", "4", "--resolution", "2k"]) == 0
    assert main(["muscle", "capture", str(session), "--out", str(cap), "--model", str(tiny_arm_model_path),
                 "--shape", f"{SHAPE},sex=male", "--for-extension"]) == 0
    return cap


def test_for_extension_fits_the_skeleton(extension_capture, tiny_arm_model_path):
    """The capture's joints are its fitted skeleton, not the model's regression (which a capture without the
    option keeps): the option reached the sequence fit."""
    from bodystudio.muscle.capture import load_arm_capture
    from bodystudio.muscle.model import load_arm_model, model_joints

    cap = load_arm_capture(extension_capture)
    regressed = model_joints(load_arm_model(tiny_arm_model_path), cap.shape)
    moved_mm = 1000 * np.linalg.norm(cap.joints - regressed, axis=1)
    assert moved_mm.max() > 0.5, moved_mm


def _api_model(capture_path, model_path, centre, captured_rest="body"):
    from bodystudio.muscle.capture import load_arm_capture
    from bodystudio.muscle.model import ArmShapeParams, capture_samples, extend_arm_model, load_arm_model

    model = load_arm_model(model_path)
    shape = ArmShapeParams(22, 0.5, 1.75, 0.5, sex=1.0)
    samples = capture_samples(load_arm_capture(capture_path), f"capture_{capture_path.name}", shape, 2,
                              model=model, centre=centre)
    return extend_arm_model(model, samples, captured_rest=captured_rest)


def test_extend_centres_by_sex_by_default_as_the_api(extension_capture, tiny_arm_model_path, tmp_path, capsys):
    """The CLI's default is the API's ``centre="sex"`` with body-space rows (seventh pass); ``--captured-rest mesh
    --centre fitted`` is the API's old construction, and with mesh rows the centring matters for a man."""
    from bodystudio.muscle.model import load_arm_model

    out = tmp_path / "m2.npz"
    assert main(["muscle", "model", "extend", str(tiny_arm_model_path), str(extension_capture), "--out", str(out),
                 "--stride", "2", "--shape", f"{SHAPE},sex=male"]) == 0
    cli = load_arm_model(out)
    by_sex = _api_model(extension_capture, tiny_arm_model_path, "sex")
    for key in ("shape_coeffs", "pose_coeffs", "joint_coeffs"):
        np.testing.assert_allclose(getattr(cli, key), getattr(by_sex, key), rtol=0, atol=1e-12)
    assert cli.subjects[-1]["rest"].startswith("body space")
    fitted = _api_model(extension_capture, tiny_arm_model_path, "fitted", "mesh")
    # a man's mesh rows centred on the regressed shoulder are not the old default's (his fitted shoulder)
    assert np.abs(_api_model(extension_capture, tiny_arm_model_path, "sex", "mesh").shape_coeffs
                  - fitted.shape_coeffs).max() > 1e-5
    assert np.abs(cli.shape_coeffs - fitted.shape_coeffs).max() > 1e-5
    out2 = tmp_path / "m_fitted.npz"
    assert main(["muscle", "model", "extend", str(tiny_arm_model_path), str(extension_capture), "--out",
                 str(out2), "--stride", "2", "--shape", f"{SHAPE},sex=male", "--centre", "fitted",
                 "--captured-rest", "mesh"]) == 0
    np.testing.assert_allclose(load_arm_model(out2).shape_coeffs, fitted.shape_coeffs, rtol=0, atol=1e-12)
    assert "captured without --for-extension" not in capsys.readouterr().err
    assert main(["muscle", "model", "info", str(out)]) == 0
    assert json.loads(capsys.readouterr().out)["n_subjects"] == 3


def test_the_batch_hash_keeps_old_units_and_tells_the_extension_apart(tmp_path):
    """A batch's options: --for-extension changes a unit's inputs hash; without it the hash is the one units
    captured before the option existed have (the option left out of the hashed fields)."""
    import hashlib
    from dataclasses import asdict

    from bodystudio import __version__
    from bodystudio.batch import MuscleOptions, sequence_inputs_sha256

    plain, ext = MuscleOptions(model="m.npz"), MuscleOptions(model="m.npz", for_extension=True)
    missing = tmp_path / "missing"
    a, b = sequence_inputs_sha256(missing, plain, "x"), sequence_inputs_sha256(missing, ext, "x")
    assert a != b
    old_fields = {k: v for k, v in asdict(plain).items() if k != "for_extension"}
    h = hashlib.sha256(json.dumps({"options": old_fields, "model": "x", "version": __version__},
                                  sort_keys=True, default=str).encode())
    from bodystudio.capture.session import open_session
    from bodystudio.errors import BodyStudioError

    try:
        open_session(missing)
    except BodyStudioError as exc:
        h.update(f"unreadable: {exc}".encode())
    assert a == h.hexdigest()


def test_a_batch_unit_captures_for_extension(extension_capture, tiny_arm_model_path, tmp_path):
    """``muscle capture S1 S2 --for-extension``: the option reaches each unit's capture (the same meshes as the
    single capture of the fixture)."""
    from bodystudio.batch import MuscleOptions, capture_unit
    from bodystudio.muscle.capture import load_arm_capture
    from bodystudio.muscle.model import ArmShapeParams

    shape = {**ArmShapeParams(22, 0.5, 1.75, 0.5, sex=1.0).to_dict()}
    options = MuscleOptions(shape=shape, model=str(tiny_arm_model_path), for_extension=True)
    unit = tmp_path / "unit"
    capture_unit(str(extension_capture.parent / "session"), str(unit), options, "x")
    got, want = load_arm_capture(unit), load_arm_capture(extension_capture)
    np.testing.assert_allclose(got.joints, want.joints, atol=1e-9)
    np.testing.assert_allclose(got.vertices, want.vertices, atol=1e-9)


def test_extend_says_when_a_capture_was_not_made_for_extension(extension_capture, tiny_arm_model_path, tmp_path,
                                                               capsys):
    # without the sequence fit: the model's regressed joints (a default capture fits the body model's skeleton to the
    # depth, docs/muscle.md tenth pass, so it has a fitted skeleton of its own)
    plain = tmp_path / "plain"
    assert main(["muscle", "capture", str(extension_capture.parent / "session"), "--out", str(plain), "--model",
                 str(tiny_arm_model_path), "--shape", f"{SHAPE},sex=male", "--frames", "2", "--no-sequence-fit"]) == 0
    capsys.readouterr()
    assert main(["muscle", "model", "extend", str(tiny_arm_model_path), str(plain), "--out", str(tmp_path / "m.npz"),
                 "--shape", f"{SHAPE},sex=male"]) == 0
    err = capsys.readouterr().err
    assert f"{plain}: captured without --for-extension" in err and err.count("\n") == 2  # one line per capture
