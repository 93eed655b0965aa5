"""mus11l's weight macro solved from the BMI, case by case (issue 17, mutation round mutR): ``model.body_space_bmi``,
``body_weight_for_bmi``, ``_body_parameters``, the ``body_weight == "bmi"`` lines of ``body_form_columns``,
``fit_body_form``, ``regressed_body_parameters``, ``with_shape_form`` and the file's ``body_weight``.

``test_body_weight_from_bmi.py`` measures the planted heavy man on the real 6k body (a 15 s fixture); these cases use
the 12-vertex stand-in space of ``test_model_body_form_mutants.py`` with the weight solve stubbed by a known function,
and an open box as the body whose BMI is measured (its volume and stature exact).
"""

import json
from dataclasses import replace

import numpy as np
import pytest
import scipy.sparse as sp

from bodystudio.body.measure import BODY_DENSITY_KG_M3
from bodystudio.errors import FileFormatError, InputError
from bodystudio.muscle import model as mm
from bodystudio.muscle.model import BODY_MACRO_NAMES
from tests.muscle.test_model_body_form_mutants import COLUMNS, _design, _model, _shape

W = BODY_MACRO_NAMES.index("weight")


def _solved(space, x, bmi):
    """The stub of the weight solve: a known function of the other parameters and the BMI."""
    return 0.01 * bmi + 0.1 * x[2] - 0.05 * x[4]


def _bmi_model(monkeypatch):
    """The stand-in model, ``BODY_FORM_WEIGHT = "bmi"`` and the solve stubbed (a helper, not a fixture: the direct
    recheck builds fixtures once)."""
    monkeypatch.setattr(mm, "BODY_FORM_WEIGHT", "bmi")
    calls = []
    monkeypatch.setattr(mm, "body_weight_for_bmi",
                        lambda s, x, b: calls.append((s, np.array(x), b)) or _solved(s, x, b))
    model, space, _ = _model(monkeypatch)
    return model, space, calls


def test_the_weight_macro_has_no_columns_with_the_bmi_solve_and_the_others_keep_theirs():
    for p, name in enumerate(BODY_MACRO_NAMES):
        assert mm.body_form_columns(p, "bmi") == ([] if name == "weight" else COLUMNS[name])
        assert mm.body_form_columns(p, "regressed") == mm.body_form_columns(p) == COLUMNS[name]
    assert mm.body_form_columns(len(BODY_MACRO_NAMES) + 1, "bmi") == [0]  # a local target: the intercept


def test_the_parameters_take_the_solved_weight_at_the_other_regressed_ones(monkeypatch):
    model, space, calls = _bmi_model(monkeypatch)
    mean, sigma = space.prior()
    u = np.linspace(-1.0, 1.0, len(mean))
    x = mm._body_parameters(space, "bmi", u, 27.5)
    expected = mean + sigma * u
    assert calls[-1][0] is space and calls[-1][2] == 27.5
    np.testing.assert_array_equal(calls[-1][1], expected)  # the solve sees the regressed parameters
    expected[W] = _solved(space, mean + sigma * u, 27.5)
    np.testing.assert_allclose(x, expected, rtol=0, atol=1e-15)
    n = len(calls)
    np.testing.assert_allclose(mm._body_parameters(space, "regressed", u, 27.5), mean + sigma * u, atol=1e-15)
    assert len(calls) == n


def test_fit_body_form_with_the_bmi_solve(monkeypatch):
    """The weight's column of ``body_coeffs`` is zero and Eq. 7 fits what the arm at the solved parameters leaves."""
    model, space, calls = _bmi_model(monkeypatch)
    model = replace(model, body_weight="bmi")
    rows, res = model.shape_rows, model.shape_residuals
    params = np.stack([space.prior()[0] + 0.1 * k for k in range(len(rows))])
    A, shape_coeffs = mm.fit_body_form(model, rows, res, params)
    assert not A[:, W].any()
    regressed = replace(model, body_weight="regressed")
    A_reg, _ = mm.fit_body_form(regressed, rows, res, params)
    np.testing.assert_allclose(np.delete(A, W, axis=1), np.delete(A_reg, W, axis=1), atol=1e-12)
    assert np.abs(A_reg[:, W]).max() > 1e-3
    mean, sigma = space.prior()
    X = _design(model, rows)
    left = []
    for i, (row, r) in enumerate(zip(rows, res, strict=True)):
        x = mean + sigma * (X[i] @ A)
        x[W] = _solved(space, mean + sigma * (X[i] @ A), _shape(row).bmi)
        left.append((model.base_vertices + mm.length_displacements(model, _shape(row)) + r.reshape(-1, 3)
                     - space.rest_and_joints(x)[0]).ravel())
    np.testing.assert_allclose(shape_coeffs, mm.fit_shape_coefficients(model, rows, np.array(left)), atol=1e-12)


