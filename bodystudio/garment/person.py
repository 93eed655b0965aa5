"""The actor's frames and person mattes from a session or a plain video file (input of §4 of Garment Replacement).

The paper starts from alpha mattes of the actor (Fig. 2a). A synthetic or imported session carries its
own (``cam_00/mask``); for a plain video the matte is computed here: a temporal median of the frames is
the background plate (valid where the actor moves across it) and each frame is segmented against it by
the capture stage's brightness/chromaticity test (:func:`bodystudio.capture.silhouettes.segment_silhouette`),
keeping the largest connected component.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bodystudio.errors import FileFormatError, InputError

log = logging.getLogger(__name__)

#: A matte covering less than this fraction of the image is "no person".
MIN_PERSON_FRACTION = 0.005
MAX_PERSON_FRACTION = 0.85  # a matte over more of the image: the background moved, not an actor
VIDEO_SUFFIXES = (".mp4", ".mov", ".avi", ".mkv", ".webm", ".m4v")
MAX_VIDEO_FRAMES = 2000


@dataclass(frozen=True, eq=False)
class PersonFrames:
    """``images`` (n, H, W, 3) uint8 linear RGB, ``masks`` (n, H, W) bool, ``frame_ids`` (n,), ``fps``."""

    source: str
    fps: float
    frame_ids: np.ndarray
    images: np.ndarray
    masks: np.ndarray
    # which recording: "session:" + capture.session.stream_fingerprint of the rgb frames, or "video:" + the
    # video file's sha256 (None: unknown)
    fingerprint: str | None = None

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) in pixels."""
        return int(self.images.shape[2]), int(self.images.shape[1])


def parse_frame_range(frames: str | None, n_available: int, where: str) -> slice:
    """``a:b`` (Python slice of frame indices, either end optional) checked against ``n_available`` frames."""
    if frames is None or frames == "":
        return slice(0, n_available)
    a, b = _frame_range_ends(frames)
    b = n_available if b is None else b
    if not 0 <= a < b <= n_available:
        raise InputError(f"--frames {frames}: out of range; {where} has frames 0:{n_available}")
    return slice(a, b)


#: The frame rates a fit may carry (``fitfile`` refuses a fit.json outside them: ``garment render`` could not write it)
MIN_FPS, MAX_FPS = 1.0, 240.0


def checked_fps(value, source: str, fix: str) -> float:
    """``value`` as a frame rate in [:data:`MIN_FPS`, :data:`MAX_FPS`], else a one-line InputError naming ``source``
    and ``fix``. Before, a session's ``metadata.fps`` of 0, NaN or 1e6 went into the fit and its fit.json, which
    ``garment render`` then refused naming fit.json (after the minutes of the fit, exit 0), and a text rate raised
    ValueError."""
    try:
        fps = float(value)
    except (TypeError, ValueError):
        fps = float("nan")
    if isinstance(value, bool) or not MIN_FPS <= fps <= MAX_FPS:
        raise InputError(f"{source}: frame rate {value!r} is not one in {MIN_FPS:g}..{MAX_FPS:g} fps; {fix}")
    return fps


def session_person_frames(path: str | os.PathLike, frames: str | None = None) -> PersonFrames:
    """Frames and person masks of a session's first camera (``cam_00/rgb``, ``cam_00/mask``)."""
    from bodystudio.capture.session import open_session

    session = open_session(path)
    metadata = session.metadata if isinstance(session.metadata, dict) else {}
    fps = checked_fps(metadata.get("fps", 30.0), f"{Path(path) / 'session.json'} (metadata.fps)",
                      "regenerate or re-import the session (capture import records the rate from the frame times)")
    if not session.camera_names or "rgb" not in session.streams or "mask" not in session.streams:
        raise InputError(f"{path}: session has no rgb and mask streams; run 'bodystudio capture silhouettes' "
                         f"first or pass the video file")
    cam = session.camera_names[0]
    ids = session.frame_ids[parse_frame_range(frames, len(session.frame_ids), str(path))]
    images, masks = [], []
    for fid in ids:
        fr = session.frame(fid)
        images.append(fr.images[cam])
        masks.append(fr.masks[cam])
    return PersonFrames(str(Path(path)), fps, np.asarray(ids, np.int64), np.stack(images), np.stack(masks),
                        source_fingerprint(session, ids, cam))


