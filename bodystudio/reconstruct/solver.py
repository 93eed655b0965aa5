"""The constraint solver of Rapid Skin §III.A/C (Algorithm 1, lines 4-8) and the §V linear baselines.

Constraints on the vertices ``V``:

* smoothness ``C_sm_i = sum_j w_ij (v_i - v_j) - delta_i`` (Eq. 9, cotangent weights summing to 1);
* silhouette ``C_sil_j = d_pl(R_j, v_i)``: distance of vertex ``i`` to the viewing ray ``R_j`` (Eq. 7);
* depth ``C_d = n . (v_i - q)``: point-to-plane distance to a Kinect depth point (our extension).

``gauss_seidel`` projects them one after the other with the Newton step of Eq. 3-4 and the
per-projection weight ``k' = 1 - (1 - k)^(1/Ni)``; ``jacobi`` computes every step from the same
positions and averages them per vertex (the paper's parallel/GPU path). ``cholesky`` and
``conjugate_gradient`` minimise the same energy ``sum k ||C||^2`` as linear Laplacian mesh editing
(LME) over all 3n coordinates (a ray constraint couples x, y and z).
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass
from functools import cached_property

import numba
import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from bodystudio.errors import InputError
from bodystudio.geometry.laplacian import DeltaOperator

SOLVERS = ("gs", "jacobi", "cholesky", "cg")


@dataclass(frozen=True, eq=False)
class SilhouetteConstraints:
    """Rim-vertex / viewing-ray pairs: vertex ids, ray origins and unit directions, weights ``k_sil``."""

    vertex: np.ndarray  # (m,) int64
    origin: np.ndarray  # (m, 3)
    direction: np.ndarray  # (m, 3) unit
    k: np.ndarray  # (m,) Eq. 10 weights in [0, 1]
    camera: np.ndarray | None = None  # (m,) camera index, for reports
    pixel_distance: np.ndarray | None = None  # (m,) initial |v_c - p_c| in pixels

    def __len__(self) -> int:
        return len(self.vertex)

    @classmethod
    def empty(cls) -> SilhouetteConstraints:
        return cls(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0),
                   np.zeros(0, np.int64), np.zeros(0))


@dataclass(frozen=True, eq=False)
class DepthConstraints:
    """Vertex / oriented depth point pairs for point-to-plane constraints."""

    vertex: np.ndarray  # (m,) int64
    point: np.ndarray  # (m, 3)
    normal: np.ndarray  # (m, 3) unit
    k: np.ndarray  # (m,)

    def __len__(self) -> int:
        return len(self.vertex)

    @classmethod
    def empty(cls) -> DepthConstraints:
        return cls(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0))


@dataclass(frozen=True, eq=False)
class ConstraintSet:
    """Everything one inner solve sees (Algorithm 1, line 3 output)."""

    delta: DeltaOperator
    delta_rest: np.ndarray  # (n, 3) delta coordinates of the initial mesh
    silhouette: SilhouetteConstraints
    depth: DepthConstraints
    k_sm: float = 1.0


@numba.njit(cache=True)
def _projection_weights(k, ni):
    r = np.empty_like(k)
    for c in range(k.shape[0]):
        r[c] = 1.0 - min(max(k[c], 0.0), 1.0)
    if ni & (ni - 1) == 0:  # Ni = 2^m (the default 8): m square roots, ~10x cheaper than pow, same to an ulp
        while ni > 1:
            for c in range(k.shape[0]):
                r[c] = np.sqrt(r[c])
            ni >>= 1
    else:
        for c in range(k.shape[0]):
            r[c] = r[c] ** (1.0 / ni)
    for c in range(k.shape[0]):
        r[c] = 1.0 - r[c]
    return r


def projection_weight(k: np.ndarray | float, inner_iterations: int) -> np.ndarray:
    """Per-projection weight ``k' = 1 - (1 - k)^(1/Ni)`` of Rapid Skin §III.C (from Müller et al. 2007)."""
    k = np.asarray(k, dtype=np.float64)
    return _projection_weights(k.ravel(), max(int(inner_iterations), 1)).reshape(k.shape)


