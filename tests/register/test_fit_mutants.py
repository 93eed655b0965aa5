"""The scan fit's steps (:mod:`bodystudio.register.fit`, eq. 5 of Avatar Reshaping) against independent references.

Mutation tests (issue 17, docs/mutation/register-fit.md), on a 4-bone chain and a 40-vertex stand-in shape space
(no body model, no scan: the file runs in a few seconds):

* the casadi kinematics and their Jacobian against numpy's forward kinematics
  (:func:`bodystudio.body.skinning.skinning_transforms`) and central finite differences of it;
* the pose step (Levenberg-Marquardt) against scipy's ``least_squares`` on the same objective written out here
  from the skinned points (the pairs' point-to-plane residuals with the tangential part weighted, plus the
  range-of-motion prior), and exact recovery of a known pose;
* the shape step against the ridge solution written from finite differences of the skinned model;
* the pairs and the distances against cases worked out by hand.
"""

from __future__ import annotations

from functools import cache
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.optimize import least_squares
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from bodystudio.body import Pose, Skeleton
from bodystudio.body.skinning import forward_kinematics, linear_blend_skinning, skinning_transforms
from bodystudio.register import fit as F

# bone names from POSE_PRIOR_SIGMA (sigma 0.3, 0.2, 0.15) and one without a prior
NAMES = ("pelvis", "spine_01", "clavicle_l", "tool")
PARENTS = np.array([-1, 0, 1, 1])


def _skeleton(shift=np.zeros(3)) -> Skeleton:
    heads = np.array([[0.0, 0.0, 0.0], [0.0, 0.3, 0.05], [0.05, 0.6, 0.0], [-0.1, 0.55, 0.1]]) + shift
    tails = np.array([[0.0, 0.3, 0.05], [0.05, 0.6, 0.0], [0.35, 0.65, 0.05], [-0.1, 0.6, 0.45]]) + shift
    return Skeleton(NAMES, PARENTS, heads, tails, np.array([0.1, -0.3, 0.0, 0.5]))


@cache
def _points():
    """60 rest points along the chain and their skin weights (each point 1-2 bones)."""
    rng = np.random.default_rng(5)
    sk = _skeleton()
    V, W = [], []
    for j in range(4):
        for _ in range(15):
            t = rng.uniform(0, 1)
            V.append(sk.heads[j] + t * (sk.tails[j] - sk.heads[j]) + rng.normal(0, 0.05, 3))
            w = np.zeros(4)
            w[j] = 1.0
            if PARENTS[j] >= 0 and rng.uniform() < 0.5:
                w[j], w[PARENTS[j]] = 0.7, 0.3
            W.append(w)
    return np.array(V), np.array(W)


def _posed(sk, pose, V, W):
    return linear_blend_skinning(V, W, skinning_transforms(sk, pose))


TRUE_POSE = Pose([[0.2, -0.1, 0.15], [0.3, 0.2, -0.1], [-0.25, 0.1, 0.4], [0.05, 0.5, -0.2]], [0.1, -0.05, 0.2])


# ---- the casadi kinematics ---------------------------------------------------------------------------------------

def test_bone_transforms_and_jacobian_match_numpy_kinematics_and_finite_differences():
    sk = _skeleton()
    free = (0, 2, 3)  # bone 1 held at its fixed rotation
    F.bone_transform_function.cache_clear()  # built here, from the Rodrigues formula, not an earlier test's copy
    f = F.bone_transform_function(tuple(PARENTS.tolist()), free)
    C, A_inv = F._frames_blocks(sk)
    rot = TRUE_POSE.rotations
    x = np.r_[rot[list(free)].ravel(), TRUE_POSE.translation]
    S, dS = f(x, rot.T.copy(), C, A_inv)
    S = np.asarray(S).reshape(4, 3, 4)
    np.testing.assert_allclose(S, skinning_transforms(sk, TRUE_POSE)[:, :3, :], atol=1e-12)

    def s_of(xv):
        r = rot.copy()
        r[list(free)] = xv[:-3].reshape(-1, 3)
        return skinning_transforms(sk, Pose(r, xv[-3:]))[:, :3, :].ravel()

    h = 1e-6
    fd = np.stack([(s_of(x + h * e) - s_of(x - h * e)) / (2 * h) for e in np.eye(len(x))], axis=1)
    np.testing.assert_allclose(np.asarray(dS), fd, atol=1e-7)
    # the rest pose (the Rodrigues formula at a zero angle): the identity transforms
    S0, _ = f(np.zeros_like(x), np.zeros((3, 4)), C, A_inv)
    np.testing.assert_allclose(np.asarray(S0).reshape(4, 3, 4), np.tile(np.eye(4)[:3], (4, 1, 1)), atol=1e-12)


