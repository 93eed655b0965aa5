"""Small rotation helpers shared by the inverse-kinematics solvers (Rapid Skin §IV.A, Real-time Reshaping §5.2)."""

from __future__ import annotations

import numpy as np


def rotation_between(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Smallest rotation (3, 3) taking unit vector ``u`` to unit vector ``v``."""
    w = np.cross(u, v)
    c = float(np.dot(u, v))
    if c < -1.0 + 1e-9:
        axis = np.cross(u, [1.0, 0, 0]) if abs(u[0]) < 0.9 else np.cross(u, [0, 1.0, 0])
        axis /= np.linalg.norm(axis)
        return 2.0 * np.outer(axis, axis) - np.eye(3)
    K = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
    return np.eye(3) + K + K @ K / (1.0 + c)
