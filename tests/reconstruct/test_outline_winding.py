"""The matching's occlusion outline kept as boundary edges on a closed mesh (issue 15's frame time, rec15k): the
winding number of the front-facing triangles' boundary covers exactly the pixels the front-facing raster sets,
and the matching built on it gives the raster path's constraints bit for bit."""

import numpy as np
import pytest

from bodystudio.geometry.camera import Camera
from bodystudio.reconstruct.silhouette import (
    SilhouetteViews,
    _draw_outline,
    _outline_rows,
    _rasterize_mask,
    area_weighted_normals,
    is_closed_mesh,
    outline_coverage,
    outline_edge_table,
    silhouette_constraints,
    silhouette_mask,
)

FIELDS = ("vertex", "origin", "direction", "k", "camera", "pixel_distance")
W, H = 240, 180


@pytest.fixture(scope="module")
def folded():
    """A bumpy blob (its bumps fold the surface: boundary edges inside the outline, pixels that two front-facing
    layers cover) through which a smaller blob passes, both closed."""
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=4, radius=0.3)
    V, F = np.asarray(m.vertices, float), np.asarray(m.faces, np.int64)
    bumps = 1.0 + 0.12 * np.sin(14 * V[:, 0]) * np.cos(11 * V[:, 1]) * np.sin(9 * V[:, 2] + 1.0)
    second = 0.45 * V + np.array([0.22, 0.08, 0.12])
    return np.vstack([V * bumps[:, None], second]), np.vstack([F, F + len(V)])


def _cameras():
    ring = [Camera.look_at(f"c{i}", (2.2 * np.sin(a), 0.5 * np.cos(3 * a), 2.2 * np.cos(a)), (0.02, 0.01, 0.0),
                           fx=300.0, width=W, height=H, dist=(-0.18, 0.04, 0.002, -0.001, 0.0) if i % 2 else None)
            for i, a in enumerate(np.linspace(0.0, 2 * np.pi, 5, endpoint=False) + 0.2)]
    # so near that the blobs leave the image; and one inside the big blob, with vertices behind it (NaN pixels)
    near = Camera.look_at("near", (0.1, 0.05, 0.62), (0.0, 0.0, 0.0), fx=260.0, width=W, height=H)
    inside = Camera.look_at("inside", (0.0, 0.02, 0.1), (0.0, 0.0, -1.0), fx=120.0, width=W, height=H)
    return ring + [near, inside]


def _outline_of(uv, F, edge_table):
    E = edge_table.shape[1]
    edges, rows = np.empty((E, 4)), np.empty((E, 2), np.int32)
    count = _draw_outline(uv, F, 1.0, *edge_table, H, np.empty(E, np.int32), edges, rows)
    return edges, rows, count


def test_edge_table_pairs_each_edge_with_its_two_faces(folded):
    V, F = folded
    a, b, f_ab, f_ba = outline_edge_table(F)
    assert is_closed_mesh(F) and len(a) == 3 * len(F) // 2 and np.all(a < b)
    directed = {(int(F[f, k]), int(F[f, (k + 1) % 3])): f for f in range(len(F)) for k in range(3)}
    for e in range(0, len(a), 7):
        assert directed[(a[e], b[e])] == f_ab[e] and directed[(b[e], a[e])] == f_ba[e]


def test_winding_coverage_is_the_front_facing_raster(folded):
    """At every pixel of views with distortion, the mesh partly off the image and vertices behind the camera; the
    folds make windings of 2 and more, so a parity rule (or dropping the inner boundary edges) would differ."""
    V, F = folded
    table = np.stack(outline_edge_table(F))
    deepest = 0
    for cam in _cameras():
        uv = np.ascontiguousarray(cam.project(V))
        raster = _rasterize_mask(uv, F, W, H, np.zeros((H, W), np.uint8), 1.0)
        edges, rows, count = _outline_of(uv, F, table)
        assert 0 < count < table.shape[1]
        np.testing.assert_array_equal(outline_coverage(edges, rows, count, W, H), raster, err_msg=cam.name)
        start, x_cross, sign = _outline_rows(edges, rows, count, H)
        for y in range(0, H, 3):
            xs, ss = x_cross[start[y]:start[y + 1]], sign[start[y]:start[y + 1]]
            winding = np.array([ss[xs > x].sum() for x in range(W)])
            deepest = max(deepest, int(winding.max()))
            np.testing.assert_array_equal(winding != 0, raster[y].astype(bool))
    assert deepest >= 2
    near_uv = _cameras()[-1].project(V)
    assert np.isnan(near_uv).any() and (np.abs(near_uv[np.isfinite(near_uv)]) > 1e3).any()


@pytest.mark.parametrize("packed", [True, False])
def test_matching_on_the_kept_edges_is_the_raster_matching(folded, packed):
    """The draw / full / keep sequence of a tracked frame on the edges equals the same sequence on the raster
    (the views' edge table taken away), and a mesh other than the views' falls back to the raster."""
    V, F = folded
    cams = _cameras()[:5]
    rng = np.random.default_rng(4)
    masks = {c.name: silhouette_mask(1.03 * V + rng.normal(0.0, 0.002, V.shape), F, c) for c in cams}
    steps = [V + rng.normal(0.0, 0.002, V.shape) for _ in range(3)]

    def run(views):
        out = []
        for V_k, outline in zip(steps, ("draw", "full", "keep"), strict=True):
            out.append(silhouette_constraints(V_k, F, area_weighted_normals(V_k, F), cams, None, 20.0, 8.0, 0.2,
                                              views=views, outline=outline))
        return out

    edge_views, raster_views = SilhouetteViews(cams, masks, F), SilhouetteViews(cams, masks, F)
    raster_views.edge_table = np.zeros((4, 0), np.int32)
    if not packed:
        edge_views.packed = raster_views.packed = None
    assert edge_views.edge_table.shape[1] == 3 * len(F) // 2
    for got, ref in zip(run(edge_views), run(raster_views), strict=True):
        assert len(ref) > 200
        for name in FIELDS:
            np.testing.assert_array_equal(getattr(got, name), getattr(ref, name), err_msg=name)
    other = np.ascontiguousarray(F[::-1])
    assert edge_views._edge_table_for(other).shape == (4, 0) and edge_views._edge_table_for(F.copy()) is not None
    open_views = SilhouetteViews(cams, masks, F[1:])
    assert open_views.facing == 0.0 and open_views.edge_table.shape == (4, 0)
