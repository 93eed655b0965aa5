"""Mutation tests of mus11t's outline pairs (``refine.outline_pairs``, ``DepthOutline.pairs``, ``weighted_pairs``;
docs/mutation/muscle-refine.md, "mus11t's outline pairs"): every pair against a per-vertex reference written from the
docstring (Eq. 6-7 of Rapid Skin as a search along the normal's image direction), on the noise-free tube of
``test_refine_depth_bias`` lying along x and along y (contours searched down the rows and along the columns), whole
and cropped so that the search runs off each border of the image, at several settings; the empty returns' shapes,
the unit directions, a single candidate, and a frame without an ``outline`` attribute. ~2 s."""

from __future__ import annotations

import functools
import inspect
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from bodystudio.geometry.mesh import vertex_normals
from bodystudio.muscle.refine import DepthOutline, outline_pairs, weighted_pairs
from tests.muscle.test_refine_depth_bias import CENTRE, tube


@functools.cache
def _tube_scene(axis: str):
    """The tube (256 around) along ``axis`` 1 m in front of a Kinect v2, its noise-free depth; a coarse tube."""
    from bodystudio.capture.kinect import simulate_kinect_depth
    from bodystudio.geometry.camera import kinect_v2

    turn = np.eye(3) if axis == "x" else np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    Vf, Ff = tube(n_around=256)
    sensor = kinect_v2(eye=(0.0, 1.0, 1.0), target=(0.0, 1.0, 0.0))
    depth = simulate_kinect_depth((Vf - CENTRE) @ turn.T + CENTRE, Ff, sensor, np.random.default_rng(0), noise=False)
    V, F = tube(radius=0.041)
    V = (V - CENTRE) @ turn.T + CENTRE
    return sensor.depth, depth, V, vertex_normals(V, F)


def _cropped(camera, depth, rows, cols):
    """The depth map's window ``rows`` x ``cols`` and the camera of that window (principal point moved)."""
    K = np.array(camera.K)
    K[0, 2] -= cols.start
    K[1, 2] -= rows.start
    cam = replace(camera, K=K, width=cols.stop - cols.start, height=rows.stop - rows.start)
    return cam, depth[rows, cols]


def _reference(V, N, depth, camera, candidates, max_facing_cos=0.3, search_px=6.0, step_px=0.25, jump_m=0.03,
               near_m=0.5, far_m=1.3):
    """One vertex at a time, from the docstring."""
    H, W = depth.shape
    ks, qs, ns = [], [], []
    steps = [-search_px + i * step_px for i in range(int(round(2 * search_px / step_px)) + 1)]
    c = len(steps) // 2
    for i in np.flatnonzero(candidates):
        v, n = V[i], N[i]
        ray = (v - camera.center) / np.linalg.norm(v - camera.center)
        z = camera.world_to_camera(v[None])[0, 2]
        if not (abs(float(n @ ray)) < max_facing_cos and z > 0.1):
            continue
        p = n - (n @ ray) * ray
        p = p / np.linalg.norm(p)
        uv = camera.project(v[None])[0]
        m = camera.project((v + 1e-3 * p)[None])[0] - uv
        m = m / np.linalg.norm(m)
        near = []
        for s in steps:
            col, row = int(np.rint(uv[0] + s * m[0])), int(np.rint(uv[1] + s * m[1]))
            d = depth[row, col] if 0 <= col < W and 0 <= row < H else 0.0
            near.append(bool(np.isfinite(d) and near_m <= d <= far_m and d < z + jump_m))
        if near[c]:
            e = next((j for j in range(c, len(steps)) if not near[j]), None)
        else:
            e = next((j + 1 for j in range(c, -1, -1) if near[j]), None)
        if e is None or e == 0:
            continue
        row_in, col_in = (int(np.rint(uv[1] + steps[e - 1] * m[1])), int(np.rint(uv[0] + steps[e - 1] * m[0])))
        d_in = depth[row_in, col_in] if 0 <= col_in < W and 0 <= row_in < H else 0.0
        if not abs(d_in - z) < jump_m:
            continue
        e_m = (steps[e] - 0.5 * step_px) * z / camera.fx
        ks.append(i)
        qs.append(v + e_m * p)
        ns.append(p)
    return np.array(ks, np.int64), np.array(qs).reshape(-1, 3), np.array(ns).reshape(-1, 3)


