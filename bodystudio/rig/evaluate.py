"""Rig evaluation against synthetic ground truth (issue 6 §9): joints, held-out-pose vertices, weights.

* ``joint_err_mm_mean/max``: transferred bind-pose joints vs the true joints of the scan's pose, over the
  body bones (:data:`EVAL_BONES`: no fingers; the finger joints are reported apart).
* ``pose_vertex_err_mm_mean``: avatar and ground truth both posed with :func:`held_out_poses` (poses no
  scan or test uses), mean vertex distance.
* ``weights_l1_mean``: mean over vertices of ``sum_j |w_j - w_j^true|`` (0 = equal, 2 = disjoint).
* ``pose_vertex_err_mm_region`` (only when a ``region`` mask of avatar vertices is given): the held-out-pose
  vertex error over that region alone, e.g. where the weight transfer had no compatible correspondence.
Avatar vertices are matched to ground-truth scan vertices by position in the bind pose (clean-up and the
UV atlas may reorder or split vertices).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from bodystudio.body import Pose
from bodystudio.errors import FileFormatError
from bodystudio.register.synthetic import ScanGroundTruth, random_pose, scan_pose
from bodystudio.rig.avatar import Avatar
from bodystudio.rig.export import check_rig_pair, rig_json_path

FINGER_PREFIXES = ("thumb", "index", "middle", "ring", "pinky")
N_HELD_OUT_RANDOM = 3


def eval_bones(bone_names: tuple[str, ...]) -> np.ndarray:
    """Indices of the body bones scored by the joint error (fingers and the floor-level Root excluded)."""
    return np.array([i for i, b in enumerate(bone_names) if not b.startswith(FINGER_PREFIXES) and b != "Root"])


def held_out_poses(bone_names: tuple[str, ...]) -> list[Pose]:
    """T-pose plus random poses from a seed stream that synthetic scans never use."""
    poses = [scan_pose("t", bone_names, 0)]
    poses += [random_pose(bone_names, np.random.default_rng([424242, k])) for k in range(N_HELD_OUT_RANDOM)]
    return poses


def match_vertices(avatar_V: np.ndarray, gt_scan_V: np.ndarray, max_mm: float = 1.0) -> np.ndarray:
    """For each avatar vertex its ground-truth scan vertex (bind pose positions must coincide)."""
    d, idx = cKDTree(gt_scan_V).query(avatar_V)
    if np.median(d) * 1000 > max_mm:
        raise FileFormatError(f"the avatar's vertices are {np.median(d) * 1000:.1f} mm (median) from the ground-truth "
                              "scan's; was it rigged from this scan (and not reshaped)?")
    return idx


def evaluate_rig(avatar: Avatar, gt: ScanGroundTruth, to_canonical: np.ndarray | None = None,
                 region: np.ndarray | None = None) -> dict:
    """Errors of a rigged avatar against the scan's ground truth (see the module docstring)."""
    R = np.eye(3) if to_canonical is None else np.asarray(to_canonical)
    gt_scan = gt.posed_vertices(gt.pose) @ R.T
    idx = match_vertices(avatar.vertices, gt_scan)
    bones = eval_bones(avatar.bone_names)
    fingers = np.array([i for i, b in enumerate(avatar.bone_names) if b.startswith(FINGER_PREFIXES)])
    gt_joints = gt.joints @ R.T
    jerr = 1000.0 * np.linalg.norm(avatar.heads - gt_joints, axis=1)
    errs = []
    for q in held_out_poses(avatar.bone_names):
        truth = gt.posed_vertices(Pose(q.rotations, gt.pose.translation)) @ R.T
        ours, _ = avatar.posed(Pose(q.rotations, avatar.bind_translation))
        errs.append(1000.0 * np.linalg.norm(ours - truth[idx], axis=1))
    W_true = np.asarray(gt.weights[idx].todense())
    l1 = np.abs(avatar.weights - W_true).sum(1).mean()
    out = {"joint_err_mm_mean": float(jerr[bones].mean()), "joint_err_mm_max": float(jerr[bones].max()),
           "joint_err_mm_mean_fingers": float(jerr[fingers].mean()) if len(fingers) else None,
           "pose_vertex_err_mm_mean": float(np.mean(errs)), "weights_l1_mean": float(l1),
           "fit_err_mm_median": avatar.metadata.get("fit_err_mm_median")}
    if region is not None:
        out["pose_vertex_err_mm_region"] = float(np.mean([e[region] for e in errs]))
    return out


