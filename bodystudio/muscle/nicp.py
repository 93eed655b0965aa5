"""Surface registration, Sec. 5 of Arm-Muscle Capture (Robertini et al. 2013): non-rigid ICP.

A similarity transform (scale, rotation, translation) found on the first frame places the template
near the point cloud (Sec. 5.1); then each iteration pairs every template vertex with its closest
depth point, rejects pairs with the six filters of Sec. 5.2 and deforms the template towards the
kept points with As-Rigid-As-Possible regularisation (Sorkine & Alexa 2007, Sec. 5.3).

ARAP is our own implementation with soft positional constraints and one sparse factorisation per
ICP iteration (the rotations' local/global sweeps reuse it). libigl's ``arap_precomputation`` /
``arap_solve`` only take hard constraints ``(b, bc)``: every noisy depth point would become an exact
interpolation target, and the precomputation must be redone whenever the filtered set changes, i.e.
at every ICP iteration (measured comparison in ``arap_deformation``).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import splu
from scipy.spatial import cKDTree

from bodystudio.errors import InputError
from bodystudio.geometry.mesh import vertex_normals

# --- Sec. 5.1 rigid alignment ---------------------------------------------------------------------

def similarity_transform(source: np.ndarray, target: np.ndarray, weights: np.ndarray | None = None,
                         with_scale: bool = True) -> tuple[float, np.ndarray, np.ndarray]:
    """Weighted least-squares similarity ``(s, R, t)`` with ``s R source + t ~ target`` (Umeyama 1991)."""
    source = np.asarray(source, np.float64)
    target = np.asarray(target, np.float64)
    w = np.ones(len(source)) if weights is None else np.asarray(weights, np.float64)
    w = w / w.sum()
    mu_s, mu_t = w @ source, w @ target
    A, B = source - mu_s, target - mu_t
    cov = (B * w[:, None]).T @ A
    U, S, Vt = np.linalg.svd(cov)
    D = np.eye(3)
    D[2, 2] = np.sign(np.linalg.det(U @ Vt)) or 1.0
    R = U @ D @ Vt
    var = float(w @ np.einsum("kd,kd->k", A, A))
    s = float(np.trace(np.diag(S) @ D) / var) if with_scale and var > 0 else 1.0
    return s, R, mu_t - s * R @ mu_s


def apply_similarity(transform: tuple[float, np.ndarray, np.ndarray], P: np.ndarray) -> np.ndarray:
    """``s R P + t`` for points (N, 3)."""
    s, R, t = transform
    return s * np.asarray(P, np.float64) @ R.T + t


def rigid_alignment_with_scale(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray,
                               sensor_center: np.ndarray, vertex_mask: np.ndarray | None = None,
                               initial: tuple[float, np.ndarray, np.ndarray] | None = None,
                               iterations: int = 30, max_distance_m: float = 0.03, with_scale: bool = True,
                               scale_range: tuple[float, float] = (0.85, 1.15), with_rotation: bool = True,
                               ) -> tuple[float, np.ndarray, np.ndarray]:
    """Global similarity (scale + rotation + translation) of the template onto the first frame, Sec. 5.1.

    ICP with scale: the template vertices in ``vertex_mask`` that face the sensor are paired with their
    closest depth points (pairs longer than ``max_distance_m`` dropped; three times that in the first
    iterations of a coarse start) and the Umeyama similarity of the pairs is composed into the
    estimate. The start is ``initial`` or the translation that matches the centroids of the visible
    template and the cloud (the subject holds the base pose in the first frame, fronto-parallel).
    The paper applies the transform to every point cloud of the sequence; we apply its inverse to the
    template, which is the same registration in world (sensor) coordinates.
    """
    V = np.asarray(vertices, np.float64)
    P = np.asarray(points, np.float64)
    if len(P) < 10:
        raise InputError(f"rigid alignment needs a point cloud, got {len(P)} points")
    mask = np.ones(len(V), bool) if vertex_mask is None else np.asarray(vertex_mask, bool)
    tree = cKDTree(P)
    coarse = initial is None
    if initial is None:
        N = vertex_normals(V, np.asarray(faces))
        front = mask & (np.einsum("kd,kd->k", N, sensor_center - V) > 0)
        initial = (1.0, np.eye(3), P.mean(0) - V[front].mean(0))
    T = initial
    for it in range(iterations):
        X = apply_similarity(T, V)
        N = vertex_normals(X, np.asarray(faces))
        front = mask & (np.einsum("kd,kd->k", N, sensor_center - X) > 0)
        d, j = tree.query(X[front])
        keep = d < (3 * max_distance_m if coarse and it < 5 else max_distance_m)
        if keep.sum() < 10:
            raise InputError("rigid alignment found fewer than 10 template-to-depth pairs; "
                             "start the sequence with the arm in the template's base pose facing the sensor")
        if with_rotation:
            step = similarity_transform(X[front][keep], P[j[keep]], with_scale=with_scale)
        else:
            step = (1.0, np.eye(3), (P[j[keep]] - X[front][keep]).mean(axis=0))
        s0, R0, t0 = T
        s1, R1, t1 = step
        s1 = float(np.clip(s1 * s0, *scale_range)) / s0
        T = (s1 * s0, R1 @ R0, s1 * R1 @ t0 + t1)
        if abs(s1 - 1) < 1e-6 and np.linalg.norm(t1) < 1e-6 and np.abs(R1 - np.eye(3)).max() < 1e-6:
            break
    return T


# --- Sec. 5.2 correspondences -------------------------------------------------------------------

@dataclass(frozen=True)
class CorrespondenceFilters:
    """Switches and thresholds of the six filters of Sec. 5.2 (angles in degrees, lengths in metres)."""

    arm_only: bool = True
    front_only: bool = True  # Eq. 1
    normals: bool = True  # Eq. 2
    neighbours: bool = True  # Eq. 3
    length: bool = True  # Eq. 4
    duplicates: bool = True
    T_N_deg: float = 45.0  # Eq. 2 normal angle threshold
    T_Ng_deg: float = 35.0  # Eq. 3 median neighbour angle threshold
    T_L_m: float = 0.008  # Eq. 4 deviation from l (see filter_correspondences: up to 2 T_L from the median)
    max_distance_m: float = 0.04  # pairs longer than this are never correspondences
    min_direction_m: float = 0.004  # Eq. 3 compares only pairs longer than this (shorter: noise)


@dataclass
class Correspondences:
    """Closest-point pairs of Sec. 5.2: vertex -> depth point, with the filters' verdict."""

    targets: np.ndarray  # (n, 3) closest depth point of every vertex
    target_normals: np.ndarray  # (n, 3)
    point_index: np.ndarray  # (n,) index into the cloud
    kept: np.ndarray  # (n,) bool, survived every enabled filter
    rejected_by: dict = field(default_factory=dict)  # filter name -> number of pairs it removed


