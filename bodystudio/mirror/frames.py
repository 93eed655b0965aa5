"""Kinect mirror frames (§3 of Real-time Reshaping of Humans): colour, depth, player mask and tracked bodies.

A :class:`MirrorFrame` bundles what the SDK delivers for one frame; :func:`register_depth_to_color` is the
SDK's depth-to-colour registration (each depth pixel back-projected through the depth camera, moved into
the colour camera and splatted over the colour pixels it covers, nearest surface first), which maps the
player mask and the depth into the colour image (:func:`player_mask_in_color`).
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterable, Iterator
from dataclasses import dataclass

import numpy as np
from numba import njit

from bodystudio.body.kinect import kinect_joint_names
from bodystudio.capture.session import MAX_PLAYERS, stream_fingerprint, stream_path
from bodystudio.errors import InputError, SessionError
from bodystudio.geometry.camera import Camera, RGBDSensor


def recording_fingerprint(session, frame_ids) -> str | None:
    """Which Kinect recording a mirror run read: one sha256 over the session manifest's digests of the colour,
    depth, player and joint files of ``frame_ids`` (:func:`~bodystudio.capture.session.stream_fingerprint`).
    It survives moving or copying the session; None when a file is not in the manifest (a live recording)."""
    parts = [stream_fingerprint(session, stream, frame_ids)
             for stream in ("kinect_rgb", "kinect_depth", "kinect_player", "kinect_joints")]
    return None if any(p is None for p in parts) else hashlib.sha256("\n".join(parts).encode()).hexdigest()


@dataclass(frozen=True, eq=False)
class TrackedBody:
    """One Kinect SDK body in one frame (joint positions in the studio frame, metres)."""

    player: int  # 1..6, the value of its pixels in the player mask
    names: tuple[str, ...]  # kinect_joint_names(version)
    positions: np.ndarray  # (J, 3); NaN where the tracker reported no position
    tracked: np.ndarray  # (J,) bool; False where the joint is only inferred (or not reported)


@dataclass(frozen=True, eq=False)
class MirrorFrame:
    """One Kinect frame of a mirror session."""

    index: int
    rgb: np.ndarray  # (H, W, 3) uint8 colour image (640x480 in mirror sessions)
    depth_m: np.ndarray  # (h, w) float64 metres, 0 = no measurement (depth camera resolution)
    player: np.ndarray  # (h, w) uint8 SDK player mask on the depth image: 0 none, k = player k
    bodies: tuple[TrackedBody, ...]

    def body(self, player: int) -> TrackedBody | None:
        """The tracked body of ``player``, or None when that player is not tracked in this frame."""
        return next((b for b in self.bodies if b.player == player), None)


def _kinect_sensor(session) -> RGBDSensor:
    sensor = session.kinect
    if sensor is None:
        raise SessionError(f"{session.path}: not a Kinect session (no kinect/calibration.json); the mirror needs "
                           "Kinect colour, depth, player mask and joints (`bodystudio synth mirror` or capture import)")
    return sensor


def read_mirror_frame(session, i: int) -> MirrorFrame:
    """Frame ``i`` of a Kinect session as a :class:`MirrorFrame`; one-line SessionError on missing or bad data.

    A frame without a joints file (or with an empty body list) has no bodies: nobody is tracked.
    """
    sensor = _kinect_sensor(session)
    frame = session.frame(i)
    rgb, depth, player = frame.kinect_rgb, frame.kinect_depth_m, frame.kinect_player
    for value, stream, what in ((rgb, "kinect_rgb", "colour image"), (depth, "kinect_depth", "depth image"),
                                (player, "kinect_player", "player mask")):
        if value is None:
            raise SessionError(f"{session.path / stream_path(stream, i)}: missing, frame {i} has no Kinect {what}; "
                               "the mirror needs colour, depth and the player mask in every frame")
    shapes = ((rgb.shape[:2], sensor.color, "kinect_rgb"), (depth.shape, sensor.depth, "kinect_depth"),
              (player.shape, sensor.depth, "kinect_player"))
    for shape, camera, stream in shapes:
        if tuple(shape) != (camera.height, camera.width):
            raise SessionError(f"{session.path / stream_path(stream, i)}: image is {shape[1]}x{shape[0]} but "
                               f"kinect/calibration.json says {camera.width}x{camera.height}; fix the calibration")
    bodies = []
    names = kinect_joint_names(sensor.version)
    for body in frame.kinect_bodies or []:
        if body["names"] != names:
            raise SessionError(f"{session.path / stream_path('kinect_joints', i)}: joints are not the Kinect "
                               f"{sensor.version} joint set (kinect/calibration.json version); re-import the joints")
        pos = body["positions"].copy()
        pos.setflags(write=False)
        tracked = body["tracked"] & np.all(np.isfinite(pos), axis=1)
        tracked.setflags(write=False)
        bodies.append(TrackedBody(int(body["player"]), tuple(names), pos, tracked))
    return MirrorFrame(int(i), rgb, depth, player, tuple(sorted(bodies, key=lambda b: b.player)))


def iter_mirror_frames(session, frames: Iterable[int] | None = None) -> Iterator[MirrorFrame]:
    """The session's mirror frames in order (``frames``: the frame ids to read, default all)."""
    _kinect_sensor(session)
    for i in session.frame_ids if frames is None else frames:
        yield read_mirror_frame(session, int(i))


