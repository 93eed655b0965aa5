"""Calibration accuracy and run time: bundle adjustment vs chained pairwise cv2.stereoCalibrate.

Full case (issue 4): the 10-camera studio ring (ring_rig, 1280x960), 30 ChArUco poses (frame 0 on the
floor), 0.2 px Gaussian corner noise on synthetic observations. The same rig and pose count also runs
the whole image pipeline: render, detect, calibrate (4 cameras x 12 poses with --quick).
"""

from __future__ import annotations

import time

import numpy as np

from benchmarks.timing import markdown_table, median_seconds
from bodystudio.calib.baseline import chained_stereo_calibration
from bodystudio.calib.board import CharucoBoardSpec
from bodystudio.calib.calibrate import CalibrationOptions, calibrate_cameras
from bodystudio.calib.evaluate import evaluate_calibration
from bodystudio.calib.synthetic import (
    board_for_resolution,
    calibration_board_poses,
    synthetic_charuco_observations,
)
from bodystudio.geometry.camera import ring_rig

NOISE_PX = 0.2


def _row(label: str, scores: dict, rms: float | str, expected: float | str, seconds: float) -> list:
    o, m = scores["overall"], scores["max"]
    return [label, rms, expected, o["center_err_mm"], m["center_err_mm"], o["rot_err_deg"], m["rot_err_deg"],
            o["focal_err_pct"], m["focal_err_pct"], o["volume_reproj_rms_px"], seconds]


def _synthetic_case(n_cameras: int, n_poses: int, width: int, height: int, seed: int, repeats: int):
    spec = board_for_resolution(width)
    rig = ring_rig(n_cameras, width=width, height=height)
    rng = np.random.default_rng(seed)
    poses = calibration_board_poses(rig, spec, n_poses, rng)
    obs = synthetic_charuco_observations(rig, spec, poses, NOISE_PX, rng)
    rows = []
    for terms in (4, 5):
        options = CalibrationOptions(distortion_terms=terms)
        result = calibrate_cameras(obs, spec, options)
        seconds = median_seconds(lambda options=options: calibrate_cameras(obs, spec, options), repeats=repeats,
                                 warmup=0)
        rows.append(_row(f"bundle adjustment (k1..{'k3' if terms == 5 else 'p2'})",
                         evaluate_calibration(result.rig, rig), result.rms_px, result.expected_rms_px(NOISE_PX),
                         seconds))
    chained = chained_stereo_calibration(obs, spec)
    seconds = median_seconds(lambda: chained_stereo_calibration(obs, spec), repeats=repeats, warmup=0)
    rows.append(_row("chained cv2.stereoCalibrate", evaluate_calibration(chained, rig), "-", "-", seconds))
    return rows, len(obs)


def _seed_spread(n_cameras: int, n_poses: int, seeds) -> str:
    """The full case on several pose plans and noise draws: the acceptance is a statement about the
    protocol, not about one lucky draw."""
    spec = board_for_resolution(1280)
    rig = ring_rig(n_cameras, width=1280, height=960)
    rows = []
    for seed in seeds:
        rng = np.random.default_rng(seed)
        poses = calibration_board_poses(rig, spec, n_poses, rng)
        obs = synthetic_charuco_observations(rig, spec, poses, NOISE_PX, rng)
        result = calibrate_cameras(obs, spec)
        rows.append([seed] + _row("", evaluate_calibration(result.rig, rig), result.rms_px,
                                  result.expected_rms_px(NOISE_PX), result.seconds)[1:])
    arr = np.array([r[1:] for r in rows], float)
    rows.append(["mean"] + list(arr.mean(0)))
    rows.append(["worst"] + list(arr.max(0)))
    return markdown_table(["seed", "RMS px", "expected RMS px", "centre mm (mean)", "centre mm (max)",
                           "rot deg (mean)", "rot deg (max)", "focal % (mean)", "focal % (max)", "volume reproj px",
                           "time s"], rows)


