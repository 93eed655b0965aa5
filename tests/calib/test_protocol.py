"""The synthetic calibration protocol's pose plan and the floor plane fitted over all floor boards."""

import cv2
import numpy as np

from bodystudio.calib.board import CharucoBoardSpec, board_corners
from bodystudio.calib.calibrate import floor_plane_board_pose
from bodystudio.calib.synthetic import (
    board_for_resolution,
    calibration_board_poses,
    floor_board_pose,
    visible_corners,
)
from bodystudio.calib.world import floor_board_to_world, rigid, rotation_angle_deg
from bodystudio.geometry.camera import ring_rig


def _tilted(T, axis, deg):
    R = cv2.Rodrigues(np.asarray(axis, float) / np.linalg.norm(axis) * np.radians(deg))[0]
    return rigid(R @ T[:3, :3], T[:3, 3])


def test_floor_plane_alone_is_the_floor_board():
    spec = CharucoBoardSpec()
    boards = np.array([_tilted(floor_board_to_world(spec), [1, 0, 0.3], 0.4),
                       rigid(np.eye(3), [0.0, 1.0, 0.0])])  # an upright board in the air
    T, frames = floor_plane_board_pose(spec, boards, 0)
    assert frames == [0]
    np.testing.assert_allclose(T, boards[0], atol=1e-12)


def test_floor_plane_fit_corrects_a_tilted_floor_board():
    spec = CharucoBoardSpec()
    truth = floor_board_to_world(spec)
    others = [floor_board_pose(spec, [1.2 * np.sin(a), 0, 1.2 * np.cos(a)], a) for a in (0.3, 2.4, 4.5)]
    tilted = _tilted(truth, [1, 0, 0.5], 0.3)  # the floor board's own pose is off by 0.3 deg
    boards = np.array([tilted, *others, rigid(np.eye(3), [0.0, 1.0, 0.0]), np.full((4, 4), np.nan)])
    T, frames = floor_plane_board_pose(spec, boards, 0)
    assert frames == [0, 1, 2, 3]
    # The plane comes from all four boards: its normal is far closer to the truth than the floor board's.
    n_err = np.degrees(np.arccos(np.clip(T[:3, 2] @ truth[:3, 2], -1, 1)))
    assert n_err < 0.1 < np.degrees(np.arccos(np.clip(tilted[:3, 2] @ truth[:3, 2], -1, 1)))
    # Origin and x axis still come from the floor board: its centre lies on the fitted plane's normal line.
    c_t = tilted[:3, :3] @ spec.center_m + tilted[:3, 3]
    c_f = T[:3, :3] @ spec.center_m + T[:3, 3]
    np.testing.assert_allclose(np.cross(c_t - c_f, T[:3, 2]), 0, atol=1e-12)
    assert rotation_angle_deg(T[:3, :3] @ tilted[:3, :3].T) < 0.31
    # Exact floor boards give the floor board back.
    T, _ = floor_plane_board_pose(spec, np.array([truth, *others]), 0)
    np.testing.assert_allclose(T, truth, atol=1e-12)


def test_pose_plan_covers_every_camera_with_tilted_boards():
    spec = board_for_resolution(1280)
    rig = ring_rig(10, width=1280, height=960)
    poses = calibration_board_poses(rig, spec, 30, np.random.default_rng(0))
    assert poses.shape == (30, 4, 4)
    np.testing.assert_allclose(poses[0], floor_board_to_world(spec), atol=1e-12)
    # Frames 1-3 lie on the floor too (printed side up, y = 0).
    corners = board_corners(spec)
    for T in poses[1:4]:
        np.testing.assert_allclose((corners @ T[:3, :3].T + T[:3, 3])[:, 1], 0, atol=1e-12)
        np.testing.assert_allclose(T[:3, 2], [0, -1, 0], atol=1e-12)
    held = poses[4:]
    for cam in rig:
        cells = np.zeros((3, 3), int)
        n_views = 0
        for T in poses:
            vis = visible_corners(cam, spec, T)
            if vis.sum() < 6:
                continue
            n_views += 1
            uv = cam.project(corners[vis] @ T[:3, :3].T + T[:3, 3])
            np.add.at(cells, (np.clip((3 * uv[:, 1] / cam.height).astype(int), 0, 2),
                              np.clip((3 * uv[:, 0] / cam.width).astype(int), 0, 2)), 1)
        assert n_views >= 8, cam.name
        assert (cells > 0).all(), (cam.name, cells)  # the image corners are covered too
    # Held boards are strongly tilted to the cameras that see them: most views are 25-75 deg oblique.
    angles = []
    for T in held:
        for cam in rig:
            if visible_corners(cam, spec, T).sum() >= 6:
                c = T[:3, :3] @ spec.center_m + T[:3, 3]
                to_cam = (cam.center - c) / np.linalg.norm(cam.center - c)
                angles.append(np.degrees(np.arccos(to_cam @ -T[:3, 2])))
    assert np.median(angles) > 25
