"""Software rendering of triangle meshes into calibrated cameras: silhouettes, depth, ids, Lambert RGB.

The studio images of Rapid Skin (Sec. 3-5: foreground silhouettes from ten cameras) and the Kinect
depth maps of Richter et al. / Robertini et al. are synthesised here. The rasteriser is a numba
z-buffer with edge functions, a top-left fill rule (adjacent triangles share edges without cracks or
double coverage) and perspective-correct barycentrics.

Lens distortion: vertices are projected with the full OpenCV distortion model, then each triangle is
rasterised linearly between its distorted vertex positions. For a body mesh (edges of a few pixels)
the error of this approximation is far below a pixel. A vertex beyond the distortion polynomial's monotonic
radius (:func:`bodystudio.geometry.camera.distortion_monotonic_radius`, where ``r_d(r)`` stops increasing and
the model folds points from beside the lens back into the image) is not drawable, like one behind the camera:
every triangle that uses it is dropped, in the colour, depth and id buffers alike (mir12t; before, a room's
ceiling corners 60 degrees off the axis folded into the mirror studio's colour images as grey wedges). Dropping
is exact where such triangles lie outside the image (big planes split finely enough); there is no clipping.

Pixel convention (OpenCV): the centre of pixel ``(row, col)`` is at image coordinates ``(u, v) = (col, row)``.
"""

from __future__ import annotations

import collections
import zlib
from dataclasses import dataclass

import igl
import numpy as np
from numba import njit

from bodystudio.errors import InputError
from bodystudio.geometry.camera import Camera

#: Light skin albedo (linear-ish sRGB in [0, 1]) used when no vertex colours are given.
SKIN_COLOR = (0.87, 0.68, 0.57)

#: Studio lighting: (direction towards the light, intensity) in world coordinates (y up).
STUDIO_LIGHTS = (
    ((0.0, 1.0, 0.3), 0.45),
    ((1.0, 0.5, 1.0), 0.25),
    ((-1.0, 0.5, 1.0), 0.25),
    ((1.0, 0.5, -1.0), 0.2),
    ((-1.0, 0.5, -1.0), 0.2),
)
AMBIENT = 0.25

NEAR_M = 1e-3


