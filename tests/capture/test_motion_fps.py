"""Motions sampled at a frame rate (issue 12): natural speed, independent of the number of frames."""

import numpy as np
import pytest

from bodystudio.capture.motion import MOTION_PERIOD_S, motion_sequence
from bodystudio.errors import InputError


@pytest.fixture(scope="module")
def skeleton(body_2k):
    return body_2k.skeleton


@pytest.mark.parametrize("name", ["walk", "arms_raise"])
def test_fps_sampling_does_not_stretch_over_the_frame_count(skeleton, name):
    short = motion_sequence(name, 10, skeleton, seed=3, fps=30.0)
    long = motion_sequence(name, 100, skeleton, seed=3, fps=30.0)
    for a, b in zip(short, long[:10], strict=True):
        np.testing.assert_allclose(a.rotations, b.rotations, atol=1e-12)
    # frame 2k at 30 fps is frame k at 15 fps
    half = motion_sequence(name, 50, skeleton, seed=3, fps=15.0)
    np.testing.assert_allclose(half[7].rotations, long[14].rotations, atol=1e-12)
    # the stretched sampling of the old callers differs, and the motion repeats after its period
    assert np.abs(motion_sequence(name, 10, skeleton, seed=3)[5].rotations - short[5].rotations).max() > 1e-3
    period = int(round(MOTION_PERIOD_S[name] * 30))
    again = motion_sequence(name, period + 6, skeleton, seed=3, fps=30.0)
    np.testing.assert_allclose(again[period + 5].rotations, again[5].rotations, atol=1e-9)


def test_a_120_frame_walk_at_30_fps_makes_one_stride_per_1_1_s(skeleton):
    poses = motion_sequence("walk", 120, skeleton, seed=0, fps=30.0)
    np.testing.assert_allclose(poses[33].rotations, poses[0].rotations, atol=1e-9)  # 1.1 s = 33 frames
    stretched = motion_sequence("walk", 120, skeleton, seed=0)  # 2 strides over the 120 frames
    assert np.abs(stretched[33].rotations - stretched[0].rotations).max() > 0.1


def test_bad_fps_is_refused(skeleton):
    with pytest.raises(InputError, match="fps"):
        motion_sequence("walk", 10, skeleton, fps=0.0)
