"""The warp's plain-Python steps after helper mir12d's commits (8eadf9c, 55c5280, be34697, e335b15), pinned for
mutation testing (issue 17; docs/mutation/mirror-warp.md, "After mir12d").

``warp_pairs``' input checks, rim vertices, z-buffer camera and closed-body path; the similarity / rigid dispatch of
``mls_transforms`` (Eq. 5 of Real-time Reshaping: a 2x2 linear part per point); the float64 pairs of
``_check_pairs`` (float32 pairs give the field of the same pairs in float64, bit for bit).
"""

import numpy as np
import pytest

from bodystudio.errors import InputError
from bodystudio.geometry.camera import Camera
from bodystudio.mirror import warp as Wp
from tests.mirror.test_warp_dense_analytic import _plate as dense_plate


def _cam(width=320, height=200):
    return Camera("c", np.array([[200.0, 0.0, 150.0], [0.0, 200.0, 110.0], [0.0, 0.0, 1.0]]), np.zeros(5),
                  np.eye(3), np.zeros(3), width, height)


def _plate(half=0.2, n=9, z=2.0, x=0.0, flip=False):
    """test_warp_dense_analytic's plate (``n`` x ``n`` vertices at depth ``z``), its winding reversed with ``flip``."""
    V, F = dense_plate(half, n, z, x)
    return V, (F[:, ::-1] if flip else F)


def _half_cylinder(radius=0.3, n=25, rows=6, z=2.0):
    """A half-cylinder bulging towards the camera: its sides are seen edge-on (rim vertices)."""
    a = np.linspace(-np.pi / 2, np.pi / 2, n)
    y = np.linspace(-0.2, 0.2, rows)
    A, Y = np.meshgrid(a, y)
    V = np.c_[radius * np.sin(A).ravel(), Y.ravel(), (z - radius * np.cos(A)).ravel()]
    F = []
    for r in range(rows - 1):
        for c in range(n - 1):
            i = r * n + c
            F += [[i, i + n, i + 1], [i + 1, i + n, i + n + 1]]
    return V, np.array(F)


@pytest.mark.parametrize("Vs, Vt", [(np.zeros((5, 2)), np.zeros((5, 2))), (np.zeros((5, 3)), np.zeros((6, 3))),
                                    (np.zeros((2, 5, 3)), np.zeros((2, 5, 3)))])
def test_warp_pairs_needs_two_n_by_3_vertex_arrays(Vs, Vt):
    with pytest.raises(InputError, match=r"^source and target vertices must both be \(n, 3\), got \("):
        Wp.warp_pairs(Vs, Vt, np.zeros((0, 3), int), _cam())


@pytest.mark.parametrize("rim_cos, ok", [(0.0, False), (-0.1, False), (1e-6, True), (1.0, True), (1.0001, False),
                                         (1.5, False)])
def test_rim_cos_lies_in_0_1(rim_cos, ok):
    V, F = _plate()
    if ok:
        Wp.warp_pairs(V, V, F, _cam(), n_handles=5, rim_cos=rim_cos)
    else:
        with pytest.raises(InputError, match=rf"^rim_cos must lie in \(0, 1\] \(None: no rim vertices\), got "
                                             rf"{rim_cos}$"):
            Wp.warp_pairs(V, V, F, _cam(), n_handles=5, rim_cos=rim_cos)


def test_rim_vertices_join_the_evenly_spread_handles():
    """The handles are the evenly spread ids and the rim vertices (``|cos| < rim_cos``), each kept where visible:
    exactly the union filtered by the visibility every vertex gets (``n_handles`` = all of them)."""
    V, F = _half_cylinder()
    cam = _cam()
    visible = Wp.warp_pairs(V, V, F, cam, n_handles=len(V)).ids
    spread = np.unique(np.linspace(0, len(V) - 1, 6).round().astype(np.int64))
    for max_cos in (0.6, 0.8):
        rim = Wp.rim_vertices(V, F, cam.center, max_cos)
        extra = np.intersect1d(np.setdiff1d(rim, spread), visible)
        assert len(extra) >= 4 and len(np.intersect1d(spread, visible)) >= 4
        p = Wp.warp_pairs(V, V, F, cam, n_handles=6, rim_cos=max_cos)
        np.testing.assert_array_equal(p.ids, np.intersect1d(np.union1d(spread, rim), visible))
    assert len(Wp.rim_vertices(V, F, cam.center, 0.6)) < len(Wp.rim_vertices(V, F, cam.center, 0.8))


