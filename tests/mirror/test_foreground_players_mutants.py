"""The graph cut's MIRFAST3 / several-players steps (§5.3 of Real-time Reshaping of Humans) on hand-made frames:
each band pixel's depth term against the player nearest it (:func:`_nearest_player_depths`, known pixel by pixel),
two actors at 2 m and 3.5 m in front of a wall of their own grey (the cut is exact with their labels, the farther
one eroded without), the labels' checks, and the unseen reach's box (unseen pixels beyond the reach, or none near the
mask, change nothing; a mask at the image's corner). Behaviour only: an equivalent speed-up keeps these passing."""

from __future__ import annotations

import numpy as np
import pytest

from bodystudio.errors import InputError
from bodystudio.mirror.foreground import _nearest_player_depths, foreground_band, refine_foreground

H, W = 80, 120


def _disc(cx, cy, r):
    rows, cols = np.mgrid[0:H, 0:W]
    return (cols - cx) ** 2 + (rows - cy) ** 2 <= r * r


def test_nearest_player_depths_by_hand():
    """Player 1 (columns 10..29) at 2.0 / 2.4 m (sure pixels: 136 at 2.0, 120 at 2.4: median 2.0, mean 2.19),
    player 2 (columns 60..79) at 3.0 m with a hole of unmeasured depth; band pixels take the median of the player
    whose mask pixels are within band_px + 1 (Chebyshev), the highest label when both are, ``z_all`` when none is."""
    mask = np.zeros((40, 100), bool)
    mask[10:30, 10:30] = True
    mask[10:30, 60:80] = True
    labels = np.zeros((40, 100), np.uint8)
    labels[:, :50] = 1
    labels[:, 50:] = 2
    labels[0, 0] = 7  # outside the mask: not a player
    depth = np.zeros((40, 100))
    depth[10:30, 10:30] = 2.0
    depth[10:30, 10:16] = 2.4  # 6 of 20 columns
    depth[10:20, 10:30] = np.where(np.arange(20) < 13, 2.4, 2.0)  # the upper half: 13 columns at 2.4
    depth[10:30, 60:80] = 3.0
    depth[15:18, 62:66] = 0.0
    inner = np.zeros_like(mask)
    inner[12:28, 12:28] = True
    inner[12:28, 62:78] = True
    want1 = float(np.median(depth[inner & (labels == 1) & (depth > 0)]))
    band_px = 2
    # band pixels: next to player 1 (at 1 and 3 px), beyond its reach (4 px), next to player 2, far from both,
    # below player 2 (6 rows), diagonal to player 1's corner
    br = np.array([20, 20, 20, 20, 20, 35, 9])
    bc = np.array([9, 32, 33, 59, 45, 70, 30])
    zs = _nearest_player_depths(labels, mask, inner, depth, band_px, br, bc, 9.0)
    assert zs.tolist() == [want1, want1, 9.0, 3.0, 9.0, 9.0, want1]
    assert want1 == 2.0
    # between the two (both within reach): the higher label
    mask2 = np.zeros((40, 100), bool)
    mask2[10:30, 10:30] = True
    mask2[10:30, 33:50] = True
    lab2 = np.where(np.arange(100)[None, :] < 31, 1, 2).repeat(40, 0).astype(np.uint8)
    inner2 = np.zeros_like(mask2)
    inner2[12:28, 12:28] = True
    inner2[12:28, 35:48] = True
    d2 = np.where(mask2, np.where(lab2 == 1, 2.0, 3.0), 0.0)
    assert _nearest_player_depths(lab2, mask2, inner2, d2, 2, np.array([20]), np.array([31]), 9.0).tolist() == [3.0]
    # one player in the sure foreground: every band pixel keeps z_all
    one = np.where(mask, 1, 0).astype(np.uint8)
    assert _nearest_player_depths(one, mask, inner, depth, band_px, br, bc, 5.0).tolist() == [5.0] * 7
    # a player with no measured sure pixel keeps z_all near it
    d3 = depth.copy()
    d3[10:30, 60:80] = 0.0
    zs = _nearest_player_depths(labels, mask, inner, d3, band_px, br, bc, 9.0)
    assert zs.tolist() == [want1, want1, 9.0, 9.0, 9.0, 9.0, want1]
    # a player whose mask has no sure (inner) pixel is not one of the players
    inner4 = inner.copy()
    inner4[:, 50:] = False
    assert _nearest_player_depths(labels, mask, inner4, depth, band_px, br, bc, 5.0).tolist() == [5.0] * 7


