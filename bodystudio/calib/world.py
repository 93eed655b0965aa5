"""The studio world frame from a board lying on the floor, and small rigid-transform helpers.

World frame (docs/calibration.md): the floor board's plane is y = 0 with y up; the board's x axis is
world x, the board's y axis (down the printed rows) is world z; the origin is the centre of the board's
chessboard area. Scale is metric because the board's square size is.
"""

from __future__ import annotations

import cv2
import numpy as np

from bodystudio.calib.board import CharucoBoardSpec

#: Rotation board->world of the floor board: columns are the board's x, y, z axes in world coordinates.
FLOOR_BOARD_ROTATION = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


def floor_board_to_world(spec: CharucoBoardSpec) -> np.ndarray:
    """4x4 board->world transform of the board that defines the world frame (printed face up)."""
    T = np.eye(4)
    T[:3, :3] = FLOOR_BOARD_ROTATION
    T[:3, 3] = -FLOOR_BOARD_ROTATION @ spec.center_m
    return T


def rigid(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = np.asarray(t).ravel()
    return T


def rigid_inverse(T: np.ndarray) -> np.ndarray:
    R, t = T[:3, :3], T[:3, 3]
    return rigid(R.T, -R.T @ t)


def rvec_t_to_rigid(rvec, tvec) -> np.ndarray:
    return rigid(cv2.Rodrigues(np.asarray(rvec, float).reshape(3))[0], tvec)


def rigid_to_rvec_t(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return cv2.Rodrigues(T[:3, :3])[0].ravel(), T[:3, 3].copy()


def rotation_angle_deg(R: np.ndarray) -> float:
    """Angle of a rotation matrix in degrees (robust near 0)."""
    return float(np.degrees(np.linalg.norm(cv2.Rodrigues(np.asarray(R, float))[0])))


def mean_rigid(transforms: list[np.ndarray], weights=None) -> np.ndarray:
    """Weighted chordal mean of rigid transforms (rotation by SVD projection, translation by mean)."""
    T = np.asarray(transforms)
    w = np.ones(len(T)) if weights is None else np.asarray(weights, float)
    w = w / w.sum()
    M = np.einsum("i,ijk->jk", w, T[:, :3, :3])
    U, _, Vt = np.linalg.svd(M)
    R = U @ np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))]) @ Vt
    return rigid(R, np.einsum("i,ij->j", w, T[:, :3, 3]))


def similarity_align(src: np.ndarray, dst: np.ndarray, with_scale: bool = True) -> tuple[float, np.ndarray, np.ndarray]:
    """Umeyama (1991) similarity ``dst ~ s R src + t`` of point sets (N, 3)."""
    mu_s, mu_d = src.mean(0), dst.mean(0)
    S, D = src - mu_s, dst - mu_d
    U, sig, Vt = np.linalg.svd(D.T @ S / len(src))
    E = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    R = U @ E @ Vt
    s = float(np.trace(np.diag(sig) @ E) / (S ** 2).sum(1).mean()) if with_scale else 1.0
    return s, R, mu_d - s * R @ mu_s
