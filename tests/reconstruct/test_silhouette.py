"""Rim vertices and contour matching (Rapid Skin §III.B) on shapes with a known outline."""

import numpy as np
import pytest

from bodystudio.errors import SessionError
from bodystudio.geometry.camera import Camera
from bodystudio.reconstruct.silhouette import (
    check_masks,
    match_contours,
    rim_vertices,
    silhouette_constraints,
    silhouette_mask,
    silhouette_weight,
)
from bodystudio.reconstruct.solver import point_to_ray_distance


def _disc(width=200, height=160, cx=100.0, cy=80.0, r=40.0):
    y, x = np.mgrid[0:height, 0:width]
    return (x - cx) ** 2 + (y - cy) ** 2 <= r * r


def test_contour_search_finds_the_edge_with_agreeing_gradient():
    mask = _disc()
    # points inside and outside the disc, searching along the outward radial direction
    ang = np.linspace(0, 2 * np.pi, 24, endpoint=False)
    radial = np.c_[np.cos(ang), np.sin(ang)]
    for r0 in (30.0, 52.0):
        uv = np.array([100.0, 80.0]) + r0 * radial
        t = match_contours(mask, uv, radial, tau_px=30.0)
        assert np.all(np.isfinite(t))
        assert np.all(np.abs((r0 + t) - 40.0) < 0.75)  # sub-pixel edge of a binary disc
    # searching along the inward direction only sees outside->inside crossings: rejected
    uv = np.array([100.0, 80.0]) + 45.0 * radial
    assert np.all(np.isnan(match_contours(mask, uv, -radial, tau_px=30.0)))
    # beyond tau nothing is matched
    uv = np.array([100.0, 80.0]) + 75.0 * radial[:1]
    assert np.isnan(match_contours(mask, uv, radial[:1], tau_px=30.0))[0]


def test_silhouette_weight_eq10():
    assert silhouette_weight(0.0, 40.0) == 1.0
    assert np.isclose(silhouette_weight(40.0, 40.0), np.exp(-0.5))
    assert silhouette_weight(30.0, 40.0) > silhouette_weight(31.0, 40.0)


def _sphere(radius=0.3):
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=4, radius=radius)
    return np.asarray(m.vertices, float), np.asarray(m.faces, np.int64), np.asarray(m.vertex_normals, float)


def test_sphere_rims_match_a_larger_sphere():
    V, F, N = _sphere(0.30)
    cams = [Camera.look_at(f"c{i}", (3 * np.sin(a), 0.2, 3 * np.cos(a)), (0, 0, 0), fx=500.0)
            for i, a in enumerate([0.0, 1.6, 3.1])]
    big = 1.05 * V
    masks = {c.name: silhouette_mask(big, F, c) for c in cams}
    rim = rim_vertices(V, N, cams[0], 0.2)
    ray = V[rim] - cams[0].center
    assert np.all(np.abs(np.sum(N[rim] * ray, 1)) < 0.2 * np.linalg.norm(ray, axis=1))
    sil = silhouette_constraints(V, F, N, cams, masks, tau_px=30, alpha_px=40, rim_cos=0.2)
    assert len(sil) > 100 and set(sil.camera.tolist()) == {0, 1, 2}
    # every matched ray is tangent to the larger sphere: its distance to the centre is ~1.05 * 0.30
    d_centre = point_to_ray_distance(np.zeros((len(sil), 3)), sil.origin, sil.direction)
    assert np.median(np.abs(d_centre - 0.315)) < 0.002
    # the contour lies outside the rim vertex, about 15 mm / 3 m * 500 px = 2.5 px away
    assert 1.5 < np.median(sil.pixel_distance) < 4.0
    assert np.all(sil.k <= 1.0) and np.all(sil.k > 0.5)