def source_fingerprint(source, frame_ids, camera: str | None = None) -> str | None:
    """The identity of a fit's source recording: ``session:`` + the sha256 over its ``camera`` rgb frames'
    manifest checksums (a :class:`~bodystudio.capture.session.Session`), or ``video:`` + the file's sha256
    (a path). Later steps refuse a source whose identity changed (another clip at the same path)."""
    from bodystudio.capture.session import stream_fingerprint
    from bodystudio.fileio import sha256_file

    if isinstance(source, (str, os.PathLike)):
        return f"video:{sha256_file(source)}"
    if getattr(source, "files", None) is None:  # a session without a manifest (a stand-in): unknown
        return None
    digest = stream_fingerprint(source, "rgb", frame_ids, camera or source.camera_names[0])
    return None if digest is None else f"session:{digest}"


#: FFmpeg output options of every read of a garment fit's video (the fit and the render must number its frames alike):
#: each decoded frame once. By default the pipe is constant-rate: a phone's variable-rate clip (10 frames over 1.7 s)
#: came out as 19 frames, held ones repeated, at the stream's nominal "30 fps", exit 0 (adv5).
VIDEO_READ_OPTIONS = ("-fps_mode", "passthrough")


def video_frame_rate(path: Path, n_frames: int, nominal_fps: float, whole: bool = True) -> float:
    """A video's frame rate from its frames' times (:func:`bodystudio.capture.importer.video_fps`: frames over their
    span when steady, one over the median period when not, with a warning), else ``nominal_fps`` (FFmpeg's stream
    line) when OpenCV does not decode the same ``n_frames`` (at least as many when not ``whole``: a range of the
    clip, whose rate is the clip's)."""
    from bodystudio.capture.importer import video_fps, video_frame_times, video_rate_varies
    from bodystudio.errors import BodyStudioError

    try:
        times = video_frame_times(path)[0]
    except BodyStudioError:
        return nominal_fps
    if len(times) != n_frames and (whole or len(times) < n_frames):
        return nominal_fps
    try:
        fps = video_fps(times, path)
    except BodyStudioError:
        return nominal_fps
    if fps is None:
        return nominal_fps
    if video_rate_varies(times):
        log.warning("%s: variable frame rate (frame periods %.0f-%.0f ms); each frame is fitted once, the output "
                    "plays at the median rate %.3g fps", path, 1e3 * np.diff(times).min(), 1e3 * np.diff(times).max(),
                    fps)
    return fps


def read_video(path: str | os.PathLike, frames: str | None = None) -> tuple[np.ndarray, float]:
    """(n, H, W, 3) uint8 RGB frames of a video file (imageio-ffmpeg, each decoded frame once) and its frame rate
    (:func:`video_frame_rate`)."""
    import imageio_ffmpeg

    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such video file or session folder")
    try:
        reader = imageio_ffmpeg.read_frames(str(path), pix_fmt="rgb24", output_params=list(VIDEO_READ_OPTIONS))
        meta = next(reader)
        width, height = meta["size"]
        fps = float(meta.get("fps") or 30.0)
        stop = _requested_end(frames)
        out = []
        for raw in reader:
            out.append(np.frombuffer(raw, np.uint8).reshape(height, width, 3))
            if stop is not None and len(out) >= stop:
                break
            if len(out) > MAX_VIDEO_FRAMES:
                raise InputError(f"{path}: more than {MAX_VIDEO_FRAMES} frames; cut the clip or pass --frames a:b")
        reader.close()
    except InputError:
        raise
    except (OSError, RuntimeError, StopIteration, KeyError, ValueError) as exc:
        first = str(exc).strip().splitlines()[0][:120] if str(exc).strip() else type(exc).__name__
        raise FileFormatError(f"{path}: unreadable video ({first}); pass a video file ffmpeg can decode") from None
    if not out:
        raise FileFormatError(f"{path}: the video has no frames; pass a video with the actor in it")
    fps = video_frame_rate(path, len(out), fps, whole=stop is None)
    fps = checked_fps(fps, str(path), "re-encode the video at its real rate (ffmpeg -r 30)")
    images = np.stack(out)
    return images[parse_frame_range(frames, len(images), str(path))], fps


def _frame_range_ends(frames: str) -> tuple[int, int | None]:
    """START and END (None when left open) of ``--frames START:END``, checked for form and order."""
    parts = frames.split(":")
    try:
        if len(parts) != 2:
            raise ValueError
        a = int(parts[0]) if parts[0] else 0
        b = int(parts[1]) if parts[1] else None
    except ValueError:
        raise InputError(f"--frames {frames!r}: use START:END (frame indices, e.g. 0:60)") from None
    if a < 0 or (b is not None and b <= a):
        raise InputError(f"--frames {frames}: START must be >= 0 and below END (e.g. 0:60)")
    return a, b


