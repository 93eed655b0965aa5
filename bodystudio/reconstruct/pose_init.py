"""Pose and size initialisation from 3D joint positions, Rapid Skin §IV.A-B (Eq. 11-12).

A global similarity ``T_G`` (rotation, uniform scale, translation; Umeyama 1991) aligns the template's
upper-body joints with the tracked ones. Down each kinematic chain, a local transform ``T_L_k``
rotates the template bone about its (already placed) parent joint onto the tracked child joint and
stretches it along its axis to the tracked length (Fig. 4a), so the template adopts the user's bone
lengths. Bones are transformed by ``T_k = (prod T_L along the chain) T_G`` (Eq. 11) and the skin by
linear blend skinning (Eq. 12).

Joints are Kinect v2 tracker joints (``bodystudio.body.kinect``); missing or untracked joints are NaN
and their segments follow the parent's transform.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bodystudio.body.ik import rotation_between
from bodystudio.body.kinect import kinect_joint_names, kinect_joints
from bodystudio.body.skinning import inverse_linear_blend_skinning as unpose  # noqa: F401 (re-exported)
from bodystudio.errors import InputError
from bodystudio.geometry.skinning import blend_skin, sparse_skin_weights

#: Upper-body joints fitted by the global transform T_G.
TORSO_JOINTS = ("SpineBase", "SpineMid", "SpineShoulder", "Neck", "ShoulderLeft", "ShoulderRight", "HipLeft",
                "HipRight")

#: Limb segments (bones moved together, parent joint, child joint), in kinematic-chain order.
SEGMENTS = (
    (("spine_01",), "SpineBase", "SpineMid"),
    (("spine_02", "spine_03"), "SpineMid", "SpineShoulder"),
    (("neck_01", "head"), "Neck", "Head"),
    (("clavicle_l",), "SpineShoulder", "ShoulderLeft"),
    (("clavicle_r",), "SpineShoulder", "ShoulderRight"),
    (("upperarm_l",), "ShoulderLeft", "ElbowLeft"),
    (("upperarm_r",), "ShoulderRight", "ElbowRight"),
    (("lowerarm_l",), "ElbowLeft", "WristLeft"),
    (("lowerarm_r",), "ElbowRight", "WristRight"),
    (("hand_l",), "WristLeft", "HandTipLeft"),
    (("hand_r",), "WristRight", "HandTipRight"),
    (("thigh_l",), "HipLeft", "KneeLeft"),
    (("thigh_r",), "HipRight", "KneeRight"),
    (("calf_l",), "KneeLeft", "AnkleLeft"),
    (("calf_r",), "KneeRight", "AnkleRight"),
    (("foot_l",), "AnkleLeft", "FootLeft"),
    (("foot_r",), "AnkleRight", "FootRight"),
)

_SCALE_RANGE = (0.6, 1.6)


@dataclass(frozen=True, eq=False)
class PoseInit:
    """The posed, resized template: vertices, per-bone transforms (B, 4, 4) and its tracker joints."""

    vertices: np.ndarray
    bone_transforms: np.ndarray
    joints: np.ndarray  # (J, 3) template Kinect joints after the transform
    global_scale: float


def similarity_transform(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Least-squares rotation, uniform scale and translation (4x4) mapping ``src`` onto ``dst`` (Umeyama)."""
    mu_s, mu_d = src.mean(0), dst.mean(0)
    a, b = src - mu_s, dst - mu_d
    U, S, Vt = np.linalg.svd(b.T @ a / len(src))
    D = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        D[2, 2] = -1.0
    R = U @ D @ Vt
    var = np.sum(a * a) / len(src)
    s = float(np.trace(np.diag(S) @ D) / var) if var > 0 else 1.0
    T = np.eye(4)
    T[:3, :3] = s * R
    T[:3, 3] = mu_d - s * R @ mu_s
    return T


def _apply(T: np.ndarray, p: np.ndarray) -> np.ndarray:
    return T[:3, :3] @ p + T[:3, 3]