def test_bad_masks_are_one_line_errors():
    cam = Camera.look_at("c0", (0, 0, 3), (0, 0, 0), fx=500.0, width=64, height=48)
    with pytest.raises(SessionError, match="empty"):
        check_masks({"c0": np.zeros((48, 64), bool)}, [cam])
    with pytest.raises(SessionError, match="mismatch"):
        check_masks({"c0": np.ones((10, 10), bool)}, [cam])
    with pytest.raises(SessionError, match="no silhouette mask for camera c0"):
        check_masks({"other": np.ones((48, 64), bool)}, [cam])


def _scan_all_samples(mask, x, y, dx, dy, tau):
    """Reference contour search: every sample from -tau to +tau, keep the nearest agreeing crossing."""
    from bodystudio.reconstruct.silhouette import _sample_bilinear

    steps = int(np.ceil(tau))
    best = np.inf
    prev = _sample_bilinear(mask, x - steps * dx, y - steps * dy)
    for s in range(-steps + 1, steps + 1):
        cur = _sample_bilinear(mask, x + s * dx, y + s * dy)
        if prev >= 0.5 and cur < 0.5:
            t = (s - 1) + (prev - 0.5) / (prev - cur)
            if abs(t) <= tau and abs(t) < abs(best):
                best = t
        prev = cur
    return best if np.isfinite(best) else np.nan


def test_outward_contour_search_equals_a_full_scan():
    rng = np.random.default_rng(3)
    # blobby mask with many contours, so crossings on both sides and at several distances occur
    mask = np.zeros((120, 160))
    for _ in range(25):
        cx, cy, r = rng.uniform(0, 160), rng.uniform(0, 120), rng.uniform(3, 18)
        y, x = np.mgrid[0:120, 0:160]
        mask[(x - cx) ** 2 + (y - cy) ** 2 <= r * r] = 1.0
    uv = rng.uniform([5, 5], [155, 115], size=(400, 2))
    ang = rng.uniform(0, 2 * np.pi, 400)
    d = np.c_[np.cos(ang), np.sin(ang)]
    got = match_contours(mask, uv, d, tau_px=12.5)
    ref = np.array([_scan_all_samples(mask, *uv[i], *d[i], 12.5) for i in range(len(uv))])
    assert np.sum(np.isfinite(ref)) > 100 and np.sum(np.isnan(ref)) > 20
    np.testing.assert_array_equal(np.isnan(got), np.isnan(ref))
    np.testing.assert_allclose(got[np.isfinite(ref)], ref[np.isfinite(ref)], atol=1e-12)


def test_front_facing_outline_equals_the_full_raster_on_a_closed_mesh():
    from bodystudio.reconstruct.silhouette import _rasterize_mask, is_closed_mesh

    V, F, _ = _sphere(0.3)
    V = V * np.array([1.0, 1.6, 0.7])
    assert is_closed_mesh(F) and not is_closed_mesh(F[1:]) and not is_closed_mesh(F[:, ::-1][np.r_[0, 0:len(F)]])
    cam = Camera.look_at("c0", (0.4, 0.3, 2.0), (0, 0, 0), fx=400.0, width=200, height=160)
    uv = np.ascontiguousarray(cam.project(V))
    full = _rasterize_mask(uv, F, 200, 160, np.zeros((160, 200), np.uint8), 0.0)
    for facing in (1.0, -1.0):
        one = _rasterize_mask(uv, F, 200, 160, np.zeros((160, 200), np.uint8), facing)
        assert full.sum() > 1000
        np.testing.assert_array_equal(one, full)


