"""Synthetic ChArUco calibration captures with ground truth.

Board poses follow the studio protocol (docs/calibration.md): the board lying on the floor at the
origin (frame 0, the world frame), a few more lying on the floor around it, then boards held in the
air, planned so that every camera sees strongly tilted boards over its whole image. Images are
rendered by ``calib.render`` (exact lens distortion, blur, uneven light, sensor noise); the Kinect's
views of the same poses by ``calib.depth``.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

import cv2
import numpy as np

from bodystudio.calib.board import CharucoBoardSpec, board_corners, save_board_json
from bodystudio.calib.observations import CharucoObservations, observations_from_views
from bodystudio.calib.render import (  # noqa: F401  (re-exported: the synthetic-capture API)
    MAX_VIEW_ANGLE_DEG,
    board_pose_facing,
    render_board_view,
    visible_corners,
    write_png,
)
from bodystudio.calib.world import FLOOR_BOARD_ROTATION, floor_board_to_world, rigid
from bodystudio.errors import InputError
from bodystudio.fileio import write_json
from bodystudio.geometry.camera import CameraRig, ring_rig, save_cameras_json

log = logging.getLogger(__name__)

def floor_board_pose(spec: CharucoBoardSpec, center, yaw_rad: float) -> np.ndarray:
    """4x4 board->world transform of a board lying printed side up on the floor (y = 0), centred at
    ``center`` and turned by ``yaw_rad`` about the vertical."""
    c, s = np.cos(yaw_rad), np.sin(yaw_rad)
    R = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]]) @ FLOOR_BOARD_ROTATION
    center = np.array([center[0], 0.0, center[2]], float)
    return rigid(R, center - R @ spec.center_m)


def calibration_board_poses(rig: CameraRig, spec: CharucoBoardSpec, n_poses: int, rng: np.random.Generator,
                            min_cameras: int = 4, n_floor: int = 4, floor_radius_m: tuple[float, float] = (1.0, 1.4),
                            depth_m: tuple[float, float] = (1.2, 2.2), tilt_deg: tuple[float, float] = (35.0, 55.0),
                            min_visible_fraction: float = 0.3, n_candidates: int = 20, grid: int = 3,
                            min_square_px: float = 9.0) -> np.ndarray:
    """(n_poses, 4, 4) board->world transforms following the studio calibration protocol
    (docs/calibration.md): frame 0 lies on the floor at the origin (the world frame), ``n_floor - 1``
    more boards lie on the floor around it (they pin the floor plane), the rest are held in the air.

    Held boards are planned greedily, as an operator watching a coverage display would: the camera with
    the fewest corners so far gets the next board, placed ``depth_m`` in front of it in the cell of its
    ``grid`` x ``grid`` image partition it has seen least (image corners included), facing between it
    and a neighbour and tilted ``tilt_deg`` about a random in-plane axis. Of ``n_candidates`` such
    boards seen (>= ``min_visible_fraction`` of the corners) by ``min_cameras`` cameras, the one adding
    most corners to little-seen cameras is kept; ``min_cameras`` is relaxed towards 2 where no candidate
    satisfies it. Tilt and image-wide coverage are what separate focal length from distance and the
    principal point from rotation.

    A camera counts a board as seen only when its squares are at least ``min_square_px`` on screen (9 px:
    the visibility model of :func:`synthetic_charuco_observations`; rendered captures plan with
    :data:`DETECTABLE_SQUARE_PX`, what OpenCV's detector really decodes).
    """
    if n_poses < 2:
        raise InputError(f"a calibration capture needs at least 2 board poses, got {n_poses}")
    cams = list(rig)
    C = len(cams)
    centers = rig.centers()
    corners = board_corners(spec)
    need = min_visible_fraction * spec.n_corners
    cover = np.zeros((C, grid, grid))
    seen_total = np.zeros(C)

    def seen_by(T: np.ndarray) -> np.ndarray:
        return np.array([visible_corners(cam, spec, T, min_square_px=min_square_px).sum() for cam in cams])

    def account(T: np.ndarray) -> None:
        for c, cam in enumerate(cams):
            vis = visible_corners(cam, spec, T, min_square_px=min_square_px)
            if vis.sum() < 6:
                continue
            uv = cam.project(corners[vis] @ T[:3, :3].T + T[:3, 3])
            gx = np.clip((uv[:, 0] / cam.width * grid).astype(int), 0, grid - 1)
            gy = np.clip((uv[:, 1] / cam.height * grid).astype(int), 0, grid - 1)
            np.add.at(cover[c], (gy, gx), 1)
            seen_total[c] += len(uv)

    poses = [floor_board_to_world(spec)]
    account(poses[0])
    n_floor = max(1, min(n_floor, n_poses))
    for k in range(1, n_floor):  # more floor boards, spread around the origin
        for _ in range(200):
            a = 2 * np.pi * (k - 1 + rng.uniform(-0.2, 0.2)) / (n_floor - 1)
            r = rng.uniform(*floor_radius_m)
            T = floor_board_pose(spec, [r * np.sin(a), 0.0, r * np.cos(a)], rng.uniform(-np.pi, np.pi))
            if (seen_by(T) >= need).sum() >= min(2, C):
                poses.append(T)
                account(T)
                break
    required = min(min_cameras, C)
    attempts = 0
    while len(poses) < n_poses:
        i = int(np.argmin(seen_total + rng.uniform(0, 1e-3, C)))
        cam = cams[i]
        gy, gx = np.unravel_index(np.argmin(cover[i] + rng.uniform(0, 1e-3, cover[i].shape)), cover[i].shape)
        best = None
        for _ in range(n_candidates):
            attempts += 1
            if attempts > 400 * n_poses:
                raise InputError("cannot place boards seen by several cameras in this rig; check the rig layout")
            u = (gx + rng.uniform(0.2, 0.8)) / grid * cam.width
            v = (gy + rng.uniform(0.2, 0.8)) / grid * cam.height
            ray = cam.R.T @ np.linalg.solve(cam.K, [u, v, 1.0])
            center = cam.center + rng.uniform(*depth_m) * ray / np.linalg.norm(ray)
            if not 0.15 < center[1] < 2.1:  # held between knee and overhead height
                continue
            j = (i + rng.choice([-1, 1])) % C
            to_i, to_j = cam.center - center, centers[j] - center
            facing = to_i / np.linalg.norm(to_i) + to_j / np.linalg.norm(to_j)
            facing /= np.linalg.norm(facing)
            axis = rng.normal(size=3)
            axis -= (axis @ facing) * facing
            axis /= np.linalg.norm(axis)
            facing = cv2.Rodrigues(axis * np.radians(rng.uniform(*tilt_deg)))[0] @ facing
            T = board_pose_facing(center, facing, rng.uniform(-0.6, 0.6), spec)
            seen = seen_by(T)
            ok = seen >= need
            if not ok[i] or ok.sum() < required:
                continue
            score = float(np.sum(seen * (seen >= 6) / (1.0 + seen_total / spec.n_corners)))
            if best is None or score > best[0]:
                best = (score, T)
        if best is None:
            required = max(2, required - 1)
            continue
        poses.append(best[1])
        account(best[1])
        required = min(min_cameras, C)
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


#: The studio calibration board of the synthetic captures at >= 1000 px: 12 x 9 squares of 100 mm
#: (1.2 x 0.9 m, 88 corners; `bodystudio calib board --squares-x 12 --squares-y 9 --dictionary DICT_4X4_100`).
#: Against the 10 x 7 default it was measured to cut the full case's rotation error by a quarter.
STUDIO_BOARD = CharucoBoardSpec(12, 9, 0.10, 0.075, "DICT_4X4_100")


#: Smallest on-screen square (px) at which the rendered boards are planned as seen: on rendered captures
#: OpenCV's ChArUco detector decoded none of 51 views with 9-12 px squares, 56 % at 12-15 px and 88-95 %
#: above (4-6 cameras at 640x480). Planning with 9 px spent poses on views no detector finds: the
#: 4-camera, 12-pose 640x480 case's centres 62.9 -> 24.9 mm mean over seeds 0-4 (docs/calibration.md).
DETECTABLE_SQUARE_PX = 15.0


def board_for_resolution(image_width: int) -> CharucoBoardSpec:
    """The studio board (:data:`STUDIO_BOARD`, 1.2 x 0.9 m) with a pattern the cameras can decode on the floor.

    Below ~1000 px wide 100 mm squares lying on the floor are too foreshortened for the upper ring
    cameras to decode the markers (measured: floor board found by 0 of 4 cameras at 640x480); 7x5
    squares of 140 mm are (2 of 2 upper cameras).
    """
    if image_width < 1000:
        return CharucoBoardSpec(7, 5, 0.14, 0.105)
    return STUDIO_BOARD


#: The manifest of a synthetic calibration capture (written last, with every file's sha256).
CAPTURE_MANIFEST = "capture.json"


def write_synthetic_calibration(out: str | os.PathLike, n_cameras: int = 10, n_poses: int = 30, seed: int = 0,
                                width: int = 1280, height: int = 960, spec: CharucoBoardSpec | None = None,
                                rig: CameraRig | None = None, progress=None, kinect: str | None = None,
                                blur_px: float = 0.7, noise_dn: float = 2.0) -> dict:
    """Render a calibration capture into ``out``: ``cam_NN/FFFFF.png``, ``board.json``, ``gt/cameras.json``,
    ``gt/board_poses.json``. Frame 0 is the board lying on the floor. With ``kinect`` ("v1"/"v2") the
    Kinect's colour and depth views are written too (``kinect/rgb``, ``kinect/depth``, ``gt/kinect.json``).
    The files are committed as one unit with ``capture.json`` last (:class:`~bodystudio.runfolder.RunWriter`).
    ``blur_px`` (Gaussian sigma) and ``noise_dn`` (sensor noise, grey levels) set the image quality.
    Returns a summary dict."""
    if not (0.0 <= blur_px <= 5.0 and 0.0 <= noise_dn <= 50.0):
        raise InputError(f"blur_px must be in [0, 5] and noise_dn in [0, 50], got {blur_px} and {noise_dn}")
    out = Path(out)
    rng = np.random.default_rng(seed)
    rig = rig or ring_rig(n_cameras, width=width, height=height)
    spec = spec or board_for_resolution(min(c.width for c in rig))
    try:
        poses = calibration_board_poses(rig, spec, n_poses, rng, min_square_px=DETECTABLE_SQUARE_PX)
    except InputError:
        log.warning("no plan with squares >= %g px in every view; planning with 9 px squares (some views will "
                    "not be detected)", DETECTABLE_SQUARE_PX)
        poses = calibration_board_poses(rig, spec, n_poses, np.random.default_rng(seed))
    if kinect is not None and kinect not in ("v1", "v2"):
        raise InputError(f"kinect must be v1 or v2, got {kinect!r}")
    from bodystudio.runfolder import RunLayout, RunWriter

    # every file staged and committed as one unit (CAPTURE_MANIFEST last): a full disk or a kill mid-way
    # left some camera images and no board.json (or no ground truth) in OUT
    with RunWriter(RunLayout(out, CAPTURE_MANIFEST, ".", str(out)), "bodystudio synth calibration",
                   {"stage": "calib", "kind": "synthetic capture"}) as w:
        stage = w.layout.staging
        total = len(rig) * len(poses)
        task = progress.add_task("rendering calibration images", total=total) if progress is not None else None
        n_visible = 0
        for cam in rig:
            for f, T in enumerate(poses):
                n_visible += int(visible_corners(cam, spec, T).sum() >= 6)
                write_png(stage / cam.name / f"{f:05d}.png", render_board_view(cam, spec, T, rng, blur_px, noise_dn))
                if task is not None:
                    progress.advance(task)
        summary = {}
        if kinect is not None:
            from bodystudio.calib.depth import write_synthetic_kinect_views
            from bodystudio.capture.session import kinect_calibration_to_dict
            from bodystudio.geometry.camera import kinect_v1, kinect_v2

            sensor = kinect_v2() if kinect == "v2" else kinect_v1()
            summary["kinect_views_with_board"] = write_synthetic_kinect_views(stage, sensor, spec, poses, rng,
                                                                              progress)
            write_json(stage / "gt" / "kinect.json", kinect_calibration_to_dict(sensor))
        save_board_json(stage / "board.json", spec)
        write_json(stage / "gt" / "board_poses.json", {"floor_frame": 0, "board_to_world": poses})
        save_cameras_json(stage / "gt" / "cameras.json", rig)
        summary = {"cameras": len(rig), "poses": len(poses), "images": total, "views_with_board": n_visible,
                   "out": str(out), **summary}
        w.commit(summary)
    return summary
