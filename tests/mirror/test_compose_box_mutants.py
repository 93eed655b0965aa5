"""``compose`` (§5.5 of Real-time Reshaping of Humans) on small hand-made frames against the whole-frame composition
(test_compose.py's reference, the composition before it worked in the people's box): foregrounds and warped people
at the image's corners and edges (the grown box clipped there), a warped person away from the old one (the box is the
union of both), no old person or no warped one, masks given as bool / 0-1 / 0-255, negative margins, background
models that saw all, part or none of the frame. Each case: the same frame bit for bit and the same hole / inpainted
counts. Behaviour, not the box itself: an equivalent speed-up keeps these passing."""

from __future__ import annotations

import numpy as np
import pytest
from test_compose import _compose_on_the_whole_frame

from bodystudio.mirror.compose import BackgroundModel, compose

H, W = 36, 48


def _frame(seed):
    rng = np.random.default_rng(seed)
    return rng.integers(0, 256, (H, W, 3), dtype=np.uint8)


def _rect(r0, r1, c0, c1):
    m = np.zeros((H, W), bool)
    m[r0:r1, c0:c1] = True
    return m


def _alpha(mask, soft=True):
    """1 inside ``mask``, a soft ring (0.25 .. 0.75) on its outer 1-pixel rim when ``soft``."""
    a = mask.astype(np.float32)
    if soft and mask.any():
        import cv2

        ring = (cv2.dilate(mask.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0) & ~mask
        a[ring] = np.linspace(0.25, 0.75, int(ring.sum()), dtype=np.float32)
    return a


FOREGROUNDS = {
    "corner_top_left": _rect(0, 6, 0, 5),
    "bottom_right": _rect(30, 36, 40, 48),
    "left_edge": _rect(10, 20, 0, 3),
    "middle": _rect(12, 24, 18, 30),
    "none": np.zeros((H, W), bool),
}
WARPED = {
    "shrunk": _rect(14, 22, 20, 28),
    "moved_away": _rect(2, 8, 38, 46),
    "at_bottom_edge": _rect(33, 36, 10, 20),
    "none": np.zeros((H, W), bool),
}
VALID = {"all": np.ones((H, W), bool), "part": np.random.default_rng(3).random((H, W)) < 0.6,
         "none": np.zeros((H, W), bool)}


def _check(fg, warped_mask, valid, margin, fg_as=bool, soft=True):
    rgb, warped, bg = _frame(1), _frame(2), _frame(4)
    alpha = _alpha(warped_mask, soft)
    background = BackgroundModel(bg, valid, 1)
    stats = {}
    out = compose(warped, alpha, background, rgb, fg.astype(fg_as) * (255 if fg_as is np.uint8 else 1), margin,
                  stats)
    want, holes, unknown = _compose_on_the_whole_frame(warped, alpha, background, rgb, fg, margin)
    np.testing.assert_array_equal(out, want)
    assert (stats["hole_px"], stats["inpainted_px"]) == (holes, unknown)
    return holes, unknown


@pytest.mark.parametrize("fg", list(FOREGROUNDS))
@pytest.mark.parametrize("warped", list(WARPED))
def test_compose_is_the_whole_frame_composition_wherever_the_people_are(fg, warped):
    """Margins 0 / 2 / 5 (5 px grows the corner and edge foregrounds past the border), background seen in part."""
    total = 0
    for margin in (0, 2, 5):
        holes, _ = _check(FOREGROUNDS[fg], WARPED[warped], VALID["part"], margin)
        total += holes
    if fg != "none" and warped != "shrunk":
        assert total > 0


@pytest.mark.parametrize("valid", list(VALID))
def test_holes_filled_from_the_model_or_inpainted_where_it_never_saw(valid):
    holes, unknown = _check(FOREGROUNDS["middle"], WARPED["shrunk"], VALID[valid], 2)
    # the grown old person (16 x 16) minus the warped person (8 x 8): 192 holes
    assert holes == 16 * 16 - 8 * 8
    assert unknown == {"all": 0, "none": holes}.get(valid, unknown) and (valid != "part" or 0 < unknown < holes)


def test_corner_holes_are_counted_inside_the_image_only():
    """The top-left foreground (6 x 5) grown by 3 px: 9 x 8 pixels in the image, all holes with nobody warped."""
    assert _check(FOREGROUNDS["corner_top_left"], WARPED["none"], VALID["all"], 3) == (9 * 8, 0)
    assert _check(FOREGROUNDS["bottom_right"], WARPED["none"], VALID["none"], 1) == (7 * 9, 7 * 9)


@pytest.mark.parametrize("fg_as", [np.uint8, np.int32, np.float32])
def test_masks_given_as_numbers(fg_as):
    """A foreground of 0 / 255 uint8 (or 0 / 1 of another dtype) is the same foreground as the bool mask."""
    _check(FOREGROUNDS["left_edge"], WARPED["moved_away"], VALID["part"], 2, fg_as=fg_as)
    _check(FOREGROUNDS["middle"], WARPED["shrunk"], VALID["part"], 0, fg_as=fg_as)


def test_a_negative_margin_is_no_margin_and_hard_alpha():
    a = _check(FOREGROUNDS["middle"], WARPED["shrunk"], VALID["part"], -3, soft=False)
    assert a == _check(FOREGROUNDS["middle"], WARPED["shrunk"], VALID["part"], 0, soft=False)
    assert a[0] == 12 * 12 - 8 * 8


def test_nobody_in_the_frame_leaves_it_unchanged_and_counts_nothing():
    rgb = _frame(1)
    stats = {}
    out = compose(_frame(2), np.zeros((H, W), np.float32), BackgroundModel(_frame(4), VALID["none"], 1), rgb,
                  np.zeros((H, W), bool), 2, stats)
    np.testing.assert_array_equal(out, rgb)
    assert stats == {"hole_px": 0, "inpainted_px": 0}
    assert out is not rgb
