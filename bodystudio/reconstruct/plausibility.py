"""Self-checks of a reconstruction from its own data (no ground truth): does every camera agree with the fit?

Rapid Skin (§III) deforms one template to all views at once, so a view whose data are wrong in a way a
studio produces (a camera bumped after calibration, one camera's masks swapped with another's, the Kinect
depth in the wrong unit) does not stop the solve: it pulls the fit into a compromise, or is silently ignored,
and the run used to end with exit 0. After the fit we measure how well the result explains each input:

* per camera, the intersection over union of the fitted mesh's silhouette with that camera's mask (the data
  term of Eq. 7 as an image comparison): a consistent rig reaches >= 0.93 in every view on the synthetic
  benchmark sessions, while a bumped or swapped camera stays far below (figures in docs/reconstruct.md);
* with depth constraints, the fraction of the fitted mesh's pixels in the depth camera that hold a usable
  depth reading, and the median gap between the measured and the rendered depth there: depth stored in
  another unit leaves no reading in range (or all of them a metre off) and adds no constraint at all.

:func:`frame_plausibility` scores one frame, :func:`run_plausibility` aggregates a run (per camera, the median
over frames) into a verdict with the cameras or inputs to blame; ``reconstruct`` refuses an implausible run
unless ``--accept-implausible``.
"""

from __future__ import annotations

import numpy as np

from bodystudio.capture.render import render

#: A view whose fitted silhouette overlaps its mask less than this (IoU, median over the run's frames) is
#: named in a warning. Clean synthetic sessions (10 cameras, 640x480: >= 0.98; 6 cameras, 320x240: >= 0.95); a
#: camera bumped by 5 cm / 3 deg: 0.23 in it and <= 0.62 in every view (the fit is pulled off), masks
#: swapped between two cameras: 0.48-0.71 (docs/reconstruct.md).
IOU_WARN = 0.85
#: Below this the run is refused: the fit cannot be trusted, that camera disagrees with the others.
IOU_REFUSE = 0.75
#: Silhouette coherence (:func:`silhouette_coherence`) below this in a view names it in a warning; clean
#: sessions: 1.00 in every view; a camera bumped 5 cm / 3 deg: 0.48-0.58 in it and in the camera opposite
#: it (the two cannot be told apart from silhouettes), >= 0.8 elsewhere; swapped masks: 0.79-0.93 everywhere.
COHERENCE_WARN = 0.9
#: ... and below this the run is refused.
COHERENCE_REFUSE = 0.8
#: A camera is named as the one that disagrees when its coherence is also this far below the views' median
#: (a bumped camera and the one opposite it: 0.51 and 0.56 against a median of 0.83; swapped masks lower
#: every view alike, 0.78-0.89, and no camera is named).
COHERENCE_OUTLIER = 0.15
#: With depth constraints: the share of the fitted mesh's depth-camera pixels that must hold a usable depth
#: reading (clean: >= 0.9; depth 10x off (a wrong --depth-scale): 0.0).
DEPTH_COVERAGE_REFUSE = 0.5
#: ... and the largest median gap (metres) between measured and rendered depth there (clean: < 0.01 m).
DEPTH_GAP_REFUSE_M = 0.05
#: The silhouettes' tolerance band (pixels at 640 px image width, scaled with it): realistic masks (a
#: segmentation's 1-3 px edge jitter, merged floor shadows, small holes, a limb lost in one view) lower the IoU of
#: a good fit (combined, 640x480: 0.67-0.75 with a 2.2 -> 8-9 mm fit; docs/plausibility.md, "reconstruct under
#: mask noise") although the fit lies inside every mask up to a few pixels; a moved camera or swapped masks do not.
TOLERANCE_PX_AT_640 = 3.0
#: A view whose IoU is low is still trusted when this share of the fit's silhouette lies within the band of its
#: mask (clean and noisy masks, 640x480: >= 0.994; a moved camera or swapped masks: 0.83-0.90 in the worst view)...
TOLERANT_PRECISION_TRUST = 0.95
#: ... and this share of the mask within the band of the fit's silhouette (clean: 1.00; noisy: >= 0.80, a shadow
#: the size of the feet 0.84; a moved camera or swapped masks: 0.31-0.54 in the worst view).
TOLERANT_RECALL_TRUST = 0.65
#: The depth range (metres) the depth constraints accept (:func:`bodystudio.reconstruct.depth.depth_observation`).
DEPTH_RANGE_M = (0.4, 5.0)


