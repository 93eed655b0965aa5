"""Analytic tests of the Sec. 4 depth pre-processing of Arm-Muscle Capture (bodystudio.muscle.depth).

Tiny synthetic depth maps where each step has an exact answer: the distance threshold, the median's
removal of a lone speck, the normalised Gaussian, the depth-jump marking, the border thinning ring, and
the point cloud / normals of planes seen by a pinhole camera.
"""

import cv2
import numpy as np
import pytest

from bodystudio.errors import InputError
from bodystudio.geometry.camera import Camera
from bodystudio.muscle.depth import DepthCleanupOptions, clean_depth, depth_point_cloud, segment_by_distance

# Every step off: the output is the segmented input itself.
OFF = DepthCleanupOptions(median_px=1, gaussian_sigma_px=0.0, thinning_px=0, discontinuity_m=10.0, min_pixels=1)


def _opts(**kw):
    return DepthCleanupOptions(**{**OFF.__dict__, **kw})


def _camera(width=12, height=10, f=20.0, R=None, t=None):
    K = np.array([[f, 0.0, (width - 1) / 2], [0.0, f, (height - 1) / 2], [0.0, 0.0, 1.0]])
    return Camera("depth", K, np.zeros(5), np.eye(3) if R is None else R, np.zeros(3) if t is None else t,
                  width, height)


# --- segmentation ---------------------------------------------------------------------------------------

def test_segmentation_keeps_exactly_the_closed_distance_range():
    d = np.array([[0.49, 0.5, 0.9, 1.3, 1.31, np.nan, np.inf, -1.0]])
    np.testing.assert_array_equal(segment_by_distance(d, 0.5, 1.3), [[0, 1, 1, 1, 0, 0, 0, 0]])
    # integer depth (millimetres as ints in metres) is compared as float
    np.testing.assert_array_equal(segment_by_distance(np.array([[1, 2]]), 0.5, 1.5), [[1, 0]])


def test_with_every_step_off_the_output_is_the_segmented_input():
    rng = np.random.default_rng(0)
    d = rng.uniform(0.3, 1.6, (9, 11)).astype(np.float32)
    out = clean_depth(d, OFF)
    assert out.dtype == np.float64
    inside = (d >= 0.5) & (d <= 1.3)
    np.testing.assert_array_equal(out, np.where(inside, d, 0.0).astype(np.float64))


def test_a_pixel_beyond_the_distance_threshold_is_removed():
    d = np.full((8, 8), 1.0)
    d[3, 4] = 1.35  # beyond far_m = 1.3
    d[5, 2] = 0.45  # nearer than near_m = 0.5
    out = clean_depth(d, OFF)
    assert out[3, 4] == 0.0 and out[5, 2] == 0.0
    rest = np.ones((8, 8), bool)
    rest[3, 4] = rest[5, 2] = False
    np.testing.assert_array_equal(out[rest], 1.0)
    # the thresholds are the options' own
    out = clean_depth(d, _opts(far_m=1.4, near_m=0.4))
    assert out[3, 4] == pytest.approx(1.35) and out[5, 2] == pytest.approx(0.45)


# --- median ---------------------------------------------------------------------------------------------

@pytest.mark.parametrize("aperture", [3, 5])
def test_a_lone_speck_is_removed_by_the_median(aperture):
    d = np.full((11, 11), 1.0, np.float32)
    d[5, 5] = 1.2  # a random outlier within range
    d[2, 7] = 0.9
    out = clean_depth(d, _opts(median_px=aperture))
    np.testing.assert_allclose(out, 1.0, atol=1e-7)
    # without the median both specks stay
    raw = clean_depth(d, OFF)
    assert raw[5, 5] == pytest.approx(1.2) and raw[2, 7] == pytest.approx(0.9)


def test_the_median_aperture_is_the_options_own():
    # a 2x2 block of 1.2 in 1.0: the 3x3 median keeps it (4 of 9 values... centre pixels see 4 of 9), the 5x5 one
    # removes it (4 of 25)
    d = np.full((12, 12), 1.0, np.float32)
    d[5:8, 5:8] = 1.2  # a 3x3 block: the centre's 3x3 window is all 1.2
    out3 = clean_depth(d, _opts(median_px=3))
    out5 = clean_depth(d, _opts(median_px=5))
    assert out3[6, 6] == pytest.approx(1.2)  # 9 of 9 in its 3x3 window
    assert out3[5, 5] == pytest.approx(1.0)  # 4 of 9
    np.testing.assert_allclose(out5, 1.0, atol=1e-7)  # at most 9 of 25 anywhere


