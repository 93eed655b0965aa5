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
