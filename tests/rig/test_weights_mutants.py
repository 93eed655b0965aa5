"""bodystudio.rig.weights cases the analytic tests leave open (issue 17, mutation testing): one free vertex
whose own closest-point weights are wrong, a bone known only weakly on the constraints, the Laplacian
option passed through, the orphan-component log line, dtypes, and CG on a right-hand side of small norm."""

import logging

import numpy as np
import pytest
import scipy.sparse as sp

from bodystudio.rig.weights import block_conjugate_gradient, harmonic_weight_transfer, limit_influences

from .test_weights_analytic import UP, _linear_weights, _sheet


def test_one_free_vertex_is_solved_not_copied():
    """Exactly one free vertex whose model weights are wrong ([0, 0, 1]): the harmonic fill gives the linear
    value there (cotangent linear precision), not the copied weights."""
    V, F, n_ring = _sheet()
    model_W = _linear_weights(V)
    one = n_ring + 5
    model_W[one] = [0.0, 0.0, 1.0]
    scan_N = np.tile(UP, (len(V), 1))
    scan_N[one] = -UP
    harm = harmonic_weight_transfer(V, F, V, F, model_W, scan_N=scan_N)
    np.testing.assert_allclose(harm[one], _linear_weights(V)[one], atol=1e-9)


def test_a_bone_known_only_weakly_on_the_constraints_is_still_filled():
    """Bone 2 carries 0.5 at a single constrained vertex (its known weights sum to 0.5): it must still be
    solved for over the free region, where it decays from that vertex."""
    V, F, n_ring = _sheet()
    model_W = _linear_weights(V)
    inner = np.all((V[:, [0, 2]] > 0.04) & (V[:, [0, 2]] < 0.16), axis=1)
    edge = np.flatnonzero(~inner & np.all((V[:, [0, 2]] > 0.03) & (V[:, [0, 2]] < 0.17), axis=1))[0]
    model_W[edge] = [0.25, 0.25, 0.5]
    scan_N = np.tile(UP, (len(V), 1))
    scan_N[inner] = -UP
    harm = harmonic_weight_transfer(V, F, V, F, model_W, scan_N=scan_N)
    assert harm[inner, 2].max() > 0.01
    assert (harm[inner, 2] >= -1e-12).all()
    np.testing.assert_allclose(harm.sum(1), 1.0, atol=1e-12)


def test_the_laplacian_option_is_passed_through():
    V, F, _ = _sheet(60)
    W = _linear_weights(V)
    scan_N = np.tile(UP, (len(V), 1))
    scan_N[:5] = -UP
    with pytest.raises(ValueError, match="cotan, robust"):
        harmonic_weight_transfer(V, F, V, F, W, laplacian="graph", scan_N=scan_N)


def test_orphan_components_are_logged_with_their_size(caplog):
    V, F, _ = _sheet(120)
    V2, F2 = V + [0.5, 0.0, 0.0], F + len(V)
    scan_V, scan_F = np.r_[V, V2], np.r_[F, F2]
    model_W = np.r_[_linear_weights(V), np.tile([0.2, 0.3, 0.5], (len(V2), 1))]
    scan_N = np.r_[np.tile(UP, (len(V), 1)), np.tile(-UP, (len(V2), 1))]
    with caplog.at_level(logging.INFO, logger="bodystudio.rig.weights"):
        harmonic_weight_transfer(scan_V, scan_F, scan_V, scan_F, model_W, scan_N=scan_N)
    assert (f"harmonic transfer: {len(V2)} scan vertices in components without compatible correspondences"
            in caplog.messages)


def test_limit_influences_returns_float64_for_any_input():
    W = np.array([[0.5, 0.3, 0.2, 0.1, 0.05]], np.float32)
    out = limit_influences(W, 3)
    assert out.dtype == np.float64
    np.testing.assert_allclose(out, [[0.5, 0.3, 0.2, 0.0, 0.0]], atol=1e-15)  # float32 0.3 would show


def test_cg_tolerance_is_relative_to_a_small_right_hand_side():
    """||B|| = 1e-3: stopping at rtol * ||B|| (not rtol / ||B||) is what makes the answer accurate."""
    n = 50
    A = sp.diags([-1.0, 2.05, -1.0], [-1, 0, 1], shape=(n, n)).tocsr()
    B = 1e-3 * np.random.default_rng(0).normal(size=(n, 1)) / np.sqrt(n)
    exact = np.linalg.solve(A.toarray(), B)
    X = block_conjugate_gradient(A, B, np.zeros_like(B), rtol=1e-6)
    assert np.linalg.norm(A @ X - B) <= 1e-6 * np.linalg.norm(B) * 1.0001
    np.testing.assert_allclose(X, exact, atol=1e-5 * np.abs(exact).max())
