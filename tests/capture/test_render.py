"""Rasteriser: exact plane depth, analytic sphere silhouette, watertight shared edges, buffer agreement."""

import cv2
import numpy as np
import pytest
import trimesh

from bodystudio.capture.render import background_plate, render, render_rgb
from bodystudio.errors import InputError
from bodystudio.geometry.camera import Camera, ring_rig

DIST = (-0.12, 0.04, 0.001, -0.0008, 0.0)


def _plane_quad(p0, normal, half_size):
    """A square (V, F) of side 2 * half_size centred at p0 with unit normal ``normal``."""
    n = np.asarray(normal, float) / np.linalg.norm(normal)
    a = np.cross(n, [0.0, 1.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(n, a)
    V = np.array([p0 + half_size * (sa * a + sb * b) for sa, sb in [(-1, -1), (1, -1), (1, 1), (-1, 1)]])
    return V, np.array([[0, 1, 2], [0, 2, 3]])


def _front_camera(dist=None, width=160, height=120, fx=150.0):
    return Camera.look_at("c", eye=(0.0, 0.0, 0.0), target=(0.0, 0.0, -1.0), fx=fx, width=width, height=height,
                          dist=dist)


def test_tilted_plane_depth_is_exact():
    cam = _front_camera()
    # plane through (0, 0, -2) with normal n; big quad covering the image
    n = np.array([0.3, -0.2, 1.0]) / np.linalg.norm([0.3, -0.2, 1.0])
    p0 = np.array([0.0, 0.0, -2.0])
    V, F = _plane_quad(p0, n, 3.0)
    res = render(V, F, cam)
    assert res.mask.all()
    rows, cols = np.nonzero(res.mask)
    origins, dirs = cam.rays(np.stack([cols, rows], 1).astype(float))
    s = ((p0 - origins) @ n) / (dirs @ n)
    z_true = cam.world_to_camera(origins + s[:, None] * dirs)[:, 2]
    np.testing.assert_allclose(res.depth[rows, cols], z_true, rtol=2e-6)
    # fronto-parallel plane: constant depth
    V2 = np.array([[-5, -5, -1.5], [5, -5, -1.5], [5, 5, -1.5], [-5, 5, -1.5]], float)
    res2 = render(V2, F, cam)
    assert res2.mask.all() and np.all(res2.depth == np.float32(1.5))


@pytest.mark.parametrize("dist", [None, DIST])
@pytest.mark.parametrize("center", [(0.0, 0.0, -2.0), (0.35, -0.2, -1.8)])
def test_sphere_silhouette_matches_analytic_disk(dist, center):
    cam = _front_camera(dist, width=200, height=160, fx=180.0)
    sphere = trimesh.creation.icosphere(subdivisions=5, radius=0.3)
    c = np.asarray(center)
    res = render(sphere.vertices + c, sphere.faces, cam)
    # analytic silhouette: rays whose angle to the centre direction is below asin(r / |c|)
    cols, rows = np.meshgrid(np.arange(cam.width), np.arange(cam.height))
    _, dirs = cam.rays(np.stack([cols.ravel(), rows.ravel()], 1).astype(float))
    inside = (dirs @ (c / np.linalg.norm(c))) > np.cos(np.arcsin(0.3 / np.linalg.norm(c)))
    disk = inside.reshape(cam.height, cam.width).astype(np.uint8)
    kernel = np.ones((3, 3), np.uint8)
    assert np.all(res.mask[cv2.erode(disk, kernel) > 0]), "pixel inside the disk (by > 1 px) not covered"
    assert not np.any(res.mask[cv2.dilate(disk, kernel) == 0]), "pixel outside the disk (by > 1 px) covered"
    assert abs(int(res.mask.sum()) - int(disk.sum())) < 0.01 * disk.sum()


def test_shared_edges_are_watertight_and_drawn_once():
    # K = I, R = I, t = 0 and depth 1: vertex (u, v, 1) projects exactly to pixel (u, v), so the grid
    # vertices sit exactly on pixel centres and many pixels lie exactly on shared edges
    cam = Camera("c", np.eye(3), np.zeros(5), np.eye(3), np.zeros(3), 64, 48)
    n = 8
    us, vs = np.meshgrid(np.linspace(2, 58, n), np.linspace(2, 44, n))  # spacing 8 x 6 px
    uv = np.stack([us.ravel(), vs.ravel()], 1)
    rng = np.random.default_rng(0)
    interior = ((uv[:, 0] > 2) & (uv[:, 0] < 58) & (uv[:, 1] > 2) & (uv[:, 1] < 44))
    uv[interior] += rng.integers(-1, 2, (interior.sum(), 2))  # small enough not to fold the grid
    V = np.c_[uv, np.ones(len(uv))]
    assert np.array_equal(cam.project(V), uv)
    F = []
    for i in range(n - 1):
        for j in range(n - 1):
            a, b, c, d = i * n + j, i * n + j + 1, (i + 1) * n + j + 1, (i + 1) * n + j
            F += [[a, b, c], [a, c, d]] if (i + j) % 2 else [[a, b, d], [b, c, d]]
    F = np.array(F)
    full = render(V, F, cam).mask
    rr, cc = np.mgrid[0:48, 0:64]
    assert full[(rr > 2) & (rr < 44) & (cc > 2) & (cc < 58)].all(), "crack inside a watertight grid"
    # split the triangles in two sets: their masks partition the full mask (no pixel drawn twice)
    half = rng.random(len(F)) < 0.5
    m1, m2 = render(V, F[half], cam).mask, render(V, F[~half], cam).mask
    assert not np.any(m1 & m2)
    assert np.array_equal(m1 | m2, full)


def test_buffers_agree_on_a_body(body_2k):
    cam = ring_rig(10)[1]
    V, F = body_2k.vertices, body_2k.faces
    res = render(V, F, cam)
    assert res.mask.sum() > 1000
    assert np.array_equal(res.mask, res.depth > 0) and np.array_equal(res.mask, res.triangle_id >= 0)
    np.testing.assert_allclose(res.barycentric[res.mask].sum(1), 1.0, atol=1e-5)
    assert res.barycentric[res.mask].min() >= -1e-6
    P, rc = res.surface_points(V, F)
    uv, z = cam.project_with_depth(P)
    np.testing.assert_allclose(z, res.depth[rc[:, 0], rc[:, 1]], rtol=1e-5)
    # linear rasterisation in the distorted image: surface points land on their pixel within 0.05 px
    assert np.abs(uv - rc[:, ::-1]).max() < 0.05
    # a second render is identical (deterministic z-buffer)
    res2 = render(V, F, cam)
    assert np.array_equal(res2.triangle_id, res.triangle_id) and np.array_equal(res2.depth, res.depth)


def test_render_rgb_composites_over_background_plate(body_2k):
    rig = ring_rig(3, width=160, height=120)
    bg = background_plate(rig[0], seed=3)
    assert bg.shape == (120, 160, 3) and bg.dtype == np.uint8
    assert np.array_equal(bg, background_plate(rig[0], seed=3))
    scribbled = background_plate(rig[0], seed=3)
    scribbled[:] = 0  # callers own their copy; the cache is unaffected
    assert np.array_equal(bg, background_plate(rig[0], seed=3))
    assert not np.array_equal(bg, background_plate(rig[0], seed=4))
    assert not np.array_equal(bg, background_plate(rig[1], seed=3))
    assert bg.std() > 10  # textured, not flat
    V, F = body_2k.vertices, body_2k.faces
    img = render_rgb(V, F, rig[0], background=bg)
    mask = render(V, F, rig[0]).mask
    assert np.array_equal(img[~mask], bg[~mask])
    diff = np.abs(img.astype(int) - bg.astype(int)).sum(2)
    assert (diff[mask] > 30).mean() > 0.9  # the body stands out from the studio
    skin = img[mask].astype(float)
    assert np.all(skin[:, 0] >= skin[:, 2])  # skin is reddish
    with pytest.raises(InputError):
        render_rgb(V, F, rig[0], background=np.zeros((10, 10, 3), np.uint8))
    with pytest.raises(InputError):
        render(V, F + len(V), rig[0])


def test_flat_plane_colour_is_lambert():
    from bodystudio.capture.render import SKIN_COLOR, lambert_shading
    cam = _front_camera()
    n = np.array([0.2, 0.5, 1.0]) / np.linalg.norm([0.2, 0.5, 1.0])  # plane normal, towards the camera side
    V, F = _plane_quad(np.array([0.0, 0.0, -2.0]), n, 3.0)
    img = render_rgb(V, F, cam)
    expected = np.round(np.clip(np.array(SKIN_COLOR) * lambert_shading(n[None])[0], 0, 1) * 255)
    assert np.abs(img.reshape(-1, 3).astype(float) - expected).max() <= 1
    colours = np.tile([[0.2, 0.4, 0.9]], (4, 1))
    img2 = render_rgb(V, F, cam, vertex_colors=colours)
    expected2 = np.round(np.clip(colours[0] * lambert_shading(n[None])[0], 0, 1) * 255)
    assert np.abs(img2.reshape(-1, 3).astype(float) - expected2).max() <= 1


def test_vectorised_projection_is_the_per_vertex_loop_bit_for_bit():
    """``_project`` (flat, branch-free: issue 15's frame time, rec15k) against the per-vertex loop it replaced, with
    and without distortion, a skewed K, vertices behind the camera, at z = 0 and NaN."""
    from bodystudio.capture.render import _project, _project_reference

    rng = np.random.default_rng(0)
    R, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    t = np.array([0.1, -0.2, 2.5])
    K = np.array([[520.0, 0.3, 320.0], [0.0, 515.0, 240.0], [0.0, 0.0, 1.0]])
    V = rng.normal(0.0, 3.0, (2000, 3))
    V[0] = R.T @ (np.array([0.3, 0.2, 0.0]) - t)  # z = 0 in the camera
    V[1, 2] = np.nan
    V = np.ascontiguousarray(V)
    for dist in (np.zeros(5), np.array([-0.2, 0.05, 0.001, -0.002, 0.01])):
        uv, z, uv_ref, z_ref = np.empty((len(V), 2)), np.empty(len(V)), np.empty((len(V), 2)), np.empty(len(V))
        _project(V, R, t, K, dist, uv, z)
        _project_reference(V, R, t, K, dist, uv_ref, z_ref)
        assert 100 < np.isnan(uv[:, 0]).sum() < 1900 and np.isnan(uv[1]).all()
        np.testing.assert_array_equal(uv, uv_ref)
        np.testing.assert_array_equal(z, z_ref)
