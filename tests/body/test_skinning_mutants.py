"""Closed-form checks of bodystudio.body.skinning that the blend tests of test_skinning.py do not reach
(issue 17, mutation testing): forward kinematics of a posed chain (a child follows its parent's rotation
and the root's translation), bone tails, the Hamilton product, DQS of screw motions (a translation along
the rotation axis), of pure translations, of quaternions exactly 90 degrees apart (dot product 0) and the
hemisphere taken from each vertex's own dominant bone."""

import numpy as np
from scipy.spatial.transform import Rotation

from bodystudio.body.pose import Pose
from bodystudio.body.skeleton import Skeleton
from bodystudio.body.skinning import (
    _quat_mul,
    dual_quaternion_skinning,
    forward_kinematics,
    linear_blend_skinning,
    posed_joints,
    skinning_transforms,
)


def _chain():
    """Three connected bones: a 1 m root up +y, a 0.5 m child bending towards +x, a 0.7 m grandchild."""
    heads = np.array([[0.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.3, 1.4, 0.0]])
    tails = np.array([[0.0, 1.0, 0.0], [0.3, 1.4, 0.0], [0.3, 2.1, 0.0]])
    return Skeleton(("root", "mid", "tip"), np.array([-1, 0, 1]), heads, tails, np.array([0.0, 0.3, -0.2]))


def _world_rotation(sk, j, rotvec):
    """A local rotation of bone ``j`` seen in world axes (its rest frame's axes)."""
    A = sk.rest_rotations[j]
    return A @ Rotation.from_rotvec(rotvec).as_matrix() @ A.T


def _rigid(R, t):
    S = np.eye(4)
    S[:3, :3], S[:3, 3] = R, t
    return S


def test_rest_pose_with_a_translation_moves_every_joint_by_it():
    sk = _chain()
    t = np.array([0.3, 0.2, -0.1])
    heads, tails = posed_joints(sk, Pose(np.zeros((3, 3)), t))
    np.testing.assert_allclose(heads, sk.heads + t, atol=1e-12)
    np.testing.assert_allclose(tails, sk.tails + t, atol=1e-12)


def test_children_follow_a_rotated_and_translated_root():
    sk = _chain()
    r0, t = np.array([0.2, -0.4, 0.9]), np.array([0.3, 0.2, -0.1])
    rot = np.zeros((3, 3))
    rot[0] = r0
    heads, tails = posed_joints(sk, Pose(rot, t))
    Rw = _world_rotation(sk, 0, r0)  # about the root's head, at the origin
    np.testing.assert_allclose(heads, sk.heads @ Rw.T + t, atol=1e-12)
    np.testing.assert_allclose(tails, sk.tails @ Rw.T + t, atol=1e-12)
    S = skinning_transforms(sk, Pose(rot, t))
    for j in range(3):  # each bone's transform carries its rest head and tail to the posed ones
        np.testing.assert_allclose(S[j, :3, :3] @ sk.heads[j] + S[j, :3, 3], heads[j], atol=1e-12)
        np.testing.assert_allclose(S[j, :3, :3] @ sk.tails[j] + S[j, :3, 3], tails[j], atol=1e-12)


def test_a_middle_bone_rotates_itself_and_its_children_about_its_head():
    sk = _chain()
    r1 = np.array([0.0, 0.0, 1.1])
    rot = np.zeros((3, 3))
    rot[1] = r1
    heads, tails = posed_joints(sk, Pose(rot, np.zeros(3)))
    Rw = _world_rotation(sk, 1, r1)
    pivot = sk.heads[1]
    np.testing.assert_allclose(heads[:2], sk.heads[:2], atol=1e-12)
    np.testing.assert_allclose(tails[0], sk.tails[0], atol=1e-12)
    np.testing.assert_allclose(tails[1:], (sk.tails[1:] - pivot) @ Rw.T + pivot, atol=1e-12)
    np.testing.assert_allclose(heads[2], (sk.heads[2] - pivot) @ Rw.T + pivot, atol=1e-12)
    # the bone's frame: column 1 runs head -> tail, lengths are kept
    M = forward_kinematics(sk, Pose(rot, np.zeros(3)))
    np.testing.assert_allclose(np.linalg.norm(tails - heads, axis=1), [1.0, 0.5, 0.7], atol=1e-12)
    np.testing.assert_allclose(M[:, :3, 1], (tails - heads) / [[1.0], [0.5], [0.7]], atol=1e-12)


