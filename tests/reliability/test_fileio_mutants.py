"""Mutation tests of ``bodystudio/fileio.py`` (docs/mutation/fileio.md, "mutBB: the whole module"): the readers and
writers every stage uses, where a survivor is a file read or written wrong without an error.

References are independent of the code under test: hashlib over the whole bytes for ``sha256_file`` (a file of
2.5 MiB crosses its 1 MiB chunks), JSON bytes written out by hand, the permission bits a umask gives by
arithmetic, a UTF-8 file read in a child process under the C locale, every refusal's whole line, and for the MP4
writer OpenCV's reader and ffmpeg's own description of the stream (codec, pixel format, size, frame rate). The
image decoder's line rule is driven by a stand-in ``cv2.imdecode`` that writes chosen lines to file descriptor 2
(the real libraries' lines carry timestamps). < 3 s.
"""
from __future__ import annotations

import functools
import hashlib
import json
import logging
import os
import re
import stat
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

import bodystudio
import bodystudio.fileio as fio
from bodystudio.errors import FileFormatError, InputError


def _names(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


# ---------------------------------------------------------------------------------------------- checksums, JSON

@functools.cache
def _big() -> bytes:
    return np.random.default_rng(7).integers(0, 256, (5 << 19) + 17, dtype=np.uint8).tobytes()  # 2.5 MiB + 17


def test_sha256_file_is_the_hash_of_the_whole_file(tmp_path):
    for name, data in (("big", _big()), ("small", b"abc"), ("empty", b"")):
        (tmp_path / name).write_bytes(data)
        assert fio.sha256_file(tmp_path / name) == hashlib.sha256(data).hexdigest(), name
    assert fio.sha256_file(tmp_path / "small") == "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"


def test_write_json_bytes_numpy_paths_and_indent(tmp_path):
    data = {"f": np.float32(0.25), "i": np.int64(3), "b": np.bool_(True), "a": np.arange(2), "p": Path("x/y")}
    fio.write_json(tmp_path / "a.json", data)
    assert (tmp_path / "a.json").read_bytes() == (b'{\n  "f": 0.25,\n  "i": 3,\n  "b": true,\n  "a": [\n    0,\n'
                                                  b'    1\n  ],\n  "p": "x/y"\n}\n')
    fio.write_json(tmp_path / "b.json", [1, {"k": 2}], indent=None)
    assert (tmp_path / "b.json").read_bytes() == b'[1, {"k": 2}]\n'


def test_write_json_refuses_what_json_cannot_hold_and_keeps_the_previous_file(tmp_path):
    fio.write_json(tmp_path / "a.json", {"v": 1})
    with pytest.raises(TypeError) as err:
        fio.write_json(tmp_path / "a.json", {"v": {1, 2}})
    assert str(err.value) == "cannot write set as JSON"
    assert fio.read_json(tmp_path / "a.json") == {"v": 1} and _names(tmp_path) == ["a.json"]
    with pytest.raises(TypeError, match="^cannot write object as JSON$"):
        fio._json_default(object())


def test_read_json_refusals_name_the_file_and_what_it_is(tmp_path):
    (tmp_path / "d.json").mkdir()
    with pytest.raises(FileFormatError) as err:
        fio.read_json(tmp_path / "d.json", "session manifest")
    assert str(err.value) == f"{tmp_path / 'd.json'}: session manifest is not a regular file"
    with pytest.raises(FileFormatError) as err:
        fio.read_json(tmp_path / "none.json")
    assert str(err.value) == f"{tmp_path / 'none.json'}: JSON file not found"
    (tmp_path / "bad.json").write_text('{"a": 1,}')
    with pytest.raises(FileFormatError) as err:
        fio.read_json(tmp_path / "bad.json", "rig file")
    with pytest.raises(json.JSONDecodeError) as why:
        json.loads('{"a": 1,}')
    assert str(err.value) == f"{tmp_path / 'bad.json'}: not a valid rig file ({why.value}); fix or regenerate the file"
    (tmp_path / "latin.json").write_bytes(b'{"name": "Ren\xe9e"}')  # Latin-1, not UTF-8
    with pytest.raises(FileFormatError, match=r"latin.json: not a valid JSON file \('utf-8' codec can't decode"):
        fio.read_json(tmp_path / "latin.json")
    os.mkfifo(tmp_path / "pipe.json")
    with pytest.raises(FileFormatError, match="pipe.json: JSON file is not a regular file"):
        fio.read_json(tmp_path / "pipe.json")


def test_read_json_reads_utf8_whatever_the_locale(tmp_path):
    """A studio machine with the C locale (ASCII) reads a subject named Renée: the file is UTF-8, always."""
    (tmp_path / "u.json").write_bytes('{"name": "Renée"}'.encode())
    assert fio.read_json(tmp_path / "u.json") == {"name": "Renée"}  # in this process too (mutmut's test selection)
    code = "import sys; from bodystudio.fileio import read_json; print(ascii(read_json(sys.argv[1])['name']))"
    env = {**os.environ, "LC_ALL": "C", "LANG": "C", "PYTHONCOERCECLOCALE": "0", "PYTHONUTF8": "0",
           "PYTHONPATH": str(Path(bodystudio.__file__).parents[1])}
    out = subprocess.run([sys.executable, "-c", code, str(tmp_path / "u.json")], env=env, capture_output=True,
                         text=True)
    assert out.returncode == 0 and out.stdout == "'Ren\\xe9e'\n", out.stderr[-500:]


@pytest.mark.parametrize("umask", [0o022, 0o077, 0o002])
def test_written_files_have_the_permissions_the_umask_gives(tmp_path, umask):
    old = os.umask(umask)
    try:
        fio.write_json(tmp_path / "a.json", {})
        assert os.umask(umask) == umask  # the umask is left as it was
    finally:
        os.umask(old)
    assert stat.S_IMODE((tmp_path / "a.json").stat().st_mode) == 0o666 & ~umask


# ---------------------------------------------------------------------------------------------- output checks

def test_existing_ancestor(tmp_path):
    (tmp_path / "f").write_text("x")
    assert fio._existing_ancestor(tmp_path / "a" / "b" / "c.txt") == tmp_path
    assert fio._existing_ancestor(tmp_path / "c.txt") == tmp_path
    assert fio._existing_ancestor(tmp_path / "f" / "x" / "y") == tmp_path / "f"  # a file where a folder should be
    assert fio._existing_ancestor(Path("/no-such-top-folder/a/b")) == Path("/")


def test_check_output_file_refusals_whole_lines(tmp_path):
    (tmp_path / "f").write_text("x")
    (tmp_path / "d.ply").mkdir()
    (tmp_path / "old.ply").write_text("x")
    os.mkfifo(tmp_path / "pipe.ply")
    cases = [
        (dict(path=tmp_path / "a.txt", suffixes=(".ply", ".obj")),
         f"scan {tmp_path / 'a.txt'}: unsupported output format; use .ply or .obj"),
        (dict(path=tmp_path / "d.ply"), f"scan {tmp_path / 'd.ply'}: is a folder; give a file path"),
        (dict(path=tmp_path / "old.ply", overwrite=False),
         f"scan {tmp_path / 'old.ply'}: exists; choose a new name or remove it"),
        (dict(path=tmp_path / "pipe.ply"),
         f"scan {tmp_path / 'pipe.ply'}: exists and is not a regular file; choose another name"),
        (dict(path=tmp_path / "f" / "x" / "a.ply"),
         f"scan {tmp_path / 'f' / 'x' / 'a.ply'}: {tmp_path / 'f'} is a file, not a folder; choose another place"),
    ]
    for kwargs, message in cases:
        with pytest.raises(InputError) as err:
            fio.check_output_file(what="scan", **kwargs)
        assert str(err.value) == message
    assert fio.check_output_file(str(tmp_path / "new" / "A.PLY"), "scan", (".ply",)) == tmp_path / "new" / "A.PLY"
    assert fio.check_output_file(tmp_path / "old.ply") == tmp_path / "old.ply"  # overwrite by default
    with pytest.raises(InputError, match=r"^output .*d\.ply: is a folder"):
        fio.check_output_file(tmp_path / "d.ply")
    assert _names(tmp_path) == ["d.ply", "f", "old.ply", "pipe.ply"]


def test_check_output_folder_refusals_whole_lines(tmp_path):
    (tmp_path / "f").write_text("x")
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "x").write_text("x")
    (tmp_path / "empty").mkdir()
    for kwargs, message in [
        (dict(path=tmp_path / "f"), f"fit folder {tmp_path / 'f'}: exists and is a file, not a folder; choose a "
                                    "folder path"),
        (dict(path=tmp_path / "full", new=True), f"fit folder {tmp_path / 'full'}: exists and is not empty; choose a "
                                                 "new folder"),
        (dict(path=tmp_path / "f" / "sub"), f"fit folder {tmp_path / 'f' / 'sub'}: {tmp_path / 'f'} is a file, not "
                                            "a folder; choose another place"),
    ]:
        with pytest.raises(InputError) as err:
            fio.check_output_folder(what="fit folder", **kwargs)
        assert str(err.value) == message
    assert fio.check_output_folder(str(tmp_path / "full")) == tmp_path / "full"
    assert fio.check_output_folder(tmp_path / "empty", new=True) == tmp_path / "empty"
    assert fio.check_output_folder(tmp_path / "a" / "b") == tmp_path / "a" / "b"
    with pytest.raises(InputError, match=r"^output folder .*: exists and is a file"):
        fio.check_output_folder(tmp_path / "f")
    assert _names(tmp_path) == ["empty", "f", "full"] and _names(tmp_path / "empty") == []


