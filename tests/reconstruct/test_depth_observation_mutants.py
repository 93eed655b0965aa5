"""The depth observation against a per-pixel loop written from its docstring (issue 17, mutation testing of
reconstruct/depth.py's ``depth_observation``, its numpy reference, the pixel grid, ``_model_depth_at`` and
``depth_constraints_reference``).

The loop: range open at both ends (NaN out), the 3x3 median of the in-range depth with out-of-range pixels as 0 and
the border pixel repeated (scipy's "reflect"), flying pixels at ``>= FLYING_PIXEL_M`` from it, the pinhole
unprojection ``R^T ((u - cx) / fx d, (v - cy) / fy d, d) - t)`` (OpenCV's ``undistortPoints`` where the lens
distorts), the floor below ``floor_m``, normals as the cross product of the central differences turned towards the
sensor where the pixel and its four neighbours are valid. The compiled path and the numpy reference are each compared
with it; ``depth_constraints_reference`` runs the analytic cases of ``test_depth_reach_analytic.py``. < 2 s.
"""

import importlib.util
from functools import cache
from pathlib import Path

import cv2
import numpy as np
import pytest

from bodystudio.errors import InputError
from bodystudio.geometry.camera import Camera
from bodystudio.reconstruct import depth as depth_mod
from bodystudio.reconstruct.depth import (
    FLOOR_M,
    FLYING_PIXEL_M,
    depth_constraints_reference,
    depth_observation,
    depth_observation_reference,
    normalised_pixel_grid,
)

OBSERVE = [depth_observation, depth_observation_reference]


def _camera(dist=None, name="d"):
    """A 23x17 sensor (fx != fy, an off-centre principal point) 2 m in front of the origin, looking slightly down."""
    cam = Camera.look_at(name, (0.3, 0.9, 2.0), (0.1, 0.5, 0.0), fx=20.0, fy=22.0, cx=10.3, cy=8.6, width=23,
                         height=17, dist=dist)
    return cam


def _normalised(cam):
    """(H, W, 2) normalised coordinates of every pixel centre: the pinhole inverse, or OpenCV's undistortion."""
    rows, cols = np.mgrid[0:cam.height, 0:cam.width]
    uv = np.c_[cols.ravel(), rows.ravel()].astype(np.float64)
    if np.any(cam.dist):
        xy = cv2.undistortPoints(uv.reshape(-1, 1, 2), cam.K, cam.dist,
                                 criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-15)).reshape(-1, 2)
    else:
        xy = np.c_[(uv[:, 0] - cam.K[0, 2]) / cam.K[0, 0], (uv[:, 1] - cam.K[1, 2]) / cam.K[1, 1]]
    return xy.reshape(cam.height, cam.width, 2)


def _loop_observation(D, cam, lo=0.4, hi=5.0, floor_m=FLOOR_M):
    """The observation pixel by pixel, from the docstring."""
    H, W = D.shape
    xy = _normalised(cam)
    inr = np.zeros((H, W), bool)
    for r in range(H):
        for c in range(W):
            inr[r, c] = bool(np.isfinite(D[r, c]) and lo < D[r, c] < hi)
    P = np.zeros((H, W, 3))
    valid = np.zeros((H, W), bool)
    for r in range(H):
        for c in range(W):
            if not inr[r, c]:
                continue
            window = [D[min(max(r + i, 0), H - 1), min(max(c + j, 0), W - 1)]
                      if inr[min(max(r + i, 0), H - 1), min(max(c + j, 0), W - 1)] else 0.0
                      for i in (-1, 0, 1) for j in (-1, 0, 1)]
            if abs(D[r, c] - sorted(window)[4]) >= FLYING_PIXEL_M:
                continue
            d = D[r, c]
            pc = np.array([xy[r, c, 0] * d, xy[r, c, 1] * d, d])
            P[r, c] = cam.R.T @ (pc - cam.t)
            valid[r, c] = P[r, c, 1] >= floor_m
    N, ok, out = np.zeros((H, W, 3)), np.zeros((H, W), bool), np.zeros((H, W))
    for r in range(1, H - 1):
        for c in range(1, W - 1):
            if not (valid[r, c] and valid[r, c + 1] and valid[r, c - 1] and valid[r + 1, c] and valid[r - 1, c]):
                continue
            n = np.cross(P[r, c + 1] - P[r, c - 1], P[r + 1, c] - P[r - 1, c])
            if n @ (cam.center - P[r, c]) < 0:
                n = -n
            if np.linalg.norm(n) > 1e-12:
                N[r, c], ok[r, c], out[r, c] = n / np.linalg.norm(n), True, D[r, c]
    return P, N, out, ok, valid


