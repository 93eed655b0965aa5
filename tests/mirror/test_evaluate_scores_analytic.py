"""Analytic tests of the mirror scores (bodystudio.mirror.evaluate; issue 17): hand-made masks and images whose
IoU, band, SSIM (Eq. 13 of Wang et al. 2004) and PSNR have a closed form, and the edits / JSON helpers."""

import math

import numpy as np
import pytest

from bodystudio.errors import InputError
from bodystudio.mirror import evaluate as ev

SIGMA = 1.5


def _gauss_taps(sigma=SIGMA, radius=5):
    g = np.exp(-np.arange(-radius, radius + 1) ** 2 / (2 * sigma**2))
    return g / g.sum()


# ------------------------------------------------------------------------------------------------ IoU

def test_mask_iou_counts_pixels():
    a = np.zeros((30, 40), bool)
    a[5:15, 5:25] = True  # 200 px
    b = np.zeros_like(a)
    b[10:20, 5:25] = True  # 200 px, 100 shared
    assert ev.mask_iou(a, b) == pytest.approx(100 / 300, abs=1e-15)
    assert ev.mask_iou(a, np.zeros_like(a)) == 0.0
    assert ev.mask_iou(np.zeros_like(a), np.zeros_like(a)) == 1.0
    # 0/255 images count as masks
    assert ev.mask_iou(a.astype(np.uint8) * 255, b.astype(np.uint8) * 255) == pytest.approx(1 / 3, abs=1e-15)


# ----------------------------------------------------------------------------------------------- band

def test_person_band_is_the_union_dilated_by_a_disc_of_band_px():
    src = np.zeros((61, 61), bool)
    src[30, 20] = True
    tgt = np.zeros_like(src)
    tgt[30, 40] = True
    band = ev.person_band(src, tgt, 4)
    import cv2

    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (9, 9)) > 0
    want = np.zeros_like(src)
    want[26:35, 16:25] |= disc
    want[26:35, 36:45] |= disc
    np.testing.assert_array_equal(band, want)
    # 4 px along the axes is in, 5 is not, and the 4-4 diagonal (5.7 px) is not
    assert band[30, 24] and band[30, 16] and band[26, 20] and band[34, 40]
    assert not band[30, 25] and not band[25, 20] and not band[26, 24] and not band[30, 30]
    far = np.zeros_like(src)
    far[30, 50] = True  # 30 px from the source pixel: the two default (10 px) discs do not touch
    disc10 = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (21, 21)) > 0
    assert ev.person_band(src, far).sum() == 2 * disc10.sum()
    assert ev.person_band(src, tgt, 0).sum() == 2 and ev.BAND_PX == 10


# ----------------------------------------------------------------------------------------------- SSIM

def _ssim_const(ma, mb, syy=0.0, sxx=0.0, sxy=0.0, data_range=255.0):
    c1, c2 = (0.01 * data_range) ** 2, (0.03 * data_range) ** 2
    return ((2 * ma * mb + c1) * (2 * sxy + c2)) / ((ma * ma + mb * mb + c1) * (sxx + syy + c2))


def test_ssim_of_flat_images_is_the_luminance_term():
    a = np.full((20, 24), 100.0)
    b = np.full((20, 24), 140.0)
    np.testing.assert_allclose(ev.ssim_map(a, b), _ssim_const(100.0, 140.0), atol=1e-12)
    np.testing.assert_allclose(ev.ssim_map(a / 255.0, b / 255.0, data_range=1.0),
                               _ssim_const(100 / 255, 140 / 255, data_range=1.0), atol=1e-12)
    np.testing.assert_allclose(ev.ssim_map(a, a), 1.0, atol=1e-12)
    assert ev.ssim_map(a, b).shape == (20, 24)


def test_ssim_is_averaged_over_the_colour_channels():
    a = np.full((20, 24, 3), 100.0)
    b = a.copy()
    b[..., 1] = 140.0
    np.testing.assert_allclose(ev.ssim_map(a, b), (2.0 + _ssim_const(100.0, 140.0)) / 3.0, atol=1e-12)
    with pytest.raises(InputError, match="differ in shape"):
        ev.ssim_map(a, b[:, :-1])


@pytest.mark.parametrize("sigma", [1.5, 2.5])
def test_ssim_of_an_impulse_uses_the_11_tap_gaussian_window(sigma):
    """b = a + delta at one pixel: in the 11x11 Gaussian window the pixel has weight w = g(dy) g(dx), so
    my = a + w delta, syy = w delta^2 - (w delta)^2, sxx = sxy = 0 (Eq. 13 with local statistics)."""
    a = np.full((41, 41), 90.0)
    b = a.copy()
    b[20, 20] += 60.0
    S = ev.ssim_map(a, b) if sigma == 1.5 else ev.ssim_map(a, b, sigma=sigma)
    g = _gauss_taps(sigma)
    for dy, dx in ((0, 0), (0, 1), (2, 3), (5, 0)):
        w = g[5 + dy] * g[5 + dx]
        want = _ssim_const(90.0, 90.0 + w * 60.0, syy=w * 60.0**2 - (w * 60.0) ** 2)
        assert S[20 + dy, 20 + dx] == pytest.approx(want, abs=1e-9), (dy, dx)
    assert S[20, 26] == pytest.approx(1.0, abs=1e-12) and S[27, 20] == pytest.approx(1.0, abs=1e-12)


