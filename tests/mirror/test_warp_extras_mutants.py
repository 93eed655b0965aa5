"""MIR12l / MIR12m's carried extras at the edges (issue 17, mutation round mutR): ``foreground_extras`` from the
outline's distances and ``carry_extras``' visited boxes against MIR12l's references (``_foreground_extras_reference``,
``_carry_extras_reference``) bit for bit, on small disc persons whose extras touch the image's borders, are one pixel
wide or tall, come as a 0/255 mask, or whose body moves farther than the fast path's 255 px; and
``mls_warp_field``'s dense branch without a foreground. ``test_warp_extras_carry_exact.py`` compares the two paths on
the bench frame and discs in the middle of the image.
"""

import functools

import numpy as np
import pytest

from bodystudio.mirror import warp
from bodystudio.mirror.warp import (
    EXTRA_REACH_PX,
    OUTLINE_BAND_PX,
    OUTSIDE_PX,
    DenseCorrespondence,
    foreground_extras,
    mls_warp_field,
    refine_outline,
)
from tests.mirror.test_warp_extras_carry_exact import _extras_both, _fields


def _disc(shape, centre, shift, r_source=14.0, r_target=11.0, rim=2.0):
    """A disc person of radius ``r_source`` at ``centre`` (x, y) shown as one of ``r_target`` moved by ``shift``,
    with a ``rim`` px misalignment ring; (dense, person) with no extras yet."""
    H, W = shape
    cx, cy = centre
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
    r = np.hypot(xx - cx, yy - cy)
    tx, ty = cx + shift[0], cy + shift[1]
    target = np.hypot(xx - tx, yy - ty) < r_target
    scale = r_source / r_target
    uv = np.full((H, W, 2), np.nan, np.float32)
    uv[target, 0] = (cx + (xx - tx) * scale)[target]
    uv[target, 1] = (cy + (yy - ty) * scale)[target]
    dense = DenseCorrespondence((0, 0), uv, r < r_source, np.full((H // 4, W // 4, 2), np.nan, np.float32))
    return dense, r < r_source + rim


@functools.cache
def _case(name):
    if name == "top-left":  # hair up to row 0, a bag out to column 0
        dense, person = _disc((64, 80), (24.0, 26.0), (4, 3))
        person[0:14, 18:30] = True
        person[22:30, 0:12] = True
    elif name == "bottom-right":  # a bag out to the last column, a strand down to the last row
        dense, person = _disc((64, 80), (54.0, 36.0), (-5, -2))
        person[32:40, 66:80] = True
        person[48:64, 52:55] = True
    elif name == "strands":  # one pixel wide hair, one pixel tall bag strap
        dense, person = _disc((64, 80), (40.0, 34.0), (2, -3))
        person[4:22, 40] = True
        person[30, 52:70] = True
    else:  # "far": the target body 300 px to the right of the source (beyond the fast path's 255 px)
        dense, person = _disc((48, 400), (30.0, 24.0), (300, 0))
        person[18:26, 42:56] = True
        person[0:8, 26:34] = True
    return dense, person


@pytest.mark.parametrize("name", ["top-left", "bottom-right", "strands", "far"])
def test_the_extras_and_their_carry_are_the_references_at_the_edges(name):
    dense, person = _case(name)
    new, ref = _extras_both(dense, person)
    assert ref.sum() >= 12, ref.sum()
    np.testing.assert_array_equal(new, ref)
    u8 = person.astype(np.uint8) * 255  # a 0/255 mask reads as the boolean one
    new8, _ = _extras_both(dense, u8)
    np.testing.assert_array_equal(new8, ref)
    field, ref_field, carried = _fields(dense, person)
    assert carried > 0
    np.testing.assert_array_equal(field, ref_field)


def test_the_far_moved_body_takes_the_reference_carry(monkeypatch):
    dense, person = _case("far")
    real = warp._carry_extras_reference
    seen = []
    monkeypatch.setattr(warp, "_carry_extras_reference", lambda *a: seen.append(a) or real(*a))
    base = refine_outline(np.full(person.shape + (2,), OUTSIDE_PX, np.float32), dense, OUTLINE_BAND_PX, 8.0)
    extras = foreground_extras(person, dense)
    out = warp.carry_extras(base.copy(), dense, extras)
    assert len(seen) == 1 and seen[0][1] is dense and seen[0][2] is extras
    np.testing.assert_array_equal(out, real(base.copy(), dense, extras))
    assert (out != base).any()


def test_no_foreground_beyond_reach_has_no_extras():
    dense, person = _disc((64, 80), (40.0, 32.0), (0, 0))
    distances = []
    refine_outline(np.full(person.shape + (2,), OUTSIDE_PX, np.float32), dense, OUTLINE_BAND_PX, 8.0, distances)
    assert foreground_extras(person, dense, EXTRA_REACH_PX, distances) is None  # the ring only
    assert foreground_extras(np.zeros_like(person), dense, EXTRA_REACH_PX, distances) is None
    assert foreground_extras(np.zeros(person.shape, np.uint8), dense, EXTRA_REACH_PX, distances) is None


@pytest.mark.parametrize("inner", [3.0, 8.0])
def test_the_dense_field_without_a_foreground_is_the_refined_outline(inner):
    dense, _ = _disc((64, 80), (40.0, 32.0), (3, 2))
    src = np.array([[30.0, 30.0], [50.0, 30.0], [40.0, 45.0], [40.0, 20.0]])
    field = mls_warp_field(src, src + 1.0, (64, 80), (16, 20), dense=dense, inner_band_px=inner, band_px=2.0)
    expected = refine_outline(np.full((64, 80, 2), OUTSIDE_PX, np.float32), dense, 2.0, inner)
    np.testing.assert_array_equal(field, expected)
    assert np.isfinite(field).all() and (field != OUTSIDE_PX).any()


def _offset(dense, person, x0, y0):
    """``dense`` cropped at (x0, y0) to the rest of the image (the run's crop) with the same foreground."""
    return DenseCorrespondence((x0, y0), dense.source_uv[y0:, x0:].copy(), dense.source_mask[y0:, x0:].copy(),
                               dense.grid_source_uv), person


@pytest.mark.parametrize("strand", ["column", "row"])
def test_a_one_pixel_strand_alone_is_an_extra(strand):
    """A foreground of one strand one pixel wide (or tall) beyond reach, on a body cropped off the image's origin:
    the same extras as the reference (not "no foreground")."""
    dense, _ = _disc((64, 80), (44.0, 36.0), (1, 1))
    person = np.zeros((64, 80), bool)
    if strand == "column":
        person[2:14, 44] = True
    else:
        person[36, 62:76] = True
    for d in (dense, _offset(dense, person, 12, 9)[0]):
        new, ref = _extras_both(d, person)
        assert ref.sum() >= 10
        np.testing.assert_array_equal(new, ref)


def test_a_body_cropped_off_the_origin_gives_the_same_extras_and_carry():
    dense, person = _offset(*_case("bottom-right"), 14, 6)
    new, ref = _extras_both(dense, person)
    assert ref.sum() >= 12
    np.testing.assert_array_equal(new, ref)
    field, ref_field, carried = _fields(dense, person)
    assert carried > 0
    np.testing.assert_array_equal(field, ref_field)


def test_a_reach_other_than_the_default_reaches_the_reference():
    dense, person = _case("top-left")
    for reach in (4.0, 12.0):
        got = foreground_extras(person, dense, reach)  # no distances: the reference itself
        want = warp._foreground_extras_reference(person, dense, reach)
        np.testing.assert_array_equal(got[0], want[0])
        assert got[1] == want[1]
    assert not np.array_equal(foreground_extras(person, dense, 4.0)[0].sum(),
                              foreground_extras(person, dense, 12.0)[0].sum())
    # distances whose boxes do not hold the reach (a crop cut by the image's edge): the reference with this reach
    cropped = DenseCorrespondence((0, 0), dense.source_uv[:, :40].copy(), dense.source_mask[:, :40].copy(),
                                  dense.grid_source_uv)
    distances = []
    refine_outline(np.full(person.shape + (2,), OUTSIDE_PX, np.float32), cropped, OUTLINE_BAND_PX, 8.0, distances)
    for reach in (4.0, 12.0):
        got = foreground_extras(person, cropped, reach, distances)
        want = warp._foreground_extras_reference(person, cropped, reach)
        np.testing.assert_array_equal(got[0], want[0])


@functools.cache
def _random_case(seed):
    """A disc person at a random place, shrunk or grown and moved up to 12 px, with three rectangles of foreground
    (some reaching a border, some one pixel thin) around it."""
    rng = np.random.default_rng(seed)
    H, W = 56, 72
    centre = (float(rng.integers(16, W - 16)), float(rng.integers(16, H - 16)))
    r_source = float(rng.integers(9, 14))
    dense, person = _disc((H, W), centre, tuple(rng.integers(-12, 13, 2)), r_source,
                          r_source * float(rng.uniform(0.7, 1.3)))
    for _ in range(3):
        w, h = int(rng.integers(1, 14)), int(rng.integers(1, 14))
        x, y = int(rng.integers(0, W - w + 1)), int(rng.integers(0, H - h + 1))
        person[y:y + h, x:x + w] = True
    return dense, person


@pytest.mark.parametrize("seed", range(16))
def test_random_discs_and_extras_carry_as_the_reference(seed):
    dense, person = _random_case(seed)
    new, ref = _extras_both(dense, person)
    np.testing.assert_array_equal(new, ref)
    field, ref_field, _ = _fields(dense, person)
    np.testing.assert_array_equal(field, ref_field)


def test_an_extra_low_and_left_of_its_body_is_visited():
    """The visited box of a bag below and left of the body (its top row beyond its right column)."""
    dense, person = _disc((64, 80), (22.0, 40.0), (3, -4))
    person[52:60, 0:9] = True
    field, ref_field, carried = _fields(dense, person)
    assert carried > 0
    np.testing.assert_array_equal(field, ref_field)