def test_an_unwritable_place_is_refused_naming_the_folder_and_the_reason(tmp_path, monkeypatch):
    probes = []

    def refused(prefix, dir):
        probes.append((prefix, dir))
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(fio.tempfile, "mkstemp", refused)
    with pytest.raises(InputError) as err:
        fio.check_output_file(tmp_path / "a" / "b.ply", "--out")
    assert str(err.value) == (f"--out {tmp_path / 'a' / 'b.ply'}: cannot write in {tmp_path} (Permission denied); "
                              "choose a writable place")
    with pytest.raises(InputError) as err:
        fio.check_output_folder(tmp_path, "--out")
    assert str(err.value) == (f"--out {tmp_path}: cannot write in {tmp_path} (Permission denied); choose a writable "
                              "place")
    with pytest.raises(InputError) as err:  # a new folder: its deepest existing ancestor is probed
        fio.check_output_folder(tmp_path / "new" / "fit", "--out")
    assert str(err.value) == (f"--out {tmp_path / 'new' / 'fit'}: cannot write in {tmp_path} (Permission denied); "
                              "choose a writable place")
    assert probes == [(".bodystudio-probe.", tmp_path)] * 3


def test_check_not_an_input(tmp_path):
    scan = tmp_path / "scan.ply"
    scan.write_text("x")
    (tmp_path / "link.ply").symlink_to(scan)
    msg = "--out {}: is the scan; writing it would replace that input, choose another path"
    for out in (scan, tmp_path / "link.ply", tmp_path / "." / "scan.ply"):
        with pytest.raises(InputError) as err:
            fio.check_not_an_input(out, {"the model": None, "the scan": scan})
        assert str(err.value) == msg.format(out)
    with pytest.raises(InputError) as err:  # not written yet: the same path
        fio.check_not_an_input(tmp_path / "new.glb", {"--bvh": str(tmp_path / "new.glb")}, "--out")
    assert str(err.value) == f"--out {tmp_path / 'new.glb'}: is --bvh; writing it would replace that input, choose " \
                             "another path"
    fio.check_not_an_input(tmp_path / "other.ply", {"the scan": scan, "the model": None})
    fio.check_not_an_input(tmp_path / "link.ply", {"the scan": tmp_path / "missing.ply"})