#: The limb joints the pose initialisation rotates each limb segment onto (Eq. 11); untracked, a segment keeps its
#: parent's transform (the template's rest limb).
LIMB_JOINTS = ("ElbowLeft", "WristLeft", "ElbowRight", "WristRight", "KneeLeft", "AnkleLeft", "KneeRight",
               "AnkleRight")
#: A frame with at least this many of them untracked is warned about: measured on a 4-camera 160x120 session of
#: subject 7 (Kinect v1, silhouettes + depth), a frame with all eight untracked fitted p90 70.7 mm, Hausdorff 289 mm
#: (its neighbours 15.4 / 15.7 mm) with every IoU >= 0.9, the other figures of this check blind to it; one arm's
#: two joints (and its hand's) untracked: the run 5.1 / 15.9 mm against 4.7 / 13.9 mm clean.
LIMB_UNTRACKED_WARN = 4
#: A frame whose fitted pose puts a limb joint further than this (mm) from the tracker's (:func:`tracker_joint_
#: residual`) is counted as far. Good runs (8 sessions, 10 cameras 640x480, per frame, --tracking and --accurate:
#: 144 frames; adv4's tiny session per frame): <= 58 mm in every frame (the tracker's noise, which the refinement
#: corrects); --tracking on 4 cameras at 160x120 (adv4's tiny session): 315-321 mm in both tracked frames, the
#: arms lost inside the visual hull (p90 77-78 mm against 14-15 mm per frame) with every silhouette IoU >= 0.86;
#: held out (seeds 2 and 3, subject 23): 176-227 mm, p90 65-91 mm (docs/reconstruct.md).
TRACKER_JOINT_FAR_MM = 150.0
#: The run is refused when at least this share of its tracked frames (``--tracking``; at least one) is far: the
#: tracking lost the limbs there (4 cameras at 320x240, 4 frames spread over a walk: one tracked frame of three at
#: 246 / 272 mm with p90 97.5 / 34.2 mm, Hausdorff 281 / 329 mm; its neighbours <= 123 mm). Fewer (one frame in a long
#: run) or far frames the joints initialised are warned about, naming the worst frame.
TRACKING_LOST_REFUSE_SHARE = 0.1


def untracked_limb_joints(joints: np.ndarray | None) -> int | None:
    """How many of :data:`LIMB_JOINTS` the frame's Kinect v2 joints ``(25, 3)`` leave NaN (None without joints)."""
    from bodystudio.body.kinect import kinect_joint_names

    if joints is None:
        return None
    names = kinect_joint_names("v2")
    J = np.asarray(joints, np.float64)
    return int(sum(not np.all(np.isfinite(J[names.index(n)])) for n in LIMB_JOINTS))


def tracker_joint_residual(fitted_joints: np.ndarray | None, tracker_joints: np.ndarray | None) -> dict | None:
    """How far the fitted pose's limb joints lie from the frame's tracker joints, both Kinect v2 ``(25, 3)``
    (:data:`LIMB_JOINTS` finite in both): ``max_mm``, ``median_mm`` and the ``joint`` of the largest (None when
    none is in both). The per-frame path starts every frame on the tracker's joints and the refinement corrects
    them by the tracker's own error; a tracked frame (``--tracking``) uses them only to (re-)initialise, so a
    limb the tracking lost inside the visual hull shows here and nowhere else in the silhouettes' figures."""
    from bodystudio.body.kinect import kinect_joint_names

    if fitted_joints is None or tracker_joints is None:
        return None
    names = kinect_joint_names("v2")
    rows = [names.index(n) for n in LIMB_JOINTS]
    A = np.asarray(fitted_joints, np.float64)[rows]
    B = np.asarray(tracker_joints, np.float64)[rows]
    ok = np.all(np.isfinite(A), axis=1) & np.all(np.isfinite(B), axis=1)
    if not ok.any():
        return None
    d = 1000.0 * np.linalg.norm(A[ok] - B[ok], axis=1)
    worst = int(np.argmax(d))
    return {"max_mm": float(d[worst]), "median_mm": float(np.median(d)),
            "joint": [n for n, k in zip(LIMB_JOINTS, ok, strict=True) if k][worst]}


