"""The capture session: one folder holding a studio recording (real or synthetic) and its ground truth.

Layout (documented in ``docs/session-format.md``)::

    session.json                      manifest, written last: version, cameras, frames, streams, sha256 of every file
    calibration/cameras.json          the studio cameras (public format, ``bodystudio.geometry.camera``)
    cam_00/rgb/00000.png              colour frames (8-bit RGB PNG)
    cam_00/mask/00000.png             silhouettes used downstream (8-bit, 0 / 255)
    cam_00/background/00000.png       empty-studio frames for background subtraction
    kinect/calibration.json           Kinect depth and colour cameras in the studio frame
    kinect/depth/00000.png            16-bit depth in millimetres (0 = no measurement)
    kinect/rgb/00000.png              Kinect colour frames
    kinect/joints/00000.json          body-tracker joints (studio frame, metres), one or several bodies
    kinect/player/00000.png           the body tracker's player mask on the depth image (uint8, 0 none, k = player k)
    gt/phenotype.json, gt/meshes/00000.ply, gt/joints/00000.json, gt/pose/00000.json, gt/masks/cam_00/00000.png
    gt/arm/00000.ply, gt/arm_pose/00000.json   arm sessions: arm mesh (ArmTemplate topology), arm joint angles
    gt/person/00000.png, gt/target/...         mirror sessions: true person labels in the Kinect colour image,
    gt/mirror/00000.npz, gt/mirror/actors.npz  the edited (target) renders, posed/rest vertices and true joints

Writes go through :class:`SessionWriter`: every file is first written atomically into ``.staging/``;
:meth:`SessionWriter.commit` writes ``.staging/commit.json`` (the commit point), moves the staged files
into place and writes ``session.json`` last. A write killed before the commit point leaves the previous
session untouched (the leftover ``.staging`` is reported by :func:`open_session`); one killed after it is
completed by :func:`recover_session`.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import re
import weakref
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from bodystudio.errors import FileFormatError, SessionError
from bodystudio.fileio import atomic_write, is_frame_number, read_json, sha256_file
from bodystudio.runfolder import (
    OutputLockedError,
    RunLayout,
    acquire_lock,
    apply_commit,
    hold_read_lock,
    lock_holder,
    read_lock,
    recover_layout,
    release_lock,
    remove_staging,
    remove_stale_staging,
)

log = logging.getLogger(__name__)

SESSION_FORMAT = "bodystudio-session"
SESSION_VERSION = 1
MANIFEST = "session.json"
STAGING = ".staging"
COMMIT = "commit.json"
CAMERAS_JSON = "calibration/cameras.json"
KINECT_CALIBRATION = "kinect/calibration.json"
GT_PHENOTYPE = "gt/phenotype.json"
GT_LIGHTING = "gt/lighting.json"
GT_GARMENT = "gt/garment.json"
GT_ALBEDO = "gt/albedo.json"
#: Labels of the per-pixel layer images (``gt_layers``, ``gt_target_layers``).
LAYER_BACKGROUND, LAYER_BODY, LAYER_GARMENT = 0, 1, 2

# Stream name -> relative path pattern ({cam}: camera name, {frame}: 5-digit frame id).
CAMERA_STREAMS = {
    "rgb": "{cam}/rgb/{frame:05d}.png",
    "mask": "{cam}/mask/{frame:05d}.png",
    "gt_mask": "gt/masks/{cam}/{frame:05d}.png",
    "gt_layers": "gt/layers/{cam}/{frame:05d}.png",
    "gt_target": "gt/garment_target/{cam}/{frame:05d}.png",
    "gt_target_layers": "gt/garment_target_layers/{cam}/{frame:05d}.png",
}
FRAME_STREAMS = {
    "kinect_depth": "kinect/depth/{frame:05d}.png",
    "kinect_rgb": "kinect/rgb/{frame:05d}.png",
    "kinect_joints": "kinect/joints/{frame:05d}.json",
    "kinect_player": "kinect/player/{frame:05d}.png",
    "gt_mesh": "gt/meshes/{frame:05d}.ply",
    "gt_joints": "gt/joints/{frame:05d}.json",
    "gt_pose": "gt/pose/{frame:05d}.json",
    "gt_arm_mesh": "gt/arm/{frame:05d}.ply",
    "gt_arm_pose": "gt/arm_pose/{frame:05d}.json",
    "gt_person": "gt/person/{frame:05d}.png",
    "gt_target_rgb": "gt/target/rgb/{frame:05d}.png",
    "gt_target_person": "gt/target/person/{frame:05d}.png",
    "gt_mirror": "gt/mirror/{frame:05d}.npz",
}
GT_MIRROR_ACTORS = "gt/mirror/actors.npz"
BACKGROUND = "{cam}/background/{index:05d}.png"
DEPTH_MM_PER_M = 1000.0
#: The Kinect SDKs track at most six bodies; player mask values are 0 (nobody) or the player 1..6.
MAX_PLAYERS = 6
# \Z, not $: "$" also matches before a trailing newline, which let "cam_00\n" through as a folder name
_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*\Z")


def stream_path(stream: str, frame: int, camera: str | None = None) -> str:
    """Relative path of one file of ``stream`` (a key of CAMERA_STREAMS or FRAME_STREAMS)."""
    if stream in CAMERA_STREAMS:
        return CAMERA_STREAMS[stream].format(cam=camera, frame=frame)
    return FRAME_STREAMS[stream].format(frame=frame)


def sha256_bytes(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def stream_fingerprint(session: Session, stream: str, frame_ids, camera: str | None = None) -> str | None:
    """One sha256 over the manifest's sha256 of ``stream``'s files for ``frame_ids`` (in that order): the
    identity of the recording a result was computed from, which survives moving or copying the session and
    files added to it later. None when one of those files is not in the manifest."""
    h = hashlib.sha256()
    for frame in frame_ids:
        rel = stream_path(stream, int(frame), camera)
        digest = session.files.get(rel)
        if digest is None:
            return None
        h.update(f"{rel} {digest}\n".encode())
    return h.hexdigest()


# ---------------------------------------------------------------------------------------------- encoding

def encode_png(image: np.ndarray, what: str = "image") -> bytes:
    """PNG bytes of an RGB (H, W, 3) uint8, grey (H, W) uint8 or 16-bit (H, W) uint16 image."""
    image = np.asarray(image)
    if image.dtype == bool:
        image = image.astype(np.uint8) * 255
    if image.dtype not in (np.uint8, np.uint16) or image.ndim not in (2, 3):
        raise ValueError(f"{what}: PNG needs (H, W[, 3]) uint8 or uint16, got {image.dtype} {image.shape}")
    if image.ndim == 3:
        image = cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_RGB2BGR)
    ok, buf = cv2.imencode(".png", image, [cv2.IMWRITE_PNG_COMPRESSION, 1])
    if not ok:
        raise ValueError(f"{what}: PNG encoding failed")
    return buf.tobytes()


def decode_png(data: bytes, source: str, color: bool) -> np.ndarray:
    """Decode PNG bytes (RGB uint8 if ``color``, else the stored single channel, 8 or 16 bit)."""
    flag = cv2.IMREAD_COLOR if color else cv2.IMREAD_UNCHANGED
    from bodystudio.fileio import decode_image

    try:
        image = decode_image(data, source, flag)
    except FileFormatError as exc:
        raise SessionError(f"{exc}; re-import or regenerate the session") from None
    if color:
        return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
    if image.ndim == 3:
        image = image[..., 0]
    return image


def depth_to_png_mm(depth_m: np.ndarray) -> np.ndarray:
    """Depth in metres (0 or non-finite = missing) -> uint16 millimetres, the session's depth encoding."""
    d = np.asarray(depth_m, dtype=np.float64)
    d = np.where(np.isfinite(d) & (d > 0), d, 0.0)
    mm = np.rint(d * DEPTH_MM_PER_M)
    if mm.max(initial=0) > 65535:
        raise ValueError(f"depth up to {d.max():.1f} m does not fit 16-bit millimetres (max 65.535 m)")
    return mm.astype(np.uint16)


