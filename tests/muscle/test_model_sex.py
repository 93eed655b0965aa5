"""Sex as an input of the arm model's shape term (issue 11 §4, the paper's Table 1), and version-1 model files."""

import json
import logging
from dataclasses import replace

import numpy as np
import pytest

from bodystudio.errors import FileFormatError, InputError
from bodystudio.muscle.model import (
    MODEL_VERSION,
    ArmShapeParams,
    extend_arm_model,
    load_arm_model,
    model_error_mm,
    model_mesh,
    parse_sex,
    save_arm_model,
)
from bodystudio.muscle.synthetic import arm_pose_from_angles, sample_arm_subject, subject_arm_samples

THIN_WOMEN = dict(gender="female", bmi_range=(16.0, 18.0))


def as_male(samples):
    """The same meshes with the sex left out (what a model without the sex input sees)."""
    return [replace(s, shape=replace(s.shape, sex=1.0)) for s in samples]


@pytest.fixture(scope="module")
def thin_women_2k():
    """Two thin women to add (1 base-pose + 6 posed meshes each) and two held out (1 + 6 each)."""
    added = [s for seed in (321, 322) for s in subject_arm_samples(sample_arm_subject(seed, **THIN_WOMEN), "2k", 1, 6)]
    held = [s for seed in (330, 331)
            for s in subject_arm_samples(sample_arm_subject(seed, **THIN_WOMEN), "2k", 1, 6, seed=3)]
    return added, held


def test_shape_params_sex_defaults_to_male_and_is_validated():
    s = ArmShapeParams(22.0, 0.5, 1.75, 0.52)
    assert s.sex == 1.0 and s.as_vector().shape == (4,) and s.as_row()[4] == 1.0
    assert ArmShapeParams.from_dict({**s.to_dict(), "sex": "female"}).sex == 0.0
    # A synthetic subject's summary carries MakeHuman's gender instead.
    assert ArmShapeParams.from_dict({"bmi": 22, "muscularity": 0.5, "height_m": 1.7, "arm_length_m": 0.5,
                                     "gender": 0.0}).sex == 0.0
    assert ArmShapeParams.from_vector(s.as_vector(), sex=0.0) == replace(s, sex=0.0)
    assert [parse_sex(v) for v in ("male", "F", " m ", 0, "1", 0.25)] == [1.0, 0.0, 1.0, 0.0, 1.0, 0.25]
    for bad in ("alien", 2, -0.5, float("nan"), None, "1.5"):
        with pytest.raises(InputError, match="sex"):
            ArmShapeParams(22.0, 0.5, 1.75, 0.52, sex=bad)


def test_the_all_male_model_ignores_sex(arm_model_2k, arm_template_2k):
    """The original training set is all male: its sex coefficient is zero, so a woman gets the men's arm."""
    assert np.abs(arm_model_2k.shape_coeffs[-1]).max() == 0.0
    ap = arm_pose_from_angles(arm_template_2k, 100, 50)
    man = ArmShapeParams(17.0, 0.3, 1.6, 0.45)
    np.testing.assert_array_equal(model_mesh(arm_model_2k, man, ap), model_mesh(arm_model_2k, replace(man, sex=0), ap))


def test_extension_with_sex_lowers_a_held_out_womans_error(arm_model_2k, thin_women_2k):
    """Two thin women added: two others' model-only error drops, and by more than without the sex input."""
    added, held = thin_women_2k
    before = model_error_mm(arm_model_2k, held, use_sample_joints=True)["median_mm"]
    with_sex = extend_arm_model(arm_model_2k, added)
    without = extend_arm_model(arm_model_2k, as_male(added))
    after = model_error_mm(with_sex, held, use_sample_joints=True)["median_mm"]
    after_without = model_error_mm(without, as_male(held), use_sample_joints=True)["median_mm"]
    assert np.abs(with_sex.shape_coeffs[-1]).max() > 1e-3  # the women taught the sex term something
    assert after < 0.55 * before  # measured 16.9 -> 6.9 mm
    assert after < 0.8 * after_without  # measured 6.9 vs 10.0 mm
    # The men the model was trained on keep their arms.
    man = [s for s in subject_arm_samples(sample_arm_subject(1000, gender="male", bmi_range=(20, 28)), "2k", 1, 4)]
    e0 = model_error_mm(arm_model_2k, man, use_sample_joints=True)["median_mm"]
    assert model_error_mm(with_sex, man, use_sample_joints=True)["median_mm"] < 1.15 * e0  # measured 3.17 -> 3.00 mm


