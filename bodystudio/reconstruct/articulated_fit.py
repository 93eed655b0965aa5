"""Joints without a tracker: an articulated fit of the body model to the visual hull, Rapid Skin Sec. IV.

Rapid Skin initialises its template from skeleton joints (Sec. IV.A) and, instead of a Kinect, derives
them from a volumetric model of the silhouettes (contribution 4). We replace the depth-map pose
estimator the paper borrows from OpenNI by an articulated ICP of our own skinned template to the visual
hull (:mod:`bodystudio.reconstruct.visual_hull`):

- unknowns: root translation and rotation and the local rotations of the main bones (spine, neck,
  clavicles, upper and lower arms, thighs, calves); all other bones keep the initial pose;
- data terms, re-matched every iteration: template vertex -> closest hull surface point and hull
  surface point -> closest template vertex, both point-to-plane, with normal compatibility and Huber
  weights (the hull is a superset of the body, so template points inside the hull are down-weighted);
- a Gauss-Newton step in world-frame rotation increments about each bone's head (the Jacobian of linear
  blend skinning is then ``d v_i = sum_j dw_j x (q_ij - a_ij p_j)``, with ``q_ij`` the part of vertex i
  carried by bone j's subtree), Levenberg damping, and a weak prior towards the initial local rotations
  (the hull cannot see limb twist);
- initialised from the previous frame's pose, or from the A-pose (rest pose) at the hull centroid under
  a few root yaw angles and per-arm raise hypotheses, keeping the best by the symmetric surface
  distance; a warm start that does not converge falls back to the A-pose initialisation;
- a uniform template scale is estimated too, so a generic template fits any subject's proportions.

The fitted skeleton gives Kinect v2 joints (:func:`bodystudio.body.kinect.kinect_joints`), so the result
feeds the same pose initialisation (:func:`bodystudio.reconstruct.pose_init.initialise_pose`) as a tracker.

The same Gauss-Newton step also refines a pose initialised from tracker joints
(:func:`refine_bone_transforms`): it works on the Eq. 11 bone transforms directly, so the tracked bone
lengths stay and only the segments' rotations (and the root's translation) move to fit the hull.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace

import igl
import numba
import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation
from threadpoolctl import ThreadpoolController

from bodystudio.body.kinect import kinect_joint_names, kinect_joints
from bodystudio.body.pose import Pose
from bodystudio.body.skinning import forward_kinematics, posed_joints
from bodystudio.errors import InputError
from bodystudio.geometry.rotation import rotvec_matrix_into
from bodystudio.reconstruct.visual_hull import VisualHull, visual_hull

log = logging.getLogger(__name__)

#: Bones whose rotations the fit estimates (plus the root translation).
FIT_BONES = ("Root", "spine_02", "neck_01", "clavicle_l", "clavicle_r", "upperarm_l", "upperarm_r",
             "lowerarm_l", "lowerarm_r", "thigh_l", "thigh_r", "calf_l", "calf_r")
#: When a warm start also runs the A-pose initialisation (ArticulatedFitParams.warm_fallback).
WARM_FALLBACKS = ("never", "unconverged", "always")
#: Kinect v2 joints the fitted bones determine (hands, feet tips and thumbs follow unfitted bones).
MAJOR_JOINTS = ("SpineBase", "SpineMid", "Neck", "Head", "SpineShoulder", "ShoulderLeft", "ElbowLeft",
                "WristLeft", "ShoulderRight", "ElbowRight", "WristRight", "HipLeft", "KneeLeft", "AnkleLeft",
                "HipRight", "KneeRight", "AnkleRight")


@dataclass(frozen=True)
class ArticulatedFitParams:
    """Settings of the articulated hull fit.

    ``iterations``: Gauss-Newton iterations (each re-matches); ``coarse_iterations``: per hypothesis of
    the A-pose search; ``robust_m``: Huber threshold of the point-to-plane residuals; ``inside_weight``:
    weight of template points inside the hull (the hull over-estimates the body); ``prior_weight``:
    prior on the limbs' local rotations, cost per squared radian (a 1 cm data residual costs 1e-4);
    ``hull_samples``: hull surface points matched to the template; ``yaw_candidates_deg``: root yaws
    tried from the A-pose; ``arm_raise_candidates_deg``: each arm is also tried reset to the A-pose and
    raised by these angles in the frontal plane (ICP alone does not swing an arm from the body's side to
    above the shoulder, and may fold the elbow instead); ``fit_scale``: also estimate a uniform template
    scale about the world origin (a generic template for any subject, as Sec. IV.A scales its template
    to the skeleton); ``warm_fallback``: when a warm start also runs the A-pose search and keeps the
    better fit: ``never``, ``unconverged`` (the warm fit hit the iteration limit, the sign of a wrong
    basin after a large motion between frames) or ``always``.
    """

    iterations: int = 40
    coarse_iterations: int = 10
    robust_m: float = 0.03
    inside_weight: float = 0.5
    prior_weight: float = 0.05
    damping: float = 1e-3
    max_step_rad: float = 0.25
    max_step_m: float = 0.10
    hull_samples: int = 3000
    yaw_candidates_deg: tuple[float, ...] = (0.0, 90.0, 180.0, 270.0)
    arm_raise_candidates_deg: tuple[float, ...] = (45.0, 90.0)
    tolerance: float = 1e-4
    fit_scale: bool = True
    warm_fallback: str = "unconverged"
    max_step_log_scale: float = 0.03


@dataclass(frozen=True, eq=False)
class ArticulatedFit:
    """Result of one fit: pose, Kinect v2 joints (25, 3), fit error, iterations run and template scale.

    ``pose`` poses the template scaled by ``scale`` about the world origin (:func:`scaled_body`).
    """

    pose: Pose
    joints: np.ndarray
    fit_error_m: float
    iterations: int
    scale: float = 1.0
    converged: bool = True


def _fit_bone_indices(skeleton) -> np.ndarray:
    missing = [b for b in FIT_BONES if b not in skeleton.bone_names]
    if missing:
        raise InputError(f"articulated fit needs the game_engine rig; bones {', '.join(missing)} are missing")
    return np.array([skeleton.index(b) for b in FIT_BONES])


def _subtree_matrix(skeleton, bones: np.ndarray) -> np.ndarray:
    """``D[k, j]``: bone k lies in the subtree of fitted bone ``bones[j]`` (itself included)."""
    B = skeleton.n_bones
    D = np.zeros((B, len(bones)))
    for j, b in enumerate(bones):
        inside = np.zeros(B, bool)
        inside[b] = True
        for k in range(B):  # parents come before children
            p = skeleton.parents[k]
            if p >= 0 and inside[p]:
                inside[k] = True
        D[:, j] = inside
    return D


_BLAS: ThreadpoolController | None = None
_SPARSE_CACHE: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}


def _one_blas_thread():
    """A context holding BLAS to one thread. ``threadpool_limits`` scans the loaded libraries at every entry
    (1.5-2.6 ms CPU, once per fit call); a controller made once keeps that scan (0.04 ms)."""
    global _BLAS
    if _BLAS is None:
        _BLAS = ThreadpoolController()
    return _BLAS.limit(limits=1, user_api="blas")


def _sparse_weights(weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Skin weights as the ``K`` (max non-zeros per vertex) largest: bone indices and weights ``(n, K)``,
    cached per array (the argsort is ~1 ms at 2.5K, once per fit call otherwise)."""
    hit = _SPARSE_CACHE.get(id(weights))
    if hit is not None and hit[0] is weights:
        return hit[1], hit[2]
    K = int(max(1, (weights > 0).sum(axis=1).max()))
    idx = np.argsort(-weights, axis=1)[:, :K]
    # contiguous int64 / float64, so a fit's np.ascontiguousarray hands back these very arrays (no copy a call)
    out = np.ascontiguousarray(idx, dtype=np.int64), np.ascontiguousarray(np.take_along_axis(weights, idx, axis=1),
                                                                          dtype=np.float64)
    if len(_SPARSE_CACHE) >= 8:
        _SPARSE_CACHE.clear()
    _SPARSE_CACHE[id(weights)] = (weights, *out)  # holding the array keeps its id from being reused
    return out


