"""Synthetic ChArUco calibration captures with ground truth.

Board poses are drawn in the middle of the capture volume, each facing a group of neighbouring
cameras, plus one board lying on the floor (frame 0) that defines the world frame. Images are
rendered by inverse mapping: every (super-sampled) pixel's undistorted viewing ray is intersected
with the board plane and the board texture sampled there, so lens distortion is exact; then blur,
uneven light and sensor noise are applied.
"""

from __future__ import annotations

import functools
import logging
import os
from pathlib import Path

import cv2
import numpy as np

from bodystudio.calib.board import CharucoBoardSpec, board_corners, board_image, board_texture_px_per_m, save_board_json
from bodystudio.calib.observations import CharucoObservations, observations_from_views
from bodystudio.calib.world import floor_board_to_world
from bodystudio.errors import InputError
from bodystudio.fileio import atomic_write, write_json
from bodystudio.geometry.camera import Camera, CameraRig, ring_rig, save_cameras_json

log = logging.getLogger(__name__)

MAX_VIEW_ANGLE_DEG = 70.0  # beyond this obliquity a printed board is not detected reliably


def board_pose_facing(center, facing, roll_rad: float, spec: CharucoBoardSpec) -> np.ndarray:
    """4x4 board->world transform with the board centre at ``center`` and its printed face towards ``facing``."""
    n = np.asarray(facing, float)
    n = n / np.linalg.norm(n)
    z = -n  # the printed face looks along the board's -z
    right = np.cross(z, [0.0, 1.0, 0.0])
    if np.linalg.norm(right) < 1e-6:
        right = np.array([1.0, 0.0, 0.0])
    right /= np.linalg.norm(right)
    down = np.cross(z, right)
    c, s = np.cos(roll_rad), np.sin(roll_rad)
    x, y = c * right + s * down, -s * right + c * down
    T = np.eye(4)
    T[:3, :3] = np.stack([x, y, z], axis=1)
    T[:3, 3] = np.asarray(center, float) - T[:3, :3] @ spec.center_m
    return T


def visible_corners(camera: Camera, spec: CharucoBoardSpec, board_to_world: np.ndarray, margin_px: float = 4.0,
                    min_square_px: float = 9.0) -> np.ndarray:
    """Mask of the board corners a detector could find: board facing the camera, not too oblique,
    squares large enough for the markers to decode, corner inside the image."""
    R, t = board_to_world[:3, :3], board_to_world[:3, 3]
    to_cam = camera.center - (R @ board_corners(spec).mean(axis=0) + t)
    n_face = -R[:, 2]
    cos_angle = to_cam @ n_face / np.linalg.norm(to_cam)
    corners = board_corners(spec)
    if cos_angle < np.cos(np.radians(MAX_VIEW_ANGLE_DEG)):
        return np.zeros(len(corners), bool)
    P = corners @ R.T + t
    uv, z = camera.project_with_depth(P)
    if np.any(z <= 0.05):
        return np.zeros(len(corners), bool)
    # Foreshortened square size: the projected board area per square.
    hull = cv2.convexHull(uv.astype(np.float32))
    n_squares = (spec.squares_x - 2) * (spec.squares_y - 2)
    if np.sqrt(cv2.contourArea(hull) / n_squares) < min_square_px:
        return np.zeros(len(corners), bool)
    inside = ((uv[:, 0] >= margin_px) & (uv[:, 0] <= camera.width - 1 - margin_px)
              & (uv[:, 1] >= margin_px) & (uv[:, 1] <= camera.height - 1 - margin_px))
    return inside