def test_hamilton_product_on_units_broadcasts_and_composes_rotations():
    one, i, j, k = np.eye(4)
    np.testing.assert_array_equal(_quat_mul(i, j), k)
    np.testing.assert_array_equal(_quat_mul(j, i), -k)
    np.testing.assert_array_equal(_quat_mul(i, i), -one)
    np.testing.assert_array_equal(_quat_mul(one, j), j)
    rng = np.random.default_rng(0)
    a, b = Rotation.random(6, random_state=rng), Rotation.random(6, random_state=rng)

    def wxyz(r):
        q = r.as_quat()
        return np.concatenate([q[..., 3:], q[..., :3]], axis=-1)

    qa, qb = wxyz(a).reshape(2, 3, 4), wxyz(b).reshape(2, 3, 4)
    got = _quat_mul(qa, qb)
    assert got.shape == (2, 3, 4)
    ref = wxyz(a * b).reshape(2, 3, 4)  # composition R_a R_b, up to the quaternion's sign
    np.testing.assert_allclose(np.abs(np.einsum("...i,...i", got, ref)), 1.0, atol=1e-12)
    # a product with a zero real part (as DQS forms t * q) whose other real part is 0 too
    np.testing.assert_allclose(_quat_mul(np.array([0.0, 1.0, 2.0, 3.0]), np.array([0.0, 0.0, 0.0, 1.0])),
                               [-3.0, 2.0, -1.0, 0.0], atol=0)


def test_dqs_reproduces_screw_motions_and_blends_pure_translations_linearly():
    rng = np.random.default_rng(1)
    V = rng.normal(size=(10, 3))
    for _ in range(3):  # general rigid motions: translation along the rotation axis too
        R = Rotation.random(random_state=rng).as_matrix()
        S = np.stack([_rigid(R, rng.normal(size=3)), np.eye(4)])
        W = np.tile([1.0, 0.0], (len(V), 1))
        np.testing.assert_allclose(dual_quaternion_skinning(V, W, S), V @ R.T + S[0, :3, 3], atol=1e-12)
    t1, t2 = np.array([0.1, -0.3, 0.2]), np.array([-0.4, 0.05, 0.6])
    S = np.stack([_rigid(np.eye(3), t1), _rigid(np.eye(3), t2)])
    W = np.tile([0.3, 0.7], (len(V), 1))
    np.testing.assert_allclose(dual_quaternion_skinning(V, W, S), V + 0.3 * t1 + 0.7 * t2, atol=1e-12)
    np.testing.assert_allclose(linear_blend_skinning(V, W, S), V + 0.3 * t1 + 0.7 * t2, atol=1e-12)
    # a 180-degree screw about z (real part 0) blended half and half with the identity
    S = np.stack([np.eye(4), _rigid(np.diag([-1.0, -1.0, 1.0]), [0.0, 0.0, 0.4])])  # exactly: quaternion (0, 0, 0, 1)
    q = Rotation.from_matrix(S[:, :3, :3]).as_quat()
    assert q[0] @ q[1] == 0.0  # the tie the sign fix breaks towards +1
    got = dual_quaternion_skinning(V, np.full((len(V), 2), 0.5), S)
    assert np.isfinite(got).all()
    for sign in (1, -1):  # 90 degrees one way or the other (the two quaternions are 90 deg apart), half the lift
        half = Rotation.from_rotvec([0, 0, sign * np.pi / 2]).as_matrix()
        if np.allclose(got, V @ half.T + [0.0, 0.0, 0.2], atol=1e-12):
            break
    else:
        raise AssertionError("the blend of 0 and 180 degrees is not a quarter turn with half the lift")


def _about_z(deg, pivot):
    R = Rotation.from_rotvec([0.0, 0.0, np.radians(deg)]).as_matrix()
    return _rigid(R, pivot - R @ pivot)


def test_dqs_takes_each_vertexs_hemisphere_from_its_own_dominant_bone():
    """Bones turned 0, 100 and 200 degrees about one axis: bones 0 and 2 are more than 180 degrees apart
    one way, less the other, so the blend depends on which bone's hemisphere is used: rotations about one
    axis blend to the angle 2 atan2(sum w sin(a/2), sum w cos(a/2)) with every angle taken within 180
    degrees of the dominant bone's."""
    pivot = np.array([0.1, 0.5, -0.2])
    angles = np.array([0.0, 100.0, 200.0])
    S = np.stack([_about_z(a, pivot) for a in angles])
    W = np.array([[0.6, 0.1, 0.3], [0.3, 0.1, 0.6], [0.2, 0.5, 0.3], [0.45, 0.1, 0.45], [0.1, 0.1, 0.8]])
    V = pivot + np.array([[0.05, 0.0, 0.01], [0.0, 0.05, 0.02], [-0.03, 0.04, 0.0], [0.02, -0.02, 0.1],
                          [0.04, 0.04, -0.03]])
    got = dual_quaternion_skinning(V, W, S)
    for n in range(len(V)):
        d = int(np.argmax(W[n]))
        a = angles + 360.0 * np.round((angles[d] - angles) / 360.0)  # within 180 deg of the dominant's
        half = np.radians(a) / 2
        blend = 2 * np.degrees(np.arctan2(W[n] @ np.sin(half), W[n] @ np.cos(half)))
        T = _about_z(blend, pivot)
        np.testing.assert_allclose(got[n], T[:3, :3] @ V[n] + T[:3, 3], atol=1e-12, err_msg=str(n))
        np.testing.assert_allclose(np.linalg.norm(got[n] - pivot), np.linalg.norm(V[n] - pivot), atol=1e-12)
    # vertex by vertex gives the same as all at once
    for n in range(len(V)):
        np.testing.assert_allclose(dual_quaternion_skinning(V[n:n + 1], W[n:n + 1], S)[0], got[n], atol=1e-12)