def test_the_regressed_parameters_of_a_bmi_model_have_the_solved_weight(monkeypatch):
    model, space, calls = _bmi_model(monkeypatch)
    body = mm.with_shape_form(model, "body")
    assert body.body_weight == "bmi"
    shape = _shape(model.shape_rows[2])
    x = mm.regressed_body_parameters(body, shape)
    mean, sigma = space.prior()
    u = mm.body_form_design(body, shape.as_row())[0] @ body.body_coeffs
    expected = mean + sigma * u
    assert u[W] == 0.0
    expected[W] = _solved(space, mean + sigma * u, shape.bmi)
    np.testing.assert_allclose(x, expected, atol=1e-15)
    assert calls[-1][2] == shape.bmi


def test_with_shape_form_switches_the_weight_and_keeps_the_rows_parameters(monkeypatch):
    model, space, calls = _bmi_model(monkeypatch)
    with pytest.raises(InputError, match=r"^body_weight='heavy' must be one of regressed, bmi$"):
        mm.with_shape_form(model, "body", "heavy")
    default = mm.with_shape_form(model, "body")
    assert default.shape_form == "body" and default.body_weight == "bmi"
    assert mm.with_shape_form(default, "body") is default
    assert mm.with_shape_form(default, "body", "bmi") is default
    reg = mm.with_shape_form(default, "body", "regressed")
    assert reg.body_weight == "regressed" and reg.shape_params is default.shape_params  # not projected again
    A, S = mm.fit_body_form(reg, model.shape_rows, model.shape_residuals, default.shape_params)
    np.testing.assert_allclose(reg.body_coeffs, A, atol=0)
    np.testing.assert_allclose(reg.shape_coeffs, S, atol=0)
    assert mm.with_shape_form(reg, "body", "bmi").body_weight == "bmi"
    lin = mm.with_shape_form(default, "linear")
    assert lin.body_weight == "regressed" and lin.shape_params is None and lin.body_coeffs is None
    assert mm.with_shape_form(lin, "linear") is lin
    assert mm.with_shape_form(lin, "linear", "bmi") is lin  # a linear model has no weight macro to switch
    assert mm.with_shape_form(model, "body", "regressed").body_weight == "regressed"


def test_the_file_keeps_the_weight_and_older_or_bad_files(monkeypatch, tmp_path):
    model, space, _ = _bmi_model(monkeypatch)
    body = mm.with_shape_form(model, "body")
    path = tmp_path / "arm.npz"
    mm.save_arm_model(path, body)
    assert mm.load_arm_model(path).body_weight == "bmi"
    assert mm.load_arm_model(path).body_coeffs is not None
    mm.save_arm_model(path, mm.with_shape_form(body, "body", "regressed"))
    assert mm.load_arm_model(path).body_weight == "regressed"
    with np.load(path) as z:
        data = {k: np.array(z[k]) for k in z.files}
    header = json.loads(str(data.pop("header")))
    for value, ok in ((None, "regressed"), ("bmi", "bmi"), ("fat", None)):
        h = dict(header)
        if value is None:
            h.pop("body_weight")
        else:
            h["body_weight"] = value
        p = tmp_path / f"arm_{value}.npz"
        np.savez(p, header=np.array(json.dumps(h)), **data)
        if ok is None:
            with pytest.raises(FileFormatError, match=rf"^{p}: arm model body_weight 'fat' is not one of "
                                                       r"regressed, bmi; rebuild the model$"):
                mm.load_arm_model(p)
        else:
            assert mm.load_arm_model(p).body_weight == ok