# ---------------------------------------------------------------------------------------------- registration

_RAY_TABLES: dict[tuple, np.ndarray] = {}


def depth_ray_table(camera: Camera) -> np.ndarray:
    """(h, w, 2) normalised undistorted coordinates ``(x/z, y/z)`` of every depth pixel centre (cached)."""
    key = (camera.K.tobytes(), camera.dist.tobytes(), camera.width, camera.height)
    table = _RAY_TABLES.get(key)
    if table is None:
        cols, rows = np.meshgrid(np.arange(camera.width, dtype=np.float64), np.arange(camera.height, dtype=np.float64))
        xy = camera.undistort_points(np.stack([cols.ravel(), rows.ravel()], axis=1), normalized=True)
        table = xy.reshape(camera.height, camera.width, 2)
        table.setflags(write=False)
        if len(_RAY_TABLES) > 8:
            _RAY_TABLES.clear()
        _RAY_TABLES[key] = table
    return table


@njit(cache=True)
def _register(depth, player, rays, T, K, dist, width, height, footprint, zbuf, pbuf):
    k1, k2, p1, p2, k3 = dist[0], dist[1], dist[2], dist[3], dist[4]
    h, w = depth.shape
    for r in range(h):
        for c in range(w):
            z = depth[r, c]
            if z <= 0.0:
                continue
            x = rays[r, c, 0] * z
            y = rays[r, c, 1] * z
            xc = T[0, 0] * x + T[0, 1] * y + T[0, 2] * z + T[0, 3]
            yc = T[1, 0] * x + T[1, 1] * y + T[1, 2] * z + T[1, 3]
            zc = T[2, 0] * x + T[2, 1] * y + T[2, 2] * z + T[2, 3]
            if zc <= 0.0:
                continue
            a = xc / zc
            b = yc / zc
            r2 = a * a + b * b
            radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
            ad = a * radial + 2.0 * p1 * a * b + p2 * (r2 + 2.0 * a * a)
            bd = b * radial + p1 * (r2 + 2.0 * b * b) + 2.0 * p2 * a * b
            u = K[0, 0] * ad + K[0, 1] * bd + K[0, 2]
            v = K[1, 1] * bd + K[1, 2]
            # the depth pixel covers [u - half, u + half] in the colour image (footprint scales with z / zc)
            half = 0.5 * footprint * z / zc + 0.25
            c0 = max(int(np.ceil(u - half)), 0)
            c1 = min(int(np.floor(u + half)), width - 1)
            r0 = max(int(np.ceil(v - half)), 0)
            r1 = min(int(np.floor(v + half)), height - 1)
            pl = player[r, c]
            if c1 - c0 < 3 and r1 - r0 < 3 and c0 + 2 < width and r0 + 2 < height:
                # the usual footprint (2-3 pixels a side): a fixed 3x3 block whose z-tests are selects, the pixels
                # past the footprint written back unchanged; the loops of the footprint's 2 or 3 pixels and the
                # z-tests mispredicted (MIR12f: 3.3 -> 2.4 ms a v1 frame, the same depth and ids bit for bit)
                for dr in range(3):
                    rr = r0 + dr
                    okr = rr <= r1
                    for dc in range(3):
                        cc = c0 + dc
                        old = zbuf[rr, cc]
                        take = okr and cc <= c1 and zc < old
                        zbuf[rr, cc] = zc if take else old
                        pbuf[rr, cc] = pl if take else pbuf[rr, cc]
                continue
            for rr in range(r0, r1 + 1):
                for cc in range(c0, c1 + 1):
                    if zc < zbuf[rr, cc]:
                        zbuf[rr, cc] = zc
                        pbuf[rr, cc] = pl
    for rr in range(height):  # colour pixels no depth pixel reached: 0 (was a numpy isfinite pass, MIR12e)
        for cc in range(width):
            if zbuf[rr, cc] == np.inf:
                zbuf[rr, cc] = 0.0


