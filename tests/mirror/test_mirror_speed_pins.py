"""MIR12d's speed changes of the mirror's image steps, each pinned to the output it replaced (bit for bit)."""

import numpy as np
import pytest

from bodystudio.mirror import foreground as F
from bodystudio.mirror.image_case import cached_image_case


def _box3_numpy(h):
    """The colour histograms' 3-bin box blur as numpy's padded slices computed it before MIR12d."""
    for axis in range(3):
        p = np.pad(h, [(1, 1) if a == axis else (0, 0) for a in range(3)])
        h = (p[tuple(slice(0, -2) if a == axis else slice(None) for a in range(3))] + h
             + p[tuple(slice(2, None) if a == axis else slice(None) for a in range(3))]) / 3.0
    return h


def test_colour_histogram_blur_in_numba_is_numpys_bit_for_bit():
    rng = np.random.default_rng(3)
    for counts in (rng.integers(0, 60, 4096), np.eye(1, 4096, 7, dtype=np.int64)[0] * 1000, np.zeros(4096)):
        h = np.asarray(counts, np.float32).reshape(16, 16, 16)
        got, want = F._box3(h), _box3_numpy(h)
        assert got.dtype == want.dtype == np.float32
        np.testing.assert_array_equal(got, want)


def test_band_pixels_are_nonzeros_raster_order_with_their_node_ids():
    rng = np.random.default_rng(4)
    band = rng.random((37, 53)) < 0.3
    rows, cols, node = F._band_pixels(band)
    want_r, want_c = np.nonzero(band)
    np.testing.assert_array_equal(rows, want_r)
    np.testing.assert_array_equal(cols, want_c)
    expected = np.full(band.shape, -1, np.int64)
    expected[want_r, want_c] = np.arange(len(want_r))
    np.testing.assert_array_equal(node, expected)


def _band_links_before(rgb, node, inner, br, bc, smoothness, source, sink):
    """The n-links as computed before MIR12d (each pair's colour difference computed in both passes), in Python."""
    h, w = node.shape
    offsets = ((0, 1), (1, 0), (0, -1), (-1, 0))
    total, count = 0.0, 0
    img = rgb.astype(np.float64)
    for r, c in zip(br, bc, strict=True):
        for dy, dx in offsets:
            qr, qc = r + dy, c + dx
            if 0 <= qr < h and 0 <= qc < w:
                d = img[r, c] - img[qr, qc]
                total += float(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
                count += 1
    beta = 1.0 / (2.0 * max(total / max(count, 1), 1e-6))
    ei, ej, ec = [], [], []
    for k, (r, c) in enumerate(zip(br, bc, strict=True)):
        for o, (dy, dx) in enumerate(offsets):
            qr, qc = r + dy, c + dx
            if not (0 <= qr < h and 0 <= qc < w):
                continue
            other = node[qr, qc]
            if other >= 0 and o >= 2:
                continue
            d = img[r, c] - img[qr, qc]
            wgt = smoothness * np.exp(-beta * float(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]))
            if other >= 0:
                ei.append(k)
                ej.append(other)
                ec.append(wgt)
            elif inner[qr, qc]:
                source[k] += wgt
            else:
                sink[k] += wgt
    return np.array(ei), np.array(ej), np.array(ec)


def test_band_links_with_each_colour_difference_computed_once_are_the_same():
    rng = np.random.default_rng(5)
    rgb = rng.integers(0, 256, (24, 31, 3)).astype(np.uint8)
    mask = np.zeros((24, 31), bool)
    mask[5:19, 8:24] = True
    inner, band = F.foreground_band(mask, 3)
    br, bc, node = F._band_pixels(band)
    got_s, got_t = rng.random(len(br)), rng.random(len(br))
    want_s, want_t = got_s.copy(), got_t.copy()
    got = F._band_links(rgb, node, inner, br, bc, 5.0, got_s, got_t)
    want = _band_links_before(rgb, node, inner, br, bc, 5.0, want_s, want_t)
    for g, w in zip(got, want, strict=True):
        np.testing.assert_allclose(g, w, rtol=1e-15, atol=0)
    np.testing.assert_allclose(got_s, want_s, rtol=1e-15)
    np.testing.assert_allclose(got_t, want_t, rtol=1e-15)


