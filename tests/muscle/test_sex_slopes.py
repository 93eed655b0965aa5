"""The women's own slopes (``ArmModel.sex_slopes``, ``muscle model build --sex-slopes``): Eq. 6's shape design
continued by the interaction ``(1 - sex) z`` (docs/muscle.md, "Women's own slopes").

Small planted models (three vertices, arrays made here; no body model): residuals made from known coefficients with
slopes of the women's own are recovered with the option and not without it; a man's design row is the same either
way; the option survives the file and a damaged flag is refused.
"""

import json

import numpy as np
import pytest

from bodystudio.errors import FileFormatError
from bodystudio.muscle.model import (
    ArmModel,
    ArmShapeParams,
    fit_shape_coefficients,
    load_arm_model,
    save_arm_model,
    shape_design,
    shape_displacements,
)

N = 3  # vertices


def _model(sex_slopes: bool, regularization: float = 1e-6) -> ArmModel:
    z3 = np.zeros((N, 3))
    return ArmModel("planted", np.array([[0, 1, 2]]), np.full((N, 4), 0.25), np.ones(N, bool), z3,
                    np.zeros((1, 3 * N)), np.zeros((2, 1)), np.zeros((5, 9)),
                    np.zeros((10 if sex_slopes else 6, 3 * N)), np.zeros((10, 3 * N)),
                    np.array([22.0, 0.5, 1.7, 0.48]), np.array([2.0, 0.2, 0.08, 0.03]), regularization,
                    np.zeros((0, 5)), np.zeros((0, 3 * N)), np.zeros((10, 10)), np.zeros((10, 3 * N)),
                    np.eye(5), np.zeros((5, 9)), sex_regularization=1e-6, sex_slopes=sex_slopes)


@pytest.fixture(scope="module")
def planted():
    """Twelve men and twelve women whose rest-arm residuals follow slopes of their own: a woman's BMI slope is the
    men's plus a planted 5 mm per standard deviation on every coordinate."""
    rng = np.random.default_rng(7)
    rows = np.c_[rng.normal([22.0, 0.5, 1.7, 0.48], [2.0, 0.2, 0.08, 0.03], (24, 4)), np.repeat([1.0, 0.0], 12)]
    W = rng.normal(0.0, 0.004, (10, 3 * N))
    W[6:] = 0.0
    W[6] = 0.005  # the women's BMI slope: the men's + 5 mm
    residuals = shape_design(_model(True), rows) @ W
    return rows, residuals, W


def test_a_mans_design_row_is_the_same_and_a_womans_is_continued(planted):
    rows, _, _ = planted
    with_slopes, without = shape_design(_model(True), rows), shape_design(_model(False), rows)
    assert without.shape == (24, 6) and with_slopes.shape == (24, 10)
    assert np.array_equal(with_slopes[:, :6], without)
    assert np.all(with_slopes[:12, 6:] == 0.0)  # men: no interaction
    assert np.allclose(with_slopes[12:, 6:], without[12:, 1:5])  # women: (1 - sex) z = z


def test_the_womens_own_slopes_are_recovered_only_with_the_option(planted):
    rows, residuals, W = planted
    slopes, shared = _model(True), _model(False)
    fitted = fit_shape_coefficients(slopes, rows, residuals)
    assert np.abs(fitted - W).max() < 1e-6
    woman = ArmShapeParams(26.0, 0.5, 1.7, 0.48, sex=0.0)  # 2 standard deviations of BMI above the mean
    truth = (shape_design(slopes, woman.as_row())[0] @ W).reshape(-1, 3)
    err = np.abs(shape_displacements(_replace(slopes, fitted), woman) - truth).max()
    err_shared = np.abs(shape_displacements(_replace(shared, fit_shape_coefficients(shared, rows, residuals)),
                                            woman) - truth).max()
    assert err < 1e-6 and err_shared > 0.004  # the shared slopes miss the planted 2 x 5 mm by half or more


def _replace(model, coeffs):
    from dataclasses import replace

    return replace(model, shape_coeffs=coeffs)


def test_the_option_survives_the_file_and_a_damaged_flag_is_refused(tmp_path, planted):
    rows, residuals, _ = planted
    model = _model(True)
    model = _replace(model, fit_shape_coefficients(model, rows, residuals))
    save_arm_model(tmp_path / "m.npz", model)
    back = load_arm_model(tmp_path / "m.npz")
    assert back.sex_slopes is True and np.array_equal(back.shape_coeffs, model.shape_coeffs)
    save_arm_model(tmp_path / "plain.npz", _model(False))
    with np.load(tmp_path / "plain.npz") as z:
        assert "sex_slopes" not in json.loads(str(z["header"]))  # files without the option are as they were
    assert load_arm_model(tmp_path / "plain.npz").sex_slopes is False
    with np.load(tmp_path / "m.npz") as z:
        arrays = {k: z[k] for k in z.files}
    header = json.loads(str(arrays["header"]))
    for flag, coeffs, phrase in (("yes", arrays["shape_coeffs"], "sex_slopes 'yes' is not true or false"),
                                 (False, arrays["shape_coeffs"], "shape arrays are inconsistent")):
        np.savez(tmp_path / "bad.npz", **{**arrays, "header": np.array(json.dumps({**header, "sex_slopes": flag})),
                                          "shape_coeffs": coeffs})
        with pytest.raises(FileFormatError, match=phrase):
            load_arm_model(tmp_path / "bad.npz")