@cache
def _depth_map():
    """A tilted wall (plane through (0, 0.6, -0.2)), a bump on it, and every case the cleaning tells apart."""
    cam = _camera()
    xy = _normalised(cam)
    rays = np.concatenate([xy, np.ones(xy.shape[:2] + (1,))], axis=2) @ cam.R  # world directions (camera z = 1)
    n, p0 = np.array([0.6, 0.2, 1.0]), np.array([0.0, 0.6, -0.2])
    D = ((p0 - cam.center) @ n) / (rays @ n)  # camera z of the plane per pixel
    D[6:9, 9:12] -= 0.02 * np.array([[0.5, 1, 0.5], [1, 1.5, 1], [0.5, 1, 0.5]])  # a bump towards the sensor
    D[3, 4] -= 0.2  # flying pixels: one in front of the wall, one behind
    D[12, 15] += 0.1
    D[10, 3] = np.nan
    D[2, 17] = np.inf
    D[14, 6] = 0.0
    D[5, 20] = 7.0  # beyond the range
    D[0, 0] = D[0, 1] + 0.001  # border pixels: the median sees the repeated edge
    D[8, 0] = 0.4  # exactly the near bound: out
    D[16, 22] = 5.0  # exactly the far bound: out
    return cam, D


def _check(obs, ref):
    P, N, out, ok, _ = ref
    np.testing.assert_array_equal(obs.valid, ok)
    np.testing.assert_array_equal(obs.depth_m, out)
    np.testing.assert_allclose(obs.normals, N, rtol=0, atol=1e-9)
    np.testing.assert_allclose(obs.points[ok], P[ok], rtol=0, atol=1e-12)
    assert obs.n_points == int(ok.sum())


@pytest.mark.parametrize("observe", OBSERVE)
def test_the_observation_is_the_per_pixel_loop(observe):
    cam, D = _depth_map()
    ref = _loop_observation(D, cam)
    obs = observe(D, cam)
    _check(obs, ref)
    assert obs.camera is cam
    ok, valid = ref[3], ref[4]
    assert 150 < ok.sum() < 23 * 17 - 60  # most of the wall; the cases cut pixels out
    assert not valid[3, 4] and not valid[12, 15] and not valid[10, 3] and not valid[2, 17] and not valid[5, 20]
    assert valid[0, 0] and valid[7, 10] and not valid[8, 0] and not valid[16, 22]
    # the normals face the sensor and are the wall's away from the bump
    n = np.array([0.6, 0.2, 1.0]) / np.linalg.norm([0.6, 0.2, 1.0])
    np.testing.assert_allclose(obs.normals[11, 10], n, atol=1e-9)
    assert not ok[14:].any() and ok[12, 5] and not ok[12, 15]  # the floor (world y below 1.5 cm) is cut


