"""Scores of an arm capture against the synthetic ground truth (issue 11, acceptance of Arm-Muscle Capture).

``evaluate_arm_capture`` reports, over the arm vertices (``ArmTemplate.arm_mask``) of every frame:
``median_mm`` and ``p90_mm`` of the per-vertex distance to the truth; ``front_median_mm`` and
``back_median_mm`` split by what the sensor sees (a vertex is visible when it faces the sensor and is
not hidden behind the rest of the arm: z-buffer of the true arm mesh); ``bulge_err_mm``: the mean
over frames of the error in biceps peak height (largest distance of the biceps region from the
shoulder-elbow axis of the true joints); ``jitter_mm``: mean norm of the frame-to-frame acceleration
``v_{i+1} - 2 v_i + v_{i-1}`` minus the truth's; ``ms_per_frame`` from the capture's timings.

``surface_median_mm`` and ``surface_p90_mm``: the same arm vertices' point-to-surface distances, both ways
(estimate -> true mesh and truth -> estimated mesh, pooled; libigl's ``point_mesh_squared_distance``), as
``eval reconstruct`` scores Rapid Skin. The per-vertex figures also count a surface that is right but whose
vertices slid along it (the pose's placement along the limb, the truth's skin sliding), which no depth image
shows; the surface figures count only where the skin is.
"""

from __future__ import annotations

import numpy as np

from bodystudio.errors import InputError, SessionError
from bodystudio.geometry.mesh import vertex_normals
from bodystudio.muscle.arm import ArmPose, ArmTemplate, part_transforms


def biceps_region(template: ArmTemplate, length_range: tuple[float, float] = (0.3, 0.8),
                  min_front_cos: float = 0.5) -> np.ndarray:
    """Biceps vertices of the template: upper arm, the middle of its length, on its front (+z) side."""
    s, e, _ = template.joints
    axis = e - s
    t = (template.vertices - s) @ axis / (axis @ axis)
    N = vertex_normals(template.vertices, template.faces)
    front = N[:, 2] > min_front_cos
    return (template.part_weights[:, 1] > 0.5) & (t > length_range[0]) & (t < length_range[1]) & front


def biceps_peak_height(vertices: np.ndarray, region: np.ndarray, shoulder: np.ndarray, elbow: np.ndarray) -> float:
    """Biceps peak height (m): the largest distance of a biceps-region vertex from the shoulder-elbow axis."""
    a = (elbow - shoulder) / np.linalg.norm(elbow - shoulder)
    d = vertices[region] - shoulder
    radial = d - np.outer(d @ a, a)
    return float(np.linalg.norm(radial, axis=1).max())


def visible_vertices(vertices: np.ndarray, faces: np.ndarray, camera, tolerance_m: float = 0.01) -> np.ndarray:
    """Vertices (n,) bool the depth camera sees: facing it and not behind the mesh's own z-buffer."""
    from bodystudio.capture.render import render

    V = np.asarray(vertices, np.float64)
    N = vertex_normals(V, faces)
    facing = np.einsum("kd,kd->k", N, camera.center - V) > 0
    depth = render(V, faces, camera).depth.astype(np.float64)
    uv, z = camera.project_with_depth(V)
    c = np.round(uv[:, 0]).astype(int)
    r = np.round(uv[:, 1]).astype(int)
    inside = (r >= 0) & (r < camera.height) & (c >= 0) & (c < camera.width)
    seen = np.zeros(len(V), bool)
    zb = depth[r[inside], c[inside]]
    seen[inside] = (zb > 0) & (z[inside] <= zb + tolerance_m)
    return facing & seen


def _true_joints(template: ArmTemplate, pose: ArmPose) -> np.ndarray:
    T = part_transforms(template.joints, pose)
    return np.stack([T[k, :3, :3] @ template.joints[k] + T[k, :3, 3] for k in range(3)])


def score_arm_sequence(estimate: np.ndarray, truth: np.ndarray, template: ArmTemplate, visible: np.ndarray,
                       true_joints: np.ndarray, positions: list[int] | None = None) -> dict:
    """Error figures of an estimated sequence (T, n, 3) against the truth (T, n, 3), both in metres. ``positions``:
    the frames' recorded numbers when frames were skipped (rel7a); the jitter then counts only three consecutive
    recorded frames (an acceleration across a gap is no frame-to-frame jitter)."""
    X = np.asarray(estimate, np.float64)
    G = np.asarray(truth, np.float64)
    if X.shape != G.shape:
        raise InputError(f"capture has {X.shape[0]} frames of {X.shape[1]} vertices, truth {G.shape[0]} of "
                         f"{G.shape[1]}; evaluate the capture against its own session and template")
    arm = template.arm_mask
    err = np.linalg.norm(X - G, axis=2)[:, arm] * 1000.0
    vis = visible[:, arm]
    region = biceps_region(template)
    bulge = [abs(biceps_peak_height(x, region, j[0], j[1]) - biceps_peak_height(g, region, j[0], j[1]))
             for x, g, j in zip(X, G, true_joints, strict=True)]
    out = {"n_frames": int(len(X)), "median_mm": float(np.median(err)), "p90_mm": float(np.percentile(err, 90)),
           "front_median_mm": float(np.median(err[vis])) if vis.any() else float("nan"),
           "back_median_mm": float(np.median(err[~vis])) if (~vis).any() else float("nan"),
           "bulge_err_mm": 1000.0 * float(np.mean(bulge))}
    surf = np.concatenate([surface_distances(x, g, template.faces, arm) for x, g in zip(X, G, strict=True)]) * 1000.0
    out["surface_median_mm"] = float(np.median(surf))
    out["surface_p90_mm"] = float(np.percentile(surf, 90))
    triple = np.ones(max(len(X) - 2, 0), bool)
    if positions is not None and len(X) >= 3:
        p = np.asarray(positions)
        triple = (p[1:-1] - p[:-2] == 1) & (p[2:] - p[1:-1] == 1)
    if len(X) >= 3 and triple.any():
        acc = np.linalg.norm(X[2:] - 2 * X[1:-1] + X[:-2], axis=2)[triple][:, arm].mean()
        acc_true = np.linalg.norm(G[2:] - 2 * G[1:-1] + G[:-2], axis=2)[triple][:, arm].mean()
        out["jitter_mm"] = 1000.0 * float(acc - acc_true)
    else:
        out["jitter_mm"] = float("nan")
    return out


