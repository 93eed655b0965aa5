"""The body form of the arm model's shape term (``model.with_shape_form``, ``extend_arm_model(shape_form="body")``;
issue 11 §4, docs/muscle.md "Dataset extension, eighth pass").

Planted: training rows that are the body model's own arms, the weight macro a linear function of BMI over BMI 18-26
(MakeHuman's weight blend below its average), plus one bump the body space cannot make. A subject of BMI 34 (weight
macro 0.95: the blend's other piece, the max-weight targets) is out of their range: the linear Eq. 6-7 extrapolates
the thin-side displacements and misses him; the body form regresses the macro, lets the body model blend it, and adds
the bump from its linear residual term."""

import numpy as np
import pytest

from bodystudio.muscle.arm import ArmPose


def _weight_macro(bmi):
    return 0.05 + (bmi - 18.0) * 0.05  # 18 -> 0.05, 26 -> 0.45, 37 -> 1.0 (the test's own made-up relation)


@pytest.fixture(scope="module")
def planted(tiny_arm_model_path):
    """(linear model, body-form model, held-out shape, its true rest arm, the bump) from the planted rows.

    The rows' body parameters are given (as a projection finds them where the arm identifies them; on the 2k arm the
    weight macro below its average is not identified: the projection itself is tested in test_extension_body_rest),
    and the body form is fitted on them with :func:`fit_body_form`, as :func:`with_shape_form` does."""
    from dataclasses import replace

    from bodystudio.muscle.model import (
        ArmShapeParams,
        body_space_for_model,
        fit_body_form,
        length_displacements,
        load_arm_model,
        with_shape_form,
    )

    model = load_arm_model(tiny_arm_model_path)
    space = body_space_for_model(model)
    mean = space.prior(ArmShapeParams(22.0, 0.5, 1.75, 0.5, sex=1.0))[0]
    n = model.n_vertices
    bump = np.zeros((n, 3))
    bump[: n // 3, 1] = 0.003  # 3 mm along y on a third of the vertices: no body-space arm makes it

    def params(bmi):
        x = mean.copy()
        x[3] = _weight_macro(bmi)
        return x

    def arm(bmi):
        return space.rest_and_joints(params(bmi))[0] + bump

    # nine subjects, three base-pose rows each (as the benchmark's ten training men)
    shapes = [ArmShapeParams(b, 0.5, 1.75, 0.5, sex=1.0) for b in np.arange(18.0, 26.5, 1.0) for _ in range(3)]
    rows = np.array([s.as_row() for s in shapes])
    residuals = np.stack([(arm(s.bmi) - model.base_vertices - length_displacements(model, s)).ravel()
                          for s in shapes])
    linear = with_shape_form(replace(model, shape_rows=rows, shape_residuals=residuals, shape_form="body"), "linear")
    P = np.stack([params(s.bmi) for s in shapes])
    body_coeffs, shape_coeffs = fit_body_form(linear, rows, residuals, P)
    body = replace(linear, shape_form="body", shape_params=P, body_coeffs=body_coeffs, shape_coeffs=shape_coeffs)
    held = ArmShapeParams(37.0, 0.5, 1.75, 0.5, sex=1.0)
    return linear, body, held, arm(held.bmi), bump


def _rest_error_mm(model, shape, truth):
    from bodystudio.muscle.model import model_rest_vertices

    rest = model_rest_vertices(model, shape, np.zeros((3, 3)))
    return 1000 * float(np.median(np.linalg.norm(rest - truth, axis=1)))


def test_the_body_form_reconstructs_an_out_of_range_subject_the_linear_form_misses(planted):
    linear, body, held, truth, _ = planted
    lin_mm, body_mm = _rest_error_mm(linear, held, truth), _rest_error_mm(body, held, truth)
    assert lin_mm > 3.0, lin_mm  # measured 3.6 mm
    # measured 1.15 mm: the weight macro regressed short of 1.0 (the Tikhonov weight, the tiny model's population scale)
    assert body_mm < 1.5 and body_mm < 0.4 * lin_mm, (body_mm, lin_mm)
    assert body.shape_form == "body" and linear.shape_form == "linear"


def test_the_body_form_keeps_the_training_rows_and_their_bump(planted):
    """In range, both forms give the rows back; the bump (outside the body space) comes from the residual term."""
    from bodystudio.muscle.model import ArmShapeParams, body_form_rest_vertices, regressed_body_parameters

    linear, body, _, _, bump = planted
    shape = ArmShapeParams(22.0, 0.5, 1.75, 0.5, sex=1.0)
    x = regressed_body_parameters(body, shape)
    assert abs(x[3] - _weight_macro(22.0)) < 0.02, x[3]  # the weight macro regressed on BMI
    assert abs(regressed_body_parameters(body, ArmShapeParams(26.0, 0.5, 1.75, 0.5, sex=1.0))[3] - x[3]) > 0.15
    truth = body_form_rest_vertices(body, shape)  # the body model's arm at it, without the residual term
    from bodystudio.muscle.model import model_rest_vertices

    rest = model_rest_vertices(body, shape, np.zeros((3, 3)))
    np.testing.assert_allclose(np.median(rest - truth, axis=0), np.median(bump, axis=0), atol=5e-4)
    assert 1000 * np.abs((rest - truth)[: len(bump) // 3, 1]).mean() > 2.0  # the bump: 3 mm on a third


def test_a_body_form_model_extends_and_saves(planted, tmp_path):
    """Extending keeps the form and its stored parameters (only the new row is projected); the file reads back."""
    from bodystudio.muscle.model import ArmSample, extend_arm_model, load_arm_model, save_arm_model

    linear, body, held, truth, _ = planted
    sample = ArmSample("held", held, truth, ArmPose.rest(), np.zeros((3, 3)))
    extended = extend_arm_model(body, [sample])
    assert extended.shape_form == "body" and len(extended.shape_params) == len(body.shape_params) + 1
    np.testing.assert_array_equal(extended.shape_params[:-1], body.shape_params)
    assert _rest_error_mm(extended, held, truth) < _rest_error_mm(extend_arm_model(linear, [sample]), held, truth)
    save_arm_model(tmp_path / "m.npz", extended)
    back = load_arm_model(tmp_path / "m.npz")
    assert back.shape_form == "body"
    np.testing.assert_allclose(back.body_coeffs, extended.body_coeffs, rtol=0, atol=0)
    assert extend_arm_model(linear, [sample]).shape_form == "linear"


def test_the_weight_macro_is_regressed_on_the_bmi_muscularity_product(planted):
    """MakeHuman's BMI is not linear in its weight and muscle macros: the weight macro's inputs include their product
    (a heavy man of muscularity 0 got 0.95 for his 0.81 without it; docs/muscle.md, eighth pass)."""
    from bodystudio.muscle.model import BODY_MACRO_NAMES, body_form_columns, body_form_design, shape_design

    _, body, held, _, _ = planted
    rows = np.array([held.as_row(), [20.0, 0.9, 1.6, 0.45, 0.0]])
    X, S = body_form_design(body, rows), shape_design(body, rows)
    np.testing.assert_array_equal(X[:, :6], S)
    np.testing.assert_allclose(X[:, 6], S[:, 1] * S[:, 2])
    assert body_form_columns(BODY_MACRO_NAMES.index("weight")) == [0, 1, 2, 3, 6]
    assert body_form_columns(BODY_MACRO_NAMES.index("gender")) == [0, 5]
    assert body_form_columns(BODY_MACRO_NAMES.index("age")) == [0] and body_form_columns(20) == [0]