@pytest.mark.parametrize("observe", OBSERVE)
def test_range_and_floor_options(observe):
    cam, D = _depth_map()
    for lo, hi, floor_m in ((1.9, 2.3, FLOOR_M), (0.4, 5.0, 0.55), (0.4, 5.0, -1.0), (1.5, 5.0, 0.45)):
        ref = _loop_observation(D, cam, lo, hi, floor_m)
        _check(observe(D, cam, (lo, hi), floor_m=floor_m), ref)
    assert _loop_observation(D, cam, 1.9, 2.3)[3].sum() < _loop_observation(D, cam)[3].sum() - 20
    assert _loop_observation(D, cam, floor_m=0.55)[3].sum() < _loop_observation(D, cam)[3].sum() - 20


@pytest.mark.parametrize("observe", OBSERVE)
def test_a_lens_unprojects_through_opencvs_undistortion(observe):
    cam0, D = _depth_map()
    cam = Camera("d", cam0.K, (0.12, -0.25, 0.002, -0.001, 0.08), cam0.R, cam0.t, cam0.width, cam0.height)
    obs = observe(D, cam)
    P, N, out, ok, _ = _loop_observation(D, cam)
    np.testing.assert_array_equal(obs.valid, ok)
    np.testing.assert_allclose(obs.points[ok], P[ok], rtol=0, atol=1e-9)
    np.testing.assert_allclose(obs.normals, N, rtol=0, atol=1e-6)


@pytest.mark.parametrize("observe", OBSERVE)
def test_a_flat_valid_map_has_every_inner_pixel(observe):
    """A fronto-parallel wall 1.5 m away from a sensor at the origin: points (x d, y d, d), normals -z."""
    cam = Camera("f", [[10.0, 0, 3.5], [0, 12.0, 2.5], [0, 0, 1]], None, np.eye(3), np.zeros(3), 8, 6)
    D = np.full((6, 8), 1.5)
    obs = observe(D, cam, floor_m=-10.0)
    assert obs.valid[1:-1, 1:-1].all() and not obs.valid[[0, -1]].any() and not obs.valid[:, [0, -1]].any()
    v, u = np.mgrid[0:6, 0:8]
    np.testing.assert_allclose(obs.points[..., 0], (u - 3.5) / 10.0 * 1.5, atol=1e-15)
    np.testing.assert_allclose(obs.points[..., 1], (v - 2.5) / 12.0 * 1.5, atol=1e-15)
    np.testing.assert_allclose(obs.points[..., 2], 1.5, atol=1e-15)
    np.testing.assert_allclose(obs.normals[1:-1, 1:-1], np.broadcast_to([0, 0, -1.0], (4, 6, 3)), atol=1e-15)
    np.testing.assert_array_equal(obs.depth_m, np.where(obs.valid, 1.5, 0.0))
    # the default floor (1.5 cm, world y): the upper rows (y < 0 here) are floor
    obs = observe(D, cam)
    assert not obs.valid[1:3].any() and obs.valid[4, 1:-1].all()


@pytest.mark.parametrize("observe", OBSERVE)
def test_the_flying_pixel_bound_is_strict(observe):
    """``|d - median| < FLYING_PIXEL_M`` keeps a pixel: 0.5 + 0.03 vs 0.5 differs by 0.030000000000000027, just out;
    0.5 + 0.0299 in."""
    cam = Camera("f", [[10.0, 0, 3.5], [0, 12.0, 2.5], [0, 0, 1]], None, np.eye(3), np.zeros(3), 8, 6)
    D = np.full((6, 8), 0.5)
    D[2, 2], D[3, 5] = 0.5 + 0.03, 0.5 + 0.0299
    assert (0.5 + 0.03) - 0.5 >= FLYING_PIXEL_M
    obs = observe(D, cam, floor_m=-10.0)
    assert obs.valid[1:-1, 1:-1].sum() == 24 - 5  # the pixel and its four neighbours lose their normal
    assert not obs.valid[2, 2] and obs.valid[3, 5]
    assert obs.depth_m[3, 5] == 0.5 + 0.0299


