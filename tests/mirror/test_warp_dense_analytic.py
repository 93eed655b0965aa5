"""The dense render-based correspondence of the mirror warp (§5.4 of Real-time Reshaping, dense counterpart of
Eq. 5's handles) against answers known exactly: the crop camera, the bodies' crop box, the grid-node samples of
the correspondence, the signed distance of a straight outline, the outline band on a straight edge (a closed
form), the block up-sampling against the full ``cv2.resize``, the dense nodes of the grid field.

Each test builds its own few-pixel scene and runs in well under a second.
"""

import types

import cv2
import numpy as np
import pytest

from bodystudio.errors import InputError
from bodystudio.geometry.camera import Camera
from bodystudio.mirror.warp import (
    _UNSOLVED_PX,
    OUTSIDE_PX,
    DenseCorrespondence,
    _body_crop,
    _grid_samples,
    _signed_distance,
    actors_warp_pairs,
    crop_camera,
    dense_source_uv,
    mls_grid_nodes,
    mls_warp_field,
    refine_outline,
    upsample_field,
    warp_pairs,
)


def _camera(width=320, height=200, dist=None):
    K = np.array([[210.0, 0.0, 151.5], [0.0, 190.0, 103.25], [0.0, 0.0, 1.0]])
    th = np.deg2rad(7.0)
    R = np.array([[np.cos(th), 0.0, np.sin(th)], [0.0, 1.0, 0.0], [-np.sin(th), 0.0, np.cos(th)]])
    return Camera("cam", K, np.zeros(5) if dist is None else np.asarray(dist, float), R,
                  np.array([0.1, -0.05, 0.2]), width, height)


# --- crop_camera --------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("scale", [(1.0, 1.0), (0.25, 0.5)])
def test_crop_camera_maps_image_pixels_to_crop_pixels(scale):
    """Pixel (c, r) of the crop is image pixel ((c + 0.5) / s_x - 0.5 + x0, (r + 0.5) / s_y - 0.5 + y0)."""
    cam = _camera()
    x0, y0 = 37, 21
    small = crop_camera(cam, x0, y0, 90.0, 61.0, scale)
    P = np.random.default_rng(0).uniform([-0.5, -0.4, 2.0], [0.5, 0.4, 3.0], (50, 3))
    uv = cam.project(P)
    expect = np.c_[(uv[:, 0] - x0 + 0.5) * scale[0] - 0.5, (uv[:, 1] - y0 + 0.5) * scale[1] - 0.5]
    np.testing.assert_allclose(small.project(P), expect, atol=1e-9)
    assert (small.width, small.height) == (90, 61) and isinstance(small.width, int)
    assert small.name == cam.name
    np.testing.assert_array_equal(small.R, cam.R)
    np.testing.assert_array_equal(small.t, cam.t)
    np.testing.assert_array_equal(cam.K, _camera().K)  # the original camera is untouched


def test_crop_camera_keeps_the_distortion():
    cam = _camera(dist=[0.12, -0.05, 0.002, -0.001, 0.01])
    small = crop_camera(cam, 10, 5, 100, 80)
    np.testing.assert_array_equal(small.dist, cam.dist)
    P = np.array([[0.4, 0.3, 2.0], [-0.3, 0.2, 2.5]])
    np.testing.assert_allclose(small.project(P), cam.project(P) - [10, 5], atol=1e-9)


# --- _body_crop ---------------------------------------------------------------------------------------------------

def test_body_crop_is_the_points_box_plus_the_margin_clipped_to_the_image():
    cam = _camera(320, 200)
    a = np.array([[100.2, 50.7], [np.nan, 3.0], [140.6, 80.1]])
    b = np.array([[120.0, 90.5], [np.nan, np.nan]])
    # x0 = floor(100.2 - 10), y0 = floor(50.7 - 10), x1 = ceil(140.6 + 10) + 1, y1 = ceil(90.5 + 10) + 1
    assert _body_crop([a, b], cam, 10.0) == (90, 40, 152, 102)
    assert _body_crop([a, b], cam, 0.0) == (100, 50, 142, 92)
    # clipped to the image on every side
    assert _body_crop([np.array([[3.5, 2.5], [315.5, 196.5]])], cam, 10.0) == (0, 0, 320, 200)
    # no finite point, or a box wholly off the image: no crop
    assert _body_crop([np.full((3, 2), np.nan)], cam, 10.0) is None
    assert _body_crop([np.array([[400.0, 50.0], [420.0, 60.0]])], cam, 10.0) is None
    assert _body_crop([np.array([[50.0, -80.0], [60.0, -40.0]])], cam, 10.0) is None


# --- _grid_samples ------------------------------------------------------------------------------------------------

def _affine_uv(h, w, x0, y0):
    """A correspondence affine in the image pixel: u = 0.8 x + 0.1 y + 5, v = -0.2 x + 1.1 y - 3."""
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    X, Y = xx + x0, yy + y0
    return np.stack([0.8 * X + 0.1 * Y + 5.0, -0.2 * X + 1.1 * Y - 3.0], -1).astype(np.float32)


