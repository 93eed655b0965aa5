"""The init's ``leg_splay`` and ``knee_hinge_weight`` options (mir12ab) and ``fit_shape``'s ``free_basis`` refuse a
bad value with one line naming it and the fix, before any work."""

import numpy as np
import pytest

from bodystudio.errors import InputError
from bodystudio.mirror.init import fit_shape, initialise_from_observations


@pytest.fixture(scope="module")
def model():
    from bodystudio.body.statistical import load_statistical_model

    return load_statistical_model("2k", progress=False)


@pytest.mark.parametrize("value", ["yes", 1, None])
def test_bad_leg_splay_is_refused(model, value):
    with pytest.raises(InputError, match=r"leg_splay must be True or False") as err:
        initialise_from_observations([], model, view_point=np.zeros(3), leg_splay=value)
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("free", [np.zeros((2, 5, 3)), np.zeros((5, 3)), "nan"])
def test_bad_free_basis_is_refused(model, free):
    V = model.mean
    if isinstance(free, str):
        free = np.full((1, len(V), 3), np.nan)
    with pytest.raises(InputError, match=rf"free_basis must be finite \(m, {len(V)}, 3\)") as err:
        fit_shape(V, model, correspondence=np.arange(len(V)), iterations=1, free_basis=free)
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("value", [-1.0, float("nan"), float("inf"), True, "3"])
def test_bad_knee_hinge_weight_is_refused(model, value):
    with pytest.raises(InputError, match=r"knee_hinge_weight must be a finite number >= 0 \(0: no knee-hinge splay "
                                         r"rows\), got") as err:
        initialise_from_observations([], model, view_point=np.zeros(3), knee_hinge_weight=value)
    assert "\n" not in str(err.value)