def _check(V, N, depth, camera, cand, **kw):
    k, q, n = outline_pairs(V, N, depth, camera, cand, **kw)
    kr, qr, nr = _reference(V, N, depth, camera, cand, **kw)
    np.testing.assert_array_equal(k, kr)
    np.testing.assert_allclose(q, qr, atol=1e-9)
    np.testing.assert_allclose(n, nr, atol=1e-9)
    assert q.shape == n.shape == (len(k), 3) and k.dtype == np.int64
    if len(k):
        np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-12)  # unit directions
    return k, q, n


@pytest.mark.parametrize("axis", ["x", "y"])
@pytest.mark.parametrize("kw", [{}, {"search_px": 3.0, "step_px": 0.5}, {"jump_m": 0.01, "max_facing_cos": 0.5},
                                {"near_m": 0.97, "far_m": 1.0}, {"step_px": 1.0, "search_px": 8.0}])
def test_every_pair_is_the_references(axis, kw):
    camera, depth, V, N = _tube_scene(axis)
    k, _, _ = _check(V, N, depth, camera, np.ones(len(V), bool), **kw)
    assert len(k) > (0 if kw.get("near_m") else 20)


@pytest.mark.parametrize("axis", ["x", "y"])
@pytest.mark.parametrize("side", ["low", "high"])
def test_a_search_off_the_image_border_reads_no_depth(axis, side):
    """The window ends 2 px beyond the tube's contour on one side: the search from those rim vertices runs off it."""
    camera, depth, V, N = _tube_scene(axis)
    rows_fg, cols_fg = np.nonzero(depth > 0)
    lo, hi = (rows_fg.min(), rows_fg.max()) if axis == "x" else (cols_fg.min(), cols_fg.max())
    span = slice(lo - 2, depth.shape[0 if axis == "x" else 1]) if side == "low" else slice(0, hi + 3)
    full = slice(0, depth.shape[1 if axis == "x" else 0])
    cam, win = _cropped(camera, depth, *((span, full) if axis == "x" else (full, span)))
    k, _, _ = _check(V, N, win, cam, np.ones(len(V), bool))
    k_full, _, _ = outline_pairs(V, N, depth, camera, np.ones(len(V), bool))
    assert 0 < len(k) <= len(k_full)
    # a window whose border is the contour itself: the pixels beyond it read as no depth, not as the edge's own
    span0 = slice(lo, depth.shape[0 if axis == "x" else 1]) if side == "low" else slice(0, hi + 1)
    cam, win = _cropped(camera, depth, *((span0, full) if axis == "x" else (full, span0)))
    _check(V, N, win, cam, np.ones(len(V), bool))


def test_the_empty_returns_have_their_shapes_and_a_single_candidate_is_paired():
    camera, depth, V, N = _tube_scene("x")
    for kw in ({"max_facing_cos": 1e-9}, {"far_m": 0.6}):  # no vertex edge-on / no contour found
        k, q, n = outline_pairs(V, N, depth, camera, np.ones(len(V), bool), **kw)
        assert k.shape == (0,) and q.shape == (0, 3) and n.shape == (0, 3), kw
    k_all, q_all, _ = outline_pairs(V, N, depth, camera, np.ones(len(V), bool))
    one = np.zeros(len(V), bool)
    one[k_all[0]] = True
    k, q, _ = _check(V, N, depth, camera, one)
    np.testing.assert_array_equal(k, k_all[:1])
    np.testing.assert_array_equal(q, q_all[:1])


