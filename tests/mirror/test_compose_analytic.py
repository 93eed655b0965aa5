"""§5.5 of Real-time Reshaping (background model and composition) on tiny images with known answers.

The background model keeps the frames where the person is absent and learns only pixels farther than the
margin (Chebyshev) from the foreground, averaging at ``rate`` where it has seen the pixel before; the
composition lays the warped person over the frame, fills the hole behind a shrunk person from the model
(never from the person), inpaints only pixels the model never saw and counts both.
"""

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

H, W = 40, 60


def _chebyshev_far(fg, margin):
    """Brute force: pixels whose Chebyshev distance to every foreground pixel exceeds ``margin``."""
    ys, xs = np.nonzero(fg)
    yy, xx = np.mgrid[: fg.shape[0], : fg.shape[1]]
    if len(ys) == 0:
        return np.ones(fg.shape, bool)
    d = np.maximum(np.abs(yy[..., None] - ys), np.abs(xx[..., None] - xs)).min(-1)
    return d > margin


def _person(top=10, bottom=30, left=20, right=40):
    fg = np.zeros((H, W), bool)
    fg[top:bottom, left:right] = True
    return fg


def test_empty_background_and_coverage():
    bg = empty_background((np.int64(H), float(W)))
    assert bg.image.shape == (H, W, 3) and bg.image.dtype == np.uint8 and not bg.image.any()
    assert bg.valid.shape == (H, W) and bg.valid.dtype == bool and not bg.valid.any()
    assert bg.frames == 0 and bg.coverage == 0.0
    valid = np.zeros((H, W), bool)
    valid[:10] = True
    assert BackgroundModel(bg.image, valid, 3).coverage == pytest.approx(10 / H)
    assert BackgroundModel(np.zeros((0, 0, 3), np.uint8), np.zeros((0, 0), bool)).coverage == 0.0


@pytest.mark.parametrize("margin", [0, 1, 3, 7])
def test_confident_background_is_farther_than_the_margin_in_chebyshev_distance(margin):
    fg = np.zeros((H, W), bool)
    fg[12, 20] = fg[25:28, 40:44] = True
    np.testing.assert_array_equal(confident_background(fg, margin), _chebyshev_far(fg, margin))
    np.testing.assert_array_equal(confident_background(fg.astype(np.uint8), margin), _chebyshev_far(fg, margin))


def test_confident_background_negative_margin_is_the_complement():
    fg = _person()
    np.testing.assert_array_equal(confident_background(fg, -2), ~fg)
    assert confident_background(np.zeros((H, W), bool)).all()
    # the default margin is 15 px
    dot = np.zeros((H, W), bool)
    dot[20, 30] = True
    np.testing.assert_array_equal(confident_background(dot), _chebyshev_far(dot, 15))


def test_first_frame_learns_the_confident_pixels_only():
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
    fg = _person()
    bg = update_background(None, rgb, fg, margin_px=4, rate=0.3)
    far = _chebyshev_far(fg, 4)
    np.testing.assert_array_equal(bg.valid, far)
    np.testing.assert_array_equal(bg.image[far], rgb[far])  # first sighting: copied, whatever the rate
    assert not bg.image[~far].any() and bg.frames == 1
    # the default margin is 15 px
    np.testing.assert_array_equal(update_background(None, rgb, fg).valid, _chebyshev_far(fg, 15))


@pytest.mark.parametrize("rate", [0.25, 0.5, 0.8])
def test_seen_pixels_move_rate_of_the_way_new_ones_are_copied_near_ones_kept(rate):
    rng = np.random.default_rng(1)
    first = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
    second = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
    fg1 = _person(left=5, right=25)
    fg2 = _person(left=35, right=55)
    m1 = update_background(None, first, fg1, margin_px=2)
    m2 = update_background(m1, second, fg2, margin_px=2, rate=rate)
    far2 = _chebyshev_far(fg2, 2)
    both = m1.valid & far2
    new = ~m1.valid & far2
    kept = ~far2
    assert both.sum() > 100 and new.sum() > 100 and (kept & m1.valid).sum() > 100
    expect = (1 - rate) * first[both].astype(float) + rate * second[both]
    assert np.abs(m2.image[both] - expect).max() <= 0.5 + 1e-9
    np.testing.assert_array_equal(m2.image[new], second[new])
    np.testing.assert_array_equal(m2.image[kept], m1.image[kept])
    np.testing.assert_array_equal(m2.valid, m1.valid | far2)
    assert m2.frames == 2
    # the old model is unchanged
    np.testing.assert_array_equal(m1.valid, _chebyshev_far(fg1, 2))
    np.testing.assert_array_equal(m1.image[m1.valid], first[m1.valid])