def _positions_json(positions: np.ndarray) -> list:
    """(J, 3) positions as JSON lists; a joint with any non-finite coordinate (not reported) becomes null."""
    return [[float(x) for x in p] if np.all(np.isfinite(p)) else [None, None, None] for p in positions]


def npz_bytes(arrays: dict[str, np.ndarray]) -> bytes:
    """An ``.npz`` of ``arrays`` with fixed zip timestamps, so the same arrays always give the same bytes."""
    import io
    import zipfile

    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_STORED) as z:
        for name, value in sorted(arrays.items()):
            one = io.BytesIO()
            np.save(one, np.asarray(value), allow_pickle=False)
            z.writestr(zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0)), one.getvalue())
    return buf.getvalue()


def parse_npz_bytes(data: bytes, source: str) -> dict[str, np.ndarray]:
    """The arrays of an ``.npz`` written by :func:`npz_bytes`; SessionError when it is not one."""
    import io
    import zipfile

    try:
        with np.load(io.BytesIO(data), allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:
        raise SessionError(f"{source}: not a readable .npz ({exc}); regenerate the session") from None


def _json_bytes(data: Any) -> bytes:
    from bodystudio.fileio import _json_default

    return (json.dumps(data, indent=1, default=_json_default) + "\n").encode()


def mesh_ply_bytes(V: np.ndarray, F: np.ndarray) -> bytes:
    """Binary little-endian PLY of a triangle mesh (float64 vertices keep ground truth exact)."""
    V = np.ascontiguousarray(V, dtype="<f8")
    F = np.asarray(F)
    header = ("ply\nformat binary_little_endian 1.0\n"
              f"element vertex {len(V)}\nproperty double x\nproperty double y\nproperty double z\n"
              f"element face {len(F)}\nproperty list uchar int vertex_indices\nend_header\n").encode()
    faces = np.empty(len(F), dtype=[("n", "u1"), ("i", "<i4", (3,))])
    faces["n"] = 3
    faces["i"] = F
    return header + V.tobytes() + faces.tobytes()


def parse_ply_bytes(data: bytes, source: str) -> tuple[np.ndarray, np.ndarray]:
    """Read the binary PLY written by :func:`mesh_ply_bytes` (other PLYs go through geometry.mesh.load_mesh)."""
    end = data.find(b"end_header\n")
    header = data[:end].decode("ascii", "replace").splitlines() if end > 0 else []
    try:
        nv = [int(l.split()[2]) for l in header if l.startswith("element vertex")]
        nf = [int(l.split()[2]) for l in header if l.startswith("element face")]
    except (IndexError, ValueError):
        nv = nf = []
    if (not header or header[0] != "ply" or not nv or not nf or min(nv[0], nf[0]) < 0
            or "property double x" not in header):
        raise SessionError(f"{source}: not a bodystudio ground-truth PLY; regenerate the session")
    body = data[end + len(b"end_header\n"):]
    need = nv[0] * 24 + nf[0] * 13
    if len(body) != need:
        raise SessionError(f"{source}: truncated PLY ({len(body)} of {need} bytes); regenerate the session")
    V = np.frombuffer(body[: nv[0] * 24], dtype="<f8").reshape(-1, 3).astype(np.float64)
    faces = np.frombuffer(body[nv[0] * 24:], dtype=[("n", "u1"), ("i", "<i4", (3,))])
    F = faces["i"].astype(np.int64)
    if np.any(faces["n"] != 3) or (len(F) and (F.min() < 0 or F.max() >= nv[0])) or not np.all(np.isfinite(V)):
        raise SessionError(f"{source}: corrupt PLY (faces that are not triangles of its {nv[0]} vertices, or "
                           "non-finite vertices); regenerate the session")
    return V, F


# ---------------------------------------------------------------------------------------------- Kinect

def kinect_calibration_to_dict(sensor) -> dict:
    """``kinect/calibration.json`` of an :class:`~bodystudio.geometry.camera.RGBDSensor`."""
    return {"format_version": 1, "depth_unit": "mm", **sensor.to_dict()}


def kinect_calibration_from_dict(data: Any, source: str):
    """An RGBDSensor from ``kinect/calibration.json``; only ``depth`` and ``color`` cameras are required.

    ``version`` (tracker joint set v1/v2) defaults to v2, ``depth_to_color`` is derived from the two
    camera poses, ``baseline_m`` defaults to 0.075 and ``depth_range_m`` to [0.5, 4.5].
    """
    from bodystudio.errors import InputError
    from bodystudio.geometry.camera import Camera, RGBDSensor

    try:
        if not isinstance(data, dict):
            raise TypeError("top level must be an object")
        name = str(data.get("name", "kinect"))
        version = data.get("version", "v2")
        if version not in ("v1", "v2"):
            raise ValueError(f"version must be v1 or v2, got {version!r}")
        depth = Camera.from_dict(f"{name}_depth", data["depth"])
        color = Camera.from_dict(f"{name}_color", data["color"])
        if "depth_to_color" in data:
            T = np.asarray(data["depth_to_color"], dtype=np.float64).reshape(4, 4)
        else:
            T = np.eye(4)
            T[:3, :3] = color.R @ depth.R.T
            T[:3, 3] = color.t - T[:3, :3] @ depth.t
        return RGBDSensor(name, version, depth, color, T, float(data.get("baseline_m", 0.075)),
                          tuple(float(x) for x in data.get("depth_range_m", (0.5, 4.5))))
    except (KeyError, TypeError, ValueError, InputError) as exc:
        raise FileFormatError(f"{source}: not a Kinect calibration ({type(exc).__name__}: {exc}); it needs "
                              "'depth' and 'color' cameras as in calibration/cameras.json") from None


def load_kinect_calibration(path: str | os.PathLike):
    return kinect_calibration_from_dict(read_json(path, "Kinect calibration"), str(path))


# ---------------------------------------------------------------------------------------------- reading

class _LazyFiles(Mapping):
    """A read-only mapping camera -> array whose files are decoded (and checksum-checked) on first access."""

    def __init__(self, session: Session, stream: str, frame: int, loader):
        self._session, self._stream, self._frame, self._loader = session, stream, frame, loader
        self._cache: dict[str, Any] = {}
        self._cameras = [c for c in session.camera_names
                         if stream_path(stream, frame, c) in session.files]

    def __getitem__(self, camera: str):
        if camera not in self._cache:
            if camera not in self._cameras:
                raise KeyError(f"{camera}: no {self._stream} for frame {self._frame} in {self._session.path}")
            self._cache[camera] = self._loader(stream_path(self._stream, self._frame, camera))
        return self._cache[camera]

    def __iter__(self) -> Iterator[str]:
        return iter(self._cameras)

    def __len__(self) -> int:
        return len(self._cameras)


def _parse_body(data: Any, source: Path, joint_set: str | None) -> dict:
    """One body of a joints file (see :attr:`Frame.kinect_bodies`); SessionError when malformed."""
    try:
        names = [str(n) for n in data["names"]]
        raw = [[np.nan if x is None else x for x in p] for p in data["positions"]]
        pos = np.asarray(raw, dtype=np.float64).reshape(len(names), 3)
        tracked = np.asarray(data.get("tracked", [True] * len(pos)), dtype=bool).reshape(len(names))
        player = data.get("player", 1)
        if type(player) is not int or not 1 <= player <= MAX_PLAYERS:
            raise ValueError(f"player must be an integer 1..{MAX_PLAYERS}, got {player!r}")
    except (KeyError, TypeError, ValueError) as exc:
        raise SessionError(f"{source}: malformed joints ({exc}); needs names and positions") from None
    return {"player": player, "names": names, "positions": pos, "tracked": tracked,
            "joint_set": data.get("joint_set", joint_set)}


@dataclass(frozen=True, eq=False)
class Frame:
    """One synchronised frame of a session; every stream is read from disk on first access."""

    session: Session
    frame_id: int

    @cached_property
    def images(self) -> Mapping[str, np.ndarray]:
        """Camera name -> RGB uint8 (H, W, 3)."""
        return _LazyFiles(self.session, "rgb", self.frame_id, lambda rel: self.session.read_image(rel, True))

    @cached_property
    def masks(self) -> Mapping[str, np.ndarray]:
        """Camera name -> bool (H, W) silhouette (ground truth in synthetic sessions until segmented)."""
        return _LazyFiles(self.session, "mask", self.frame_id, lambda rel: self.session.read_image(rel, False) > 127)

    @cached_property
    def gt_masks(self) -> Mapping[str, np.ndarray]:
        """Camera name -> bool (H, W) rendered ground-truth silhouette (synthetic sessions)."""
        return _LazyFiles(self.session, "gt_mask", self.frame_id,
                          lambda rel: self.session.read_image(rel, False) > 127)

    @cached_property
    def gt_layers(self) -> Mapping[str, np.ndarray]:
        """Camera name -> uint8 (H, W) labels: 0 background, 1 body (skin), 2 the garment the actor wears."""
        return _LazyFiles(self.session, "gt_layers", self.frame_id, lambda rel: self.session.read_image(rel, False))

    @cached_property
    def gt_target(self) -> Mapping[str, np.ndarray]:
        """Camera name -> RGB uint8: the true render of the actor wearing the target garment (garment sessions)."""
        return _LazyFiles(self.session, "gt_target", self.frame_id, lambda rel: self.session.read_image(rel, True))

    @cached_property
    def gt_target_layers(self) -> Mapping[str, np.ndarray]:
        """Camera name -> uint8 (H, W) labels of ``gt_target``: 0 background, 1 body, 2 the target garment."""
        return _LazyFiles(self.session, "gt_target_layers", self.frame_id,
                          lambda rel: self.session.read_image(rel, False))

    def _optional(self, stream: str):
        rel = stream_path(stream, self.frame_id)
        return rel if rel in self.session.files else None

    @cached_property
    def kinect_depth_m(self) -> np.ndarray | None:
        """Kinect depth in metres, float64 (H, W); 0 where the sensor measured nothing."""
        rel = self._optional("kinect_depth")
        if rel is None:
            return None
        raw = self.session.read_image(rel, False)
        if raw.dtype != np.uint16:
            raise SessionError(f"{self.session.path / rel}: depth must be a 16-bit PNG in millimetres, "
                               f"got {raw.dtype}; re-import with the right --depth-scale")
        return raw.astype(np.float64) / DEPTH_MM_PER_M

    @cached_property
    def kinect_rgb(self) -> np.ndarray | None:
        rel = self._optional("kinect_rgb")
        return None if rel is None else self.session.read_image(rel, True)

    @cached_property
    def kinect_player(self) -> np.ndarray | None:
        """The body tracker's player mask (H, W) uint8 on the depth image: 0 nobody, k = player k (1..6)."""
        rel = self._optional("kinect_player")
        if rel is None:
            return None
        mask = self.session.read_image(rel, False)
        if mask.dtype != np.uint8 or mask.max(initial=0) > MAX_PLAYERS:
            raise SessionError(f"{self.session.path / rel}: a player mask must be an 8-bit PNG with values 0..."
                               f"{MAX_PLAYERS}, got {mask.dtype} up to {mask.max(initial=0)}; regenerate the session")
        return mask

    @cached_property
    def kinect_bodies(self) -> list[dict] | None:
        """Every tracked body of the frame: ``[{"player", "names", "positions" (J, 3), "tracked" (J,)}]``.

        ``positions`` are metres in the studio frame, NaN where the tracker reported none. The single-body
        layout of older sessions reads as player 1; None when the frame has no joints file.
        """
        rel = self._optional("kinect_joints")
        if rel is None:
            return None
        data = self.session.read_json(rel)
        source = self.session.path / rel
        if not isinstance(data, dict):
            raise SessionError(f"{source}: malformed joints (top level must be an object); regenerate the session")
        if "bodies" in data:
            if not isinstance(data["bodies"], list):
                raise SessionError(f"{source}: malformed joints ('bodies' must be a list); regenerate the session")
            bodies = [_parse_body(b, source, data.get("joint_set")) for b in data["bodies"]]
            players = [b["player"] for b in bodies]
            if len(set(players)) != len(players):
                raise SessionError(f"{source}: malformed joints (player ids {players} repeat); regenerate the session")
            return bodies
        return [_parse_body({**data, "player": 1}, source, data.get("joint_set"))]

    @cached_property
    def kinect_joints(self) -> dict | None:
        """``{"names": [...], "positions": (J, 3) metres in the studio frame, "tracked": (J,) bool, "player"}``.

        With several bodies in the frame this is the one with the lowest player id; None when nobody is
        tracked (see :attr:`kinect_bodies` for all of them).
        """
        bodies = self.kinect_bodies
        if not bodies:
            return None
        first = min(bodies, key=lambda b: b["player"])
        return {k: first[k] for k in ("names", "positions", "tracked", "joint_set", "player")}

    def _optional_labels(self, stream: str) -> np.ndarray | None:
        rel = self._optional(stream)
        if rel is None:
            return None
        labels = self.session.read_image(rel, False)
        if labels.dtype != np.uint8 or labels.max(initial=0) > MAX_PLAYERS:
            raise SessionError(f"{self.session.path / rel}: a person label image must be an 8-bit PNG with values "
                               f"0..{MAX_PLAYERS}; regenerate the session")
        return labels

    @cached_property
    def gt_person(self) -> np.ndarray | None:
        """Mirror sessions: true person labels (H, W) uint8 in the Kinect colour image (0 none, k = actor k)."""
        return self._optional_labels("gt_person")

    @cached_property
    def gt_target_rgb(self) -> np.ndarray | None:
        """Mirror sessions: the frame rendered with the edited (target) bodies, same pose and background."""
        rel = self._optional("gt_target_rgb")
        return None if rel is None else self.session.read_image(rel, True)

    @cached_property
    def gt_target_person(self) -> np.ndarray | None:
        """Mirror sessions: person labels (H, W) uint8 of the target render."""
        return self._optional_labels("gt_target_person")

    @cached_property
    def gt_mirror(self) -> dict[str, np.ndarray] | None:
        """Mirror sessions: the frame's ground truth arrays (see ``bodystudio.mirror.synthetic``)."""
        rel = self._optional("gt_mirror")
        return None if rel is None else parse_npz_bytes(self.session.read_bytes(rel), str(self.session.path / rel))

    def _optional_mesh(self, stream: str):
        from bodystudio.geometry.mesh import Mesh

        rel = self._optional(stream)
        if rel is None:
            return None
        V, F = parse_ply_bytes(self.session.read_bytes(rel), str(self.session.path / rel))
        return Mesh(V, F)

    @cached_property
    def gt_mesh(self):
        """Ground-truth posed mesh (:class:`bodystudio.geometry.mesh.Mesh`) of a synthetic session."""
        return self._optional_mesh("gt_mesh")

    @cached_property
    def gt_joints(self) -> dict | None:
        """``{"bone_names", "heads" (B, 3), "tails" (B, 3)}`` of the posed ground-truth skeleton."""
        rel = self._optional("gt_joints")
        if rel is None:
            return None
        data = self.session.read_json(rel)
        return {"bone_names": list(data["bone_names"]), "heads": np.asarray(data["heads"], dtype=np.float64),
                "tails": np.asarray(data["tails"], dtype=np.float64)}

    @cached_property
    def gt_pose(self):
        """Ground-truth :class:`bodystudio.body.Pose` (bone order of ``gt_joints``)."""
        from bodystudio.body.pose import pose_from_dict

        rel = self._optional("gt_pose")
        if rel is None:
            return None
        data = self.session.read_json(rel)
        bones = tuple(data.get("bone_names") or self.gt_joints["bone_names"])
        return pose_from_dict(data, bones, str(self.session.path / rel))

    @cached_property
    def gt_arm_mesh(self):
        """Ground-truth arm mesh (ArmTemplate topology, :class:`~bodystudio.geometry.mesh.Mesh`) of an arm session."""
        return self._optional_mesh("gt_arm_mesh")

    @cached_property
    def gt_arm_pose(self) -> dict | None:
        """Ground-truth arm joint angles ``{"root": 4x4, "shoulder", "elbow", "wrist": rotation vectors}``."""
        rel = self._optional("gt_arm_pose")
        return None if rel is None else self.session.read_json(rel)


@dataclass(frozen=True, eq=False)
class Session:
    """An opened session folder: manifest, cameras and lazily read frames."""

    path: Path
    manifest: dict
    interrupted_write: str | None = None  # description of a leftover, uncommitted write (previous state shown)

    @property
    def files(self) -> dict[str, str]:
        """Relative path -> sha256 of every file the manifest lists."""
        return self.manifest["files"]

    @property
    def camera_names(self) -> list[str]:
        return list(self.manifest["cameras"])

    @property
    def frame_ids(self) -> list[int]:
        return list(self.manifest["frames"])

    @property
    def streams(self) -> list[str]:
        return list(self.manifest["streams"])

    @property
    def source(self) -> str:
        return self.manifest.get("source", "unknown")

    @property
    def metadata(self) -> dict:
        return self.manifest.get("metadata", {})

    @cached_property
    def cameras(self):
        """The studio cameras (:class:`bodystudio.geometry.camera.CameraRig`)."""
        from bodystudio.geometry.camera import load_cameras_json

        self.read_bytes(CAMERAS_JSON)  # checksum check before parsing
        return load_cameras_json(self.path / CAMERAS_JSON)

    @cached_property
    def kinect(self):
        """The RGB-D sensor (:class:`~bodystudio.geometry.camera.RGBDSensor`, studio frame) or None."""
        if KINECT_CALIBRATION not in self.files:
            return None
        return kinect_calibration_from_dict(self.read_json(KINECT_CALIBRATION), str(self.path / KINECT_CALIBRATION))

    @cached_property
    def gt_subject(self) -> dict | None:
        """``{"phenotype": {...}, "local": {...}, "resolution", "rig", "faces"?}`` of a synthetic session."""
        return self.read_json(GT_PHENOTYPE) if GT_PHENOTYPE in self.files else None

    @cached_property
    def gt_mirror_actors(self) -> dict[str, np.ndarray] | None:
        """Mirror sessions: the actors' rest meshes, coefficients and skeletons (``gt/mirror/actors.npz``)."""
        if GT_MIRROR_ACTORS not in self.files:
            return None
        return parse_npz_bytes(self.read_bytes(GT_MIRROR_ACTORS), str(self.path / GT_MIRROR_ACTORS))

    @cached_property
    def gt_lighting(self) -> dict | None:
        """Garment sessions: ``{"directions", "colors", "ambient", "space": "world"}`` of the true lights."""
        return self.read_json(GT_LIGHTING) if GT_LIGHTING in self.files else None

    @cached_property
    def gt_garment(self) -> dict | None:
        """Garment sessions: the worn and the target garments (name, pattern, seed) to rebuild them."""
        return self.read_json(GT_GARMENT) if GT_GARMENT in self.files else None

    @cached_property
    def gt_albedo(self) -> np.ndarray | None:
        """Garment sessions: the subject's per-vertex skin albedo (n, 3) in [0, 1] (template of ``gt_subject``)."""
        return self._gt_albedo("albedo")

    @cached_property
    def gt_appearance_albedo(self) -> np.ndarray | None:
        """Garment sessions: per body vertex the albedo the video shows (the worn garment's where it covers)."""
        return self._gt_albedo("appearance")

    def _gt_albedo(self, key: str) -> np.ndarray | None:
        if GT_ALBEDO not in self.files:
            return None
        data = self.read_json(GT_ALBEDO)
        try:
            return np.asarray(data[key], dtype=np.float64).reshape(-1, 3)
        except (KeyError, TypeError, ValueError) as exc:
            raise SessionError(f"{self.path / GT_ALBEDO}: malformed albedo ({exc}); regenerate the session") from None

    def frame(self, frame_id: int) -> Frame:
        if frame_id not in self.manifest["frames"]:
            raise SessionError(f"{self.path / MANIFEST}: no frame {frame_id}; frames are "
                               f"{_ranges(self.frame_ids)}")
        return Frame(self, int(frame_id))

    def __iter__(self) -> Iterator[Frame]:
        return (Frame(self, f) for f in self.frame_ids)

    def __len__(self) -> int:
        return len(self.manifest["frames"])

    def background_frames(self, camera: str) -> list[np.ndarray]:
        """The empty-studio RGB frames of one camera (for background models)."""
        rels = sorted(r for r in self.files if r.startswith(f"{camera}/background/"))
        return [self.read_image(r, True) for r in rels]

    # -- raw access, every read is checked against the manifest's sha256
    def read_bytes(self, rel: str) -> bytes:
        path = self.path / rel
        try:
            data = path.read_bytes()
        except FileNotFoundError:
            raise SessionError(f"{path}: missing (listed in {MANIFEST}); the session is incomplete, "
                               "re-import or regenerate it") from None
        expected = self.files.get(rel)
        if expected is not None and sha256_bytes(data) != expected:
            self._check_not_rewritten(path)
            raise SessionError(f"{path}: corrupted (sha256 differs from {MANIFEST}); re-import or regenerate it")
        return data

    def _check_not_rewritten(self, path: Path) -> None:
        """A file that differs from the manifest because another command is rewriting the session is no
        corruption: say who writes it (or that it changed since it was opened) instead."""
        holder = lock_holder(session_layout(self.path))
        if holder is not None:
            raise SessionError(f"{path}: changed while being read; the session is being written by pid "
                               f"{holder.get('pid')} ({holder.get('command')}, since {holder.get('since')}); "
                               "wait for it to finish and re-run")
        try:
            current = json.loads((self.path / MANIFEST).read_bytes())
        except (OSError, ValueError):
            current = None
        if current != self.manifest or (self.path / STAGING / COMMIT).is_file():
            raise SessionError(f"{path}: changed while being read (the session was rewritten by another command "
                               "since it was opened); re-run")

    def read_image(self, rel: str, color: bool) -> np.ndarray:
        return decode_png(self.read_bytes(rel), str(self.path / rel), color)

    def read_json(self, rel: str) -> Any:
        try:
            return json.loads(self.read_bytes(rel))
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise SessionError(f"{self.path / rel}: not valid JSON ({exc}); regenerate the session") from None

    def verify(self) -> int:
        """Check every listed file's sha256; raise SessionError naming the first bad file. Returns the count."""
        bad = []
        for rel, expected in self.files.items():
            path = self.path / rel
            if not path.is_file():
                bad.append(f"{path}: missing")
            elif sha256_file(path) != expected:
                bad.append(f"{path}: corrupted (sha256 mismatch)")
        bad += self._unbacked_entries()
        if bad:
            more = f" (and {len(bad) - 1} more problems)" if len(bad) > 1 else ""
            raise SessionError(f"{bad[0]}{more}; re-import or regenerate the session")
        return len(self.files)

    def _unbacked_entries(self) -> list[str]:
        """Cameras, frames and streams the manifest lists without any file behind them (and, for the
        studio images, every camera x frame: a session whose rgb stream has holes is not a recording)."""
        manifest = self.path / MANIFEST
        problems = []
        for cam in self.camera_names:
            if not any(rel.startswith(f"{cam}/") or rel.startswith(f"gt/masks/{cam}/") for rel in self.files):
                problems.append(f"{manifest}: camera {cam} is listed but has no files")
        frame_files = {}
        for rel in self.files:
            stem = rel.rsplit("/", 1)[-1].split(".", 1)[0]
            if is_frame_number(stem) and "/background/" not in rel:
                frame_files.setdefault(int(stem), 0)
                frame_files[int(stem)] += 1
        for frame in self.frame_ids:
            if not frame_files.get(frame):
                problems.append(f"{manifest}: frame {frame} is listed but has no files")
        for stream in self.streams:
            if stream in CAMERA_STREAMS or stream in FRAME_STREAMS:
                rels = [stream_path(stream, f, c) for f in self.frame_ids
                        for c in (self.camera_names if stream in CAMERA_STREAMS else [None])]
                if not any(r in self.files for r in rels):
                    problems.append(f"{manifest}: stream {stream} is listed but has no files")
                elif stream == "rgb":
                    missing = [r for r in rels if r not in self.files]
                    if missing:
                        problems.append(f"{manifest}: {missing[0]} (rgb of a listed camera and frame) is not "
                                        f"in the manifest ({len(missing)} such)")
        return problems


def progress_bar(enabled: bool):
    """A rich progress bar (disabled: a silent stand-in with the same API) for long session writes."""
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    # stderr, so that commands printing JSON on stdout stay parseable; only on a terminal (in a log or a
    # pipe a bar leaves its last state around the output and the error line)
    console = Console(stderr=True)
    return Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn(),
                    console=console, disable=not enabled or not console.is_terminal)