def limb_transform(parent: np.ndarray, a0: np.ndarray, b0: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Local limb transform of Fig. 4a: rotate and stretch the bone ``a0 -> b0`` (after ``parent``)
    about its placed parent joint so that its end lands on the tracked joint ``b``; returns ``T_L T_parent``."""
    a_p, b_p = _apply(parent, a0), _apply(parent, b0)
    rest = b_p - a_p
    target = b - a_p
    lr, lt = np.linalg.norm(rest), np.linalg.norm(target)
    if lr < 1e-9 or lt < 1e-9:
        return parent
    u, v = rest / lr, target / lt
    s = float(np.clip(lt / lr, *_SCALE_RANGE))
    M = rotation_between(u, v) @ (np.eye(3) + (s - 1.0) * np.outer(u, u))
    TL = np.eye(4)
    TL[:3, :3] = M
    TL[:3, 3] = a_p - M @ a_p
    return TL @ parent


def joints_from_mapping(joints: dict, names: list[str]) -> np.ndarray:
    """``(J, 3)`` array in ``names`` order from a name -> xyz mapping; missing or non-finite joints are NaN."""
    out = np.full((len(names), 3), np.nan)
    for k, name in enumerate(names):
        if name in joints and joints[name] is not None:
            p = np.asarray(joints[name], dtype=np.float64).reshape(-1)
            if p.shape == (3,) and np.all(np.isfinite(p)):
                out[k] = p
    return out


def initialise_pose(body, joints: np.ndarray, version: str = "v2", rest_vertices: np.ndarray | None = None
                    ) -> PoseInit:
    """Pose and resize the template ``body`` to tracked joints ``(J, 3)`` (NaN = untracked), Eq. 11-12.

    ``rest_vertices`` replaces the template's rest shape (a warm start: the previous frame's result
    un-skinned by :func:`unpose`); the skeleton and skin weights stay the template's.
    """
    names = kinect_joint_names(version)
    joints = np.asarray(joints, dtype=np.float64)
    if joints.shape != (len(names), 3):
        raise InputError(f"pose initialisation needs {len(names)} Kinect {version} joints (J, 3), got {joints.shape}")
    valid = np.all(np.isfinite(joints), axis=1)
    index = {n: i for i, n in enumerate(names)}
    skel = body.skeleton
    rest = kinect_joints(skel, skel.heads, skel.tails, version)
    torso = [index[n] for n in TORSO_JOINTS if n in index and valid[index[n]]]
    if len(torso) < 3:
        raise InputError(f"no valid joints: pose initialisation needs at least 3 tracked upper-body joints "
                         f"({', '.join(TORSO_JOINTS)}), got {len(torso)}")
    TG = similarity_transform(rest[torso], joints[torso])
    B = skel.n_bones
    driver = {}
    for bones, a, b in SEGMENTS:
        if a in index and b in index:
            for bone in bones:
                if bone in skel.bone_names:
                    driver[skel.bone_names.index(bone)] = (bones, index[a], index[b])
    T = np.empty((B, 4, 4))
    done = {}
    for j in range(B):
        p = skel.parents[j]
        parent = TG if p < 0 else T[p]
        seg = driver.get(j)
        if seg is None:
            T[j] = TG if p < 0 else parent
            continue
        bones, ia, ib = seg
        if bones in done:  # later bones of a multi-bone segment share its transform
            T[j] = done[bones]
            continue
        if valid[ib]:
            T[j] = limb_transform(parent, rest[ia], rest[ib], joints[ib])
        else:
            T[j] = parent
        done[bones] = T[j]
    return pose_template(body, T, float(np.cbrt(np.linalg.det(TG[:3, :3]))), version, rest_vertices)


def neck_at_joint(body, bone_transforms: np.ndarray, neck: np.ndarray, unstretch_head: bool = False) -> np.ndarray:
    """Bone transforms ``(B, 4, 4)`` with the neck bone's base moved onto the tracked Neck joint ``neck`` and its
    end kept: Fig. 4a's limb transform of ``neck_01`` about ``neck``, onto where ``bone_transforms`` put its tail.

    Eq. 11 places the neck bone by its parent's transform (spine_03, fitted to SpineMid -> SpineShoulder), so where
    the template's SpineShoulder -> Neck span differs from the subject's, the neck's base lands beside the tracked
    Neck joint and the neck is posed from there (issue 15: 28-71 mm behind / below it on the hidden male subjects,
    whose span is 1.02-1.09 of SpineMid -> SpineShoulder where the androgynous template's is 0.80). The head keeps
    its transform, so the head's fit is unchanged. Returns ``bone_transforms`` itself when the template has no
    ``neck_01`` or ``neck`` is not finite.

    ``unstretch_head`` (issue 15, rec15m): Eq. 11 stretches the neck and head as one segment (Fig. 4a) from that
    misplaced base onto the tracked Head joint, 1.24-1.43x on the hidden subjects, and the head keeps the stretch
    (placing the neck takes it off the neck only). The head and its children then get the segment's rotation at the
    run's scale (the polar rotation of the head's transform times its middle singular value, the scale across the
    stretch) about the head's midpoint (the Head joint, where the fit put the head), and the neck ends at the head's
    new base.
    """
    skel = body.skeleton
    neck = np.asarray(neck, dtype=np.float64)
    if "neck_01" not in skel.bone_names or not np.all(np.isfinite(neck)):
        return bone_transforms
    b = skel.index("neck_01")
    T = np.array(bone_transforms, dtype=np.float64)
    base, tail = skel.heads[b], skel.tails[b]
    moved = T[b].copy()
    moved[:3, 3] += neck - _apply(T[b], base)
    end = _apply(bone_transforms[b], tail)
    if unstretch_head and "head" in skel.bone_names:
        h = skel.index("head")
        U, S, Vt = np.linalg.svd(T[h, :3, :3])
        rigid = np.eye(4)
        rigid[:3, :3] = float(np.median(S)) * (U @ Vt)
        mid = 0.5 * (skel.heads[h] + skel.tails[h])
        rigid[:3, 3] = _apply(T[h], mid) - rigid[:3, :3] @ mid
        change = rigid @ np.linalg.inv(T[h])
        for j in (h, *_descendants(skel, h)):
            T[j] = change @ T[j]
        end = _apply(T[h], skel.heads[h])
    T[b] = limb_transform(moved, base, tail, end)
    return T


def _descendants(skel, bone: int) -> list[int]:
    """Bones below ``bone`` in the skeleton (not itself)."""
    out, todo = [], [bone]
    while todo:
        k = todo.pop()
        children = [j for j, p in enumerate(skel.parents) if p == k]
        out += children
        todo += children
    return out


def pose_template(body, bone_transforms: np.ndarray, global_scale: float = 1.0, version: str = "v2",
                  rest_vertices: np.ndarray | None = None) -> PoseInit:
    """The template ``body`` (or ``rest_vertices``) posed by bone transforms ``(B, 4, 4)``: LBS, Eq. 12."""
    skel = body.skeleton
    T = np.asarray(bone_transforms, dtype=np.float64)
    V0 = body.vertices if rest_vertices is None else np.asarray(rest_vertices, dtype=np.float64)
    # sparse LBS (the few non-zero weights of each vertex; equal to the dense blend to rounding): 13K 6.5 -> ~0.5 ms
    idx, w = sparse_skin_weights(body.weights, k=None)
    V = blend_skin(np.ascontiguousarray(T[:, :3, :]), np.ascontiguousarray(idx), np.ascontiguousarray(w),
                   np.ascontiguousarray(V0), np.empty((0, 3)))[0]
    heads = np.einsum("bij,bj->bi", T[:, :3, :3], skel.heads) + T[:, :3, 3]
    tails = np.einsum("bij,bj->bi", T[:, :3, :3], skel.tails) + T[:, :3, 3]
    return PoseInit(V, T, kinect_joints(skel, heads, tails, version), global_scale)


def tracked_bone_lengths(joints: np.ndarray, version: str = "v2") -> np.ndarray:
    """Length (m) of each Kinect bone (joint -> its SDK parent) of one frame's joints ``(J, 3)``; NaN for the
    root and where either end is untracked."""
    from bodystudio.capture.kinect import kinect_parent_indices

    J = np.asarray(joints, dtype=np.float64)
    parents = kinect_parent_indices(version)
    out = np.full(len(parents), np.nan)
    child = parents >= 0
    out[child] = np.linalg.norm(J[child] - J[parents[child]], axis=1)
    return out


def sequence_bone_lengths(joint_frames, version: str = "v2") -> np.ndarray:
    """One length per Kinect bone for a whole sequence: the median over frames of the tracked lengths.

    A body's bones do not change length, but a tracker's do (the Kinect SDK enforces no constant bone
    lengths; the simulated tracker jitters each bone by 3 % per frame), so the median over ``joint_frames``
    (each ``(J, 3)``, NaN untracked) is a steadier estimate than any one frame's (its spread falls as
    ``1 / sqrt(frames)``). NaN where a bone was never tracked.
    """
    L = np.array([tracked_bone_lengths(J, version) for J in joint_frames])
    if L.size == 0:
        raise InputError("sequence bone lengths need at least one frame of joints")
    with np.errstate(all="ignore"):
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            return np.nanmedian(L, axis=0)


def with_bone_lengths(joints: np.ndarray, lengths: np.ndarray, version: str = "v2") -> np.ndarray:
    """Joints ``(J, 3)`` rebuilt down the Kinect hierarchy from the root with the bone ``lengths`` and
    each frame's own bone directions (a joint whose bone has no finite length or direction keeps its
    offset to its parent)."""
    from bodystudio.capture.kinect import _topological_order, kinect_parent_indices

    J = np.asarray(joints, dtype=np.float64)
    parents = kinect_parent_indices(version)
    lengths = np.asarray(lengths, dtype=np.float64)
    if J.shape != (len(parents), 3) or lengths.shape != (len(parents),):
        raise InputError(f"bone lengths need {len(parents)} Kinect {version} joints and lengths, got "
                         f"{J.shape} and {lengths.shape}")
    out = J.copy()
    for j in _topological_order(parents):
        p = parents[j]
        if p < 0:
            continue
        d = J[j] - J[p]
        n = np.linalg.norm(d)
        if np.isfinite(lengths[j]) and np.isfinite(n) and n > 1e-9:
            out[j] = out[p] + lengths[j] * d / n
        else:
            out[j] = out[p] + d
    return out


def smooth_joint_track(frames: np.ndarray, joint_frames: np.ndarray, half_window: int,
                       break_m: float | None = 0.25) -> np.ndarray:
    """Tracker joints ``(T, J, 3)`` of frames ``(T,)`` smoothed over time by a local linear fit.

    Each frame's joint is the value at that frame of the least-squares line through the joint's positions
    in the frames within ``half_window`` frame numbers of it (a Savitzky-Golay filter of degree 1 where the
    frames are consecutive; one-sided at the ends of the run). It is exact for a joint moving at constant
    velocity and averages the tracker's independent per-frame noise (1 cm per axis) over up to
    ``2 half_window + 1`` frames: meant for video-rate sequences, where a limb moves little in a few frames.
    Untracked (NaN) positions are left out of the fit and stay NaN; a joint with fewer than two tracked
    frames in its window keeps its own position. ``half_window = 0`` returns the joints unchanged. The window
    does not reach across a jump: where the median joint displacement between consecutive frames exceeds
    ``break_m`` (the tracking's lost-track ``joint_jump_m``; a person moves a few cm between video frames)
    the track is smoothed as separate pieces, so a glitch or a cut is not smeared over its neighbours.
    """
    J = np.asarray(joint_frames, dtype=np.float64)
    t = np.asarray(frames, dtype=np.float64)
    if J.ndim != 3 or J.shape[2] != 3 or len(t) != len(J):
        raise InputError(f"joint smoothing needs joints (T, J, 3) and T frame numbers, got {J.shape} and {t.shape}")
    if half_window < 0:
        raise InputError(f"joint smoothing half window {half_window} must be >= 0")
    if half_window == 0:
        return J.copy()
    out = J.copy()
    piece = np.zeros(len(t), dtype=np.int64)
    if break_m is not None and len(t) > 1:
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            jump = np.nanmedian(np.linalg.norm(J[1:] - J[:-1], axis=2), axis=1)
        piece[1:] = np.cumsum(np.nan_to_num(jump, nan=0.0) > break_m)
    for k in range(len(t)):
        near = np.flatnonzero((np.abs(t - t[k]) <= half_window) & (piece == piece[k]))
        dt = t[near] - t[k]
        for j in range(J.shape[1]):
            P = J[near, j]
            ok = np.all(np.isfinite(P), axis=1)
            if not np.all(np.isfinite(J[k, j])) or ok.sum() < 2 or np.ptp(dt[ok]) == 0:
                continue
            A = np.stack([np.ones(ok.sum()), dt[ok]], axis=1)
            coef, *_ = np.linalg.lstsq(A, P[ok], rcond=None)
            out[k, j] = coef[0]
    return out
