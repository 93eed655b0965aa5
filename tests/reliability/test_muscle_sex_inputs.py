"""Bad input for the arm model's sex input: --shape sex values, version-1 and broken model files (one line, exit 2)."""

import json
import logging

import numpy as np
import pytest

from bodystudio.cli.main import main

from .conftest import run_bad

SHAPE = "bmi=20,muscularity=0.5,height_m=1.7,arm_length_m=0.5"


@pytest.fixture(scope="module")
def arm_session(tmp_path_factory):
    out = tmp_path_factory.mktemp("arm") / "session"
    assert main(["synth", "arm", str(out), "--subject-seed", "5", "--frames", "3", "--resolution", "2k"]) == 0
    return out


@pytest.fixture(scope="module")
def models(tmp_path_factory, tiny_arm_model_path):
    """A tiny 2k model rewritten as version 2 (no shape form) and as version 1 (no sex)."""
    import shutil

    folder = tmp_path_factory.mktemp("models")
    shutil.copyfile(tiny_arm_model_path, folder / "v2.npz")
    with np.load(folder / "v2.npz") as z:
        arrays = {k: z[k] for k in z.files}
    header = json.loads(str(arrays.pop("header")))
    header.pop("shape_form", None)  # a version-2 file: no shape form (the linear one)
    np.savez(folder / "v2.npz", header=np.array(json.dumps({**header, "version": 2})), **arrays)
    del header["sex_regularization"]
    arrays["shape_rows"], arrays["shape_coeffs"] = arrays["shape_rows"][:, :4], arrays["shape_coeffs"][:5]
    np.savez(folder / "v1.npz", header=np.array(json.dumps({**header, "version": 1})), **arrays)
    np.savez(folder / "v4.npz", header=np.array(json.dumps({**header, "version": 4})), **arrays)
    np.savez(folder / "badsex.npz", header=np.array(json.dumps({**header, "version": 2, "sex_regularization": -1})),
             **arrays)
    return folder


@pytest.mark.parametrize("sex, phrase", [
    ("alien", "sex 'alien' is not male, female"),
    ("2", "is not male, female or a number in [0, 1]"),
    ("-1", "is not male, female or a number in [0, 1]"),
    ("nan", "is not male, female or a number in [0, 1]"),
    ("", "is not male, female"),
])
def test_capture_and_extend_refuse_a_bad_sex(arm_session, models, tmp_path, capsys, sex, phrase):
    shape = f"{SHAPE},sex={sex}"
    run_bad(["muscle", "capture", arm_session, "--out", tmp_path / "cap", "--model", models / "v2.npz",
             "--shape", shape], capsys, phrase)
    run_bad(["muscle", "model", "extend", models / "v2.npz", tmp_path, "--out", tmp_path / "m2.npz",
             "--shape", shape], capsys, phrase)
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_shape_names_list_sex(arm_session, models, tmp_path, capsys):
    run_bad(["muscle", "capture", arm_session, "--out", tmp_path / "cap", "--model", models / "v2.npz",
             "--shape", f"{SHAPE},gender=female"], capsys, "names are bmi, muscularity, height_m, arm_length_m, sex")


@pytest.mark.parametrize("name, phrase", [
    ("v4.npz", "arm model version 4 is not supported"),
    ("badsex.npz", "sex_regularization -1 is not a positive number"),
])
def test_unreadable_model_versions_and_fields(arm_session, models, tmp_path, capsys, name, phrase):
    run_bad(["muscle", "model", "info", models / name], capsys, phrase)
    run_bad(["muscle", "capture", arm_session, "--out", tmp_path / "cap", "--model", models / name], capsys, phrase)
    assert not (tmp_path / "cap").exists()


def test_a_version_1_model_is_upgraded_with_one_warning(arm_session, models, tmp_path, capsys, caplog):
    """An old model still captures and extends; a woman's capture extends it into a current-version model."""
    with caplog.at_level(logging.WARNING):
        assert main(["muscle", "model", "info", str(models / "v1.npz")]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["version"] == 3 and info["shape_form"] == "linear"
    warning = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert len(warning) == 1 and "version 1" in warning[0] and "male" in warning[0] and "\n" not in warning[0]
    cap = tmp_path / "cap"
    assert main(["muscle", "capture", str(arm_session), "--out", str(cap), "--model", str(models / "v1.npz"),
                 "--frames", "2", "--no-refine", "--shape", f"{SHAPE},sex=female"]) == 0
    params = json.loads((cap / "params.json").read_text())
    assert params["shape"]["sex"] == 0.0
    capsys.readouterr()
    assert main(["muscle", "model", "extend", str(models / "v1.npz"), str(cap), "--out", str(tmp_path / "m2.npz"),
                 "--stride", "1", "--shape", f"{SHAPE},sex=f"]) == 0
    capsys.readouterr()
    assert main(["muscle", "model", "info", str(tmp_path / "m2.npz")]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["version"] == 3 and info["subjects"][-1]["shape"]["sex"] == 0.0
