"""Fast closed-form checks of §7's image-space refinement (issue 17, mutation testing of garment/refine.py).

Each test is a small synthetic image or point set whose answer is known exactly: an integer shift, a
constant field, a square silhouette, Eq. 9 written out at single pixels, one-pixel depth layers.
"""

import numpy as np
import pytest

from bodystudio.errors import InputError
from bodystudio.garment import refine


def _texture(h, w, seed=0):
    """A smooth random RGB texture (uint8) that optical flow can lock onto."""
    import cv2

    rng = np.random.default_rng(seed)
    noise = rng.uniform(0, 255, (h, w, 3)).astype(np.float32)
    return np.clip(cv2.GaussianBlur(noise, (0, 0), 2.0) * 3 - 255, 0, 255).astype(np.uint8)


# --- to_gray8 -----------------------------------------------------------------------------------------


def test_gray_of_a_float_image_equals_gray_of_its_uint8_and_is_clipped():
    import cv2

    rng = np.random.default_rng(0)
    img8 = rng.integers(0, 256, (6, 7, 3)).astype(np.uint8)
    expected = cv2.cvtColor(img8, cv2.COLOR_RGB2GRAY)
    assert np.array_equal(refine.to_gray8(img8), expected)
    assert np.array_equal(refine.to_gray8(img8.astype(np.float64) / 255.0), expected)
    # 0.4 / 255 rounds down, 0.6 / 255 up; out-of-range floats clip to 0 and 255
    assert refine.to_gray8(np.full((2, 2, 3), 0.4 / 255)).max() == 0
    assert refine.to_gray8(np.full((2, 2, 3), 0.6 / 255)).min() == 1
    assert refine.to_gray8(np.full((2, 2, 3), 1.7)).min() == 255
    assert refine.to_gray8(np.full((2, 2, 3), -0.5)).max() == 0
    # RGB order: pure red and pure blue differ in grey (0.299 vs 0.114)
    red = np.zeros((1, 1, 3), np.uint8)
    red[..., 0] = 255
    assert refine.to_gray8(red)[0, 0] == 76


# --- dense_optical_flow -------------------------------------------------------------------------------


@pytest.mark.parametrize("preset", ["medium", "fast", "ultrafast"])
def test_flow_of_an_integer_shift_at_full_resolution(preset):
    """source(p) = target(p + flow(p)) for a target that is the source moved by (-3, +2) px."""
    big = _texture(140, 180)
    source = big[10:130, 10:170]
    # target(p) = big(p + (3, -2) + 10), so source(p) = target(p + (-3, 2))
    target = np.roll(np.roll(big, 2, axis=0), -3, axis=1)[10:130, 10:170]
    flow = refine.dense_optical_flow(source, target, preset=preset)
    assert flow.shape == (120, 160, 2) and flow.dtype == np.float32
    inner = flow[25:-25, 25:-25].reshape(-1, 2)
    assert np.abs(np.median(inner, axis=0) - [-3.0, 2.0]).max() < 0.3


def test_flow_computed_on_a_smaller_image_is_scaled_back_to_pixels():
    """max_height below the image height: flow measured at half size, returned at full size in full pixels."""
    big = _texture(260, 300, seed=2)
    source = big[20:220, 20:280]
    target = np.roll(big, 4, axis=1)[20:220, 20:280]  # target(p) = source(p - (4, 0)): flow (4, 0)
    flow = refine.dense_optical_flow(source, target, max_height=100)
    assert flow.shape == (200, 260, 2)
    inner = flow[40:-40, 40:-40].reshape(-1, 2)
    assert np.abs(np.median(inner, axis=0) - [4.0, 0.0]).max() < 0.4
    full = refine.dense_optical_flow(source, target, max_height=200)  # scale exactly 1: the direct branch
    assert np.abs(np.median(full[40:-40, 40:-40].reshape(-1, 2), axis=0) - [4.0, 0.0]).max() < 0.3


def test_flow_default_works_on_small_images_below_the_flow_height():
    src = _texture(64, 80, seed=3)
    flow = refine.dense_optical_flow(src, src)
    assert flow.shape == (64, 80, 2) and np.abs(flow).max() < 0.05
    assert refine.FLOW_HEIGHT_PX == 320


