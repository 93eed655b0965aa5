"""MIR12h's pose refinement changes on a synthetic case: the root turned about the body's centroid, the spine's twist.

A 2k MakeHuman body in a known pose seen by a 640x480 camera 2.6 m away (its filled silhouette, its front-facing
vertices as depth points, its Kinect joints), as in test_pose_refine_analytic.py. Planted IK errors:

* the root tilted 5 degrees about the pelvis toward the camera (the Root bone's head is on the floor, so the root's
  translation is off by ~8 cm): one step turned about the centroid takes more of it out than one about the floor;
* the pelvis yawed 10 degrees with the shoulders right (the root yawed, spine_01 twisted back, as the IK does when
  the hip joints are off): without the spine's twist the root can only turn both together; with it the yaw goes.
"""

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bodystudio.body import Phenotype, Pose, build_body
from bodystudio.body.skinning import forward_kinematics, posed_joints
from bodystudio.geometry.camera import Camera
from bodystudio.geometry.mesh import vertex_normals
from bodystudio.mirror import refine as refine_module
from bodystudio.mirror.refine import TWIST_BONES, refine_plan, refine_pose
from bodystudio.mirror.track import posed_kinect_joints, skin_vertices


@pytest.fixture(scope="module")
def case():
    body = build_body(Phenotype(), resolution="2k")
    sk = body.skeleton
    rng = np.random.default_rng(4)
    rot = rng.normal(0, 0.05, (sk.n_bones, 3))
    for arm, sign in (("upperarm_l", 1), ("upperarm_r", -1)):  # arms away from the torso
        rot[sk.index(arm)] = Rotation.from_euler("z", sign * 0.5).as_rotvec()
    true = Pose(rot, np.zeros(3))
    camera = Camera.look_at("kinect", eye=(0.3, 1.0, 2.6), target=(0.0, 0.95, 0.0), fx=525.0)
    V = skin_vertices(body.vertices, body.weights, sk, true)
    uv = camera.project(V)
    mask = np.zeros((camera.height, camera.width), np.uint8)
    for tri in np.round(uv[body.faces] * 16).astype(np.int32):  # one by one: fillPoly's even-odd rule leaves holes
        cv2.fillConvexPoly(mask, tri, 1, lineType=cv2.LINE_8, shift=4)
    N = vertex_normals(V, body.faces)
    front = np.einsum("ij,ij->i", N, camera.center - V) > 0
    plans = {twist: refine_plan(body.vertices, body.faces, body.weights, sk, twist_bones=twist)
             for twist in ((), TWIST_BONES)}
    return body, plans, camera, true, V, mask.astype(bool), V[front]


def _vertex_err_mm(body, pose, V_true):
    V = skin_vertices(body.vertices, body.weights, body.skeleton, pose)
    return 1e3 * np.linalg.norm(V - V_true, axis=1).mean()


def _world_rotation(sk, pose, bone):
    return forward_kinematics(sk, pose)[sk.index(bone), :3, :3] @ sk.rest_rotations[sk.index(bone)].T


def _tilted_about_the_pelvis(sk, pose, rotvec):
    """``pose`` with the root turned by ``rotvec`` (world axes) about the posed pelvis head."""
    root = sk.index("Root")
    pelvis = posed_joints(sk, pose)[0][sk.index("pelvis")]
    turn = Rotation.from_rotvec(rotvec)
    rot = pose.rotations.copy()
    W = turn.as_matrix() @ _world_rotation(sk, pose, "Root")
    rot[root] = Rotation.from_matrix(sk.rest_rotations[root].T @ W @ sk.rest_rotations[root]).as_rotvec()
    head = sk.heads[root] + pose.translation
    return Pose(rot, pose.translation + turn.apply(head - pelvis) + pelvis - head)


def _refined(case, ik, twist=(), pivot="centroid", **kw):
    body, plans, camera, true, _, mask, points = case
    joints = posed_kinect_joints(body.skeleton, true)
    original = refine_module.ROOT_PIVOT
    refine_module.ROOT_PIVOT = pivot
    try:
        return refine_pose(plans[twist], body.skeleton, ik, camera, mask, joints, None, points, **kw)
    finally:
        refine_module.ROOT_PIVOT = original


def test_the_run_turns_the_root_about_the_centroid_and_refines_the_spine_twist():
    assert refine_module.ROOT_PIVOT == "centroid"
    assert TWIST_BONES == ("spine_01", "spine_02")