def _noise_scaling(n_cameras: int, n_poses: int) -> str:
    """Errors against corner noise on one capture: zero at zero noise and linear in it means no bias."""
    spec = board_for_resolution(1280)
    rig = ring_rig(n_cameras, width=1280, height=960)
    poses = calibration_board_poses(rig, spec, n_poses, np.random.default_rng(1))
    rows = []
    for noise in (0.0, 0.05, 0.2):
        obs = synthetic_charuco_observations(rig, spec, poses, noise, np.random.default_rng(5))
        result = calibrate_cameras(obs, spec)
        s = evaluate_calibration(result.rig, rig)
        rows.append([noise, result.rms_px, s["overall"]["center_err_mm"], s["max"]["center_err_mm"],
                     s["overall"]["rot_err_deg"], s["max"]["rot_err_deg"], s["max"]["focal_err_pct"]])
    return markdown_table(["noise px", "RMS px", "centre mm (mean)", "centre mm (max)", "rot deg (mean)",
                           "rot deg (max)", "focal % (max)"], rows)


def _rendered_case(tmp, n_cameras: int, n_poses: int) -> list:
    from bodystudio.calib.board import load_board_json
    from bodystudio.calib.observations import detect_capture
    from bodystudio.calib.synthetic import write_synthetic_calibration
    from bodystudio.geometry.camera import load_cameras_json

    t0 = time.perf_counter()
    write_synthetic_calibration(tmp, n_cameras, n_poses, seed=0 if n_cameras >= 10 else 3)
    t_render = time.perf_counter() - t0
    spec = load_board_json(tmp / "board.json")
    t0 = time.perf_counter()
    obs, _ = detect_capture(tmp, spec)
    t_detect = time.perf_counter() - t0
    result = calibrate_cameras(obs, spec)
    scores = evaluate_calibration(result.rig, load_cameras_json(tmp / "gt" / "cameras.json"))
    row = _row(f"rendered {n_cameras} cams x {n_poses} poses: detect + BA", scores, result.rms_px, "-",
               t_detect + result.seconds)
    return row, t_render, t_detect, len(obs), int((~result.inliers).sum())


def _depth_case(n_poses: int) -> str:
    from bodystudio.calib.depth import calibrate_rgbd_sensor, rgbd_board_poses, synthetic_rgbd_views
    from bodystudio.calib.world import rotation_angle_deg
    from bodystudio.geometry.camera import kinect_v2

    spec = CharucoBoardSpec()
    sensor = kinect_v2()
    rng = np.random.default_rng(2)
    poses = rgbd_board_poses(sensor, spec, n_poses, rng)
    views = synthetic_rgbd_views(sensor, spec, poses, NOISE_PX, rng)
    t0 = time.perf_counter()
    est, report = calibrate_rgbd_sensor(sensor, spec, views, list(poses), rng)
    seconds = time.perf_counter() - t0
    D, G = est.depth_to_color, sensor.depth_to_color
    row = [f"Kinect v2, {len(views)} board poses", 1000 * np.linalg.norm(D[:3, 3] - G[:3, 3]),
           rotation_angle_deg(D[:3, :3] @ G[:3, :3].T), 1000 * np.linalg.norm(est.color.center - sensor.color.center),
           1000 * np.linalg.norm(est.depth.center - sensor.depth.center), float(np.mean(report["plane_rms_mm"])),
           seconds]
    return markdown_table(["case", "depth->colour t err mm", "depth->colour rot err deg", "colour centre err mm",
                           "depth centre err mm", "plane fit RMS mm", "time s"], [row])