def test_frames_blocks_are_parent_relative_frames_and_inverse_rest_frames():
    # upright bones with roll 0: rest frames are pure translations to the heads (worked out by hand)
    heads = np.array([[1.0, 0.0, 0.0], [1.0, 2.0, 0.0], [0.0, 2.0, 3.0]])
    sk = Skeleton(("a", "b", "c"), np.array([-1, 0, 0]), heads, heads + [0.0, 1.0, 0.0], np.zeros(3))
    C, A_inv = F._frames_blocks(sk)
    assert C.shape == (4, 12) and A_inv.shape == (4, 12)
    expect_C = [[1.0, 0.0, 0.0], [0.0, 2.0, 0.0], [-1.0, 2.0, 3.0]]  # root: its head; children: head - parent's
    for j in range(3):
        np.testing.assert_allclose(C[:3, 4 * j: 4 * j + 3], np.eye(3), atol=1e-12)
        np.testing.assert_allclose(C[:3, 4 * j + 3], expect_C[j], atol=1e-12)
        np.testing.assert_allclose(A_inv[:3, 4 * j + 3], -heads[j], atol=1e-12)
        np.testing.assert_allclose(C[3, 4 * j: 4 * j + 4], [0, 0, 0, 1])


# ---- the pose step -------------------------------------------------------------------------------------------

def _reference_pose_fit(sk, pose, V, W, Z, free, normals=None, tangent_weight=0.1, residual_std_m=0.002,
                        prior_scale=1.0):
    """scipy's least_squares on eq. 5's pose objective, written from the skinned points."""
    sigma = np.array([F.POSE_PRIOR_SIGMA.get(sk.bone_names[j], np.inf) for j in free])
    sq = np.sqrt(prior_scale) * residual_std_m / np.repeat(sigma, 3)

    def unpack(x):
        r = pose.rotations.copy()
        r[list(free)] = x[:-3].reshape(-1, 3)
        return Pose(r, x[-3:])

    def residuals(x):
        d = _posed(sk, unpack(x), V, W) - Z
        if normals is not None:
            dn = np.sum(d * normals, 1, keepdims=True) * normals
            d = dn + np.sqrt(tangent_weight) * (d - dn)
        return np.r_[d.ravel(), sq * x[:-3]]

    x0 = np.r_[pose.rotations[list(free)].ravel(), pose.translation]
    return unpack(least_squares(residuals, x0, xtol=1e-15, ftol=1e-15, gtol=1e-15, max_nfev=2000).x)


def test_pose_step_recovers_a_known_pose_from_exact_pairs():
    sk = _skeleton()
    V, W = _points()
    Z = _posed(sk, TRUE_POSE, V, W)
    # no prior: the exact pose; bone 1 not free keeps the start's rotation, which is the true one here
    start = Pose(np.r_[TRUE_POSE.rotations[:1] * 0, TRUE_POSE.rotations[1:2], np.zeros((2, 3))], np.zeros(3))
    got = F.fit_pose_step(sk, start, V, W, Z, (0, 2, 3), lm_iterations=40, prior_scale=0.0)
    np.testing.assert_allclose(got.rotations, TRUE_POSE.rotations, atol=1e-7)
    np.testing.assert_allclose(got.translation, TRUE_POSE.translation, atol=1e-8)
    # the start pose is not modified
    np.testing.assert_array_equal(start.rotations[0], np.zeros(3))