def test_numba_rays_agree_with_the_camera_model_under_distortion():
    """The fused per-view pass (projection, rim test, occlusion, search, ray) against the camera API."""
    from bodystudio.reconstruct.silhouette import area_weighted_normals

    V, F, _ = _sphere(0.30)
    N = area_weighted_normals(V, F)
    base = Camera.look_at("c0", (0.3, 0.2, 2.5), (0, 0, 0), fx=420.0, width=240, height=200)
    cam = Camera("c0", base.K, np.array([-0.12, 0.05, 0.001, -0.002, 0.0]), base.R, base.t, 240, 200)
    masks = {"c0": silhouette_mask(1.05 * V, F, cam)}
    sil = silhouette_constraints(V, F, N, [cam], masks)
    assert len(sil) > 30
    uv = cam.project(V[sil.vertex])
    n2 = cam.project(V[sil.vertex] + 0.005 * N[sil.vertex]) - uv
    n2 /= np.linalg.norm(n2, axis=1, keepdims=True)
    t = match_contours(masks["c0"], uv, n2, 30.0)
    np.testing.assert_allclose(t, sil.pixel_distance * np.sign(t), atol=1e-9)
    o, d = cam.rays(uv + t[:, None] * n2)
    np.testing.assert_allclose(sil.direction, d, atol=1e-9)
    np.testing.assert_allclose(sil.origin, o, atol=1e-12)