def test_ssim_of_an_edge_at_the_border_reflects_the_image():
    """An impulse on the first column: cv2's BORDER_REFLECT mirrors it onto itself, so in the window of the
    corner pixel it counts twice in the column direction."""
    a = np.full((30, 30), 90.0)
    b = a.copy()
    b[15, 0] += 60.0
    g = _gauss_taps()
    w = g[5] * (g[5] + g[4])  # the pixel itself (g0 g0) and its reflection on column -1 (g0 g1)
    want = _ssim_const(90.0, 90.0 + w * 60.0, syy=w * 60.0**2 - (w * 60.0) ** 2)
    assert ev.ssim_map(a, b)[15, 0] == pytest.approx(want, abs=1e-9)


def test_ssim_structure_term_sees_a_correlated_change():
    """b = 2a - mean: the same structure with twice the contrast: sxy = 2 sxx, syy = 4 sxx, my = mx."""
    rng = np.random.default_rng(0)
    a = 100.0 + 20.0 * rng.standard_normal((40, 40))
    b = 2.0 * a - 100.0
    S = ev.ssim_map(a, b)
    import cv2

    def blur(x):
        return cv2.GaussianBlur(x, (11, 11), SIGMA, borderType=cv2.BORDER_REFLECT)

    mx = blur(a)
    sxx = blur(a * a) - mx * mx
    want = _ssim_const(mx, 2 * mx - 100.0, sxx=sxx, syy=4 * sxx, sxy=2 * sxx)
    np.testing.assert_allclose(S, want, atol=1e-9)
    assert 0.5 < S.mean() < 0.95


# ----------------------------------------------------------------------------------------------- PSNR

def test_psnr_is_pooled_over_the_values():
    assert ev.psnr_from_sse(4 * 25.5**2, 4) == pytest.approx(20.0, abs=1e-12)
    assert ev.psnr_from_sse(2 * 0.1**2, 2, data_range=1.0) == pytest.approx(20.0, abs=1e-12)
    assert ev.psnr_from_sse(0.0, 5) == math.inf
    assert math.isnan(ev.psnr_from_sse(0.0, 0))
    assert ev.psnr_from_sse(3 * 255.0**2, 3) == pytest.approx(0.0, abs=1e-12)


# ------------------------------------------------------------------------------------------------ edits

def test_nonzero_edits_keep_the_set_ones_as_floats():
    assert ev._nonzero({"taller": 0.15, "wider": 0.0, "heavier": "0", "arms": -2}) == {"taller": 0.15, "arms": -2.0}
    out = ev._nonzero({"taller": "tall", 3: None})
    assert list(out) == ["taller", "3"] and all(math.isnan(v) for v in out.values())
    assert ev._nonzero(None) == {} and ev._nonzero([("taller", 1.0)]) == {}


def test_strict_json_scores_clean_nested_values_and_keep_the_identical_flag():
    out = ev.strict_json_scores({"a": [1.0, float("nan"), (np.float32(2.5), -math.inf)], "b": {"c": np.int32(4)},
                                 "s": "x", "n": None, "t": True})
    assert out == {"a": [1.0, None, [2.5, None]], "b": {"c": 4}, "s": "x", "n": None, "t": True}
    assert type(out["b"]["c"]) is int and type(out["a"][2][0]) is float
    assert "psnr_person_identical" not in out
    assert ev.strict_json_scores({"psnr_person": -math.inf})["psnr_person_identical"] is False
    assert ev.strict_json_scores({"psnr_person": np.float64(np.inf)})["psnr_person_identical"] is True
    # already strict: the flag stays as it was
    assert ev.strict_json_scores({"psnr_person": None, "psnr_person_identical": True})["psnr_person_identical"]
    assert ev.strict_json_scores({"psnr_person": None})["psnr_person_identical"] is False
    assert ev.strict_json_scores({"psnr_person": None, "psnr_person_identical": False})["psnr_person_identical"] \
        is False


def test_masks_of_any_nonzero_value_and_images_of_any_dtype_score_the_same():
    """A mask is its nonzero pixels whatever its dtype (0/128 uint8, 0/1 float), and SSIM of uint8 images (what
    the run's PNGs are) is that of the same values as floats: no uint8 overflow in the squares."""
    a = np.zeros((30, 40), bool)
    a[5:15, 5:25] = True
    b = np.zeros_like(a)
    b[10:20, 5:25] = True
    half = np.uint8(128)  # its lowest bit is 0: a bitwise AND with True would drop it
    assert ev.mask_iou(a, b.astype(np.uint8) * half) == pytest.approx(1 / 3, abs=1e-15)
    assert ev.mask_iou(a.astype(np.uint8) * half, b) == pytest.approx(1 / 3, abs=1e-15)
    np.testing.assert_array_equal(ev.person_band(a.astype(float), b.astype(float), 3), ev.person_band(a, b, 3))
    rng = np.random.default_rng(1)
    x = rng.integers(0, 256, (32, 32, 3)).astype(np.uint8)
    y = np.clip(x.astype(int) + rng.integers(-40, 41, x.shape), 0, 255).astype(np.uint8)
    np.testing.assert_allclose(ev.ssim_map(x, y), ev.ssim_map(x.astype(float), y.astype(float)), atol=1e-9)
    np.testing.assert_allclose(ev.ssim_map(x.astype(float), y), ev.ssim_map(x.astype(float), y.astype(float)),
                               atol=1e-9)
