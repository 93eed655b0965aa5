"""Silhouette constraints of Rapid Skin §III.B: rim vertices, contour matching along the normal, Eq. 6-7, 10.

For each camera the template is projected (Eq. 6, with the camera's lens distortion), rim vertices are
those whose normal is almost perpendicular to the viewing ray, and each rim vertex searches the
silhouette mask along its projected normal within ``+-tau`` pixels for an inside->outside crossing (a
silhouette gradient that agrees with the normal). A match becomes a viewing-ray constraint weighted by
``k_sil = exp(-|v_c - p_c|^2 / 2 alpha^2)``.

Rim vertices hidden behind another body part in a view would match the occluder's contour; we drop
them by checking that one step outwards along the projected normal leaves the template's own
projected silhouette (a cheap visibility test the paper leaves implicit).

Everything per view runs in one numba pass (:func:`_match_view`); the masks are prepared once per
frame (:class:`SilhouetteViews`) for Algorithm 1's ``No`` re-matchings.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numba
import numpy as np

from bodystudio.capture.render import _project_flat, render  # _project_flat: the flat, vectorised projection
from bodystudio.errors import InputError, SessionError
from bodystudio.reconstruct.solver import SilhouetteConstraints

#: Step (pixels) along the projected normal used for the template-outline test.
_OUTLINE_STEP_PX = 2.0
#: Distance (metres) along the 3D normal used to find the normal's image direction.
_NORMAL_PROBE_M = 0.005


#: Tile size (pixels) of the probe map that culls triangles in the occlusion raster.
_TILE = 8


@numba.njit(cache=True)
def _rasterize_needed(uv, F, width, height, mask, facing, need):
    """:func:`_rasterize_mask` restricted to triangles whose bounding box touches a tile flagged in
    ``need``; pixels in flagged tiles come out exactly as in the full raster.

    The pixel-centre box of a triangle is ``ceil(min)`` .. ``floor(max)`` of its vertices, i.e. the min of
    their ceils and the max of their floors (both monotone): computed once per vertex (clamped a little
    beyond the image, which changes no box inside it) instead of once per triangle, and a triangle whose box
    spans at most two tiles each way reads its (up to four) tiles without branching; the same triangles
    are drawn (rec15c: 4.9 -> 4.7 ms a pass of 10 views, A/B alternated)."""
    th, tw = need.shape
    n = uv.shape[0]
    box = np.zeros((n, 4), np.int32)  # ceil(u), floor(u), ceil(v), floor(v); a NaN vertex fails the area test
    for i in range(n):
        u, v = uv[i, 0], uv[i, 1]
        if u == u and v == v:
            u = min(max(u, -2.0), width + 2.0)
            v = min(max(v, -2.0), height + 2.0)
            box[i, 0], box[i, 1] = int(np.ceil(u)), int(np.floor(u))
            box[i, 2], box[i, 3] = int(np.ceil(v)), int(np.floor(v))
    for f in range(F.shape[0]):
        a, b, c = F[f, 0], F[f, 1], F[f, 2]
        ax, ay, bx, by, cx, cy = uv[a, 0], uv[a, 1], uv[b, 0], uv[b, 1], uv[c, 0], uv[c, 1]
        area = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)
        if not np.isfinite(area) or area == 0.0 or area * facing < 0.0:
            continue
        x0 = max(min(box[a, 0], box[b, 0], box[c, 0]), 0)
        x1 = min(max(box[a, 1], box[b, 1], box[c, 1]), width - 1)
        y0 = max(min(box[a, 2], box[b, 2], box[c, 2]), 0)
        y1 = min(max(box[a, 3], box[b, 3], box[c, 3]), height - 1)
        tx0, tx1 = x0 // _TILE, min(x1 // _TILE, tw - 1)
        ty0, ty1 = y0 // _TILE, min(y1 // _TILE, th - 1)
        if tx1 - tx0 <= 1 and ty1 - ty0 <= 1:
            # indices clamped so that an empty box reads some tile; the emptiness test decides
            cx0, cx1 = min(max(tx0, 0), tw - 1), min(max(tx1, 0), tw - 1)
            cy0, cy1 = min(max(ty0, 0), th - 1), min(max(ty1, 0), th - 1)
            if not ((need[cy0, cx0] | need[cy0, cx1] | need[cy1, cx0] | need[cy1, cx1]) & (x0 <= x1) & (y0 <= y1)):
                continue
        else:
            if x0 > x1 or y0 > y1:
                continue
            hit = False
            for ty in range(ty0, ty1 + 1):
                for tx in range(tx0, tx1 + 1):
                    if need[ty, tx]:
                        hit = True
            if not hit:
                continue
        s = 1.0 if area > 0 else -1.0
        for y in range(y0, y1 + 1):
            for x in range(x0, x1 + 1):
                w0 = s * ((bx - x) * (cy - y) - (by - y) * (cx - x))
                w1 = s * ((cx - x) * (ay - y) - (cy - y) * (ax - x))
                w2 = s * ((ax - x) * (by - y) - (ay - y) * (bx - x))
                # Branch-free: the inside test of a rim triangle's pixels is a coin flip for the branch
                # predictor (measured 0.8 -> 0.5 ms a 13K view).
                mask[y, x] |= (w0 >= 0) & (w1 >= 0) & (w2 >= 0)
    return mask


def _rasterize_mask(uv, F, width, height, mask, facing=0.0):
    """Pixel centres covered by the projected triangles. ``facing = +-1`` rasterises only triangles of
    that screen-space orientation: on a closed mesh every covered pixel is covered by a front-facing
    triangle as well as a back-facing one, so one orientation gives the same mask at half the work."""
    need = np.ones(((height + _TILE - 1) // _TILE, (width + _TILE - 1) // _TILE), np.uint8)
    return _rasterize_needed(uv, F, width, height, mask, facing, need)


def is_closed_mesh(F: np.ndarray) -> bool:
    """Every directed edge (a, b) has exactly one opposite (b, a): a closed, consistently oriented mesh."""
    F = np.asarray(F, dtype=np.int64)
    if len(F) == 0:
        return False
    e = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    n = int(F.max()) + 1
    key = np.sort(e[:, 0] * n + e[:, 1])
    if np.any(key[1:] == key[:-1]):
        return False
    rkey = e[:, 1] * n + e[:, 0]
    pos = np.searchsorted(key, rkey)
    return bool(np.all(pos < len(key)) and np.all(key[np.minimum(pos, len(key) - 1)] == rkey))


def outline_edge_table(F: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The undirected edges of a closed, consistently oriented mesh (:func:`is_closed_mesh`) for
    :func:`_outline_edges`: ends ``a < b`` and the faces ``f_ab`` (traversing a -> b) and ``f_ba`` (b -> a), int32."""
    F = np.asarray(F, dtype=np.int64)
    a = np.concatenate([F[:, 0], F[:, 1], F[:, 2]])
    b = np.concatenate([F[:, 1], F[:, 2], F[:, 0]])
    face = np.tile(np.arange(len(F), dtype=np.int64), 3)
    n = int(F.max()) + 1
    key = a * n + b
    order = np.argsort(key, kind="stable")
    fwd = a < b
    opposite = order[np.searchsorted(key[order], b[fwd] * n + a[fwd])]
    return tuple(np.ascontiguousarray(x, dtype=np.int32) for x in (a[fwd], b[fwd], face[fwd], face[opposite]))