# --- median_outlier_removal ---------------------------------------------------------------------------


def test_median_outlier_removal_threshold_is_the_distance_to_the_median():
    """A constant field with one vector off by exactly 2 px (kept, <=) and one by 2.01 px (dropped)."""
    flow = np.zeros((20, 20, 2), np.float32)
    flow[5, 5] = [1.2, 1.6]          # |.| = 2.0 exactly (float32 1.2/1.6: norm 2.0 to 1e-7)
    flow[14, 14] = [0.0, 2.01]
    valid = np.ones((20, 20), bool)
    kept = refine.median_outlier_removal(flow, valid, max_deviation_px=2.0 + 1e-6)
    assert kept[5, 5] and not kept[14, 14]
    assert kept.sum() == 399
    # the default deviation is 2 px: a vector 1.9 px off stays, 2.1 px off goes
    flow[5, 5] = [1.9, 0.0]
    flow[14, 14] = [-2.1, 0.0]
    kept = refine.median_outlier_removal(flow, valid)
    assert kept[5, 5] and not kept[14, 14]
    # exactly 2 px off with the default threshold: kept (<=)
    flow[5, 5] = [0.0, 2.0]
    assert refine.median_outlier_removal(flow, valid)[5, 5]
    # invalid pixels stay invalid, whatever their flow
    valid[7, 3] = False
    assert not refine.median_outlier_removal(flow, valid)[7, 3]


def test_median_outlier_removal_uses_both_components_and_the_window_size():
    flow = np.zeros((20, 20, 2), np.float32)
    flow[10, 10, 1] = 5.0            # wrong in y only
    flow[3, 4, 0] = -5.0             # wrong in x only
    kept = refine.median_outlier_removal(flow, np.ones((20, 20), bool))
    assert not kept[10, 10] and not kept[3, 4] and kept.sum() == 398
    # a 2x2 blob of wrong vectors: the 3x3 median (4 of 9) drops them, the 5x5 median too
    flow = np.zeros((20, 20, 2), np.float32)
    flow[8:10, 8:10] = [4.0, 0.0]
    for k in (3, 5):
        kept = refine.median_outlier_removal(flow, np.ones((20, 20), bool), ksize=k)
        assert not kept[8:10, 8:10].any() and kept.sum() == 396
    # a 3x3 blob: 5 of the 9 in a 3x3 window are wrong, so the 3x3 median keeps the centre; 5x5 drops it
    flow = np.zeros((20, 20, 2), np.float32)
    flow[8:11, 8:11] = [4.0, 0.0]
    assert refine.median_outlier_removal(flow, np.ones((20, 20), bool), ksize=3)[9, 9]
    assert not refine.median_outlier_removal(flow, np.ones((20, 20), bool), ksize=5)[9, 9]
    assert not refine.median_outlier_removal(flow, np.ones((20, 20), bool))[9, 9]


# --- domain_transform_smoothing -----------------------------------------------------------------------


def test_domain_transform_keeps_a_constant_field_constant_and_zero_where_unreached():
    rng = np.random.default_rng(4)
    guide = np.tile(np.linspace(0, 200, 70).astype(np.uint8)[None, :, None], (50, 1, 3))
    field = np.zeros((50, 70, 2), np.float32)
    field[...] = [2.5, -1.5]
    valid = rng.random((50, 70)) < 0.05
    out = refine.domain_transform_smoothing(field, valid, guide, sigma_spatial=30.0, sigma_color=50.0)
    assert out.shape == (50, 70, 2)
    assert np.abs(out - [2.5, -1.5]).max() < 1e-4
    # the default sigma (a quarter of the height), default colour sigma and support: still constant
    out = refine.domain_transform_smoothing(field, valid, guide)
    assert np.abs(out - [2.5, -1.5]).max() < 1e-4
    # no valid pixel at all: 0 everywhere (dt(valid) = 0 < min_support), not NaN
    out = refine.domain_transform_smoothing(field, np.zeros((50, 70), bool), guide)
    assert np.isfinite(out).all() and np.abs(out).max() == 0


