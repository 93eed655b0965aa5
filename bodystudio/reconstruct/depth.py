"""Kinect depth constraints: the paper's future work (§VI, "constraints that deform a mesh to fit depth
maps") and our design's second data term. Depth pixels are cleaned and unprojected into the studio
frame; each template vertex facing the sensor and not hidden behind the observed surface is associated
projectively with the depth pixel it projects to (as KinectFusion's ICP) and pulled to that pixel's
tangent plane by a point-to-plane constraint ``C_d = n . (v - q)`` in the same Gauss-Seidel solve.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
from numba import njit
from scipy.ndimage import median_filter

from bodystudio.capture.render import depth_buffer, project_vertices
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


def _checked_depth(depth_m: np.ndarray, camera) -> np.ndarray:
    D = np.asarray(depth_m, dtype=np.float64)
    if D.shape != (camera.height, camera.width):
        raise InputError(f"depth map is {D.shape[1]}x{D.shape[0]} but the depth camera {camera.name} is "
                         f"{camera.width}x{camera.height}; camera/session mismatch")
    return D


def depth_observation(depth_m: np.ndarray, camera, depth_range_m: tuple[float, float] = (0.4, 5.0),
                      floor_m: float = FLOOR_M) -> DepthObservation:
    """Clean a depth map (range, flying pixels, floor) and unproject it into the studio frame.

    Flying pixels: further than ``FLYING_PIXEL_M`` from the 3x3 median of the in-range depth (out-of-range pixels
    count as 0, the image's border reflected, as ``scipy.ndimage.median_filter``); floor: points below
    ``floor_m``; normals: the cross product of the point map's central differences, facing the sensor, where
    all four neighbours are valid. One compiled pass over the image with the sensor's undistorted pixel grid
    cached (:func:`normalised_pixel_grid`): the same arrays as :func:`depth_observation_reference` to rounding
    (issue 15's frame time, rec15f: ~28 -> ~2 ms a 512x424 frame, tested).
    """
    D = _checked_depth(depth_m, camera)
    xy = normalised_pixel_grid(camera)
    H, W = D.shape
    P, N = np.zeros((H, W, 3)), np.zeros((H, W, 3))
    depth_out, ok = np.zeros((H, W)), np.zeros((H, W), np.bool_)
    _observe(D, xy, float(depth_range_m[0]), float(depth_range_m[1]), float(floor_m), FLYING_PIXEL_M,
             np.ascontiguousarray(camera.R, dtype=np.float64), np.ascontiguousarray(camera.t, dtype=np.float64),
             np.ascontiguousarray(camera.center, dtype=np.float64), P, N, depth_out, ok)
    return DepthObservation(camera, P, N, depth_out, ok)


_PIXEL_GRIDS: dict = {}


def normalised_pixel_grid(camera) -> np.ndarray:
    """Normalised image coordinates ``(x/z, y/z)`` (H, W, 2) of every pixel centre of ``camera`` (distortion
    removed, :meth:`Camera.undistort_points`), cached per intrinsics: a depth frame's unprojection is then
    ``(x d, y d, d)`` per pixel, without undistorting its points again every frame."""
    key = (np.asarray(camera.K, np.float64).tobytes(), np.asarray(camera.dist, np.float64).tobytes(),
           int(camera.width), int(camera.height))
    grid = _PIXEL_GRIDS.get(key)
    if grid is None:
        rows, cols = np.mgrid[0:camera.height, 0:camera.width]
        uv = np.c_[cols.ravel(), rows.ravel()].astype(np.float64)
        grid = np.ascontiguousarray(camera.undistort_points(uv, normalized=True).reshape(camera.height,
                                                                                         camera.width, 2))
        grid.setflags(write=False)
        if len(_PIXEL_GRIDS) >= 8:
            _PIXEL_GRIDS.clear()
        _PIXEL_GRIDS[key] = grid
    return grid


@njit(cache=True)
def _median9(a):
    """The median of a 9-element array (sorted in place)."""
    for i in range(1, 9):
        x = a[i]
        j = i - 1
        while j >= 0 and a[j] > x:
            a[j + 1] = a[j]
            j -= 1
        a[j + 1] = x
    return a[4]


@njit(cache=True, parallel=True)
def _observe(D, xy, lo, hi, floor_m, flying_m, R, t, center, P, N, depth_out, ok):
    """:func:`depth_observation`'s pass: range, flying pixels (3x3 median, reflected border), unprojection, floor,
    then the normals of pixels whose four neighbours are valid. Writes ``P``, ``N``, ``depth_out``, ``ok``. Rows
    in ``prange`` (each pixel's arithmetic is the serial loop's: the same arrays on any number of threads)."""
    H, W = D.shape
    valid = np.zeros((H, W), np.bool_)
    for r in numba.prange(H):
        window = np.empty(9)
        for c in range(W):
            d = D[r, c]
            if not np.isfinite(d) or not (d > lo and d < hi):
                continue
            k = 0
            for dr in (-1, 0, 1):
                rr = min(max(r + dr, 0), H - 1)  # scipy's "reflect" repeats the edge pixel
                for dc in (-1, 0, 1):
                    cc = min(max(c + dc, 0), W - 1)
                    e = D[rr, cc]
                    window[k] = e if np.isfinite(e) and e > lo and e < hi else 0.0
                    k += 1
            if not abs(d - _median9(window)) < flying_m:
                continue
            x, y = xy[r, c, 0] * d, xy[r, c, 1] * d
            px, py, pz = x - t[0], y - t[1], d - t[2]
            for j in range(3):
                P[r, c, j] = px * R[0, j] + py * R[1, j] + pz * R[2, j]
            valid[r, c] = P[r, c, 1] >= floor_m
    for r in numba.prange(1, H - 1):
        for c in range(1, W - 1):
            if not (valid[r, c] and valid[r, c + 1] and valid[r, c - 1] and valid[r + 1, c] and valid[r - 1, c]):
                continue
            ux, uy, uz = (P[r, c + 1, 0] - P[r, c - 1, 0], P[r, c + 1, 1] - P[r, c - 1, 1],
                          P[r, c + 1, 2] - P[r, c - 1, 2])
            vx, vy, vz = (P[r + 1, c, 0] - P[r - 1, c, 0], P[r + 1, c, 1] - P[r - 1, c, 1],
                          P[r + 1, c, 2] - P[r - 1, c, 2])
            nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
            if nx * (center[0] - P[r, c, 0]) + ny * (center[1] - P[r, c, 1]) + nz * (center[2] - P[r, c, 2]) < 0:
                nx, ny, nz = -nx, -ny, -nz
            norm = np.sqrt(nx * nx + ny * ny + nz * nz)
            if not norm > 1e-12:
                continue
            N[r, c, 0], N[r, c, 1], N[r, c, 2] = nx / norm, ny / norm, nz / norm
            depth_out[r, c] = D[r, c]
            ok[r, c] = True


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

    One compiled pass over the vertices (projection, facing, association, the near / far tests) and, for the far
    candidates, the template's depth raster alone (no triangle ids or barycentrics) from that same projection:
    the pairs of :func:`depth_constraints_reference` (issue 15's frame time, rec15f; tested).
    """
    cam = obs.camera
    V = np.ascontiguousarray(V, dtype=np.float64)
    uv, z = project_vertices(V, cam)
    reach = F is not None and reach_m > max_distance_m
    ids, rc, d, far = _depth_pairs(V, np.ascontiguousarray(N, dtype=np.float64), uv, z,
                                   np.ascontiguousarray(cam.center, dtype=np.float64), obs.valid, obs.depth_m,
                                   obs.points, obs.normals, float(min_normal_dot), float(max_distance_m),
                                   float(reach_m) if reach else 0.0, OCCLUSION_M)
    if len(ids) == 0:
        return DepthConstraints.empty()
    if far.any():
        own = _model_depth_at(np.ascontiguousarray(F, dtype=np.int64), cam, uv, z, rc[far])
        front = (own > 0) & (z[ids[far]] <= own + MODEL_FRONT_M)
        keep = ~far
        keep[far] = front
        ids, rc, d, far = ids[keep], rc[keep], d[keep], far[keep]
    r, c = rc[:, 0], rc[:, 1]
    k = np.exp(-(d * d) / (2.0 * np.where(far, reach_sigma_m, sigma_m) ** 2))
    return DepthConstraints(ids, obs.points[r, c], obs.normals[r, c], k)


def _model_depth_at(F, cam, uv, z, pixels) -> np.ndarray:
    """The mesh's camera z (0 where it does not cover the pixel) at ``pixels`` ((row, col) rows) of ``cam``, from
    its projection ``uv, z``: :func:`render_depth`'s z-buffer there bit for bit, without the triangle ids and
    barycentrics, drawing only the triangles whose pixel box touches a ``_TILE``-pixel tile holding one of
    ``pixels`` (every triangle that covers such a pixel, in the same order), into a buffer cleared on those tiles
    only."""
    H, W = cam.height, cam.width
    need = np.zeros(((H + _TILE - 1) // _TILE, (W + _TILE - 1) // _TILE), np.bool_)
    need[pixels[:, 0] // _TILE, pixels[:, 1] // _TILE] = True
    own = depth_buffer(uv, z, F[_faces_touching(uv, F, W, H, need)], W, H, need, _TILE)[pixels[:, 0], pixels[:, 1]]
    own[own == np.inf] = 0.0
    return own


#: Tile size (pixels) of :func:`_model_depth_at`'s triangle culling.
_TILE = 8


@njit(cache=True)
def _faces_touching(uv, F, width, height, need):
    """Triangles whose pixel-centre box (``_rasterize``'s: ``ceil(min)`` .. ``floor(max)`` clipped to the image)
    touches a tile flagged in ``need``; a triangle with a non-finite vertex (which ``_rasterize`` skips) is not.

    The box's ends are the min of the vertices' ceils and the max of their floors (both monotone), taken once per
    vertex (clamped a little beyond the image, which changes no box that meets it) instead of once per triangle
    (issue 15's frame time, rec15k: 0.39 -> 0.33 ms a call at 13K, the same triangles;
    :func:`_faces_touching_reference` is the loop before)."""
    n = uv.shape[0]
    box = np.zeros((n, 4), np.int64)
    finite = np.zeros(n, np.bool_)
    for i in range(n):
        u, v = uv[i, 0], uv[i, 1]
        if np.isfinite(u) and np.isfinite(v):
            finite[i] = True
            u = min(max(u, -2.0), width + 2.0)
            v = min(max(v, -2.0), height + 2.0)
            box[i, 0], box[i, 1] = int(np.ceil(u)), int(np.floor(u))
            box[i, 2], box[i, 3] = int(np.ceil(v)), int(np.floor(v))
    m = F.shape[0]
    keep = np.zeros(m, np.bool_)
    th, tw = need.shape
    for f in range(m):
        a, b, c = F[f, 0], F[f, 1], F[f, 2]
        if not (finite[a] and finite[b] and finite[c]):
            continue
        x0 = max(min(box[a, 0], box[b, 0], box[c, 0]), 0)
        x1 = min(max(box[a, 1], box[b, 1], box[c, 1]), width - 1)
        y0 = max(min(box[a, 2], box[b, 2], box[c, 2]), 0)
        y1 = min(max(box[a, 3], box[b, 3], box[c, 3]), height - 1)
        if x0 > x1 or y0 > y1:
            continue
        for ty in range(y0 // _TILE, min(y1 // _TILE, th - 1) + 1):
            for tx in range(x0 // _TILE, min(x1 // _TILE, tw - 1) + 1):
                if need[ty, tx]:
                    keep[f] = True
        # a kept triangle is drawn whole; its pixels outside the tiles are never read
    return keep


@njit(cache=True)
def _faces_touching_reference(uv, F, width, height, need):
    """:func:`_faces_touching` with each triangle's box from its vertices' coordinates (before rec15k), kept as the
    equality test's reference."""
    m = F.shape[0]
    keep = np.zeros(m, np.bool_)
    th, tw = need.shape
    for f in range(m):
        a, b, c = F[f, 0], F[f, 1], F[f, 2]
        xa, xb, xc, ya, yb, yc = uv[a, 0], uv[b, 0], uv[c, 0], uv[a, 1], uv[b, 1], uv[c, 1]
        if not (np.isfinite(xa) and np.isfinite(xb) and np.isfinite(xc) and np.isfinite(ya) and np.isfinite(yb)
                and np.isfinite(yc)):
            continue
        lo_x, hi_x = min(xa, min(xb, xc)), max(xa, max(xb, xc))
        lo_y, hi_y = min(ya, min(yb, yc)), max(ya, max(yb, yc))
        if hi_x < 0.0 or hi_y < 0.0 or lo_x > width or lo_y > height:
            continue
        x0 = max(int(np.ceil(lo_x)), 0)
        x1 = min(int(np.floor(hi_x)), width - 1)
        y0 = max(int(np.ceil(lo_y)), 0)
        y1 = min(int(np.floor(hi_y)), height - 1)
        if x0 > x1 or y0 > y1:
            continue
        for ty in range(y0 // _TILE, min(y1 // _TILE, th - 1) + 1):
            for tx in range(x0 // _TILE, min(x1 // _TILE, tw - 1) + 1):
                if need[ty, tx]:
                    keep[f] = True
    return keep


@njit(cache=True)
def _depth_pairs(V, N, uv, z, center, valid, depth_m, points, normals, min_normal_dot, max_distance_m, reach_m,
                 occlusion_m):
    """:func:`depth_constraints`' association: vertices facing the sensor whose rounded pixel holds a valid point,
    with normals agreeing; near (not hidden, within ``max_distance_m``) or far candidates (within ``reach_m``, > 0
    only when reach is on). Returns ids, (row, col), distances and the far flags, in vertex order."""
    n = V.shape[0]
    H, W = valid.shape
    ids = np.empty(n, np.int64)
    rc = np.empty((n, 2), np.int64)
    dist = np.empty(n)
    far = np.zeros(n, np.bool_)
    m = 0
    for i in range(n):
        tx, ty, tz = center[0] - V[i, 0], center[1] - V[i, 1], center[2] - V[i, 2]
        if not N[i, 0] * tx + N[i, 1] * ty + N[i, 2] * tz > 0.2 * np.sqrt(tx * tx + ty * ty + tz * tz):
            continue
        u, v = uv[i, 0], uv[i, 1]
        if not (u > -1.0 and u < W + 1.0 and v > -1.0 and v < H + 1.0 and z[i] > 0):  # NaN fails too
            continue
        c, r = int(np.rint(u)), int(np.rint(v))
        if c < 0 or c >= W or r < 0 or r >= H or not valid[r, c]:
            continue
        dx, dy, dz = V[i, 0] - points[r, c, 0], V[i, 1] - points[r, c, 1], V[i, 2] - points[r, c, 2]
        d = np.sqrt(dx * dx + dy * dy + dz * dz)
        if not N[i, 0] * normals[r, c, 0] + N[i, 1] * normals[r, c, 1] + N[i, 2] * normals[r, c, 2] > min_normal_dot:
            continue
        near = depth_m[r, c] > z[i] - occlusion_m and d < max_distance_m
        if not near and not d < reach_m:
            continue
        ids[m], rc[m, 0], rc[m, 1], dist[m], far[m] = i, r, c, d, not near
        m += 1
    return ids[:m], rc[:m], dist[:m], far[:m]


def depth_observation_reference(depth_m: np.ndarray, camera, depth_range_m: tuple[float, float] = (0.4, 5.0),
                                floor_m: float = FLOOR_M) -> DepthObservation:
    """:func:`depth_observation` by whole-image numpy operations: the path the compiled one replaced (issue 15's
    frame time, rec15f), kept as the equality test's reference."""
    D = _checked_depth(depth_m, camera)
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


def depth_constraints_reference(V: np.ndarray, N: np.ndarray, obs: DepthObservation, sigma_m: float = 0.02,
                                max_distance_m: float = 0.05, min_normal_dot: float = 0.5,
                                F: np.ndarray | None = None, reach_m: float = 0.0,
                                reach_sigma_m: float = 0.05) -> DepthConstraints:
    """:func:`depth_constraints` by vectorised numpy over all vertices and the template's full render (ids and
    barycentrics too): the path the compiled one replaced (issue 15's frame time, rec15f), kept as the equality
    test's reference."""
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
