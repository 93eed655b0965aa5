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
