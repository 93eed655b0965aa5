"""The body form's weight macro solved from the BMI through the body model's own measurement
(``model.body_space_bmi``, ``model.body_weight_for_bmi``, ``ArmModel.body_weight == "bmi"``; issue 11 §4,
docs/muscle.md "Dataset extension, ninth pass").

Planted: training men whose weight macro is the one that gives their BMI at their muscularity (MakeHuman's BMI is not
linear in its weight and muscle macros: BMI 19-25 at muscularity 0.3-0.6 spans weights 0 to 0.8), and a heavy man of
BMI 31 and muscularity 0 out of their range (weight 0.75). Regressed on the numbers, his weight macro extrapolates
past the blend's end (1.6); solved from his BMI it is within a few hundredths of his own."""

import numpy as np
import pytest

TRAIN = [(19.0, 0.6), (21.0, 0.5), (23.0, 0.4), (24.0, 0.3), (20.0, 0.3), (25.0, 0.35)]  # (BMI, muscularity)


@pytest.fixture(scope="module")
def planted(tiny_arm_model_path):
    """(the body space, {"regressed": model, "bmi": model}, the held-out shape, his parameters, his rest arm)."""
    from dataclasses import replace

    from bodystudio.muscle.model import (
        ArmShapeParams,
        body_space_for_model,
        body_weight_for_bmi,
        fit_body_form,
        length_displacements,
        load_arm_model,
        with_shape_form,
    )

    model = load_arm_model(tiny_arm_model_path)
    space = body_space_for_model(model)

    def params(shape):
        x = space.prior(shape)[0]
        x[3] = body_weight_for_bmi(space, x, shape.bmi)
        return x

    shapes = [ArmShapeParams(b, m, 1.75, 0.5, sex=1.0) for b, m in TRAIN]
    P = np.stack([params(s) for s in shapes])
    rows = np.array([s.as_row() for s in shapes])
    residuals = np.stack([(space.rest_and_joints(x)[0] - model.base_vertices - length_displacements(model, s)).ravel()
                          for x, s in zip(P, shapes, strict=True)])
    linear = with_shape_form(replace(model, shape_rows=rows, shape_residuals=residuals, shape_form="body"), "linear")
    forms = {}
    for weight in ("regressed", "bmi"):
        base = replace(linear, body_weight=weight)
        body_coeffs, shape_coeffs = fit_body_form(base, rows, residuals, P)
        forms[weight] = replace(base, shape_form="body", shape_params=P, body_coeffs=body_coeffs,
                                shape_coeffs=shape_coeffs)
    held = ArmShapeParams(31.0, 0.0, 1.75, 0.5, sex=1.0)
    x = params(held)
    return space, forms, held, x, space.rest_and_joints(x)[0]


def test_the_body_space_bmi_is_the_subjects_own_measurement(planted):
    """``body_space_bmi`` gives ``measure_arm_shape``'s BMI (the 6k body's volume mass over its stature squared) for a
    body with an arm modifier, which moves both arms: the space holds one side's target, the measurement both."""
    from bodystudio.body.phenotype import Phenotype
    from bodystudio.muscle.model import body_parameters_of, body_space_bmi, measure_arm_shape

    space = planted[0]
    phenotype, local = Phenotype(gender=1.0, muscle=0.3, weight=0.7), {"upperarm-fat-decr-incr": 0.8}
    x = body_parameters_of(phenotype, local, space)
    bmi, stature = body_space_bmi(space, x)
    measured = measure_arm_shape(phenotype, local)
    assert abs(bmi - measured.bmi) < 1e-6 and abs(stature - measured.height_m) < 1e-9, (bmi, measured)
    without = body_space_bmi(space, body_parameters_of(phenotype, {}, space))[0]
    assert 2 * abs(bmi - without) > 0.05, (bmi, without)  # each arm's fat moves the BMI by > 0.025


def test_the_weight_solved_from_the_bmi_reaches_a_heavy_man_the_regression_misses(planted):
    from bodystudio.muscle.model import body_space_bmi, model_rest_vertices, regressed_body_parameters

    space, forms, held, truth_x, truth = planted
    x = {k: regressed_body_parameters(m, held) for k, m in forms.items()}
    err = {k: 1000 * float(np.median(np.linalg.norm(model_rest_vertices(m, held, np.zeros((3, 3))) - truth, axis=1)))
           for k, m in forms.items()}
    # measured: weight 0.80 for his 0.75 (his regressed muscularity 0.07, not 0), 0.6 mm; regressed 1.65, 10.8 mm
    assert abs(x["bmi"][3] - truth_x[3]) < 0.08, (x["bmi"][3], truth_x[3])
    assert x["regressed"][3] > truth_x[3] + 0.3, (x["regressed"][3], truth_x[3])
    assert err["bmi"] < 1.5 and err["bmi"] < 0.25 * err["regressed"], err
    assert abs(body_space_bmi(space, x["bmi"])[0] - held.bmi) < 0.01  # the body it makes has his BMI
    assert not forms["bmi"].body_coeffs[:, 3].any()  # not regressed: solved


def test_the_body_weight_is_saved_and_older_files_read_as_regressed(planted, tmp_path):
    import json

    from bodystudio.muscle.model import load_arm_model, model_rest_vertices, save_arm_model

    _, forms, held, _, _ = planted
    save_arm_model(tmp_path / "m.npz", forms["bmi"])
    back = load_arm_model(tmp_path / "m.npz")
    assert back.body_weight == "bmi"
    np.testing.assert_allclose(model_rest_vertices(back, held), model_rest_vertices(forms["bmi"], held), atol=1e-12)
    with np.load(tmp_path / "m.npz") as z:  # a file of the eighth pass: no body_weight in its header
        arrays = {k: z[k] for k in z.files}
    header = json.loads(str(arrays.pop("header")))
    del header["body_weight"]
    np.savez(tmp_path / "old.npz", header=np.array(json.dumps(header)), **arrays)
    assert load_arm_model(tmp_path / "old.npz").body_weight == "regressed"