@pytest.mark.parametrize("actors", [1, 2])
def test_graph_cut_of_the_bench_frames_is_pinned(actors):
    """The refined masks of the bench frames (1 and 2 actors, without and with the background model): pixel counts
    and IoU with the true mask as main (MIRFAST3, 9f60d9f) gave them before MIR12d's changes of the cut."""
    from bodystudio.mirror.compose import update_background
    from bodystudio.mirror.image_case import iou

    case = cached_image_case(None, 0, actors)
    bg = update_background(None, case.background, np.zeros(case.true_mask.shape, bool))
    before = {1: ((18240, 0.995036), (18292, 0.997872)), 2: ((44364, 0.996585), (44445, 0.998854))}[actors]
    for options, (count, score) in zip(({}, {"background": bg}), before, strict=True):
        mask = F.refine_foreground(case.rgb, case.player_mask, **options)
        assert int(mask.sum()) == count
        assert iou(mask, case.true_mask) == pytest.approx(score, abs=1e-6)


@pytest.mark.parametrize("actors", [1, 2])
def test_outline_band_per_person_box_and_fused_samples_give_the_same_field(actors):
    """refine_outline on each person's box (``warp.people_boxes``) and the signed distance's five samples from one
    cell: the same field bit for bit as the whole crop's transforms and five clamped samples (before MIR12d)."""
    import cv2

    from bodystudio.mirror import warp as W
    from bodystudio.mirror.run import MLS_ALPHA, MLS_RADIUS_PX

    case = cached_image_case(None, 0, actors)
    dense = case.dense
    field = W.mls_warp_field(case.src_uv, case.dst_uv, kind="similarity", alpha=MLS_ALPHA, groups=case.pair_groups,
                             radius_px=MLS_RADIUS_PX)
    got = W.refine_outline(field.copy(), dense)
    # before: the whole crop at once, every sample through the clamped sampler
    want = field.copy()
    h, w = dense.source_mask.shape
    x0, y0 = dense.origin
    inside = np.isfinite(dense.source_uv[..., 0])
    dist, label = cv2.distanceTransformWithLabels((~inside).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_5,
                                                  labelType=cv2.DIST_LABEL_PIXEL)
    depth_in = cv2.distanceTransform(inside.astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_5)
    sd = W._signed_distance(dense.source_mask)
    zr, zc = np.nonzero(inside)
    crop = want[y0:y0 + h, x0:x0 + w]

    def moved(u, wanted):
        x, y = u[0] - x0, u[1] - y0
        s = [W._sample(sd, x + dx, y + dy) for dx, dy in ((1, 0), (-1, 0), (0, 1), (0, -1), (0, 0))]
        nx, ny = s[0] - s[1], s[2] - s[3]
        norm = max(np.sqrt(nx * nx + ny * ny), 1e-6)
        step = s[4] - wanted
        return u[0] - step * nx / norm, u[1] - step * ny / norm

    for r, c in zip(*np.nonzero(inside | (dist <= 6.0)), strict=True):
        if inside[r, c]:
            crop[r, c] = dense.source_uv[r, c]
            if depth_in[r, c] <= 8.0:
                crop[r, c] = moved(dense.source_uv[r, c].astype(np.float64), float(depth_in[r, c]) - 0.5)
        else:
            k = label[r, c] - 1
            crop[r, c] = moved(dense.source_uv[zr[k], zc[k]].astype(np.float64), 0.5 - float(dist[r, c]))
    assert len(W.people_boxes(inside | dense.source_mask, 12)) == actors  # the bench's actors stand apart
    np.testing.assert_array_equal(got, want)


def test_people_boxes_split_at_empty_columns_only():
    from bodystudio.mirror.warp import people_boxes

    m = np.zeros((50, 120), bool)
    assert people_boxes(m, 3) == []
    m[10:20, 5:15] = True
    m[30:40, 40:50] = True  # 25 empty columns between them: two boxes at margin 3 (or 12), one at 13
    assert people_boxes(m, 3) == [((7, 23), (2, 18)), ((27, 43), (37, 53))]
    assert people_boxes(m, 13) == [((0, 50), (0, 63))]
    m[25, 20:35] = True  # something in the gap: one box
    assert len(people_boxes(m, 3)) == 1


