"""Analytic checks of the two §5 additions in garment/lighting.py: the L1 ``sparsity`` penalty of Eq. 7's
solve and ``chromaticity_groups`` (§5.1's "intensity changes, chromaticity does not").

Written for mutation testing (issue 17, re-measure after b089271): no body model, each test well under a second.
The penalised solve has a closed form when the shading columns do not overlap (each light's own least squares,
shifted by the penalty and clamped at zero); the groups are exact when the colours take a few chromaticities.
"""

import re

import numpy as np
import pytest

from bodystudio.errors import InputError
from bodystudio.garment import lighting as lt


def exact(message):
    """A ``pytest.raises(match=...)`` pattern for exactly this message."""
    return "^" + re.escape(message) + "$"


# ------------------------------------------------------------------------------------------ L1 penalty


def disjoint_columns(K=12):
    """A shading matrix whose three columns light disjoint rows (K/3 each) with known values, an albedo per
    channel and pixels: the penalised Eq. 7 then splits into one scalar problem per column."""
    rng = np.random.default_rng(3)
    G = np.zeros((K, 3))
    third = K // 3
    for j in range(3):
        G[j * third:(j + 1) * third, j] = rng.uniform(0.3, 1.0, third)
    albedo = rng.uniform(0.3, 0.9, (K, 3))
    observed = rng.uniform(0.1, 0.8, (K, 3))
    return G, albedo, observed


def scalar_solution(G, albedo, observed, penalty):
    """Column j, channel c: argmin_{x >= 0} ||a x - b||^2 / 2 + p x = max(0, (a.b - p) / a.a)."""
    want = np.zeros((G.shape[1], 3))
    for c in range(3):
        A = G * albedo[:, c:c + 1]
        for j in range(G.shape[1]):
            a, b = A[:, j], observed[:, c]
            want[j, c] = max(0.0, (a @ b - penalty[j]) / (a @ a))
    return want


@pytest.mark.parametrize("n_penalised", [None, 2, 0])
def test_sparsity_is_an_l1_penalty_of_sparsity_times_rows_on_the_penalised_columns(n_penalised):
    """``||A x - b||^2 / (2 K) + s sum x``: per column ``max(0, (a.b - s K) / a.a)``; unpenalised columns keep
    their plain least squares."""
    G, albedo, observed = disjoint_columns()
    K = len(G)
    s = 0.01
    got = lt.solve_lights(G, albedo, observed, "fast_nnls", sparsity=s, n_penalised=n_penalised)
    penalty = np.zeros(3)
    penalty[:3 if n_penalised is None else n_penalised] = s * K
    want = scalar_solution(G, albedo, observed, penalty)
    assert np.abs(got - want).max() < 1e-12
    plain = scalar_solution(G, albedo, observed, np.zeros(3))
    # the penalty lowers every penalised light that stays on, and leaves the others alone
    k = 3 if n_penalised is None else n_penalised
    assert np.all(got[:k] < plain[:k]) and np.abs(got[k:] - plain[k:]).max(initial=0.0) < 1e-12


def test_a_large_penalty_switches_a_light_off_and_zero_changes_nothing():
    G, albedo, observed = disjoint_columns()
    plain = lt.solve_lights(G, albedo, observed, "fast_nnls")
    assert np.array_equal(lt.solve_lights(G, albedo, observed, "fast_nnls", sparsity=0.0), plain)
    A = G * albedo[:, :1]
    # just above column 0's correlation a.b / K in channel 0: that light goes off in that channel, the other
    # lights keep their values
    s = (A[:, 0] @ observed[:, 0]) / len(G) * 1.0001
    got = lt.solve_lights(G, albedo, observed, "fast_nnls", sparsity=s, n_penalised=1)
    assert got[0, 0] == 0.0 and np.abs(got[1:] - plain[1:]).max() < 1e-12
    s = (A[:, 0] @ observed[:, 0]) / len(G) * 0.9999
    assert lt.solve_lights(G, albedo, observed, "fast_nnls", sparsity=s, n_penalised=1)[0, 0] > 0


