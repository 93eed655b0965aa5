"""Import real recordings into a session (``docs/session-format.md``).

Inputs, each optional except the cameras:

* cameras: our ``cameras.json`` or EasyMocap's OpenCV-YAML pair ``intri.yml`` / ``extri.yml``
  (``names``, ``K_<cam>``, ``dist_<cam>``, ``Rot_<cam>`` or ``R_<cam>`` (Rodrigues), ``T_<cam>``,
  optional ``H_<cam>``/``W_<cam>``), read with ``cv2.FileStorage``;
* studio frames: one folder of images per camera (``images/<cam>/*.png|jpg``) or one video per camera
  (``videos/<cam>.avi|mp4|...``, decoded with ``cv2.VideoCapture``), synchronised by frame index or,
  with ``timestamps/<cam>.txt`` (one time in seconds per frame), by nearest timestamp;
* empty-studio frames for background subtraction: ``backgrounds/<cam>/`` images, ``<cam>.png`` or a video;
* Kinect: a TUM RGB-D folder (``depth.txt``, ``rgb.txt``, ``depth/*.png`` 16-bit, 5000 units per metre;
  depth and colour associated by timestamp as TUM's ``associate.py``) with a Kinect calibration JSON;
* tracker joints: a folder of per-frame JSON, one JSON with all frames, or a CSV ``frame,joint,x,y,z``.
"""

from __future__ import annotations

import csv
import json
import logging
import os
import re
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from bodystudio.capture.session import Session, SessionWriter, load_kinect_calibration, open_session
from bodystudio.errors import FileFormatError, InputError
from bodystudio.fileio import is_frame_number
from bodystudio.opencv_yaml import check_opencv_yaml, opencv_matrix

log = logging.getLogger(__name__)

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")
VIDEO_SUFFIXES = (".avi", ".mp4", ".mkv", ".mov", ".webm", ".m4v")
#: TUM RGB-D depth images store 5000 units per metre.
TUM_DEPTH_SCALE = 5000.0
#: The Kinect's valid range: the median depth of a frame must fall inside it, which tells units apart (m).
PLAUSIBLE_DEPTH_M = (0.5, 4.5)
#: TUM's associate.py default: depth and colour frames further apart than this are not paired (s).
TUM_MAX_DIFFERENCE_S = 0.02


# ---------------------------------------------------------------------------------------------- cameras

def load_studio_cameras(path: str | os.PathLike, image_sizes: dict[str, tuple[int, int]] | None = None):
    """Cameras from ``cameras.json``, or from EasyMocap ``intri.yml``/``extri.yml`` (a folder or either file)."""
    from bodystudio.geometry.camera import load_cameras_json

    path = Path(path)
    if path.suffix.lower() == ".json":
        return load_cameras_json(path)
    folder = path if path.is_dir() else path.parent
    intri, extri = folder / "intri.yml", folder / "extri.yml"
    for p in (intri, extri):
        if not p.is_file():
            raise FileFormatError(f"{p}: not found; give cameras.json or a folder with EasyMocap "
                                  "intri.yml and extri.yml")
    return load_easymocap_cameras(intri, extri, image_sizes)


def _read_storage(path: Path) -> cv2.FileStorage:
    check_opencv_yaml(path)
    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError) as exc:
        reason = str(exc).strip().splitlines()[-1] if str(exc).strip() else type(exc).__name__
        raise FileFormatError(f"{path}: not an OpenCV YAML file ({reason})") from None
    if not fs.isOpened():
        raise FileFormatError(f"{path}: cannot be opened as OpenCV YAML")
    return fs


def _storage_names(fs: cv2.FileStorage, path: Path) -> list[str]:
    node = fs.getNode("names")
    if node.empty() or not node.isSeq():
        raise FileFormatError(f"{path}: no 'names' list of cameras (EasyMocap layout)")
    return [node.at(i).string() or str(int(node.at(i).real())) for i in range(node.size())]


def _storage_mat(fs: cv2.FileStorage, key: str, path: Path, required: bool = True) -> np.ndarray | None:
    node = fs.getNode(key)
    m = opencv_matrix(node, f"{path}: {key}")
    if m is None:
        if required:
            raise FileFormatError(f"{path}: missing matrix {key!r}; EasyMocap files need K_, dist_, Rot_/R_ "
                                  "and T_ per camera")
        return None
    return np.asarray(m, dtype=np.float64)


def load_easymocap_cameras(intri: Path, extri: Path, image_sizes: dict[str, tuple[int, int]] | None = None,
                           default_size: tuple[int, int] | None = None):
    """Cameras from EasyMocap's ``intri.yml`` and ``extri.yml`` (translations in metres, OpenCV axes).

    The image size of a camera comes from its ``W_``/``H_`` entries, else from ``image_sizes[name]``, else
    from ``default_size`` (w, h); the one EasyMocap reader of the package (:mod:`bodystudio.calib.io` wraps it).
    """
    fi, fe = _read_storage(intri), _read_storage(extri)
    try:
        return _easymocap_rig(fi, fe, intri, extri, image_sizes, default_size)
    except (cv2.error, SystemError, ValueError, TypeError, OverflowError) as exc:  # YAML nodes of the wrong type
        raise FileFormatError(f"{intri.parent}: malformed EasyMocap intri.yml/extri.yml "
                              f"({str(exc).strip().splitlines()[-1] if str(exc).strip() else type(exc).__name__}); "
                              "re-export the calibration") from None
    finally:
        fi.release()
        fe.release()


def _easymocap_rig(fi, fe, intri: Path, extri: Path, image_sizes, default_size):
    from bodystudio.geometry.camera import Camera, CameraRig, check_intrinsics

    names = _storage_names(fi, intri)
    cams = {}
    for name in names:
        K = _storage_mat(fi, f"K_{name}", intri)
        dist = _storage_mat(fi, f"dist_{name}", intri, required=False)
        dist = np.zeros(5) if dist is None else np.r_[dist.ravel(), np.zeros(5)][:5]
        # Prefer the Rodrigues vector: 6-decimal rotation matrices are not orthonormal to 1e-6.
        rvec = _storage_mat(fe, f"R_{name}", extri, required=False)
        if rvec is not None and rvec.size == 3:
            R = cv2.Rodrigues(rvec.reshape(3, 1))[0]
        else:
            R = _nearest_rotation(_storage_mat(fe, f"Rot_{name}", extri), extri, name)
        T = _storage_mat(fe, f"T_{name}", extri).ravel()
        w, h = fi.getNode(f"W_{name}"), fi.getNode(f"H_{name}")
        if not w.empty() and not h.empty():
            size = _image_size(w.real(), h.real(), intri, name)
        elif image_sizes and name in image_sizes:
            size = image_sizes[name]
            check_principal_point_centred(K, size, intri, name)
        elif default_size is not None:
            size = default_size
        else:
            raise FileFormatError(f"{intri}: no image size for camera {name} (W_{name}/H_{name}) and no frames "
                                  "to take it from; add them or import with --images/--videos")
        safe = _safe_name(name)
        if safe in cams:  # 'cam 1' and 'cam_1' were one camera, the other's calibration silently dropped
            other = next(n for n in names if _safe_name(n) == safe)
            if other == name:
                raise FileFormatError(f"{intri}: camera {name!r} is listed twice in 'names'; list each camera once")
            raise FileFormatError(f"{intri}: cameras {other!r} and {name!r} both become {safe!r} as folder names; "
                                  "rename one (letters, digits, _ . -)")
        try:
            cams[safe] = check_intrinsics(Camera(safe, K, dist, R, T, *size))
        except InputError as exc:
            raise FileFormatError(f"{intri}: {exc}") from None
    if not cams:
        raise FileFormatError(f"{intri}: the 'names' list is empty; list the cameras")
    return CameraRig(cams)