def test_pose_step_with_the_prior_and_normals_is_the_minimum_of_eq5():
    sk = _skeleton()
    V, W = _points()
    rng = np.random.default_rng(8)
    Z = _posed(sk, TRUE_POSE, V, W) + rng.normal(0, 0.01, V.shape)
    normals = rng.normal(size=V.shape)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    free = (0, 1, 2, 3)
    start = Pose(np.zeros((4, 3)), np.zeros(3))
    kw = dict(residual_std_m=0.01, prior_scale=3.0, normals=normals, tangent_weight=0.25)
    got = F.fit_pose_step(sk, start, V, W, Z, free, lm_iterations=60, **kw)
    ref = _reference_pose_fit(sk, start, V, W, Z, free, **kw)
    np.testing.assert_allclose(got.rotations, ref.rotations, atol=2e-6)
    np.testing.assert_allclose(got.translation, ref.translation, atol=2e-7)
    # the prior pulls toward rest: the unregularised fit lies further from it
    loose = F.fit_pose_step(sk, start, V, W, Z, free, lm_iterations=60, **{**kw, "prior_scale": 0.0})
    assert np.linalg.norm(loose.rotations[:3]) > np.linalg.norm(got.rotations[:3]) + 0.01


def test_pose_step_defaults_are_the_documented_constants():
    assert (F.TANGENT_WEIGHT, F.LM_ITERATIONS, F.RESIDUAL_STD_M) == (0.1, 4, 0.002)
    sk = _skeleton()
    V, W = _points()
    rng = np.random.default_rng(2)
    Z = _posed(sk, TRUE_POSE, V, W) + rng.normal(0, 0.01, V.shape)
    normals = np.tile([0.0, 0.0, 1.0], (len(V), 1))
    start = Pose(np.zeros((4, 3)), np.zeros(3))
    default = F.fit_pose_step(sk, start, V, W, Z, (0, 1, 2, 3), normals=normals, prior_scale=50.0)
    spelled = F.fit_pose_step(sk, start, V, W, Z, (0, 1, 2, 3), lm_iterations=4, residual_std_m=0.002,
                              prior_scale=50.0, normals=normals, tangent_weight=0.1)
    np.testing.assert_array_equal(default.rotations, spelled.rotations)
    np.testing.assert_array_equal(default.translation, spelled.translation)
    three = F.fit_pose_step(sk, start, V, W, Z, (0, 1, 2, 3), lm_iterations=3, normals=normals, prior_scale=50.0)
    assert not np.array_equal(three.rotations, default.rotations)
    # no LM iteration: the start pose itself
    zero = F.fit_pose_step(sk, start, V, W, Z, (0, 1, 2, 3), lm_iterations=0)
    np.testing.assert_array_equal(zero.rotations, start.rotations)
    np.testing.assert_array_equal(zero.translation, start.translation)


def test_tangential_offsets_are_invisible_at_tangent_weight_zero():
    # the pairs slid along the scan's tangent planes: point-to-plane (weight 0) recovers the exact pose,
    # point-to-point (weight 1) does not
    sk = _skeleton()
    V, W = _points()
    rng = np.random.default_rng(4)
    normals = rng.normal(size=V.shape)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    slide = rng.normal(0, 0.02, V.shape)
    slide -= np.sum(slide * normals, 1, keepdims=True) * normals
    Z = _posed(sk, TRUE_POSE, V, W) + slide
    start = Pose(TRUE_POSE.rotations * 0.5, np.zeros(3))
    got = F.fit_pose_step(sk, start, V, W, Z, (0, 1, 2, 3), lm_iterations=40, prior_scale=0.0, normals=normals,
                          tangent_weight=0.0)
    np.testing.assert_allclose(got.rotations, TRUE_POSE.rotations, atol=1e-6)
    p2p = F.fit_pose_step(sk, start, V, W, Z, (0, 1, 2, 3), lm_iterations=40, prior_scale=0.0, normals=normals,
                          tangent_weight=1.0)
    assert np.abs(p2p.rotations - TRUE_POSE.rotations).max() > 1e-3