def test_grid_samples_are_the_bilinear_value_at_each_node():
    """Nodes sit at pixel 4 j + 1.5: the mean of the 2x2 pixels around a node is an affine map's value there; a
    node whose 2x2 block is not wholly covered, or leaves the crop, is NaN; the person is the face group of
    the block's top-left pixel."""
    cam = types.SimpleNamespace(width=64, height=48)
    grid = (12, 16)
    x0, y0, h, w = 9, 6, 30, 41
    uv = _affine_uv(h, w, x0, y0)
    tri = np.full((h, w), -1, np.int32)
    tri[:, :20] = 0
    tri[:, 20:] = 1
    tri[25:, :] = -1  # the lowest rows uncovered
    uv[tri < 0] = np.nan
    out, groups = _grid_samples(uv, tri, (x0, y0), cam, grid, np.array([3, 7]))
    xs, ys = mls_grid_nodes((48, 64), grid)
    assert out.shape == (12, 16, 2) and out.dtype == np.float32
    X, Y = np.meshgrid(xs, ys)
    expect = np.stack([0.8 * X + 0.1 * Y + 5.0, -0.2 * X + 1.1 * Y - 3.0], -1)
    cx, cy = np.floor(xs).astype(int) - x0, np.floor(ys).astype(int) - y0
    inx = (cx >= 0) & (cx + 1 < w)
    iny = (cy >= 0) & (cy + 1 < 25)
    ok = iny[:, None] & inx[None, :]
    assert ok.sum() == 6 * 10  # nodes x = 9.5 .. 45.5 and y = 5.5 .. 25.5 in the crop: 10 x 6 (y = 5.5 is out)
    np.testing.assert_allclose(out[ok], expect[ok], atol=1e-4)
    assert np.isnan(out[~ok]).all()
    # the person: face 0 left of crop column 20 (image x 29), face 1 right of it; 0 where uncovered
    expect_g = np.where(np.floor(xs) < 29, 3, 7)[None, :] * ok
    np.testing.assert_array_equal(groups, np.broadcast_to(expect_g, (12, 16)))
    assert groups.dtype == np.int64
    assert _grid_samples(uv, tri, (x0, y0), cam, grid, None)[1] is None


def test_grid_samples_nodes_at_the_crops_last_pixels():
    """A node whose 2x2 block ends on the crop's last column / row is sampled; one pixel further it is not."""
    cam = types.SimpleNamespace(width=16, height=16)
    # nodes at 1.5, 5.5, 9.5, 13.5: the block of node 2 is pixels 9..10
    for w, n_in in ((11, 3), (10, 2)):
        uv = _affine_uv(w, w, 0, 0)
        tri = np.zeros((w, w), np.int32)
        out, _ = _grid_samples(uv, tri, (0, 0), cam, (4, 4), None)
        inside = np.isfinite(out[..., 0])
        assert inside.sum() == n_in * n_in and inside[:n_in, :n_in].all()


# --- _signed_distance ---------------------------------------------------------------------------------------------

def test_signed_distance_of_a_straight_outline_is_exact():
    """Columns 0..41 inside: the pixel centre x lies 41.5 - x from the outline (positive inside)."""
    m = np.zeros((20, 80), bool)
    m[:, :42] = True
    sd = _signed_distance(m)
    assert sd.dtype == np.float32
    np.testing.assert_array_equal(sd, np.broadcast_to(41.5 - np.arange(80, dtype=np.float32), (20, 80)))
    # a disc: the outline at the radius, to the distance transform's 5x5 mask accuracy
    yy, xx = np.mgrid[0:81, 0:81]
    r = np.hypot(xx - 40, yy - 40)
    sd = _signed_distance(r < 25.3)
    near = np.abs(r - 25.3) < 6
    assert np.abs(sd[near] - (25.3 - r[near])).max() < 0.7


# --- refine_outline: the outline band on a straight edge ----------------------------------------------------------

def _straight_edge_case(x0=7, y0=4, h=24, w=90, shift=(-10.0, 3.0)):
    """Target covers crop columns 0..49, its correspondence a shift of -10 px in x and +3 in y; the source's
    outline is at crop column 41.5 (covers 0..41), 2 px left of where the shifted target outline lands (39.5 + 2):
    the band must take the target's outline onto the source's."""
    target = np.zeros((h, w), bool)
    target[:, :50] = True
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    uv = np.full((h, w, 2), np.nan, np.float32)
    uv[target, 0] = (xx + x0 + shift[0])[target]
    uv[target, 1] = (yy + y0 + shift[1])[target]
    source = np.zeros((h, w), bool)
    source[:, :42] = True
    return DenseCorrespondence((x0, y0), uv, source, np.full((2, 2, 2), np.nan, np.float32))


@pytest.mark.parametrize("shift", [(-10.0, 3.0), (-10.3, 3.4)])
def test_outline_band_on_a_straight_edge_is_the_closed_form(shift):
    """Crop column c (image x = c + x0). Covered and deeper than ``inner_px`` (depth 50 - c > 8): the
    correspondence, x - 10. Covered within 8 px of the outline: moved to the source's signed distance
    depth - 0.5, i.e. source crop column 41.5 - (49.5 - c) = c - 8. Outside, within ``band_px`` (distance c - 49
    <= 6): signed distance 0.5 - (c - 49), column 41 + c - 49 = c - 8 again. Beyond: the grid field, untouched.
    The y component keeps the correspondence's (the outline's normal is horizontal). A fractional shift samples
    the signed distance between pixel centres (bilinear: still exact, it is linear)."""
    x0, y0, h, w = 7, 4, 24, 90
    dense = _straight_edge_case(x0, y0, h, w, shift)
    H, W = 40, 110
    field = np.full((H, W, 2), 123.0, np.float32)
    out = refine_outline(field, dense, band_px=6.0, inner_px=8.0)
    assert out is field  # in place
    c = np.arange(w)
    expect_x = np.where(c <= 41, c + x0 + shift[0], np.where(c <= 55, c + x0 - 8.0, 123.0))
    crop = field[y0:y0 + h, x0:x0 + w]
    np.testing.assert_allclose(crop[..., 0], np.broadcast_to(expect_x, (h, w)), atol=1e-4)
    yy = np.arange(h)[:, None] + y0 + shift[1]
    expect_y = np.where(c <= 55, yy, 123.0)
    np.testing.assert_allclose(crop[..., 1], np.broadcast_to(expect_y, (h, w)), atol=1e-4)
    # nothing outside the crop is written
    rest = np.ones((H, W), bool)
    rest[y0:y0 + h, x0:x0 + w] = False
    assert (field[rest] == 123.0).all()