def vertex_neighbourhoods(faces: np.ndarray, n_vertices: int, rings: int = 2) -> sp.csr_matrix:
    """Boolean sparse (n, n) adjacency of the ``rings``-ring mesh neighbourhood (without the vertex)."""
    F = np.asarray(faces)
    i = np.concatenate([F[:, 0], F[:, 1], F[:, 2], F[:, 1], F[:, 2], F[:, 0]])
    j = np.concatenate([F[:, 1], F[:, 2], F[:, 0], F[:, 0], F[:, 1], F[:, 2]])
    A = sp.csr_matrix((np.ones(len(i), bool), (i, j)), shape=(n_vertices, n_vertices))
    R = A.copy()
    for _ in range(rings - 1):
        R = (R + R @ A).astype(bool)
    R.setdiag(False)
    R.eliminate_zeros()
    return R.tocsr()


def _neighbour_medians(adjacency: sp.csr_matrix, values: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Per-vertex median of ``values`` over the valid entries of each neighbourhood row (NaN if none)."""
    n = adjacency.shape[0]
    indptr, indices = adjacency.indptr, adjacency.indices
    counts = np.diff(indptr)
    width = max(int(counts.max()) if n else 1, 1)
    table = np.full((n, width), np.nan)
    rows = np.repeat(np.arange(n), counts)
    cols = np.arange(len(indices)) - np.repeat(indptr[:-1], counts)
    table[rows, cols] = np.where(valid[indices], values[indices], np.nan)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN rows give NaN: no valid neighbour
        return np.nanmedian(table, axis=1)


def _neighbour_angle_medians(adjacency: sp.csr_matrix, vectors: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Eq. 3's alpha: median angle (rad) between each vector and its valid neighbours' vectors."""
    n = adjacency.shape[0]
    indptr, indices = adjacency.indptr, adjacency.indices
    counts = np.diff(indptr)
    rows = np.repeat(np.arange(n), counts)
    unit = vectors / np.maximum(np.linalg.norm(vectors, axis=1, keepdims=True), 1e-12)
    cos = np.clip(np.einsum("kd,kd->k", unit[rows], unit[indices]), -1.0, 1.0)
    angle = np.where(valid[indices], np.arccos(cos), np.nan)
    width = max(int(counts.max()) if n else 1, 1)
    table = np.full((n, width), np.nan)
    table[rows, np.arange(len(indices)) - np.repeat(indptr[:-1], counts)] = angle
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return np.nanmedian(table, axis=1)


def closest_point_correspondences(vertices: np.ndarray, points: np.ndarray, point_normals: np.ndarray,
                                  tree: cKDTree | None = None) -> Correspondences:
    """Closest depth point of every template vertex (Sec. 5.2, before filtering); all pairs kept."""
    tree = cKDTree(points) if tree is None else tree
    _, j = tree.query(np.asarray(vertices, np.float64))
    return Correspondences(points[j], point_normals[j], j, np.ones(len(vertices), bool), {})


def filter_correspondences(vertices: np.ndarray, normals: np.ndarray, pairs: Correspondences,
                           sensor_center: np.ndarray, arm_mask: np.ndarray, adjacency: sp.csr_matrix,
                           filters: CorrespondenceFilters = CorrespondenceFilters()) -> Correspondences:
    """The six correspondence filters of Sec. 5.2, applied in the paper's order.

    1. Arm vertices only: pairs of torso and hand vertices are dropped (``arm_mask``).
    2. Front side only (Eq. 1): ``arccos(n_v . -s) < pi/2``, the vertex normal must face the sensor
       (``s`` the viewing direction from the sensor centre to the vertex).
    3. Normals check (Eq. 2): ``arccos(n_p . n_v) < T_N`` between vertex and depth-point normals.
    4. Neighbours check (Eq. 3): the median angle between the correspondence vector ``c_i`` and those
       of the still-valid neighbours ``N(i)`` (the 2-ring) must stay below ``T_Ng``; pairs shorter
       than ``min_direction_m`` (their direction is sensor noise) are neither tested nor compared.
    5. Length limitation (Eq. 4): ``| ||c_i|| - l | < T_L``; pairs longer than ``max_distance_m`` are
       dropped as well. The paper's ``l`` is ``median({||c_i||, ||c_j||, j in N(i)})``; ours is the median of
       the two values ``{median_j ||c_j||, ||c_i||}``, i.e. their mean, so a pair may deviate up to
       ``2 T_L`` from its neighbourhood's median. The paper's form (tried in issue 17's mutation work)
       tracks the 15 deg elbow flexion of tests/muscle/test_capture.py worse: 17.6 vs 15.5 mm median
       forearm error after 10 iterations (start 32.9 mm), as it rejects three times as many pairs.
    6. Duplicates elimination: of the vertices paired with the same depth point, only the one whose
       normal agrees best with the point's normal keeps it.
    Returns a copy of ``pairs`` with ``kept`` and the per-filter rejection counts.
    """
    f = filters
    V = np.asarray(vertices, np.float64)
    kept = pairs.kept.copy()
    rejected: dict[str, int] = {}

    def apply(name: str, ok: np.ndarray) -> None:
        nonlocal kept
        rejected[name] = int((kept & ~ok).sum())
        kept = kept & ok

    c = pairs.targets - V
    length = np.linalg.norm(c, axis=1)
    if f.arm_only:
        apply("arm_only", np.asarray(arm_mask, bool))
    if f.front_only:
        s = V - np.asarray(sensor_center, np.float64)
        apply("front_only", np.einsum("kd,kd->k", normals, -s) > 0)
    if f.normals:
        cos = np.clip(np.einsum("kd,kd->k", pairs.target_normals, normals), -1, 1)
        apply("normals", np.arccos(cos) < np.radians(f.T_N_deg))
    if f.neighbours:
        # Directions of pairs shorter than the sensor noise are random: only longer ones are compared.
        longer = length > f.min_direction_m
        alpha = _neighbour_angle_medians(adjacency, c, kept & longer)
        apply("neighbours", ~longer | ~(alpha >= np.radians(f.T_Ng_deg)))  # no valid neighbour: keep
    if f.length:
        med = _neighbour_medians(adjacency, length, kept)
        med = np.where(np.isnan(med), length, np.median(np.c_[med, length], axis=1))
        apply("length", (np.abs(length - med) < f.T_L_m) & (length < f.max_distance_m))
    else:
        apply("max_distance", length < f.max_distance_m)
    if f.duplicates:
        cos = np.einsum("kd,kd->k", pairs.target_normals, normals)
        idx = np.nonzero(kept)[0]
        order = idx[np.lexsort((-cos[idx], pairs.point_index[idx]))]
        first = np.ones(len(order), bool)
        first[1:] = pairs.point_index[order][1:] != pairs.point_index[order][:-1]
        ok = np.ones(len(V), bool)
        ok[order[~first]] = False
        apply("duplicates", ok)
    return Correspondences(pairs.targets, pairs.target_normals, pairs.point_index, kept, rejected)


# --- Sec. 5.3 ARAP deformation ------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class ArapSystem:
    """Precomputed As-Rigid-As-Possible operators of a rest mesh (Sorkine & Alexa 2007)."""

    rest: np.ndarray  # (n, 3)
    edges: np.ndarray  # (e, 2) directed half-edges i -> j (both directions)
    edge_weights: np.ndarray  # (e,) cotangent weights w_ij (clamped positive)
    laplacian: sp.csr_matrix  # (n, n) sum_j w_ij (x_i - x_j)


def arap_system(rest: np.ndarray, faces: np.ndarray) -> ArapSystem:
    """Cotangent-weighted ARAP operators of the rest mesh, Eq. 3-9 of Sorkine & Alexa (2007)."""
    V = np.asarray(rest, np.float64)
    F = np.asarray(faces, np.int64)
    n = len(V)
    rows, cols, vals = [], [], []
    for k in range(3):
        i, j, o = F[:, k], F[:, (k + 1) % 3], F[:, (k + 2) % 3]
        a, b = V[i] - V[o], V[j] - V[o]
        cot = np.einsum("kd,kd->k", a, b) / np.maximum(np.linalg.norm(np.cross(a, b), axis=1), 1e-12)
        rows += [i, j]
        cols += [j, i]
        vals += [0.5 * cot, 0.5 * cot]
    W = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n))
    W.data = np.maximum(W.data, 1e-4)  # obtuse triangles: keep the energy convex and the system SPD
    W = W.tocoo()
    L = (sp.diags(np.asarray(W.sum(axis=1)).ravel()) - W).tocsr()
    return ArapSystem(V, np.c_[W.row, W.col], W.data, L)