#: How far (a fraction of the side) a lens's principal point may lie from the image centre before an image size taken
#: from the frames is doubted (calibrated cameras: a few %; K of 1920x1080 on 1280x720 frames: 25 %; a 4:3 portrait
#: K on landscape frames: 17 %).
MAX_PRINCIPAL_POINT_OFFSET = 0.15


def check_principal_point_centred(K: np.ndarray, size: tuple[int, int], source: Path, name: str) -> None:
    """Refuse an EasyMocap camera without ``W_``/``H_`` whose frames (``size``, w x h) are not the size its ``K`` was
    calibrated at: K's principal point far from the frames' centre. K of a 1920x1080 calibration on 1280x720 frames
    (principal point (960, 540) inside the image) or on a phone's portrait frames was taken with exit 0, every pixel
    ray wrong (adv5)."""
    w, h = size
    cx, cy = float(K[0, 2]), float(K[1, 2])
    off = max(abs(cx - w / 2) / w, abs(cy - h / 2) / h)
    if off <= MAX_PRINCIPAL_POINT_OFFSET:
        return
    turned = max(abs(cx - h / 2) / h, abs(cy - w / 2) / w) <= MAX_PRINCIPAL_POINT_OFFSET
    likely = (f"the frames are turned 90 degrees against it ({h}x{w})" if turned
              else f"it is for about {2 * cx:.0f}x{2 * cy:.0f} images")
    raise FileFormatError(f"{source}: camera {name} has no W_{name}/H_{name} and its frames are {w}x{h}, but K's "
                          f"principal point ({cx:g}, {cy:g}) is {100 * off:.0f} % of the image off their centre (a "
                          f"lens's lies within a few %): {likely}; calibrate at the frames' size and orientation, or "
                          f"add W_{name}/H_{name} to intri.yml")


def _image_size(w: float, h: float, source: Path, name: str) -> tuple[int, int]:
    """W_/H_ as whole pixel counts in 1..MAX_IMAGE_SIDE (NaN, inf, 1e400 and 0.5 are refused, not cast)."""
    from bodystudio.geometry.camera import MAX_IMAGE_SIDE

    if not all(1 <= v <= MAX_IMAGE_SIDE and float(v).is_integer() for v in (w, h)):
        raise FileFormatError(f"{source}: camera {name} has image size W_{name}={w:g} H_{name}={h:g}; "
                              f"use whole pixel counts 1-{MAX_IMAGE_SIDE}")
    return int(w), int(h)


def _nearest_rotation(M: np.ndarray, source: Path, name: str) -> np.ndarray:
    """The rotation closest to a rounded rotation matrix (SVD); anything far from one is an error."""
    U, _, Vt = np.linalg.svd(M.reshape(3, 3))
    R = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
    if np.abs(R - M.reshape(3, 3)).max() > 1e-3:
        raise FileFormatError(f"{source}: Rot_{name} is not a rotation matrix; fix the calibration")
    return R


def save_easymocap_cameras(folder: str | os.PathLike, rig) -> None:
    """Write a rig as EasyMocap ``intri.yml``/``extri.yml`` (for exchange and tests)."""
    from bodystudio.fileio import atomic_path

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    for fname, write in (("intri.yml", _write_intri), ("extri.yml", _write_extri)):
        with atomic_path(folder / fname) as tmp:
            fs = cv2.FileStorage(str(tmp), cv2.FILE_STORAGE_WRITE)
            fs.startWriteStruct("names", cv2.FileNode_SEQ)
            for cam in rig:
                fs.write("", cam.name)
            fs.endWriteStruct()
            for cam in rig:
                write(fs, cam)
            fs.release()


def _write_intri(fs, cam):
    fs.write(f"K_{cam.name}", np.asarray(cam.K))
    fs.write(f"dist_{cam.name}", np.asarray(cam.dist)[None])
    fs.write(f"H_{cam.name}", cam.height)
    fs.write(f"W_{cam.name}", cam.width)


def _write_extri(fs, cam):
    fs.write(f"R_{cam.name}", cv2.Rodrigues(np.asarray(cam.R))[0])
    fs.write(f"Rot_{cam.name}", np.asarray(cam.R))
    fs.write(f"T_{cam.name}", np.asarray(cam.t)[:, None])


#: A camera name the session format takes as a folder name (``capture.session._NAME``).
_CAMERA_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]*")


def _safe_name(name: str) -> str:
    """``name`` when the session takes it as a folder name, else with every other character made '_' (a full match:
    ``^...$`` matched ``'cam1\\n'``, which the session writer then refused; rel6b)."""
    return name if _CAMERA_NAME.fullmatch(name) else re.sub(r"[^A-Za-z0-9_.-]", "_", name)


# ---------------------------------------------------------------------------------------------- frame sources

#: A 16-bit colour frame whose brightest value is below this uses 12 bits or fewer (a machine-vision camera's Mono12 /
#: RGB12 stored right-aligned): read as 8 bits (the top byte) it is nearly black.
MIN_16BIT_PEAK = 4096


def read_image_file(path: Path, flags: int = cv2.IMREAD_COLOR) -> np.ndarray:
    """Read an image (RGB for colour); an unreadable file raises a one-line FileFormatError naming it.

    Colour frames are 8-bit: a 16-bit one keeps its top byte (as OpenCV's colour read), unless its brightest value
    is below :data:`MIN_16BIT_PEAK`: a 12-bit camera's right-aligned data read that way peaked at 15 of 255 (a
    black frame, exit 0; adv5), and is refused; so is a floating-point colour image (0..1 read as 0 and 1)."""
    from bodystudio.fileio import read_image

    if flags != cv2.IMREAD_COLOR:
        return read_image(path, flags)
    image = read_image(path, cv2.IMREAD_COLOR | cv2.IMREAD_ANYDEPTH)
    if image.dtype == np.uint16:
        peak = int(image.max(initial=0))
        if 0 < peak < MIN_16BIT_PEAK:
            raise FileFormatError(f"{path}: 16-bit image whose brightest value is {peak} (12 bits or fewer used): read "
                                  "as 8 bits it is nearly black; export 8-bit frames or scale the data to 16 bits "
                                  "(x16 for 12-bit)")
        image = (image >> 8).astype(np.uint8)
    elif image.dtype != np.uint8:
        raise FileFormatError(f"{path}: {image.dtype} colour image; export 8- or 16-bit frames")
    return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)


def frame_order(path: Path) -> list:
    """Sort key of a frame file: its name with each run of digits compared as a number, so that a recorder's
    unpadded ``frame_9.png, frame_10.png`` keep their order (by plain name ``frame_10`` came before ``frame_2``:
    frames out of time order, exit 0); zero-padded names sort as by plain name."""
    # ASCII digits only: '²' is isdigit() but not int() (rel6b)
    return [(0, int(part), part) if is_frame_number(part) else (1, 0, part)
            for part in re.split(r"([0-9]+)", path.name)]


