"""MIR12h's plan entries for the twist bones and the step's pieces that the fast-vs-reference comparison shares
(``refine.refine_plan(twist_bones=...)``, ``_RefinePlan.n_twist``; issue 17, mutation testing; branch mutP). The
refinement's own lines (the root's pivot, the twist columns, the one-pass projection) are pinned against the reference
implementation by tests/mirror/test_refine_root_pivot_twist_analytic.py; these pin what both read."""

import numpy as np
import pytest

from bodystudio.errors import InputError
from bodystudio.geometry.camera import Camera
from bodystudio.mirror import refine as rf
from bodystudio.mirror.track import posed_kinect_joints
from tests.mirror.test_pose_refine_mutants import body  # noqa: F401  (the 2k body, built once)
from tests.mirror.test_refine_root_pivot_twist_analytic import _tilted_about_the_pelvis, case  # noqa: F401


def test_the_twist_bones_are_the_plans_last_entries_and_counted(body):  # noqa: F811
    sk = body.skeleton
    names = list(sk.bone_names)
    plain = rf.refine_plan(body.vertices, body.faces, body.weights, sk)
    assert plain.n_twist == 0
    twist = rf.refine_plan(body.vertices, body.faces, body.weights, sk, twist_bones=rf.TWIST_BONES)
    assert twist.n_twist == 2
    assert list(twist.bones) == list(plain.bones) + [names.index(b) for b in rf.TWIST_BONES]
    # a twist entry moves what its bone's swing entry moves: the same subtree, the same Kinect joints
    S = len(plain.bones)
    for k, b in enumerate(rf.TWIST_BONES):
        c = list(plain.bones).index(names.index(b))
        np.testing.assert_allclose(twist.subtree_weight[:, S + k], plain.subtree_weight[:, c], rtol=0, atol=1e-12)
        np.testing.assert_array_equal(twist.joint_moves[:, S + k], plain.joint_moves[:, c])
    np.testing.assert_array_equal(twist.subtree_weight[:, :S], plain.subtree_weight)
    np.testing.assert_allclose(twist.rest_inverse, np.linalg.inv(sk.rest_frames), rtol=0, atol=1e-12)
    few = rf.refine_plan(body.vertices, body.faces, body.weights, sk, swing_bones=("thigh_l",), twist_bones=("calf_l",))
    assert list(few.bones) == [names.index("Root"), names.index("thigh_l"), names.index("calf_l")]
    assert few.n_twist == 1


def test_a_rig_without_a_twist_bone_is_a_one_line_error_naming_it(body):  # noqa: F811
    with pytest.raises(InputError, match=r"^pose refinement needs the game_engine rig; bone 'no_twist' is missing$"):
        rf.refine_plan(body.vertices, body.faces, body.weights, body.skeleton, twist_bones=("spine_01", "no_twist"))


def test_a_distorted_camera_gives_the_reference_pose(case):  # noqa: F811
    """The one-pass projection gets the lens's coefficients when the camera has them (MIR12h): the fast refinement
    with the run's twist entries equals the reference implementation's (which projects with the camera's own
    distortion), and differs from the same refinement seen through the undistorted lens."""
    from refine_reference import refine_pose_reference

    body_, plans, camera, true, _, mask, points = case
    sk = body_.skeleton
    lens = Camera(camera.name, camera.K, np.array([0.08, -0.2, 0.002, -0.001, 0.05]), camera.R, camera.t,
                  camera.width, camera.height)
    assert lens.has_distortion and not camera.has_distortion
    ik = _tilted_about_the_pelvis(sk, true, np.radians([3.0, 6.0, 4.0]))
    args = dict(kinect_positions=posed_kinect_joints(sk, true), depth_points=points, iterations=2)
    fast = rf.refine_pose(plans[rf.TWIST_BONES], sk, ik, lens, mask, **args)
    reference = refine_pose_reference(plans[rf.TWIST_BONES], sk, ik, lens, mask, **args)
    np.testing.assert_allclose(fast.rotations, reference.rotations, atol=1e-6)
    np.testing.assert_allclose(fast.translation, reference.translation, atol=1e-6)
    plain = rf.refine_pose(plans[rf.TWIST_BONES], sk, ik, camera, mask, **args)
    assert np.abs(plain.translation - fast.translation).max() > 1e-4