def fitted_silhouettes(V: np.ndarray, F: np.ndarray, cameras) -> dict[str, np.ndarray]:
    """Per camera, the fitted mesh's silhouette (bool image): the constraint matching's rasteriser (render()'s
    depth and ids cost ~4x more)."""
    from bodystudio.reconstruct.silhouette import _rasterize_mask

    F = np.ascontiguousarray(F, dtype=np.int64)
    V = np.asarray(V, dtype=np.float64)
    return {cam.name: _rasterize_mask(np.ascontiguousarray(cam.project(V)), F, cam.width, cam.height,
                                      np.zeros((cam.height, cam.width), np.bool_)) for cam in cameras}


def silhouette_agreement(V: np.ndarray, F: np.ndarray, cameras, masks: dict,
                         fitted: dict | None = None) -> dict[str, float]:
    """Per camera, the IoU of the fitted mesh's silhouette with the camera's mask: how well the fit explains
    the silhouette data (Eq. 7 of Rapid Skin) of each view. ``fitted``: :func:`fitted_silhouettes` when already
    drawn."""
    fitted = fitted_silhouettes(V, F, cameras) if fitted is None else fitted
    out = {}
    for cam in cameras:
        mine = fitted[cam.name]
        ref = np.asarray(masks[cam.name]) > 0
        union = np.count_nonzero(mine | ref)
        out[cam.name] = float(np.count_nonzero(mine & ref) / union) if union else 1.0
    return out


def silhouette_tolerant_agreement(V: np.ndarray, F: np.ndarray, cameras, masks: dict,
                                   tolerance_px_at_640: float = TOLERANCE_PX_AT_640,
                                   fitted: dict | None = None) -> dict[str, dict[str, float]]:
    """Per camera, the fit's silhouette against the mask up to a band of a few pixels (the data term of Eq. 7 of
    Rapid Skin without the segmentation's own noise): ``precision``, the share of the fit's silhouette within
    the band of the mask, and ``recall``, the share of the mask within the band of the fit's silhouette.
    ``fitted``: :func:`fitted_silhouettes` when already drawn."""
    import cv2

    fitted = fitted_silhouettes(V, F, cameras) if fitted is None else fitted
    out = {}
    for cam in cameras:
        mine = fitted[cam.name]
        ref = np.asarray(masks[cam.name]) > 0
        band = tolerance_px_at_640 * cam.width / 640.0
        rows, cols = np.nonzero(mine | ref)
        if len(rows) == 0:
            out[cam.name] = {"precision": 1.0, "recall": 1.0}
            continue
        # the distance transforms on the box around both silhouettes only (the body fills a small part of the
        # image: 6 cameras at 640x480, 29 -> 9 ms CPU per frame); both silhouettes lie inside it, so every
        # distance to them is the whole image's
        pad = int(np.ceil(band)) + 2
        box = (slice(max(rows.min() - pad, 0), rows.max() + pad + 1),
               slice(max(cols.min() - pad, 0), cols.max() + pad + 1))
        mine, ref = mine[box], ref[box]
        to_ref = cv2.distanceTransform((~ref).astype(np.uint8), cv2.DIST_L2, 5)
        to_mine = cv2.distanceTransform((~mine).astype(np.uint8), cv2.DIST_L2, 5)
        out[cam.name] = {"precision": float(np.mean(to_ref[mine] <= band)) if mine.any() else 1.0,
                         "recall": float(np.mean(to_mine[ref] <= band)) if ref.any() else 1.0}
    return out


