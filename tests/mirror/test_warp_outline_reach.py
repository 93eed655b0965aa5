"""MIR12k: the dense warp shows the person on the target body and 1 px around its outline, nothing farther out.

A shrinking edit on a disc: the fitted source body is a disc of radius 30 px, the target one of radius 24 with the
exact radial correspondence; the person's foreground is larger than the fitted source body (a 3 px rim all round,
as a fitted body's pose and shape errors leave it) and has a bag held out to the right, which the body does not
explain. Before MIR12k the outline band (6 px) carried the rim outside the target body and MLS farther out, so the
warped person was ~3 px too wide all round and the bag showed.
"""

import cv2
import numpy as np

from bodystudio.mirror.evaluate import mask_iou
from bodystudio.mirror.warp import (
    OUTLINE_BAND_PX,
    OUTSIDE_PX,
    DenseCorrespondence,
    mls_grid_nodes,
    mls_warp_field,
    warp_foreground,
)

H, W = 120, 160
CX, CY = 80.0, 60.0
R_SOURCE, R_TARGET = 30.0, 24.0


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
    person[52:68, 108:124] = True  # and a bag held out to the right
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
    return dense, src_pts, dst_pts, person, rgb, target_body


def _warped(field, person, rgb):
    _, alpha = warp_foreground(rgb, person, field)
    return alpha > 0.5


def test_the_warped_person_is_the_target_body_and_one_pixel_around_it():
    dense, src_pts, dst_pts, person, rgb, target_body = _case()
    field = mls_warp_field(src_pts, dst_pts, (H, W), grid=(H // 4, W // 4), kind="similarity", alpha=2.0,
                           radius_px=32.0, dense=dense)
    warped = _warped(field, person, rgb)
    out = cv2.distanceTransform((~target_body).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_5)
    assert OUTLINE_BAND_PX == 1.0
    # nothing of the rim or the bag farther out than the band; the field maps every such pixel outside
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