def test_outline_band_widths_and_defaults():
    """``band_px`` and ``inner_px`` set where the band stops on each side; the defaults are 6 and 8 px; no
    covered pixel: the field is returned untouched."""
    x0, y0, h, w = 7, 4, 24, 90
    c = np.arange(w)
    for band, inner in ((3.0, 2.0), (10.0, 0.0)):
        field = np.full((40, 110, 2), 123.0, np.float32)
        refine_outline(field, _straight_edge_case(x0, y0, h, w), band_px=band, inner_px=inner)
        inner_first = 50 - int(inner)  # depth 50 - c <= inner
        expect_x = np.where(c < inner_first, c + x0 - 10.0, np.where(c <= 49 + band, c + x0 - 8.0, 123.0))
        np.testing.assert_allclose(field[y0 + 5, x0:x0 + w, 0], expect_x, atol=1e-4)
    default = np.full((40, 110, 2), 123.0, np.float32)
    refine_outline(default, _straight_edge_case(x0, y0, h, w))
    explicit = np.full((40, 110, 2), 123.0, np.float32)
    refine_outline(explicit, _straight_edge_case(x0, y0, h, w), 6.0, 8.0)
    np.testing.assert_array_equal(default, explicit)
    empty = DenseCorrespondence((0, 0), np.full((5, 6, 2), np.nan, np.float32), np.ones((5, 6), bool),
                                np.full((2, 2, 2), np.nan, np.float32))
    field = np.full((10, 10, 2), 5.0, np.float32)
    assert refine_outline(field, empty) is field and (field == 5.0).all()


def test_outline_band_follows_the_nearest_covered_pixel_of_a_corner():
    """A band pixel takes the correspondence of its nearest covered pixel (label), not of another one: below a
    target covering crop rows 0..9 whose correspondence is the identity plus (0, 0) but whose source outline is
    at row 11.5 (covers 0..11), the band row 10 + k maps to source row 11 + k + 1 - 1 = 12 + k - 1 ... exactly
    2 rows down, whatever the column."""
    h, w = 30, 40
    target = np.zeros((h, w), bool)
    target[:10, :] = True
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    uv = np.full((h, w, 2), np.nan, np.float32)
    uv[target] = np.stack([xx, yy], -1)[target] + [2.0, 0.0]
    source = np.zeros((h, w), bool)
    source[:12, :] = True
    dense = DenseCorrespondence((0, 0), uv, source, np.full((2, 2, 2), np.nan, np.float32))
    field = np.full((h, w, 2), -7.0, np.float32)
    refine_outline(field, dense, band_px=5.0, inner_px=0.0)
    # outside rows 10..14 (distance 1..5): source row 11.5 - (0.5 - d) = 11 + d = r + 2; x: the nearest covered
    # pixel is straight above (same column), its correspondence x + 2
    r = np.arange(10, 15)[:, None]
    np.testing.assert_allclose(field[10:15, :, 1], np.broadcast_to(r + 2.0, (5, w)), atol=1e-4)
    np.testing.assert_allclose(field[10:15, 2:-2, 0], np.broadcast_to(np.arange(2, w - 2) + 2.0, (5, w - 4)),
                               atol=1e-4)
    # inside (inner 0 px: no pixel is that shallow) the correspondence as it is; beyond the band untouched
    np.testing.assert_allclose(field[:10], uv[:10], atol=0)
    assert (field[15:] == -7.0).all()


# --- upsample_field -----------------------------------------------------------------------------------------------

@pytest.mark.parametrize("shape, grid", [((480, 640), (120, 160)), ((96, 128), (24, 32)), ((100, 150), (25, 30))])
def test_block_upsampling_equals_resizing_the_whole_grid(shape, grid):
    """The field up-sampled only on the block of solved nodes (+1 node) is the whole grid resized bilinearly,
    clamped to OUTSIDE_PX: pixels next to an unsolved node map outside."""
    gh, gw = grid
    rng = np.random.default_rng(3)
    field = np.full((gh, gw, 2), _UNSOLVED_PX, np.float32)
    r0, c0 = gh // 3, gw // 4
    field[r0:r0 + 7, c0:c0 + 9] = rng.uniform(0, 100, (7, 9, 2))
    field[r0 + 3, c0 + 9] = rng.uniform(0, 100, 2)  # a ragged edge
    full = np.maximum(cv2.resize(field, (shape[1], shape[0]), interpolation=cv2.INTER_LINEAR), OUTSIDE_PX)
    out = upsample_field(field, shape)
    assert out.shape == (*shape, 2) and out.dtype == np.float32
    np.testing.assert_allclose(out, full, atol=1e-3)
    assert (out > OUTSIDE_PX).sum() > 0 and (out == OUTSIDE_PX).any()


@pytest.mark.parametrize("where", ["top-left", "bottom-right"])
def test_block_upsampling_at_the_grid_corners(where):
    """Solved nodes on the grid's first / last row and column: the block is clipped to the grid, the image's edge
    pixels are the edge nodes' values (cv2.resize replicates the border)."""
    gh, gw, H, W = 12, 16, 48, 64
    field = np.full((gh, gw, 2), _UNSOLVED_PX, np.float32)
    sl = (slice(0, 4), slice(0, 5)) if where == "top-left" else (slice(gh - 4, gh), slice(gw - 5, gw))
    field[sl] = np.random.default_rng(4).uniform(0, 50, (4, 5, 2))
    full = np.maximum(cv2.resize(field, (W, H), interpolation=cv2.INTER_LINEAR), OUTSIDE_PX)
    np.testing.assert_allclose(upsample_field(field, (H, W)), full, atol=1e-3)


def test_upsampling_an_unsolved_grid_maps_everything_outside():
    out = upsample_field(np.full((6, 8, 2), _UNSOLVED_PX, np.float32), (24, 32))
    assert out.shape == (24, 32, 2) and (out == OUTSIDE_PX).all() and out.dtype == np.float32
    # the default shape is the Kinect colour image
    assert upsample_field(np.full((120, 160, 2), _UNSOLVED_PX, np.float32)).shape == (480, 640, 2)


# --- mls_warp_field with dense grid nodes -------------------------------------------------------------------------

def _square_pairs(cx, cy, half, shift):
    t = np.array([[cx - half, cy - half], [cx + half, cy - half], [cx, cy + half], [cx + half, cy + half]])
    return t + shift, t


