"""E_upright of the pose refinement (mir12ad, ``RefineWeights.pelvis_tilt_rad``, off by default): the pelvis's
forward lean off the vertical, a prior that keeps a stooping person's bend out of the pelvis.

A 2k MakeHuman body stands upright (its pelvis turned about the vertical only, as the synthetic studio's walks are),
turned 50 degrees from a 640x480 camera; the "IK" pose leans the root 6 degrees forward (about the body's own left
axis), and the Kinect joints agree with that wrong pose (so they hold it back). The refinement with E_upright must
take the lean nearer upright than without it, more so with a tighter scale; off, it must be the refinement as before
(bit for bit). ``pelvis_tilt`` / ``pelvis_lean`` themselves: 0 for a turn about the vertical, the tilt's rotation
vector for a tilt, the lean its part about the body's lateral axis, additive to first order in a world turn (what
the Gauss-Newton step assumes).
"""

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bodystudio.body import Phenotype, Pose, build_body
from bodystudio.body.skinning import forward_kinematics
from bodystudio.capture.motion import world_to_local_rotvecs
from bodystudio.geometry.camera import Camera
from bodystudio.geometry.mesh import vertex_normals
from bodystudio.mirror.refine import (
    PELVIS_TILT_RAD,
    RefineWeights,
    pelvis_lean,
    pelvis_tilt,
    refine_plan,
    refine_pose,
)
from bodystudio.mirror.track import posed_kinect_joints, skin_vertices


def test_pelvis_tilt_is_the_swing_off_the_vertical():
    yaw = Rotation.from_rotvec([0.0, 0.7, 0.0])
    assert np.allclose(pelvis_tilt(yaw.as_matrix()), 0.0, atol=1e-12)
    tilt = Rotation.from_rotvec([0.05, 0.0, -0.03])
    assert np.allclose(pelvis_tilt(tilt.as_matrix()), [0.05, 0.0, -0.03], atol=1e-12)
    # a tilt after a yaw (world axes): the yaw adds nothing
    assert np.allclose(pelvis_tilt((tilt * yaw).as_matrix()), [0.05, 0.0, -0.03], atol=1e-12)
    # first order: a small world turn w about x / z adds w to the tilt (the step's Jacobian is the identity there)
    base = Rotation.from_rotvec([0.04, 0.3, 0.02])
    w = np.array([1e-4, 0.0, -2e-4])
    moved = pelvis_tilt((Rotation.from_rotvec(w) * base).as_matrix()) - pelvis_tilt(base.as_matrix())
    assert np.allclose(moved[[0, 2]], w[[0, 2]], atol=2e-6)
    # the lean: about the body's own left axis (x at rest, turned by the yaw), a sideways tilt left out
    yawed = Rotation.from_rotvec([0.0, np.pi / 2, 0.0])  # the body's left now points along -z
    lean, axis = pelvis_lean((Rotation.from_rotvec([0.0, 0.0, -0.05]) * yawed).as_matrix())
    assert np.isclose(lean, 0.05) and np.allclose(axis, [0.0, 0.0, -1.0], atol=1e-12)
    lean, _ = pelvis_lean((Rotation.from_rotvec([0.05, 0.0, 0.0]) * yawed).as_matrix())
    assert abs(lean) < 1e-12


@pytest.fixture(scope="module")
def case():
    body = build_body(Phenotype(), resolution="2k")
    sk = body.skeleton
    world = np.zeros((sk.n_bones, 3))  # rotations in rest-world axes, as the synthetic studio's motions give them
    for arm, sign in (("upperarm_l", 1), ("upperarm_r", -1)):  # arms away from the torso
        world[sk.index(arm)] = Rotation.from_euler("z", sign * 0.5).as_rotvec()
    world[sk.index("pelvis")] = (0.0, np.radians(4.0), 0.0)  # the walk's turn of the pelvis about the vertical
    world[sk.index("Root")] = (0.0, np.radians(50.0), 0.0)  # turned from the camera
    rot = world_to_local_rotvecs(sk, world)
    true = Pose(rot, np.zeros(3))
    camera = Camera.look_at("kinect", eye=(1.2, 1.0, 2.4), target=(0.0, 0.95, 0.0), fx=525.0)
    V = skin_vertices(body.vertices, body.weights, sk, true)
    uv = camera.project(V)
    mask = np.zeros((camera.height, camera.width), np.uint8)
    for tri in np.round(uv[body.faces] * 16).astype(np.int32):
        cv2.fillConvexPoly(mask, tri, 1, lineType=cv2.LINE_8, shift=4)
    N = vertex_normals(V, body.faces)
    front = np.einsum("ij,ij->i", N, camera.center - V) > 0
    plan = refine_plan(body.vertices, body.faces, body.weights, sk)
    root = sk.index("Root")
    tilted = world.copy()
    left = Rotation.from_rotvec(world[root]).apply([1.0, 0.0, 0.0])  # the body's left, turned
    tilted[root] = (Rotation.from_rotvec(np.radians(6.0) * left) * Rotation.from_rotvec(world[root])).as_rotvec()
    ik = Pose(world_to_local_rotvecs(sk, tilted), np.zeros(3))
    joints = posed_kinect_joints(sk, ik)  # joints that agree with the tilted pose
    return body, plan, camera, true, ik, mask.astype(bool), V[front], joints


def _tilt_deg(skeleton, pose) -> float:
    G = forward_kinematics(skeleton, pose)[:, :3, :3]
    j = skeleton.index("pelvis")
    return float(np.degrees(abs(pelvis_lean(G[j] @ skeleton.rest_rotations[j].T)[0])))


def test_the_prior_takes_the_pelvis_nearer_upright(case):
    body, plan, camera, true, ik, mask, points, joints = case
    sk = body.skeleton
    assert _tilt_deg(sk, true) < 1e-6
    before = _tilt_deg(sk, ik)
    assert 5.9 < before < 6.1
    off = refine_pose(plan, sk, ik, camera, mask, joints, None, points, iterations=2)
    on = refine_pose(plan, sk, ik, camera, mask, joints, None, points, iterations=2,
                     weights=RefineWeights(pelvis_tilt_rad=PELVIS_TILT_RAD))
    t_off, t_on = _tilt_deg(sk, off), _tilt_deg(sk, on)
    assert t_on < 0.6 * t_off, (before, t_off, t_on)
    assert t_on < 0.5 * before, (before, t_off, t_on)
    # a tighter prior holds it nearer still
    tight = refine_pose(plan, sk, ik, camera, mask, joints, None, points, iterations=2,
                        weights=RefineWeights(pelvis_tilt_rad=PELVIS_TILT_RAD / 4))
    assert _tilt_deg(sk, tight) < t_on


def test_off_by_default_the_refinement_is_unchanged(case):
    body, plan, camera, true, ik, mask, points, joints = case
    sk = body.skeleton
    assert RefineWeights().pelvis_tilt_rad is None
    a = refine_pose(plan, sk, ik, camera, mask, joints, None, points)
    b = refine_pose(plan, sk, ik, camera, mask, joints, None, points, weights=RefineWeights(pelvis_tilt_rad=None))
    assert np.array_equal(a.rotations, b.rotations) and np.array_equal(a.translation, b.translation)