def test_a_root_tilt_is_taken_out_further_in_one_step_about_the_centroid(case):
    body, plans, camera, true, V_true, *_ = case
    sk = body.skeleton
    ik = _tilted_about_the_pelvis(sk, true, np.radians([5.0, 0.0, 0.0]))  # a lean toward the camera
    root_offset_mm = 1e3 * np.linalg.norm(ik.translation - true.translation)
    assert root_offset_mm > 60.0  # the pelvis stays: the floor point moves
    before = _vertex_err_mm(body, ik, V_true)
    centroid = _vertex_err_mm(body, _refined(case, ik), V_true)
    head = _vertex_err_mm(body, _refined(case, ik, pivot="head"), V_true)
    # measured 40.9 -> 9.6 (centroid) and 13.3 mm (head): about the floor the first-order turn also shrinks the
    # body toward the floor; a translation that did not make up for the pivot would leave centimetres
    assert centroid < 0.25 * before, (before, centroid, head)
    assert centroid < 0.8 * head, (before, centroid, head)


def test_the_pelvis_yaw_under_right_shoulders_needs_the_spine_twist(case):
    body, plans, camera, true, V_true, *_ = case
    sk = body.skeleton
    yaw = np.radians(10.0)
    ik = _tilted_about_the_pelvis(sk, true, [0.0, yaw, 0.0])
    # spine_01 twisted back about its own axis: the upper body stays where it is, the pelvis and legs are yawed
    j = sk.index("spine_01")
    d = _world_rotation(sk, ik, "spine_01") @ sk.rest_rotations[j][:, 1]
    W_spine = Rotation.from_rotvec(-yaw * np.array([0.0, 1.0, 0.0])).as_matrix() @ _world_rotation(sk, ik, "spine_01")
    W_parent = _world_rotation(sk, ik, "pelvis")
    rot = ik.rotations.copy()
    rot[j] = Rotation.from_matrix(sk.rest_rotations[j].T @ W_parent.T @ W_spine @ sk.rest_rotations[j]).as_rotvec()
    ik = Pose(rot, ik.translation)
    assert abs(d[1]) > 0.95  # spine_01 is near vertical: its twist is the upper body's yaw

    def yaw_err_deg(pose):
        E = _world_rotation(sk, pose, "Root") @ _world_rotation(sk, true, "Root").T
        return abs(np.degrees(Rotation.from_matrix(E).as_rotvec()[1]))

    before = _vertex_err_mm(body, ik, V_true)
    without = _refined(case, ik, twist=(), iterations=3)
    with_twist = _refined(case, ik, twist=TWIST_BONES, iterations=3)
    err_without, err_with = _vertex_err_mm(body, without, V_true), _vertex_err_mm(body, with_twist, V_true)
    assert yaw_err_deg(ik) > 9.0
    assert yaw_err_deg(with_twist) < 2.0 < 0.5 * yaw_err_deg(without), (yaw_err_deg(with_twist),
                                                                         yaw_err_deg(without))
    # measured 14.4 mm before, 7.5 without the twist, 5.1 with it
    assert err_with < 0.75 * err_without < 0.6 * before, (before, err_without, err_with)


def test_the_twist_entries_turn_the_bone_about_itself(case):
    """A twist entry's column turns its bone about the bone (the direction stays), and a bone listed for its
    swing and its twist turns by both."""
    body, plans, camera, true, *_ = case
    sk = body.skeleton
    plan = plans[TWIST_BONES]
    M, _ = refine_module._forward_kinematics(plan, sk.parents, true)
    world, heads, axes = refine_module._bone_frames(M, np.ascontiguousarray(sk.rest_rotations), plan.bones)
    n_swing = len(plan.bones) - 1 - plan.n_twist
    for k in range(n_swing, len(plan.bones) - 1):
        axes[k, 0] = M[plan.bones[k + 1], :3, 1]
        axes[k, 1] = 0.0
    k_twist = n_swing + TWIST_BONES.index("spine_02")
    k_swing = list(plan.bones[1:]).index(sk.index("spine_02"))
    j = sk.index("spine_02")
    for deltas, twist_deg in (({6 + 2 * k_twist: np.radians(5.0)}, 5.0),
                              ({6 + 2 * k_twist: np.radians(5.0), 6 + 2 * k_swing: np.radians(3.0)}, 5.0)):
        delta = np.zeros(6 + 2 * (len(plan.bones) - 1))
        for c, v in deltas.items():
            delta[c] = v
        turned = refine_module.apply_update(sk, true, delta, plan.bones, axes, world)
        W0, W1 = _world_rotation(sk, true, "spine_02"), _world_rotation(sk, turned, "spine_02")
        turn = Rotation.from_matrix(W1 @ W0.T).as_rotvec()
        d = M[j, :3, 1]
        assert np.degrees(turn @ d) == pytest.approx(twist_deg, abs=0.05)
        swing = turn - (turn @ d) * d
        assert np.degrees(np.linalg.norm(swing)) == pytest.approx(3.0 if len(deltas) > 1 else 0.0, abs=0.05)