def test_domain_transform_default_sigma_is_a_quarter_of_the_height():
    """A ramp of valid values fills the gap between: the amount of smoothing depends on sigma_spatial."""
    guide = np.full((80, 100), 128, np.uint8)
    xx = np.tile(np.arange(100, dtype=np.float32), (80, 1))
    field = np.dstack([xx, -xx])
    valid = np.zeros((80, 100), bool)
    valid[:, ::9] = True
    default = refine.domain_transform_smoothing(field, valid, guide)
    explicit = refine.domain_transform_smoothing(field, valid, guide, sigma_spatial=0.25 * 80, sigma_color=100.0)
    assert np.allclose(default, explicit, atol=1e-5)
    other = refine.domain_transform_smoothing(field, valid, guide, sigma_spatial=0.5 * 80)
    assert np.abs(other - default).max() > 0.5
    # the two components are filtered separately: y is exactly -x
    assert np.allclose(default[..., 1], -default[..., 0], atol=1e-4)


def test_domain_transform_min_support_fades_weak_pixels():
    """Raising min_support above dt(valid) scales the field down there: num / max(den, s)."""
    guide = np.full((40, 60), 100, np.uint8)
    field = np.ones((40, 60, 2), np.float32)
    valid = np.zeros((40, 60), bool)
    valid[20, 30] = True
    out_default = refine.domain_transform_smoothing(field, valid, guide, sigma_spatial=20.0)
    assert np.abs(out_default - 1.0).max() < 1e-3  # one valid pixel reaches every pixel of a flat guide
    out = refine.domain_transform_smoothing(field, valid, guide, sigma_spatial=20.0, min_support=1.0)
    assert out.max() < 0.5 and out.min() >= 0
    assert refine.SUPPORT == 1e-4 and refine.DT_SIGMA_SPATIAL_FRACTION == 0.25


# --- garment_motion_correction ------------------------------------------------------------------------


def _shifted_person(dx, dy, h=120, w=160):
    """The actor's frame and the render of the same textured person moved so that actor(p) = render(p + d)."""
    big = _texture(h + 40, w + 40, seed=5)
    person = np.zeros((h + 40, w + 40), bool)
    person[40:140, 50:150] = True
    frame = big[20:20 + h, 20:20 + w]
    pmask = person[20:20 + h, 20:20 + w]
    shifted = np.roll(np.roll(big, -dy, axis=0), -dx, axis=1)
    smask = np.roll(np.roll(person, -dy, axis=0), -dx, axis=1)
    body = shifted[20:20 + h, 20:20 + w].astype(np.float64) / 255.0
    bmask = smask[20:20 + h, 20:20 + w]
    # actor(p) = big(p+20), render(q) = big(q + d + 20): render(p - d) = actor(p), so D = -d
    return frame, pmask, body, bmask


def test_motion_correction_recovers_a_translation_of_the_fit():
    frame, pmask, body, bmask = _shifted_person(3, -2)
    field = refine.garment_motion_correction(frame, pmask, body, bmask)
    assert field.shape == (120, 160, 2)
    core = field[45:95, 55:115].reshape(-1, 2)
    assert np.abs(np.median(core, axis=0) - [-3.0, 2.0]).max() < 0.35
    # only the region near the garment mask is trusted: a garment far from the person gives no support (0)
    g = np.zeros_like(bmask)
    g[0:3, 0:3] = True
    far = refine.garment_motion_correction(frame, pmask, body, bmask, garment_mask=g)
    assert np.abs(far).max() < 1e-6
    near = refine.garment_motion_correction(frame, pmask, body, bmask, garment_mask=bmask)
    assert np.abs(np.median(near[45:95, 55:115].reshape(-1, 2), axis=0) - [-3.0, 2.0]).max() < 0.35


