"""MIR12k: the dense warp shows the person on the target body and 1 px around its outline; MIR12l: and what reaches
well beyond the fitted body (a bag, hair), carried with the body.

A shrinking edit on a disc: the fitted source body is a disc of radius 30 px, the target one of radius 24 with the
exact radial correspondence; the person's foreground is larger than the fitted source body (a 3 px rim all round,
as a fitted body's pose and shape errors leave it), has a bag held out to the right and hair on top, which the body
does not explain. Before MIR12k the outline band (6 px) carried the rim outside the target body and MLS farther out,
so the warped person was ~3 px too wide all round and the bag showed; MIR12k cut the rim and the bag with it; MIR12l
cuts the rim and carries the bag and the hair (regions reaching more than ``EXTRA_REACH_PX`` outside the source body).
"""

import cv2
import numpy as np

from bodystudio.mirror.evaluate import mask_iou
from bodystudio.mirror.warp import (
    EXTRA_REACH_PX,
    OUTLINE_BAND_PX,
    OUTSIDE_PX,
    DenseCorrespondence,
    carry_extras,
    foreground_extras,
    mls_grid_nodes,
    mls_warp_field,
    refine_outline,
    warp_foreground,
)

H, W = 120, 160
CX, CY = 80.0, 60.0
R_SOURCE, R_TARGET = 30.0, 24.0
# attached to the source body (its edge: x 108.9 at rows 52-67, y 30 at columns 74-86), reaching well beyond it
BAG = np.s_[52:68, 108:int(CX + R_SOURCE + EXTRA_REACH_PX) + 10]
HAIR = np.s_[int(CY - R_SOURCE - EXTRA_REACH_PX) - 6:31, 74:87]


