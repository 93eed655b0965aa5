"""The compiled depth path (issue 15's frame time, rec15f) against the numpy path it replaced: the cleaned
observation (:func:`depth_observation`) and the constraints (:func:`depth_constraints`) equal
:func:`depth_observation_reference` / :func:`depth_constraints_reference` to rounding, on a distorted sensor whose
image has every case the cleaning tells apart (out of range, NaN, flying pixels, the floor, valid border pixels,
holes that cut a pixel's normal) and a template whose far pairs its own limb hides."""

import numpy as np
import pytest

from bodystudio.capture.render import render_depth
from bodystudio.geometry.camera import Camera
from bodystudio.geometry.mesh import vertex_normals
from bodystudio.reconstruct.depth import (
    depth_constraints,
    depth_constraints_reference,
    depth_observation,
    depth_observation_reference,
    normalised_pixel_grid,
)


@pytest.fixture(scope="module")
def scene():
    """A torso sphere (r 0.30 m, the body 0.35 m) and a limb sphere in front of it, over a floor plane and before a
    wall the sensor sees too, from a distorted 160x120 sensor looking slightly down."""
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=4, radius=1.0)
    S, Fs = np.asarray(m.vertices, float), np.asarray(m.faces, np.int64)
    centre, limb_c = np.array([0.0, 0.45, 0.0]), np.array([0.05, 0.5, 0.40])
    V = np.vstack([S * 0.30 + centre, S * 0.06 + limb_c])
    F = np.vstack([Fs, Fs + len(S)])
    V_gt = np.vstack([S * 0.35 + centre, S * 0.06 + limb_c])
    cam = Camera.look_at("depth", (0.0, 0.9, 2.2), (0.0, 0.4, 0.0), fx=120.0, width=160, height=120,
                         dist=(0.09, -0.27, 0.001, -0.002, 0.09))
    D = render_depth(V_gt, F, cam).astype(np.float64)
    # the floor (y = 0) behind the body: a plane's depth per pixel, where the body does not cover it
    xy = normalised_pixel_grid(cam)
    rays = np.concatenate([xy, np.ones(xy.shape[:2] + (1,))], axis=2) @ cam.R  # world directions per pixel
    s = -cam.center[1] / np.where(rays[..., 1] < -1e-9, rays[..., 1], np.nan)  # ray parameter at y = 0
    floor_z = s * (rays @ cam.R[2])  # camera z of the floor point
    background = np.fmin(np.where(floor_z > 0, floor_z, np.nan), 3.0)  # the floor, else a wall 3 m away
    D = np.where(D == 0, background, D)
    D[5:15, 100:130] = 7.0  # beyond the range
    D[40:43, 60:64] = np.nan
    D[70, 80] -= 0.2  # flying pixels
    D[55, 75] += 0.1
    D[0, :] = D[1, :] + 0.001  # a valid border row: the median's reflected edge counts
    D[:, 0] = 1.9
    D[90:92, 10:14] = 0.0  # a hole
    return V, F, cam, D


def test_the_observation_equals_the_numpy_one(scene):
    V, F, cam, D = scene
    ref, new = depth_observation_reference(D, cam), depth_observation(D, cam)
    assert ref.n_points > 5000 and ref.valid[1].sum() > 50  # the cases are there; row 1 needs row 0 valid
    assert not ref.valid[70, 80] and not ref.valid[41, 61]
    np.testing.assert_array_equal(new.valid, ref.valid)
    np.testing.assert_array_equal(new.depth_m, ref.depth_m)
    np.testing.assert_allclose(new.points, ref.points, rtol=0, atol=1e-12)  # the floor's points are kept too
    np.testing.assert_allclose(new.normals, ref.normals, rtol=0, atol=1e-9)
    assert new.camera is cam