@numba.njit(cache=True, error_model="numpy")
def _front_faces(uvf, Ff, facing, front):
    """Triangles :func:`_rasterize_needed` draws with ``facing = +-1`` (finite, non-zero screen area of that sign),
    one branch-free pass over flat views."""
    for f in range(front.shape[0]):
        a, b, c = Ff[3 * f], Ff[3 * f + 1], Ff[3 * f + 2]
        ax, ay, bx, by = uvf[2 * a], uvf[2 * a + 1], uvf[2 * b], uvf[2 * b + 1]
        cx, cy = uvf[2 * c], uvf[2 * c + 1]
        area = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)
        front[f] = (area * facing > 0.0) & (abs(area) < np.inf)


@numba.njit(cache=True, error_model="numpy")
def _boundary_edge_ids(face_ab, face_ba, front, out):
    """Ids of the edges with a drawn triangle on one side only, compacted without a branch (they are ~10 % of the
    edges, spread: a branch per edge mispredicts); returns their number."""
    k = 0
    for e in range(face_ab.shape[0]):
        out[k] = e
        k += front[face_ab[e]] != front[face_ba[e]]
    return k


@numba.njit(cache=True)
def _outline_edges(uv, edge_a, edge_b, face_ab, front, boundary, n_boundary, height, edges, rows):
    """The boundary of the drawn triangles' union as directed edges ``(x0, y0, x1, y1)`` (as their drawn triangle
    traverses them) with the pixel-centre rows ``r0 .. r1`` they cross (``min(y) <= r < max(y)``, in the image);
    edges that cross none are left out. Returns their number."""
    k = 0
    for j in range(n_boundary):
        e = boundary[j]
        a, b = edge_a[e], edge_b[e]
        if not front[face_ab[e]]:
            a, b = b, a
        y0, y1 = uv[a, 1], uv[b, 1]
        r0 = np.ceil(min(max(min(y0, y1), 0.0), height))
        r1 = np.ceil(min(max(max(y0, y1), 0.0), height)) - 1.0
        edges[k, 0], edges[k, 1], edges[k, 2], edges[k, 3] = uv[a, 0], y0, uv[b, 0], y1
        rows[k, 0], rows[k, 1] = int(r0), int(r1)
        k += r1 >= r0
    return k


@numba.njit(cache=True)
def _outline_rows(edges, rows, k, height):
    """The outline edges' crossings of the pixel-centre rows: row ``r``'s are ``start[r]:start[r + 1]``, at
    ``x_cross`` with ``sign`` +1 where the edge runs down the image (``y0 < y1``), -1 up."""
    start = np.zeros(height + 1, np.int64)
    for i in range(k):
        for r in range(rows[i, 0], rows[i, 1] + 1):
            start[r + 1] += 1
    for r in range(height):
        start[r + 1] += start[r]
    x_cross = np.empty(start[height])
    sign = np.empty(start[height], np.int64)
    fill = start[:height].copy()
    for i in range(k):
        x0, y0, x1, y1 = edges[i, 0], edges[i, 1], edges[i, 2], edges[i, 3]
        slope = (x1 - x0) / (y1 - y0)  # y1 != y0: the edge crosses a row
        for r in range(rows[i, 0], rows[i, 1] + 1):
            j = fill[r]
            x_cross[j] = x0 + (r - y0) * slope
            sign[j] = 1 if y0 < y1 else -1
            fill[r] = j + 1
    return start, x_cross, sign


@numba.njit(cache=True)
def _outline_covers(start, x_cross, sign, px, py):
    """Whether pixel centre ``(px, py)`` lies in the union of the drawn triangles: the winding number of its
    boundary (the signed crossings right of the pixel on its row, Sunday's rule) is the number of drawn triangles
    covering it, so non-zero exactly where :func:`_rasterize_needed` sets it (up to rounding at a pixel centre
    on an edge: one on an outline crossing counts as covered, as the raster's inclusive edge tests have it). One
    branch-free pass over the row's crossings."""
    w = 0
    on_edge = False
    for j in range(start[py], start[py + 1]):
        w += sign[j] * (x_cross[j] > px)
        on_edge |= x_cross[j] == px
    return w != 0 or on_edge