def _case():
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
    r = np.hypot(xx - CX, yy - CY)
    source_body, target_body = r < R_SOURCE, r < R_TARGET
    scale = R_SOURCE / R_TARGET
    uv = np.full((H, W, 2), np.nan, np.float32)
    uv[target_body, 0] = (CX + (xx - CX) * scale)[target_body]
    uv[target_body, 1] = (CY + (yy - CY) * scale)[target_body]
    xs, ys = mls_grid_nodes((H, W), (H // 4, W // 4))
    X, Y = np.meshgrid(xs, ys)
    node_in = np.hypot(X - CX, Y - CY) < R_TARGET - 1.0
    grid_uv = np.full(X.shape + (2,), np.nan, np.float32)
    grid_uv[node_in, 0] = (CX + (X - CX) * scale)[node_in]
    grid_uv[node_in, 1] = (CY + (Y - CY) * scale)[node_in]
    dense = DenseCorrespondence((0, 0), uv, source_body, grid_uv)
    angles = np.linspace(0.0, 2.0 * np.pi, 48, endpoint=False)
    ring = np.stack([np.cos(angles), np.sin(angles)], 1)
    src_pts, dst_pts = [CX, CY] + R_SOURCE * ring, [CX, CY] + R_TARGET * ring
    person = r < R_SOURCE + 3.0  # the person: 3 px beyond the fitted body all round
    person[BAG] = True  # a bag held out to the right
    person[HAIR] = True  # hair on top
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
    return dense, src_pts, dst_pts, person, rgb, target_body


def _warped(field, person, rgb):
    _, alpha = warp_foreground(rgb, person, field)
    return alpha > 0.5


def test_without_the_foreground_the_warped_person_is_the_target_body_and_one_pixel_around_it():
    """MIR12k's field (``foreground`` not given): the rim, the bag and the hair all cut."""
    dense, src_pts, dst_pts, person, rgb, target_body = _case()
    field = mls_warp_field(src_pts, dst_pts, (H, W), grid=(H // 4, W // 4), kind="similarity", alpha=2.0,
                           radius_px=32.0, dense=dense)
    warped = _warped(field, person, rgb)
    out = cv2.distanceTransform((~target_body).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_5)
    assert OUTLINE_BAND_PX == 1.0
    # nothing of the rim, the bag or the hair farther out than the band; the field maps every such pixel outside
    assert not (warped & (out > 1.0)).any()
    assert (field[out > 1.0] == OUTSIDE_PX).all()
    # the body is all there, and the band's ring of 4-neighbours takes the rim just outside the source body
    assert warped[target_body].all()
    assert warped[out == 1.0].mean() > 0.95
    iou = mask_iou(warped, target_body)
    assert iou > 0.92, iou  # measured 0.929: the 1 px ring of 4-neighbours on a radius-24 disc

    # before MIR12k (a 6 px band, MLS farther out): the rim comes out ~3 px too wide and the bag shows
    before = mls_warp_field(src_pts, dst_pts, (H, W), grid=(H // 4, W // 4), kind="similarity", alpha=2.0,
                            radius_px=32.0, dense=dense, band_px=6.0, mls_outside=True)
    warped_before = _warped(before, person, rgb)
    assert (warped_before & (out > 2.0)).sum() > 300
    assert mask_iou(warped_before, target_body) < iou - 0.1


def test_without_the_dense_correspondence_the_field_is_eq5_mls_as_before():
    """The MLS-only warp (``mirror run --correspondence mls``) is untouched: the field is solved around the target
    points and up-sampled, whatever the band."""
    dense, src_pts, dst_pts, person, rgb, target_body = _case()
    a = mls_warp_field(src_pts, dst_pts, (H, W), grid=(H // 4, W // 4), kind="similarity", alpha=2.0, radius_px=32.0)
    b = mls_warp_field(src_pts, dst_pts, (H, W), grid=(H // 4, W // 4), kind="similarity", alpha=2.0, radius_px=32.0,
                       band_px=6.0)
    np.testing.assert_array_equal(a, b)
    yy, xx = np.mgrid[0:H, 0:W]
    far_out = np.hypot(xx - CX, yy - CY) > R_TARGET + 8.0
    assert (a[far_out & (np.hypot(xx - CX, yy - CY) < R_TARGET + 16.0)] != OUTSIDE_PX).all()
    # the MLS similarity of a scaled ring is the scaling (the target ring onto the source's) inside it
    inner = np.hypot(xx - CX, yy - CY) < R_TARGET - 4.0
    expect = np.stack([CX + (xx - CX) * 1.25, CY + (yy - CY) * 1.25], -1)
    assert np.abs(a[inner] - expect[inner]).max() < 0.5


def _carried(region, person):
    """Where the disc's exact warp puts the part of ``region`` outside the source body: each pixel moved as the
    target body's nearest outline point is (by R_SOURCE - R_TARGET px towards the centre)."""
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
    r = np.hypot(xx - CX, yy - CY)
    src = np.zeros((H, W), bool)
    src[region] = person[region]
    src &= r >= R_SOURCE
    ys, xs = np.nonzero(src)
    d = R_SOURCE - R_TARGET
    rr = np.hypot(xs - CX, ys - CY)
    out = np.zeros((H, W), bool)
    out[np.round(ys - d * (ys - CY) / rr).astype(int), np.round(xs - d * (xs - CX) / rr).astype(int)] = True
    return out


def test_the_bag_and_the_hair_are_carried_and_the_misalignment_ring_is_still_cut():
    """MIR12l: with the person's foreground, the regions reaching beyond ``EXTRA_REACH_PX`` (the bag, the hair) are
    warped with the body, attached to it; the 3 px rim (the fit's misalignment) stays cut."""
    dense, src_pts, dst_pts, person, rgb, target_body = _case()
    field = mls_warp_field(src_pts, dst_pts, (H, W), grid=(H // 4, W // 4), kind="similarity", alpha=2.0,
                           radius_px=32.0, dense=dense, foreground=person)
    assert 4.0 <= EXTRA_REACH_PX <= 12.0
    warped = _warped(field, person, rgb)
    out = cv2.distanceTransform((~target_body).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_5)
    assert warped[target_body].all()
    for region in (BAG, HAIR):
        # beyond the rim's reach (3 px out; the rim next to a blob is carried with it, as its attachment)
        expect = _carried(region, person) & (out > 3.5)
        got = warped & (out > 3.5)
        # each blob where the body's displacement puts it (within a pixel), nearly all of it
        near = cv2.dilate(expect.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
        blob = got & cv2.dilate(near.astype(np.uint8), np.ones((9, 9), np.uint8)).astype(bool)
        assert (blob & ~near).sum() <= 0.05 * expect.sum(), (blob & ~near).sum()
        assert (expect & got).sum() >= 0.9 * expect.sum(), ((expect & got).sum(), expect.sum())
        # the colours are the blob's own: the warp samples the source pixel the body's displacement says
        ys, xs = np.nonzero(expect & got)
        u = field[ys, xs]
        assert np.abs(u - np.round(u)).max() < 0.51
    # the rim away from the blobs: nothing farther out than the band
    yy, xx = np.mgrid[0:H, 0:W]
    away = (xx < CX + 12) & (yy > CY - 12)
    assert not (warped & (out > 1.0) & away).any()
    # nothing else beyond the band than the two blobs and their attachment (the rim next to them)
    blobs = cv2.dilate((_carried(BAG, person) | _carried(HAIR, person)).astype(np.uint8),
                       np.ones((2 * int(EXTRA_REACH_PX) + 5,) * 2, np.uint8)) > 0
    assert not (warped & (out > 1.0) & ~blobs).any()
    iou = mask_iou(warped & ~blobs, target_body & ~blobs)
    assert iou > 0.92, iou


def test_the_extras_need_to_reach_beyond_the_threshold():
    """The same person with the bag and hair shortened to ``EXTRA_REACH_PX`` - 2 px outside the body: all cut, as
    the rim (a planted threshold of 0 or a dropped distance test would carry the rim and the stubs)."""
    dense, src_pts, dst_pts, person, rgb, target_body = _case()
    yy, xx = np.mgrid[0:H, 0:W]
    r = np.hypot(xx - CX, yy - CY)
    short = person.copy()
    short[r > R_SOURCE + EXTRA_REACH_PX - 2.0] = False
    field = mls_warp_field(src_pts, dst_pts, (H, W), grid=(H // 4, W // 4), kind="similarity", alpha=2.0,
                           radius_px=32.0, dense=dense, foreground=short)
    plain = mls_warp_field(src_pts, dst_pts, (H, W), grid=(H // 4, W // 4), kind="similarity", alpha=2.0,
                           radius_px=32.0, dense=dense)
    np.testing.assert_array_equal(field, plain)


def test_no_extras_transform_where_the_foreground_stays_within_reach(monkeypatch):
    """The 3 px rim alone: the outline's distances tell, ``foreground_extras`` (its distance transform) is not run."""
    from bodystudio.mirror import warp

    dense, src_pts, dst_pts, _, _, _ = _case()
    yy, xx = np.mgrid[0:H, 0:W]
    person = np.hypot(xx - CX, yy - CY) < R_SOURCE + 3.0
    plain = mls_warp_field(src_pts, dst_pts, (H, W), grid=(H // 4, W // 4), kind="similarity", alpha=2.0,
                           radius_px=32.0, dense=dense)

    def never(*a, **k):
        raise AssertionError("foreground_extras run where no foreground reaches beyond the threshold")

    monkeypatch.setattr(warp, "foreground_extras", never)
    field = mls_warp_field(src_pts, dst_pts, (H, W), grid=(H // 4, W // 4), kind="similarity", alpha=2.0,
                           radius_px=32.0, dense=dense, foreground=person)
    np.testing.assert_array_equal(field, plain)


def test_the_quick_check_for_no_extras_is_the_full_one():
    """``mls_warp_field`` skips the extras' own distance transform where the outline's distances show no foreground
    beyond reach; with rims of every width around the threshold the field is the full path's (refine_outline, then
    carry_extras of foreground_extras), and the rims beyond it are carried."""
    dense, src_pts, dst_pts, _, _, _ = _case()
    yy, xx = np.mgrid[0:H, 0:W]
    r = np.hypot(xx - CX, yy - CY)
    carried = 0
    for rim in np.arange(EXTRA_REACH_PX - 2.0, EXTRA_REACH_PX + 3.0, 0.5):
        person = r < R_SOURCE + rim
        field = mls_warp_field(src_pts, dst_pts, (H, W), grid=(H // 4, W // 4), kind="similarity", alpha=2.0,
                               radius_px=32.0, dense=dense, foreground=person)
        full = refine_outline(np.full((H, W, 2), OUTSIDE_PX, np.float32), dense, OUTLINE_BAND_PX, 8.0)
        carry_extras(full, dense, foreground_extras(person, dense))
        np.testing.assert_array_equal(field, full)
        carried += int((field != OUTSIDE_PX).any(-1).sum() > (np.hypot(xx - CX, yy - CY) < R_TARGET + 1.5).sum())
    assert 2 <= carried <= 6, carried
    # a bag held apart from the body, beyond the outline's boxes (their margin: 12 px), with the 3 px rim: carried
    person = r < R_SOURCE + 3.0
    person[56:64, 126:134] = True
    field = mls_warp_field(src_pts, dst_pts, (H, W), grid=(H // 4, W // 4), kind="similarity", alpha=2.0,
                           radius_px=32.0, dense=dense, foreground=person)
    full = refine_outline(np.full((H, W, 2), OUTSIDE_PX, np.float32), dense, OUTLINE_BAND_PX, 8.0)
    carry_extras(full, dense, foreground_extras(person, dense))
    np.testing.assert_array_equal(field, full)
    # moved in by ~6 px with the side, and ~15 % shorter as the radial displacement squeezes it (6 rows of 8)
    shown = (field != OUTSIDE_PX).all(-1) & (r > R_TARGET + 8.0)
    assert shown[56:64, 120:128].sum() == 48 and shown.sum() == 48