def _spy_render(monkeypatch):
    import bodystudio.capture.render as R

    seen = []

    def spying(real):
        def spy(V, F, camera, *a, **k):
            seen.append((np.asarray(F).copy(), camera))
            return real(V, F, camera, *a, **k)
        return spy

    # both z-buffers: the source's silhouette and depth alone (render_silhouette_depth, MIR12f), the target's render
    monkeypatch.setattr(R, "render", spying(R.render))
    monkeypatch.setattr(R, "render_silhouette_depth", spying(R.render_silhouette_depth))
    return seen


@pytest.mark.parametrize("scale, size", [(0.25, (80, 50)), (0.5, (160, 100)), (0.001, (1, 1)), (0.004, (1, 1))])
def test_the_z_buffers_are_the_whole_image_at_z_buffer_scale(monkeypatch, scale, size):
    V, F = _plate()
    cam = _cam()
    seen = _spy_render(monkeypatch)
    Wp.warp_pairs(V, V * [1.1, 1.0, 1.0], F, cam, n_handles=10, z_buffer_scale=scale)
    assert len(seen) == 2
    for _, small in seen:
        assert (small.width, small.height) == size
        sx, sy = size[0] / 320, size[1] / 200
        want = Wp.crop_camera(cam, 0, 0, size[0], size[1], (sx, sy))
        np.testing.assert_allclose(small.K, want.K, atol=1e-12)


def test_closed_bodies_draw_only_their_camera_facing_triangles(monkeypatch):
    """Two plates, one wound towards the camera and one away: ``closed`` draws the facing one only, in both
    z-buffers; open meshes draw every triangle."""
    Va, Fa = _plate(x=-0.3)
    Vb, Fb = _plate(x=0.3, flip=True)
    V, F = np.vstack([Va, Vb]), np.vstack([Fa, Fb + len(Va)])
    cam = _cam()
    front = Wp.facing_faces(cam.project(V), F)
    assert 0 < len(front) < len(F)
    seen = _spy_render(monkeypatch)
    Wp.warp_pairs(V, V, F, cam, n_handles=20, closed=True)
    assert len(seen) == 2 and all(np.array_equal(f, F[front]) for f, _ in seen)
    seen.clear()
    Wp.warp_pairs(V, V, F, cam, n_handles=20)
    assert all(np.array_equal(f, F) for f, _ in seen)


def test_float32_vertices_give_the_float64_pairs():
    V, F = _half_cylinder()
    Vt = V * [1.1, 1.0, 1.0] + [0.02, 0.0, 0.0]
    cam = _cam()
    V32, Vt32 = V.astype(np.float32), Vt.astype(np.float32)
    p = Wp.warp_pairs(V32, Vt32, F, cam, n_handles=40, dense=True, grid=(50, 80))
    q = Wp.warp_pairs(V32.astype(np.float64), Vt32.astype(np.float64), F, cam, n_handles=40, dense=True,
                      grid=(50, 80))
    assert p.src_uv.dtype == np.float64
    np.testing.assert_array_equal(p.src_uv, q.src_uv)
    np.testing.assert_array_equal(p.dst_uv, q.dst_uv)
    np.testing.assert_array_equal(p.dense.source_uv, q.dense.source_uv)


