"""Cotangent-weighted delta coordinates (Laplacian mesh editing, Sorkine et al. 2004; Rapid Skin §III.B).

Weights come from libigl's cotangent matrix, clamped to be non-negative (obtuse triangles give negative
cotangents, which would let a vertex's delta coordinate point outside its 1-ring) and normalised so
that each row sums to one, as Eq. 8 of Rapid Skin asks.
"""

from __future__ import annotations

from dataclasses import dataclass

import igl
import numba
import numpy as np
import scipy.sparse as sp

#: Relative floor of a cotangent weight (fraction of the row's mean), keeps every 1-ring edge alive.
_WEIGHT_FLOOR = 1e-3


@dataclass(frozen=True, eq=False)
class DeltaOperator:
    """Row-normalised cotangent weights in CSR form: ``delta_i = v_i - sum_j w_ij v_j``."""

    indptr: np.ndarray  # (n + 1,) int64
    indices: np.ndarray  # (nnz,) int64 neighbour ids
    weights: np.ndarray  # (nnz,) float64, each row sums to 1
    reverse: np.ndarray  # (nnz,) position of entry (j, i) for entry (i, j)

    @property
    def n_vertices(self) -> int:
        return len(self.indptr) - 1

    @property
    def matrix(self) -> sp.csr_matrix:
        """``L = I - W`` with ``W`` the normalised weights, so ``L @ V`` are the delta coordinates."""
        n = self.n_vertices
        W = sp.csr_matrix((self.weights, self.indices, self.indptr), shape=(n, n))
        return (sp.identity(n, format="csr") - W).tocsr()

    def apply(self, V: np.ndarray) -> np.ndarray:
        """Delta coordinates ``(n, 3)`` of vertex positions ``V``, Eq. 8 of Rapid Skin.

        One compiled pass over the rings (issue 15's frame time: building :attr:`matrix` for ``matrix @ V`` was
        ~1 ms of a 13K frame): each row summed in ``matrix @ V``'s order (columns ascending, the diagonal's 1 in
        its place), so the same values bit for bit (tested; :meth:`apply_reference`)."""
        V = np.asarray(V)
        if V.shape != (self.n_vertices, 3) or V.dtype != np.float64:
            return self.apply_reference(V)
        ok, out = _delta_rows(self.indptr, self.indices, self.weights, np.ascontiguousarray(V))
        return out if ok else self.apply_reference(V)

    def apply_reference(self, V: np.ndarray) -> np.ndarray:
        """:meth:`apply` as the sparse product ``matrix @ V`` (the path the compiled one replaced)."""
        return self.matrix @ V


def cotangent_weights(V: np.ndarray, F: np.ndarray) -> DeltaOperator:
    """Cotangent weights of every 1-ring, normalised to sum 1 (Eq. 8 of Rapid Skin)."""
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    C = sp.csr_matrix(igl.cotmatrix(V, F))
    C.setdiag(0.0)
    C.eliminate_zeros()
    # The adjacency structure comes from the faces, so zero-cotangent edges keep their entry.
    A = sp.csr_matrix(igl.adjacency_matrix(F).astype(np.float64))
    C = (A.multiply(1e-30) + C.maximum(0.0)).tocsr()
    C.sort_indices()
    n = len(V)
    indptr = C.indptr.astype(np.int64)
    indices = C.indices.astype(np.int64)
    w = C.data.astype(np.float64)
    rows = np.repeat(np.arange(n), np.diff(indptr))
    row_sum = np.bincount(rows, weights=w, minlength=n)
    row_count = np.maximum(np.diff(indptr), 1)
    floor = _WEIGHT_FLOOR * (row_sum / row_count)
    w = np.maximum(w, floor[rows])
    w /= np.bincount(rows, weights=w, minlength=n)[rows]
    reverse = _reverse_entries(indptr, indices)
    if np.any(reverse < 0):
        raise ValueError("the face adjacency is not symmetric: every edge needs both of its directions")
    return DeltaOperator(indptr, indices, w, reverse)


@numba.njit(cache=True)
def _delta_rows(indptr, indices, weights, V):
    """``(I - W) V`` of ``(n, 3)`` positions row by row as scipy's CSR product sums it: from 0, over the columns
    in ascending order, ``-w_ij v_j`` and ``1 v_i`` at the diagonal's place. ``ok`` False when a row's columns
    are not strictly ascending or hold the diagonal (then the caller takes the sparse product)."""
    n = V.shape[0]
    out = np.empty((n, 3))
    for i in range(n):
        x = y = z = 0.0
        placed = False
        last = -1
        for e in range(indptr[i], indptr[i + 1]):
            j = indices[e]
            if j <= last or j == i:
                return False, out
            last = j
            if not placed and j > i:
                x += 1.0 * V[i, 0]
                y += 1.0 * V[i, 1]
                z += 1.0 * V[i, 2]
                placed = True
            w = -weights[e]
            x += w * V[j, 0]
            y += w * V[j, 1]
            z += w * V[j, 2]
        if not placed:
            x += 1.0 * V[i, 0]
            y += 1.0 * V[i, 1]
            z += 1.0 * V[i, 2]
        out[i, 0], out[i, 1], out[i, 2] = x, y, z
    return True, out


@numba.njit(cache=True)
def _reverse_entries(indptr, indices):
    """Position of entry ``(j, i)`` for each entry ``(i, j)`` of a structurally symmetric CSR matrix,
    found by scanning row ``j`` (a 1-ring: a few entries; 0.7 ms at 13K where sorting keys took 5 ms)."""
    reverse = np.empty(len(indices), np.int64)
    for i in range(len(indptr) - 1):
        for e in range(indptr[i], indptr[i + 1]):
            j = indices[e]
            reverse[e] = -1
            for f in range(indptr[j], indptr[j + 1]):
                if indices[f] == i:
                    reverse[e] = f
                    break
    return reverse


def cotangent_delta_coordinates(V: np.ndarray, F: np.ndarray) -> tuple[DeltaOperator, np.ndarray]:
    """Normalised cotangent weights and the delta coordinates ``(n, 3)`` of ``V``, Eq. 8 of Rapid Skin."""
    op = cotangent_weights(V, F)
    return op, op.apply(np.asarray(V, dtype=np.float64))
