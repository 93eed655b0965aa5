"""mir12y's and mir12ab's Eq. 2 fit against references written from the docstrings (mutLL).

* ``closest_vertex_matches`` (the KD query reused between re-matchings) and its kernel ``_closest_of_kept``: against
  a brute-force nearest vertex (the full distance matrix), over moves that keep, and moves that break, each point's
  kept vertices, with a vertex from outside a point's kept four coming nearest (a stale match must not be reused).
* ``fit_shape`` (normal equations formed once, ``bincount`` sums, the weighted pool's ``point_weight``, the free
  columns of ``leg_splay_basis`` with their Kinect joints and prior, ``coeff_rows``): against ``numpy.linalg.lstsq``
  on the full dense design, and over several re-matchings against the same solve in a loop that matches by brute
  force.
* ``leg_splay_basis``: against the derivative of a real rotation of the lower leg about the knee (scipy); and
  ``knee_hinge_splay_rows``' rows against the model's Kinect joints, with a median over frames that differ.

The 2k statistical model (loaded once per process); every case well under a second.
"""

from __future__ import annotations

import functools

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bodystudio.mirror import init as init_mod
from bodystudio.mirror.init import (
    LEG_SPLAY_CHAINS,
    _model_kinect_joints,
    closest_vertex_matches,
    fit_shape,
    knee_hinge_splay_rows,
    leg_splay_basis,
)
from tests.mirror.test_init_analytic import _model_2k, _planted_coeffs


def _brute(P, V):
    """Each point's nearest vertex by the full distance matrix: (distance, index), first index on a tie."""
    D = np.sqrt(((P[:, None, :] - V[None, :, :]) ** 2).sum(-1))
    m = np.argmin(D, axis=1)
    return D[np.arange(len(P)), m], m


def _kept(P, V, k):
    """Each point's ``k`` nearest vertices (nearest first) and the k-th distance, by brute force."""
    D = np.sqrt(((P[:, None, :] - V[None, :, :]) ** 2).sum(-1))
    order = np.argsort(D, axis=1, kind="stable")[:, :k]
    return order, D[np.arange(len(P)), order[:, -1]]


# --- the closest-vertex query reused ------------------------------------------------------------------------------

def test_kept_vertices_kernel_is_the_nearest_of_each_points_own_list():
    rng = np.random.default_rng(1)
    P, V = rng.random((50, 3)), rng.random((30, 3))
    near = np.stack([rng.permutation(30)[:5] for _ in range(50)])
    d, m = init_mod._closest_of_kept(P, V, near)
    D = np.sqrt(((P[:, None, :] - V[near]) ** 2).sum(-1))  # (50, 5): each point against its own five
    j = np.argmin(D, axis=1)
    np.testing.assert_array_equal(m, near[np.arange(50), j])
    np.testing.assert_allclose(d, D[np.arange(50), j], rtol=0, atol=1e-15)
    assert m.dtype == near.dtype
    # the nearest in the last column, and a single column
    near[:, -1] = _brute(P, V)[1]
    assert np.array_equal(init_mod._closest_of_kept(P, V, near)[1], near[:, -1])
    d1, m1 = init_mod._closest_of_kept(P, V, near[:, 2:3])
    np.testing.assert_array_equal(m1, near[:, 2])
    np.testing.assert_allclose(d1, np.linalg.norm(P - V[near[:, 2]], axis=1), rtol=0, atol=1e-15)