def test_float32_pairs_give_the_float64_field():
    rng = np.random.default_rng(5)
    s = rng.uniform(20, 100, (40, 2)).astype(np.float32)
    t = (s * np.float32(1.07) + np.float32(3.3)).astype(np.float32)
    a, b = Wp._check_pairs(s, t)
    assert a.dtype == b.dtype == np.float64
    for kind in ("affine", "similarity"):
        f32 = Wp.mls_warp_field(s, t, (120, 160), (30, 40), kind=kind, alpha=2.0)
        f64 = Wp.mls_warp_field(s.astype(np.float64), t.astype(np.float64), (120, 160), (30, 40), kind=kind,
                                alpha=2.0)
        np.testing.assert_array_equal(f32, f64)


@pytest.mark.parametrize("kind", ["similarity", "rigid", "affine"])
def test_each_point_gets_a_2x2_linear_part(kind):
    """Eq. 5: the linear part is 2x2 (the similarity / rigid ones [[a, b], [-b, a]]); handles moved by a rotation
    by 30 degrees and a scale 1.5 are reproduced exactly by every kind (rigid: the rotation only)."""
    rng = np.random.default_rng(2)
    p = rng.uniform(0, 50, (12, 2))
    th = np.deg2rad(30.0)
    M = np.array([[np.cos(th), np.sin(th)], [-np.sin(th), np.cos(th)]])
    q = 1.5 * p @ M + [4.0, -2.0]
    v = rng.uniform(0, 50, (7, 2))
    A, mapped = Wp.mls_transforms(v, p, q, kind)
    assert A.shape == (7, 2, 2) and mapped.shape == (7, 2)
    want = M if kind == "rigid" else 1.5 * M
    np.testing.assert_allclose(A, np.broadcast_to(want, (7, 2, 2)), atol=1e-9)
    if kind != "rigid":
        np.testing.assert_allclose(mapped, 1.5 * v @ M + [4.0, -2.0], atol=1e-9)


def test_pairs_are_the_vertices_inside_the_image_borders_included():
    """A plate larger than the view of a 301 x 201 camera, vertices every 0.25 m at 2 m: those projected to
    0 <= u <= 300, 0 <= v <= 200 (the borders exactly hit) are the pairs, the rest are not."""
    cam = Camera("c", np.array([[200.0, 0.0, 150.0], [0.0, 200.0, 100.0], [0.0, 0.0, 1.0]]), np.zeros(5), np.eye(3),
                 np.zeros(3), 301, 201)
    xs, ys = np.linspace(-1.75, 1.75, 15), np.linspace(-1.25, 1.25, 11)
    X, Y = np.meshgrid(xs, ys)
    V = np.c_[X.ravel(), Y.ravel(), np.full(X.size, 2.0)]
    F = np.array([[a, a + 15, a + 1] for r in range(10) for a in range(r * 15, r * 15 + 14)]
                 + [[a + 1, a + 15, a + 16] for r in range(10) for a in range(r * 15, r * 15 + 14)])
    uv = cam.project(V)
    assert {0.0, 300.0} <= set(uv[:, 0]) and {0.0, 200.0} <= set(uv[:, 1])
    inside = np.flatnonzero((uv[:, 0] >= 0) & (uv[:, 0] <= 300) & (uv[:, 1] >= 0) & (uv[:, 1] <= 200))
    assert 0 < len(inside) < len(V)
    for options in ({}, {"z_buffer_scale": 1.0}, {"dense": True, "grid": (50, 75)}):
        p = Wp.warp_pairs(V, V, F, cam, n_handles=len(V), **options)
        np.testing.assert_array_equal(p.ids, inside)


@pytest.mark.parametrize("options", [{}, {"z_buffer_scale": 0.5}, {"z_buffer_scale": 1.0},
                                     {"dense": True, "grid": (50, 80)}])