def test_a_map_of_the_wrong_size_is_refused_word_for_word():
    cam = _camera()
    for observe in OBSERVE:
        with pytest.raises(InputError) as info:
            observe(np.ones((23, 17)), cam)
        assert str(info.value) == ("depth map is 17x23 but the depth camera d is 23x17; camera/session mismatch")
    assert depth_mod._checked_depth([[1, 2], [3, 4]], Camera("c", np.eye(3), None, np.eye(3), np.zeros(3), 2, 2)
                                    ).dtype == np.float64


def test_an_integer_map_is_read_as_metres():
    cam, D = _depth_map()
    Di = np.where(np.isfinite(D), np.round(D), 0).astype(np.int64)  # whole metres: 2 everywhere on the wall
    for observe in OBSERVE:
        _check(observe(Di, cam, floor_m=-10.0), _loop_observation(Di.astype(float), cam, floor_m=-10.0))


def test_an_empty_map_has_no_points():
    cam, _ = _depth_map()
    for observe in OBSERVE:
        obs = observe(np.zeros((17, 23)), cam)
        assert obs.n_points == 0 and not obs.points.any() and not obs.normals.any()


def test_the_pixel_grid_is_opencvs_and_cached_per_intrinsics():
    depth_mod._PIXEL_GRIDS.clear()
    cam = _camera((0.1, -0.2, 0.001, 0.002, 0.05))
    grid = normalised_pixel_grid(cam)
    assert grid.shape == (17, 23, 2) and grid.flags.c_contiguous and not grid.flags.writeable
    np.testing.assert_allclose(grid, _normalised(cam), rtol=0, atol=1e-10)
    assert normalised_pixel_grid(_camera((0.1, -0.2, 0.001, 0.002, 0.05), name="other")) is grid  # same intrinsics
    plain = normalised_pixel_grid(_camera())
    assert plain is not grid
    np.testing.assert_allclose(plain, _normalised(_camera()), rtol=0, atol=1e-15)
    # every part of the key: K, the lens, the size
    c = _camera()
    wider = Camera("w", c.K, None, c.R, c.t, 24, 17)
    taller = Camera("t", c.K, None, c.R, c.t, 23, 18)
    assert normalised_pixel_grid(wider).shape == (17, 24, 2) and normalised_pixel_grid(taller).shape == (18, 23, 2)
    assert len(depth_mod._PIXEL_GRIDS) == 4
    # at most 8 grids: the ninth clears the cache
    for i in range(5):
        normalised_pixel_grid(Camera(f"k{i}", c.K + [[i + 1.0, 0, 0], [0, 0, 0], [0, 0, 0]], None, c.R, c.t, 23, 17))
    assert len(depth_mod._PIXEL_GRIDS) == 1
    depth_mod._PIXEL_GRIDS.clear()


def test_the_model_depth_at_pixels_is_the_full_raster_there():
    """``_model_depth_at``: the template's z-buffer at the pixels (0 where it covers none), as render_depth's."""
    from bodystudio.capture.render import project_vertices, render_depth

    cam = Camera.look_at("m", (0.0, 0.0, 1.0), (0.0, 0.0, 0.0), fx=40.0, width=41, height=33)
    g = np.linspace(-0.3, 0.3, 7)
    X, Y = np.meshgrid(g, g)
    V = np.c_[X.ravel(), Y.ravel(), 0.05 * np.sin(3 * X.ravel()) * np.cos(2 * Y.ravel())]
    a = (np.arange(6)[:, None] * 7 + np.arange(6)[None, :]).ravel()
    F = np.r_[np.c_[a, a + 1, a + 7], np.c_[a + 1, a + 8, a + 7]].astype(np.int64)
    full = render_depth(V, F, cam)
    uv, z = project_vertices(V, cam)
    pixels = np.array([[16, 20], [0, 0], [32, 40], [5, 30], [25, 9], [16, 21]])
    own = depth_mod._model_depth_at(F, cam, uv, z, pixels)
    expected = full[pixels[:, 0], pixels[:, 1]].astype(np.float64)
    np.testing.assert_array_equal(own, expected)
    assert own[1] == 0.0 and own[0] > 0.9 and own[3] > 0.9


