"""Kinect depth<->colour and Kinect<->studio extrinsics from boards seen in colour and depth."""

import numpy as np
import pytest

from bodystudio.calib.board import CharucoBoardSpec
from bodystudio.calib.depth import (
    calibrate_rgbd_sensor,
    fit_plane_ransac,
    rgbd_board_poses,
    synthetic_rgbd_views,
)
from bodystudio.calib.world import rotation_angle_deg
from bodystudio.errors import SessionError
from bodystudio.geometry.camera import kinect_v2


def test_ransac_plane_ignores_outliers():
    rng = np.random.default_rng(0)
    n = np.array([0.2, -0.3, -1.0])
    n /= np.linalg.norm(n)
    uv = rng.uniform(-0.5, 0.5, (800, 2))
    basis = np.linalg.svd(n[None])[2][1:]
    pts = uv @ basis - 2.0 * n + rng.normal(0, 0.003, (800, 1)) * n
    pts[:200] += rng.uniform(0.1, 1.0, (200, 1)) * n  # background behind / flying pixels
    n_fit, d_fit, inliers = fit_plane_ransac(pts, 0.01, rng)
    assert np.degrees(np.arccos(abs(n_fit @ n))) < 0.5
    assert abs(d_fit - 2.0) < 0.003
    assert inliers[200:].mean() > 0.95 and inliers[:200].mean() < 0.1


def test_kinect_extrinsics_from_board_planes():
    spec = CharucoBoardSpec()
    sensor = kinect_v2()
    rng = np.random.default_rng(2)
    poses = rgbd_board_poses(sensor, spec, 6, rng)
    views = synthetic_rgbd_views(sensor, spec, poses, 0.2, rng)
    est, report = calibrate_rgbd_sensor(sensor, spec, views, list(poses), rng)
    D, G = est.depth_to_color, sensor.depth_to_color
    assert 1000 * np.linalg.norm(D[:3, 3] - G[:3, 3]) < 3.0
    assert rotation_angle_deg(D[:3, :3] @ G[:3, :3].T) < 0.5
    # Kinect in the studio frame: colour and depth cameras where they really are.
    assert 1000 * np.linalg.norm(est.color.center - sensor.color.center) < 2.0
    assert 1000 * np.linalg.norm(est.depth.center - sensor.depth.center) < 4.0
    assert report["corner_to_plane_rms_mm"] < 2.0
    with pytest.raises(SessionError, match="at least 3 board poses"):
        calibrate_rgbd_sensor(sensor, spec, views[:2])
