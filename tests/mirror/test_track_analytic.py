"""IK of §5.2 (Real-time Reshaping) and its skinning against answers known in closed form.

The weighted Procrustes rotation recovers a known rotation and refuses collinear vectors; a reachable
target is reached (one bone moved, the others held by the warm start); inferred joints weigh
INFERRED_WEIGHT in the root's rigid fit; the six-weight sparse skinning equals dense LBS.
"""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bodystudio.body import Pose, build_body
from bodystudio.body.population import sample_population
from bodystudio.body.skinning import linear_blend_skinning, skinning_transforms
from bodystudio.errors import InputError
from bodystudio.mirror.track import (
    INFERRED_WEIGHT,
    _procrustes,
    _sparse_weights,
    check_kinect_joints,
    ik_pose,
    posed_kinect_joints,
    skin_vertices,
)


@pytest.fixture(scope="module")
def subject():
    phenotype, local = sample_population(1, seed=5)[0]
    return build_body(phenotype, local, resolution="6k")


def test_procrustes_recovers_a_rotation_and_refuses_collinear_vectors():
    R = Rotation.from_rotvec([0.3, -0.5, 0.8]).as_matrix()
    U = np.array([[1.0, 0.1, 0.0], [0.0, 0.8, 0.2], [0.1, 0.0, 1.2], [0.5, 0.5, 0.5]])
    w = np.array([1.0, 0.5, 2.0, 0.25])
    np.testing.assert_allclose(_procrustes(U, U @ R.T, w), R, atol=1e-12)
    # two vectors fix a rotation too
    np.testing.assert_allclose(_procrustes(U[:2], U[:2] @ R.T, w[:2]), R, atol=1e-12)
    # a mirrored target: still a rotation (det +1), never a reflection
    M = np.diag([1.0, 1.0, -1.0])
    Rm = _procrustes(U, U @ M.T, w)
    np.testing.assert_allclose(np.linalg.det(Rm), 1.0, atol=1e-12)
    np.testing.assert_allclose(Rm @ Rm.T, np.eye(3), atol=1e-12)
    # weights matter: noise on a low-weight vector moves the fit less than on a high-weight one
    V = U @ R.T
    V_noisy = V.copy()
    V_noisy[3] += [0.3, -0.2, 0.1]
    low = _procrustes(U, V_noisy, w)
    high = _procrustes(U, V_noisy, np.array([1.0, 0.5, 2.0, 4.0]))
    assert np.abs(low - R).max() < np.abs(high - R).max()
    # collinear (or nearly: second singular value below 8 % of the first) cannot fix the twist
    u = np.array([[1.0, 2.0, 0.5], [2.0, 4.0, 1.0], [-1.0, -2.0, -0.5]])
    assert _procrustes(u, u @ R.T, np.ones(3)) is None
    nearly = u + np.array([[0.0, 0.0, 0.0], [0.0, 0.05, 0.0], [0.0, 0.0, 0.0]])
    assert _procrustes(nearly, nearly @ R.T, np.ones(3)) is None
    wide = u + np.array([[0.0, 0.0, 0.0], [2.0, -1.0, 0.0], [0.0, 0.0, 2.0]])  # ratio 0.12
    np.testing.assert_allclose(_procrustes(wide, wide @ R.T, np.ones(3)), R, atol=1e-12)
    assert _procrustes(np.zeros((3, 3)), np.zeros((3, 3)), np.ones(3)) is None


def test_a_reachable_target_is_reached_and_the_other_bones_hold(subject):
    """Bend one elbow (lowerarm_l) from a posed start: the IK warm-started from the true pose with every other
    joint where it was puts the wrist back exactly and leaves the rest untouched."""
    sk = subject.skeleton
    rng = np.random.default_rng(1)
    rot = rng.normal(0, 0.15, (sk.n_bones, 3))
    pose = Pose(rot, np.array([0.2, 0.05, 1.8]))
    truth = posed_kinect_joints(sk, pose)
    bent = rot.copy()
    b = sk.index("lowerarm_l")
    bent[b] = rot[b] + np.array([0.0, 0.0, 0.6])
    target = posed_kinect_joints(sk, Pose(bent, pose.translation))
    est = ik_pose(sk, target, None, "v2", previous=pose)
    np.testing.assert_allclose(posed_kinect_joints(sk, est), target, atol=2e-4)
    assert np.linalg.norm(target - truth, axis=1).max() > 0.05  # the wrist did move
    # only the bent bone changed
    # the bent bone takes the bend (the smallest rotation to one joint: its twist is the warm start's, to 0.01
    # rad), the hand below it is re-fit to its three joints; every other bone holds its warm start
    change = np.abs(est.rotations - rot).max(1)
    np.testing.assert_allclose(est.rotations[b], bent[b], atol=0.01)
    hand = sk.index("hand_l")
    assert change[hand] < 0.01
    assert np.delete(change, [b, hand]).max() < 1e-9


