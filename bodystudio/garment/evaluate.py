"""Scores of a garment fit (§4-5 of Garment Replacement) against a synthetic session's ground truth.

The fit is uncalibrated: its camera is an assumption (``fit.camera``) and the world frame is that
camera's, so joints and light directions are compared in each camera's own frame (fitted camera for the
fit, the session's true camera for the ground truth). ``joint_err_mm`` is root-relative (pelvis
aligned, the usual monocular measure: the absolute depth scales with the assumed focal length).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from bodystudio.errors import InputError

#: The joints scored (bone heads): hips, knees, ankles, shoulders, elbows, wrists, neck, head.
MAJOR_JOINTS = ("thigh_l", "thigh_r", "calf_l", "calf_r", "foot_l", "foot_r", "upperarm_l", "upperarm_r",
                "lowerarm_l", "lowerarm_r", "hand_l", "hand_r", "neck_01", "head")
ROOT_JOINT = "pelvis"


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    c = float(np.dot(a, b) / (np.linalg.norm(a) * np.linalg.norm(b)))
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def fitted_joints(fit) -> np.ndarray:
    """(n, B, 3) posed bone heads of every fitted frame (world of the fit's camera)."""
    from bodystudio.body.skinning import posed_joints

    body = fit.body()
    return np.stack([posed_joints(body.skeleton, fit.pose(i))[0] for i in range(len(fit.frame_ids))])


def joint_errors(fit, session) -> dict:
    """``joint_err_px`` (projected, each in its camera) and root-relative ``joint_err_mm`` (camera frames)."""
    cam_gt = session.cameras[session.camera_names[0]]
    J_fit = fitted_joints(fit)
    names = list(fit.bone_names)
    ids = [names.index(n) for n in MAJOR_JOINTS]
    root = names.index(ROOT_JOINT)
    px, mm = [], []
    for i, fid in enumerate(fit.frame_ids):
        gt = session.frame(int(fid)).gt_joints
        if gt is None:
            raise InputError(f"{session.path}: frame {fid} has no gt/joints; eval garment needs a synthetic session")
        gt_names = list(gt["bone_names"])
        J_gt = gt["heads"][[gt_names.index(n) for n in MAJOR_JOINTS]]
        r_gt = gt["heads"][gt_names.index(ROOT_JOINT)]
        px.append(np.linalg.norm(fit.camera.project(J_fit[i, ids]) - cam_gt.project(J_gt), axis=1))
        a = (J_fit[i, ids] - J_fit[i, root]) @ fit.camera.R.T
        b = (J_gt - r_gt) @ cam_gt.R.T
        mm.append(1e3 * np.linalg.norm(a - b, axis=1))
    return {"joint_err_px": float(np.mean(px)), "joint_err_px_max": float(np.max(px)),
            "joint_err_mm": float(np.mean(mm)), "joint_err_mm_max": float(np.max(mm))}


def principal_light_direction(directions: np.ndarray, colors: np.ndarray) -> np.ndarray:
    """The dominant direction of a set of lights as the power-weighted sum ``sum_l |c_l| d_l``: the direction
    of the light field's first-order (linear) term, i.e. of the one light that produces the same shading
    gradient on a Lambertian surface. Unlike the brightest light's cone, it does not jump between the
    many weak lights NNLS leaves when the fitted normals are imperfect (measured in docs/garment.md)."""
    d = (np.clip(colors, 0.0, None).sum(1)[:, None] * directions).sum(0)
    n = np.linalg.norm(d)
    if n < 1e-12:
        raise InputError("no light has positive intensity; the scene's lighting could not be estimated")
    return d / n


def light_direction_errors(fit, session) -> dict:
    """Angles (deg) between the fit's and the true dominant light, both in their camera's frame:
    ``light_dir_err_deg`` (:func:`principal_light_direction`) and ``light_brightest_dir_err_deg``
    (lighting.py's ``dominant_light_direction``, the brightest light's 25 deg cone)."""
    from bodystudio.garment.lighting import dominant_light_direction

    gt = session.gt_lighting
    if fit.lighting is None or gt is None:
        return {"light_dir_err_deg": None, "light_brightest_dir_err_deg": None}
    cam_gt = session.cameras[session.camera_names[0]]
    gd, gc = np.asarray(gt["directions"], float), np.asarray(gt["colors"], float)
    out = {}
    for key, fn in (("light_dir_err_deg", principal_light_direction),
                    ("light_brightest_dir_err_deg", dominant_light_direction)):
        d_fit = fit.camera.R @ fn(fit.lighting.directions, fit.lighting.colors)
        out[key] = _angle_deg(d_fit, cam_gt.R @ fn(gd, gc))
    return out


def albedo_error(fit, session) -> float | None:
    """Mean absolute albedo error against the appearance the video shows (``gt/albedo.json``), after one
    least-squares scale per channel (albedo and light share a global scale); over the fit's vertices."""
    from bodystudio.body.model import template_topology

    gt = session.gt_appearance_albedo
    if fit.albedo is None or gt is None:
        return None
    gt_template = session.gt_subject.get("template", "6k")
    ids_fit, _ = template_topology(fit.template)
    ids_gt, _ = template_topology(gt_template)
    if fit.template == gt_template:
        truth = gt
    else:  # both templates select full-body vertices: compare on the nearest full-body id
        from scipy.spatial import cKDTree

        full = np.arange(13380) if ids_gt is None else ids_gt
        want = np.arange(len(fit.albedo)) if ids_fit is None else ids_fit
        _, j = cKDTree(full[:, None].astype(float)).query(want[:, None].astype(float))
        truth = gt[j]
    a = np.asarray(fit.albedo, float)
    scale = (a * truth).sum(0) / np.maximum((a * a).sum(0), 1e-12)
    return float(np.mean(np.abs(a * scale - truth)))


def shape_error_mm(fit, body, subject: dict) -> float:
    """Mean distance (mm) between the fitted body and the true one in the rest pose (same template)."""
    from bodystudio.body import build_body
    from bodystudio.body.phenotype import Phenotype

    truth = build_body(Phenotype.from_dict(subject["phenotype"]), subject.get("local", {}), resolution=fit.template)
    return float(1e3 * np.linalg.norm(body.vertices - truth.vertices, axis=1).mean())


def fit_errors(fit, session) -> dict:
    """The fit's scores (issue 13): stature, joints, dominant light, albedo, silhouette IoU, timings."""
    from bodystudio.capture.session import Session, open_session
    from bodystudio.capture.silhouettes import mask_iou

    if not isinstance(session, Session):
        session = open_session(session)
    subject = session.gt_subject
    if subject is None or "stature_m" not in subject:
        raise InputError(f"{session.path}: no gt/phenotype.json with a stature; eval garment needs a synthetic "
                         f"session (bodystudio synth garment)")
    body = fit.body()
    stature_fit = float(body.vertices[:, 1].max() - body.vertices[:, 1].min())
    out = {"frames": len(fit.frame_ids), "stature_m": stature_fit,
           "stature_err_mm": abs(stature_fit - float(subject["stature_m"])) * 1e3}
    out["shape_err_mm"] = shape_error_mm(fit, body, subject)
    out.update(joint_errors(fit, session))
    out.update(light_direction_errors(fit, session))
    out["albedo_err"] = albedo_error(fit, session)
    out["silhouette_iou"] = float(np.mean(fit.silhouette_iou))
    out["silhouette_iou_min"] = float(np.min(fit.silhouette_iou))
    cam = session.camera_names[0]
    out["mask_iou_vs_gt"] = float(np.mean([mask_iou(m, session.frame(int(f)).gt_masks[cam])
                                           for f, m in zip(fit.frame_ids, fit.masks, strict=True)]))
    out["ms_per_frame"] = dict(fit.timings_ms)
    return out


def check_fit_source(fit_dir, fit, session) -> None:
    """Refuse to score a fit against another recording's ground truth: a fit of a session must match that
    session's frames (their fingerprint, written by the fit); a fit of a video must at least have the session's
    frame ids and image size. A score against the wrong truth would be meaningless, not merely bad."""
    from bodystudio.garment.person import source_fingerprint

    cam = session.camera_names[0] if session.camera_names else None
    if fit.source_fingerprint is not None and fit.source_fingerprint.startswith("session:"):
        if cam is None or source_fingerprint(session, fit.frame_ids, cam) != fit.source_fingerprint:
            raise InputError(f"{fit_dir}: fitted on another recording than {session.path} (its frames differ); "
                             f"pass --session with the session it was fitted on ({fit.source})")
        return
    missing = sorted(set(int(f) for f in fit.frame_ids) - set(session.frame_ids))
    if missing:
        raise InputError(f"{fit_dir}: frames {missing[:3]} of the fit are not in {session.path}; pass --session with "
                         f"the session the video was made from")
    if cam is not None:
        c = session.cameras[cam]
        if tuple(fit.masks.shape[1:]) != (int(c.height), int(c.width)):
            raise InputError(f"{fit_dir}: the fit's frames are {fit.masks.shape[2]}x{fit.masks.shape[1]}, "
                             f"{session.path}'s {c.width}x{c.height}; pass --session with the session the video "
                             f"was made from")


def evaluate_garment(fit_dir: str | os.PathLike, session: str | os.PathLike | None = None) -> dict:
    """``bodystudio eval garment DIR``: the fit's scores, plus the composite's when DIR/render/render.json exists
    (:func:`bodystudio.garment.composite.composite_errors`; refused when the render is not of the session's target)."""
    from bodystudio.capture.session import open_session
    from bodystudio.garment.fitfile import load_garment_fit

    fit = load_garment_fit(fit_dir)
    src = Path(session if session is not None else fit.source)
    if not src.is_dir():
        raise InputError(f"{src}: the fit's source is not a session folder; eval garment needs the synthetic session "
                         f"(pass --session)")
    s = open_session(src)
    check_fit_source(fit_dir, fit, s)
    scores = fit_errors(fit, s)
    if (Path(fit_dir) / "render" / "render.json").is_file():
        from bodystudio.garment.composite import composite_errors

        scores.update(composite_errors(fit_dir, s))
    scores.update(scored_run_ids(fit_dir))
    return scores


def scored_run_ids(fit_dir: str | os.PathLike) -> dict:
    """``{"fit_run_id": ..., "render_run_id": ...}``: which fit and render a score is of (None: none, or no
    run id recorded). A saved ``eval.json`` whose ids differ from the folder's now scores an earlier run."""
    import json

    ids = {}
    for key, path in (("fit_run_id", Path(fit_dir) / "fit.json"),
                      ("render_run_id", Path(fit_dir) / "render" / "render.json")):
        try:
            run = json.loads(path.read_text(encoding="utf-8")).get("run")
        except (OSError, ValueError, AttributeError):
            run = None
        ids[key] = run.get("run_id") if isinstance(run, dict) else None
    return ids