def test_the_weight_solve_is_keyed_on_the_parameters_bits_and_the_bmi_to_nine_decimals(monkeypatch):
    seen = []
    monkeypatch.setattr(mm, "_body_weight_for_bmi", lambda s, key, bmi: seen.append((s, key, bmi)) or 0.25)
    x = [0.5, 0.25, 0.125]
    assert mm.body_weight_for_bmi("space", x, np.float32(22.5)) == 0.25
    assert mm.body_weight_for_bmi("space", np.array(x, np.float32), 22.12345678949) == 0.25
    assert seen[0] == ("space", np.array(x, np.float64).tobytes(), 22.5) and type(seen[0][2]) is float
    assert seen[1][1] == np.array(x, np.float64).tobytes() and seen[1][2] == 22.123456789


# --- the body model's own measurement, on an open box closed at its rim ---------------------------------------------

def _box(space):
    """(V0, D, macro, local_cols, Fc, loops) of an open box 0.3 x 1.6 x 0.2 m whose top rim is one loop (closed by a
    fan to its centroid, the last vertex of the closed mesh); the macro targets raise the top by 1 m per unit weight
    (target 0), widen it (target 1); the local target 0 (with a twin column) deepens it."""
    a, h, c = 0.3, 1.6, 0.2
    V0 = np.array([[x, y, z] for y in (0.0, h) for x in (0.0, a) for z in (0.0, c)], float)  # 0-3 bottom, 4-7 top
    top = [4, 5, 7, 6]
    bottom = [[0, 2, 3], [0, 3, 1]]
    sides = []
    ring_b, ring_t = [0, 1, 3, 2], [4, 5, 7, 6]
    for k in range(4):
        b0, b1, t0, t1 = ring_b[k], ring_b[(k + 1) % 4], ring_t[k], ring_t[(k + 1) % 4]
        sides += [[b0, b1, t1], [b0, t1, t0]]
    fan = [[top[k], top[(k + 1) % 4], 8] for k in range(4)]
    Fc = np.array(bottom + sides + fan)
    macro = list(space.macro_names)
    K = len(macro) + 4
    D = np.zeros((24, K))
    D[3 * np.arange(4, 8) + 1, 0] = 1.0  # target 0: the top up
    D[3 * np.array([2, 3, 6, 7]) + 0, 1] = 1.0  # target 1: the x = a side out
    local_cols = [[len(macro), len(macro) + 1], [len(macro) + 2], [len(macro) + 3]]
    D[3 * np.array([1, 3, 5, 7]) + 2, len(macro)] = 0.5  # local 0 and its twin: the z = c side out, half each
    D[3 * np.array([1, 3, 5, 7]) + 2, len(macro) + 1] = 0.5
    D[3 * np.array([0, 1]) + 1, len(macro) + 2] = -1.0  # local 1: two bottom corners down (the stature)
    return V0, sp.csr_matrix(D), macro, local_cols, Fc, [np.array(top)]


def test_the_body_spaces_bmi_is_the_closed_bodys_volume_mass_over_its_stature_squared(monkeypatch):
    from tests.muscle.test_body_rest_extension_mutants import _space

    space = _space(n_local=3)
    box = _box(space)
    seen = []
    monkeypatch.setattr(mm, "_body_measure", lambda names: seen.append(names) or box)
    x = np.r_[np.full(len(BODY_MACRO_NAMES), 0.4), 0.1, 0.0, 0.0]
    x[0] = 0.7
    w = space.macro_weights(x)
    a, h, c = 0.3 + w[1], 1.6 + w[0], 0.2 + 0.1
    bmi, stature = mm.body_space_bmi(space, x)
    assert seen == [tuple(space.local_names)]
    assert stature == pytest.approx(h, abs=1e-12)
    assert bmi == pytest.approx(a * h * c * BODY_DENSITY_KG_M3 / h ** 2, rel=1e-12)
    # the local target 1 lowers two bottom corners: the stature grows, the volume by the wedge
    x[len(BODY_MACRO_NAMES) + 1] = 0.05
    bmi2, stature2 = mm.body_space_bmi(space, x)
    assert stature2 == pytest.approx(h + 0.05, abs=1e-12)
    assert bmi2 == pytest.approx((a * h * c + 0.5 * 0.05 * a * c) * BODY_DENSITY_KG_M3 / (h + 0.05) ** 2, rel=1e-12)
    assert isinstance(bmi, float) and isinstance(stature, float)
    for n in (2, 4):  # a local value for each local target of the space, no more, no fewer
        with pytest.raises(ValueError, match="zip"):
            mm.body_space_bmi(space, np.r_[x[:len(BODY_MACRO_NAMES)], np.zeros(n)])
