"""MIR12m: :func:`carry_extras` visits only the output pixels that can land on an extra and transforms only their
box; the field is MIR12l's (:func:`_carry_extras_reference`, the whole body's box) bit for bit.

Planted frames: the bench's rendered person (the true bodies, +10 % stature +15 kg, displacements up to 35 px) with
a bag beside the hip and hair on the head, and a shrinking / moving disc with a bag, hair and a bag held apart.
"""

import numpy as np
import pytest

from bodystudio.mirror import warp
from bodystudio.mirror.image_case import cached_image_case
from bodystudio.mirror.run import N_HANDLES, RIM_COS
from bodystudio.mirror.warp import (
    EXTRA_REACH_PX,
    OUTLINE_BAND_PX,
    OUTSIDE_PX,
    DenseCorrespondence,
    _carry_extras_reference,
    _foreground_extras_reference,
    carry_extras,
    foreground_extras,
    mls_warp_field,
    refine_outline,
    warp_pairs,
)


def _rendered_frame():
    case = cached_image_case(None)
    fg = case.true_mask.copy()
    rows = np.flatnonzero(fg.any(1))
    person = fg.copy()
    for r in range((rows[0] + rows[-1]) // 2 + 10, (rows[0] + rows[-1]) // 2 + 34):  # a bag at the hip
        right = np.flatnonzero(fg[r])[-1]
        person[r, right - 2:right + int(EXTRA_REACH_PX) + 14] = True
    cols = np.flatnonzero(fg[rows[0] + 4])
    person[rows[0] - int(EXTRA_REACH_PX) - 6:rows[0] + 4, cols[0] - 2:cols[-1] + 3] = True  # hair
    pairs = warp_pairs(case.source_vertices, case.target_vertices, case.faces, case.camera, N_HANDLES,
                       rim_cos=RIM_COS, dense=True, closed=True)
    return pairs, person


def _disc(shift_px, shape=(120, 160), centre=(80.0, 60.0), r_source=30.0, r_target=24.0):
    """A disc person (source radius 30) shown as a disc of radius 24 moved by ``shift_px`` (x, y), with a 3 px
    misalignment rim, a bag to the right, hair on top and a bag held apart below right."""
    H, W = shape
    cx, cy = centre
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
    r = np.hypot(xx - cx, yy - cy)
    tx, ty = cx + shift_px[0], cy + shift_px[1]
    target = np.hypot(xx - tx, yy - ty) < r_target
    scale = r_source / r_target
    uv = np.full((H, W, 2), np.nan, np.float32)
    uv[target, 0] = (cx + (xx - tx) * scale)[target]
    uv[target, 1] = (cy + (yy - ty) * scale)[target]
    dense = DenseCorrespondence((0, 0), uv, r < r_source, np.full((H // 4, W // 4, 2), np.nan, np.float32))
    person = r < r_source + 3.0
    person[52:68, 108:int(cx + r_source + EXTRA_REACH_PX) + 10] = True
    person[int(cy - r_source - EXTRA_REACH_PX) - 6:31, 74:87] = True
    person[96:104, 112:122] = True
    return dense, person


def _fields(dense, person):
    """(this tree's carry, the reference's) on the refined outline of ``dense``, and how many pixels were carried."""
    base = refine_outline(np.full(person.shape + (2,), OUTSIDE_PX, np.float32), dense, OUTLINE_BAND_PX, 8.0)
    extras = foreground_extras(person, dense)
    new = carry_extras(base.copy(), dense, extras)
    ref = _carry_extras_reference(base.copy(), dense, extras)
    return new, ref, int((ref != base).any(-1).sum())


@pytest.mark.parametrize("shift_px", [(0, 0), (9, -4), (-14, 11), (3, 17)])
def test_the_disc_carry_is_the_reference_bit_for_bit(shift_px):
    new, ref, carried = _fields(*_disc(shift_px))
    assert carried >= 150, carried
    np.testing.assert_array_equal(new, ref)


def test_the_rendered_frame_field_is_the_reference_bit_for_bit(monkeypatch):
    pairs, person = _rendered_frame()

    def field():
        return mls_warp_field(pairs.src_uv, pairs.dst_uv, person.shape, dense=pairs.dense, foreground=person)

    new = field()
    monkeypatch.setattr(warp, "carry_extras", _carry_extras_reference)
    monkeypatch.setattr(warp, "foreground_extras", lambda fg, dense, reach, distances=None:
                        _foreground_extras_reference(fg, dense, reach))
    ref = field()
    nothing = mls_warp_field(pairs.src_uv, pairs.dst_uv, person.shape, dense=pairs.dense, foreground=None)
    carried = int((ref != nothing).any(-1).sum())
    assert carried >= 600, carried  # measured 859: the bag's and the hair's
    np.testing.assert_array_equal(new, ref)


def test_planted_bugs_change_the_field(monkeypatch):
    """The visited box without the body's displacements, or one extra's box only: the field differs."""
    dense, person = _disc((9, -4))
    true_range = warp._displacement_range
    monkeypatch.setattr(warp, "_displacement_range",
                        lambda *a: np.r_[np.zeros(4), true_range(*a)[4]])
    new, ref, _ = _fields(dense, person)
    assert not np.array_equal(new, ref)
    monkeypatch.setattr(warp, "_displacement_range", true_range)
    boxes = warp._extras_boxes
    monkeypatch.setattr(warp, "_extras_boxes", lambda *a: boxes(*a)[:1])
    new, ref, _ = _fields(dense, person)
    assert not np.array_equal(new, ref)


def _painted(extras, shape):
    out = np.zeros(shape, bool)
    if extras is not None:
        mask, (x0, y0) = extras
        out[y0:y0 + mask.shape[0], x0:x0 + mask.shape[1]] = mask
    return out


def _extras_both(dense, person):
    distances = []
    refine_outline(np.full(person.shape + (2,), OUTSIDE_PX, np.float32), dense, OUTLINE_BAND_PX, 8.0, distances)
    return (_painted(foreground_extras(person, dense, EXTRA_REACH_PX, distances), person.shape),
            _painted(warp._foreground_extras_reference(person, dense, EXTRA_REACH_PX), person.shape))


def _cropped(dense, x0, y0, w, h):
    """``dense`` on the crop of its image at (x0, y0), w x h (the run's crop holds the bodies only)."""
    return DenseCorrespondence((x0, y0), dense.source_uv[y0:y0 + h, x0:x0 + w].copy(),
                               dense.source_mask[y0:y0 + h, x0:x0 + w].copy(), dense.grid_source_uv)


def _two_discs():
    """Two disc persons side by side (the second the first moved 150 px right) on a 320 px wide image."""
    dense, person = _disc((4, 3))
    wide = np.zeros((person.shape[0], 320), bool)
    wide[:, :160], wide[:, 150:310] = person, wide[:, 150:310] | person
    uv = np.full(wide.shape + (2,), np.nan, np.float32)
    uv[:, :160] = dense.source_uv
    right = dense.source_uv + np.float32([150.0, 0.0])
    uv[:, 150:310] = np.where(np.isfinite(right), right, uv[:, 150:310])
    mask = np.zeros_like(wide)
    mask[:, :160] = dense.source_mask
    mask[:, 150:310] |= dense.source_mask
    return DenseCorrespondence((0, 0), uv, mask, dense.grid_source_uv), wide


@pytest.mark.parametrize("case", ["disc", "moved", "two", "cropped"])
def test_the_extras_from_the_outline_distances_are_the_reference(case, monkeypatch):
    """The cores read from ``refine_outline``'s distances (one person, two side by side; a crop whose box is cut by
    its edge falls back to the extras' own transform): the same extras as MIR12l's, and the same carried field."""
    dense, person = {"disc": lambda: _disc((0, 0)), "moved": lambda: _disc((-14, 11)), "two": _two_discs,
                     "cropped": lambda: _disc((0, 0))}[case]()
    if case == "cropped":
        dense = _cropped(dense, 50, 30, 62, 62)
    calls = []
    monkeypatch.setattr(warp, "_foreground_extras_reference",
                        lambda *a: calls.append(1) or _foreground_extras_reference(*a))
    new, ref = _extras_both(dense, person)
    assert len(calls) == (2 if case == "cropped" else 1)  # the fast path but where the crop cuts the box
    assert ref.sum() >= 150, ref.sum()
    np.testing.assert_array_equal(new, ref)


def test_the_rendered_frame_extras_are_the_reference():
    pairs, person = _rendered_frame()
    new, ref = _extras_both(pairs.dense, person)
    assert ref.sum() >= 600, ref.sum()
    np.testing.assert_array_equal(new, ref)


def test_planted_bugs_in_the_extras_change_them(monkeypatch):
    """The boxes' reach not checked (a crop cut at the silhouette), or the cores' distance test dropped: other
    extras."""
    dense, person = _disc((0, 0))
    monkeypatch.setattr(warp, "_boxes_hold_reach", lambda *a: True)
    new, ref = _extras_both(_cropped(dense, 50, 30, 62, 62), person)
    assert not np.array_equal(new, ref)
    monkeypatch.undo()
    distances = []
    refine_outline(np.full(person.shape + (2,), OUTSIDE_PX, np.float32), dense, OUTLINE_BAND_PX, 8.0, distances)
    far = [(box, np.full_like(sd, -100.0)) for box, sd in distances]
    assert not np.array_equal(_painted(foreground_extras(person, dense, EXTRA_REACH_PX, far), person.shape),
                              _painted(warp._foreground_extras_reference(person, dense, EXTRA_REACH_PX), person.shape))


def test_the_two_actor_frame_field_is_the_reference_bit_for_bit(monkeypatch):
    """The bench's two-actor frame, each actor with a bag at the hip and hair on the head."""
    import cv2

    case = cached_image_case(None, actors=2)
    n, actor = cv2.connectedComponents(case.true_mask.astype(np.uint8))
    person = case.true_mask.copy()
    for k in range(1, n):
        own = actor == k
        rows = np.flatnonzero(own.any(1))
        if len(rows) < 100:
            continue
        mid = (rows[0] + rows[-1]) // 2 + 10
        for r in range(mid, mid + 20):
            right = np.flatnonzero(own[r])[-1]
            person[r, right - 2:right + int(EXTRA_REACH_PX) + 12] = True
        cols = np.flatnonzero(own[rows[0] + 4])
        person[rows[0] - int(EXTRA_REACH_PX) - 5:rows[0] + 4, cols[0] - 2:cols[-1] + 3] = True

    def field():
        return mls_warp_field(case.src_uv, case.dst_uv, person.shape, groups=case.pair_groups, dense=case.dense,
                              foreground=person)

    monkeypatch.setattr(warp, "_foreground_extras_reference", None)  # the fast path: the outline's distances
    new = field()
    monkeypatch.undo()
    monkeypatch.setattr(warp, "carry_extras", _carry_extras_reference)
    monkeypatch.setattr(warp, "foreground_extras", lambda fg, dense, reach, distances=None:
                        _foreground_extras_reference(fg, dense, reach))
    ref = field()
    nothing = mls_warp_field(case.src_uv, case.dst_uv, person.shape, groups=case.pair_groups, dense=case.dense)
    carried = int((ref != nothing).any(-1).sum())
    assert carried >= 1000, carried
    np.testing.assert_array_equal(new, ref)