def test_sex_regularization_is_the_knob_of_the_sex_column(arm_model_2k, thin_women_2k):
    added, held = thin_women_2k
    strong = extend_arm_model(replace(arm_model_2k, sex_regularization=100.0), added)
    weak = extend_arm_model(arm_model_2k, added)
    assert np.abs(strong.shape_coeffs[-1]).max() < 0.05 * np.abs(weak.shape_coeffs[-1]).max()
    e = [model_error_mm(m, held, use_sample_joints=True)["median_mm"] for m in (strong, weak)]
    assert e[1] < 0.8 * e[0]  # measured 10.0 vs 6.9 mm


def as_version_1(path, out, **changed):
    """Rewrite a saved model the way version 1 stored it: four shape columns, no sex row, no sex weight
    (``changed``: arrays to replace, for damaged version-1 files). Returns ``out``."""
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    header = json.loads(str(arrays.pop("header")))
    header["version"] = 1
    del header["sex_regularization"]
    arrays["shape_rows"] = arrays["shape_rows"][:, :4]
    arrays["shape_coeffs"] = arrays["shape_coeffs"][:5]
    arrays.update(changed)
    np.savez(out, header=np.array(json.dumps(header)), **arrays)
    return out


def test_version_1_files_are_read_as_all_male_models(arm_model_2k, arm_template_2k, thin_women_2k, tmp_path,
                                                     caplog):
    path, old = tmp_path / "v2.npz", tmp_path / "v1.npz"
    save_arm_model(path, arm_model_2k)
    as_version_1(path, old)
    with caplog.at_level(logging.WARNING, logger="bodystudio.muscle.model"):
        loaded = load_arm_model(old, arm_template_2k)
    assert loaded.version == MODEL_VERSION
    assert len(caplog.records) == 1 and "version 1" in caplog.records[0].getMessage()
    assert "\n" not in caplog.records[0].getMessage()
    ap = arm_pose_from_angles(arm_template_2k, 120, 40)
    for sex in (1.0, 0.0):
        shape = ArmShapeParams(19.0, 0.4, 1.62, 0.47, sex=sex)
        np.testing.assert_allclose(model_mesh(loaded, shape, ap), model_mesh(arm_model_2k, shape, ap), atol=1e-12)
    # An upgraded model extends like a new one and is saved as the new version.
    added, _ = thin_women_2k
    ext = extend_arm_model(loaded, added)
    np.testing.assert_allclose(ext.shape_coeffs, extend_arm_model(arm_model_2k, added).shape_coeffs, atol=1e-9)
    save_arm_model(tmp_path / "ext.npz", ext)
    with np.load(tmp_path / "ext.npz") as z:
        assert json.loads(str(z["header"]))["version"] == MODEL_VERSION


def test_broken_sex_fields_in_a_model_file_are_refused(arm_model_2k, tmp_path):
    path = tmp_path / "m.npz"
    save_arm_model(path, arm_model_2k)
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    header = json.loads(str(arrays.pop("header")))
    cases = [({**header, "sex_regularization": -1}, {}, "sex_regularization"),
             ({**header, "sex_regularization": "x"}, {}, "sex_regularization"),
             ({**header, "version": 4}, {}, "version 4"),
             ({**header, "version": True}, {}, "version True"),
             (header, {"shape_rows": arrays["shape_rows"][:, :4]}, "inconsistent"),
             ({**header, "version": 1}, {"shape_coeffs": arrays["shape_coeffs"][:3]}, "inconsistent")]
    for h, changed, phrase in cases:
        bad = tmp_path / "bad.npz"
        np.savez(bad, header=np.array(json.dumps(h)), **{**arrays, **changed})
        with pytest.raises(FileFormatError, match=phrase) as err:
            load_arm_model(bad)
        assert "bad.npz" in str(err.value) and "\n" not in str(err.value)