def image_files(folder: Path) -> list[Path]:
    """The image files of a folder in frame order (:func:`frame_order`); a non-regular entry with an image name (a
    FIFO would block the import) is an error, not silently skipped or read."""
    found = sorted((p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and not p.name.startswith(".")),
                   key=frame_order)
    for p in found:
        if not p.is_file():
            raise FileFormatError(f"{p}: not a regular file (a folder, pipe or device); remove it from the "
                                  "image folder")
    return found


class ImageFolderSource:
    """The frames of one camera as an image sequence (sorted by file name)."""

    def __init__(self, folder: Path):
        self.where = folder
        self.files = image_files(folder)
        if not self.files:
            raise FileFormatError(f"{folder}: no images ({', '.join(IMAGE_SUFFIXES)}) in this camera folder")

    def __len__(self) -> int:
        return len(self.files)

    def read(self, k: int) -> tuple[np.ndarray, str]:
        return read_image_file(self.files[k]), str(self.files[k])

    def close(self) -> None:
        pass


def open_video(path: Path) -> cv2.VideoCapture:
    """``cv2.VideoCapture`` of a video file, FFmpeg's demuxer chatter kept off the terminal (an error is one line)."""
    from bodystudio.fileio import native_stderr_captured

    with native_stderr_captured():
        capture = cv2.VideoCapture(str(path))
    if not capture.isOpened():
        raise FileFormatError(f"{path}: cannot open the video (unsupported codec or not a video); "
                              "convert it (e.g. ffmpeg -c:v mjpeg) or export an image folder")
    return capture


def video_frame_times(path: Path) -> tuple[np.ndarray, int, str | None, list[tuple[int, str]]]:
    """The presentation time (s) of every frame of a video that decodes, by decoding it once; with the header's
    frame count (an estimate in Matroska / WebM), FFmpeg's first complaint (None if it had none) and the frames it
    complained while decoding (index, message; a frame-threaded decoder may name a frame a few late)."""
    from bodystudio.fileio import ffmpeg_message, native_stderr_captured

    capture = open_video(path)
    times, complaints, last = [], [], None
    try:
        header_frames = max(0, int(capture.get(cv2.CAP_PROP_FRAME_COUNT)))
        while True:
            with native_stderr_captured() as captured:
                ok = capture.grab()
            said = ffmpeg_message(captured)
            if not ok:
                last = said
                break
            times.append(capture.get(cv2.CAP_PROP_POS_MSEC) / 1000.0)
            if said:
                complaints.append((len(times) - 1, said))
    finally:
        capture.release()
    return np.asarray(times, np.float64), header_frames, complaints[0][1] if complaints else last, complaints


def video_rate_varies(times_s: np.ndarray) -> bool:
    """Whether a video's frame periods stray from their median by more than :data:`VIDEO_PERIOD_TOLERANCE` (a
    phone's variable frame rate, a dropped or held frame)."""
    if len(times_s) < 3:
        return False
    periods = np.diff(times_s)
    median = float(np.median(periods))
    return median > 0 and bool(np.any(np.abs(periods - median) > VIDEO_PERIOD_TOLERANCE * median))


class VideoSource:
    """The frames of one camera as a video file, decoded in order with cv2.VideoCapture.

    The frames are counted, and their presentation times read, by decoding the file once when it is opened: the
    header's frame count is an estimate (duration x rate) in Matroska/WebM and wrong in a variable-rate or truncated
    recording (a good 10-frame VFR video whose header said 17 was refused as "truncated or damaged"; adv5).
    ``times_s`` are the container's frame times (s, from 0)."""

    def __init__(self, path: Path):
        self.where = path
        self.header_frames = 0
        self.times_s, message = self._frame_times(path)
        self.n = len(self.times_s)
        why = f" ({message})" if message else ""
        if self.complaints:  # a frame decoded with errors (an MJPEG frame with a damaged scan): passed on, named
            k, said = self.complaints[0]
            log.warning("%s: FFmpeg reported %r decoding frame %d%s; it may be damaged: check it or re-export the "
                        "recording", path, said, k, f" (and {len(self.complaints) - 1} more frames)"
                        if len(self.complaints) > 1 else "")
        if self.n == 0:
            raise FileFormatError(f"{path}: the video has no frames that decode{why} (an audio-only, empty or damaged "
                                  "recording); give the camera's video")
        if self.header_frames > self.n:
            log.warning("%s: %d frames decode but the header says %d (a truncated recording or a variable frame "
                        "rate%s); using the %d", path, self.n, self.header_frames, f": {message}" if message else "",
                        self.n)
        self.capture = self._open(path)
        self.next = 0

    def _open(self, path: Path) -> cv2.VideoCapture:
        return open_video(path)

    def _frame_times(self, path: Path) -> tuple[np.ndarray, str | None]:
        times, self.header_frames, message, self.complaints = video_frame_times(path)
        return times, message

    def __len__(self) -> int:
        return self.n

    def read(self, k: int) -> tuple[np.ndarray, str]:
        if k < self.next:
            raise ValueError("video frames must be read in increasing order")
        from bodystudio.fileio import native_stderr_captured

        with native_stderr_captured():  # counted when opened: what FFmpeg says now was said then
            while self.next < k:
                if not self.capture.grab():
                    break
                self.next += 1
            ok, image = self.capture.read() if self.next == k else (False, None)
        self.next += 1
        if not ok or image is None:
            raise FileFormatError(f"{self.where}: frame {k} cannot be decoded (the video had {self.n} frames when "
                                  "it was opened); the file changed or is damaged")
        return cv2.cvtColor(image, cv2.COLOR_BGR2RGB), f"{self.where} frame {k}"

    def close(self) -> None:
        self.capture.release()


#: Frame periods within this fraction of the median are one constant rate (the container's rounding, a camera's
#: clock jitter); a period further off is a dropped or held frame of a variable-rate recording.
VIDEO_PERIOD_TOLERANCE = 0.25


def check_video_rates(sources: dict, paired: bool = True, n_frames: int | None = None) -> None:
    """Refuse videos that frame-index synchronisation would pair wrongly (adv5): cameras recording at different
    rates (a 30 fps and a 15 fps camera: session frame 20 paired 0.67 s with 1.33 s), or a camera whose frame times
    are not evenly spaced (a phone's variable frame rate, a dropped frame: every later frame paired with another
    camera's later one). Both imported with exit 0 before; the fix is a timestamps folder."""
    rates = {}
    for name, source in sources.items():
        times = getattr(source, "times_s", None)
        times = None if times is None else times[:n_frames]  # the frames imported
        if times is None or len(times) < 2:
            continue
        periods = np.diff(times)
        median = float(np.median(periods))
        if median <= 0:
            continue
        off = np.abs(periods - median) > VIDEO_PERIOD_TOLERANCE * median
        rates[name] = 1.0 / median if np.any(off) else (len(times) - 1) / float(times[-1] - times[0])
        if paired and np.any(off):
            k = int(np.argmax(off)) + 1
            raise FileFormatError(f"{source.where}: variable frame rate (frame {k} comes {1e3 * periods[k - 1]:.0f} "
                                  f"ms after frame {k - 1}, the median period is {1e3 * median:.0f} ms); frames "
                                  "paired by index would be recorded at different times; give --timestamps with "
                                  "each camera's frame times")
    if len(rates) > 1:
        first, *rest = rates
        for name in rest:
            if abs(rates[name] - rates[first]) > 0.01 * rates[first]:
                raise FileFormatError(f"{sources[name].where}: {rates[name]:.3g} fps but {sources[first].where} is "
                                      f"{rates[first]:.3g} fps; frames paired by index would be recorded at "
                                      "different times; give --timestamps with each camera's frame times")