def point_to_ray_distance(P: np.ndarray, origin: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """Shortest distance ``d_pl`` of points to 3D lines, Eq. 7 of Rapid Skin."""
    p = P - origin
    perp = p - np.sum(p * direction, axis=1, keepdims=True) * direction
    return np.linalg.norm(perp, axis=1)


def constraint_energy(V: np.ndarray, cs: ConstraintSet) -> float:
    """Energy ``sum k_sm ||C_sm||^2 + sum k_sil C_sil^2 + sum k_d C_d^2`` (Eq. 5 with squared norms)."""
    r_sm = cs.delta.apply(V) - cs.delta_rest
    e = cs.k_sm * float(np.sum(r_sm * r_sm))
    sil = cs.silhouette
    if len(sil):
        d = point_to_ray_distance(V[sil.vertex], sil.origin, sil.direction)
        e += float(np.sum(sil.k * d * d))
    dep = cs.depth
    if len(dep):
        r = np.sum((V[dep.vertex] - dep.point) * dep.normal, axis=1)
        e += float(np.sum(dep.k * r * r))
    return e


# --- Gauss-Seidel constraint projection (Algorithm 1, lines 4-8) ---------------------------------

#: Every fast-math flag but ``reassoc``: FMA contraction stays, while the 1-ring sums keep their written
#: order (with ``reassoc`` LLVM vectorises them for rings of >= 8 vertices, a path the usual valence-6 ring
#: never takes but whose setup every vertex pays; measured 5-7 % slower at 13K).
_FASTMATH = {"nnan", "ninf", "nsz", "arcp", "contract", "afn"}


@numba.njit(cache=True)
def _smoothness_layout(indptr, indices, weights):
    """uint32 row pointers and flat neighbour offsets ``3 j``, and ``1 / |grad C_sm_i|^2 =
    1 / (1 + sum_j w_ij^2)`` for the vector-valued smoothness constraint (Eq. 9), in one pass."""
    n = len(indptr) - 1
    ptr32 = np.empty(n + 1, np.uint32)
    offsets = np.empty(len(indices), np.uint32)
    inv_grad2 = np.empty(n)
    ptr32[0] = indptr[0]
    for i in range(n):
        ptr32[i + 1] = indptr[i + 1]
        s = 1.0
        for e in range(indptr[i], indptr[i + 1]):
            offsets[e] = 3 * indices[e]
            s += weights[e] * weights[e]
        inv_grad2[i] = 1.0 / s
    return ptr32, offsets, inv_grad2


@dataclass(frozen=True, eq=False)
class _SmoothnessArrays:
    """A :class:`DeltaOperator` laid out for the compiled sweeps: uint32 row pointers and flat xyz
    neighbour offsets ``3 j`` (unsigned indices compile without numba's negative-index wraparound and
    halve the index traffic: ~20 % of a sweep), the weights ``w_ij`` and ``1 / |grad C_sm_i|^2``."""

    indptr: np.ndarray
    offsets: np.ndarray
    weights: np.ndarray
    reverse: np.ndarray
    inv_grad2: np.ndarray

    @cached_property
    def weights_t(self) -> np.ndarray:
        """``w_ji`` at the position of ``w_ij``: the weight of ``i`` in ``j``'s ring (Jacobi's gather)."""
        return np.ascontiguousarray(self.weights[self.reverse])


#: One layout per delta operator: Algorithm 1 solves ``No`` times (and a sequence every frame) with it.
_SMOOTHNESS_ARRAYS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _smoothness_arrays(delta: DeltaOperator) -> _SmoothnessArrays:
    arrays = _SMOOTHNESS_ARRAYS.get(delta)
    if arrays is None:
        if max(3 * delta.n_vertices, len(delta.indices)) >= 2**32:
            raise InputError(f"{delta.n_vertices} vertices are too many for the uint32 solver indices")
        # The entry must not refer to ``delta`` itself, or the weak key would never be collected.
        weights = np.ascontiguousarray(delta.weights, dtype=np.float64)
        ptr32, offsets, inv_grad2 = _smoothness_layout(delta.indptr, delta.indices, weights)
        arrays = _SmoothnessArrays(ptr32, offsets, weights, delta.reverse, inv_grad2)
        _SMOOTHNESS_ARRAYS[delta] = arrays
    return arrays


@numba.njit(cache=True, fastmath=_FASTMATH, boundscheck=False, error_model="numpy")
def _gauss_seidel_sweeps(V, indptr, offsets, weights, inv_grad2, k_sm_prime, delta_rest, sil_vertex, sil_origin,
                         sil_dir, sil_k, dep_vertex, dep_point, dep_normal, dep_k, n_sweeps):
    """``n_sweeps`` Gauss-Seidel sweeps: silhouette, then depth, then smoothness constraints in vertex
    order, each smoothness step scaled by ``f_i = k'_sm / |grad C_sm_i|^2``. ``V`` is updated in place."""
    n = V.shape[0]
    Vf = V.reshape(-1)  # views of the C-contiguous (n, 3) arrays, addressed by the flat offsets 3 j
    rest = delta_rest.reshape(-1)
    for _ in range(n_sweeps):
        # Silhouette constraints (Eq. 7): |grad d_pl| = 1, so the step removes k' of the offset to the ray.
        for c in range(sil_vertex.shape[0]):
            i = sil_vertex[c]
            px = V[i, 0] - sil_origin[c, 0]
            py = V[i, 1] - sil_origin[c, 1]
            pz = V[i, 2] - sil_origin[c, 2]
            t = px * sil_dir[c, 0] + py * sil_dir[c, 1] + pz * sil_dir[c, 2]
            k = sil_k[c]
            V[i, 0] -= k * (px - t * sil_dir[c, 0])
            V[i, 1] -= k * (py - t * sil_dir[c, 1])
            V[i, 2] -= k * (pz - t * sil_dir[c, 2])
        # Depth constraints: point-to-plane distance, gradient = the plane normal.
        for c in range(dep_vertex.shape[0]):
            i = dep_vertex[c]
            r = ((V[i, 0] - dep_point[c, 0]) * dep_normal[c, 0] + (V[i, 1] - dep_point[c, 1]) * dep_normal[c, 1]
                 + (V[i, 2] - dep_point[c, 2]) * dep_normal[c, 2])
            k = dep_k[c] * r
            V[i, 0] -= k * dep_normal[c, 0]
            V[i, 1] -= k * dep_normal[c, 1]
            V[i, 2] -= k * dep_normal[c, 2]
        # Smoothness constraints (Eq. 9), Newton step of Eq. 4 on v_i and its 1-ring: r = f_i C_sm_i,
        # v_i -= r, v_j += w_ij r.
        for i in range(n):
            a = indptr[i]
            b = indptr[i + 1]
            i3 = 3 * i
            f = k_sm_prime * inv_grad2[i]
            if b - a == 6:
                # Regular vertex (valence 6, most of a body template): the ring's offsets and weights stay
                # in registers from the residual to the update (saves ~8 % of a sweep).
                j0, j1, j2 = offsets[a], offsets[a + 1], offsets[a + 2]
                j3, j4, j5 = offsets[a + 3], offsets[a + 4], offsets[a + 5]
                w0, w1, w2 = weights[a], weights[a + 1], weights[a + 2]
                w3, w4, w5 = weights[a + 3], weights[a + 4], weights[a + 5]
                rx = f * (Vf[i3] - rest[i3] - ((w0 * Vf[j0] + w1 * Vf[j1]) + (w2 * Vf[j2] + w3 * Vf[j3])
                                                + (w4 * Vf[j4] + w5 * Vf[j5])))
                ry = f * (Vf[i3 + 1] - rest[i3 + 1] - ((w0 * Vf[j0 + 1] + w1 * Vf[j1 + 1])
                                                        + (w2 * Vf[j2 + 1] + w3 * Vf[j3 + 1])
                                                        + (w4 * Vf[j4 + 1] + w5 * Vf[j5 + 1])))
                rz = f * (Vf[i3 + 2] - rest[i3 + 2] - ((w0 * Vf[j0 + 2] + w1 * Vf[j1 + 2])
                                                        + (w2 * Vf[j2 + 2] + w3 * Vf[j3 + 2])
                                                        + (w4 * Vf[j4 + 2] + w5 * Vf[j5 + 2])))
                Vf[i3] -= rx
                Vf[i3 + 1] -= ry
                Vf[i3 + 2] -= rz
                for j, w in ((j0, w0), (j1, w1), (j2, w2), (j3, w3), (j4, w4), (j5, w5)):
                    Vf[j] += w * rx
                    Vf[j + 1] += w * ry
                    Vf[j + 2] += w * rz
                continue
            # Any other valence: two interleaved partial sums (measured ~5 % faster than one running sum).
            ax = ay = az = bx = by = bz = 0.0
            for e in range(a, b - 1, 2):
                j = offsets[e]
                w = weights[e]
                ax += w * Vf[j]
                ay += w * Vf[j + 1]
                az += w * Vf[j + 2]
                j = offsets[e + 1]
                w = weights[e + 1]
                bx += w * Vf[j]
                by += w * Vf[j + 1]
                bz += w * Vf[j + 2]
            if (b - a) & 1:
                j = offsets[b - 1]
                w = weights[b - 1]
                ax += w * Vf[j]
                ay += w * Vf[j + 1]
                az += w * Vf[j + 2]
            rx = f * (Vf[i3] - rest[i3] - (ax + bx))
            ry = f * (Vf[i3 + 1] - rest[i3 + 1] - (ay + by))
            rz = f * (Vf[i3 + 2] - rest[i3 + 2] - (az + bz))
            Vf[i3] -= rx
            Vf[i3 + 1] -= ry
            Vf[i3 + 2] -= rz
            for e in range(a, b):
                j = offsets[e]
                w = weights[e]
                Vf[j] += w * rx
                Vf[j + 1] += w * ry
                Vf[j + 2] += w * rz
    return V


def _check(V: np.ndarray, cs: ConstraintSet) -> np.ndarray:
    V = np.array(V, dtype=np.float64, order="C", copy=True)
    if V.ndim != 2 or V.shape[1] != 3 or len(V) != cs.delta.n_vertices:
        raise InputError(f"vertices must be ({cs.delta.n_vertices}, 3) for this template, got {V.shape}")
    return V


def _vertex_ids(vertex: np.ndarray, n: int) -> np.ndarray:
    """Constraint vertex ids as uint32 for the sweeps, which do not check bounds: checked here."""
    if len(vertex) and not (0 <= vertex.min() and vertex.max() < n):
        raise InputError(f"constraint vertex ids must lie in [0, {n}), got [{vertex.min()}, {vertex.max()}]")
    return np.ascontiguousarray(vertex, dtype=np.uint32)


def gauss_seidel(V: np.ndarray, cs: ConstraintSet, inner_iterations: int = 8,
                 callback=None) -> np.ndarray:
    """Sequential constraint projection, Eq. 3-4 and Algorithm 1 of Rapid Skin (lines 4-8).

    Runs ``inner_iterations`` sweeps over all constraints with weights ``k' = 1 - (1 - k)^(1/Ni)``.
    ``callback(iteration, V)`` is called after every sweep when given (for convergence plots).
    """
    V = _check(V, cs)
    sm = _smoothness_arrays(cs.delta)
    sil, dep = cs.silhouette, cs.depth
    k_sil = projection_weight(sil.k, inner_iterations)
    k_dep = projection_weight(dep.k, inner_iterations)
    k_sm = float(projection_weight(cs.k_sm, inner_iterations))
    n = len(V)
    rest = np.ascontiguousarray(cs.delta_rest, dtype=np.float64)
    args = (sm.indptr, sm.offsets, sm.weights, sm.inv_grad2, k_sm, rest,
            _vertex_ids(sil.vertex, n), np.ascontiguousarray(sil.origin), np.ascontiguousarray(sil.direction), k_sil,
            _vertex_ids(dep.vertex, n), np.ascontiguousarray(dep.point), np.ascontiguousarray(dep.normal), k_dep)
    if callback is None:
        return _gauss_seidel_sweeps(V, *args, int(inner_iterations))
    for it in range(int(inner_iterations)):
        V = _gauss_seidel_sweeps(V, *args, 1)
        callback(it + 1, V)
    return V


# --- Jacobi (parallel) variant ------------------------------------------------------------------

@numba.njit(cache=True, fastmath=_FASTMATH, parallel=True, boundscheck=False, error_model="numpy")
def _jacobi_sweeps(V, indptr, offsets, weights, weights_t, inv_grad2, k_sm_prime, delta_rest, sil_ptr, sil_origin,
                   sil_dir, sil_k, dep_ptr, dep_point, dep_normal, dep_k, relaxation, n_sweeps):
    """``n_sweeps`` Jacobi sweeps, smoothness steps scaled by ``f_i = k'_sm / |grad C_sm_i|^2``; ``V`` is
    updated in place."""
    n = V.shape[0]
    Vf = V.reshape(-1)  # flat views addressed by the offsets 3 j, as in the Gauss-Seidel sweep
    rest = delta_rest.reshape(-1)
    r_sm = np.empty(3 * n)  # f_i C_sm_i: the smoothness constraint's Newton step, Eq. 4
    for _ in range(n_sweeps):
        for i in numba.prange(n):
            i3 = 3 * i
            rx = Vf[i3] - rest[i3]
            ry = Vf[i3 + 1] - rest[i3 + 1]
            rz = Vf[i3 + 2] - rest[i3 + 2]
            for e in range(indptr[i], indptr[i + 1]):
                j = offsets[e]
                w = weights[e]
                rx -= w * Vf[j]
                ry -= w * Vf[j + 1]
                rz -= w * Vf[j + 2]
            f = k_sm_prime * inv_grad2[i]
            r_sm[i3] = f * rx
            r_sm[i3 + 1] = f * ry
            r_sm[i3 + 2] = f * rz
        # Gather every constraint's correction of vertex i and apply the average: this reads V only at i
        # and r_sm everywhere, so no two threads touch one vertex and V can be written in the same pass.
        for i in numba.prange(n):
            i3 = 3 * i
            ax = -r_sm[i3]
            ay = -r_sm[i3 + 1]
            az = -r_sm[i3 + 2]
            for e in range(indptr[i], indptr[i + 1]):
                j = offsets[e]
                w = weights_t[e]  # weight of i in j's 1-ring
                ax += w * r_sm[j]
                ay += w * r_sm[j + 1]
                az += w * r_sm[j + 2]
            for c in range(sil_ptr[i], sil_ptr[i + 1]):
                px = V[i, 0] - sil_origin[c, 0]
                py = V[i, 1] - sil_origin[c, 1]
                pz = V[i, 2] - sil_origin[c, 2]
                t = px * sil_dir[c, 0] + py * sil_dir[c, 1] + pz * sil_dir[c, 2]
                k = sil_k[c]
                ax -= k * (px - t * sil_dir[c, 0])
                ay -= k * (py - t * sil_dir[c, 1])
                az -= k * (pz - t * sil_dir[c, 2])
            for c in range(dep_ptr[i], dep_ptr[i + 1]):
                r = ((V[i, 0] - dep_point[c, 0]) * dep_normal[c, 0] + (V[i, 1] - dep_point[c, 1]) * dep_normal[c, 1]
                     + (V[i, 2] - dep_point[c, 2]) * dep_normal[c, 2])
                k = dep_k[c] * r
                ax -= k * dep_normal[c, 0]
                ay -= k * dep_normal[c, 1]
                az -= k * dep_normal[c, 2]
            count = (1 + indptr[i + 1] - indptr[i] + sil_ptr[i + 1] - sil_ptr[i] + dep_ptr[i + 1] - dep_ptr[i])
            g = relaxation / count
            V[i, 0] += ax * g
            V[i, 1] += ay * g
            V[i, 2] += az * g
    return V


@numba.njit(cache=True)
def _group_by_vertex(vertex, n, a, b, k):
    """Constraints ``(a (m, 3), b (m, 3), k (m,))`` stably grouped by vertex, with CSR pointers ``(n + 1,)``:
    a counting sort, O(m + n), where an argsort and fancy indexing cost ~5 ms a frame at 13K."""
    m = vertex.shape[0]
    ptr = np.zeros(n + 1, np.int64)
    for c in range(m):
        ptr[vertex[c] + 1] += 1
    for i in range(n):
        ptr[i + 1] += ptr[i]
    fill = ptr[:-1].copy()
    a_out = np.empty((m, 3))
    b_out = np.empty((m, 3))
    k_out = np.empty(m)
    for c in range(m):
        d = fill[vertex[c]]
        fill[vertex[c]] += 1
        for x in range(3):
            a_out[d, x] = a[c, x]
            b_out[d, x] = b[c, x]
        k_out[d] = k[c]
    return ptr, a_out, b_out, k_out


def jacobi(V: np.ndarray, cs: ConstraintSet, inner_iterations: int = 32, relaxation: float = 1.5,
           callback=None) -> np.ndarray:
    """Parallel constraint projection: every step of Eq. 4 from the same ``V``, averaged per vertex.

    Rapid Skin §III.C's GPU variant; it needs more inner iterations than :func:`gauss_seidel`. The
    per-projection weights use ``inner_iterations`` as ``Ni``; ``relaxation`` scales the averaged step.
    """
    V = _check(V, cs)
    n = len(V)
    sil, dep = cs.silhouette, cs.depth
    sil_ptr, sil_origin, sil_dir, sil_k = _group_by_vertex(_vertex_ids(sil.vertex, n), n, sil.origin, sil.direction,
                                                           projection_weight(sil.k, inner_iterations))
    dep_ptr, dep_point, dep_normal, dep_k = _group_by_vertex(_vertex_ids(dep.vertex, n), n, dep.point, dep.normal,
                                                             projection_weight(dep.k, inner_iterations))
    sm = _smoothness_arrays(cs.delta)
    k_sm = float(projection_weight(cs.k_sm, inner_iterations))
    args = (sm.indptr, sm.offsets, sm.weights, sm.weights_t, sm.inv_grad2, k_sm,
            np.ascontiguousarray(cs.delta_rest, dtype=np.float64), sil_ptr, sil_origin, sil_dir, sil_k,
            dep_ptr, dep_point, dep_normal, dep_k, float(relaxation))
    if callback is None:
        return _jacobi_sweeps(V, *args, int(inner_iterations))
    for it in range(int(inner_iterations)):
        V = _jacobi_sweeps(V, *args, 1)
        callback(it + 1, V)
    return V


# --- Linear Laplacian mesh editing baselines (Rapid Skin §V) -----------------------------------

#: Weight of a tiny Tikhonov term on every vertex: keeps the normal equations positive definite (L has
#: the translations in its null space) and their sparsity pattern fixed, so CHOLMOD's symbolic analysis
#: is done once per frame and only the numeric factorisation is redone after each re-matching.
_TIKHONOV = 1e-12
_PATTERN_FILL = 1e-30


def laplacian_gram_matrix(delta: DeltaOperator) -> sp.csr_matrix:
    """``kron(L^T L, I3)``: the smoothness part of the LME normal equations over interleaved xyz."""
    L = delta.matrix
    return sp.kron(L.T @ L, sp.identity(3), format="csr")


class LMESystem:
    """Linear Laplacian mesh editing on one template/frame: ``L^T L`` built once, Cholesky analysed once.

    The energy is :func:`constraint_energy`; a ray constraint ``|(I - d d^T)(v - o)|^2`` couples the
    x, y, z of its vertex, so the unknowns are all ``3n`` coordinates (interleaved xyz).
    """

    def __init__(self, delta: DeltaOperator):
        self.delta = delta
        self.gram = laplacian_gram_matrix(delta)
        n = delta.n_vertices
        base = 3 * np.arange(n)
        a = np.arange(3)
        self._block_rows = (base[:, None, None] + a[None, :, None] + 0 * a[None, None, :]).ravel()
        self._block_cols = (base[:, None, None] + 0 * a[None, :, None] + a[None, None, :]).ravel()
        fill = np.full((n, 3, 3), _PATTERN_FILL) + (_TIKHONOV - _PATTERN_FILL) * np.eye(3)[None]
        self._block_fill = fill.ravel()
        self._symbolic = None

    def normal_equations(self, cs: ConstraintSet) -> tuple[sp.csr_matrix, np.ndarray]:
        """``A x = b`` minimising :func:`constraint_energy` (plus the negligible Tikhonov term)."""
        n = self.delta.n_vertices
        L = self.delta.matrix
        b = (cs.k_sm * (L.T @ cs.delta_rest)).ravel()
        blocks = np.zeros((n, 3, 3))
        sil = cs.silhouette
        if len(sil):
            d = sil.direction
            kP = sil.k[:, None, None] * (np.eye(3)[None] - d[:, :, None] * d[:, None, :])
            np.add.at(blocks, sil.vertex, kP)
            np.add.at(b.reshape(-1, 3), sil.vertex, np.einsum("mij,mj->mi", kP, sil.origin))
        dep = cs.depth
        if len(dep):
            nn = dep.k[:, None, None] * dep.normal[:, :, None] * dep.normal[:, None, :]
            np.add.at(blocks, dep.vertex, nn)
            rhs = (dep.k * np.sum(dep.normal * dep.point, axis=1))[:, None] * dep.normal
            np.add.at(b.reshape(-1, 3), dep.vertex, rhs)
        C = sp.csr_matrix((blocks.ravel() + self._block_fill, (self._block_rows, self._block_cols)),
                          shape=(3 * n, 3 * n))
        return sp.csr_matrix(cs.k_sm * self.gram + C), b

    def cholesky(self, cs: ConstraintSet) -> np.ndarray:
        """Exact minimiser by sparse Cholesky (CHOLMOD through cvxopt; SuperLU if cvxopt is missing)."""
        A, b = self.normal_equations(cs)
        try:
            import cvxopt
            import cvxopt.cholmod
        except ImportError:  # pragma: no cover - cvxopt is a dependency; keep a working fallback
            return spla.splu(A.tocsc(), permc_spec="COLAMD").solve(b).reshape(-1, 3)
        coo = A.tocoo()
        M = cvxopt.spmatrix(coo.data, coo.row.astype(int), coo.col.astype(int), size=A.shape)
        if self._symbolic is None:
            self._symbolic = cvxopt.cholmod.symbolic(M)
        cvxopt.cholmod.numeric(M, self._symbolic)
        x = cvxopt.matrix(b)
        cvxopt.cholmod.solve(self._symbolic, x)
        return np.array(x).reshape(-1, 3)


def lme_normal_equations(cs: ConstraintSet) -> tuple[sp.csr_matrix, np.ndarray]:
    """Normal equations of :func:`constraint_energy` over ``x = V.ravel()`` (see :class:`LMESystem`)."""
    return LMESystem(cs.delta).normal_equations(cs)


def cholesky(V: np.ndarray, cs: ConstraintSet, lme: LMESystem | None = None) -> np.ndarray:
    """Exact LME minimiser by sparse Cholesky, Rapid Skin §V baseline.

    The constraint set changes at every contour re-matching, so the matrix is factored numerically
    anew each call (the paper's argument); ``L^T L`` and the symbolic analysis are reused via ``lme``.
    """
    _check(V, cs)
    return (lme or LMESystem(cs.delta)).cholesky(cs)


def conjugate_gradient(V: np.ndarray, cs: ConstraintSet, inner_iterations: int = 8, lme: LMESystem | None = None,
                       callback=None) -> np.ndarray:
    """``inner_iterations`` conjugate-gradient steps on the LME normal equations, warm-started at ``V``."""
    V = _check(V, cs)
    A, b = (lme or LMESystem(cs.delta)).normal_equations(cs)
    x = V.ravel().copy()
    r = b - A @ x
    p = r.copy()
    # einsum dots: BLAS dot products spin up threads, which costs more than the dot on a busy machine
    rr = float(np.einsum("i,i->", r, r))
    for it in range(int(inner_iterations)):
        if rr <= 1e-30:
            break
        Ap = A @ p
        alpha = rr / float(np.einsum("i,i->", p, Ap))
        x += alpha * p
        r -= alpha * Ap
        rr_new = float(np.einsum("i,i->", r, r))
        p = r + (rr_new / rr) * p
        rr = rr_new
        if callback is not None:
            callback(it + 1, x.reshape(-1, 3))
    return x.reshape(-1, 3)


def solve_constraints(V: np.ndarray, cs: ConstraintSet, solver: str = "gs", inner_iterations: int = 8,
                      lme: LMESystem | None = None) -> np.ndarray:
    """One inner solve (Algorithm 1, lines 4-8) with the chosen solver: gs, jacobi, cholesky or cg."""
    if solver == "gs":
        return gauss_seidel(V, cs, inner_iterations)
    if solver == "jacobi":
        return jacobi(V, cs, inner_iterations)
    if solver == "cholesky":
        return cholesky(V, cs, lme)
    if solver == "cg":
        return conjugate_gradient(V, cs, inner_iterations, lme)
    raise InputError(f"unknown solver {solver!r}; valid: {', '.join(SOLVERS)}")