def test_dense_nodes_take_their_value_and_set_the_region_around_them():
    """Grid = image (nodes on pixels, up-sampling the identity): covered nodes hold ``dense_src_uv`` exactly, the
    nodes within the margin of a covered node or a target point are solved by MLS (here a pure translation of the
    pairs), everything farther maps outside."""
    H, W = 40, 60
    s, t = _square_pairs(10.0, 10.0, 3.0, [2.0, -1.0])
    node_uv = np.full((H, W, 2), np.nan, np.float32)
    node_uv[25:30, 40:46] = [[[7.0, 9.0]]]
    field = mls_warp_field(s, t, shape=(H, W), grid=(H, W), kind="similarity", roi_margin_px=3.0,
                           dense_src_uv=node_uv)
    assert (field[25:30, 40:46] == [7.0, 9.0]).all()
    yy, xx = np.mgrid[0:H, 0:W]
    # reach = margin / cell + 1 = 4 nodes (cells 1 px): Chebyshev-ish rings around the covered block
    d_dense = cv2.distanceTransform((~np.isfinite(node_uv[..., 0])).astype(np.uint8), cv2.DIST_L2,
                                    cv2.DIST_MASK_PRECISE)
    solved = (d_dense <= 4.0) & ~np.isfinite(node_uv[..., 0])
    np.testing.assert_allclose(field[solved], np.stack([xx, yy], -1)[solved] + [2.0, -1.0], atol=1e-6)
    far = (d_dense > 4.0)
    free = np.ones((H, W), np.uint8)
    free[np.round(t[:, 1]).astype(int), np.round(t[:, 0]).astype(int)] = 0
    far &= cv2.distanceTransform(free, cv2.DIST_L2, cv2.DIST_MASK_PRECISE) > 4.0
    assert (field[far] == OUTSIDE_PX).all()
    assert far[30:, :].any() and solved.sum() > 0


def test_dense_nodes_bring_their_persons_region():
    """``dense_groups``: the region around a covered node is solved with the pairs of that node's person."""
    H, W = 40, 80
    s1, t1 = _square_pairs(10.0, 10.0, 3.0, [2.0, 0.0])
    s2, t2 = _square_pairs(70.0, 10.0, 3.0, [0.0, 3.0])
    s, t = np.vstack([s1, s2]), np.vstack([t1, t2])
    groups = np.array([0] * 4 + [1] * 4)
    node_uv = np.full((H, W, 2), np.nan, np.float32)
    node_uv[30:33, 20:23] = 1.0  # person 1's body far from person 1's points, nearer person 0's
    dense_groups = np.zeros((H, W), np.int64)
    dense_groups[30:33, 20:23] = 1
    field = mls_warp_field(s, t, shape=(H, W), grid=(H, W), kind="similarity", roi_margin_px=2.0, groups=groups,
                           dense_src_uv=node_uv, dense_groups=dense_groups)
    # the node left of the block: person 1's translation (0, 3)
    np.testing.assert_allclose(field[31, 19], [19.0, 34.0], atol=1e-6)
    field0 = mls_warp_field(s, t, shape=(H, W), grid=(H, W), kind="similarity", roi_margin_px=2.0, groups=groups,
                            dense_src_uv=node_uv)  # no groups: person 0
    np.testing.assert_allclose(field0[31, 19], [21.0, 31.0], atol=1e-6)


def test_dense_node_grid_of_the_wrong_shape_is_refused():
    s, t = _square_pairs(10.0, 10.0, 3.0, [2.0, 0.0])
    with pytest.raises(InputError, match=r"dense correspondence of shape \(4, 4, 2\), expected \(10, 12, 2\)"):
        mls_warp_field(s, t, shape=(20, 24), grid=(10, 12), dense_src_uv=np.zeros((4, 4, 2)))


def test_the_dense_correspondence_object_gives_the_nodes_and_the_band():
    """``dense=`` with ``mls_outside``: takes the grid nodes and groups from the object and refines the band with
    ``band_px`` / ``inner_band_px``: the same as passing the nodes and refining by hand. Without it (the default
    since MIR12k) only the body and the band are set, every other pixel maps outside, and the band is 1 px."""
    H, W = 40, 110
    d = _straight_edge_case()
    nodes = np.full((20, 55, 2), np.nan, np.float32)
    nodes[5:10, 5:20] = [[[30.0, 12.0]]]
    d = DenseCorrespondence(d.origin, d.source_uv, d.source_mask, nodes, np.zeros((20, 55), np.int64))
    s, t = _square_pairs(30.0, 20.0, 6.0, [1.0, 1.0])
    got = mls_warp_field(s, t, shape=(H, W), grid=(20, 55), kind="similarity", dense=d, band_px=3.0,
                         inner_band_px=2.0, mls_outside=True)
    by_hand = mls_warp_field(s, t, shape=(H, W), grid=(20, 55), kind="similarity", dense_src_uv=nodes)
    refine_outline(by_hand, d, 3.0, 2.0)
    np.testing.assert_array_equal(got, by_hand)
    assert (by_hand[30:, :5] != OUTSIDE_PX).any()  # the MLS solve reaches past the band
    default = mls_warp_field(s, t, shape=(H, W), grid=(20, 55), kind="similarity", dense=d)
    by_hand = np.full((H, W, 2), OUTSIDE_PX, np.float32)
    refine_outline(by_hand, d, 1.0, 8.0)
    np.testing.assert_array_equal(default, by_hand)


# --- dense_source_uv ----------------------------------------------------------------------------------------------

def _fake_raster(h, w):
    tri = np.full((h, w), -1, np.int32)
    tri[2:5, 3:7] = 1
    tri[6, 1] = 0
    bary = np.zeros((h, w, 3), np.float32)
    rng = np.random.default_rng(5)
    b = rng.uniform(0.1, 1.0, (h, w, 3))
    bary[:] = b / b.sum(2, keepdims=True)
    return types.SimpleNamespace(triangle_id=tri, barycentric=bary)


