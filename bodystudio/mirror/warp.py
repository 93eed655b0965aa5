"""Image warping of the foreground, §5.4 of Real-time Reshaping of Humans (Eq. 5, MLS of Schaefer et al. 2006).

The constraints are the projections of a sparse subset of vertices of the posed source and target bodies
(:func:`visible_vertex_pairs`). For ``cv2.remap`` the field is a *backward* map: for every output pixel
(where the target person is) the input pixel it samples. So Eq. 5 is solved with the handles swapped,
target positions ``t_i`` as the handles' rest positions and source positions ``s_i`` as their deformed
ones: ``x = M_x'(x')`` with weights ``1 / |x' - t_i|^2``. The solve is done only on the nodes of a
160x120 grid (the paper's GPU trick, 16x fewer solves), and only on the nodes of the region the target
person can occupy; the field is up-sampled bilinearly. Nodes sit at pixel ``4 j + 1.5`` so that
``cv2.resize(..., INTER_LINEAR)`` is exactly the bilinear interpolation between them.

All weighted sums of the closed-form solutions (affine, similarity, rigid) are expanded into sums of
monomials of the handles, accumulated by one numba pass per node; the mirror sums only over the handles
within 32 px of a node (``radius_px``; with weight exponent 2 the far ones add nothing a pixel can see).
The handles are the target's rim vertices plus an evenly spread set (:func:`visible_vertex_pairs`).
"""

from __future__ import annotations

import cv2
import numpy as np
from numba import njit

from bodystudio.errors import InputError

MLS_KINDS = ("affine", "similarity", "rigid")
#: Added to the squared node-handle distance (pixels^2): a node on a handle takes that handle's offset.
EPS_PX2 = 1e-3
#: Field value of pixels that show no foreground: a source position outside the image.
OUTSIDE_PX = -16.0
#: Field value of grid nodes that were not solved, before up-sampling (see :func:`mls_warp_field`).
_UNSOLVED_PX = -1.0e6


def _check_pairs(src_pts, dst_pts, return_kept: bool = False):
    s = np.asarray(src_pts, dtype=np.float64)
    t = np.asarray(dst_pts, dtype=np.float64)
    if s.ndim != 2 or s.shape[1] != 2 or s.shape != t.shape:
        raise InputError(f"MLS warp needs source and target points of the same shape (n, 2), got {s.shape} "
                         f"and {t.shape}")
    keep = np.isfinite(s).all(1) & np.isfinite(t).all(1)
    s, t = s[keep], t[keep]
    if len(s) < 3:
        raise InputError(f"MLS warp needs at least 3 finite point pairs, got {len(s)}")
    return (s, t, keep) if return_kept else (s, t)


def mls_grid_nodes(shape=(480, 640), grid=(120, 160)) -> tuple[np.ndarray, np.ndarray]:
    """Pixel x (cols) and y (rows) of the grid nodes, placed so that ``cv2.resize`` interpolates between them."""
    H, W = int(shape[0]), int(shape[1])
    gh, gw = int(grid[0]), int(grid[1])
    sy, sx = H / gh, W / gw
    return (np.arange(gw) + 0.5) * sx - 0.5, (np.arange(gh) + 0.5) * sy - 0.5


@njit(cache=True, fastmath=True)
def _weighted_sums(v, px, py, monomials, alpha, eps):
    """``S[a, j] = sum_i w_i(v_a) monomials[j, i]`` with ``w_i = 1 / (|v_a - p_i|^2 + eps)^alpha``."""
    N, n, k = v.shape[0], px.shape[0], monomials.shape[0]
    S = np.empty((N, k))
    w = np.empty(n)
    for a in range(N):
        vx, vy = v[a, 0], v[a, 1]
        for i in range(n):
            dx, dy = vx - px[i], vy - py[i]
            d2 = dx * dx + dy * dy + eps
            if alpha == 1.0:
                w[i] = 1.0 / d2
            elif alpha == 2.0:
                w[i] = 1.0 / (d2 * d2)
            elif alpha == 1.5:
                w[i] = 1.0 / (d2 * np.sqrt(d2))
            else:
                w[i] = d2 ** -alpha
        for j in range(k):
            total = 0.0
            for i in range(n):
                total += w[i] * monomials[j, i]
            S[a, j] = total
    return S