def test_where_the_median_window_is_mostly_empty_the_raw_depth_stays():
    d = np.zeros((9, 9), np.float32)
    d[4, 4], d[4, 5] = 1.1, 1.0  # two valid pixels: every window's median is 0
    out = clean_depth(d, _opts(median_px=3))
    assert out[4, 4] == pytest.approx(1.1) and out[4, 5] == pytest.approx(1.0)
    assert np.count_nonzero(out) == 2


# --- Gaussian -------------------------------------------------------------------------------------------

def test_the_gaussian_is_a_normalised_convolution_over_valid_pixels():
    # a flat patch surrounded by missing pixels: the normalised Gaussian leaves it exactly flat (a plain one
    # would pull the border pixels towards 0)
    d = np.zeros((15, 15), np.float32)
    d[4:11, 3:12] = 1.0
    out = clean_depth(d, _opts(gaussian_sigma_px=1.5))
    np.testing.assert_allclose(out[4:11, 3:12], 1.0, atol=1e-6)
    assert np.count_nonzero(out) == 7 * 9


def test_the_gaussian_smooths_a_quantisation_step_with_its_kernel():
    d = np.full((9, 30), 1.0, np.float32)
    d[:, 15:] = 1.01  # a 1 cm quantisation step (below the 3 cm jump threshold)
    for sigma in (1.0, 2.0):
        out = clean_depth(d, _opts(gaussian_sigma_px=sigma))
        g = cv2.getGaussianKernel(int(round(sigma * 8 + 1)) | 1, sigma).ravel()
        row = d[4].astype(np.float64)
        r = len(g) // 2
        expected = np.array([g @ row[c - r:c + r + 1] for c in range(r, 30 - r)])
        np.testing.assert_allclose(out[4, r:30 - r], expected, atol=2e-6)
        assert 1.0 < out[4, 15] < 1.01 and 1.0 < out[4, 14] < 1.01


# --- depth jumps and border thinning ------------------------------------------------------------------------

def test_pixels_next_to_a_depth_jump_are_dropped_and_below_the_threshold_kept():
    d = np.full((8, 12), 1.0)
    d[:, 6:] = 1.05  # a 5 cm jump between columns 5 and 6
    out = clean_depth(d, _opts(discontinuity_m=0.03))
    np.testing.assert_array_equal(np.flatnonzero(out[0] == 0), [5, 6])
    assert (out[:, 5:7] == 0).all() and (out[:, :5] > 0).all() and (out[:, 7:] > 0).all()
    # the same step below the threshold stays
    assert (clean_depth(d, _opts(discontinuity_m=0.06)) > 0).all()
    # the step the other way round, and along the rows: the same two lines either side of it
    d_rev = np.full((8, 12), 1.05)
    d_rev[:, 6:] = 1.0
    out = clean_depth(d_rev, _opts(discontinuity_m=0.03))
    np.testing.assert_array_equal(np.flatnonzero((out == 0).all(axis=0)), [5, 6])
    assert np.count_nonzero(out == 0) == 16
    out = clean_depth(d_rev.T.copy(), _opts(discontinuity_m=0.03))
    np.testing.assert_array_equal(np.flatnonzero((out == 0).all(axis=1)), [5, 6])
    assert np.count_nonzero(out == 0) == 16
    # "farther than" the threshold: a jump of exactly the threshold stays (0.0625 is exact in float32)
    d_eq = np.full((8, 12), 1.0)
    d_eq[:, 6:] = 1.0625
    assert (clean_depth(d_eq, _opts(discontinuity_m=0.0625)) > 0).all()
    assert (clean_depth(d_eq, _opts(discontinuity_m=0.0624))[:, 5:7] == 0).all()
    # the threshold is strict and measured on the raw depth (before the median smooths the step)
    d2 = np.full((8, 12), 1.0)
    d2[:, 6:] = 1.25
    out2 = clean_depth(d2, _opts(discontinuity_m=0.2, median_px=5))
    assert (out2[:, 5:7] == 0).all() and (out2[:, :5] > 0).all()