def test_check_not_an_input_when_the_files_cannot_be_compared(tmp_path, monkeypatch):
    scan = tmp_path / "scan.ply"
    scan.write_text("x")
    (tmp_path / "other.ply").write_text("y")
    monkeypatch.setattr(fio.os.path, "samefile", lambda a, b: (_ for _ in ()).throw(PermissionError(13, "denied")))
    with pytest.raises(InputError, match="is the scan"):  # the paths still compare
        fio.check_not_an_input(scan, {"the scan": str(scan)})
    fio.check_not_an_input(tmp_path / "other.ply", {"the scan": scan})  # both exist, not comparable: not refused


# ---------------------------------------------------------------------------------------------- image decoding

@functools.cache
def _png() -> bytes:
    img = np.zeros((6, 8, 3), np.uint8)
    img[..., 0], img[..., 1], img[..., 2] = 10, 120, 250  # BGR
    return cv2.imencode(".png", img)[1].tobytes()


_IMDECODE = cv2.imdecode


def _noisy_decoder(monkeypatch, lines: str | bytes, result: bool = True):
    """``cv2.imdecode`` that writes ``lines`` to file descriptor 2, as libjpeg / libpng do, then decodes."""
    def imdecode(buf, flags):
        os.write(2, lines if isinstance(lines, bytes) else lines.encode())
        return _IMDECODE(buf, flags) if result else None

    monkeypatch.setattr(cv2, "imdecode", imdecode)