def test_signed_distance_in_one_pass_is_numpys():
    import cv2

    from bodystudio.mirror.warp import _signed_distance

    for mask in (cached_image_case(None, 0, 2).dense.source_mask, np.random.default_rng(6).random((40, 50)) < 0.5,
                 np.ones((8, 9), bool), np.zeros((8, 9), bool)):
        m = np.asarray(mask, np.uint8)
        want = cv2.distanceTransform(m, cv2.DIST_L2, cv2.DIST_MASK_5) - \
            cv2.distanceTransform(1 - m, cv2.DIST_L2, cv2.DIST_MASK_5)
        want += np.where(m > 0, np.float32(-0.5), np.float32(0.5))
        got = _signed_distance(mask)
        assert got.dtype == np.float32
        np.testing.assert_array_equal(got, want)


def _similarity_numpy(v, p, q, kind, alpha):
    """Eq. 5's similarity / rigid closed forms in numpy over all handles, as mls_transforms computed them before
    MIR12d moved them into one numba pass."""
    from bodystudio.mirror.warp import EPS_PX2, _weighted_sums

    c = p.mean(0)
    v, p, q = v - c, p - c, q - c
    px, py, qx, qy = p[:, 0], p[:, 1], q[:, 0], q[:, 1]
    monomials = np.stack([np.ones_like(px), px, py, qx, qy, px * px + py * py, px * qx + py * qy, px * qy - py * qx])
    S = _weighted_sums(np.ascontiguousarray(v), np.ascontiguousarray(px), np.ascontiguousarray(py),
                       np.ascontiguousarray(monomials), float(alpha), EPS_PX2)
    W = S[:, 0]
    ps, qs = S[:, 1:3] / W[:, None], S[:, 3:5] / W[:, None]
    mu = S[:, 5] - W * (ps[:, 0] ** 2 + ps[:, 1] ** 2)
    zr = (S[:, 6] - W * (ps[:, 0] * qs[:, 0] + ps[:, 1] * qs[:, 1])) / mu
    zi = (S[:, 7] - W * (ps[:, 0] * qs[:, 1] - ps[:, 1] * qs[:, 0])) / mu
    if kind == "rigid":
        norm = np.hypot(zr, zi)
        zr, zi = zr / norm, zi / norm
    A = np.empty((len(v), 2, 2))
    A[:, 0, 0], A[:, 0, 1], A[:, 1, 0], A[:, 1, 1] = zr, zi, -zi, zr
    return A, np.einsum("ni,nij->nj", v - ps, A) + qs + c


@pytest.mark.parametrize("kind", ["similarity", "rigid"])
@pytest.mark.parametrize("alpha", [1.0, 2.0])
def test_similarity_closed_form_in_numba_is_numpys(kind, alpha):
    from bodystudio.mirror.warp import mls_transforms

    rng = np.random.default_rng(7)
    p = rng.uniform(0, 300, (60, 2))
    q = p + rng.normal(0, 5, p.shape)
    v = rng.uniform(0, 300, (500, 2))
    got, want = mls_transforms(v, p, q, kind, alpha), _similarity_numpy(v, p, q, kind, alpha)
    np.testing.assert_array_equal(got[0], want[0])
    np.testing.assert_array_equal(got[1], want[1])


def test_finite_rows_is_isfinite_all_over_the_last_axis():
    from bodystudio.mirror.warp import _finite_rows

    xy = np.array([[1.0, 2.0], [np.nan, 2.0], [1.0, np.nan], [np.nan, np.nan], [np.inf, 0.0], [0.0, -np.inf]])
    np.testing.assert_array_equal(_finite_rows(xy), np.isfinite(xy).all(1))
    grid = np.random.default_rng(8).normal(size=(7, 9, 2))
    grid[grid > 1.2] = np.nan
    np.testing.assert_array_equal(_finite_rows(grid), np.isfinite(grid).all(2))