def register_depth_to_color(depth_m: np.ndarray, player: np.ndarray,
                            sensor: RGBDSensor) -> tuple[np.ndarray, np.ndarray]:
    """Depth (H, W) float64 metres in the colour camera (0 = none) and the player mask (H, W) uint8 there.

    The SDK's registration: every measured depth pixel is back-projected, moved by ``depth_to_color``,
    projected with the colour camera's distortion and splatted over the colour pixels its footprint
    covers; the nearest surface wins. Colour pixels no depth pixel reaches stay 0 in both outputs.
    """
    depth_m = np.ascontiguousarray(depth_m, dtype=np.float64)
    player = np.ascontiguousarray(player, dtype=np.uint8)
    d, col = sensor.depth, sensor.color
    if depth_m.shape != (d.height, d.width) or player.shape != depth_m.shape:
        raise InputError(f"register_depth_to_color: depth {depth_m.shape} and player {player.shape} must be "
                         f"({d.height}, {d.width}), the depth camera's size")
    zbuf = np.full((col.height, col.width), np.inf)
    pbuf = np.zeros((col.height, col.width), dtype=np.uint8)
    footprint = 0.5 * (col.fx / d.fx + col.fy / d.fy)
    _register(depth_m, player, depth_ray_table(d), np.ascontiguousarray(sensor.depth_to_color, dtype=np.float64),
              col.K, col.dist, col.width, col.height, footprint, zbuf, pbuf)
    return zbuf, pbuf


def player_mask_in_color(frame: MirrorFrame, sensor: RGBDSensor, player: int | None = None) -> np.ndarray:
    """(H, W) bool colour-image mask of ``player`` (None: any player), mapped through the depth (the SDK's
    registration, :func:`register_depth_to_color`)."""
    if player is not None and not 1 <= int(player) <= MAX_PLAYERS:
        raise InputError(f"player {player} is not a Kinect player id; valid: 1..{MAX_PLAYERS}")
    _, mapped = register_depth_to_color(frame.depth_m, frame.player, sensor)
    return mapped > 0 if player is None else mapped == int(player)


def point_cloud(frame: MirrorFrame, sensor: RGBDSensor, player: int) -> np.ndarray:
    """(N, 3) studio-frame points of the depth pixels of ``player`` that have a depth measurement."""
    if not 1 <= int(player) <= MAX_PLAYERS:
        raise InputError(f"player {player} is not a Kinect player id; valid: 1..{MAX_PLAYERS}")
    d = sensor.depth
    if frame.depth_m.shape != (d.height, d.width):
        raise InputError(f"point_cloud: depth {frame.depth_m.shape} is not the depth camera's ({d.height}, {d.width})")
    return _player_points(np.ascontiguousarray(frame.depth_m, dtype=np.float64),
                          np.ascontiguousarray(frame.player, dtype=np.uint8), depth_ray_table(d), int(player),
                          np.ascontiguousarray(d.R, dtype=np.float64), np.ascontiguousarray(d.t, dtype=np.float64))


@njit(cache=True)
def _player_points(depth, player, rays, which, R, t):
    """The depth pixels of player ``which`` with a measurement, back-projected (``rays`` times the depth) and moved
    into the studio frame (``(P - t) R``, as ``Camera.camera_to_world``), in raster order, in one pass (MIR12e:
    the mask, the gathers and the transform were ~0.35 ms of numpy per player and frame)."""
    h, w = depth.shape
    n = 0
    for r in range(h):
        for c in range(w):
            if player[r, c] == which and depth[r, c] > 0.0:
                n += 1
    out = np.empty((n, 3))
    k = 0
    for r in range(h):
        for c in range(w):
            z = depth[r, c]
            if player[r, c] == which and z > 0.0:
                x = rays[r, c, 0] * z - t[0]
                y = rays[r, c, 1] * z - t[1]
                zz = z - t[2]
                for j in range(3):
                    out[k, j] = x * R[0, j] + y * R[1, j] + zz * R[2, j]
                k += 1
    return out