def test_a_vertex_hidden_in_either_body_is_no_pair(options):
    """A back plate partly behind a front plate in the source, the front plate moved aside in the target: the back
    plate's vertices hidden in the source are dropped, whatever the z-buffer resolution."""
    cam = _cam()
    back, Fb = _plate(half=0.3, n=13, z=3.0)
    front, Ff = _plate(half=0.15, n=5, z=2.0, x=0.1)
    Vs = np.vstack([back, front])
    Vt = np.vstack([back, front + [0.9, 0.0, 0.0]])
    F = np.vstack([Fb, Ff + len(back)])
    uv = cam.project(Vs)
    fu = cam.project(front)
    hidden = ((uv[:len(back), 0] > fu[:, 0].min() + 2) & (uv[:len(back), 0] < fu[:, 0].max() - 2)
              & (uv[:len(back), 1] > fu[:, 1].min() + 2) & (uv[:len(back), 1] < fu[:, 1].max() - 2))
    shown = ((uv[:len(back), 0] < fu[:, 0].min() - 6) | (uv[:len(back), 0] > fu[:, 0].max() + 6)
             | (uv[:len(back), 1] < fu[:, 1].min() - 6) | (uv[:len(back), 1] > fu[:, 1].max() + 6))
    assert hidden.sum() >= 4 and shown.sum() >= 30
    ids = set(Wp.warp_pairs(Vs, Vt, F, cam, n_handles=len(Vs), **options).ids)
    assert not ids & set(np.flatnonzero(hidden)) and set(np.flatnonzero(shown)) <= ids
    assert set(range(len(back), len(Vs))) <= ids  # the front plate is seen in both
    # the other way round (hidden in the target only): dropped as well
    ids = set(Wp.warp_pairs(Vt, Vs, F, cam, n_handles=len(Vs), **options).ids)
    assert not ids & set(np.flatnonzero(hidden)) and set(np.flatnonzero(shown)) <= ids


def test_closed_dense_correspondence_is_the_facing_triangles_with_their_groups():
    """``closed`` with ``dense``: the target raster holds the front faces only, so the correspondence and the
    nodes' persons are looked up in those faces (the away-facing plate listed first shifts their ids)."""
    Vb, Fb = _plate(x=-0.3, flip=True)
    Va, Fa = _plate(x=0.3)
    V, F = np.vstack([Vb, Va]), np.vstack([Fb, Fa + len(Vb)])
    groups = np.r_[np.full(len(Fb), 3), np.full(len(Fa), 7)]
    cam = _cam()
    Vt = V + [0.02, 0.01, 0.0]
    closed = Wp.warp_pairs(V, Vt, F, cam, n_handles=20, dense=True, grid=(50, 80), face_groups=groups, closed=True)
    both = Wp.warp_pairs(V, Vt, F, cam, n_handles=20, dense=True, grid=(50, 80), face_groups=groups)
    cov_c = np.isfinite(closed.dense.source_uv[..., 0])
    cov_b = np.isfinite(both.dense.source_uv[..., 0])
    assert 0 < cov_c.sum() < cov_b.sum() and not (cov_c & ~cov_b).any()
    np.testing.assert_array_equal(closed.dense.source_uv[cov_c], both.dense.source_uv[cov_c])
    nodes = np.isfinite(closed.dense.grid_source_uv[..., 0])
    assert nodes.any() and (closed.dense.grid_groups[nodes] == 7).all()


def _boxes_by_hand(m, margin):
    """people_boxes written out column by column: a new group after more than 2 margin + 1 empty columns."""
    h, w = m.shape
    groups, last = [], None
    for c in range(w):
        if m[:, c].any():
            if last is None or c - last > 2 * margin + 1:
                groups.append([c, c])
            groups[-1][1] = c
            last = c
    out = []
    for c0, c1 in groups:
        rows = [r for r in range(h) if m[r, c0:c1 + 1].any()]
        out.append(((max(rows[0] - margin, 0), min(rows[-1] + margin + 1, h)),
                    (max(c0 - margin, 0), min(c1 + margin + 1, w))))
    return out