def test_the_fast_refinement_with_twist_entries_gives_the_reference_pose(case):
    from refine_reference import refine_pose_reference

    body, plans, camera, true, V_true, mask, points = case
    sk = body.skeleton
    ik = _tilted_about_the_pelvis(sk, true, np.radians([3.0, 6.0, 4.0]))
    joints = posed_kinect_joints(sk, true) + np.random.default_rng(7).normal(0, 0.015, (25, 3))
    args = dict(kinect_positions=joints, depth_points=points, iterations=2)
    fast = refine_pose(plans[TWIST_BONES], sk, ik, camera, mask, **args)
    reference = refine_pose_reference(plans[TWIST_BONES], sk, ik, camera, mask, **args)
    assert np.abs(reference.translation - ik.translation).max() > 1e-3  # the case exercises the step
    np.testing.assert_allclose(fast.rotations, reference.rotations, atol=1e-6)
    np.testing.assert_allclose(fast.translation, reference.translation, atol=1e-6)


def test_the_one_pass_projection_is_the_cameras():
    """``refine._project_body`` (MIR12h: the projection, the window and rim tests in one numba pass) against
    ``Camera.project_with_depth`` and numpy's tests, with lens distortion and points behind the camera."""
    rng = np.random.default_rng(3)
    camera = Camera.look_at("kinect", eye=(0.3, 1.0, 2.6), target=(0.0, 0.95, 0.0), fx=525.0)
    camera = Camera(camera.name, camera.K, np.array([0.08, -0.2, 0.002, -0.001, 0.05]), camera.R, camera.t,
                    camera.width, camera.height)
    V = np.r_[rng.normal([0.0, 1.0, 0.0], [0.6, 0.6, 0.3], (400, 3)), [[0.3, 1.0, 3.5], [0.3, 1.0, 2.6001]]]
    N = rng.normal(size=V.shape)
    N /= np.linalg.norm(N, axis=1, keepdims=True)
    origin, dist_shape = np.array([150.0, 60.0]), np.array([300.0, 350.0])
    Pc, uv, local, in_box, rim, cos = refine_module._project_body(
        V, N, camera.R, camera.t, camera.K, np.asarray(camera.dist, float), camera.has_distortion, camera.center,
        camera.width, camera.height, origin, dist_shape, 0.3)
    uv_ref, z = camera.project_with_depth(V)
    np.testing.assert_allclose(Pc, V @ camera.R.T + camera.t, atol=1e-12)
    np.testing.assert_allclose(uv, uv_ref, atol=1e-9)
    assert np.isnan(uv[-2:]).all() and z[-2] < 0  # behind the camera: no pixel, in no window
    with np.errstate(invalid="ignore"):
        ok = (uv_ref[:, 0] >= 0) & (uv_ref[:, 0] <= camera.width - 1) & (uv_ref[:, 1] >= 0) \
            & (uv_ref[:, 1] <= camera.height - 1)
        lo = uv_ref - origin
        box = ok & (lo[:, 0] >= 1) & (lo[:, 1] >= 1) & (lo[:, 0] < dist_shape[0] - 2) & (lo[:, 1] < dist_shape[1] - 2)
    ray = V - camera.center
    cos_ref = np.einsum("ij,ij->i", N, ray) / np.linalg.norm(ray, axis=1)
    np.testing.assert_allclose(cos, cos_ref, atol=1e-12)
    np.testing.assert_array_equal(in_box, box)
    np.testing.assert_array_equal(rim, ok & (np.abs(cos_ref) < 0.3))
    assert 50 < box.sum() < ok.sum() < len(V) - 2 and 0 < rim.sum() < ok.sum()  # every test is exercised