def test_dense_source_uv_projects_the_same_surface_point_of_the_source():
    """Each covered pixel: the projection of sum_k b_k V[f_k]; with ``projected``, sum_k b_k uv[f_k]; NaN elsewhere
    and where the point is behind the camera."""
    cam = _camera()
    V = np.array([[0.1, 0.0, 2.0], [0.3, 0.1, 2.2], [0.0, 0.3, 2.5], [-0.2, -0.1, 1.8]])
    F = np.array([[0, 1, 2], [1, 3, 2]])
    ras = _fake_raster(8, 9)
    out = dense_source_uv(V, F, ras, cam)
    assert out.shape == (8, 9, 2) and out.dtype == np.float32
    cov = ras.triangle_id >= 0
    rows, cols = np.nonzero(cov)
    b = ras.barycentric[rows, cols].astype(np.float64)
    X = np.einsum("nk,nkd->nd", b, V[F[ras.triangle_id[rows, cols]]])
    np.testing.assert_allclose(out[rows, cols], cam.project(X), atol=1e-3)
    assert np.isnan(out[~cov]).all()
    uv = cam.project(V)
    interp = dense_source_uv(V, F, ras, cam, projected=uv)
    np.testing.assert_allclose(interp[rows, cols], np.einsum("nk,nkd->nd", b, uv[F[ras.triangle_id[rows, cols]]]),
                               atol=1e-3)
    assert np.isnan(interp[~cov]).all() and interp.dtype == np.float32
    # the interpolated projection is not the projected point (perspective): the two paths differ
    assert np.abs(interp[rows, cols] - out[rows, cols]).max() > 1e-3
    # a source body behind the camera at some pixels: those stay NaN
    Vb = V.copy()
    Vb[3, 2] = -4.0  # face 1's vertex: points with enough weight on it are behind the camera
    back = dense_source_uv(Vb, F, ras, cam)
    z = (np.einsum("nk,nkd->nd", b, Vb[F[ras.triangle_id[rows, cols]]]) @ cam.R.T + cam.t)[:, 2]
    assert (z <= 0).any() and (z > 0).any()
    assert np.isnan(back[rows[z <= 0], cols[z <= 0]]).all()
    assert np.isfinite(back[rows[z > 0], cols[z > 0]]).all()
    empty = types.SimpleNamespace(triangle_id=np.full((3, 4), -1, np.int32), barycentric=np.zeros((3, 4, 3)))
    assert np.isnan(dense_source_uv(V, F, empty, cam)).all()


# --- warp_pairs with dense ----------------------------------------------------------------------------------------

def _plate(half, n, z, x=0.0):
    u = np.linspace(-half, half, n)
    X, Y = np.meshgrid(u + x, u)
    V = np.c_[X.ravel(), Y.ravel(), np.full(n * n, z)]
    F = []
    for r in range(n - 1):
        for c in range(n - 1):
            a = r * n + c
            F += [[a, a + n, a + 1], [a + 1, a + n, a + n + 1]]
    return V, np.array(F)


def test_dense_pairs_render_both_bodies_on_the_crop_holding_them():
    """A square plate at 2 m (the source) and the same plate moved and tilted (the target), 320 x 200 camera: the
    crop is both plates' box plus ``margin_px``; the correspondence covers exactly the target's render, maps each
    pixel to the source's projection of the same surface point, and the source mask is the source's render."""
    from bodystudio.capture.render import render

    V, F = _plate(0.2, 9, 2.0)
    cam = Camera("c", np.array([[200.0, 0.0, 150.0], [0.0, 200.0, 110.0], [0.0, 0.0, 1.0]]), np.zeros(5),
                 np.eye(3), np.zeros(3), 320, 200)
    Vt = V * [1.2, 1.1, 1.0] + [0.15, -0.05, 0.0]
    Vt[:, 2] += 0.1 * V[:, 0]  # a tilt: perspective differs across the plate
    p = warp_pairs(V, Vt, F, cam, n_handles=30, dense=True, grid=(50, 80), margin_px=7.0)
    uv_s, uv_t = cam.project(V), cam.project(Vt)
    both = np.vstack([uv_s, uv_t])
    x0, y0 = int(np.floor(both[:, 0].min() - 7)), int(np.floor(both[:, 1].min() - 7))
    x1, y1 = int(np.ceil(both[:, 0].max() + 7) + 1), int(np.ceil(both[:, 1].max() + 7) + 1)
    d = p.dense
    assert d.origin == (x0, y0) and d.source_uv.shape == (y1 - y0, x1 - x0, 2)
    full_t, full_s = render(Vt, F, cam), render(V, F, cam)
    np.testing.assert_array_equal(np.isfinite(d.source_uv[..., 0]), full_t.mask[y0:y1, x0:x1])
    np.testing.assert_array_equal(d.source_mask, full_s.mask[y0:y1, x0:x1])
    assert full_t.mask.sum() == np.isfinite(d.source_uv[..., 0]).sum()  # the crop holds the whole target
    # each pixel: the source point of the target's surface point there (the plates share the topology)
    Pt, rc = full_t.surface_points(Vt, F)
    Ps, _ = full_t.surface_points(V, F)
    inside = (rc[:, 0] >= y0) & (rc[:, 1] >= x0)
    np.testing.assert_allclose(d.source_uv[rc[inside, 0] - y0, rc[inside, 1] - x0], cam.project(Ps[inside]),
                               atol=0.02)
    # the grid nodes: the 2x2 means of that correspondence on the 50 x 80 grid, person None
    g, _ = _grid_samples(d.source_uv, render(Vt, F, crop_camera(cam, x0, y0, x1 - x0, y1 - y0)).triangle_id,
                         (x0, y0), cam, (50, 80), None)
    np.testing.assert_array_equal(d.grid_source_uv, g)
    assert np.isfinite(g).any() and d.grid_groups is None
    # every vertex of both plates is visible: all 30 evenly spread ids kept, the pairs are the projections
    ids = np.unique(np.linspace(0, len(V) - 1, 30).round().astype(int))
    np.testing.assert_array_equal(p.ids, ids)
    np.testing.assert_allclose(p.src_uv, uv_s[ids], atol=1e-9)
    np.testing.assert_allclose(p.dst_uv, uv_t[ids], atol=1e-9)
    # without dense: no correspondence, the same pairs
    q = warp_pairs(V, Vt, F, cam, n_handles=30)
    assert q.dense is None
    np.testing.assert_array_equal(q.ids, p.ids)


