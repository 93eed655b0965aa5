"""Silhouette constraints (Rapid Skin §III.B, Eq. 6, 7, 10): the plain-Python layer around the compiled
per-view pass, where mutation testing found no test: closed-mesh test, defaults, mask preparation, the
camera bookkeeping of the constraints and the one-line mask errors."""

import numpy as np
import pytest

from bodystudio.errors import SessionError
from bodystudio.geometry.camera import Camera
from bodystudio.reconstruct import silhouette as S
from bodystudio.reconstruct.silhouette import (
    SilhouetteViews,
    area_weighted_normals,
    check_masks,
    is_closed_mesh,
    match_contours,
    rim_vertices,
    silhouette_constraints,
    silhouette_mask,
    silhouette_weight,
)

# A closed, consistently oriented octahedron.
_OCT_F = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])


def _sphere(radius=0.3, subdivisions=3):
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    return np.asarray(m.vertices, float), np.asarray(m.faces, np.int64)


def test_is_closed_mesh_cases():
    assert is_closed_mesh(_OCT_F) and is_closed_mesh(_OCT_F.tolist())
    assert not is_closed_mesh(np.zeros((0, 3), np.int64))  # no faces: not a closed surface
    assert not is_closed_mesh(_OCT_F[:-1])  # a hole: three edges without their opposite
    flipped = _OCT_F.copy()
    flipped[0] = flipped[0, ::-1]
    assert not is_closed_mesh(flipped)  # one face turned: its edges are duplicated, their opposites missing
    assert not is_closed_mesh(np.r_[_OCT_F, _OCT_F[:1]])  # a face listed twice
    # the largest vertex id takes part in the edge keys: a mesh whose ids are all shifted is still closed
    assert is_closed_mesh(_OCT_F + 7)
    assert is_closed_mesh(np.array([[0, 1, 2], [0, 2, 1]]))  # two-sided triangle: every edge has its opposite
    assert not is_closed_mesh(np.array([[0, 1, 2], [0, 2, 3]]))
    assert not is_closed_mesh(np.array([[0, 1, 2]]))  # an opposite key beyond every key: searchsorted's end


def test_silhouette_views_prepare_masks_once():
    V, F = _sphere()
    cam = Camera.look_at("c0", (0, 0, 3), (0, 0, 0), fx=400.0, width=80, height=60)
    cam2 = Camera.look_at("c1", (3, 0, 0), (0, 0, 0), fx=400.0, width=80, height=60)
    mask = silhouette_mask(V, F, cam)
    for given in (mask, mask.astype(np.uint8) * 255, mask.astype(float) * 0.7):
        views = SilhouetteViews([cam, cam2], {"c0": given, "c1": mask}, F)
        assert views.facing == 1.0 and len(views.views) == 2
        c, m, own, K, dist, R, t, center, has_dist = views.views[0]
        assert c is cam and m.dtype == np.uint8 and m.flags.c_contiguous
        np.testing.assert_array_equal(m, mask.astype(np.uint8))  # 0 / 1 whatever the input's scale
        assert own.shape == (60, 80) and own.dtype == np.uint8 and not own.any()
        assert np.array_equal(K, cam.K) and np.array_equal(R, cam.R) and np.array_equal(t, cam.t)
        assert np.array_equal(center, cam.center) and np.array_equal(dist, cam.dist) and has_dist is False
        assert views.views[1][0] is cam2
    # without faces, or with an open mesh, the outline raster draws both orientations
    assert SilhouetteViews([cam], {"c0": mask}).facing == 0.0
    assert SilhouetteViews([cam], {"c0": mask}, F[:-1]).facing == 0.0


def test_closed_mesh_test_is_cached_per_face_array(monkeypatch):
    calls = []
    real = S.is_closed_mesh
    monkeypatch.setattr(S, "is_closed_mesh", lambda F: calls.append(1) or real(F))
    S._CLOSED_CACHE.clear()
    F = _OCT_F + 100  # a face array not used by other tests
    assert S._is_closed_cached(F) and S._is_closed_cached(F.astype(np.int32)) and len(calls) == 1
    assert not S._is_closed_cached(F[:-1]) and len(calls) == 2
    # the cache is bounded: it is emptied once it holds more than 16 face arrays
    sizes = []
    for k in range(40):
        S._is_closed_cached(_OCT_F + 1000 + k)
        sizes.append(len(S._CLOSED_CACHE))
    assert max(sizes) == 17 and min(sizes[5:]) == 1