def test_the_floor_and_the_border_decide_as_the_numpy_one(scene):
    """Cases a shortcut would get wrong one by one: the floor drops pixels the range and median keep, and the
    border pixels' medians see their reflected edge."""
    V, F, cam, D = scene
    # the floor test removes pixels here (the plane behind the body), and border pixels stay valid
    assert (depth_observation_reference(D, cam, floor_m=-10.0).valid & ~depth_observation_reference(D, cam).valid
            ).sum() > 100
    assert depth_observation_reference(D, cam).valid[1:-1, 1].sum() > 20
    for floor_m in (-10.0, 0.015, 0.3):
        np.testing.assert_array_equal(depth_observation(D, cam, floor_m=floor_m).valid,
                                      depth_observation_reference(D, cam, floor_m=floor_m).valid)
    for rng in ((0.4, 5.0), (1.5, 3.0)):
        np.testing.assert_array_equal(depth_observation(D, cam, rng).valid,
                                      depth_observation_reference(D, cam, rng).valid)


@pytest.mark.parametrize("reach", [False, True])
def test_the_constraints_equal_the_numpy_ones(scene, reach):
    """The same pairs in the same order, the same targets, normals and weights, with the depth reach's far pairs
    (the template's own raster hides the torso behind its limb) and without."""
    V, F, cam, D = scene
    obs = depth_observation(D, cam)
    rng = np.random.default_rng(3)
    for shift in (0.0, 0.03, 0.07):  # the template nearer, then further from the body than the near pairing
        Vs = V + rng.normal(0.0, 0.004, V.shape) - shift * (V - [0.0, 0.45, 0.0])
        N = vertex_normals(Vs, F)
        kw = dict(F=F, reach_m=0.10, reach_sigma_m=0.05) if reach else {}
        ref, new = depth_constraints_reference(Vs, N, obs, **kw), depth_constraints(Vs, N, obs, **kw)
        assert len(ref) > 100
        np.testing.assert_array_equal(new.vertex, ref.vertex)
        np.testing.assert_array_equal(new.point, ref.point)
        np.testing.assert_array_equal(new.normal, ref.normal)
        np.testing.assert_allclose(new.k, ref.k, rtol=1e-12, atol=0)
    if reach:  # the far pairs were exercised, the hidden ones dropped
        far = depth_constraints_reference(Vs, N, obs, F=F, reach_m=0.10)
        near = depth_constraints_reference(Vs, N, obs)
        assert len(far) > len(near) + 50
        behind = ((np.hypot(Vs[:, 0] - 0.05, Vs[:, 1] - 0.5) < 0.03) & (Vs[:, 2] > 0.2)
                  & (np.arange(len(V)) < len(V) // 2))
        assert behind.any() and not np.isin(np.flatnonzero(behind), new.vertex).any()


def test_the_pixel_grid_is_the_cameras_undistortion():
    cam = Camera.look_at("d", (0.0, 1.0, 2.0), (0.0, 1.0, 0.0), fx=100.0, width=40, height=30,
                         dist=(0.1, -0.2, 0.0, 0.0, 0.05))
    grid = normalised_pixel_grid(cam)
    uv = np.array([[0.0, 0.0], [39.0, 29.0], [17.0, 11.0]])
    np.testing.assert_allclose(grid[uv[:, 1].astype(int), uv[:, 0].astype(int)],
                               cam.undistort_points(uv, normalized=True), rtol=0, atol=1e-12)
    assert normalised_pixel_grid(cam) is grid  # cached
    other = Camera.look_at("d", (0.0, 1.0, 2.0), (0.0, 1.0, 0.0), fx=101.0, width=40, height=30)
    assert not np.allclose(normalised_pixel_grid(other), grid)


def test_the_culled_raster_is_the_full_one_at_its_pixels(scene):
    """The far pairs' visibility reads the template's depth raster drawn only where their pixels' tiles are: the
    same z-buffer values as the full render there (scattered pixels, tile corners, the image border)."""
    from bodystudio.capture.render import depth_buffer, project_vertices
    from bodystudio.reconstruct.depth import _model_depth_at

    V, F, cam, D = scene
    uv, z = project_vertices(V, cam)
    full = render_depth(V, F, cam)
    whole = depth_buffer(uv, z, F, cam.width, cam.height)  # the renderer's z-buffer, empty pixels inf
    np.testing.assert_array_equal(np.where(np.isinf(whole), 0, whole), full)
    rng = np.random.default_rng(0)
    pixels = np.c_[rng.integers(0, cam.height, 40), rng.integers(0, cam.width, 40)]
    covered = np.argwhere(full > 0)
    pixels = np.r_[pixels, covered[rng.choice(len(covered), 40, replace=False)], [[0, 0], [119, 159], [63, 71],
                                                                                  [64, 72], [7, 8]]]
    np.testing.assert_array_equal(_model_depth_at(F, cam, uv, z, pixels), full[pixels[:, 0], pixels[:, 1]])
    one = covered[len(covered) // 2][None]
    np.testing.assert_array_equal(_model_depth_at(F, cam, uv, z, one), full[one[:, 0], one[:, 1]])
    # the buffer cleared only on flagged tiles (rec15i): every pixel of those tiles as the whole buffer's, with
    # tiles of 7 px that the image's edges clip, empty and covered ones
    tiles = np.zeros(((cam.height + 6) // 7, (cam.width + 6) // 7), bool)
    tiles[::3, ::2] = True
    tiles[-1, -1] = True
    part = depth_buffer(uv, z, F, cam.width, cam.height, tiles, 7)
    flagged = np.kron(tiles, np.ones((7, 7), bool))[:cam.height, :cam.width]
    assert flagged[-1, -1] and (np.isinf(whole) & flagged).any() and (np.isfinite(whole) & flagged).sum() > 100
    np.testing.assert_array_equal(part[flagged], whole[flagged])


def test_the_observation_is_the_same_on_two_threads(scene):
    """The rows run in ``prange``: the same arrays on one and two numba threads."""
    import numba

    V, F, cam, D = scene
    before = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        one = depth_observation(D, cam)
        numba.set_num_threads(min(2, numba.config.NUMBA_NUM_THREADS))
        two = depth_observation(D, cam)
    finally:
        numba.set_num_threads(before)
    for a, b in ((one.points, two.points), (one.normals, two.normals), (one.depth_m, two.depth_m),
                 (one.valid, two.valid)):
        np.testing.assert_array_equal(a, b)


def test_the_triangle_cull_from_vertex_boxes_is_the_per_triangle_one(scene):
    """``_faces_touching`` (each vertex's ceil / floor once, rec15k) keeps the triangles of the per-triangle loop
    before it: views with the mesh partly off the image, vertices behind the camera (NaN) or at infinity, tiles
    flagged at random, on the border and none."""
    from bodystudio.capture.render import project_vertices
    from bodystudio.reconstruct.depth import _TILE, _faces_touching, _faces_touching_reference

    V, F, cam, _ = scene
    uv, _ = project_vertices(V, cam)
    uv = np.ascontiguousarray(uv)
    rng = np.random.default_rng(3)
    th, tw = (cam.height + _TILE - 1) // _TILE, (cam.width + _TILE - 1) // _TILE
    cases = [uv, uv * 1.7 - 40.0, uv.copy(), uv.copy()]
    cases[2][::9] = np.nan
    cases[3][::13, 0] = np.inf
    for points in cases:
        for need in (rng.random((th, tw)) < 0.2, np.zeros((th, tw), bool), np.pad(np.zeros((th - 2, tw - 2), bool), 1,
                                                                                   constant_values=True)):
            got = _faces_touching(points, F, cam.width, cam.height, need)
            ref = _faces_touching_reference(points, F, cam.width, cam.height, need)
            np.testing.assert_array_equal(got, ref)
    assert 0 < _faces_touching(cases[2], F, cam.width, cam.height, np.ones((th, tw), bool)).sum() < \
        _faces_touching(uv, F, cam.width, cam.height, np.ones((th, tw), bool)).sum()