@njit(cache=True, fastmath=True)
def _weighted_sums_local(v, px, py, monomials, alpha, eps, radius):
    """:func:`_weighted_sums` over the handles within ``radius`` of each point only (all of them for a point with
    fewer than 3 there): the sums of Eq. 5's closed forms, local.

    The handles are bucketed in square cells of ``radius / 2``; a point visits the 5x5 cells around its own.
    """
    N, n, k = v.shape[0], px.shape[0], monomials.shape[0]
    rows = np.ascontiguousarray(monomials.T)  # (n, k): one handle's monomials side by side in memory
    x0, y0 = px.min(), py.min()
    # at most 1024 x 1024 cells however far apart the handles are (cells never smaller than radius / 2)
    cell = max(0.5 * radius, (px.max() - x0) / 1024.0, (py.max() - y0) / 1024.0)
    nx = int((px.max() - x0) / cell) + 1
    ny = int((py.max() - y0) / cell) + 1
    counts = np.zeros(nx * ny + 1, np.int64)
    where = np.empty(n, np.int64)
    for i in range(n):
        where[i] = int((py[i] - y0) / cell) * nx + int((px[i] - x0) / cell)
        counts[where[i] + 1] += 1
    for c in range(nx * ny):
        counts[c + 1] += counts[c]
    order = np.empty(n, np.int64)
    fill = counts[:-1].copy()
    for i in range(n):
        order[fill[where[i]]] = i
        fill[where[i]] += 1
    r2 = radius * radius
    S = np.zeros((N, k))
    for a in range(N):
        vx, vy = v[a, 0], v[a, 1]
        cx = int(np.floor((vx - x0) / cell))
        cy = int(np.floor((vy - y0) / cell))
        found = 0
        for gy in range(max(cy - 2, 0), min(cy + 3, ny)):
            for gx in range(max(cx - 2, 0), min(cx + 3, nx)):
                c = gy * nx + gx
                for o in range(counts[c], counts[c + 1]):
                    i = order[o]
                    dx, dy = vx - px[i], vy - py[i]
                    d2 = dx * dx + dy * dy
                    if d2 > r2:
                        continue
                    d2 += eps
                    if alpha == 2.0:
                        w = 1.0 / (d2 * d2)
                    elif alpha == 1.0:
                        w = 1.0 / d2
                    else:
                        w = d2 ** -alpha
                    found += 1
                    for j in range(k):
                        S[a, j] += w * rows[i, j]
        if found < 3:  # too few handles near: the global solve for this point
            for j in range(k):
                S[a, j] = 0.0
            for i in range(n):
                dx, dy = vx - px[i], vy - py[i]
                d2 = dx * dx + dy * dy + eps
                w = 1.0 / (d2 * d2) if alpha == 2.0 else d2 ** -alpha
                for j in range(k):
                    S[a, j] += w * monomials[j, i]
    return S


