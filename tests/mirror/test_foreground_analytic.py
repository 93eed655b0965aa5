"""Foreground graph cut of §5.3 (Boykov and Jolly 2001) on small scenes whose answer is known.

A disc the player mask misses by a few pixels: where the colour (or depth, or the learnt background) tells
person from scene, each band pixel's strong data term decides its label and the cut is the true disc; the
colour model's histogram smoothing and the band geometry are checked against hand-computed values.
"""

import cv2
import numpy as np
import pytest

from bodystudio.errors import InputError
from bodystudio.mirror.compose import update_background
from bodystudio.mirror.foreground import (
    HIST_BINS,
    _band_links,
    _colour_index,
    colour_log_likelihood,
    colour_log_table,
    foreground_band,
    refine_foreground,
)

H, W = 80, 100


def _disc(cx=50, cy=40, r=20, h=H, w=W):
    rows, cols = np.mgrid[0:h, 0:w]
    return (cols - cx) ** 2 + (rows - cy) ** 2 <= r * r


def _scene(person=(200, 60, 40), scene=(40, 90, 200), noise=0, seed=0):
    truth = _disc()
    rgb = np.empty((H, W, 3), np.uint8)
    rgb[...] = scene
    rgb[truth] = person
    if noise:
        rng = np.random.default_rng(seed)
        rgb = np.clip(rgb + rng.integers(-noise, noise + 1, rgb.shape), 0, 255).astype(np.uint8)
    return rgb, truth


def test_colour_index_is_the_16_bin_quantisation():
    rgb = np.array([[[255, 0, 17], [16, 15, 240], [0, 0, 0]]], np.uint8)
    np.testing.assert_array_equal(_colour_index(rgb), [[15 * 256 + 0 + 1, 1 * 256 + 0 * 16 + 15, 0]])


def test_colour_table_is_the_box_blurred_histogram_plus_the_prior():
    """27 samples in bin (5, 6, 7): the 3x3x3 box blur puts 1 in each of the 27 bins around it, then every bin gets
    the prior 0.5; in a corner bin (0, 0, 0) only the 8 bins inside the cube receive their 1 (the rest falls off)."""
    n = HIST_BINS ** 3
    counts = np.zeros(n, int)
    counts[(5 * 16 + 6) * 16 + 7] = 27
    table = colour_log_table(counts)
    near = np.zeros((16, 16, 16), bool)
    near[4:7, 5:8, 6:9] = True
    total = 27 * 1.5 + (n - 27) * 0.5
    np.testing.assert_allclose(table[near.ravel()], np.log(1.5 / total), rtol=1e-6)
    np.testing.assert_allclose(table[~near.ravel()], np.log(0.5 / total), rtol=1e-6)
    corner = np.zeros(n, int)
    corner[0] = 27
    total = 8 * 1.5 + (n - 8) * 0.5
    t2 = colour_log_table(corner, prior_count=0.5)
    inside = np.zeros((16, 16, 16), bool)
    inside[:2, :2, :2] = True
    np.testing.assert_allclose(t2[inside.ravel()], np.log(1.5 / total), rtol=1e-6)
    np.testing.assert_allclose(t2[~inside.ravel()], np.log(0.5 / total), rtol=1e-6)
    # another prior count; the likelihood of samples is the table at their bins
    t3 = colour_log_table(counts, prior_count=2.0)
    np.testing.assert_allclose(t3[(5 * 16 + 6) * 16 + 7], np.log(3.0 / (27 * 3.0 + (n - 27) * 2.0)), rtol=1e-6)
    samples = np.full(27, (5 * 16 + 6) * 16 + 7)
    np.testing.assert_allclose(colour_log_likelihood(np.array([0, (5 * 16 + 6) * 16 + 7]), samples),
                               table[[0, (5 * 16 + 6) * 16 + 7]], rtol=1e-6)


def test_band_is_the_disc_dilation_minus_the_disc_erosion():
    mask = np.zeros((60, 60), bool)
    mask[20:40, 15:45] = True
    inner, band = foreground_band(mask, 3)
    want_inner = np.zeros_like(mask)
    want_inner[23:37, 18:42] = True
    np.testing.assert_array_equal(inner, want_inner)
    outer = band | inner
    assert outer[17:43, 15:45].all() and outer[20:40, 12:48].all()  # 3 px out along the sides
    assert not outer[16, 30] and not outer[30, 11]
    assert not outer[17, 12]  # the corner is rounded (disc of radius 3)
    assert not (band & inner).any()


