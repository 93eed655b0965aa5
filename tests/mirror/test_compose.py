"""Output composition over a learnt background model (§5.5 of Real-time Reshaping of Humans)."""

import cv2
import numpy as np
import pytest

from bodystudio.errors import InputError
from bodystudio.mirror.compose import (
    BackgroundModel,
    compose,
    confident_background,
    empty_background,
    update_background,
)
from bodystudio.mirror.image_case import cached_image_case
from bodystudio.mirror.warp import mls_warp_field, warp_foreground

SHRINK = (("stature_m", -0.16), ("mass_kg", -15.0))


def _psnr(a, b, m):
    d = (a[m].astype(float) - b[m].astype(float)) ** 2
    return 10 * np.log10(255**2 / d.mean())


def _mirror(case, background):
    field = mls_warp_field(case.src_uv, case.dst_uv, kind="similarity")
    warped, alpha = warp_foreground(case.rgb, case.true_mask, field)
    stats = {}
    return compose(warped, alpha, background, case.rgb, case.true_mask, stats=stats), alpha, stats


@pytest.mark.parametrize("edits, measured_db", [(None, 30.29), (SHRINK, 28.53)])
def test_composition_matches_the_target_render(edits, measured_db):
    """PSNR in a 10 px band around source and target person: measured 30.3 dB (grown) / 28.5 dB (shrunk);
    the unedited input scores 16 dB and holes inpainted instead of filled from the model 25.0 / 21.0 dB."""
    case = cached_image_case(edits)
    background = update_background(None, case.background, np.zeros(case.true_mask.shape, bool))
    out, _, stats = _mirror(case, background)
    band = cv2.dilate((case.true_mask | case.target_mask).astype(np.uint8), np.ones((21, 21), np.uint8)) > 0
    # 1.5x the measured mean squared error
    assert _psnr(out, case.target_rgb, band) >= measured_db - 10 * np.log10(1.5)
    assert _psnr(case.rgb, case.target_rgb, band) < 17
    assert stats["inpainted_px"] == 0 and stats["hole_px"] > 1000


def test_holes_are_filled_from_the_background_not_smeared():
    case = cached_image_case(SHRINK)
    background = update_background(None, case.background, np.zeros(case.true_mask.shape, bool))
    out, alpha, _ = _mirror(case, background)
    hole = cv2.erode((case.true_mask & ~case.target_mask & (alpha < 0.01)).astype(np.uint8), np.ones((3, 3))) > 0
    assert hole.sum() > 2000
    assert np.abs(out[hole].astype(float) - case.background[hole]).mean() < 1.0  # measured 0.0
    smeared, _, stats = _mirror(case, empty_background(case.true_mask.shape))
    assert stats["inpainted_px"] > 2000
    assert np.abs(smeared[hole].astype(float) - case.background[hole]).mean() > 10  # measured 32


def test_background_learns_only_confident_pixels():
    rng = np.random.default_rng(0)
    first = rng.integers(0, 255, (60, 80, 3), dtype=np.uint8)
    fg = np.zeros((60, 80), bool)
    fg[20:40, 30:50] = True
    model = update_background(None, first, fg, margin_px=5)
    far = confident_background(fg, 5)
    assert np.array_equal(model.valid, far)
    assert np.array_equal(model.image[far], first[far])
    assert not model.valid[18, 40] and model.valid[10, 40]  # 2 px from the person: not confident
    second = np.full_like(first, 200)
    updated = update_background(model, second, np.zeros_like(fg), margin_px=5, rate=0.5)
    expect = np.round(0.5 * first[far].astype(float) + 100)
    assert np.abs(updated.image[far].astype(float) - expect).max() <= 1
    assert np.all(updated.image[~far] == 200)  # first sighting: copied
    assert updated.valid.all() and updated.frames == 2
    assert np.array_equal(model.image[far], first[far])  # the old model is unchanged
    replaced = update_background(model, second, np.zeros_like(fg), rate=1.0)
    assert np.all(replaced.image == 200)


def test_bad_inputs_are_one_line_errors():
    rgb = np.zeros((48, 64, 3), np.uint8)
    mask = np.zeros((48, 64), bool)
    with pytest.raises(InputError, match="rate"):
        update_background(None, rgb, mask, rate=0.0)
    with pytest.raises(InputError, match="must match"):
        update_background(None, rgb, mask[:10])
    with pytest.raises(InputError, match="does not match"):
        update_background(empty_background((10, 10)), rgb, mask)
    with pytest.raises(InputError, match="does not match"):
        compose(rgb, mask.astype(float), empty_background((10, 10)), rgb, mask)
    with pytest.raises(InputError, match="uint8"):
        compose(rgb.astype(float), mask, empty_background((48, 64)), rgb, mask)


