"""The hem matte's parts on exact inputs (issue 17 on gar13e's code, branch mutI): the worn garment's colour model
against a written-out Bayes posterior and held-out error, its training sets' size limits, the matte's reach and
0.5 threshold on a given probability, and the composite of the matte. Milliseconds."""
import numpy as np
from scipy import ndimage

from bodystudio.garment import refine

BINS = (32, 32, 8)


def rect(shape, y0, y1, x0, x1):
    m = np.zeros(shape, bool)
    m[y0:y1, x0:x1] = True
    return m


def _bin_of(frame):
    """Each pixel's histogram bin: chromaticity r, g (32 bins each) and brightness (8), as the docstring says."""
    rgb = frame.astype(np.float64)
    total = rgb.sum(axis=2)
    r, g = rgb[..., 0] / np.maximum(total, 1.0), rgb[..., 1] / np.maximum(total, 1.0)
    b = total / 765.0
    idx = [np.clip((f * n).astype(int), 0, n - 1) for f, n in zip((r, g, b), BINS, strict=True)]
    return tuple(idx)


def _posterior(frame, train_in, train_out):
    """Bayes with equal priors of the two sides' smoothed (sigma 1 bin) normalised colour histograms."""
    idx = _bin_of(frame)
    dens = []
    for side in (train_in, train_out):
        hist = np.zeros(BINS)
        np.add.at(hist, tuple(i[side] for i in idx), 1.0)
        dens.append(ndimage.gaussian_filter(hist, 1.0) / side.sum())
    p = dens[0] / np.maximum(dens[0] + dens[1], 1e-12)
    return p[idx]


def _overlapping_actor(seed=0):
    """A 96 x 128 frame: the person's shown garment region is rows 8-60 (of 8-88, cols 16-112), its colours drawn
    from a blue and a skin-like cloud that overlap; the background grey."""
    rng = np.random.default_rng(seed)
    H, W = 96, 128
    person = rect((H, W), 8, 88, 16, 112)
    shown = rect((H, W), 8, 60, 16, 112)
    frame = np.full((H, W, 3), 128.0)
    frame[shown] = np.array([70.0, 90.0, 150.0]) + rng.normal(0, 25.0, (shown.sum(), 3))
    rest = person & ~shown
    frame[rest] = np.array([150.0, 110.0, 95.0]) + rng.normal(0, 25.0, (rest.sum(), 3))
    return np.clip(np.round(frame), 0, 255).astype(np.uint8), person, shown