def _best_rotations(system: ArapSystem, X: np.ndarray) -> np.ndarray:
    """Local step: per-vertex rotation R_i maximising tr(R_i S_i), S_i = sum_j w_ij e_ij e'_ij^T."""
    i, j = system.edges[:, 0], system.edges[:, 1]
    e = system.rest[i] - system.rest[j]
    e2 = X[i] - X[j]
    outer = system.edge_weights[:, None, None] * e[:, :, None] * e2[:, None, :]
    S = np.zeros((len(X), 3, 3))
    np.add.at(S, i, outer)
    U, _, Vt = np.linalg.svd(S)
    R = np.einsum("nji,nkj->nik", Vt, U)  # V U^T
    flip = np.linalg.det(R) < 0
    if flip.any():
        U[flip, :, 2] *= -1
        R[flip] = np.einsum("nji,nkj->nik", Vt[flip], U[flip])
    return R


def arap_deformation(system: ArapSystem, initial: np.ndarray, targets: np.ndarray, weights: np.ndarray,
                     data_weight: float = 2.0, iterations: int = 5) -> np.ndarray:
    """ARAP deformation (Sec. 5.3; Sorkine & Alexa 2007) pulled by soft point constraints.

    Minimises ``sum_ij w_ij ||(x_i - x_j) - R_i (p_i - p_j)||^2 + lambda sum_k a_k ||x_k - q_k||^2``
    (``p`` the rest mesh, ``q = targets``, ``a = weights`` per vertex, 0 = unconstrained,
    ``lambda = data_weight`` times the mean cotangent degree) by alternating the local rotation fit
    and the global sparse solve ``(L + lambda A) x = b(R) + lambda A q``, factorised once per call.

    Why our own: libigl's ``arap_precomputation``/``arap_solve`` take hard constraints only, so each
    noisy depth point would be interpolated exactly, and the precomputation must be redone whenever
    the kept set changes (every ICP iteration). Speed, measured on the 6k arm (1 050 vertices, half
    the arm vertices constrained, 4 sweeps, on the shared 2-core machine under load): libigl 16-39 ms
    including its precomputation, ours 78-89 ms, of which numpy's batched 3x3 SVD is ~70 %
    (a numba SVD loop and a numba Newton polar iteration were no faster). The ARAP is the largest
    cost of non-rigid ICP; a faster local step is open work.
    """
    X = np.asarray(initial, np.float64).copy()
    a = np.asarray(weights, np.float64)
    if a.max(initial=0.0) <= 0:
        return X
    L = system.laplacian
    lam = data_weight * float(L.diagonal().mean())
    solver = splu((L + sp.diags(lam * a)).tocsc())
    i, j = system.edges[:, 0], system.edges[:, 1]
    e = system.rest[i] - system.rest[j]
    rhs_data = lam * a[:, None] * np.asarray(targets, np.float64)
    for _ in range(iterations):
        R = _best_rotations(system, X)
        rot_e = 0.5 * np.einsum("eab,eb->ea", R[i] + R[j], e)
        b = np.zeros_like(X)
        np.add.at(b, i, system.edge_weights[:, None] * rot_e)
        X = solver.solve(b + rhs_data)
    return X