@dataclass(frozen=True, eq=False)
class RenderResult:
    """Per-pixel render buffers of one camera.

    ``mask`` (H, W) bool silhouette; ``depth`` (H, W) float32 camera z in metres, 0 where empty;
    ``triangle_id`` (H, W) int32 face index, -1 where empty; ``barycentric`` (H, W, 3) float32
    perspective-correct barycentric coordinates of the visible surface point in that face.
    """

    mask: np.ndarray
    depth: np.ndarray
    triangle_id: np.ndarray
    barycentric: np.ndarray

    def surface_points(self, V: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World points (K, 3) seen by the covered pixels, and those pixels' (row, col) indices (K, 2)."""
        rows, cols = np.nonzero(self.mask)
        tri = F[self.triangle_id[rows, cols]]
        b = self.barycentric[rows, cols].astype(np.float64)
        P = np.einsum("kj,kjd->kd", b, V[tri])
        return P, np.stack([rows, cols], axis=1)


@njit(cache=True)
def _is_top_left(ax, ay, bx, by):
    # With counter-clockwise (positive-area) triangles in image coordinates (y down), a "top" edge is
    # horizontal with b left of a, and a "left" edge goes upwards in the image (by < ay).
    return (ay == by and bx < ax) or (by < ay)


@njit(cache=True, inline="always")
def _edge(ia, xa, ya, ib, xb, yb, px, py):
    # Edge function of the directed edge a->b at p, evaluated in a canonical vertex order (lower
    # index first) and negated if needed, so two triangles sharing an edge get bit-identical values
    # of opposite sign: with the top-left rule no pixel on a shared edge is lost or drawn twice.
    if ia < ib:
        return (xb - xa) * (py - ya) - (yb - ya) * (px - xa)
    return -((xa - xb) * (py - yb) - (ya - yb) * (px - xb))


@njit(cache=True)
def _rasterize(uv, z, F, width, height, zbuf, tri_id, bary, ids=True):
    """Z-buffer rasterisation with edge functions and perspective-correct barycentrics (``ids`` False: the z-buffer
    only, ``tri_id`` and ``bary`` untouched)."""
    for f in range(F.shape[0]):
        i0, i1, i2 = F[f, 0], F[f, 1], F[f, 2]
        z0, z1, z2 = z[i0], z[i1], z[i2]
        if z0 <= NEAR_M or z1 <= NEAR_M or z2 <= NEAR_M:
            continue
        x0, y0 = uv[i0, 0], uv[i0, 1]
        x1, y1 = uv[i1, 0], uv[i1, 1]
        x2, y2 = uv[i2, 0], uv[i2, 1]
        area = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)
        if not (area > 1e-12 or area < -1e-12):
            continue  # degenerate or NaN
        swapped = False
        if area < 0.0:  # render both faces: reorder to positive orientation
            i1, i2 = i2, i1
            x1, y1, x2, y2 = x2, y2, x1, y1
            z1, z2 = z2, z1
            area = -area
            swapped = True
        xmin = max(int(np.ceil(min(x0, min(x1, x2)))), 0)
        xmax = min(int(np.floor(max(x0, max(x1, x2)))), width - 1)
        ymin = max(int(np.ceil(min(y0, min(y1, y2)))), 0)
        ymax = min(int(np.floor(max(y0, max(y1, y2)))), height - 1)
        if xmin > xmax or ymin > ymax:
            continue
        tl0 = _is_top_left(x1, y1, x2, y2)
        tl1 = _is_top_left(x2, y2, x0, y0)
        tl2 = _is_top_left(x0, y0, x1, y1)
        iz0, iz1, iz2 = 1.0 / z0, 1.0 / z1, 1.0 / z2
        for py in range(ymin, ymax + 1):
            for px in range(xmin, xmax + 1):
                # the edge function of edge (1,2) is the weight of vertex 0, etc.
                w0 = _edge(i1, x1, y1, i2, x2, y2, px, py)
                if w0 < 0.0 or (w0 == 0.0 and not tl0):
                    continue
                w1 = _edge(i2, x2, y2, i0, x0, y0, px, py)
                if w1 < 0.0 or (w1 == 0.0 and not tl1):
                    continue
                w2 = _edge(i0, x0, y0, i1, x1, y1, px, py)
                if w2 < 0.0 or (w2 == 0.0 and not tl2):
                    continue
                wsum = w0 + w1 + w2  # equals the area up to rounding; normalising keeps sum(b) = 1
                b0 = w0 / wsum
                b1 = w1 / wsum
                b2 = w2 / wsum
                inv_depth = b0 * iz0 + b1 * iz1 + b2 * iz2
                depth = 1.0 / inv_depth
                if depth < zbuf[py, px]:  # float32 buffer: ties closer than ~1e-7 z are resolved by order
                    zbuf[py, px] = depth
                    if not ids:
                        continue
                    tri_id[py, px] = f
                    p0 = b0 * iz0 * depth
                    p1 = b1 * iz1 * depth
                    p2 = b2 * iz2 * depth
                    bary[py, px, 0] = p0
                    if swapped:
                        bary[py, px, 1] = p2
                        bary[py, px, 2] = p1
                    else:
                        bary[py, px, 1] = p1
                        bary[py, px, 2] = p2


@njit(cache=True)
def _project(V, R, t, K, dist, uv, z):
    """Vertices into pixels with the OpenCV distortion model (same maths as ``Camera.project_with_depth``); NaN pixels
    behind the camera. ``V``, ``uv`` and ``z`` C-contiguous."""
    _project_flat(V.reshape(-1), R, t, K, dist, uv.reshape(-1), z)