def _skin_parts(body, pose: Pose, bone_idx: np.ndarray, bone_w: np.ndarray):
    """Weighted per-influence skinned positions ``C (n, K, 3)`` (``w_ik S_k v_i``), posed frames ``M``."""
    M = forward_kinematics(body.skeleton, pose)
    S = M @ np.linalg.inv(body.skeleton.rest_frames)
    Sk = S[bone_idx]  # (n, K, 4, 4)
    Sv = np.einsum("nkij,nj->nki", Sk[:, :, :3, :3], body.vertices) + Sk[:, :, :3, 3]
    return bone_w[:, :, None] * Sv, M


@numba.njit(cache=True)
def skinned_parts(T, rest, bone_idx, bone_w):
    """Weighted per-influence skinned positions ``C[i, k] = w_ik (T_b v_i + t_b)`` ``(n, K, 3)`` and their sum,
    the LBS vertices ``(n, 3)`` (Eq. 12 of Rapid Skin), of the sparse skin weights ``(n, K)``."""
    n, K = bone_idx.shape
    C = np.zeros((n, K, 3))
    V = np.zeros((n, 3))
    for i in range(n):
        x, y, z = rest[i, 0], rest[i, 1], rest[i, 2]
        for k in range(K):
            w = bone_w[i, k]
            if w == 0.0:
                continue
            b = bone_idx[i, k]
            for r in range(3):
                c = w * (T[b, r, 0] * x + T[b, r, 1] * y + T[b, r, 2] * z + T[b, r, 3])
                C[i, k, r] = c
                V[i, r] += c
    return C, V


@numba.njit(cache=True)
def data_normal_equations(C, bone_idx, bone_w, D, heads, rows, r, w, G):
    """Gauss-Newton normal equations ``H = J^T W J``, ``g = J^T W r`` of the data term of
    :func:`refine_bone_transforms` without forming ``J``: a row is ``[G_i, lever_ij x G_i for each segment j]``
    (root translation, then the segments' rotations about their heads), ``lever_ij`` the vertex's skinned
    parts carried by segment j minus its share of the head, zero for segments the vertex does not follow;
    only those non-zero blocks are accumulated (a vertex follows a few of the 18 segments)."""
    n, n_seg = bone_idx.shape[0], D.shape[1]  # every segment listed for every vertex: the scan of all 18
    seg_ptr = np.arange(n + 1) * n_seg
    seg = np.empty(n * n_seg, np.int64)
    for i in range(n):
        for j in range(n_seg):
            seg[i * n_seg + j] = j
    return data_normal_equations_listed(C, bone_idx, bone_w, D, heads, rows, r, w, G, seg_ptr, seg)


@numba.njit(cache=True)
def vertex_segments(bone_idx, D):
    """The fitted segments each vertex follows, CSR ``(ptr, seg)`` in ascending segment order: ``j`` with some
    influence ``k`` of the vertex in segment j's subtree (``D[bone_idx[i, k], j] != 0``). Fixed for a fit, so
    :func:`data_normal_equations_listed` skips the other segments without looking at them."""
    n, K = bone_idx.shape
    n_seg = D.shape[1]
    ptr = np.zeros(n + 1, np.int64)
    seg = np.empty(n * n_seg, np.int64)
    m = 0
    for i in range(n):
        for j in range(n_seg):
            hit = False
            for k in range(K):
                if D[bone_idx[i, k], j] != 0.0:
                    hit = True
            if hit:
                seg[m] = j
                m += 1
        ptr[i + 1] = m
    return ptr, seg[:m]


@numba.njit(cache=True)
def quaternion_rotation_matrices(rotvecs):
    """Rotation matrices of rotation vectors by the unit quaternion ``(sin(a/2) w/a, cos(a/2))`` (Rodrigues'
    formula in quaternion form, scipy's ``Rotation.from_rotvec(w).as_matrix()`` compiled: the same formulas and
    small-angle series; issue 15's frame time, rec15j)."""
    n = rotvecs.shape[0]
    out = np.empty((n, 3, 3))
    for i in range(n):
        rotvec_matrix_into(rotvecs[i, 0], rotvecs[i, 1], rotvecs[i, 2], out[i])
    return out