def calibration_board_poses(rig: CameraRig, spec: CharucoBoardSpec, n_poses: int, rng: np.random.Generator,
                            min_cameras: int = 2, volume_radius_m: float = 1.1,
                            min_visible_fraction: float = 1.0, heights_m: tuple[float, float] = (0.5, 1.8),
                            elevation_rad: tuple[float, float] = (-0.5, 0.7)) -> np.ndarray:
    """(n_poses, 4, 4) board->world transforms: frame 0 lies on the floor, the rest face camera groups."""
    if n_poses < 2:
        raise InputError(f"a calibration capture needs at least 2 board poses, got {n_poses}")
    poses = [floor_board_to_world(spec)]
    centers = rig.centers()
    attempts = 0
    while len(poses) < n_poses:
        attempts += 1
        if attempts > 200 * n_poses:
            raise InputError("cannot place boards seen by several cameras in this rig; check the rig layout")
        # Cycle the facing direction around the ring so every camera group gets boards.
        k = len(poses) - 1
        azimuth = 2 * np.pi * (k + rng.uniform(-0.3, 0.3)) / max(n_poses - 1, 1) * 2.0
        toward = np.array([np.sin(azimuth), 0.0, np.cos(azimuth)])
        # Boards nearer the cameras they face, at many heights and strongly tilted: tilt and image-wide
        # coverage are what separate focal length from distance and principal point from rotation.
        center = toward * rng.uniform(0.2, volume_radius_m) + np.array([0.0, rng.uniform(*heights_m), 0.0])
        elevation = rng.uniform(*elevation_rad)
        yaw = rng.uniform(-0.8, 0.8)
        cy, sy = np.cos(yaw), np.sin(yaw)
        toward_yawed = np.array([cy * toward[0] + sy * toward[2], 0.0, -sy * toward[0] + cy * toward[2]])
        facing = toward_yawed * np.cos(elevation) + np.array([0.0, np.sin(elevation), 0.0])
        pose = board_pose_facing(center, facing, rng.uniform(-0.6, 0.6), spec)
        n_seen = sum(visible_corners(cam, spec, pose).sum() >= min_visible_fraction * spec.n_corners for cam in rig)
        if n_seen >= min_cameras:
            poses.append(pose)
    del centers
    return np.array(poses)


def synthetic_charuco_observations(rig: CameraRig, spec: CharucoBoardSpec, board_poses: np.ndarray,
                                   noise_px: float, rng: np.random.Generator, min_corners: int = 6,
                                   outlier_fraction: float = 0.0) -> CharucoObservations:
    """Corner observations of the boards in every camera with Gaussian pixel noise (no rendering).

    ``outlier_fraction`` of the observations are displaced by 5-20 px (a mis-detected corner).
    """
    corners = board_corners(spec)
    views = {}
    for c, cam in enumerate(rig):
        for f, T in enumerate(board_poses):
            vis = visible_corners(cam, spec, T)
            if vis.sum() < min_corners:
                continue
            ids = np.flatnonzero(vis)
            uv = cam.project(corners[ids] @ T[:3, :3].T + T[:3, 3])
            uv = uv + rng.normal(0.0, noise_px, uv.shape)
            if outlier_fraction > 0:
                bad = rng.random(len(ids)) < outlier_fraction
                direction = rng.normal(size=(bad.sum(), 2))
                direction /= np.linalg.norm(direction, axis=1, keepdims=True)
                uv[bad] += direction * rng.uniform(5, 20, (bad.sum(), 1))
            views[(c, f)] = (ids, uv)
    return observations_from_views(rig.names, [c.image_size for c in rig], range(len(board_poses)), views)


# --- rendering ----------------------------------------------------------------------------------