def camera_sources(root: Path, names: list[str], videos: bool):
    """One frame source per camera: ``root/<cam>/`` image folders or ``root/<cam>.<video>`` files."""
    sources = {}
    for name in names:
        if videos:
            found = [root / f"{name}{s}" for s in VIDEO_SUFFIXES if (root / f"{name}{s}").is_file()]
            if not found:
                present = sorted(p.name for p in root.iterdir() if p.suffix.lower() in VIDEO_SUFFIXES)
                raise FileFormatError(f"{root / name}.*: no video for camera {name} (the calibration lists it); "
                                      f"found {', '.join(present) or 'no videos'}; name each video after its camera")
            sources[name] = VideoSource(found[0])
        else:
            if not (root / name).is_dir():
                present = sorted(p.name for p in root.iterdir() if p.is_dir())
                raise FileFormatError(f"{root / name}: missing image folder for camera {name} (the calibration "
                                      f"lists it); found {', '.join(present) or 'no folders'}")
            sources[name] = ImageFolderSource(root / name)
    return sources


def file_frame_number(path: Path) -> int | None:
    """The frame number a recorder wrote into a file name: the last run of ASCII digits of its stem, else None."""
    runs = re.findall(r"[0-9]+", path.stem)
    return int(runs[-1]) if runs else None


def check_frame_numbers(sources: dict, n_frames: int) -> None:
    """Refuse image folders paired by order whose file names say the pairs are of different frames: numbered files
    whose numbers drift apart between two cameras (a dropped frame each: ``cam_a`` without 3, ``cam_b`` without 4,
    five files each, paired 4 with 3 from there on, exit 0 before; adv5). A constant offset (one camera's counter
    started at 100) is no drift; numbers that mostly do not step by one are no frame counter and are not compared."""
    numbered = {}
    for name, source in sources.items():
        files = getattr(source, "files", None)
        if files is None:
            return
        numbers = [file_frame_number(f) for f in files[:n_frames]]
        if any(n is None for n in numbers):
            return
        numbered[name] = np.asarray(numbers, np.int64)
        if len(numbers) > 1 and np.median(np.diff(numbered[name])) != 1:
            return  # not a frame counter (a phone's IMG_20240101_120003 times, every other frame kept)
    names = list(numbered)
    first = numbered[names[0]]
    for name in names[1:]:
        drift = numbered[name] - first
        if np.any(drift != drift[0]):
            k = int(np.argmax(drift != drift[0]))
            raise FileFormatError(f"{sources[name].files[k]}: paired by order with {sources[names[0]].files[k].name} "
                                  f"of {names[0]}, but their frame numbers drift apart from there ({numbered[name][k]} "
                                  f"and {first[k]}, {drift[0]} apart before): a frame dropped by one camera; remove "
                                  "the frames not every camera has, or give --timestamps")


