"""ChArUco corner observations of a multi-camera capture: detection over a folder and validation.

A calibration capture folder holds ``cam_NN/FFFFF.png`` images (one sub-folder per camera, the same
frame number in every camera for one board pose) and, usually, ``board.json``.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bodystudio.calib.board import CharucoBoardSpec, detect_charuco, read_image_grey
from bodystudio.errors import SessionError
from bodystudio.fileio import is_frame_number

log = logging.getLogger(__name__)

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")


@dataclass(frozen=True, eq=False)
class CharucoObservations:
    """Flat arrays of corner observations: observation ``i`` is corner ``corner_id[i]`` of the board in
    frame ``frame[i]`` seen by camera ``camera[i]`` at pixel ``uv[i]``."""

    camera_names: tuple[str, ...]
    image_sizes: tuple[tuple[int, int], ...]  # (width, height) per camera
    frame_ids: tuple[int, ...]  # the capture's frame numbers, index = frame slot
    camera: np.ndarray  # (M,) int
    frame: np.ndarray  # (M,) int, index into frame_ids
    corner_id: np.ndarray  # (M,) int
    uv: np.ndarray  # (M, 2) float64

    @property
    def n_cameras(self) -> int:
        return len(self.camera_names)

    @property
    def n_frames(self) -> int:
        return len(self.frame_ids)

    def __len__(self) -> int:
        return len(self.camera)

    def view(self, cam: int, frame: int) -> tuple[np.ndarray, np.ndarray]:
        """(corner ids, pixels) of one camera in one frame."""
        m = (self.camera == cam) & (self.frame == frame)
        return self.corner_id[m], self.uv[m]

    def views(self) -> dict[tuple[int, int], np.ndarray]:
        """Observation indices of every (camera, frame) view with at least one corner."""
        key = self.camera.astype(np.int64) * max(self.n_frames, 1) + self.frame
        order = np.argsort(key, kind="stable")
        uniq, start = np.unique(key[order], return_index=True)
        groups = np.split(order, start[1:])
        n = max(self.n_frames, 1)
        return {(int(k) // n, int(k) % n): g for k, g in zip(uniq, groups, strict=True)}

    def subset(self, mask: np.ndarray) -> CharucoObservations:
        return CharucoObservations(self.camera_names, self.image_sizes, self.frame_ids, self.camera[mask],
                                   self.frame[mask], self.corner_id[mask], self.uv[mask])

    def covisibility(self) -> np.ndarray:
        """(C, C) count of corners seen by both cameras in the same frame."""
        C = self.n_cameras
        seen = np.zeros((C, self.n_frames * (int(self.corner_id.max(initial=0)) + 1)), dtype=np.int32)
        seen[self.camera, self.frame * (int(self.corner_id.max(initial=0)) + 1) + self.corner_id] = 1
        return seen @ seen.T


def observations_from_views(camera_names, image_sizes, frame_ids, views: dict) -> CharucoObservations:
    """Build observations from ``{(cam_index, frame_index): (corner_ids, uv)}``."""
    cams, frames, ids, uvs = [], [], [], []
    for (c, f), (cid, uv) in sorted(views.items()):
        cams.append(np.full(len(cid), c))
        frames.append(np.full(len(cid), f))
        ids.append(np.asarray(cid, int))
        uvs.append(np.asarray(uv, float).reshape(-1, 2))
    def cat(a, dt):
        return np.concatenate(a).astype(dt) if a else np.zeros(0, dt)

    return CharucoObservations(tuple(camera_names), tuple(tuple(map(int, s)) for s in image_sizes),
                               tuple(int(f) for f in frame_ids), cat(cams, np.int64), cat(frames, np.int64),
                               cat(ids, np.int64), np.concatenate(uvs) if uvs else np.zeros((0, 2)))


def capture_images(folder: str | os.PathLike) -> dict[str, dict[int, Path]]:
    """``{camera name: {frame number: image path}}`` of a ``cam_NN/FFFFF.png`` capture folder."""
    folder = Path(folder)
    if not folder.is_dir():
        raise SessionError(f"{folder}: calibration capture folder not found")
    images: dict[str, dict[int, Path]] = {}
    for sub in sorted(p for p in folder.iterdir() if p.is_dir() and p.name not in ("gt",)):
        frames = {}
        for img in sorted(sub.iterdir()):
            if img.suffix.lower() in IMAGE_SUFFIXES and is_frame_number(img.stem):
                frames[int(img.stem)] = img
        if frames:
            images[sub.name] = frames
    if not images:
        raise SessionError(f"{folder}: no camera folders with numbered images (cam_00/00000.png ...); "
                           "capture the board with every camera first")
    return images


def detect_capture(folder: str | os.PathLike, spec: CharucoBoardSpec, progress=None,
                   min_corners: int = 6) -> tuple[CharucoObservations, dict]:
    """Detect the board in every image of a capture folder.

    Returns the observations and a quality report ``{camera: {frame: {n_corners, coverage}}}``.
    Raises SessionError naming the camera when its images differ in size or none shows the board.
    """
    images = capture_images(folder)
    names = list(images)
    frame_ids = sorted({f for frames in images.values() for f in frames})
    slot = {f: i for i, f in enumerate(frame_ids)}
    sizes, views, quality = [], {}, {}
    total = sum(len(v) for v in images.values())
    task = progress.add_task("detecting ChArUco corners", total=total) if progress is not None else None
    for c, name in enumerate(names):
        size = None
        quality[name] = {}
        for frame, path in images[name].items():
            img = read_image_grey(path)
            h, w = img.shape[:2]
            if size is None:
                size = (w, h)
            elif size != (w, h):
                raise SessionError(f"camera {name}: {path.name} is {w}x{h} but earlier images are "
                                   f"{size[0]}x{size[1]}; recapture so all images of one camera share a size")
            det = detect_charuco(img, spec, min_corners=min_corners)
            quality[name][frame] = det.quality()
            if det.n_corners:
                views[(c, slot[frame])] = (det.corner_ids, det.corners_px)
            if task is not None:
                progress.advance(task)
        n_views = sum(1 for (cc, _) in views if cc == c)
        log.info("camera %s: board found in %d of %d images", name, n_views, len(images[name]))
        if n_views == 0:
            raise SessionError(f"camera {name}: no ChArUco board found in any of its {len(images[name])} images; "
                               "capture the board filling part of this camera's view")
        sizes.append(size)
    return observations_from_views(names, sizes, frame_ids, views), quality