def test_culled_outline_raster_is_exact_on_flagged_tiles():
    from bodystudio.reconstruct.silhouette import _TILE, _rasterize_mask, _rasterize_needed

    V, F, _ = _sphere(0.3)
    cam = Camera.look_at("c0", (0.4, 0.3, 2.0), (0, 0, 0), fx=400.0, width=200, height=160)
    uv = np.ascontiguousarray(cam.project(V))
    full = _rasterize_mask(uv, F, 200, 160, np.zeros((160, 200), np.uint8), 1.0)
    need = (np.random.default_rng(1).random(((160 + _TILE - 1) // _TILE, (200 + _TILE - 1) // _TILE)) < 0.3)
    culled = _rasterize_needed(uv, F, 200, 160, np.zeros((160, 200), np.uint8), 1.0, need.astype(np.uint8))
    flagged = np.kron(need, np.ones((_TILE, _TILE), bool))[:160, :200]
    assert full[flagged].sum() > 200 and culled.sum() < full.sum()  # culling skipped work, kept flagged pixels
    np.testing.assert_array_equal(culled[flagged], full[flagged])


def test_constraint_weights_are_eq10_of_the_matched_offset():
    """``k_sil = exp(-d^2 / 2 alpha^2)`` as silhouette_constraints applies it, with alpha far from tau and from
    1 so that k = 1 or alpha replaced by tau changes the weights: a 1.05x sphere's contour lies ~2.5 px out."""
    V, F, N = _sphere(0.30)
    cams = [Camera.look_at(f"c{i}", (3 * np.sin(a), 0.2, 3 * np.cos(a)), (0, 0, 0), fx=500.0)
            for i, a in enumerate([0.0, 1.6, 3.1])]
    masks = {c.name: silhouette_mask(1.05 * V, F, c) for c in cams}
    for alpha in (2.0, 5.0):
        sil = silhouette_constraints(V, F, N, cams, masks, tau_px=20.0, alpha_px=alpha, rim_cos=0.2)
        d = sil.pixel_distance
        assert len(sil) > 100 and 1.5 < np.median(d) < 4.0
        np.testing.assert_allclose(sil.k, np.exp(-d * d / (2 * alpha * alpha)), rtol=1e-12)
    sil = silhouette_constraints(V, F, N, cams, masks, tau_px=20.0, alpha_px=2.0, rim_cos=0.2)
    assert 0.25 < np.median(sil.k) < 0.7  # exp(-2.5^2 / 8) = 0.46: a real down-weighting, not k = 1


def test_all_views_at_once_equal_the_views_one_by_one():
    """The vectorised assembly over views (origins, weights, camera ids in one pass) gives exactly the
    per-view constraints concatenated in camera order, each origin its camera's centre."""
    V, F, N = _sphere(0.30)
    cams = [Camera.look_at(f"c{i}", (3 * np.sin(a), 0.2, 3 * np.cos(a)), (0, 0, 0), fx=500.0)
            for i, a in enumerate([0.0, 1.6, 3.1])]
    masks = {c.name: silhouette_mask(1.05 * V, F, c) for c in cams}
    sil = silhouette_constraints(V, F, N, cams, masks, alpha_px=5.0)
    one = [silhouette_constraints(V, F, N, [c], masks, alpha_px=5.0) for c in cams]
    assert all(len(s) > 30 for s in one)
    for name in ("vertex", "origin", "direction", "k", "pixel_distance"):
        np.testing.assert_array_equal(getattr(sil, name), np.concatenate([getattr(s, name) for s in one]))
    np.testing.assert_array_equal(sil.camera, np.repeat(np.arange(3), [len(s) for s in one]))
    np.testing.assert_array_equal(sil.origin, np.array([c.center for c in cams])[sil.camera])


def test_outline_raster_equals_a_per_pixel_reference_on_awkward_triangles():
    """rec15c's raster (pixel boxes from per-vertex ceil / floor, a branch-free tile test for small
    triangles) against a per-pixel numpy evaluation of the same edge functions: sub-pixel, thin, huge,
    partly and wholly off-image triangles, both orientations, a vertex behind the camera (NaN); full raster
    and the tile-culled one on its flagged tiles."""
    from bodystudio.reconstruct.silhouette import _TILE, _rasterize_mask, _rasterize_needed

    W, H = 90, 70
    rng = np.random.default_rng(5)
    centre = rng.uniform([-15, -15], [W + 15, H + 15], (300, 1, 2))
    size = np.exp(rng.uniform(np.log(0.2), np.log(12.0), (300, 1, 1)))
    small = (centre + size * rng.uniform(-1, 1, (300, 3, 2))).reshape(-1, 2)  # sub-pixel to 24 px, some off-image
    uv = np.concatenate([small, [[-1e4, -1e4], [1e4, 35.0], [45.0, 1e4], [np.nan, np.nan], [200.0, 200.0]]])
    n = len(uv)
    F_small = np.concatenate([np.arange(900).reshape(300, 3), [[n - 2, 0, 1], [n - 1, 7, 5]]]).astype(np.int64)
    F_small[1::2] = F_small[1::2, ::-1]  # both orientations
    F_huge = np.array([[n - 5, n - 4, n - 3], [n - 1, n - 5, 5], [10, 11, n - 4]], np.int64)
    yy, xx = np.mgrid[:H, :W].astype(np.float64)

    def reference(F, facing):
        out = np.zeros((H, W), bool)
        for a, b, c in F:
            ax, ay, bx, by, cx, cy = *uv[a], *uv[b], *uv[c]
            area = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)
            if not np.isfinite(area) or area == 0.0 or area * facing < 0.0:
                continue
            s = 1.0 if area > 0 else -1.0
            w0 = s * ((bx - xx) * (cy - yy) - (by - yy) * (cx - xx))
            w1 = s * ((cx - xx) * (ay - yy) - (cy - yy) * (ax - xx))
            w2 = s * ((ax - xx) * (by - yy) - (ay - yy) * (bx - xx))
            out |= (w0 >= 0) & (w1 >= 0) & (w2 >= 0)
        return out

    need = (rng.random(((H + _TILE - 1) // _TILE, (W + _TILE - 1) // _TILE)) < 0.35).astype(np.uint8)
    flagged = np.kron(need, np.ones((_TILE, _TILE), np.uint8))[:H, :W] > 0
    for F in (F_small, np.concatenate([F_small, F_huge])):
        for facing in (0.0, 1.0, -1.0):
            ref = reference(F, facing)
            assert ref.sum() > 200 and (F is not F_small or ref.sum() < H * W - 200)
            full = _rasterize_mask(uv, F, W, H, np.zeros((H, W), np.uint8), facing)
            np.testing.assert_array_equal(full > 0, ref)
            culled = _rasterize_needed(uv, F, W, H, np.zeros((H, W), np.uint8), facing, need)
            np.testing.assert_array_equal(culled[flagged] > 0, ref[flagged])
