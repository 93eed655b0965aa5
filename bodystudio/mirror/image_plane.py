"""The posed bodies registered in the image plane to the person's observed outline (MIR12p).

The pose refinement (:mod:`bodystudio.mirror.refine`) balances the silhouette against the Kinect joints and the depth,
and the source body's outline ends up ~0.5 px (mean) beside the person's refined foreground. That offset, measured at
the source's visible rim vertices along its outline's normal, is taken off both bodies alike: a 2D translation per
bone fitted to the offsets (point-to-line least squares, tied to the parent bone's translation; one step of an
articulated 2D ICP), blended per vertex by the skin weights and applied parallel to the image plane
(:func:`image_plane_shift`). The displacement ``V_T - V_S`` in 3D is unchanged; where the image shows the person,
both bodies move onto them (benchmarks/mirror_image_plane.py; docs/mirror.md, MIR12p).
"""

from __future__ import annotations

import cv2
import numpy as np

from bodystudio.mirror.refine import _one_blas_thread
from bodystudio.mirror.warp import _area_weighted_normals, _nearest_depth_3x3, _signed_distance

#: Rim test of the outline's vertices: |cos| between the vertex normal and the viewing ray below this.
RIM_COS = 0.3
#: A rim vertex counts as on the source's outline within this many pixels of it.
ON_OUTLINE_PX = 1.0
#: Outline offsets beyond this (pixels) are not the fit's misalignment (hair, a bag, the cut's errors): dropped.
MAX_OFFSET_PX = 6.0
#: Tikhonov weights of the per-bone translations: toward the parent bone's and toward none (per outline vertex
#: they are a fraction of one vertex's row; bones nobody sees take their neighbours' translation).
SMOOTH_WEIGHT = 20.0
RIDGE_WEIGHT = 1.0
#: Huber threshold (pixels) of the one reweighted solve.
HUBER_PX = 1.5


def outline_offsets(uv: np.ndarray, source_mask: np.ndarray, foreground: np.ndarray, origin) -> tuple:
    """Signed outline offsets at image points ``uv`` (n, 2) near the source silhouette's outline.

    ``source_mask`` (h, w) the source body's silhouette on a crop at ``origin`` (x0, y0), ``foreground`` the
    person's mask, full image. Returns ``(offset_px, normal, on_outline)``: how far the foreground's outline lies
    outside the source's along the source's outward normal (its signed distance minus the source's, positive where
    the person reaches beyond the body), the unit outward normal (n, 2) and whether the point lies within
    :data:`ON_OUTLINE_PX` of the source's outline.
    """
    x0, y0 = origin
    h, w = source_mask.shape
    H, W = foreground.shape
    fg = np.zeros((h, w), bool)
    ys, xs = slice(max(y0, 0), min(y0 + h, H)), slice(max(x0, 0), min(x0 + w, W))
    fg[ys.start - y0:ys.stop - y0, xs.start - x0:xs.stop - x0] = foreground[ys, xs]
    sd_s = _signed_distance(source_mask)
    sd_f = _signed_distance(fg)
    x = np.asarray(uv[:, 0], np.float32) - x0
    y = np.asarray(uv[:, 1], np.float32) - y0

    def at(img, dx=0.0, dy=0.0):
        return cv2.remap(img, (x + dx)[None], (y + dy)[None], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)[0]

    s = at(sd_s)
    g = np.stack([at(sd_s, 1.0) - at(sd_s, -1.0), at(sd_s, 0.0, 1.0) - at(sd_s, 0.0, -1.0)], axis=1)
    normal = -g / np.maximum(np.linalg.norm(g, axis=1, keepdims=True), 1e-6)
    inside_crop = (x >= 1) & (x < w - 2) & (y >= 1) & (y < h - 2)
    return (at(sd_f) - s).astype(np.float64), normal.astype(np.float64), inside_crop & (np.abs(s) <= ON_OUTLINE_PX)


def bone_translations(weights: np.ndarray, parents, normal: np.ndarray, offset: np.ndarray,
                      smooth: float = SMOOTH_WEIGHT, ridge: float = RIDGE_WEIGHT, huber_px: float = HUBER_PX,
                      dilation: bool = False):
    """Per-bone 2D translations (B, 2) whose skin-weighted blend moves each outline point by ``offset`` along
    ``normal`` (least squares, point-to-line), tied to the parent bone's translation and to zero. ``dilation``: also
    a per-bone growth along the outline's normal (B,), returned as a third column."""
    Wt = np.asarray(weights, np.float64)
    n, B = Wt.shape
    blocks = [Wt * normal[:, :1], Wt * normal[:, 1:]] + ([Wt] if dilation else [])
    A = np.concatenate(blocks, axis=1)  # (n, 2B or 3B): [t_x, t_y, growth]
    L = np.zeros((B, B))
    for b, p in enumerate(parents):
        if p >= 0:
            L[b, b] += 1
            L[p, p] += 1
            L[b, p] -= 1
            L[p, b] -= 1
    reg = np.kron(np.eye(len(blocks)), smooth * L + ridge * np.eye(B))
    r = np.ones(n)
    t = np.zeros(A.shape[1])
    # one BLAS thread: a few hundred rows by ~106 columns, where OpenBLAS's threads spinning on a loaded machine
    # cost 160 ms instead of ~1 (as refine's normal equations, MIR12b)
    with _one_blas_thread():
        for _ in range(2):
            Aw = A * r[:, None]
            t = np.linalg.solve(A.T @ Aw + reg, Aw.T @ offset)
            res = np.abs(A @ t - offset)
            r = np.where(res <= huber_px, 1.0, huber_px / np.maximum(res, 1e-9))
    return t.reshape(len(blocks), B).T


