"""The hem matte (issue 13, gar13e): the new garment's hem lines moved onto the worn garment's edges in the video.

A toy actor (a torso and a horizontal arm) in a plain blue shirt over skin, with shading and noise; the new
garment's composited region is the worn shirt's with its waist hem too low and its sleeve too short. Milliseconds.
"""

from types import SimpleNamespace

import numpy as np
import pytest

from bodystudio.garment import composite as cp
from bodystudio.garment import refine

SKIN = np.array([170.0, 120.0, 95.0])
SHIRT = np.array([40.0, 60.0, 140.0])


def rect(shape, y0, y1, x0, x1):
    m = np.zeros(shape, bool)
    m[y0:y1, x0:x1] = True
    return m


def actor(H=120, W=160, s=1, sleeve_end=130, shirt=SHIRT, seed=0):
    """(frame uint8, person mask, worn shirt mask) at scale ``s`` (coordinates of the 120x160 layout times s): torso
    rows 20-100 x cols 50-110, arm rows 30-45 x cols 110-158; the worn shirt covers the torso down to row 80 and the
    arm to ``sleeve_end``."""
    H, W = H * s, W * s
    person = rect((H, W), 20 * s, 100 * s, 50 * s, 110 * s) | rect((H, W), 30 * s, 45 * s, 110 * s, 158 * s)
    worn = person & (rect((H, W), 20 * s, 80 * s, 50 * s, 110 * s) | rect((H, W), 30 * s, 45 * s, 110 * s,
                                                                            sleeve_end * s))
    rng = np.random.default_rng(seed)
    shading = np.linspace(0.75, 1.1, W)[None, :, None] * np.ones((H, 1, 1))  # a light from the right
    frame = np.full((H, W, 3), 90.0)
    frame[person] = SKIN
    frame[worn] = shirt
    frame = np.where(person[..., None], frame * shading, frame) + rng.normal(0, 2.0, (H, W, 3))
    return np.clip(np.round(frame), 0, 255).astype(np.uint8), person, worn


def new_garment(person, s=1, hem_row=86, sleeve_end=125):
    """The composited new garment: the worn shirt's region with the waist hem at ``hem_row`` (worn: 80) and the
    sleeve ending at ``sleeve_end`` (worn: 130)."""
    H, W = person.shape
    return person & (rect((H, W), 20 * s, hem_row * s, 50 * s, 110 * s) | rect((H, W), 30 * s, 45 * s, 110 * s,
                                                                                 sleeve_end * s))


def snap(frame, person, shown, reach_px=8.0):
    prob, error = refine.worn_garment_probability(frame, person, shown, reach_px)
    return refine.hem_matte(shown, prob, person, reach_px), error


def test_the_hems_move_onto_the_worn_garments_edges():
    frame, person, worn = actor()
    shown = new_garment(person)
    wrong_before = int((shown ^ worn).sum())
    assert wrong_before == 6 * 60 + 5 * 15  # 6 rows of hem too long, 5 columns of sleeve too short
    matte, error = snap(frame, person, shown)
    assert error < 0.02
    wrong_after = int((matte ^ worn).sum())
    assert wrong_after <= 0.05 * wrong_before  # measured 12 of 435 (the median filter rounds the armpit corner)
    # both ways: the hem drawn over the skin is given up, the sleeve is carried on to the worn sleeve's end
    assert not (matte & rect(person.shape, 82, 100, 0, 160)).any()
    assert matte[30:45, 110:130].mean() > 0.97
    # nothing beyond the reach changes
    far = np.ones_like(person)
    far[12:98, 42:138] = False
    assert np.array_equal(matte[far], shown[far])


def test_a_hem_without_a_worn_edge_near_it_stays():
    frame, person, worn = actor()
    # a long sleeve over the bare arm: its end (col 150) is 20 px past the worn sleeve's (130), beyond the reach
    long_sleeve = new_garment(person, hem_row=80, sleeve_end=150)
    matte, _ = snap(frame, person, long_sleeve)
    assert np.array_equal(matte[:, 120:], long_sleeve[:, 120:])
    # a short sleeve over a worn long one: the worn sleeve goes on to the hand, no worn edge near the new end
    frame, person, worn = actor(sleeve_end=158)
    short = new_garment(person, hem_row=80, sleeve_end=125)
    matte, _ = snap(frame, person, short)
    assert np.array_equal(matte[:, 110:], short[:, 110:])


def test_the_classifier_error_tells_a_shirt_of_the_skins_colour():
    frame, person, worn = actor(shirt=SKIN)
    _, error = refine.worn_garment_probability(frame, person, new_garment(person), 8.0)
    assert error > refine.MAX_HEM_CLASSIFIER_ERROR
    frame, person, worn = actor()
    prob, error = refine.worn_garment_probability(frame, person, new_garment(person), 8.0)
    assert error < 0.02
    assert prob[worn].mean() > 0.95 and prob[person & ~worn].mean() < 0.05 and not prob[~person].any()
    # too few pixels on either side: no model
    assert refine.worn_garment_probability(frame, person, np.zeros_like(person), 8.0)[1] == 0.5


def _layer(shown):
    H, W = shown.shape
    rgb = np.zeros((H, W, 3), np.float32)
    rgb[shown] = [0.9, 0.1, 0.1]
    body = np.ones((H, W), bool)
    return SimpleNamespace(rgb=rgb, mask=shown.copy(), depth=np.where(shown, 1.9, 0.0).astype(np.float32),
                           body_image=np.full((H, W, 3), 0.5, np.float32), body_mask=body,
                           body_depth=np.full((H, W), 2.0, np.float32))


@pytest.mark.parametrize("hem", [True, False])
def test_refine_and_composite_applies_the_matte_at_the_frames_scale(hem):
    # 240 px high: the reach is 4 px (a 60th of the height); the hem 3 rows too low, the sleeve 3 columns short
    frame, person, worn = actor(s=2)
    shown = person & (rect(person.shape, 40, 163, 100, 220) | rect(person.shape, 60, 90, 220, 257))
    layer = _layer(shown)
    out = cp.refine_and_composite(frame, person, layer, flow=False, rbf=False, hem=hem)
    assert out.hem_applied == hem
    if not hem:
        assert np.array_equal(out.garment_mask, shown)
        return
    assert int((out.garment_mask ^ worn).sum()) <= 0.05 * int((shown ^ worn).sum())
    removed, added = shown & ~out.garment_mask, out.garment_mask & ~shown
    assert removed.sum() >= 3 * 120 - 10 and added.sum() >= 3 * 30 - 10
    assert np.array_equal(out.image[removed], frame[removed])  # the actor again
    assert np.all(out.image[added] == [230, 26, 26])  # the garment's colour, carried on
    assert np.array_equal(out.unrefined_mask, shown)  # the plain 3D composite is the render's


def test_refine_and_composite_skips_the_matte_when_the_colours_do_not_separate():
    frame, person, worn = actor(s=2, shirt=SKIN)
    shown = person & (rect(person.shape, 40, 163, 100, 220) | rect(person.shape, 60, 90, 220, 257))
    out = cp.refine_and_composite(frame, person, _layer(shown), flow=False, rbf=False)
    assert not out.hem_applied and np.array_equal(out.garment_mask, shown)
