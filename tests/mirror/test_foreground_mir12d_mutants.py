"""The graph cut's wiring after 7d01aec (helper mir12d), pinned for mutation testing (issue 17).

What ``_band_graph_cut`` hands its numba kernels (docs/mutation/mirror-foreground.md, "After mir12d"): the ring the
colour models are learnt from is the band dilated by a (4 band_px + 1) square (MIRFAST3), the data terms get the
background cue's gain ``4 background_weight`` and ``1 / (2 * 3 sigma^2)`` (three channels, §5.3), the unseen pixels
as ``extra`` and a 1x1 placeholder without them, and the person's depth is 0 (no depth term) when none of the sure
foreground is measured. Spies wrap the kernels; the cut itself is the kernels' (tests/mirror/test_foreground*.py).
"""

import numpy as np
from scipy import ndimage

from bodystudio.mirror import foreground as F

H, W = 60, 70


def _case(band_px=3):
    rows, cols = np.mgrid[0:H, 0:W]
    truth = (cols - 35) ** 2 + (rows - 30) ** 2 <= 14 ** 2
    rgb = np.empty((H, W, 3), np.uint8)
    rgb[...] = (40, 90, 200)
    rgb[truth] = (200, 60, 40)
    mask = (cols - 36) ** 2 + (rows - 30) ** 2 <= 13 ** 2  # misses the disc by about a pixel
    inner, band = F.foreground_band(mask, band_px)
    return rgb, mask, inner, band


def _spy(monkeypatch, name, seen, result=None):
    real = getattr(F, name)

    def spy(*args):
        seen.append(args)
        return real(*args) if result is None else result(*args)

    monkeypatch.setattr(F, name, spy)


def _cut(rgb, mask, inner, band, band_px=3, depth=None, background=None, weight=1.0, sigma=12.0, extra=None):
    return F._band_graph_cut(rgb, mask, inner, band, band_px, 5.0, depth, 3.0, 0.35, background, weight, sigma,
                             extra)


def test_the_colour_models_ring_is_the_band_dilated_by_a_4b_plus_1_square(monkeypatch):
    for band_px in (2, 3):
        rgb, mask, inner, band = _case(band_px)
        seen = []
        _spy(monkeypatch, "_ring_histograms", seen)
        _cut(rgb, mask, inner, band, band_px)
        near = seen[-1][1]
        want = ndimage.maximum_filter(band.astype(np.uint8), size=4 * band_px + 1, mode="constant")
        assert near.dtype == np.uint8 and np.array_equal(near > 0, want > 0)


def test_one_background_count_is_a_colour_model(monkeypatch):
    """The cut runs unless a ring is empty: a background ring of a single pixel still learns a model."""
    rgb, mask, inner, band = _case()
    counts = F._ring_histograms(rgb, F.cv2.dilate(band.view(np.uint8), np.ones((13, 13), np.uint8)),
                                inner.view(np.uint8), band.view(np.uint8))
    one = np.zeros_like(counts[1])
    one[np.argmax(counts[1])] = 1
    seen = []
    _spy(monkeypatch, "_ring_histograms", [], lambda *a: (counts[0], one))
    _spy(monkeypatch, "_band_pixels", seen)
    _cut(rgb, mask, inner, band)
    assert len(seen) == 1
    _spy(monkeypatch, "_ring_histograms", [], lambda *a: (counts[0], np.zeros_like(one)))
    assert np.array_equal(_cut(rgb, mask, inner, band), mask & band) and len(seen) == 1


def test_the_data_terms_get_the_background_gain_and_variance_and_the_unseen_pixels(monkeypatch):
    rgb, mask, inner, band = _case()
    seen = []
    _spy(monkeypatch, "_band_data_costs_z", seen)
    image = rgb.copy()
    valid = np.ones((H, W), bool)
    extra = band & ~mask
    _cut(rgb, mask, inner, band, background=(image, valid), weight=1.5, sigma=10.0, extra=extra)
    args = seen[-1]
    assert args[11] == 1.5 * 4.0 and args[12] == 1.0 / (2 * 3 * 10.0 ** 2)
    assert np.array_equal(args[13], extra.view(np.uint8)) and args[14] == F.UNSEEN_BACKGROUND_GAIN
    assert args[9] is image and np.array_equal(args[10], valid.view(np.uint8))
    _cut(rgb, mask, inner, band, background=(image, valid))  # no unseen pixels: a 1x1 placeholder (no extra gain)
    assert seen[-1][13].shape == (1, 1) and not seen[-1][13].any()
    _cut(rgb, mask, inner, band)  # no background: no gain
    assert seen[-1][11] == 0.0 and not seen[-1][10].any()


def test_no_measured_sure_foreground_means_no_depth_term(monkeypatch):
    rgb, mask, inner, band = _case()
    seen = []
    _spy(monkeypatch, "_band_data_costs_z", seen)
    depth = np.where(inner, 0.0, 2.0)  # the band measured, the sure foreground not
    _cut(rgb, mask, inner, band, depth=depth)
    assert np.array_equal(seen[-1][6], np.zeros(int(band.sum())))
    depth = np.where(inner, 1.5, 0.0)
    depth[inner.nonzero()[0][0], inner.nonzero()[1][0]] = 1.7
    _cut(rgb, mask, inner, band, depth=depth)
    assert np.all(seen[-1][6] == 1.5) and seen[-1][5] is depth


def test_box3_blurs_any_histogram_in_float32():
    """``_box3`` takes counts of any dtype and blurs them in float32, as ``colour_log_table`` always did."""
    h = np.arange(4096, dtype=np.float64).reshape(16, 16, 16) / 7.0
    got = F._box3(h)
    want = F._box3(h.astype(np.float32))
    assert got.dtype == np.float32 and np.array_equal(got, want)
    assert not np.array_equal(want.astype(np.float64), F._box3_axes(h.copy()))  # float64 sums differ