def _ranges(ids: list[int]) -> str:
    if not ids:
        return "none"
    return f"{ids[0]}..{ids[-1]} ({len(ids)} frames)" if ids == list(range(ids[0], ids[-1] + 1)) else str(ids)


def open_session(path: str | os.PathLike) -> Session:
    """Open a session folder, checking the manifest and that every file it lists exists.

    A leftover ``.staging`` folder of an interrupted write is reported (warning and
    ``Session.interrupted_write``) while the previous, committed state is returned; a write
    interrupted after its commit point raises and names :func:`recover_session` as the fix.
    """
    path = Path(path)
    manifest_path = path / MANIFEST
    staging = path / STAGING
    if not path.is_dir():
        raise SessionError(f"{path}: no such session folder")
    try:  # a shared read lock for as long as this command reads the session: no writer may start meanwhile
        read_lock = hold_read_lock(session_layout(path))
    except OutputLockedError as exc:
        raise SessionError(str(exc).replace(": being written", ": session is being written", 1)) from None
    try:
        session = _open_checked(path, manifest_path, staging)
    except BaseException:
        if read_lock is not None:
            read_lock.release()
        raise
    if read_lock is not None:
        weakref.finalize(session, read_lock.release)
    return session


def _open_checked(path: Path, manifest_path: Path, staging: Path) -> Session:
    if (staging / COMMIT).is_file():
        raise SessionError(f"{staging / COMMIT}: a write was interrupted while committing; run "
                           f"`bodystudio capture recover {path}` to finish it")
    interrupted = None
    if staging.is_dir():
        n = sum(1 for p in staging.rglob("*") if p.is_file())
        interrupted = f"{staging}: an interrupted write left {n} uncommitted files"
    if not manifest_path.is_file():
        what = f" ({interrupted})" if interrupted else ""
        raise SessionError(f"{manifest_path}: missing, the session was never completed{what}; "
                           "regenerate or re-import it")
    try:
        manifest = json.loads(manifest_path.read_bytes())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise SessionError(f"{manifest_path}: corrupted manifest ({exc}); "
                           "regenerate or re-import the session") from None
    _check_manifest(manifest, manifest_path)
    for rel in manifest["files"]:
        if not (path / rel).is_file():
            raise SessionError(f"{path / rel}: missing (listed in {MANIFEST}); the session is incomplete, "
                               "re-import or regenerate it")
    if interrupted:
        log.warning("%s; showing the last committed state (run `bodystudio capture recover %s` to discard it)",
                    interrupted, path)
    return Session(path, manifest, interrupted)