def read_timestamps(path: Path) -> np.ndarray:
    """Frame times in seconds, one per non-comment line (first column)."""
    if not path.is_file():
        raise FileFormatError(f"{path}: timestamps file not found; give one <camera>.txt per camera")
    out = []
    previous = None
    for n, line in enumerate(path.read_text().splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        try:
            t = float(line.replace(",", " ").split()[0])
        except ValueError:
            raise FileFormatError(f"{path}:{n}: {line!r} is not a time in seconds") from None
        if not np.isfinite(t):
            raise FileFormatError(f"{path}:{n}: {line!r} is not a time in seconds")
        # a repeated or earlier time is a duplicated or reordered frame: matched by nearest time it became a
        # repeated frame of the session, or frames out of time order, with exit 0
        if previous is not None and t <= previous[0]:
            raise FileFormatError(f"{path}:{n}: time {t:g} s is not after line {previous[1]}'s {previous[0]:g} s "
                                  "(a duplicated or out-of-order frame); one time per frame, increasing, in the "
                                  "order of the camera's frames: remove the duplicate or sort the frames")
        previous = (t, n)
        out.append(t)
    if not out:
        raise FileFormatError(f"{path}: no timestamps")
    return np.asarray(out)


def synchronise_by_timestamps(times: dict[str, np.ndarray], tolerance_s: float | None = None) -> list[dict[str, int]]:
    """Frame index per camera for each reference-camera frame that every camera saw within ``tolerance_s``.

    The first camera is the reference; the tolerance defaults to half its median frame period.
    """
    names = list(times)
    ref = times[names[0]]
    if tolerance_s is None:
        tolerance_s = 0.5 * float(np.median(np.diff(ref))) if len(ref) > 1 else np.inf
    frames = []
    for k, t in enumerate(ref):
        match = {names[0]: k}
        for name in names[1:]:
            j = int(np.argmin(np.abs(times[name] - t)))
            if abs(times[name][j] - t) > tolerance_s:
                break
            match[name] = j
        else:
            frames.append(match)
    return frames


# ---------------------------------------------------------------------------------------------- TUM depth

def read_tum_list(path: Path) -> list[tuple[float, str]]:
    """A TUM ``depth.txt``/``rgb.txt``: ``timestamp filename`` lines, ``#`` comments."""
    if not path.is_file():
        raise FileFormatError(f"{path}: not found; a TUM RGB-D folder has depth.txt and rgb.txt")
    out, seen = [], {}
    for n, line in enumerate(path.read_text().splitlines(), 1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        parts = line.split()
        try:
            t = float(parts[0])
            out.append((t, parts[1]))
        except (ValueError, IndexError):
            raise FileFormatError(f"{path}:{n}: expected 'timestamp filename', got {line.strip()!r}") from None
        # a repeated time (a duplicated line) was paired with two colour frames when the colour stream runs faster
        # than the depth (60 / 30 fps): one depth image in two session frames, exit 0. Lines out of order are
        # harmless (the pairs are sorted by time).
        if not np.isfinite(t) or t in seen:
            raise FileFormatError(f"{path}:{n}: time {parts[0]} "
                                  + (f"repeats line {seen[t]}'s (a duplicated frame); remove the duplicate"
                                     if t in seen else "is not a time in seconds"))
        seen[t] = n
    return out


def associate_tum(depth: list[tuple[float, str]], rgb: list[tuple[float, str]],
                  max_difference_s: float = TUM_MAX_DIFFERENCE_S) -> list[tuple[float, str, str]]:
    """Pair depth and colour frames by timestamp (TUM's associate.py: greedy on the closest pairs)."""
    candidates = sorted((abs(td - tr), i, j) for i, (td, _) in enumerate(depth) for j, (tr, _) in enumerate(rgb)
                        if abs(td - tr) < max_difference_s)
    used_d, used_r, pairs = set(), set(), []
    for _, i, j in candidates:
        if i not in used_d and j not in used_r:
            used_d.add(i)
            used_r.add(j)
            pairs.append((depth[i][0], depth[i][1], rgb[j][1]))
    return sorted(pairs)


def depth_scale_of(raw: np.ndarray, source: str, depth_scale: float | None, default: float = TUM_DEPTH_SCALE) -> float:
    """Units per metre of a raw depth image, checked against the depth a Kinect sees a body at.

    With an explicit ``depth_scale`` only the dtype is checked. Otherwise the TUM scale is expected;
    depth that looks like millimetres (or anything implausible) raises a one-line error naming the fix.
    """
    if raw.dtype.kind == "f":
        if depth_scale is None:
            raise FileFormatError(f"{source}: depth is stored as floating point (metres?); pass --depth-scale 1 "
                                  "for metres, or store 16-bit PNG in TUM units (5000 per metre)")
        return depth_scale
    if raw.dtype != np.uint16:
        raise FileFormatError(f"{source}: depth must be a 16-bit PNG, got {raw.dtype} (8-bit images lose the "
                              "depth); export 16-bit depth")
    if depth_scale is not None:
        return depth_scale
    valid = raw[raw > 0]
    if valid.size == 0:
        return default
    median = float(np.median(valid))
    lo, hi = PLAUSIBLE_DEPTH_M
    units = {default: "TUM units", 1000.0: "millimetres", 1.0: "metres"}
    plausible = [scale for scale in units if lo <= median / scale <= hi]
    if plausible == [default]:
        return default
    if len(plausible) > 1:
        readings = " or ".join(f"{median / sc:.2f} m as {units[sc]}" for sc in plausible)
        raise FileFormatError(f"{source}: depth units are ambiguous (median {readings}); pass --depth-scale "
                              f"{' or --depth-scale '.join(f'{sc:g}' for sc in plausible)}")
    if plausible:
        scale = plausible[0]
        raise FileFormatError(f"{source}: depth looks like {units[scale]} (median {median / scale:.2f} m at "
                              f"{scale:g} per metre, {median / default:.2f} m at TUM's {default:g}); "
                              f"pass --depth-scale {scale:g}")
    raise FileFormatError(f"{source}: depth values (median {median:g}) are not in a known unit; pass --depth-scale "
                          "(units per metre)")


#: The median depth (m) a stated ``--depth-scale`` must give a frame: any depth camera's working range, wide enough
#: for sensors other than the Kinect, narrow enough to catch a factor of 1000 (metres read as mm, mm as metres).
STATED_DEPTH_M = (0.1, 20.0)


def check_stated_depth_scale(raw: np.ndarray, source: Path, depth_scale: float) -> None:
    """Refuse a ``--depth-scale`` that puts a frame's median depth outside :data:`STATED_DEPTH_M`: float depth in
    millimetres with ``--depth-scale 1`` (2000 m) raised a ValueError traceback when stored, and metres read at 1000
    per metre (2 mm) were stored as no depth, exit 0 (adv5)."""
    finite = raw[np.isfinite(raw) & (raw > 0)] if raw.dtype.kind == "f" else raw[raw > 0]
    if finite.size == 0:
        return
    median = float(np.median(finite)) / depth_scale
    lo, hi = STATED_DEPTH_M
    if not lo <= median <= hi:
        raise FileFormatError(f"{source}: at --depth-scale {depth_scale:g} the median depth is {median:g} m, no depth "
                              f"camera's ({lo:g}-{hi:g} m); pass the units per metre the file is stored in (metres: "
                              "1, millimetres: 1000, TUM: 5000)")


def check_depth_unit(raw: np.ndarray, source: Path, scale: float, first: Path, first_dtype, explicit: bool) -> None:
    """Refuse a depth frame in another format or unit than the frame the unit was taken from (``first``): a
    float frame after 16-bit ones was divided by the 16-bit scale (metres read as 1/5000 m), a frame in
    millimetres after TUM units stored 5x short, both with exit 0 (adv5). Only a frame that another unit makes
    plausible (and its own does not) is refused: a frame of a far wall stays."""
    if raw.dtype.kind != "f" and raw.dtype != np.uint16:
        depth_scale_of(raw, str(source), None)  # 8-bit depth: its own refusal
    if raw.dtype != first_dtype:
        raise FileFormatError(f"{source}: depth stored as {raw.dtype} but {first} as {first_dtype}; export every "
                              "depth frame of the recording in one format")
    if explicit or raw.dtype.kind == "f":
        return
    valid = raw[raw > 0]
    if valid.size == 0:
        return
    median = float(np.median(valid))
    lo, hi = PLAUSIBLE_DEPTH_M
    if lo <= median / scale <= hi:
        return
    units = {TUM_DEPTH_SCALE: "TUM units", 1000.0: "millimetres", 1.0: "metres"}
    others = [other for other in units if other != scale and lo <= median / other <= hi]
    if len(others) == 1:
        other = others[0]
        raise FileFormatError(f"{source}: depth looks like {units[other]} (median {median / other:.2f} m; "
                              f"{median / scale:.2f} m at {scale:g} per metre) but {first} was read at {scale:g} per "
                              "metre; export every depth frame of the recording in one unit")


# ---------------------------------------------------------------------------------------------- joints

JOINT_FRAMES = ("studio", "kinect-sdk")
#: Kinect SDK camera space (x left, y up, z forward) -> OpenCV camera axes (x right, y down, z forward).
_SDK_TO_OPENCV = np.diag([-1.0, -1.0, 1.0])


def kinect_sdk_to_studio(points: np.ndarray, sensor) -> np.ndarray:
    """Joints (J, 3) in the Kinect SDK's camera space (metres, depth camera origin) -> studio frame."""
    return sensor.depth.camera_to_world(np.asarray(points, dtype=np.float64) @ _SDK_TO_OPENCV.T)


def studio_to_kinect_sdk(points: np.ndarray, sensor) -> np.ndarray:
    """Inverse of :func:`kinect_sdk_to_studio`."""
    return sensor.depth.world_to_camera(points) @ _SDK_TO_OPENCV


@dataclass(frozen=True)
class JointTrack:
    names: list[str]
    positions: np.ndarray  # (T, J, 3) metres
    tracked: np.ndarray  # (T, J) bool


def load_joints(path: str | os.PathLike) -> JointTrack:
    """Tracker joints: per-frame JSON folder, one JSON (``names`` + ``frames``) or CSV ``frame,joint,x,y,z``."""
    path = Path(path)
    if path.is_dir():
        files = sorted(path.glob("*.json"), key=frame_order)
        if not files:
            raise FileFormatError(f"{path}: no per-frame joint JSON files")
        numbers = [file_frame_number(f) for f in files]
        if None not in numbers:  # per-frame files named by frame number
            check_joint_frame_numbers(numbers, path, [f.name for f in files])
        per_frame = [_joint_frame(json_or_error(f), f) for f in files]
        names = per_frame[0][0]
        for (n, _, _), f in zip(per_frame, files, strict=True):
            if n != names:
                raise FileFormatError(f"{f}: joint names differ from {files[0].name}; every frame needs the "
                                      "same joints")
        track = JointTrack(names, np.stack([p for _, p, _ in per_frame]), np.stack([t for _, _, t in per_frame]))
    elif path.suffix.lower() == ".json":
        data = json_or_error(path)
        try:
            names = list(data["names"])
            pos = np.asarray(data["frames"], dtype=np.float64).reshape(-1, len(names), 3)
            tracked = np.asarray(data.get("tracked", np.ones(pos.shape[:2], bool)), bool).reshape(pos.shape[:2])
        except (KeyError, TypeError, ValueError) as exc:
            raise FileFormatError(f"{path}: joints JSON needs 'names' and 'frames' (T x J x 3 metres): {exc}") from None
        track = JointTrack(names, pos, tracked)
    elif path.suffix.lower() == ".csv":
        track = _joints_csv(path)
    else:
        raise FileFormatError(f"{path}: joints must be a folder of JSON, a .json or a .csv file")
    if not np.all(np.isfinite(track.positions)):
        raise FileFormatError(f"{path}: joint positions contain NaN or infinity")
    if np.abs(track.positions).max(initial=0) > 20.0:
        raise FileFormatError(f"{path}: joint coordinates up to {np.abs(track.positions).max():.0f} look like "
                              "millimetres; give metres")
    return track


#: Where the Kinect's depth camera sees the tracked person: the median joint this far in front of it (m; the
#: sensors' range is 0.5-4.5 m) and projecting within half an image of the depth image.
JOINTS_IN_VIEW_M = (0.3, 8.0)


def check_joints_frame(track: JointTrack, sensor, joints_frame: str, source: Path) -> None:
    """Refuse joints given in the other frame than ``--joints-frame`` says: studio-frame joints read as the Kinect
    SDK's camera space, or the SDK's read as the studio's, put the person ~0 m from the depth camera and far outside
    its image (the synthetic studio: 0.0-0.02 m, 1000+ px off), which the import stored with exit 0 and the stages
    then fitted to."""
    P = track.positions.reshape(-1, 3)
    if joints_frame == "kinect-sdk":
        P = kinect_sdk_to_studio(P, sensor)
    camera = sensor.depth
    C = camera.world_to_camera(P)
    z = float(np.median(C[:, 2]))
    u, v = (np.median(C[:, :2] / np.maximum(C[:, 2:3], 1e-6), axis=0) * np.diag(camera.K)[:2] + camera.K[:2, 2])
    W, H = camera.width, camera.height
    lo, hi = JOINTS_IN_VIEW_M
    if lo <= z <= hi and -W / 2 <= u <= 1.5 * W and -H / 2 <= v <= 1.5 * H:
        return
    other = "studio" if joints_frame == "kinect-sdk" else "kinect-sdk"
    raise FileFormatError(f"{source}: read as --joints-frame {joints_frame}, the joints lie {z:.2f} m in front of "
                          f"the Kinect depth camera at pixel ({u:.0f}, {v:.0f}) of its {W}x{H} image, not where it "
                          f"sees a person; if they are in the {other} frame pass --joints-frame {other}, else check "
                          "the --kinect-calibration")


def check_joint_frame_numbers(numbers: list[int], source: Path, names: list[str] | None = None) -> None:
    """Refuse tracker joints whose frame numbers jump (a frame the tracker wrote nothing for): joints go to the
    recording's frames in order, so every later frame's joints went to the frame before its own; the count refusal
    that followed suggested the ``--frames`` that did exactly that, exit 0 (adv5)."""
    gaps = np.flatnonzero(np.diff(np.asarray(numbers, np.int64)) != 1)
    if gaps.size:
        k = int(gaps[0])
        what = f"{names[k]} to {names[k + 1]}" if names else f"frame {numbers[k]} to frame {numbers[k + 1]}"
        raise FileFormatError(f"{source}: the joint frames jump from {what}; joints go to the recording's frames in "
                              "order, so each later frame's would go to an earlier frame: give one entry per "
                              "recorded frame (tracked 0 where the body was lost)")


def json_or_error(path: Path):
    if not path.is_file():  # a pipe would block the read forever
        raise FileFormatError(f"{path}: not a regular file")
    try:
        return json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise FileFormatError(f"{path}: not valid JSON ({exc})") from None


def _joint_frame(data, source: Path):
    try:
        if "joints" in data:
            names = list(data["joints"])
            pos = np.asarray([data["joints"][n] for n in names], dtype=np.float64).reshape(-1, 3)
        else:
            names = list(data["names"])
            pos = np.asarray(data["positions"], dtype=np.float64).reshape(len(names), 3)
        tracked = np.asarray(data.get("tracked", [True] * len(names)), bool)
    except (KeyError, TypeError, ValueError) as exc:
        raise FileFormatError(f"{source}: joints need 'names' + 'positions' or a 'joints' object ({exc})") from None
    return names, pos, tracked


def _joints_csv(path: Path) -> JointTrack:
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    need = {"frame", "joint", "x", "y", "z"}
    if not rows or not need <= set(rows[0]):
        raise FileFormatError(f"{path}: CSV needs a header with columns frame,joint,x,y,z[,tracked]")
    names = list(dict.fromkeys(r["joint"] for r in rows))
    numbers = []
    for line, r in enumerate(rows, 2):
        try:
            numbers.append(int(r["frame"]))
        except (TypeError, ValueError):  # '1.5', '' or a missing cell: a traceback before (adv5)
            raise FileFormatError(f"{path}:{line}: frame {r['frame']!r} is not a whole frame number") from None
    frames = sorted(set(numbers))
    check_joint_frame_numbers(frames, path)
    index = {f: i for i, f in enumerate(frames)}
    pos = np.full((len(frames), len(names), 3), np.nan)
    tracked = np.zeros((len(frames), len(names)), bool)
    jn = {n: j for j, n in enumerate(names)}
    for line, r in enumerate(rows, 2):
        try:
            i, j = index[int(r["frame"])], jn[r["joint"]]
            pos[i, j] = float(r["x"]), float(r["y"]), float(r["z"])
            tracked[i, j] = str(r.get("tracked", "1")).strip().lower() not in ("0", "false", "no")
        except ValueError:
            raise FileFormatError(f"{path}:{line}: frame, x, y, z must be numbers") from None
    missing = np.argwhere(np.isnan(pos[..., 0]))
    if len(missing):
        i, j = missing[0]
        raise FileFormatError(f"{path}: frame {frames[i]} has no row for joint {names[j]}")
    return JointTrack(names, pos, tracked)


# ---------------------------------------------------------------------------------------------- import

def import_recording(out: str | os.PathLike, cameras: str | os.PathLike | None = None,
                     images: str | os.PathLike | None = None, videos: str | os.PathLike | None = None,
                     timestamps: str | os.PathLike | None = None, backgrounds: str | os.PathLike | None = None,
                     tum: str | os.PathLike | None = None, kinect_calibration: str | os.PathLike | None = None,
                     depth_scale: float | None = None, joints: str | os.PathLike | None = None,
                     n_frames: int | None = None, masks: str | os.PathLike | None = None,
                     joints_frame: str = "studio", progress: bool = False) -> Session:
    """Convert a recording into the session folder ``out``; every input problem is a one-line error.

    Studio frames come from ``images`` (folder per camera) or ``videos`` (file per camera), synchronised
    by index or, with ``timestamps`` (``<cam>.txt`` per camera), by time. ``tum`` adds Kinect depth and
    colour (needs ``kinect_calibration``); ``joints`` adds tracker joints, one entry per session frame,
    given in the studio frame or (``joints_frame="kinect-sdk"``) in the Kinect SDK's camera space (x left,
    y up, z forward from the depth camera; converted with the Kinect calibration). ``masks`` imports
    existing silhouettes (``masks/<cam>/`` image folders, same order as the frames; :func:`subject_pixels`).
    """
    from bodystudio.capture.session import progress_bar

    out = Path(out)
    if out.exists() and any(out.iterdir()):
        raise InputError(f"{out}: output folder exists and is not empty; choose a new folder")
    if images and videos:
        raise InputError("give --images or --videos, not both")
    frame_root = Path(images or videos) if (images or videos) else None
    if frame_root is not None and not frame_root.is_dir():
        raise FileFormatError(f"{frame_root}: no such folder")
    if cameras is None and tum is None:
        raise InputError("give --cameras (cameras.json or EasyMocap intri.yml/extri.yml)")
    if tum is not None and kinect_calibration is None:
        raise InputError(f"{tum}: Kinect depth needs --kinect-calibration (JSON with 'depth' and 'color' cameras, "
                         "see docs/session-format.md)")
    if n_frames is not None and n_frames < 1:
        raise InputError(f"--frames {n_frames}: import at least one frame")
    if depth_scale is not None and not (np.isfinite(depth_scale) and depth_scale > 0):
        raise InputError(f"--depth-scale {depth_scale}: give the depth units per metre (> 0; TUM: 5000)")
    if joints_frame not in JOINT_FRAMES:
        raise InputError(f"--joints-frame {joints_frame!r} is not one of {', '.join(JOINT_FRAMES)}")
    if joints_frame != "studio" and kinect_calibration is None:
        raise InputError(f"--joints-frame {joints_frame} needs --kinect-calibration to place the Kinect in the studio")
    sensor = load_kinect_calibration(kinect_calibration) if kinect_calibration else None
    rig = _cameras_for_import(cameras, frame_root, videos is not None, sensor)
    names = list(rig.cameras)
    mask_sources = camera_sources(Path(masks), names, videos=False) if masks is not None else {}

    # -- studio frame plan: one {camera: source frame index} per session frame
    sources = camera_sources(frame_root, names, videos is not None) if frame_root is not None else {}
    if timestamps is not None and sources:
        ts = {n: read_timestamps(Path(timestamps) / f"{n}.txt") for n in names}
        for n in names:
            if len(ts[n]) != len(sources[n]):
                raise FileFormatError(f"{Path(timestamps) / (n + '.txt')}: {len(ts[n])} timestamps but "
                                      f"{sources[n].where} has {len(sources[n])} frames")
        plan = synchronise_by_timestamps(ts)
        frame_times = [float(ts[names[0]][p[names[0]]]) for p in plan]
    elif sources:
        counts = {n: len(s) for n, s in sources.items()}
        n_common = min(counts.values())
        if len(set(counts.values())) > 1 and n_frames is None:
            worst = next(n for n in names if counts[n] != counts[names[0]])
            raise FileFormatError(f"{sources[worst].where}: {counts[worst]} frames but {sources[names[0]].where} has "
                                  f"{counts[names[0]]}; give a timestamps folder to synchronise, or --frames "
                                  f"{n_common} to use the first frames")
        n_imported = min(n_common, n_frames or n_common)
        check_video_rates(sources, paired=len(sources) > 1 or tum is not None, n_frames=n_imported)
        check_frame_numbers(sources, n_imported)
        for name, masks_of in mask_sources.items():  # a mask folder missing one frame's mask, one more at the end
            check_frame_numbers({name: sources[name], f"{name} (masks)": masks_of}, min(n_imported, len(masks_of)))
        plan = [{n: k for n in names} for k in range(n_common)]
        frame_times = None
    else:
        plan, frame_times = None, None

    tum_pairs = None
    if tum is not None:
        tum = Path(tum)
        tum_pairs = associate_tum(read_tum_list(tum / "depth.txt"), read_tum_list(tum / "rgb.txt"))
        if not tum_pairs:
            raise FileFormatError(f"{tum / 'depth.txt'}: no depth frame has a colour frame within "
                                  f"{TUM_MAX_DIFFERENCE_S} s in rgb.txt")
        if frame_times is not None:
            stamps = np.array([p[0] for p in tum_pairs])
            nearest = [int(np.argmin(np.abs(stamps - t))) for t in frame_times]
            tum_pairs = [tum_pairs[j] if abs(stamps[j] - t) <= TUM_MAX_DIFFERENCE_S else None
                         for j, t in zip(nearest, frame_times, strict=True)]
    track = load_joints(joints) if joints is not None else None
    if track is not None and sensor is not None:
        check_joints_frame(track, sensor, joints_frame, Path(joints))

    total = len(plan) if plan is not None else len(tum_pairs) if tum_pairs is not None else None
    if total is None:
        raise InputError("nothing to import: give --images, --videos or --tum")
    if n_frames is not None:
        total = min(total, n_frames)
    # joints are per recorded frame: with --timestamps the first camera's frame (the synchronisation drops the
    # frames another camera missed; by session index the joints after a dropped frame were a frame late, exit 0)
    joint_index = [p[names[0]] for p in plan[:total]] if frame_times is not None else list(range(total))
    for what, available, index, where in (
            ("TUM depth/colour pairs", len(tum_pairs) if tum_pairs is not None else None, range(total),
             tum / "depth.txt" if tum is not None else None),
            ("joint frames", len(track.positions) if track is not None else None, joint_index, joints)):
        if available is not None and total and available <= index[-1]:
            fitting = sum(1 for k in index if k < available)
            raise FileFormatError(f"{where}: {available} {what} but the recording has {index[-1] + 1} frames; "
                                  + (f"pass --frames {fitting}" if fitting else "give one per recorded frame"))

    scale, scale_frame = None, None
    metadata = {"generator": "bodystudio capture import", "inputs": {
        k: str(v) for k, v in dict(cameras=cameras, images=images, videos=videos, timestamps=timestamps,
                                   backgrounds=backgrounds, tum=tum, kinect_calibration=kinect_calibration,
                                   joints=joints).items() if v is not None}}
    fps = recording_fps(frame_times if frame_times is not None else
                        [p[0] for p in tum_pairs] if tum_pairs is not None and plan is None else None,
                        Path(timestamps) / f"{names[0]}.txt" if frame_times is not None else tum / "depth.txt"
                        if tum is not None else None)
    if fps is None and plan is not None and frame_times is None and videos is not None:
        # the videos' own frame times (a 15 fps webcam's video imported without metadata.fps was read as 30 fps:
        # the arm capture's filters twice as wide in seconds, the mirror video twice as fast; adv5)
        fps = video_fps(sources[names[0]].times_s[:total], sources[names[0]].where)
    if fps is not None:  # readers assume 30 without it: a 15 fps recording's mirror video played twice as fast
        metadata["fps"] = fps
    try:
        with progress_bar(progress) as bar, SessionWriter(out, rig, source="import", metadata=metadata,
                                                                      command="bodystudio capture import") as writer:
            task = bar.add_task("import", total=total)
            if sensor is not None:
                writer.write_kinect_calibration(sensor)
            if backgrounds is not None:
                _import_backgrounds(writer, Path(backgrounds), rig)
            for i in range(total):
                if plan is not None:
                    for name in names:
                        image, where = sources[name].read(plan[i][name])
                        _check_size(image, rig[name], where)
                        writer.write_image(name, i, image)
                if tum_pairs is not None and tum_pairs[i] is not None:
                    _, depth_file, rgb_file = tum_pairs[i]
                    raw = read_image_file(tum / depth_file, cv2.IMREAD_UNCHANGED)
                    if scale is None:
                        found = depth_scale_of(raw, str(tum / depth_file), depth_scale)
                        # a blank first frame (a Kinect's first frames often are) says nothing about the unit: the
                        # TUM default it gave was kept for every later frame, millimetres stored 5x short, exit 0
                        if depth_scale is not None or raw.dtype.kind == "f" or np.any(raw > 0):
                            scale, scale_frame = found, (tum / depth_file, raw.dtype)
                    else:
                        check_depth_unit(raw, tum / depth_file, scale, *scale_frame, explicit=depth_scale is not None)
                    _check_size(raw, sensor.depth, str(tum / depth_file))
                    if depth_scale is not None:
                        check_stated_depth_scale(raw, tum / depth_file, depth_scale)
                    writer.write_kinect_depth(i, raw.astype(np.float64) / (scale or TUM_DEPTH_SCALE))
                    color = read_image_file(tum / rgb_file)
                    _check_size(color, sensor.color, str(tum / rgb_file))
                    writer.write_kinect_rgb(i, color)
                for name, source in mask_sources.items():
                    k = plan[i][name] if plan is not None else i
                    if k >= len(source):
                        raise FileFormatError(f"{source.where}: {len(source)} masks but frame {k} is needed; "
                                              "give one mask per frame")
                    mask = read_image_file(source.files[k], cv2.IMREAD_GRAYSCALE)
                    _check_size(mask, rig[name], str(source.files[k]))
                    writer.write_mask(name, i, subject_pixels(mask))
                if track is not None:
                    positions = track.positions[joint_index[i]]
                    if joints_frame == "kinect-sdk":
                        positions = kinect_sdk_to_studio(positions, sensor)
                    writer.write_kinect_joints(i, track.names, positions, track.tracked[joint_index[i]],
                                               joint_set=sensor.version if sensor is not None else None)
                bar.advance(task)
    finally:
        for s in sources.values():
            s.close()
    log.info("imported %d frames of %d cameras into %s", total, len(names), out)
    return open_session(out)


def recording_fps(frame_times, source: Path | None = None) -> float | None:
    """The frame rate of a recording from its frame times (s): one over the median frame period (None with fewer
    than two frames: readers then assume 30). A rate outside 1..240 fps is refused naming ``source`` (times in
    milliseconds read as a frame every 33 s)."""
    if frame_times is None or len(frame_times) < 2:
        return None
    period = float(np.median(np.diff(np.sort(np.asarray(frame_times, np.float64)))))
    fps = 1.0 / period if period > 0 else float("inf")
    if not 1.0 <= fps <= 240.0:
        raise FileFormatError(f"{source}: the median frame period {period:g} s is not a camera's (1..240 fps); give "
                              "the times in seconds")
    return round(fps, 3)


def video_fps(times_s: np.ndarray, source: Path) -> float | None:
    """A video's frame rate from its frame times (s): frames over the time they span when evenly spaced (Matroska's
    millisecond times put a 15 fps video's median period at 67 ms: 14.925 fps), else :func:`recording_fps`'s median
    period; None with fewer than two frames or no times (a backend that reads 0 for every frame)."""
    if len(times_s) < 2:
        return None
    periods = np.diff(times_s)
    median = float(np.median(periods))
    if median <= 0:
        return None
    if np.all(np.abs(periods - median) <= VIDEO_PERIOD_TOLERANCE * median):
        return recording_fps([0.0, (times_s[-1] - times_s[0]) / (len(times_s) - 1)], source)
    return recording_fps(times_s, source)


def _cameras_for_import(cameras, frame_root, videos, sensor):
    from bodystudio.geometry.camera import CameraRig

    if cameras is None:
        # A Kinect-only recording: its colour camera is the session's one studio camera.
        return CameraRig({"kinect_color": sensor.color.with_name("kinect_color")})
    sizes = None
    cameras = Path(cameras)
    if cameras.suffix.lower() != ".json" and frame_root is not None:
        sizes = _frame_sizes(frame_root, videos)
    return load_studio_cameras(cameras, sizes)


def _frame_sizes(root: Path, videos: bool) -> dict[str, tuple[int, int]]:
    """Image size per camera from its first frame (EasyMocap calibrations may not store it)."""
    sizes = {}
    for p in sorted(root.iterdir()):
        if videos and p.suffix.lower() in VIDEO_SUFFIXES:
            cap = cv2.VideoCapture(str(p))
            if cap.isOpened():
                sizes[p.stem] = (int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)))
            cap.release()
        elif not videos and p.is_dir():
            files = image_files(p)
            if files:
                h, w = read_image_file(files[0]).shape[:2]
                sizes[p.name] = (w, h)
    return sizes