def test_motion_correction_rejects_flow_off_the_render_and_grey_mismatch():
    frame, pmask, body, bmask = _shifted_person(3, -2)
    # a render with no body at all: no pixel is valid, the field is 0
    assert np.abs(refine.garment_motion_correction(frame, pmask, body, np.zeros_like(bmask))).max() < 1e-6
    # a render whose grey differs by far more than max_grey_diff everywhere: nothing valid
    dark = body * 0.1
    out = refine.garment_motion_correction(frame, pmask, dark, bmask, max_grey_diff=0.5)
    assert np.abs(out).max() < 1e-6
    # forward and backward flow can never agree within a negative tolerance: nothing valid (the check is applied)
    assert np.abs(refine.garment_motion_correction(frame, pmask, body, bmask, max_fb_px=-1.0)).max() < 1e-6
    assert np.abs(refine.garment_motion_correction(frame, pmask, body, bmask, max_grey_diff=-1.0)).max() < 1e-6
    # the median test runs with median_ksize: an even size is refused by OpenCV
    import cv2

    with pytest.raises(cv2.error):
        refine.garment_motion_correction(frame, pmask, body, bmask, median_ksize=4)
    # an actor mask that is empty: nothing valid
    assert np.abs(refine.garment_motion_correction(frame, np.zeros_like(pmask), body, bmask)).max() < 1e-6


def test_motion_correction_size_mismatch_is_an_input_error():
    frame, pmask, body, bmask = _shifted_person(0, 0)
    with pytest.raises(InputError, match="same size"):
        refine.garment_motion_correction(frame[:-1], pmask, body, bmask)
    with pytest.raises(InputError, match="same size"):
        refine.garment_motion_correction(frame, pmask[:, :-1], body, bmask)


# --- silhouettes --------------------------------------------------------------------------------------


def test_mask_boundary_of_a_square_and_at_the_image_border():
    m = np.zeros((10, 12), bool)
    m[2:7, 3:9] = True
    b = refine.mask_boundary(m)
    expected = m.copy()
    expected[3:6, 4:8] = False
    assert np.array_equal(b, expected)
    # the image border is not a boundary (border_value 1): a mask filling the image has none
    assert not refine.mask_boundary(np.ones((5, 5), bool)).any()
    # 4-neighbours only: a diagonal notch does not make the opposite pixel a boundary
    full = np.ones((7, 7), bool)
    full[0, 0] = False
    assert refine.mask_boundary(full).sum() == 2  # (0, 1) and (1, 0), not (1, 1)


def test_outer_silhouette_is_the_garment_against_background_only():
    g = np.zeros((12, 12), bool)
    g[3:9, 3:9] = True
    body = np.zeros_like(g)
    pts = refine.outer_silhouette(g, body)
    ring = g & ~np.pad(np.ones((4, 4), bool), 4)
    assert pts.dtype == np.float64 and pts.shape == (20, 2)
    assert sorted(map(tuple, pts.astype(int))) == sorted((x, y) for y, x in zip(*np.nonzero(ring), strict=True))
    # body below the garment: the bottom hem (row 8) is against skin, not a silhouette; corners still touch bg
    body[9:12, 3:9] = True
    pts = refine.outer_silhouette(g, body)
    ys = pts[:, 1].astype(int)
    xs = pts[:, 0].astype(int)
    assert not ((ys == 8) & (xs > 3) & (xs < 8)).any() and ((ys == 8) & (xs == 3)).any()
    assert len(pts) == 16
    # diagonal contact does not count (4-neighbourhood)
    g2 = np.ones((5, 5), bool)
    g2[0, 0] = False
    pts2 = refine.outer_silhouette(g2, np.zeros_like(g2))
    assert sorted(map(tuple, pts2.astype(int))) == [(0, 1), (1, 0)]