@njit(cache=True, error_model="numpy")
def _project_flat(Vf, R, t, K, dist, uvf, z):
    """:func:`_project` over flat views with numpy's division and no branch in the loop, which LLVM vectorises (issue
    15's frame time, rec15k: the depth term projects the 13K template every outer iteration); elementwise the
    operations of the per-vertex loop it replaced, so the same values (a vertex at ``z <= 0`` or NaN: NaN pixels,
    as before). The silhouette matching projects its vertices and probes with it too
    (``reconstruct.silhouette``, rec15i)."""
    r00, r01, r02, r10, r11, r12 = R[0, 0], R[0, 1], R[0, 2], R[1, 0], R[1, 1], R[1, 2]
    r20, r21, r22, t0, t1, t2 = R[2, 0], R[2, 1], R[2, 2], t[0], t[1], t[2]
    k1, k2, p1, p2, k3 = dist[0], dist[1], dist[2], dist[3], dist[4]
    fx, sk, cx, fy, cy = K[0, 0], K[0, 1], K[0, 2], K[1, 1], K[1, 2]
    for i in range(z.shape[0]):
        X, Y, Z = Vf[3 * i], Vf[3 * i + 1], Vf[3 * i + 2]
        zc = r20 * X + r21 * Y + r22 * Z + t2
        x = (r00 * X + r01 * Y + r02 * Z + t0) / zc
        y = (r10 * X + r11 * Y + r12 * Z + t1) / zc
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
        yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
        uvf[2 * i] = fx * xd + sk * yd + cx
        uvf[2 * i + 1] = fy * yd + cy
        z[i] = zc
    for i in range(z.shape[0]):
        if not z[i] > 0.0:
            uvf[2 * i] = np.nan
            uvf[2 * i + 1] = np.nan


@njit(cache=True)
def _project_reference(V, R, t, K, dist, uv, z):
    """:func:`_project` as a per-vertex loop with a branch (before rec15k), the equality test's reference."""
    k1, k2, p1, p2, k3 = dist[0], dist[1], dist[2], dist[3], dist[4]
    for i in range(V.shape[0]):
        xc = R[0, 0] * V[i, 0] + R[0, 1] * V[i, 1] + R[0, 2] * V[i, 2] + t[0]
        yc = R[1, 0] * V[i, 0] + R[1, 1] * V[i, 1] + R[1, 2] * V[i, 2] + t[1]
        zc = R[2, 0] * V[i, 0] + R[2, 1] * V[i, 1] + R[2, 2] * V[i, 2] + t[2]
        z[i] = zc
        if zc <= 0.0:
            uv[i, 0] = np.nan
            uv[i, 1] = np.nan
            continue
        x = xc / zc
        y = yc / zc
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
        yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
        uv[i, 0] = K[0, 0] * xd + K[0, 1] * yd + K[0, 2]
        uv[i, 1] = K[1, 1] * yd + K[1, 2]


@njit(cache=True)
def _drop_folded(Vf, R, t, r2_max, uvf):
    """NaN pixels for the vertices in front of the camera whose normalised radius squared exceeds ``r2_max`` (the
    distortion's monotonic range): the rasteriser skips every triangle with a NaN vertex. Over flat views (``Vf``
    (3n,), ``uvf`` (2n,)); the test is a first loop without a branch, the rare write a second."""
    n = Vf.shape[0] // 3
    beyond = np.empty(n)
    r00, r01, r02, r10, r11, r12 = R[0, 0], R[0, 1], R[0, 2], R[1, 0], R[1, 1], R[1, 2]
    r20, r21, r22, t0, t1, t2 = R[2, 0], R[2, 1], R[2, 2], t[0], t[1], t[2]
    for i in range(n):
        X, Y, Z = Vf[3 * i], Vf[3 * i + 1], Vf[3 * i + 2]
        xc = r00 * X + r01 * Y + r02 * Z + t0
        yc = r10 * X + r11 * Y + r12 * Z + t1
        zc = r20 * X + r21 * Y + r22 * Z + t2
        beyond[i] = min(xc * xc + yc * yc - r2_max * zc * zc, zc)
    for i in range(n):
        if beyond[i] > 0.0:
            uvf[2 * i] = np.nan
            uvf[2 * i + 1] = np.nan