@pytest.mark.parametrize("gap", [4, 5, 6, 7, 12])
def test_people_boxes_split_where_more_than_2_margin_plus_1_columns_are_empty(gap):
    """margin 2: gaps of 4 empty columns or less keep one box, 5 and more split (np.diff of the columns > 5)."""
    m = np.zeros((30, 60), bool)
    m[3:9, 10:14] = True  # person 1, rows 3..8
    m[12:20, 14 + gap:20 + gap] = True  # person 2, rows 12..19, `gap` empty columns to its left
    m[25, 14 + gap + 2] = True  # a pixel of person 2 lower down
    boxes = Wp.people_boxes(m, 2)
    assert boxes == _boxes_by_hand(m, 2)
    if gap >= 5:  # np.diff of the columns is gap + 1
        assert boxes == [((1, 11), (8, 16)), ((10, 28), (12 + gap, 22 + gap))]
    else:
        assert boxes == [((1, 28), (8, 22 + gap))]


def test_people_boxes_at_the_image_edges_and_three_people():
    m = np.zeros((20, 50), bool)
    m[0:4, 0:3] = True
    m[5:9, 20:22] = True
    m[16:20, 47:50] = True
    assert Wp.people_boxes(m, 3) == _boxes_by_hand(m, 3) == [((0, 7), (0, 6)), ((2, 12), (17, 25)),
                                                             ((13, 20), (44, 50))]
    assert Wp.people_boxes(np.zeros((5, 5), bool), 3) == []
    assert Wp.people_boxes(m.astype(np.uint8) * 7, 3) == _boxes_by_hand(m, 3)


def test_targets_outside_the_image_solve_the_border_nodes_and_only_within_reach():
    """Target points 10 px beyond each border mark the nearest border nodes (clipped, not wrapped round); a node
    farther than the margin (+1 cell) from every target stays unsolved (OUTSIDE_PX)."""
    H, W = 120, 160
    rng = np.random.default_rng(4)
    d = rng.uniform(0, 4, 12)  # not collinear
    for t in (np.c_[-10.0 - d, rng.uniform(40, 80, 12)], np.c_[rng.uniform(60, 100, 12), -10.0 - d],
              np.c_[W + 10.0 + d, rng.uniform(40, 80, 12)], np.c_[rng.uniform(60, 100, 12), H + 10.0 + d]):
        s = t + rng.uniform(-3, 3, t.shape)
        f = Wp.mls_warp_field(s, t, (H, W), (30, 40), roi_margin_px=8.0)
        x = int(np.clip(t[0, 0], 0, W - 1))
        y = int(np.clip(t[0, 1], 0, H - 1))
        assert (f[y, x] > Wp.OUTSIDE_PX).all()  # the border next to the targets is solved
        far = (np.abs(np.arange(W)[None, :] - np.clip(t[:, 0], 0, W - 1).mean()) > 60) | \
              (np.abs(np.arange(H)[:, None] - np.clip(t[:, 1], 0, H - 1).mean()) > 60)
        assert (f[far] == Wp.OUTSIDE_PX).all()


def test_a_person_with_fewer_than_3_pairs_is_not_solved_and_3_are_enough():
    H, W = 120, 160
    rng = np.random.default_rng(6)
    a = rng.uniform(10, 40, (10, 2))
    for n, solved in ((2, False), (3, True)):
        b = np.array([[130.0, 95.0], [140.0, 100.0], [135.0, 108.0]])[:n]
        t = np.vstack([a, b])
        f = Wp.mls_warp_field(t + 1.0, t, (H, W), (30, 40), roi_margin_px=6.0, groups=[0] * 10 + [1] * n)
        assert (f[100, 136] > Wp.OUTSIDE_PX).all() == solved and (f[25, 25] > Wp.OUTSIDE_PX).all()
        if solved:
            np.testing.assert_allclose(f[100, 136], [137.0, 101.0], atol=1e-3)  # the shift of its three pairs