#: The uncertainty validation's 20 rendered captures of varying quality: (cameras, poses, width, seed,
#: blur px, sensor noise grey levels). The first is the issue's known bad case (4 cameras x 12 poses at
#: 640x480, seed 0: 70 mm off with 0.41 px RMS before the verdict existed).
UNCERTAINTY_CASES = (
    (4, 12, 640, 0, 0.7, 2.0), (4, 12, 640, 1, 0.7, 2.0), (4, 12, 640, 2, 1.2, 4.0), (3, 8, 640, 0, 0.7, 2.0),
    (3, 10, 640, 1, 0.7, 4.0), (5, 15, 640, 0, 0.7, 2.0), (6, 18, 640, 1, 1.0, 2.0), (4, 20, 640, 3, 0.7, 2.0),
    (6, 20, 960, 0, 0.7, 2.0), (6, 12, 960, 1, 0.7, 5.0), (4, 16, 960, 2, 0.7, 2.0), (8, 24, 960, 0, 1.0, 2.0),
    (5, 10, 960, 3, 0.5, 1.0), (6, 20, 1280, 0, 0.7, 2.0), (4, 12, 1280, 1, 0.7, 2.0), (8, 24, 1280, 2, 0.7, 3.0),
    (10, 30, 1280, 1, 0.7, 2.0), (3, 6, 1280, 0, 0.7, 2.0), (5, 15, 1280, 4, 1.2, 4.0), (10, 20, 1280, 3, 0.7, 2.0),
    # Spares: captures the calibration refuses (a camera never co-visible, no floor board) have no sigma
    # to check, so these keep >= 20 calibrated captures.
    (5, 14, 640, 5, 0.7, 2.0), (6, 16, 960, 6, 1.0, 3.0), (4, 14, 1280, 7, 0.7, 2.0), (7, 21, 960, 8, 0.7, 2.0),
)


def uncertainty_validation(workdir, cases=UNCERTAINTY_CASES) -> tuple[str, dict]:
    """Render, detect and calibrate each capture; per camera compare the predicted 1-sigma with the true
    error (``evaluate.uncertainty_consistency``), and count how many errors fall within 1, 2, 3 sigma.
    Returns (markdown table, totals)."""
    from pathlib import Path

    from bodystudio.calib.board import load_board_json
    from bodystudio.calib.evaluate import uncertainty_consistency
    from bodystudio.calib.observations import detect_capture
    from bodystudio.calib.synthetic import write_synthetic_calibration
    from bodystudio.errors import BodyStudioError
    from bodystudio.geometry.camera import load_cameras_json

    rows, n_cams, n_within, n_flagged, n_bad_unflagged, maha, z, view_px = [], 0, 0, 0, 0, [], [], []
    for cams, poses, width, seed, blur, noise in cases:
        folder = Path(workdir) / f"c{cams}_p{poses}_w{width}_s{seed}_b{blur}_n{noise}"
        label = f"{cams} x {poses} @ {width}, seed {seed}, blur {blur}, noise {noise}"
        if not (folder / "gt" / "cameras.json").is_file():
            write_synthetic_calibration(folder, cams, poses, seed, width, width * 3 // 4, blur_px=blur,
                                        noise_dn=noise)
        spec = load_board_json(folder / "board.json")
        try:
            obs, _ = detect_capture(folder, spec)
            result = calibrate_cameras(obs, spec)
        except BodyStudioError as e:
            rows.append([label, "refused: " + str(e)[:60]] + [""] * 8)
            continue
        gt = load_cameras_json(folder / "gt" / "cameras.json")
        cons = uncertainty_consistency(result.rig, gt, result.uncertainty)
        v = list(cons.values())
        n_cams += len(v)
        n_within += sum(c["within_3sigma"] for c in v)
        flagged = [c["verdict"] != "ok" for c in v]
        n_flagged += sum(flagged)
        n_bad_unflagged += sum(c["center_err_mm"] > 6.0 and c["verdict"] == "ok" for c in v)
        maha += [c["center_mahalanobis2"] for c in v]
        z += [c[f"{k}_z"] for c in v for k in ("fx", "fy", "cx", "cy")]
        view_px.append(result.uncertainty.view_sigma_px)
        worst = max(v, key=lambda c: c["center_err_mm"])
        rows.append([label, f"{result.rms_px:.3f}", f"{result.uncertainty.view_sigma_px:.3f}",
                     f"{np.mean([c['center_sigma_mm'] for c in v]):.2f}",
                     f"{np.mean([c['center_err_mm'] for c in v]):.2f}",
                     f"{worst['center_err_mm']:.2f} / {worst['center_sigma_mm']:.2f}",
                     f"{max(c['fx_z'] for c in v):.1f} / {max(c['fy_z'] for c in v):.1f} / "
                     f"{max(c['cx_z'] for c in v):.1f} / {max(c['cy_z'] for c in v):.1f}",
                     f"{max(c['center_mahalanobis2'] for c in v):.1f}",
                     f"{sum(c['within_3sigma'] for c in v)}/{len(v)}", f"{sum(flagged)}/{len(v)}"])
    table = markdown_table(["capture (cams x poses @ width)", "RMS px", "view field px", "centre sigma mm (mean)",
                            "centre err mm (mean)", "worst centre err / sigma mm", "max |z| fx / fy / cx / cy",
                            "max centre Mahalanobis^2", "cameras within 3 sigma", "cameras flagged"], rows)
    totals = {"captures_calibrated": sum(1 for r in rows if r[3]), "cameras": n_cams, "within_3sigma": n_within,
              "flagged": n_flagged, "large_error_not_flagged": n_bad_unflagged,
              "mean_centre_mahalanobis2": float(np.mean(maha)) if maha else float("nan"),
              "rms_z_intrinsics": float(np.sqrt(np.mean(np.square(z)))) if z else float("nan"),
              "mean_view_sigma_px": float(np.mean(view_px)) if view_px else float("nan"),
              **coverage_at_k_sigma(maha, z)}
    return table, totals


