"""Kinect simulation: Khoshelham noise statistics, quantisation, range, projector shadow, tracker jitter."""

import numpy as np
import pytest

from bodystudio.body.kinect import kinect_joints
from bodystudio.capture.kinect import (
    KINECT_NOISE,
    KinectNoiseModel,
    depth_to_millimetres,
    kinect_parent_indices,
    millimetres_to_depth,
    projector_shadow_mask,
    read_depth_png,
    simulate_kinect_depth,
    simulate_tracker_joints,
    write_depth_png,
)
from bodystudio.errors import FileFormatError
from bodystudio.geometry.camera import kinect_v1

SENSOR = kinect_v1("640x480")


def _quad_in_depth_frame(center_z, half_size, tilt_deg=0.0, center_xy=(0.0, 0.0)):
    """A square (V, F) in world coordinates, given in the depth camera's frame, tilted about its y axis."""
    c = np.array([center_xy[0], center_xy[1], center_z])
    t = np.radians(tilt_deg)
    a, b = np.array([np.cos(t), 0.0, np.sin(t)]), np.array([0.0, 1.0, 0.0])
    Pc = np.array([c + half_size * (sa * a + sb * b) for sa, sb in [(-1, -1), (1, -1), (1, 1), (-1, 1)]])
    return SENSOR.depth.camera_to_world(Pc), np.array([[0, 1, 2], [0, 2, 3]])


@pytest.mark.parametrize("z0", [1.0, 2.0, 3.0])
def test_axial_noise_matches_khoshelham_model(z0):
    # A slightly tilted plane spans many disparity quanta, so the true disparity is uniformly spread
    # over the 1/8 px grid and the quantisation error is independent of the noise: the disparity
    # residual variance is sigma_d^2 + step^2 / 12 (Sheppard). Subtracting the quantisation part
    # leaves the Gaussian disparity noise, which maps to the axial depth sigma at z0.
    V, F = _quad_in_depth_frame(z0, 0.9 * z0, tilt_deg=15.0)
    rng = np.random.default_rng(int(z0 * 10))
    ideal = simulate_kinect_depth(V, F, SENSOR, rng, noise=False).astype(np.float64)
    measured = simulate_kinect_depth(V, F, SENSOR, rng).astype(np.float64)
    ok = (measured > 0) & (ideal > 0)
    assert ok.mean() > 0.8
    fb = SENSOR.depth.fx * SENSOR.baseline_m
    d_meas, d_true = fb / measured[ok], fb / ideal[ok]
    step = KINECT_NOISE.disparity_step_px
    np.testing.assert_allclose(d_meas / step, np.round(d_meas / step), atol=1e-3)  # on the 1/8 px grid
    residual = d_meas - d_true
    sigma_d = np.sqrt(residual.var() - step**2 / 12.0)
    sigma_z = sigma_d * z0**2 / fb
    assert abs(sigma_z / (1.425e-3 * z0**2) - 1.0) < 0.10
    assert abs(residual.mean()) < 0.1 * step
    # direct depth-domain check at the plane centre rows: spread grows like z^2
    depth_std = np.std(measured[ok] - ideal[ok])
    resolution = KINECT_NOISE.depth_resolution_m(z0, SENSOR.depth.fx, SENSOR.baseline_m)
    expected = np.sqrt((1.425e-3 * z0**2) ** 2 + resolution**2 / 12)
    assert abs(depth_std / expected - 1.0) < 0.25


def test_valid_range():
    rng = np.random.default_rng(0)
    for z, expect_data in [(0.45, False), (4.0, True), (4.8, False)]:
        V, F = _quad_in_depth_frame(z, 0.9 * z)
        depth = simulate_kinect_depth(V, F, SENSOR, rng)
        assert (depth > 0).any() == expect_data, z


def test_projector_shadow_width_and_side():
    # occluder at 1.5 m in front of a wall at 2 m; the shadow on the wall is f b (1/1.5 - 1/2) px wide,
    # on the side away from the projector (the projector sits at +x of the IR camera)
    wall_V, wall_F = _quad_in_depth_frame(2.0, 3.0)
    occ_V, occ_F = _quad_in_depth_frame(1.5, 0.2)
    V = np.r_[wall_V, occ_V]
    F = np.r_[wall_F, occ_F + 4]
    shadow = projector_shadow_mask(V, F, SENSOR)
    expected = SENSOR.depth.fx * SENSOR.baseline_m * (1 / 1.5 - 1 / 2.0)
    cx = SENSOR.depth.K[0, 2]
    rows = range(int(SENSOR.depth.K[1, 2]) - 50, int(SENSOR.depth.K[1, 2]) + 50)
    widths = [shadow[r, int(cx) - 120: int(cx)].sum() for r in rows]
    assert abs(np.mean(widths) - expected) < 1.5
    assert shadow[list(rows), int(cx):].sum() == 0
    # the projector does not light the image's left band either: width f b / z_wall
    assert abs(shadow[list(rows), :40].sum(1).mean() - SENSOR.depth.fx * SENSOR.baseline_m / 2.0) < 1.5
    # the full simulation drops those pixels
    depth = simulate_kinect_depth(V, F, SENSOR, np.random.default_rng(1))
    assert np.all(depth[shadow] == 0)


