"""Kinect joint maps: SDK joint counts and order, anatomy of the mapped joints, they follow the pose."""

import numpy as np
import pytest

from bodystudio.body import Pose, posed_joints
from bodystudio.body.kinect import kinect_joint_names, kinect_joints
from bodystudio.errors import InputError


@pytest.mark.parametrize("version, count, first, last", [("v1", 20, "HipCenter", "FootRight"),
                                                         ("v2", 25, "SpineBase", "ThumbRight")])
def test_joint_sets_follow_the_sdk_order(version, count, first, last):
    names = kinect_joint_names(version)
    assert len(names) == count and names[0] == first and names[-1] == last
    assert names[4:20] == kinect_joint_names("v1")[4:20]  # limbs share SDK indices 4..19


def test_mapped_joints_are_anatomical(default_body):
    sk = default_body.skeleton
    J = dict(zip(kinect_joint_names("v2"), kinect_joints(sk, sk.heads, sk.tails, "v2"), strict=True))
    assert J["Head"][1] > J["Neck"][1] > J["SpineMid"][1] > J["SpineBase"][1] > J["KneeLeft"][1] > J["FootLeft"][1]
    assert J["ShoulderLeft"][0] > 0.1 > -0.1 > J["ShoulderRight"][0]  # the person's left is +x
    assert 0.2 < np.linalg.norm(J["ElbowLeft"] - J["ShoulderLeft"]) < 0.4


def test_joints_follow_the_pose(default_body):
    sk = default_body.skeleton
    rotations = np.zeros((sk.n_bones, 3))
    rotations[sk.index("lowerarm_r")] = [1.2, 0, 0]
    heads, tails = posed_joints(sk, Pose(rotations, [0.0, 0.0, 0.5]))
    rest = kinect_joints(sk, sk.heads, sk.tails, "v1")
    posed = kinect_joints(sk, heads, tails, "v1")
    names = kinect_joint_names("v1")
    moved = np.linalg.norm(posed - rest - [0, 0, 0.5], axis=1)
    assert moved[names.index("WristRight")] > 0.1
    assert moved[names.index("WristLeft")] < 1e-9 and moved[names.index("ElbowRight")] < 1e-9


def test_unknown_version_is_a_user_error(default_body):
    with pytest.raises(InputError, match="valid: v1, v2"):
        kinect_joint_names("v3")