def silhouette_coherence(cameras, masks: dict, center: np.ndarray, half_size_m=(0.6, 1.1, 0.6),
                         voxel_m: float = 0.04) -> dict[str, float]:
    """Per camera, the share of its mask that the visual hull of the OTHER cameras explains: silhouette
    coherence (Hernandez, Schmitt & Cipolla 2007, Eq. 2, as a leave-one-out coverage), from the inputs alone.

    Voxels of a box around ``center`` (the fitted body) are tested against every camera's mask, as a sphere
    of the voxel's size (a consistent rig's hull contains the body, so its projection covers every mask up to
    the voxel size); for camera ``c`` the voxels inside all the other masks are drawn into ``c``'s image and
    the covered share of ``c``'s mask is its coherence. A consistent rig gives ~1 in every view; a camera
    whose pose or masks are wrong sees the others' hull beside its silhouette. A point no camera but ``c``
    images stays uncarved, so views outside the box agree by construction.
    """
    import cv2

    cams = list(cameras)
    lo = np.asarray(center, float) - np.asarray(half_size_m, float)
    n = np.maximum(np.ceil(2 * np.asarray(half_size_m, float) / voxel_m).astype(int), 1)
    grid = np.stack(np.meshgrid(*[np.arange(k) for k in n], indexing="ij"), axis=-1).reshape(-1, 3)
    P = lo + voxel_m * (grid + 0.5)
    inside = np.ones((len(cams), len(P)), bool)
    pixels, radii = [], []
    for k, cam in enumerate(cams):
        z = P @ cam.R[2] + cam.t[2]
        uv = cam.project(P[z > 1e-3]) if np.all(z > 1e-3) else np.full((len(P), 2), np.nan)
        fx = float(cam.K[0, 0])
        r = np.where(z > 0, 0.87 * voxel_m * fx / np.maximum(z, 1e-6), 0.0)  # the voxel's sphere, in pixels
        mask = np.asarray(masks[cam.name]) > 0
        dist = cv2.distanceTransform((~mask).astype(np.uint8), cv2.DIST_L2, 5)
        px = np.round(np.nan_to_num(uv, nan=-1.0)).astype(np.int64)
        seen = (z > 0) & (px[:, 0] >= 0) & (px[:, 0] < cam.width) & (px[:, 1] >= 0) & (px[:, 1] < cam.height)
        inside[k, seen] = dist[px[seen, 1], px[seen, 0]] <= r[seen] + 0.5
        pixels.append((px, seen))
        radii.append(r)
    out = {}
    for k, cam in enumerate(cams):
        mask = np.asarray(masks[cam.name]) > 0
        if not mask.any():
            out[cam.name] = 1.0
            continue
        others = np.delete(inside, k, axis=0).all(axis=0) if len(cams) > 1 else np.ones(len(P), bool)
        px, seen = pixels[k]
        hit = others & seen
        drawn = np.zeros(mask.shape, np.uint8)
        drawn[px[hit, 1], px[hit, 0]] = 1
        r = int(np.ceil(np.median(radii[k][hit]))) if hit.any() else 0
        if r > 0:
            drawn = cv2.dilate(drawn, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1)))
        out[cam.name] = float(np.count_nonzero(mask & (drawn > 0)) / np.count_nonzero(mask))
    return out