def test_sparsity_matches_a_direct_minimisation_of_the_penalised_objective():
    """Overlapping columns (a real Eq. 7 matrix): the KKT conditions of the penalised NNLS hold."""
    rng = np.random.default_rng(5)
    normals = rng.normal(size=(300, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    directions = lt.golden_spiral_hemisphere(20, np.array([0.0, 0.0, 1.0]))
    G = lt.lambert_light_matrix(normals, directions)
    albedo = rng.uniform(0.3, 0.9, (300, 3))
    observed = albedo * (0.2 + 0.7 * np.clip(normals @ [0.3, 0.2, 0.93], 0, None))[:, None]
    observed += rng.normal(0, 0.02, observed.shape)
    s = 2e-3
    X = lt.solve_lights(G, albedo, observed, "fast_nnls", sparsity=s, n_penalised=20)
    for c in range(3):
        A = G * albedo[:, c:c + 1]
        grad = A.T @ (A @ X[:, c] - observed[:, c]) / len(G)
        grad[:20] += s
        on = X[:, c] > 0
        assert np.abs(grad[on]).max() < 1e-9  # stationary where a light is on
        assert grad[~on].min() > -1e-9  # no light would lower the objective by switching on
        assert X[20, c] > 0  # the ambient column is free and carries the constant part
    assert (X[:20] > 0).sum() < (lt.solve_lights(G, albedo, observed, "fast_nnls")[:20] > 0).sum()


@pytest.mark.parametrize("value", [-1e-9, float("nan"), float("inf"), -float("inf")])
def test_sparsity_must_be_finite_and_not_negative(value):
    G, albedo, observed = disjoint_columns()
    with pytest.raises(InputError, match=exact(f"lighting sparsity must be a finite number >= 0, got {value}")):
        lt.solve_lights(G, albedo, observed, "fast_nnls", sparsity=value)


@pytest.mark.parametrize("solver", ["nnls", "lstsq"])
def test_sparsity_needs_the_fast_solver_and_zero_passes_with_any(solver):
    G, albedo, observed = disjoint_columns()
    with pytest.raises(InputError, match=exact(f"lighting sparsity needs the fast_nnls solver, not {solver!r}")):
        lt.solve_lights(G, albedo, observed, solver, sparsity=1e-6)
    plain = scalar_solution(G, albedo, observed, np.zeros(3))
    assert np.abs(lt.solve_lights(G, albedo, observed, solver, sparsity=0.0) - plain).max() < 1e-12


def test_estimate_lighting_penalises_the_directional_lights_not_the_ambient():
    """With a penalty above every light's correlation, all directional lights go off and the ambient is the
    per-channel least squares ``sum a b / sum a^2``; below it, Eq. 7 with ``n_penalised`` = the lights."""
    rng = np.random.default_rng(2)
    normals = rng.normal(size=(200, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    albedo = rng.uniform(0.3, 0.9, (200, 3))
    axis = np.array([0.0, 0.0, 1.0])
    observed = albedo * (0.3 + 0.6 * np.clip(normals @ axis, 0, None))[:, None]
    points = normals.copy()
    off = lt.estimate_lighting(points, normals, albedo, observed, axis, n_lights=16, sparsity=10.0)
    assert off.directions.shape == (0, 3)
    assert np.abs(off.ambient - (albedo * observed).sum(0) / (albedo ** 2).sum(0)).max() < 1e-12
    s = 1e-3
    got = lt.estimate_lighting(points, normals, albedo, observed, axis, n_lights=16, sparsity=s)
    directions = lt.golden_spiral_hemisphere(16, axis)
    X = lt.solve_lights(lt.lambert_light_matrix(normals, directions), albedo, observed, "fast_nnls", s,
                        n_penalised=16)
    on = X[:16].sum(1) > 1e-9
    assert np.abs(got.directions - directions[on]).max() < 1e-15 and np.abs(got.colors - X[:16][on]).max() < 1e-12
    assert np.abs(got.ambient - X[16]).max() < 1e-12
    plain = lt.estimate_lighting(points, normals, albedo, observed, axis, n_lights=16)
    assert got.colors.sum() < plain.colors.sum() and got.ambient.sum() > plain.ambient.sum()


def test_estimate_lighting_default_is_no_penalty():
    rng = np.random.default_rng(4)
    normals = rng.normal(size=(100, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    albedo = rng.uniform(0.3, 0.9, (100, 3))
    axis = np.array([0.0, 0.0, 1.0])
    observed = albedo * (0.2 + 0.6 * np.clip(normals @ [0.2, 0.1, 0.97], 0, None))[:, None]
    a = lt.estimate_lighting(normals, normals, albedo, observed, axis, n_lights=16)
    b = lt.estimate_lighting(normals, normals, albedo, observed, axis, n_lights=16, sparsity=0.0)
    assert np.array_equal(a.colors, b.colors) and np.array_equal(a.ambient, b.ambient)


# ------------------------------------------------------------------------------------------ materials


def shaded(colour, n, rng):
    """One material under ``n`` shading levels: the same chromaticity, intensities 0.2-1."""
    return np.asarray(colour) * rng.uniform(0.2, 1.0, n)[:, None]


def test_one_chromaticity_is_one_group_and_unseen_vertices_are_minus_one():
    rng = np.random.default_rng(0)
    albedo = shaded([0.6, 0.3, 0.1], 50, rng)
    seen = np.ones(50, bool)
    seen[[3, 17]] = False
    labels = lt.chromaticity_groups(albedo, seen)
    assert labels.shape == (50,) and np.all(labels[seen] == 0) and np.all(labels[~seen] == -1)
    assert np.array_equal(lt.chromaticity_groups(albedo, np.zeros(50, bool)), np.full(50, -1))
    # a list of lists and an int mask are accepted like arrays
    assert np.array_equal(lt.chromaticity_groups(albedo.tolist(), seen.astype(int)), labels)


def test_chromaticity_is_r_and_g_over_the_sum_so_intensity_and_black_do_not_split():
    """(0.2, 0.2, 0.6) and (0.4, 0.4, 1.2) are one material; (0.2, 0.2, 0.2) is another (same r, g); black
    pixels (sum 0) get the chromaticity (0, 0), the same as pure blue."""
    albedo = np.array([[0.2, 0.2, 0.6], [0.4, 0.4, 1.2], [0.2, 0.2, 0.2], [0.3, 0.3, 0.3],
                       [0.0, 0.0, 0.0], [0.0, 0.0, 0.5]])
    labels = lt.chromaticity_groups(albedo, np.ones(6, bool))
    assert labels[0] == labels[1] and labels[2] == labels[3] and labels[4] == labels[5]
    assert len({labels[0], labels[2], labels[4]}) == 3
    assert sorted(set(labels)) == [0, 1, 2]


def test_groups_closer_than_merge_are_one_material():
    """Two chromaticities 0.02 apart (< merge 0.03) are one group, 0.04 apart are two; a chain 0, 0.02, 0.04 is
    merged transitively into one."""
    def colours(chromas):
        rgb = [[r, g, 1.0 - r - g] for r, g in chromas]
        return np.repeat(np.array(rgb), 10, axis=0)

    near = colours([(0.30, 0.30), (0.32, 0.30)])
    far = colours([(0.30, 0.30), (0.34, 0.30)])
    chain = colours([(0.30, 0.30), (0.32, 0.30), (0.34, 0.30)])
    assert np.all(lt.chromaticity_groups(near, np.ones(20, bool)) == 0)
    two = lt.chromaticity_groups(far, np.ones(20, bool))
    assert np.all(two[:10] == two[0]) and np.all(two[10:] == 1 - two[0])
    assert np.all(lt.chromaticity_groups(chain, np.ones(30, bool)) == 0)
    # a larger merge radius joins the far pair; a smaller one splits the near pair
    assert np.all(lt.chromaticity_groups(far, np.ones(20, bool), merge=0.05) == 0)
    split = lt.chromaticity_groups(near, np.ones(20, bool), merge=0.01)
    assert split[0] != split[10]


def test_at_most_max_groups_materials_labelled_from_zero():
    rng = np.random.default_rng(1)
    palette = [[0.8, 0.1, 0.1], [0.1, 0.8, 0.1], [0.1, 0.1, 0.8], [0.45, 0.45, 0.1], [0.1, 0.45, 0.45],
               [0.45, 0.1, 0.45], [0.34, 0.33, 0.33], [0.6, 0.3, 0.1]]
    albedo = np.vstack([shaded(c, 25, rng) for c in palette])
    seen = np.ones(len(albedo), bool)
    for m in (1, 2, 3, 6, 8):
        labels = lt.chromaticity_groups(albedo, seen, max_groups=m)
        assert labels.min() == 0 and labels.max() + 1 == len(np.unique(labels)) <= m
    six = lt.chromaticity_groups(albedo, seen)  # default six
    assert len(np.unique(six)) == 6
    eight = lt.chromaticity_groups(albedo, seen, max_groups=8)
    assert len(np.unique(eight)) == 8  # well-separated palette: every colour its own material
    assert all(len(np.unique(eight[i * 25:(i + 1) * 25])) == 1 for i in range(8))


def test_groups_are_deterministic_for_a_seed():
    rng = np.random.default_rng(2)
    albedo = rng.uniform(0.1, 0.9, (300, 3))  # no material structure: k-means depends on its start
    seen = np.ones(300, bool)
    a = lt.chromaticity_groups(albedo, seen)
    assert np.array_equal(a, lt.chromaticity_groups(albedo, seen))
    assert np.array_equal(a, lt.chromaticity_groups(albedo, seen, seed=0))
    assert any(not np.array_equal(a, lt.chromaticity_groups(albedo, seen, seed=s)) for s in (1, 2, 3))


def test_chromaticities_equal_to_four_decimals_count_as_one():
    """k is the number of distinct chromaticities rounded to 1e-4 (at most ``max_groups``): two colours whose
    chromaticity differs by 1e-6 are one group without running k-means."""
    albedo = np.array([[0.3, 0.3, 0.4], [0.300001, 0.3, 0.399999]] * 5)
    assert np.all(lt.chromaticity_groups(albedo, np.ones(10, bool)) == 0)
    # only the seen vertices count: an unseen outlier does not make a second group
    albedo = np.vstack([albedo, [[0.9, 0.05, 0.05]]])
    seen = np.r_[np.ones(10, bool), False]
    assert np.array_equal(lt.chromaticity_groups(albedo, seen), np.r_[np.zeros(10, int), -1])