def test_a_disc_the_mask_misses_by_3_px_is_recovered_exactly_by_colour():
    """Person and scene in distinct colours: each band pixel's data term decides, the cut is the true disc."""
    rgb, truth = _scene()
    player = np.roll(truth, (2, 3), axis=(0, 1))
    assert np.count_nonzero(player != truth) > 100
    for method in ("maxflow", "grabcut"):
        np.testing.assert_array_equal(refine_foreground(rgb, player, method=method), truth, err_msg=method)
    # a uint8 0/255 mask is the same mask
    np.testing.assert_array_equal(refine_foreground(rgb, player.astype(np.uint8) * 255), truth)
    # a band narrower than the miss leaves the far pixels as the mask says
    narrow = refine_foreground(rgb, player, band_px=1)
    assert np.count_nonzero(narrow != truth) > 20


def test_strong_data_terms_hold_against_any_smoothness():
    """Noisy colours (+-10 per channel): the cut is the disc to a few pixels with the default lambda, without the
    pairwise term, and with lambda 1e4 nats: the contrast-sensitive n-links across the colour edge weigh
    exp(-beta |I_p - I_q|^2) ~ 0, so a strong data term keeps its label whatever lambda."""
    rgb, truth = _scene(noise=10, seed=1)
    player = np.roll(truth, (-2, 2), axis=(0, 1))
    for smoothness in (5.0, 0.0, 1e4):
        assert np.count_nonzero(refine_foreground(rgb, player, smoothness=smoothness) != truth) <= 3, smoothness


def test_depth_decides_where_colour_cannot():
    """Person and scene the same grey: the depth term (person at 2 m, wall at 4 m) makes the cut; the band's
    wall pixels behind the person cost depth_weight as foreground, its person pixels as background."""
    rgb = np.full((H, W, 3), 128, np.uint8)
    rgb += np.random.default_rng(2).integers(0, 3, rgb.shape, dtype=np.uint8)  # texture, same for both
    truth = _disc()
    depth = np.where(truth, 2.0, 4.0)
    player = np.roll(truth, (3, -2), axis=(0, 1))
    cut = refine_foreground(rgb, player, depth, smoothness=0.5)
    np.testing.assert_array_equal(cut, truth)
    # unmeasured depth (0) gives no depth term: the cut stays near the mask
    none = refine_foreground(rgb, player, np.zeros((H, W)), smoothness=0.5)
    assert np.count_nonzero(none != truth) > 50
    # a person within the tolerance of the wall: depth says nothing either
    close = refine_foreground(rgb, player, np.where(truth, 2.0, 2.2), smoothness=0.5)
    assert np.count_nonzero(close != truth) > 50


def test_the_learnt_background_decides_where_colour_histograms_cannot():
    """Person and scene drawn from the same colours (random texture), the empty scene known: only the person
    differs from the background image."""
    rng = np.random.default_rng(3)
    palette = np.array([[200, 60, 40], [40, 90, 200]], np.uint8)
    empty = palette[rng.integers(0, 2, (H, W))]
    person = palette[rng.integers(0, 2, (H, W))]
    truth = _disc()
    rgb = np.where(truth[..., None], person, empty)
    # where the person's random texture equals the scene behind, no cue can tell them apart: score those out
    same = truth & np.all(person == empty, axis=2)
    player = np.roll(truth, (2, 2), axis=(0, 1))
    background = update_background(None, empty, np.zeros((H, W), bool))
    cut = refine_foreground(rgb, player, background=background, smoothness=0.5)
    decided = ~same
    assert np.count_nonzero((cut != truth) & decided) <= 3
    plain = refine_foreground(rgb, player, smoothness=0.5)
    assert np.count_nonzero((plain != truth) & decided) > 20


def test_unseen_pixels_near_the_mask_join_the_band():
    """The left 12 columns of the disc are outside the depth view (no player mask there): with them marked
    unseen the colour cut completes the disc; beyond unseen_reach_px they are left out."""
    rgb, truth = _scene()
    cut_col = 42
    player = truth.copy()
    player[:, :cut_col] = False
    unseen = np.zeros_like(truth)
    unseen[:, :cut_col] = True
    np.testing.assert_array_equal(refine_foreground(rgb, player, unseen=unseen), truth)
    short = refine_foreground(rgb, player, unseen=unseen, unseen_reach_px=3)
    assert not short[:, :cut_col - 10].any()
    assert np.count_nonzero(short != truth) > 50
    with pytest.raises(InputError, match="unseen mask"):
        refine_foreground(rgb, player, unseen=unseen[:10])


def test_a_disc_at_the_image_border_and_a_mask_too_thin_for_a_colour_model():
    rgb, truth = _scene()
    rgb = np.ascontiguousarray(rgb[:, 35:])  # the disc touches the left border
    truth = np.ascontiguousarray(truth[:, 35:])
    player = np.roll(truth, (0, 2), axis=(0, 1))
    np.testing.assert_array_equal(refine_foreground(rgb, player), truth)
    # a 4 px wide strip with band 6 has no sure interior: no foreground model, the mask comes back unchanged
    thin = np.zeros((H, W), bool)
    thin[20:60, 40:44] = True
    np.testing.assert_array_equal(refine_foreground(_scene()[0], thin), thin)
    with pytest.raises(InputError, match="band_px must lie in 1..64"):
        refine_foreground(rgb, player, band_px=65)
    assert refine_foreground(rgb, player, band_px=64).shape == player.shape