def test_match_silhouettes_of_a_shifted_square():
    """The garment square 2 px left of the actor's: each left-edge point maps 2 px right, one pair per cell."""
    person = np.zeros((60, 60), bool)
    person[12:48, 14:50] = True
    garment = np.zeros_like(person)
    garment[12:48, 12:48] = True
    pts = refine.outer_silhouette(garment, np.zeros_like(person))
    src, tgt = refine.match_silhouettes(pts, person, spacing_px=1.0)
    b = refine.mask_boundary(person)
    assert b[tgt[:, 1].astype(int), tgt[:, 0].astype(int)].all()
    left = np.abs(src[:, 0] - 12) < 0.5
    assert left.sum() >= 30
    assert np.allclose(tgt[left, 0], 14) and np.allclose(tgt[left, 1], src[left, 1])
    # one pair per target cell: targets are unique
    assert len(np.unique(tgt, axis=0)) == len(tgt)
    # spacing 2: one target per 2x2 cell, each the mean of its members
    src2, tgt2 = refine.match_silhouettes(pts, person)
    cells = np.floor(tgt2 / 2.0).astype(int)
    assert len(np.unique(cells, axis=0)) == len(cells) and len(tgt2) < len(tgt)
    # the left edge's 36 targets (x = 14, y = 12..47) fall into 18 cells of 2 px, each the mean of two
    left2 = np.abs(tgt2[:, 0] - 14) < 0.5
    # (the two corner cells also take top / bottom edge points)
    assert left2.sum() == 18 and np.allclose(np.sort(tgt2[left2, 1])[1:-1], np.arange(14.5, 46, 2))
    inner = left2 & (tgt2[:, 1] > 13) & (tgt2[:, 1] < 46)
    assert np.allclose(src2[inner, 0], 12) and np.allclose(src2[inner, 1], tgt2[inner, 1])


def test_match_silhouettes_distance_cut_and_empty_cases():
    person = np.zeros((80, 80), bool)
    person[30:50, 30:50] = True
    # points 20 px and 30 px from the boundary: the first matched, the second not (24 px)
    pts = np.array([[10.0, 40.0], [0.0, 40.0]])
    src, tgt = refine.match_silhouettes(pts, person)
    assert np.array_equal(src, [[10.0, 40.0]]) and np.array_equal(tgt, [[30.0, 40.0]])
    src, tgt = refine.match_silhouettes(pts, person, max_match_px=20.0)  # exactly 20: kept (<=)
    assert len(src) == 1
    src, tgt = refine.match_silhouettes(pts, person, max_match_px=19.5)
    assert src.shape == (0, 2) and tgt.shape == (0, 2)
    # a single point is matched
    assert np.array_equal(refine.match_silhouettes(pts[:1], person)[1], [[30.0, 40.0]])
    # no points, or no person: empty pairs
    for s, t in (refine.match_silhouettes(np.zeros((0, 2)), person),
                 refine.match_silhouettes(pts, np.zeros_like(person))):
        assert s.shape == (0, 2) and t.shape == (0, 2)
    assert refine.MAX_MATCH_PX == 24.0


def test_match_silhouettes_drops_a_pair_that_disagrees_with_its_neighbours():
    """A straight edge where all points are 2 px off except one 6 px off: that one pair is dropped."""
    person = np.zeros((80, 80), bool)
    person[10:70, 30:70] = True
    ys = np.arange(14, 66, 2, dtype=np.float64)
    pts = np.column_stack([np.full(len(ys), 28.0), ys])
    pts[12, 0] = 23.0  # 7 px from the edge, its neighbours 2 px
    src, tgt = refine.match_silhouettes(pts, person)
    assert len(src) == len(pts) - 1 and not (src[:, 0] == 23.0).any()
    assert np.allclose(src[:, 0], 28.0) and np.allclose(tgt[:, 0], 30.0)
    # a looser deviation keeps it; so does having no more pairs than neighbours (no test at all)
    assert len(refine.match_silhouettes(pts, person, max_deviation_px=6.0)[0]) == len(pts)
    few = pts[8:17]  # 9 pairs = neighbours
    assert len(refine.match_silhouettes(few, person)[0]) == 9
    assert len(refine.match_silhouettes(pts[8:18], person)[0]) == 9  # 10 pairs: tested, one dropped
    # the default deviation is 3 px: 3.5 px off the neighbours' median is dropped
    pts[12, 0] = 24.5
    assert len(refine.match_silhouettes(pts, person)[0]) == len(pts) - 1
    # a deviation exactly at the threshold is kept (<=): the outlier is 5 px off the median 2 px -> 3 px
    pts[12, 0] = 25.0
    assert len(refine.match_silhouettes(pts, person)[0]) == len(pts)


# --- Eq. 9 --------------------------------------------------------------------------------------------


def test_inverse_multiquadric_values():
    r = np.array([0.0, 3.0, 8.0, 99.0])
    assert np.allclose(refine.inverse_multiquadric(r), [1.0, 0.5, 1 / 3, 0.1])


