"""Small rotation helpers shared by the inverse-kinematics solvers (Rapid Skin §IV.A, Real-time Reshaping §5.2)."""

from __future__ import annotations

import numpy as np


def rotation_between(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Smallest rotation (3, 3) taking unit vector ``u`` to unit vector ``v``.

    Written on scalars: the IK calls it for every bone of every frame, and ``np.cross`` on one pair of
    3-vectors costs several times the arithmetic.
    """
    u0, u1, u2 = float(u[0]), float(u[1]), float(u[2])
    v0, v1, v2 = float(v[0]), float(v[1]), float(v[2])
    c = u0 * v0 + u1 * v1 + u2 * v2
    if c < -1.0 + 1e-9:
        axis = np.cross(u, [1.0, 0, 0]) if abs(u0) < 0.9 else np.cross(u, [0, 1.0, 0])
        axis /= np.linalg.norm(axis)
        return 2.0 * np.outer(axis, axis) - np.eye(3)
    w0, w1, w2 = u1 * v2 - u2 * v1, u2 * v0 - u0 * v2, u0 * v1 - u1 * v0
    K = np.array([[0.0, -w2, w1], [w2, 0.0, -w0], [-w1, w0, 0.0]])
    return np.eye(3) + K + K @ K / (1.0 + c)