def test_decode_image_flags(tmp_path):
    colour = fio.decode_image(_png(), "a.png")
    assert colour.shape == (6, 8, 3) and colour[0, 0].tolist() == [10, 120, 250]
    grey = fio.decode_image(_png(), "a.png", cv2.IMREAD_GRAYSCALE)
    assert grey.shape == (6, 8) and abs(int(grey[0, 0]) - round(0.114 * 10 + 0.587 * 120 + 0.299 * 250)) <= 1
    (tmp_path / "a.png").write_bytes(_png())
    assert fio.read_image(tmp_path / "a.png", cv2.IMREAD_GRAYSCALE).shape == (6, 8)
    assert fio.read_image(str(tmp_path / "a.png")).shape == (6, 8, 3)


def test_an_unreadable_image_is_refused_with_or_without_the_decoders_line(monkeypatch):
    with pytest.raises(FileFormatError) as err:
        fio.decode_image(b"not an image", "cam0/00001.png")
    assert str(err.value) == ("cam0/00001.png: unreadable image (truncated, damaged or not an image); replace or "
                              "remove it")
    _noisy_decoder(monkeypatch, "libpng error: IDAT: CRC error\nlibpng warning: second\n", result=False)
    with pytest.raises(FileFormatError) as err:
        fio.decode_image(_png(), "cam0/00002.png")
    assert str(err.value) == ("cam0/00002.png: unreadable image (truncated, damaged or not an image: libpng error: "
                              "IDAT: CRC error); replace or remove it")


def test_a_decoder_warning_refuses_the_image_and_other_output_goes_back_to_stderr(monkeypatch, capfd, caplog):
    _noisy_decoder(monkeypatch, "progress 50%\nprogress 90%\n"
                                "  Corrupt JPEG data: 3 extraneous bytes before marker 0xd9\n"
                                "Premature end of JPEG file\n")
    with pytest.raises(FileFormatError) as err:
        fio.decode_image(_png(), "k/0.jpg")
    assert str(err.value) == ("k/0.jpg: damaged image (Corrupt JPEG data: 3 extraneous bytes before marker 0xd9); the "
                              "decoder could not read all of it, replace or remove it")
    assert capfd.readouterr().err == "progress 50%\nprogress 90%\n"
    _noisy_decoder(monkeypatch, "")
    assert fio.decode_image(_png(), "k/1.png").shape == (6, 8, 3)
    assert capfd.readouterr().err == ""
    _noisy_decoder(monkeypatch, "libpng warning: iCCP: known incorrect sRGB profile\nanother thread's line\n")
    with caplog.at_level(logging.INFO, logger="bodystudio.fileio"):
        assert fio.decode_image(_png(), "k/2.png")[0, 0].tolist() == [10, 120, 250]
    assert capfd.readouterr().err == "another thread's line\n"
    assert caplog.messages == ["k/2.png: colour profile ignored (libpng warning: iCCP: known incorrect sRGB profile); "
                               "pixels are read as stored"]
    _noisy_decoder(monkeypatch, "libpng warning: iCCP: CRC error\n")  # damage in a colour chunk: refused
    with pytest.raises(FileFormatError, match=r"damaged image \(libpng warning: iCCP: CRC error\)"):
        fio.decode_image(_png(), "k/3.png")