@numba.njit(cache=True)
def rotation_vector_of_matrix(m):
    """Rotation vector of a rotation matrix: Markley's quaternion (the largest of the trace and the diagonal
    picks the stable formula) and its log ``2 atan2(|q_xyz|, q_w) q_xyz / |q_xyz|``, scipy's
    ``Rotation.from_matrix(m).as_rotvec()`` compiled without its re-orthogonalisation (the matrices here are
    products of rotations; issue 15's frame time, rec15j)."""
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    q = np.empty(4)
    choice, best = 0, m[0, 0]  # the first largest of (m00, m11, m22, trace), as argmax picks it
    for d in (1, 2):
        if m[d, d] > best:
            choice, best = d, m[d, d]
    if tr > best:
        choice = 3
    if choice == 3:
        q[0], q[1], q[2], q[3] = m[2, 1] - m[1, 2], m[0, 2] - m[2, 0], m[1, 0] - m[0, 1], 1.0 + tr
    else:
        i = choice
        j = (i + 1) % 3
        k = (j + 1) % 3
        q[i] = 1.0 - tr + 2.0 * m[i, i]
        q[j] = m[j, i] + m[i, j]
        q[k] = m[k, i] + m[i, k]
        q[3] = m[k, j] - m[j, k]
    qn = np.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    if q[3] < 0.0:
        qn = -qn
    x, y, z, w = q[0] / qn, q[1] / qn, q[2] / qn, q[3] / qn
    angle = 2.0 * np.arctan2(np.sqrt(x * x + y * y + z * z), w)
    if angle <= 1e-3:
        a2 = angle * angle
        scale = 2.0 + a2 / 12.0 + 7.0 * a2 * a2 / 2880.0
    else:
        scale = angle / np.sin(angle / 2.0)
    return scale * x, scale * y, scale * z


@numba.njit(cache=True)
def rotation_vectors_of_matrices(matrices):
    """:func:`rotation_vector_of_matrix` of each of ``(n, 3, 3)`` matrices, ``(n, 3)``."""
    out = np.empty((matrices.shape[0], 3))
    for i in range(matrices.shape[0]):
        out[i, 0], out[i, 1], out[i, 2] = rotation_vector_of_matrix(matrices[i])
    return out


@numba.njit(cache=True)
def segment_prior_gradient(Q, fitted_parent, prior_segments, prior_weight, g):
    """Adds the prior's gradient ``prior_weight Q_p log(Q_p^T Q_j)`` of each segment with a refined parent to
    ``g`` (the rotation block of segment j at ``3 + 3 j``), compiled (issue 15's frame time, rec15j)."""
    rel = np.empty((3, 3))
    for j in prior_segments:
        p = max(fitted_parent[j], 0)
        for a in range(3):
            for b in range(3):
                rel[a, b] = Q[p, 0, a] * Q[j, 0, b] + Q[p, 1, a] * Q[j, 1, b] + Q[p, 2, a] * Q[j, 2, b]
        rx, ry, rz = rotation_vector_of_matrix(rel)
        for a in range(3):
            g[3 + 3 * j + a] += prior_weight * (Q[p, a, 0] * rx + Q[p, a, 1] * ry + Q[p, a, 2] * rz)


@numba.njit(cache=True)
def rotate_segments(T, Q, dw, heads, order, sub_ptr, sub_idx, child_ptr, child_idx):
    """Each refined segment ``j`` (leaves first) and its subtree rotated by ``exp(dw_j)`` about its head: ``T_b <-
    [R_j, h_j - R_j h_j] T_b`` for the bones ``b`` of its subtree, ``Q_c <- R_j Q_c`` for its refined descendants
    (the Gauss-Newton update of :func:`refine_bone_transforms`), compiled (issue 15's frame time, rec15j)."""
    R = quaternion_rotation_matrices(dw)
    tmp = np.empty((4, 4))
    tq = np.empty((3, 3))
    for j in order:
        Rj = R[j]
        off = np.empty(3)
        for a in range(3):
            off[a] = heads[j, a] - (Rj[a, 0] * heads[j, 0] + Rj[a, 1] * heads[j, 1] + Rj[a, 2] * heads[j, 2])
        for s in range(sub_ptr[j], sub_ptr[j + 1]):
            b = sub_idx[s]
            for a in range(3):
                for c in range(4):
                    tmp[a, c] = (Rj[a, 0] * T[b, 0, c] + Rj[a, 1] * T[b, 1, c] + Rj[a, 2] * T[b, 2, c]
                                 + off[a] * T[b, 3, c])
            for a in range(3):
                for c in range(4):
                    T[b, a, c] = tmp[a, c]
        for s in range(child_ptr[j], child_ptr[j + 1]):
            ci = child_idx[s]
            for a in range(3):
                for c in range(3):
                    tq[a, c] = Rj[a, 0] * Q[ci, 0, c] + Rj[a, 1] * Q[ci, 1, c] + Rj[a, 2] * Q[ci, 2, c]
            for a in range(3):
                for c in range(3):
                    Q[ci, a, c] = tq[a, c]


_SEGMENT_CACHE: dict = {}