@numba.njit(cache=True)
def _draw_outline(uv, F, facing, edge_a, edge_b, face_ab, face_ba, height, boundary, edges, rows):
    """:func:`_front_faces`, :func:`_boundary_edge_ids` and :func:`_outline_edges` of one view; returns the
    number of outline edges left in ``edges`` / ``rows``."""
    front = np.empty(F.shape[0], np.bool_)
    _front_faces(uv.reshape(-1), F.reshape(-1), facing, front)
    nb = _boundary_edge_ids(face_ab, face_ba, front, boundary)
    return _outline_edges(uv, edge_a, edge_b, face_ab, front, boundary, nb, height, edges, rows)


@numba.njit(cache=True)
def outline_coverage(edges, rows, count, width, height):
    """The ``(height, width)`` uint8 mask of the pixel centres inside an outline of :func:`_draw_outline` (a
    view's kept one: :meth:`SilhouetteViews.kept_outline`), :func:`_rasterize_mask`'s mask; for tests."""
    start, x_cross, sign = _outline_rows(edges, rows, count, height)
    out = np.zeros((height, width), np.uint8)
    for y in range(height):
        for x in range(width):
            out[y, x] = _outline_covers(start, x_cross, sign, x, y)
    return out


def silhouette_mask(V: np.ndarray, F: np.ndarray, camera) -> np.ndarray:
    """Binary mask ``(H, W)`` of the mesh's projection, by the capture stage's renderer (the same
    rasteriser that made the ground-truth masks, so silhouette IoUs compare like with like)."""
    return render(V, F, camera).mask


def rim_vertices(V: np.ndarray, N: np.ndarray, camera, max_cos: float = 0.2) -> np.ndarray:
    """Rim vertices of a view: normal almost parallel to the image plane, ``|n . ray| < max_cos`` (§III.B)."""
    ray = V - camera.center
    ray /= np.linalg.norm(ray, axis=1, keepdims=True)
    return np.abs(np.sum(N * ray, axis=1)) < max_cos


@numba.njit(cache=True)
def _sample_bilinear(img, x, y):
    h, w = img.shape
    if not (x >= 0.0 and y >= 0.0 and x <= w - 1 and y <= h - 1):
        return 0.0
    x0 = min(int(x), w - 2)
    y0 = min(int(y), h - 2)
    fx = x - x0
    fy = y - y0
    return ((1 - fx) * (1 - fy) * img[y0, x0] + fx * (1 - fy) * img[y0, x0 + 1]
            + (1 - fx) * fy * img[y0 + 1, x0] + fx * fy * img[y0 + 1, x0 + 1])


@numba.njit(cache=True, inline="always")
def _crossing(prev, cur, s):
    """Sub-pixel inside -> outside crossing between samples ``s - 1`` and ``s`` (NaN if none)."""
    if prev >= 0.5 and cur < 0.5:
        return (s - 1) + (prev - 0.5) / (prev - cur)
    return np.nan


@numba.njit(cache=True)
def _nearest_crossing(mask, x, y, dx, dy, steps, tau_px):
    """Nearest agreeing crossing along ``l(t) = (x, y) + t (dx, dy)``, ``|t| <= tau`` (§III.B), searched
    outwards from ``t = 0``: the unit intervals ``[k, k+1]`` and ``[-k-1, -k]`` hold every crossing with
    ``k <= |t| < k+1``, so the first pair that holds one ends the search (same result as scanning all
    ``2 tau`` samples; ties go to the negative side, as a scan in increasing ``t`` would)."""
    c0 = _sample_bilinear(mask, x, y)
    pos_prev = c0  # sample at +k
    neg_next = c0  # sample at -k
    for k in range(steps):
        pos_cur = _sample_bilinear(mask, x + (k + 1) * dx, y + (k + 1) * dy)
        neg_cur = _sample_bilinear(mask, x - (k + 1) * dx, y - (k + 1) * dy)
        tn = _crossing(neg_cur, neg_next, -k)
        tp = _crossing(pos_prev, pos_cur, k + 1)
        if not abs(tn) <= tau_px:
            tn = np.nan
        if not abs(tp) <= tau_px:
            tp = np.nan
        if np.isfinite(tn) and not (abs(tp) < abs(tn)):
            return tn
        if np.isfinite(tp):
            return tp
        pos_prev = pos_cur
        neg_next = neg_cur
    return np.nan


@numba.njit(cache=True)
def _search_contours(mask, uv, direction, tau_px):
    m = uv.shape[0]
    out = np.full(m, np.nan)
    steps = int(np.ceil(tau_px))
    for i in range(m):
        out[i] = _nearest_crossing(mask, uv[i, 0], uv[i, 1], direction[i, 0], direction[i, 1], steps, tau_px)
    return out


def match_contours(mask: np.ndarray, uv: np.ndarray, normal_2d: np.ndarray, tau_px: float = 30.0) -> np.ndarray:
    """Signed offsets ``t`` (pixels, NaN = no match) of the nearest agreeing contour crossing along
    ``l(t) = uv + t n`` for ``|t| <= tau`` (Rapid Skin §III.B); sub-pixel by bilinear interpolation."""
    return _search_contours(np.ascontiguousarray(mask, dtype=np.float64), np.ascontiguousarray(uv, dtype=np.float64),
                            np.ascontiguousarray(normal_2d, dtype=np.float64), float(tau_px))


def silhouette_weight(pixel_distance: np.ndarray, alpha_px: float = 40.0) -> np.ndarray:
    """Silhouette constraint weight, Eq. 10 of Rapid Skin: ``exp(-d^2 / 2 alpha^2)``."""
    d = np.asarray(pixel_distance, dtype=np.float64)
    return np.exp(-(d * d) / (2.0 * alpha_px * alpha_px))


