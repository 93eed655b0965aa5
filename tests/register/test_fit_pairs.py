"""Compatible pairs of the fit (eq. 5): scan -> model pairs land on the model surface, not its vertices."""

import numpy as np
from scipy.spatial import cKDTree

from bodystudio.register.fit import compatible_pairs


def _grid(n: int, size: float = 0.2):
    xs = np.linspace(0.0, size, n)
    X, Y = np.meshgrid(xs, xs)
    V = np.c_[X.ravel(), Y.ravel(), np.zeros(n * n)]
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    F = np.r_[np.c_[a, b, d], np.c_[a, d, c]]
    return V, F


def test_scan_to_model_pairs_on_the_surface():
    model_V, model_F = _grid(6)  # 4 cm spacing: vertex snapping would be off by up to ~3 cm
    rng = np.random.default_rng(0)
    scan_V = np.c_[rng.uniform(0.02, 0.18, (500, 2)), np.full(500, 0.002)]
    scan_N = np.tile([0.0, 0.0, 1.0], (500, 1))
    model_N = np.tile([0.0, 0.0, 1.0], (len(model_V), 1))
    sample = np.arange(500)
    for surface, bound in ((True, 0.0021), (False, None)):
        corners, bary, Z, _ = compatible_pairs(model_V, model_F, model_N, scan_V, scan_N, cKDTree(scan_V), 0.05, sample,
                                            surface=surface)
        P = np.einsum("nk,nki->ni", bary, model_V[corners])
        d = np.linalg.norm(P - Z, axis=1)[-500:]  # the scan -> model pairs come last
        if surface:
            assert np.allclose(bary.sum(1), 1.0) and (bary >= 0).all()
            assert d.max() < bound  # only the 2 mm offset along the normal
        else:
            assert np.median(d) > 0.01  # snapped to vertices