def test_dense_pairs_person_per_node_and_visibility_on_the_full_resolution_buffer():
    """Two plates side by side in one mesh (``face_groups`` 0 / 1): each covered node carries its plate's person;
    a third plate behind the first hides the vertices behind it in the full-resolution crop z-buffer."""
    V1, F1 = _plate(0.15, 7, 2.0, x=-0.25)
    V2, F2 = _plate(0.15, 7, 2.0, x=0.25)
    V3, F3 = _plate(0.1, 5, 2.5, x=-0.25)  # behind plate 1, hidden by it
    V = np.vstack([V1, V2, V3])
    F = np.vstack([F1, F2 + len(V1), F3 + 2 * len(V1)])
    cam = Camera("c", np.array([[200.0, 0.0, 160.0], [0.0, 200.0, 100.0], [0.0, 0.0, 1.0]]), np.zeros(5),
                 np.eye(3), np.zeros(3), 320, 200)
    fg = np.r_[np.zeros(len(F1), int), np.ones(len(F2), int), np.full(len(F3), 5)]
    p = warp_pairs(V, V, F, cam, n_handles=len(V), dense=True, grid=(50, 80), face_groups=fg)
    xs, _ = mls_grid_nodes((200, 320), (50, 80))
    g = p.dense.grid_groups
    covered = np.isfinite(p.dense.grid_source_uv[..., 0])
    left = covered & (xs[None, :] < 160)
    right = covered & (xs[None, :] > 160)
    assert left.sum() > 20 and right.sum() > 20
    assert (g[left] == 0).all() and (g[right] == 1).all() and (g[~covered] == 0).all()
    # the hidden plate's vertices are dropped, both visible plates kept
    hidden = np.arange(2 * len(V1), len(V))
    assert not np.isin(hidden, p.ids).any()
    assert np.isin(np.arange(2 * len(V1)), p.ids).all()


def _plate_camera():
    return Camera("c", np.array([[200.0, 0.0, 150.0], [0.0, 200.0, 110.0], [0.0, 0.0, 1.0]]), np.zeros(5),
                  np.eye(3), np.zeros(3), 320, 200)


def test_dense_pairs_interpolate_the_source_projections_unless_a_vertex_is_behind_the_camera():
    """All source vertices in front (here 0.8 m away, nearer than a metre): each covered pixel interpolates the
    source vertices' projections (:func:`dense_source_uv` with ``projected``). A source vertex behind the camera
    (a triangle of the mesh far behind, outside the target's render): the exact path, the surface point projected."""
    from bodystudio.capture.render import render

    cam = _plate_camera()
    V, F = _plate(0.1, 4, 0.8)
    V[:, 2] += 0.6 * V[:, 0]  # tilted: projection is not affine over a triangle
    Vt = V * [1.1, 1.0, 1.0] + [0.02, 0.01, 0.0]
    Vt[:, 2] += 0.3 * V[:, 0]
    p = warp_pairs(V, Vt, F, cam, n_handles=10, dense=True)
    d = p.dense
    assert d is not None
    x0, y0 = d.origin
    h, w = d.source_mask.shape
    rt = render(Vt, F, crop_camera(cam, x0, y0, w, h))
    interp = dense_source_uv(V, F, rt, cam, projected=cam.project(V))
    exact = dense_source_uv(V, F, rt, cam)
    np.testing.assert_array_equal(d.source_uv, interp)
    assert np.nanmax(np.abs(interp - exact)) > 1e-3  # the two paths differ here (a tilted plate, near)
    # a triangle behind the camera in the source (and in the target: not rendered)
    tri = np.array([[0.0, 0.0, -1.0], [0.1, 0.0, -1.0], [0.0, 0.1, -1.0]])
    V2, Vt2 = np.vstack([V, tri]), np.vstack([Vt, tri])
    F2 = np.vstack([F, [[len(V), len(V) + 1, len(V) + 2]]])
    q = warp_pairs(V2, Vt2, F2, cam, n_handles=10, dense=True)
    assert q.dense.origin == d.origin
    np.testing.assert_array_equal(q.dense.source_uv, dense_source_uv(V2, F2, rt, cam))
    # the default margin is 10 px around both bodies' projections
    both = np.vstack([cam.project(V), cam.project(Vt)])
    assert d.origin == (int(np.floor(both[:, 0].min() - 10)), int(np.floor(both[:, 1].min() - 10)))
    assert (w, h) == (int(np.ceil(both[:, 0].max() + 10) + 1) - d.origin[0],
                      int(np.ceil(both[:, 1].max() + 10) + 1) - d.origin[1])


def test_warp_pairs_defaults_800_candidates_and_the_quarter_size_z_buffer():
    """Without ``dense``: 800 evenly spread candidate ids by default, visibility on the quarter-size z-buffer (the
    same pairs as ``z_buffer_scale=0.25``); no rim vertices unless ``rim_cos``."""
    V, F = _plate(0.3, 31, 2.0)  # 961 vertices
    cam = _plate_camera()
    p = warp_pairs(V, V, F, cam)
    np.testing.assert_array_equal(p.ids, np.unique(np.linspace(0, len(V) - 1, 800).round().astype(np.int64)))
    assert len(p.ids) == 800 and p.dense is None
    from tests.mirror.test_warp_analytic import _occluder_scene

    Vo, Fo, camo, _ = _occluder_scene(0.32)
    shift = np.array([0.013, -0.007, 0.0])
    got = warp_pairs(Vo, Vo + shift, Fo, camo, n_handles=len(Vo))
    quarter = warp_pairs(Vo, Vo + shift, Fo, camo, n_handles=len(Vo), z_buffer_scale=0.25)
    full = warp_pairs(Vo, Vo + shift, Fo, camo, n_handles=len(Vo), z_buffer_scale=1.0)
    np.testing.assert_array_equal(got.ids, quarter.ids)
    assert not np.array_equal(quarter.ids, full.ids)  # the scale matters on this scene