def _eq9(p, targets, disp, sigma=refine.RBF_SIGMA_PX):
    """Eq. 9 written out at one pixel p (x, y)."""
    Phi = 1 / np.sqrt(1 + np.linalg.norm(targets[:, None] - targets[None], axis=2))
    c = np.linalg.solve(Phi, disp)
    d = np.linalg.norm(targets - p, axis=1)
    return (1 / np.sqrt(1 + d)) @ c * np.exp(-0.5 * d.min() ** 2 / sigma ** 2)


def test_rbf_warp_equals_eq9_at_every_pixel_of_the_band_and_zero_outside():
    targets = np.array([[20.0, 20.0], [30.0, 22.0], [25.0, 35.0], [50.0, 40.0]])
    disp = np.array([[1.0, -2.0], [0.5, 0.5], [-3.0, 1.0], [2.0, 2.0]])
    field = refine.silhouette_rbf_warp(targets, disp, (70, 90), chunk=97)
    assert field.shape == (70, 90, 2) and field.dtype == np.float32
    for x, y in [(20, 20), (50, 40), (24, 27), (35, 30), (10, 5), (60, 55), (40, 40), (58, 36)]:
        assert field[y, x] == pytest.approx(_eq9(np.array([x, y], float), targets, disp), abs=1e-5)
    assert np.allclose(field[[20, 22, 35, 40], [20, 30, 25, 50]], disp, atol=1e-5)
    # outside the 4.3 sigma band: exactly 0 (about 35.7 px from every target)
    yy, xx = np.mgrid[0:70, 0:90]
    dmin = np.min([np.hypot(xx - tx, yy - ty) for tx, ty in targets], axis=0)
    assert np.abs(field[dmin > 4.3 * refine.RBF_SIGMA_PX + 0.01]).max() == 0
    inside = dmin <= 4.3 * refine.RBF_SIGMA_PX - 0.01
    ref = np.array([_eq9(np.array([x, y], float), targets, disp) for y, x in zip(*np.nonzero(inside), strict=True)])
    assert np.abs(field[inside] - ref).max() < 1e-5
    # the chunk size changes nothing; a different sigma does
    assert np.array_equal(field, refine.silhouette_rbf_warp(targets, disp, (70, 90)))
    wide = refine.silhouette_rbf_warp(targets, disp, (70, 90), sigma_px=12.0)
    assert wide[30, 35] == pytest.approx(_eq9(np.array([35.0, 30.0]), targets, disp, 12.0), abs=1e-5)
    assert refine.RBF_SIGMA_PX == 8.3


def test_rbf_warp_of_no_points_is_zero_and_targets_off_the_image_are_clipped():
    assert np.array_equal(refine.silhouette_rbf_warp(np.zeros((0, 2)), np.zeros((0, 2)), (5, 6)),
                          np.zeros((5, 6, 2), np.float32))
    targets = np.array([[-3.0, 4.0], [8.0, 12.0]])  # one left of the image, one below it (H = 10)
    disp = np.array([[1.0, 0.0], [0.0, 1.0]])
    field = refine.silhouette_rbf_warp(targets, disp, (10, 8))
    assert field[4, 0] == pytest.approx(_eq9(np.array([0.0, 4.0]), targets, disp), abs=1e-5)
    assert field[9, 7] == pytest.approx(_eq9(np.array([7.0, 9.0]), targets, disp), abs=1e-5)


# --- warps and compositing ----------------------------------------------------------------------------