def test_frames_without_the_person_teach_the_whole_background_and_rate_one_replaces():
    rng = np.random.default_rng(2)
    empty_scene = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
    nobody = np.zeros((H, W), bool)
    m = update_background(None, empty_scene, nobody, rate=0.5)
    assert m.valid.all() and np.array_equal(m.image, empty_scene)
    other = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
    replaced = update_background(m, other, nobody, rate=1.0)
    np.testing.assert_array_equal(replaced.image, other)
    averaged = update_background(m, other, nobody, rate=0.5)
    assert np.abs(averaged.image - (empty_scene / 2.0 + other / 2.0)).max() <= 0.5 + 1e-9
    # a model that has seen nothing: rate < 1 copies (nothing to average with)
    fresh = update_background(empty_background((H, W)), other, nobody, rate=0.1)
    np.testing.assert_array_equal(fresh.image, other)


def test_unverified_pixels_are_learnt_once_then_kept():
    scene = np.full((H, W, 3), 50, np.uint8)
    later = np.full((H, W, 3), 200, np.uint8)
    nobody = np.zeros((H, W), bool)
    strip = np.zeros((H, W), bool)
    strip[:, :8] = True
    m = update_background(None, scene, nobody, unverified=strip)
    assert m.valid.all() and (m.image == 50).all()
    after = update_background(m, later, nobody, unverified=strip, rate=1.0)
    assert (after.image[strip] == 50).all() and (after.image[~strip] == 200).all()
    # an unverified pixel the model has not seen yet is learnt
    partial = update_background(None, scene, _person(top=0, bottom=H, left=0, right=4), margin_px=1)
    assert not partial.valid[:, :5].any()
    learnt = update_background(partial, later, nobody, unverified=strip, rate=1.0)
    assert (learnt.image[:, :5] == 200).all() and (learnt.image[:, 5:8] == 50).all()
    # near the person nothing is learnt, unverified or not; a 0/1 uint8 mask reads as bool
    fg = _person(top=15, bottom=25, left=20, right=30)
    near = ~_chebyshev_far(fg, 3)
    for mask in (strip, strip.astype(np.uint8)):
        both = update_background(m, later, fg, margin_px=3, unverified=mask, rate=1.0)
        assert (both.image[strip] == 50).all() and (both.image[near] == 50).all()
        assert (both.image[~strip & ~near] == 200).all()
    with pytest.raises(InputError, match=r"unverified mask \(3, 3\) must match the frame \(40, 60\)"):
        update_background(m, later, nobody, unverified=np.zeros((3, 3), bool))


def test_update_background_refusals():
    rgb = np.zeros((H, W, 3), np.uint8)
    mask = np.zeros((H, W), bool)
    for rate in (0.0, -0.5, 1.5):
        with pytest.raises(InputError, match=f"rate must lie in \\(0, 1\\], got {rate}"):
            update_background(None, rgb, mask, rate=rate)
    with pytest.raises(InputError, match=r"update_background needs an \(H, W, 3\) uint8 colour image"):
        update_background(None, rgb[..., 0], mask)
    with pytest.raises(InputError, match="uint8 colour image"):
        update_background(None, rgb[..., :2], mask)
    with pytest.raises(InputError, match="uint8 colour image"):
        update_background(None, rgb.astype(np.float32), mask)
    with pytest.raises(InputError, match=r"update_background: mask \(40, 59\) must match the colour image \(40, 60\)"):
        update_background(None, rgb, mask[:, 1:])
    with pytest.raises(InputError, match=r"background model \(10, 10, 3\) does not match the frame \(40, 60, 3\)"):
        update_background(empty_background((10, 10)), rgb, mask)