def test_an_unseen_bone_is_pulled_to_rest_by_its_prior_and_one_without_a_prior_stays():
    # no point is weighted to clavicle_l (sigma 0.15) or tool (no prior): the data cannot move them
    sk = _skeleton()
    V, W = _points()
    keep = (W[:, 2] == 0) & (W[:, 3] == 0)
    V, W = V[keep], W[keep]
    Z = _posed(sk, TRUE_POSE, V, W)
    start = Pose(np.r_[np.zeros((2, 3)), [[0.3, 0.0, 0.0], [0.0, 0.4, 0.0]]], np.zeros(3))
    got = F.fit_pose_step(sk, start, V, W, Z, (0, 1, 2, 3), lm_iterations=25)
    assert np.abs(got.rotations[2]).max() < 1e-3
    np.testing.assert_allclose(got.rotations[3], [0.0, 0.4, 0.0], atol=1e-12)
    np.testing.assert_allclose(got.rotations[:2], TRUE_POSE.rotations[:2], atol=3e-3)


# ---- the shape step ------------------------------------------------------------------------------------------

K_COMPONENTS = 3


@cache
def _shape_model():
    """A stand-in shape space: 60 vertices and the 4 joints move linearly in 3 coefficients; each bone's head and
    tail move together, so the bone directions (and rest frames) do not depend on the shape."""
    rng = np.random.default_rng(11)
    V, W = _points()
    sk = _skeleton()
    basis = rng.normal(0, 0.03, (K_COMPONENTS, len(V), 3))
    joint_basis = rng.normal(0, 0.03, (K_COMPONENTS, 4, 3))
    stddev = np.array([1.0, 0.5, 0.25])

    def skeleton(c):
        d = np.tensordot(c, joint_basis, axes=1)
        return Skeleton(NAMES, PARENTS, sk.heads + d, sk.tails + d, sk.rolls)

    return SimpleNamespace(basis=basis, joint_basis_heads=joint_basis, weights=W, stddev=stddev,
                           skeleton=skeleton, vertices=lambda c: V + np.tensordot(c, basis, axes=1))


def _skinned(model, c, pose):
    return linear_blend_skinning(model.vertices(c), model.weights, skinning_transforms(model.skeleton(c), pose))


def test_posed_vertices_are_affine_in_shape_with_the_derivative_given():
    model = _shape_model()
    c0 = np.array([0.3, -0.2, 0.5])
    P0, D = F.posed_affine_in_shape(model, c0, TRUE_POSE)
    np.testing.assert_allclose(P0, _skinned(model, c0, TRUE_POSE), atol=1e-12)
    for dc in (np.array([1.0, 0, 0]), np.array([0, -2.0, 0]), np.array([0.4, 0.7, -1.5])):
        np.testing.assert_allclose(_skinned(model, c0 + dc, TRUE_POSE), P0 + D @ dc, atol=1e-12)


def _ridge_reference(model, c0, pose, idx, bary, Z, residual_std_m):
    """Ridge least squares in β from the skinned model's finite differences (affine: exact)."""
    def pts(c):
        return np.einsum("nk,nki->ni", bary, _skinned(model, c, pose)[idx]).ravel()

    base = pts(c0)
    A = np.stack([pts(c0 + e) - base for e in np.eye(K_COMPONENTS)], axis=1)
    lam = residual_std_m / model.stddev
    # minimise |A d - (Z - P)|^2 + sum (lam (c0 + d))^2
    M = np.r_[A, np.diag(lam)]
    rhs = np.r_[Z.ravel() - base, -lam * c0]
    return c0 + np.linalg.lstsq(M, rhs, rcond=None)[0]


