"""Mutation tests of mir12t's lens rule (``distortion_monotonic_radius``, the cached root finder, ``_drop_folded``):
the radius against the polynomial's roots written by hand, and the numba kernel called directly against a numpy
reference on rotated, translated cameras (docs/mutation/capture-render.md, "mir12t's folded triangles")."""

import numpy as np
import pytest

from bodystudio.capture.render import _drop_folded, project_vertices
from bodystudio.geometry.camera import Camera, _radial_monotonic_radius, distortion_monotonic_radius


def test_the_smallest_positive_root_of_the_cubic_in_r_squared():
    # 1 + 3 k1 u + 5 k2 u^2 + 7 k3 u^3 = (1 - u)(1 - u / 2)(1 + u / 4): positive roots u = 1 and 2, the first wins
    c = np.polynomial.polynomial.polyfromroots([1.0, 2.0, -4.0])
    c = c / c[0]
    k1, k2, k3 = c[1] / 3.0, c[2] / 5.0, c[3] / 7.0
    assert distortion_monotonic_radius((k1, k2, 0.0, 0.0, k3)) == pytest.approx(1.0, rel=1e-12)
    # k3 alone: 1 + 7 k3 u^3 = 0
    assert distortion_monotonic_radius((0.0, 0.0, 0.0, 0.0, -0.05)) == pytest.approx((1.0 / 0.35) ** (1 / 6),
                                                                                        rel=1e-12)
    # the tangential p1 p2 do not enter; OpenCV's longer vectors (k4 k5 k6 ...) are read for their k1 k2 p1 p2 k3
    assert distortion_monotonic_radius((0.02, -0.03, 0.3, -0.2, 0.0)) == distortion_monotonic_radius(
        (0.02, -0.03, 0.0, 0.0, 0.0))
    assert distortion_monotonic_radius([0.02, -0.03, 0.0, 0.0, 0.0, 0.1, 0.2, 0.3]) == pytest.approx(
        distortion_monotonic_radius((0.02, -0.03, 0.0, 0.0, 0.0)), rel=1e-15)
    # the cached root finder gives the same for the same lens, and inf with only complex or negative roots
    assert _radial_monotonic_radius(k1, k2, k3) == pytest.approx(1.0, rel=1e-12)
    assert _radial_monotonic_radius(0.1, 0.0, 0.0) == np.inf
    assert _radial_monotonic_radius(-0.08, 0.02, 0.0) == np.inf  # 1 - 0.24 u + 0.1 u^2: a complex pair, Re > 0


def _reference_beyond(V, R, t, r2_max):
    P = V @ R.T + t
    return (P[:, 2] > 0.0) & (P[:, 0] ** 2 + P[:, 1] ** 2 > r2_max * P[:, 2] ** 2)


def test_drop_folded_against_a_numpy_reference_on_a_rotated_camera():
    rng = np.random.default_rng(4)
    cam = Camera.look_at("c", eye=(0.3, 1.2, 2.0), target=(-0.4, 0.9, -0.5), fx=300.0, width=320, height=240)
    R, t = cam.R, cam.t
    assert np.abs(R - R.T).max() > 0.1 and np.abs(t).min() > 0.05  # no symmetry hides a swapped entry
    V = cam.center + rng.normal(size=(400, 3)) * [1.5, 1.0, 1.5]
    V[-1] = cam.R.T @ (np.array([3.0, 0.5, 1.0]) - cam.t)  # the last vertex beyond both (the loop's end)
    uv0 = rng.normal(size=(400, 2))
    for r2_max in (0.5, 2.0):
        uv = uv0.copy()
        _drop_folded(V.reshape(-1), R, t, r2_max, uv.reshape(-1))
        beyond = _reference_beyond(V, R, t, r2_max)
        assert 20 < beyond.sum() < 380 and beyond[-1]
        assert np.isnan(uv[beyond]).all()
        assert np.array_equal(uv[~beyond], uv0[~beyond])  # the others untouched, both coordinates


def test_drop_folded_keeps_a_vertex_on_the_radius_and_behind_the_camera():
    R, t = np.eye(3), np.zeros(3)
    # x^2 + y^2 == r2_max z^2 exactly: on the radius is not beyond it ("exceeds"); z <= 0 is left to _project
    V = np.array([[1.0, 0.0, 1.0], [3.0, 4.0, 1.0], [3.0, 4.0, -1.0], [0.0, 5.0, 0.0], [1.0, 1.0, 1.0]])
    uv = np.zeros((5, 2))
    _drop_folded(V.reshape(-1), R, t, 1.0, uv.reshape(-1))
    assert np.array_equal(np.isnan(uv), np.array([[0, 0], [1, 1], [0, 0], [0, 0], [1, 1]], bool))


def test_project_vertices_drops_exactly_the_vertices_beyond_on_a_folding_lens():
    cam = Camera.look_at("c", eye=(0.1, 1.0, 1.5), target=(0.0, 1.0, -1.0), fx=300.0, width=320, height=240,
                         dist=(0.02, -0.03, 0.001, -0.001, 0.0))
    rng = np.random.default_rng(9)
    V = cam.center + rng.normal(size=(300, 3)) * [2.0, 2.0, 1.0] + [0.0, 0.0, -1.0]
    uv, z = project_vertices(V, cam)
    r = cam.monotonic_radius
    beyond = _reference_beyond(V, cam.R, cam.t, r * r)
    front = (V @ cam.R.T + cam.t)[:, 2] > 0.0
    assert beyond.sum() > 10 and (front & ~beyond).sum() > 10
    assert np.isnan(uv[beyond | ~front]).all() and np.isfinite(uv[front & ~beyond]).all()
    assert np.allclose(z, (V @ cam.R.T + cam.t)[:, 2], atol=1e-12)