def subject_pixels(mask: np.ndarray) -> np.ndarray:
    """The subject of an imported mask image: the pixels above half its brightest value, or every non-zero pixel of a
    0/1 label image. Read as non-zero, a JPEG mask's ringing and a matting tool's soft edge were subject: a 0/255
    ellipse saved at JPEG quality 90 lost 2 % of its IoU (0.980), exit 0 (adv5)."""
    top = int(mask.max(initial=0))
    return mask > 0 if top <= 1 else mask.astype(np.int32) * 2 > top


def _check_size(image: np.ndarray, camera, where: str) -> None:
    h, w = image.shape[:2]
    if (w, h) == (camera.height, camera.width) and w != h:
        raise FileFormatError(f"{where}: image is {w}x{h}, turned 90 degrees against the calibration of {camera.name} "
                              f"({camera.width}x{camera.height}; a phone video's rotation flag or a photo's EXIF "
                              "orientation, which the reader applies); calibrate on frames read the same way, or "
                              "drop the flag (ffmpeg -display_rotation 0 -i IN -c copy OUT)")
    if (w, h) != (camera.width, camera.height):
        raise FileFormatError(f"{where}: image is {w}x{h} but the calibration of {camera.name} says "
                              f"{camera.width}x{camera.height}; use the matching calibration or frames")