def test_cv2_morphology_is_a_disc_of_radius_band_px():
    """foreground_band's structuring element: a disc (ellipse) of radius band_px, so 45 degree corners are cut."""
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (13, 13))
    assert k.shape == (13, 13) and k[6].all() and not k[0, 0]


def test_input_checks_name_the_shapes():
    rgb, truth = _scene()
    with pytest.raises(InputError, match=r"needs an \(H, W, 3\) uint8 colour image, got \(80, 100\) uint8"):
        refine_foreground(rgb[..., 0], truth)
    with pytest.raises(InputError, match=r"player mask \(80, 99\) must match the colour image \(80, 100\)$"):
        refine_foreground(rgb, truth[:, 1:])
    with pytest.raises(InputError, match=r"depth \(80, 99\) must be registered to colour \(80, 100\)$"):
        refine_foreground(rgb, truth, np.zeros((80, 99)))
    with pytest.raises(InputError, match=r"^foreground method 'watershed'; valid: maxflow, grabcut$"):
        refine_foreground(rgb, truth, method="watershed")
    # the colour likelihood passes its prior on
    samples = np.full(27, 7)
    np.testing.assert_allclose(colour_log_likelihood(np.array([7, 2000]), samples, prior_count=3.0),
                               colour_log_table(np.bincount(samples, minlength=4096), 3.0)[[7, 2000]], rtol=1e-6)


def test_unseen_reach_is_exact_and_unseen_may_be_0_1_integers():
    """The person reaches 12 px left of (and 12 px above) the depth camera's view: unseen_reach_px 12 completes
    the disc exactly, whichever way the view is cut; the unseen mask may be given as 0 / 1 integers; a negative
    reach is 0 (no extension)."""
    rgb, truth = _scene()  # disc x 30..70, y 20..60
    for axis in (1, 0):
        player = truth.copy()
        unseen = np.zeros_like(truth)
        if axis == 1:
            player[:, :42] = False
            unseen[:, :42] = True
        else:
            player[:32] = False
            unseen[:32] = True
        np.testing.assert_array_equal(refine_foreground(rgb, player, unseen=unseen, unseen_reach_px=12), truth)
        np.testing.assert_array_equal(refine_foreground(rgb, player, unseen=unseen.astype(np.uint8),
                                                        unseen_reach_px=12), truth)
        np.testing.assert_array_equal(refine_foreground(rgb, player, unseen=unseen, unseen_reach_px=-5),
                                      refine_foreground(rgb, player))


def test_a_disc_at_the_top_border_is_refined_up_to_row_0():
    rgb, truth = _scene()
    rgb = np.ascontiguousarray(rgb[25:])  # the disc (y 20..60) now starts at row 0
    truth = np.ascontiguousarray(truth[25:])
    player = np.roll(truth, (2, 0), axis=(0, 1))
    player[:2] = False
    np.testing.assert_array_equal(refine_foreground(rgb, player), truth)


@pytest.mark.parametrize("person_m, holes", [(0.8, 0.0), (2.0, 0.6)])
def test_the_persons_depth_is_the_median_of_the_measured_pixels(person_m, holes):
    """A person 0.8 m away, and one at 2 m with 60 % of their depth pixels unmeasured (0): the median of the
    measured pixels is the person's depth either way, and the depth term cuts the grey scene."""
    rgb = np.full((H, W, 3), 128, np.uint8)
    rgb += np.random.default_rng(2).integers(0, 3, rgb.shape, dtype=np.uint8)
    truth = _disc()
    depth = np.where(truth, person_m, person_m + 2.0)
    depth[truth & (np.random.default_rng(4).random((H, W)) < holes)] = 0.0
    player = np.roll(truth, (3, -2), axis=(0, 1))
    cut = refine_foreground(rgb, player, depth, smoothness=0.5)
    # holes in the band carry no depth term: score the measured pixels
    measured = depth > 0
    assert np.count_nonzero((cut != truth) & measured) <= 2


