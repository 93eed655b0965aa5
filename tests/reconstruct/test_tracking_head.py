"""The tracker's head segment (TrackParams.head_weight, issue 15's neck): a head pitch carried from the
previous frame is pulled back to this frame's tracker joints."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bodystudio.body.kinect import kinect_joint_names
from bodystudio.errors import InputError
from bodystudio.reconstruct.pose_init import initialise_pose, pose_template
from bodystudio.reconstruct.tracking import SilhouetteFields, TrackParams, track_bone_transforms

NAMES = kinect_joint_names("v2")


def _pitched_head(joints: np.ndarray, angle_rad: float) -> np.ndarray:
    """The tracker joints with the Head joint turned about the Neck (the head nodding forwards)."""
    J = joints.copy()
    neck, head = NAMES.index("Neck"), NAMES.index("Head")
    R = Rotation.from_rotvec([angle_rad, 0.0, 0.0]).as_matrix()
    J[head] = (J[head] - J[neck]) @ R.T + J[neck]
    return J


def _head_error_mm(body, T, scale, truth) -> float:
    J = pose_template(body, T, scale).joints
    return float(1000 * np.linalg.norm(J[NAMES.index("Head")] - truth[NAMES.index("Head")]))


@pytest.fixture(scope="module")
def carried_pitch(body_2k, synthetic_capture):
    cap = synthetic_capture
    fields = SilhouetteFields(cap["rig"], cap["masks"])
    previous = initialise_pose(body_2k, _pitched_head(cap["joints"], 0.3))  # the previous frame's head pitch
    now = initialise_pose(body_2k, cap["joints"])  # this frame's tracker joints (here exact)
    return cap, fields, previous, now


def test_head_weight_pulls_a_carried_head_pitch_back(body_2k, carried_pitch):
    cap, fields, previous, now = carried_pitch
    before = _head_error_mm(body_2k, previous.bone_transforms, previous.global_scale, cap["joints"])
    off = track_bone_transforms(body_2k, previous.bone_transforms, fields, TrackParams(),
                                now.bone_transforms)
    on = track_bone_transforms(body_2k, previous.bone_transforms, fields, TrackParams(head_weight=100.0),
                               now.bone_transforms)
    e_off = _head_error_mm(body_2k, off, previous.global_scale, cap["joints"])
    e_on = _head_error_mm(body_2k, on, previous.global_scale, cap["joints"])
    # Measured (4 cameras, 2.5K): a 0.3 rad pitch puts the Head joint 51.0 mm off; the tracker without the
    # head segment (only the neck's rotation) leaves 20.5 mm, head_weight 10 / 100 / 1000 11.2 / 4.4 / 2.4 mm
    # (0.6 rad: 100.8 -> 26.8 without, 5.6 mm with 100).
    assert before > 45.0
    assert e_off > 15.0
    assert e_on < 6.5 < 0.35 * e_off


def test_head_weight_needs_the_joint_transforms(body_2k, carried_pitch):
    """Without this frame's joints there is nothing to pull towards: the fit equals the default's."""
    cap, fields, previous, _ = carried_pitch
    a = track_bone_transforms(body_2k, previous.bone_transforms, fields, TrackParams())
    b = track_bone_transforms(body_2k, previous.bone_transforms, fields, TrackParams(head_weight=100.0))
    np.testing.assert_array_equal(a, b)


def test_head_weight_out_of_range():
    with pytest.raises(InputError, match="head_weight"):
        TrackParams(head_weight=-1.0)
