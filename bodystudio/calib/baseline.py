"""Baseline multi-camera calibration: chained pairwise ``cv2.stereoCalibrate`` along the spanning tree.

What a studio without bundle adjustment does: calibrate each camera alone, then each camera pair of
the co-visibility spanning tree with fixed intrinsics, and chain the relative poses from the root. The
errors of every link accumulate down the chain; the benchmark compares it with the bundle adjustment.
"""

from __future__ import annotations

import cv2
import numpy as np
import scipy.sparse
from scipy.sparse.csgraph import breadth_first_order, minimum_spanning_tree

from bodystudio.calib.board import CharucoBoardSpec, board_corners
from bodystudio.calib.calibrate import (
    CalibrationOptions,
    _rig_from,
    camera_graph_extrinsics,
    initial_intrinsics,
    world_from_root,
)
from bodystudio.calib.observations import CharucoObservations
from bodystudio.calib.world import rigid, rigid_inverse
from bodystudio.geometry.camera import CameraRig


def chained_stereo_calibration(obs: CharucoObservations, spec: CharucoBoardSpec,
                               options: CalibrationOptions | None = None) -> CameraRig:
    """Rig from per-camera ``calibrateCamera`` + chained ``stereoCalibrate`` (CALIB_FIX_INTRINSIC)."""
    options = options or CalibrationOptions()
    Ks, dists, view_poses = initial_intrinsics(obs, spec, options.distortion_terms)
    _, root, W = camera_graph_extrinsics(obs, view_poses)
    cost = np.where(W > 0, 1.0 / np.maximum(W, 1e-9), 0.0)
    tree = minimum_spanning_tree(scipy.sparse.csr_matrix(cost))
    order, parent = breadth_first_order(tree + tree.T, root, directed=False, return_predecessors=True)
    corners = board_corners(spec)
    views = obs.views()
    cam_from_root = np.zeros((obs.n_cameras, 4, 4))
    cam_from_root[root] = np.eye(4)
    for c in order[1:]:
        p = parent[c]
        obj, img_p, img_c = [], [], []
        for f in range(obs.n_frames):
            if (p, f) not in views or (c, f) not in views:
                continue
            ids_p, ids_c = obs.corner_id[views[(p, f)]], obs.corner_id[views[(c, f)]]
            common, ip, ic = np.intersect1d(ids_p, ids_c, return_indices=True)
            if len(common) < 6:
                continue
            obj.append(corners[common].astype(np.float32))
            img_p.append(obs.uv[views[(p, f)]][ip].astype(np.float32))
            img_c.append(obs.uv[views[(c, f)]][ic].astype(np.float32))
        size = obs.image_sizes[p]
        _, _, _, _, _, R, T, _, _ = cv2.stereoCalibrate(obj, img_p, img_c, Ks[p], dists[p], Ks[c], dists[c], size,
                                                        flags=cv2.CALIB_FIX_INTRINSIC)
        cam_from_root[c] = rigid(R, T) @ cam_from_root[p]
    # Floor board pose from the camera that sees the most of it.
    boards = np.full((obs.n_frames, 4, 4), np.nan)
    for f in range(obs.n_frames):
        seen = [(len(views[(c, f)]), c) for c in range(obs.n_cameras) if (c, f) in view_poses]
        if seen:
            c = max(seen)[1]
            boards[f] = rigid_inverse(cam_from_root[c]) @ view_poses[(c, f)]
    world_T_root, _ = world_from_root(obs, spec, boards, cam_from_root, options)
    root_T_world = rigid_inverse(world_T_root)
    intr = np.concatenate([Ks[:, 0, 0:1], Ks[:, 1, 1:2], Ks[:, 0, 2:3], Ks[:, 1, 2:3], dists], axis=1)
    return _rig_from(obs, intr, np.array([T @ root_T_world for T in cam_from_root]))
