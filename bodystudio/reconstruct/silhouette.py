"""Silhouette constraints of Rapid Skin §III.B: rim vertices, contour matching along the normal, Eq. 6-7, 10.

For each camera the template is projected (Eq. 6, with the camera's lens distortion), rim vertices are
those whose normal is almost perpendicular to the viewing ray, and each rim vertex searches the
silhouette mask along its projected normal within ``+-tau`` pixels for an inside->outside crossing (a
silhouette gradient that agrees with the normal). A match becomes a viewing-ray constraint weighted by
``k_sil = exp(-|v_c - p_c|^2 / 2 alpha^2)``.

Rim vertices hidden behind another body part in a view would match the occluder's contour; we drop
them by checking that one step outwards along the projected normal leaves the template's own
projected silhouette (a cheap visibility test the paper leaves implicit).
"""

from __future__ import annotations

import numba
import numpy as np

from bodystudio.errors import SessionError
from bodystudio.reconstruct.solver import SilhouetteConstraints

#: Step (pixels) along the projected normal used for the template-outline test.
_OUTLINE_STEP_PX = 2.0
#: Distance (metres) along the 3D normal used to find the normal's image direction.
_NORMAL_PROBE_M = 0.005


@numba.njit(cache=True)
def _rasterize_mask(uv, F, width, height, mask):
    for f in range(F.shape[0]):
        a, b, c = F[f, 0], F[f, 1], F[f, 2]
        ax, ay, bx, by, cx, cy = uv[a, 0], uv[a, 1], uv[b, 0], uv[b, 1], uv[c, 0], uv[c, 1]
        if not (np.isfinite(ax) and np.isfinite(bx) and np.isfinite(cx)
                and np.isfinite(ay) and np.isfinite(by) and np.isfinite(cy)):
            continue
        area = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)
        if area == 0.0:
            continue
        x0 = max(int(np.ceil(min(ax, bx, cx))), 0)
        x1 = min(int(np.floor(max(ax, bx, cx))), width - 1)
        y0 = max(int(np.ceil(min(ay, by, cy))), 0)
        y1 = min(int(np.floor(max(ay, by, cy))), height - 1)
        s = 1.0 if area > 0 else -1.0
        for y in range(y0, y1 + 1):
            for x in range(x0, x1 + 1):
                w0 = s * ((bx - x) * (cy - y) - (by - y) * (cx - x))
                w1 = s * ((cx - x) * (ay - y) - (cy - y) * (ax - x))
                w2 = s * ((ax - x) * (by - y) - (ay - y) * (bx - x))
                if w0 >= 0 and w1 >= 0 and w2 >= 0:
                    mask[y, x] = 1
    return mask


def silhouette_mask(V: np.ndarray, F: np.ndarray, camera) -> np.ndarray:
    """Binary mask ``(H, W)`` of the mesh's projection (pixel centres at integer coordinates)."""
    uv = camera.project(V)
    mask = np.zeros((camera.height, camera.width), np.uint8)
    return _rasterize_mask(np.ascontiguousarray(uv), np.ascontiguousarray(F, dtype=np.int64),
                           camera.width, camera.height, mask).astype(bool)


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


@numba.njit(cache=True)
def _search_contours(mask, uv, direction, tau_px):
    m = uv.shape[0]
    out = np.full(m, np.nan)
    steps = int(np.ceil(tau_px))
    for i in range(m):
        x, y = uv[i, 0], uv[i, 1]
        dx, dy = direction[i, 0], direction[i, 1]
        best = np.inf
        prev = _sample_bilinear(mask, x - steps * dx, y - steps * dy)
        for s in range(-steps + 1, steps + 1):
            cur = _sample_bilinear(mask, x + s * dx, y + s * dy)
            # Inside -> outside going along the normal: the silhouette gradient opposes n, i.e. agrees
            # with the outward normal; outside -> inside crossings belong to other contours.
            if prev >= 0.5 and cur < 0.5:
                t = (s - 1) + (prev - 0.5) / (prev - cur)
                if abs(t) <= tau_px and abs(t) < abs(best):
                    best = t
            prev = cur
        if np.isfinite(best):
            out[i] = best
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


def silhouette_constraints(V: np.ndarray, F: np.ndarray, N: np.ndarray, cameras, masks: dict,
                           tau_px: float = 30.0, alpha_px: float = 40.0, rim_cos: float = 0.2
                           ) -> SilhouetteConstraints:
    """Match rim vertices with silhouette contours in every camera (Rapid Skin §III.B, Eq. 6, 7, 10).

    ``masks`` maps camera names to boolean ``(H, W)`` silhouettes. Returns viewing-ray constraints.
    """
    vid, origin, direction, k, cam_ids, dist = [], [], [], [], [], []
    for c, cam in enumerate(cameras):
        mask = np.asarray(masks[cam.name]) > 0
        uv, z = cam.project_with_depth(V)
        rim = rim_vertices(V, N, cam, rim_cos) & (z > 0) & cam.in_image(np.nan_to_num(uv, nan=-1.0))
        ids = np.flatnonzero(rim)
        if len(ids) == 0:
            continue
        probe = cam.project(V[ids] + _NORMAL_PROBE_M * N[ids])
        n2 = probe - uv[ids]
        norm = np.linalg.norm(n2, axis=1)
        ok = np.isfinite(norm) & (norm > 1e-9)
        ids, n2 = ids[ok], n2[ok] / norm[ok, None]
        own = silhouette_mask(V, F, cam)
        outer = uv[ids] + _OUTLINE_STEP_PX * n2
        xi = np.clip(np.round(outer[:, 0]).astype(int), 0, cam.width - 1)
        yi = np.clip(np.round(outer[:, 1]).astype(int), 0, cam.height - 1)
        on_outline = ~own[yi, xi]
        ids, n2 = ids[on_outline], n2[on_outline]
        t = match_contours(mask, uv[ids], n2, tau_px)
        hit = np.isfinite(t)
        if not np.any(hit):
            continue
        ids, n2, t = ids[hit], n2[hit], t[hit]
        pixels = uv[ids] + t[:, None] * n2
        o, d = cam.rays(pixels)
        vid.append(ids)
        origin.append(o)
        direction.append(d)
        k.append(silhouette_weight(t, alpha_px))
        cam_ids.append(np.full(len(ids), c))
        dist.append(np.abs(t))
    if not vid:
        return SilhouetteConstraints.empty()
    return SilhouetteConstraints(np.concatenate(vid).astype(np.int64), np.concatenate(origin),
                                 np.concatenate(direction), np.concatenate(k), np.concatenate(cam_ids),
                                 np.concatenate(dist))
