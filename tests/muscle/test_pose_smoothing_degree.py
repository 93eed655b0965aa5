"""The pose smoothing's local quadratic (``refine.smooth_arm_poses(degree=2)``,
``CaptureOptions.pose_smoothing_degree``; docs/muscle.md "Capture, fifteenth pass"): the Gaussian mean cuts a flexion
cycle's turning points, the local quadratic over the same kind of window keeps them and still takes the noise out."""

import numpy as np

from bodystudio.muscle.arm import ArmPose
from bodystudio.muscle.refine import smooth_arm_poses


def _poses(elbow_rad):
    return [ArmPose(np.eye(4), np.array([[0.01, 0.02, 0.03], [a, 0.0, 0.0], [0.0, 0.0, 0.0]])) for a in elbow_rad]


def _elbow(poses):
    return np.array([p.angles[1, 0] for p in poses])


def test_a_quadratic_trajectory_is_kept_exactly_and_a_constant_angle_untouched():
    k = np.arange(40, dtype=np.float64)
    truth = 0.3 + 0.02 * k - 0.0009 * k ** 2
    for sigma, radius in ((2.5, None), (5.0, None), (1.0, 3)):
        out = smooth_arm_poses(_poses(truth), sigma, radius, degree=2)
        np.testing.assert_allclose(_elbow(out), truth, atol=1e-12)  # every frame, the ends too
        np.testing.assert_allclose(np.stack([p.angles[0] for p in out]), [[0.01, 0.02, 0.03]] * 40, atol=1e-15)
    # the mean cuts the same parabola's curvature: its window's variance (~sigma^2, the +-5 frames cut it) times
    # half the second difference (2 x 0.0009)
    mean = _elbow(smooth_arm_poses(_poses(truth), 2.5))
    k = np.arange(-5, 6)
    w = np.exp(-k ** 2 / (2 * 2.5 ** 2))
    np.testing.assert_allclose(mean[20] - truth[20], -0.0009 * (w @ k ** 2) / w.sum(), atol=1e-12)


def test_the_local_quadratic_keeps_a_flexion_cycles_extremes_and_takes_out_the_noise():
    """The benchmark's elbow flexion (15-140 deg, one cycle per ~100 frames) with 0.7 deg of per-frame noise."""
    rng = np.random.default_rng(3)
    t = np.arange(200)
    truth = np.radians(15.0 + 62.5 * (1.0 - np.cos(2.0 * np.pi * t / 100.0)))
    noisy = truth + np.radians(0.7) * rng.normal(size=t.size)
    inner = slice(10, -10)

    def rms_deg(x):
        return float(np.degrees(np.sqrt(np.mean((x[inner] - truth[inner]) ** 2))))

    raw = rms_deg(noisy)
    mean = rms_deg(_elbow(smooth_arm_poses(_poses(noisy), 2.5)))
    quad = rms_deg(_elbow(smooth_arm_poses(_poses(noisy), 5.0, degree=2)))
    # measured: raw 0.70, the mean at sigma 2.5 0.54 (its extremes 0.64-0.8 deg off), the quadratic at sigma 5 0.24 deg
    assert quad < 0.5 * raw and quad < 0.5 * mean
    extremes = (np.abs(np.cos(2.0 * np.pi * t / 100.0)) > 0.99) & (t > 10) & (t < 190)
    noise_free = _elbow(smooth_arm_poses(_poses(truth), 2.5))
    assert np.degrees(np.abs(noise_free - truth)[extremes]).min() > 0.6  # the mean's bias at the turning points
    quad_free = _elbow(smooth_arm_poses(_poses(truth), 5.0, degree=2))
    assert np.degrees(np.abs(quad_free - truth)[extremes]).max() < 0.05


def test_degree_zero_is_the_gaussian_mean_and_short_windows_fall_back_to_it():
    rng = np.random.default_rng(0)
    a = rng.normal(size=9)
    np.testing.assert_array_equal(_elbow(smooth_arm_poses(_poses(a), 1.5, degree=0)),
                                  _elbow(smooth_arm_poses(_poses(a), 1.5)))
    # radius 2: the first frame's window holds 3 frames, fewer than a quadratic's 4: the mean there
    g = np.exp(-np.arange(3) ** 2 / 2.0)
    out = _elbow(smooth_arm_poses(_poses(a), 1.0, radius=2, degree=2))
    np.testing.assert_allclose(out[0], g @ a[:3] / g.sum(), atol=1e-14)
    assert abs(out[4] - g[::-1] @ a[2:5] / g.sum()) > 1e-6  # an inner frame: the quadratic, not the mean
    assert smooth_arm_poses(_poses(a), 0.0, degree=2)[3].angles[1, 0] == a[3]  # sigma 0: off


def test_the_shoulder_can_keep_the_mean_while_the_elbow_takes_the_quadratic():
    rng = np.random.default_rng(1)
    A = rng.normal(size=(30, 3, 3))
    poses = [ArmPose(np.eye(4), a) for a in A]
    mixed = np.stack([p.angles for p in smooth_arm_poses(poses, 5.0, degree=2, shoulder_degree=0)])
    mean = np.stack([p.angles for p in smooth_arm_poses(poses, 5.0)])
    quad = np.stack([p.angles for p in smooth_arm_poses(poses, 5.0, degree=2)])
    np.testing.assert_allclose(mixed[:, 0], mean[:, 0], atol=1e-14)
    np.testing.assert_allclose(mixed[:, 1:], quad[:, 1:], atol=1e-14)
    assert np.abs(mean[:, 0] - quad[:, 0]).max() > 1e-3  # the two degrees differ on this noise
    same = np.stack([p.angles for p in smooth_arm_poses(poses, 5.0, degree=2, shoulder_degree=2)])
    np.testing.assert_array_equal(same, quad)
