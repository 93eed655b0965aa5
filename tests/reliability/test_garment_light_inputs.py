"""Bad values for the lighting options added for the fit's §5 (sparsity, chromaticity groups)."""

import numpy as np
import pytest

from bodystudio.errors import InputError


@pytest.mark.parametrize("sparsity, solver, phrase", [
    (-1e-4, "fast_nnls", "lighting sparsity must be a finite number >= 0, got -0.0001"),
    (float("nan"), "fast_nnls", "lighting sparsity must be a finite number >= 0, got nan"),
    (1e-4, "nnls", "lighting sparsity needs the fast_nnls solver, not 'nnls'"),
    (1e-4, "lstsq", "lighting sparsity needs the fast_nnls solver, not 'lstsq'"),
])
def test_sparsity_is_checked(sparsity, solver, phrase):
    from bodystudio.garment.lighting import solve_lights

    with pytest.raises(InputError) as e:
        solve_lights(np.ones((20, 4)), np.ones((20, 3)), np.ones((20, 3)), solver, sparsity=sparsity)
    assert str(e.value) == phrase and "\n" not in str(e.value)


def test_sparsity_leaves_the_unpenalised_columns_free():
    """A huge penalty switches every penalised light off but not the ambient column."""
    from bodystudio.garment.lighting import solve_lights

    rng = np.random.default_rng(0)
    G = np.hstack([rng.uniform(0, 1, (50, 3)), np.ones((50, 1))])
    X = solve_lights(G, np.ones((50, 3)), np.full((50, 3), 0.5), sparsity=10.0, n_penalised=3)
    assert np.all(X[:3] == 0) and np.allclose(X[3], 0.5)


def test_chromaticity_groups_of_nothing_seen_or_one_colour():
    from bodystudio.garment.lighting import chromaticity_groups

    colours = np.tile([0.5, 0.4, 0.3], (10, 1))
    assert np.all(chromaticity_groups(colours, np.zeros(10, bool)) == -1)
    assert np.all(chromaticity_groups(colours, np.ones(10, bool)) == 0)