# --- non-rigid ICP ------------------------------------------------------------------------------

@dataclass(frozen=True)
class NicpOptions:
    """Non-rigid ICP of Sec. 5: iterations, ARAP data weight, and the Sec. 5.2 filters."""

    iterations: int = 6
    arap_iterations: int = 4
    data_weight: float = 1.0
    filters: CorrespondenceFilters = CorrespondenceFilters()
    point_to_plane: bool = True  # target = the vertex projected on the depth point's tangent plane


def plane_targets(vertices: np.ndarray, pairs: Correspondences) -> np.ndarray:
    """Each vertex projected onto the tangent plane of its depth point: ``v + ((p - v) . n_p) n_p``.

    The depth samples are ~3 mm apart and noisy: pulling a vertex onto the sample itself drags it
    sideways (measured on the 2k arm at its true position, noise-free depth: 1.6 mm median drift with
    point targets); the plane keeps the normal part of the pair only.
    """
    d = np.einsum("kd,kd->k", pairs.targets - vertices, pairs.target_normals)
    return vertices + d[:, None] * pairs.target_normals


def nonrigid_icp(system: ArapSystem, faces: np.ndarray, initial: np.ndarray, points: np.ndarray,
                 point_normals: np.ndarray, sensor_center: np.ndarray, arm_mask: np.ndarray,
                 adjacency: sp.csr_matrix, options: NicpOptions = NicpOptions(),
                 tree: cKDTree | None = None) -> tuple[np.ndarray, Correspondences]:
    """Non-rigid ICP of Sec. 5: closest points, the six filters (Sec. 5.2), ARAP towards the kept pairs (Sec. 5.3).

    ``system`` holds the ARAP rest shape (the aligned template or the model mesh); the deformation
    starts at ``initial`` (the previous frame's result). Returns the deformed vertices and the last
    correspondences.
    """
    tree = cKDTree(points) if tree is None else tree
    X = np.asarray(initial, np.float64).copy()
    pairs = None
    for _ in range(options.iterations):
        N = vertex_normals(X, faces)
        pairs = closest_point_correspondences(X, points, point_normals, tree)
        pairs = filter_correspondences(X, N, pairs, sensor_center, arm_mask, adjacency, options.filters)
        targets = plane_targets(X, pairs) if options.point_to_plane else pairs.targets
        X = arap_deformation(system, X, targets, pairs.kept.astype(np.float64), options.data_weight,
                             options.arap_iterations)
    return X, pairs
