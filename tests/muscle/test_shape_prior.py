"""The Sec. 6.2 shape fit's population prior (mus12a; ``refine.population_shape_prior``,
``fit_shape_parameters(prior=)``, ``CaptureOptions.shape_prior_weight``): the prior's figures from the model's
training rows, and its pull in the fit."""

from types import SimpleNamespace

import numpy as np
import pytest

from bodystudio.errors import InputError
from bodystudio.muscle import refine
from bodystudio.muscle.arm import ArmPose
from tests.muscle.test_refine_analytic import _frame, _no_data_frame, model_case  # noqa: F401 (the fixture)

#: training rows (BMI, muscularity, height, arm length, sex), each subject three times as the model stores them
ROWS = np.repeat(np.array([[20.0, 0.5, 1.80, 0.50, 1.0],
                           [26.0, 0.3, 1.70, 0.50, 1.0],
                           [18.0, 0.6, 1.57, 0.44, 0.0],
                           [22.0, 0.4, 1.62, 0.45, 0.0],
                           [20.0, 0.5, 1.60, 0.44, 0.0]]), 3, axis=0)


def test_the_prior_is_the_training_subjects_of_the_sex_and_the_height_follows_the_arm():
    model = SimpleNamespace(shape_rows=ROWS)
    women = ROWS[6:][::3]
    mean, sigma = refine.population_shape_prior(model, 0.0, 0.46)
    np.testing.assert_allclose(mean[:2], women[:, :2].mean(axis=0), rtol=1e-12)  # each subject once
    np.testing.assert_allclose(sigma[:2], women[:, :2].std(axis=0, ddof=1), rtol=1e-12)
    ratio = women[:, 2] / women[:, 3]
    assert mean[2] == pytest.approx(ratio.mean() * 0.46, rel=1e-12)
    assert sigma[2] == pytest.approx(ratio.std(ddof=1) * 0.46, rel=1e-12)
    assert np.isnan(mean[3]) and np.isinf(sigma[3])  # the arm length: the tracker's, no prior
    men_mean, _ = refine.population_shape_prior(model, 0.96, 0.46)  # the sex rounded
    assert men_mean[0] == pytest.approx(23.0)
    # without the tracker's arm length: the height's own mean and spread
    mean, sigma = refine.population_shape_prior(model, 0.0, None)
    assert mean[2] == pytest.approx(women[:, 2].mean()) and sigma[2] == pytest.approx(women[:, 2].std(ddof=1))
    # one subject of the sex: every subject's
    one = SimpleNamespace(shape_rows=ROWS[:9])
    np.testing.assert_allclose(refine.population_shape_prior(one, 0.0, None)[0][:3],
                               ROWS[:9:3, :3].mean(axis=0), rtol=1e-12)
    # one training subject: no spread, no prior
    assert np.isinf(refine.population_shape_prior(SimpleNamespace(shape_rows=ROWS[:3]), 1.0, 0.5)[1]).all()


def test_the_prior_pulls_the_fit_in_units_of_its_spread(model_case):  # noqa: F811
    """No depth pairs: alone, the prior takes BMI, muscularity and height to its mean; against the tracker's joints of
    another shape the fit lies between the two, nearer the prior the larger the weight; scaling the spreads by k and
    the weight by k^2 gives the same fit (the residual is sqrt(weight) (x - mean) / sigma)."""
    from bodystudio.muscle.model import ArmShapeParams, model_joints

    model, shape, J, truth, mesh, sensor = model_case
    frame = _no_data_frame(model_case)
    poses = [truth, ArmPose(truth.root, truth.angles * 0.5)]
    mean = np.array([shape.bmi - 2.0, min(shape.muscularity + 0.1, 0.9), shape.height_m - 0.04, np.nan])
    sigma = np.array([1.0, 0.1, 0.02, np.inf])
    alone, _ = refine.fit_shape_parameters(model, [mesh, mesh], poses, [frame, frame], initial=shape, rounds=1,
                                           prior=(mean, sigma, 1.0))
    np.testing.assert_allclose(alone.as_vector()[:3], mean[:3], atol=1e-4)
    assert alone.arm_length_m == pytest.approx(shape.arm_length_m, abs=1e-6)  # no prior on it

    target = ArmShapeParams(shape.bmi + 1.5, shape.muscularity, shape.height_m + 0.03, shape.arm_length_m)
    Jt = model_joints(model, target)
    tracked = np.stack([refine.posed_joints(Jt, p) for p in poses])

    def fit(weight, scale=1.0):
        return refine.fit_shape_parameters(model, [mesh, mesh], poses, [frame, frame], initial=shape, rounds=1,
                                           tracker_joints=tracked, tracker_weight=1.0,
                                           prior=None if weight is None else (mean, scale * sigma,
                                                                              scale ** 2 * weight))[0].as_vector()

    free, weak, strong = fit(None), fit(1e-6), fit(1e-2)
    assert abs(free[0] - target.bmi) < 0.3  # the tracker's joints alone give the target's shape
    d_free, d_weak, d_strong = (np.abs(x[0] - mean[0]) for x in (free, weak, strong))
    assert d_strong < d_weak < d_free
    assert d_free - d_strong > 1.0  # the strong prior moves the BMI by more than a unit
    np.testing.assert_allclose(fit(1e-4, scale=3.0), fit(1e-4), atol=1e-5)


def test_the_capture_option_is_range_checked():
    from bodystudio.muscle.capture import CaptureOptions

    assert CaptureOptions().shape_prior_weight >= 0
    for bad in (-0.1, float("nan")):
        with pytest.raises(InputError, match="shape_prior_weight must be >= 0"):
            CaptureOptions(shape_prior_weight=bad)
