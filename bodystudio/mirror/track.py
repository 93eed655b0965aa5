"""Pose deformation by inverse kinematics against the Kinect joints, §5.2 of Real-time Reshaping of Humans.

Every frame the source skeleton (the source body's rest skeleton, fixed bone lengths) is posed so that
its joints come as close as they can to the Kinect SDK joints ``K_i``: "the standard IK-solve
procedure by consecutively estimating the root position and joint rotation angles down the kinematic
chains". The root gets the weighted rigid fit (Kabsch) of the pelvis joints; then each driven bone,
parents first, is rotated about its posed head so that the joints it carries reach their Kinect joints:
the smallest rotation for one target joint, a weighted orthogonal Procrustes rotation for several
(the upper spine with the neck and shoulders, the hand with tip and thumb), which also fixes the twist.

The solve is warm-started: each bone starts from its rotation in the previous frame's pose, so the twist
that one target joint cannot determine carries over from frame to frame and the result is temporally
coherent. A frame costs a few hundred small 3x3 operations (well under a millisecond; see
:func:`bodystudio.mirror.init.time_init_and_track`).

The same pose drives the source and the target body (§5.2 "pose transfer"): the target keeps the local
rotations and the root translation, on its own skeleton (Eq. 3 of the target's rest mesh).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import lru_cache

import numpy as np
from numba import njit
from scipy.spatial.transform import Rotation

from bodystudio.body.ik import rotation_between
from bodystudio.body.kinect import KINECT_JOINT_SETS, kinect_joint_names
from bodystudio.body.pose import Pose
from bodystudio.body.skeleton import Skeleton
from bodystudio.body.skinning import skinning_transforms
from bodystudio.errors import InputError
from bodystudio.geometry.rotation import rotvec_matrix_into

# the sparse skinning kernel moved to geometry (shared with reconstruct); the names stay importable here
from bodystudio.geometry.skinning import (
    blend_skin,  # noqa: F401
    blend_skin_pair,
)
from bodystudio.geometry.skinning import sparse_skin_weights as _sparse_weights

#: Kinect v1 names of the v2 joints the IK uses (v1 lacks Neck, hand tips and thumbs).
V1_NAMES = {"SpineBase": "HipCenter", "SpineMid": "Spine", "SpineShoulder": "ShoulderCenter"}

#: Driven bones in kinematic order and the Kinect (v2) joints they carry, with weights. The first is
#: the root: a rigid fit with translation. Bones not listed keep their warm-start rotation.
IK_SEGMENTS: tuple[tuple[str, dict[str, float]], ...] = (
    ("Root", {"SpineBase": 1.0, "HipLeft": 1.0, "HipRight": 1.0, "SpineMid": 0.5}),
    ("spine_01", {"SpineMid": 1.0}),
    ("spine_02", {"SpineShoulder": 1.0, "Neck": 0.5, "ShoulderLeft": 0.5, "ShoulderRight": 0.5}),
    ("neck_01", {"Head": 1.0}),
    ("clavicle_l", {"ShoulderLeft": 1.0}),
    ("clavicle_r", {"ShoulderRight": 1.0}),
    ("upperarm_l", {"ElbowLeft": 1.0}),
    ("upperarm_r", {"ElbowRight": 1.0}),
    ("lowerarm_l", {"WristLeft": 1.0}),
    ("lowerarm_r", {"WristRight": 1.0}),
    ("hand_l", {"HandLeft": 1.0, "HandTipLeft": 1.0, "ThumbLeft": 0.5}),
    ("hand_r", {"HandRight": 1.0, "HandTipRight": 1.0, "ThumbRight": 0.5}),
    ("thigh_l", {"KneeLeft": 1.0}),
    ("thigh_r", {"KneeRight": 1.0}),
    ("calf_l", {"AnkleLeft": 1.0}),
    ("calf_r", {"AnkleRight": 1.0}),
    ("foot_l", {"FootLeft": 1.0}),
    ("foot_r", {"FootRight": 1.0}),
)

#: Weight of a joint the SDK reports as inferred (not tracked) relative to a tracked one.
INFERRED_WEIGHT = 0.25
#: Below this ratio of the second to the first singular value a multi-joint fit is treated as one target
#: (the joints are nearly collinear with the pivot and cannot fix the twist).
_DEGENERATE_RATIO = 0.08


@dataclass(frozen=True)
class _Target:
    joint: int  # index into the Kinect joint list
    weight: float
    terms: tuple[tuple[int, bool, float], ...]  # (bone, is_tail, weight) making the joint


@dataclass(frozen=True)
class _Segment:
    driver: int
    targets: tuple[_Target, ...]
    chain: tuple[int, ...]  # descendants of the driver the targets need, parents first


@dataclass(frozen=True, eq=False)
class _IKPlan:
    """Per-skeleton data of the IK: rest frames, the joint definitions and the bones to visit."""

    rest_rotations: np.ndarray  # (B, 3, 3)
    heads: np.ndarray
    tails: np.ndarray
    parents: np.ndarray
    segments: tuple[_Segment, ...]
    order: tuple[int, ...]  # drivers and their ancestors, parents first
    driver_segment: dict
    flat: tuple = ()  # the same plan as flat arrays for :func:`_ik_kernel` (:func:`_flat_plan`)


@lru_cache(maxsize=16)
def _plan(skeleton: Skeleton, version: str) -> _IKPlan:
    names = kinect_joint_names(version)
    index = {n: i for i, n in enumerate(names)}
    bone = {b: i for i, b in enumerate(skeleton.bone_names)}
    joint_defs = KINECT_JOINT_SETS[version]
    parents = np.asarray(skeleton.parents)

    def ancestors(b):
        out = []
        while b >= 0:
            out.append(b)
            b = int(parents[b])
        return out

    segments = []
    for driver_name, targets in IK_SEGMENTS:
        if driver_name not in bone:
            raise InputError(f"mirror tracking needs the game_engine rig; bone {driver_name!r} is missing")
        d = bone[driver_name]
        tlist, chain = [], set()
        for joint_name, w in targets.items():
            name = V1_NAMES.get(joint_name, joint_name) if version == "v1" else joint_name
            if name not in index:
                continue
            terms = []
            for b_name, end, tw in joint_defs[name]:
                b = bone[b_name]
                path = ancestors(b)
                if d not in path:
                    raise InputError(f"Kinect joint {name} is not carried by bone {driver_name}")
                chain.update(path[: path.index(d)])
                terms.append((b, end == "tail", tw))
            tlist.append(_Target(index[name], w, tuple(terms)))
        segments.append(_Segment(d, tuple(tlist), tuple(sorted(chain))))  # bone order is topological
    visit = sorted({a for s in segments for a in ancestors(s.driver)})
    plan = _IKPlan(skeleton.rest_rotations, np.asarray(skeleton.heads, float), np.asarray(skeleton.tails, float),
                   parents, tuple(segments), tuple(visit), {s.driver: s for s in segments})
    return replace(plan, flat=_flat_plan(plan))


def _flat_plan(plan: _IKPlan) -> tuple:
    """The plan's segments as flat arrays (CSR-style offsets) for :func:`_ik_kernel`: the segment of each bone (-1:
    none), each segment's chain, targets (Kinect joint, weight) and each target's terms (bone, is_tail, weight)."""
    B = len(plan.parents)
    seg_of = np.full(B, -1, np.int64)
    chain_ptr, chain, target_ptr, t_joint, t_weight, term_ptr, terms, term_w = [0], [], [0], [], [], [0], [], []
    for k, seg in enumerate(plan.segments):
        seg_of[seg.driver] = k
        chain += seg.chain
        chain_ptr.append(len(chain))
        for t in seg.targets:
            t_joint.append(t.joint)
            t_weight.append(t.weight)
            for b, is_tail, tw in t.terms:
                terms.append((b, int(is_tail)))
                term_w.append(tw)
            term_ptr.append(len(terms))
        target_ptr.append(len(t_joint))
    i64 = np.int64
    return (np.ascontiguousarray(plan.rest_rotations, np.float64), np.ascontiguousarray(plan.heads, np.float64),
            np.ascontiguousarray(plan.tails, np.float64), np.asarray(plan.parents, i64), np.asarray(plan.order, i64),
            seg_of, np.asarray(chain_ptr, i64), np.asarray(chain, i64).reshape(-1), np.asarray(target_ptr, i64),
            np.asarray(t_joint, i64), np.asarray(t_weight, np.float64), np.asarray(term_ptr, i64),
            np.asarray(terms, i64).reshape(-1, 2), np.asarray(term_w, np.float64))


def check_kinect_joints(kinect_positions, tracked, version: str) -> tuple[np.ndarray, np.ndarray]:
    """Validated ``(J, 3)`` float positions and ``(J,)`` bool tracked flags of one Kinect body."""
    names = kinect_joint_names(version)
    K = np.asarray(kinect_positions, dtype=np.float64)
    if K.shape != (len(names), 3):
        raise InputError(f"tracking needs {len(names)} Kinect {version} joints as a (J, 3) array, got {K.shape}")
    t = np.ones(len(names), bool) if tracked is None else np.asarray(tracked, dtype=bool).reshape(-1)
    if t.shape != (len(names),):
        raise InputError(f"tracked flags must be one per Kinect {version} joint ({len(names)}), got {t.shape}")
    return K, t


def _procrustes(U: np.ndarray, V: np.ndarray, w: np.ndarray) -> np.ndarray | None:
    """Rotation R minimising sum w |R u - v|^2, or None when the vectors cannot fix it (near collinear)."""
    H = (V * w[:, None]).T @ U
    Us, S, Vt = np.linalg.svd(H)
    if S[0] <= 0 or S[1] < _DEGENERATE_RATIO * S[0]:
        return None
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Us @ Vt)) or 1.0])
    return Us @ D @ Vt


def ik_pose_numpy(skeleton: Skeleton, kinect_positions, tracked=None, version: str = "v2",
                  previous: Pose | None = None) -> Pose:
    """:func:`ik_pose` as numpy computed it bone by bone before MIR12f (~0.9 ms a frame, ~40 % of it the Python of
    the 3x3 algebra): the reference the numba kernel is pinned to (tests/mirror/test_session_speed_pins.py).

    Pose of ``skeleton`` whose joints fit the Kinect joints: the IK solve of §5.2 (root, then down the chains).

    ``kinect_positions`` (J, 3) metres in the studio frame with NaN where the SDK gave nothing;
    ``tracked`` (J,) False for inferred joints (they count with :data:`INFERRED_WEIGHT`). ``previous``
    warm-starts every bone (the last frame's pose); without it the solve starts from the rest pose. A
    body with fewer than two usable pelvis/spine joints raises InputError (the frame cannot be tracked).
    """
    K, tracked = check_kinect_joints(kinect_positions, tracked, version)
    plan = _plan(skeleton, version)
    B = len(plan.parents)
    usable = np.all(np.isfinite(K), axis=1)
    joint_w = np.where(usable, np.where(tracked, 1.0, INFERRED_WEIGHT), 0.0)
    Rr = plan.rest_rotations
    if previous is None:
        rotvecs = np.zeros((B, 3))
        translation = np.zeros(3)
    else:
        if previous.rotations.shape != (B, 3):
            raise InputError(f"previous pose has {len(previous.rotations)} bones, the skeleton {B}")
        rotvecs = previous.rotations.copy()
        translation = previous.translation.copy()
    # L_j: bone j's local rotation expressed in rest-world axes, so that W_j = W_parent L_j.
    L = Rr @ Rotation.from_rotvec(rotvecs).as_matrix() @ np.transpose(Rr, (0, 2, 1))
    H, T, P = plan.heads, plan.tails, plan.parents
    W = np.empty((B, 3, 3))
    ph = np.empty((B, 3))
    changed = []
    for j in plan.order:
        p = P[j]
        if p < 0:
            W[j] = L[j]
            ph[j] = H[j] + translation
        else:
            W[j] = W[p] @ L[j]
            ph[j] = W[p] @ (H[j] - H[p]) + ph[p]
        seg = plan.driver_segment.get(j)
        if seg is None:
            continue
        targets = [t for t in seg.targets if joint_w[t.joint] > 0]
        if not targets:
            if p < 0:
                raise InputError("no tracked pelvis joints in this frame: the body cannot be tracked")
            continue
        current = _segment_joints(j, W[j], ph[j], seg, targets, L, H, T, P)
        observed = K[[t.joint for t in targets]]
        w = np.array([t.weight * joint_w[t.joint] for t in targets])
        if p < 0:
            if len(targets) < 2:
                raise InputError("fewer than two tracked pelvis/spine joints in this frame: the body cannot be tracked")
            mc = (w[:, None] * current).sum(0) / w.sum()
            mo = (w[:, None] * observed).sum(0) / w.sum()
            R = _procrustes(current - mc, observed - mo, w) if len(targets) >= 3 else None
            R = np.eye(3) if R is None else R
            W[j] = R @ W[j]
            ph[j] = R @ (ph[j] - mc) + mo
            translation = ph[j] - H[j]
        else:
            U, V = current - ph[j], observed - ph[j]
            R = _procrustes(U, V, w) if len(targets) >= 2 else None
            if R is None:
                u, v = (w[:, None] * U).sum(0), (w[:, None] * V).sum(0)
                nu, nv = np.linalg.norm(u), np.linalg.norm(v)
                if nu < 1e-9 or nv < 1e-9:
                    continue
                R = rotation_between(u / nu, v / nv)
            W[j] = R @ W[j]
        L[j] = W[j] if p < 0 else W[p].T @ W[j]
        changed.append(j)
    if changed:
        idx = np.array(changed)
        local = np.transpose(Rr[idx], (0, 2, 1)) @ L[idx] @ Rr[idx]
        rotvecs[idx] = Rotation.from_matrix(local).as_rotvec()
    return Pose(rotvecs, translation)


#: :func:`_ik_kernel`'s failures, raised by :func:`ik_pose` as the numpy path raised them.
_IK_ERRORS = {1: "no tracked pelvis joints in this frame: the body cannot be tracked",
              2: "fewer than two tracked pelvis/spine joints in this frame: the body cannot be tracked"}


def ik_pose(skeleton: Skeleton, kinect_positions, tracked=None, version: str = "v2",
            previous: Pose | None = None) -> Pose:
    """Pose of ``skeleton`` whose joints fit the Kinect joints: the IK solve of §5.2 (root, then down the chains).

    ``kinect_positions`` (J, 3) metres in the studio frame with NaN where the SDK gave nothing;
    ``tracked`` (J,) False for inferred joints (they count with :data:`INFERRED_WEIGHT`). ``previous``
    warm-starts every bone (the last frame's pose); without it the solve starts from the rest pose. A
    body with fewer than two usable pelvis/spine joints raises InputError (the frame cannot be tracked).

    One numba pass (:func:`_ik_kernel`, MIR12f): the operations of :func:`ik_pose_numpy` in its order, the
    rotation-vector conversions scipy's formulas; the same pose to ~1e-13 (0.9 -> ~0.05 ms a frame).
    """
    K, tracked = check_kinect_joints(kinect_positions, tracked, version)
    plan = _plan(skeleton, version)
    B = len(plan.parents)
    if previous is None:
        rotvecs = np.zeros((B, 3))
        translation = np.zeros(3)
    else:
        if previous.rotations.shape != (B, 3):
            raise InputError(f"previous pose has {len(previous.rotations)} bones, the skeleton {B}")
        rotvecs = np.array(previous.rotations, dtype=np.float64)
        translation = np.array(previous.translation, dtype=np.float64)
    status = _ik_kernel(np.ascontiguousarray(K), np.ascontiguousarray(tracked), INFERRED_WEIGHT, _DEGENERATE_RATIO,
                        rotvecs, translation, *plan.flat)
    if status:
        raise InputError(_IK_ERRORS[status])
    return Pose(rotvecs, translation)


@njit(cache=True)
def _matrix_rotvec(m, out):
    """``Rotation.from_matrix(m).as_rotvec()`` of a rotation matrix (scipy's: the largest of the diagonal and the
    trace picks the quaternion's formula, normalised, w >= 0, then the rotation vector) into ``out`` (3,)."""
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    choice = 0
    best = m[0, 0]
    for k, v in ((1, m[1, 1]), (2, m[2, 2]), (3, trace)):
        if v > best:
            best = v
            choice = k
    if choice == 0:
        q = (1 - trace + 2 * m[0, 0], m[1, 0] + m[0, 1], m[2, 0] + m[0, 2], m[2, 1] - m[1, 2])
    elif choice == 1:
        q = (m[1, 0] + m[0, 1], 1 - trace + 2 * m[1, 1], m[2, 1] + m[1, 2], m[0, 2] - m[2, 0])
    elif choice == 2:
        q = (m[2, 0] + m[0, 2], m[2, 1] + m[1, 2], 1 - trace + 2 * m[2, 2], m[1, 0] - m[0, 1])
    else:
        q = (m[2, 1] - m[1, 2], m[0, 2] - m[2, 0], m[1, 0] - m[0, 1], 1 + trace)
    norm = np.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    x, y, z, w = q[0] / norm, q[1] / norm, q[2] / norm, q[3] / norm
    if w < 0 or (w == 0 and (x < 0 or (x == 0 and (y < 0 or (y == 0 and z < 0))))):
        x, y, z, w = -x, -y, -z, -w
    angle = 2 * np.arctan2(np.sqrt(x * x + y * y + z * z), w)
    if angle <= 1e-3:
        a2 = angle * angle
        scale = 2 + a2 / 12 + 7 * a2 * a2 / 2880
    else:
        scale = angle / np.sin(angle / 2.0)
    out[0] = scale * x
    out[1] = scale * y
    out[2] = scale * z


@njit(cache=True)
def _mm(A, B):
    """``A @ B`` of 3x3 matrices as loops (numba's ``@`` goes through BLAS, whose bindings took seconds to compile)."""
    out = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            out[i, j] = A[i, 0] * B[0, j] + A[i, 1] * B[1, j] + A[i, 2] * B[2, j]
    return out


@njit(cache=True)
def _mtm(A, B):
    """``A.T @ B`` of 3x3 matrices as loops."""
    out = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            out[i, j] = A[0, i] * B[0, j] + A[1, i] * B[1, j] + A[2, i] * B[2, j]
    return out


@njit(cache=True)
def _mv(A, v):
    """``A @ v`` of a 3x3 matrix and a 3-vector as loops."""
    out = np.empty(3)
    for i in range(3):
        out[i] = A[i, 0] * v[0] + A[i, 1] * v[1] + A[i, 2] * v[2]
    return out


@njit(cache=True)
def _det3(M):
    """Determinant of a 3x3 matrix."""
    return (M[0, 0] * (M[1, 1] * M[2, 2] - M[1, 2] * M[2, 1]) - M[0, 1] * (M[1, 0] * M[2, 2] - M[1, 2] * M[2, 0])
            + M[0, 2] * (M[1, 0] * M[2, 1] - M[1, 1] * M[2, 0]))


@njit(cache=True)
def _procrustes_kernel(U, V, w, n, ratio, R):
    """:func:`_procrustes` of the first ``n`` rows into ``R``; False where it returns None."""
    H = np.zeros((3, 3))
    for k in range(n):
        for a in range(3):
            for b in range(3):
                H[a, b] += V[k, a] * w[k] * U[k, b]
    Us, S, Vt = np.linalg.svd(H)
    if S[0] <= 0 or S[1] < ratio * S[0]:
        return False
    d = np.sign(_det3(_mm(Us, Vt)))
    if d == 0:
        d = 1.0
    Us[:, 2] *= d
    R[:, :] = _mm(Us, Vt)
    return True


@njit(cache=True)
def _rotation_between_kernel(u0, u1, u2, v0, v1, v2, R):
    """:func:`bodystudio.body.ik.rotation_between` of unit vectors ``u``, ``v`` into ``R``."""
    c = u0 * v0 + u1 * v1 + u2 * v2
    if c < -1.0 + 1e-9:
        if abs(u0) < 0.9:  # u x (1, 0, 0)
            a0, a1, a2 = 0.0, u2, -u1
        else:  # u x (0, 1, 0)
            a0, a1, a2 = -u2, 0.0, u0
        na = np.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
        axis = (a0 / na, a1 / na, a2 / na)
        for i in range(3):
            for j in range(3):
                R[i, j] = 2.0 * axis[i] * axis[j] - (1.0 if i == j else 0.0)
        return
    w0, w1, w2 = u1 * v2 - u2 * v1, u2 * v0 - u0 * v2, u0 * v1 - u1 * v0
    Km = np.zeros((3, 3))
    Km[0, 1], Km[0, 2], Km[1, 0], Km[1, 2], Km[2, 0], Km[2, 1] = -w2, w1, w2, -w0, -w1, w0
    KK = _mm(Km, Km)
    for i in range(3):
        for j in range(3):
            R[i, j] = (1.0 if i == j else 0.0) + Km[i, j] + KK[i, j] / (1.0 + c)


@njit(cache=True)
def _ik_kernel(K, tracked, inferred_weight, ratio, rotvecs, translation, Rr, H, T, P, order, seg_of, chain_ptr,
               chain, target_ptr, t_joint, t_weight, term_ptr, terms, term_w):
    """:func:`ik_pose_numpy`'s solve on the flat plan (:func:`_flat_plan`), ``rotvecs`` and ``translation`` (the
    warm start) updated in place; returns 0, or the code of an :data:`_IK_ERRORS` failure."""
    B = P.shape[0]
    J = K.shape[0]
    joint_w = np.zeros(J)
    for i in range(J):
        if np.isfinite(K[i, 0]) and np.isfinite(K[i, 1]) and np.isfinite(K[i, 2]):
            joint_w[i] = 1.0 if tracked[i] else inferred_weight
    L = np.empty((B, 3, 3))
    local = np.empty((3, 3))
    for b in range(B):
        rotvec_matrix_into(rotvecs[b, 0], rotvecs[b, 1], rotvecs[b, 2], local)
        L[b] = _mm(_mm(Rr[b], local), Rr[b].T)
    W = np.empty((B, 3, 3))
    ph = np.empty((B, 3))
    Wc = np.empty((B, 3, 3))
    pc = np.empty((B, 3))
    changed = np.zeros(B, np.bool_)
    n_targets = t_joint.shape[0]
    current = np.empty((n_targets, 3))
    observed = np.empty((n_targets, 3))
    w = np.empty(n_targets)
    R = np.empty((3, 3))
    for j in order:
        p = P[j]
        if p < 0:
            W[j] = L[j]
            ph[j] = H[j] + translation
        else:
            W[j] = _mm(W[p], L[j])
            ph[j] = _mv(W[p], H[j] - H[p]) + ph[p]
        s = seg_of[j]
        if s < 0:
            continue
        # the segment's usable targets, posed with the driver at (W[j], ph[j]) and the rest warm-started
        Wc[j] = W[j]
        pc[j] = ph[j]
        for c in chain[chain_ptr[s]:chain_ptr[s + 1]]:
            q = P[c]
            Wc[c] = _mm(Wc[q], L[c])
            pc[c] = _mv(Wc[q], H[c] - H[q]) + pc[q]
        n = 0
        for t in range(target_ptr[s], target_ptr[s + 1]):
            jw = joint_w[t_joint[t]]
            if jw <= 0:
                continue
            acc = np.zeros(3)
            for e in range(term_ptr[t], term_ptr[t + 1]):
                b = terms[e, 0]
                if terms[e, 1]:
                    acc += term_w[e] * (pc[b] + _mv(Wc[b], T[b] - H[b]))
                else:
                    acc += term_w[e] * pc[b]
            current[n] = acc
            observed[n] = K[t_joint[t]]
            w[n] = t_weight[t] * jw
            n += 1
        if n == 0:
            if p < 0:
                return 1
            continue
        if p < 0:
            if n < 2:
                return 2
            wsum = 0.0
            mc = np.zeros(3)
            mo = np.zeros(3)
            for k in range(n):
                mc += w[k] * current[k]
                mo += w[k] * observed[k]
                wsum += w[k]
            mc /= wsum
            mo /= wsum
            if not (n >= 3 and _procrustes_kernel(current[:n] - mc, observed[:n] - mo, w, n, ratio, R)):
                R[:, :] = 0.0
                R[0, 0] = R[1, 1] = R[2, 2] = 1.0
            W[j] = _mm(R, W[j])
            ph[j] = _mv(R, ph[j] - mc) + mo
            translation[:] = ph[j] - H[j]
        else:
            U = current[:n] - ph[j]
            V = observed[:n] - ph[j]
            if not (n >= 2 and _procrustes_kernel(U, V, w, n, ratio, R)):
                u = np.zeros(3)
                v = np.zeros(3)
                for k in range(n):
                    u += w[k] * U[k]
                    v += w[k] * V[k]
                nu = np.sqrt(u[0] * u[0] + u[1] * u[1] + u[2] * u[2])
                nv = np.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
                if nu < 1e-9 or nv < 1e-9:
                    continue
                _rotation_between_kernel(u[0] / nu, u[1] / nu, u[2] / nu, v[0] / nv, v[1] / nv, v[2] / nv, R)
            W[j] = _mm(R, W[j])
        L[j] = W[j] if p < 0 else _mtm(W[p], W[j])
        changed[j] = True
    for j in range(B):
        if changed[j]:
            _matrix_rotvec(_mm(_mtm(Rr[j], L[j]), Rr[j]), rotvecs[j])
    return 0


def _segment_joints(d, W_d, ph_d, seg: _Segment, targets, L, H, T, P) -> np.ndarray:
    """Posed positions of the segment's target joints with the driver at (W_d, ph_d), the rest warm-started."""
    Wc = {d: W_d}
    pc = {d: ph_d}
    for c in seg.chain:
        p = P[c]
        Wc[c] = Wc[p] @ L[c]
        pc[c] = Wc[p] @ (H[c] - H[p]) + pc[p]
    out = np.zeros((len(targets), 3))
    for k, t in enumerate(targets):
        for b, is_tail, tw in t.terms:
            out[k] += tw * (pc[b] + Wc[b] @ (T[b] - H[b]) if is_tail else pc[b])
    return out


def posed_kinect_joints(skeleton: Skeleton, pose: Pose, version: str = "v2") -> np.ndarray:
    """Kinect joints ``(J, 3)`` of ``skeleton`` in ``pose`` (the model side of the IK's objective)."""
    from bodystudio.body.kinect import kinect_joints
    from bodystudio.body.skinning import posed_joints

    heads, tails = posed_joints(skeleton, pose)
    return kinect_joints(skeleton, heads, tails, version)


def skin_vertices(vertices: np.ndarray, weights: np.ndarray, skeleton: Skeleton, pose: Pose,
                  subset: np.ndarray | None = None, transforms: np.ndarray | None = None) -> np.ndarray:
    """Linear blend skinning of rest ``vertices`` by ``pose``, optionally only the rows ``subset``.

    Each vertex blends only its six largest skin weights (the MakeHuman weights have at most six
    non-zeros, so this equals the dense (n, B) blend), which makes a 6k-vertex body several times cheaper.
    """
    S = skinning_transforms(skeleton, pose) if transforms is None else transforms
    idx, w = _sparse_weights(weights)
    V = np.asarray(vertices, dtype=np.float64)
    if subset is not None:
        idx, w, V = idx[subset], w[subset], V[subset]
    return blend_skin(np.ascontiguousarray(S[:, :3, :], dtype=np.float64), np.ascontiguousarray(idx),
                      np.ascontiguousarray(w, dtype=np.float64), np.ascontiguousarray(V), np.empty((0, 3)))[0]


def rest_chain(skeleton: Skeleton) -> tuple[np.ndarray, np.ndarray]:
    """``(A_parent^-1 A_j`` (the root: ``A_root``), ``A_j^-1)`` (B, 4, 4) each: the rest-frame products of the
    forward kinematics (:func:`bodystudio.body.skinning.forward_kinematics` solves them bone by bone per call),
    batched, for :func:`posed_frames`."""
    A = skeleton.rest_frames
    parents = np.asarray(skeleton.parents)
    rel = A.copy()
    child = np.flatnonzero(parents >= 0)
    rel[child] = np.linalg.solve(A[parents[child]], A[child])
    return rel, np.linalg.inv(A)


@njit(cache=True)
def posed_frames(rest_relative, rest_inverse, local_rotations, translation, parents):
    """``M_j = M_parent (A_parent^-1 A_j) L_j`` down the chain (parents before children), the root moved by
    ``translation``; and the top rows of the skinning transforms ``(M_j A_j^-1)[:3]`` (B, 3, 4)."""
    B = len(parents)
    M = np.zeros((B, 4, 4))
    transforms = np.empty((B, 3, 4))
    local = np.eye(4)
    for j in range(B):
        local[:3, :3] = local_rotations[j]
        Mj = rest_relative[j] @ local
        if parents[j] < 0:
            Mj[:3, 3] += translation
        else:
            Mj = M[parents[j]] @ Mj
        M[j] = Mj
        transforms[j] = (Mj @ rest_inverse[j])[:3]
    return M, transforms


_CHAIN_CACHE: dict[int, tuple] = {}


def _cached_rest_chain(skeleton: Skeleton) -> tuple[np.ndarray, np.ndarray]:
    """:func:`rest_chain` of ``skeleton``, cached per object (a source body's skeleton is posed every frame)."""
    hit = _CHAIN_CACHE.get(id(skeleton))
    if hit is not None and hit[0] is skeleton:
        return hit[1]
    chain = rest_chain(skeleton)
    if len(_CHAIN_CACHE) >= 8:
        _CHAIN_CACHE.clear()
    _CHAIN_CACHE[id(skeleton)] = (skeleton, chain)  # holding the skeleton keeps its id from being reused
    return chain


_CONTENT_CHAINS: dict[bytes, tuple] = {}


def _rest_chain_by_content(skeleton: Skeleton) -> tuple[np.ndarray, np.ndarray]:
    """:func:`rest_chain` cached by the rest frames' and parents' bytes: the run builds the target rig anew every
    frame (the same one once the ramp is over), so it cannot be cached per object (MIR12f: ~0.06 ms an actor)."""
    key = np.ascontiguousarray(skeleton.rest_frames, np.float64).tobytes() + \
        np.asarray(skeleton.parents, np.int64).tobytes()
    hit = _CONTENT_CHAINS.get(key)
    if hit is None:
        if len(_CONTENT_CHAINS) >= 8:
            _CONTENT_CHAINS.clear()
        hit = _CONTENT_CHAINS[key] = rest_chain(skeleton)
    return hit


@njit(cache=True)
def _transferred_rotations(Rs, Rt, L):
    """The target's local rotations ``R_T^T (R_S L R_S^T) R_T`` per bone (B, 3, 3) (the einsums of MIR12e as 3x3
    products in numba, MIR12f)."""
    out = np.empty_like(L)
    for b in range(L.shape[0]):
        out[b] = Rt[b].T @ (Rs[b] @ L[b] @ Rs[b].T) @ Rt[b]
    return out


def skin_source_and_target(source_vertices: np.ndarray, target_vertices: np.ndarray, weights: np.ndarray,
                           source_skeleton: Skeleton, target_skeleton: Skeleton, pose: Pose
                           ) -> tuple[np.ndarray, np.ndarray]:
    """The source and the target body posed by ``pose`` in one pass (MIR12e): what
    ``skin_vertices(source, .., pose)`` and ``skin_vertices(target, .., transfer_pose(pose, ..))`` give
    (:func:`bodystudio.body.pose.transfer_pose`: every bone turns by the same world rotation), to ~1e-15 m.

    One rig, one set of skin weights: the two bodies differ only in their rest shapes and skeletons. The target's
    local rotations are ``R_T^T (R_S L R_S^T) R_T`` as matrices (no rotation-vector round trip), both chains are
    posed in numba from their rest-frame products (the source's cached) and each vertex's six weights are read
    once for both bodies (:func:`bodystudio.geometry.skinning.blend_skin_pair`); ~0.5 ms for two 6k bodies
    against ~2 for two :func:`skin_vertices` calls (most of it ``skinning_transforms``' numpy forward kinematics)."""
    parents = np.asarray(source_skeleton.parents, np.int64)
    L = Rotation.from_rotvec(pose.rotations).as_matrix()
    Rs, Rt = source_skeleton.rest_rotations, target_skeleton.rest_rotations
    Lt = _transferred_rotations(np.ascontiguousarray(Rs, np.float64), np.ascontiguousarray(Rt, np.float64), L)
    translation = np.asarray(pose.translation, np.float64)
    _, Ts = posed_frames(*_cached_rest_chain(source_skeleton), L, translation, parents)
    _, Tt = posed_frames(*_rest_chain_by_content(target_skeleton), Lt, translation, parents)
    idx, w = _sparse_weights(weights)
    return blend_skin_pair(Ts, Tt, idx, w, np.ascontiguousarray(source_vertices, dtype=np.float64),
                           np.ascontiguousarray(target_vertices, dtype=np.float64))


#: The limbs whose twist :func:`untwisted_pose` takes off the IK pose (MIR12p): their single Kinect target fixes only
#: their direction, and the IK, warm-started by the last frame's pose, turns each by the smallest rotation onto its
#: new direction, so a limb swinging in a loop gathers twist frame by frame (the rotation's holonomy: session 42's
#: walking left arm drifted from -4 to -25 degrees of twist in 84 frames, a long live run without bound).
UNTWIST_BONES = ("upperarm_l", "lowerarm_l", "upperarm_r", "lowerarm_r", "thigh_l", "calf_l", "thigh_r", "calf_r")

#: The feet, which the IK turns the same way (one Kinect target each, FootLeft / FootRight, warm-started): on the
#: walking sessions their twist drifts as the limbs' did (mir12aa: session 52's right foot 7.7 degrees off the truth's
#: twist on average, up to 14; 1.3 on average untwisted). ``run.UNTWIST_FEET`` adds them to the run's untwisting.
UNTWIST_FEET_BONES = ("foot_l", "foot_r")


def untwisted_pose(skeleton: Skeleton, pose: Pose, bones=UNTWIST_BONES) -> Pose:
    """``pose`` with each of ``bones`` turned about its own axis to no twist against its parent: its local rotation
    the smallest one from its rest direction to its posed direction (in the parent's frame). Every bone keeps its
    posed direction and every other bone its world rotation (the children of ``bones`` take the change off their
    local rotations), so the joints do not move; the twist no longer depends on the frames before (MIR12p)."""
    names = list(skeleton.bone_names)
    missing = [b for b in bones if b not in names]
    if missing:
        raise InputError(f"untwisted_pose: no bone {missing[0]!r} in the skeleton ({len(names)} bones); name bones "
                         "of its rig, e.g. track.UNTWIST_BONES")
    idx = sorted(names.index(b) for b in bones)
    if not idx:
        return pose
    parents = np.asarray(skeleton.parents)
    Rr = skeleton.rest_rotations
    rv = np.array(pose.rotations, dtype=np.float64)
    L = Rr @ Rotation.from_rotvec(rv).as_matrix() @ np.transpose(Rr, (0, 2, 1))  # local, in rest-world axes
    W = np.empty_like(L)
    for j, p in enumerate(parents):  # parents come before children
        W[j] = L[j] if p < 0 else W[p] @ L[j]
    d = skeleton.tails - skeleton.heads
    d = d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
    changed = set()
    for j in idx:
        p = parents[j]
        L[j] = rotation_between(d[j], L[j] @ d[j])
        W_new = L[j] if p < 0 else W[p] @ L[j]
        for c in np.flatnonzero(parents == j):  # the children keep their world rotations
            L[c] = W_new.T @ W[c]
            changed.add(int(c))
        W[j] = W_new
        changed.add(j)
    ch = np.array(sorted(changed))
    rv[ch] = Rotation.from_matrix(np.transpose(Rr[ch], (0, 2, 1)) @ L[ch] @ Rr[ch]).as_rotvec()
    return Pose(rv, np.array(pose.translation, dtype=np.float64))


def upright_root(skeleton: Skeleton, pose: Pose, up=(0.0, 1.0, 0.0)) -> Pose:
    """The same posed body with the root turned about the world's ``up`` axis only (MIR12s).

    The game_engine rig's ``Root`` is the floor anchor between the feet: it carries no skin weight, and its one
    child (the pelvis) takes any posed frame through its own rotation and the pose's translation, so the root's
    tilt is free for the posed source (a gauge: the IK and the refinement leave 3-5 degrees of it on a walk). It is
    not free for the target: the target's joints hang off the root's rest frame, so a tilt ``e`` of the root turns
    the reshape's change of the pelvis height (-8 cm for 17 cm shorter) by ``e``, a few mm forward or back that a
    person side-on shows as a shift of the whole outline. Here the root keeps only its turn about ``up`` (the
    swing-twist decomposition), its children keep their world rotations and the translation keeps their heads in
    place: every posed vertex and joint of the source stays (to rounding), the target no longer depends on the tilt.
    A root with children at different rest heads cannot keep them all: InputError.
    """
    parents = np.asarray(skeleton.parents)
    roots = np.flatnonzero(parents < 0)
    up = np.asarray(up, dtype=np.float64)
    up = up / np.linalg.norm(up)
    Rr = skeleton.rest_rotations
    rv = np.array(pose.rotations, dtype=np.float64)
    translation = np.array(pose.translation, dtype=np.float64)
    for r in roots:
        children = np.flatnonzero(parents == r)
        if not len(children):
            continue
        if np.abs(skeleton.heads[children] - skeleton.heads[children[0]]).max() > 1e-9:
            raise InputError(f"upright_root: the root {skeleton.bone_names[r]!r} has children at different rest "
                             "heads; the root's tilt cannot move into them")
        M = np.empty((3, 3))
        rotvec_matrix_into(rv[r, 0], rv[r, 1], rv[r, 2], M)  # scipy's values, without its per-call overhead
        W = Rr[r] @ M @ Rr[r].T  # the root's rotation in world axes
        a = np.empty(3)
        _matrix_rotvec(W, a)
        angle = np.linalg.norm(a)  # the twist about up of the unit quaternion (sin(angle / 2) a / angle, cos(...))
        s = 0.0 if angle < 1e-15 else np.sin(angle / 2.0) * (a @ up) / angle
        c = np.cos(angle / 2.0)
        norm = np.hypot(s, c)
        s, c = (0.0, 1.0) if norm < 1e-12 else (s / norm, c / norm)
        K = np.array([[0.0, -up[2], up[1]], [up[2], 0.0, -up[0]], [-up[1], up[0], 0.0]])
        W_up = np.eye(3) + 2.0 * c * s * K + 2.0 * s * s * (K @ K)  # the rotation of the quaternion (s up, c)
        translation = translation + (W - W_up) @ (skeleton.heads[children[0]] - skeleton.heads[r])
        turn = W_up.T @ W
        for j in children:  # each child keeps its world rotation: W_up L_j' = W L_j
            rotvec_matrix_into(rv[j, 0], rv[j, 1], rv[j, 2], M)
            _matrix_rotvec(Rr[j].T @ turn @ Rr[j] @ M, a)
            rv[j] = a
        _matrix_rotvec(Rr[r].T @ W_up @ Rr[r], a)
        rv[r] = a
    return Pose(rv, translation)
