"""Skin weight transfer: barycentric baseline, harmonic (eq. 7), influence limit."""

import numpy as np

from bodystudio.body import build_body
from bodystudio.rig.weights import barycentric_weight_transfer, harmonic_weight_transfer, limit_influences


def test_limit_influences_keeps_four_largest_and_normalises():
    W = np.array([[0.1, 0.2, 0.3, 0.15, 0.25], [1.0, 0, 0, 0, 0]])
    L = limit_influences(W)
    assert ((L > 0).sum(1) <= 4).all()
    np.testing.assert_allclose(L.sum(1), 1.0)
    assert L[0, 0] == 0.0


def test_transfer_from_2k_to_full_body_recovers_its_weights(body_2k):
    full = build_body(resolution="full")
    true = limit_influences(full.weights)
    bary = barycentric_weight_transfer(full.vertices, body_2k.vertices, body_2k.faces, body_2k.weights)
    harm = harmonic_weight_transfer(full.vertices, full.faces, body_2k.vertices, body_2k.faces, body_2k.weights)
    for W in (bary, harm):
        assert ((W > 0).sum(1) <= 4).all()
        np.testing.assert_allclose(W.sum(1), 1.0, atol=1e-9)
    l1_bary = np.abs(bary - true).sum(1).mean()
    l1_harm = np.abs(harm - true).sum(1).mean()
    assert l1_bary < 0.15 and l1_harm < 0.15, (l1_bary, l1_harm)


def test_block_conjugate_gradient_matches_direct_solve(body_2k):
    import igl
    import scipy.sparse as sp
    from scipy.sparse.linalg import spsolve

    from bodystudio.rig.weights import block_conjugate_gradient

    L = -igl.cotmatrix(body_2k.vertices, body_2k.faces)
    A = (L + 1e-3 * sp.identity(L.shape[0])).tocsr()
    B = np.random.default_rng(0).normal(size=(A.shape[0], 3))
    X = block_conjugate_gradient(A, B, np.zeros_like(B), rtol=1e-10, max_iterations=5000)
    exact = np.column_stack([spsolve(A.tocsc(), B[:, k]) for k in range(3)])
    assert np.abs(X - exact).max() < 1e-6 * np.abs(exact).max()
