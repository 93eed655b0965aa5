"""The IK's limb twist taken off (MIR12p): ``track.untwisted_pose`` keeps every joint and every other bone's world
rotation, takes a planted twist off, and an IK warm-started frame to frame over a limb swinging in a loop no longer
gathers twist (the warm-started IK alone drifts by tens of degrees over three loops)."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bodystudio.body import Pose, build_body
from bodystudio.body.population import sample_population
from bodystudio.body.skinning import forward_kinematics, posed_joints
from bodystudio.errors import InputError
from bodystudio.mirror.track import UNTWIST_BONES, ik_pose, posed_kinect_joints, untwisted_pose


@pytest.fixture(scope="module")
def skeleton():
    phenotype, local = sample_population(1, seed=5)[0]
    return build_body(phenotype, local, resolution="2k").skeleton


def _world(skeleton, pose):
    """(B, 3, 3) rest-world to posed-world rotation of each bone."""
    return forward_kinematics(skeleton, pose)[:, :3, :3] @ np.transpose(skeleton.rest_rotations, (0, 2, 1))


def _random_pose(skeleton, seed, scale=0.35):
    rng = np.random.default_rng(seed)
    return Pose(rng.normal(0.0, scale, (skeleton.n_bones, 3)), rng.normal(0.0, 0.2, 3))


def _twist_deg(skeleton, W_a, W_b, bone):
    """Angle (degrees) about the bone's posed axis between two world rotations that give it the same direction."""
    j = skeleton.index(bone)
    d = skeleton.tails[j] - skeleton.heads[j]
    axis = W_a[j] @ (d / np.linalg.norm(d))
    return float(np.degrees(Rotation.from_matrix(W_a[j] @ W_b[j].T).as_rotvec() @ axis))


def test_untwisting_moves_no_joint_and_no_other_bone(skeleton):
    pose = _random_pose(skeleton, 1)
    out = untwisted_pose(skeleton, pose)
    h0, t0 = posed_joints(skeleton, pose)
    h1, t1 = posed_joints(skeleton, out)
    np.testing.assert_allclose(h1, h0, atol=1e-9)
    np.testing.assert_allclose(t1, t0, atol=1e-9)
    np.testing.assert_allclose(posed_kinect_joints(skeleton, out), posed_kinect_joints(skeleton, pose), atol=1e-9)
    W0, W1 = _world(skeleton, pose), _world(skeleton, out)
    listed = [skeleton.index(b) for b in UNTWIST_BONES]
    others = np.setdiff1d(np.arange(skeleton.n_bones), listed)
    np.testing.assert_allclose(W1[others], W0[others], atol=1e-9)  # the hands and feet keep their rotations
    assert max(abs(_twist_deg(skeleton, W1, W0, b)) for b in UNTWIST_BONES) > 5.0  # the random pose had twist
    # no twist left against the parent: each listed bone's local rotation (rest-world axes) turns about an axis
    # square to the bone
    for j in listed:
        L = W1[skeleton.parents[j]].T @ W1[j]
        d = skeleton.tails[j] - skeleton.heads[j]
        assert abs(Rotation.from_matrix(L).as_rotvec() @ (d / np.linalg.norm(d))) < 1e-9
    assert untwisted_pose(skeleton, pose, ()) is pose
    np.testing.assert_allclose(untwisted_pose(skeleton, out).rotations, out.rotations, atol=1e-9)  # idempotent


def test_a_planted_forearm_twist_is_taken_off(skeleton):
    base = untwisted_pose(skeleton, _random_pose(skeleton, 2))
    j = skeleton.index("lowerarm_l")
    rv = base.rotations.copy()  # 40 degrees about the bone's own axis (the bone frame's y)
    rv[j] = (Rotation.from_rotvec(rv[j]) * Rotation.from_rotvec([0.0, np.radians(40.0), 0.0])).as_rotvec()
    twisted = Pose(rv, base.translation)
    Wb, Wt = _world(skeleton, base), _world(skeleton, twisted)
    assert abs(abs(_twist_deg(skeleton, Wt, Wb, "lowerarm_l")) - 40.0) < 1e-6
    W = _world(skeleton, untwisted_pose(skeleton, twisted))
    np.testing.assert_allclose(W[j], Wb[j], atol=1e-9)
    hand = skeleton.index("hand_l")
    np.testing.assert_allclose(W[hand], Wt[hand], atol=1e-9)  # the hand keeps where the twisted pose put it


def test_a_warm_started_ik_gathers_no_twist_over_a_swinging_loop(skeleton):
    """The left arm's tip swings round a cone three times (the upper arm 25 degrees off its rest direction): the
    true poses have no twist; the IK warm-started by its last pose turns each bone by the smallest rotation onto its
    new direction and, untwisted as the run does, ends within 0.5 degrees of the truth; without, it drifts."""
    up = skeleton.index("upperarm_l")
    d = skeleton.tails[up] - skeleton.heads[up]
    d /= np.linalg.norm(d)
    a = np.cross(d, [0.0, 0.0, 1.0])
    a /= np.linalg.norm(a)
    b = np.cross(d, a)
    truth = []
    for phase in np.linspace(0.0, 6 * np.pi, 91):
        direction = np.cos(np.radians(25)) * d + np.sin(np.radians(25)) * (np.cos(phase) * a + np.sin(phase) * b)
        rv = np.zeros((skeleton.n_bones, 3))
        rv[skeleton.index("lowerarm_l")] = [0.5, 0.0, 0.0]
        pose = Pose(rv, np.zeros(3))
        W = _world(skeleton, pose)
        p = skeleton.parents[up]  # the arm onto ``direction`` (any twist: untwisted below)
        L = Rotation.align_vectors([direction], [d])[0].as_matrix()
        Rr = skeleton.rest_rotations[up]
        rv[up] = Rotation.from_matrix(Rr.T @ W[p].T @ L @ Rr).as_rotvec()  # W_up = W_p L_up = L
        truth.append(untwisted_pose(skeleton, Pose(rv, np.zeros(3))))
    drift = {}
    for untwist in (False, True):
        previous = None
        for pose in truth:
            K = posed_kinect_joints(skeleton, pose)
            est = ik_pose(skeleton, K, np.ones(len(K), bool), "v2", previous=previous)
            previous = untwisted_pose(skeleton, est) if untwist else est
        W_true, W_est = _world(skeleton, truth[-1]), _world(skeleton, previous)
        drift[untwist] = max(abs(_twist_deg(skeleton, W_est, W_true, b)) for b in ("upperarm_l", "lowerarm_l"))
    assert drift[True] < 0.5
    assert drift[False] > 10.0


def test_untwisting_a_bone_the_skeleton_lacks_is_refused(skeleton):
    with pytest.raises(InputError, match="^untwisted_pose: no bone 'forearm_x' in the skeleton"):
        untwisted_pose(skeleton, _random_pose(skeleton, 3), ("forearm_x",))


def test_the_run_untwists_the_limbs_by_default():
    from bodystudio.mirror import run

    assert run.UNTWIST_BONES == UNTWIST_BONES
    assert {"upperarm_l", "lowerarm_l", "upperarm_r", "lowerarm_r"} <= set(run.UNTWIST_BONES)