def _two_actors():
    """Two discs the grey of the wall (colour says nothing): player 1 at 2 m (r 22), player 2 at 3.5 m (r 14),
    the wall at 5 m; the SDK masks moved by 3 px."""
    rng = np.random.default_rng(2)
    rgb = (128 + rng.integers(0, 3, (H, W, 3))).astype(np.uint8)
    p1, p2 = _disc(35, 40, 22), _disc(88, 40, 14)
    depth = np.where(p1, 2.0, np.where(p2, 3.5, 5.0))
    player = np.roll(p1 | p2, (3, -2), axis=(0, 1))
    labels = np.where(np.arange(W)[None, :] < 62, 1, 2).repeat(H, 0).astype(np.uint8)
    return rgb, depth, player, labels, p1, p2


def test_two_players_are_cut_each_against_its_own_depth():
    """With the players' labels each band pixel is compared with its own player's depth: both discs exactly.
    Without them, player 2 (1.5 m behind the joint median, beyond the 0.35 m tolerance) loses its band pixels."""
    rgb, depth, player, labels, p1, p2 = _two_actors()
    cut = refine_foreground(rgb, player, depth, smoothness=0.5, labels=labels)
    np.testing.assert_array_equal(cut, p1 | p2)
    joint = refine_foreground(rgb, player, depth, smoothness=0.5)
    np.testing.assert_array_equal(joint & p1, p1)
    assert np.count_nonzero(p2 & ~joint) > 50
    # labels as int lists of the right shape are taken as they are
    np.testing.assert_array_equal(refine_foreground(rgb, player, depth, smoothness=0.5,
                                                    labels=labels.astype(np.int64).tolist()), p1 | p2)
    # labels without depth: nothing to compare, the colour-only cut
    np.testing.assert_array_equal(refine_foreground(rgb, player, None, smoothness=0.5, labels=labels),
                                  refine_foreground(rgb, player, None, smoothness=0.5))


def test_labels_of_one_player_are_no_labels_and_a_wrong_shape_is_refused():
    rgb, depth, player, labels, _, _ = _two_actors()
    np.testing.assert_array_equal(refine_foreground(rgb, player, depth, smoothness=0.5, labels=np.ones((H, W))),
                                  refine_foreground(rgb, player, depth, smoothness=0.5))
    with pytest.raises(InputError) as e:
        refine_foreground(rgb, player, depth, labels=labels[:, :-1])
    assert str(e.value) == f"refine_foreground: labels ({H}, {W - 1}) must match the colour image ({H}, {W})"
    # no band (an empty mask): no check needed, nothing to cut
    assert not refine_foreground(rgb, np.zeros((H, W), bool), depth, labels=labels[:, :-1]).any()


