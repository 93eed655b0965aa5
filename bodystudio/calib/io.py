"""Rig exchange formats: EasyMocap's OpenCV YAML (``intri.yml`` / ``extri.yml``) and COLMAP text models.

Our own ``cameras.json`` is read and written by :mod:`bodystudio.geometry.camera`.

EasyMocap layout (cv2.FileStorage): ``intri.yml`` holds ``names`` (list), ``K_<name>`` (3x3),
``dist_<name>`` (1x5), ``H_<name>``, ``W_<name>``; ``extri.yml`` holds ``names``, ``R_<name>`` (3x1
Rodrigues), ``Rot_<name>`` (3x3) and ``T_<name>`` (3x1), world->camera like ours.

COLMAP (through pycolmap): one camera per studio camera with model OPENCV (k1 k2 p1 p2) when k3 is 0,
else FULL_OPENCV (k1 k2 p1 p2 k3, k4..k6 = 0), one image ``<name>.png`` per camera with its pose, each
in its own trivial rig and frame; written as cameras.txt, images.txt, points3D.txt, rigs.txt, frames.txt.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

import cv2
import numpy as np

from bodystudio.errors import FileFormatError, InputError
from bodystudio.geometry.camera import Camera, CameraRig, check_intrinsics
from bodystudio.runfolder import RunLayout, check_readable, verify_run_files


def _write_filestorage(path: Path, names: list[str], entries: list[tuple[str, object]]) -> None:
    from bodystudio.fileio import atomic_path

    with atomic_path(path, ".yml") as tmp:
        fs = cv2.FileStorage(str(tmp), cv2.FILE_STORAGE_WRITE)
        fs.startWriteStruct("names", cv2.FileNode_SEQ)
        for n in names:
            fs.write("", n)
        fs.endWriteStruct()
        for key, value in entries:
            fs.write(key, value)
        fs.release()


def save_easymocap_yaml(folder: str | os.PathLike, rig: CameraRig) -> tuple[Path, Path]:
    """Write ``folder/intri.yml`` and ``folder/extri.yml`` in EasyMocap's layout."""
    folder = Path(folder)
    intri, extri = [], []
    for c in rig:
        intri += [(f"K_{c.name}", c.K), (f"dist_{c.name}", c.dist.reshape(1, 5)), (f"H_{c.name}", c.height),
                  (f"W_{c.name}", c.width)]
        extri += [(f"R_{c.name}", cv2.Rodrigues(c.R)[0]), (f"Rot_{c.name}", c.R), (f"T_{c.name}", c.t.reshape(3, 1))]
    _write_filestorage(folder / "intri.yml", rig.names, intri)
    _write_filestorage(folder / "extri.yml", rig.names, extri)
    return folder / "intri.yml", folder / "extri.yml"


def load_easymocap_yaml(folder: str | os.PathLike, default_size: tuple[int, int] | None = None) -> CameraRig:
    """Read ``intri.yml`` + ``extri.yml``; image sizes come from ``H_/W_`` or ``default_size`` (w, h).

    The reader is :func:`bodystudio.capture.importer.load_easymocap_cameras` (one parser for both stages).
    """
    from bodystudio.capture.importer import load_easymocap_cameras

    folder = Path(folder)
    for name in ("intri.yml", "extri.yml"):
        if not (folder / name).is_file():
            raise FileFormatError(f"{folder / name}: not found; EasyMocap calibrations need intri.yml and extri.yml")
    return load_easymocap_cameras(folder / "intri.yml", folder / "extri.yml", default_size=default_size)


def rig_to_colmap(rig: CameraRig):
    """A pycolmap.Reconstruction holding the rig's cameras and one posed image per camera."""
    import pycolmap

    rec = pycolmap.Reconstruction()
    for i, c in enumerate(rig, start=1):
        fx, fy, cx, cy = c.K[0, 0], c.K[1, 1], c.K[0, 2], c.K[1, 2]
        k1, k2, p1, p2, k3 = c.dist
        if k3 == 0.0:
            model, params = "OPENCV", [fx, fy, cx, cy, k1, k2, p1, p2]
        else:
            model, params = "FULL_OPENCV", [fx, fy, cx, cy, k1, k2, p1, p2, k3, 0.0, 0.0, 0.0]
        rec.add_camera_with_trivial_rig(pycolmap.Camera(model=model, width=c.width, height=c.height,
                                                        params=params, camera_id=i))
        image = pycolmap.Image(name=f"{c.name}.png", camera_id=i, image_id=i)
        pose = pycolmap.Rigid3d(pycolmap.Rotation3d(c.R), c.t.reshape(3, 1))
        rec.add_image_with_trivial_frame(image, pose)
    return rec


