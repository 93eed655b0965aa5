"""The mirror warp's MIRFAST3 steps on hand-made scenes whose answers are known: :func:`facing_faces` on single
triangles (the sign of the y-down area; NaN projections face nothing), :func:`front_render` and ``warp_pairs(closed=
True)`` on closed boxes wound outwards (one box hiding another, a box half behind the camera) against the full
render / ``closed=False`` (the same silhouette, depth and pairs; triangle ids that index the faces), and
:func:`warp_foreground` against the whole-image remap it replaced (fields pointing partly outside, masks at the
image's edges, nothing inside). Behaviour only: an equivalent speed-up keeps these passing."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from bodystudio.capture.render import render
from bodystudio.geometry.camera import Camera
from bodystudio.mirror.warp import (
    OUTSIDE_PX,
    actors_warp_pairs,
    facing_faces,
    front_render,
    warp_foreground,
    warp_pairs,
)


def _camera(w=160, h=120, f=150.0):
    return Camera("c", np.array([[f, 0.0, w / 2 - 0.5], [0.0, f, h / 2 - 0.5], [0.0, 0.0, 1.0]]), np.zeros(5),
                  np.eye(3), np.zeros(3), w, h)


def _box(half, center):
    """A closed box, every face wound outwards (counter-clockwise seen from outside, y-down image: negative area
    when it faces the camera)."""
    c = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    V = c * np.asarray(half, float) + np.asarray(center, float)
    F = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                  [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    # orient each face outwards: its normal points away from the centre
    n = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    out = np.einsum("ij,ij->i", n, V[F].mean(1) - np.asarray(center, float)) > 0
    F[~out] = F[~out][:, ::-1]
    return V, F


def _subdivided_box(half, center, n=4):
    """A closed box of n x n quads per side (more vertices for the pairs), wound outwards."""
    V, F = [], []
    for axis in range(3):
        for sign in (-1.0, 1.0):
            u = np.linspace(-1, 1, n + 1)
            A, B = np.meshgrid(u, u, indexing="ij")
            P = np.zeros((n + 1, n + 1, 3))
            others = [a for a in range(3) if a != axis]
            P[..., axis] = sign
            P[..., others[0]], P[..., others[1]] = A, B
            base = len(V)
            V.extend(P.reshape(-1, 3))
            for i in range(n):
                for j in range(n):
                    a, b, c, d = base + i * (n + 1) + j, base + (i + 1) * (n + 1) + j, base + i * (n + 1) + j + 1, \
                        base + (i + 1) * (n + 1) + j + 1
                    F += [[a, b, c], [c, b, d]]
    V = np.array(V) * np.asarray(half, float) + np.asarray(center, float)
    F = np.array(F)
    nrm = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    out = np.einsum("ij,ij->i", nrm, V[F].mean(1) - np.asarray(center, float)) > 0
    F[~out] = F[~out][:, ::-1]
    return V, F


# --- facing_faces -------------------------------------------------------------------------------------------------

def test_facing_faces_are_the_negative_area_triangles_in_order():
    uv = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [2.0, 2.0], [np.nan, 0.0]])
    F = np.array([[0, 1, 2],   # area +1 (y down: clockwise on screen): away
                  [0, 2, 1],   # -1: facing
                  [1, 2, 0],   # +1
                  [3, 2, 1],   # (0-2)*(0-2) - (1-2)*(1-2) = 3: away
                  [0, 1, 3],   # +2
                  [0, 3, 1],   # -2: facing
                  [0, 4, 1],   # a NaN corner: neither
                  [0, 0, 1]])  # zero area: neither
    area = [(uv[b, 0] - uv[a, 0]) * (uv[c, 1] - uv[a, 1]) - (uv[c, 0] - uv[a, 0]) * (uv[b, 1] - uv[a, 1])
            for a, b, c in F]
    expected = [k for k, s in enumerate(area) if s < 0]
    assert expected == [1, 5]
    out = facing_faces(uv, F)
    assert out.dtype == np.int64 and out.tolist() == expected
    # faces as a list of int32, projections as float32: the same ids
    assert facing_faces(uv.astype(np.float32), F.astype(np.int32).tolist()).tolist() == expected
    assert facing_faces(uv, np.zeros((0, 3), np.int64)).tolist() == []


def test_a_closed_box_faces_the_camera_with_its_front_side_only():
    cam = _camera()
    V, F = _box((0.2, 0.15, 0.1), (0.05, 0.0, 2.0))
    front = facing_faces(cam.project(V), F)
    n = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    towards = np.einsum("ij,ij->i", n, -V[F].mean(1)) > 0  # outward normal towards the camera at the origin
    assert sorted(front.tolist()) == np.flatnonzero(towards).tolist() and 2 <= len(front) <= 6


# --- front_render -------------------------------------------------------------------------------------------------

def _two_boxes():
    V1, F1 = _box((0.2, 0.15, 0.1), (0.0, 0.0, 2.0))
    V2, F2 = _box((0.3, 0.1, 0.1), (0.15, 0.05, 2.6))  # behind the first, sticking out to the right
    return np.vstack([V1, V2]), np.vstack([F1, F2 + len(V1)])


def test_front_render_of_closed_boxes_is_the_full_render_with_ids_into_the_faces():
    cam = _camera()
    V, F = _two_boxes()
    full, front = render(V, F, cam), front_render(V, F, cam)
    np.testing.assert_array_equal(front.mask, full.mask)
    np.testing.assert_array_equal(front.depth, full.depth)
    assert front.mask.sum() > 500
    # the ids index F: the face drawn at each pixel faces the camera and is the full render's nearest face's plane
    facing = set(facing_faces(cam.project(V), F).tolist())
    ids = front.triangle_id[front.mask]
    assert set(np.unique(ids).tolist()) <= facing and (front.triangle_id[~front.mask] == -1).all()
    Pf, _ = front.surface_points(V, F)
    Pr, _ = full.surface_points(V, F)
    np.testing.assert_allclose(Pf, Pr, atol=1e-6)


def test_front_render_leaves_out_triangles_behind_the_camera():
    """A box straddling the camera plane: its vertices behind the camera project to NaN and face nothing; the
    front render draws no triangle with such a corner and agrees with the full render where the full render drew a
    triangle in front."""
    cam = _camera()
    V, F = _box((0.3, 0.2, 0.6), (0.0, 0.0, 0.3))  # z from -0.3 to 0.9
    fr = front_render(V, F, cam)
    uv, z = cam.project_with_depth(V)
    behind = np.flatnonzero(z <= 0)
    assert len(behind) == 4
    drawn = np.unique(fr.triangle_id[fr.mask])
    assert not np.isin(F[drawn], behind).any()
    # the box's far face (z = 0.9) faces the camera from inside: not drawn; the near one is behind the camera
    assert fr.mask.sum() == 0 or (fr.depth[fr.mask] > 0).all()


def test_front_render_of_a_box_nearer_than_a_metre():
    cam = _camera()
    V, F = _box((0.1, 0.08, 0.05), (0.0, 0.0, 0.8))
    full, front = render(V, F, cam), front_render(V, F, cam)
    assert front.mask.sum() > 1000
    np.testing.assert_array_equal(front.mask, full.mask)
    np.testing.assert_array_equal(front.depth, full.depth)


# --- warp_pairs(closed=True) --------------------------------------------------------------------------------------

def _pairs_scene():
    Vs, F = _subdivided_box((0.2, 0.3, 0.15), (0.0, 0.0, 2.2))
    Vt = Vs * [1.1, 1.05, 1.0] + [0.03, -0.02, 0.05]
    Vt[:, 2] += 0.1 * Vs[:, 0]
    return Vs, Vt, F


@pytest.mark.parametrize("dense", [False, True])
def test_closed_pairs_are_the_pairs_of_every_face(dense):
    """A closed box wound outwards, moved and tilted: the pairs (ids, both projections) and the dense
    correspondence (source pixel per target pixel, source mask, grid nodes) from the front faces are those from
    every face."""
    cam = _camera()
    Vs, Vt, F = _pairs_scene()
    a = warp_pairs(Vs, Vt, F, cam, n_handles=60, dense=dense, grid=(30, 40), closed=True)
    b = warp_pairs(Vs, Vt, F, cam, n_handles=60, dense=dense, grid=(30, 40), closed=False)
    np.testing.assert_array_equal(a.ids, b.ids)
    np.testing.assert_array_equal(a.src_uv, b.src_uv)
    np.testing.assert_array_equal(a.dst_uv, b.dst_uv)
    assert 10 < len(a.ids) < 60  # the back of the box is hidden
    if not dense:
        assert a.dense is None and b.dense is None
        return
    assert a.dense.origin == b.dense.origin
    np.testing.assert_array_equal(a.dense.source_mask, b.dense.source_mask)
    np.testing.assert_allclose(a.dense.source_uv, b.dense.source_uv, atol=1e-3, equal_nan=True)
    np.testing.assert_allclose(a.dense.grid_source_uv, b.dense.grid_source_uv, atol=1e-3, equal_nan=True)
    assert np.isfinite(a.dense.source_uv[..., 0]).sum() > 500


def test_closed_pairs_of_two_actors_keep_each_nodes_person():
    """Two boxes (actors) side by side through ``actors_warp_pairs``: the person at each grid node from the front
    faces is the one from every face (the front faces' groups are the faces' groups)."""
    cam = _camera()
    Vs, Vt, F = _pairs_scene()
    shift = np.array([0.45, 0.0, 0.3])
    sources, targets = [Vs - shift / 2, Vs + shift], [Vt - shift / 2, Vt + shift]
    a = actors_warp_pairs(sources, targets, F, cam, n_handles=80, dense=True, grid=(30, 40), closed=True)
    b = actors_warp_pairs(sources, targets, F, cam, n_handles=80, dense=True, grid=(30, 40), closed=False)
    np.testing.assert_array_equal(a.ids, b.ids)
    np.testing.assert_array_equal(a.groups, b.groups)
    np.testing.assert_array_equal(a.dense.grid_groups, b.dense.grid_groups)
    covered = np.isfinite(a.dense.grid_source_uv[..., 0])
    assert set(np.unique(a.dense.grid_groups[covered]).tolist()) == {0, 1}


# --- warp_foreground: the whole-image remap -----------------------------------------------------------------------

def _warp_whole_image(rgb, mask, field):
    """warp_foreground before MIRFAST3: both remaps over the whole image (the reference); since MIR12g a source
    position less than 16 px (-OUTSIDE_PX) off the image, other than OUTSIDE_PX itself, is taken on its edge."""
    m8 = mask.astype(np.uint8) * np.uint8(255)
    h, w = mask.shape
    mx, my = field[..., 0].copy(), field[..., 1].copy()
    valid = mx > OUTSIDE_PX
    near = valid & (mx > -16) & (my > -16) & (mx < w - 1 + 16) & (my < h - 1 + 16)
    mx[near] = np.clip(mx[near], 0, w - 1)
    my[near] = np.clip(my[near], 0, h - 1)
    alpha8 = cv2.remap(m8, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    premult = cv2.bitwise_and(rgb, rgb, mask=m8)
    out = cv2.remap(premult, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    er, ec = np.nonzero((alpha8 > 0) & (alpha8 < 255))
    if len(er):
        a = alpha8[er, ec].astype(np.float32)[:, None] / 255.0
        out[er, ec] = np.clip(out[er, ec] / a + 0.5, 0, 255).astype(np.uint8)
    return out, alpha8.astype(np.float32) * np.float32(1.0 / 255.0)


def _field(h, w, shift, inside):
    """A backward field moving the image by ``shift`` (dx, dy) with sub-pixel parts inside ``inside`` (a box
    (r0, r1, c0, c1)), OUTSIDE_PX elsewhere (as the MLS field outside the people)."""
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    field = np.full((h, w, 2), OUTSIDE_PX, np.float32)
    r0, r1, c0, c1 = inside
    field[r0:r1, c0:c1, 0] = xs[r0:r1, c0:c1] - shift[0]
    field[r0:r1, c0:c1, 1] = ys[r0:r1, c0:c1] - shift[1]
    return field


MASKS = {"middle": (20, 50, 30, 70), "top_left_corner": (0, 12, 0, 15), "right_edge": (40, 70, 90, 100),
         "empty": (0, 0, 0, 0), "disc": None}
INSIDE = {"around": (10, 60, 20, 85), "whole": (0, 80, 0, 100), "corner": (0, 20, 0, 25), "none": (0, 0, 0, 0),
          "one_column": (10, 60, 40, 41), "one_row": (30, 31, 20, 85)}


@pytest.mark.parametrize("mask", list(MASKS))
@pytest.mark.parametrize("inside", list(INSIDE))
@pytest.mark.parametrize("shift", [(3.25, -2.5), (-7.5, 4.75)])
def test_warp_foreground_is_the_whole_image_remap(mask, inside, shift):
    rng = np.random.default_rng(5)
    rgb = rng.integers(0, 256, (80, 100, 3), dtype=np.uint8)
    m = np.zeros((80, 100), bool)
    if MASKS[mask] is None:  # a disc: its box holds background pixels, whose colour must not be dragged in
        rows, cols = np.mgrid[0:80, 0:100]
        m = (cols - 50) ** 2 + (rows - 35) ** 2 <= 18 ** 2
    else:
        r0, r1, c0, c1 = MASKS[mask]
        m[r0:r1, c0:c1] = True
    field = _field(80, 100, shift, INSIDE[inside])
    out, alpha = warp_foreground(rgb, m, field)
    want, want_alpha = _warp_whole_image(rgb, m, field)
    np.testing.assert_array_equal(out, want)
    np.testing.assert_array_equal(alpha, want_alpha)
    assert out.dtype == np.uint8 and alpha.dtype == np.float32 and out.shape == rgb.shape
    if mask in ("middle", "disc") and inside in ("whole", "around", "one_column", "one_row"):
        assert (alpha > 0).any() and ((alpha > 0) & (alpha < 1)).any()


def test_warp_foreground_of_a_uint8_mask_and_a_field_pointing_at_the_last_pixel():
    rgb = np.random.default_rng(6).integers(0, 256, (30, 40, 3), dtype=np.uint8)
    m = np.zeros((30, 40), np.uint8)
    m[10:30, 25:40] = 1
    ys, xs = np.mgrid[0:30, 0:40].astype(np.float32)
    field = np.stack([xs + 0.5, ys + 0.25], axis=-1).astype(np.float32)  # every pixel inside, half a pixel off
    out, alpha = warp_foreground(rgb, m, field)
    want, want_alpha = _warp_whole_image(rgb, m.astype(bool), field)
    np.testing.assert_array_equal(out, want)
    np.testing.assert_array_equal(alpha, want_alpha)
    # the last pixel samples half a pixel beyond the image: taken on its edge since MIR12g (before: half outside)
    assert alpha[29, 39] == 1


# --- mls_transforms: the affine closed form with every entry of A non-zero ----------------------------------------

@pytest.mark.parametrize("alpha", [1.0, 2.0])
def test_affine_mls_reproduces_a_sheared_rotated_map_exactly(alpha):
    """Handles moved by one affine map with rotation, shear and unequal scales (every entry of its linear part
    non-zero): Eq. 5's affine solution is that map at every point, A its linear part (row vectors)."""
    from bodystudio.mirror.warp import mls_transforms

    rng = np.random.default_rng(11)
    p = rng.uniform(0, 200, (25, 2))
    M = np.array([[1.1, 0.3], [-0.25, 0.9]])
    t = np.array([4.0, -7.5])
    q = p @ M + t
    v = rng.uniform(10, 190, (40, 2))
    A, mapped = mls_transforms(v, p, q, kind="affine", alpha=alpha)
    np.testing.assert_allclose(A, np.broadcast_to(M, A.shape), atol=1e-9)
    np.testing.assert_allclose(mapped, v @ M + t, atol=1e-7)