def _requested_end(frames: str | None) -> int | None:
    """The END of ``--frames START:END`` when given (reading can stop there), else None; a malformed or
    reversed range is refused here, before the video is read."""
    if not frames:
        return None
    return _frame_range_ends(frames)[1]


def temporal_background(images: np.ndarray) -> np.ndarray:
    """The background plate as the per-pixel temporal median of the frames (float32, (H, W, 3))."""
    step = max(1, len(images) // 60)
    return np.median(images[::step].astype(np.float32), axis=0)


def person_mattes(images: np.ndarray, plate: np.ndarray | None = None) -> np.ndarray:
    """Person masks (n, H, W) of a video against ``plate`` (a clean plate of the empty set, (H, W, 3)) or,
    without one, against the video's temporal median (capture's segmentation)."""
    from bodystudio.capture.silhouettes import (
        SegmentationParams,
        background_model,
        largest_components,
        segment_silhouette,
    )

    plate = temporal_background(images) if plate is None else np.asarray(plate, np.float32)
    params = SegmentationParams(close_px=2, open_px=1)
    model = background_model([plate], single_frame_std=4.0)
    masks = [largest_components(segment_silhouette(img, model, params), min_fraction=0.5) for img in images]
    return np.stack(masks).astype(bool)


def check_person(masks: np.ndarray, source: str) -> None:
    """Refuse (one line) a clip where no frame shows a person-sized matte."""
    frac = masks.reshape(len(masks), -1).mean(1)
    if not np.any(frac >= MIN_PERSON_FRACTION):
        raise InputError(f"{source}: no person found (the largest moving region covers {100 * frac.max():.2f} % of "
                         f"the image); film the actor moving in front of a static background, or pass "
                         f"--background PLATE.png (a frame of the empty set)")
    flooded = int(np.count_nonzero(frac > MAX_PERSON_FRACTION))
    if flooded > len(masks) // 2:
        raise InputError(f"{source}: no person found (the moving region covers {100 * np.median(frac):.0f} % of the "
                         f"image in {flooded} of {len(masks)} frames: the camera, the light or the image noise "
                         f"moves, not an actor); use a clip from a fixed camera in front of a static background, "
                         f"or pass --background PLATE.png (a frame of the empty set)")
    empty = int(np.count_nonzero(frac < MIN_PERSON_FRACTION))
    if empty:
        raise InputError(f"{source}: no person found in {empty} of {len(masks)} frames; pass --frames to the range "
                         f"where the actor is in view, or --background PLATE.png (a frame of the empty set) when the "
                         f"actor stays on the spot")


def read_background_plate(path: str | os.PathLike, size: tuple[int, int]) -> np.ndarray:
    """A clean plate (an image of the set without the actor) as float32 RGB, checked against the video's
    (width, height)."""
    import cv2

    from bodystudio.fileio import read_image

    path = Path(path)
    if not path.is_file():
        raise InputError(f"--background {path}: no such image; give a frame of the empty set (PNG or JPEG)")
    image = read_image(path, cv2.IMREAD_COLOR)
    if (image.shape[1], image.shape[0]) != tuple(size):
        raise InputError(f"--background {path}: {image.shape[1]}x{image.shape[0]} but the video is "
                         f"{size[0]}x{size[1]}; give a frame of the same camera and resolution")
    return cv2.cvtColor(image, cv2.COLOR_BGR2RGB).astype(np.float32)


def person_frames(source: str | os.PathLike, frames: str | None = None,
                  background: str | os.PathLike | None = None) -> PersonFrames:
    """Frames + person mattes of a session folder (its masks) or a video file (mattes computed against
    ``background``, a clean plate image, or the video's temporal median)."""
    source = Path(source)
    if source.is_dir():
        if background is not None:
            raise InputError(f"--background: {source} is a session with its own masks; pass it for a video file only")
        pf = session_person_frames(source, frames)
    else:
        if not source.exists():
            raise InputError(f"{source}: no such video file or session folder")
        images, fps = read_video(source, frames)
        start = parse_frame_range(frames, 10 ** 9, str(source)).start if frames else 0
        ids = np.arange(start, start + len(images), dtype=np.int64)
        plate = None if background is None else read_background_plate(background, (images.shape[2], images.shape[1]))
        pf = PersonFrames(str(source), fps, ids, images, person_mattes(images, plate),
                          source_fingerprint(source, ids))
    check_person(pf.masks, str(source))
    return pf