def image_plane_shift(V: np.ndarray, shift_px: np.ndarray, camera) -> np.ndarray:
    """``V`` (n, 3) moved parallel to the image plane so that each projects ``shift_px`` (n, 2) further (pinhole)."""
    Xc = V @ camera.R.T + camera.t
    d = np.zeros_like(Xc)
    d[:, 0] = shift_px[:, 0] * Xc[:, 2] / camera.K[0, 0]
    d[:, 1] = shift_px[:, 1] * Xc[:, 2] / camera.K[1, 1]
    return V + d @ camera.R


def register_to_outline(Vs: np.ndarray, Vt: np.ndarray, faces: np.ndarray, weights: np.ndarray, parents, camera,
                        foreground: np.ndarray, source_mask: np.ndarray, source_depth: np.ndarray, origin,
                        gain: float = 1.0, **kw) -> tuple[np.ndarray, np.ndarray, dict]:
    """Source and target vertices moved in the image plane by the source outline's registration to ``foreground``.

    ``source_mask`` / ``source_depth`` the source body's silhouette and z-buffer on the crop at ``origin``.
    Returns the moved ``(Vs, Vt)`` and a dict of diagnostics (outline vertices used, mean |offset| before).
    """
    with _one_blas_thread():  # the blend (n, B) @ (B, 2) and the solve are BLAS's: off its thread pool
        return _register_to_outline(Vs, Vt, faces, weights, parents, camera, foreground, source_mask, source_depth,
                                    origin, gain, **kw)


def _register_to_outline(Vs, Vt, faces, weights, parents, camera, foreground, source_mask, source_depth, origin,
                         gain, **kw):
    uv, z = camera.project_with_depth(Vs)
    N = _area_weighted_normals(Vs, np.asarray(faces, np.int64))
    ray = Vs - camera.center
    cos = np.abs(np.einsum("ij,ij->i", N, ray)) / np.maximum(
        np.linalg.norm(N, axis=1) * np.linalg.norm(ray, axis=1), 1e-12)
    x0, y0 = origin
    col = np.clip(np.round(uv[:, 0] - x0), 0, source_mask.shape[1] - 1).astype(np.int64)
    row = np.clip(np.round(uv[:, 1] - y0), 0, source_mask.shape[0] - 1).astype(np.int64)
    visible = z <= _nearest_depth_3x3(source_depth, row, col) + 0.02
    cand = np.flatnonzero((cos < RIM_COS) & visible & (z > 0))
    offset, normal, on = outline_offsets(uv[cand], source_mask, foreground, origin)
    keep = on & (np.abs(offset) <= MAX_OFFSET_PX)
    ids = cand[keep]
    info = {"outline_vertices": int(len(ids)), "mean_abs_offset_px": float(np.abs(offset[keep]).mean())
            if len(ids) else 0.0}
    if len(ids) < 20:
        return Vs, Vt, info
    t = bone_translations(weights[ids], parents, normal[keep], offset[keep], **kw)
    Wt = np.asarray(weights, np.float64)
    shift = gain * (Wt @ t[:, :2])
    if t.shape[1] == 3:  # growth along each vertex's projected normal (the rim's full, a front-facing one's none)
        Np = _projected_normals(Vs, N, camera)
        shift_s = shift + gain * (Wt @ t[:, 2])[:, None] * Np
        Np_t = _projected_normals(Vt, _area_weighted_normals(Vt, np.asarray(faces, np.int64)), camera)
        shift_t = shift + gain * (Wt @ t[:, 2])[:, None] * Np_t
        return image_plane_shift(Vs, shift_s, camera), image_plane_shift(Vt, shift_t, camera), info
    return image_plane_shift(Vs, shift, camera), image_plane_shift(Vt, shift, camera), info


def _projected_normals(V, N, camera) -> np.ndarray:
    """Each vertex's unit normal turned into the camera frame, its image-plane part (n, 2): length 1 on the rim."""
    Nc = (N / np.maximum(np.linalg.norm(N, axis=1, keepdims=True), 1e-12)) @ camera.R.T
    return Nc[:, :2]
