"""The constraint solver (Rapid Skin §III, Eq. 3-5, 7, 9) on a tiny irregular mesh where the answers are exact:
the LME normal equations are the energy's gradient, CG reaches the direct minimiser, every solver is
reachable by name, defaults are the documented ones, and bad inputs are refused before the compiled sweeps."""

import sys

import numpy as np
import pytest

from bodystudio.errors import InputError
from bodystudio.geometry.laplacian import cotangent_delta_coordinates
from bodystudio.reconstruct import solver
from bodystudio.reconstruct.solver import (
    ConstraintSet,
    DepthConstraints,
    LMESystem,
    SilhouetteConstraints,
    cholesky,
    conjugate_gradient,
    constraint_energy,
    gauss_seidel,
    jacobi,
    lme_normal_equations,
    solve_constraints,
)

# An irregular octahedron (every edge length differs): 6 vertices, 18 unknowns.
_V = np.array([[1.0, 0.1, 0.05], [-0.1, 0.9, -0.1], [-1.2, -0.1, 0.1],
               [0.05, -0.8, 0.0], [0.1, 0.05, 1.1], [-0.05, 0.1, -0.7]])
_F = np.array([[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4], [1, 0, 5], [2, 1, 5], [3, 2, 5], [0, 3, 5]])


def _constraints(k_sm=1.0, n_sil=4, n_dep=3, seed=0):
    """Smoothness to a rest shape differing from ``_V``, rays and planes pulling some vertices elsewhere."""
    rng = np.random.default_rng(seed)
    rest_shape = _V * [1.1, 0.9, 1.05] + 0.02 * rng.normal(size=_V.shape)
    delta, delta_rest = cotangent_delta_coordinates(rest_shape, _F)
    target = _V + 0.1 * rng.normal(size=_V.shape)
    vid = np.array([0, 2, 4, 2])[:n_sil]
    d = rng.normal(size=(n_sil, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    sil = SilhouetteConstraints(vid, target[vid] - 3.0 * d, d, np.array([0.9, 0.5, 0.7, 0.3])[:n_sil])
    dvid = np.array([1, 3, 5])[:n_dep]
    nrm = rng.normal(size=(n_dep, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    dep = DepthConstraints(dvid, target[dvid], nrm, np.array([0.8, 0.4, 0.6])[:n_dep])
    return ConstraintSet(delta, delta_rest, sil, dep, k_sm)


def _energy_gradient(V, cs, h=1e-5):
    """Central differences of the quadratic energy: exact up to round-off."""
    g = np.zeros(V.size)
    x = V.ravel()
    for i in range(V.size):
        e = np.zeros(V.size)
        e[i] = h
        g[i] = (constraint_energy((x + e).reshape(-1, 3), cs) - constraint_energy((x - e).reshape(-1, 3), cs)) / (2 * h)
    return g


def test_constraint_energy_is_the_weighted_sum_of_squared_residuals():
    """Eq. 5 with squared norms, computed term by term by hand."""
    cs = _constraints(k_sm=0.7)
    V = _V + 0.05
    L = cs.delta.matrix.toarray()
    e_sm = 0.7 * np.sum((L @ V - cs.delta_rest) ** 2)
    sil = cs.silhouette
    e_sil = 0.0
    for c, i in enumerate(sil.vertex):
        p = V[i] - sil.origin[c]
        e_sil += sil.k[c] * np.sum((p - (p @ sil.direction[c]) * sil.direction[c]) ** 2)
    dep = cs.depth
    e_dep = sum(dep.k[c] * ((V[i] - dep.point[c]) @ dep.normal[c]) ** 2 for c, i in enumerate(dep.vertex))
    assert min(e_sm, e_sil, e_dep) > 1e-4  # every term contributes
    assert constraint_energy(V, cs) == pytest.approx(e_sm + e_sil + e_dep, rel=1e-12)


@pytest.mark.parametrize("k_sm,n_sil,n_dep", [(0.7, 4, 3), (1.0, 0, 3), (1.3, 4, 0)])
def test_lme_normal_equations_are_the_energy_gradient(k_sm, n_sil, n_dep):
    """E(x) = x^T A x - 2 b^T x + c, so grad E = 2 (A x - b) at any x (the Tikhonov term is 1e-12)."""
    cs = _constraints(k_sm, n_sil, n_dep)
    A, b = lme_normal_equations(cs)
    assert A.shape == (18, 18) and b.shape == (18,)
    rng = np.random.default_rng(1)
    for V in (_V, _V + 0.1 * rng.normal(size=_V.shape)):
        g = _energy_gradient(V, cs)
        np.testing.assert_allclose(2 * (A @ V.ravel() - b), g, rtol=0, atol=1e-8 * np.abs(g).max())
    np.testing.assert_allclose(A.toarray(), A.toarray().T, atol=1e-15)


def test_cholesky_is_the_energy_minimiser_and_cg_reaches_it():
    cs = _constraints(0.7)
    lme = LMESystem(cs.delta)
    V_min = cholesky(_V, cs, lme)
    assert np.abs(_energy_gradient(V_min, cs)).max() < 1e-9  # stationary point of the quadratic energy
    assert constraint_energy(V_min, cs) < 0.5 * constraint_energy(_V, cs)
    # the symbolic analysis is reused: a second constraint set on the same operator solves correctly
    cs2 = _constraints(1.0, seed=2)
    cs2 = ConstraintSet(cs.delta, cs.delta_rest, cs2.silhouette, cs2.depth, 1.0)
    V2 = cholesky(_V, cs2, lme)
    assert np.abs(_energy_gradient(V2, cs2)).max() < 1e-9
    # CG on 18 unknowns: close to exact after a few x 18 steps, warm-started at V
    seen = []
    V_cg = conjugate_gradient(_V, cs, 60, lme, callback=lambda it, X: seen.append(it))
    assert seen == list(range(1, len(seen) + 1)) and len(seen) >= 18
    np.testing.assert_allclose(V_cg, V_min, atol=1e-7)
    # a few steps lower the energy monotonically but do not reach the minimum yet
    e = [constraint_energy(conjugate_gradient(_V, cs, n, lme), cs) for n in (0, 1, 2, 4)]
    assert e[0] == pytest.approx(constraint_energy(_V, cs), rel=1e-12)
    assert e[0] > e[1] > e[2] > e[3] > constraint_energy(V_min, cs)
    # at the minimum CG stops at once (residual 0) and returns its start
    np.testing.assert_allclose(conjugate_gradient(V_min, cs, 5, lme), V_min, atol=1e-9)


def test_cholesky_without_cvxopt_falls_back_to_superlu(monkeypatch):
    cs = _constraints(0.7)
    ref = cholesky(_V, cs)
    monkeypatch.setitem(sys.modules, "cvxopt", None)  # import cvxopt -> ImportError
    monkeypatch.setitem(sys.modules, "cvxopt.cholmod", None)
    np.testing.assert_allclose(LMESystem(cs.delta).cholesky(cs), ref, atol=1e-9)


def test_solve_constraints_dispatches_with_the_documented_defaults():
    cs = _constraints(0.7)
    assert np.array_equal(solve_constraints(_V, cs), gauss_seidel(_V, cs, 8))
    assert np.array_equal(solve_constraints(_V, cs, "gs", 3), gauss_seidel(_V, cs, 3))
    assert np.array_equal(solve_constraints(_V, cs, "jacobi", 5), jacobi(_V, cs, 5))
    np.testing.assert_allclose(solve_constraints(_V, cs, "cholesky"), cholesky(_V, cs), atol=1e-12)
    np.testing.assert_allclose(solve_constraints(_V, cs, "cg", 4), conjugate_gradient(_V, cs, 4), atol=1e-12)
    # the defaults: GS 8 sweeps, Jacobi 32 sweeps with relaxation 1.5, CG 8 steps
    assert not np.array_equal(gauss_seidel(_V, cs), gauss_seidel(_V, cs, 7))
    assert np.array_equal(gauss_seidel(_V, cs), gauss_seidel(_V, cs, 8))
    assert np.array_equal(jacobi(_V, cs), jacobi(_V, cs, 32, 1.5))
    assert not np.array_equal(jacobi(_V, cs), jacobi(_V, cs, 32, 1.0))
    assert np.array_equal(conjugate_gradient(_V, cs), conjugate_gradient(_V, cs, 8))
    with pytest.raises(InputError, match="unknown solver 'lu'; valid: gs, jacobi, cholesky, cg"):
        solve_constraints(_V, cs, "lu")


@pytest.mark.parametrize("solve", [gauss_seidel, jacobi, conjugate_gradient])
def test_callbacks_see_every_iteration_and_the_same_result(solve):
    cs = _constraints(0.7)
    seen = []
    V = solve(_V, cs, 5, callback=lambda it, X: seen.append((it, X.copy())))
    assert [it for it, _ in seen] == [1, 2, 3, 4, 5]
    np.testing.assert_allclose(seen[-1][1], V, atol=1e-15)
    np.testing.assert_allclose(V, solve(_V, cs, 5), atol=1e-13)
    assert not np.allclose(seen[0][1], V)  # each call sees that iteration's mesh, not the final one


def test_solvers_do_not_modify_their_input():
    cs = _constraints(0.7)
    V = _V.copy()
    for solve in (gauss_seidel, jacobi, conjugate_gradient, cholesky):
        solve(V, cs)
        assert np.array_equal(V, _V)


@pytest.mark.parametrize("V", [_V[:5], _V[:, :2], _V.ravel(), _V[None]])
def test_wrong_vertex_arrays_are_input_errors(V):
    cs = _constraints(0.7)
    for solve in (gauss_seidel, jacobi, conjugate_gradient, cholesky):
        with pytest.raises(InputError, match=r"vertices must be \(6, 3\) for this template"):
            solve(V, cs)


def test_negative_constraint_vertex_is_an_input_error():
    cs = _constraints(0.7)
    sil = cs.silhouette
    bad = SilhouetteConstraints(np.r_[-1, sil.vertex[1:]], sil.origin, sil.direction, sil.k)
    for kind in ("sil", "dep"):
        if kind == "sil":
            cs_bad = ConstraintSet(cs.delta, cs.delta_rest, bad, cs.depth)
        else:
            dep = cs.depth
            cs_bad = ConstraintSet(cs.delta, cs.delta_rest, cs.silhouette,
                                   DepthConstraints(np.r_[dep.vertex[:-1], 6], dep.point, dep.normal, dep.k))
        for solve in (gauss_seidel, jacobi):
            with pytest.raises(InputError, match=r"constraint vertex ids must lie in \[0, 6\)"):
                solve(_V, cs_bad)


class _HugeDelta:
    """Stands in for a DeltaOperator too large for the solver's uint32 indices (never allocated)."""

    def __init__(self, n_vertices, n_entries):
        self.n_vertices = n_vertices
        self.indices = range(n_entries)


@pytest.mark.parametrize("n_vertices,n_entries,too_big", [
    ((2**32) // 3 + 1, 10, True),  # 3 n >= 2^32 (flat xyz offsets)
    ((2**32) // 3, 10, False),
    (10, 2**32, True),  # nnz >= 2^32
    (10, 2**32 - 1, False),
])
def test_uint32_index_limit(n_vertices, n_entries, too_big, monkeypatch):
    calls = []
    monkeypatch.setattr(solver, "_smoothness_layout", lambda *a: calls.append(a) or (None, None, None))
    delta = _HugeDelta(n_vertices, n_entries)
    delta.indptr = delta.weights = delta.reverse = np.zeros(1)
    if too_big:
        with pytest.raises(InputError, match=f"{n_vertices} vertices are too many for the uint32 solver indices"):
            solver._smoothness_arrays(delta)
        assert not calls
    else:
        solver._smoothness_arrays(delta)
        assert len(calls) == 1


def test_empty_constraint_sets():
    sil, dep = SilhouetteConstraints.empty(), DepthConstraints.empty()
    assert len(sil) == 0 and len(dep) == 0
    assert sil.origin.shape == sil.direction.shape == (0, 3) and dep.point.shape == dep.normal.shape == (0, 3)
    assert sil.vertex.dtype == dep.vertex.dtype == np.int64 and sil.camera.dtype == np.int64
    assert sil.vertex.shape == dep.vertex.shape == sil.camera.shape == (0,)
    for a in (sil.origin, sil.direction, sil.k, sil.pixel_distance, dep.point, dep.normal, dep.k):
        assert a.dtype == np.float64
    assert sil.k.shape == sil.pixel_distance.shape == dep.k.shape == (0,)
    # smoothness alone: the rest shape's delta coordinates are kept, so the rest shape is a fixed point
    delta, rest = cotangent_delta_coordinates(_V, _F)
    cs = ConstraintSet(delta, rest, sil, dep)
    assert constraint_energy(_V, cs) < 1e-25
    for name in ("gs", "jacobi"):
        np.testing.assert_allclose(solve_constraints(_V, cs, name), _V, atol=1e-9)
    # the LME system has translations in its null space (its 1e-12 Tikhonov term picks one): shape kept
    X = solve_constraints(_V, cs, "cholesky")
    np.testing.assert_allclose(X - X.mean(0), _V - _V.mean(0), atol=1e-6)


def test_any_vertex_array_layout_is_solved_in_float64():
    """float32 or Fortran-ordered vertices are copied to C-ordered float64 before the compiled sweeps."""
    cs = _constraints(0.7)
    V32 = _V.astype(np.float32)
    Vf = np.asfortranarray(_V)
    for solve in (gauss_seidel, jacobi, conjugate_gradient, cholesky):
        ref = solve(V32.astype(np.float64), cs)
        got = solve(V32, cs)
        assert got.dtype == np.float64
        np.testing.assert_allclose(got, ref, rtol=0, atol=1e-15)
        np.testing.assert_allclose(solve(Vf, cs), solve(_V, cs), rtol=0, atol=1e-15)
    np.testing.assert_allclose(solver.projection_weight(np.float32(0.5), 8), 1 - 0.5 ** (1 / 8), rtol=1e-15)
    assert solver.projection_weight(np.array([0.5], np.float32), 3).dtype == np.float64


def test_smoothness_layout_is_computed_once_per_operator(monkeypatch):
    cs = _constraints(0.7)
    calls = []
    real = solver._smoothness_layout
    monkeypatch.setattr(solver, "_smoothness_layout", lambda *a: calls.append(1) or real(*a))
    gauss_seidel(_V, cs, 2)
    jacobi(_V, cs, 2)
    gauss_seidel(_V, cs, 2)
    assert len(calls) == 1


def test_cg_stops_at_a_zero_residual():
    """Nothing to do (zero rest deltas, zero mesh, no data terms): CG returns its start, not None."""
    delta, _ = cotangent_delta_coordinates(_V, _F)
    cs = ConstraintSet(delta, np.zeros((6, 3)), SilhouetteConstraints.empty(), DepthConstraints.empty())
    seen = []
    X = conjugate_gradient(np.zeros((6, 3)), cs, 5, callback=lambda it, X: seen.append(it))
    assert isinstance(X, np.ndarray) and X.shape == (6, 3) and not X.any() and seen == []


def test_solve_constraints_uses_the_lme_system_it_is_given():
    """The LME system carries L^T L and the symbolic Cholesky analysis from one re-matching to the next."""
    cs = _constraints(0.7)
    lme = LMESystem(cs.delta)
    calls = []
    real = lme.normal_equations
    lme.normal_equations = lambda c: calls.append(c) or real(c)
    X = solve_constraints(_V, cs, "cholesky", lme=lme)
    assert len(calls) == 1 and lme._symbolic is not None
    np.testing.assert_allclose(X, cholesky(_V, cs), atol=1e-12)
    solve_constraints(_V, cs, "cg", 3, lme=lme)
    assert len(calls) == 2
