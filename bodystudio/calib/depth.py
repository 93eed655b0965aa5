"""RGB-D (Kinect) calibration from ChArUco boards seen by the colour camera and the depth camera.

Depth -> colour extrinsics are solved from planes (Unnikrishnan & Hebert 2005, "Fast extrinsic
calibration of a laser rangefinder to a camera"; also Herrera et al. 2012): in every board pose the
colour camera gives the board's pose from its ChArUco corners (PnP), the depth camera gives the
board's plane (RANSAC plane fit of the depth points inside the board's region). Rotation aligns the
plane normals (Kabsch), translation follows linearly from the plane offsets, and a final
least-squares refinement puts the colour-frame board corners onto the depth planes. Kinect -> studio
extrinsics come from one PnP of all board corners (known in the world from the studio calibration)
against the Kinect colour detections.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.optimize import least_squares

from bodystudio.calib.board import CharucoBoardSpec, board_corners
from bodystudio.calib.render import board_pose_facing, render_board_depth, render_board_view, visible_corners, write_png
from bodystudio.calib.world import rigid, rigid_inverse, rvec_t_to_rigid
from bodystudio.errors import SessionError
from bodystudio.fileio import is_frame_number
from bodystudio.geometry.camera import Camera, RGBDSensor

log = logging.getLogger(__name__)


@dataclass(frozen=True, eq=False)
class RGBDBoardView:
    """One board pose seen by an RGB-D sensor: colour ChArUco corners and the depth image (metres, 0 = none)."""

    corner_ids: np.ndarray
    corners_px: np.ndarray
    depth_m: np.ndarray


def fit_plane_ransac(points: np.ndarray, threshold_m: float, rng: np.random.Generator,
                     iterations: int = 200) -> tuple[np.ndarray, float, np.ndarray]:
    """Plane ``n . x + d = 0`` (unit n, d >= 0: the normal faces the sensor origin) through points (N, 3)
    by RANSAC on 3-point samples, refined by least squares (SVD) on the inliers. Returns (n, d, inliers)."""
    if len(points) < 3:
        raise SessionError("too few depth points on the board to fit its plane; move the board closer to the sensor")
    best = None
    for _ in range(iterations):
        p = points[rng.choice(len(points), 3, replace=False)]
        n = np.cross(p[1] - p[0], p[2] - p[0])
        norm = np.linalg.norm(n)
        if norm < 1e-12:
            continue
        n /= norm
        inliers = np.abs(points @ n - n @ p[0]) < threshold_m
        if best is None or inliers.sum() > best.sum():
            best = inliers
    for _ in range(3):
        q = points[best]
        c = q.mean(0)
        n = np.linalg.svd(q - c, full_matrices=False)[2][2]
        best = np.abs((points - c) @ n) < threshold_m
    d = -float(n @ c)
    if d < 0:
        n, d = -n, -d
    return n, d, best


def _board_outline(spec: CharucoBoardSpec) -> np.ndarray:
    w, h = spec.size_m
    return np.array([[0, 0, 0], [w, 0, 0], [w, h, 0], [0, h, 0.0]])


def board_depth_points(depth_m: np.ndarray, depth_cam: Camera, board_in_depth: np.ndarray, spec: CharucoBoardSpec,
                       shrink: float) -> np.ndarray:
    """Depth-camera-frame points (N, 3) of the depth pixels inside the board outline shrunk about its centre.

    ``board_in_depth`` is the (estimated) board->depth-camera transform; shrinking keeps the region
    on the board despite an error in that estimate.
    """
    outline = _board_outline(spec)
    outline = spec.center_m + shrink * (outline - spec.center_m)
    P = outline @ board_in_depth[:3, :3].T + board_in_depth[:3, 3]
    cam0 = Camera(depth_cam.name, depth_cam.K, depth_cam.dist, np.eye(3), np.zeros(3), depth_cam.width,
                  depth_cam.height)
    poly = cam0.project(P)
    mask = np.zeros(depth_m.shape, np.uint8)
    if np.all(np.isfinite(poly)):
        cv2.fillConvexPoly(mask, np.round(poly).astype(np.int32), 1)
    mask &= (depth_m > 0).astype(np.uint8)
    v, u = np.nonzero(mask)
    if len(u) == 0:
        return np.zeros((0, 3))
    xy = cam0.undistort_points(np.c_[u, v].astype(float), normalized=True)
    z = depth_m[v, u]
    return np.c_[xy * z[:, None], z]


def color_board_pose(view: RGBDBoardView, color: Camera, spec: CharucoBoardSpec) -> np.ndarray:
    """Board->colour-camera transform from the colour ChArUco corners (IPPE, then iterative PnP)."""
    P = board_corners(spec)[view.corner_ids]
    ok, rvec, tvec = cv2.solvePnP(P, view.corners_px, color.K, color.dist, flags=cv2.SOLVEPNP_IPPE)
    ok, rvec, tvec = cv2.solvePnP(P, view.corners_px, color.K, color.dist, rvec, tvec, useExtrinsicGuess=True)
    return rvec_t_to_rigid(rvec, tvec)


def depth_to_color_from_planes(normals_d: np.ndarray, offsets_d: np.ndarray, normals_c: np.ndarray,
                               offsets_c: np.ndarray) -> np.ndarray:
    """Closed form x_c = R x_d + t from >= 3 non-parallel planes seen in both frames (Unnikrishnan & Hebert):
    R by Kabsch on the normals, t from n_c . t = d_d - d_c."""
    H = normals_d.T @ normals_c
    U, _, Vt = np.linalg.svd(H)
    R = Vt.T @ np.diag([1, 1, np.sign(np.linalg.det(Vt.T @ U.T))]) @ U.T
    t = np.linalg.lstsq(normals_c, offsets_d - offsets_c, rcond=None)[0]
    return rigid(R, t)


def calibrate_depth_to_color(views: list[RGBDBoardView], depth_cam: Camera, color: Camera, spec: CharucoBoardSpec,
                             rng: np.random.Generator | None = None, initial: np.ndarray | None = None,
                             plane_threshold_m: float = 0.02) -> tuple[np.ndarray, dict]:
    """Depth->colour 4x4 transform from board views; returns it and a report (plane RMS per view, mm).

    ``depth_cam`` and ``color`` supply intrinsics (their poses are ignored). ``initial`` (default:
    identity, i.e. the two cameras about co-located) only picks the board region in the first pass.
    """
    rng = rng or np.random.default_rng(0)
    if len(views) < 3:
        raise SessionError(f"depth calibration needs at least 3 board poses seen by colour and depth, got "
                           f"{len(views)}; capture the board tilted in different directions")
    board_in_color = [color_board_pose(v, color, spec) for v in views]
    T = np.eye(4) if initial is None else np.asarray(initial, float)
    corners = board_corners(spec)
    for shrink in (0.6, 0.85):
        planes, used = [], []
        for k, v in enumerate(views):
            pts = board_depth_points(v.depth_m, depth_cam, rigid_inverse(T) @ board_in_color[k], spec, shrink)
            if len(pts) < 50:
                continue
            n, d, inl = fit_plane_ransac(pts, plane_threshold_m, rng)
            planes.append((n, d, pts[inl]))
            used.append(k)
        if len(used) < 3:
            raise SessionError(f"the board was found in depth in only {len(used)} poses; capture it within the "
                               "depth camera's range (0.5-4.5 m) in at least 3 tilted poses")
        n_d = np.array([p[0] for p in planes])
        d_d = np.array([p[1] for p in planes])
        n_c = np.array([board_in_color[k][:3, 2] for k in used])
        d_c = np.array([-board_in_color[k][:3, 2] @ board_in_color[k][:3, 3] for k in used])
        neg = d_c < 0  # orient colour normals like the depth ones: towards the sensor (d >= 0)
        n_c[neg], d_c[neg] = -n_c[neg], -d_c[neg]
        T = depth_to_color_from_planes(n_d, d_d, n_c, d_c)
        # Refine: colour-frame board corners must lie on their depth planes.
        Xc = [corners @ board_in_color[k][:3, :3].T + board_in_color[k][:3, 3] for k in used]

        def residuals(x, Xc=Xc, planes=planes):
            M = rvec_t_to_rigid(x[:3], x[3:])
            Minv = rigid_inverse(M)
            return np.concatenate([(X @ Minv[:3, :3].T + Minv[:3, 3]) @ n + d
                                   for X, (n, d, _) in zip(Xc, planes, strict=True)])

        x0 = np.r_[cv2.Rodrigues(T[:3, :3])[0].ravel(), T[:3, 3]]
        sol = least_squares(residuals, x0, loss="soft_l1", f_scale=0.005)
        T = rvec_t_to_rigid(sol.x[:3], sol.x[3:])
    plane_rms = [float(1000 * np.sqrt(np.mean((p[2] @ p[0] + p[1]) ** 2))) for p in planes]
    report = {"n_views": len(used), "plane_rms_mm": plane_rms,
              "corner_to_plane_rms_mm": float(1000 * np.sqrt(np.mean(sol.fun ** 2)))}
    return T, report


def sensor_to_studio(color: Camera, spec: CharucoBoardSpec, views: list[RGBDBoardView],
                     board_to_world: list[np.ndarray]) -> np.ndarray:
    """World->colour-camera 4x4 transform from one PnP of every board corner (world coordinates from the
    studio calibration's board poses) against the Kinect colour detections."""
    P, uv, shared = [], [], []
    for k, (v, T) in enumerate(zip(views, board_to_world, strict=True)):
        if np.all(np.isfinite(T)):  # NaN: a pose the studio did not see
            P.append(board_corners(spec)[v.corner_ids] @ T[:3, :3].T + T[:3, 3])
            uv.append(v.corners_px)
            shared.append(k)
    if not P:
        raise SessionError("no Kinect colour view shares a board pose with the studio cameras; capture boards "
                           "seen by the Kinect and the studio at the same time")
    P, uv = np.concatenate(P), np.concatenate(uv)
    # Start from the first shared view's planar pose, then refine on all (non-coplanar) points.
    first = color_board_pose(views[shared[0]], color, spec) @ rigid_inverse(board_to_world[shared[0]])
    rvec, tvec = cv2.Rodrigues(first[:3, :3])[0], first[:3, 3].reshape(3, 1).copy()
    ok, rvec, tvec = cv2.solvePnP(P, uv, color.K, color.dist, rvec, tvec, useExtrinsicGuess=True)
    return rvec_t_to_rigid(rvec, tvec)


def calibrate_rgbd_sensor(sensor: RGBDSensor, spec: CharucoBoardSpec, views: list[RGBDBoardView],
                          board_to_world: list[np.ndarray] | None = None,
                          rng: np.random.Generator | None = None) -> tuple[RGBDSensor, dict]:
    """Calibrated copy of ``sensor`` (intrinsics kept): depth->colour from board planes and, when the
    studio's board poses are given, both cameras' poses in the studio frame."""
    D, report = calibrate_depth_to_color(views, sensor.depth, sensor.color, spec, rng)
    color, depth = sensor.color, sensor.depth
    if board_to_world is not None:
        W = sensor_to_studio(sensor.color, spec, views, board_to_world)
        color = Camera(color.name, color.K, color.dist, W[:3, :3], W[:3, 3], color.width, color.height)
        Wd = rigid_inverse(D) @ W
        depth = Camera(depth.name, depth.K, depth.dist, Wd[:3, :3], Wd[:3, 3], depth.width, depth.height)
    out = RGBDSensor(sensor.name, sensor.version, depth, color, D, sensor.baseline_m, sensor.depth_range_m)
    return out, report


# --- synthetic RGB-D board views --------------------------------------------------------------------

def synthetic_rgbd_views(sensor: RGBDSensor, spec: CharucoBoardSpec, board_to_world: np.ndarray, noise_px: float,
                         rng: np.random.Generator) -> list[RGBDBoardView]:
    """Colour ChArUco corners (Gaussian pixel noise) and Kinect-noise depth images of boards in front of a sensor."""
    from bodystudio.capture.kinect import quantized_disparity_depth

    views = []
    for T in board_to_world:
        vis = visible_corners(sensor.color, spec, T)
        if vis.sum() < 6:
            continue
        ids = np.flatnonzero(vis)
        uv = sensor.color.project(board_corners(spec)[ids] @ T[:3, :3].T + T[:3, 3])
        uv = uv + rng.normal(0, noise_px, uv.shape)
        z = render_board_depth(sensor.depth, spec, T)
        z = quantized_disparity_depth(z, sensor.depth.fx, sensor.baseline_m, rng)
        views.append(RGBDBoardView(ids, uv, z))
    return views


def rgbd_board_poses(sensor: RGBDSensor, spec: CharucoBoardSpec, n_poses: int, rng: np.random.Generator) -> np.ndarray:
    """Board poses 1.2-2.5 m in front of the sensor, tilted up to ~35 degrees in varied directions."""
    poses = []
    c = sensor.color
    forward = c.R[2]
    while len(poses) < n_poses:
        dist = rng.uniform(1.4, 2.5)
        center = c.center + forward * dist + c.R[0] * rng.uniform(-0.25, 0.25) + c.R[1] * rng.uniform(-0.2, 0.2)
        tilt = rng.normal(0, 0.35, 2)
        facing = -forward + c.R[0] * tilt[0] + c.R[1] * tilt[1]
        T = board_pose_facing(center, facing, rng.uniform(-0.3, 0.3), spec)
        if visible_corners(c, spec, T).sum() == spec.n_corners:
            poses.append(T)
    return np.array(poses)


# --- capture folders ----------------------------------------------------------------------------------

def detect_rgbd_capture(folder, spec: CharucoBoardSpec, min_corners: int = 6) -> tuple[list[int], list[RGBDBoardView]]:
    """Board views of ``FOLDER/kinect/rgb/FFFFF.png`` + ``FOLDER/kinect/depth/FFFFF.png`` (16-bit mm).

    Frames whose colour image shows no board are skipped. Returns (frame numbers, views).
    """
    from pathlib import Path

    from bodystudio.calib.board import detect_charuco, read_image_grey
    from bodystudio.capture.kinect import read_depth_png

    folder = Path(folder)
    rgb_dir, depth_dir = folder / "kinect" / "rgb", folder / "kinect" / "depth"
    if not rgb_dir.is_dir() or not depth_dir.is_dir():
        raise SessionError(f"{folder}: no kinect/rgb and kinect/depth folders; record the boards with the Kinect too")
    frames, views = [], []
    for rgb in sorted(rgb_dir.glob("*.png")):
        if not is_frame_number(rgb.stem):
            continue
        depth_path = depth_dir / rgb.name
        if not depth_path.is_file():
            raise SessionError(f"camera kinect: frame {rgb.stem} has a colour image but no depth image "
                               f"({depth_path}); export both streams")
        det = detect_charuco(read_image_grey(rgb), spec, min_corners)
        if det.n_corners:
            frames.append(int(rgb.stem))
            views.append(RGBDBoardView(det.corner_ids, det.corners_px, read_depth_png(depth_path).astype(np.float64)))
    if not views:
        raise SessionError(f"camera kinect: no ChArUco board found in {rgb_dir}; capture the board in front of "
                           "the Kinect")
    return frames, views


def write_synthetic_kinect_views(out, sensor: RGBDSensor, spec: CharucoBoardSpec, board_to_world: np.ndarray,
                                 rng: np.random.Generator, progress=None) -> int:
    """Render the Kinect's colour images and noisy depth of every board pose into ``out/kinect/{rgb,depth}``."""
    from pathlib import Path

    from bodystudio.capture.kinect import quantized_disparity_depth, write_depth_png

    out = Path(out)
    task = progress.add_task("rendering Kinect colour + depth", total=len(board_to_world)) if progress else None
    n_seen = 0
    for f, T in enumerate(board_to_world):
        n_seen += int(visible_corners(sensor.color, spec, T).sum() >= 6)
        write_png(out / "kinect" / "rgb" / f"{f:05d}.png", render_board_view(sensor.color, spec, T, rng))
        z = render_board_depth(sensor.depth, spec, T)
        z = quantized_disparity_depth(z, sensor.depth.fx, sensor.baseline_m, rng)
        write_depth_png(out / "kinect" / "depth" / f"{f:05d}.png", z)
        if task is not None:
            progress.advance(task)
    return n_seen