def test_the_edge_of_the_valid_region_is_no_depth_jump():
    # valid pixels next to missing ones (0 or out of range) are not marked: only valid neighbours count
    d = np.zeros((10, 10))
    d[2:8, 2:8] = 1.0
    d[0, :] = 2.0  # beyond far_m
    out = clean_depth(d, _opts(discontinuity_m=0.03))
    np.testing.assert_array_equal(out > 0, d == 1.0)
    # ... but a jump right at the edge of the valid region is marked (missing neighbours are ignored, not
    # allowed to hide it)
    e = np.zeros((8, 12))
    e[:, 2] = 1.05
    e[:, 3:9] = 1.0
    out = clean_depth(e, _opts(discontinuity_m=0.03))
    np.testing.assert_array_equal(np.flatnonzero((out > 0).all(axis=0)), [4, 5, 6, 7, 8])
    np.testing.assert_array_equal(np.flatnonzero((out > 0).any(axis=0)), [4, 5, 6, 7, 8])
    # the image border is no jump either
    full = clean_depth(np.full((6, 7), 0.8), _opts(discontinuity_m=0.03))
    np.testing.assert_allclose(full, 0.8, atol=1e-7)


@pytest.mark.parametrize("px", [1, 2])
def test_border_thinning_removes_exactly_the_boundary_ring(px):
    d = np.zeros((16, 18))
    d[3:13, 4:15] = 1.0
    out = clean_depth(d, _opts(thinning_px=px))
    expected = np.zeros_like(d, bool)
    expected[3 + px:13 - px, 4 + px:15 - px] = True
    np.testing.assert_array_equal(out > 0, expected)
    np.testing.assert_allclose(out[expected], 1.0)


def test_border_thinning_also_removes_the_image_border():
    out = clean_depth(np.full((7, 9), 1.0), _opts(thinning_px=1))
    expected = np.zeros((7, 9), bool)
    expected[1:-1, 1:-1] = True
    np.testing.assert_array_equal(out > 0, expected)


def test_default_options_on_a_flat_patch():
    # segment 0.5-1.3 m, median 5, Gaussian 1, thinning 1 px: a flat in-range patch loses its one-pixel ring
    d = np.zeros((30, 30))
    d[5:25, 5:25] = 1.0
    d[0:3, :] = 1.6  # background beyond the threshold
    out = clean_depth(d, DepthCleanupOptions(min_pixels=10))
    expected = np.zeros_like(d, bool)
    expected[6:24, 6:24] = True
    np.testing.assert_array_equal(out > 0, expected)
    np.testing.assert_allclose(out[expected], 1.0, atol=1e-6)
    o = DepthCleanupOptions()
    assert (o.near_m, o.far_m, o.median_px, o.gaussian_sigma_px, o.thinning_px, o.discontinuity_m, o.min_pixels) \
        == (0.5, 1.3, 5, 1.0, 1, 0.03, 200)


# --- refusals -------------------------------------------------------------------------------------------

def test_min_pixels_before_and_after_thinning():
    d = np.zeros((10, 10))
    d[2:7, 2:7] = 1.0  # 25 pixels, 9 after thinning
    assert np.count_nonzero(clean_depth(d, _opts(min_pixels=25))) == 25
    with pytest.raises(InputError, match=r"^frame 3: only 25 depth pixels within 0.5-1.3 m; no arm in range"):
        clean_depth(d, _opts(min_pixels=26), source="frame 3")
    assert np.count_nonzero(clean_depth(d, _opts(min_pixels=9, thinning_px=1))) == 9
    with pytest.raises(InputError, match=r"^frame 3: 9 depth pixels left after border thinning; .*lower thinning_px$"):
        clean_depth(d, _opts(min_pixels=10, thinning_px=1), source="frame 3")


def test_bad_shapes_and_ranges_are_refused():
    with pytest.raises(InputError, match=r"^depth: depth map must be a non-empty 2-D image, got shape \(4,\)$"):
        clean_depth(np.ones(4))
    with pytest.raises(InputError, match=r"^d: depth map must be a non-empty 2-D image, got shape \(0, 3\)$"):
        clean_depth(np.ones((0, 3)), source="d")
    with pytest.raises(InputError, match=r"^depth: depth segmentation needs 0 < near_m < far_m, got 1.3, 1.3$"):
        clean_depth(np.ones((4, 4)), _opts(near_m=1.3))
    with pytest.raises(InputError, match="0 < near_m"):
        clean_depth(np.ones((4, 4)), _opts(near_m=0.0))
    with pytest.raises(InputError, match="0 < near_m"):
        clean_depth(np.ones((4, 4)), _opts(near_m=1.4))


# --- point cloud and normals ------------------------------------------------------------------------------

