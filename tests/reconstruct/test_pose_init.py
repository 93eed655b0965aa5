"""Pose and size initialisation from tracker joints (Rapid Skin §IV.A, Eq. 11-12)."""

import numpy as np
import pytest

from bodystudio.errors import InputError
from bodystudio.reconstruct.evaluate import joint_error_mm, point_to_surface_mm
from bodystudio.reconstruct.pose_init import initialise_pose, similarity_transform


def test_similarity_transform_recovers_a_known_one():
    rng = np.random.default_rng(0)
    P = rng.normal(size=(10, 3))
    from scipy.spatial.transform import Rotation

    R = Rotation.from_rotvec([0.3, -0.5, 0.2]).as_matrix()
    Q = 1.15 * P @ R.T + [0.1, 0.2, -0.3]
    T = similarity_transform(P, Q)
    assert np.allclose(P @ T[:3, :3].T + T[:3, 3], Q, atol=1e-12)


def test_initialisation_lands_on_the_joints(body_2k, synthetic_capture):
    cap = synthetic_capture
    init = initialise_pose(body_2k, cap["joints"])
    # every chain end is placed on its tracked joint (the torso is a least-squares fit)
    assert joint_error_mm(init.joints, cap["joints"]) < 15.0
    limb_ends = [5, 6, 9, 10, 13, 14, 17, 18]  # elbows, wrists, knees, ankles (Kinect v2 order)
    assert np.max(np.linalg.norm(init.joints[limb_ends] - cap["joints"][limb_ends], axis=1)) < 0.005
    # the posed template is close to the subject's surface, far closer than the rest pose
    d_init = np.median(point_to_surface_mm(init.vertices, cap["V"], cap["F"]))
    d_rest = np.median(point_to_surface_mm(body_2k.vertices, cap["V"], cap["F"]))
    assert d_init < 20.0 and d_init < 0.3 * d_rest


def test_untracked_joints(body_2k, synthetic_capture):
    J = synthetic_capture["joints"].copy()
    J[[5, 6]] = np.nan  # left elbow and wrist lost: the forearm follows the shoulder
    init = initialise_pose(body_2k, J)
    assert np.all(np.isfinite(init.vertices))
    with pytest.raises(InputError, match="no valid joints"):
        initialise_pose(body_2k, np.full_like(J, np.nan))
    with pytest.raises(InputError, match="25 Kinect v2 joints"):
        initialise_pose(body_2k, J[:10])
