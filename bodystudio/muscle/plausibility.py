"""Self-checks of an arm capture from its own data (no ground truth): does the fitted arm explain the depth?

Arm-Muscle Capture (Robertini et al. 2013) registers a template to one depth camera and fits the learned model
(Sec. 5-7); every step finds *some* minimum, so a session that is well-formed but wrong used to end with
exit 0 and a confident mesh: the right arm captured with the left-arm template (``--side``, or a real session
that records no side), a subject far outside the model's training range (the paper's Table 1 subjects that
the model extrapolates to), depth sampled too sparsely for the model's accuracy, depth in another unit (the
latter two were refused, with a message blaming the pose or the subject's distance). Before the capture
(:func:`session_checks`, a few frames) we measure the depth where the tracked arm's joints project against
their distance (:func:`depth_to_tracker_ratio`: another unit reads 10x, 1.1x, ...), and which tracked arm the
sensor faces (:func:`arm_geometry`: the capture's Kinect stands ~1 m in front of the arm it records, Sec. 8.1).
After the capture (:func:`capture_checks`), from the session's own depth and tracker joints:

* per region (upper arm, forearm; the parts of Eq. 12), the median distance of the fitted mesh's visible
  vertices to the depth points, and the share of them with a depth point within :data:`EXPLAINED_MM`
  (the depth residual of Sec. 7's data term, and the fraction of the arm the data explain);
* the fraction of the depth points around the arm that the fitted arm explains (points within
  :data:`EXPLAINED_MM` of it, among the points within :data:`NEAR_ARM_M` of the tracked arm bones);
* the body tracker's shoulder, elbow and wrist against the fitted ones (median over frames, mm);
* the depth sampling on the arm: the median pixel footprint (mm) where the arm is seen;
* the fitted (or given) shape parameters against the model's training range (Eq. 6 regresses them linearly:
  outside the range the model extrapolates), and a given sex against the training subjects' (an all-male model
  describes a man's arm); without ``--shape`` the sex the capture chose from the depth when the model knows women
  (``capture.sex_from_depth_energies``: both held-out depth energies, warned when they lie within the margin);
* the fitted rest skeleton's bones against the model's regressed ones (:func:`rest_bone_turn_deg`), recorded
  without a verdict: the women 512 / 516 / 518 captured with the all-male model (7-8.5 mm median) turn the forearm
  2.9-4.1 deg, the men 501-513 / 517 0.08-1.68, but the short man 514 (a good capture, 1.85 mm) 3.4 deg.

:func:`capture_verdict` turns the figures into a verdict (``warnings``, ``problems``, ``ok``);
:func:`check_before_capture` and :func:`check_after_capture` (called by ``capture_session_arm``) refuse a
problem unless ``--accept-implausible``, and ``muscle capture`` writes the verdict to ``plausibility.json``.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

#: A visible vertex with a depth point within this distance (mm) counts as explained by the depth data.
EXPLAINED_MM = 10.0
#: Depth points within this distance (m) of the tracked arm bones count as the arm's points.
NEAR_ARM_M = 0.06
#: The first frames whose tracked joints are compared with the depth readings there.
RATIO_FRAMES = 5

# Thresholds, from 2k Kinect v2 sessions of 12 frames (benchmarks/muscle_plausibility.py; docs/plausibility.md,
# "muscle capture"): clean = subjects 501, 620, 5, 7 and the out-of-range 611-614 at 1 m.
#: Depth at the tracked arm joints over their distance (median of the first frames' shoulder, elbow, wrist):
#: clean 0.937-0.979 (the joints sit inside the limb); depth 1.1x: 1.048, 0.9x: 0.857, 10x: 9.5, 0.2x: 0.19.
DEPTH_RATIO_CLEAN = (0.937, 0.979)
DEPTH_RATIO_RANGE = (0.88, 1.03)
#: The other tracked arm this much nearer to the sensor than the captured one: the session records the other
#: arm. Clean: the other arm 0.27-0.38 m farther; the right arm's session captured with --side left: 0.30 nearer.
SIDE_NEARER_M = 0.15
#: The depth's pixel footprint on the arm (mm) above which the capture warns: clean (1 m) 2.4-2.7, 1.2 m: 3.2.
SAMPLING_WARN_MM = 3.5
#: A region's visible skin this far (median, mm) from the depth points: the fit does not explain the depth.
#: Clean captures 2.1-9.1 mm (final meshes), the out-of-range subjects 2.5-7.9.
RESIDUAL_CLEAN_MM = 9.1
RESIDUAL_REFUSE_MM = 20.0
#: ... warned above this: the tracker 10 frames (0.33 s) out of sync with the depth: 13.0 / 11.2 mm (the fit
#: follows the tracker; its fitted shape ran to BMI 35, muscularity 1).
RESIDUAL_WARN_MM = 11.0
#: Share of the depth points around the tracked arm within EXPLAINED_MM of the fitted arm: clean >= 0.979.
POINTS_EXPLAINED_CLEAN = 0.979
POINTS_EXPLAINED_REFUSE = 0.8
#: ... warned below this (the tracker 10 frames out of sync: 0.912).
POINTS_EXPLAINED_WARN = 0.95
#: Fitted vs tracked shoulder / elbow / wrist (median over frames): clean 14-27 mm (the tracker's noise and its
#: joints' offsets inside the limb).
JOINT_RESIDUAL_CLEAN_MM = 27.0
JOINT_RESIDUAL_WARN_MM = 45.0
#: A fitted shape parameter outside the model's training range by more than this share of the range's span: the
#: model extrapolates (warning). Clean fits: <= 0.026 at 12 frames (620's fitted height 1.88 m against 1.87), 0.064
#: at 4 frames (501's muscularity 0.767 against 0.732); out-of-range subjects 613: 0.47 (height), 614: 1.0
#: (height) are flagged; 611 (0.049-0.095: BMI, muscularity, height) and 612 (BMI 32, fitted in range at 25.5)
#: are not. A shape the user gives (--shape, measured) is flagged as soon as it leaves the range.
SHAPE_OUTSIDE_WARN = 0.10
#: The subject's sex (given with --shape: 1 male, 0 female) this far from every training subject's: the model
#: describes the other sex's arm (its female column is zero unless women are in it: ``muscle model build --women K``,
#: ``muscle model extend``). The
#: benchmark's all-male model on 200 frames (docs/muscle.md, "Capture, seventeenth pass"): the men 501-517 (sex
#: 0.89-1.0) 1.65-2.85 mm median, the women 516 / 518 / 512 (sex 0.07 / 0.08 / 0.01) 6.8 / 7.1 / 8.5 mm (p90 15.7 /
#: 17.8 / 20.3).
SEX_OUTSIDE_WARN = 0.5


def region_of_vertices(part_weights: np.ndarray) -> dict[str, np.ndarray]:
    """The upper-arm and forearm vertices of the template (Eq. 12's parts, by largest weight)."""
    from bodystudio.muscle.arm import PARTS

    part = np.argmax(np.asarray(part_weights), axis=1)
    return {name: part == PARTS.index(name) for name in ("upperarm", "forearm")}


def segment_distances(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance of each point (n, 3) to the segment from ``a`` to ``b`` (3,)."""
    ab = b - a
    s = np.clip((points - a) @ ab / max(float(ab @ ab), 1e-12), 0.0, 1.0)
    return np.linalg.norm(points - (a + s[:, None] * ab), axis=1)


def fitted_world_joints(capture) -> np.ndarray | None:
    """The capture's shoulder, elbow and wrist per frame (T, 3, 3) in world metres: its rest joints carried by
    each frame's fitted pose (Eq. 12's skinning), then the Sec. 5.1 similarity. None without a model."""
    from bodystudio.muscle.nicp import apply_similarity
    from bodystudio.muscle.refine import posed_joints

    if capture.joints is None or not capture.poses or capture.poses[0] is None:
        return None
    return np.stack([apply_similarity(capture.similarity, posed_joints(capture.joints, p)) for p in capture.poses])


def frame_depth_agreement(vertices: np.ndarray, faces: np.ndarray, regions: dict, depth_m: np.ndarray, camera,
                          tracked: np.ndarray | None, options=None) -> dict:
    """One frame: per region the visible vertices' median distance to the depth points (``residual_mm``) and the
    share within :data:`EXPLAINED_MM` (``explained``); ``points_explained`` the share of the arm's depth points
    (near the tracked bones, else near the fit) within :data:`EXPLAINED_MM` of the fitted mesh; ``sampling_mm``
    the median pixel footprint at the arm's depth (the spacing of the depth samples on the arm)."""
    from bodystudio.muscle.depth import DepthCleanupOptions, clean_depth, depth_point_cloud
    from bodystudio.muscle.evaluate import visible_vertices

    options = options or DepthCleanupOptions()
    V = np.asarray(vertices, np.float64)
    out: dict = {}
    from bodystudio.errors import BodyStudioError

    try:
        P, _ = depth_point_cloud(clean_depth(depth_m, options), camera)
    except BodyStudioError:  # no usable depth in this frame: nothing explains the fit there
        P = np.zeros((0, 3))
    vis = visible_vertices(V, faces, camera)
    if len(P) == 0:
        for name, mask in regions.items():
            out[name] = {"residual_mm": float("inf"), "explained": 0.0, "vertices": int(np.count_nonzero(vis & mask))}
        out.update(points_explained=0.0, sampling_mm=float("nan"), arm_points=0)
        return out
    d_vertex, _ = cKDTree(P).query(V)
    for name, mask in regions.items():
        sel = vis & mask
        if not sel.any():
            out[name] = {"residual_mm": float("nan"), "explained": float("nan"), "vertices": 0}
            continue
        d = 1000.0 * d_vertex[sel]
        out[name] = {"residual_mm": float(np.median(d)), "explained": float(np.mean(d <= EXPLAINED_MM)),
                     "vertices": int(np.count_nonzero(sel))}
    if tracked is not None:
        near = np.minimum(segment_distances(P, tracked[0], tracked[1]), segment_distances(P, tracked[1], tracked[2]))
        arm_points = P[near <= NEAR_ARM_M]
    else:
        arm_points = P[cKDTree(V).query(P)[0] <= NEAR_ARM_M]
    if len(arm_points):
        d_point = _point_to_mesh_m(arm_points, V, faces)
        out["points_explained"] = float(np.mean(1000.0 * d_point <= EXPLAINED_MM))
        z = (arm_points - camera.center) @ camera.R[2]
        out["sampling_mm"] = float(1000.0 * np.median(z) / float(camera.K[0, 0]))
    else:
        out["points_explained"] = 0.0
        out["sampling_mm"] = float("nan")
    out["arm_points"] = int(len(arm_points))
    return out


def _point_to_mesh_m(points: np.ndarray, V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Distance (m) of each point to the triangle mesh (V, F)."""
    import igl

    d2 = igl.point_mesh_squared_distance(np.ascontiguousarray(points, np.float64),
                                         np.ascontiguousarray(V, np.float64), np.ascontiguousarray(F, np.int64))[0]
    return np.sqrt(d2)


def tracked_arm(joints: dict | None, side: str) -> np.ndarray | None:
    """The body tracker's shoulder, elbow and wrist (3, 3) of ``side`` in one frame's joints, or None (also when one
    of them is stored as null: not reported in that frame)."""
    from bodystudio.muscle.capture import TRACKER_JOINTS

    want = TRACKER_JOINTS[side]
    if joints is None or not all(n in joints["names"] for n in want):
        return None
    arm = np.asarray(joints["positions"], np.float64)[[joints["names"].index(n) for n in want]]
    return arm if np.all(np.isfinite(arm)) else None


def depth_to_tracker_ratio(depth_m: np.ndarray, camera, joints: np.ndarray, window_px: int = 2) -> np.ndarray:
    """Per joint, the depth reading where the tracked joint projects (median of the non-zero readings in a
    small window) over the joint's own distance along the optical axis; NaN where there is no reading.

    The tracker's joints sit inside the limb, ~3-4 cm behind the skin the sensor sees, so a consistent session
    reads a little under 1; depth stored in another unit (a wrong ``--depth-scale``) reads 10x, 0.2x, ..."""
    D = np.nan_to_num(np.asarray(depth_m, np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    J = np.asarray(joints, np.float64)
    z = (J - camera.center) @ camera.R[2]
    uv = np.round(camera.project(J)).astype(np.int64)
    out = np.full(len(J), np.nan)
    h, w = D.shape
    for k, (u, v) in enumerate(uv):
        if z[k] <= 0 or not (0 <= u < w and 0 <= v < h):
            continue
        patch = D[max(v - window_px, 0):v + window_px + 1, max(u - window_px, 0):u + window_px + 1]
        patch = patch[patch > 0]
        if patch.size:
            out[k] = float(np.median(patch)) / float(z[k])
    return out


def arm_geometry(joints: np.ndarray, camera) -> tuple[float, float]:
    """Distance (m) from the depth camera to the middle of the tracked upper arm, and its angle (degrees) off
    the optical axis: the capture's sensor is placed ~1 m in front of the arm it captures (Sec. 8.1)."""
    mid = 0.5 * (np.asarray(joints[0], float) + np.asarray(joints[1], float)) - camera.center
    distance = float(np.linalg.norm(mid))
    return distance, float(np.degrees(np.arccos(np.clip(mid @ camera.R[2] / max(distance, 1e-12), -1.0, 1.0))))


def session_checks(session, frame_ids: list, side: str) -> dict:
    """The checks of the session's inputs before the capture: the depth readings against the tracked arm's
    distance (:func:`depth_to_tracker_ratio`, median over the first frames' joints), and which arm the
    sensor faces (:func:`arm_geometry` of both tracked arms on the first frame). Empty without tracker joints."""
    if session.kinect is None:
        return {}
    from bodystudio.capture.subject import follow_subject, frame_bodies
    from bodystudio.errors import BodyStudioError

    camera = session.kinect.depth
    ratios, geometry = [], {}
    frames = [session.frame(fid) for fid in frame_ids[:RATIO_FRAMES]]

    def readable(read):  # a bad frame is the capture's to skip and name (rel7a), not these checks' to refuse
        try:
            return read()
        except BodyStudioError:
            return None

    # the capture's person (the first frame's, followed: capture.session_arm_tracker)
    bodies = [readable(lambda f=f: frame_bodies(f)) or [] for f in frames]
    for frame, joints in zip(frames, follow_subject(bodies), strict=True):
        mine = tracked_arm(joints, side)
        depth = None if mine is None else readable(lambda f=frame: f.kinect_depth_m)
        if mine is None or depth is None or depth.shape != (camera.height, camera.width):
            continue
        ratios.extend(depth_to_tracker_ratio(depth, camera, mine).tolist())
        if not geometry:
            for s in ("left", "right"):
                J = tracked_arm(joints, s)
                if J is not None:
                    geometry[s] = arm_geometry(J, camera)
    out: dict = {}
    ratios = [r for r in ratios if np.isfinite(r)]
    if ratios:
        out["depth_to_tracker_ratio"] = float(np.median(ratios))
    elif geometry:
        out["depth_to_tracker_ratio"] = float("nan")  # tracked, but no depth reading where the arm is
    fx = float(camera.K[0, 0])
    out["sampling_at_1m_mm"] = 1000.0 / fx
    if geometry:
        out["arm_distance_m"] = {s: g[0] for s, g in geometry.items()}
        out["arm_off_axis_deg"] = {s: g[1] for s, g in geometry.items()}
        if side in geometry:
            out["sampling_at_arm_mm"] = 1000.0 * geometry[side][0] / fx
    return out


def capture_checks(capture, session, template, model=None, max_frames: int = 40, shape_given: bool = False) -> dict:
    """The checks of a finished capture against its session's depth and tracker (up to ``max_frames`` evenly
    spaced frames): per region the visible vertices' depth residual and explained share, the arm's depth points
    explained, the sampling, the tracker-vs-fit joint residual (median over frames, mm), and for the model's
    fit the same depth figures of the model-only meshes (Sec. 6.2, before the refinement) and the shape against
    the model's training range."""
    camera = session.kinect.depth
    regions = region_of_vertices(template.part_weights)
    n = capture.n_frames
    picks = sorted({int(round(x)) for x in np.linspace(0, n - 1, min(n, max_frames))})
    fitted = fitted_world_joints(capture)
    model_meshes = capture.stages.get("model") if capture.stages else None
    from bodystudio.capture.subject import follow_subject, frame_bodies

    rows, model_rows, joint_mm = [], [], []
    frames = [session.frame(capture.frame_ids[k]) for k in picks]
    # the capture's person (the first frame's, followed: capture.session_arm_tracker)
    subject = follow_subject(frame_bodies(f) for f in frames)
    for k, frame, joints in zip(picks, frames, subject, strict=True):
        tracked = tracked_arm(joints, template.side)
        depth = frame.kinect_depth_m
        rows.append(frame_depth_agreement(capture.vertices[k], capture.faces, regions, depth, camera, tracked))
        if model_meshes is not None and capture.mode == "full":
            model_rows.append(frame_depth_agreement(model_meshes[k], capture.faces, regions, depth, camera, tracked))
        if fitted is not None and tracked is not None:
            joint_mm.append(1000.0 * np.linalg.norm(fitted[k] - tracked, axis=1))
    out: dict = {"frames_checked": len(picks), "mode": capture.mode, **_median_figures(rows)}
    if model_rows:
        out["model_only"] = {r: v for r, v in _median_figures(model_rows).items() if r in regions}
    if joint_mm:
        out["tracker_joint_residual_mm"] = dict(zip(("shoulder", "elbow", "wrist"),
                                                    np.median(joint_mm, axis=0).round(2).tolist(), strict=True))
    turn = rest_bone_turn_deg(capture.joints, getattr(capture, "regressed_joints", None))
    if turn is not None:
        out["rest_bone_turn_deg"] = turn
    if model is not None and capture.shape is not None and getattr(model, "subjects", None):
        out["shape"] = shape_extrapolation(capture.shape, model)
        out["shape_given"] = bool(shape_given)
    if getattr(capture, "sex_fit", None) is not None:
        out["sex_fit"] = capture.sex_fit
    return out


def _median_figures(rows: list[dict]) -> dict:
    out: dict = {}
    for region in ("upperarm", "forearm"):
        res = [r[region]["residual_mm"] for r in rows if np.isfinite(r[region]["residual_mm"])]
        exp = [r[region]["explained"] for r in rows if np.isfinite(r[region]["explained"])]
        out[region] = {"residual_mm": float(np.median(res)) if res else float("inf"),
                       "explained": float(np.median(exp)) if exp else 0.0}
    for key in ("points_explained", "sampling_mm"):
        vals = [r[key] for r in rows if np.isfinite(r[key])]
        out[key] = float(np.median(vals)) if vals else float("nan")
    return out


def rest_bone_turn_deg(fitted, regressed) -> dict | None:
    """Angle (degrees) between the fitted rest skeleton's upper arm and forearm (shoulder, elbow, wrist (3, 3)) and
    the model's regressed ones for the subject's shape (the rest joints the model's Eq. 6 puts the arm on); None
    without both."""
    if fitted is None or regressed is None:
        return None
    F, R = np.diff(np.asarray(fitted, np.float64), axis=0), np.diff(np.asarray(regressed, np.float64), axis=0)
    cos = np.sum(F * R, axis=1) / np.maximum(np.linalg.norm(F, axis=1) * np.linalg.norm(R, axis=1), 1e-12)
    return dict(zip(("upperarm", "forearm"), np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))).round(3).tolist(),
                    strict=True))


