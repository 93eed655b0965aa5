"""Fixtures of the mirror tests: the 6k statistical model and small synthetic Kinect scenes (tests/mirror/scene.py)."""

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))


@pytest.fixture(scope="session")
def model_6k():
    from bodystudio.body.statistical import load_statistical_model

    return load_statistical_model("6k", progress=False)


@pytest.fixture(scope="session")
def walk_scene():
    """Subject 13 walking (14 cm taller, 20 kg heavier than the mean shape), 6 frames (every 6th of a
    36-frame walk), Kinect v2 depth noise and tracker noise."""
    from tests.mirror.scene import synthetic_scene

    return synthetic_scene(13, n_frames=6, motion="walk", frame_stride=6, seed=3)
