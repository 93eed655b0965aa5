"""The rasteriser draws nothing beyond the lens distortion's monotonic radius (mir12t): no folded triangles."""

import numpy as np
import pytest

from bodystudio.capture.render import depth_buffer, project_vertices, render, render_rgb, render_silhouette_depth
from bodystudio.geometry.camera import STUDIO_DISTORTION, Camera, distortion_monotonic_radius

#: The Kinect v2 colour lens (k1 0.02, k2 -0.03): r_d(r) peaks at r = 1.670 and folds back beyond.
FOLDING = (0.02, -0.03, 0.0, 0.0, 0.0)


def _camera(dist=FOLDING):
    return Camera.look_at("c", eye=(0.0, 0.0, 0.0), target=(0.0, 0.0, -1.0), fx=300.0, width=320, height=240,
                          dist=dist)


def _triangle_at_radius(r: float, spread_deg: float = 12.0, size: float = 0.04, depth_m: float = 1.0):
    """A small triangle ``depth_m`` in front of the camera at normalised radius ``r`` (along +x)."""
    angles = np.radians([0.0, spread_deg, -spread_deg])
    radii = np.array([r, r + size, r + size])
    V = depth_m * np.stack([radii * np.cos(angles), radii * np.sin(angles), -np.ones(3)], axis=1)
    return V, np.array([[0, 1, 2]])


def test_monotonic_radius_closed_form():
    # k1 alone: d r_d / d r = 1 + 3 k1 r^2 = 0 at r = 1 / sqrt(-3 k1)
    assert distortion_monotonic_radius((-0.3, 0.0, 0.0, 0.0, 0.0)) == pytest.approx(1.0 / np.sqrt(0.9), rel=1e-12)
    r = distortion_monotonic_radius(FOLDING)
    k1, k2 = FOLDING[:2]
    assert 1.0 + 3.0 * k1 * r**2 + 5.0 * k2 * r**4 == pytest.approx(0.0, abs=1e-12)
    assert r == pytest.approx(1.6703, abs=1e-4)
    # no fold: a pinhole, the studio rig's lens (1 - 0.24 u + 0.1 u^2 has no real root), a pincushion
    assert distortion_monotonic_radius(np.zeros(5)) == np.inf
    assert distortion_monotonic_radius(STUDIO_DISTORTION) == np.inf
    assert distortion_monotonic_radius((0.1, 0.01, 0.0, 0.0, 0.0)) == np.inf
    assert _camera().monotonic_radius == pytest.approx(r)


def test_triangle_beyond_the_monotonic_radius_is_not_drawn():
    cam = _camera()
    # r_d(2.35) = 0.46: the polynomial folds it into the image; 0.5 m away, the test must compare x^2 + y^2 with
    # r_max^2 z^2, not r_max^2
    V, F = _triangle_at_radius(2.35, depth_m=0.5)
    uv, _ = project_vertices(V, cam)
    assert np.isnan(uv).all()
    for mask in (render(V, F, cam).mask, render_silhouette_depth(V, F, cam)[0]):
        assert not mask.any()
    plate = np.full((240, 320, 3), 7, np.uint8)
    assert np.array_equal(render_rgb(V, F, cam, background=plate), plate)
    # one well inside the monotonic range is drawn, by every path alike
    V_in, F_in = _triangle_at_radius(0.3, spread_deg=20.0, size=0.1, depth_m=2.0)
    result = render(V_in, F_in, cam)
    assert result.mask.sum() > 200
    assert np.array_equal(depth_buffer(*project_vertices(V_in, cam), F_in, 320, 240) < np.inf, result.mask)


def test_a_triangle_straddling_the_radius_is_dropped_whole():
    cam = _camera()
    r_max = cam.monotonic_radius
    V, F = _triangle_at_radius(r_max - 0.05, spread_deg=3.0, size=0.1)  # two vertices beyond
    assert not render(V, F, cam).mask.any()
    uv, _ = project_vertices(V, cam)
    assert np.isfinite(uv[0]).all() and np.isnan(uv[1:]).all()