def test_first_query_fills_the_cache_with_each_points_four_nearest():
    rng = np.random.default_rng(2)
    P, V = rng.random((300, 3)), rng.random((200, 3))
    cache: dict = {}
    d, m = closest_vertex_matches(P, V, cache)
    bd, bm = _brute(P, V)
    np.testing.assert_array_equal(m, bm)
    np.testing.assert_allclose(d, bd, rtol=0, atol=1e-12)
    order, reach = _kept(P, V, 4)
    np.testing.assert_array_equal(cache["near"], order)
    np.testing.assert_allclose(cache["reach"], reach, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(cache["vertices"], V)
    # the cache holds a copy: the caller's array changed in place afterwards is a move the next call must see
    V[:] += 0.5
    assert not np.array_equal(cache["vertices"], V)
    # other neighbour counts
    cache3: dict = {}
    closest_vertex_matches(P, V, cache3, neighbours=3)
    np.testing.assert_array_equal(cache3["near"], _kept(P, V, 3)[0])
    cache2: dict = {}
    closest_vertex_matches(P, V, cache2, neighbours=2)
    assert cache2["near"].shape == (300, 2)
    # fewer than two neighbours, or fewer vertices than neighbours: the plain query, nothing cached
    for neighbours, n_vertices in ((1, 200), (0, 200), (4, 3)):
        cache1: dict = {}
        d, m = closest_vertex_matches(P, V[:n_vertices], cache1, neighbours=neighbours)
        np.testing.assert_array_equal(m, _brute(P, V[:n_vertices])[1])
        assert cache1 == {}
    cache4: dict = {}
    d, m = closest_vertex_matches(P, V[:4], cache4, neighbours=4)  # exactly as many vertices as neighbours: cached
    np.testing.assert_array_equal(m, _brute(P, V[:4])[1])
    assert cache4["near"].shape == (300, 4)


def _stale_case():
    """One point at the origin, its kept four vertices at 1.0, 1.1, 1.2 and 1.3 (the reach), two more at 1.5 and 3;
    then the vertex at 1.5 moves to 0.5 from the point (moved 1.0): the kept four miss it."""
    P = np.zeros((1, 3))
    V = np.array([[1.0, 0, 0], [0, 1.1, 0], [0, 0, 1.2], [-1.3, 0, 0], [0, -1.5, 0], [0, 0, -3.0]])
    V2 = V.copy()
    V2[4] = [0, -0.5, 0]
    return P, V, V2


def test_a_vertex_from_outside_the_kept_four_that_came_nearest_is_found():
    P, V, V2 = _stale_case()
    cache: dict = {}
    d, m = closest_vertex_matches(P, V, cache)
    assert m[0] == 0 and d[0] == 1.0 and cache["reach"][0] == pytest.approx(1.3, abs=1e-15)
    assert list(cache["near"][0]) == [0, 1, 2, 3]
    d, m = closest_vertex_matches(P, V2, cache)
    assert m[0] == 4 and d[0] == pytest.approx(0.5, abs=1e-15)
    # a small move of a far vertex: the kept nearest is still nearer than anything outside could be (1.0 <= 1.3 -
    # 0.25): reused, the cache unchanged
    cache = {}
    closest_vertex_matches(P, V, cache)
    near = cache["near"]
    V3 = V.copy()
    V3[5] = [0, 0, -2.75]
    d, m = closest_vertex_matches(P, V3, cache)
    assert (d[0], m[0]) == (1.0, 0) and cache["near"] is near and np.array_equal(cache["vertices"], V)
    # the kept vertices' own move counts: the nearest kept one moved 0.2 further, the second now nearest
    V4 = V.copy()
    V4[0] = [1.2, 0, 0]
    d, m = closest_vertex_matches(P, V4, cache)
    assert m[0] == 1 and d[0] == pytest.approx(1.1, abs=1e-15)


def _quiet_group():
    """A point whose nearest vertex is 0.01 away and the rest 2 m or more (reach 2.2): never stale under a 1 m move."""
    return np.array([[0.01, 0, 0], [0, 2.0, 0], [0, 0, 2.1], [-2.2, 0, 0], [0, -2.5, 0], [0, 0, -3.0]])


def test_many_points_a_quarter_requeried_keeps_the_cache_more_redoes_it():
    """Eight groups side by side (100 m apart): ``n_stale`` of the stale case's and the rest quiet ones. With two
    stale points (a quarter) the cached lists are kept and those two queried again; with three the whole query is
    redone; the answer is the brute-force one either way."""
    P1, V1, V2 = _stale_case()
    for n_stale, reused in ((2, True), (3, False), (0, True)):
        groups = [V1] * n_stale + [_quiet_group()] * (8 - n_stale)
        shifts = 100.0 * np.arange(8)[:, None] * np.array([[1.0, 0, 0]])
        P = (P1 + shifts).reshape(-1, 3)
        V = np.concatenate([g + s for g, s in zip(groups, shifts, strict=True)])
        cache: dict = {}
        closest_vertex_matches(P, V, cache)
        near = cache["near"]
        moved = V.copy()
        for p in range(n_stale):
            moved[6 * p + 4] = V2[4] + shifts[p]
        d, m = closest_vertex_matches(P, moved, cache)
        bd, bm = _brute(P, moved)
        np.testing.assert_array_equal(m, bm)
        np.testing.assert_allclose(d, bd, rtol=0, atol=1e-12)
        assert list(m[:n_stale]) == [6 * p + 4 for p in range(n_stale)]
        assert (cache["near"] is near) is reused
        if not reused:
            np.testing.assert_array_equal(cache["vertices"], moved)
            np.testing.assert_array_equal(cache["near"], _kept(P, moved, 4)[0])
    # another number of vertices (the candidates changed): the cache is not used
    cache = {}
    closest_vertex_matches(P, V, cache)
    d, m = closest_vertex_matches(P, V[:-1], cache)
    np.testing.assert_array_equal(m, _brute(P, V[:-1])[1])
    assert len(cache["vertices"]) == len(V) - 1


def test_a_chain_of_random_moves_matches_brute_force_every_time():
    rng = np.random.default_rng(7)
    P, V = rng.random((400, 3)), rng.random((250, 3))
    cache: dict = {}
    for step in range(6):
        d, m = closest_vertex_matches(P, V, cache)
        bd, bm = _brute(P, V)
        np.testing.assert_array_equal(m, bm)
        np.testing.assert_allclose(d, bd, rtol=0, atol=1e-12)
        V = V + rng.normal(0.0, 0.004 * (1 + step), V.shape)


# --- Eq. 2 against a dense least-squares solve ----------------------------------------------------------------------

@functools.cache
def _leg_columns():
    model = _model_2k()
    c = np.zeros(model.n_components)
    return leg_splay_basis(model.vertices(c), model.weights, model.skeleton(c))


def _dense(model, P, m, *, c_prior_sigma, point_weight=1.0, free=None, free_joints=None, free_sigma=0.1,
           joints=None, joint_weight=0.0, coeff_rows=None):
    """Eq. 2 as one stacked least-squares problem over (coeffs, translation, free amounts)."""
    k = model.n_components
    nf = 0 if free is None else len(free)
    sw = np.sqrt(point_weight)
    A_pts = np.concatenate([model.basis[:, m].reshape(k, -1).T, np.tile(np.eye(3), (len(m), 1))]
                           + ([free[:, m].reshape(nf, -1).T] if nf else []), axis=1)
    rows, rhs = [sw * A_pts], [sw * (P - model.mean[m]).ravel()]
    prior = np.zeros((k + nf, k + 3 + nf))
    prior[np.arange(k), np.arange(k)] = c_prior_sigma / model.stddev
    if nf:
        prior[k + np.arange(nf), k + 3 + np.arange(nf)] = c_prior_sigma / free_sigma
    rows.append(prior)
    rhs.append(np.zeros(k + nf))
    if joints is not None and joint_weight > 0:
        Jm, Jb = _model_kinect_joints(model, "v2")
        Jd = joints.reshape(-1, len(Jm), 3)
        f, j = np.nonzero(np.isfinite(Jd).all(2))
        cols = [Jb[:, j].reshape(k, -1).T, np.tile(np.eye(3), (len(j), 1))]
        if nf:
            cols.append(free_joints[:, j].reshape(nf, -1).T if free_joints is not None else np.zeros((3 * len(j), nf)))
        rows.append(np.sqrt(joint_weight) * np.concatenate(cols, axis=1))
        rhs.append(np.sqrt(joint_weight) * (Jd[f, j] - Jm[j]).ravel())
    if coeff_rows is not None:
        rows.append(np.hstack([coeff_rows[0], np.zeros((len(coeff_rows[0]), 3 + nf))]))
        rhs.append(coeff_rows[1])
    x = np.linalg.lstsq(np.concatenate(rows), np.concatenate(rhs), rcond=None)[0]
    return x[:k], x[k:k + 3], x[k + 3:]


def _data(seed, n_points=500, delta=None):
    model = _model_2k()
    rng = np.random.default_rng(seed)
    c_true = _planted_coeffs(model, seed=seed)
    V = model.vertices(c_true)
    if delta is not None:
        V = V + np.tensordot(delta, _leg_columns()[0], axes=1)
    m = np.concatenate([rng.integers(0, len(V), n_points), [0, 0, 0, 5, 5]])  # vertices matched several times
    P = V[m] + np.array([0.02, -0.01, 0.03]) + rng.normal(0, 0.005, (len(m), 3))
    return model, rng, c_true, P, m


def _joints(model, c, rng, n_frames=2, delta=None):
    Jm, Jb = _model_kinect_joints(model, "v2")
    J = Jm + np.einsum("k,kjd->jd", c, Jb)
    if delta is not None:
        J = J + np.tensordot(delta, _leg_columns()[1], axes=1)
    Jd = np.stack([J + np.array([0.02, -0.01, 0.03]) + rng.normal(0, 0.01, J.shape) for _ in range(n_frames)])
    Jd[0, 4] = np.nan
    Jd[1, :3] = np.nan
    return Jd


@pytest.mark.parametrize("point_weight", [1.0, 0.37])
def test_eq2_with_joints_and_a_weighted_pool_is_the_dense_solve(point_weight):
    model, rng, c_true, P, m = _data(11)
    Jd = _joints(model, c_true, rng)
    sigma = 0.02
    c = fit_shape(P, model, correspondence=m, iterations=1, point_sigma_m=sigma, joints_default=Jd, joint_weight=9.0,
                  point_weight=point_weight)
    c_ref, _, _ = _dense(model, P, m, c_prior_sigma=sigma, point_weight=point_weight, joints=Jd, joint_weight=9.0)
    np.testing.assert_allclose(c, c_ref, rtol=0, atol=1e-8 * model.stddev.max())


def test_eq2_with_free_columns_their_joints_and_coeff_rows_is_the_dense_solve():
    delta = np.radians([3.0, 2.0, -3.0, 2.0])
    model, rng, c_true, P, m = _data(12, delta=delta)
    free, free_joints = _leg_columns()
    Jd = _joints(model, c_true, rng, delta=delta)
    A = rng.normal(0, 1.0, (2, model.n_components))
    coeff_rows = (3.0 * A, 3.0 * (A @ c_true + 0.1))
    sigma, free_sigma = 0.02, 0.05
    c = fit_shape(P, model, correspondence=m, iterations=1, point_sigma_m=sigma, joints_default=Jd, joint_weight=4.0,
                  free_basis=free, free_joint_basis=free_joints, free_sigma=free_sigma, coeff_rows=coeff_rows,
                  point_weight=0.6)
    c_ref, t_ref, d_ref = _dense(model, P, m, c_prior_sigma=sigma, point_weight=0.6, free=free,
                                 free_joints=free_joints, free_sigma=free_sigma, joints=Jd, joint_weight=4.0,
                                 coeff_rows=coeff_rows)
    np.testing.assert_allclose(c, c_ref, rtol=0, atol=1e-8 * model.stddev.max())
    # the free amounts are not returned, but they are in the solve: the residual is measured with them
    c, res = fit_shape(P, model, correspondence=m, iterations=1, point_sigma_m=sigma, joints_default=Jd,
                       joint_weight=4.0, free_basis=free, free_joint_basis=free_joints, free_sigma=free_sigma,
                       coeff_rows=coeff_rows, point_weight=0.6, return_residual=True)
    V = model.vertices(c_ref) + np.tensordot(d_ref, free, axes=1)
    assert res == pytest.approx(np.median(np.linalg.norm(P - t_ref - V[m], axis=1)), rel=1e-8)
    assert c.shape == (model.n_components,)
    # free columns without their joints: the joint rows see no free amount
    c = fit_shape(P, model, correspondence=m, iterations=1, point_sigma_m=sigma, joints_default=Jd, joint_weight=4.0,
                  free_basis=free, free_sigma=free_sigma)
    c_ref, _, _ = _dense(model, P, m, c_prior_sigma=sigma, free=free, free_sigma=free_sigma, joints=Jd,
                         joint_weight=4.0)
    np.testing.assert_allclose(c, c_ref, rtol=0, atol=1e-8 * model.stddev.max())
    # the default free prior is LEG_SPLAY_SIGMA_RAD
    c = fit_shape(P, model, correspondence=m, iterations=1, point_sigma_m=sigma, free_basis=free)
    c_ref, _, _ = _dense(model, P, m, c_prior_sigma=sigma, free=free, free_sigma=init_mod.LEG_SPLAY_SIGMA_RAD)
    np.testing.assert_allclose(c, c_ref, rtol=0, atol=1e-8 * model.stddev.max())


def _icp_reference(model, P, c0, iterations, sigma, trim_m, candidates=None, free=None, free_sigma=0.1,
                   symmetric=False, joints=None, joint_weight=0.0, point_weight=1.0):
    """fit_shape's loop written out: match each point to its nearest candidate vertex by brute force (every match
    from the current fit: nothing reused), trim after the first, solve densely; the residual of the last."""
    k = model.n_components
    cand = np.arange(len(model.mean)) if candidates is None else candidates
    c, t, delta = c0.copy(), np.zeros(3), np.zeros(0 if free is None else len(free))
    for it in range(iterations):
        V = model.vertices(c) + (0 if free is None else np.tensordot(delta, free, axes=1))
        d, j = _brute(P, V[cand] + t)
        keep = d <= (np.inf if it == 0 else trim_m)
        Pk, mk = P[keep], cand[j[keep]]
        if symmetric:
            dd, q = _brute(V[cand] + t, P)
            near = dd <= trim_m
            Pk, mk = np.concatenate([Pk, P[q[near]]]), np.concatenate([mk, cand[near]])
        c, t, delta = _dense(model, Pk, mk, c_prior_sigma=sigma, point_weight=point_weight, free=free,
                             free_joints=None, free_sigma=free_sigma, joints=joints, joint_weight=joint_weight)
        assert c.shape == (k,)
    V = model.vertices(c) + (0 if free is None else np.tensordot(delta, free, axes=1))
    return c, float(np.median(np.linalg.norm(P[keep] - t - V[cand[j[keep]]], axis=1)))


def test_eq2_rematching_over_iterations_is_the_brute_force_loop():
    """Four re-matchings from the mean shape (every point's match moves), some points beyond the trim: the fit's
    reused KD query must give the loop's matches every time (a stale match changes the coefficients)."""
    model, rng, c_true, _, _ = _data(13)
    V = model.vertices(c_true)
    cand = np.arange(0, len(V), 3)
    P = V[rng.integers(0, len(V), 700)] + rng.normal(0, 0.004, (700, 3))
    P[::40] += np.array([0.0, 0.0, 0.12])  # 12 cm off: trimmed from the second match on
    sigma, trim = 0.02, 0.05
    c, res = fit_shape(P, model, iterations=4, point_sigma_m=sigma, trim_m=trim, candidates=cand,
                       return_residual=True)
    c_ref, res_ref = _icp_reference(model, P, np.zeros(model.n_components), 4, sigma, trim, candidates=cand)
    np.testing.assert_allclose(c, c_ref, rtol=0, atol=1e-8 * model.stddev.max())
    assert res == pytest.approx(res_ref, rel=1e-8)
    # one iteration fewer is another answer (the planted "skipped re-matching")
    c3 = fit_shape(P, model, iterations=3, point_sigma_m=sigma, trim_m=trim, candidates=cand)
    assert np.abs(c3 - c_ref).max() > 1e-4 * model.stddev.max()


def test_eq2_rematching_with_free_columns_symmetric_and_weighted_is_the_brute_force_loop():
    delta = np.radians([4.0, 0.0, -4.0, 0.0])
    model, rng, c_true, _, _ = _data(14, delta=delta)
    free, _ = _leg_columns()
    V = model.vertices(c_true) + np.tensordot(delta, free, axes=1)
    cand = np.arange(1, len(V), 2)
    P = V[rng.integers(0, len(V), 600)] + rng.normal(0, 0.004, (600, 3))
    c, res = fit_shape(P, model, iterations=3, point_sigma_m=0.02, trim_m=0.04, candidates=cand, free_basis=free,
                       free_sigma=0.07, symmetric=True, point_weight=0.5, return_residual=True)
    c_ref, res_ref = _icp_reference(model, P, np.zeros(model.n_components), 3, 0.02, 0.04, candidates=cand, free=free,
                                    free_sigma=0.07, symmetric=True, point_weight=0.5)
    np.testing.assert_allclose(c, c_ref, rtol=0, atol=1e-8 * model.stddev.max())
    assert res == pytest.approx(res_ref, rel=1e-8)


# --- the legs' free columns and the knee-hinge rows -----------------------------------------------------------------

def test_leg_splay_columns_are_the_derivative_of_turning_the_lower_leg_about_the_knee():
    model = _model_2k()
    c = _planted_coeffs(model, seed=3, scale=0.5)
    V, sk = model.vertices(c), model.skeleton(c)
    cols, joint_cols = leg_splay_basis(V, model.weights, sk)
    assert cols.shape == (4, len(V), 3) and joint_cols.shape[0] == 4
    names = list(sk.bone_names)
    eps = 1e-6
    base = init_mod.skeleton_kinect_joints(sk, sk.heads, sk.tails, "v2")
    for leg, (calf, below) in enumerate(LEG_SPLAY_CHAINS):
        knee = sk.heads[names.index(calf)]
        w = sum(model.weights[:, names.index(b)] for b in below)
        for a, axis in enumerate(([0.0, 0.0, 1.0], [1.0, 0.0, 0.0])):
            R = Rotation.from_rotvec(eps * np.array(axis)).as_matrix()
            turned = knee + (V - knee) @ R.T
            np.testing.assert_allclose(cols[2 * leg + a], w[:, None] * (turned - V) / eps, rtol=0, atol=1e-6)
            heads, tails = sk.heads.copy(), sk.tails.copy()
            idx = [names.index(b) for b in below]
            heads[idx] = knee + (heads[idx] - knee) @ R.T
            tails[idx] = knee + (tails[idx] - knee) @ R.T
            fd = (init_mod.skeleton_kinect_joints(sk, heads, tails, "v2") - base) / eps
            np.testing.assert_allclose(joint_cols[2 * leg + a], fd, rtol=0, atol=1e-5)
    # the left leg's columns move the left foot's joint, not the right one's
    J = list(init_mod.kinect_joint_names("v2"))
    assert np.abs(joint_cols[0][J.index("FootLeft")]).max() > 0.1
    assert np.abs(joint_cols[0][J.index("FootRight")]).max() == 0
    # v1 joints: the v1 names' count
    assert leg_splay_basis(V, model.weights, sk, "v1")[1].shape[1] == len(init_mod.kinect_joint_names("v1"))


def _hinge_poses(sk, eps_list, flexion=0.7, seed=0):
    from bodystudio.body.pose import Pose

    rng = np.random.default_rng(seed)
    poses = []
    for eps in eps_list:
        rot = np.zeros((sk.n_bones, 3))
        for bone in ("Root", "thigh_l", "thigh_r"):
            rot[sk.index(bone)] = rng.normal(0.0, 0.3, 3)
        calf = (Rotation.from_rotvec([flexion, 0.0, 0.0]) * Rotation.from_rotvec([0.0, 0.0, eps])).as_rotvec()
        rot[sk.index("calf_l")] = calf
        rot[sk.index("calf_r")] = calf
        poses.append(Pose(rot, np.zeros(3)))
    return poses


def test_knee_hinge_rows_are_the_models_calf_along_the_hinge_axis_at_the_median_over_frames():
    model = _model_2k()
    # a fitted body's skeleton, not the mean's: the mean calf's own Kinect segment then has a component along this
    # skeleton's hinge axis, which the rows' right-hand side takes off
    sk = model.skeleton(_planted_coeffs(model, seed=4, scale=1.0))
    Jm, Jb = _model_kinect_joints(model, "v2")
    names = list(init_mod.kinect_joint_names("v2"))
    eps_list = [0.02, 0.09, -0.04, 0.2]  # median 0.055, mean 0.0675
    A, b = knee_hinge_splay_rows(model, sk, _hinge_poses(sk, eps_list), "v2", weight=2.25)
    for row, (calf, knee, ankle) in enumerate((("calf_l", "KneeLeft", "AnkleLeft"),
                                               ("calf_r", "KneeRight", "AnkleRight"))):
        i = sk.index(calf)
        axis = sk.rest_rotations[i][:, 0]
        ka, kk = names.index(ankle), names.index(knee)
        np.testing.assert_allclose(A[row], 1.5 * (Jb[:, ka] - Jb[:, kk]) @ axis, rtol=0, atol=1e-12)
        measured = np.median([-np.sin(e) for e in eps_list]) * sk.lengths[i]
        assert abs((Jm[ka] - Jm[kk]) @ axis) > 1e-4
        np.testing.assert_allclose(b[row], 1.5 * (measured - (Jm[ka] - Jm[kk]) @ axis), rtol=0, atol=1e-9)
    # the default joint set is v2
    A2, b2 = knee_hinge_splay_rows(model, sk, _hinge_poses(sk, eps_list), weight=2.25)
    np.testing.assert_array_equal(A2, A)
    np.testing.assert_array_equal(b2, b)
    # one leg only
    A1, b1 = knee_hinge_splay_rows(model, sk, _hinge_poses(sk, eps_list), "v2", weight=2.25,
                                   legs=(("calf_r", "KneeRight", "AnkleRight"),))
    np.testing.assert_allclose(A1, A[1:], rtol=0, atol=1e-12)
    np.testing.assert_allclose(b1, b[1:], rtol=0, atol=1e-12)