def test_the_worn_probability_is_the_bayes_posterior_and_the_error_is_measured_on_held_out_blocks():
    frame, person, shown = _overlapping_actor()
    margin = 3.0
    cross = ndimage.generate_binary_structure(2, 1)
    inside = person & ndimage.binary_erosion(shown, cross, iterations=3)
    outside = person & ~ndimage.binary_dilation(shown, cross, iterations=3)
    ys, xs = np.indices(person.shape)
    even = (ys // 8 + xs // 8) % 2 == 0
    held = _posterior(frame, inside & even, outside & even)
    error = 0.5 * ((held[inside & ~even] < 0.5).mean() + (held[outside & ~even] >= 0.5).mean())
    want = np.where(person, _posterior(frame, inside, outside), 0.0)
    prob, err = refine.worn_garment_probability(frame, person, shown, margin)
    assert prob.dtype == np.float64 and prob.shape == person.shape
    np.testing.assert_allclose(prob, want, atol=1e-12)
    assert 0.02 < error < 0.3  # the clouds overlap: an error the model can get wrong
    assert abs(err - error) < 1e-12, (err, error)
    # a sharper model (the same posterior without smoothing) differs: the smoothing is part of the model
    assert np.abs(prob - np.where(person, _posterior_raw(frame, inside, outside), 0.0)).max() > 0.05


def _posterior_raw(frame, train_in, train_out):
    idx = _bin_of(frame)
    dens = []
    for side in (train_in, train_out):
        hist = np.zeros(BINS)
        np.add.at(hist, tuple(i[side] for i in idx), 1.0)
        dens.append(hist / side.sum())
    return (dens[0] / np.maximum(dens[0] + dens[1], 1e-12))[idx]


def test_colours_that_differ_only_in_green_chromaticity_are_told_apart():
    # same red chromaticity (1/3) and brightness (300 / 765): only the green chromaticity tells them apart
    H, W = 64, 64
    person = rect((H, W), 0, 64, 0, 64)
    shown = rect((H, W), 0, 32, 0, 64)
    frame = np.zeros((H, W, 3), np.uint8)
    frame[shown] = (100, 150, 50)
    frame[~shown] = (100, 50, 150)
    prob, err = refine.worn_garment_probability(frame, person, shown, 2.0)
    assert err == 0.0
    assert prob[shown].min() > 0.99 and prob[~shown].max() < 0.01


def _counted(n_in_missing_corner=True, outside_px=50):
    """A shown region whose interior (one 4-neighbour erosion) is 50 pixels (5 x 10) and a separate block of the
    rest of the actor of ``outside_px`` pixels; with its corner pixel gone, a square (8-neighbour) erosion would
    leave 49."""
    H, W = 40, 60
    shown = rect((H, W), 2, 9, 2, 14)  # 7 x 12: interior 5 x 10
    if n_in_missing_corner:
        shown[2, 2] = False
    other = rect((H, W), 20, 25, 30, 40) if outside_px == 50 else rect((H, W), 20, 25, 30, 39)
    person = shown | other
    frame = np.zeros((H, W, 3), np.uint8)
    frame[shown] = (40, 60, 140)
    frame[other] = (170, 120, 95)
    return frame, person, shown


def test_the_training_sets_need_fifty_pixels_each_eroded_along_four_neighbours_by_the_rounded_margin():
    frame, person, shown = _counted()
    inside = person & ndimage.binary_erosion(shown, ndimage.generate_binary_structure(2, 1))
    assert inside.sum() == 50
    prob1, err1 = refine.worn_garment_probability(frame, person, shown, 1.2)  # rounds to one step
    assert err1 < 0.5 and prob1[shown & inside].min() > 0.9 and prob1[~shown].max() < 0.1
    # 49 on the rest of the actor's side: no model, the probability all 0 (float, the frame's shape)
    frame, person, shown = _counted(outside_px=45)
    prob, err = refine.worn_garment_probability(frame, person, shown, 1.2)
    assert err == 0.5 and prob.dtype == np.float64 and prob.shape == person.shape and not prob.any()
    # a margin of 2 steps leaves 24 inside: no model
    frame, person, shown = _counted()
    assert refine.worn_garment_probability(frame, person, shown, 2.0)[1] == 0.5
    # a margin below half a pixel is still one step (not none: the garment's own edge pixels are not trained on)
    prob0, err0 = refine.worn_garment_probability(frame, person, shown, 0.2)
    assert err0 == err1 and np.array_equal(prob0, prob1)


def _band_case():
    """A torso (rows 10-70, cols 20-80) with an arm (rows 16-44, cols 80-118); worn: rows 10-50 of the torso and the
    arm to col 103 (exclusive); shown: the torso to row 58 (8 rows too long) and the arm to col 95 (8 columns
    short)."""
    H, W = 80, 120
    person = rect((H, W), 10, 70, 20, 80) | rect((H, W), 16, 44, 80, 118)
    worn = rect((H, W), 10, 50, 20, 80) | rect((H, W), 16, 44, 80, 103)
    shown = rect((H, W), 10, 58, 20, 80) | rect((H, W), 16, 44, 80, 95)
    return person, worn, shown


def _is_worn(matte, worn):
    """``matte`` is ``worn`` but for the corners of the worn region (the 5x5 median rounds them)."""
    np.testing.assert_array_equal(matte[:, 22:78], worn[:, 22:78])
    np.testing.assert_array_equal(matte[:, 80:100], worn[:, 80:100])
    np.testing.assert_array_equal(matte[24:36], worn[24:36])
    assert not matte[:, 103:].any()


def test_the_matte_reaches_exactly_reach_px_both_ways_on_a_given_probability():
    person, worn, shown = _band_case()
    matte = refine.hem_matte(shown, worn.astype(float), person, 8.0)
    _is_worn(matte, worn)  # 8 rows given up, 8 columns added: exactly the reach
    # one pixel less reach: row 50 (8 from the bare skin below) and row 57 (8 from the worn edge) stay; col 95
    # (8 from the bare arm) and col 102 (8 from the shown sleeve) are not added
    matte7 = refine.hem_matte(shown, worn.astype(float), person, 7.0)
    assert matte7[50, 22:78].all() and matte7[57, 22:78].all() and not matte7[51:57, 22:78].any()
    assert not matte7[24:36, 95].any() and not matte7[24:36, 102].any() and matte7[24:36, 96:102].all()


def test_a_probability_of_exactly_one_half_is_not_the_worn_garment():
    person, worn, shown = _band_case()
    prob = np.where(worn, 1.0, 0.5)
    _is_worn(refine.hem_matte(shown, prob, person, 8.0), worn)
    prob = np.full(person.shape, 0.5000001)  # just above: all of the person worn, the hem stays
    everything = refine.hem_matte(shown, prob, person, 8.0)
    assert everything[50:58, 22:78].all()


def test_the_matte_at_the_image_corner_changes_nothing_without_a_worn_edge_or_a_free_side():
    # the actor at the top-left corner, where a distance transform of a mask with no zero measures from beyond
    # the corner: the matte must not read that as an edge
    H, W = 40, 40
    person = rect((H, W), 0, 30, 0, 30)
    shown = rect((H, W), 0, 6, 0, 30)  # a short top within the reach of the corner
    np.testing.assert_array_equal(refine.hem_matte(shown, np.zeros((H, W)), person, 12.0), shown)  # none worn
    np.testing.assert_array_equal(refine.hem_matte(shown, np.ones((H, W)), person, 12.0), shown)  # all worn
    # the whole person shown (no bare part of the actor): nothing to move, whatever the video says
    half_worn = np.where(rect((H, W), 0, 30, 6, 30), 1.0, 0.0)
    np.testing.assert_array_equal(refine.hem_matte(person, half_worn, person, 12.0), person)
    # no garment shown: none added
    np.testing.assert_array_equal(refine.hem_matte(np.zeros_like(person), np.ones((H, W)), person, 12.0),
                                  np.zeros_like(person))


def test_a_colour_both_sides_share_equally_is_a_coin_toss_the_error_counts_as_half_wrong():
    # one colour everywhere; the training halves hold 64 and 128 pixels (powers of two: both densities are the same
    # number exactly), so every held-out posterior is exactly 0.5: a garment pixel at 0.5 is not called garment, a
    # pixel of the rest at 0.5 is: the balanced error is 0.5, neither 0 nor 1
    H, W = 25, 18
    person = np.ones((H, W), bool)
    shown = rect((H, W), 0, 10, 0, W)
    frame = np.full((H, W, 3), (40, 60, 140), np.uint8)
    prob, err = refine.worn_garment_probability(frame, person, shown, 1.0)
    assert err == 0.5
    np.testing.assert_allclose(prob, 0.5, atol=1e-12)


def test_the_composite_gives_up_adds_and_leaves_the_rest_as_it_was():
    H, W = 30, 40
    composite = np.full((H, W, 3), 7, np.uint8)
    frame = np.full((H, W, 3), 200, np.uint8)
    shown = rect((H, W), 5, 20, 5, 20)
    matte = rect((H, W), 5, 15, 5, 24)  # rows 15-19 given up, cols 20-23 added
    g_mask = rect((H, W), 5, 20, 5, 22)  # the layer reaches cols 20-21, not 22-23
    g_rgb = np.zeros((H, W, 3), np.float32)
    g_rgb[5:20, 5:21] = (0.6, 1.3, -0.2)  # out of [0, 1]: clipped
    g_rgb[5:20, 21] = (0.2, 0.4, 0.8)
    out = refine.composite_hem_matte(composite, frame, matte, shown, g_rgb, g_mask)
    removed = shown & ~matte
    added = matte & ~shown
    assert out.dtype == np.uint8
    np.testing.assert_array_equal(out[removed], frame[removed])
    np.testing.assert_array_equal(out[~removed & ~added], composite[~removed & ~added])
    np.testing.assert_array_equal(out[5:15, 20], np.tile([153, 255, 0], (10, 1)))
    for c in (21, 22, 23):  # the layer's own colour, then the nearest garment pixel's beyond it
        np.testing.assert_array_equal(out[5:15, c], np.tile([51, 102, 204], (10, 1)))
    # no garment layer at all: an added pixel keeps the composite
    out = refine.composite_hem_matte(composite, frame, matte, shown, g_rgb, np.zeros_like(g_mask))
    np.testing.assert_array_equal(out[added], composite[added])
    np.testing.assert_array_equal(out[removed], frame[removed])


def test_a_training_half_of_one_pixel_is_a_density_of_that_one_pixel():
    # the garment's interior (57 px) lies in an odd 8 px block but for one pixel, so the model the error is measured
    # with has one garment pixel to learn from: its density there is that pixel's own (divided by 1), and the
    # held-out garment pixels of the same colour are called garment however much of the rest shares it
    H, W = 48, 48
    person = np.ones((H, W), bool)
    shown = rect((H, W), 0, 9, 7, 17)
    shown[9, 8] = True  # keeps (8, 8), in an even block, through the erosion
    cross = ndimage.generate_binary_structure(2, 1)
    inside = ndimage.binary_erosion(shown, cross)
    ys, xs = np.indices((H, W))
    even = (ys // 8 + xs // 8) % 2 == 0
    assert inside.sum() == 57 and (inside & even).sum() == 1
    rng = np.random.default_rng(0)
    frame = np.where(rng.random((H, W, 1)) < 0.5, (40, 60, 140), (170, 120, 95)).astype(np.uint8)
    frame[inside] = (40, 60, 140)
    _, err = refine.worn_garment_probability(frame, person, shown, 1.0)
    assert err < 0.5  # the garment's held-out pixels all right, about half of the rest's wrong: ~0.25
