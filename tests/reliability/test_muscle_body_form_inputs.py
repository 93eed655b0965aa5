"""Bad input for the body form of the arm model's shape term (issue 11 §4, eighth extension pass): broken body-form
model files (one line, exit 2, for `muscle model info` and `muscle capture`), and a good one read back as it was."""

import json

import numpy as np
import pytest

from bodystudio.cli.main import main

from .conftest import run_bad


@pytest.fixture(scope="module")
def arm_session(tmp_path_factory):
    out = tmp_path_factory.mktemp("arm") / "session"
    assert main(["synth", "arm", str(out), "--subject-seed", "5", "--frames", "3", "--resolution", "2k"]) == 0
    return out


@pytest.fixture(scope="module")
def body_models(tmp_path_factory, tiny_arm_model_path):
    """The tiny 2k model in the body form, saved, and damaged copies of it."""
    from bodystudio.muscle.model import load_arm_model, save_arm_model, with_shape_form

    folder = tmp_path_factory.mktemp("body_form")
    save_arm_model(folder / "body.npz", with_shape_form(load_arm_model(tiny_arm_model_path), "body"))
    with np.load(folder / "body.npz") as z:
        arrays = {k: z[k] for k in z.files}
    header = json.loads(str(arrays.pop("header")))

    def write(name, header_change=None, drop=(), **changed):
        kept = {k: v for k, v in {**arrays, **changed}.items() if k not in drop}
        np.savez(folder / name, header=np.array(json.dumps({**header, **(header_change or {})})), **kept)

    write("no_coeffs.npz", drop=("body_coeffs",))
    write("short_params.npz", shape_params=arrays["shape_params"][:1])
    write("nan_coeffs.npz", body_coeffs=np.full_like(arrays["body_coeffs"], np.nan))
    write("other_space.npz", {"body_space": {"local_targets": ["armslegs/no-such-target.target"]}})
    write("form.npz", {"shape_form": "kernel"})
    return folder


@pytest.mark.parametrize("name, phrase", [
    ("no_coeffs.npz", "arm model of the body form lacks consistent shape_params / body_coeffs; rebuild the model"),
    ("short_params.npz", "lacks consistent shape_params / body_coeffs"),
    ("nan_coeffs.npz", "lacks consistent shape_params / body_coeffs"),
    ("other_space.npz", "was learned on another body shape space (1 local targets"),
    ("form.npz", "arm model shape_form 'kernel' is not one of linear, body"),
])
def test_broken_body_form_models_are_refused(arm_session, body_models, tmp_path, capsys, name, phrase):
    line = run_bad(["muscle", "model", "info", body_models / name], capsys, phrase)
    assert name in line
    run_bad(["muscle", "capture", arm_session, "--out", tmp_path / "cap", "--model", body_models / name], capsys,
            phrase)
    assert not (tmp_path / "cap").exists()


def test_a_body_form_model_reads_back_and_info_names_its_form(body_models, tiny_arm_model_path, capsys):
    from bodystudio.muscle.arm import ArmPose
    from bodystudio.muscle.model import ArmShapeParams, load_arm_model, model_mesh, with_shape_form

    assert main(["muscle", "model", "info", str(body_models / "body.npz")]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["shape_form"] == "body" and info["version"] == 3
    loaded = load_arm_model(body_models / "body.npz")
    fresh = with_shape_form(load_arm_model(tiny_arm_model_path), "body")
    shape = ArmShapeParams(31.0, 0.3, 1.95, 0.56, sex=1.0)
    np.testing.assert_allclose(model_mesh(loaded, shape, ArmPose.rest()), model_mesh(fresh, shape, ArmPose.rest()),
                               rtol=0, atol=1e-12)