# --- composition ------------------------------------------------------------------------------------------

def _scene():
    """A grey wall with a known background model, a red person, and the person shrunk by the warp."""
    wall = np.zeros((H, W, 3), np.uint8)
    wall[..., 0] = np.arange(W)[None, :] * 4
    wall[..., 1] = np.arange(H)[:, None] * 5
    wall[..., 2] = 90
    fg = _person()
    rgb = wall.copy()
    rgb[fg] = (250, 20, 20)
    warped_mask = _person(top=14, bottom=30, left=24, right=36)  # shorter and thinner
    warped = np.zeros_like(rgb)
    warped[warped_mask] = (30, 240, 30)
    bg = update_background(None, wall, np.zeros((H, W), bool))
    return wall, rgb, fg, warped, warped_mask, bg


def test_the_hole_behind_a_shrunk_person_is_filled_from_the_background_never_the_person():
    wall, rgb, fg, warped, alpha, bg = _scene()
    stats = {}
    out = compose(warped, alpha.astype(np.float32), bg, rgb, fg, hole_margin_px=2, stats=stats)
    grown = _chebyshev_far(fg, 2) == 0
    hole = grown & ~alpha
    np.testing.assert_array_equal(out[alpha], warped[alpha])  # the warped person
    np.testing.assert_array_equal(out[hole], wall[hole])  # the background model, exactly
    np.testing.assert_array_equal(out[~grown], rgb[~grown])  # elsewhere the frame, untouched
    assert not np.all(out[hole] == (250, 20, 20), axis=1).any()
    assert stats == {"hole_px": int(hole.sum()), "inpainted_px": 0}
    # a bool alpha gives the same frame
    np.testing.assert_array_equal(compose(warped, alpha, bg, rgb, fg, hole_margin_px=2), out)


@pytest.mark.parametrize("margin", [0, 1, 4])
def test_the_hole_margin_grows_the_old_silhouette(margin):
    wall, rgb, fg, warped, alpha, bg = _scene()
    rgb = rgb.copy()
    rgb[~fg] = 7  # a frame that differs from the model everywhere outside the person
    stats = {}
    out = compose(warped, alpha, bg, rgb, fg, hole_margin_px=margin, stats=stats)
    grown = _chebyshev_far(fg, margin) == 0 if margin > 0 else fg
    from_model = grown & ~alpha
    np.testing.assert_array_equal(out[from_model], wall[from_model])
    assert (out[~grown] == 7).all()
    assert stats["hole_px"] == int(from_model.sum())
    if margin == 1:  # the default is 2 px
        default = compose(warped, alpha, bg, rgb, fg, stats=stats)
        assert stats["hole_px"] == int(((_chebyshev_far(fg, 2) == 0) & ~alpha).sum())
        assert (default != out).any()


