"""The frame's kernels that LLVM vectorises (issue 15's frame time, rec15i: flat views, numpy's division model, no
branches) against the per-point arithmetic they replaced, bit for bit, on small random inputs with the edge cases
(behind the camera, at z = 0, on and off the image's edges, NaN, ties at the rim threshold)."""

import numpy as np
import pytest

from bodystudio.reconstruct.silhouette import _project_into, _project_point, _rim_flags


def _camera(rng, distorted=True):
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    if np.linalg.det(q) < 0:
        q[:, 0] *= -1
    t = np.array([0.1, -0.2, 2.5])
    K = np.array([[520.0, 0.3, 321.5], [0.0, 515.0, 239.0], [0.0, 0.0, 1.0]])
    dist = np.array([0.08, -0.21, 0.001, -0.002, 0.05]) if distorted else np.zeros(5)
    return q, t, K, dist


@pytest.mark.parametrize("distorted", [True, False])
def test_projection_is_the_per_point_one(distorted):
    rng = np.random.default_rng(11)
    R, t, K, dist = _camera(rng, distorted)
    V = rng.normal(scale=0.8, size=(301, 3))
    V[:5] = R.T @ (np.array([0.0, 0.0, -2.5]) - t) + rng.normal(scale=1e-3, size=(5, 3))  # near the camera plane
    V[5] = R.T @ (np.array([0.3, 0.1, 0.0]) - t)  # z = 0 exactly (up to rounding): NaN, no exception
    V[6] = R.T @ (np.array([0.0, 0.0, -1.0]) - t)  # behind
    V[7] = np.nan
    uv, z = np.empty((len(V), 2)), np.empty(len(V))
    _project_into(V, R, t, K, dist, uv, z)
    for i, X in enumerate(V):
        u, v, zc, _, _ = _project_point(X[0], X[1], X[2], R, t, K, dist, True)
        assert z[i] == zc or (np.isnan(z[i]) and np.isnan(zc))
        if zc > 0:
            assert uv[i, 0] == u and uv[i, 1] == v, i
        else:
            assert np.isnan(uv[i]).all(), i
    assert np.isfinite(uv[8:]).sum() > 100


def test_rim_flags_are_the_per_vertex_tests():
    rng = np.random.default_rng(12)
    R, t, K, dist = _camera(rng)
    center = -R.T @ t
    n = 2000
    V = rng.normal(scale=0.6, size=(n, 3))
    N = rng.normal(size=(n, 3))
    N /= np.linalg.norm(N, axis=1, keepdims=True)
    ray = V - center
    # a tenth of the normals exactly perpendicular to the ray, some exactly at the threshold's side
    k = slice(0, n // 10)
    N[k] = np.cross(ray[k], rng.normal(size=(n // 10, 3)))
    N[k] /= np.linalg.norm(N[k], axis=1, keepdims=True)
    N[n // 10] = np.nan
    uv, z = np.empty((n, 2)), np.empty(n)
    _project_into(V, R, t, K, dist, uv, z)
    uv[5] = [0.0, 479.0]  # on the image's edges: in
    uv[6] = [640.0, 10.0]  # one past: out
    width, height, rim_cos = 640.0, 480.0, 0.2
    got = np.empty(n, np.bool_)
    _rim_flags(V.reshape(-1), N.reshape(-1), uv.reshape(-1), z, center, width, height, rim_cos, got)
    ref = np.zeros(n, bool)
    for i in range(n):  # the branches of _match_view before rec15i, in their order
        u, v = uv[i]
        if not (z[i] > 0.0 and u >= 0.0 and u < width and v >= 0.0 and v < height):
            continue
        rx, ry, rz = V[i] - center
        rn = np.sqrt(rx * rx + ry * ry + rz * rz)
        ref[i] = abs(N[i, 0] * rx + N[i, 1] * ry + N[i, 2] * rz) < rim_cos * rn
    np.testing.assert_array_equal(got, ref)
    assert 100 < ref.sum() < n - 100 and got[5] == ref[5] and not got[6]