def test_closed_mesh_cache_tells_apart_face_arrays_that_share_the_hashed_rows():
    """The cache key hashes every 97th face only; a face array equal there but different elsewhere (a face
    flipped: open, inconsistently oriented) is compared in full and gets its own answer."""
    S._CLOSED_CACHE.clear()
    V, F = _sphere()
    F = np.asarray(F, dtype=np.int64)
    assert len(F) > 200 and S._is_closed_cached(F)
    flipped = F.copy()
    flipped[50] = flipped[50, ::-1]  # row 50 is not hashed (0, 97, 194, ...)
    assert not S._is_closed_cached(flipped) and not is_closed_mesh(flipped)
    assert S._is_closed_cached(F)  # and the closed one is still answered as closed


def test_defaults_of_the_helpers():
    V, F = _sphere()
    N = area_weighted_normals(V, F)
    cam = Camera.look_at("c0", (0, 0, 3), (0, 0, 0), fx=400.0, width=160, height=120)
    ray = V - cam.center
    cos = np.abs(np.sum(N * ray, 1)) / np.linalg.norm(ray, axis=1)
    assert np.array_equal(rim_vertices(V, N, cam), cos < 0.2)  # default max_cos 0.2
    assert np.array_equal(rim_vertices(V, N, cam, 0.35), cos < 0.35)
    assert 0 < (cos < 0.2).sum() < (cos < 0.35).sum()
    d = np.array([0.0, 5.0, 20.0, 40.0, 70.0])
    np.testing.assert_allclose(silhouette_weight(d), np.exp(-d * d / (2 * 40.0 * 40.0)), rtol=1e-15)  # alpha 40
    np.testing.assert_allclose(silhouette_weight(d, 7.0), np.exp(-d * d / 98.0), rtol=1e-15)
    np.testing.assert_allclose(silhouette_weight(-d, 7.0), silhouette_weight(d, 7.0), rtol=0)
    x32 = (d + 0.1).astype(np.float32)  # float32 input, float64 arithmetic
    w32 = silhouette_weight(x32, 7.0)
    assert w32.dtype == np.float64
    np.testing.assert_allclose(w32, silhouette_weight(x32.astype(np.float64), 7.0), rtol=1e-15)
    # match_contours: tau defaults to 30 px; boolean masks and integer pixel coordinates are accepted
    y, x = np.mgrid[0:100, 0:120]
    disc = (x - 60) ** 2 + (y - 50) ** 2 <= 10 * 10
    # the disc's right edge lies at x = 70.5: 30.5 px from x = 40 (beyond the default tau), 28.5 from x = 42
    uv = np.array([[40, 50], [42, 50]])
    plus_x = np.array([[1, 0], [1, 0]])
    t = match_contours(disc, uv, plus_x)
    assert np.isnan(t[0]) and t[1] == pytest.approx(28.5, abs=1e-9)
    assert match_contours(disc, uv, plus_x, 31.0)[0] == pytest.approx(30.5, abs=1e-9)
    assert np.all(np.isnan(match_contours(disc, uv + [40, 0], -plus_x)))  # inwards from outside: no agreeing edge