def surface_distances(estimate: np.ndarray, truth: np.ndarray, faces: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Point-to-surface distances both ways of the ``mask`` vertices of two meshes in one topology: each masked
    estimated vertex to the true surface, then each masked true vertex to the estimated surface (metres)."""
    import igl

    F = np.ascontiguousarray(faces, dtype=np.int64)
    X = np.ascontiguousarray(estimate, dtype=np.float64)
    G = np.ascontiguousarray(truth, dtype=np.float64)
    d_xg = igl.point_mesh_squared_distance(np.ascontiguousarray(X[mask]), G, F)[0]
    d_gx = igl.point_mesh_squared_distance(np.ascontiguousarray(G[mask]), X, F)[0]
    return np.sqrt(np.concatenate([d_xg, d_gx]))


def session_ground_truth(session, template: ArmTemplate, frame_ids: list) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Truth arm meshes (T, n, 3), visibility (T, n) and true joints (T, 3, 3) of an arm session's frames."""
    camera = session.kinect.depth
    G, vis, joints = [], [], []
    for fid in frame_ids:
        fr = session.frame(fid)
        mesh = fr.gt_arm_mesh
        pose = fr.gt_arm_pose
        if mesh is None or pose is None:
            raise SessionError(f"{session.path}: frame {fid} has no gt/arm mesh or pose; only synthetic arm "
                               "sessions (bodystudio synth arm) can be scored")
        V = np.asarray(mesh.vertices, np.float64)
        if len(V) != template.n_vertices:
            raise InputError(f"{session.path}: ground-truth arm has {len(V)} vertices, the template "
                             f"{template.n_vertices}; use the session's template resolution")
        G.append(V)
        vis.append(visible_vertices(V, template.faces, camera))
        joints.append(_true_joints(template, ArmPose.from_dict(pose, f"{session.path} gt arm pose {fid}")))
    return np.stack(G), np.stack(vis), np.stack(joints)


def evaluate_arm_capture(capture, session, template: ArmTemplate) -> dict:
    """Issue 11's figures for an :class:`~bodystudio.muscle.capture.ArmCapture` of a synthetic arm session.

    ``template`` is the arm template in the session's topology (its rest joints give the true joint
    positions through the ground-truth arm poses). Returns median_mm, p90_mm, surface_median_mm,
    surface_p90_mm, front_median_mm, back_median_mm, bulge_err_mm, jitter_mm, ms_per_frame (+ n_frames, mode).
    """
    if capture.template_key != template.key:
        raise InputError(f"capture is on template {capture.template_key}, the session's template is "
                         f"{template.key}; capture with the session's resolution and side")
    G, vis, joints = session_ground_truth(session, template, list(capture.frame_ids))
    skipped = list(getattr(capture, "skipped", None) or [])
    out = score_arm_sequence(capture.vertices, G, template, vis, joints,
                             None if getattr(capture, "frame_positions", None) is None else capture.positions)
    out["ms_per_frame"] = capture.ms_per_frame
    out["mode"] = capture.mode
    if skipped:  # rel7a: the figures are over the captured frames; the skipped ones are named
        out["n_skipped"] = len(skipped)
        out["skipped_frames"] = [int(s["frame"]) for s in skipped]
    return out


def nricp_amberg_anchor(template: ArmTemplate, depths: list[np.ndarray], camera, initial: np.ndarray,
                        depth_options=None, steps=None) -> tuple[np.ndarray, float]:
    """Outside anchor: trimesh's ``registration.nricp_amberg`` (Amberg et al. 2007) frame by frame.

    Same input as the pipeline (cleaned depth points, world frame); each frame starts from the previous
    result (``initial`` for the first: e.g. the capture's first-frame alignment), only the arm vertices
    carry data. Returns the per-frame vertices (T, n, 3) and milliseconds per frame.
    """
    import time

    import trimesh
    from trimesh.registration import nricp_amberg

    from bodystudio.muscle.depth import DepthCleanupOptions, clean_depth, depth_point_cloud

    o = depth_options or DepthCleanupOptions()
    X = np.asarray(initial, np.float64)
    out = []
    t0 = time.perf_counter()
    for d in depths:
        P, _ = depth_point_cloud(clean_depth(d, o), camera)
        # Only depth points near the arm: Amberg's closest-point search would otherwise pull towards the torso.
        from scipy.spatial import cKDTree

        near = cKDTree(X).query(P, distance_upper_bound=0.05)[0] < 0.05
        src = trimesh.Trimesh(X, template.faces, process=False)
        kw = {} if steps is None else {"steps": steps}
        X = np.asarray(nricp_amberg(src, trimesh.PointCloud(P[near]), distance_threshold=0.03, use_faces=False,
                                    use_vertex_normals=False, **kw), np.float64)
        out.append(X)
    ms = 1000.0 * (time.perf_counter() - t0) / max(len(depths), 1)
    return np.stack(out), ms