def mls_transforms(points: np.ndarray, handles: np.ndarray, deformed: np.ndarray, kind: str = "affine",
                   alpha: float = 1.0, radius_px: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Per-point MLS transform, Eq. 5 of Real-time Reshaping (Schaefer et al. 2006 closed forms).

    For each point ``v`` (N, 2) minimises ``sum_i w_i |M(p_i) - q_i|^2``, ``w_i = 1 / |v - p_i|^(2 alpha)``,
    over affine, similarity or rigid ``M``; ``p`` = ``handles``, ``q`` = ``deformed`` (n, 2). Returns the
    linear parts ``A`` (N, 2, 2) and the mapped points ``M_v(v) = (v - p*) A + q*`` (N, 2) (row vectors).
    ``radius_px``: sum the weights over the handles within that distance of ``v`` only (all of them for a
    point with fewer than 3 there), a local approximation that the fast fall-off of alpha 2 makes exact to a
    fraction of a pixel (docs/mirror.md); None: every handle, as Eq. 5.
    """
    if kind not in MLS_KINDS:
        raise InputError(f"MLS kind {kind!r}; valid: {', '.join(MLS_KINDS)}")
    if radius_px is not None and not (np.isfinite(radius_px) and radius_px > 0):
        raise InputError(f"MLS radius_px must be a positive number of pixels (or None: all handles), got {radius_px}")
    v = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    p, q = _check_pairs(handles, deformed)
    # Centre everything for conditioning (sums of squares of pixel coordinates lose digits otherwise).
    c = p.mean(0)
    v, p, q = v - c, p - c, q - c
    px, py, qx, qy = p[:, 0], p[:, 1], q[:, 0], q[:, 1]
    monomials = np.stack([np.ones_like(px), px, py, qx, qy, px * px, px * py, py * py,
                          px * qx, px * qy, py * qx, py * qy])
    args = (np.ascontiguousarray(v), np.ascontiguousarray(px), np.ascontiguousarray(py),
            np.ascontiguousarray(monomials), float(alpha), EPS_PX2)
    S = _weighted_sums(*args) if radius_px is None else _weighted_sums_local(*args, float(radius_px))  # (N, 12)
    W = S[:, 0]
    ps = S[:, 1:3] / W[:, None]  # p*
    qs = S[:, 3:5] / W[:, None]  # q*
    # sum w p^ p^T and sum w p^ q^T with p^ = p - p*, q^ = q - q* (expanded: sum w p p^T - W p* p*^T)
    Pxx = S[:, 5] - W * ps[:, 0] ** 2
    Pxy = S[:, 6] - W * ps[:, 0] * ps[:, 1]
    Pyy = S[:, 7] - W * ps[:, 1] ** 2
    Qxx = S[:, 8] - W * ps[:, 0] * qs[:, 0]
    Qxy = S[:, 9] - W * ps[:, 0] * qs[:, 1]
    Qyx = S[:, 10] - W * ps[:, 1] * qs[:, 0]
    Qyy = S[:, 11] - W * ps[:, 1] * qs[:, 1]
    A = np.empty((len(v), 2, 2))
    if kind == "affine":
        det = Pxx * Pyy - Pxy * Pxy
        det = np.where(np.abs(det) > 1e-12 * (Pxx * Pyy + 1e-300), det, np.nan)
        # A = P^-1 Q (row-vector convention: M(x) = x A)
        A[:, 0, 0] = (Pyy * Qxx - Pxy * Qyx) / det
        A[:, 0, 1] = (Pyy * Qxy - Pxy * Qyy) / det
        A[:, 1, 0] = (-Pxy * Qxx + Pxx * Qyx) / det
        A[:, 1, 1] = (-Pxy * Qxy + Pxx * Qyy) / det
    else:
        # complex form: M(x) = z x, z = sum w conj(p^) q^ / sum w |p^|^2 (similarity); z / |z| (rigid)
        mu = Pxx + Pyy
        zr = (Qxx + Qyy) / mu
        zi = (Qxy - Qyx) / mu
        if kind == "rigid":
            norm = np.hypot(zr, zi)
            zr, zi = zr / norm, zi / norm
        # row vector [x, y] times [[zr, zi], [-zi, zr]] = (zr x - zi y, zi x + zr y) = z * (x + i y)
        A[:, 0, 0] = zr
        A[:, 0, 1] = zi
        A[:, 1, 0] = -zi
        A[:, 1, 1] = zr
    mapped = np.einsum("ni,nij->nj", v - ps, A) + qs + c
    return A, mapped


def mls_warp_field(src_pts, dst_pts, shape=(480, 640), grid=(120, 160), kind: str = "affine",
                   roi_margin_px: float = 24.0, alpha: float = 1.0, groups=None,
                   radius_px: float | None = None) -> np.ndarray:
    """Backward warp field (H, W, 2) float32 for ``cv2.remap``, Eq. 5 of Real-time Reshaping on a 160x120 grid.

    ``src_pts`` (n, 2) are the source body's projected vertices (where the person is in the input),
    ``dst_pts`` the target body's (where the mirror should show them); pixel (x, y) of the output samples
    the input at ``field[y, x]``. The MLS solve runs only on the grid nodes within ``roi_margin_px`` of a
    target point, the only region where the target person can be; every pixel not surrounded by solved
    nodes maps outside the image (-16, -16), so nothing of the source person shows there unwarped (a
    shrunk person leaves no remnant). Up-sampling is bilinear.

    ``groups`` (n,) labels the pairs by person (several actors): each node is solved with the pairs of
    the person whose target points are nearest, so one actor's body does not pull on another's.
    ``radius_px`` as in :func:`mls_transforms` (the mirror uses 32 px).
    """
    if radius_px is not None and not (np.isfinite(radius_px) and radius_px > 0):
        raise InputError(f"MLS radius_px must be a positive number of pixels (or None: all handles), got {radius_px}")
    s, t, kept = _check_pairs(src_pts, dst_pts, return_kept=True)
    groups = np.zeros(len(kept), np.int64) if groups is None else np.asarray(groups).ravel()
    if len(groups) != len(kept):
        raise InputError(f"MLS warp: {len(groups)} group labels for {len(kept)} point pairs")
    groups = groups[kept]
    H, W = int(shape[0]), int(shape[1])
    gh, gw = int(grid[0]), int(grid[1])
    if H <= 0 or W <= 0 or gh < 2 or gw < 2 or gh > H or gw > W:
        raise InputError(f"MLS warp: image shape {shape} and grid {grid} must be positive, grid >= 2 and <= image")
    xs, ys = mls_grid_nodes((H, W), (gh, gw))
    sx, sy = W / gw, H / gh
    # grid nodes near a target point: splat each group's points on the grid, distance in cells; a node is
    # solved by the nearest group within the margin (+1 cell)
    col = np.clip(np.round((t[:, 0] + 0.5) / sx - 0.5), 0, gw - 1).astype(np.int64)
    row = np.clip(np.round((t[:, 1] + 0.5) / sy - 0.5), 0, gh - 1).astype(np.int64)
    reach = max(roi_margin_px / sx, roi_margin_px / sy) + 1.0
    labels = np.unique(groups)
    dist = np.full((len(labels), gh, gw), np.inf, np.float32)
    for k, g in enumerate(labels):
        free = np.ones((gh, gw), np.uint8)
        free[row[groups == g], col[groups == g]] = 0
        dist[k] = cv2.distanceTransform(free, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    owner = np.argmin(dist, axis=0)
    solve = np.min(dist, axis=0) <= reach
    rows, cols = np.nonzero(solve)
    nodes = np.stack([xs[cols], ys[rows]], axis=1)
    mapped = np.full((len(nodes), 2), np.nan)
    node_owner = owner[rows, cols]
    for k, g in enumerate(labels):
        mine = node_owner == k
        pairs = groups == g
        if mine.any() and pairs.sum() >= 3:
            _, mapped[mine] = mls_transforms(nodes[mine], t[pairs], s[pairs], kind, alpha, radius_px)
    valid = np.isfinite(mapped).all(1)  # degenerate (collinear) handle layouts: no value there
    # unsolved nodes hold a value so far out that any pixel they touch (bilinear weight >= 1/64 on the
    # mirror's grid) interpolates to beyond OUTSIDE_PX, then clamped to it: no second resize of a coverage map
    field = np.full((gh, gw, 2), _UNSOLVED_PX, np.float32)
    field[rows[valid], cols[valid]] = mapped[valid]
    r0, r1 = max(rows.min() - 1, 0), min(rows.max() + 2, gh)
    c0, c1 = max(cols.min() - 1, 0), min(cols.max() + 2, gw)
    # up-sample only the block holding the solved nodes (one node of border so the edge pixels are right)
    y0, y1 = int(round(r0 * sy)), int(round(r1 * sy))
    x0, x1 = int(round(c0 * sx)), int(round(c1 * sx))
    block = cv2.resize(field[r0:r1, c0:c1], (x1 - x0, y1 - y0), interpolation=cv2.INTER_LINEAR)
    np.maximum(block, OUTSIDE_PX, out=block)
    out = np.full((H, W, 2), OUTSIDE_PX, np.float32)
    out[y0:y1, x0:x1] = block
    return out


def warp_foreground(rgb: np.ndarray, fg_mask: np.ndarray, field: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The foreground moved by the backward field (§5.4): warped image (H, W, 3) uint8 and alpha (H, W) float32.

    Only the foreground moves: the alpha is the warped mask (bilinear, so edges are soft), the
    background is composed separately (§5.5). Warped colours next to the edge are taken from foreground
    pixels only (colour premultiplied by the mask, then divided), so no background colour is dragged along.
    """
    rgb = np.asarray(rgb)
    mask = np.asarray(fg_mask)
    if rgb.ndim != 3 or rgb.shape[2] != 3 or mask.shape != rgb.shape[:2] or field.shape != (*rgb.shape[:2], 2):
        raise InputError(f"warp_foreground: image {rgb.shape}, mask {mask.shape} and field {field.shape} "
                         "must share the image size (H, W, 3) / (H, W) / (H, W, 2)")
    m8 = mask.astype(np.uint8) * np.uint8(255)
    mx, my = field[..., 0], field[..., 1]
    alpha8 = cv2.remap(m8, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    premult = cv2.bitwise_and(rgb, rgb, mask=m8)  # background pixels black
    out = cv2.remap(premult, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    # edge pixels mixed foreground with black: divide by their coverage (few pixels)
    er, ec = np.nonzero((alpha8 > 0) & (alpha8 < 255))
    if len(er):
        a = alpha8[er, ec].astype(np.float32)[:, None] / 255.0
        out[er, ec] = np.clip(out[er, ec] / a + 0.5, 0, 255).astype(np.uint8)
    alpha = alpha8.astype(np.float32) * np.float32(1.0 / 255.0)
    return out, alpha


def visible_vertex_pairs(source_vertices: np.ndarray, target_vertices: np.ndarray, faces: np.ndarray, camera,
                         n_handles: int = 800, depth_tol_m: float = 0.08, z_buffer_scale: float = 0.25,
                         rim_cos: float | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The sparse constraints of §5.4: projections of vertices of the posed source and target bodies.

    An evenly spread subset of ``n_handles`` vertex ids is taken (the same ids every frame, so the
    warp is temporally stable), and a vertex is kept when it is visible in both bodies: its depth
    within ``depth_tol_m`` of a z-buffer of that body rendered at ``z_buffer_scale`` of the camera's
    size (occluded vertices would pull the visible surface in front of them). Returns the source
    pixels (m, 2), the target pixels (m, 2) and the vertex ids (m,).
    """
    from bodystudio.capture.render import render
    from bodystudio.geometry.camera import Camera

    Vs = np.asarray(source_vertices, dtype=np.float64)
    Vt = np.asarray(target_vertices, dtype=np.float64)
    if Vs.shape != Vt.shape or Vs.ndim != 2 or Vs.shape[1] != 3:
        raise InputError(f"source and target vertices must both be (n, 3), got {Vs.shape} and {Vt.shape}")
    if rim_cos is not None and not 0.0 < rim_cos <= 1.0:
        raise InputError(f"rim_cos must lie in (0, 1] (None: no rim vertices), got {rim_cos}")
    ids = np.unique(np.linspace(0, len(Vs) - 1, min(int(n_handles), len(Vs))).round().astype(np.int64))
    if rim_cos is not None:
        ids = np.union1d(ids, rim_vertices(Vt, faces, camera.center, rim_cos))
    s = z_buffer_scale
    w, h = max(int(round(camera.width * s)), 1), max(int(round(camera.height * s)), 1)
    sx, sy = w / camera.width, h / camera.height
    K = camera.K.copy()
    K[0] *= sx
    K[1] *= sy
    K[0, 2] = (camera.K[0, 2] + 0.5) * sx - 0.5
    K[1, 2] = (camera.K[1, 2] + 0.5) * sy - 0.5
    small = Camera(camera.name, K, camera.dist, camera.R, camera.t, w, h)
    keep = np.ones(len(ids), bool)
    uvs = []
    for V in (Vs, Vt):
        uv, z = camera.project_with_depth(V[ids])
        zbuf = render(V, faces, small).depth
        col = np.clip(np.round((uv[:, 0] + 0.5) * sx - 0.5), 0, w - 1)
        row = np.clip(np.round((uv[:, 1] + 0.5) * sy - 0.5), 0, h - 1)
        ok = np.isfinite(uv).all(1) & (z > 0)
        col, row = np.where(ok, col, 0).astype(np.int64), np.where(ok, row, 0).astype(np.int64)
        # the nearest z in the 3x3 neighbourhood: a vertex on a silhouette edge falls next to the covered pixel
        zpad = np.pad(np.where(zbuf > 0, zbuf, np.inf), 1, constant_values=np.inf)
        near = np.min([zpad[row + 1 + dr, col + 1 + dc] for dr in (-1, 0, 1) for dc in (-1, 0, 1)], axis=0)
        keep &= ok & (z <= near + depth_tol_m)
        keep &= (uv[:, 0] >= 0) & (uv[:, 0] <= camera.width - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= camera.height - 1)
        uvs.append(uv)
    return uvs[0][keep], uvs[1][keep], ids[keep]


def rim_vertices(vertices: np.ndarray, faces: np.ndarray, eye: np.ndarray, max_cos: float = 0.3) -> np.ndarray:
    """Ids of the vertices seen edge-on from ``eye``: ``|cos|`` of the normal and the viewing ray below ``max_cos``."""
    V = np.asarray(vertices, dtype=np.float64)
    F = np.asarray(faces)
    n = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    N = np.stack([sum(np.bincount(F[:, k], n[:, c], len(V)) for k in range(3)) for c in range(3)], axis=1)
    ray = V - np.asarray(eye, dtype=np.float64)
    norm = np.linalg.norm(N, axis=1) * np.linalg.norm(ray, axis=1)
    cos = np.einsum("ij,ij->i", N, ray) / np.maximum(norm, 1e-300)
    return np.flatnonzero((np.abs(cos) < max_cos) & (norm > 0))  # vertices on no face have no normal: not rim