def test_a_moved_and_turned_body_is_found_by_the_root_fit(subject):
    """A rigid motion of the whole posed body (turn 40 degrees about y, move 0.5 m): the root's weighted Kabsch
    fit takes it, the joints are reached exactly from the unmoved pose as warm start."""
    sk = subject.skeleton
    pose = Pose(np.random.default_rng(2).normal(0, 0.1, (sk.n_bones, 3)), np.array([0.0, 0.0, 2.0]))
    J = posed_kinect_joints(sk, pose)
    R = Rotation.from_euler("y", 40, degrees=True).as_matrix()
    moved = (J - J.mean(0)) @ R.T + J.mean(0) + [0.5, 0.0, -0.3]
    est = ik_pose(sk, moved, None, "v2", previous=pose)
    np.testing.assert_allclose(posed_kinect_joints(sk, est), moved, atol=1e-3)


def test_inferred_joints_weigh_a_quarter_in_the_root_fit(subject):
    """Only the three pelvis joints seen, HipLeft 4 cm off: the root's weighted Kabsch fit puts the weighted
    centroid of its joints on the observed one, so an inferred (not tracked) HipLeft pulls INFERRED_WEIGHT as
    hard as a tracked one."""
    sk = subject.skeleton
    pose = Pose(np.zeros((sk.n_bones, 3)), np.array([0.0, 0.0, 2.0]))
    J = posed_kinect_joints(sk, pose)
    from bodystudio.body.kinect import kinect_joint_names

    names = kinect_joint_names("v2")
    pelvis = [names.index(n) for n in ("SpineBase", "HipLeft", "HipRight")]
    w = np.array([1.0, 1.0, 1.0])
    K = np.full_like(J, np.nan)
    K[pelvis] = J[pelvis]
    K[pelvis[1]] += [0.04, 0.0, 0.0]  # HipLeft off by 4 cm in x
    for tracked_flag, weight in ((True, 1.0), (False, INFERRED_WEIGHT)):
        tracked = np.ones(len(names), bool)
        tracked[pelvis[1]] = tracked_flag
        est = ik_pose(sk, K, tracked, "v2")
        ww = w.copy()
        ww[1] *= weight
        shift = ww[1] * 0.04 / ww.sum()
        # the centroid of the fitted pelvis joints moves by the weighted mean shift (the rotation is about it)
        fitted = posed_kinect_joints(sk, est)[pelvis]
        centroid = (ww[:, None] * fitted).sum(0) / ww.sum()
        want = (ww[:, None] * J[pelvis]).sum(0) / ww.sum() + [shift, 0.0, 0.0]
        np.testing.assert_allclose(centroid, want, atol=1e-6)
    # only one pelvis joint: cannot be tracked
    K1 = np.full_like(J, np.nan)
    K1[pelvis[0]] = J[pelvis[0]]
    with pytest.raises(InputError, match="fewer than two tracked pelvis"):
        ik_pose(sk, K1, None, "v2")


def test_kinect_joint_and_previous_pose_validation(subject):
    sk = subject.skeleton
    J = posed_kinect_joints(sk, Pose.rest(sk.n_bones))
    K, t = check_kinect_joints(J.tolist(), None, "v2")
    assert K.dtype == np.float64 and t.dtype == bool and t.all() and t.shape == (len(J),)
    K, t = check_kinect_joints(J, np.zeros(len(J)), "v2")
    assert not t.any()
    with pytest.raises(InputError, match=f"tracking needs {len(J)} Kinect v2 joints"):
        check_kinect_joints(J[:-1], None, "v2")
    with pytest.raises(InputError, match=f"tracked flags must be one per Kinect v2 joint \\({len(J)}\\)"):
        check_kinect_joints(J, np.ones(3, bool), "v2")
    with pytest.raises(InputError, match="previous pose has 3 bones"):
        ik_pose(sk, J, None, "v2", previous=Pose(np.zeros((3, 3)), np.zeros(3)))


