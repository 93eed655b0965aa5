"""Background subtraction (Horprasert et al. 1999, as cleaned in Rapid Skin Sec. V.A) on cases with one
right answer: a subject darker than any shadow, specks, small holes, big gaps and companions."""

import numpy as np
import pytest

from bodystudio.capture.silhouettes import (
    SegmentationParams,
    background_model,
    clean_mask,
    fill_small_holes,
    foreground_pixels,
    largest_components,
    mask_iou,
    segment_silhouette,
)

SIZE = 320  # 102400 px: the default max_hole_fraction 1e-4 fills holes up to 10 px
SKIN = (220, 60, 30)  # channel ratios beyond any background block's (grey levels 70-140): never a shadow of one


def _noisy(image, rng, sigma=2.0):
    return np.clip(np.round(image + rng.normal(0, sigma, image.shape)), 0, 255).astype(np.uint8)


@pytest.fixture(scope="module")
def studio():
    """A blocky coloured background (grey levels 70-140, so highlights do not saturate) and its model."""
    rng = np.random.default_rng(11)
    plate = np.kron(rng.uniform(70, 140, (8, 8, 3)), np.ones((SIZE // 8, SIZE // 8, 1)))
    model = background_model([_noisy(plate, rng) for _ in range(6)])
    return plate, model


def _subject():
    truth = np.zeros((SIZE, SIZE), bool)
    truth[60:260, 110:210] = True
    return truth


@pytest.mark.parametrize("factor", [0.15, 0.3, 0.4])
def test_a_subject_darker_than_any_shadow_is_foreground(studio, factor):
    """Same chromaticity as the background (CD ~ 0) but darker than a shadow can make it: the
    shadow-floor rule alone makes it foreground; a shadow (0.6) beside it stays background."""
    plate, model = studio
    rng = np.random.default_rng(12)
    truth = _subject()
    image = plate.copy()
    image[:, :100] *= 0.6  # a cast shadow
    image[truth] *= factor
    seg = segment_silhouette(_noisy(image, rng), model)
    assert mask_iou(seg, truth) > 0.99, mask_iou(seg, truth)
    raw = foreground_pixels(_noisy(image, rng), model)
    assert raw[:, :100].mean() < 0.001


def test_a_subject_brighter_than_a_highlight_is_foreground(studio):
    plate, model = studio
    truth = _subject()
    image = plate.copy()
    image[:, 240:] *= 1.3  # a highlight stays background
    image[truth] *= 1.8
    seg = segment_silhouette(_noisy(image, np.random.default_rng(13)), model)
    assert mask_iou(seg, truth) > 0.99, mask_iou(seg, truth)


def test_shadow_thresholds_are_brightness_ratios(studio):
    plate, model = studio
    params = SegmentationParams()
    for factor, fg in [(0.5, False), (0.4, True), (1.5, False), (1.7, True)]:
        raw = foreground_pixels(plate * factor, model, params)
        assert raw.mean() == (1.0 if fg else 0.0), (factor, raw.mean())


def test_specks_are_dropped_and_a_large_companion_kept(studio):
    plate, model = studio
    rng = np.random.default_rng(14)
    truth = _subject()
    companion = np.zeros_like(truth)
    companion[20:70, 240:290] = True  # 2500 px, 12.5 % of the subject: a second person / prop kept
    image = plate.copy()
    image[truth | companion] = SKIN
    small = np.zeros_like(truth)
    small[250:290, 20:60] = True  # 1600 px, 8 % of the subject: dropped
    image[small] = (40, 160, 60)
    for r, c in rng.integers(10, SIZE - 10, (40, 2)):
        if not (truth | companion | small)[r - 3:r + 4, c - 3:c + 4].any():
            image[r:r + 3, c:c + 3] = (250, 20, 250)  # 3x3 specks
    raw = foreground_pixels(_noisy(image, rng), model)
    assert raw.sum() > (truth | companion | small).sum() + 200  # the specks are in the raw foreground
    seg = segment_silhouette(_noisy(image, rng), model)
    assert mask_iou(seg, truth | companion) > 0.995, mask_iou(seg, truth | companion)


def test_largest_components_thresholds():
    mask = np.zeros((100, 100), bool)
    mask[10:60, 10:60] = True  # 2500
    mask[70:90, 70:90] = True  # 400: 16 % of the largest, kept
    mask[5:15, 80:90] = True  # 100: 4 %, dropped
    mask[95:98, 0:3] = True  # 9 px
    keep = largest_components(mask)
    assert keep[10:60, 10:60].all() and keep[70:90, 70:90].all() and keep.sum() == 2900
    assert largest_components(mask, 0.03).sum() == 3000
    assert largest_components(mask, 0.0, min_px=9).sum() == 3009
    assert largest_components(mask, 0.0, min_px=101).sum() == 2900
    assert not largest_components(np.zeros((10, 10), bool)).any()
    diagonal = np.eye(60, dtype=bool)  # one 8-connected component of 60 px
    assert largest_components(diagonal, min_px=50).sum() == 60


def test_small_holes_are_filled_big_gaps_and_border_notches_stay(studio):
    plate, model = studio
    rng = np.random.default_rng(15)
    truth = _subject()
    image = plate.copy()
    image[truth] = SKIN
    hole = np.zeros_like(truth)
    hole[100:103, 150:153] = True  # 9 px inside the subject: filled
    gap = np.zeros_like(truth)
    gap[150:155, 140:145] = True  # 25 px: the gap between an arm and the torso, stays background
    image[hole | gap] = plate[hole | gap]
    seg = segment_silhouette(_noisy(image, rng), model)
    assert seg[hole].all()
    assert not seg[gap].any()
    assert mask_iou(seg, truth & ~gap) > 0.995


def test_fill_small_holes_only_fills_enclosed_regions():
    mask = np.zeros((40, 40), bool)
    mask[5:35, 5:35] = True
    mask[10:12, 10:12] = False  # 4 px enclosed
    mask[20:24, 20:24] = False  # 16 px enclosed
    mask[0:40, 0:3] = False
    notch = np.zeros_like(mask)
    notch[5:7, 15:17] = True
    mask[notch] = False  # touching the outer background (4-connected)
    out = fill_small_holes(mask, 4)
    assert out[10:12, 10:12].all() and not out[20:24, 20:24].any() and not out[notch].any()
    assert fill_small_holes(mask, 16)[20:24, 20:24].all()
    assert not fill_small_holes(mask, 3)[10:12, 10:12].any()
    assert not out[:, :5].any()
    for border in (np.s_[0:3, 18:20], np.s_[37:40, 18:20], np.s_[18:20, 37:40], np.s_[18:20, 0:3]):
        m = np.ones((40, 40), bool)
        m[border] = False  # a small notch on each image border: not a hole
        assert not fill_small_holes(m, 100)[border].any()


def test_clean_mask_opening_and_closing():
    mask = np.zeros((60, 60), bool)
    mask[10:50, 10:50] = True
    mask[10:50, 29:31] = False  # a 2 px slit: closing joins it
    mask[55, 55] = True
    closed = clean_mask(mask, SegmentationParams(close_px=5, max_hole_fraction=0.0))
    assert closed[20:40, 29:31].all()
    opened = clean_mask(mask, SegmentationParams(open_px=5, min_component_px=1, min_component_fraction=0.0))
    assert not opened[55, 55]
    plain = clean_mask(mask, SegmentationParams(min_component_px=1, min_component_fraction=0.0))
    assert plain[55, 55] and not plain[20:40, 29:31].any()


def test_background_model_statistics_and_floors():
    rng = np.random.default_rng(16)
    plate = rng.uniform(60, 200, (30, 40, 3))
    frames = [plate + rng.normal(0, 5.0, plate.shape) for _ in range(40)]
    model = background_model(frames)
    assert model.n_frames == 40 and model.shape == (30, 40)
    np.testing.assert_allclose(model.mean, np.mean(frames, 0), rtol=1e-5)
    assert abs(np.median(model.std) / 5.0 - 1.0) < 0.05
    raw_std = np.std(frames, 0, ddof=1)
    np.testing.assert_allclose(model.std, np.maximum(raw_std, np.median(raw_std)), rtol=1e-5)  # median floor
    # training frames are within the noise: CD rms about chi_2's sqrt(2) times (n-1)/n, alpha rms ~ s/|E|
    assert 1.2 < model.cd_rms < 1.45 and model.alpha_rms < 0.1
    still = background_model([plate, plate, plate])  # identical frames: std floor 1, rms floors
    np.testing.assert_allclose(still.std, 1.0)
    assert still.cd_rms == 1.0 and still.alpha_rms == pytest.approx(1e-3)
    single = background_model([plate], single_frame_std=3.0)
    np.testing.assert_allclose(single.std, 3.0)
    assert single.cd_rms == pytest.approx(np.sqrt(2.0))
    expected_alpha = np.median(np.sqrt(1.0 / ((plate / 3.0) ** 2).sum(-1)))
    assert single.alpha_rms == pytest.approx(expected_alpha, rel=1e-4)
    with pytest.raises(ValueError, match="at least one"):
        background_model([])


def test_mask_iou():
    a = np.zeros((4, 4), bool)
    assert mask_iou(a, a) == 1.0
    b = a.copy()
    b[0, :2] = True
    c = a.copy()
    c[0, 1:3] = True
    assert mask_iou(b, c) == pytest.approx(1 / 3) and mask_iou(b, a) == 0.0
