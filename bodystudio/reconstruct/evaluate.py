"""Evaluation of reconstructed meshes against ground truth (Rapid Skin §V.B, Fig. 7a).

Point-to-surface distances both ways (libigl's ``point_mesh_squared_distance``): median, 90th
percentile, Hausdorff distance and the area share of the ground-truth surface within 10 mm; the same
on the *visible* surface (ground-truth points seen by at least one camera, which silhouettes can
constrain at all); silhouette IoU per view; joint error; and a per-region breakdown by the dominant
skinning bone, with the crotch as its own region (the concavity the paper singles out).
"""

from __future__ import annotations

from dataclasses import dataclass

import igl
import numpy as np

from bodystudio.geometry.mesh import vertex_areas
from bodystudio.reconstruct.silhouette import silhouette_mask

#: Region -> bones whose dominant skin weight puts a vertex in it (game_engine rig).
REGIONS = {
    "head": ("neck_01", "head"),
    "torso": ("Root", "pelvis", "spine_01", "spine_02", "spine_03", "clavicle_l", "clavicle_r"),
    "arms": ("upperarm_l", "upperarm_r", "lowerarm_l", "lowerarm_r"),
    "hands": ("hand_l", "hand_r"),
    "legs": ("thigh_l", "thigh_r", "calf_l", "calf_r"),
    "feet": ("foot_l", "foot_r", "ball_l", "ball_r"),
}
CROTCH_RADIUS_M = 0.12


@dataclass(frozen=True)
class SurfaceError:
    """Distances in millimetres; ``pct_under_10mm`` is the area share of the ground-truth surface."""

    median_mm: float
    p90_mm: float
    hausdorff_mm: float
    pct_under_10mm: float
    visible_median_mm: float
    visible_p90_mm: float

    def as_dict(self) -> dict:
        return {k: float(v) for k, v in self.__dict__.items()}


def point_to_surface_mm(P: np.ndarray, V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Distance (mm) of every point to the triangle mesh ``(V, F)``."""
    d2, _, _ = igl.point_mesh_squared_distance(np.ascontiguousarray(P, dtype=np.float64),
                                               np.ascontiguousarray(V, dtype=np.float64),
                                               np.ascontiguousarray(F, dtype=np.int64))
    return 1000.0 * np.sqrt(np.maximum(d2, 0.0))


def visible_vertices(V: np.ndarray, F: np.ndarray, cameras, tolerance_m: float = 0.01) -> np.ndarray:
    """Vertices of ``(V, F)`` seen by at least one camera (z-buffer test with the capture renderer)."""
    from bodystudio.capture.render import render

    seen = np.zeros(len(V), bool)
    for cam in cameras:
        depth = render(V, F, cam).depth
        uv, z = cam.project_with_depth(V)
        px = np.round(np.nan_to_num(uv, nan=-1.0)).astype(int)
        inside = (px[:, 0] >= 0) & (px[:, 0] < cam.width) & (px[:, 1] >= 0) & (px[:, 1] < cam.height) & (z > 0)
        ids = np.flatnonzero(inside)
        d = depth[px[ids, 1], px[ids, 0]]
        seen[ids[(d > 0) & (z[ids] <= d + tolerance_m)]] = True
    return seen


def surface_error(V: np.ndarray, F: np.ndarray, V_gt: np.ndarray, F_gt: np.ndarray,
                  visible: np.ndarray | None = None) -> SurfaceError:
    """Two-way point-to-surface error of reconstruction ``(V, F)`` against ground truth ``(V_gt, F_gt)``.

    Median and p90 pool both directions; ``visible`` (bool per ground-truth vertex) restricts the
    ``visible_*`` figures to the ground-truth surface the cameras see, and reconstructed vertices near it.
    """
    to_gt = point_to_surface_mm(V, V_gt, F_gt)
    from_gt = point_to_surface_mm(V_gt, V, F)
    both = np.concatenate([to_gt, from_gt])
    area = vertex_areas(V_gt, F_gt)
    under = float(100.0 * area[from_gt < 10.0].sum() / max(area.sum(), 1e-300))
    if visible is None:
        vis = both
    else:
        # A reconstructed vertex counts as visible when its nearest ground-truth vertex is visible.
        from scipy.spatial import cKDTree

        _, nearest = cKDTree(V_gt).query(V)
        vis = np.concatenate([to_gt[visible[nearest]], from_gt[visible]])
    return SurfaceError(float(np.median(both)), float(np.percentile(both, 90)), float(both.max()), under,
                        float(np.median(vis)), float(np.percentile(vis, 90)))


def silhouette_iou(V: np.ndarray, F: np.ndarray, cameras, masks: dict) -> dict[str, float]:
    """Intersection over union of the reconstruction's silhouette with each view's mask."""
    out = {}
    for cam in cameras:
        mine = silhouette_mask(V, F, cam)
        ref = np.asarray(masks[cam.name]) > 0
        union = np.count_nonzero(mine | ref)
        out[cam.name] = float(np.count_nonzero(mine & ref) / union) if union else 1.0
    return out


def vertex_regions(body) -> np.ndarray:
    """Region name per template vertex (dominant skinning bone; the crotch around the hip-joint midpoint)."""
    names = body.skeleton.bone_names
    dominant = np.argmax(body.weights, axis=1)
    region = np.full(len(body.vertices), "other", dtype=object)
    for r, bones in REGIONS.items():
        ids = [names.index(b) for b in bones if b in names]
        region[np.isin(dominant, ids)] = r
    for b in ("index", "middle", "pinky", "ring", "thumb"):
        ids = [i for i, n in enumerate(names) if n.startswith(b)]
        region[np.isin(dominant, ids)] = "hands"
    skel = body.skeleton
    hips = 0.5 * (skel.heads[names.index("thigh_l")] + skel.heads[names.index("thigh_r")])
    crotch = (np.linalg.norm(body.vertices - hips, axis=1) < CROTCH_RADIUS_M) & (body.vertices[:, 1] < hips[1])
    crotch &= np.abs(body.vertices[:, 0] - hips[0]) < 0.06
    region[crotch] = "crotch"
    return region


def region_errors(V: np.ndarray, V_gt: np.ndarray, F_gt: np.ndarray, regions: np.ndarray) -> dict[str, dict]:
    """Median and p90 (mm) of reconstructed-vertex-to-ground-truth distances per region."""
    d = point_to_surface_mm(V, V_gt, F_gt)
    out = {}
    for r in sorted(set(regions.tolist())):
        sel = regions == r
        out[r] = {"median_mm": float(np.median(d[sel])), "p90_mm": float(np.percentile(d[sel], 90)),
                  "n_vertices": int(sel.sum())}
    return out


def joint_error_mm(joints: np.ndarray, joints_gt: np.ndarray) -> float:
    """Mean Euclidean joint error (mm) over joints finite in both."""
    ok = np.all(np.isfinite(joints), axis=1) & np.all(np.isfinite(joints_gt), axis=1)
    if not np.any(ok):
        return float("nan")
    return float(1000.0 * np.mean(np.linalg.norm(joints[ok] - joints_gt[ok], axis=1)))
