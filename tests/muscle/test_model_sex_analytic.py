"""Fast checks of the arm model's sex input (bodystudio.muscle.model): its Tikhonov weight, version-1 files, messages.

Each test learns or rewrites its own tiny model (a session fixture's calls are credited by mutmut to the one
test that built it; see docs/mutation/muscle-model.md).
"""

import logging

import numpy as np
import pytest

from bodystudio.errors import FileFormatError, InputError
from bodystudio.muscle.model import MODEL_VERSION, ArmShapeParams, learn_arm_model, load_arm_model

from .test_model_sex import as_version_1


@pytest.fixture(scope="module")
def tiny_samples():
    from bodystudio.body import build_body
    from bodystudio.muscle.arm import arm_template
    from bodystudio.muscle.synthetic import sample_arm_subject, subject_arm_samples

    samples = subject_arm_samples(sample_arm_subject(1000), "2k", n_shapes=1, n_poses=2)
    samples += subject_arm_samples(sample_arm_subject(1001), "2k", n_shapes=1, n_poses=2)
    return samples, arm_template(build_body(resolution="2k"), "left")


def test_the_sex_weight_must_be_positive_and_is_kept(tiny_samples):
    samples, template = tiny_samples
    for q in (0, -1.0, float("nan")):
        with pytest.raises(InputError, match=rf"^sex_regularization={q} must be > 0$"):
            learn_arm_model(samples, template, population_size=3, sex_regularization=q)
    m = learn_arm_model(samples, template, population_size=3, sex_regularization=0.25)
    assert m.sex_regularization == 0.25 and isinstance(m.sex_regularization, float)
    # the weight is the one the shape term was solved with: the sex row differs from the default weight's
    d = learn_arm_model(samples, template, population_size=3)
    assert d.sex_regularization == 0.1
    assert np.abs(m.shape_coeffs[-1] - d.shape_coeffs[-1]).max() > 1e-6


def _version_1(tmp_path, model_path, **changed):
    return as_version_1(model_path, tmp_path / "v1.npz", **changed)


def test_a_version_1_file_warns_once_naming_the_file(tmp_path, tiny_arm_model_path, caplog):
    path = _version_1(tmp_path, tiny_arm_model_path)
    with caplog.at_level(logging.WARNING, logger="bodystudio.muscle.model"):
        m = load_arm_model(path)
    assert [r.getMessage() for r in caplog.records] == [
        f"{path}: arm model version 1 (no sex input) read as version {MODEL_VERSION} with every subject male; "
        "`bodystudio muscle model extend` writes the new version"]
    assert m.version == MODEL_VERSION and m.shape_rows.shape[1] == 5 and (m.shape_rows[:, 4] == 1).all()
    assert (m.shape_coeffs[-1] == 0).all()


@pytest.mark.parametrize("which", ["rows_1d", "rows_5_columns", "coeffs_1d", "coeffs_short"])
def test_inconsistent_version_1_arrays_are_refused(tmp_path, tiny_arm_model_path, which):
    with np.load(tiny_arm_model_path) as z:
        rows, coeffs = z["shape_rows"][:, :4], z["shape_coeffs"][:5]
    changed = {"rows_1d": {"shape_rows": rows.ravel()},
               "rows_5_columns": {"shape_rows": np.c_[rows, np.ones(len(rows))]},
               "coeffs_1d": {"shape_coeffs": coeffs[:, 0]},
               "coeffs_short": {"shape_coeffs": coeffs[:4]}}[which]
    path = _version_1(tmp_path, tiny_arm_model_path, **changed)
    with pytest.raises(FileFormatError, match=r"^.*v1.npz: version-1 arm model arrays are inconsistent; rebuild the "
                                              r"model$"):
        load_arm_model(path)


def test_shape_parameters_from_a_dict_name_their_source():
    d = {"bmi": 22, "muscularity": 0.5, "height_m": 1.7, "arm_length_m": 0.5}
    assert ArmShapeParams.from_dict({**d, "sex": "female"}).sex == 0.0
    with pytest.raises(InputError, match=r"^subject.json: sex 'x' is not male, female or a number in \[0, 1\]"):
        ArmShapeParams.from_dict({**d, "sex": "x"}, "subject.json")
    with pytest.raises(InputError, match=r"^shape parameters: sex 2.0 is not male"):
        ArmShapeParams.from_dict({**d, "sex": 2.0})


def test_measured_shape_carries_the_phenotypes_sex():
    from bodystudio.body import Phenotype
    from bodystudio.muscle.model import measure_arm_shape

    assert measure_arm_shape(Phenotype(gender=0.3, muscle=0.5, weight=0.5)).sex == 0.3


def test_sex_names_are_parsed_into_the_shape_and_a_bad_one_is_named():
    """``ArmShapeParams(sex=...)`` stores the model's number (names and numeric strings parsed), and ``parse_sex``'s
    refusal names its source (default "sex") and the convention. Issue 17: these survived with float sexes only."""
    from bodystudio.muscle.model import parse_sex

    assert ArmShapeParams(24.0, 0.5, 1.7, 0.5, sex="female").sex == 0.0
    assert ArmShapeParams(24.0, 0.5, 1.7, 0.5, sex=" M ").sex == 1.0
    assert ArmShapeParams(24.0, 0.5, 1.7, 0.5, sex="0.25").sex == 0.25
    with pytest.raises(InputError, match=r"^sex: sex 'x' is not male, female or a number in \[0, 1\] "
                                         r"\(1 = male, 0 = female\)$"):
        parse_sex("x")
    with pytest.raises(InputError, match=r"^--shape: sex 'x' is not male"):
        parse_sex("x", "--shape")