def shape_extrapolation(shape, model) -> dict:
    """Per shape parameter of Eq. 6 (BMI, muscularity, height, arm length): the value, the model's training
    range, and how far outside it the value lies as a share of the range's span (0 inside)."""
    from bodystudio.muscle.model import SHAPE_NAMES

    span = model.shape_range()
    out = {}
    for name in SHAPE_NAMES:
        lo, hi = span[name]
        value = float(getattr(shape, name))
        width = max(hi - lo, 1e-9)
        out[name] = {"value": value, "range": [lo, hi], "outside": float(max(lo - value, value - hi, 0.0) / width)}
    rows = getattr(model, "shape_rows", None)
    if rows is not None and np.ndim(rows) == 2 and np.shape(rows)[1] > len(SHAPE_NAMES):
        sexes = np.asarray(rows, np.float64)[:, len(SHAPE_NAMES)]
        value = float(getattr(shape, "sex", 1.0))
        # sex spans 0 (female) to 1 (male): the distance to the nearest training subject's, not a share of a span
        out["sex"] = {"value": value, "range": [float(sexes.min()), float(sexes.max())],
                      "outside": float(np.min(np.abs(sexes - value)))}
    return out


def capture_verdict(figures: dict, side: str, session_path=None, near_m: float = 0.5, far_m: float = 1.3) -> dict:
    """The verdict on a capture's figures (:func:`session_checks` merged with :func:`capture_checks`):
    ``warnings`` and ``problems`` (one sentence each naming the input and the fix), ``ok`` (no problem) and the
    ``thresholds`` used. ``near_m``, ``far_m``: the capture's depth window (Sec. 4's segmentation)."""
    where = f"{session_path}/" if session_path is not None else ""
    other = "right" if side == "left" else "left"
    warnings, problems = [], []
    ratio = figures.get("depth_to_tracker_ratio")
    distance = figures.get("arm_distance_m", {})
    # no reading at all where the arm is (an empty depth map) is left to the capture's own "no arm in range"
    if ratio is not None and np.isfinite(ratio) and not (DEPTH_RATIO_RANGE[0] <= ratio <= DEPTH_RATIO_RANGE[1]):
        seen = f"the depth where the tracked {side} arm's joints are reads {ratio:.3g}x their distance"
        if side in distance and not near_m < ratio * distance[side] < far_m:
            seen += f", {ratio * distance[side]:.2f} m: no arm in range of the {near_m:g}-{far_m:g} m depth window"
        problems.append(f"{seen} (a consistent session: {DEPTH_RATIO_CLEAN[0]:.2f}-{DEPTH_RATIO_CLEAN[1]:.2f}): "
                        f"the depth is in another unit or the tracker belongs to another recording; check the "
                        f"unit of {where}kinect/depth (re-import with the right --depth-scale) and "
                        f"{where}kinect/calibration.json")
    off_axis = figures.get("arm_off_axis_deg", {})
    if side in distance and other in distance and distance[other] <= distance[side] - SIDE_NEARER_M:
        problems.append(f"the Kinect faces the {other} arm ({distance[other]:.2f} m away, {off_axis[other]:.0f} deg "
                        f"off its axis) while the capture is of the {side} arm ({distance[side]:.2f} m, "
                        f"{off_axis[side]:.0f} deg): the session records the {other} arm; capture it with "
                        f"--side {other} and a model built with --side {other}")
    elif side in distance and distance[side] > far_m:
        problems.append(f"the {side} arm is {distance[side]:.2f} m from the Kinect, beyond the capture's depth "
                        f"window (up to {far_m:g} m); there the depth samples the arm every "
                        f"{figures.get('sampling_at_arm_mm', float('nan')):.1f} mm against "
                        f"{figures.get('sampling_at_1m_mm', float('nan')):.1f} mm at 1 m, too sparse for the "
                        "model's few-millimetre accuracy: record with the sensor about 1 m from the arm")
    sampling = figures.get("sampling_mm")
    if sampling is not None and np.isfinite(sampling) and sampling > SAMPLING_WARN_MM:
        warnings.append(f"the depth samples the arm every {sampling:.1f} mm (at 1 m: "
                        f"{figures.get('sampling_at_1m_mm', float('nan')):.1f} mm); the capture's accuracy was "
                        "measured at about 1 m: expect larger errors, or record closer")
    # the depth-residual thresholds were measured on full captures (refined surface); the ablations (model only,
    # NICP only) keep their figures without a verdict on them
    judged = figures.get("mode", "full") == "full"
    for region in ("upperarm", "forearm") if judged else ():
        r = figures.get(region)
        if r and r["residual_mm"] > RESIDUAL_REFUSE_MM:
            problems.append(f"the fitted {region} does not explain the depth (its visible skin is "
                            f"{r['residual_mm']:.0f} mm from the depth points, median; consistent captures "
                            f"<= {RESIDUAL_CLEAN_MM:g} mm): check {where}kinect/calibration.json and the arm side")
    explained = figures.get("points_explained") if judged else None
    if explained is not None and np.isfinite(explained) and explained < POINTS_EXPLAINED_REFUSE:
        problems.append(f"the fitted arm explains {explained:.0%} of the depth points around the tracked arm "
                        f"(consistent captures >= {POINTS_EXPLAINED_CLEAN:.0%}): check {where}kinect/calibration.json "
                        "and the arm side")
    residuals = {r: figures[r]["residual_mm"] for r in ("upperarm", "forearm") if judged and figures.get(r)}
    loose = [r for r, v in residuals.items() if RESIDUAL_WARN_MM < v <= RESIDUAL_REFUSE_MM]
    if not problems and (loose or (explained is not None and np.isfinite(explained)
                                   and POINTS_EXPLAINED_REFUSE <= explained < POINTS_EXPLAINED_WARN)):
        warnings.append(f"the fitted arm explains the depth less well than a consistent capture (visible skin "
                        f"{', '.join(f'{r} {v:.1f} mm' for r, v in residuals.items())} from the depth points, "
                        f"{explained:.0%} of the arm's points explained; consistent <= {RESIDUAL_CLEAN_MM:g} mm, "
                        f">= {POINTS_EXPLAINED_CLEAN:.0%}): the body tracker may be out of sync with the depth "
                        f"({where}kinect/joints) or the calibration off; the fitted shape and poses are suspect")
    joints = figures.get("tracker_joint_residual_mm")
    if joints and max(joints.values()) > JOINT_RESIDUAL_WARN_MM:
        worst = max(joints, key=joints.get)
        warnings.append(f"the fitted {worst} is {joints[worst]:.0f} mm from the body tracker's (median over frames; "
                        f"consistent captures <= {JOINT_RESIDUAL_CLEAN_MM:g} mm): the tracker or the fit is off")
    shape = figures.get("shape")
    if shape:
        margin = 0.0 if figures.get("shape_given") else SHAPE_OUTSIDE_WARN
        outside = [n for n, s in shape.items() if n != "sex" and s["outside"] > margin]
        if outside:
            listing = "; ".join(f"{n} {shape[n]['value']:.3g} (trained on {shape[n]['range'][0]:.3g}-"
                                f"{shape[n]['range'][1]:.3g})" for n in outside)
            warnings.append(f"the subject lies outside the model's training range, so the model extrapolates "
                            f"({listing}): its muscle shapes are less certain; extend the model with such "
                            "subjects (muscle model extend)")
        sex = shape.get("sex")
        if sex and sex["outside"] > SEX_OUTSIDE_WARN:
            given, trained, missing = ("female", "men", "women") if sex["value"] < 0.5 else ("male", "women", "men")
            lo, hi = sex["range"]
            span = f"{lo:.2g}" if lo == hi else f"{lo:.2g}-{hi:.2g}"
            fix = "build a model that knows women (muscle model build --women 5) and capture again" \
                if missing == "women" else "capture with a model that knows men (muscle model build)"
            warnings.append(f"the subject is {given} (sex {sex['value']:.2g}) and the model was trained on {trained} "
                            f"only (sex {span}): its rest arm, joints and muscle "
                            f"shapes are a {trained[:-2]}an's, and such captures were measured 3-4x less accurate "
                            f"(7 mm median against 2 mm); {fix} before relying on this capture")
        elif sex and not figures.get("shape_given") and sex["range"][0] == sex["range"][1]:
            # nothing in the depth tells a woman's capture from a man's (docs/muscle.md, seventeenth pass): with
            # no sex given, the capture assumes the only one the model knows, and says so
            trained, other = ("men", "woman") if sex["range"][0] >= 0.5 else ("women", "man")
            warnings.append(f"the subject's sex was not given (--shape): assumed like every training subject of the "
                            f"model ({trained} only); a {other}'s capture with this model was measured 3-4x less "
                            f"accurate (7 mm median against 2 mm); give --shape with the subject's sex, and for a "
                            f"{other} a model that knows {other.replace('an', 'en')} ("
                            + ("muscle model build --women 5)" if other == "woman" else "muscle model build)"))
        elif sex and not figures.get("shape_given") and figures.get("sex_fit"):
            # the sex chosen from the depth (capture.sex_from_depth_energies): recorded; warned when the two fits'
            # held-out depth energies lie within the margin (docs/muscle.md, "The sex from the depth")
            fit = figures["sex_fit"]
            if fit.get("ambiguous"):
                e = fit["energy_mm"]
                warnings.append(f"the subject's sex was not given (--shape) and the depth hardly tells it: captured "
                                f"as a man the held-out depth energy is {e['male']:.3f} mm, as a woman "
                                f"{e['female']:.3f} mm (within {fit['margin_mm']:g} mm); taken as {fit['chosen']}, "
                                f"and a capture of the wrong sex was measured 2-3x less accurate; give --shape with "
                                f"the subject's sex")
        elif sex and not figures.get("shape_given"):
            # a model of both sexes (muscle model build --women K) gives a woman's arm only when told: the capture
            # fits no sex (docs/muscle.md, "Women in the capture": 516 without --shape 7.38 mm, with sex=female 2.83)
            taken = "male" if sex["value"] >= 0.5 else "female"
            warnings.append(f"the subject's sex was not given (--shape): taken as {taken} (sex {sex['value']:.2g}); "
                            f"the model knows both sexes but gives a woman's arm only when told, and a woman captured "
                            f"so was measured 2.6x less accurate (7.4 mm median against 2.8 with sex=female); give "
                            f"--shape with the subject's sex")
    return {"thresholds": {"depth_ratio_range": list(DEPTH_RATIO_RANGE), "side_nearer_m": SIDE_NEARER_M,
                           "far_m": far_m, "sampling_warn_mm": SAMPLING_WARN_MM,
                           "residual_refuse_mm": RESIDUAL_REFUSE_MM, "points_explained_refuse": POINTS_EXPLAINED_REFUSE,
                           "residual_warn_mm": RESIDUAL_WARN_MM, "points_explained_warn": POINTS_EXPLAINED_WARN,
                           "joint_residual_warn_mm": JOINT_RESIDUAL_WARN_MM, "shape_outside_warn": SHAPE_OUTSIDE_WARN,
                           "sex_outside_warn": SEX_OUTSIDE_WARN},
            "figures": _json_safe(figures), "warnings": warnings, "problems": problems, "ok": not problems}