def _project_drawable(V: np.ndarray, camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_project`, with NaN pixels also for the vertices beyond ``camera.monotonic_radius`` (nothing changes
    for a camera without a fold, or where no vertex reaches it)."""
    uv, z = np.empty((len(V), 2)), np.empty(len(V))
    _project(V, camera.R, camera.t, camera.K, camera.dist, uv, z)
    r_max = camera.monotonic_radius
    if np.isfinite(r_max):
        _drop_folded(V.reshape(-1), camera.R, camera.t, r_max * r_max, uv.reshape(-1))
    return uv, z


def _check_mesh(V, F) -> tuple[np.ndarray, np.ndarray]:
    V = np.ascontiguousarray(V, dtype=np.float64)
    F = np.ascontiguousarray(F, dtype=np.int64)
    if V.ndim != 2 or V.shape[1] != 3 or F.ndim != 2 or F.shape[1] != 3:
        raise InputError(f"render needs vertices (n, 3) and triangles (m, 3), got {V.shape} and {F.shape}")
    if len(F) and (F.min() < 0 or F.max() >= len(V)):
        raise InputError(f"render: face indices must lie in [0, {len(V)}), got [{F.min()}, {F.max()}]")
    return V, F


def render(V: np.ndarray, F: np.ndarray, camera: Camera) -> RenderResult:
    """Rasterise mesh ``(V, F)`` into ``camera``: silhouette, depth, triangle ids and barycentrics.

    Both triangle orientations are drawn (no back-face culling); the nearest surface wins. There is
    no near-plane clipping: triangles with a vertex less than 1 mm in front of the camera, or beyond the
    distortion's monotonic radius (``camera.monotonic_radius``), are skipped.
    """
    V, F = _check_mesh(V, F)
    uv, z = _project_drawable(V, camera)
    H, W = camera.height, camera.width
    depth = np.full((H, W), np.inf, dtype=np.float32)  # the z-buffer; empty pixels become 0 below
    tri_id = np.full((H, W), -1, dtype=np.int32)
    bary = np.zeros((H, W, 3), dtype=np.float32)
    _rasterize(uv, z, F, W, H, depth, tri_id, bary)
    mask = tri_id >= 0
    depth[~mask] = 0.0
    return RenderResult(mask, depth, tri_id, bary)


def project_vertices(V: np.ndarray, camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """Pixels (n, 2) (NaN behind the camera or beyond the lens's monotonic radius) and camera z (n,) of vertices
    ``V`` as the rasteriser projects them (OpenCV distortion), for :func:`depth_buffer`."""
    return _project_drawable(np.ascontiguousarray(V, dtype=np.float64), camera)


def depth_buffer(uv: np.ndarray, z: np.ndarray, F: np.ndarray, width: int, height: int,
                 tiles: np.ndarray | None = None, tile_px: int = 8) -> np.ndarray:
    """The z-buffer (height, width) float32 of the triangles ``F`` over vertices projected to ``uv, z``
    (:func:`project_vertices`), ``inf`` where none covers the pixel: :func:`render_depth`'s, bit for bit, before
    its empty pixels become 0. Drawing a subset of ``F`` (in their order) leaves the pixels that only those
    triangles can cover as the whole mesh's. ``tiles`` (bool, one per ``tile_px`` square): only the flagged
    tiles' pixels are defined (the buffer starts at ``inf`` there and nowhere else: a caller that reads a few
    pixels does not clear the whole image, ~0.5 ms at 512x424); the others hold arbitrary values."""
    if tiles is None:
        depth = np.full((height, width), np.inf, dtype=np.float32)
    else:
        depth = np.empty((height, width), dtype=np.float32)
        _fill_tiles(depth, np.ascontiguousarray(tiles, dtype=np.bool_), int(tile_px), np.float32(np.inf))
    _rasterize(uv, z, np.ascontiguousarray(F, dtype=np.int64), width, height, depth, np.empty((0, 0), np.int32),
               np.empty((0, 0, 3), np.float32), False)
    return depth


@njit(cache=True)
def _fill_tiles(image, tiles, tile_px, value):
    """``value`` into the pixels of the ``tile_px`` squares flagged in ``tiles`` (clipped to the image)."""
    H, W = image.shape
    for ty in range(tiles.shape[0]):
        for tx in range(tiles.shape[1]):
            if tiles[ty, tx]:
                for y in range(ty * tile_px, min((ty + 1) * tile_px, H)):
                    for x in range(tx * tile_px, min((tx + 1) * tile_px, W)):
                        image[y, x] = value


def render_silhouette_depth(V: np.ndarray, F: np.ndarray, camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """:func:`render`'s ``mask`` and ``depth`` alone (the same z-buffer bit for bit), without the triangle ids and
    barycentrics: the mirror's source body needs only its silhouette and depth (MIR12f: ~15 % of a render)."""
    V, F = _check_mesh(V, F)
    uv, z = _project_drawable(V, camera)
    depth = np.full((camera.height, camera.width), np.inf, dtype=np.float32)
    _rasterize(uv, z, F, camera.width, camera.height, depth, np.empty((0, 0), np.int32),
               np.empty((0, 0, 3), np.float32), False)
    mask = depth < np.inf
    depth[~mask] = 0.0
    return mask, depth


def render_depth(V: np.ndarray, F: np.ndarray, camera: Camera) -> np.ndarray:
    """Camera-z depth image (H, W) float32 in metres, 0 where the mesh does not cover the pixel."""
    return render(V, F, camera).depth


def vertex_normals_area_weighted(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Unit vertex normals, area-weighted mean of incident face normals (libigl ``per_vertex_normals``)."""
    return igl.per_vertex_normals(np.ascontiguousarray(V, dtype=np.float64), np.ascontiguousarray(F, dtype=np.int64),
                                  igl.PER_VERTEX_NORMALS_WEIGHTING_TYPE_AREA)


def lambert_shading(normals: np.ndarray, lights=STUDIO_LIGHTS, ambient: float = AMBIENT) -> np.ndarray:
    """Lambert irradiance ``ambient + sum_k I_k max(0, n . l_k)`` for unit normals (K, 3)."""
    shade = np.full(len(normals), ambient)
    for direction, intensity in lights:
        l = np.asarray(direction, dtype=np.float64)
        l = l / np.linalg.norm(l)
        shade += intensity * np.clip(normals @ l, 0.0, None)
    return shade


@njit(cache=True)
def _shade(tri_id, bary, V, F, N, albedo, per_vertex_albedo, center, light_dirs, light_intensity, ambient, image):
    """Smooth Lambert shading of every covered pixel, written into ``image`` (uint8)."""
    H, W = tri_id.shape
    for py in range(H):
        for px in range(W):
            f = tri_id[py, px]
            if f < 0:
                continue
            n = np.zeros(3)
            p = np.zeros(3)
            c = np.zeros(3)
            for k in range(3):
                v = F[f, k]
                b = bary[py, px, k]
                for d in range(3):
                    n[d] += b * N[v, d]
                    p[d] += b * V[v, d]
                    if per_vertex_albedo:
                        c[d] += b * albedo[v, d]
            if not per_vertex_albedo:
                for d in range(3):
                    c[d] = albedo[0, d]
            length = np.sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2])
            if length > 0.0:
                n /= length
            # normals facing away from the camera (thin parts, holes) are flipped: two-sided lighting
            if n[0] * (p[0] - center[0]) + n[1] * (p[1] - center[1]) + n[2] * (p[2] - center[2]) > 0.0:
                n = -n
            shade = ambient
            for li in range(light_dirs.shape[0]):
                cos = n[0] * light_dirs[li, 0] + n[1] * light_dirs[li, 1] + n[2] * light_dirs[li, 2]
                if cos > 0.0:
                    shade += light_intensity[li] * cos
            for d in range(3):
                value = c[d] * shade * 255.0 + 0.5
                image[py, px, d] = np.uint8(min(max(value, 0.0), 255.0))


def render_rgb(V: np.ndarray, F: np.ndarray, camera: Camera, vertex_colors: np.ndarray | None = None,
               background: np.ndarray | None = None, skin_color=SKIN_COLOR, lights=STUDIO_LIGHTS,
               ambient: float = AMBIENT, result: RenderResult | None = None, noise_std: float = 0.0,
               rng: np.random.Generator | None = None, normals: np.ndarray | None = None) -> np.ndarray:
    """Lambert-shaded colour image (H, W, 3) uint8 of the mesh over ``background`` (default mid grey).

    ``vertex_colors`` (n, 3) in [0, 1] or 0..255, else a flat ``skin_color``; ``lights`` are
    directional (direction towards the light, intensity) in world coordinates. ``noise_std`` adds
    Gaussian sensor noise (in 0..255 units) with ``rng``. Pass ``result`` to reuse a rasterisation
    and ``normals`` (vertex normals of this frame) to share them between the views of a rig.
    """
    H, W = camera.height, camera.width
    if background is None:
        image = np.full((H, W, 3), 128, dtype=np.uint8)
    else:
        image = np.array(background, dtype=np.uint8, copy=True)
        if image.shape != (H, W, 3):
            raise InputError(f"background must be ({H}, {W}, 3) for camera {camera.name}, got {image.shape}")
    V, F = _check_mesh(V, F)
    result = render(V, F, camera) if result is None else result
    N = vertex_normals_area_weighted(V, F) if normals is None else np.ascontiguousarray(normals, dtype=np.float64)
    if vertex_colors is None:
        albedo, per_vertex = np.asarray(skin_color, dtype=np.float64).reshape(1, 3), False
    else:
        albedo, per_vertex = np.ascontiguousarray(vertex_colors, dtype=np.float64), True
        if albedo.shape != V.shape:
            raise InputError(f"vertex_colors must be (n, 3) like the vertices, got {albedo.shape}")
        if albedo.max(initial=0.0) > 1.0:
            albedo = albedo / 255.0
    directions = np.array([d for d, _ in lights], dtype=np.float64).reshape(-1, 3)
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    intensities = np.array([i for _, i in lights], dtype=np.float64)
    _shade(result.triangle_id, result.barycentric, V, F, N, albedo, per_vertex, camera.center, directions,
           intensities, float(ambient), image)
    if noise_std > 0:
        rng = np.random.default_rng() if rng is None else rng
        noisy = image.astype(np.float32) + rng.normal(0.0, noise_std, image.shape).astype(np.float32)
        image = np.clip(np.round(noisy), 0, 255).astype(np.uint8)
    return image


# --- background plates -------------------------------------------------------------------------

def _value_noise(u: np.ndarray, v: np.ndarray, rng: np.random.Generator, octaves: int = 4) -> np.ndarray:
    """Smooth lattice value noise in [-1, 1] at continuous coordinates (u, v) (periodic, 64x64 lattice)."""
    out = np.zeros_like(u)
    amplitude, total = 1.0, 0.0
    for _ in range(octaves):
        lattice = rng.uniform(-1.0, 1.0, (64, 64))
        iu, iv = np.floor(u).astype(np.int64), np.floor(v).astype(np.int64)
        fu, fv = u - iu, v - iv
        fu, fv = fu * fu * (3 - 2 * fu), fv * fv * (3 - 2 * fv)
        a = lattice[iu % 64, iv % 64]
        b = lattice[(iu + 1) % 64, iv % 64]
        c = lattice[iu % 64, (iv + 1) % 64]
        d = lattice[(iu + 1) % 64, (iv + 1) % 64]
        out += amplitude * ((a * (1 - fu) + b * fu) * (1 - fv) + (c * (1 - fu) + d * fu) * fv)
        total += amplitude
        amplitude *= 0.5
        u, v = u * 2.0, v * 2.0
    return out / total


def background_plate(camera: Camera, seed: int = 0, wall_radius_m: float = 5.0) -> np.ndarray:
    """A deterministic textured studio background (H, W, 3) uint8 for ``camera``.

    The studio is a cylindrical curtain wall (radius ``wall_radius_m``) with folds and a mottled
    texture, standing on a tiled floor at y = 0. Textures live in world coordinates, so all cameras
    see the same studio; ``seed`` and the camera name vary the texture and a slight per-camera gain.
    Plates are cached per camera and seed (a fresh copy is returned each call).
    """
    key = (camera.name, camera.K.tobytes(), camera.dist.tobytes(), camera.R.tobytes(), camera.t.tobytes(),
           camera.width, camera.height, int(seed), float(wall_radius_m))
    return _cached_plate(key, camera, int(seed), float(wall_radius_m)).copy()


_PLATES: collections.OrderedDict[tuple, np.ndarray] = collections.OrderedDict()


def _cached_plate(key, camera: Camera, seed: int, wall_radius_m: float) -> np.ndarray:
    if key in _PLATES:
        _PLATES.move_to_end(key)
        return _PLATES[key]
    plate = _studio_plate(camera, seed, wall_radius_m)
    plate.setflags(write=False)
    _PLATES[key] = plate
    while len(_PLATES) > 32:
        _PLATES.popitem(last=False)
    return plate


def _studio_plate(camera: Camera, seed: int, wall_radius_m: float) -> np.ndarray:
    H, W = camera.height, camera.width
    cols, rows = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
    origins, dirs = camera.rays(np.stack([cols.ravel(), rows.ravel()], axis=1))
    rng = np.random.default_rng(seed)
    cam_rng = np.random.default_rng([seed, zlib.crc32(camera.name.encode())])
    # floor hit
    with np.errstate(divide="ignore", invalid="ignore"):
        s_floor = -origins[:, 1] / dirs[:, 1]
    floor_pts = origins + s_floor[:, None] * dirs
    on_floor = (s_floor > 0) & (np.hypot(floor_pts[:, 0], floor_pts[:, 2]) < wall_radius_m)
    # wall hit: |o_xz + s d_xz| = r
    o, d = origins[:, [0, 2]], dirs[:, [0, 2]]
    a = np.einsum("ij,ij->i", d, d)
    bq = 2 * np.einsum("ij,ij->i", o, d)
    cq = np.einsum("ij,ij->i", o, o) - wall_radius_m**2
    with np.errstate(invalid="ignore", divide="ignore"):
        s_wall = (-bq + np.sqrt(np.maximum(bq * bq - 4 * a * cq, 0.0))) / (2 * a)
    wall_pts = origins + s_wall[:, None] * dirs
    angle = np.arctan2(wall_pts[:, 2], wall_pts[:, 0])
    height = wall_pts[:, 1]

    img = np.zeros((H * W, 3))
    # curtain: muted blue-grey with folds (sinusoid in angle) and mottling
    wall_noise = _value_noise((angle + np.pi) * 12.0, height * 2.5, rng)
    folds = 0.5 + 0.5 * np.sin(angle * 60.0 + 2.0 * wall_noise)
    wall_base = np.array([0.30, 0.36, 0.42])
    img[:] = wall_base * (0.75 + 0.2 * folds + 0.15 * wall_noise)[:, None]
    img[height > 2.6] = np.array([0.22, 0.22, 0.24])  # dark ceiling band
    # floor: grey-green tiles (0.5 m) with grout lines and noise
    fx, fz = floor_pts[on_floor, 0], floor_pts[on_floor, 2]
    tile = ((np.floor(fx / 0.5) + np.floor(fz / 0.5)) % 2).astype(np.float64)
    grout = (np.minimum(np.abs(fx / 0.5 - np.round(fx / 0.5)), np.abs(fz / 0.5 - np.round(fz / 0.5))) < 0.02)
    floor_noise = _value_noise(fx * 4.0 + 32.0, fz * 4.0 + 32.0, rng)
    floor = np.array([0.42, 0.45, 0.40]) * (0.85 + 0.1 * tile + 0.1 * floor_noise)[:, None]
    floor[grout] = np.array([0.2, 0.2, 0.2])
    img[on_floor] = floor
    img *= cam_rng.uniform(0.95, 1.05, 3)  # per-camera white balance
    return np.clip(np.round(img * 255.0), 0, 255).astype(np.uint8).reshape(H, W, 3)