def test_body_crop_of_zero_width_or_height_is_none():
    """Points just beyond the right / bottom edge: the clipped box is empty (x0 = x1 = width)."""
    cam = _camera(320, 200)
    assert _body_crop([np.array([[330.0, 50.0], [335.0, 60.0]])], cam, 10.0) is None
    assert _body_crop([np.array([[50.0, 210.0], [60.0, 215.0]])], cam, 10.0) is None
    assert _body_crop([np.array([[329.5, 50.0]])], cam, 10.0) == (319, 40, 320, 61)


def test_grid_samples_node_block_on_the_crops_first_row_and_column():
    """Nodes at 5.5, 9.5, ...: a crop at (5, 5) starts with node 1's block, which is sampled; one at (6, 6) does
    not hold it."""
    cam = types.SimpleNamespace(width=16, height=16)
    for origin, first in (((5, 5), True), ((6, 6), False)):
        uv = _affine_uv(8, 8, *origin)
        out, _ = _grid_samples(uv, np.zeros((8, 8), np.int32), origin, cam, (4, 4), None)
        assert np.isfinite(out[1, 1]).all() == first
        assert np.isnan(out[0]).all() and np.isnan(out[:, 0]).all()


def test_the_radius_is_checked_even_when_the_dense_nodes_cover_the_grid():
    s, t = _square_pairs(10.0, 10.0, 3.0, [2.0, 0.0])
    node_uv = np.ones((20, 24, 2), np.float32)
    field = mls_warp_field(s, t, shape=(20, 24), grid=(20, 24), dense_src_uv=node_uv, radius_px=5.0)
    assert (field == 1.0).all()
    for bad in (0.0, np.inf, -3.0):
        with pytest.raises(InputError, match="radius_px"):
            mls_warp_field(s, t, shape=(20, 24), grid=(20, 24), dense_src_uv=node_uv, radius_px=bad)


def test_target_points_on_the_grid_corners_solve_exactly_their_neighbouring_nodes():
    """Grid = image (1 px cells), margin 0: reach 1 node, so each corner point solves its node and the 2 next to
    it along the edges, nothing else (a point splatted one node inside would solve a node 2 away)."""
    H, W = 20, 30
    t = np.array([[0.0, 0.0], [W - 1.0, 0.0], [0.0, H - 1.0], [W - 1.0, H - 1.0]])
    field = mls_warp_field(t + [3.0, 1.0], t, shape=(H, W), grid=(H, W), kind="similarity", roi_margin_px=0.0)
    solved = field[..., 0] != OUTSIDE_PX
    expect = np.zeros((H, W), bool)
    for r, c in ((0, 0), (0, W - 1), (H - 1, 0), (H - 1, W - 1)):
        for dr, dc in ((0, 0), (1, 0), (-1, 0), (0, 1), (0, -1)):
            if 0 <= r + dr < H and 0 <= c + dc < W:
                expect[r + dr, c + dc] = True
    np.testing.assert_array_equal(solved, expect)
    yy, xx = np.nonzero(expect)
    np.testing.assert_allclose(field[yy, xx], np.c_[xx, yy] + [3.0, 1.0], atol=1e-4)


def test_a_group_without_an_affine_fit_leaves_its_region_outside_next_to_a_solved_one():
    """Two people, affine MLS: one person's pairs collinear (no fit: NaN), the other's a translation. The field is
    finite everywhere: the first person's region maps outside, the second's is the translation."""
    u = np.linspace(0, 1, 8)
    t0 = np.c_[150 + 36 * u, 60 + 0 * u]  # next to the other person: their nodes share the up-sampled block
    t1 = np.array([[200.0, 50.0], [240.0, 55.0], [220.0, 90.0], [205.0, 80.0]])
    t = np.vstack([t0, t1])
    s = t + [4.0, -2.0]
    groups = np.r_[np.zeros(8, int), np.ones(4, int)]
    field = mls_warp_field(s, t, shape=(120, 320), grid=(30, 80), kind="affine", roi_margin_px=8.0, groups=groups)
    assert np.isfinite(field).all()
    assert (field[55:66, 140:187] == OUTSIDE_PX).all()
    np.testing.assert_allclose(field[55, 240], [244.0, 53.0], atol=1e-3)


@pytest.mark.parametrize("axis", [0, 1])
def test_a_one_pixel_bar_hides_the_wall_vertex_right_behind_it(axis):
    """Full-resolution z-buffer (``dense``): a bar 0.8 px wide at 1 m covers exactly the pixel column (row) of a wall
    vertex at 3 m; the vertex is hidden by its own pixel's column (row) of the 3x3 neighbourhood, while its
    neighbours on either side show the wall. A wall vertex 3 px beside the bar is kept."""
    cam = _plate_camera()  # f 200 px, principal point (150, 110): x = 0, y = 0 project onto pixel centres
    half_w, half_l = 0.4 / 200.0, 0.3  # 0.8 px wide, 60 px long at 1 m
    bar = np.array([[-half_w, -half_l, 1.0], [half_w, -half_l, 1.0], [half_w, half_l, 1.0], [-half_w, half_l, 1.0]])
    if axis == 1:
        bar = bar[:, [1, 0, 2]]
    Fb = np.array([[0, 1, 2], [0, 2, 3]])
    Vw, Fw = _plate(0.3, 13, 3.0)  # 5 cm spacing: a vertex at (0, 0, 3) and at (0.05, 0, 3) (3.3 px aside)
    V = np.vstack([bar, Vw])
    F = np.vstack([Fb, Fw + 4])
    p = warp_pairs(V, V, F, cam, n_handles=len(V), dense=True)
    centre = 4 + int(np.flatnonzero(np.all(np.abs(Vw - [0.0, 0.0, 3.0]) < 1e-9, axis=1))[0])
    aside = 4 + int(np.flatnonzero(np.all(np.abs(Vw - ([0.05, 0.0, 3.0] if axis == 0 else [0.0, 0.05, 3.0]))
                                          < 1e-9, axis=1))[0])
    assert centre not in p.ids and aside in p.ids
    assert np.isin(np.arange(4), p.ids).all()  # the bar's corners are seen