def _check_manifest(m: Any, source: Path) -> None:
    if not isinstance(m, dict) or m.get("format") != SESSION_FORMAT:
        raise SessionError(f"{source}: not a bodystudio session manifest (format != {SESSION_FORMAT!r})")
    if m.get("version") != SESSION_VERSION:
        raise SessionError(f"{source}: session format version {m.get('version')!r} is not supported "
                           f"(this bodystudio reads version {SESSION_VERSION}); upgrade bodystudio or re-import")
    for key, kind in (("cameras", list), ("frames", list), ("streams", list), ("files", dict)):
        if not isinstance(m.get(key), kind):
            raise SessionError(f"{source}: manifest field {key!r} is missing or not a {kind.__name__}")
    if not all(isinstance(c, str) and _NAME.match(c) for c in m["cameras"]):
        raise SessionError(f"{source}: manifest field 'cameras' must list camera names (letters, digits, _ . -)")
    if not all(type(f) is int and f >= 0 for f in m["frames"]):
        raise SessionError(f"{source}: manifest field 'frames' must list non-negative integer frame ids")
    # the writer sorts them; a repeated or reordered id (a hand-merged manifest) was processed twice or out of time
    # order by every stage (tracking, smoothing, the arm capture's neighbouring frames), with exit 0
    bad = next((k for k in range(1, len(m["frames"])) if m["frames"][k] <= m["frames"][k - 1]), None)
    if bad is not None:
        raise SessionError(f"{source}: manifest field 'frames' lists frame {m['frames'][bad]} after "
                           f"{m['frames'][bad - 1]}; each frame id once, increasing: fix session.json or re-import")
    if not all(isinstance(s, str) for s in m["streams"]):
        raise SessionError(f"{source}: manifest field 'streams' must list stream names")
    for rel, digest in m["files"].items():
        parts = Path(rel).parts
        if not isinstance(digest, str) or not parts or Path(rel).is_absolute() or ".." in parts:
            raise SessionError(f"{source}: manifest entry {rel!r} is not a relative path inside the session with "
                               "a sha256; the manifest is corrupt, regenerate or re-import the session")
    if CAMERAS_JSON not in m["files"]:
        raise SessionError(f"{source}: lists no {CAMERAS_JSON}; every session needs the studio calibration")


