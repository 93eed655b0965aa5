"""Kinect depth constraints: the paper's future work (§VI, "constraints that deform a mesh to fit depth
maps") and our design's second data term. Depth pixels are cleaned and unprojected into the studio
frame; each template vertex facing the sensor and not hidden behind the observed surface is associated
projectively with the depth pixel it projects to (as KinectFusion's ICP) and pulled to that pixel's
tangent plane by a point-to-plane constraint ``C_d = n . (v - q)`` in the same Gauss-Seidel solve.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import median_filter

from bodystudio.errors import InputError
from bodystudio.reconstruct.solver import DepthConstraints

#: Depth pixels further than this from their 3x3 median are "flying pixels" at silhouette edges.
FLYING_PIXEL_M = 0.03
#: Points below this height (metres) are floor.
FLOOR_M = 0.015
#: A vertex is hidden when the observed surface is this much closer to the sensor along its pixel.
OCCLUSION_M = 0.04
#: A vertex is the template's own front surface at its pixel when it is at most this far behind the
#: template's depth raster there (the raster interpolates the surface at the pixel centre, not at the vertex).
MODEL_FRONT_M = 0.01


@dataclass(frozen=True, eq=False)
class DepthObservation:
    """A cleaned depth map in the studio frame: per-pixel points, unit normals and validity."""

    camera: object  # the depth camera (studio-frame pose)
    points: np.ndarray  # (H, W, 3) world points
    normals: np.ndarray  # (H, W, 3) unit normals facing the sensor
    depth_m: np.ndarray  # (H, W) cleaned depth, 0 = invalid
    valid: np.ndarray  # (H, W) bool

    @property
    def n_points(self) -> int:
        return int(self.valid.sum())


def depth_observation(depth_m: np.ndarray, camera, depth_range_m: tuple[float, float] = (0.4, 5.0),
                      floor_m: float = FLOOR_M) -> DepthObservation:
    """Clean a depth map (range, flying pixels, floor) and unproject it into the studio frame."""
    D = np.asarray(depth_m, dtype=np.float64)
    if D.shape != (camera.height, camera.width):
        raise InputError(f"depth map is {D.shape[1]}x{D.shape[0]} but the depth camera {camera.name} is "
                         f"{camera.width}x{camera.height}; camera/session mismatch")
    D = np.where(np.isfinite(D), D, 0.0)
    valid = (D > depth_range_m[0]) & (D < depth_range_m[1])
    med = median_filter(np.where(valid, D, 0.0), size=3)
    valid &= np.abs(D - med) < FLYING_PIXEL_M
    rows, cols = np.nonzero(valid)
    P = np.zeros(D.shape + (3,))
    if len(rows):
        P[rows, cols] = camera.unproject(np.c_[cols, rows].astype(np.float64), D[rows, cols])
        floor = P[rows, cols, 1] < floor_m
        valid[rows[floor], cols[floor]] = False
    # Normals from central differences of the point map; both neighbours must be valid.
    N = np.zeros_like(P)
    ok = valid.copy()
    ok[:, [0, -1]] = False
    ok[[0, -1], :] = False
    ok[1:-1, 1:-1] &= valid[1:-1, 2:] & valid[1:-1, :-2] & valid[2:, 1:-1] & valid[:-2, 1:-1]
    du = P[1:-1, 2:] - P[1:-1, :-2]
    dv = P[2:, 1:-1] - P[:-2, 1:-1]
    n = np.cross(du, dv)
    N[1:-1, 1:-1] = n
    to_cam = camera.center - P
    flip = np.sum(N * to_cam, axis=2) < 0
    N[flip] *= -1.0
    norm = np.linalg.norm(N, axis=2)
    ok &= norm > 1e-12
    N[ok] /= norm[ok, None]
    N[~ok] = 0.0
    # Keep only pixels with a usable normal: the constraint is point-to-plane.
    return DepthObservation(camera, P, N, np.where(ok, D, 0.0), ok)


def depth_constraints(V: np.ndarray, N: np.ndarray, obs: DepthObservation, sigma_m: float = 0.02,
                      max_distance_m: float = 0.05, min_normal_dot: float = 0.5, F: np.ndarray | None = None,
                      reach_m: float = 0.0, reach_sigma_m: float = 0.05) -> DepthConstraints:
    """Point-to-plane constraints of visible vertices to their projectively associated depth points.

    Weight ``k = exp(-d^2 / 2 sigma^2)`` of the initial point-to-point distance ``d`` (Eq. 10's scheme in 3D).
    A vertex counts as hidden where the observed surface is more than ``OCCLUSION_M`` closer to the sensor,
    and pairs further apart than ``max_distance_m`` are dropped: that also drops the largest errors of the
    visible surface (a chest 5 cm inside the body it should fit). With the faces ``F`` and ``reach_m >
    max_distance_m`` (ours, issue 15's worst regions: depth owns what silhouettes cannot see) visibility
    comes from the template itself (:func:`model_front_vertices`: the vertex is its own front surface in the
    sensor's view, so no limb of it is in front), and such vertices pair with depth points up to ``reach_m``
    away, those beyond ``max_distance_m`` with ``k = exp(-d^2 / 2 reach_sigma^2)``.
    """
    cam = obs.camera
    uv, z = cam.project_with_depth(V)
    to_cam = cam.center - V
    facing = np.sum(N * to_cam, axis=1) > 0.2 * np.linalg.norm(to_cam, axis=1)
    px = np.round(np.nan_to_num(uv, nan=-1.0)).astype(np.int64)
    inside = (px[:, 0] >= 0) & (px[:, 0] < cam.width) & (px[:, 1] >= 0) & (px[:, 1] < cam.height) & (z > 0)
    ids = np.flatnonzero(facing & inside)
    if len(ids) == 0:
        return DepthConstraints.empty()
    r, c = px[ids, 1], px[ids, 0]
    has = obs.valid[r, c]
    ids, r, c = ids[has], r[has], c[has]
    observed = obs.depth_m[r, c]
    q = obs.points[r, c]
    nq = obs.normals[r, c]
    d = np.linalg.norm(V[ids] - q, axis=1)
    agree = np.sum(N[ids] * nq, axis=1) > min_normal_dot
    near = (observed > z[ids] - OCCLUSION_M) & (d < max_distance_m) & agree
    far = np.zeros(len(ids), bool)
    if F is not None and reach_m > max_distance_m:
        far = ~near & agree & (d < reach_m)
        if far.any():
            far[far] = model_front_vertices(V, F, cam, z[ids[far]], px[ids[far]])
    keep = near | far
    ids, q, nq, d, far = ids[keep], q[keep], nq[keep], d[keep], far[keep]
    k = np.exp(-(d * d) / (2.0 * np.where(far, reach_sigma_m, sigma_m) ** 2))
    return DepthConstraints(ids.astype(np.int64), q, nq, k)


def model_front_vertices(V: np.ndarray, F: np.ndarray, cam, z: np.ndarray, px: np.ndarray) -> np.ndarray:
    """Whether points of the mesh ``(V, F)`` at camera depth ``z`` and pixel ``px`` lie on its own front
    surface in ``cam``: at most ``MODEL_FRONT_M`` behind the mesh's depth raster at that pixel."""
    from bodystudio.capture.render import render_depth

    own = render_depth(V, F, cam)[px[:, 1], px[:, 0]]
    return (own > 0) & (z <= own + MODEL_FRONT_M)
