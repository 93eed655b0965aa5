"""Calibration accuracy against ground truth: camera centres, rotations, focal lengths, reprojection.

Both rigs are compared in their own world frames, which the floor board defines identically, so no
alignment is applied by default (the world-frame error is part of the score). ``align="similarity"``
first maps the estimate onto the ground truth with Umeyama's similarity on the camera centres, which
isolates the relative geometry.
"""

from __future__ import annotations

import numpy as np

from bodystudio.calib.world import rotation_angle_deg, similarity_align
from bodystudio.errors import InputError
from bodystudio.geometry.camera import Camera, CameraRig


def volume_points(n: int = 2000, seed: int = 0) -> np.ndarray:
    """Points filling the capture volume (2 m diameter cylinder, 0-2.2 m high) for reprojection checks."""
    rng = np.random.default_rng(seed)
    r = 1.0 * np.sqrt(rng.random(n))
    a = rng.uniform(0, 2 * np.pi, n)
    return np.c_[r * np.sin(a), rng.uniform(0.0, 2.2, n), r * np.cos(a)]


def _aligned(est: CameraRig, gt: CameraRig) -> CameraRig:
    names = list(gt.names)
    s, R, t = similarity_align(np.array([est[n].center for n in names]), np.array([gt[n].center for n in names]))
    cams = {}
    for n in est.names:
        c = est[n]
        center = s * R @ c.center + t
        Rc = c.R @ R.T
        cams[n] = Camera(n, c.K, c.dist, Rc, -Rc @ center, c.width, c.height)
    return CameraRig(cams)


def evaluate_calibration(est: CameraRig, gt: CameraRig, report: dict | None = None, align: str = "floor") -> dict:
    """Per-camera and overall ``center_err_mm``, ``rot_err_deg``, ``focal_err_pct``, ``volume_reproj_rms_px``
    (GT-vs-estimate pixel distance of points in the capture volume) and, from the calibration report,
    ``reproj_rms_px``. Overall values are means; ``max`` holds the worst camera."""
    missing = [n for n in gt.names if n not in est]
    if missing:
        raise InputError(f"camera {missing[0]} of the ground truth is missing from the estimate; calibrate it too")
    if align == "similarity":
        est = _aligned(est, gt)
    elif align != "floor":
        raise InputError(f"align must be 'floor' or 'similarity', got {align!r}")
    P = volume_points()
    per = {}
    for n in gt.names:
        e, g = est[n], gt[n]
        focal = 100 * max(abs(e.fx - g.fx) / g.fx, abs(e.fy - g.fy) / g.fy)
        uv_g, z = g.project_with_depth(P)
        uv_e = e.project(P)
        inside = g.in_image(uv_g) & (z > 0)
        vol = float(np.sqrt(((uv_e[inside] - uv_g[inside]) ** 2).sum(1).mean())) if inside.any() else float("nan")
        entry = {"center_err_mm": float(1000 * np.linalg.norm(e.center - g.center)),
                 "rot_err_deg": rotation_angle_deg(e.R @ g.R.T), "focal_err_pct": float(focal),
                 "volume_reproj_rms_px": vol}
        if report and n in report.get("cameras", {}):
            entry["reproj_rms_px"] = report["cameras"][n]["reproj_rms_px"]
        per[n] = entry
    keys = list(next(iter(per.values())).keys())
    overall = {k: float(np.mean([p[k] for p in per.values()])) for k in keys}
    if report and "reproj_rms_px" in report:
        overall["reproj_rms_px"] = float(report["reproj_rms_px"])
    worst = {k: float(np.max([p[k] for p in per.values()])) for k in keys}
    return {"align": align, "overall": overall, "max": worst, "cameras": per}


def evaluate_rgbd_sensor(est, gt) -> dict:
    """Depth->colour and studio-pose errors of a calibrated RGB-D sensor (RGBDSensor) against ground truth."""
    D, G = np.asarray(est.depth_to_color), np.asarray(gt.depth_to_color)
    out = {"depth_to_color_t_err_mm": float(1000 * np.linalg.norm(D[:3, 3] - G[:3, 3])),
           "depth_to_color_rot_err_deg": rotation_angle_deg(D[:3, :3] @ G[:3, :3].T)}
    for which in ("color", "depth"):
        e, g = getattr(est, which), getattr(gt, which)
        out[f"{which}_center_err_mm"] = float(1000 * np.linalg.norm(e.center - g.center))
        out[f"{which}_rot_err_deg"] = rotation_angle_deg(e.R @ g.R.T)
    return out
