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

With the dense correspondence (the run's default) the field is set per pixel on the target body and in a 1 px band
around it (MIR12k), and the foreground regions reaching well beyond the fitted source body (hair, a bag: MIR12l,
:func:`foreground_extras`) move with their nearest body pixel (:func:`carry_extras`).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

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


def _finite_rows(xy: np.ndarray) -> np.ndarray:
    """Whether both coordinates of each point (..., 2) are finite: ``np.isfinite(xy).all(-1)``, whose reduction over
    a last axis of two is ~5x slower than the two columns' tests (MIR12d)."""
    return np.isfinite(xy[..., 0]) & np.isfinite(xy[..., 1])


def _check_pairs(src_pts, dst_pts, return_kept: bool = False):
    s = np.asarray(src_pts, dtype=np.float64)
    t = np.asarray(dst_pts, dtype=np.float64)
    if s.ndim != 2 or s.shape[1] != 2 or s.shape != t.shape:
        raise InputError(f"MLS warp needs source and target points of the same shape (n, 2), got {s.shape} "
                         f"and {t.shape}")
    keep = _finite_rows(s) & _finite_rows(t)
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
    if kind == "affine":
        monomials = np.stack([np.ones_like(px), px, py, qx, qy, px * px, px * py, py * py,
                              px * qx, px * qy, py * qx, py * qy])
    else:  # similarity and rigid need only |p|^2, p.q and p x q: 8 weighted sums per point instead of 12 (MIRFAST3)
        monomials = np.stack([np.ones_like(px), px, py, qx, qy, px * px + py * py, px * qx + py * qy,
                              px * qy - py * qx])
    args = (np.ascontiguousarray(v), np.ascontiguousarray(px), np.ascontiguousarray(py),
            np.ascontiguousarray(monomials), float(alpha), EPS_PX2)
    S = _weighted_sums(*args) if radius_px is None else _weighted_sums_local(*args, float(radius_px))  # (N, k)
    if kind != "affine":  # one numba pass over the points (MIR12d)
        A = np.empty((len(v), 2, 2))
        mapped = np.empty((len(v), 2))
        _similarity_closed_form(S, v, c, kind == "rigid", A, mapped)
        return A, mapped
    W = S[:, 0]
    ps = S[:, 1:3] / W[:, None]  # p*
    qs = S[:, 3:5] / W[:, None]  # q*
    A = np.empty((len(v), 2, 2))
    # affine: sum w p^ p^T and sum w p^ q^T with p^ = p - p*, q^ = q - q* (expanded: sum w p p^T - W p* p*^T)
    Pxx = S[:, 5] - W * ps[:, 0] ** 2
    Pxy = S[:, 6] - W * ps[:, 0] * ps[:, 1]
    Pyy = S[:, 7] - W * ps[:, 1] ** 2
    Qxx = S[:, 8] - W * ps[:, 0] * qs[:, 0]
    Qxy = S[:, 9] - W * ps[:, 0] * qs[:, 1]
    Qyx = S[:, 10] - W * ps[:, 1] * qs[:, 0]
    Qyy = S[:, 11] - W * ps[:, 1] * qs[:, 1]
    det = Pxx * Pyy - Pxy * Pxy
    det = np.where(np.abs(det) > 1e-12 * (Pxx * Pyy + 1e-300), det, np.nan)
    # A = P^-1 Q (row-vector convention: M(x) = x A)
    A[:, 0, 0] = (Pyy * Qxx - Pxy * Qyx) / det
    A[:, 0, 1] = (Pyy * Qxy - Pxy * Qyy) / det
    A[:, 1, 0] = (-Pxy * Qxx + Pxx * Qyx) / det
    A[:, 1, 1] = (-Pxy * Qxy + Pxx * Qyy) / det
    mapped = np.einsum("ni,nij->nj", v - ps, A) + qs + c
    return A, mapped


@njit(cache=True, error_model="numpy")  # a degenerate layout (mu = 0) gives inf / NaN as numpy does, no exception
def _similarity_closed_form(S, v, c, rigid, A, mapped):
    """Eq. 5's similarity (``rigid``: rigid) closed form per point from its weighted sums ``S`` (N, 8) (see
    :func:`mls_transforms`): ``A`` (N, 2, 2) and ``mapped`` (N, 2) filled in. Complex form: M(x) = z x,
    z = sum w conj(p^) q^ / sum w |p^|^2 (similarity), z / |z| (rigid), with p^ = p - p*, q^ = q - q* expanded as
    sums (sum w |p^|^2 = S5 - W |p*|^2, ...); the row vector [x, y] times [[zr, zi], [-zi, zr]] is z (x + i y).
    (The numpy expressions it replaced, operation for operation: the same values bit for bit, MIR12d; the numpy
    branch was removed as unreachable.)"""
    for a in range(S.shape[0]):
        W = S[a, 0]
        psx, psy = S[a, 1] / W, S[a, 2] / W
        qsx, qsy = S[a, 3] / W, S[a, 4] / W
        mu = S[a, 5] - W * (psx ** 2 + psy ** 2)
        zr = (S[a, 6] - W * (psx * qsx + psy * qsy)) / mu
        zi = (S[a, 7] - W * (psx * qsy - psy * qsx)) / mu
        if rigid:
            norm = np.hypot(zr, zi)
            zr, zi = zr / norm, zi / norm
        A[a, 0, 0] = zr
        A[a, 0, 1] = zi
        A[a, 1, 0] = -zi
        A[a, 1, 1] = zr
        dx, dy = v[a, 0] - psx, v[a, 1] - psy
        mapped[a, 0] = (dx * zr + dy * -zi) + qsx + c[0]
        mapped[a, 1] = (dx * zi + dy * zr) + qsy + c[1]


#: How far outside the target body's outline (pixels) the dense warp maps outline onto outline
#: (:func:`refine_outline`'s ``band_px`` as :func:`mls_warp_field` passes it); farther out nothing of the person
#: shows. MIR12k: the person's pixels beyond the fitted source body's outline, carried out there by the band (6 px
#: before) and by MLS farther out, are mostly the fitted bodies' pose and shape errors, not the person: end to end
#: on sessions 41 / 42 / 43 warp_iou 0.956 / 0.924 / 0.941 -> 0.960 / 0.934 / 0.950 with 1 px, and the warp field
#: 4.5 -> 1.8 ms CPU on one actor (no MLS solve; docs/mirror.md).
OUTLINE_BAND_PX = 1.0
#: How far outside the fitted source body's silhouette (pixels) the person's foreground may reach and still be taken
#: for the fit's misalignment, which the warp cuts (:data:`OUTLINE_BAND_PX`); a region of foreground reaching farther
#: out is something the body does not explain (hair, a bag, loose clothes) and the warp carries it
#: (:func:`foreground_extras`, :func:`carry_extras`). MIR12l: chosen on how far the run's foreground reaches outside
#: the fitted source body on sessions 41 / 42 / 43 (per frame at most 10 / 11 / 13 px, 90th percentile 7 / 9 / 10):
#: end to end warp_iou 0.9635 / 0.9407 / 0.9524 -> 0.9634 / 0.9406 / 0.9515, a bag or hair beyond it kept
#: (docs/mirror.md).
EXTRA_REACH_PX = 8.0


def mls_warp_field(src_pts, dst_pts, shape=(480, 640), grid=(120, 160), kind: str = "affine",
                   roi_margin_px: float = 24.0, alpha: float = 1.0, groups=None,
                   radius_px: float | None = None, dense=None, dense_src_uv=None,
                   dense_groups=None, band_px: float = OUTLINE_BAND_PX, inner_band_px: float = 8.0,
                   mls_outside: bool = False, foreground=None,
                   extra_reach_px: float | None = EXTRA_REACH_PX) -> np.ndarray:
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

    ``dense_src_uv`` (gh, gw, 2), NaN where unknown: the field's exact value at the nodes the target body
    covers, which take it instead of an MLS solve (``dense_groups`` (gh, gw): their person, for the region
    solved around them).

    ``dense`` (a :class:`DenseCorrespondence`, from :func:`warp_pairs`) sets the field exactly, per pixel, on the
    target body and in a ``band_px`` band outside its outline, ``inner_band_px`` inside (:func:`refine_outline`);
    every pixel farther out maps outside the image (no foreground) and no MLS is solved (MIR12k:
    :data:`OUTLINE_BAND_PX`). ``mls_outside``: with ``dense``, the field beyond the band is Eq. 5's MLS as before
    MIR12k (``dense`` gives ``dense_src_uv``/``dense_groups`` and the band is refined on the up-sampled field).
    ``foreground`` (H, W) the person's foreground mask: with ``dense`` (not ``mls_outside``), the regions of it that
    reach more than ``extra_reach_px`` outside the fitted source body (hair, a bag) are carried beyond the band
    (:func:`carry_extras`, MIR12l; None: cut as the rest).
    """
    if radius_px is not None and not (np.isfinite(radius_px) and radius_px > 0):
        raise InputError(f"MLS radius_px must be a positive number of pixels (or None: all handles), got {radius_px}")
    s, t, kept = _check_pairs(src_pts, dst_pts, return_kept=True)
    groups = np.zeros(len(kept), np.int64) if groups is None else np.asarray(groups).ravel()
    if len(groups) != len(kept):
        raise InputError(f"MLS warp: {len(groups)} group labels for {len(kept)} point pairs")
    groups = groups[kept].astype(np.int64)
    H, W = int(shape[0]), int(shape[1])
    gh, gw = int(grid[0]), int(grid[1])
    if H <= 0 or W <= 0 or gh < 2 or gw < 2 or gh > H or gw > W:
        raise InputError(f"MLS warp: image shape {shape} and grid {grid} must be positive, grid >= 2 and <= image")
    xs, ys = mls_grid_nodes((H, W), (gh, gw))
    sx, sy = W / gw, H / gh
    covered = np.zeros((gh, gw), bool)
    t_roi, groups_roi = t, groups
    if dense is not None and not mls_outside:  # the body and its outline band only (MIR12k)
        out = np.full((H, W, 2), OUTSIDE_PX, np.float32)
        if foreground is None or extra_reach_px is None:
            return refine_outline(out, dense, band_px, inner_band_px)
        distances: list = []
        refine_outline(out, dense, band_px, inner_band_px, distances)
        if extra_reach_px < _outline_margin_px(band_px, inner_band_px) - 1 and \
                not _beyond_reach(foreground, distances, extra_reach_px):
            return out  # no foreground that far out (most frames): the outline's distances tell, no transform
        return carry_extras(out, dense, foreground_extras(foreground, dense, extra_reach_px, distances))
    if dense is not None:
        dense_src_uv, dense_groups = dense.grid_source_uv, dense.grid_groups
    if dense_src_uv is not None:
        node_uv = np.asarray(dense_src_uv, dtype=np.float32)
        if node_uv.shape != (gh, gw, 2):
            raise InputError(f"MLS warp: dense correspondence of shape {node_uv.shape}, expected {(gh, gw, 2)}")
        covered = _finite_rows(node_uv)
        if covered.any():  # the covered nodes count as target points for the region solved around them
            crow, ccol = np.nonzero(covered)
            node_groups = np.zeros(len(crow), np.int64) if dense_groups is None else \
                np.asarray(dense_groups)[crow, ccol].astype(np.int64)
            t_roi = np.concatenate([t, np.stack([xs[ccol], ys[crow]], axis=1)])
            groups_roi = np.concatenate([groups, node_groups])
    # grid nodes near a target point: splat each group's points on the grid, distance in cells; a node is
    # solved by the nearest group within the margin (+1 cell)
    col = np.clip(np.round((t_roi[:, 0] + 0.5) / sx - 0.5), 0, gw - 1).astype(np.int64)
    row = np.clip(np.round((t_roi[:, 1] + 0.5) / sy - 0.5), 0, gh - 1).astype(np.int64)
    reach = max(roi_margin_px / sx, roi_margin_px / sy) + 1.0
    labels = np.unique(groups_roi)
    dist = np.full((len(labels), gh, gw), np.inf, np.float32)
    for k, g in enumerate(labels):
        free = np.ones((gh, gw), np.uint8)
        free[row[groups_roi == g], col[groups_roi == g]] = 0
        dist[k] = cv2.distanceTransform(free, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    owner = np.argmin(dist, axis=0)
    solve = (np.min(dist, axis=0) <= reach) & ~covered
    rows, cols = np.nonzero(solve)
    nodes = np.stack([xs[cols], ys[rows]], axis=1)
    mapped = np.full((len(nodes), 2), np.nan)
    node_owner = owner[rows, cols]
    for k, g in enumerate(labels):
        mine = node_owner == k
        pairs = groups == g
        if mine.any() and pairs.sum() >= 3:
            _, mapped[mine] = mls_transforms(nodes[mine], t[pairs], s[pairs], kind, alpha, radius_px)
    valid = _finite_rows(mapped)  # degenerate (collinear) handle layouts: no value there
    # unsolved nodes hold a value so far out that any pixel they touch (bilinear weight >= 1/64 on the
    # mirror's grid) interpolates to beyond OUTSIDE_PX, then clamped to it: no second resize of a coverage map
    field = np.full((gh, gw, 2), _UNSOLVED_PX, np.float32)
    field[rows[valid], cols[valid]] = mapped[valid]
    if covered.any():
        field[covered] = node_uv[covered]
    out = upsample_field(field, (H, W))
    if dense is not None:
        refine_outline(out, dense, band_px, inner_band_px)
    return out


def _beyond_reach(fg_mask: np.ndarray, distances: list, reach_px: float) -> bool:
    """Whether a pixel of ``fg_mask`` may lie more than ``reach_px`` outside the source body: one outside every box
    of :func:`refine_outline`'s ``distances``, or one in a box whose signed distance says so (within a box's margin
    its distances are the image's: :func:`people_boxes`; so False means :func:`foreground_extras` finds none)."""
    m8 = fg_mask.view(np.uint8) if fg_mask.dtype == bool else (np.asarray(fg_mask) != 0).astype(np.uint8)
    left = cv2.countNonZero(m8)
    for (y0, y1, x0, x1), sd in distances:
        sub = m8[y0:y1, x0:x1]
        left -= cv2.countNonZero(sub)
        # outside the silhouette the signed distance is 0.5 - the distance (``_signed_distance``)
        if _any_beyond(sub, sd, np.float32(0.5 - reach_px)):
            return True
    return left > 0


@njit(cache=True)
def _any_beyond(fg, sd, below):
    """Whether any pixel of ``fg`` has ``sd`` below ``below``."""
    for r in range(fg.shape[0]):
        for c in range(fg.shape[1]):
            if fg[r, c] and sd[r, c] < below:
                return True
    return False


def foreground_extras(fg_mask: np.ndarray, dense, reach_px: float = EXTRA_REACH_PX, distances: list | None = None):
    """The foreground the fitted source body does not explain: (mask (h, w) bool, (x0, y0)) of an image box, or None.

    A pixel of ``fg_mask`` (H, W) outside the source body's silhouette (``dense.source_mask``) is an extra when it lies
    more than ``reach_px`` outside it, or within ``reach_px + 1`` of such a pixel (the part of a bag or of hair
    between the body and ``reach_px``, so the carried region stays attached); the rest of the foreground outside the
    body, a ring a few pixels wide, is the fitted body's misalignment (MIR12k cuts it).

    ``distances``: :func:`refine_outline`'s per-person boxes and signed distances (MIR12m): the extras' cores are
    read from them instead of a distance transform of their own (the same chamfer distances: each box holds its
    person's whole silhouette; the foreground outside every box lies farther than ``reach_px`` from any person when
    each box reaches that far beyond its silhouette, else :func:`_foreground_extras_reference`), and the attachment
    is grown around the cores only. The same extras as :func:`_foreground_extras_reference`, in a smaller box."""
    if distances is None:
        return _foreground_extras_reference(fg_mask, dense, reach_px)
    fg = np.asarray(fg_mask)
    H, W = fg.shape
    m8 = fg.view(np.uint8) if fg.dtype == bool else (fg != 0).astype(np.uint8)
    bx, by, bw, bh = cv2.boundingRect(m8)
    if bw == 0 or bh == 0:
        return None
    x0, y0 = dense.origin
    h, w = dense.source_mask.shape
    silhouettes = []
    for (r0, r1, c0, c1), _ in distances:
        sx, sy, sw, sh = cv2.boundingRect(dense.source_mask[r0 - y0:r1 - y0, c0 - x0:c1 - x0].astype(np.uint8))
        silhouettes.append((c0 + sx, r0 + sy, c0 + sx + sw, r0 + sy + sh) if sw else None)
    if not _boxes_hold_reach(distances, silhouettes, reach_px, H, W):
        return _foreground_extras_reference(fg_mask, dense, reach_px)
    core = m8[by:by + bh, bx:bx + bw] > 0
    for ((r0, r1, c0, c1), sd), s in zip(distances, silhouettes, strict=True):
        R0, R1, C0, C1 = max(r0, by), min(r1, by + bh), max(c0, bx), min(c1, bx + bw)
        if s is not None and R0 < R1 and C0 < C1:  # none: all of the box's foreground beyond reach
            # outside the silhouette the signed distance is 0.5 - the distance, exactly (``_signed_distance``; the
            # distances are multiples of 2^-16)
            outside = np.float32(0.5) - sd[R0 - r0:R1 - r0, C0 - c0:C1 - c0]
            core[R0 - by:R1 - by, C0 - bx:C1 - bx] &= outside > reach_px
    cx, cy, cw, ch = cv2.boundingRect(core.view(np.uint8))
    if cw == 0 or ch == 0:
        return None
    r = int(np.ceil(reach_px)) + 1
    X0, Y0 = max(bx + cx - r, 0), max(by + cy - r, 0)
    X1, Y1 = min(bx + cx + cw + r, W), min(by + cy + ch + r, H)
    # the dilation of the cores is the union of each group's (the hair, a bag): their boxes only, not the box between
    near = np.zeros((Y1 - Y0, X1 - X0), np.uint8)
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
    for gx0, gy0, gx1, gy1 in _extras_boxes(core, bx - X0, by - Y0):
        a0, b0 = max(gx0 - r, 0), max(gy0 - r, 0)
        a1, b1 = min(gx1 + r, X1 - X0), min(gy1 + r, Y1 - Y0)
        seeds = np.zeros((b1 - b0, a1 - a0), np.uint8)
        seeds[gy0 - b0:gy1 - b0, gx0 - a0:gx1 - a0] = core[gy0 - (by - Y0):gy1 - (by - Y0),
                                                           gx0 - (bx - X0):gx1 - (bx - X0)]
        near[b0:b1, a0:a1] |= cv2.dilate(seeds, disc)
    body = np.zeros((Y1 - Y0, X1 - X0), bool)
    ix0, iy0, ix1, iy1 = max(X0, x0), max(Y0, y0), min(X1, x0 + w), min(Y1, y0 + h)
    if ix0 < ix1 and iy0 < iy1:
        body[iy0 - Y0:iy1 - Y0, ix0 - X0:ix1 - X0] = dense.source_mask[iy0 - y0:iy1 - y0, ix0 - x0:ix1 - x0]
    return (m8[Y0:Y1, X0:X1] > 0) & (near > 0) & ~body, (X0, Y0)


def _boxes_hold_reach(distances, silhouettes, reach_px, H, W) -> bool:
    """Whether each box of ``distances`` reaches more than ``reach_px`` beyond its silhouette's bounding box
    (``silhouettes``, image ``(x0, y0, x1, y1)``; None: no silhouette pixel in the box) on each side but the image's
    edge, and lies more than ``reach_px`` from every other silhouette's (people side by side): then the foreground
    outside every box, and that in a box beyond ``reach_px`` by its own distances, is beyond ``reach_px`` from all."""
    need = int(np.floor(reach_px)) + 1
    for i, ((r0, r1, c0, c1), _) in enumerate(distances):
        s = silhouettes[i]
        if s is not None and ((c0 > 0 and s[0] - c0 < need) or (r0 > 0 and s[1] - r0 < need) or
                              (c1 < W and c1 - s[2] < need) or (r1 < H and r1 - s[3] < need)):
            return False
        for j, o in enumerate(silhouettes):
            if j != i and o is not None and max(o[0] - c1, c0 - o[2], o[1] - r1, r0 - o[3]) + 1 < need:
                return False
    return True


def _foreground_extras_reference(fg_mask: np.ndarray, dense, reach_px: float = EXTRA_REACH_PX):
    """:func:`foreground_extras` as MIR12l wrote it (its own distance transform over the foreground's and the body's
    box): (mask (h, w) bool, (x0, y0)) of an image box, or None.

    A pixel of ``fg_mask`` (H, W) outside the source body's silhouette (``dense.source_mask``) is an extra when it lies
    more than ``reach_px`` outside it, or within ``reach_px + 1`` of such a pixel (the part of a bag or of hair
    between the body and ``reach_px``, so the carried region stays attached); the rest of the foreground outside the
    body, a ring a few pixels wide, is the fitted body's misalignment (MIR12k cuts it)."""
    fg = np.asarray(fg_mask)
    H, W = fg.shape
    m8 = fg.view(np.uint8) if fg.dtype == bool else (fg != 0).astype(np.uint8)
    bx, by, bw, bh = cv2.boundingRect(m8)
    if bw == 0 or bh == 0:
        return None
    x0, y0 = dense.origin
    h, w = dense.source_mask.shape
    r = int(np.ceil(reach_px)) + 1
    # the box: the foreground's and the body's crop, so that every distance to the body within reach is exact there
    X0, Y0 = max(min(bx, x0) - r, 0), max(min(by, y0) - r, 0)
    X1, Y1 = min(max(bx + bw, x0 + w) + r, W), min(max(by + bh, y0 + h) + r, H)
    body = np.zeros((Y1 - Y0, X1 - X0), np.uint8)
    body[y0 - Y0:y0 - Y0 + h, x0 - X0:x0 - X0 + w] = dense.source_mask
    outside = cv2.distanceTransform(1 - body, cv2.DIST_L2, cv2.DIST_MASK_5)
    fg_box = m8[Y0:Y1, X0:X1] > 0
    core = fg_box & (outside > reach_px)
    if not core.any():
        return None
    near = cv2.dilate(core.view(np.uint8), cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1)))
    return fg_box & (near > 0) & (body == 0), (X0, Y0)