def test_constraints_carry_their_camera_origin_and_offset():
    """Three views, the middle one sees nothing to match (its mask is a far-away blob): the camera ids of the
    constraints still name the right views, origins are the camera centres and k is Eq. 10 of |offset|."""
    V, F = _sphere(0.30)
    N = area_weighted_normals(V, F)
    cams = [Camera.look_at(f"c{i}", (3 * np.sin(a), 0.2, 3 * np.cos(a)), (0, 0, 0), fx=500.0, width=320, height=240)
            for i, a in enumerate([0.0, 1.6, 3.1])]
    masks = {c.name: silhouette_mask(1.05 * V, F, c) for c in cams}
    far = np.zeros((240, 320), bool)
    far[:6, :6] = True
    masks["c1"] = far
    sil = silhouette_constraints(V, F, N, cams, masks, tau_px=20.0, alpha_px=3.0, rim_cos=0.2)
    assert set(sil.camera.tolist()) == {0, 2} and sil.camera.dtype.kind == "i"
    for c in (0, 2):
        m = sil.camera == c
        assert m.sum() > 50
        np.testing.assert_array_equal(sil.origin[m], np.broadcast_to(cams[c].center, (m.sum(), 3)))
    assert sil.origin.flags.c_contiguous and sil.origin.shape == sil.direction.shape == (len(sil), 3)
    np.testing.assert_allclose(np.linalg.norm(sil.direction, axis=1), 1.0, atol=1e-12)
    assert np.all(sil.pixel_distance >= 0) and np.median(sil.pixel_distance) > 1.5
    np.testing.assert_allclose(sil.k, np.exp(-sil.pixel_distance**2 / 18.0), rtol=1e-12)
    # the matched rays pass within a pixel's width of the larger sphere's rim (radius 0.315)
    from bodystudio.reconstruct.solver import point_to_ray_distance

    d_centre = point_to_ray_distance(np.zeros((len(sil), 3)), sil.origin, sil.direction)
    assert np.median(np.abs(d_centre - 0.315)) < 0.002
    # prepared views give the same constraints
    views = SilhouetteViews(cams, masks, F)
    again = silhouette_constraints(V, F, N, cams, None, 20.0, 3.0, 0.2, views=views)
    assert np.array_equal(again.vertex, sil.vertex) and np.array_equal(again.direction, sil.direction)
    # float32 vertices and normals, int32 faces: computed in float64 (exactly as if widened first)
    V32, N32 = V.astype(np.float32), N.astype(np.float32)
    a = silhouette_constraints(V32, F.astype(np.int32), N32, cams, masks, 20.0, 3.0, 0.2)
    b = silhouette_constraints(V32.astype(float), F, N32.astype(float), cams, masks, 20.0, 3.0, 0.2)
    assert len(a) > 100 and np.array_equal(a.vertex, b.vertex)
    np.testing.assert_allclose(a.direction, b.direction, rtol=0, atol=1e-15)
    np.testing.assert_allclose(a.pixel_distance, b.pixel_distance, rtol=0, atol=1e-12)
    # the defaults are tau 30 px, alpha 40 px, rim cosine 0.2
    d = silhouette_constraints(V, F, N, cams, masks)
    e = silhouette_constraints(V, F, N, cams, masks, 30.0, 40.0, 0.2)
    assert np.array_equal(d.vertex, e.vertex) and np.array_equal(d.k, e.k)
    assert not np.array_equal(d.k, silhouette_constraints(V, F, N, cams, masks, 30.0, 39.0, 0.2).k)
    assert len(silhouette_constraints(V, F, N, cams, masks, 30.0, 40.0, 0.25)) > len(d)
    # a 1.58x sphere puts the contour 29.4-30.5 px from the rims: the default tau (30) keeps part of them
    big = {c.name: silhouette_mask(1.58 * V, F, c) for c in cams}
    n30 = len(silhouette_constraints(V, F, N, cams, big, 30.0))
    assert 0 < n30 == len(silhouette_constraints(V, F, N, cams, big)) < len(silhouette_constraints(V, F, N, cams,
                                                                                                   big, 31.0))


def test_a_view_with_a_single_match_keeps_it():
    """A mask of one pixel on one rim vertex's contour crossing: exactly one constraint from that view."""
    V, F = _sphere(0.30)
    N = area_weighted_normals(V, F)
    cams = [Camera.look_at(f"c{i}", (3 * np.sin(a), 0.2, 3 * np.cos(a)), (0, 0, 0), fx=500.0, width=320, height=240)
            for i, a in enumerate([0.0, 2.1])]
    full = {c.name: silhouette_mask(1.05 * V, F, c) for c in cams}
    sil = silhouette_constraints(V, F, N, cams[:1], full, 20.0, 3.0)
    uv = cams[0].project(V[sil.vertex])
    j = int(np.argmax(uv[:, 0]))  # the rightmost rim vertex: its normal points along +u
    n2 = cams[0].project(V[sil.vertex[j]] + 0.005 * N[sil.vertex[j]]) - uv[j]
    p = (uv[j] + (sil.pixel_distance[j] - 0.5) * n2 / np.linalg.norm(n2)).ravel()  # last pixel inside
    one = np.zeros((240, 320), bool)
    one[int(round(p[1])), int(round(p[0]))] = True
    got = silhouette_constraints(V, F, N, cams, {"c0": one, "c1": full["c1"]}, 20.0, 3.0)
    assert (got.camera == 0).sum() == 1 and got.vertex[got.camera == 0][0] == sil.vertex[j]
    assert (got.camera == 1).sum() > 50