def test_the_field_uses_the_local_radius():
    rng = np.random.default_rng(8)
    s = rng.uniform(20, 140, (60, 2))
    t = s + np.c_[np.sin(s[:, 1] / 9.0), np.cos(s[:, 0] / 7.0)] * 4
    f_all = Wp.mls_warp_field(s, t, (120, 160), (30, 40), alpha=2.0)
    f_near = Wp.mls_warp_field(s, t, (120, 160), (30, 40), alpha=2.0, radius_px=12.0)
    on = f_all[..., 0] > Wp.OUTSIDE_PX
    assert np.abs(f_all[on] - f_near[on]).max() > 0.05


def _warp_whole_image(rgb, mask, field):
    """warp_foreground before MIRFAST3 / MIR12d: both remaps over the whole image, the field's channels apart."""
    import cv2

    m8 = mask.astype(np.uint8) * 255
    premult = rgb * mask[..., None].astype(np.uint8)
    fx, fy = np.ascontiguousarray(field[..., 0]), np.ascontiguousarray(field[..., 1])
    a8 = cv2.remap(m8, fx, fy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    o = cv2.remap(premult, fx, fy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    er, ec = np.nonzero((a8 > 0) & (a8 < 255))
    a = a8[er, ec].astype(np.float32)[:, None] / 255.0
    o[er, ec] = np.clip(o[er, ec] / a + 0.5, 0, 255).astype(np.uint8)
    return o, a8.astype(np.float32) * np.float32(1.0 / 255.0)


@pytest.mark.parametrize("shift", [(3.0, 2.0), (2.37, -1.61), (-4.5, 0.25)])
def test_warp_foreground_is_the_whole_image_remap_on_the_fields_box(shift):
    """A disc of saturated colours on a busy background, a sub-pixel shift on the field's box (OUTSIDE_PX on the
    left and top bands): image and alpha are the whole-image remap's bit for bit, alpha in float32."""
    H, W = 60, 80
    rng = np.random.default_rng(1)
    rgb = rng.integers(0, 256, (H, W, 3)).astype(np.uint8)
    rows, cols = np.mgrid[0:H, 0:W]
    mask = (cols - 45) ** 2 + (rows - 32) ** 2 <= 12 ** 2
    rgb[mask] = [255, 255, 40]
    rgb[mask & (cols > 45)] = [255, 0, 255]
    field = np.stack([cols + shift[0], rows + shift[1]], -1).astype(np.float32)
    field[:, :20] = Wp.OUTSIDE_PX
    field[:15] = Wp.OUTSIDE_PX
    out, alpha = Wp.warp_foreground(rgb, mask, field)
    want_o, want_a = _warp_whole_image(rgb, mask, field)
    assert alpha.dtype == np.float32 and out.dtype == np.uint8
    np.testing.assert_array_equal(alpha, want_a)
    np.testing.assert_array_equal(out, want_o)
    assert (out[alpha == 0] == 0).all() and (((alpha > 0) & (alpha < 1)).sum() > 0) == (shift[0] % 1 > 0)


def test_warp_foreground_of_a_field_one_pixel_wide_or_all_outside():
    H, W = 30, 40
    rgb = np.full((H, W, 3), 200, np.uint8)
    mask = np.zeros((H, W), bool)
    mask[10:20, 10:20] = True
    rows, cols = np.mgrid[0:H, 0:W]
    for keep in ((slice(None), slice(14, 15)), (slice(14, 15), slice(None))):  # one column, one row
        field = np.full((H, W, 2), Wp.OUTSIDE_PX, np.float32)
        field[keep] = np.stack([cols, rows], -1)[keep]
        out, alpha = Wp.warp_foreground(rgb, mask, field)
        assert alpha.sum() == 10 and (out[alpha > 0] == 200).all()
    out, alpha = Wp.warp_foreground(rgb, mask, np.full((H, W, 2), Wp.OUTSIDE_PX, np.float32))
    assert alpha.dtype == np.float32 and not alpha.any() and not out.any()