def _vertex_segments_cached(bone_idx: np.ndarray, D: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`vertex_segments` memoised on the skin's index array (the same object for a body's weights,
    :func:`_sparse_weights`) and the segments: a tracked sequence fits the same template every frame."""
    key = (id(bone_idx), D.shape, D.tobytes())
    hit = _SEGMENT_CACHE.get(key)
    if hit is None or hit[0] is not bone_idx:
        if len(_SEGMENT_CACHE) >= 8:
            _SEGMENT_CACHE.clear()
        hit = _SEGMENT_CACHE[key] = (bone_idx, *vertex_segments(bone_idx, D))  # holding it keeps its id unique
    return hit[1], hit[2]


@numba.njit(cache=True)
def data_normal_equations_listed(C, bone_idx, bone_w, D, heads, rows, r, w, G, seg_ptr, seg):
    """:func:`data_normal_equations` reading each row's segments from :func:`vertex_segments` instead of
    scanning all of them (issue 15's frame time, rec15i): the same terms in the same order, so the same ``H`` and
    ``g`` bit for bit (tested)."""
    n_seg = D.shape[1]
    n_par = 3 + 3 * n_seg
    H = np.zeros((n_par, n_par))
    g = np.zeros(n_par)
    K = bone_idx.shape[1]
    cols = np.empty(n_par, np.int64)
    vals = np.empty(n_par)
    for m in range(rows.shape[0]):
        i = rows[m]
        gx, gy, gz = G[m, 0], G[m, 1], G[m, 2]
        cols[0], cols[1], cols[2] = 0, 1, 2
        vals[0], vals[1], vals[2] = gx, gy, gz
        nnz = 3
        for e in range(seg_ptr[i], seg_ptr[i + 1]):
            j = seg[e]
            a = 0.0
            lx = 0.0
            ly = 0.0
            lz = 0.0
            for k in range(K):
                d = D[bone_idx[i, k], j]
                if d != 0.0:
                    a += bone_w[i, k] * d
                    lx += d * C[i, k, 0]
                    ly += d * C[i, k, 1]
                    lz += d * C[i, k, 2]
            if a == 0.0:
                continue
            lx -= a * heads[j, 0]
            ly -= a * heads[j, 1]
            lz -= a * heads[j, 2]
            base = 3 + 3 * j
            cols[nnz], cols[nnz + 1], cols[nnz + 2] = base, base + 1, base + 2
            vals[nnz] = ly * gz - lz * gy
            vals[nnz + 1] = lz * gx - lx * gz
            vals[nnz + 2] = lx * gy - ly * gx
            nnz += 3
        wm = w[m]
        rm = r[m]
        for p in range(nnz):  # cols ascend, so the upper triangle; mirrored below
            wv = wm * vals[p]
            g[cols[p]] += wv * rm
            for q in range(p, nnz):
                H[cols[p], cols[q]] += wv * vals[q]
    for p in range(n_par):
        for q in range(p):
            H[p, q] = H[q, p]
    return H, g


def _huber_weights(r: np.ndarray, delta: float) -> np.ndarray:
    a = np.abs(r)
    return np.where(a <= delta, 1.0, delta / np.maximum(a, 1e-12))


def symmetric_hull_distance(V: np.ndarray, F: np.ndarray, hull: VisualHull) -> float:
    """Fit error (m): mean of the mean surface distances template -> hull and hull -> template."""
    d_th = np.sqrt(igl.point_mesh_squared_distance(V, hull.vertices, hull.faces)[0])
    d_ht = np.sqrt(igl.point_mesh_squared_distance(hull.vertices, V, F)[0])
    return float(0.5 * (d_th.mean() + d_ht.mean()))


def a_pose_at_hull(body, hull: VisualHull, yaw_deg: float = 0.0) -> Pose:
    """The template's rest (A-) pose turned by ``yaw_deg`` about the vertical and centred on the hull centroid."""
    skel = body.skeleton
    root = _fit_bone_indices(skel)[0]
    A = skel.rest_frames[root]
    R_world = Rotation.from_euler("y", yaw_deg, degrees=True).as_matrix()
    rotations = np.zeros((skel.n_bones, 3))
    rotations[root] = Rotation.from_matrix(A[:3, :3].T @ R_world @ A[:3, :3]).as_rotvec()
    head = A[:3, 3]
    center = body.vertices.mean(axis=0)
    translation = hull.centroid - (head + R_world @ (center - head))
    return Pose(rotations, translation)


def body_facing(body, pose: Pose) -> np.ndarray:
    """The body's facing direction (rest +z turned by the root rotation), e.g. for the virtual depth camera."""
    root = _fit_bone_indices(body.skeleton)[0]
    A = body.skeleton.rest_frames[root, :3, :3]
    R_world = A @ Rotation.from_rotvec(pose.rotations[root]).as_matrix() @ A.T
    return R_world @ np.array([0.0, 0.0, 1.0])


def raise_arm(body, pose: Pose, side: str, degrees: float) -> Pose:
    """``pose`` with the upper arm ``side`` ('l' or 'r') abducted by ``degrees`` in the body's frontal plane."""
    skel = body.skeleton
    j = skel.index(f"upperarm_{side}")
    M = forward_kinematics(skel, pose)
    P = M[j, :3, :3] @ Rotation.from_rotvec(pose.rotations[j]).as_matrix().T  # parent frame of the bone
    # Facing +z, the left arm points to +x and rises by a positive rotation about the facing axis.
    sign = 1.0 if side == "l" else -1.0
    omega = sign * np.radians(degrees) * body_facing(body, pose)
    rotations = np.array(pose.rotations, dtype=np.float64)
    rotations[j] = (Rotation.from_rotvec(P.T @ omega) * Rotation.from_rotvec(rotations[j])).as_rotvec()
    return Pose(rotations, np.array(pose.translation, dtype=np.float64))


def scaled_body(body, scale: float):
    """The template ``body`` uniformly scaled by ``scale`` about the world origin (feet stay on y = 0)."""
    skel = body.skeleton
    return replace(body, vertices=body.vertices * scale,
                   skeleton=replace(skel, heads=skel.heads * scale, tails=skel.tails * scale))


def articulated_fit(body, hull: VisualHull, init: Pose, params: ArticulatedFitParams | None = None,
                    iterations: int | None = None, scale: float = 1.0) -> ArticulatedFit:
    """Articulated ICP of the skinned template ``body`` to the visual hull from pose ``init`` (Sec. IV).

    ``init`` poses the template scaled by ``scale`` (the initial scale, refined when ``fit_scale``).
    """
    if not scale > 0:
        raise InputError(f"template scale must be positive, got {scale}")
    # The normal equations are tiny (40 unknowns): multi-threaded BLAS only adds contention.
    with _one_blas_thread():
        return _articulated_fit(body, hull, init, params or ArticulatedFitParams(), iterations, float(scale))


def _articulated_fit(body, hull: VisualHull, init: Pose, params: ArticulatedFitParams,
                     iterations: int | None, scale: float) -> ArticulatedFit:
    # Posing the template scaled by s with root translation t equals s times the unscaled template
    # posed with translation t / s, so the fit runs on the unscaled template and d v / d log s = v.
    n_iter = params.iterations if iterations is None else iterations
    skel = body.skeleton
    bones = _fit_bone_indices(skel)
    D = _subtree_matrix(skel, bones)
    a = body.weights @ D  # (n, J): weight of each fitted subtree on each vertex
    bone_idx, bone_w = _sparse_weights(body.weights)
    Dk = D[bone_idx]  # (n, K, J): influence k of vertex i lies in fitted subtree j
    nJ = len(bones)
    n_par = 4 + 3 * nJ
    prior = np.asarray(init.rotations, dtype=np.float64)[bones]
    rotations = np.array(init.rotations, dtype=np.float64)
    translation = np.array(init.translation, dtype=np.float64) / scale  # of the unscaled template
    hull_pts = hull.vertices
    hull_nrm = hull.normals
    step = max(1, len(hull_pts) // max(params.hull_samples, 1))
    sample = np.arange(0, len(hull_pts), step)
    hull_tree = cKDTree(hull_pts)
    prior_sqrt = np.sqrt(params.prior_weight)
    robust = params.robust_m
    it, converged = 0, False
    while it < n_iter:
        it += 1
        pose = Pose(rotations, translation)
        C, M = _skin_parts(body, pose, bone_idx, bone_w)
        V = scale * C.sum(axis=1)
        N = np.nan_to_num(igl.per_vertex_normals(V, body.faces))
        heads = M[bones, :3, 3]
        lever = scale * (np.einsum("nkd,nkj->njd", C, Dk) - a[:, :, None] * heads[None])  # r_ij (n, J, 3)

        # template -> hull: point-to-plane on the hull's tangent plane
        _, k = hull_tree.query(V)
        n_h = hull_nrm[k]
        ok1 = np.einsum("ij,ij->i", N, n_h) > 0.2
        r1 = np.einsum("ij,ij->i", V - hull_pts[k], n_h)
        w1 = _huber_weights(r1, robust) * np.where(r1 < 0, params.inside_weight, 1.0) * ok1
        J1 = np.concatenate([scale * n_h, np.einsum("ij,ij->i", n_h, V)[:, None],
                             np.cross(lever, n_h[:, None, :]).reshape(len(V), -1)], axis=1)

        # hull -> template: point-to-plane on the template's tangent plane
        P = hull_pts[sample]
        _, i2 = cKDTree(V).query(P)
        n_t = N[i2]
        ok2 = np.einsum("ij,ij->i", n_t, hull_nrm[sample]) > 0.2
        r2 = np.einsum("ij,ij->i", V[i2] - P, n_t)
        w2 = _huber_weights(r2, robust) * ok2
        J2 = np.concatenate([scale * n_t, np.einsum("ij,ij->i", n_t, V[i2])[:, None],
                             np.cross(lever[i2], n_t[:, None, :]).reshape(len(P), -1)], axis=1)

        J = np.concatenate([J1, J2])
        r = np.concatenate([r1, r2])
        w = np.concatenate([w1, w2])
        H = J.T @ (w[:, None] * J)
        g = J.T @ (w * r)
        # prior on local rotations of the limbs (not the root): d theta_local ~ P_j^T d omega_world
        local_frames = M[bones, :3, :3] @ Rotation.from_rotvec(rotations[bones]).as_matrix().transpose(0, 2, 1)
        for j in range(1, nJ):
            Pj = local_frames[j]
            cols = slice(4 + 3 * j, 7 + 3 * j)
            rp = prior_sqrt * (rotations[bones[j]] - prior[j])
            Jp = prior_sqrt * Pj.T
            H[cols, cols] += Jp.T @ Jp
            g[cols] += Jp.T @ rp
        if not params.fit_scale:
            H[3, :], H[:, 3], g[3] = 0.0, 0.0, 0.0
        H[np.diag_indices(n_par)] += params.damping * (np.diag(H).mean() + 1e-12)
        delta = -np.linalg.solve(H, g)
        dt, dlog_s = delta[:3], delta[3]
        dw = delta[4:].reshape(nJ, 3)
        # Clamp the step (Gauss-Newton on a linearised rotation is only trusted near the current pose).
        shrink = min(1.0, params.max_step_m / max(np.linalg.norm(dt) * scale, 1e-12),
                     params.max_step_rad / max(np.linalg.norm(dw, axis=1).max(), 1e-12),
                     params.max_step_log_scale / max(abs(dlog_s), 1e-12))
        dt, dw, dlog_s = dt * shrink, dw * shrink, dlog_s * shrink
        # world-frame increments: v -> v + s dt + v dlog_s + dw x lever; in the unscaled frame the
        # translation moves by dt and, as all of v is scaled, nothing else changes
        translation = translation + dt
        scale *= float(np.exp(dlog_s))
        for j, b in enumerate(bones):
            local = Rotation.from_rotvec(local_frames[j].T @ dw[j]) * Rotation.from_rotvec(rotations[b])
            rotations[b] = local.as_rotvec()
        if (np.linalg.norm(dt) * scale < params.tolerance and np.abs(dw).max() < params.tolerance * 10
                and abs(dlog_s) < params.tolerance):
            converged = True
            break
    pose = Pose(rotations, translation)
    V, _ = body.pose(pose)
    heads, tails = posed_joints(skel, pose)
    joints = scale * kinect_joints(skel, heads, tails, "v2")
    return ArticulatedFit(Pose(rotations, scale * translation), joints,
                          symmetric_hull_distance(scale * V, body.faces, hull), it, scale, converged)


def fit_body_to_hull(body, hull: VisualHull, previous_pose: Pose | None = None,
                     params: ArticulatedFitParams | None = None, previous_scale: float = 1.0) -> ArticulatedFit:
    """Pose of ``body`` fitted to ``hull``: warm-started from ``previous_pose`` (of the template scaled by
    ``previous_scale``, as a previous :class:`ArticulatedFit` gives them), else from the A-pose at the
    hull centroid under each candidate root yaw, then per-arm raise hypotheses, the best refined."""
    params = params or ArticulatedFitParams()
    if params.warm_fallback not in WARM_FALLBACKS:
        raise InputError(f"unknown warm_fallback {params.warm_fallback!r}; valid: {', '.join(WARM_FALLBACKS)}")
    if previous_pose is not None:
        if previous_pose.rotations.shape != (body.skeleton.n_bones, 3):
            raise InputError(f"previous pose has {len(previous_pose.rotations)} bones, the body "
                             f"{body.skeleton.n_bones}")
        warm = articulated_fit(body, hull, previous_pose, params, scale=previous_scale)
        if params.warm_fallback == "always" or (params.warm_fallback == "unconverged" and not warm.converged):
            cold = _fit_from_a_pose(body, hull, params)
            log.debug("hull fit: warm start %s (%.4f m), A-pose start %.4f m",
                      "converged" if warm.converged else "did not converge", warm.fit_error_m, cold.fit_error_m)
            return warm if warm.fit_error_m <= cold.fit_error_m else cold
        return warm
    return _fit_from_a_pose(body, hull, params)


def _fit_from_a_pose(body, hull: VisualHull, params: ArticulatedFitParams) -> ArticulatedFit:
    if not params.yaw_candidates_deg:
        raise InputError("articulated fit from the A-pose needs at least one root yaw candidate")
    candidates = [articulated_fit(body, hull, a_pose_at_hull(body, hull, yaw), params, params.coarse_iterations)
                  for yaw in params.yaw_candidates_deg]
    errors = [c.fit_error_m for c in candidates]
    log.debug("hull fit: yaw candidates %s -> fit errors %s m", params.yaw_candidates_deg, np.round(errors, 4))
    best = candidates[int(np.argmin(errors))]
    for side in ("l", "r"):
        reset = np.array(best.pose.rotations)
        for bone in (f"upperarm_{side}", f"lowerarm_{side}"):
            reset[body.skeleton.index(bone)] = 0.0
        straight = Pose(reset, best.pose.translation)
        trials = [articulated_fit(body, hull, raise_arm(body, straight, side, deg), params,
                                  params.coarse_iterations, best.scale) for deg in params.arm_raise_candidates_deg]
        for trial in trials:
            if trial.fit_error_m < best.fit_error_m:
                best = trial
        log.debug("hull fit: arm %s raise candidates -> fit errors %s m", side,
                  np.round([t.fit_error_m for t in trials], 4))
    refined = articulated_fit(body, hull, best.pose, params, scale=best.scale)
    return refined if refined.fit_error_m <= best.fit_error_m else best


def hull_joints(cameras, masks, body, previous_pose: Pose | None = None, voxel_m: float = 0.015,
                params: ArticulatedFitParams | None = None, bounds=None,
                previous_scale: float = 1.0) -> tuple[np.ndarray, Pose, float]:
    """Kinect v2 joints ``(25, 3)`` from silhouettes alone, Rapid Skin contribution 4 / Sec. IV.

    Visual hull of ``masks`` (camera name -> (H, W) bool) seen by ``cameras``, then the articulated fit
    of ``body`` to it. Returns ``(joints_v2, pose, fit_error_m)``; pass ``pose`` of one frame as
    ``previous_pose`` of the next (the template scale is re-estimated every frame; pass the previous
    :attr:`ArticulatedFit.scale` as ``previous_scale`` to start from it, see :func:`fit_body_to_hull`).
    """
    hull = visual_hull(cameras, masks, bounds=bounds, voxel_m=voxel_m)
    fit = fit_body_to_hull(body, hull, previous_pose, params, previous_scale)
    return fit.joints, fit.pose, fit.fit_error_m


def joint_error_m(joints: np.ndarray, joints_gt: np.ndarray, names=MAJOR_JOINTS) -> float:
    """Mean Euclidean error (m) of Kinect v2 ``joints`` against ground truth over the joints ``names``."""
    index = {n: i for i, n in enumerate(kinect_joint_names("v2"))}
    unknown = [n for n in names if n not in index]
    if unknown:
        raise InputError(f"unknown Kinect v2 joint(s): {', '.join(unknown)}")
    sel = [index[n] for n in names]
    J, G = np.asarray(joints, float)[sel], np.asarray(joints_gt, float)[sel]
    return float(np.mean(np.linalg.norm(J - G, axis=1)))


#: Segments whose rotation the refinement of a tracker pose corrects (plus the root's rigid motion).
REFINE_BONES = ("pelvis", "spine_01", "spine_02", "neck_01", "clavicle_l", "clavicle_r", "upperarm_l",
                "upperarm_r", "lowerarm_l", "lowerarm_r", "hand_l", "hand_r", "thigh_l", "thigh_r", "calf_l", "calf_r",
                "foot_l", "foot_r")


#: The refined segments with the head apart from the neck (its pitch): used with smoothed joints
#: (``--joint-smoothing``), whose Neck -> Head direction is steady enough for the head's prior.
REFINE_BONES_WITH_HEAD = REFINE_BONES + ("head",)
#: Bones whose heads are the pelvis joints (SpineBase, HipLeft, HipRight) that ``pelvis_weight`` holds.
PELVIS_BONES = ("pelvis", "thigh_l", "thigh_r")


@dataclass(frozen=True)
class PoseRefineParams:
    """Settings of :func:`refine_bone_transforms`: Gauss-Newton ``iterations`` (each re-matches),
    ``prior_weight`` per squared radian of local correction (a 1 cm data residual costs 1e-4 per
    point), and the data-term settings shared with :class:`ArticulatedFitParams`."""

    iterations: int = 10
    prior_weight: float = 0.05
    bones: tuple[str, ...] = REFINE_BONES
    robust_m: float = 0.03
    inside_weight: float = 0.5
    damping: float = 1e-3
    max_step_rad: float = 0.15
    max_step_m: float = 0.05
    tolerance: float = 1e-4
    #: Stop when the data energy ``sum w r^2`` fell by less than this fraction since the previous iteration
    #: (0: run all ``iterations`` unless the step is below ``tolerance``).
    min_decrease: float = 0.0
    pelvis_weight: float = 0.0
    pelvis_bones: tuple[str, ...] = PELVIS_BONES
    #: The rotation bookkeeping of each iteration (the prior's relative rotations, the segments' update) in
    #: compiled code instead of scipy's ``Rotation`` and numpy's 4x4 products (issue 15's frame time, rec15j): the
    #: same formulas, not the same rounding (BLAS's products, scipy's re-orthogonalisation), so not bit-equal.
    compiled_rotations: bool = False


def refine_bone_transforms(body, transforms: np.ndarray, hull: VisualHull | None,
                           params: PoseRefineParams | None = None, data_term=None, anchors=None) -> np.ndarray:
    """Bone transforms ``(B, 4, 4)`` of a posed template corrected to fit the visual hull.

    ``transforms`` are the Eq. 11 bone transforms of :func:`bodystudio.reconstruct.pose_init.initialise_pose`
    (tracker joints: right bone lengths up to jitter, limb directions off by the joint noise). The
    Gauss-Newton step of :func:`articulated_fit` then rotates the root and each segment of
    :data:`REFINE_BONES` about its placed head (with its subtree) and translates the root; the bone
    stretches are kept, and a prior holds each segment's rotation relative to its parent near the
    tracker's (the hull does not see limb twist). The data term is template -> hull only: the hull is a
    superset of the body, so a template point outside it is surely wrong, while hull points in volume
    no camera carves away (between the thighs, under the arms) would pull limbs outward (with the
    hull -> template term as well, surface p90 was 0.3-1.1 mm worse on three test sequences).

    ``data_term(V, N) -> (rows, r, w, G)`` replaces the hull term (``hull`` may then be None): residuals
    ``r`` (m) of template vertices ``rows`` with weights ``w`` and gradients ``G = dr / dv`` ``(m, 3)``,
    e.g. the silhouette distance term of the tracker (:mod:`bodystudio.reconstruct.tracking`).
    ``anchors = (bones, rest_points, targets, weight)`` adds point terms: ``rest_points`` ``(m, 3)``
    carried rigidly by ``bones`` ``(m,)`` are pulled onto ``targets`` with ``weight`` per squared metre
    (the tracker's joints).
    """
    params = params or PoseRefineParams()
    if data_term is None:
        if hull is None:
            raise InputError("pose refinement needs a visual hull or a data term")
        data_term = hull_data_term(hull, params)
    transforms = np.asarray(transforms, dtype=np.float64)
    if params.pelvis_weight > 0:
        anchors = _merge_anchors(anchors, pelvis_anchors(body, transforms, params.pelvis_bones, params.pelvis_weight))
    with _one_blas_thread():
        return _refine_bone_transforms(body, transforms, data_term, params, anchors)


def pelvis_anchors(body, transforms: np.ndarray, bones=PELVIS_BONES, weight: float = 1.0):
    """Anchors holding the pelvis joints where the initial bone ``transforms`` put them.

    The heads of ``bones`` (pelvis, thighs: the tracker's SpineBase and hips) placed by ``transforms``
    (the Eq. 11 transforms of the frame's tracker joints), as ``(bones, rest_points, targets, weight)``
    for :func:`refine_bone_transforms`: the silhouettes fix the legs' ends but not the root's height,
    and with the tracker's per-frame bone lengths (3 % jitter, 1-2.5 cm over a leg) a leg fitted to
    its silhouette moves the whole pelvis up or down; the root joint itself has only the tracker's
    1 cm joint noise, so it is the better estimate of the pelvis height.
    """
    skel = body.skeleton
    missing = [b for b in bones if b not in skel.bone_names]
    if missing:
        raise InputError(f"pose refinement: the template has no pelvis bone(s) {', '.join(missing)}")
    ids = np.array([skel.index(b) for b in bones])
    rest = skel.heads[ids]
    T = np.asarray(transforms, dtype=np.float64)[ids]
    return ids, rest, np.einsum("mij,mj->mi", T[:, :3, :3], rest) + T[:, :3, 3], float(weight)


def _merge_anchors(a, b):
    """Two anchor sets as one; the weights are folded into per-point weights."""
    if a is None:
        return b
    n_a, n_b = len(a[0]), len(b[0])
    w = np.concatenate([np.broadcast_to(np.asarray(a[3], float), n_a), np.broadcast_to(np.asarray(b[3], float), n_b)])
    return (np.concatenate([a[0], b[0]]), np.concatenate([a[1], b[1]]), np.concatenate([a[2], b[2]]), w)


def hull_data_term(hull: VisualHull, params: PoseRefineParams):
    """Template -> hull point-to-plane residuals, Huber-weighted, inside points down-weighted (see
    :func:`refine_bone_transforms`), as a ``data_term(V, N) -> (rows, r, w, G)``."""
    hull_pts, hull_nrm = hull.vertices, hull.normals
    hull_tree = cKDTree(hull_pts)

    def term(V: np.ndarray, N: np.ndarray):
        _, k = hull_tree.query(V)
        n_h = hull_nrm[k]
        ok1 = np.einsum("ij,ij->i", N, n_h) > 0.2
        r = np.einsum("ij,ij->i", V - hull_pts[k], n_h)
        w = _huber_weights(r, params.robust_m) * np.where(r < 0, params.inside_weight, 1.0) * ok1
        return np.arange(len(V)), r, w, n_h

    return term


_FIT_SEGMENTS_CACHE: dict = {}


def _fit_segments_cached(skel, bone_names: tuple[str, ...]):
    """The refinement's segment bookkeeping of ``bone_names`` on ``skel``, made once per skeleton (rec15j: 0.3 ms a
    fit, one a tracked frame): the bone ids, the subtree matrix ``D``, each segment's nearest refined ancestor
    (-1: the root segment), the update order (leaves first, so each rotation is about its head before an
    ancestor's rotation moves it), each segment's subtree bones and refined descendants (as lists and flattened for
    :func:`rotate_segments`), and the prior's segments and diagonal. Read only."""
    key = (id(skel), bone_names)
    hit = _FIT_SEGMENTS_CACHE.get(key)
    if hit is not None and hit[0] is skel:
        return hit[1]
    bones = np.array([skel.index(b) for b in bone_names])
    D = _subtree_matrix(skel, bones)
    nJ = len(bones)
    fitted_parent = []
    for j, b in enumerate(bones):
        anc = [i for i in range(nJ) if i != j and D[b, i]]
        fitted_parent.append(min(anc, key=lambda i: D[:, i].sum()) if anc else -1)
    fitted_parent = np.array(fitted_parent)
    order = sorted(range(nJ), key=lambda j: -D[bones[j]].sum())
    is_child = D[bones] > 0  # is_child[i, j]: segment i lies in segment j's subtree
    # index lists fixed for the fit (the boolean masks they replace select the same rows in the same order)
    subtree_bones = [np.flatnonzero(D[:, j] > 0) for j in range(nJ)]
    child_segments = [np.flatnonzero(is_child[:, j]) for j in range(nJ)]
    order_arr = np.array(order, dtype=np.int64)
    sub_ptr = np.cumsum([0] + [len(x) for x in subtree_bones]).astype(np.int64)
    sub_idx = np.concatenate(subtree_bones).astype(np.int64)
    child_ptr = np.cumsum([0] + [len(x) for x in child_segments]).astype(np.int64)
    child_idx = np.concatenate(child_segments).astype(np.int64)
    prior_segments = np.flatnonzero(fitted_parent >= 0)
    prior_diag = (3 + 3 * prior_segments[:, None] + np.arange(3)).ravel()
    out = (bones, D, fitted_parent, order, subtree_bones, child_segments, order_arr, sub_ptr, sub_idx, child_ptr,
           child_idx, prior_segments, prior_diag)
    for a in out:
        if isinstance(a, np.ndarray):
            a.flags.writeable = False
    if len(_FIT_SEGMENTS_CACHE) >= 8:
        _FIT_SEGMENTS_CACHE.clear()
    _FIT_SEGMENTS_CACHE[key] = (skel, out)
    return out


def _refine_bone_transforms(body, T: np.ndarray, data_term, params: PoseRefineParams, anchors=None) -> np.ndarray:
    skel = body.skeleton
    missing = [b for b in params.bones if b not in skel.bone_names]
    if missing:
        raise InputError(f"pose refinement: the template has no bone(s) {', '.join(missing)}")
    (bones, D, fitted_parent, order, subtree_bones, child_segments, order_arr, sub_ptr, sub_idx, child_ptr,
     child_idx, prior_segments, prior_diag) = _fit_segments_cached(skel, tuple(params.bones))
    bone_idx, bone_w = _sparse_weights(body.weights)
    bone_idx = np.ascontiguousarray(bone_idx, dtype=np.int64)
    bone_w = np.ascontiguousarray(bone_w, dtype=np.float64)
    nJ = len(bones)
    seg_ptr, seg = _vertex_segments_cached(bone_idx, D)  # the segments each vertex follows (normal equations)
    Q = np.tile(np.eye(3), (nJ, 1, 1))  # accumulated world correction of each segment
    T = T.copy()
    n_par = 3 + 3 * nJ
    rest = np.ascontiguousarray(body.vertices, dtype=np.float64)
    previous_energy = np.inf
    for _ in range(params.iterations):
        # weighted per-influence skinned positions C (n, K, 3); the lever arms about each segment's head
        # and the data rows' normal equations in one compiled pass (data_normal_equations)
        C, V = skinned_parts(T, rest, bone_idx, bone_w)
        N = np.nan_to_num(igl.per_vertex_normals(V, body.faces))
        heads = np.einsum("bij,bj->bi", T[bones, :3, :3], skel.heads[bones]) + T[bones, :3, 3]

        ids, r, w, G = data_term(V, N)
        energy = float(np.sum(w * r * r))
        if params.min_decrease > 0 and energy > (1.0 - params.min_decrease) * previous_energy:
            break  # the last step lowered the data energy by less than min_decrease: converged
        previous_energy = energy
        H, g = data_normal_equations_listed(C, bone_idx, bone_w, D, heads, np.ascontiguousarray(ids, dtype=np.int64),
                                            np.ascontiguousarray(r, dtype=np.float64),
                                            np.ascontiguousarray(np.broadcast_to(w, r.shape), dtype=np.float64),
                                            np.ascontiguousarray(G, dtype=np.float64), seg_ptr, seg)
        if anchors is not None:
            a_bones, a_rest, a_target, a_weight = anchors
            X = np.einsum("mij,mj->mi", T[a_bones, :3, :3], a_rest) + T[a_bones, :3, 3]
            a_lever = D[a_bones][:, :, None] * (X[:, None, :] - heads[None])  # (m, nJ, 3)
            a_w = np.broadcast_to(np.asarray(a_weight, dtype=np.float64), len(X))
            for e in np.eye(3):
                Ja = np.concatenate([np.tile(e, (len(X), 1)), np.cross(a_lever, e).reshape(len(X), -1)], axis=1)
                H += Ja.T @ (a_w[:, None] * Ja)
                g += Ja.T @ (a_w * ((X - a_target) @ e))
        # prior on each segment's correction relative to its refined parent, Q_p^T Q_j; dw_j is segment
        # j's rotation on top of its ancestors', so only it changes that relative rotation
        # the prior's diagonal in one assignment (rec15i): adding prior_weight * I added 0.0 off the diagonal, which
        # changes no entry (H is accumulated from +0.0, so none is -0.0)
        H[prior_diag, prior_diag] += params.prior_weight
        if params.compiled_rotations:
            segment_prior_gradient(Q, fitted_parent, prior_segments, float(params.prior_weight), g)
        else:
            Qp = Q[np.maximum(fitted_parent, 0)]
            rel = rotation_vectors_of_matrices(Qp.transpose(0, 2, 1) @ Q)
            for j in prior_segments:
                cj = slice(3 + 3 * j, 6 + 3 * j)
                g[cj] += params.prior_weight * Qp[j] @ rel[j]
        H[np.diag_indices(n_par)] += params.damping * (np.diag(H).mean() + 1e-12)
        delta = -np.linalg.solve(H, g)
        dt, dw = delta[:3], delta[3:].reshape(nJ, 3)
        shrink = min(1.0, params.max_step_m / max(np.linalg.norm(dt), 1e-12),
                     params.max_step_rad / max(np.linalg.norm(dw, axis=1).max(), 1e-12))
        dt, dw = dt * shrink, dw * shrink
        if params.compiled_rotations:
            rotate_segments(T, Q, np.ascontiguousarray(dw), heads, order_arr, sub_ptr, sub_idx, child_ptr, child_idx)
        else:
            R = quaternion_rotation_matrices(np.ascontiguousarray(dw))
            for j in order:
                G = np.eye(4)
                G[:3, :3] = R[j]
                G[:3, 3] = heads[j] - R[j] @ heads[j]
                sub = subtree_bones[j]
                T[sub] = G @ T[sub]
                Q[child_segments[j]] = R[j] @ Q[child_segments[j]]
        T[:, :3, 3] += dt
        if np.linalg.norm(dt) < params.tolerance and np.abs(dw).max() < params.tolerance * 10:
            break
    return T