def _import_backgrounds(writer: SessionWriter, root: Path, rig) -> None:
    """Empty-studio frames: ``root/<cam>/`` images, ``root/<cam>.<image>`` or ``root/<cam>.<video>``."""
    if not root.is_dir():
        raise FileFormatError(f"{root}: no such backgrounds folder")
    for cam in rig:
        frames: list[tuple[np.ndarray, str]] = []
        if (root / cam.name).is_dir():
            src = ImageFolderSource(root / cam.name)
            frames = [src.read(k) for k in range(len(src))]
        else:
            files = [root / f"{cam.name}{s}" for s in IMAGE_SUFFIXES + VIDEO_SUFFIXES
                     if (root / f"{cam.name}{s}").is_file()]
            if not files:
                raise FileFormatError(f"{root / cam.name}: no empty-studio frames for camera {cam.name} "
                                      "(a folder, an image or a video named after the camera)")
            if files[0].suffix.lower() in VIDEO_SUFFIXES:
                src = VideoSource(files[0])
                frames = [src.read(k) for k in range(len(src))]
                src.close()
            else:
                frames = [(read_image_file(files[0]), str(files[0]))]
        for k, (image, where) in enumerate(frames):
            _check_size(image, cam, where)
            writer.write_background(cam.name, k, image)
