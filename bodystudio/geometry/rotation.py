"""Rotation-vector maths compiled for hot loops (numba): the one kernel the reconstruct fit and the mirror's IK
share."""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def rotvec_matrix_into(rx, ry, rz, out):
    """Rotation matrix of the rotation vector ``(rx, ry, rz)`` into ``out`` (3, 3): the unit quaternion
    ``(sin(a/2) w/a, cos(a/2))`` turned into a matrix (Rodrigues' formula in quaternion form), the same formulas and
    small-angle series as scipy's ``Rotation.from_rotvec(w).as_matrix()``, so the same values bit for bit."""
    angle = np.sqrt(rx * rx + ry * ry + rz * rz)
    if angle <= 1e-3:
        a2 = angle * angle
        scale = 0.5 - a2 / 48.0 + a2 * a2 / 3840.0
    else:
        scale = np.sin(angle / 2.0) / angle
    x, y, z, w = scale * rx, scale * ry, scale * rz, np.cos(angle / 2.0)
    x2, y2, z2, w2 = x * x, y * y, z * z, w * w
    xy, zw, xz, yw, yz, xw = x * y, z * w, x * z, y * w, y * z, x * w
    out[0, 0], out[0, 1], out[0, 2] = x2 - y2 - z2 + w2, 2.0 * (xy - zw), 2.0 * (xz + yw)
    out[1, 0], out[1, 1], out[1, 2] = 2.0 * (xy + zw), -x2 + y2 - z2 + w2, 2.0 * (yz - xw)
    out[2, 0], out[2, 1], out[2, 2] = 2.0 * (xz - yw), 2.0 * (yz + xw), -x2 - y2 + z2 + w2
