"""Helpers of ``benchmarks.muscle_owners`` (issue 11, pass 11): the truth's pieces moved into the capture's space."""

import numpy as np

from bodystudio.muscle.arm import ArmPose
from bodystudio.muscle.refine import posed_joints


def _pose(t, deg):
    root = np.eye(4)
    root[:3, 3] = t
    return ArmPose(root, np.stack([[0.0, 0.0, np.radians(deg)], [0.0, 0.0, np.radians(2 * deg)], np.zeros(3)]))


def test_with_shoulders_moves_each_root_so_the_posed_shoulder_lands_on_the_target():
    from benchmarks.muscle_owners import with_shoulders

    J = np.array([[0.2, 1.4, 0.0], [0.25, 1.1, 0.0], [0.3, 0.85, 0.02]])
    poses = [_pose([0.01, 0.0, 0.0], 10.0), _pose([0.0, -0.02, 0.01], 40.0)]
    targets = np.array([[0.3, 1.5, 0.1], [0.1, 1.3, -0.05]])
    out = with_shoulders(poses, J, targets)
    for p, q, t in zip(out, poses, targets, strict=True):
        np.testing.assert_allclose(posed_joints(J, p)[0], t, atol=1e-12)
        np.testing.assert_array_equal(p.angles, q.angles)  # the angles untouched
        np.testing.assert_allclose(p.root[:3, :3], q.root[:3, :3])


def test_the_truth_is_moved_into_the_template_space_by_the_inverse_similarity():
    from benchmarks.muscle_owners import truth_in_template_space

    S = (1.0, np.eye(3), np.array([0.1, -0.2, 0.9]))  # template -> world (the capture's default: a translation)
    poses = [_pose([0.0, 0.0, 0.0], 20.0)]
    gtJ = np.array([[[1.0, 2.0, 3.0], [1.1, 1.8, 3.0], [1.2, 1.6, 3.1]]])
    out, J = truth_in_template_space({"poses": poses, "gtJ": gtJ}, S)
    np.testing.assert_allclose(J, gtJ - S[2], atol=1e-12)
    np.testing.assert_allclose(out[0].root[:3, 3], -S[2], atol=1e-12)
    np.testing.assert_array_equal(out[0].angles, poses[0].angles)