def test_shape_step_is_the_ridge_solution_and_exact_without_noise():
    model = _shape_model()
    rng = np.random.default_rng(1)
    idx = rng.integers(0, 60, (30, 3))
    bary = rng.dirichlet(np.ones(3), 30)
    c_true = np.array([0.8, -0.6, 0.3])
    Z = np.einsum("nk,nki->ni", bary, _skinned(model, c_true, TRUE_POSE)[idx])
    c0 = np.array([0.1, 0.1, -0.2])
    got = F.fit_shape_step(model, c0, TRUE_POSE, idx, bary, Z, residual_std_m=1e-9)
    np.testing.assert_allclose(got, c_true, atol=1e-8)
    noisy = Z + rng.normal(0, 0.01, Z.shape)
    for std in (0.005, 0.05):
        got = F.fit_shape_step(model, c0, TRUE_POSE, idx, bary, noisy, residual_std_m=std)
        ref = _ridge_reference(model, c0, TRUE_POSE, idx, bary, noisy, std)
        np.testing.assert_allclose(got, ref, atol=1e-10)
    default = F.fit_shape_step(model, c0, TRUE_POSE, idx, bary, noisy)
    np.testing.assert_array_equal(default, F.fit_shape_step(model, c0, TRUE_POSE, idx, bary, noisy, 0.005))


# ---- pairs and distances ---------------------------------------------------------------------------------------

def _square():
    """A unit square in z = 0 of two triangles, normals +z."""
    V = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]])
    Fc = np.array([[0, 1, 2], [0, 2, 3]])
    return V, Fc, np.tile([0.0, 0.0, 1.0], (4, 1))


def _tilted(deg):
    a = np.radians(deg)
    return np.array([np.sin(a), 0.0, np.cos(a)])


def test_model_to_scan_pairs_take_the_nearest_compatible_scan_vertex_within_reach():
    V, Fc, N = _square()
    # scan points near model vertex 0: the nearest one's normal is 70 deg off (incompatible), the next 50 deg;
    # near vertex 1: only a point 0.3 away (beyond reach 0.2); near vertex 2: exactly 60 deg off (cos 0.5: not
    # compatible); near vertex 3: a compatible point
    S = np.array([[0.0, 0.0, 0.01], [0.0, 0.0, 0.02], [1.3, 0.0, 0.0], [1.0, 1.0, 0.01], [0.0, 1.0, 0.05]])
    SN = np.array([_tilted(70), _tilted(50), [0, 0, 1.0], [np.sqrt(0.75), 0.0, 0.5], [0, 0, 1.0]])
    corners, bary, Z, zi = F.compatible_pairs(V, Fc, N, S, SN, cKDTree(S), 0.2, np.array([], int), k=3)
    np.testing.assert_array_equal(corners, [[0, 0, 0], [3, 3, 3]])
    np.testing.assert_array_equal(bary, [[1, 0, 0], [1, 0, 0]])
    np.testing.assert_array_equal(zi, [1, 4])
    np.testing.assert_array_equal(Z, S[[1, 4]])
    # the model sample: only vertex 3 asked
    corners, _, _, zi = F.compatible_pairs(V, Fc, N, S, SN, cKDTree(S), 0.2, np.array([], int), k=3,
                                           model_sample=np.array([3, 1]))
    np.testing.assert_array_equal(corners[:, 0], [3])
    np.testing.assert_array_equal(zi, [4])
    # k = 2 for vertex 0: its two nearest scan points (0 incompatible, 1) are looked at; the pair is point 1
    _, _, _, zi = F.compatible_pairs(V, Fc, N, S, SN, cKDTree(S), 0.2, np.array([], int), k=2)
    np.testing.assert_array_equal(zi, [1, 4])
    assert F.COMPATIBLE_COS == 0.5