def test_colour_profile_warning_strips_the_line():
    assert fio.colour_profile_warning("  libpng warning: sRGB: invalid rendering intent \n")
    assert not fio.colour_profile_warning("libpng warning: gAMA: zlib error")
    assert not fio.colour_profile_warning("Premature end of JPEG file")


def test_read_image_refusals_whole_lines(tmp_path, monkeypatch):
    (tmp_path / "f").write_text("x")
    (tmp_path / "d.png").mkdir()
    for path, message in [
        (tmp_path / "none.png", f"{tmp_path / 'none.png'}: image not found"),
        (tmp_path / "f" / "a.png", f"{tmp_path / 'f' / 'a.png'}: cannot read the image (Not a directory)"),
        (tmp_path / "d.png", f"{tmp_path / 'd.png'}: not a regular file (a folder, pipe or device); remove it from "
                             "the image folder"),
    ]:
        with pytest.raises(FileFormatError) as err:
            fio.read_image(path)
        assert str(err.value) == message
    (tmp_path / "a.png").write_bytes(_png())
    monkeypatch.setattr(fio.Path, "read_bytes", lambda self: (_ for _ in ()).throw(OSError(5, "Input/output error")))
    with pytest.raises(FileFormatError) as err:
        fio.read_image(tmp_path / "a.png")
    assert str(err.value) == f"{tmp_path / 'a.png'}: cannot read the image (Input/output error)"


# ---------------------------------------------------------------------------------------------- MP4

def _stream_line(path: Path) -> str:
    """ffmpeg's own description of the file's video stream."""
    import imageio_ffmpeg

    err = subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-hide_banner", "-i", str(path)], capture_output=True,
                         text=True).stderr
    return next(line for line in err.splitlines() if "Video:" in line)


def test_mp4_writer_writes_h264_yuv420p_mp4_of_the_given_size_and_rate(tmp_path, capfd):
    path = tmp_path / "staged"  # a run's staged file has no extension
    colours = [(250, 10, 10), (10, 250, 10), (10, 10, 250)]
    w = fio.Mp4Writer(path, (40, 24), 10.0)
    for rgb in colours:
        frame = np.empty((24, 40, 3), np.uint8)
        frame[:] = rgb
        w.write(frame[:, ::-1])  # not contiguous
    w.close()
    assert capfd.readouterr().err == ""  # ffmpeg at log level "error"
    assert path.read_bytes()[4:8] == b"ftyp"
    line = _stream_line(path)
    assert re.search(r"Video: h264 .*yuv420p.*, 40x24\b.*\b10 fps", line), line
    cap = cv2.VideoCapture(str(path))
    frames = []
    while True:
        ok, bgr = cap.read()
        if not ok:
            break
        frames.append(bgr)
    assert len(frames) == 3 and frames[0].shape == (24, 40, 3)
    for bgr, rgb in zip(frames, colours, strict=True):
        assert np.abs(bgr.reshape(-1, 3).mean(0)[::-1] - rgb).max() < 12, (bgr[0, 0], rgb)


def _x264_settings(path: Path) -> dict[str, str]:
    """The encoder settings x264 writes into the stream (``options: cabac=1 ref=1 ...``)."""
    text = re.search(r"options: (.*?)\x00", path.read_bytes().decode("latin-1")).group(1)
    return dict(item.split("=", 1) for item in text.split() if "=" in item)


@pytest.mark.parametrize("preset, ref, subme", [(None, "1", "2"), ("ultrafast", "1", "0"), ("veryslow", "16", "10")])
def test_mp4_writer_preset_and_quality_reach_x264(tmp_path, preset, ref, subme):
    """x264's presets differ in reference frames and sub-pixel refinement (default veryfast: 1 and 2); quality 7
    is imageio-ffmpeg's crf 15 whatever the preset."""
    path = tmp_path / "v.mp4"
    w = fio.Mp4Writer(path, (16, 16), 5.0) if preset is None else fio.Mp4Writer(path, (16, 16), 5.0, preset=preset)
    w.write(np.zeros((16, 16, 3), np.uint8))
    w.close()
    settings = _x264_settings(path)
    assert (settings["ref"], settings["subme"], settings["crf"]) == (ref, subme, "15.0")


