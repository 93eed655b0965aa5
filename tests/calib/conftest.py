"""Small synthetic calibration problems shared by the calib tests (module-scoped: the BA runs once)."""

import numpy as np
import pytest

from bodystudio.calib.board import CharucoBoardSpec
from bodystudio.calib.synthetic import calibration_board_poses, synthetic_charuco_observations
from bodystudio.geometry.camera import ring_rig

NOISE_PX = 0.2


@pytest.fixture(scope="session")
def small_capture():
    """4 cameras, 10 board poses (frame 0 on the floor), 640x480, 0.2 px Gaussian corner noise."""
    spec = CharucoBoardSpec()
    rig = ring_rig(4, width=640, height=480)
    rng = np.random.default_rng(1)
    poses = calibration_board_poses(rig, spec, 10, rng)
    obs = synthetic_charuco_observations(rig, spec, poses, NOISE_PX, rng)
    return spec, rig, poses, obs


@pytest.fixture(scope="session")
def small_calibration(small_capture):
    from bodystudio.calib.calibrate import calibrate_cameras

    spec, rig, poses, obs = small_capture
    return calibrate_cameras(obs, spec)