def load_avatar(glb: str | Path) -> Avatar:
    """Read an avatar written by ``bodystudio rig`` (the .glb and its ``.rig.json`` beside it)."""
    import pygltflib as g

    glb = Path(glb)
    if not glb.is_file():
        raise FileFormatError(f"{glb}: no such avatar file")
    meta = check_rig_pair(glb)
    if meta is None:
        raise FileFormatError(f"{rig_json_path(glb)}: rig description not found; `bodystudio rig` writes it beside "
                              f"{glb.name}")
    try:
        gltf = g.GLTF2().load(str(glb))
        blob = gltf.binary_blob()
        prim = gltf.meshes[0].primitives[0]
        skin = gltf.skins[0]
    except Exception as exc:  # pygltflib raises many types for broken files
        raise FileFormatError(f"{glb}: not a skinned glTF binary ({type(exc).__name__}: {exc})") from None

    def read(i, dtype, width):
        acc = gltf.accessors[i]
        view = gltf.bufferViews[acc.bufferView]
        start = (view.byteOffset or 0) + (acc.byteOffset or 0)
        n = acc.count * width
        return np.frombuffer(blob, dtype=dtype, count=n, offset=start).reshape(acc.count, width)

    V = read(prim.attributes.POSITION, np.float32, 3).astype(np.float64)
    F = read(prim.indices, np.uint32, 1).reshape(-1, 3).astype(np.int64)
    J = read(prim.attributes.JOINTS_0, np.uint16, 4).astype(np.int64)
    Wt = read(prim.attributes.WEIGHTS_0, np.float32, 4).astype(np.float64)
    ibm = read(skin.inverseBindMatrices, np.float32, 16).reshape(-1, 4, 4).transpose(0, 2, 1).astype(np.float64)
    bind = np.linalg.inv(ibm)
    order = np.asarray(skin.joints)
    B = len(order)
    W = np.zeros((len(V), B))
    np.add.at(W, (np.repeat(np.arange(len(V)), 4), J.ravel()), Wt.ravel())
    colors = None
    if prim.attributes.COLOR_0 is not None:
        colors = read(prim.attributes.COLOR_0, np.uint8, 4)[:, :3].copy()
    if len(V) != meta.get("n_vertices", len(V)):
        raise FileFormatError(f"{rig_json_path(glb)}: describes {meta['n_vertices']} vertices but {glb} has "
                              f"{len(V)}; the two are from different runs, re-run `bodystudio rig`")
    if "vertex_source" in meta:
        # The UV atlas split vertices along its seams: score the avatar's own vertices, once each.
        source = np.asarray(meta["vertex_source"], dtype=np.int64)
        n = int(meta.get("n_avatar_vertices", source.max(initial=-1) + 1))
        if len(source) != len(V) or source.min(initial=0) < 0 or source.max(initial=-1) >= n:
            raise FileFormatError(f"{rig_json_path(glb)}: vertex_source does not fit {glb}; re-run `bodystudio rig`")
        first = np.full(n, -1)
        first[source[::-1]] = np.arange(len(source))[::-1]
        if np.any(first < 0):
            raise FileFormatError(f"{rig_json_path(glb)}: vertex_source misses avatar vertices; "
                                  "re-run `bodystudio rig`")
        V, W, F = V[first], W[first], source[F]
        colors = colors[first] if colors is not None else None
    U, _, Vt = np.linalg.svd(bind[:, :3, :3])
    return Avatar(V, F, colors, tuple(meta["bones"]), np.asarray(meta["parents"]), None, U @ Vt,
                  np.asarray(meta["rest_rotations"]), np.asarray(meta["bone_lengths_m"]), W,
                  np.asarray(meta["bind_translation_m"]),
                  {k: v for k, v in meta.items() if k in ("fit_err_mm_median", "seconds", "scan")},
                  loaded_heads=bind[:, :3, 3].copy())