def test_no_match_in_any_view_gives_the_empty_set():
    V, F = _sphere(0.30)
    N = area_weighted_normals(V, F)
    cam = Camera.look_at("c0", (0, 0.2, 3), (0, 0, 0), fx=500.0, width=160, height=120)
    far = np.zeros((120, 160), bool)
    far[:4, :4] = True
    sil = silhouette_constraints(V, F, N, [cam], {"c0": far})
    assert len(sil) == 0 and sil.origin.shape == (0, 3) and sil.camera.dtype == np.int64


def test_mask_errors_name_the_camera_and_the_fix():
    cam = Camera.look_at("c0", (0, 0, 3), (0, 0, 0), fx=500.0, width=64, height=48)
    cam1 = Camera.look_at("c1", (3, 0, 0), (0, 0, 0), fx=500.0, width=64, height=48)
    ok = np.ones((48, 64), bool)
    check_masks({"c0": ok, "c1": ok}, [cam, cam1])
    check_masks({"c0": ok, "c1": ok[..., None]}, [cam, cam1])  # an (H, W, 1) mask has the camera's size
    cases = [
        ({"c0": ok}, "frame: no silhouette mask for camera c1; the session and its cameras.json disagree "
                     "(masks for c0)"),
        ({}, "frame: no silhouette mask for camera c0; the session and its cameras.json disagree (masks for none)"),
        ({"c1": ok, "b": ok}, "frame: no silhouette mask for camera c0; the session and its cameras.json disagree "
                              "(masks for b, c1)"),
        ({"c0": ok, "c1": np.ones((48, 60), bool)}, "frame: mask of c1 is 60x48 but the camera is 64x48; "
                                                    "camera/session mismatch"),
        ({"c0": ok, "c1": np.zeros((48, 64), bool)}, "frame: the silhouette mask of c1 is empty; check the "
                                                     "segmentation or drop the camera"),
    ]
    for masks, msg in cases:
        with pytest.raises(SessionError) as exc:
            check_masks(masks, [cam, cam1])
        assert str(exc.value) == msg
    with pytest.raises(SessionError) as exc:
        check_masks({}, [cam], where="walk frame 3")
    assert str(exc.value).startswith("walk frame 3: no silhouette mask for camera c0")


def test_pixel_distance_is_the_offsets_magnitude_on_either_side():
    """A 5 % smaller sphere in the masks: the contour lies inside the rims, the offsets are negative, the
    pixel distance (and Eq. 10's argument) is their magnitude."""
    V, F = _sphere(0.30)
    N = area_weighted_normals(V, F)
    cams = [Camera.look_at(f"c{i}", (3 * np.sin(a), 0.2, 3 * np.cos(a)), (0, 0, 0), fx=500.0, width=320, height=240)
            for i, a in enumerate([0.0, 2.1])]
    masks = {c.name: silhouette_mask(0.95 * V, F, c) for c in cams}
    sil = silhouette_constraints(V, F, N, cams, masks, tau_px=20.0, alpha_px=3.0)
    assert len(sil) > 50 and np.all(sil.pixel_distance >= 0) and np.median(sil.pixel_distance) > 1.5
    np.testing.assert_allclose(sil.k, np.exp(-sil.pixel_distance**2 / 18.0), rtol=1e-12)
    from bodystudio.reconstruct.solver import point_to_ray_distance

    d_centre = point_to_ray_distance(np.zeros((len(sil), 3)), sil.origin, sil.direction)
    assert np.median(np.abs(d_centre - 0.285)) < 0.002


def test_outline_raster_draws_both_orientations_by_default():
    """On an open mesh one triangle is front- or back-facing: the default raster draws it either way."""
    uv = np.array([[10.0, 10.0], [50.0, 12.0], [20.0, 40.0]])
    for F in (np.array([[0, 1, 2]]), np.array([[0, 2, 1]])):
        m = S._rasterize_mask(uv, F, 64, 48, np.zeros((48, 64), np.uint8))
        assert 400 < m.sum() < 700  # the triangle's area is 590 px^2
        assert m[20, 25] and not m[45, 60]
    # the last row / column of an image whose size is no multiple of the tile is drawn too
    uv = np.array([[-5.0, -5.0], [70.0, -5.0], [-5.0, 60.0], [70.0, 60.0]])
    for w, h in ((61, 41), (1, 1), (9, 1), (1, 9), (5, 3)):
        m = S._rasterize_mask(uv, np.array([[0, 1, 2], [1, 3, 2]]), w, h, np.zeros((h, w), np.uint8))
        assert m.shape == (h, w) and m.all(), (w, h)
