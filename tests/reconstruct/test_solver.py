"""Constraint solver core (Rapid Skin §III): energy behaviour of GS, Jacobi, CG and the LME minimiser."""

import numpy as np
import pytest
import scipy.sparse as sp

from bodystudio.geometry.laplacian import cotangent_delta_coordinates
from bodystudio.reconstruct.solver import (
    ConstraintSet,
    DepthConstraints,
    SilhouetteConstraints,
    cholesky,
    conjugate_gradient,
    constraint_energy,
    gauss_seidel,
    jacobi,
    point_to_ray_distance,
    projection_weight,
)


@pytest.fixture(scope="module")
def fixed_constraints(body_2k):
    """Rays through the vertices of a locally bulged body (a known deformation), fixed for the solve."""
    V0, F = body_2k.vertices, body_2k.faces
    delta, delta_rest = cotangent_delta_coordinates(V0, F)
    rng = np.random.default_rng(3)
    from bodystudio.geometry.mesh import vertex_normals

    N = vertex_normals(V0, F)
    centre = V0[np.argmax(V0[:, 2])]
    bulge = 0.02 * np.exp(-np.sum((V0 - centre) ** 2, axis=1) / (2 * 0.08**2))
    target = V0 + bulge[:, None] * N
    vid = rng.choice(len(V0), 500, replace=False)
    d = rng.normal(size=(500, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    sil = SilhouetteConstraints(vid, target[vid] - 2.5 * d, d, rng.uniform(0.2, 1.0, 500))
    dvid = rng.choice(len(V0), 200, replace=False)
    dep = DepthConstraints(dvid, target[dvid], N[dvid], np.full(200, 0.8))
    return V0, ConstraintSet(delta, delta_rest, sil, dep), target


def test_delta_weights_are_normalised_cotangents(body_2k):
    delta, delta_rest = cotangent_delta_coordinates(body_2k.vertices, body_2k.faces)
    rows = np.repeat(np.arange(delta.n_vertices), np.diff(delta.indptr))
    assert np.allclose(np.bincount(rows, weights=delta.weights), 1.0)
    assert np.all(delta.weights > 0)
    # reverse maps (i, j) to (j, i)
    assert np.array_equal(delta.indices[delta.reverse], rows)
    # delta coordinates are translation invariant and small compared with the body
    assert np.allclose(delta.apply(body_2k.vertices + [0.3, -1.0, 2.0]), delta_rest, atol=1e-12)
    assert np.median(np.linalg.norm(delta_rest, axis=1)) < 0.01


def test_projection_weight():
    assert projection_weight(1.0, 8) == 1.0
    assert projection_weight(0.0, 8) == 0.0
    # Ni projections with k' remove the same share as one projection with k
    k = np.array([0.1, 0.5, 0.9])
    assert np.allclose(1 - (1 - projection_weight(k, 8)) ** 8, k)


def test_gauss_seidel_lowers_energy_monotonically(fixed_constraints):
    V0, cs, target = fixed_constraints
    energies = [constraint_energy(V0, cs)]
    V = gauss_seidel(V0, cs, 8, callback=lambda it, V: energies.append(constraint_energy(V, cs)))
    e = np.array(energies)
    assert np.all(np.diff(e) <= 1e-15 * e[0])
    # k' = 1 - (1 - k)^(1/Ni) fixes the data/smoothness balance of the fixed point; 8 sweeps get most of it
    assert e[-1] < 0.75 * e[0]
    # the silhouette constraints pull the vertices onto their rays
    sil = cs.silhouette
    before = point_to_ray_distance(V0[sil.vertex], sil.origin, sil.direction)
    after = point_to_ray_distance(V[sil.vertex], sil.origin, sil.direction)
    assert np.mean(after) < 0.9 * np.mean(before)
    # and the mesh approaches the bulged body it was built from
    assert np.mean(np.linalg.norm(V - target, axis=1)) < np.mean(np.linalg.norm(V0 - target, axis=1))


def test_baselines_agree_on_the_energy(fixed_constraints):
    V0, cs, _ = fixed_constraints
    e0 = constraint_energy(V0, cs)
    V_chol = cholesky(V0, cs)
    e_min = constraint_energy(V_chol, cs)
    # the direct solve is the minimiser: no iterative result goes below it, small perturbations go up
    e_gs = constraint_energy(gauss_seidel(V0, cs, 8), cs)
    e_cg = constraint_energy(conjugate_gradient(V0, cs, 200), cs)
    e_jac = constraint_energy(jacobi(V0, cs, 32), cs)
    assert e_min <= min(e_gs, e_cg, e_jac) + 1e-12
    assert e_min < e0
    rng = np.random.default_rng(0)
    assert constraint_energy(V_chol + 1e-4 * rng.normal(size=V_chol.shape), cs) > e_min
    assert e_cg < e_min * 1.01 + 1e-9
    assert e_jac < e0 and e_gs < e0


def test_jacobi_decreases_energy(fixed_constraints):
    V0, cs, _ = fixed_constraints
    energies = [constraint_energy(V0, cs)]
    jacobi(V0, cs, 20, callback=lambda it, V: energies.append(constraint_energy(V, cs)))
    assert energies[-1] < 0.8 * energies[0]
    assert np.all(np.diff(energies) <= 1e-15 * energies[0])


def _reference_gauss_seidel(V, cs, ni):
    """Eq. 3-4 projections one constraint at a time in plain numpy: silhouettes, depth, then the smoothness
    constraint of every vertex in order (the compiled sweep must follow the same order)."""
    V = V.copy()
    delta, sil, dep = cs.delta, cs.silhouette, cs.depth
    k_sil = 1 - (1 - sil.k) ** (1 / ni)
    k_dep = 1 - (1 - dep.k) ** (1 / ni)
    k_sm = 1 - (1 - cs.k_sm) ** (1 / ni)
    for _ in range(ni):
        for c, i in enumerate(sil.vertex):
            p = V[i] - sil.origin[c]
            V[i] -= k_sil[c] * (p - (p @ sil.direction[c]) * sil.direction[c])
        for c, i in enumerate(dep.vertex):
            V[i] -= k_dep[c] * ((V[i] - dep.point[c]) @ dep.normal[c]) * dep.normal[c]
        for i in range(delta.n_vertices):
            ring = slice(delta.indptr[i], delta.indptr[i + 1])
            J, W = delta.indices[ring], delta.weights[ring]
            r = k_sm / (1 + W @ W) * (V[i] - W @ V[J] - cs.delta_rest[i])
            V[i] -= r
            V[J] += W[:, None] * r
    return V


def _reference_jacobi(V, cs, ni, relaxation):
    """Every constraint's Eq. 4 step from the same positions, averaged per vertex, in plain numpy."""
    V = V.copy()
    delta, sil, dep = cs.delta, cs.silhouette, cs.depth
    n = delta.n_vertices
    W = sp.csr_matrix((delta.weights, delta.indices, delta.indptr), shape=(n, n))
    step = (1 - (1 - cs.k_sm) ** (1 / ni)) / (1 + np.asarray(W.multiply(W).sum(axis=1)).ravel())
    k_sil = 1 - (1 - sil.k) ** (1 / ni)
    k_dep = 1 - (1 - dep.k) ** (1 / ni)
    count = 1 + np.diff(delta.indptr) + np.bincount(sil.vertex, minlength=n) + np.bincount(dep.vertex, minlength=n)
    for _ in range(ni):
        r = step[:, None] * (delta.apply(V) - cs.delta_rest)
        move = W.T @ r - r
        p = V[sil.vertex] - sil.origin
        np.add.at(move, sil.vertex, -k_sil[:, None] * (p - np.sum(p * sil.direction, axis=1)[:, None] * sil.direction))
        res = np.sum((V[dep.vertex] - dep.point) * dep.normal, axis=1)
        np.add.at(move, dep.vertex, -(k_dep * res)[:, None] * dep.normal)
        V += relaxation * move / count[:, None]
    return V


def test_compiled_sweeps_match_plain_projections(fixed_constraints):
    """The body template mixes valence 3-10 vertices: both code paths of the compiled smoothness sweep
    (valence 6 and any other) and the vertex-grouped Jacobi gather reproduce the plain formulas."""
    V0, cs, _ = fixed_constraints
    assert {5, 6, 7} <= set(np.diff(cs.delta.indptr))
    ref = _reference_gauss_seidel(V0, cs, 8)
    assert np.max(np.abs(ref - V0)) > 1e-3  # the solve moves the mesh, so agreement is not trivial
    assert np.max(np.abs(gauss_seidel(V0, cs, 8) - ref)) < 1e-12
    assert np.max(np.abs(jacobi(V0, cs, 8, relaxation=1.5) - _reference_jacobi(V0, cs, 8, 1.5))) < 1e-12


def test_projection_weight_any_inner_iterations():
    k = np.array([[0.0, 0.3], [0.99, 1.0]])
    for ni in (1, 3, 8, 12, 32):
        assert np.allclose(projection_weight(k, ni), 1 - (1 - k) ** (1 / ni), rtol=0, atol=1e-15)
    assert projection_weight(np.array([-0.5, 1.5]), 8).tolist() == [0.0, 1.0]  # k is clipped to [0, 1]


def test_solver_layout_cache_follows_the_delta_operator():
    """The per-operator solver layout is reused across solves and freed with its operator (one per frame)."""
    import gc

    from bodystudio.reconstruct import solver

    V = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float)
    F = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])
    delta, rest = cotangent_delta_coordinates(V, F)
    cs = ConstraintSet(delta, rest, SilhouetteConstraints.empty(), DepthConstraints.empty())
    n_before = len(solver._SMOOTHNESS_ARRAYS)
    gauss_seidel(V, cs)
    jacobi(V, cs)
    assert len(solver._SMOOTHNESS_ARRAYS) == n_before + 1
    del cs, delta
    gc.collect()
    assert len(solver._SMOOTHNESS_ARRAYS) == n_before


def test_out_of_range_constraint_vertex_is_an_input_error(fixed_constraints):
    """The compiled sweeps do not check bounds, so a bad vertex id must be caught before them."""
    from bodystudio.errors import InputError

    V0, cs, _ = fixed_constraints
    sil = cs.silhouette
    bad = SilhouetteConstraints(np.r_[sil.vertex[:-1], len(V0)], sil.origin, sil.direction, sil.k)
    cs_bad = ConstraintSet(cs.delta, cs.delta_rest, bad, cs.depth)
    for solve in (gauss_seidel, jacobi):
        with pytest.raises(InputError, match="vertex ids"):
            solve(V0, cs_bad)