#: chi-square (3 dof) quantiles at the probabilities of |z| <= 1, 2, 3 for one normal variable.
CHI2_3DOF_K_SIGMA = {1: 3.527, 2: 8.025, 3: 14.156}


def coverage_at_k_sigma(centre_mahalanobis2, intrinsics_z) -> dict:
    """Share of centre errors (Mahalanobis^2 against the chi-square quantile) and of intrinsics errors
    (|z|) within 1, 2 and 3 sigma: 68.3 / 95.4 / 99.7 % when the sigmas are right, so a sigma that is
    3x too big shows as ~100 % at 1 sigma and one too small as too little at 3."""
    m, z = np.asarray(centre_mahalanobis2, float), np.asarray(intrinsics_z, float)
    out = {}
    for k, q in CHI2_3DOF_K_SIGMA.items():
        out[f"centre_within_{k}sigma_pct"] = float(100 * np.mean(m <= q)) if len(m) else float("nan")
        out[f"intrinsics_within_{k}sigma_pct"] = float(100 * np.mean(z <= k)) if len(z) else float("nan")
    return out


def run(quick: bool = False) -> str:
    import tempfile
    from pathlib import Path

    header = ["method", "RMS px", "expected RMS px", "centre mm (mean)", "centre mm (max)", "rot deg (mean)",
              "rot deg (max)", "focal % (mean)", "focal % (max)", "volume reproj px", "time s"]
    n_cams, n_poses = (6, 15) if quick else (10, 30)
    spec = board_for_resolution(1280)
    seeds = (1, 2) if quick else tuple(range(1, 7))
    repeats = 1 if quick else 5
    rows, n_obs = _synthetic_case(n_cams, n_poses, 1280, 960, seed=1, repeats=repeats)
    rows_vga, n_obs_vga = _synthetic_case(n_cams, n_poses, 640, 480, seed=1, repeats=1)
    with tempfile.TemporaryDirectory() as tmp:
        rendered, t_render, t_detect, n_det, n_out = _rendered_case(Path(tmp), *((4, 12) if quick else (10, 30)))
    text = [f"## calib: multi-camera calibration ({n_cams} cameras, {n_poses} board poses)",
            "",
            f"Synthetic ChArUco corners ({spec.squares_x}x{spec.squares_y} board, {spec.square_m} m squares, "
            "poses planned by the studio protocol: 4 floor boards, then tilted boards covering every image) "
            f"on the `ring_rig` studio at 1280x960 with {NOISE_PX} px Gaussian noise: "
            f"{n_obs} corner observations. Errors against ground truth in the floor-board world frame (no "
            "alignment); *expected RMS* is sigma * sqrt(2 (m - p) / m) for m residuals and p parameters; "
            "*volume reproj* is the GT-vs-estimate pixel distance of points filling the capture volume. Time: "
            f"median of {max(repeats, 5) if repeats > 1 else 1} runs, BLAS on one thread.",
            "",
            markdown_table(header, rows),
            "",
            f"Same layout at 640x480 with the VGA board (7x5 squares of 0.14 m; {n_obs_vga} observations, "
            "single run):",
            "",
            markdown_table(header, rows_vga),
            "",
            f"The same case over pose plans and noise draws (seeds {seeds[0]}-{seeds[-1]}, single runs; seed 1 is "
            "the table above; *mean* / *worst* are over the seeds):",
            "",
            _seed_spread(n_cams, n_poses, seeds),
            "",
            "Error against corner noise (same poses, fresh noise): the bundle adjustment recovers the rig "
            "exactly from exact corners and its error grows linearly with the noise, i.e. what remains is "
            "the information the board poses carry, not a bias:",
            "",
            _noise_scaling(n_cams, n_poses),
            "",
            f"Image pipeline: {rendered[0]} ({n_det} corners detected, {n_out} rejected as outliers; rendering "
            f"took {t_render:.1f} s, detection {t_detect:.1f} s, single run):",
            "",
            markdown_table(header, [rendered]),
            "",
            "Depth camera (Kinect v2 noise: 1/8 px disparity quantisation, sigma_Z = 1.425e-3 Z^2): depth->colour "
            "extrinsics from RANSAC board planes in depth and colour ChArUco corners; sensor->studio by PnP on "
            "the boards' world corners (exact board poses here; in a session they come from the studio BA):",
            "",
            _depth_case(8),
            "",
            "Command: `.venv/bin/python -m benchmarks.run --only calib`."]
    return "\n".join(text)


