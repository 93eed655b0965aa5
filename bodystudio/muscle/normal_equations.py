"""Normal equations of the rest-shape fits (Sec. 6.2 of Arm-Muscle Capture, docs/muscle.md) in a fixed summation order.

The Gauss-Newton steps of ``refine.fit_body_rest_shape`` / ``fit_body_rest_shape_and_poses`` and
``model.project_to_body_space`` accumulate ``G^T W G`` and ``G^T W r`` over thousands of point-to-plane pairs for
~100 parameters and solve a ~100 x 100 system. OpenBLAS splits such a skinny product (and the LU of ``np.linalg.solve``)
differently between 1 and 2 threads, so the results differed in their last bits with the machine's core count; the
sequence fit after the rest shape (``refine.fit_arm_sequence_skeleton``: a trust-region fit stopped at ``max_nfev``
before it converges) turns a 1e-13 m change of the rest mesh into up to millimetres (docs/muscle.md, "the thread
count"). These helpers do the same algebra with numpy's own loops (``np.einsum`` without ``optimize``, which never
calls BLAS) and a Jacobi-scaled Cholesky written out in numpy, so a fit gives the same bits with any thread count.
They are for the small dense systems of these fits only (a Cholesky of n = 110 takes ~2 ms).
"""

from __future__ import annotations

import numpy as np

#: rows of a Jacobian summed per ``np.einsum`` call in :func:`normal_matrix` (their order is fixed, so is the sum)
ROWS_PER_BLOCK = 256


def ordered_product(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``A @ B`` (2-D by 1-D or 2-D) summed in numpy's fixed order, whatever the BLAS thread count."""
    A, B = np.asarray(A, np.float64), np.asarray(B, np.float64)
    return np.einsum("ik,k->i" if B.ndim == 1 else "ik,kj->ij", A, B)


def normal_matrix(G: np.ndarray, w: np.ndarray | None = None) -> np.ndarray:
    """``G^T diag(w) G`` (P, P) of a Jacobian ``G`` (k, P) with per-row weights ``w`` (k,) (default 1), in a fixed
    summation order; exactly symmetric."""
    G = np.ascontiguousarray(G, np.float64)
    wG = G if w is None else G * np.asarray(w, np.float64)[:, None]
    H = np.zeros((G.shape[1], G.shape[1]))
    # blocks of rows, each a sum of rank-1 updates: 2.7 ms for 1000 x 108 (one einsum over all rows: 41 ms, a dot
    # per entry: more; BLAS 0.6 ms)
    for s in range(0, len(G), ROWS_PER_BLOCK):
        H += np.einsum("kp,kq->pq", G[s:s + ROWS_PER_BLOCK], wG[s:s + ROWS_PER_BLOCK])
    return 0.5 * (H + H.T)


def normal_rhs(G: np.ndarray, r: np.ndarray, w: np.ndarray | None = None) -> np.ndarray:
    """``G^T diag(w) r`` (P,) or (P, m) for residuals ``r`` (k,) or (k, m), in a fixed summation order."""
    G, r = np.asarray(G, np.float64), np.asarray(r, np.float64)
    if w is not None:
        r = r * (np.asarray(w, np.float64) if r.ndim == 1 else np.asarray(w, np.float64)[:, None])
    return np.einsum("kp,k->p" if r.ndim == 1 else "kp,km->pm", G, r)


def spd_solve(H: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``H^-1 b`` for a symmetric positive definite ``H`` (n, n) and ``b`` (n,) or (n, m): Cholesky of the
    Jacobi-scaled ``S H S`` (``S = diag(H)^-1/2``: the parameters' units out; the projection's normal matrix of the 2k
    test case has a condition number 8.3e6 unscaled, 1.7e6 scaled) and two triangular solves, in numpy's fixed order.
    Raises ``np.linalg.LinAlgError`` when ``H`` is not positive definite (as ``np.linalg.cholesky``)."""
    H, b = np.asarray(H, np.float64), np.asarray(b, np.float64)
    n = len(H)
    d = np.diag(H)
    if not np.all(d > 0):
        raise np.linalg.LinAlgError("spd_solve: the matrix has a non-positive diagonal entry")
    s = 1.0 / np.sqrt(d)
    A = H * s[:, None] * s[None, :]
    L = np.zeros((n, n))
    for j in range(n):
        pivot = A[j, j] - np.einsum("k,k->", L[j, :j], L[j, :j])
        if not pivot > 0:
            raise np.linalg.LinAlgError("spd_solve: the matrix is not positive definite")
        L[j, j] = np.sqrt(pivot)
        L[j + 1:, j] = (A[j + 1:, j] - np.einsum("ik,k->i", L[j + 1:, :j], L[j, :j])) / L[j, j]
    sb = b * (s if b.ndim == 1 else s[:, None])
    y = np.zeros_like(sb)
    for i in range(n):
        y[i] = (sb[i] - np.einsum("k,k...->...", L[i, :i], y[:i])) / L[i, i]
    x = np.zeros_like(sb)
    for i in range(n - 1, -1, -1):
        x[i] = (y[i] - np.einsum("k,k...->...", L[i + 1:, i], x[i + 1:])) / L[i, i]
    return x * (s if b.ndim == 1 else s[:, None])
