"""Bad input for the body form's weight macro (issue 11 §4, ninth extension pass): a model file whose header names
another ``body_weight`` is refused in one line (exit 2) by `muscle model info` and `muscle model extend`; a good one
names its weight macro in `model info`, and a body-form file of the eighth pass (no ``body_weight``) reads as
"regressed", the form it was learned in (`muscle capture` reads models through the same loader)."""

import json

import numpy as np
import pytest

from bodystudio.cli.main import main

from .conftest import run_bad


@pytest.fixture(scope="module")
def weight_models(tmp_path_factory, tiny_arm_model_path):
    from bodystudio.muscle.model import load_arm_model, save_arm_model, with_shape_form

    folder = tmp_path_factory.mktemp("body_weight")
    save_arm_model(folder / "bmi.npz", with_shape_form(load_arm_model(tiny_arm_model_path), "body", body_weight="bmi"))
    with np.load(folder / "bmi.npz") as z:
        arrays = {k: z[k] for k in z.files}
    header = json.loads(str(arrays.pop("header")))
    for name, change in (("kernel.npz", {"body_weight": "kernel"}), ("number.npz", {"body_weight": 0.8})):
        np.savez(folder / name, header=np.array(json.dumps({**header, **change})), **arrays)
    np.savez(folder / "eighth.npz", header=np.array(json.dumps({k: v for k, v in header.items()
                                                                 if k != "body_weight"})), **arrays)
    return folder


@pytest.mark.parametrize("name, phrase", [
    ("kernel.npz", "arm model body_weight 'kernel' is not one of regressed, bmi; rebuild the model"),
    ("number.npz", "arm model body_weight 0.8 is not one of regressed, bmi"),
])
def test_a_model_with_another_body_weight_is_refused(weight_models, tmp_path, capsys, name, phrase):
    line = run_bad(["muscle", "model", "info", weight_models / name], capsys, phrase)
    assert name in line
    run_bad(["muscle", "model", "extend", weight_models / name, weight_models, "--out", tmp_path / "m2.npz"], capsys,
            phrase)
    assert not (tmp_path / "m2.npz").exists()


def test_model_info_names_the_weight_macro(weight_models, capsys):
    assert main(["muscle", "model", "info", str(weight_models / "bmi.npz")]) == 0
    assert json.loads(capsys.readouterr().out)["body_weight"] == "bmi"
    assert main(["muscle", "model", "info", str(weight_models / "eighth.npz")]) == 0
    assert json.loads(capsys.readouterr().out)["body_weight"] == "regressed"