def test_flying_pixels_only_at_discontinuities():
    wall_V, wall_F = _quad_in_depth_frame(2.5, 3.0)
    occ_V, occ_F = _quad_in_depth_frame(1.5, 0.3)
    V, F = np.r_[wall_V, occ_V], np.r_[wall_F, occ_F + 4]
    model = KinectNoiseModel(hole_rate=0, dropout_rate=0, flying_pixel_prob=1.0)
    depth = simulate_kinect_depth(V, F, SENSOR, np.random.default_rng(2), model=model)
    between = (depth > 1.65) & (depth < 2.3)
    assert between.sum() > 50
    ideal = simulate_kinect_depth(V, F, SENSOR, None, noise=False)
    from scipy import ndimage
    edge = ndimage.maximum_filter(ideal, 3) - ndimage.minimum_filter(ideal, 3) > 0.5
    assert np.all(edge[between])
    no_fly = simulate_kinect_depth(V, F, SENSOR, np.random.default_rng(2),
                                   model=KinectNoiseModel(hole_rate=0, dropout_rate=0, flying_pixel_prob=0.0))
    assert not ((no_fly > 1.65) & (no_fly < 2.3)).any()


def test_millimetre_png_round_trip(tmp_path):
    depth = np.random.default_rng(0).uniform(0.5, 4.5, (24, 32)).astype(np.float32)
    depth[0, :5] = 0
    path = tmp_path / "depth.png"
    write_depth_png(path, depth)
    back = read_depth_png(path)
    assert back.dtype == np.float32 and np.abs(back - depth).max() <= 0.0005 + 1e-6
    assert np.all(back[0, :5] == 0)
    assert np.array_equal(depth_to_millimetres(millimetres_to_depth(depth_to_millimetres(depth))),
                          depth_to_millimetres(depth))
    (tmp_path / "bad.png").write_bytes(b"not a png")
    with pytest.raises(FileFormatError, match="bad.png"):
        read_depth_png(tmp_path / "bad.png")


def test_tracker_noise_jitter_and_dropout(body_2k):
    sk = body_2k.skeleton
    truth = kinect_joints(sk, sk.heads, sk.tails, "v2")
    parents = kinect_parent_indices("v2")
    child = np.nonzero(parents >= 0)[0]
    rest_len = np.linalg.norm(truth[child] - truth[parents[child]], axis=1)
    rng = np.random.default_rng(0)
    # bone-length jitter alone: relative bone-length spread equals the jitter
    ratios = []
    for _ in range(400):
        J, tracked = simulate_tracker_joints(sk.heads, sk.tails, sk, "v2", rng, noise_m=0.0, bone_length_jitter=0.03)
        assert tracked.all()
        ratios.append(np.linalg.norm(J[child] - J[parents[child]], axis=1) / rest_len)
    ratios = np.array(ratios)
    assert abs(ratios.std() / 0.03 - 1) < 0.1 and abs(ratios.mean() - 1) < 0.01
    # joint noise alone: per-axis residual sigma equals noise_m
    res = np.array([simulate_tracker_joints(sk.heads, sk.tails, sk, "v2", rng, noise_m=0.01,
                                            bone_length_jitter=0.0)[0] - truth for _ in range(400)])
    assert abs(res.std() / 0.01 - 1) < 0.05
    # dropouts: fraction of untracked joints, and inferred joints are noisier
    out = [simulate_tracker_joints(sk.heads, sk.tails, sk, "v1", rng, noise_m=0.01, bone_length_jitter=0.0,
                                   dropout=0.2) for _ in range(400)]
    tracked = np.array([t for _, t in out])
    assert abs((~tracked).mean() - 0.2) < 0.02
    truth1 = kinect_joints(sk, sk.heads, sk.tails, "v1")
    err = np.array([j - truth1 for j, _ in out])
    assert err[~tracked].std() > 2.5 * err[tracked].std()
