"""Images of a ChArUco board seen by a camera, for synthetic captures: which corners a detector could
find (:func:`visible_corners`), the rendered grey image with exact lens distortion (inverse mapping:
every super-sampled pixel's undistorted ray meets the board plane and samples the board texture, then
blur, uneven light and sensor noise), and the ideal depth image of the board for a depth camera.

Shared by the studio captures (``calib.synthetic``) and the RGB-D captures (``calib.depth``), so that
neither imports the other for it.
"""

from __future__ import annotations

import functools
from pathlib import Path

import cv2
import numpy as np

from bodystudio.calib.board import CharucoBoardSpec, board_corners, board_image, board_texture_px_per_m
from bodystudio.calib.world import rigid_inverse
from bodystudio.fileio import atomic_write
from bodystudio.geometry.camera import Camera

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


def render_board_depth(depth_cam: Camera, spec: CharucoBoardSpec, board_to_world: np.ndarray,
                       wall_depth_m: float = 4.0, margin_m: float = 0.03) -> np.ndarray:
    """Ideal z-depth (H, W) of a board (with its white margin) in front of a fronto-parallel wall."""
    xy = _supersampled_rays(_camera_key(depth_cam), 1).reshape(-1, 2).astype(np.float64)
    uv = xy  # one entry per pixel
    rays_cam = np.c_[xy, np.ones(len(xy))]
    B = rigid_inverse(board_to_world)
    C_b = B[:3, :3] @ depth_cam.center + B[:3, 3]
    d_b = rays_cam @ (B[:3, :3] @ depth_cam.R.T).T
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = -C_b[2] / d_b[:, 2]
    p = C_b + lam[:, None] * d_b
    w, h = spec.size_m
    on = (lam > 0) & (p[:, 0] > -margin_m) & (p[:, 0] < w + margin_m) & (p[:, 1] > -margin_m) & (p[:, 1] < h + margin_m)
    z = np.full(len(uv), wall_depth_m)
    z[on] = lam[on]  # rays have unit z in the camera frame, so lambda is the z-depth
    return z.reshape(depth_cam.height, depth_cam.width)
