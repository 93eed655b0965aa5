"""E_trunk acts on the trunk bones the refinement plan swings, and on nothing else (MIR12g; issue 17, branch mutI).

A plan that swings only the limbs has no trunk bone to hold: the default weights (E_trunk on) give exactly the pose
of ``trunk_rad=None``; a plan that also swings spine_01 has it held (the two differ). Built on the 2k body, one
Gauss-Newton step each; about a second."""
import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from bodystudio.body import Pose
from bodystudio.geometry.camera import Camera
from bodystudio.mirror.refine import RefineWeights, refine_plan, refine_pose
from bodystudio.mirror.track import posed_kinect_joints, skin_vertices

LIMBS = ("upperarm_l", "upperarm_r", "lowerarm_l", "lowerarm_r", "thigh_l", "thigh_r", "calf_l", "calf_r")


def _trunk_scene(body):
    sk = body.skeleton
    true = Pose(np.zeros((sk.n_bones, 3)), np.zeros(3))
    camera = Camera.look_at("kinect", eye=(0.3, 1.0, 2.6), target=(0.0, 0.95, 0.0), fx=525.0)
    V = skin_vertices(body.vertices, body.weights, sk, true)
    mask = np.zeros((camera.height, camera.width), np.uint8)
    for tri in np.round(camera.project(V)[body.faces] * 16).astype(np.int32):
        cv2.fillConvexPoly(mask, tri, 1, lineType=cv2.LINE_8, shift=4)
    rot = true.rotations.copy()
    rot[sk.index("spine_01")] = Rotation.from_euler("x", 9.0, degrees=True).as_rotvec()
    rot[sk.index("upperarm_l")] = Rotation.from_euler("z", 0.2).as_rotvec()
    ik = Pose(rot, np.zeros(3))
    return camera, mask.astype(bool), ik, posed_kinect_joints(sk, ik)


def test_the_trunk_prior_holds_only_the_trunk_bones_the_plan_swings(body_2k):
    body = body_2k
    sk = body.skeleton
    camera, mask, ik, joints = _trunk_scene(body)
    for bones, acts in ((LIMBS, False), (("spine_01", *LIMBS), True)):
        plan = refine_plan(body.vertices, body.faces, body.weights, sk, swing_bones=bones)
        on = refine_pose(plan, sk, ik, camera, mask, joints)
        off = refine_pose(plan, sk, ik, camera, mask, joints, weights=RefineWeights(trunk_rad=None))
        moved = np.abs(on.rotations - off.rotations).max()
        assert (moved > 1e-3) == acts, (bones, moved)
        if not acts:
            np.testing.assert_array_equal(on.rotations, off.rotations)
            np.testing.assert_array_equal(on.translation, off.translation)
