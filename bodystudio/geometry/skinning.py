"""Sparse linear blend skinning (Eq. 12 of Rapid Skin; Eq. 1 of Real-time Reshaping): each vertex blends only
its few non-zero skin weights (MakeHuman's have at most six), shared by the mirror's tracker and the
reconstruction's posing."""

from __future__ import annotations

import numpy as np
from numba import njit

_SPARSE_CACHE: dict[tuple[int, int | None], tuple[np.ndarray, np.ndarray, np.ndarray]] = {}


def sparse_skin_weights(weights: np.ndarray, k: int | None = 6) -> tuple[np.ndarray, np.ndarray]:
    """The ``k`` largest skin weights of each vertex (indices and renormalised values), cached per array and
    ``k``. ``k=None`` keeps every non-zero (as many as the vertex with the most), so the sparse blend is the
    dense one for any weights; the mirror's ``k=6`` truncates weights with more influences (MakeHuman's have six)."""
    key = (id(weights), k)
    hit = _SPARSE_CACHE.get(key)
    if hit is not None and hit[0] is weights:
        return hit[1], hit[2]
    if k is None:
        k = max(1, int(np.count_nonzero(weights, axis=1).max(initial=0)))
    idx = np.ascontiguousarray(np.argsort(-weights, axis=1)[:, :k])  # contiguous once, not per blend call
    w = np.take_along_axis(weights, idx, 1)
    w = w / w.sum(1, keepdims=True)
    if len(_SPARSE_CACHE) >= 8:
        _SPARSE_CACHE.clear()
    _SPARSE_CACHE[key] = (weights, idx, w)  # holding the array keeps its id from being reused
    return idx, w


@njit(cache=True)
def blend_skin(transforms, weight_idx, weight_val, rest_vertices, rest_normals):
    """Linear blend skinning ``(sum_k w_k T_k) v`` of points, and of unit normals when ``rest_normals`` has a row
    per point (an empty (0, 3) array: points only), skipping the zero weights (2.2 bones of the six on average):
    the numpy gather of (n, 6, 4, 4) transforms and its two einsums took ~2 ms for a 6k body, this ~0.2
    (MIRFAST2). ``transforms`` (B, 3, 4); returns ``(V, N)``, ``N`` empty without normals."""
    n, k_max = weight_idx.shape
    with_normals = rest_normals.shape[0] == n
    V = np.empty((n, 3))
    N = np.empty((n if with_normals else 0, 3))
    M = np.empty((3, 4))
    for i in range(n):
        M[:] = 0.0
        for k in range(k_max):
            w = weight_val[i, k]
            if w == 0.0:
                continue
            T = transforms[weight_idx[i, k]]
            for r in range(3):
                for c in range(4):
                    M[r, c] += w * T[r, c]
        for r in range(3):
            V[i, r] = M[r, 0] * rest_vertices[i, 0] + M[r, 1] * rest_vertices[i, 1] + M[r, 2] * rest_vertices[i, 2] \
                + M[r, 3]
        if with_normals:
            length = 0.0
            for r in range(3):
                N[i, r] = M[r, 0] * rest_normals[i, 0] + M[r, 1] * rest_normals[i, 1] + M[r, 2] * rest_normals[i, 2]
                length += N[i, r] * N[i, r]
            length = max(np.sqrt(length), 1e-12)
            for r in range(3):
                N[i, r] /= length
    return V, N


@njit(cache=True)
def blend_skin_pair(source_transforms, target_transforms, weight_idx, weight_val, source_rest, target_rest):
    """:func:`blend_skin` of two bodies with the same skin weights (points only): each vertex's weights read once,
    its two blended matrices accumulated in one loop; the same sums in the same order as two calls."""
    n, k_max = weight_idx.shape
    Vs = np.empty((n, 3))
    Vt = np.empty((n, 3))
    Ms = np.empty((3, 4))
    Mt = np.empty((3, 4))
    for i in range(n):
        Ms[:] = 0.0
        Mt[:] = 0.0
        for k in range(k_max):
            w = weight_val[i, k]
            if w == 0.0:
                continue
            S = source_transforms[weight_idx[i, k]]
            T = target_transforms[weight_idx[i, k]]
            for r in range(3):
                for c in range(4):
                    Ms[r, c] += w * S[r, c]
                    Mt[r, c] += w * T[r, c]
        for r in range(3):
            Vs[i, r] = Ms[r, 0] * source_rest[i, 0] + Ms[r, 1] * source_rest[i, 1] + Ms[r, 2] * source_rest[i, 2] \
                + Ms[r, 3]
            Vt[i, r] = Mt[r, 0] * target_rest[i, 0] + Mt[r, 1] * target_rest[i, 1] + Mt[r, 2] * target_rest[i, 2] \
                + Mt[r, 3]
    return Vs, Vt
