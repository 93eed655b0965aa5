"""LBS and DQS on a two-bone 50/50 blend, where both have closed-form answers (Kavan et al. 2007)."""

import numpy as np
from scipy.spatial.transform import Rotation

from bodystudio.body.skinning import dual_quaternion_skinning, linear_blend_skinning

_JOINT = np.array([0.2, 1.0, -0.1])


def _about_joint(angle_deg, axis=(0.0, 0.0, 1.0)):
    """Rigid 4x4 rotating by ``angle_deg`` about ``axis`` through ``_JOINT`` (a translation part != 0)."""
    R = Rotation.from_rotvec(np.deg2rad(angle_deg) * np.asarray(axis)).as_matrix()
    S = np.eye(4)
    S[:3, :3] = R
    S[:3, 3] = _JOINT - R @ _JOINT
    return S


def _elbow_points(radius=0.05, n=12):
    """Points on a circle of ``radius`` around the joint in the bend plane (the elbow's skin)."""
    a = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return _JOINT + radius * np.c_[np.cos(a), np.sin(a), np.zeros(n)]


def test_lbs_puts_a_half_blended_vertex_at_the_midpoint():
    V = _elbow_points()
    S = np.stack([np.eye(4), _about_joint(90.0)])
    W = np.full((len(V), 2), 0.5)
    moved = V @ S[1, :3, :3].T + S[1, :3, 3]
    np.testing.assert_allclose(linear_blend_skinning(V, W, S), 0.5 * (V + moved), atol=1e-12)
    # LBS's candy-wrapper loss at 90 degrees: the blended point is cos(45 deg) of the radius from the joint
    r = np.linalg.norm(linear_blend_skinning(V, W, S) - _JOINT, axis=1)
    np.testing.assert_allclose(r, 0.05 * np.cos(np.pi / 4), atol=1e-12)
    # unequal weights blend linearly as well
    W = np.tile([0.8, 0.2], (len(V), 1))
    np.testing.assert_allclose(linear_blend_skinning(V, W, S), 0.8 * V + 0.2 * moved, atol=1e-12)


def test_dqs_puts_a_half_blended_vertex_on_the_arc_at_the_preserved_radius():
    V = _elbow_points()
    W = np.full((len(V), 2), 0.5)
    for angle in (30.0, 90.0, 150.0):
        S = np.stack([np.eye(4), _about_joint(angle)])
        half = _about_joint(angle / 2)
        expected = V @ half[:3, :3].T + half[:3, 3]  # rotation by half the angle about the joint
        got = dual_quaternion_skinning(V, W, S)
        np.testing.assert_allclose(got, expected, atol=1e-9, err_msg=f"{angle} deg")
        np.testing.assert_allclose(np.linalg.norm(got - _JOINT, axis=1), 0.05, atol=1e-9)
    # a 3:1 blend of a 90-degree bend rotates by the weighted angle's interpolation (ScLERP of one axis)
    S = np.stack([np.eye(4), _about_joint(90.0)])
    W = np.tile([0.25, 0.75], (len(V), 1))
    q_angle = 2 * np.arctan2(0.75 * np.sin(np.pi / 4), 0.25 + 0.75 * np.cos(np.pi / 4))  # nlerp angle
    part = _about_joint(np.rad2deg(q_angle))
    np.testing.assert_allclose(dual_quaternion_skinning(V, W, S), V @ part[:3, :3].T + part[:3, 3], atol=1e-9)


def test_dqs_blends_antipodal_quaternions_in_one_hemisphere():
    """Two near-identical 170-degree bends whose axes lean to either side of (1, 0, -1): the rotation
    matrices' quaternions come out with opposite signs (negative dot product), so a blend without the
    hemisphere fix cancels them into an unrelated rotation. The right blend is the symmetric middle: about
    (1, 0, -1), by the angle of the normalised mean quaternion (a hair under 170 degrees)."""
    V = _elbow_points()
    W = np.full((len(V), 2), 0.5)
    a0, a1 = np.array([1.1, 0.0, -0.9]), np.array([0.9, 0.0, -1.1])
    S = np.stack([_about_joint(170.0, a0 / np.linalg.norm(a0)), _about_joint(170.0, a1 / np.linalg.norm(a1))])
    q = Rotation.from_matrix(S[:, :3, :3]).as_quat()
    assert q[0] @ q[1] < -0.5  # the case the fix exists for
    u0, u1 = a0 / np.linalg.norm(a0), a1 / np.linalg.norm(a1)
    half = np.arctan2(np.sin(np.deg2rad(85.0)) * np.linalg.norm(u0 + u1) / 2, np.cos(np.deg2rad(85.0)))
    mid = _about_joint(np.rad2deg(2 * half), np.array([1.0, 0.0, -1.0]) / np.sqrt(2))
    np.testing.assert_allclose(dual_quaternion_skinning(V, W, S), V @ mid[:3, :3].T + mid[:3, 3], atol=1e-9)


def test_single_bone_weights_reproduce_the_rigid_motion():
    V = _elbow_points() + np.array([0.3, -0.2, 0.1])
    S = np.stack([_about_joint(40.0, (1.0, 0.0, 0.0)), _about_joint(-70.0, (0.0, 1.0, 0.0))])
    for b in range(2):
        W = np.zeros((len(V), 2))
        W[:, b] = 1.0
        rigid = V @ S[b, :3, :3].T + S[b, :3, 3]
        np.testing.assert_allclose(linear_blend_skinning(V, W, S), rigid, atol=1e-12)
        np.testing.assert_allclose(dual_quaternion_skinning(V, W, S), rigid, atol=1e-9)