def test_mp4_writer_refusal_names_the_file(tmp_path):
    w = fio.Mp4Writer(tmp_path / "v.mp4", (16, 16), 5.0)

    class Broken:
        def send(self, frame):
            raise OSError("[Errno 32] Broken pipe\n\nFFMPEG COMMAND:\nffmpeg -y ...")

        def close(self):
            pass

    w._gen.close()
    w._gen = Broken()
    with pytest.raises(FileFormatError) as err:
        w.write(np.zeros((16, 16, 3), np.uint8))
    assert str(err.value) == (f"{tmp_path / 'v.mp4'}: ffmpeg could not write the video ([Errno 32] Broken pipe); "
                              "check the disk space and the output path")


# ---------------------------------------------------------------------------------------------- atomic writes
# atomic_path / atomic_write are @contextlib.contextmanager generators, which mutmut does not mutate: these cases are
# what docs/mutation/fileio-plant.py plants its bugs against.

def test_atomic_path_keeps_the_extension_libraries_pick_a_format_by(tmp_path):
    with fio.atomic_path(tmp_path / "new" / "deeper" / "b.npz") as tmp:
        assert tmp.parent == tmp_path / "new" / "deeper" and tmp.name.startswith(".b.") and tmp.suffix == ".npz"
        np.savez(tmp, x=np.arange(3))  # numpy appends .npz to a name without it
    assert _names(tmp_path / "new" / "deeper") == ["b.npz"]
    assert np.load(tmp_path / "new" / "deeper" / "b.npz")["x"].tolist() == [0, 1, 2]
    with fio.atomic_path(tmp_path / "c.bin", suffix=".npy") as tmp:
        assert tmp.name.startswith(".c.") and tmp.name.endswith(".tmp.npy")
        np.save(tmp, np.ones(2))
    assert np.load(tmp_path / "c.bin").tolist() == [1.0, 1.0]


def test_atomic_write_is_hidden_beside_its_target_until_synced_and_renamed(tmp_path, monkeypatch):
    events = []
    real_fsync, real_replace = os.fsync, os.replace
    monkeypatch.setattr(fio.os, "fsync", lambda fd: (events.append(("fsync", os.readlink(f"/proc/self/fd/{fd}"))),
                                                     real_fsync(fd))[1])
    monkeypatch.setattr(fio.os, "replace", lambda a, b: (events.append(("replace", str(a), str(b))),
                                                         real_replace(a, b))[1])
    with fio.atomic_write(tmp_path / "a.txt", "w") as f:
        f.write("text")
        hidden = [p.name for p in tmp_path.iterdir()]
    assert len(hidden) == 1 and hidden[0].startswith(".a.") and hidden[0].endswith(".tmp")
    tmp = str(tmp_path / hidden[0])
    assert events == [("fsync", tmp), ("replace", tmp, str(tmp_path / "a.txt"))]
    assert (tmp_path / "a.txt").read_text() == "text" and _names(tmp_path) == ["a.txt"]


@pytest.mark.parametrize("where", ["create", "write"])
@pytest.mark.parametrize("strerror", ["Disk quota exceeded", None])
def test_a_full_disk_is_one_line_naming_the_file_and_leaves_the_previous_one(tmp_path, monkeypatch, where, strerror):
    import errno

    (tmp_path / "a.json").write_text("previous")
    full = OSError(errno.ENOSPC, "x")
    full.strerror = strerror  # None: a library that raised it without a reason
    if where == "create":
        monkeypatch.setattr(fio.tempfile, "mkstemp", lambda **kw: (_ for _ in ()).throw(full))
    with pytest.raises(fio.OutputSpaceError) as err:
        with fio.atomic_write(tmp_path / "a.json", "w") as f:
            f.write("new")
            raise full
    reason = strerror or "no space left on device"
    assert str(err.value) == (f"{tmp_path / 'a.json'}: {reason} while writing it; the output was not written (a "
                              "previous result stays as it was); free space on that disk or give an output on another "
                              "one")
    assert (tmp_path / "a.json").read_text() == "previous" and _names(tmp_path) == ["a.json"]