def session_layout(path: str | os.PathLike) -> RunLayout:
    """The session's lock (``.lock``), staging (``.staging``) and manifest (:mod:`bodystudio.runfolder`)."""
    return RunLayout(Path(path), MANIFEST, ".", str(path))


def recover_session(path: str | os.PathLike) -> str:
    """Finish a write interrupted after its commit point, or discard one interrupted before it."""
    try:
        return recover_layout(session_layout(path)) or "nothing to recover"
    except OutputLockedError as exc:
        raise SessionError(str(exc)) from None


def _apply_commit(path: Path, plan: dict) -> None:
    apply_commit(session_layout(path), plan)


# ---------------------------------------------------------------------------------------------- writing

@dataclass
class SessionWriter:
    """Write a new session, or update an existing one (``update=True``), frame by frame.

    >>> with SessionWriter(out, rig, source="synthetic") as w:
    ...     w.write_image("cam_00", 0, rgb)
    ...     w.write_mask("cam_00", 0, mask)

    Nothing becomes visible before :meth:`commit` (called on a clean exit of the ``with`` block); an
    exception inside the block discards the staged files (:meth:`abort`). A process killed before the
    commit leaves the previous state and a ``.staging`` folder that :func:`open_session` reports.
    """

    path: Path
    cameras: Any = None  # CameraRig; required for a new session
    source: str = "import"
    update: bool = False
    metadata: dict = field(default_factory=dict)
    command: str = ""  # named in the lock, so that a refused reader or writer learns who holds the session
    _manifest: dict = field(init=False, repr=False)
    _staged: dict = field(init=False, repr=False, default_factory=dict)
    _deletes: set = field(init=False, repr=False, default_factory=set)

    def __post_init__(self):
        self.path = Path(self.path)
        existed = self.path.is_dir()
        layout = session_layout(self.path)
        holder = read_lock(layout.lock)
        if holder is not None and holder["pid"] == os.getpid() and layout.lock.exists():
            raise SessionError(f"{self.path / STAGING}: another write is in progress or was interrupted; run "
                               f"`bodystudio capture recover {self.path}` first")
        try:
            acquire_lock(layout, self.command or f"bodystudio ({self.source})")
        except OutputLockedError as exc:
            raise SessionError(str(exc).replace(": being written", ": session is being written", 1)) from None
        try:
            self._start()
        except BaseException:
            release_lock(layout)
            if not existed and self.path.is_dir() and not any(self.path.iterdir()):
                self.path.rmdir()
            raise

    def _start(self) -> None:
        if (self.path / STAGING).exists():
            raise SessionError(f"{self.path / STAGING}: another write is in progress or was interrupted; run "
                               f"`bodystudio capture recover {self.path}` first")
        remove_stale_staging(session_layout(self.path))
        if self.update:
            self._manifest = json.loads(json.dumps(open_session(self.path).manifest))
            self._manifest.setdefault("metadata", {}).update(self.metadata)
        else:
            if (self.path / MANIFEST).exists():
                raise SessionError(f"{self.path}: already holds a session; choose a new folder or delete it")
            if self.cameras is None:
                raise ValueError("a new session needs its cameras (CameraRig)")
            names = list(self.cameras.cameras)
            for name in names:
                if not _NAME.match(name):
                    raise SessionError(f"camera name {name!r} cannot be a folder name; use letters, digits, _ . -")
            self._manifest = {"format": SESSION_FORMAT, "version": SESSION_VERSION, "source": self.source,
                              "cameras": names, "frames": [], "streams": [], "files": {},
                              "metadata": dict(self.metadata)}
            self._stage(CAMERAS_JSON, _json_bytes(self.cameras.to_dict()))
        (self.path / STAGING).mkdir(parents=True, exist_ok=True)

    def __enter__(self) -> SessionWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.commit()
        else:
            self.abort()

    def abort(self) -> None:
        """Discard the staged files (the previous state stays); a new session's empty folder goes too."""
        remove_staging(session_layout(self.path))
        self._staged = {}
        release_lock(session_layout(self.path))
        if not self.update and self.path.is_dir() and not any(self.path.iterdir()):
            self.path.rmdir()

    @property
    def camera_names(self) -> list[str]:
        return list(self._manifest["cameras"])

    def _stage(self, rel: str, data: bytes, stream: str | None = None, frame: int | None = None) -> None:
        with atomic_write(self.path / STAGING / rel, "wb") as f:
            f.write(data)
        self._staged[rel] = sha256_bytes(data)
        if stream is not None and stream not in self._manifest["streams"]:
            self._manifest["streams"].append(stream)
        if frame is not None and frame not in self._manifest["frames"]:
            self._manifest["frames"].append(int(frame))

    def _check_camera(self, camera: str) -> None:
        if camera not in self._manifest["cameras"]:
            raise SessionError(f"camera {camera!r} is not in this session's calibration "
                               f"({', '.join(self._manifest['cameras'])})")

    def write_image(self, camera: str, frame: int, rgb: np.ndarray) -> None:
        self._check_camera(camera)
        self._stage(stream_path("rgb", frame, camera), encode_png(rgb, f"{camera} frame {frame}"), "rgb", frame)

    def write_mask(self, camera: str, frame: int, mask: np.ndarray, ground_truth: bool = False) -> None:
        self._check_camera(camera)
        m = (np.asarray(mask) > 0).astype(np.uint8) * 255
        stream = "gt_mask" if ground_truth else "mask"
        self._stage(stream_path(stream, frame, camera), encode_png(m), stream, frame)

    def write_layers(self, camera: str, frame: int, labels: np.ndarray, target: bool = False) -> None:
        """Per-pixel layer labels (uint8: 0 background, 1 body, 2 garment) of the frame or of the target render."""
        self._check_camera(camera)
        stream = "gt_target_layers" if target else "gt_layers"
        self._stage(stream_path(stream, frame, camera), encode_png(np.asarray(labels, dtype=np.uint8)), stream, frame)

    def write_target(self, camera: str, frame: int, rgb: np.ndarray) -> None:
        """The true render of the actor wearing the target garment (garment sessions)."""
        self._check_camera(camera)
        self._stage(stream_path("gt_target", frame, camera), encode_png(rgb, f"{camera} target {frame}"),
                    "gt_target", frame)

    def write_gt_json(self, rel: str, data: dict) -> None:
        """A ground-truth JSON file of the whole session (``GT_LIGHTING``, ``GT_GARMENT``, ``GT_ALBEDO``)."""
        if rel not in (GT_LIGHTING, GT_GARMENT, GT_ALBEDO):
            raise ValueError(f"unknown ground-truth file {rel!r}")
        self._stage(rel, _json_bytes(data))

    def write_background(self, camera: str, index: int, rgb: np.ndarray) -> None:
        self._check_camera(camera)
        self._stage(BACKGROUND.format(cam=camera, index=index), encode_png(rgb), "background")

    def write_kinect_calibration(self, sensor) -> None:
        """The RGB-D sensor (RGBDSensor: depth and colour cameras in the studio frame)."""
        self._stage(KINECT_CALIBRATION, _json_bytes(kinect_calibration_to_dict(sensor)))

    def write_kinect_depth(self, frame: int, depth_m: np.ndarray) -> None:
        self._stage(stream_path("kinect_depth", frame), encode_png(depth_to_png_mm(depth_m)), "kinect_depth", frame)

    def write_kinect_rgb(self, frame: int, rgb: np.ndarray) -> None:
        self._stage(stream_path("kinect_rgb", frame), encode_png(rgb), "kinect_rgb", frame)

    def write_kinect_joints(self, frame: int, names: list[str], positions: np.ndarray,
                            tracked: np.ndarray | None = None, joint_set: str | None = None) -> None:
        positions = np.asarray(positions, dtype=np.float64).reshape(len(names), 3)
        data = {"joint_set": joint_set, "frame": "studio", "unit": "m", "names": list(names),
                "positions": _positions_json(positions),
                "tracked": (np.ones(len(names), bool) if tracked is None else np.asarray(tracked, bool)).tolist()}
        self._stage(stream_path("kinect_joints", frame), _json_bytes(data), "kinect_joints", frame)

    def write_kinect_bodies(self, frame: int, bodies: list[dict], joint_set: str | None = None) -> None:
        """Several tracked bodies: ``[{"player": k, "names", "positions" (J, 3), "tracked" (J,)}]``.

        The body with the lowest player id is also written in the single-body layout (top-level
        ``names``/``positions``/``tracked``), so readers of one body keep working; an empty list
        records a frame in which nobody is tracked. NaN positions (not reported) are stored as null.
        """
        out = []
        for body in bodies:
            player = int(body["player"])
            if not 1 <= player <= MAX_PLAYERS:
                raise ValueError(f"player ids are 1..{MAX_PLAYERS}, got {player}")
            names = list(body["names"])
            positions = np.asarray(body["positions"], dtype=np.float64).reshape(len(names), 3)
            tracked = body.get("tracked")
            tracked = np.ones(len(names), bool) if tracked is None else np.asarray(tracked, bool).reshape(len(names))
            out.append({"player": player, "names": names, "positions": _positions_json(positions),
                        "tracked": tracked.tolist()})
        players = [b["player"] for b in out]
        if len(set(players)) != len(players):
            raise ValueError(f"player ids must differ between bodies, got {players}")
        out.sort(key=lambda b: b["player"])
        data: dict = {"joint_set": joint_set, "frame": "studio", "unit": "m"}
        if out:
            data.update({k: out[0][k] for k in ("names", "positions", "tracked")})
        data["bodies"] = out
        self._stage(stream_path("kinect_joints", frame), _json_bytes(data), "kinect_joints", frame)

    def write_kinect_player(self, frame: int, player: np.ndarray) -> None:
        """The body tracker's player mask (H, W) on the depth image: 0 nobody, k = player k (1..6)."""
        mask = np.asarray(player)
        if mask.ndim != 2 or not (np.issubdtype(mask.dtype, np.integer) or mask.dtype == bool):
            raise ValueError(f"player mask must be an (H, W) integer image, got {mask.dtype} {mask.shape}")
        if mask.size and (mask.min() < 0 or mask.max() > MAX_PLAYERS):
            raise ValueError(f"player mask values must be 0..{MAX_PLAYERS}, got {mask.min()}..{mask.max()}")
        self._stage(stream_path("kinect_player", frame), encode_png(mask.astype(np.uint8), "player mask"),
                    "kinect_player", frame)

    def write_gt_subject(self, phenotype: dict, local: dict, **extra) -> None:
        self._stage(GT_PHENOTYPE, _json_bytes({"phenotype": phenotype, "local": local, **extra}))

    def write_gt_mesh(self, frame: int, V: np.ndarray, F: np.ndarray) -> None:
        self._stage(stream_path("gt_mesh", frame), mesh_ply_bytes(V, F), "gt_mesh", frame)

    def write_gt_joints(self, frame: int, bone_names, heads: np.ndarray, tails: np.ndarray) -> None:
        data = {"bone_names": list(bone_names), "heads": np.asarray(heads), "tails": np.asarray(tails)}
        self._stage(stream_path("gt_joints", frame), _json_bytes(data), "gt_joints", frame)

    def write_gt_pose(self, frame: int, pose, bone_names) -> None:
        from bodystudio.body.pose import pose_to_dict

        data = {**pose_to_dict(pose, tuple(bone_names)), "bone_names": list(bone_names)}
        self._stage(stream_path("gt_pose", frame), _json_bytes(data), "gt_pose", frame)

    def write_gt_arm_mesh(self, frame: int, V: np.ndarray, F: np.ndarray) -> None:
        """Arm sessions: the ground-truth arm mesh in the arm template's topology."""
        self._stage(stream_path("gt_arm_mesh", frame), mesh_ply_bytes(V, F), "gt_arm_mesh", frame)

    def write_gt_arm_pose(self, frame: int, arm_pose: dict) -> None:
        """Arm sessions: the ground-truth arm joint angles (``ArmPose.to_dict()``)."""
        self._stage(stream_path("gt_arm_pose", frame), _json_bytes(arm_pose), "gt_arm_pose", frame)

    def write_gt_person(self, frame: int, labels: np.ndarray, target: bool = False) -> None:
        """Mirror sessions: true person labels (0 none, k = actor k) in the colour image, of the input
        (``target=False``) or of the target render."""
        labels = np.asarray(labels)
        if labels.ndim != 2 or labels.min(initial=0) < 0 or labels.max(initial=0) > MAX_PLAYERS:
            raise ValueError(f"person labels must be an (H, W) image with values 0..{MAX_PLAYERS}")
        stream = "gt_target_person" if target else "gt_person"
        self._stage(stream_path(stream, frame), encode_png(labels.astype(np.uint8)), stream, frame)

    def write_gt_target_rgb(self, frame: int, rgb: np.ndarray) -> None:
        """Mirror sessions: the frame rendered with the edited (target) bodies."""
        self._stage(stream_path("gt_target_rgb", frame), encode_png(rgb), "gt_target_rgb", frame)

    def write_gt_mirror(self, frame: int, arrays: dict[str, np.ndarray]) -> None:
        """Mirror sessions: the frame's ground-truth arrays (one ``.npz``)."""
        self._stage(stream_path("gt_mirror", frame), npz_bytes(arrays), "gt_mirror", frame)

    def write_gt_mirror_actors(self, arrays: dict[str, np.ndarray]) -> None:
        """Mirror sessions: the actors' rest meshes, coefficients and skeletons (``gt/mirror/actors.npz``)."""
        self._stage(GT_MIRROR_ACTORS, npz_bytes(arrays))

    def commit(self) -> Session:
        """Make the staged files visible: commit record, moves, manifest last. Returns the opened session."""
        manifest = self._manifest
        manifest["frames"] = sorted(manifest["frames"])
        manifest["files"] = {**manifest["files"], **self._staged}
        manifest["files"] = dict(sorted(manifest["files"].items()))
        plan = {"moves": sorted(self._staged), "deletes": sorted(self._deletes), "manifest": manifest,
                "manifest_name": MANIFEST}
        with atomic_write(self.path / STAGING / COMMIT, "wb") as f:
            f.write(_json_bytes(plan))
        _apply_commit(self.path, plan)
        self._staged = {}
        session = open_session(self.path)
        release_lock(session_layout(self.path))
        return session