def test_sparse_skinning_is_dense_lbs_over_the_six_largest_weights(subject):
    """With at most six non-zero weights per vertex it equals dense LBS; with more, it is LBS with the six
    largest renormalised; ``subset`` and ``transforms`` give the same rows."""
    sk = subject.skeleton
    pose = Pose(np.random.default_rng(3).normal(0, 0.3, (sk.n_bones, 3)), np.array([0.1, 0.0, 0.4]))
    S = skinning_transforms(sk, pose)
    V = subject.vertices[:300]
    rng = np.random.default_rng(4)
    Wd = rng.random((300, sk.n_bones)) ** 8  # dense weights: every bone has some
    Wd /= Wd.sum(1, keepdims=True)
    idx = np.argsort(-Wd, axis=1)[:, :6]
    W6 = np.zeros_like(Wd)
    np.put_along_axis(W6, idx, np.take_along_axis(Wd, idx, 1), 1)
    W6 /= W6.sum(1, keepdims=True)
    np.testing.assert_allclose(skin_vertices(V, Wd, sk, pose), linear_blend_skinning(V, W6, S), atol=1e-12)
    np.testing.assert_allclose(skin_vertices(V, W6, sk, pose), linear_blend_skinning(V, W6, S), atol=1e-12)
    assert np.abs(linear_blend_skinning(V, Wd, S) - linear_blend_skinning(V, W6, S)).max() > 1e-4
    sub = np.array([5, 17, 299])
    np.testing.assert_allclose(skin_vertices(V, Wd, sk, pose, subset=sub), linear_blend_skinning(V, W6, S)[sub],
                               atol=1e-12)
    np.testing.assert_allclose(skin_vertices(V, Wd, sk, None, transforms=S), linear_blend_skinning(V, W6, S),
                               atol=1e-12)
    # the cache is per array: another array of the same shape gets its own weights
    i1, w1 = _sparse_weights(Wd)
    i2, w2 = _sparse_weights(W6[::-1].copy())
    assert not np.array_equal(i1, i2)
    np.testing.assert_allclose(w1.sum(1), 1.0, atol=1e-12)
    assert i1.shape == (300, 6)
    # more arrays than the cache holds: still right
    for k in range(10):
        Wk = np.roll(Wd, k, axis=1)
        ik, wk = _sparse_weights(Wk)
        np.testing.assert_array_equal(ik, np.argsort(-Wk, axis=1)[:, :6])


def test_root_fit_from_four_and_from_two_pelvis_joints(subject):
    """Only the pelvis joints and SpineMid seen, the body turned 30 degrees and moved: the root's Kabsch fit
    matches them exactly (SpineBase and the hips alone are nearly collinear: no rotation from them); two joints
    are enough to track (translation only); the default version is v2; the refusals carry their exact messages."""
    from bodystudio.body.kinect import kinect_joint_names

    sk = subject.skeleton
    names = kinect_joint_names("v2")
    pelvis = [names.index(n) for n in ("SpineBase", "HipLeft", "HipRight", "SpineMid")]
    J = posed_kinect_joints(sk, Pose.rest(sk.n_bones))
    R = Rotation.from_euler("y", 30, degrees=True).as_matrix()
    moved = (J - J[pelvis].mean(0)) @ R.T + J[pelvis].mean(0) + [0.3, 0.0, 1.5]
    K = np.full_like(J, np.nan)
    K[pelvis] = moved[pelvis]
    est = ik_pose(sk, K)
    np.testing.assert_allclose(posed_kinect_joints(sk, est)[pelvis], moved[pelvis], atol=1e-9)
    np.testing.assert_array_equal(est.rotations, ik_pose(sk, K, None, "v2").rotations)
    K2 = np.full_like(J, np.nan)
    K2[pelvis[:2]] = J[pelvis[:2]] + [0.1, 0.0, 0.0]
    est2 = ik_pose(sk, K2, None, "v2")
    np.testing.assert_allclose(posed_kinect_joints(sk, est2)[pelvis[:2]], K2[pelvis[:2]], atol=1e-9)
    with pytest.raises(InputError, match="^fewer than two tracked pelvis/spine joints in this frame: the body "
                                         "cannot be tracked$"):
        ik_pose(sk, np.where(np.arange(len(J))[:, None] == pelvis[0], J, np.nan), None, "v2")
    with pytest.raises(InputError, match="^no tracked pelvis joints in this frame: the body cannot be tracked$"):
        ik_pose(sk, np.full_like(J, np.nan), None, "v2")