def depth_agreement(V: np.ndarray, F: np.ndarray, depth_m: np.ndarray, depth_camera,
                    depth_range_m: tuple[float, float] = DEPTH_RANGE_M) -> dict[str, float]:
    """How well the measured depth explains the fitted mesh seen by the depth camera: ``coverage`` (share of
    the mesh's pixels with a reading in range), ``gap_m`` (median |measured - rendered| over those) and
    ``ratio`` (median measured over rendered depth over every mesh pixel with a reading, in range or not: a
    depth map in another unit shows here as 10, 1000 or 0.001)."""
    rendered = render(V, F, depth_camera).depth.astype(np.float64)
    D = np.nan_to_num(np.asarray(depth_m, dtype=np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    covered = rendered > 0
    n = int(np.count_nonzero(covered))
    if n == 0:
        return {"coverage": 0.0, "gap_m": float("inf"), "ratio": float("nan"), "pixels": 0}
    measured = covered & (D > 0)
    in_range = measured & (D > depth_range_m[0]) & (D < depth_range_m[1])
    gap = float(np.median(np.abs(D[in_range] - rendered[in_range]))) if in_range.any() else float("inf")
    ratio = float(np.median(D[measured] / rendered[measured])) if measured.any() else float("nan")
    return {"coverage": float(np.count_nonzero(in_range) / n), "gap_m": gap, "ratio": ratio, "pixels": n}


def frame_plausibility(V: np.ndarray, F: np.ndarray, cameras, masks: dict | None, depth_m: np.ndarray | None = None,
                       depth_camera=None, coherence: bool = False) -> dict:
    """One frame's self-check: ``silhouette_iou`` per camera, with ``coherence`` the inputs' own
    :func:`silhouette_coherence` around the fit, and with depth ``depth`` (:func:`depth_agreement`)."""
    out: dict = {}
    if masks is not None:
        cameras = list(cameras)
        fitted = fitted_silhouettes(V, F, cameras)  # drawn once for both agreements
        out["silhouette_iou"] = silhouette_agreement(V, F, cameras, masks, fitted=fitted)
        tolerant = silhouette_tolerant_agreement(V, F, cameras, masks, fitted=fitted)
        out["silhouette_precision_tol"] = {c: v["precision"] for c, v in tolerant.items()}
        out["silhouette_recall_tol"] = {c: v["recall"] for c, v in tolerant.items()}
        if coherence and len(list(cameras)) > 1:
            out["coherence"] = silhouette_coherence(cameras, masks, np.asarray(V).mean(axis=0))
    if depth_m is not None and depth_camera is not None:
        out["depth"] = depth_agreement(V, F, depth_m, depth_camera)
    return out


def coherence_frames(n_frames: int, most: int = 3) -> set[int]:
    """Which of a run's frames (indices) get the silhouette-coherence check: first, middle and last (the faults
    it finds, a moved camera or a camera's mask folder swapped, last the whole run)."""
    return {int(round(x)) for x in np.linspace(0, n_frames - 1, min(most, n_frames))}


def _per_camera_median(frames: list[dict], key: str) -> dict[str, float]:
    rows = [f[key] for f in frames if f.get(key)]
    if not rows:
        return {}
    return {c: float(np.median([r[c] for r in rows if c in r])) for c in rows[0]}


def run_plausibility(frames: list[dict], session_path=None) -> dict:
    """A run's verdict from its frames' :func:`frame_plausibility`: per camera the median IoU (and coherence)
    over frames, the depth figures' medians, ``warnings`` and ``problems`` (one sentence each, naming the input
    and the fix) and ``ok`` (no problem). ``session_path`` names the files in the sentences."""
    where = f"{session_path}/" if session_path is not None else ""
    report: dict = {"thresholds": {"iou_warn": IOU_WARN, "iou_refuse": IOU_REFUSE,
                                   "tolerance_px_at_640": TOLERANCE_PX_AT_640,
                                   "tolerant_precision_trust": TOLERANT_PRECISION_TRUST,
                                   "tolerant_recall_trust": TOLERANT_RECALL_TRUST,
                                   "coherence_warn": COHERENCE_WARN, "coherence_refuse": COHERENCE_REFUSE,
                                   "depth_coverage_refuse": DEPTH_COVERAGE_REFUSE,
                                   "depth_gap_refuse_m": DEPTH_GAP_REFUSE_M}}
    warnings, problems = [], []
    iou = _per_camera_median(frames, "silhouette_iou")
    coherence = _per_camera_median(frames, "coherence")
    if iou:
        report["camera_iou"] = iou
    if coherence:
        report["camera_coherence"] = coherence
    precision_tol = _per_camera_median(frames, "silhouette_precision_tol")
    recall_tol = _per_camera_median(frames, "silhouette_recall_tol")
    if precision_tol:
        report["camera_precision_tol"] = precision_tol
        report["camera_recall_tol"] = recall_tol
    # a low IoU in a view whose fit lies inside the mask's band and covers it up to the band: the mask is noisy
    # (shadows, holes, a lost limb), the fit and the rig are not wrong; warned, not refused
    noisy = sorted(c for c in iou if iou[c] < IOU_WARN and precision_tol.get(c, 0.0) >= TOLERANT_PRECISION_TRUST
                   and recall_tol.get(c, 0.0) >= TOLERANT_RECALL_TRUST)
    low_iou = sorted((c for c in iou if iou[c] < IOU_REFUSE and c not in noisy), key=iou.get)
    low_coh = sorted((c for c in coherence if coherence[c] < COHERENCE_REFUSE), key=coherence.get)
    if low_iou or low_coh:
        figures = []
        if low_iou:
            figures.append(f"the fit's silhouette IoU {_listing(low_iou[:3], iou)}"
                           f"{' ...' if len(low_iou) > 3 else ''}, trusted >= {IOU_REFUSE}")
        typical = float(np.median(list(coherence.values()))) if coherence else 1.0
        suspects = sorted((c for c in coherence if coherence[c] < min(COHERENCE_REFUSE, typical - COHERENCE_OUTLIER)),
                          key=coherence.get)
        if suspects:
            blame = (f"camera{'s' if len(suspects) > 1 else ''} {', '.join(suspects)} disagree"
                     f"{'s' if len(suspects) == 1 else ''} with the other cameras")
            figures.append(f"the share of each mask the other cameras' visual hull explains "
                           f"{_listing(suspects, coherence)}, the others' median {typical:.2f}, consistent views ~1.0")
        else:
            blame = "the cameras disagree with each other"
            if coherence:
                figures.append(f"the share of each mask the other cameras' visual hull explains "
                               f"{min(coherence.values()):.2f}..{max(coherence.values()):.2f}, consistent views ~1.0")
        if coherence and min(coherence.values()) >= COHERENCE_WARN:
            # the inputs agree with each other: it is the fit that does not explain them
            problems.append(f"the fit does not explain the silhouettes although the cameras agree with each other "
                            f"({'; '.join(figures)}): it did not converge or started from wrong joints; raise "
                            "--outer/--inner, check the joints (--joints)")
        else:
            problems.append(f"{blame} ({'; '.join(figures)}): check {where}calibration/cameras.json for a moved "
                            "camera (re-calibrate) and the masks for another camera's files")
    else:
        weak = sorted(({c for c in iou if iou[c] < IOU_WARN} - set(noisy))
                      | {c for c in coherence if coherence[c] < COHERENCE_WARN})
        if noisy:
            warnings.append(f"camera{'s' if len(noisy) > 1 else ''} {', '.join(noisy)}: the masks hold regions the "
                            f"fit does not explain (silhouette IoU {_listing(noisy, iou)}) although the fit lies "
                            f"inside them up to {TOLERANCE_PX_AT_640:g} px (at 640 px width; "
                            f"{_listing(noisy, precision_tol)} of its silhouette; {_listing(noisy, recall_tol)} of "
                            "the masks): shadows, holes or a lost limb in the segmentation; check the masks")
        if weak:
            warnings.append(f"camera{'s' if len(weak) > 1 else ''} {', '.join(weak)} agree less with the fit or "
                            f"the other cameras (silhouette IoU {_listing(weak, iou)}; coherence "
                            f"{_listing(weak, coherence)}); the calibration or masks may be off")
    _tracker_joint_verdict(frames, where, report, warnings, problems)
    lost = [f for f in frames if f.get("untracked_limb_joints", 0) >= LIMB_UNTRACKED_WARN]
    if lost:
        report["frames_limbs_untracked"] = len(lost)
        warnings.append(f"{len(lost)} of {len(frames)} frames had {LIMB_UNTRACKED_WARN} or more of the 8 limb "
                        f"joints untracked by {where}kinect/joints (elbows, wrists, knees, ankles; "
                        f"frames.json: untracked_limb_joints): their limbs start from the template's rest pose and "
                        "can be 5x worse; check the tracker there, or use --joints hull")
    depths = [f["depth"] for f in frames if f.get("depth")]
    if depths:
        coverage = float(np.median([d["coverage"] for d in depths]))
        gap = float(np.median([d["gap_m"] for d in depths]))
        ratios = [d["ratio"] for d in depths if np.isfinite(d["ratio"])]
        ratio = float(np.median(ratios)) if ratios else float("nan")
        report["depth"] = {"coverage": coverage, "gap_m": gap, "ratio": ratio}
        if coverage < DEPTH_COVERAGE_REFUSE or gap > DEPTH_GAP_REFUSE_M:
            unit = (f"the readings are {ratio:.3g}x the fitted body's distance, " if np.isfinite(ratio)
                    else "no depth reading where the body is, ")
            problems.append(f"the Kinect depth does not fit the body the silhouettes give ({unit}"
                            f"{coverage:.0%} of its pixels usable, median gap {gap:.3g} m): check the unit of "
                            f"{where}kinect/depth (re-import with the right --depth-scale) and "
                            f"{where}kinect/calibration.json, or use --constraints silhouette")
    report["warnings"] = warnings
    report["problems"] = problems
    report["ok"] = not problems
    return report


def _tracker_joint_verdict(frames: list[dict], where: str, report: dict, warnings: list, problems: list) -> None:
    """The fitted limbs against the tracker's joints (:func:`tracker_joint_residual`, per frame
    ``tracker_joint_residual`` with ``tracked``: a ``--tracking`` frame that did not re-initialise): a problem when
    :data:`TRACKING_LOST_REFUSE_SHARE` of the tracked frames put a limb joint over :data:`TRACKER_JOINT_FAR_MM`
    from the tracker's, a warning when fewer frames do (or frames the joints initialised)."""
    residuals = [f["tracker_joint_residual"] for f in frames if f.get("tracker_joint_residual")]
    if not residuals:
        return
    far = [r for r in residuals if r["max_mm"] > TRACKER_JOINT_FAR_MM]
    tracked = [r for r in residuals if r.get("tracked")]
    far_tracked = [r for r in far if r.get("tracked")]
    worst = max(residuals, key=lambda r: r["max_mm"])
    report["tracker_joints"] = {"max_mm": worst["max_mm"], "joint": worst["joint"], "frames_far": len(far),
                                "tracked_frames": len(tracked), "tracked_frames_far": len(far_tracked),
                                "far_mm": TRACKER_JOINT_FAR_MM, "refuse_share": TRACKING_LOST_REFUSE_SHARE}
    if not far:
        return
    at = f", frame {worst['frame']}" if "frame" in worst else ""
    if far_tracked and len(far_tracked) >= TRACKING_LOST_REFUSE_SHARE * len(tracked):
        problems.append(f"the tracking lost the limbs: {len(far_tracked)} of {len(tracked)} tracked frames put a "
                        f"limb joint over {TRACKER_JOINT_FAR_MM:.0f} mm from the tracker's ({where}kinect/joints; "
                        f"worst {worst['joint']} {worst['max_mm']:.0f} mm{at}; good runs <= 60 mm) where the "
                        "silhouettes do not hold them (few or small views); reconstruct without --tracking or "
                        "--accurate (each frame from its joints), or record more cameras or a higher resolution")
    else:
        warnings.append(f"{len(far)} of {len(residuals)} frames put a limb joint over {TRACKER_JOINT_FAR_MM:.0f} mm "
                        f"from the tracker's ({where}kinect/joints; worst {worst['joint']} {worst['max_mm']:.0f} "
                        f"mm{at}; good runs <= 60 mm; frames.json: tracker_joint_residual): the fit or the tracker "
                        "is wrong there; check the joints, or reconstruct those frames without --tracking")


def _listing(names, values: dict) -> str:
    return ", ".join(f"{c} {values[c]:.2f}" for c in names if c in values) or "-"