def test_unverified_pixels_are_learnt_once_from_the_empty_scene():
    """Outside the depth view there is no player mask: a person walking in there must not become background."""
    empty = np.full((40, 60, 3), 50, np.uint8)
    person_in_strip = empty.copy()
    person_in_strip[:, :10] = 220
    no_fg = np.zeros((40, 60), bool)
    unseen = np.zeros((40, 60), bool)
    unseen[:, :10] = True
    model = update_background(None, empty, no_fg, unverified=unseen)
    assert model.valid.all() and np.all(model.image == 50)  # first sighting: learnt
    after = update_background(model, person_in_strip, no_fg, unverified=unseen)
    assert np.all(after.image[:, :10] == 50)  # kept
    naive = update_background(model, person_in_strip, no_fg)
    assert np.all(naive.image[:, :10] > 100)  # without the mask the person is learnt


def _compose_by_blending_the_whole_box(warped_rgb, alpha, out):
    """The composition's last step as it was before MIRFAST2: every pixel of the covered box blended."""
    x, y, w, h = cv2.boundingRect((alpha > 0).astype(np.uint8))
    roi = (slice(y, y + h), slice(x, x + w))
    a = alpha[roi][..., None]
    out = out.copy()
    out[roi] = np.clip(warped_rgb[roi].astype(np.float32) * a + out[roi].astype(np.float32) * (1.0 - a) + 0.5, 0,
                       255).astype(np.uint8)
    return out


def test_only_the_soft_edge_is_blended_and_the_frame_is_the_same():
    """Two warped people with soft edges (alpha 0, 1 and in between): the composition equals blending every pixel of
    their box, bit for bit (the background model has seen everything, so no inpainting is involved)."""
    rng = np.random.default_rng(3)
    H, W = 120, 200
    rgb = rng.integers(0, 256, (H, W, 3), np.uint8)
    warped = rng.integers(0, 256, (H, W, 3), np.uint8)
    alpha = np.zeros((H, W), np.float32)
    alpha[20:90, 20:60] = 1.0
    alpha[30:100, 130:170] = 1.0
    alpha = cv2.GaussianBlur(alpha, (7, 7), 2.0)
    alpha[alpha < 0.02] = 0.0
    alpha[alpha > 0.98] = 1.0
    assert ((alpha > 0) & (alpha < 1)).sum() > 200 and (alpha == 1).sum() > 2000
    fg = np.zeros((H, W), bool)
    fg[25:95, 25:55] = True
    background = BackgroundModel(rng.integers(0, 256, (H, W, 3), np.uint8), np.ones((H, W), bool), 1)
    out = compose(warped, alpha, background, rgb, fg)
    hole = (cv2.dilate(fg.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0) & (alpha < 1.0)
    before = rgb.copy()
    before[hole] = background.image[hole]
    np.testing.assert_array_equal(out, _compose_by_blending_the_whole_box(warped, alpha, before))
    assert (out[alpha == 1.0] == warped[alpha == 1.0]).all()


def _compose_on_the_whole_frame(warped, alpha, background, rgb, fg, margin):
    """compose before MIRFAST3: holes, background copy and inpainting over the whole frame (the reference)."""
    m8 = fg.astype(np.uint8)
    if margin > 0:
        m8 = cv2.dilate(m8, np.ones((2 * margin + 1,) * 2, np.uint8))
    hole = (m8 > 0) & (alpha < 1.0)
    out = cv2.copyTo(background.image, (hole & background.valid).astype(np.uint8), rgb.copy())
    unknown = hole & ~background.valid
    if unknown.any():
        out = cv2.inpaint(out, unknown.astype(np.uint8), 3, cv2.INPAINT_TELEA)
    return _compose_by_blending_the_whole_box(warped, alpha, out), int(hole.sum()), int(unknown.sum())


@pytest.mark.parametrize("actors", [1, 2])
def test_compose_on_the_people_box_is_the_whole_frame_composition(actors):
    """compose works in the box of the grown input foreground and the warped people: the same frame, hole and
    inpainted counts as over the whole frame, with a background model that saw all, part or none of the frame."""
    from bodystudio.mirror.foreground import refine_foreground
    from bodystudio.mirror.run import MLS_ALPHA, MLS_RADIUS_PX

    case = cached_image_case(None, 0, actors)
    fg = refine_foreground(case.rgb, case.player_mask)
    field = mls_warp_field(case.src_uv, case.dst_uv, kind="similarity", alpha=MLS_ALPHA, groups=case.pair_groups,
                           radius_px=MLS_RADIUS_PX, dense=case.dense)
    warped, alpha = warp_foreground(case.rgb, fg, field)
    rng = np.random.default_rng(0)
    for valid in (np.ones(fg.shape, bool), rng.random(fg.shape) < 0.7):
        background = BackgroundModel(case.background, valid, 1)
        for margin in (2, 0):
            stats = {}
            out = compose(warped, alpha, background, case.rgb, fg, margin, stats)
            want, holes, unknown = _compose_on_the_whole_frame(warped, alpha, background, case.rgb, fg, margin)
            np.testing.assert_array_equal(out, want)
            assert (stats["hole_px"], stats["inpainted_px"]) == (holes, unknown) and holes > 0
    nobody = np.zeros_like(alpha)
    np.testing.assert_array_equal(compose(warped, nobody, background, case.rgb, np.zeros_like(fg)), case.rgb)
