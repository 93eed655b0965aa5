"""Forward kinematics, linear blend skinning and dual-quaternion skinning.

Bone ``j`` has rest frame ``A_j`` (bone -> world). Its posed frame is
``M_j = M_parent(j) A_parent^-1 A_j Rot(theta_j)`` (the root: ``T(t) A_root Rot(theta_root)``), and it
moves vertices by ``S_j = M_j A_j^-1``. Linear blend skinning: ``v' = sum_j w_ij S_j v``.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from bodystudio.body.pose import Pose
from bodystudio.body.skeleton import Skeleton


def forward_kinematics(skeleton: Skeleton, pose: Pose) -> np.ndarray:
    """Posed bone frames ``(B, 4, 4)`` (bone -> world) for local rotations and root translation."""
    A = skeleton.rest_frames
    local_rot = np.tile(np.eye(4), (skeleton.n_bones, 1, 1))
    local_rot[:, :3, :3] = Rotation.from_rotvec(pose.rotations).as_matrix()
    M = np.empty_like(A)
    for j, p in enumerate(skeleton.parents):  # parents come before children
        if p < 0:
            T = np.eye(4)
            T[:3, 3] = pose.translation
            M[j] = T @ A[j] @ local_rot[j]
        else:
            M[j] = M[p] @ np.linalg.solve(A[p], A[j]) @ local_rot[j]
    return M


def skinning_transforms(skeleton: Skeleton, pose: Pose) -> np.ndarray:
    """``S_j = M_j A_j^-1``: the rigid motion each bone applies to rest-pose points, ``(B, 4, 4)``."""
    return forward_kinematics(skeleton, pose) @ np.linalg.inv(skeleton.rest_frames)


def posed_joints(skeleton: Skeleton, pose: Pose) -> tuple[np.ndarray, np.ndarray]:
    """Posed bone heads and tails ``(B, 3)`` each."""
    M = forward_kinematics(skeleton, pose)
    heads = M[:, :3, 3]
    tails = heads + M[:, :3, 1] * skeleton.lengths[:, None]
    return heads, tails


def linear_blend_skinning(vertices: np.ndarray, weights: np.ndarray, transforms: np.ndarray) -> np.ndarray:
    """``v'_i = sum_j w_ij (R_j v_i + t_j)`` for ``(n, 3)`` vertices, ``(n, B)`` weights, ``(B, 4, 4)``."""
    R = np.einsum("nb,bij->nij", weights, transforms[:, :3, :3])
    t = weights @ transforms[:, :3, 3]
    return np.einsum("nij,nj->ni", R, vertices) + t


def inverse_linear_blend_skinning(V: np.ndarray, weights: np.ndarray, transforms: np.ndarray) -> np.ndarray:
    """Inverse of LBS: rest positions whose blend by ``transforms`` (B, 4, 4) with ``weights`` (n, B) gives ``V``.

    Each point's blended affine map ``sum_k w_ik T_k`` is inverted (invertible for rotations and
    moderate stretches); Rapid Skin's un-skinning and the "inverse of the pose transformations ...
    blended with linear blend skinning" of Real-time Reshaping §4.
    """
    A = np.einsum("nb,bij->nij", weights, transforms[:, :3, :3])
    t = weights @ transforms[:, :3, 3]
    return np.linalg.solve(A, (V - t)[:, :, None])[:, :, 0]


def _quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of (..., 4) quaternions stored (w, x, y, z)."""
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack([aw * bw - ax * bx - ay * by - az * bz,
                     aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw], axis=-1)


def dual_quaternion_skinning(vertices: np.ndarray, weights: np.ndarray, transforms: np.ndarray) -> np.ndarray:
    """Dual-quaternion skinning (Kavan et al. 2007): blend unit dual quaternions, normalise, apply."""
    xyzw = Rotation.from_matrix(transforms[:, :3, :3]).as_quat()
    q_real = np.concatenate([xyzw[:, 3:], xyzw[:, :3]], axis=1)
    t_quat = np.concatenate([np.zeros((len(transforms), 1)), transforms[:, :3, 3]], axis=1)
    q_dual = 0.5 * _quat_mul(t_quat, q_real)
    # Keep all quaternions in the hemisphere of each vertex's dominant bone to avoid antipodal cancellation.
    dominant = np.argmax(weights, axis=1)
    sign = np.sign(q_real @ q_real.T)[dominant]  # (n, B)
    sign[sign == 0] = 1.0
    ws = weights * sign
    b_real = ws @ q_real
    b_dual = ws @ q_dual
    norm = np.linalg.norm(b_real, axis=1, keepdims=True)
    b_real /= norm
    b_dual /= norm
    w, xyz = b_real[:, :1], b_real[:, 1:]
    v = vertices
    rotated = v + 2.0 * np.cross(xyz, np.cross(xyz, v) + w * v)
    dw, dxyz = b_dual[:, :1], b_dual[:, 1:]
    translation = 2.0 * (w * dxyz - dw * xyz + np.cross(xyz, dxyz))
    return rotated + translation