def check_masks(masks: dict, cameras, where: str = "frame") -> None:
    """Every camera needs a mask of its image size with some foreground; one-line SessionError otherwise."""
    for cam in cameras:
        if cam.name not in masks:
            raise SessionError(f"{where}: no silhouette mask for camera {cam.name}; the session and its "
                               f"cameras.json disagree (masks for {', '.join(sorted(masks)) or 'none'})")
        mk = np.asarray(masks[cam.name])
        if mk.shape[:2] != (cam.height, cam.width):
            raise SessionError(f"{where}: mask of {cam.name} is {mk.shape[1]}x{mk.shape[0]} but the camera is "
                               f"{cam.width}x{cam.height}; camera/session mismatch")
        if not np.any(mk):
            raise SessionError(f"{where}: the silhouette mask of {cam.name} is empty; check the segmentation "
                               f"or drop the camera")


@numba.njit(cache=True, inline="always")
def _project_point(X, Y, Z, R, t, K, dist, has_dist):
    """Eq. 6 with OpenCV's Brown-Conrady distortion: pixel (u, v), depth z and undistorted (x, y)."""
    xc = R[0, 0] * X + R[0, 1] * Y + R[0, 2] * Z + t[0]
    yc = R[1, 0] * X + R[1, 1] * Y + R[1, 2] * Z + t[1]
    zc = R[2, 0] * X + R[2, 1] * Y + R[2, 2] * Z + t[2]
    if not zc > 0.0:
        return np.nan, np.nan, zc, np.nan, np.nan
    x = xc / zc
    y = yc / zc
    xd, yd = x, y
    if has_dist:
        k1, k2, p1, p2, k3 = dist[0], dist[1], dist[2], dist[3], dist[4]
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
        yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    u = K[0, 0] * xd + K[0, 1] * yd + K[0, 2]
    v = K[1, 1] * yd + K[1, 2]
    return u, v, zc, x, y


@numba.njit(cache=True)
def _project_all(V, R, t, K, dist):
    """Pixels ``(n, 2)`` (NaN behind the camera) and depths ``(n,)`` of all vertices, Eq. 6 with OpenCV
    distortion; camera constants hoisted out of the loop (zero distortion reproduces the pinhole exactly)."""
    n = V.shape[0]
    uv = np.empty((n, 2))
    z = np.empty(n)
    _project_into(V, R, t, K, dist, uv, z)
    return uv, z


@numba.njit(cache=True)
def _project_into(V, R, t, K, dist, uv, z):
    """:func:`_project_all` into the buffers ``uv`` and ``z`` (all three C-contiguous)."""
    _project_flat(V.reshape(-1), R, t, K, dist, uv.reshape(-1), z)


@numba.njit(cache=True)
def _undistort_from(u, v, x, y, K, dist, has_dist):
    """Normalised undistorted point of pixel (u, v) by Newton's method started at (x, y) (the rim vertex's
    own undistorted image point, <= tau pixels away, so a few steps reach machine precision)."""
    ty = (v - K[1, 2]) / K[1, 1]
    tx = (u - K[0, 2] - K[0, 1] * ty) / K[0, 0]
    if not has_dist:
        return tx, ty
    k1, k2, p1, p2, k3 = dist[0], dist[1], dist[2], dist[3], dist[4]
    for _ in range(20):
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        rx = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x) - tx
        ry = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y - ty
        if abs(rx) < 1e-15 and abs(ry) < 1e-15:
            break
        dr = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)
        j00 = radial + x * dr * 2 * x + 2 * p1 * y + p2 * 6 * x
        j01 = x * dr * 2 * y + 2 * p1 * x + p2 * 2 * y
        j10 = y * dr * 2 * x + p1 * 2 * x + 2 * p2 * y
        j11 = radial + y * dr * 2 * y + p1 * 6 * y + 2 * p2 * x
        det = j00 * j11 - j01 * j10
        x -= (j11 * rx - j01 * ry) / det
        y -= (j00 * ry - j10 * rx) / det
    return x, y


@numba.njit(cache=True)
def area_weighted_normals(V, F):
    """Area-weighted unit vertex normals (the rim test's ``n``, §III.B), one pass over the faces."""
    N = np.zeros_like(V)
    for f in range(F.shape[0]):
        a, b, c = F[f, 0], F[f, 1], F[f, 2]
        e1x, e1y, e1z = V[b, 0] - V[a, 0], V[b, 1] - V[a, 1], V[b, 2] - V[a, 2]
        e2x, e2y, e2z = V[c, 0] - V[a, 0], V[c, 1] - V[a, 1], V[c, 2] - V[a, 2]
        nx = e1y * e2z - e1z * e2y
        ny = e1z * e2x - e1x * e2z
        nz = e1x * e2y - e1y * e2x
        for v in (a, b, c):
            N[v, 0] += nx
            N[v, 1] += ny
            N[v, 2] += nz
    for i in range(V.shape[0]):
        ln = max(np.sqrt(N[i, 0] ** 2 + N[i, 1] ** 2 + N[i, 2] ** 2), 1e-300)
        N[i, 0] /= ln
        N[i, 1] /= ln
        N[i, 2] /= ln
    return N