def _bar(c0, c1, r0, r1, z, cam):
    """A rectangle at depth ``z`` covering image columns [c0, c1] and rows [r0, r1] (pixel units)."""
    f, cx, cy = cam.K[0, 0], cam.K[0, 2], cam.K[1, 2]
    x0, x1, y0, y1 = ((c0 - cx) * z / f, (c1 - cx) * z / f, (r0 - cy) * z / f, (r1 - cy) * z / f)
    return np.array([[x0, y0, z], [x1, y0, z], [x1, y1, z], [x0, y1, z]]), np.array([[0, 1, 2], [0, 2, 3]])


def test_vertices_on_the_image_border_look_at_their_own_3x3_neighbourhood():
    """A wall at 3 m filling the image, with vertices on its first / last pixel column and row; a 0.8 px bar at 1 m
    two pixels inside each of them. The border vertex's neighbourhood (its pixel and the next one inside; beyond
    the border nothing) does not reach the bar: all four are kept. (Looked up one pixel further inside, the bar
    would hide them.)"""
    cam = _plate_camera()  # 320 x 200, f 200, principal point (150, 110)
    z = 3.0
    left, right = (0.0002 - 150) * z / 200, (319 - 0.0002 - 150) * z / 200
    top, bottom = (0.0002 - 110) * z / 200, (199 - 0.0002 - 110) * z / 200
    xs = np.array([left, -1.5, -0.75, 0.0, 0.15, 0.75, 1.5, right])
    ys = np.array([top, -0.8, 0.0, 0.8, bottom])
    X, Y = np.meshgrid(xs, ys)
    Vw = np.c_[X.ravel(), Y.ravel(), np.full(X.size, z)]
    n = len(xs)
    Fw = np.array([f for r in range(len(ys) - 1) for c in range(n - 1)
                   for f in ([r * n + c, (r + 1) * n + c, r * n + c + 1],
                             [r * n + c + 1, (r + 1) * n + c, (r + 1) * n + c + 1])])
    V, F = [Vw], [Fw]
    for c0, c1, r0, r1 in ((1.6, 2.4, 90, 130), (316.6, 317.4, 90, 130), (140, 180, 1.6, 2.4),
                           (140, 180, 196.6, 197.4)):
        Vb, Fb = _bar(c0, c1, r0, r1, 1.0, cam)
        F.append(Fb + sum(len(v) for v in V))
        V.append(Vb)
    V, F = np.vstack(V), np.vstack(F)
    uv = cam.project(Vw)
    probes = [int(np.argmin(np.hypot(*(uv - p).T))) for p in ((0, 110), (319, 110), (160, 0), (160, 199))]
    assert np.abs(uv[probes] - [[0, 110], [319, 110], [160, 0], [160, 199]]).max() < 1e-3
    p = warp_pairs(V, V, F, cam, n_handles=len(V), dense=True)
    assert p.dense.origin == (0, 0) and p.dense.source_mask.shape == (200, 320)
    assert np.isin(probes, p.ids).all()
    # the bars are where they are meant to be: two pixels inside the border, one pixel wide
    from bodystudio.capture.render import render

    d = render(V, F, cam).depth
    assert d[100:120, 2].max() < 1.5 and d[100:120, [1, 3]].min() > 2.5 and d[100:120, 317].max() < 1.5
    assert d[2, 150:170].max() < 1.5 and d[[1, 3], 150:170].min() > 2.5 and d[197, 150:170].max() < 1.5


def test_actors_pairs_in_one_call_are_each_actors_own_pairs():
    """Two plates (two actors, the same faces) side by side, each reshaped differently: one call over both gives
    every actor's own dense pairs (all vertices as candidates, each plate's pixels the same in the shared crop),
    the person of each pair, and the dense nodes of each person; and a plate hidden behind the other loses its
    hidden vertices, which a call per actor would keep."""
    cam = _plate_camera()
    V1, F = _plate(0.12, 7, 2.0, x=-0.25)
    V2, _ = _plate(0.12, 7, 2.0, x=0.25)
    T1 = V1 * [1.1, 1.05, 1.0] + [0.01, -0.02, 0.0]
    T2 = V2 * [0.95, 1.0, 1.0] + [-0.01, 0.01, 0.0]
    p = actors_warp_pairs([V1, V2], [T1, T2], F, cam, n_handles=2 * len(V1), dense=True, grid=(50, 80))
    n = len(V1)
    np.testing.assert_array_equal(p.groups, p.ids // n)
    for a, (V, T) in enumerate(((V1, T1), (V2, T2))):
        own = warp_pairs(V, T, F, cam, n_handles=n, dense=True, grid=(50, 80))
        mine = p.groups == a
        np.testing.assert_array_equal(p.ids[mine] - a * n, own.ids)
        np.testing.assert_array_equal(p.src_uv[mine], own.src_uv)
        np.testing.assert_array_equal(p.dst_uv[mine], own.dst_uv)
        covered = np.isfinite(own.dense.grid_source_uv[..., 0])
        np.testing.assert_array_equal(p.dense.grid_source_uv[covered], own.dense.grid_source_uv[covered])
        assert (p.dense.grid_groups[covered] == a).all() and covered.sum() > 20
    # the second actor right behind the first: its vertices behind the first plate are not pairs
    B = V1 * [0.5, 0.5, 1.0] + [-0.125, 0.0, 0.4]  # half the size, centred behind it
    q = actors_warp_pairs([V1, B], [V1, B], F, cam, n_handles=2 * n, dense=True, grid=(50, 80))
    assert not (q.groups == 1).any() and (q.groups == 0).sum() == n
    with pytest.raises(InputError):
        actors_warp_pairs([V1], [T1, T2], F, cam)