#: Held-out captures (seeds 10-23, none of them used while the error model was chosen) for
#: ``python -m benchmarks.bench_calib WORKDIR --held-out``.
HELD_OUT_CASES = (
    (6, 20, 1280, 10, 0.7, 2.0), (8, 24, 960, 22, 1.0, 2.0), (6, 20, 960, 13, 0.7, 2.0), (4, 14, 1280, 23, 0.7, 2.0),
    (5, 15, 1280, 15, 1.2, 4.0), (7, 21, 960, 18, 0.7, 2.0), (4, 12, 640, 14, 0.7, 2.0), (5, 10, 960, 19, 0.5, 1.0),
    (6, 12, 960, 20, 0.7, 5.0), (4, 20, 640, 21, 0.7, 2.0), (4, 16, 960, 17, 0.7, 2.0), (8, 24, 1280, 12, 0.7, 3.0),
)


if __name__ == "__main__":  # the uncertainty validation alone: python -m benchmarks.bench_calib WORKDIR [--held-out]
    import json
    import sys

    args = [a for a in sys.argv[1:] if not a.startswith("--")]
    table, totals = uncertainty_validation(args[0] if args else "/tmp/calib_uncertainty",
                                           HELD_OUT_CASES if "--held-out" in sys.argv else UNCERTAINTY_CASES)
    print(table)
    print(json.dumps(totals))