@numba.njit(cache=True)
def _match_view(V, N, F, R, t, K, dist, has_dist, center, width, height, mask, own, facing, tau_px, rim_cos,
                probe_m, outline_px, uv, z, outline_mode, rim_stride, edge_table, boundary, outline_edges,
                outline_rows, outline_count):
    """Rim vertices of one view matched with its silhouette contour (Rapid Skin §III.B, Eq. 6-7).

    Projects the vertices (Eq. 6), keeps rim vertices (``|n . ray| < rim_cos``) and their outward
    probe pixels, rasterises the template's own silhouette into ``own`` only where a probe can read it
    (triangles whose bounding box misses every probe tile cannot cover a probe pixel, so the test is
    exact), drops rim vertices whose probe lies inside it (occluded), searches ``mask`` along the
    projected normal (``+-tau``) and turns each match into a viewing ray through the matched pixel
    (Eq. 7). Returns vertex ids, signed offsets ``t`` (pixels) and unit ray directions; the projection of
    every vertex is left in ``uv`` and ``z`` (for the visual-hull gate).

    ``outline_mode`` (issue 15's frame time): 0 draws the outline raster where the probes need it (exact);
    1 draws all of it, so that 2 can keep it as it is (the outline of an earlier outer iteration: the mesh
    moved by millimetres since). ``rim_stride`` keeps every ``rim_stride``-th vertex id as a rim candidate.

    On a closed mesh (``edge_table`` from :func:`outline_edge_table`, ``(4, E)``; empty otherwise) the outline is
    not rasterised: its boundary edges are kept in ``outline_edges`` / ``outline_rows`` (``outline_count[0]`` of
    them, ``boundary`` their scratch) and a probe is inside where their winding number is not zero
    (:func:`_outline_covers`; issue 15's frame time, rec15k: the same pixels as the raster, without its loop over
    every triangle's box). Modes 0 and 1 are then the same, and 2 reads the kept edges.
    """
    n = V.shape[0]
    _project_into(V, R, t, K, dist, uv, z)
    cand = np.empty(n, np.int64)
    cdir = np.empty((n, 2))
    cpix = np.empty((n, 2), np.int64)
    tiles_w = (width + _TILE - 1) // _TILE
    tiles_h = (height + _TILE - 1) // _TILE
    need = np.zeros((tiles_h, tiles_w), np.uint8)
    rim = np.empty(n, np.bool_)
    _rim_flags(V.reshape(-1), N.reshape(-1), uv.reshape(-1), z, center, float(width), float(height), rim_cos, rim)
    # the rim candidates' probe points projected in one vectorised pass (issue 15's frame time, rec15k: the same
    # operations as a per-point _project_point, whose pinhole branch is the zero-distortion formula exactly)
    nr = 0
    for i in range(0, n, rim_stride):
        cand[nr] = i
        nr += rim[i]
    probe = np.empty(3 * nr)
    for j in range(nr):
        i = cand[j]
        probe[3 * j] = V[i, 0] + probe_m * N[i, 0]
        probe[3 * j + 1] = V[i, 1] + probe_m * N[i, 1]
        probe[3 * j + 2] = V[i, 2] + probe_m * N[i, 2]
    probe_uv = np.empty(2 * nr)
    _project_flat(probe, R, t, K, dist, probe_uv, np.empty(nr))
    nc = 0
    for j in range(nr):
        i = cand[j]
        u, v = uv[i, 0], uv[i, 1]
        dx, dy = probe_uv[2 * j] - u, probe_uv[2 * j + 1] - v
        dn = np.sqrt(dx * dx + dy * dy)
        if not (np.isfinite(dn) and dn > 1e-9):
            continue
        dx /= dn
        dy /= dn
        ox = int(min(max(np.round(u + outline_px * dx), 0.0), width - 1.0))
        oy = int(min(max(np.round(v + outline_px * dy), 0.0), height - 1.0))
        cand[nc] = i
        cdir[nc, 0], cdir[nc, 1] = dx, dy
        cpix[nc, 0], cpix[nc, 1] = ox, oy
        need[oy // _TILE, ox // _TILE] = 1
        nc += 1
    closed = edge_table.shape[1] > 0
    if closed:
        if outline_mode != 2:
            outline_count[0] = _draw_outline(uv, F, facing, edge_table[0], edge_table[1], edge_table[2],
                                             edge_table[3], height, boundary, outline_edges, outline_rows)
        row_start, x_cross, cross_sign = _outline_rows(outline_edges, outline_rows, outline_count[0], height)
    else:
        row_start, x_cross, cross_sign = np.zeros(1, np.int64), np.zeros(0), np.zeros(0, np.int64)
        if outline_mode == 1:
            need[:, :] = 1
        if outline_mode != 2:
            own[:, :] = 0
            _rasterize_needed(uv, F, width, height, own, facing, need)
    ids = np.empty(nc, np.int64)
    offs = np.empty(nc)
    dirs = np.empty((nc, 3))
    m = 0
    steps = int(np.ceil(tau_px))
    for c in range(nc):
        # Occlusion: one step outwards must leave the template's own projected silhouette.
        if closed:
            if _outline_covers(row_start, x_cross, cross_sign, cpix[c, 0], cpix[c, 1]):
                continue
        elif own[cpix[c, 1], cpix[c, 0]] != 0:
            continue
        i = cand[c]
        u, v, dx, dy = uv[i, 0], uv[i, 1], cdir[c, 0], cdir[c, 1]
        best = _nearest_crossing(mask, u, v, dx, dy, steps, tau_px)
        if not np.isfinite(best):
            continue
        # Newton's start: the vertex's undistorted image point, as _project_point has it (a rim vertex has z > 0)
        X, Y, Z = V[i, 0], V[i, 1], V[i, 2]
        zc = R[2, 0] * X + R[2, 1] * Y + R[2, 2] * Z + t[2]
        x0 = (R[0, 0] * X + R[0, 1] * Y + R[0, 2] * Z + t[0]) / zc
        y0 = (R[1, 0] * X + R[1, 1] * Y + R[1, 2] * Z + t[1]) / zc
        x, y = _undistort_from(u + best * dx, v + best * dy, x0, y0, K, dist, has_dist)
        # World direction R^T (x, y, 1), normalised.
        wx = R[0, 0] * x + R[1, 0] * y + R[2, 0]
        wy = R[0, 1] * x + R[1, 1] * y + R[2, 1]
        wz = R[0, 2] * x + R[1, 2] * y + R[2, 2]
        wn = np.sqrt(wx * wx + wy * wy + wz * wz)
        ids[m] = i
        offs[m] = best
        dirs[m, 0], dirs[m, 1], dirs[m, 2] = wx / wn, wy / wn, wz / wn
        m += 1
    return ids[:m], offs[:m], dirs[:m]


@numba.njit(cache=True, error_model="numpy")
def _rim_flags(Vf, Nf, uvf, z, center, width, height, rim_cos, rim):
    """Rim candidates of :func:`_match_view` (in the image, in front of the camera, ``|n . ray| < rim_cos |ray|``,
    §III.B) of every vertex in one branch-free pass over flat views, which LLVM vectorises (issue 15's frame time,
    rec15i); the same tests on the same values, so the same decisions as the per-vertex branches they replace."""
    cx, cy, cz = center[0], center[1], center[2]
    for i in range(z.shape[0]):
        u, v = uvf[2 * i], uvf[2 * i + 1]
        rx, ry, rz = Vf[3 * i] - cx, Vf[3 * i + 1] - cy, Vf[3 * i + 2] - cz
        rn = np.sqrt(rx * rx + ry * ry + rz * rz)
        seen = (z[i] > 0.0) & (u >= 0.0) & (u < width) & (v >= 0.0) & (v < height)
        rim[i] = seen & (abs(Nf[3 * i] * rx + Nf[3 * i + 1] * ry + Nf[3 * i + 2] * rz) < rim_cos * rn)


@numba.njit(cache=True, parallel=True)
def _match_views(V, N, F, R, t, K, dist, has_dist, center, width, height, masks, owns, facing, tau_px, rim_cos,
                 probe_m, outline_px, uv, z, outline_mode, rim_stride, use_view, edge_table, boundary, outline_edges,
                 outline_rows, outline_count):
    """:func:`_match_view` of every camera in one compiled call, ``prange`` over the cameras (each its own
    mask and outline buffer, so the views run on as many threads as numba has); the matches concatenated
    in camera order, as the per-view loop of :func:`silhouette_constraints` builds them, with their camera
    ids. The per-view arithmetic is :func:`_match_view`'s, so the constraints are bit-identical. Cameras with
    ``use_view[c]`` false are not matched (nor projected into ``uv`` / ``z``)."""
    C, n = R.shape[0], V.shape[0]
    ids_c = np.empty((C, n), np.int64)
    offs_c = np.empty((C, n))
    dirs_c = np.empty((C, n, 3))
    counts = np.zeros(C, np.int64)
    for c in numba.prange(C):
        if not use_view[c]:
            continue
        ids, offs, dirs = _match_view(V, N, F, R[c], t[c], K[c], dist[c], has_dist[c], center[c], width, height,
                                      masks[c], owns[c], facing, tau_px, rim_cos, probe_m, outline_px, uv[c], z[c],
                                      outline_mode, rim_stride, edge_table, boundary[c], outline_edges[c],
                                      outline_rows[c], outline_count[c:c + 1])
        m = ids.shape[0]
        counts[c] = m
        ids_c[c, :m] = ids
        offs_c[c, :m] = offs
        dirs_c[c, :m] = dirs
    total = counts.sum()
    ids_out = np.empty(total, np.int64)
    offs_out = np.empty(total)
    dirs_out = np.empty((total, 3))
    cam_out = np.empty(total, np.int64)
    k = 0
    for c in range(C):
        m = counts[c]
        ids_out[k:k + m] = ids_c[c, :m]
        offs_out[k:k + m] = offs_c[c, :m]
        dirs_out[k:k + m] = dirs_c[c, :m]
        cam_out[k:k + m] = c
        k += m
    return ids_out, offs_out, dirs_out, cam_out


_CLOSED_CACHE: dict = {}


def _is_closed_cached(F: np.ndarray) -> bool:
    """:func:`is_closed_mesh` memoised on the face array's content (one template, many frames): keyed by a
    hash of every 97th face and checked against a stored copy (hashing all 26K faces was 0.8 ms a frame;
    the comparison is ~0.1 ms)."""
    F = np.ascontiguousarray(F, dtype=np.int64)
    key = (F.shape, hashlib.blake2b(F[::97].tobytes(), digest_size=16).digest())
    hit = _CLOSED_CACHE.get(key)
    if hit is None or not np.array_equal(hit[0], F):
        if len(_CLOSED_CACHE) > 16:
            _CLOSED_CACHE.clear()
        hit = _CLOSED_CACHE[key] = [F.copy(), is_closed_mesh(F), None]
    return hit[1]


def _outline_table_cached(F: np.ndarray) -> np.ndarray:
    """:func:`outline_edge_table` of a closed mesh as one ``(4, E)`` int32 array, memoised with
    :func:`_is_closed_cached` (~3 ms at 13K, once per template); ``(4, 0)`` for any other mesh."""
    if not _is_closed_cached(F):
        return np.zeros((4, 0), np.int32)
    F = np.ascontiguousarray(F, dtype=np.int64)
    hit = _CLOSED_CACHE[(F.shape, hashlib.blake2b(F[::97].tobytes(), digest_size=16).digest())]
    if hit[2] is None:
        hit[2] = np.ascontiguousarray(np.stack(outline_edge_table(F)))
    return hit[2]


@dataclass(frozen=True)
class MatchSchedule:
    """Cheaper matchings at the last outer iterations of Algorithm 1 (issue 15's frame time; by default every
    outer iteration matches every view, rim vertex and outline, as the paper).

    The last ``cheap_iterations`` outer iterations (never the first: it moves the mesh the most) match with:
    ``keep_outline``, the occlusion raster (the template's own outline) drawn whole at the iteration before
    them and kept (the mesh moves by millimetres between them), read ``kept_outline_step_px`` out from a rim
    vertex (the occlusion test's step; a vertex that moved inwards since reads further in the kept outline);
    ``rim_stride`` / ``view_stride``, every
    ``k``-th rim vertex / camera only (the cameras rotate with the iteration); ``gate``, the visual-hull gate:
    ``"each"`` decides every match, ``"reuse"`` keeps the decision an earlier outer iteration of the frame made
    for the same vertex in the same view and decides only the new pairs (the target moves with its vertex,
    by millimetres), ``"off"`` gates nothing. A tracked frame (No = 3) with ``cheap_iterations = 2`` has one
    full matching; a re-initialised one (No = 8) six.
    """

    cheap_iterations: int = 0
    keep_outline: bool = False
    kept_outline_step_px: float = _OUTLINE_STEP_PX
    rim_stride: int = 1
    view_stride: int = 1
    gate: str = "each"

    def __post_init__(self):
        for name, value, lo, hi in (("cheap_iterations", self.cheap_iterations, 0, 100),
                                    ("rim_stride", self.rim_stride, 1, 16), ("view_stride", self.view_stride, 1, 16)):
            if not lo <= value <= hi:
                raise InputError(f"matching {name} {value} is out of range; use a value in [{lo}, {hi}]")
        if not (np.isfinite(self.kept_outline_step_px) and 0.5 <= self.kept_outline_step_px <= 20.0):
            raise InputError(f"matching kept_outline_step_px {self.kept_outline_step_px:g} is out of range; use a "
                             "value in [0.5, 20] (pixels)")
        if self.gate not in ("each", "reuse", "off"):
            raise InputError(f"matching gate {self.gate!r} is unknown; use each, reuse or off")

    def first_cheap(self, n_outer: int) -> int:
        """The first outer iteration (from 0) that matches the cheaper way (``n_outer``: none)."""
        return max(n_outer - self.cheap_iterations, 1) if self.cheap_iterations else n_outer

    def matching_args(self, outer: int, n_outer: int, n_views: int) -> dict:
        """Keyword arguments of :func:`silhouette_constraints` at outer iteration ``outer`` of ``n_outer`` (none
        where the matching is the exact one)."""
        first = self.first_cheap(n_outer)
        if outer < first:
            keep_next = self.keep_outline and self.cheap_iterations and outer == first - 1
            return {"outline": "full"} if keep_next else {}
        use_view = None
        if self.view_stride > 1:
            use_view = (np.arange(n_views) % self.view_stride) == (outer % self.view_stride)
        return {"outline": "keep" if self.keep_outline else "draw", "rim_stride": self.rim_stride,
                "use_view": use_view,
                "outline_step_px": self.kept_outline_step_px if self.keep_outline else _OUTLINE_STEP_PX}

    def gate_at(self, outer: int, n_outer: int) -> str:
        """The gate's mode at outer iteration ``outer`` of ``n_outer``: each, reuse or off."""
        return "each" if outer < self.first_cheap(n_outer) else self.gate


class SilhouetteViews:
    """Per-frame camera and mask data for :func:`silhouette_constraints`, prepared once per frame.

    Algorithm 1 re-matches the same masks ``No`` times; the float masks, camera matrices and the
    template-outline raster buffers are built here once instead of at every outer iteration. With the
    template faces ``F`` of a closed mesh the outline is that of the front-facing triangles, kept as their
    boundary edges (``outline``: per view the edges' scratch ids, ``(x0, y0, x1, y1)``, rows and count; the
    matching's occlusion test reads their winding number) instead of a raster.
    """

    def __init__(self, cameras, masks: dict, F: np.ndarray | None = None):
        self.facing = 1.0 if F is not None and _is_closed_cached(F) else 0.0
        self.faces = None if F is None else np.ascontiguousarray(F, dtype=np.int64)
        self.edge_table = _outline_table_cached(self.faces) if self.facing else np.zeros((4, 0), np.int32)
        C, E = len(cameras), self.edge_table.shape[1]
        self.outline = (np.empty((C, E), np.int32), np.empty((C, E, 4)), np.empty((C, E, 2), np.int32),
                        np.zeros(C, np.int64))
        self.views = []
        for cam in cameras:
            mask = np.asarray(masks[cam.name])
            # Sampled as 0 / 1: a boolean mask is viewed as bytes as it is (no compare, ~0.25 ms a 640x480 view).
            mask = np.ascontiguousarray(mask if mask.dtype == np.bool_ else mask > 0).view(np.uint8)
            self.views.append((cam, mask, np.zeros((cam.height, cam.width), np.uint8),
                               np.ascontiguousarray(cam.K), np.ascontiguousarray(cam.dist),
                               np.ascontiguousarray(cam.R), np.ascontiguousarray(cam.t),
                               np.ascontiguousarray(cam.center), bool(cam.has_distortion)))
        # All views of one image size: the same data packed for :func:`_match_views` (the cameras in one
        # compiled call, ``prange`` over them: the second core). Views of different sizes keep the loop.
        sizes = {(cam.height, cam.width) for cam in cameras}
        self.packed = None
        if len(self.views) > 1 and len(sizes) == 1:
            (h, w), = sizes
            C = len(self.views)
            masks3 = np.empty((C, h, w), np.uint8)
            for c, v in enumerate(self.views):
                masks3[c] = v[1]
            self.packed = (masks3, np.zeros((C, h, w), np.uint8),
                           np.array([v[5] for v in self.views], dtype=np.float64).reshape(C, 3, 3),
                           np.array([v[6] for v in self.views], dtype=np.float64).reshape(C, 3),
                           np.array([v[3] for v in self.views], dtype=np.float64).reshape(C, 3, 3),
                           np.array([np.asarray(v[4], float).ravel()[:5] for v in self.views],
                                    dtype=np.float64).reshape(C, 5),
                           np.array([v[8] for v in self.views], dtype=np.bool_),
                           np.array([v[7] for v in self.views], dtype=np.float64).reshape(C, 3), w, h)
        self._projected = None  # (V, uv (C, n, 2), z (C, n)) of the last packed matching
        self.outline_whole = False  # the outline buffers hold whole rasters (``outline="full"``) of one mesh

    def kept_outline(self, c: int) -> np.ndarray:
        """The ``(H, W)`` uint8 mask of view ``c``'s outline as the last matching left it (the raster buffer, or
        on a closed mesh the coverage of its kept edges): what ``outline="keep"`` reads."""
        cam = self.views[c][0]
        if self.edge_table.shape[1]:
            _, edges, rows, count = self.outline
            return outline_coverage(edges[c], rows[c], count[c], cam.width, cam.height)
        return self.packed[1][c] if self.packed is not None else self.views[c][2]

    def _edge_table_for(self, F: np.ndarray) -> np.ndarray:
        """The closed mesh's edge table if ``F`` is the mesh these views were made with, else an empty one (the
        raster path)."""
        if self.edge_table.shape[1] and (F is self.faces or np.array_equal(F, self.faces)):
            return self.edge_table
        return np.zeros((4, 0), np.int32)

    def projection(self, V: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """Pixels ``(C, n, 2)`` (NaN behind a camera) and depths ``(C, n)`` of every vertex in every view as the
        last :func:`silhouette_constraints` call projected them (Eq. 6), if that call matched this very array
        ``V`` (the same memory, shape and strides: ``np.ascontiguousarray`` may hand back a view of it; the
        reference kept here keeps that memory from being reused) on the packed path; None otherwise. The
        visual-hull gate reads its vertices' fields there instead of projecting them again."""
        if self._projected is None or self._projected[0] is None:
            return None
        W = self._projected[0]
        if not (W.__array_interface__["data"][0] == V.__array_interface__["data"][0] and W.shape == V.shape
                and W.strides == V.strides and W.dtype == V.dtype):
            return None
        return self._projected[1], self._projected[2]

    def _projection_buffers(self, V: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        C, n = len(self.views), len(V)
        if self._projected is None or self._projected[2].shape != (C, n):
            self._projected = (None, np.empty((C, n, 2)), np.empty((C, n)))
        self._projected = (V, self._projected[1], self._projected[2])
        return self._projected[1], self._projected[2]


def silhouette_constraints(V: np.ndarray, F: np.ndarray, N: np.ndarray, cameras, masks: dict | None,
                           tau_px: float = 30.0, alpha_px: float = 40.0, rim_cos: float = 0.2,
                           views: SilhouetteViews | None = None, outline: str = "draw", rim_stride: int = 1,
                           use_view: np.ndarray | None = None, outline_step_px: float = _OUTLINE_STEP_PX
                           ) -> SilhouetteConstraints:
    """Match rim vertices with silhouette contours in every camera (Rapid Skin §III.B, Eq. 6, 7, 10).

    ``masks`` maps camera names to boolean ``(H, W)`` silhouettes; ``views`` (from
    :class:`SilhouetteViews`) may carry them prepared. Returns viewing-ray constraints, one numba pass
    per camera (:func:`_match_view`).

    Faster, inexact matchings (issue 15's frame time; exact by default): ``outline="keep"`` reuses the
    occlusion raster ``views`` kept from its last ``outline="full"`` call (drawn whole) instead of drawing
    the template's outline again; ``rim_stride`` keeps every ``rim_stride``-th vertex as a rim candidate;
    ``use_view`` (bool per camera) matches only those views; ``outline_step_px``: how far out along the
    projected normal the occlusion test reads the outline.
    """
    if views is None:
        views = SilhouetteViews(cameras, masks, F)
    mode = {"draw": 0, "full": 1, "keep": 2}[outline]
    if mode == 2 and not views.outline_whole:
        mode = 1  # nothing whole to keep yet
    V = np.ascontiguousarray(V, dtype=np.float64)
    N = np.ascontiguousarray(N, dtype=np.float64)
    F = np.ascontiguousarray(F, dtype=np.int64)
    C = len(views.views)
    use = np.ones(C, np.bool_) if use_view is None else np.ascontiguousarray(use_view, dtype=np.bool_)
    if mode == 1:
        use = np.ones(C, np.bool_)  # a whole outline for every view, to keep
    stride = max(int(rim_stride), 1)
    edge_table, outline = views._edge_table_for(F), views.outline
    if views.packed is not None:  # all cameras in one compiled call (prange over them)
        masks3, owns, Rs, ts, Ks, dists, has_dists, centers3, w, h = views.packed
        uv, z = views._projection_buffers(V)
        vid, off, direction, cam_of = _match_views(V, N, F, Rs, ts, Ks, dists, has_dists, centers3, w, h, masks3,
                                                   owns, views.facing, float(tau_px), float(rim_cos),
                                                   _NORMAL_PROBE_M, float(outline_step_px), uv, z, mode, stride,
                                                   use, edge_table, *outline)
        if not use.all():  # the skipped views' projections are stale: the gate projects for itself
            views._projected = (None, uv, z)
        views.outline_whole = mode in (1, 2)
        if len(vid) == 0:
            return SilhouetteConstraints.empty()
        origin = centers3[cam_of]
    else:
        vids, directions, offsets, cam_ids, centers = [], [], [], [], []
        for c, (cam, mask, own, K, dcoef, R, t, center, has_dist) in enumerate(views.views):
            if not use[c]:
                continue
            ids, o, d = _match_view(V, N, F, R, t, K, dcoef, has_dist, center, cam.width, cam.height, mask, own,
                                    views.facing, float(tau_px), float(rim_cos), _NORMAL_PROBE_M,
                                    float(outline_step_px), np.empty((len(V), 2)), np.empty(len(V)), mode, stride,
                                    edge_table, outline[0][c], outline[1][c], outline[2][c], outline[3][c:c + 1])
            if len(ids) == 0:
                continue
            vids.append(ids)
            directions.append(d)
            offsets.append(o)
            cam_ids.append(c)
            centers.append(center)
        views.outline_whole = mode in (1, 2)
        if not vids:
            return SilhouetteConstraints.empty()
        # one vectorised pass over all views (elementwise, so the same values as per view)
        counts = [len(ids) for ids in vids]
        vid, off, direction = np.concatenate(vids), np.concatenate(offsets), np.concatenate(directions)
        origin = np.repeat(np.array(centers, dtype=np.float64), counts, axis=0)
        cam_of = np.repeat(np.array(cam_ids, dtype=np.int64), counts)
    return SilhouetteConstraints(vid, origin, direction, silhouette_weight(off, alpha_px),
                                 cam_of, np.abs(off))