def test_method_grabcut_runs_grabcut_on_the_band_and_defaults_matter():
    """method="grabcut" is OpenCV's GrabCut on the same sure / probable labels (inner | GrabCut's band labels, to
    the few pixels its random k-means start moves), not the max-flow cut;
    the default band is 6 px (a mask 7 px off is not fully fixed, band_px 7 fixes it) and the default depth
    tolerance 0.35 m (a wall 0.8 m behind the person is "behind"; with a 1.35 m tolerance it is not)."""
    from bodystudio.mirror.foreground import _grabcut

    rgb, truth = _scene(scene=(120, 70, 60), noise=60, seed=5)  # colours close enough for the two cuts to differ
    player = np.roll(truth, (2, 3), axis=(0, 1))
    x, y, w, h = cv2.boundingRect(player.astype(np.uint8))
    crop = (slice(max(y - 20, 0), min(y + h + 20, H)), slice(max(x - 20, 0), min(x + w + 20, W)))  # pad 3 * 6 + 2
    inner, band = foreground_band(player[crop], 6)
    want = player.copy()
    want[crop] = inner | _grabcut(rgb[crop], inner, band)
    cut = refine_foreground(rgb, player, method="grabcut")  # GrabCut's k-means start draws from OpenCV's RNG
    assert np.count_nonzero(cut != want) <= 6
    assert np.count_nonzero(refine_foreground(rgb, player) != cut) > 5
    rgb, truth = _scene()
    off7 = np.roll(truth, (0, 7), axis=(0, 1))
    assert np.count_nonzero(refine_foreground(rgb, off7) != truth) > 0
    np.testing.assert_array_equal(refine_foreground(rgb, off7, band_px=7), truth)
    grey = np.full((H, W, 3), 128, np.uint8) + np.random.default_rng(2).integers(0, 3, (H, W, 3), dtype=np.uint8)
    depth = np.where(truth, 2.0, 2.8)
    player = np.roll(truth, (3, -2), axis=(0, 1))
    default = refine_foreground(grey, player, depth, smoothness=0.5)
    np.testing.assert_array_equal(default, truth)
    assert np.count_nonzero(refine_foreground(grey, player, depth, smoothness=0.5, depth_tol_m=1.35) != truth) > 20


def _n_links_reference(rgb, node, inner, br, bc, smoothness, source, sink):
    """Boykov-Jolly's n-links written out: beta over every (ordered) neighbour pair of a band pixel, each band-band
    pair once (right and down), a sure-interior neighbour's weight onto the source, an outside one's onto the sink."""
    h, w = node.shape
    offsets = ((0, 1), (1, 0), (0, -1), (-1, 0))
    img = rgb.astype(float)
    d2 = [[float(np.sum((img[r, c] - img[r + dy, c + dx]) ** 2)) if 0 <= r + dy < h and 0 <= c + dx < w else None
           for dy, dx in offsets] for r, c in zip(br, bc, strict=True)]
    seen = [v for row in d2 for v in row if v is not None]
    beta = 1.0 / (2.0 * max(sum(seen) / max(len(seen), 1), 1e-6))
    edges = []
    for k, (r, c) in enumerate(zip(br, bc, strict=True)):
        for o, (dy, dx) in enumerate(offsets):
            if d2[k][o] is None:
                continue
            wgt = smoothness * np.exp(-beta * d2[k][o])
            other = node[r + dy, c + dx]
            if other >= 0:
                if o < 2:
                    edges.append((k, other, wgt))
            elif inner[r + dy, c + dx]:
                source[k] += wgt
            else:
                sink[k] += wgt
    return edges


def test_band_links_are_the_contrast_sensitive_n_links_of_the_band():
    """:func:`_band_links` (numba; MIRFAST2 skips the weight of a band-band pair seen from its second pixel) against
    the n-links written out, on a random image with a ring-shaped band touching the image border."""
    rng = np.random.default_rng(11)
    h, w = 23, 31
    rgb = rng.integers(0, 256, (h, w, 3), np.uint8)
    yy, xx = np.mgrid[:h, :w]
    radius = np.hypot(yy - 10.0, xx - 6.0)
    inner = radius < 5
    band = (radius >= 5) & (radius < 9)
    br, bc = np.nonzero(band)
    node = np.full((h, w), -1, np.int64)
    node[br, bc] = np.arange(len(br))
    source, sink = rng.uniform(0, 1, len(br)), rng.uniform(0, 1, len(br))
    ref_source, ref_sink = source.copy(), sink.copy()
    i, j, cap = _band_links(rgb, node, inner, br, bc, 5.0, source, sink)
    edges = _n_links_reference(rgb, node, inner, br, bc, 5.0, ref_source, ref_sink)
    assert len(edges) > 50 and (bc == 0).any()
    np.testing.assert_array_equal(i, [e[0] for e in edges])
    np.testing.assert_array_equal(j, [e[1] for e in edges])
    np.testing.assert_allclose(cap, [e[2] for e in edges], rtol=1e-12)
    np.testing.assert_allclose(source, ref_source, rtol=1e-12)
    np.testing.assert_allclose(sink, ref_sink, rtol=1e-12)
