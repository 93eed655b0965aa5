"""The pose oracle of benchmarks/mirror_pose_oracle.py (issue 12: what the IK's twist costs the warp).

A planted forearm twist is measured as twist (not swing), a planted swing as swing (not twist); the oracle
that keeps the IK's bone directions and takes the true twist gives back the true bone rotation when only
the twist was wrong, and leaves the planted swing in place when the swing was wrong; world rotations and
poses convert into each other exactly.
"""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from benchmarks.mirror_pose_oracle import (
    oracle_swing,
    oracle_twist,
    pose_from_world,
    swing_twist_errors,
    world_rotations,
)
from bodystudio.body import Phenotype, Pose, build_body
from bodystudio.body.skinning import posed_joints


@pytest.fixture(scope="module")
def skeleton():
    return build_body(Phenotype(), resolution="2k").skeleton


def _pose(skeleton, seed=0):
    rng = np.random.default_rng(seed)
    return Pose(rng.normal(0, 0.3, (skeleton.n_bones, 3)), np.array([0.1, 0.0, 2.5]))


def _planted(skeleton, pose, bone, local_axis, angle_rad):
    """``pose`` with ``bone`` turned further by ``angle_rad`` about its rest frame's ``local_axis``
    (1 = along the bone: a twist)."""
    rot = pose.rotations.copy()
    j = skeleton.index(bone)
    axis = np.zeros(3)
    axis[local_axis] = angle_rad
    rot[j] = (Rotation.from_rotvec(rot[j]) * Rotation.from_rotvec(axis)).as_rotvec()
    return Pose(rot, pose.translation)


def test_world_rotations_and_poses_round_trip(skeleton):
    pose = _pose(skeleton)
    back = pose_from_world(skeleton, world_rotations(skeleton, pose), pose.translation)
    for a, b in zip(posed_joints(skeleton, pose), posed_joints(skeleton, back), strict=True):
        np.testing.assert_allclose(a, b, atol=1e-10)


def test_a_planted_forearm_twist_is_twist_and_the_oracle_restores_it(skeleton):
    ik = _pose(skeleton, 1)
    true = _planted(skeleton, ik, "lowerarm_l", 1, np.radians(12.0))
    W_ik, W_true = world_rotations(skeleton, ik), world_rotations(skeleton, true)
    j = skeleton.index("lowerarm_l")
    swing, twist = swing_twist_errors(skeleton, W_ik, W_true, [j])
    assert swing[0] < 1e-6 and abs(twist[0] - 12.0) < 1e-6
    # the twist does not move a joint: the IK (joints only) cannot see it
    for a, b in zip(posed_joints(skeleton, ik), posed_joints(skeleton, true), strict=True):
        assert np.abs(a[j] - b[j]).max() < 1e-12
    W = oracle_twist(skeleton, W_ik, W_true, [j])
    np.testing.assert_allclose(W[j], W_true[j], atol=1e-10)
    others = np.arange(skeleton.n_bones) != j
    np.testing.assert_allclose(W[others], W_ik[others], atol=1e-12)
    # the child (the hand) inherited the twist in the true pose; the oracle keeps the IK's world rotation there
    hand = skeleton.index("hand_l")
    assert np.abs(W_true[hand] - W_ik[hand]).max() > 0.05


def test_a_planted_swing_is_swing_and_the_twist_oracle_keeps_it(skeleton):
    ik = _pose(skeleton, 2)
    true = _planted(skeleton, ik, "upperarm_r", 0, np.radians(7.0))
    W_ik, W_true = world_rotations(skeleton, ik), world_rotations(skeleton, true)
    j = skeleton.index("upperarm_r")
    swing, twist = swing_twist_errors(skeleton, W_ik, W_true, [j])
    assert abs(swing[0] - 7.0) < 1e-6 and twist[0] < 1e-6
    np.testing.assert_allclose(oracle_twist(skeleton, W_ik, W_true, [j])[j], W_ik[j], atol=1e-10)
    np.testing.assert_allclose(oracle_swing(skeleton, W_ik, W_true, [j])[j], W_true[j], atol=1e-10)
