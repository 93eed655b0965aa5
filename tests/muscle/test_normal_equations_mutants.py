"""``muscle.normal_equations`` against numpy's BLAS algebra on small analytic systems (issue 17, mutation round mutR).

The module's only other test (``test_thread_independence.py``) imports the planted 2k subject; these cases build
their inputs in microseconds: a Jacobian with more rows than one summation block (``ROWS_PER_BLOCK``) and a row
count that is not a multiple of it, residuals of one and several columns, SPD systems with parameters in units from
2^-500 to 2^500 (only the Jacobi scaling keeps their Cholesky finite), and the refusals of non-SPD matrices.
"""

import functools

import numpy as np
import pytest

from bodystudio.muscle import normal_equations as ne


@functools.cache
def _jacobian():
    """k = 2 blocks + 37 rows by P = 7 parameters, positive weights, one- and three-column residuals."""
    rng = np.random.default_rng(11)
    k = 2 * ne.ROWS_PER_BLOCK + 37
    return rng.standard_normal((k, 7)), 0.5 + rng.random(k), rng.standard_normal(k), rng.standard_normal((k, 3))


def _close(a, b, tol=1e-12):
    a, b = np.asarray(a), np.asarray(b)
    assert a.shape == b.shape, (a.shape, b.shape)
    np.testing.assert_allclose(a, b, rtol=0, atol=tol * max(1.0, np.abs(b).max()))


def test_ordered_product_is_the_matrix_product_of_vectors_and_matrices_in_float64():
    rng = np.random.default_rng(1)
    A, v, B = rng.standard_normal((5, 4)), rng.standard_normal(4), rng.standard_normal((4, 3))
    _close(ne.ordered_product(A, v), A @ v)
    _close(ne.ordered_product(A, B), A @ B)
    Ai, vi = np.arange(6).reshape(2, 3), np.array([1, 2, 3])  # integers in, float64 out
    out = ne.ordered_product(Ai, vi)
    assert out.dtype == np.float64 and np.array_equal(out, [8.0, 26.0])
    assert ne.ordered_product(Ai, vi.astype(np.float32)).dtype == np.float64


def test_normal_matrix_sums_every_block_of_rows_with_its_weights_and_is_exactly_symmetric():
    G, w, _, _ = _jacobian()
    H = ne.normal_matrix(G, w)
    assert H.shape == (7, 7) and H.dtype == np.float64
    _close(H, G.T @ (w[:, None] * G))
    assert np.array_equal(H, H.T)
    _close(ne.normal_matrix(G), G.T @ G)
    _close(ne.normal_matrix(G, np.ones(len(G))), G.T @ G)
    _close(ne.normal_matrix(G[:3]), G[:3].T @ G[:3])  # fewer rows than parameters, one block
    # an asymmetric product's symmetrisation is the mean of the two halves: a rank-1 G gives g g^T exactly
    g = np.array([[1.0, 2.0, -3.0]])
    assert np.array_equal(ne.normal_matrix(g, [2.0]), 2.0 * g.T @ g)


def test_normal_rhs_of_one_and_several_residual_columns_with_and_without_weights():
    G, w, r, R = _jacobian()
    _close(ne.normal_rhs(G, r, w), G.T @ (w * r))
    _close(ne.normal_rhs(G, R, w), G.T @ (w[:, None] * R))
    _close(ne.normal_rhs(G, r), G.T @ r)
    _close(ne.normal_rhs(G, R), G.T @ R)
    out = ne.normal_rhs(np.array([[1, 2], [3, 4]]), np.array([1, 1]))  # integers in, float64 out
    assert out.dtype == np.float64 and np.array_equal(out, [4.0, 6.0])
    assert ne.normal_rhs(np.array([[1, 2], [3, 4]]), np.array([1, 1]), np.array([2, 1])).dtype == np.float64


@functools.cache
def _spd(n=6):
    rng = np.random.default_rng(7)
    M = rng.standard_normal((n + 3, n))
    return M.T @ M + 0.1 * np.eye(n), rng.standard_normal(n), rng.standard_normal((n, 2))


def test_spd_solve_solves_one_and_several_right_hand_sides():
    H, b, B = _spd()
    _close(ne.spd_solve(H, b), np.linalg.solve(H, b), 1e-10)
    _close(ne.spd_solve(H, B), np.linalg.solve(H, B), 1e-10)
    _close(ne.spd_solve(H.tolist(), b.tolist()), np.linalg.solve(H, b), 1e-10)
    # a diagonal system and a 1 x 1 one: exact
    assert np.array_equal(ne.spd_solve(np.diag([4.0, 16.0, 0.25]), np.array([2.0, 4.0, 1.0])), [0.5, 0.25, 4.0])
    assert np.array_equal(ne.spd_solve(np.array([[4.0]]), np.array([[8.0, 2.0]])), [[2.0, 0.5]])


def test_spd_solve_takes_the_parameters_units_out():
    """Parameters scaled by 2^-500 .. 2^500: unscaled (or scaled the wrong way) the Cholesky's entries overflow to
    inf / underflow to 0; with the Jacobi scaling the solve is the unscaled one's, scaled back, to rounding."""
    H, b, B = _spd()
    D = 2.0 ** np.linspace(-500, 500, len(b)).round()
    x = ne.spd_solve(H * D[:, None] * D[None, :], D * b)
    assert np.all(np.isfinite(x))
    _close(x * D, np.linalg.solve(H, b), 1e-10)
    X = ne.spd_solve(H * D[:, None] * D[None, :], D[:, None] * B)
    _close(X * D[:, None], np.linalg.solve(H, B), 1e-10)


NOT_PD = r"^spd_solve: the matrix is not positive definite$"
NON_POSITIVE = r"^spd_solve: the matrix has a non-positive diagonal entry$"


@pytest.mark.parametrize("H, message", [
    ([[1.0, 2.0], [2.0, 1.0]], NOT_PD),  # indefinite
    ([[1.0, 1.0], [1.0, 1.0]], NOT_PD),  # singular: a pivot of exactly 0
    ([[1.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 2.0]], NON_POSITIVE),
    ([[1.0, 0.0], [0.0, -2.0]], NON_POSITIVE),
    ([[4.0, 2.0, 2.0], [2.0, 1.0, 1.0], [2.0, 1.0, 5.0]], NOT_PD),  # the 2nd pivot 0
])
def test_spd_solve_refuses_what_is_not_positive_definite(H, message):
    with pytest.raises(np.linalg.LinAlgError, match=message):
        ne.spd_solve(np.array(H), np.ones(len(H)))