def test_the_defaults_are_the_documented_ones():
    """A contour 6-7 px outside a thin tube is beyond the default 6 px search; the tube 1.5 times as far (beyond 1.3 m)
    is beyond the default far limit (the defaults called, not read: mutmut keeps the wrapper's signature)."""
    camera, depth, _, _ = _tube_scene("x")
    V, F = tube(radius=0.0239)
    N = vertex_normals(V, F)
    cand = np.ones(len(V), bool)
    k6 = outline_pairs(V, N, depth, camera, cand, search_px=6.0)[0]
    assert len(outline_pairs(V, N, depth, camera, cand, search_px=7.0)[0]) > len(k6)
    np.testing.assert_array_equal(outline_pairs(V, N, depth, camera, cand)[0], k6)
    _, _, V, N = _tube_scene("x")  # the scene 1.5 times as far from the sensor: the same image, depth 1.44-1.5 m
    V = camera.center + 1.5 * (V - camera.center)
    assert len(outline_pairs(V, N, 1.5 * depth, camera, cand, far_m=2.3)[0]) > 0
    assert len(outline_pairs(V, N, 1.5 * depth, camera, cand)[0]) == 0
    p = inspect.signature(outline_pairs).parameters
    assert {n: p[n].default for n in ("max_facing_cos", "search_px", "step_px", "jump_m", "near_m", "far_m")} == {
        "max_facing_cos": 0.3, "search_px": 6.0, "step_px": 0.25, "jump_m": 0.03, "near_m": 0.5, "far_m": 1.3}


def test_the_depth_outline_passes_its_depth_range():
    camera, depth, V, N = _tube_scene("x")
    S = (1.0, np.eye(3), np.zeros(3))
    cand = np.ones(len(V), bool)
    for near_m, far_m in ((0.97, 1.0), (0.5, 0.99), (0.99, 1.3)):
        k, q, n = DepthOutline(depth, camera, S, 1.0, cand, 0.0, near_m, far_m).pairs(V, N)
        kr, qr, nr = outline_pairs(V, N, depth, camera, cand, near_m=near_m, far_m=far_m)
        np.testing.assert_array_equal(k, kr)
        np.testing.assert_allclose(q, qr, atol=1e-12)


def test_weighted_pairs_of_a_frame_without_an_outline_attribute():
    idx, q, n = np.array([3, 5]), np.ones((2, 3)), np.zeros((2, 3))
    frame = SimpleNamespace(plane_pairs=lambda vertices: (idx, q, n))
    k, qq, nn, w = weighted_pairs(frame, np.zeros((8, 3)))
    np.testing.assert_array_equal(k, idx)
    np.testing.assert_array_equal(w, [1.0, 1.0])


def test_contours_at_the_end_of_the_search_are_the_references():
    """Thin tubes whose contours lie 5-7 px outside their rims and wide ones whose contours lie 5-7 px inside: the
    search's first and last steps (6 px) decide."""
    camera, depth, _, _ = _tube_scene("x")
    cand = None
    far_px = []
    for r in (0.0245, 0.025, 0.0255, 0.026, 0.0265, 0.0535, 0.054, 0.0545, 0.055, 0.0555):
        V, F = tube(radius=r)
        N = vertex_normals(V, F)
        cand = np.ones(len(V), bool)
        k, q, n = _check(V, N, depth, camera, cand)
        z = camera.world_to_camera(V[k])[:, 2]
        far_px += list(np.einsum("kd,kd->k", q - V[k], n) * camera.fx / z)
    assert max(far_px) > 5.7 and min(far_px) < -5.7, (max(far_px), min(far_px))


@pytest.mark.parametrize("weight", [None, 0.5])
def test_the_capture_attaches_the_outlines_at_the_default_weight_and_below_one(weight):
    """``with_outlines`` at the capture's default (weight 1: on since the sixteenth pass) and at 0.5."""
    from bodystudio.muscle import capture as cm
    from bodystudio.muscle.refine import DepthFrame

    camera, depth, V, _ = _tube_scene("x")
    frames = [DepthFrame(np.zeros((1, 3)), np.zeros((1, 3)), None, camera.center, None, None, None, None)]
    o = cm.CaptureOptions() if weight is None else cm.CaptureOptions(body_rest_outline_weight=weight)
    out = cm.with_outlines(frames, [depth], camera, (1.0, np.eye(3), np.zeros(3)), SimpleNamespace(arm_mask=None), o)
    assert out[0].outline is not None and out[0].outline.weight == (1.0 if weight is None else weight)