def test_warp_image_integer_shift_masks_nearest_and_outside():
    rng = np.random.default_rng(6)
    img = rng.random((20, 30, 3)).astype(np.float32)
    field = np.zeros((20, 30, 2), np.float32)
    field[..., 0] = 2.0
    field[..., 1] = -1.0
    out = refine.warp_image(img, field)
    assert np.allclose(out[1:, :28], img[:-1, 2:])
    assert np.abs(out[0]).max() == 0 and np.abs(out[:, 28:]).max() == 0
    # bool masks come back bool, sampled bilinearly and thresholded at 0.5
    m = np.zeros((20, 30), bool)
    m[5:10, 5:10] = True
    half = np.zeros((20, 30, 2), np.float32)
    half[..., 0] = 0.4
    wm = refine.warp_image(m, half)
    assert wm.dtype == np.bool_ and not wm[7, 4] and wm[7, 9] and wm[7, 5]  # x=4 samples 4.4: 0.4 < 0.5
    half[..., 0] = 0.6
    wm = refine.warp_image(m, half)
    assert wm[7, 4] and not wm[7, 9]  # x=4 samples 4.6: 0.6; x=9 samples 9.6: 0.4
    # exactly half covered (x=4 samples 4.5: 0.5) is not in the mask (> 0.5)
    half[..., 0] = 0.5
    assert not refine.warp_image(m, half)[7, 4]
    # nearest: no blending of depth values
    depth = np.zeros((4, 6), np.float32)
    depth[:, 3:] = 2.0
    f = np.zeros((4, 6, 2), np.float32)
    f[..., 0] = 0.4
    assert set(np.unique(refine.warp_image(depth, f, nearest=True))) == {0.0, 2.0}
    lin = refine.warp_image(depth, f)
    assert lin[0, 2] == pytest.approx(0.8)
    # a uint8 image stays uint8
    assert refine.warp_image((img * 255).astype(np.uint8), field).dtype == np.uint8


def test_concatenated_warps_compose_as_backward_maps():
    """first then second: out(p) = p + s(p) + f(p + s(p)); with f affine in x and y, the order matters."""
    H, W = 30, 40
    ys, xs = np.mgrid[0:H, 0:W].astype(np.float32)
    first = np.dstack([0.1 * xs, 0.05 * ys])
    second = np.zeros((H, W, 2), np.float32)
    second[..., 0] = 3.5
    second[..., 1] = 1.25
    c = refine.concatenate_warps(first, second)
    # bilinear sampling of an affine field is exact (nearest would be off by 0.05 / 0.0125)
    assert np.allclose(c[..., 0], 3.5 + 0.1 * np.clip(xs + 3.5, 0, W - 1), atol=1e-5)
    assert np.allclose(c[..., 1], 1.25 + 0.05 * np.clip(ys + 1.25, 0, H - 1), atol=1e-5)
    # replicated border: beyond the right / bottom edge first's last column / row is used
    assert c[5, W - 1, 0] == pytest.approx(3.5 + 0.1 * (W - 1))
    assert c[H - 1, 5, 1] == pytest.approx(1.25 + 0.05 * (H - 1))
    # applying the concatenation equals applying first, then second (exact on a linear image inside the frame)
    img = (0.3 * xs + 0.7 * ys).astype(np.float32)
    two = refine.warp_image(refine.warp_image(img, first), second)
    one = refine.warp_image(img, c)
    assert np.abs(one - two)[:26, :31].max() < 1e-3


def test_depth_composite_picks_the_nearer_layer_per_pixel():
    frame = np.full((2, 3, 3), 10, np.uint8)
    garment = np.full((2, 3, 3), 0.5)
    garment[0, 0] = [1.2, -0.1, 0.25]
    garment[1, 0] = 0.99  # 252.45 -> 252
    gmask = np.array([[True, True, True], [True, True, False]])
    gdepth = np.full((2, 3), 2.0)
    bdepth = np.array([[0.0, 1.5, 2.5], [2.0, 1.0, 1.0]])  # none, in front, behind, equal, in front, no garment
    out, show = refine.depth_composite(frame, garment, gmask, gdepth, bdepth)
    assert np.array_equal(show, [[True, False, True], [True, False, False]])
    assert out[0, 0].tolist() == [255, 0, 64] and out[0, 2].tolist() == [128] * 3 and out[1, 0].tolist() == [252] * 3
    assert (out[0, 1] == 10).all() and (out[1, 1] == 10).all() and (out[1, 2] == 10).all()
    assert out.dtype == np.uint8 and (frame == 10).all() and gmask[0, 1]  # inputs untouched
    # no garment and no body: not shown
    _, show3 = refine.depth_composite(frame, garment, gmask, gdepth, np.zeros((2, 3)))
    assert np.array_equal(show3, gmask)
    out2, show2 = refine.depth_composite(frame, garment, gmask, gdepth, bdepth, use_depth=False)
    assert np.array_equal(show2, gmask) and out2[0, 1].tolist() == [128] * 3