# --- depth_constraints_reference: the analytic cases of the compiled function -----------------------------------

@cache
def _analytic():
    path = Path(__file__).with_name("test_depth_reach_analytic.py")
    spec = importlib.util.spec_from_file_location("_depth_reach_analytic_for_reference", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize("case", ["test_near_and_far_pairs_are_gaussians_of_their_own_sigma",
                                  "test_pairing_bounds_are_strict",
                                  "test_far_pairs_need_agreeing_normals_and_the_templates_own_front",
                                  "test_no_far_candidate_needs_no_raster",
                                  "test_only_vertices_facing_the_sensor_inside_its_image_pair"])
def test_the_reference_constraints_pass_the_analytic_cases(case, monkeypatch):
    module = _analytic()
    monkeypatch.setattr(module, "depth_constraints", depth_constraints_reference)
    test = getattr(module, case)
    test(monkeypatch) if "monkeypatch" in test.__code__.co_varnames[:test.__code__.co_argcount] else test()


def test_the_reference_constraints_with_no_candidate_are_empty():
    cam, V, F, N = _analytic()._scene()
    obs = _analytic()._obs(cam, V, {})
    dep = depth_constraints_reference(V, N, obs, F=F, reach_m=0.1)
    assert len(dep) == 0
    dep = depth_constraints_reference(V, -N, obs)  # nobody faces the sensor
    assert len(dep) == 0


# --- exact bounds on a flat map -------------------------------------------------------------------------------------

def _flat_cam():
    return Camera("f", [[10.0, 0, 3.5], [0, 12.0, 2.5], [0, 0, 1]], None, np.eye(3), np.zeros(3), 8, 6)


@pytest.mark.parametrize("observe", OBSERVE)
def test_the_range_is_open_at_both_ends(observe):
    cam = _flat_cam()
    for depth, rng, inner in ((0.4, (0.4, 5.0), False), (5.0, (0.4, 5.0), False), (0.4, (0.39, 5.0), True),
                              (5.0, (0.4, 5.01), True)):
        obs = observe(np.full((6, 8), depth), cam, rng, floor_m=-10.0)
        assert obs.valid[1:-1, 1:-1].all() == inner and obs.valid[1:-1, 1:-1].any() == inner
    # one pixel exactly at a bound among in-range ones: out, though its median (its neighbours') is 1 cm away
    for depth, bound, rng in ((0.41, 0.4, (0.4, 5.0)), (4.99, 5.0, (0.4, 5.0))):
        D = np.full((6, 8), depth)
        D[3, 4] = bound
        obs = observe(D, cam, rng, floor_m=-10.0)
        assert not obs.valid[3, 4] and not obs.valid[2, 4] and obs.valid[2, 2]
        assert np.all(obs.points[3, 4] == 0.0)
        D[3, 4] = np.nextafter(bound, depth)
        assert observe(D, cam, rng, floor_m=-10.0).valid[3, 4]


@pytest.mark.parametrize("observe", OBSERVE)
def test_out_of_range_pixels_count_as_zero_in_the_median(observe):
    """Five of (3, 3)'s eight neighbours empty: its median is 0, a flying pixel, so (4, 3) below it has no normal;
    counted as anything but 0 (1 m here) it would keep it."""
    cam = _flat_cam()
    D = np.full((6, 8), 1.0)
    for r, c in ((2, 2), (2, 3), (2, 4), (3, 2), (3, 4)):
        D[r, c] = 0.0
    obs = observe(D, cam, floor_m=-10.0)
    _check(obs, _loop_observation(D, cam, floor_m=-10.0))
    assert not obs.valid[4, 3] and obs.valid[4, 5] and obs.valid[1, 6]


@pytest.mark.parametrize("observe", OBSERVE)
def test_a_pixel_exactly_the_flying_bound_off_its_median_is_dropped(observe):
    """0.155 - 0.125 == 0.03 in binary: exactly ``FLYING_PIXEL_M`` off the median, out."""
    assert 0.155 - 0.125 == FLYING_PIXEL_M
    cam = _flat_cam()
    D = np.full((6, 8), 0.125)
    D[2, 2] = 0.155
    obs = observe(D, cam, (0.1, 5.0), floor_m=-10.0)
    assert not obs.valid[2, 2] and not obs.valid[2, 3] and obs.valid[3, 3]
    D[2, 2] = np.nextafter(0.155, 0.0)
    assert observe(D, cam, (0.1, 5.0), floor_m=-10.0).valid[2, 2]


@pytest.mark.parametrize("observe", OBSERVE)
def test_a_point_exactly_at_the_floor_height_is_kept(observe):
    """Row 3 of the flat map at the floor height itself: kept (``y >= floor_m``), so row 4 below has its normal; a
    floor one ulp higher drops row 3 and row 4's normals with it."""
    cam = _flat_cam()
    D = np.full((6, 8), 1.5)
    y0 = observe(D, cam, floor_m=-10.0).points[3, 1:-1, 1]
    assert np.all(y0 == y0[0]) and y0[0] > 0
    assert observe(D, cam, floor_m=float(y0[0])).valid[4, 1:-1].all()
    assert not observe(D, cam, floor_m=float(np.nextafter(y0[0], 1.0))).valid[4].any()


@pytest.mark.parametrize("constraints", ["compiled", "reference"])
def test_a_vertex_rounding_to_column_w_or_minus_one_never_pairs(constraints):
    """Vertices whose pixel rounds to column W (u = W - 0.3) or -1 (u = -0.7) are outside the image; the pixels a
    wrapped or unchecked index would read instead ((r + 1, 0) after (r, W - 1) in memory, (r, W - 1) for -1) hold
    points 1 cm from them with agreeing normals, so reading them would pair."""
    from bodystudio.reconstruct.depth import DepthObservation, depth_constraints

    fn = depth_constraints if constraints == "compiled" else depth_constraints_reference
    cam = Camera.look_at("d", (0.0, 0.0, 0.9), (0.0, 0.0, 0.0), fx=90.0, width=101, height=81)
    W, H, r = cam.width, cam.height, 40
    V = cam.unproject(np.array([[W - 0.3, r], [-0.7, r]]), np.array([0.9, 0.9]))
    up = np.array([0.0, 0.0, 1.0])
    N = np.tile(up, (2, 1))
    P, Nq, D, valid = np.zeros((H, W, 3)), np.zeros((H, W, 3)), np.zeros((H, W)), np.zeros((H, W), bool)
    for (rr, cc), v in (((r + 1, 0), V[0]), ((r, W - 1), V[1])):
        P[rr, cc], Nq[rr, cc], D[rr, cc], valid[rr, cc] = v + 0.01 * up, up, 0.89, True
    obs = DepthObservation(cam, P, Nq, D, valid)
    assert len(fn(V, N, obs)) == 0
    # the same points one pixel inside pair: the readings above are what an off-by-one would see
    V_in = cam.unproject(np.array([[W - 0.7, r + 1], [0.3, r]]), np.array([0.9, 0.9]))
    P2 = P.copy()
    P2[r + 1, W - 1], Nq[r + 1, W - 1], D[r + 1, W - 1], valid[r + 1, W - 1] = V_in[0] + 0.01 * up, up, 0.89, True
    P2[r, 0], Nq[r, 0], D[r, 0], valid[r, 0] = V_in[1] + 0.01 * up, up, 0.89, True
    assert fn(V_in, N, DepthObservation(cam, P2, Nq, D, valid)).vertex.tolist() == [0, 1]