def test_scan_to_model_pairs_land_on_the_surface_or_the_nearest_compatible_vertex():
    V, Fc, N = _square()
    far = np.array([[9.0, 9.0, 9.0]])  # no model vertex pairs with it
    S = np.r_[far, [[0.25, 0.75, 0.02], [0.6, 0.2, -0.01], [0.9, 0.1, 0.03], [0.45, 0.45, 0.05]]]
    SN = np.array([[0, 0, 1.0], [0, 0, 1.0], _tilted(40), [0, 0, -1.0], [0, 0, 1.0]])
    sample = np.array([1, 2, 3, 4])
    # by hand, reach 0.8: model -> scan: vertex 0 -> point 2 (0.632; point 4 at 0.638), 1 -> 2 (point 3 nearer,
    # 0.145, faces away), 2 -> 4 (0.779), 3 -> 1 (0.354); scan -> model: point 1 -> vertex 3, 2 -> 1, 3: its
    # nearest vertex 1 faces away and the others are beyond reach, 4 -> 0 (0.638)
    corners, bary, Z, zi = F.compatible_pairs(V, Fc, N, S, SN, cKDTree(S), 0.8, sample, k=4, surface=False)
    np.testing.assert_array_equal(zi, [2, 2, 4, 1, 1, 2, 4])
    np.testing.assert_array_equal(Z, S[zi])
    np.testing.assert_array_equal(corners, np.repeat([[0], [1], [2], [3], [3], [1], [0]], 3, axis=1))
    np.testing.assert_array_equal(bary, np.tile([1.0, 0, 0], (7, 1)))
    corners, bary, Z, zi = F.compatible_pairs(V, Fc, N, S, SN, cKDTree(S), 0.8, sample, k=4, surface=True)
    np.testing.assert_array_equal(zi, [2, 2, 4, 1, 1, 2, 4])
    P = np.einsum("nk,nki->ni", bary[4:], V[corners[4:]])
    np.testing.assert_allclose(P, [[0.25, 0.75, 0.0], [0.6, 0.2, 0.0], [0.45, 0.45, 0.0]], atol=1e-12)
    np.testing.assert_allclose(bary.sum(1), 1.0)
    assert (bary >= 0).all()
    # the model -> scan pairs (vertex -> scan vertex) stay as they are
    np.testing.assert_array_equal(corners[:4], np.repeat([[0], [1], [2], [3]], 3, axis=1))
    np.testing.assert_array_equal(bary[:4], np.tile([1.0, 0, 0], (4, 1)))
    # reach 0.4: only vertex 3 -> point 1 and point 1 -> vertex 3 (point 2 is 0.447 from vertex 1)
    _, _, _, zi = F.compatible_pairs(V, Fc, N, S, SN, cKDTree(S), 0.4, sample, k=4)
    np.testing.assert_array_equal(zi, [1, 1])