@pytest.mark.parametrize("actors", [1, 2])
def test_source_silhouette_and_depth_alone_are_the_renders(actors, monkeypatch):
    """warp_pairs renders the source body's silhouette and depth without triangle ids and barycentrics (MIR12f,
    capture.render.render_silhouette_depth): the same mask and z-buffer as render's, front faces and both sides,
    and the same pairs and dense correspondence of the bench frames bit for bit as with the full render."""
    from bodystudio.capture import render as R
    from bodystudio.mirror import warp as W
    from bodystudio.mirror.run import frame_pairs

    case = cached_image_case(None, 0, actors)
    S, T = np.split(case.source_vertices, actors), np.split(case.target_vertices, actors)
    F1 = case.faces[: len(case.faces) // actors]
    V = np.concatenate(S)
    F_all = np.concatenate([F1 + k * len(S[0]) for k in range(actors)])
    for faces in (F_all, F_all[W.facing_faces(case.camera.project(V), F_all)]):
        mask, depth = R.render_silhouette_depth(V, faces, case.camera)
        full = R.render(V, faces, case.camera)
        assert mask.sum() > 10000
        np.testing.assert_array_equal(mask, full.mask)
        np.testing.assert_array_equal(depth, full.depth)
    got = frame_pairs(S, T, F1, case.camera)

    def full_render(V, F, camera):
        r = R.render(V, F, camera)
        return r.mask, r.depth

    monkeypatch.setattr(R, "render_silhouette_depth", full_render)
    want = frame_pairs(S, T, F1, case.camera)
    for name in ("src_uv", "dst_uv", "ids", "groups"):
        np.testing.assert_array_equal(getattr(got, name), getattr(want, name))
    for name in ("origin", "source_uv", "source_mask", "grid_source_uv", "grid_groups"):
        np.testing.assert_array_equal(getattr(got.dense, name), getattr(want.dense, name))


def _rim_vertices_numpy(V, faces, eye, max_cos):
    """warp.rim_vertices as numpy computed it before MIR12f."""
    from bodystudio.mirror.warp import _area_weighted_normals

    N = _area_weighted_normals(np.ascontiguousarray(V), np.ascontiguousarray(faces, dtype=np.int64))
    ray = V - np.asarray(eye, dtype=np.float64)
    norm = np.linalg.norm(N, axis=1) * np.linalg.norm(ray, axis=1)
    cos = np.einsum("ij,ij->i", N, ray) / np.maximum(norm, 1e-300)
    return np.flatnonzero((np.abs(cos) < max_cos) & (norm > 0))


def _body_crop_numpy(uv_list, camera, margin_px):
    """warp._body_crop as numpy computed it before MIR12f."""
    from bodystudio.mirror.warp import _finite_rows

    pts = np.concatenate([uv[_finite_rows(uv)] for uv in uv_list])
    if not len(pts):
        return None
    x0 = int(max(np.floor(pts[:, 0].min() - margin_px), 0))
    y0 = int(max(np.floor(pts[:, 1].min() - margin_px), 0))
    x1 = int(min(np.ceil(pts[:, 0].max() + margin_px) + 1, camera.width))
    y1 = int(min(np.ceil(pts[:, 1].max() + margin_px) + 1, camera.height))
    return (x0, y0, x1, y1) if x1 > x0 and y1 > y0 else None


@pytest.mark.parametrize("actors", [1, 2])
def test_rim_test_crop_bounds_and_spread_ids_in_numba_are_numpys(actors):
    """The pairs' rim test and crop bounds in one numba pass each and the spread ids cached (MIR12f): the same ids
    and boxes as the numpy code, on the bench frames' bodies (two rim thresholds, an unused vertex), on points with
    NaN and inf, none finite; the cached ids are numpy's and read-only."""
    from bodystudio.mirror import warp as W

    case = cached_image_case(None, 0, actors)
    eye = case.camera.center
    V = np.concatenate([case.target_vertices, [[0.1, 1.0, 2.0]]])  # the last vertex is on no face
    for max_cos in (0.3, 0.05):
        got = W.rim_vertices(V, case.faces, eye, max_cos)
        want = _rim_vertices_numpy(V, case.faces, eye, max_cos)
        assert len(want) > 100
        np.testing.assert_array_equal(got, want)
    uv = case.camera.project(case.source_vertices)
    rng = np.random.default_rng(6)
    odd = uv.copy()
    odd[rng.integers(0, len(uv), 50)] = np.nan
    odd[rng.integers(0, len(uv), 5), 0] = np.inf
    for uv_list in ([uv], [odd, uv + 7.0], [odd[:0]], [np.full((4, 2), np.nan)], [uv - 1e4]):
        for margin in (10.0, 0.0):
            assert W._body_crop(uv_list, case.camera, margin) == _body_crop_numpy(uv_list, case.camera, margin)
    for n, k in ((len(V), 400), (30, 400), (1, 5)):
        ids = W._spread_ids(n, k)
        np.testing.assert_array_equal(ids, np.unique(np.linspace(0, n - 1, min(k, n)).round().astype(np.int64)))
        assert not ids.flags.writeable