def test_only_pixels_the_model_never_saw_are_inpainted_and_counted():
    """The upper part of the person's old place was never seen: it is inpainted (from the surrounding uniform
    background; the part is more than Telea's 3 px radius from the warped person), the rest copied."""
    wall, rgb, fg, _, _, _ = _scene()
    alpha = _person(top=20, bottom=30, left=27, right=33)
    warped = np.zeros_like(rgb)
    warped[alpha] = (30, 240, 30)
    flat = np.full((H, W, 3), 120, np.uint8)
    seen = np.ones((H, W), bool)
    seen[10:15, 20:40] = False
    bg = BackgroundModel(flat, seen, 5)
    frame = rgb.copy()
    frame[~fg] = 120
    stats = {}
    out = compose(warped, alpha, bg, frame, fg, hole_margin_px=0, stats=stats)
    hole = fg & ~alpha
    unknown = hole & ~seen
    assert stats == {"hole_px": int(hole.sum()), "inpainted_px": int(unknown.sum())} and unknown.sum() == 100
    np.testing.assert_array_equal(out[hole & seen], flat[hole & seen])
    assert np.abs(out[unknown].astype(int) - 120).max() <= 2  # not the person's red
    # OpenCV's Telea with a 3 px radius over the frame whose known holes are filled (a textured wall here)
    bg2 = BackgroundModel(wall, seen, 5)
    frame2 = rgb.copy()
    out2 = compose(warped, alpha, bg2, frame2, fg, hole_margin_px=0)
    filled = frame2.copy()
    filled[hole & seen] = wall[hole & seen]
    telea = cv2.inpaint(filled, unknown.astype(np.uint8), 3, cv2.INPAINT_TELEA)
    np.testing.assert_array_equal(out2[unknown], telea[unknown])
    for other in (cv2.inpaint(filled, unknown.astype(np.uint8), 4, cv2.INPAINT_TELEA),
                  cv2.inpaint(filled, unknown.astype(np.uint8), 3, cv2.INPAINT_NS)):
        assert (other[unknown] != telea[unknown]).any()
    np.testing.assert_array_equal(out[alpha], warped[alpha])
    np.testing.assert_array_equal(out[~fg], frame[~fg])
    # without stats nothing is recorded and the frame is the same
    np.testing.assert_array_equal(compose(warped, alpha, bg, frame, fg, hole_margin_px=0), out)


def test_soft_alpha_blends_the_warped_person_rounding_to_nearest():
    wall, rgb, fg, warped, _, bg = _scene()
    alpha = np.zeros((H, W), np.float32)
    alpha[14:30, 24:36] = 1.0
    alpha[14:30, 36] = 0.5
    alpha[14:30, 23] = 0.25
    alpha[5, 5] = 0.75  # outside the old silhouette: blended over the frame
    warped = warped.copy()
    warped[alpha > 0] = (0, 255, 31)  # the channel extremes round to 0 and 255
    out = compose(warped, alpha, bg, rgb, fg, hole_margin_px=0)
    under = rgb.copy()
    hole = fg & (alpha < 1)
    under[hole] = wall[hole]
    expect = np.floor(warped.astype(np.float64) * alpha[..., None] + under * (1 - alpha[..., None]) + 0.5)
    np.testing.assert_array_equal(out, np.clip(expect, 0, 255).astype(np.uint8))
    assert (out[14:30, 36] != under[14:30, 36]).all() and (out[5, 5] != rgb[5, 5]).any()
    assert (out[20, 28] == (0, 255, 31)).all()
    # nobody in the warped frame: the frame with its holes filled
    out0 = compose(warped, np.zeros((H, W), np.float32), bg, rgb, fg, hole_margin_px=0)
    under[fg] = wall[fg]
    np.testing.assert_array_equal(out0, under)


def test_compose_refusals():
    wall, rgb, fg, warped, alpha, bg = _scene()
    with pytest.raises(InputError, match=r"background model \(10, 10, 3\) does not match the frame \(40, 60, 3\)"):
        compose(warped, alpha, empty_background((10, 10)), rgb, fg)
    with pytest.raises(InputError, match=r"compose: mask \(40, 59\) must match"):
        compose(warped, alpha, bg, rgb, fg[:, 1:])
    with pytest.raises(InputError, match=r"compose \(warped foreground\) needs an \(H, W, 3\) uint8"):
        compose(warped.astype(float), alpha, bg, rgb, fg)
    with pytest.raises(InputError, match=r"compose \(warped foreground\): mask \(40, 59\)"):
        compose(warped, alpha[:, 1:], bg, rgb, fg)
    with pytest.raises(InputError, match=r"compose needs an \(H, W, 3\) uint8"):
        compose(warped, alpha, bg, rgb[..., 0], fg)


def test_inputs_are_not_modified():
    wall, rgb, fg, warped, alpha, bg = _scene()
    copies = [a.copy() for a in (rgb, fg, warped, alpha, bg.image, bg.valid)]
    compose(warped, alpha, bg, rgb, fg)
    update_background(bg, rgb, fg)
    for a, b in zip((rgb, fg, warped, alpha, bg.image, bg.valid), copies, strict=True):
        np.testing.assert_array_equal(a, b)