def test_unseen_pixels_beyond_the_reach_change_nothing():
    """Unseen pixels count only within ``unseen_reach_px`` of the mask: the cut with unseen pixels everywhere is the
    cut with them restricted to the reach (a Chebyshev dilation of the mask), and unseen pixels out of reach are
    no unseen pixels; a mask at the image's corner (its reach clipped by the border) likewise."""
    import cv2

    rgb = np.full((H, W, 3), (40, 90, 200), np.uint8)
    truth = _disc(60, 40, 18)
    rgb[truth] = (200, 60, 40)
    for player, reach in ((truth & (np.arange(W)[None, :] >= 55), 9), (truth, 5)):
        unseen = np.zeros((H, W), bool)
        unseen[:, :55] = True
        near = cv2.dilate(player.astype(np.uint8), np.ones((2 * reach + 1,) * 2, np.uint8)) > 0
        got = refine_foreground(rgb, player, unseen=unseen, unseen_reach_px=reach)
        np.testing.assert_array_equal(got, refine_foreground(rgb, player, unseen=unseen & near,
                                                             unseen_reach_px=reach))
    far = np.zeros((H, W), bool)
    far[:, :5] = True  # 37 px from the disc
    np.testing.assert_array_equal(refine_foreground(rgb, truth, unseen=far, unseen_reach_px=30),
                                  refine_foreground(rgb, truth))
    # the person in the image's top-left corner, cut by the depth view's left edge at column 6
    corner = np.zeros((H, W, 3), np.uint8)
    corner[...] = (40, 90, 200)
    person = _disc(8, 6, 14)
    corner[person] = (200, 60, 40)
    seen = person & (np.arange(W)[None, :] >= 6)
    unseen = np.zeros((H, W), bool)
    unseen[:, :6] = True
    np.testing.assert_array_equal(refine_foreground(corner, seen, unseen=unseen, unseen_reach_px=8), person)
    inner, band = foreground_band(seen, 6)
    assert band.any() and inner.any()


def test_a_decoy_of_the_persons_colour_beyond_the_reach_stays_background():
    """A second disc of the person's colour (a decoy) 30 px right of the person, inside the unseen view, beyond
    the 12 px reach, and a small one in the corner of the person's box grown by the reach (unseen, but 24 px from the
    person): neither joins the band, so both stay background; unseen pixels within the reach (the
    person's own cut-off left part) are completed. The decoy inside the reach (reach 40) is taken: the reach
    decides."""
    rgb = np.full((H, W, 3), (40, 90, 200), np.uint8)
    person = _disc(40, 40, 16)
    decoy = _disc(95, 40, 8)
    corner = _disc(16, 16, 3)  # in the mask's box grown by the reach, but 24 px from the person: beyond it
    rgb[person | decoy | corner] = (200, 60, 40)
    seen = person & (np.arange(W)[None, :] >= 35)
    unseen = (np.arange(W)[None, :] < 35) | (np.arange(W)[None, :] >= 75)
    unseen = np.broadcast_to(unseen, (H, W))
    np.testing.assert_array_equal(refine_foreground(rgb, seen, unseen=unseen, unseen_reach_px=12), person)
    far = refine_foreground(rgb, seen, unseen=unseen, unseen_reach_px=40)
    np.testing.assert_array_equal(far & person, person)
    assert (far & decoy).sum() > 0


def test_nearest_player_depths_of_a_near_player_and_unlabelled_mask_pixels():
    """A player 0.9 m from the camera takes its own median (any reading > 0 counts); mask pixels labelled 0 (no
    player) are nobody's: a band pixel next to them alone keeps ``z_all``."""
    mask = np.zeros((40, 100), bool)
    mask[10:30, 10:30] = True
    mask[10:30, 60:80] = True
    mask[10:30, 40:50] = True  # a third blob, unlabelled
    labels = np.zeros((40, 100), np.uint8)
    labels[:, :35] = 1
    labels[:, 55:] = 2
    depth = np.where(mask, 0.9, 0.0)
    depth[10:30, 60:80] = 3.0
    inner = np.zeros_like(mask)
    inner[12:28, 12:28] = True
    inner[12:28, 62:78] = True
    inner[12:28, 42:48] = True
    br, bc = np.array([20, 20, 20]), np.array([9, 59, 51])
    assert _nearest_player_depths(labels, mask, inner, depth, 2, br, bc, 7.0).tolist() == [0.9, 3.0, 7.0]