@functools.lru_cache(maxsize=2)
def _supersampled_rays(camera_key: tuple, supersample: int, step_px: int = 4) -> np.ndarray:
    """Undistorted normalised coordinates (H*s, W*s, 2) of the sub-pixel sample centres.

    Lens undistortion is exact on a grid every ``step_px`` pixels and bilinearly interpolated between
    (the distortion field is smooth: the interpolation error is below 0.01 px for studio lenses).
    """
    K, dist, width, height = np.array(camera_key[0]).reshape(3, 3), np.array(camera_key[1]), *camera_key[2:]
    cam = Camera("ray_cache", K, dist, np.eye(3), np.zeros(3), width, height)
    gu = np.arange(-step_px, width + 2 * step_px, step_px, dtype=np.float64)
    gv = np.arange(-step_px, height + 2 * step_px, step_px, dtype=np.float64)
    guu, gvv = np.meshgrid(gu, gv)
    coarse = cam.undistort_points(np.c_[guu.ravel(), gvv.ravel()], normalized=True)
    coarse = coarse.reshape(len(gv), len(gu), 2).astype(np.float32)
    offsets = (np.arange(supersample) + 0.5) / supersample - 0.5
    us = (np.arange(width)[:, None] + offsets[None]).ravel()
    vs = (np.arange(height)[:, None] + offsets[None]).ravel()
    map_u = np.broadcast_to(((us - gu[0]) / step_px).astype(np.float32), (len(vs), len(us)))
    map_v = np.broadcast_to(((vs - gv[0]) / step_px).astype(np.float32)[:, None], (len(vs), len(us)))
    return cv2.remap(coarse, np.ascontiguousarray(map_u), np.ascontiguousarray(map_v), cv2.INTER_LINEAR)


def _camera_key(cam: Camera) -> tuple:
    return (tuple(cam.K.ravel()), tuple(cam.dist), cam.width, cam.height)


@functools.lru_cache(maxsize=8)
def _texture(spec: CharucoBoardSpec, px_per_m: float, margin_m: float) -> tuple[np.ndarray, float, float]:
    img = board_image(spec, px_per_m=px_per_m, margin_m=margin_m).astype(np.float32)
    ppm = board_texture_px_per_m(spec, px_per_m)
    pad_px = (img.shape[1] - spec.squares_x * int(round(spec.square_m * ppm))) // 2
    return img, ppm, pad_px / ppm


def render_board_view(camera: Camera, spec: CharucoBoardSpec, board_to_world: np.ndarray, rng: np.random.Generator,
                      blur_px: float = 0.7, noise_dn: float = 2.0, supersample: int = 1,
                      margin_m: float = 0.03) -> np.ndarray:
    """uint8 grey image of the board seen by ``camera`` (exact lens distortion), with blur, light, noise."""
    xy = _supersampled_rays(_camera_key(camera), supersample)
    R_wb, t_wb = board_to_world[:3, :3], board_to_world[:3, 3]
    # Rays in the board frame: origin C_b, direction d_b = R_wb^T R^T (x, y, 1).
    C_b = R_wb.T @ (camera.center - t_wb)
    M = R_wb.T @ camera.R.T
    d_b = xy[..., 0:1] * M[:, 0] + xy[..., 1:2] * M[:, 1] + M[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = -C_b[2] / d_b[..., 2]
    hit = lam > 0
    u = C_b[0] + lam * d_b[..., 0]
    v = C_b[1] + lam * d_b[..., 1]
    # Pick a texture resolution about twice the finest on-screen sampling to avoid aliasing.
    depth = np.linalg.norm(camera.center - (R_wb @ spec.center_m + t_wb))
    want_ppm = 2.0 * camera.fx * supersample / max(depth - 0.5, 0.3)
    want_ppm = float(2 ** np.ceil(np.log2(want_ppm)))
    tex, ppm, margin = _texture(spec, min(want_ppm, 16384.0), margin_m)
    map_x = ((u + margin) * ppm - 0.5).astype(np.float32)
    map_y = ((v + margin) * ppm - 0.5).astype(np.float32)
    map_x[~hit] = -1e6
    front = C_b[2] < 0  # the camera is on the printed side
    background = np.float32(70.0)
    if front:
        img = cv2.remap(tex, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=-1.0)
    else:
        img = cv2.remap(np.full_like(tex, 150.0), map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                        borderValue=-1.0)
    img = np.where(img < 0, background, img)
    h, w = camera.height, camera.width
    img = cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)
    if blur_px > 0:
        img = cv2.GaussianBlur(img, (0, 0), blur_px)
    # Uneven light: a random linear gradient times a vignette.
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    xn, yn = (xx - w / 2) / (w / 2), (yy - h / 2) / (h / 2)
    gx, gy = rng.uniform(-0.2, 0.2, 2)
    gain = rng.uniform(0.75, 1.0) * (1 + gx * xn + gy * yn) * (1 - 0.2 * (xn ** 2 + yn ** 2) / 2)
    img = img * gain + rng.normal(0.0, noise_dn, img.shape)
    return np.clip(np.round(img), 0, 255).astype(np.uint8)