def test_a_full_disk_of_another_file_inside_the_block_keeps_its_own_name(tmp_path):
    inner = fio.OutputSpaceError(tmp_path / "b.png", "quota exceeded")
    with pytest.raises(fio.OutputSpaceError) as err, fio.atomic_write(tmp_path / "a.json", "w"):
        raise inner
    assert err.value is inner and _names(tmp_path) == []
    with pytest.raises(KeyError), fio.atomic_write(tmp_path / "a.json", "w"):
        raise KeyError("not an OSError")
    assert _names(tmp_path) == []


def test_a_process_without_a_stderr_decodes_without_capturing(monkeypatch, capfd):
    """A daemon has no file descriptor 2 (``os.dup(2)`` fails): nothing to capture, the image still decodes."""
    def no_fd2(fd):
        raise OSError(9, "Bad file descriptor")

    with monkeypatch.context() as m:  # undone before capfd's own teardown, which needs os.dup
        m.setattr(fio.os, "dup", no_fd2)
        assert fio.decode_image(_png(), "a.png")[0, 0].tolist() == [10, 120, 250]
    assert capfd.readouterr().err == ""


# ``_native_stderr_captured`` is a @contextlib.contextmanager generator (no mutmut mutant): the cases below are what
# docs/mutation/fileio-plant.py's capture plants run against.

def test_each_image_gets_only_its_own_decoder_lines(monkeypatch, capfd):
    """The capture file is reused: a long capture then a short one must read the short one alone (emptied and
    rewound, no stale bytes or holes), and fd 2 is the terminal again after each."""
    _noisy_decoder(monkeypatch, "x" * 300 + "\nPremature end of JPEG file\n")
    with pytest.raises(FileFormatError, match=r"damaged image \(Premature end of JPEG file\)"):
        fio.decode_image(_png(), "a.jpg")
    _noisy_decoder(monkeypatch, "Corrupt JPEG data: bad Huffman code\n")
    with pytest.raises(FileFormatError, match=r"damaged image \(Corrupt JPEG data: bad Huffman code\)"):
        fio.decode_image(_png(), "b.jpg")
    _noisy_decoder(monkeypatch, "short\n")
    fio.decode_image(_png(), "c.png")
    os.write(2, b"the program's own line\n")
    assert capfd.readouterr().err == "x" * 300 + "\nshort\nthe program's own line\n"


def test_bytes_that_are_not_utf8_do_not_hide_the_warning(monkeypatch, capfd):
    _noisy_decoder(monkeypatch, b"\xff\xfe raw\nlibpng error: IDAT: CRC error\n")
    with pytest.raises(FileFormatError, match=r"damaged image \(libpng error: IDAT: CRC error\)"):
        fio.decode_image(_png(), "a.png")
    assert capfd.readouterr().err == "\ufffd\ufffd raw\n"


def test_decoding_leaks_no_file_descriptor():
    before = len(os.listdir("/proc/self/fd"))
    for _ in range(20):
        fio.decode_image(_png(), "a.png")
    assert len(os.listdir("/proc/self/fd")) == before


def test_two_threads_decoding_take_turns_on_fd_2(monkeypatch):
    """fd 2 and the capture file are the process's: a second thread's decode waits until the first one's capture
    is read back, so each image gets its own lines (A waits 0.3 s for B to get in; B must not)."""
    import threading
    import time

    a_inside, b_inside = threading.Event(), threading.Event()
    spans, messages = {}, {}

    def imdecode(buf, flags):
        name = threading.current_thread().name
        start = time.monotonic()
        if name == "A":
            a_inside.set()
            b_inside.wait(0.3)
        else:
            b_inside.set()
        os.write(2, f"Corrupt JPEG data: from {name}\n".encode())
        spans[name] = (start, time.monotonic())
        return None

    def decode(name):
        if name == "B":
            a_inside.wait(5)
        try:
            fio.decode_image(b"x", name)
        except FileFormatError as exc:
            messages[name] = str(exc)

    monkeypatch.setattr(cv2, "imdecode", imdecode)
    threads = [threading.Thread(target=decode, args=(n,), name=n) for n in "AB"]
    for t in threads:
        t.start()
    for t in threads:
        t.join(10)
    assert messages == {n: f"{n}: unreadable image (truncated, damaged or not an image: Corrupt JPEG data: from {n}); "
                           "replace or remove it" for n in "AB"}
    assert spans["B"][0] >= spans["A"][1]  # B's decode started after A's ended