def colmap_to_rig(rec) -> CameraRig:
    """Cameras of a pycolmap.Reconstruction (OPENCV, FULL_OPENCV with k4..k6 = 0, PINHOLE, SIMPLE_*)."""
    cams = {}
    for image_id in sorted(rec.images):
        image = rec.images[image_id]
        cam = rec.cameras[image.camera_id]
        model, p = cam.model.name, np.asarray(cam.params, float)
        if model == "OPENCV":
            fx, fy, cx, cy, *d = p
            d = list(d) + [0.0]
        elif model == "FULL_OPENCV":
            if np.any(p[9:] != 0):
                raise FileFormatError(f"COLMAP camera {image.camera_id}: rational distortion k4..k6 is not supported")
            fx, fy, cx, cy, *d = p[:9]
        elif model == "PINHOLE":
            fx, fy, cx, cy = p
            d = [0.0] * 5
        elif model in ("SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL"):
            fx, cx, cy = p[:3]
            fy = fx
            d = [p[3] if len(p) > 3 else 0.0, p[4] if len(p) > 4 else 0.0, 0.0, 0.0, 0.0]
        else:
            raise FileFormatError(f"COLMAP camera {image.camera_id}: model {model} is not supported; use OPENCV")
        pose = image.cam_from_world() if callable(image.cam_from_world) else image.cam_from_world
        M = np.asarray(pose.matrix())
        name = Path(image.name).with_suffix("").as_posix().replace("/", "_")
        K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])
        try:
            cams[name] = check_intrinsics(Camera(name, K, np.asarray(d, float), M[:, :3], M[:, 3], cam.width,
                                                 cam.height))
        except InputError as exc:
            raise FileFormatError(f"COLMAP image {image.name}: {exc}") from None
    return CameraRig(cams)


def save_colmap_model(folder: str | os.PathLike, rig: CameraRig) -> Path:
    """Write the rig as a COLMAP text model into ``folder`` (replaced as a whole, atomically)."""
    folder = Path(folder)
    check_colmap_output(folder)
    folder.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{folder.name}.", dir=folder.parent))
    try:
        rig_to_colmap(rig).write_text(str(tmp))
        if folder.exists():
            shutil.rmtree(folder)
        os.replace(tmp, folder)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return folder


COLMAP_MODEL_FILES = {"cameras.txt", "images.txt", "points3D.txt", "cameras.bin", "images.bin", "points3D.bin",
                      "rigs.txt", "frames.txt", "rigs.bin", "frames.bin"}


def check_colmap_output(folder: Path) -> None:
    """The COLMAP model replaces ``folder`` as a whole: refuse a file there or a folder holding anything else."""
    if folder.exists() and not folder.is_dir():
        raise InputError(f"--colmap {folder}: exists and is a file; give a folder for the COLMAP model")
    if folder.is_dir():
        other = sorted(p.name for p in folder.iterdir() if p.name not in COLMAP_MODEL_FILES)
        if other:
            raise InputError(f"--colmap {folder}: the folder holds other files ({', '.join(other[:3])}); "
                             "the model replaces the whole folder, so give an empty or a COLMAP model folder")


def load_colmap_model(folder: str | os.PathLike) -> CameraRig:
    import pycolmap

    folder = Path(folder)
    if not (folder / "cameras.txt").is_file() and not (folder / "cameras.bin").is_file():
        raise FileFormatError(f"{folder}: no COLMAP model (cameras.txt/.bin) found")
    try:
        # pycolmap reports a malformed text model as ValueError / IndexError, a non-UTF-8 image name on access
        return colmap_to_rig(pycolmap.Reconstruction(str(folder)))
    except (RuntimeError, ValueError, TypeError, OSError, IndexError, KeyError) as exc:
        reason = str(exc).strip().splitlines()[-1] if str(exc).strip() else type(exc).__name__
        raise FileFormatError(f"{folder}: not a readable COLMAP model ({reason[:200]}); re-export it") from None


# ---------------------------------------------------------------------------------------------- whole calibration

def calibration_report_path(cameras_json: str | os.PathLike) -> Path:
    cameras_json = Path(cameras_json)
    return cameras_json.with_name(cameras_json.stem + ".report.json")


def calibration_layout(cameras_json: str | os.PathLike) -> RunLayout:
    """A calibration's lock and staging (``.cameras.json.lock`` / ``.staging``) and its manifest, the report
    written last (it records the sha256 of cameras.json and of the EasyMocap / COLMAP exports)."""
    cameras_json = Path(cameras_json)
    return RunLayout(cameras_json.parent, calibration_report_path(cameras_json).name, f".{cameras_json.name}.",
                     str(cameras_json))


def check_calibration_outputs(cameras_json: str | os.PathLike, report: str | os.PathLike | None = None) -> dict | None:
    """The report of ``cameras.json`` when the two (and the exports) belong to one run; None without a report.

    Refused with one line: a calibration writing them now, an interrupted commit (``bodystudio recover``), or
    files whose sha256 differ from the report's record (parts of two runs).
    """
    from bodystudio.fileio import read_json

    layout = calibration_layout(cameras_json)
    check_readable(layout)
    report = Path(report) if report is not None else layout.manifest_path
    if not report.is_file():
        return None
    data = read_json(report, "calibration report")
    if isinstance(data, dict) and "run" in data:
        verify_run_files(RunLayout(report.parent, report.name, layout.prefix, layout.what), data["run"])
    return data