def write_png(path: Path, img: np.ndarray) -> None:
    ok, buf = cv2.imencode(".png", img)
    if not ok:
        raise OSError(f"{path}: PNG encoding failed")
    with atomic_write(path, "wb") as f:
        f.write(buf.tobytes())


def board_for_resolution(image_width: int) -> CharucoBoardSpec:
    """The studio board (about 1.0 x 0.7 m) with a pattern the cameras can decode on the floor.

    Below ~1000 px wide the default 100 mm squares lying on the floor are too foreshortened for the
    upper ring cameras to decode the markers (measured: floor board found by 0 of 4 cameras at 640x480);
    7x5 squares of 140 mm are (2 of 2 upper cameras).
    """
    if image_width < 1000:
        return CharucoBoardSpec(7, 5, 0.14, 0.105)
    return CharucoBoardSpec()


def write_synthetic_calibration(out: str | os.PathLike, n_cameras: int = 10, n_poses: int = 30, seed: int = 0,
                                width: int = 1280, height: int = 960, spec: CharucoBoardSpec | None = None,
                                rig: CameraRig | None = None, progress=None, kinect: str | None = None) -> dict:
    """Render a calibration capture into ``out``: ``cam_NN/FFFFF.png``, ``board.json``, ``gt/cameras.json``,
    ``gt/board_poses.json``. Frame 0 is the board lying on the floor. With ``kinect`` ("v1"/"v2") the
    Kinect's colour and depth views are written too (``kinect/rgb``, ``kinect/depth``, ``gt/kinect.json``).
    Returns a summary dict."""
    out = Path(out)
    rng = np.random.default_rng(seed)
    rig = rig or ring_rig(n_cameras, width=width, height=height)
    spec = spec or board_for_resolution(min(c.width for c in rig))
    poses = calibration_board_poses(rig, spec, n_poses, rng)
    total = len(rig) * len(poses)
    task = progress.add_task("rendering calibration images", total=total) if progress is not None else None
    n_visible = 0
    for cam in rig:
        for f, T in enumerate(poses):
            n_visible += int(visible_corners(cam, spec, T).sum() >= 6)
            write_png(out / cam.name / f"{f:05d}.png", render_board_view(cam, spec, T, rng))
            if task is not None:
                progress.advance(task)
    summary = {}
    if kinect is not None:
        from bodystudio.calib.depth import write_synthetic_kinect_views
        from bodystudio.capture.session import kinect_calibration_to_dict
        from bodystudio.geometry.camera import kinect_v1, kinect_v2

        if kinect not in ("v1", "v2"):
            raise InputError(f"kinect must be v1 or v2, got {kinect!r}")
        sensor = kinect_v2() if kinect == "v2" else kinect_v1()
        summary["kinect_views_with_board"] = write_synthetic_kinect_views(out, sensor, spec, poses, rng, progress)
        write_json(out / "gt" / "kinect.json", kinect_calibration_to_dict(sensor))
    save_board_json(out / "board.json", spec)
    write_json(out / "gt" / "board_poses.json", {"floor_frame": 0, "board_to_world": poses})
    save_cameras_json(out / "gt" / "cameras.json", rig)
    return {"cameras": len(rig), "poses": len(poses), "images": total, "views_with_board": n_visible,
            "out": str(out), **summary}
