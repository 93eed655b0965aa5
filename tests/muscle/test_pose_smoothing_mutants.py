"""mus11q's pose smoothing options where the other files do not reach them (issue 17, mutation testing):
``CaptureOptions``' refusals of a smoothing degree / sigma in their whole text, the bounds accepted (degrees 0 and
3, a numpy integer, a shoulder degree of its own, sigma 0), and ``capture_arm_frames`` handing both degrees, the
shoulder's set apart from the elbow's, to ``smooth_arm_poses``."""
from __future__ import annotations

import re

import numpy as np
import pytest

from bodystudio.errors import InputError
from bodystudio.muscle import capture as cap_mod
from bodystudio.muscle.capture import CaptureOptions, capture_arm_frames
from bodystudio.muscle.refine import smooth_arm_poses
from tests.muscle.test_capture_analytic import FAST, scene  # noqa: F401  (the tiny capture scene)


@pytest.mark.parametrize(("name", "value"), [("pose_smoothing_degree", 4), ("pose_smoothing_degree", True),
                                             ("pose_smoothing_degree", None), ("shoulder_smoothing_degree", -1),
                                             ("shoulder_smoothing_degree", 2.0)])
def test_a_bad_degree_is_refused_in_one_whole_line(name, value):
    msg = f"{name} must be 0 (the Gaussian mean), 1, 2 or 3, got {value!r}"
    with pytest.raises(InputError, match="^" + re.escape(msg) + "$"):
        CaptureOptions(**{name: value})


def test_a_negative_sigma_is_refused_in_one_whole_line():
    with pytest.raises(InputError, match=r"^pose_sigma_frames must be >= 0 \(0: no smoothing\), got -0\.5$"):
        CaptureOptions(pose_sigma_frames=-0.5)


def test_the_bounds_are_accepted():
    for degree in (0, 1, 3, np.int64(2)):
        assert CaptureOptions(pose_smoothing_degree=degree).pose_smoothing_degree == degree
        assert CaptureOptions(shoulder_smoothing_degree=degree).shoulder_smoothing_degree == degree
    assert CaptureOptions(pose_sigma_frames=0.0).pose_sigma_frames == 0.0


def test_capture_arm_frames_hands_both_degrees_to_the_smoothing(scene, monkeypatch):  # noqa: F811
    """Degree 3 for the elbow and 1 for the shoulder reach ``smooth_arm_poses`` as they were set."""
    seen = []

    def smooth(poses, sigma, radius=None, degree=0, shoulder_degree=None):
        seen.append((len(poses), sigma, radius, degree, shoulder_degree))
        return poses

    monkeypatch.setattr(cap_mod, "smooth_arm_poses", smooth)
    o = CaptureOptions(mode="model", **{**FAST, "pose_sigma_frames": 0.7, "pose_smoothing_degree": 3,
                                        "shoulder_smoothing_degree": 1, "body_rest_shape": False})
    capture_arm_frames(scene.depths[:2], scene.camera, scene.template, scene.model, o, known_shape=scene.shape)
    assert seen == [(2, 0.7, None, 3, 1)]


# --- refine.smooth_arm_poses ------------------------------------------------------------------------------------

def _poses(A):
    from bodystudio.muscle.arm import ArmPose

    return [ArmPose(np.eye(4), a) for a in A]


def _angles(poses):
    return np.stack([p.angles for p in poses])


@pytest.mark.parametrize("degree", [1, 2, 3])
def test_each_degree_is_the_weighted_least_squares_polynomial_at_the_frame(degree):
    """Every frame (ends included, where the window is cut short) is the Gaussian-weighted least-squares polynomial
    of ``degree`` over its window evaluated at the frame (numpy's polyfit with sqrt weights), for every angle."""
    rng = np.random.default_rng(degree)
    A = rng.normal(size=(12, 3, 3))
    sigma, radius = 2.0, 4
    out = _angles(smooth_arm_poses(_poses(A), sigma, radius, degree=degree))
    for i in range(12):
        lo, hi = max(0, i - radius), min(12, i + radius + 1)
        k = np.arange(lo, hi) - i
        w = np.exp(-k ** 2 / (2 * sigma ** 2))
        for j in range(3):
            for c in range(3):
                want = np.polyval(np.polyfit(k, A[lo:hi, j, c], degree, w=np.sqrt(w)), 0.0)
                assert abs(out[i, j, c] - want) < 1e-10


def test_a_linear_trajectory_is_kept_by_degree_one_even_at_the_ends():
    k = np.arange(10, dtype=np.float64)
    A = np.zeros((10, 3, 3))
    A[:, 1, 0] = 0.2 + 0.05 * k
    np.testing.assert_allclose(_angles(smooth_arm_poses(_poses(A), 2.0, degree=1))[:, 1, 0], A[:, 1, 0], atol=1e-12)
    assert abs(_angles(smooth_arm_poses(_poses(A), 2.0))[0, 1, 0] - A[0, 1, 0]) > 0.01  # the mean is biased there


def test_the_defaults_sigma_and_radius_and_three_frames_are_smoothed():
    rng = np.random.default_rng(4)
    A = rng.normal(size=(9, 3, 3))
    # the default sigma is 1.5 frames; sigma 1 reaches 2 frames each side (max(2, ceil(2 sigma)))
    np.testing.assert_array_equal(_angles(smooth_arm_poses(_poses(A))), _angles(smooth_arm_poses(_poses(A), 1.5)))
    np.testing.assert_array_equal(_angles(smooth_arm_poses(_poses(A), 1.0)),
                                  _angles(smooth_arm_poses(_poses(A), 1.0, radius=2)))
    assert np.abs(_angles(smooth_arm_poses(_poses(A), 1.0)) - _angles(smooth_arm_poses(_poses(A), 1.0, 3))).max() > 1e-6
    # three poses are the shortest sequence smoothed: the middle one is the weighted mean of all three
    out = _angles(smooth_arm_poses(_poses(A[:3]), 1.0))
    g = np.exp(-np.array([1.0, 0.0, 1.0]) / 2.0)
    np.testing.assert_allclose(out[1], np.tensordot(g / g.sum(), A[:3], axes=1), atol=1e-14)
