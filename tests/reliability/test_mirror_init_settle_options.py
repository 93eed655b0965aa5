"""The init's settling options (mir12x: ``pass_relaxation``, ``pooled_points``, ``fixed_pool``, ``weighted_pool``;
mir12y: ``pool_seed`` of ``initialise_from_observations``) refuse a bad value with one line
naming it and the fix, before any work."""

import numpy as np
import pytest

from bodystudio.errors import InputError
from bodystudio.mirror.init import initialise_from_observations


@pytest.fixture(scope="module")
def model():
    from bodystudio.body.statistical import load_statistical_model

    return load_statistical_model("2k", progress=False)


@pytest.mark.parametrize("options, message", [
    (dict(pass_relaxation=0.0), r"pass_relaxation must be in \(0, 1\] \(1: each pass takes its own fit\), got 0.0"),
    (dict(pass_relaxation=1.5), r"pass_relaxation must be in \(0, 1\]"),
    (dict(pass_relaxation=float("nan")), r"pass_relaxation must be in \(0, 1\]"),
    (dict(pooled_points=0), r"pooled_points must be an integer >= 1 \(the depth points of one Eq. 2 fit\), got 0"),
    (dict(pooled_points=2.5), r"pooled_points must be an integer >= 1"),
    (dict(pooled_points=True), r"pooled_points must be an integer >= 1"),
    (dict(pool_seed=-1), r"pool_seed must be an integer >= 0 \(the seed of the random depth-point subsets\), got -1"),
    (dict(pool_seed=1.0), r"pool_seed must be an integer >= 0"),
    (dict(pool_seed=False), r"pool_seed must be an integer >= 0"),
])
def test_bad_settling_options_are_refused(model, options, message):
    with pytest.raises(InputError, match=message) as err:
        initialise_from_observations([], model, view_point=np.zeros(3), **options)
    assert "\n" not in str(err.value)