def carry_extras(field: np.ndarray, dense, extras) -> np.ndarray:
    """The backward field (in place; returns it) also showing the foreground extras (:func:`foreground_extras`).

    Each output pixel that shows nothing (OUTSIDE_PX) takes the displacement of its nearest pixel on the target body
    (``field`` there minus its position: the body's own correspondence, Eq. 5's dense counterpart), so an extra moves
    with the part of the body it is attached to; it keeps that source position where it lands on an extra, and
    shows nothing elsewhere (the misalignment ring stays cut).

    MIR12m: only the output pixels that can land on an extra are visited (the extras' box less the range of the
    body's displacements), and the labelled distance transform runs on their box grown until it holds, for each of
    them, every body pixel as near as the nearest it found (the chamfer distance is at least the larger of the two
    offsets); the same field as :func:`_carry_extras_reference`, which transformed the whole body's box."""
    if extras is None:
        return field
    mask, (ex, ey) = extras
    H, W = field.shape[:2]
    x0, y0 = dense.origin
    inside = np.isfinite(dense.source_uv[..., 0])
    h, w = inside.shape
    if not inside.any():
        return field
    lo_hi = _displacement_range(field[y0:y0 + h, x0:x0 + w], inside, float(x0), float(y0))
    if not np.all(np.isfinite(lo_hi)) or lo_hi[4] > 255.0:
        return _carry_extras_reference(field, dense, extras)
    dx0, dx1, dy0, dy1, largest = (float(v) for v in lo_hi)
    # the reference's box: nothing outside it changes
    reach = int(np.ceil(largest)) + 1
    eh, ew = mask.shape
    ref = (max(min(ex, x0) - reach, 0), max(min(ey, y0) - reach, 0),
           min(max(ex + ew, x0 + w) + reach, W), min(max(ey + eh, y0 + h) + reach, H))
    for tx0, ty0, tx1, ty1 in _extras_boxes(mask, ex, ey):
        # an output pixel lands on the box [tx0, tx1) x [ty0, ty1) when its position plus a displacement rounds
        # into it
        visit = (max(int(np.floor(tx0 - 0.5 - dx1)) - 1, ref[0]), max(int(np.floor(ty0 - 0.5 - dy1)) - 1, ref[1]),
                 min(int(np.ceil(tx1 - 0.5 - dx0)) + 2, ref[2]), min(int(np.ceil(ty1 - 0.5 - dy0)) + 2, ref[3]))
        if visit[0] < visit[2] and visit[1] < visit[3]:
            # the visited pixels lie up to about half the body's largest displacement from it (and the extras'
            # reach): one transform on the bench frame, whose head moves 35 px (16 px: two, the second larger;
            # the whole displacement + 8 px: one, larger)
            _carry_near(field, inside, (x0, y0), mask, (ex, ey), visit, ref, reach // 2 + 16)
    return field


def _extras_boxes(mask: np.ndarray, ex: int, ey: int) -> list[tuple[int, int, int, int]]:
    """Image boxes ``(x0, y0, x1, y1)`` that hold the extras' pixels: the mask's rows split where empty rows part
    them, each band's columns where empty columns do (the hair above the head, a bag at the hip: a box each)."""
    m = np.asarray(mask, bool)
    boxes = []
    for r0, r1 in _runs(m.any(1)):
        for c0, c1 in _runs(m[r0:r1].any(0)):
            rows = np.flatnonzero(m[r0:r1, c0:c1].any(1))
            boxes.append((ex + c0, ey + r0 + int(rows[0]), ex + c1, ey + r0 + int(rows[-1]) + 1))
    return boxes


def _runs(flags: np.ndarray) -> list[tuple[int, int]]:
    """``[(start, stop), ...]`` of the runs of True in ``flags`` (1-D)."""
    padded = np.zeros(len(flags) + 2, np.int8)
    padded[1:-1] = flags
    edges = np.flatnonzero(padded[1:] != padded[:-1]).tolist()
    return list(zip(edges[::2], edges[1::2], strict=True))


def _carry_near(field, inside, origin, mask, offset, visit, ref, grow: int = 16):
    """:func:`carry_extras` on the output pixels of the box ``visit`` (x0, y0, x1, y1) only: the labelled distance
    transform on it grown by ``grow`` (within the reference's box ``ref``), and more until it holds, for each of its
    pixels, every body pixel as near as the nearest it found."""
    x0, y0 = origin
    h, w = inside.shape
    CX0, CY0, CX1, CY1 = visit
    while True:
        BX0, BY0 = max(CX0 - grow, ref[0]), max(CY0 - grow, ref[1])
        BX1, BY1 = min(CX1 + grow, ref[2]), min(CY1 + grow, ref[3])
        whole = (BX0, BY0, BX1, BY1) == tuple(ref)
        body = np.zeros((BY1 - BY0, BX1 - BX0), np.uint8)
        ix0, iy0, ix1, iy1 = max(BX0, x0), max(BY0, y0), min(BX1, x0 + w), min(BY1, y0 + h)
        if ix0 < ix1 and iy0 < iy1:
            body[iy0 - BY0:iy1 - BY0, ix0 - BX0:ix1 - BX0] = inside[iy0 - y0:iy1 - y0, ix0 - x0:ix1 - x0]
        if not body.any():
            if whole:
                return
            grow *= 2
            continue
        dist, label = cv2.distanceTransformWithLabels(1 - body, cv2.DIST_L2, cv2.DIST_MASK_5,
                                                      labelType=cv2.DIST_LABEL_PIXEL)
        # a body pixel outside the box lies farther than ``grow`` from every visited pixel in x or y, so farther
        # by the chamfer distance too: none is as near as the nearest found once that is within ``grow - 2``
        nearest = float(dist[CY0 - BY0:CY1 - BY0, CX0 - BX0:CX1 - BX0].max())
        if whole or nearest <= grow - 2:
            break
        grow = int(np.ceil(nearest)) + 4
    _carry_box(field[BY0:BY1, BX0:BX1], body, label, mask, float(offset[0]), float(offset[1]), OUTSIDE_PX,
               CY0 - BY0, CY1 - BY0, CX0 - BX0, CX1 - BX0)


@njit(cache=True)
def _displacement_range(crop, inside, x0, y0):
    """(min dx, max dx, min dy, max dy, largest |d|) of the backward displacement ``crop - position`` over the
    ``inside`` pixels (float32 as :func:`_carry_extras_reference` computes it); all NaN where one is not finite."""
    out = np.array([np.inf, -np.inf, np.inf, -np.inf, 0.0])
    for r in range(inside.shape[0]):
        for c in range(inside.shape[1]):
            if inside[r, c]:
                dx = crop[r, c, 0] - np.float32(x0 + c)
                dy = crop[r, c, 1] - np.float32(y0 + r)
                if not (np.isfinite(dx) and np.isfinite(dy)):
                    out[:] = np.nan
                    return out
                out[0] = min(out[0], dx)
                out[1] = max(out[1], dx)
                out[2] = min(out[2], dy)
                out[3] = max(out[3], dy)
                out[4] = max(out[4], abs(dx), abs(dy))
    return out


@njit(cache=True)
def _carry_box(crop, body, label, extras, ex, ey, outside, r0, r1, c0, c1):
    """:func:`carry_extras` on the rows ``r0:r1`` and columns ``c0:c1`` of a box of the field: ``label`` numbers the
    body's pixels in raster order; ``extras`` is a mask whose pixel (0, 0) is the image's ``(ex, ey)``. Each empty
    pixel moves as its nearest body pixel does (that pixel's source position, offset as this one is) and keeps it
    where it lands on an extra."""
    h, w = body.shape
    zr = np.empty(h * w, np.int64)
    zc = np.empty(h * w, np.int64)
    n = 0
    for r in range(h):
        for c in range(w):
            if body[r, c]:
                zr[n], zc[n] = r, c
                n += 1
    eh, ew = extras.shape
    for r in range(r0, r1):
        for c in range(c0, c1):
            if body[r, c] or crop[r, c, 0] != outside:
                continue
            k = label[r, c] - 1
            ux = crop[zr[k], zc[k], 0] + (c - zc[k])
            uy = crop[zr[k], zc[k], 1] + (r - zr[k])
            er = int(np.floor(uy - ey + 0.5))
            ec = int(np.floor(ux - ex + 0.5))
            if 0 <= er < eh and 0 <= ec < ew and extras[er, ec]:
                crop[r, c, 0] = ux
                crop[r, c, 1] = uy


def _carry_extras_reference(field: np.ndarray, dense, extras) -> np.ndarray:
    """:func:`carry_extras` as MIR12l wrote it (the reference its tests compare with): the labelled distance transform
    over the whole body and the extras' box grown by the body's largest displacement.

    Each output pixel that shows nothing (OUTSIDE_PX) takes the displacement of its nearest pixel on the target body
    (``field`` there minus its position: the body's own correspondence, Eq. 5's dense counterpart), so an extra moves
    with the part of the body it is attached to; it keeps that source position where it lands on an extra, and
    shows nothing elsewhere (the misalignment ring stays cut)."""
    if extras is None:
        return field
    mask, (ex, ey) = extras
    H, W = field.shape[:2]
    x0, y0 = dense.origin
    inside = np.isfinite(dense.source_uv[..., 0])
    rows, cols = np.nonzero(inside)
    if not len(rows):
        return field
    d = field[y0 + rows, x0 + cols] - np.stack([x0 + cols, y0 + rows], 1).astype(np.float32)
    # every output pixel that can land on an extra lies within the largest displacement of the extras' box
    reach = int(min(np.ceil(np.nanmax(np.abs(d))), 256.0)) + 1 if np.isfinite(d).any() else 0
    eh, ew = mask.shape
    X0, Y0 = max(min(ex, x0) - reach, 0), max(min(ey, y0) - reach, 0)
    X1 = min(max(ex + ew, x0 + inside.shape[1]) + reach, W)
    Y1 = min(max(ey + eh, y0 + inside.shape[0]) + reach, H)
    body = np.zeros((Y1 - Y0, X1 - X0), np.uint8)
    body[y0 - Y0:y0 - Y0 + inside.shape[0], x0 - X0:x0 - X0 + inside.shape[1]] = inside
    _, label = cv2.distanceTransformWithLabels(1 - body, cv2.DIST_L2, cv2.DIST_MASK_5,
                                               labelType=cv2.DIST_LABEL_PIXEL)
    _carry_box(field[Y0:Y1, X0:X1], body, label, mask, float(ex), float(ey), OUTSIDE_PX, 0, body.shape[0], 0,
               body.shape[1])
    return field


def upsample_field(field: np.ndarray, shape=(480, 640)) -> np.ndarray:
    """The grid field (gh, gw, 2) up-sampled bilinearly to (H, W, 2); pixels next to unsolved nodes map outside."""
    H, W = int(shape[0]), int(shape[1])
    gh, gw = field.shape[:2]
    sx, sy = W / gw, H / gh
    rows, cols = np.nonzero(field[..., 0] > _UNSOLVED_PX)
    if not len(rows):
        return np.full((H, W, 2), OUTSIDE_PX, np.float32)
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


def refine_outline(field: np.ndarray, dense, band_px: float = 6.0, inner_px: float = 8.0,
                   distances: list | None = None) -> np.ndarray:
    """The backward field set per pixel on the target body and around its outline (in place; returns it).

    On the pixels the target body covers the field takes the exact correspondence (``dense.source_uv``: the
    source body's projection of the same surface point, front surface by the z-buffer). A pixel ``x'`` outside
    it, within ``band_px`` of its outline, takes the correspondence ``u`` of the nearest covered pixel moved
    along the outward normal of the source silhouette (its signed-distance gradient at ``u``) to lie as far
    outside the source's outline as ``x'`` lies outside the target's: outline maps onto outline. (The surface
    point under the target's outline is not on the source's outline, since the contour generator slides over a
    reshaped surface; mapping it unchanged put the warped outline up to a few pixels off, as MLS from vertex
    handles does.) The covered pixels within ``inner_px`` of the outline are moved the same way, to lie as far
    inside the source's outline as they lie inside the target's, so the map stays continuous across the outline
    (MIR-SYNTH 41 / 42, true vertices: 0.948 / 0.965 without, 0.958 / 0.981 with 8 px). Outside the band the
    grid field stays. ``distances``: a list that gets, per person's box of the crop, its image box
    ``(y0, y1, x0, x1)`` and the source silhouette's signed distance there (:func:`foreground_extras` reuses them).
    """
    x0, y0 = dense.origin
    inside = np.isfinite(dense.source_uv[..., 0])
    if not inside.any():
        return field
    # each person's part of the crop on its own when empty columns separate them (two actors' crop spans the gap
    # between them; its distance transforms paid for the gap's pixels too: MIR12d)
    for (r0, r1), (c0, c1) in people_boxes(inside | dense.source_mask, _outline_margin_px(band_px, inner_px)):
        sub = inside[r0:r1, c0:c1]
        dist, label = cv2.distanceTransformWithLabels((~sub).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_5,
                                                      labelType=cv2.DIST_LABEL_PIXEL)
        depth_in = cv2.distanceTransform(sub.astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_5)
        sd = _signed_distance(dense.source_mask[r0:r1, c0:c1])
        _outline_band(field[y0 + r0:y0 + r1, x0 + c0:x0 + c1], dense.source_uv[r0:r1, c0:c1], sub, dist, label,
                      sd, float(band_px), float(x0 + c0), float(y0 + r0), depth_in, float(inner_px))
        if distances is not None:
            distances.append(((y0 + r0, y0 + r1, x0 + c0, x0 + c1), sd))
    return field


def _outline_margin_px(band_px: float, inner_px: float) -> int:
    """The margin around a person's pixels that :func:`refine_outline` works in: the outer band, the inner band's
    reach and the source points' central differences, with room to spare."""
    return int(np.ceil(max(band_px, inner_px))) + 4


def people_boxes(mask: np.ndarray, margin_px: int) -> list[tuple[tuple[int, int], tuple[int, int]]]:
    """``[((r0, r1), (c0, c1)), ...]``: a box per group of ``mask``'s columns that more than ``2 margin_px + 1``
    empty columns separate (people side by side), each its pixels' bounding box grown by ``margin_px`` (clipped to
    ``mask``); one box (the mask's bounding box grown) when nothing separates them, none for an empty mask.

    Whatever lies within ``margin_px`` of a group's pixels lies in its box and in no other box's reach, so a
    distance transform of the box gives, within that reach, the distances one of the whole image gives (a chamfer
    path stays in the bounding box of its ends); where several pixels are equally near, the one it labels nearest
    could in principle differ (the bench frames' fields are the same bit for bit:
    tests/mirror/test_mirror_speed_pins.py).
    """
    m = np.asarray(mask, bool)
    cols = np.flatnonzero(m.any(0))
    if not len(cols):
        return []
    h, w = m.shape
    cuts = np.flatnonzero(np.diff(cols) > 2 * margin_px + 1)
    out = []
    for c0, c1 in zip(np.r_[cols[0], cols[cuts + 1]], np.r_[cols[cuts], cols[-1]], strict=True):
        rows = np.flatnonzero(m[:, c0:c1 + 1].any(1))
        out.append(((max(int(rows[0]) - margin_px, 0), min(int(rows[-1]) + margin_px + 1, h)),
                    (max(int(c0) - margin_px, 0), min(int(c1) + margin_px + 1, w))))
    return out


@njit(cache=True)
def _sample(image, x, y):
    """``image`` at (x, y), bilinear, clamped at the border."""
    h, w = image.shape
    x = min(max(x, 0.0), w - 1.0)
    y = min(max(y, 0.0), h - 1.0)
    c, r = min(int(x), w - 2), min(int(y), h - 2)
    fx, fy = x - c, y - r
    return ((1 - fy) * ((1 - fx) * image[r, c] + fx * image[r, c + 1])
            + fy * ((1 - fx) * image[r + 1, c] + fx * image[r + 1, c + 1]))


@njit(cache=True, inline="always")
def _bilinear(image, r, c, fx, fy, gx, gy):
    """:func:`_sample`'s sum at the cell ``(r, c)`` with fractions ``fx, fy`` (``gx = 1 - fx``, ``gy = 1 - fy``)."""
    return gy * (gx * image[r, c] + fx * image[r, c + 1]) + fy * (gx * image[r + 1, c] + fx * image[r + 1, c + 1])


@njit(cache=True)
def _outline_band(crop, source_uv, inside, dist, label, sd, band_px, x0, y0, depth_in, inner_px):
    """:func:`refine_outline` on the crop: ``label`` numbers the covered pixels in raster order (DIST_LABEL_PIXEL),
    ``depth_in`` is their distance from the nearest uncovered pixel."""
    h, w = inside.shape
    zr = np.empty(h * w, np.int64)
    zc = np.empty(h * w, np.int64)
    n = 0
    for r in range(h):
        for c in range(w):
            if inside[r, c]:
                zr[n], zc[n] = r, c
                n += 1
    if h < 2 or w < 2:
        return
    for r in range(h):
        for c in range(w):
            if inside[r, c]:
                crop[r, c, 0] = source_uv[r, c, 0]
                crop[r, c, 1] = source_uv[r, c, 1]
                if depth_in[r, c] <= inner_px:  # as far inside the source's outline as inside the target's
                    _to_signed_distance(crop, r, c, source_uv[r, c, 0], source_uv[r, c, 1], sd, x0, y0,
                                        depth_in[r, c] - 0.5)
            elif dist[r, c] <= band_px:  # the nearest covered pixel's point, as far outside as this pixel
                k = label[r, c] - 1
                _to_signed_distance(crop, r, c, source_uv[zr[k], zc[k], 0], source_uv[zr[k], zc[k], 1], sd, x0, y0,
                                    0.5 - dist[r, c])


@njit(cache=True)
def _to_signed_distance(crop, r, c, ux, uy, sd, x0, y0, wanted):
    """``crop[r, c]`` = the image point ``u`` moved along the gradient of ``sd`` (a crop at ``x0, y0``) to the
    signed distance ``wanted`` (positive inside)."""
    x, y = ux - x0, uy - y0
    h, w = sd.shape
    if 1.0 <= x < w - 3.0 and 1.0 <= y < h - 3.0:
        # away from the border the five samples share the fractions and differ by whole pixels: the same sums as
        # :func:`_sample`'s, without its clamping five times (MIR12d)
        sc, sr = int(x), int(y)
        fx, fy = x - sc, y - sr
        gx, gy = 1 - fx, 1 - fy
        nx = _bilinear(sd, sr, sc + 1, fx, fy, gx, gy) - _bilinear(sd, sr, sc - 1, fx, fy, gx, gy)
        ny = _bilinear(sd, sr + 1, sc, fx, fy, gx, gy) - _bilinear(sd, sr - 1, sc, fx, fy, gx, gy)
        centre = _bilinear(sd, sr, sc, fx, fy, gx, gy)
    else:
        nx = _sample(sd, x + 1.0, y) - _sample(sd, x - 1.0, y)
        ny = _sample(sd, x, y + 1.0) - _sample(sd, x, y - 1.0)
        centre = _sample(sd, x, y)
    norm = max(np.sqrt(nx * nx + ny * ny), 1e-6)
    step = centre - wanted
    crop[r, c, 0] = ux - step * nx / norm
    crop[r, c, 1] = uy - step * ny / norm


def _signed_distance(mask: np.ndarray) -> np.ndarray:
    """Signed distance (pixels, float32) to the outline of ``mask``: positive inside, negative outside."""
    m = np.asarray(mask, np.uint8)
    inside = cv2.distanceTransform(m, cv2.DIST_L2, cv2.DIST_MASK_5)
    outside = cv2.distanceTransform(1 - m, cv2.DIST_L2, cv2.DIST_MASK_5)
    # in float32: the difference of two float32 distances plus 0.5 rounds once either way (the same values); one
    # numba pass instead of numpy's difference, comparison, choice and sum (MIR12d: the same values bit for bit)
    _signed_from_distances(inside, outside, m)
    return inside


@njit(cache=True)
def _signed_from_distances(inside, outside, m):
    """``inside`` (in place) = ``inside - outside`` -/+ 0.5 (inside / outside ``m``), in float32 as numpy does."""
    half = np.float32(0.5)
    for r in range(inside.shape[0]):
        for c in range(inside.shape[1]):
            d = inside[r, c] - outside[r, c]
            inside[r, c] = d - half if m[r, c] > 0 else d + half


#: How far outside the image (pixels) a source position is taken from the image's edge (:func:`edge_clamped`):
#: the field's own limit (OUTSIDE_PX) on the left and top.
EDGE_REACH_PX = -OUTSIDE_PX


def edge_clamped(xy: np.ndarray, shape, reach_px: float = EDGE_REACH_PX) -> np.ndarray:
    """The backward field ``xy`` (h, w, 2) with source positions up to ``reach_px`` outside the image (H, W) moved
    onto its edge (a copy where any is; ``xy`` itself otherwise); OUTSIDE_PX, no foreground, stays.

    A person cut by the image's edge goes on beyond it: where the reshaped body reaches into the image from
    there (a heavier body entering from the side: its back maps to just outside the frame), the warp shows the
    edge's pixels, as the body would continue, not a gap (MIR12g: with the true bodies the walk-in frames of
    MIR-SYNTH 41 lost up to 0.19 of warp_iou to it, docs/mirror.md)."""
    H, W = int(shape[0]), int(shape[1])
    if not _points_off_the_image(xy, OUTSIDE_PX, H, W):
        return xy
    x, y = xy[..., 0], xy[..., 1]
    off = (x > OUTSIDE_PX) & ((x < 0) | (y < 0) | (x > W - 1) | (y > H - 1))
    near = off & (x > -reach_px) & (y > -reach_px) & (x < W - 1 + reach_px) & (y < H - 1 + reach_px)
    xy = xy.copy()
    np.clip(xy[..., 0], 0, W - 1, out=xy[..., 0], where=near)
    np.clip(xy[..., 1], 0, H - 1, out=xy[..., 1], where=near)
    return xy


@njit(cache=True)
def _points_off_the_image(xy, outside, H, W):
    """Whether any position of the field ``xy`` (h, w, 2) other than ``outside`` (no foreground) lies off the
    (H, W) image: one pass that stops at the first (most frames have none)."""
    for r in range(xy.shape[0]):
        for c in range(xy.shape[1]):
            x, y = xy[r, c, 0], xy[r, c, 1]
            if x > outside and (x < 0 or y < 0 or x > W - 1 or y > H - 1):
                return True
    return False


def warp_foreground(rgb: np.ndarray, fg_mask: np.ndarray, field: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The foreground moved by the backward field (§5.4): warped image (H, W, 3) uint8 and alpha (H, W) float32.

    Only the foreground moves: the alpha is the warped mask (bilinear, so edges are soft), the
    background is composed separately (§5.5). Warped colours next to the edge are taken from foreground
    pixels only (colour premultiplied by the mask, then divided), so no background colour is dragged along.
    Source positions just outside the image take its edge's pixels (:func:`edge_clamped`).
    """
    rgb = np.asarray(rgb)
    mask = np.asarray(fg_mask)
    if rgb.ndim != 3 or rgb.shape[2] != 3 or mask.shape != rgb.shape[:2] or field.shape != (*rgb.shape[:2], 2):
        raise InputError(f"warp_foreground: image {rgb.shape}, mask {mask.shape} and field {field.shape} "
                         "must share the image size (H, W, 3) / (H, W) / (H, W, 2)")
    H, W = mask.shape
    alpha8 = np.zeros((H, W), np.uint8)
    out = np.zeros((H, W, 3), np.uint8)
    # only the box of pixels whose field points inside can be covered (elsewhere it holds OUTSIDE_PX, which samples
    # the constant border, 0), and only the mask's box of the input has colour: the same frame as remapping all of
    # it, in less time (MIRFAST3)
    x, y, w, h = cv2.boundingRect((field[..., 0] > OUTSIDE_PX).view(np.uint8))
    if w == 0 or h == 0:
        return out, alpha8.astype(np.float32)
    m8 = mask.view(np.uint8) if mask.dtype == bool else mask.astype(np.uint8)
    # the premultiplied colour and the mask (255 in it) as one RGBA image, remapped once: OpenCV's bilinear remap
    # interpolates each channel with the same fixed-point weights, so the same samples as the colour and the mask
    # remapped apart, and the map's conversion is done once (MIR12f: the two remaps were ~1.4 ms of a two-actor
    # frame, the RGBA one ~0.5)
    rgba = np.zeros((H, W, 4), np.uint8)  # background pixels black and transparent
    bx, by, bw, bh = cv2.boundingRect(m8)
    if bw and bh:
        _premultiplied_rgba(rgb, m8, by, by + bh, bx, bx + bw, rgba)
    roi = (slice(y, y + h), slice(x, x + w))
    # the field as one two-channel map (x, y interleaved, as it is stored): the same samples as its two channels
    # given apart, which OpenCV first copies out of the interleaved array (MIR12d)
    xy = edge_clamped(field[roi], (H, W))
    warped = cv2.remap(rgba, xy, None, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    # OpenCV's channel copies: numpy's of the strided RGBA channels cost what the second remap did
    alpha8[roi] = a8 = cv2.extractChannel(warped, 3)
    o = cv2.cvtColor(warped, cv2.COLOR_RGBA2RGB)
    # edge pixels mixed foreground with black: divide by their coverage (few pixels; one numba pass instead of
    # numpy's masks, nonzero and gathers, the same float32 operations: MIR12f)
    _unpremultiply_edges(o, a8)
    out[roi] = o
    alpha = alpha8.astype(np.float32) * np.float32(1.0 / 255.0)
    return out, alpha


@njit(cache=True)
def _unpremultiply_edges(o, a8):
    """``o`` (h, w, 3) uint8, in place: where ``0 < a8 < 255``, ``clip(o / (a8 / 255) + 0.5, 0, 255)`` truncated to
    uint8, in float32 as numpy computed it (``a8.astype(float32) / 255.0``, the division and the rounding offset)."""
    h, w = a8.shape
    for r in range(h):
        for c in range(w):
            v = a8[r, c]
            if v == 0 or v == 255:
                continue
            a = np.float32(v) / np.float32(255.0)
            for ch in range(3):
                x = np.float32(o[r, c, ch]) / a + np.float32(0.5)
                o[r, c, ch] = np.uint8(min(max(x, np.float32(0.0)), np.float32(255.0)))


@njit(cache=True)
def _premultiplied_rgba(rgb, mask, r0, r1, c0, c1, out):
    """``out[r0:r1, c0:c1]`` = the colour where ``mask`` is non-zero (black elsewhere) and 255 / 0 as its alpha."""
    for r in range(r0, r1):
        for c in range(c0, c1):
            if mask[r, c]:
                out[r, c, 0] = rgb[r, c, 0]
                out[r, c, 1] = rgb[r, c, 1]
                out[r, c, 2] = rgb[r, c, 2]
                out[r, c, 3] = 255


#: Where the warp field comes from: ``dense``, the target body rasterised, each pixel it covers mapped to the
#: same surface point on the source body, its outline onto the source's outline in a 1 px band, nothing farther out
#: but the foreground the body does not explain (MIR12l: :data:`EXTRA_REACH_PX`) (MIR12k; before it MLS, Eq. 5, from
#: the vertex pairs and the covered grid nodes beyond a 6 px band); ``mls``,
#: Eq. 5 from the sparse vertex pairs everywhere (the paper).
CORRESPONDENCES = ("dense", "mls")


@dataclass(frozen=True, eq=False)
class DenseCorrespondence:
    """The dense backward correspondence of one frame's posed bodies, on an image crop holding both.

    ``origin`` (x0, y0) of the crop; ``source_uv`` (h, w, 2) float32: at each crop pixel the target body
    covers, the input pixel where the source body shows the same surface point (:func:`dense_source_uv`),
    NaN elsewhere; ``source_mask`` (h, w) the source body's silhouette; ``grid_source_uv`` (gh, gw, 2) the same
    at the warp grid's nodes (the mean of the 2x2 pixels around each node; NaN unless all four are covered),
    ``grid_groups`` (gh, gw) the person at each node (None: one); ``source_depth`` (h, w) the source body's z-buffer
    (0 where it does not cover; :func:`warp_pairs` keeps it for :mod:`bodystudio.mirror.image_plane`).
    """

    origin: tuple[int, int]
    source_uv: np.ndarray
    source_mask: np.ndarray
    grid_source_uv: np.ndarray
    grid_groups: np.ndarray | None = None
    source_depth: np.ndarray | None = None


@dataclass(frozen=True, eq=False)
class WarpPairs:
    """The constraints of the warp: sparse vertex pairs and, optionally, the dense correspondence.

    ``src_uv``/``dst_uv`` (m, 2) projected visible vertices of the posed source/target body, ``ids`` (m,) their
    vertex ids; ``dense`` a :class:`DenseCorrespondence` or None.
    """

    src_uv: np.ndarray
    dst_uv: np.ndarray
    ids: np.ndarray
    dense: DenseCorrespondence | None = None
    groups: np.ndarray | None = None  # (m,) the person of each pair (:func:`actors_warp_pairs`), None: one


def crop_camera(camera, x0: int, y0: int, width: int, height: int, scale=(1.0, 1.0)):
    """``camera`` restricted to the pixels ``[x0, x0 + width) x [y0, y0 + height)`` and scaled by ``scale`` (x, y):
    pixel (c, r) of the result is image pixel ``((c + 0.5) / scale_x - 0.5 + x0, (r + 0.5) / scale_y - 0.5 + y0)``."""
    from bodystudio.geometry.camera import Camera

    sx, sy = scale
    K = camera.K.copy()
    K[0, 2] -= x0
    K[1, 2] -= y0
    K[0, :2] *= sx
    K[1, :2] *= sy
    K[0, 2] = (K[0, 2] + 0.5) * sx - 0.5
    K[1, 2] = (K[1, 2] + 0.5) * sy - 0.5
    return Camera(camera.name, K, camera.dist, camera.R, camera.t, int(width), int(height))


def dense_source_uv(source_vertices: np.ndarray, faces: np.ndarray, target_raster, camera,
                    projected: np.ndarray | None = None) -> np.ndarray:
    """Dense backward correspondence: the exact counterpart of Eq. 5's handles at every pixel of a raster.

    ``target_raster`` is the posed target body rendered (triangle ids and perspective-correct barycentrics
    of the front surface); each covered pixel's surface point ``sum_k b_k V_S[f_k]`` on the posed source body
    (same topology) is projected by ``camera`` (the full image's). ``projected`` (n, 2): the source vertices'
    projections, already at hand; the point's projection is then interpolated from them with the same
    barycentrics (projection is affine to far below a pixel over a triangle of a few pixels). Returns
    (h, w, 2) float32 input pixels, NaN where the target does not cover the pixel.
    """
    tri = target_raster.triangle_id
    out = np.full((*tri.shape, 2), np.nan, np.float32)
    if projected is not None:
        _interpolate_projections(tri, target_raster.barycentric, np.asarray(faces, np.int64),
                                 np.asarray(projected, np.float32), out)
        return out
    rows, cols = np.nonzero(tri >= 0)
    if len(rows):
        F = np.asarray(faces)[tri[rows, cols]]
        b = target_raster.barycentric[rows, cols]
        V = np.asarray(source_vertices, dtype=np.float64)
        X = np.einsum("nk,nkd->nd", b.astype(np.float64), V[F])
        uv, z = camera.project_with_depth(X)
        out[rows[z > 0], cols[z > 0]] = uv[z > 0]
    return out


@njit(cache=True)
def _interpolate_projections(tri, bary, faces, projected, out):
    """``out[r, c] = sum_k bary[r, c, k] projected[faces[tri[r, c], k]]`` where ``tri >= 0``."""
    for r in range(tri.shape[0]):
        for c in range(tri.shape[1]):
            f = tri[r, c]
            if f >= 0:
                b0, b1, b2 = bary[r, c, 0], bary[r, c, 1], bary[r, c, 2]
                for d in range(2):
                    out[r, c, d] = (b0 * projected[faces[f, 0], d] + b1 * projected[faces[f, 1], d]
                                    + b2 * projected[faces[f, 2], d])


@lru_cache(maxsize=32)
def _spread_ids(n_vertices: int, n_handles: int) -> np.ndarray:
    """``n_handles`` evenly spread vertex ids of ``n_vertices`` (sorted, unique), the same every frame (cached:
    MIR12f; read-only)."""
    ids = np.unique(np.linspace(0, n_vertices - 1, min(n_handles, n_vertices)).round().astype(np.int64))
    ids.setflags(write=False)
    return ids


def _body_crop(uv_list, camera, margin_px: float):
    lo_hi = np.array([np.inf, np.inf, -np.inf, -np.inf])
    for uv in uv_list:  # the finite points' bounds in one numba pass each (MIR12f: was a concatenation of them)
        _finite_bounds(np.ascontiguousarray(uv, dtype=np.float64), lo_hi)
    if not lo_hi[0] <= lo_hi[2]:
        return None
    x0 = int(max(np.floor(lo_hi[0] - margin_px), 0))
    y0 = int(max(np.floor(lo_hi[1] - margin_px), 0))
    x1 = int(min(np.ceil(lo_hi[2] + margin_px) + 1, camera.width))
    y1 = int(min(np.ceil(lo_hi[3] + margin_px) + 1, camera.height))
    return (x0, y0, x1, y1) if x1 > x0 and y1 > y0 else None


@njit(cache=True)
def _finite_bounds(uv, lo_hi):
    """``lo_hi`` (min x, min y, max x, max y), in place, widened to the rows of ``uv`` (n, 2) with both finite."""
    for i in range(uv.shape[0]):
        x, y = uv[i, 0], uv[i, 1]
        if np.isfinite(x) and np.isfinite(y):
            lo_hi[0] = min(lo_hi[0], x)
            lo_hi[1] = min(lo_hi[1], y)
            lo_hi[2] = max(lo_hi[2], x)
            lo_hi[3] = max(lo_hi[3], y)


def facing_faces(uv: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Indices of the triangles whose projection ``uv`` (n, 2) has negative area in the y-down image: those facing the
    camera on a body wound outwards (the model templates); NaN projections (behind the camera) are not."""
    out = np.empty(len(F), np.int64)
    n = _facing(np.ascontiguousarray(uv, dtype=np.float64), np.ascontiguousarray(F, dtype=np.int64), out)
    return out[:n]


@njit(cache=True)
def _facing(uv, F, out):
    """:func:`facing_faces`' loop (numpy's three gathers of the corners cost ~0.7 ms a 10k-face mesh): the ids whose
    ``(b - a) x (c - a)`` is negative into ``out``; returns how many."""
    n = 0
    for f in range(F.shape[0]):
        a, b, c = F[f, 0], F[f, 1], F[f, 2]
        if (uv[b, 0] - uv[a, 0]) * (uv[c, 1] - uv[a, 1]) < (uv[c, 0] - uv[a, 0]) * (uv[b, 1] - uv[a, 1]):
            out[n] = f
            n += 1
    return n


def front_render(V: np.ndarray, F: np.ndarray, camera):
    """``capture.render.render`` of a closed body drawing only the triangles that face the camera
    (:func:`facing_faces`), half of them: silhouette the same pixel for pixel (every ray into a closed surface
    enters through a front face), depth, triangle ids (into ``F``) and barycentrics the same except where a back face
    lies in front of every front face (a self-intersection: the 2k bench frames differ at 0-3 pixels of ~50k; pinned
    in tests/mirror/test_warp.py). :func:`warp_pairs` with ``closed`` draws its z-buffers so (MIRFAST3)."""
    from bodystudio.capture.render import render

    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    uv, z = camera.project_with_depth(V)
    front = facing_faces(np.where((z > 0)[:, None], uv, np.nan), F)
    raster = render(V, F[front], camera)
    tri = raster.triangle_id
    tri[raster.mask] = front[tri[raster.mask]]
    return raster


def warp_pairs(source_vertices: np.ndarray, target_vertices: np.ndarray, faces: np.ndarray, camera,
               n_handles: int = 800, depth_tol_m: float = 0.08, z_buffer_scale: float = 0.25,
               rim_cos: float | None = None, dense: bool = False, grid=(120, 160), face_groups=None,
               margin_px: float = 10.0, closed: bool = False) -> WarpPairs:
    """The warp's constraints: :func:`visible_vertex_pairs` and, with ``dense``, the :class:`DenseCorrespondence`.

    With ``dense`` both bodies are rendered at full resolution on the crop holding them (plus ``margin_px``),
    and that z-buffer also decides the vertices' visibility; otherwise the z-buffers are rendered at
    ``z_buffer_scale``. ``face_groups`` (f,) the person of each face (several actors in one mesh). ``closed``: the
    mesh is closed and wound outwards (the statistical model's bodies): the z-buffers draw the camera-facing
    triangles only (:func:`front_render`, half the work); otherwise every triangle, both sides.
    """
    from bodystudio.capture.render import render, render_silhouette_depth

    Vs = np.asarray(source_vertices, dtype=np.float64)
    Vt = np.asarray(target_vertices, dtype=np.float64)
    if Vs.shape != Vt.shape or Vs.ndim != 2 or Vs.shape[1] != 3:
        raise InputError(f"source and target vertices must both be (n, 3), got {Vs.shape} and {Vt.shape}")
    if rim_cos is not None and not 0.0 < rim_cos <= 1.0:
        raise InputError(f"rim_cos must lie in (0, 1] (None: no rim vertices), got {rim_cos}")
    ids = _spread_ids(len(Vs), int(n_handles))
    if rim_cos is not None:
        ids = np.union1d(ids, rim_vertices(Vt, faces, camera.center, rim_cos))
    projected = [camera.project_with_depth(V) for V in (Vs, Vt)]
    box = _body_crop([np.where((z > 0)[:, None], uv, np.nan) for uv, z in projected], camera, margin_px) \
        if dense else None
    if box is not None:
        x0, y0, x1, y1 = box
        w, h = x1 - x0, y1 - y0
        sx = sy = 1.0
    else:
        x0 = y0 = 0
        w = max(int(round(camera.width * z_buffer_scale)), 1)
        h = max(int(round(camera.height * z_buffer_scale)), 1)
        sx, sy = w / camera.width, h / camera.height
    small = crop_camera(camera, x0, y0, w, h, (sx, sy))
    keep = np.ones(len(ids), bool)
    uvs, rasters = [], []
    F = np.asarray(faces, dtype=np.int64)
    # closed bodies: each z-buffer draws the triangles facing the camera (their projections, at hand, tell: the
    # crop's are an affine map of them); the target raster's triangle ids then index its front faces
    drawn = [facing_faces(uv, F) if closed else None for uv, _ in projected]
    for k, (V, (uv_all, z_all), front) in enumerate(zip((Vs, Vt), projected, drawn, strict=True)):
        uv, z = uv_all[ids], z_all[ids]
        # the source's raster is read for its silhouette and depth only: no triangle ids and barycentrics (MIR12f)
        if k == 0:
            raster = render_silhouette_depth(V, F if front is None else F[front], small)
            zbuf = raster[1]
        else:
            raster = render(V, F if front is None else F[front], small)
            zbuf = raster.depth
        col = np.clip(np.round((uv[:, 0] - x0 + 0.5) * sx - 0.5), 0, w - 1)
        row = np.clip(np.round((uv[:, 1] - y0 + 0.5) * sy - 0.5), 0, h - 1)
        ok = _finite_rows(uv) & (z > 0)
        col, row = np.where(ok, col, 0).astype(np.int64), np.where(ok, row, 0).astype(np.int64)
        # the nearest z in the 3x3 neighbourhood: a vertex on a silhouette edge falls next to the covered pixel
        near = _nearest_depth_3x3(zbuf, row, col)
        keep &= ok & (z <= near + depth_tol_m)
        keep &= (uv[:, 0] >= 0) & (uv[:, 0] <= camera.width - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= camera.height - 1)
        uvs.append(uv)
        rasters.append(raster)
    correspondence = None
    if box is not None:
        uv_s, z_s = projected[0]
        front = drawn[1]
        F_t = F if front is None else F[front]
        groups_t = face_groups if face_groups is None or front is None else np.asarray(face_groups)[front]
        source_uv = dense_source_uv(Vs, F_t, rasters[1], camera, projected=uv_s if np.all(z_s > 0) else None)
        correspondence = DenseCorrespondence((x0, y0), source_uv, rasters[0][0],
                                             *_grid_samples(source_uv, rasters[1].triangle_id, (x0, y0), camera,
                                                            grid, groups_t), source_depth=rasters[0][1])
    return WarpPairs(uvs[0][keep], uvs[1][keep], ids[keep], correspondence)


def actors_warp_pairs(sources, targets, faces, camera, n_handles: int = 800, rim_cos: float | None = None,
                      dense: bool = False, **options) -> WarpPairs:
    """:func:`warp_pairs` of several actors at once: their bodies (each ``(n_a, 3)``, the same ``faces``) stacked
    into one mesh, rendered in one z-buffer per body (which also lets one actor hide the other's vertices), the
    ``n_handles`` candidates spread over all of them; ``groups`` says whose each pair is, ``ids`` index the stack.

    Two actors cost one call instead of one per actor plus one for the dense correspondence of both: 16 -> 12 ms
    CPU on the bench's two-actor frame, the same warp_iou (docs/mirror.md, MIRFAST2).
    """
    if len(sources) != len(targets) or not len(sources):
        raise InputError(f"actors_warp_pairs needs as many target bodies as source bodies (>= 1), got {len(sources)} "
                         f"and {len(targets)}")
    F = np.asarray(faces, dtype=np.int64)
    sizes = np.array([len(V) for V in sources], np.int64)
    starts = np.concatenate([[0], np.cumsum(sizes)])
    F_all = np.concatenate([F + s for s in starts[:-1]])
    face_groups = np.repeat(np.arange(len(sources)), len(F))
    p = warp_pairs(np.concatenate(sources), np.concatenate(targets), F_all, camera, n_handles, rim_cos=rim_cos,
                   dense=dense, face_groups=face_groups, **options)
    groups = np.searchsorted(starts, p.ids, side="right") - 1
    return WarpPairs(p.src_uv, p.dst_uv, p.ids, p.dense, groups)


@njit(cache=True)
def _nearest_depth_3x3(zbuf, rows, cols):
    """The smallest covered depth (``zbuf`` > 0) in the 3x3 neighbourhood of each pixel ``(rows, cols)``, inf where
    none; only the candidates' pixels are read (padding the whole buffer and nine gathers cost ~0.3 ms a body)."""
    h, w = zbuf.shape
    out = np.full(rows.shape[0], np.inf)
    for i in range(rows.shape[0]):
        best = np.inf
        for r in range(max(rows[i] - 1, 0), min(rows[i] + 2, h)):
            for c in range(max(cols[i] - 1, 0), min(cols[i] + 2, w)):
                z = zbuf[r, c]
                if z > 0 and z < best:
                    best = z
        out[i] = best
    return out


def _grid_samples(source_uv, triangle_id, origin, camera, grid, face_groups):
    """Grid-node values of a crop's correspondence: the mean of the 2x2 pixels around each node (its bilinear
    value: nodes sit at pixel ``4 j + 1.5``), NaN unless all four are covered; and the node's person."""
    gh, gw = int(grid[0]), int(grid[1])
    xs, ys = mls_grid_nodes((camera.height, camera.width), (gh, gw))
    h, w = triangle_id.shape
    cx = np.floor(xs).astype(np.int64) - origin[0]  # left pixel of the 2x2 block
    cy = np.floor(ys).astype(np.int64) - origin[1]
    okx = (cx >= 0) & (cx + 1 < w)
    oky = (cy >= 0) & (cy + 1 < h)
    out = np.full((gh, gw, 2), np.nan, np.float32)
    groups = None if face_groups is None else np.zeros((gh, gw), np.int64)
    person = np.zeros(1, np.int64) if groups is None else np.asarray(face_groups, np.int64)
    _node_blocks(np.ascontiguousarray(source_uv, dtype=np.float32), triangle_id, np.flatnonzero(oky), cy,
                 np.flatnonzero(okx), cx, person, out, np.zeros((1, 1), np.int64) if groups is None else groups,
                 groups is not None)
    return out, groups


@njit(cache=True)
def _node_blocks(source_uv, triangle_id, rows, cy, cols, cx, face_groups, out, groups, with_groups):
    """:func:`_grid_samples`' loop: ``out[r, c]`` the mean of the 2x2 block at ``(cy[r], cx[c])`` (NaN wherever one
    of the four is), ``groups[r, c]`` the person of its top-left pixel's triangle (0 where none); one pass instead
    of four fancy-indexed gathers (1 -> <0.1 ms for a two-actor crop, MIRFAST2)."""
    for r in rows:
        py = cy[r]
        for c in cols:
            px = cx[c]
            for d in range(2):
                out[r, c, d] = (source_uv[py, px, d] + source_uv[py + 1, px, d] + source_uv[py, px + 1, d]
                                + source_uv[py + 1, px + 1, d]) / np.float32(4.0)
            if with_groups:
                tri = triangle_id[py, px]
                groups[r, c] = face_groups[tri] if tri >= 0 else 0


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
    p = warp_pairs(source_vertices, target_vertices, faces, camera, n_handles, depth_tol_m, z_buffer_scale,
                   rim_cos)
    return p.src_uv, p.dst_uv, p.ids


def rim_vertices(vertices: np.ndarray, faces: np.ndarray, eye: np.ndarray, max_cos: float = 0.3) -> np.ndarray:
    """Ids of the vertices seen edge-on from ``eye``: ``|cos|`` of the normal and the viewing ray below ``max_cos``."""
    V = np.ascontiguousarray(vertices, dtype=np.float64)
    N = _area_weighted_normals(V, np.ascontiguousarray(faces, dtype=np.int64))
    out = np.empty(len(V), np.int64)
    return out[:_rim_test(V, N, np.asarray(eye, dtype=np.float64).reshape(3), float(max_cos), out)]


@njit(cache=True)
def _rim_test(V, N, eye, max_cos, out):
    """:func:`rim_vertices`' test in one pass (MIR12f; numpy's norms, einsum and masks over the vertices were ~0.3 ms
    of a two-actor frame), the same operations in the same order: ``cos = N.ray / max(|N| |ray|, 1e-300)``, the
    ids with ``|cos| < max_cos`` and ``|N| |ray| > 0`` (a vertex on no face has no normal: not rim) into ``out``;
    returns how many."""
    n = 0
    for i in range(V.shape[0]):
        rx, ry, rz = V[i, 0] - eye[0], V[i, 1] - eye[1], V[i, 2] - eye[2]
        nx, ny, nz = N[i, 0], N[i, 1], N[i, 2]
        norm = np.sqrt(nx * nx + ny * ny + nz * nz) * np.sqrt(rx * rx + ry * ry + rz * rz)
        cos = (nx * rx + ny * ry + nz * rz) / max(norm, 1e-300)
        if abs(cos) < max_cos and norm > 0:
            out[n] = i
            n += 1
    return n


@njit(cache=True)
def _area_weighted_normals(V, F):
    """Unnormalised vertex normals: the sum of the cross products (twice the area-weighted normals) of each
    vertex's faces, in one pass (the per-frame rim test; numpy's bincounts took 1 ms for a 6k body)."""
    N = np.zeros_like(V)
    for f in range(F.shape[0]):
        a, b, c = F[f, 0], F[f, 1], F[f, 2]
        ux, uy, uz = V[b, 0] - V[a, 0], V[b, 1] - V[a, 1], V[b, 2] - V[a, 2]
        vx, vy, vz = V[c, 0] - V[a, 0], V[c, 1] - V[a, 1], V[c, 2] - V[a, 2]
        nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
        for k in (a, b, c):
            N[k, 0] += nx
            N[k, 1] += ny
            N[k, 2] += nz
    return N
