"""Atomic file writes and small JSON helpers shared by every stage.

Every write goes through :func:`atomic_write`: a temporary file in the destination folder is
written, flushed, fsync'ed and renamed over the target, so a reader never sees half a file.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import os
import re
import stat
import sys
import tempfile
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from bodystudio.errors import FileFormatError, InputError, OutputSpaceError, disk_full

log = logging.getLogger(__name__)


def is_frame_number(text: str) -> bool:
    """Whether ``text`` (a file stem) is a frame number: ASCII digits only. ``str.isdigit`` also accepts '²'
    (which ``int`` then refuses with a traceback) and other scripts' digits ('٠٠٠٠١', which ``int`` reads as 1:
    a second file for frame 1, silently taken instead of ``00001.png``) (rel6b)."""
    return text.isascii() and text.isdigit()


def _umask_mode() -> int:
    """Permissions a plain ``open(path, "w")`` would give (mkstemp's temp files are 0600)."""
    mask = os.umask(0)
    os.umask(mask)
    return 0o666 & ~mask


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path beside ``path`` for libraries that write by filename; rename on success.

    ``suffix`` keeps the extension libraries use to pick a format (defaults to ``path``'s own).
    """
    path = Path(path)
    suffix = path.suffix if suffix is None else suffix
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=f".tmp{suffix}", dir=path.parent)
    except OSError as exc:
        if disk_full(exc):
            raise OutputSpaceError(path, exc.strerror or "no space left on device") from None
        raise
    os.close(fd)
    try:
        yield Path(tmp)
        with open(tmp, "rb+") as f:
            os.fsync(f.fileno())
        os.chmod(tmp, _umask_mode())
        os.replace(tmp, path)
    except BaseException as exc:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        if disk_full(exc) and not isinstance(exc, OutputSpaceError):  # one line naming the file, not a traceback
            raise OutputSpaceError(path, exc.strerror or "no space left on device") from None
        raise


@contextlib.contextmanager
def atomic_write(path: str | os.PathLike, mode: str = "wb") -> Iterator[Any]:
    """Open a temporary file beside ``path``; on success rename it over ``path``."""
    with atomic_path(path, suffix="") as tmp, open(tmp, mode) as f:
        yield f


def sha256_file(path: str | os.PathLike) -> str:
    """Hex sha256 of a file, read in 1 MiB chunks."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"cannot write {type(obj).__name__} as JSON")


def write_json(path: str | os.PathLike, data: Any, indent: int | None = 2) -> None:
    """Write ``data`` (numpy arrays allowed) as JSON, atomically."""
    text = json.dumps(data, indent=indent, default=_json_default)
    with atomic_write(path, "w") as f:
        f.write(text + "\n")


def read_json(path: str | os.PathLike, what: str = "JSON file") -> Any:
    """Read a JSON file; a missing or malformed file raises a one-line FileFormatError."""
    path = Path(path)
    if path.exists() and not path.is_file():  # a folder, or a pipe that would block the read forever
        raise FileFormatError(f"{path}: {what} is not a regular file")
    try:
        with open(path, encoding="utf-8") as f:
            return json.load(f)
    except FileNotFoundError:
        raise FileFormatError(f"{path}: {what} not found") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise FileFormatError(f"{path}: not a valid {what} ({exc}); fix or regenerate the file") from None


def _existing_ancestor(path: Path) -> Path:
    """The deepest ancestor of ``path`` that exists (``path``'s parent when it exists)."""
    parent = path.absolute().parent
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    return parent


def _probe_writable(folder: Path, path: Path, what: str) -> None:
    """Create and remove a temporary file in ``folder``: the only test that also holds for root,
    read-only mounts and pseudo file systems (/sys, /proc), where ``os.access`` says yes."""
    try:
        fd, tmp = tempfile.mkstemp(prefix=".bodystudio-probe.", dir=folder)
    except OSError as exc:
        raise InputError(f"{what} {path}: cannot write in {folder} ({exc.strerror}); choose a writable place") \
            from None
    os.close(fd)
    os.unlink(tmp)


def check_not_an_input(out: str | os.PathLike, inputs: dict[str, str | os.PathLike | None], what: str = "--out"
                       ) -> None:
    """Refuse (one-line InputError, before any work) an output path that is one of the command's inputs
    (``{"the scan": path, ...}``): writing it would replace the input the run was made from."""
    out_path = Path(out)
    for name, path in inputs.items():
        if path is None:
            continue
        same = False
        try:
            same = out_path.exists() and Path(path).exists() and os.path.samefile(out_path, path)
        except OSError:
            pass
        if same or out_path.absolute() == Path(path).absolute():
            raise InputError(f"{what} {out}: is {name}; writing it would replace that input, choose another path")


def check_output_file(path: str | os.PathLike, what: str = "output", suffixes: tuple[str, ...] | None = None,
                      overwrite: bool = True) -> Path:
    """Check, before any work, that a file can be written at ``path``; raises a one-line InputError.

    Refuses a folder in the file's place, a file or a missing/unwritable place where its folder should be,
    a wrong suffix (``suffixes``, lower case with dot) and, unless ``overwrite``, an existing file.
    """
    path = Path(path)
    if suffixes is not None and path.suffix.lower() not in suffixes:
        raise InputError(f"{what} {path}: unsupported output format; use {' or '.join(suffixes)}")
    if path.is_dir():
        raise InputError(f"{what} {path}: is a folder; give a file path")
    if path.exists() and not overwrite:
        raise InputError(f"{what} {path}: exists; choose a new name or remove it")
    if path.exists() and not path.is_file():
        raise InputError(f"{what} {path}: exists and is not a regular file; choose another name")
    parent = _existing_ancestor(path)
    if not parent.is_dir():
        raise InputError(f"{what} {path}: {parent} is a file, not a folder; choose another place")
    _probe_writable(parent, path, what)
    return path


def check_output_folder(path: str | os.PathLike, what: str = "output folder", new: bool = False) -> Path:
    """Check, before any work, that ``path`` can be a folder of outputs; raises a one-line InputError.

    Refuses an existing file in its place, an unwritable place and, with ``new``, a non-empty folder.
    """
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise InputError(f"{what} {path}: exists and is a file, not a folder; choose a folder path")
    if path.is_dir():
        if new and any(path.iterdir()):
            raise InputError(f"{what} {path}: exists and is not empty; choose a new folder")
        _probe_writable(path, path, what)
        return path
    parent = _existing_ancestor(path)
    if not parent.is_dir():
        raise InputError(f"{what} {path}: {parent} is a file, not a folder; choose another place")
    _probe_writable(parent, path, what)
    return path


# ---------------------------------------------------------------------------------------------- image decoding

#: Lines libjpeg and libpng write to stderr for damaged data (libjpeg's warnings carry no file name and
#: leave the undecodable part of the image grey).
_DECODER_WARNING = re.compile(r"^(libpng (warning|error)|Premature end of JPEG|Corrupt JPEG|Invalid JPEG|"
                              r"Bogus |Warning: |Unsupported JPEG|Improper call|JPEG datastream|Not a JPEG|"
                              r"Huffman|Inconsistent progression|Invalid SOS|Invalid component|"
                              r"Application transferred too few|Unknown APP|Ss=|Suspension|"
                              r"\[ ?WARN:.*(imgcodecs|grfmt|loadsave|imdecode))", re.MULTILINE)
_OPENCV_LOG_PREFIX = re.compile(r"^\[ ?WARN:[^\]]*\]\s*(global\s+)?\S+\.cpp(:\d+)?\s+\w+\s+")
#: The one kind of libpng warning that does not refuse an image: the content of a colour-management chunk
#: (iCCP, sRGB, cHRM, gAMA) that libpng finds non-conforming, e.g. "iCCP: known incorrect sRGB profile"
#: (the HP/Photoshop sRGB profile many tools embed), "iCCP: cHRM chunk does not match sRGB", "iCCP: profile
#: 'x': 'GRAY': Gray color space not permitted on RGB PNG", "sRGB: invalid". Such a chunk passed its CRC, so
#: it is what the writing software wrote, and OpenCV applies no colour management: the decoded pixels come
#: from IDAT alone and are exact. "Interlace handling ..." is OpenCV's own call order for interlaced files
#: (pixels exact too). A CRC error in ANY chunk (the bytes changed after writing) or a decompression error
#: is damage and is refused like every other decoder warning (docs/reliability.md: decoder rule).
_COLOUR_CHUNK_WARNING = re.compile(r"^libpng warning: ((iCCP|sRGB|cHRM|gAMA): |Interlace handling)")
_DAMAGE_WORDS = re.compile(r"CRC|zlib|compress|truncat|damaged|incomplete|too many|extra", re.IGNORECASE)


def colour_profile_warning(line: str) -> bool:
    """True for a libpng warning about a colour-management chunk's content (accepted, logged); False for
    everything else, CRC and decompression errors in those chunks included (refused)."""
    line = line.strip()
    return bool(_COLOUR_CHUNK_WARNING.match(line)) and not _DAMAGE_WORDS.search(line)


_stderr_lock = threading.Lock()
#: The capture file of :func:`_native_stderr_captured`, made once per process (pid, file): a temporary file made
#: per decode was ~0.15 ms of each image read (issue 15's frame time reads 11 a frame). A forked child makes its
#: own (the parent's would mix both processes' output).
_capture_file: list = [None, None]


def _stderr_capture_file():
    if _capture_file[0] != os.getpid():
        _capture_file[1] = tempfile.TemporaryFile()
        _capture_file[0] = os.getpid()
    return _capture_file[1]


@contextlib.contextmanager
def _native_stderr_captured() -> Iterator[list[str]]:
    """Collect what C libraries write to file descriptor 2 while the block runs (into the yielded list)."""
    out: list[str] = []
    with _stderr_lock:
        with contextlib.suppress(AttributeError, ValueError, OSError):
            sys.stderr.flush()
        try:
            saved = os.dup(2)
        except OSError:  # no fd 2 (a daemon): nothing to capture or to pollute
            yield out
            return
        try:
            tmp = _stderr_capture_file()
            fd = tmp.fileno()
            os.ftruncate(fd, 0)
            os.lseek(fd, 0, os.SEEK_SET)
            os.dup2(fd, 2)
            try:
                yield out
            finally:
                os.dup2(saved, 2)
                size = os.lseek(fd, 0, os.SEEK_END)
                os.lseek(fd, 0, os.SEEK_SET)
                chunks = []
                while size > 0:
                    chunk = os.read(fd, size)
                    if not chunk:
                        break
                    chunks.append(chunk)
                    size -= len(chunk)
                out.append(b"".join(chunks).decode("utf-8", "replace"))
        finally:
            os.close(saved)


@contextlib.contextmanager
def native_stderr_captured() -> Iterator[list[str]]:
    """What C libraries (FFmpeg inside OpenCV, libjpeg) write to file descriptor 2 while the block runs, kept off
    the terminal (a user error is one line) and yielded as a list holding the text once the block ends."""
    with _native_stderr_captured() as out:
        yield out


#: FFmpeg's log prefix, ``[mjpeg @ 0x55a5...] `` (the codec or demuxer and an address).
_FFMPEG_LOG_PREFIX = re.compile(r"^\[[\w,.-]+ @ 0x[0-9a-f]+\]\s*")


def ffmpeg_message(captured: list[str]) -> str | None:
    """The first FFmpeg log line of :func:`native_stderr_captured`'s text, without its ``[codec @ 0x...]`` prefix."""
    for line in "".join(captured).splitlines():
        if _FFMPEG_LOG_PREFIX.match(line.strip()):
            return _FFMPEG_LOG_PREFIX.sub("", line.strip())
    return None


def decode_image(data: bytes, source: str | os.PathLike, flags: int | None = None) -> np.ndarray:
    """Decode image bytes with OpenCV, treating any libjpeg/libpng warning as an error naming ``source``,
    except a PNG colour-profile warning on an intact chunk (:func:`colour_profile_warning`; logged).

    ``flags`` are cv2.imread flags (default IMREAD_COLOR, BGR). A truncated JPEG decodes "successfully" with
    a grey bottom and only a nameless warning on stderr; here it raises a one-line FileFormatError.
    """
    import cv2

    flags = cv2.IMREAD_COLOR if flags is None else flags
    with _native_stderr_captured() as captured:
        image = cv2.imdecode(np.frombuffer(data, np.uint8), flags)
    text = captured[0] if captured else ""
    profile = [line.strip() for line in text.splitlines() if colour_profile_warning(line)]
    text = "\n".join(line for line in text.splitlines() if not colour_profile_warning(line))
    # OpenCV's own log lines lose their prefix ("[ WARN:0@0.103] global grfmt_png.cpp:793 readFromStreamOrBuffer "):
    # the one-line error says what is wrong with the file, not where in OpenCV it was noticed (rel6a)
    warnings = [_OPENCV_LOG_PREFIX.sub("", line.strip()) for line in text.splitlines()
                if _DECODER_WARNING.match(line.strip())]
    others = [line for line in text.splitlines() if line.strip() and not _DECODER_WARNING.match(line.strip())]
    if others:  # not the decoder's (another thread's output): give it back
        sys.stderr.write("\n".join(others) + "\n")
    if image is None:
        raise FileFormatError(f"{source}: unreadable image (truncated, damaged or not an image"
                              f"{': ' + warnings[0] if warnings else ''}); replace or remove it")
    if warnings:
        raise FileFormatError(f"{source}: damaged image ({warnings[0]}); the decoder could not read all of it, "
                              "replace or remove it")
    if profile:
        log.info("%s: colour profile ignored (%s); pixels are read as stored", source, profile[0])
    return image


def read_image(path: str | os.PathLike, flags: int | None = None) -> np.ndarray:
    """Read an image file with :func:`decode_image`'s checks; only regular files are read (a FIFO or a
    device would block or stream forever), so anything else raises a one-line FileFormatError."""
    path = Path(path)
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        raise FileFormatError(f"{path}: image not found") from None
    except OSError as exc:
        raise FileFormatError(f"{path}: cannot read the image ({exc.strerror})") from None
    if not stat.S_ISREG(mode):
        raise FileFormatError(f"{path}: not a regular file (a folder, pipe or device); remove it from the "
                              "image folder")
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise FileFormatError(f"{path}: cannot read the image ({exc.strerror})") from None
    return decode_image(data, path, flags)


#: x264's presets, fastest first (``Mp4Writer(preset=...)``).
X264_PRESETS = ("ultrafast", "superfast", "veryfast", "faster", "fast", "medium", "slow", "slower", "veryslow")


class Mp4Writer:
    """H.264 MP4 through imageio-ffmpeg from RGB uint8 frames of ``size`` (w, h). ``path`` may have no
    extension (a run's staged file): the container is named explicitly. A write that ffmpeg refuses (disk
    full, path gone) raises a one-line FileFormatError naming the file. ``preset``: x264's speed / size trade-off
    (:data:`X264_PRESETS`), the same quality setting."""

    def __init__(self, path: str | os.PathLike, size: tuple[int, int], fps: float, preset: str = "veryfast"):
        import imageio_ffmpeg

        self.path = Path(path)
        self._gen = imageio_ffmpeg.write_frames(str(path), size, fps=fps, codec="libx264", pix_fmt_in="rgb24",
                                                pix_fmt_out="yuv420p", quality=7, macro_block_size=8,
                                                ffmpeg_log_level="error",
                                                output_params=["-f", "mp4", "-preset", preset])
        self._gen.send(None)

    def write(self, rgb) -> None:
        import numpy as np

        try:
            self._gen.send(np.ascontiguousarray(rgb))
        except OSError as exc:
            raise FileFormatError(f"{self.path}: ffmpeg could not write the video ({str(exc).splitlines()[0]}); "
                                  "check the disk space and the output path") from None

    def close(self) -> None:
        self._gen.close()
