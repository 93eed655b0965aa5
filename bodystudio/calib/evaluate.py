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
    # a report may cover some cameras only: each figure over the cameras that have it
    keys = list(dict.fromkeys(k for p in per.values() for k in p))
    overall = {k: float(np.mean([p[k] for p in per.values() if k in p])) for k in keys}
    if report and "reproj_rms_px" in report:
        overall["reproj_rms_px"] = float(report["reproj_rms_px"])
    worst = {k: float(np.max([p[k] for p in per.values() if k in p])) for k in keys}
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


#: chi-square quantile of 3 degrees of freedom at the probability of |z| < 3 for one (99.73 %): the
#: "within 3 sigma" test of a 3-D error against its covariance.
CHI2_3DOF_3SIGMA = 14.156


def uncertainty_consistency(est: CameraRig, gt: CameraRig, uncertainty) -> dict:
    """Does a calibration's own uncertainty predict its true error? Per camera: the errors of fx, fy,
    cx, cy (px) and of the centre (mm) against ground truth, their predicted 1-sigma, the normalised
    errors ``z = err / sigma`` and ``centre_mahalanobis2 = e^T Sigma^-1 e`` (chi-square with 3 degrees
    of freedom when the covariance is right), and ``within_3sigma``: every |z| <= 3 and the centre's
    Mahalanobis distance within the 3-sigma-equivalent chi-square bound (99.73 %).

    ``uncertainty`` is a :class:`bodystudio.calib.uncertainty.CalibrationUncertainty`; both rigs must be
    in the same world frame (the floor board's, as ``evaluate_calibration`` assumes).
    """
    out = {}
    for cam in uncertainty.cameras:
        e, g = est[cam.name], gt[cam.name]
        err = {"fx": e.fx - g.fx, "fy": e.fy - g.fy, "cx": e.K[0, 2] - g.K[0, 2], "cy": e.K[1, 2] - g.K[1, 2]}
        sig = {"fx": cam.fx_sigma_px, "fy": cam.fy_sigma_px, "cx": cam.cx_sigma_px, "cy": cam.cy_sigma_px}
        z = {k: abs(err[k]) / sig[k] if sig[k] > 0 else float("inf") for k in err}
        d_mm = 1000.0 * (e.center - g.center)
        cov = cam.center_cov_mm2
        if np.isfinite(cov).all() and np.linalg.matrix_rank(cov) == 3:
            maha2 = float(d_mm @ np.linalg.solve(cov, d_mm))
        else:
            maha2 = float("inf") if np.linalg.norm(d_mm) > 1e-6 else 0.0
        within = all(v <= 3.0 for v in z.values()) and maha2 <= CHI2_3DOF_3SIGMA
        out[cam.name] = {**{f"{k}_err_px": float(v) for k, v in err.items()},
                         **{f"{k}_sigma_px": float(v) for k, v in sig.items()},
                         **{f"{k}_z": float(v) for k, v in z.items()},
                         "center_err_mm": float(np.linalg.norm(d_mm)), "center_sigma_mm": cam.center_sigma_mm,
                         "center_mahalanobis2": maha2, "verdict": cam.verdict, "within_3sigma": bool(within)}
    return out