def test_a_surface_pair_on_a_triangle_facing_away_keeps_the_nearest_vertex():
    # the model's own vertex normals agree with the scan point's (compatible), its triangle faces the other way
    V = np.array([[0.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])  # winding: normal -z
    Fc = np.array([[0, 1, 2]])
    N = np.tile([0.0, 0.0, 1.0], (3, 1))
    S = np.array([[0.2, 0.1, 0.01]])
    SN = np.array([[0.0, 0.0, 1.0]])
    corners, bary, _, _ = F.compatible_pairs(V, Fc, N, S, SN, cKDTree(S), 0.5, np.array([0]), k=2, surface=True,
                                             model_sample=np.array([], int))
    np.testing.assert_array_equal(corners, [[0, 0, 0]])
    np.testing.assert_array_equal(bary, [[1.0, 0.0, 0.0]])
    # wound the other way (normal +z): the closest surface point (0.2, 0.1, 0)
    corners, bary, _, _ = F.compatible_pairs(V, Fc[:, [0, 2, 1]], N, S, SN, cKDTree(S), 0.5, np.array([0]), k=2,
                                             surface=True, model_sample=np.array([], int))
    np.testing.assert_allclose(np.einsum("nk,nki->ni", bary, V[corners]), [[0.2, 0.1, 0.0]], atol=1e-12)


def test_surface_distance_in_millimetres():
    V, Fc, _ = _square()
    pts = np.array([[0.5, 0.5, 0.01], [0.2, 0.3, -0.004], [1.003, 0.5, 0.004], [-0.003, -0.004, 0.0]])
    np.testing.assert_allclose(F.surface_distance_mm(pts, V, Fc), [10.0, 4.0, 5.0, 5.0], atol=1e-9)


def test_rotation_angle_and_posed_frames():
    R = np.stack([Rotation.from_rotvec([0, 0, np.radians(30)]).as_matrix(), np.eye(3),
                  Rotation.from_rotvec(np.radians(120) * np.array([0.6, 0.8, 0.0])).as_matrix()])
    np.testing.assert_allclose(F.rotation_angle_deg(R), [30.0, 0.0, 120.0], atol=1e-9)
    sk = _skeleton()
    fitted = SimpleNamespace(skeleton=sk, pose=TRUE_POSE)
    np.testing.assert_allclose(F.posed_frames(fitted), forward_kinematics(sk, TRUE_POSE))


def test_model_fit_mesh_is_its_posed_vertices():
    V, Fc, _ = _square()
    fit = F.ModelFit(np.zeros(1), Pose.rest(1), _skeleton(), V * 0, V, Fc, np.ones((4, 1)), 1.0, 2.0, 0, ())
    np.testing.assert_array_equal(fit.mesh.vertices, V)
    np.testing.assert_array_equal(fit.mesh.faces, Fc)


@pytest.mark.parametrize("name", ["pelvis", "spine_01", "clavicle_l"])
def test_the_chain_bones_have_a_prior(name):
    assert name in F.POSE_PRIOR_SIGMA and "tool" not in F.POSE_PRIOR_SIGMA


# ---- second pass: the survivors of the first mutation run -------------------------------------------------------

def test_pose_step_converges_like_gauss_newton_from_near_and_recovers_from_far():
    # exact pairs, no prior: from 0.9 of the pose three LM steps (damping 1e-3, divided by 3.3 per accepted step)
    # land within 2e-7 rad; from the mirrored pose (-1x: steps get rejected and damped first) eight steps are exact
    sk = _skeleton()
    V, W = _points()
    Z = _posed(sk, TRUE_POSE, V, W)
    near = Pose(TRUE_POSE.rotations * 0.9, TRUE_POSE.translation * 0.9)
    got = F.fit_pose_step(sk, near, V, W, Z, (0, 1, 2, 3), lm_iterations=3, prior_scale=0.0)
    assert np.abs(got.rotations - TRUE_POSE.rotations).max() < 1e-6
    far = Pose(-TRUE_POSE.rotations, -TRUE_POSE.translation)
    got = F.fit_pose_step(sk, far, V, W, Z, (0, 1, 2, 3), lm_iterations=8, prior_scale=0.0)
    assert np.abs(got.rotations - TRUE_POSE.rotations).max() < 1e-9
    got5 = F.fit_pose_step(sk, far, V, W, Z, (0, 1, 2, 3), lm_iterations=5, prior_scale=0.0)
    assert 1e-6 < np.abs(got5.rotations - TRUE_POSE.rotations).max() < 1e-3


def test_pose_step_prior_scale_defaults_to_one():
    sk = _skeleton()
    V, W = _points()
    Z = _posed(sk, TRUE_POSE, V, W) + np.random.default_rng(6).normal(0, 0.01, V.shape)
    start = Pose(np.zeros((4, 3)), np.zeros(3))
    a = F.fit_pose_step(sk, start, V, W, Z, (0, 1, 2, 3), residual_std_m=0.05)
    b = F.fit_pose_step(sk, start, V, W, Z, (0, 1, 2, 3), residual_std_m=0.05, prior_scale=1.0)
    c = F.fit_pose_step(sk, start, V, W, Z, (0, 1, 2, 3), residual_std_m=0.05, prior_scale=2.0)
    np.testing.assert_array_equal(a.rotations, b.rotations)
    assert np.abs(a.rotations - c.rotations).max() > 1e-4


def _tilt(deg):
    a = np.radians(deg)
    return np.array([np.sin(a), 0.0, np.cos(a)])


def test_the_ninth_nearest_scan_point_is_looked_at_by_default():
    # 8 scan points right at model vertex 0 face away, the 9th (a little farther) is compatible
    V = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    Fc = np.array([[0, 1, 2]])
    N = np.tile([0.0, 0.0, 1.0], (3, 1))
    S = np.r_[np.c_[np.linspace(0, 0.007, 8), np.zeros(8), np.full(8, 0.001)], [[0.0, 0.0, 0.05]]]
    SN = np.r_[np.tile([0.0, 0.0, -1.0], (8, 1)), [[0.0, 0.0, 1.0]]]
    corners, _, _, zi = F.compatible_pairs(V, Fc, N, S, SN, cKDTree(S), 0.1, np.array([], int),
                                           model_sample=np.array([0]))
    assert zi.tolist() == [] and len(corners) == 0  # k = 8: none of the 8 nearest is compatible
    _, _, _, zi = F.compatible_pairs(V, Fc, N, S, SN, cKDTree(S), 0.1, np.array([], int), k=9,
                                     model_sample=np.array([0]))
    assert zi.tolist() == [8]


def test_surface_pairs_by_default_and_on_a_small_square_away_from_the_origin():
    # side 0.5 (twice the triangles' area 0.25: their normals must be normalised), at (5, 3, 1)
    V = np.array([[0.0, 0.0, 0.0], [0.5, 0.0, 0.0], [0.5, 0.5, 0.0], [0.0, 0.5, 0.0]]) + [5.0, 3.0, 1.0]
    Fc = np.array([[0, 1, 2], [0, 2, 3]])
    N = np.tile([0.0, 0.0, 1.0], (4, 1))
    # two scan points (not three: a (n,) array would broadcast), normals tilted 50 deg about y either way
    S = np.array([[5.3, 3.1, 1.01], [5.1, 3.4, 0.99]])
    SN = np.array([_tilt(50), _tilt(-50)])
    corners, bary, Z, zi = F.compatible_pairs(V, Fc, N, S, SN, cKDTree(S), 0.4, np.array([0, 1]), k=4,
                                              model_sample=np.array([], int))
    np.testing.assert_array_equal(zi, [0, 1])
    P = np.einsum("nk,nki->ni", bary, V[corners])
    np.testing.assert_allclose(P, [[5.3, 3.1, 1.0], [5.1, 3.4, 1.0]], atol=1e-12)
    np.testing.assert_allclose(bary.sum(1), 1.0, atol=1e-15)


def test_scan_to_model_compatibility_is_strictly_within_60_degrees():
    V = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    Fc = np.array([[0, 1, 2]])
    at60 = np.array([np.sqrt(0.75), 0.0, 0.5])  # cos 0.5 with +z, exactly
    S = np.array([[0.2, 0.2, 0.01]])
    # the model vertex normals +z: cos 0.5 exactly: no pair
    corners, _, _, _ = F.compatible_pairs(V, Fc, np.tile([0.0, 0.0, 1.0], (3, 1)), S, at60[None], cKDTree(S), 0.5,
                                          np.array([0]), model_sample=np.array([], int))
    assert len(corners) == 0
    # vertex normals equal to the scan's (compatible), the triangle's normal +z at cos 0.5: the nearest vertex
    corners, bary, _, _ = F.compatible_pairs(V, Fc, np.tile(at60, (3, 1)), S, at60[None], cKDTree(S), 0.5,
                                             np.array([0]), model_sample=np.array([], int))
    np.testing.assert_array_equal(corners, [[0, 0, 0]])
    np.testing.assert_array_equal(bary, [[1.0, 0.0, 0.0]])


def test_pairs_with_fewer_points_than_k():
    # one model vertex, one scan point, k = 2: the missing second neighbours must not index past the arrays
    V = np.array([[0.0, 0.0, 0.0]])
    S = np.array([[0.0, 0.0, 0.01]])
    up = np.array([[0.0, 0.0, 1.0]])
    corners, bary, Z, zi = F.compatible_pairs(V, np.zeros((0, 3), int), up, S, up, cKDTree(S), 0.1, np.array([0]),
                                              k=2, surface=False)
    np.testing.assert_array_equal(zi, [0, 0])
    np.testing.assert_array_equal(corners, np.zeros((2, 3), int))


def test_rotation_angle_of_one_matrix():
    R = Rotation.from_rotvec([0.0, np.radians(45.0), 0.0]).as_matrix()
    assert float(F.rotation_angle_deg(R)) == pytest.approx(45.0)