def _json_safe(value):
    """``value`` with every non-finite float as None (strict JSON)."""
    if isinstance(value, dict):
        return {k: _json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(v) for v in value]
    if isinstance(value, (float, np.floating)):
        return float(value) if np.isfinite(value) else None
    return value


def _refuse(verdict: dict, session_path, accept_implausible: bool) -> None:
    from bodystudio.errors import ImplausibleResultError

    if verdict["problems"] and not accept_implausible:
        raise ImplausibleResultError(f"{session_path}: arm capture not written, {verdict['problems'][0]}; "
                                     "or pass --accept-implausible")


def check_before_capture(session, frame_ids: list, side: str, accept_implausible: bool = False) -> dict:
    """:func:`session_checks` and their verdict; raises ImplausibleResultError (one line: the input and the fix)
    on a problem unless ``accept_implausible``. Cheap (a few frames), so a wrong session is refused before the
    capture's minutes."""
    checks = session_checks(session, list(frame_ids), side)
    _refuse(capture_verdict(checks, side, session.path), session.path, accept_implausible)
    return checks


def check_after_capture(capture, session, template, model, before: dict, accept_implausible: bool = False,
                        shape_given: bool = False) -> dict:
    """:func:`capture_checks` with ``before`` (:func:`check_before_capture`'s figures): the capture's verdict,
    refused (ImplausibleResultError) on a problem unless ``accept_implausible``; warnings are logged at INFO
    (the CLI prints them)."""
    import logging

    verdict = capture_verdict({**before, **capture_checks(capture, session, template, model,
                                                          shape_given=shape_given)}, template.side, session.path)
    _refuse(verdict, session.path, accept_implausible)
    for line in verdict["warnings"] + verdict["problems"]:
        logging.getLogger(__name__).info("%s: %s", session.path, line)
    return verdict