def test_point_cloud_of_a_fronto_parallel_plane():
    cam = _camera()
    d = np.zeros((10, 12))
    d[2:8, 3:10] = 0.9
    P, N = depth_point_cloud(d, cam)
    # points: the valid pixels whose 4 neighbours (radius 1) are valid: the interior 4 x 5
    rows, cols = np.mgrid[3:7, 4:9]
    expected = np.stack([(cols.ravel() - 5.5) / 20.0 * 0.9, (rows.ravel() - 4.5) / 20.0 * 0.9,
                         np.full(rows.size, 0.9)], axis=1)
    np.testing.assert_allclose(P, expected, atol=1e-12)
    np.testing.assert_allclose(N, np.tile([0.0, 0.0, -1.0], (len(P), 1)), atol=1e-12)  # towards the sensor


def test_point_cloud_radius_and_image_border():
    cam = _camera()
    d = np.full((10, 12), 1.0)
    P1, _ = depth_point_cloud(d, cam, normal_radius_px=1)
    P2, _ = depth_point_cloud(d, cam, normal_radius_px=2)
    assert len(P1) == 8 * 10 and len(P2) == 6 * 8  # pixels within r of the image border get no point
    u = np.round(P2[:, 0] / P2[:, 2] * 20 + 5.5)
    v = np.round(P2[:, 1] / P2[:, 2] * 20 + 4.5)
    assert u.min() == 2 and u.max() == 9 and v.min() == 2 and v.max() == 7
    # a hole two pixels away is a missing neighbour at radius 2 only
    d[5, 7] = 0.0
    Q1, _ = depth_point_cloud(d, cam, normal_radius_px=1)
    Q2, _ = depth_point_cloud(d, cam, normal_radius_px=2)
    assert len(Q1) == 80 - 5 and len(Q2) == 48 - 5  # the hole and its 4 neighbours at distance r


@pytest.mark.parametrize("slope", [0.3, -0.5])
def test_normals_of_a_tilted_plane_are_exact_and_face_the_sensor(slope):
    # plane z = 1 + slope * x (camera frame): depth along the ray (x/z = a): z = 1 / (1 - slope * a)
    cam = _camera(width=16, height=12)
    cols = np.arange(16)
    a = (cols - 7.5) / 20.0
    d = np.tile(1.0 / (1.0 - slope * a), (12, 1))
    P, N = depth_point_cloud(d, cam)
    n_true = np.array([-slope, 0.0, 1.0]) / np.hypot(slope, 1.0)
    n_true = -n_true  # facing the sensor at the origin: negative z
    np.testing.assert_allclose(N, np.tile(n_true, (len(N), 1)), atol=1e-9)
    np.testing.assert_allclose(P[:, 2], 1.0 + slope * P[:, 0], atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(N, axis=1), 1.0, atol=1e-12)


def test_points_and_normals_in_world_coordinates():
    th = 0.7
    R = np.array([[np.cos(th), 0.0, np.sin(th)], [0.0, 1.0, 0.0], [-np.sin(th), 0.0, np.cos(th)]])
    t = np.array([0.1, -0.2, 0.3])
    cam, cam0 = _camera(R=R, t=t), _camera()
    d = np.full((10, 12), 1.2)
    P, N = depth_point_cloud(d, cam)
    P0, N0 = depth_point_cloud(d, cam0)
    np.testing.assert_allclose(P, (P0 - t) @ R, atol=1e-12)
    np.testing.assert_allclose(N, N0 @ R, atol=1e-12)
    # the normals face the camera centre
    C = -R.T @ t
    assert (np.einsum("kd,kd->k", N, C - P) > 0).all()


def test_a_degenerate_neighbourhood_gives_no_point_and_a_wrong_size_is_refused():
    cam = _camera()
    d = np.full((10, 12), 1.0)
    d[4, 5] = 0.0
    d[4, 7] = 0.0  # pixel (4, 6) has no left/right neighbour
    P, _ = depth_point_cloud(d, cam)
    assert len(P) == 80 - 2 - 4 - 4 + 1  # two holes and their 4 neighbours each ((4, 6) shared)
    with pytest.raises(InputError, match=r"^f: depth map is 11x10 but the depth camera depth is 12x10; "):
        depth_point_cloud(np.ones((10, 11)), cam, source="f")
    with pytest.raises(InputError, match=r"^depth: depth map is 11x10 but the depth camera depth is 12x10; use the "
                                         r"session's own calibration$"):
        depth_point_cloud(np.ones((10, 11)), cam)
