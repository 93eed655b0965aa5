"""Synthetic scans: the ground truth reproduces the scan; subdivision keeps the surface."""

import numpy as np
import scipy.sparse as sp

from bodystudio.register.synthetic import densify, ground_truth_dir, load_ground_truth, midpoint_subdivision


def test_ground_truth_reproduces_scan(small_scan):
    path, scan, gt = small_scan
    np.testing.assert_allclose(gt.posed_vertices(gt.pose), scan.vertices, atol=1e-9)
    W = gt.weights
    np.testing.assert_allclose(np.asarray(W.sum(1)).ravel(), 1.0, atol=1e-9)
    # Noise along normals with the requested spread (1 mm).
    assert 0.7 < 1000 * np.linalg.norm(gt.noise, axis=1).std() / np.sqrt(1 - 2 / np.pi) < 1.3
    loaded = load_ground_truth(ground_truth_dir(path))
    np.testing.assert_allclose(loaded.joints, gt.joints)
    np.testing.assert_allclose(loaded.posed_vertices(loaded.pose), scan.vertices, atol=1e-9)


def test_midpoint_subdivision_is_a_linear_map_on_the_surface(body_2k):
    V, F = body_2k.vertices, body_2k.faces
    S, F2 = midpoint_subdivision(F, len(V))
    assert len(F2) == 4 * len(F)
    V2 = S @ V
    np.testing.assert_allclose(np.asarray(S.sum(1)).ravel(), 1.0)
    # Area is preserved exactly by flat subdivision.
    def area(V, F):
        return 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1).sum()
    assert abs(area(V2, F2) - area(V, F)) < 1e-9
    S2, F3 = densify(V, F, 12_000)
    assert 10_000 < S2.shape[0] < 14_000 and sp.issparse(S2)
