"""Pinhole cameras with OpenCV lens distortion, camera rigs, the cameras.json format and RGB-D sensors.

Conventions (OpenCV): camera x right, y down, z forward; ``x_cam = R @ X_world + t``; pixels
``u = fx * x'' + s * y'' + cx``, ``v = fy * y'' + cy`` where ``(x'', y'')`` is the normalised point
after the Brown-Conrady distortion ``dist = (k1, k2, p1, p2, k3)``. World: metres, y up, floor y = 0.

The studio layout follows Rapid Skin Sec. 5 (ten synchronised cameras on a ring around a ~2 m
capture volume); the RGB-D sensors carry the published Kinect v1 / v2 intrinsics and the
projector-camera baseline used by the depth model of Khoshelham & Elberink (2012).
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from dataclasses import dataclass, field
from functools import cached_property, lru_cache

import cv2
import numpy as np

from bodystudio.errors import FileFormatError, InputError
from bodystudio.fileio import read_json, write_json

CAMERAS_JSON_VERSION = 1


def distort_normalized(xy: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """OpenCV's Brown-Conrady distortion (k1, k2, p1, p2, k3) of normalised points (N, 2), vectorised."""
    k1, k2, p1, p2, k3 = dist
    x, y = xy[:, 0], xy[:, 1]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    return np.stack([xd, yd], axis=1)


def _distortion_jacobian(xy: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """Jacobians (N, 2, 2) of :func:`distort_normalized` with respect to the undistorted point."""
    k1, k2, p1, p2, k3 = dist
    x, y = xy[:, 0], xy[:, 1]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    dradial = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)  # d radial / d r2
    J = np.empty((len(xy), 2, 2))
    J[:, 0, 0] = radial + x * dradial * 2 * x + 2 * p1 * y + p2 * 6 * x
    J[:, 0, 1] = x * dradial * 2 * y + 2 * p1 * x + p2 * 2 * y
    J[:, 1, 0] = y * dradial * 2 * x + p1 * 2 * x + 2 * p2 * y
    J[:, 1, 1] = radial + y * dradial * 2 * y + p1 * 6 * y + 2 * p2 * x
    return J


def pinhole_projection_jacobian(camera, V: np.ndarray, J: np.ndarray) -> np.ndarray:
    """(n, 2, k) derivative of the pixel positions of points ``V`` (n, 3) whose derivative with respect to k
    parameters is ``J`` (n, 3, k): the chain rule through ``(fx x / z, fy y / z)`` of the camera frame, lens
    distortion left out (the Gauss-Newton steps of the silhouette shape refinements, mirror and garment)."""
    Pc = V @ camera.R.T + camera.t
    z = Pc[:, 2]
    dP = np.einsum("ij,njk->nik", camera.R, J)
    du = camera.fx * (dP[:, 0] - Pc[:, 0:1] / z[:, None] * dP[:, 2]) / z[:, None]
    dv = camera.fy * (dP[:, 1] - Pc[:, 1:2] / z[:, None] * dP[:, 2]) / z[:, None]
    return np.stack([du, dv], axis=1)


def distortion_monotonic_radius(dist: np.ndarray) -> float:
    """The normalised radius ``r`` up to which the OpenCV radial distortion ``r_d = r (1 + k1 r^2 + k2 r^4 + k3 r^6)``
    increases: the smallest root of ``d r_d / d r = 1 + 3 k1 r^2 + 5 k2 r^4 + 7 k3 r^6``, ``inf`` where none.

    Beyond it the polynomial folds back (a point further off the axis lands nearer the centre): a real lens cannot
    see there, so the renderer draws no triangle with a vertex beyond it. Radial terms only (the tangential ``p1 p2``
    are small and do not fold).
    """
    k1, k2, _, _, k3 = (float(c) for c in np.asarray(dist, dtype=np.float64).ravel()[:5])
    return _radial_monotonic_radius(k1, k2, k3)


@lru_cache(maxsize=64)
def _radial_monotonic_radius(k1: float, k2: float, k3: float) -> float:
    # cached: the mirror's crop cameras (a new Camera every frame) share their lens's radius (np.roots ~40 us)
    roots = np.roots([7.0 * k3, 5.0 * k2, 3.0 * k1, 1.0]) if (k1, k2, k3) != (0.0, 0.0, 0.0) else np.empty(0)
    u = [r.real for r in np.atleast_1d(roots) if abs(r.imag) <= 1e-12 * max(1.0, abs(r)) and r.real > 0.0]
    return float(np.sqrt(min(u))) if u else float("inf")


@dataclass(frozen=True, eq=False)
class Camera:
    """One calibrated camera: intrinsics ``K``, distortion, world->camera pose ``(R, t)``, image size."""

    name: str
    K: np.ndarray
    dist: np.ndarray
    R: np.ndarray
    t: np.ndarray
    width: int
    height: int

    def __post_init__(self):
        K = np.asarray(self.K, dtype=np.float64)
        dist = np.zeros(5) if self.dist is None else np.asarray(self.dist, dtype=np.float64).ravel()
        R = np.asarray(self.R, dtype=np.float64)
        t = np.asarray(self.t, dtype=np.float64).ravel()
        if K.shape != (3, 3):
            raise InputError(f"camera {self.name}: K must be 3x3, got {K.shape}")
        if dist.shape != (5,):
            raise InputError(f"camera {self.name}: dist must have 5 entries (k1 k2 p1 p2 k3), got {dist.shape}")
        if R.shape != (3, 3) or t.shape != (3,):
            raise InputError(f"camera {self.name}: R must be 3x3 and t 3-vector, got {R.shape}, {t.shape}")
        if not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
            raise InputError(f"camera {self.name}: R is not a rotation matrix (R R^T != I or det < 0)")
        if int(self.width) <= 0 or int(self.height) <= 0:
            raise InputError(f"camera {self.name}: image size must be positive, got {self.width}x{self.height}")
        for name, value in (("K", K), ("dist", dist), ("R", R), ("t", t)):
            if not np.all(np.isfinite(value)):
                raise InputError(f"camera {self.name}: {name} has non-finite entries")
            value.setflags(write=False)
            object.__setattr__(self, name, value)
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))

    # --- derived quantities -------------------------------------------------------------------
    @cached_property
    def center(self) -> np.ndarray:
        """Optical centre in world coordinates, ``-R^T t``."""
        return -self.R.T @ self.t

    @cached_property
    def monotonic_radius(self) -> float:
        """:func:`distortion_monotonic_radius` of this camera's ``dist`` (``inf`` without distortion)."""
        return distortion_monotonic_radius(self.dist)

    @property
    def fx(self) -> float:
        return float(self.K[0, 0])

    @property
    def fy(self) -> float:
        return float(self.K[1, 1])

    @property
    def image_size(self) -> tuple[int, int]:
        """(width, height) as OpenCV wants it."""
        return self.width, self.height

    @cached_property
    def extrinsic(self) -> np.ndarray:
        """4x4 world->camera matrix."""
        T = np.eye(4)
        T[:3, :3] = self.R
        T[:3, 3] = self.t
        return T

    @cached_property
    def has_distortion(self) -> bool:
        return bool(np.any(self.dist != 0.0))

    # --- projection ---------------------------------------------------------------------------
    def world_to_camera(self, P: np.ndarray) -> np.ndarray:
        """World points (N, 3) in camera coordinates (N, 3)."""
        P = np.asarray(P, dtype=np.float64).reshape(-1, 3)
        return P @ self.R.T + self.t

    def camera_to_world(self, Pc: np.ndarray) -> np.ndarray:
        """Camera-frame points (N, 3) in world coordinates (N, 3)."""
        Pc = np.asarray(Pc, dtype=np.float64).reshape(-1, 3)
        return (Pc - self.t) @ self.R

    def project_with_depth(self, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixels (N, 2) with lens distortion and camera depth z (N,) of world points (N, 3).

        Points behind the camera (z <= 0) get NaN pixels.
        """
        Pc = self.world_to_camera(P)
        z = Pc[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            xy = Pc[:, :2] / z[:, None]
        xy[z <= 0] = np.nan
        if self.has_distortion:
            xy = distort_normalized(xy, self.dist)
        K = self.K
        u = K[0, 0] * xy[:, 0] + K[0, 1] * xy[:, 1] + K[0, 2]
        v = K[1, 1] * xy[:, 1] + K[1, 2]
        return np.stack([u, v], axis=1), z

    def project(self, P: np.ndarray) -> np.ndarray:
        """Pixels (N, 2) of world points (N, 3), with lens distortion (OpenCV model)."""
        return self.project_with_depth(P)[0]

    def undistort_points(self, uv: np.ndarray, normalized: bool = False) -> np.ndarray:
        """Remove lens distortion from pixels (N, 2) with cv2.undistortPointsIter.

        Returns undistorted pixel coordinates (same K) or, with ``normalized=True``, normalised
        image coordinates ``(x/z, y/z)``.
        """
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        if len(uv) == 0:
            return np.zeros((0, 2))
        if not self.has_distortion:
            Kinv = np.linalg.inv(self.K)
            xy = np.c_[uv, np.ones(len(uv))] @ Kinv.T
            xy = xy[:, :2] / xy[:, 2:3]
            return xy if normalized else uv.copy()
        criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-12)
        xy = cv2.undistortPoints(uv.reshape(-1, 1, 2), self.K, self.dist, R=None, P=None,
                                 criteria=criteria).reshape(-1, 2)
        # OpenCV's fixed-point iteration stalls near the image corners; polish with Newton steps.
        Kinv = np.linalg.inv(self.K)
        target = (np.c_[uv, np.ones(len(uv))] @ Kinv.T)[:, :2]
        for _ in range(4):
            residual = distort_normalized(xy, self.dist) - target
            if np.abs(residual).max() < 1e-14:
                break
            J = _distortion_jacobian(xy, self.dist)
            det = J[:, 0, 0] * J[:, 1, 1] - J[:, 0, 1] * J[:, 1, 0]
            dx = (J[:, 1, 1] * residual[:, 0] - J[:, 0, 1] * residual[:, 1]) / det
            dy = (J[:, 0, 0] * residual[:, 1] - J[:, 1, 0] * residual[:, 0]) / det
            xy = xy - np.stack([dx, dy], axis=1)
        if normalized:
            return xy
        return (np.c_[xy, np.ones(len(xy))] @ self.K.T)[:, :2]

    def rays(self, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World rays through pixels (N, 2): origins (N, 3) (the camera centre) and unit directions (N, 3)."""
        xy = self.undistort_points(uv, normalized=True)
        d_cam = np.c_[xy, np.ones(len(xy))]
        d = d_cam @ self.R  # R^T d for each row
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        return np.broadcast_to(self.center, d.shape).copy(), d

    def unproject(self, uv: np.ndarray, depth: np.ndarray) -> np.ndarray:
        """World points (N, 3) at camera depth z ``depth`` (N,) behind pixels (N, 2)."""
        xy = self.undistort_points(uv, normalized=True)
        depth = np.asarray(depth, dtype=np.float64).reshape(-1)
        Pc = np.c_[xy, np.ones(len(xy))] * depth[:, None]
        return self.camera_to_world(Pc)

    def in_image(self, uv: np.ndarray) -> np.ndarray:
        """Mask (N,) of pixels inside the image rectangle [0, W) x [0, H)."""
        uv = np.asarray(uv)
        return (uv[:, 0] >= 0) & (uv[:, 0] < self.width) & (uv[:, 1] >= 0) & (uv[:, 1] < self.height)

    def frustum(self, near: float = 0.1, far: float = 5.0) -> np.ndarray:
        """World corners (8, 3) of the viewing frustum: the four image corners at ``near`` then at ``far``."""
        corners = np.array([[0, 0], [self.width, 0], [self.width, self.height], [0, self.height]], float)
        uv = np.r_[corners, corners]
        depth = np.r_[np.full(4, near), np.full(4, far)]
        return self.unproject(uv, depth)

    # --- construction and serialisation -------------------------------------------------------
    def with_name(self, name: str) -> Camera:
        return Camera(name, self.K, self.dist, self.R, self.t, self.width, self.height)

    def to_dict(self) -> dict:
        """The cameras.json entry of this camera."""
        return {"K": self.K.tolist(), "dist": self.dist.tolist(), "R": self.R.tolist(), "t": self.t.tolist(),
                "width": self.width, "height": self.height}

    @classmethod
    def from_dict(cls, name: str, d: dict) -> Camera:
        """Camera from a cameras.json entry; a malformed or physically invalid entry raises InputError."""
        try:
            return check_intrinsics(cls(name, np.asarray(d["K"], float), np.asarray(d.get("dist", [0.0] * 5), float),
                                        np.asarray(d["R"], float), np.asarray(d["t"], float), int(d["width"]),
                                        int(d["height"])))
        except KeyError as exc:
            raise InputError(f"camera {name}: missing key {exc.args[0]!r} (need K, dist, R, t, width, height)") \
                from None
        except (TypeError, ValueError) as exc:
            raise InputError(f"camera {name}: malformed entry ({exc})") from None

    @classmethod
    def look_at(cls, name: str, eye, target, up=(0.0, 1.0, 0.0), fx: float = 600.0, width: int = 640,
                height: int = 480, fy: float | None = None, cx: float | None = None, cy: float | None = None,
                dist=None) -> Camera:
        """A camera at ``eye`` looking at ``target`` with world ``up`` pointing up in the image."""
        eye = np.asarray(eye, dtype=np.float64)
        forward = np.asarray(target, dtype=np.float64) - eye
        if np.linalg.norm(forward) < 1e-12:
            raise InputError(f"camera {name}: eye and target coincide")
        forward /= np.linalg.norm(forward)
        right = np.cross(forward, np.asarray(up, dtype=np.float64))
        if np.linalg.norm(right) < 1e-9:
            raise InputError(f"camera {name}: viewing direction is parallel to up; choose another up vector")
        right /= np.linalg.norm(right)
        down = np.cross(forward, right)
        R = np.stack([right, down, forward])
        K = np.array([[fx, 0.0, (width - 1) / 2 if cx is None else cx],
                      [0.0, fx if fy is None else fy, (height - 1) / 2 if cy is None else cy],
                      [0.0, 0.0, 1.0]])
        return cls(name, K, np.zeros(5) if dist is None else np.asarray(dist, float), R, -R @ eye, width, height)


@dataclass(frozen=True, eq=False)
class CameraRig:
    """An ordered set of cameras that owns the multi-camera operations (aniposelib's CameraGroup)."""

    cameras: dict = field(default_factory=dict)

    def __post_init__(self):
        cams = self.cameras
        if not isinstance(cams, dict):
            cams = {c.name: c for c in cams}
        object.__setattr__(self, "cameras", dict(cams))

    @property
    def names(self) -> list[str]:
        return list(self.cameras)

    def __getitem__(self, key) -> Camera:
        if isinstance(key, int):
            return list(self.cameras.values())[key]
        try:
            return self.cameras[key]
        except KeyError:
            raise InputError(f"no camera named {key!r}; the rig has {', '.join(self.cameras)}") from None

    def __len__(self) -> int:
        return len(self.cameras)

    def __iter__(self) -> Iterator[Camera]:
        return iter(self.cameras.values())

    def __contains__(self, name) -> bool:
        return name in self.cameras

    def project(self, P: np.ndarray) -> np.ndarray:
        """Pixels (C, N, 2) of world points (N, 3) in every camera."""
        P = np.asarray(P, dtype=np.float64).reshape(-1, 3)
        if not self.cameras:
            return np.zeros((0, len(P), 2))
        return np.stack([c.project(P) for c in self])

    def centers(self) -> np.ndarray:
        """Camera centres (C, 3) in world coordinates."""
        return np.array([c.center for c in self]).reshape(-1, 3)

    def subset(self, names) -> CameraRig:
        return CameraRig({n: self[n] for n in names})

    def to_dict(self) -> dict:
        return {"version": CAMERAS_JSON_VERSION, "cameras": {n: c.to_dict() for n, c in self.cameras.items()}}

    @classmethod
    def from_dict(cls, d: dict) -> CameraRig:
        cams = d["cameras"]
        return cls({str(n): Camera.from_dict(str(n), e) for n, e in cams.items()})


#: Largest |distortion coefficient| accepted at load: real lenses (fisheyes aside) stay far below; larger
#: values come from a failed calibration or a unit mix-up and make the undistortion diverge.
MAX_DISTORTION = 100.0
#: Largest image side (pixels) a camera file may declare (a 16K sensor is 15360 wide).
MAX_IMAGE_SIDE = 65536


def check_intrinsics(camera: Camera) -> Camera:
    """Refuse intrinsics no camera can have (raises InputError): fx, fy > 0, principal point inside the
    image, K's last row (0, 0, 1) and no K[1, 0] term, finite and bounded distortion. Returns ``camera``.

    Applied where cameras come from outside (cameras.json, EasyMocap, COLMAP, Kinect calibrations), so that
    fx = 0 cannot divide by zero in a reconstruction and fx < 0 cannot mirror it silently.
    """
    K, name = camera.K, camera.name
    if not all(isinstance(v, (int, np.integer)) and 1 <= v <= MAX_IMAGE_SIDE for v in (camera.width, camera.height)):
        raise InputError(f"camera {name}: image size {camera.width!r}x{camera.height!r} must be whole pixel counts "
                         f"1-{MAX_IMAGE_SIDE}")
    if not (K[0, 0] > 0 and K[1, 1] > 0):
        raise InputError(f"camera {name}: focal lengths fx={K[0, 0]:g}, fy={K[1, 1]:g} must be > 0 (pixels)")
    cx, cy = K[0, 2], K[1, 2]
    if not (0 <= cx <= camera.width and 0 <= cy <= camera.height):
        raise InputError(f"camera {name}: principal point ({cx:g}, {cy:g}) lies outside the "
                         f"{camera.width}x{camera.height} image; check K and the image size")
    if K[1, 0] != 0 or not np.allclose(K[2], (0.0, 0.0, 1.0)):
        raise InputError(f"camera {name}: K must be [[fx, s, cx], [0, fy, cy], [0, 0, 1]], got {K.tolist()}")
    if np.abs(camera.dist).max() > MAX_DISTORTION:
        raise InputError(f"camera {name}: distortion {camera.dist.tolist()} is implausibly large (|k| > "
                         f"{MAX_DISTORTION:g}); recalibrate")
    return camera


def save_cameras_json(path: str | os.PathLike, rig: CameraRig) -> None:
    """Write ``{"version": 1, "cameras": {"cam_00": {K, dist, R, t, width, height}, ...}}`` atomically."""
    write_json(path, rig.to_dict())


def load_cameras_json(path: str | os.PathLike) -> CameraRig:
    """Read a cameras.json file; any problem raises FileFormatError naming the file and the fix."""
    data = read_json(path, "cameras.json")
    if not isinstance(data, dict) or not isinstance(data.get("cameras"), dict):
        raise FileFormatError(f"{path}: cameras.json needs a top-level object with a 'cameras' mapping; "
                              "regenerate it with `bodystudio synth` or calibration")
    version = data.get("version", CAMERAS_JSON_VERSION)
    if version != CAMERAS_JSON_VERSION:
        raise FileFormatError(f"{path}: cameras.json version {version} is not supported (expected "
                              f"{CAMERAS_JSON_VERSION}); regenerate the file")
    if not data["cameras"]:
        raise FileFormatError(f"{path}: cameras.json lists no cameras; add at least one entry")
    try:
        return CameraRig.from_dict(data)
    except (InputError, AttributeError, TypeError) as exc:
        raise FileFormatError(f"{path}: {exc}; fix the entry or regenerate the file") from None


# --- studio and sensor layouts -----------------------------------------------------------------

#: Mild barrel distortion typical of the studio's machine-vision lenses.
STUDIO_DISTORTION = (-0.08, 0.02, 0.0004, -0.0003, 0.0)


def ring_rig(n: int = 10, width: int = 640, height: int = 480, radius: float = 3.0,
             heights: tuple[float, float] = (1.0, 2.2), target=(0.0, 0.9, 0.0), fx: float | None = None,
             distortion=STUDIO_DISTORTION, volume_height: float = 2.2) -> CameraRig:
    """A Rapid-Skin-like studio (Sec. 5): ``n`` cameras evenly on a ring, alternating between two heights.

    Camera ``cam_00`` stands in front of the subject (+z); the others follow counter-clockwise seen
    from above. The focal length, unless given, frames a ``volume_height`` tall capture volume
    (2 m diameter) in the image height with a small margin.
    """
    if n < 1:
        raise InputError(f"ring_rig needs at least one camera, got n={n}")
    target = np.asarray(target, dtype=np.float64)
    cams = {}
    for i in range(n):
        angle = 2.0 * np.pi * i / n
        h = heights[i % len(heights)]
        eye = np.array([radius * np.sin(angle), h, radius * np.cos(angle)])
        distance = np.linalg.norm(eye - target)
        f = fx if fx is not None else 0.5 * height * (distance - 0.8) / (0.5 * volume_height + 0.1)
        name = f"cam_{i:02d}"
        cams[name] = Camera.look_at(name, eye, target, fx=f, width=width, height=height, dist=distortion)
    return CameraRig(cams)


@dataclass(frozen=True, eq=False)
class RGBDSensor:
    """A Kinect-like RGB-D sensor: depth camera, colour camera and the rigid depth->colour transform.

    ``baseline_m`` is the projector-to-depth-camera distance along the depth camera's x axis
    (structured-light disparity, Khoshelham & Elberink 2012 Eq. 3); ``depth_range_m`` the valid range.
    """

    name: str
    version: str
    depth: Camera
    color: Camera
    depth_to_color: np.ndarray
    baseline_m: float = 0.075
    depth_range_m: tuple[float, float] = (0.5, 4.5)

    @property
    def projector(self) -> Camera:
        """The IR projector as a pinhole at ``baseline_m`` along the depth camera's +x axis."""
        d = self.depth
        t = d.t - np.array([self.baseline_m, 0.0, 0.0])
        return Camera(f"{d.name}_projector", d.K, np.zeros(5), d.R, t, d.width, d.height)

    def to_dict(self) -> dict:
        return {"name": self.name, "version": self.version, "depth": self.depth.to_dict(),
                "color": self.color.to_dict(), "depth_to_color": np.asarray(self.depth_to_color).tolist(),
                "baseline_m": self.baseline_m, "depth_range_m": list(self.depth_range_m)}

    @classmethod
    def from_dict(cls, d: dict) -> RGBDSensor:
        name = d["name"]
        return cls(name, d["version"], Camera.from_dict(f"{name}_depth", d["depth"]),
                   Camera.from_dict(f"{name}_color", d["color"]), np.asarray(d["depth_to_color"], float),
                   float(d["baseline_m"]), tuple(d["depth_range_m"]))


def _rgbd_sensor(name: str, version: str, eye, target, depth_size, depth_f, depth_c, color_size, color_f,
                 color_c, color_offset_m: float, depth_dist, color_dist, baseline_m: float) -> RGBDSensor:
    depth = Camera.look_at(f"{name}_depth", eye, target, fx=depth_f, width=depth_size[0], height=depth_size[1],
                           cx=depth_c[0], cy=depth_c[1], dist=depth_dist)
    # The colour camera sits beside the depth camera along the sensor's x axis, same orientation.
    T = np.eye(4)
    T[0, 3] = -color_offset_m
    color = Camera(f"{name}_color", np.array([[color_f, 0, color_c[0]], [0, color_f, color_c[1]], [0, 0, 1.0]]),
                   np.asarray(color_dist, float), depth.R, depth.t + T[:3, 3], color_size[0], color_size[1])
    return RGBDSensor(name, version, depth, color, T, baseline_m)


def kinect_v2(eye=(0.0, 1.0, 2.6), target=(0.0, 0.95, 0.0), name: str = "kinect") -> RGBDSensor:
    """A Kinect for Xbox One (v2): 512x424 depth (fx ~ 365 px), 1920x1080 colour (fx ~ 1060 px).

    Placed in front of the subject (who faces +z). v2 measures time of flight; bodystudio applies the
    same Khoshelham-style noise model with a 7.5 cm emitter baseline.
    """
    return _rgbd_sensor(name, "v2", eye, target, (512, 424), 365.0, (255.5, 211.5), (1920, 1080), 1060.0,
                        (959.5, 539.5), 0.052, (0.09, -0.27, 0.0, 0.0, 0.09), (0.02, -0.03, 0.0, 0.0, 0.0), 0.075)


def kinect_v1(depth_resolution: str = "640x480", eye=(0.0, 1.0, 2.6), target=(0.0, 0.95, 0.0),
              name: str = "kinect") -> RGBDSensor:
    """A Kinect for Xbox 360 (v1): structured light, depth fx ~ 580 px at 640x480, 7.5 cm baseline.

    ``depth_resolution`` "320x240" halves the depth focal length (the SDK's low-resolution mode);
    colour is 640x480 with fx ~ 525 px, 2.5 cm beside the depth camera.
    """
    sizes = {"640x480": 1.0, "320x240": 0.5}
    if depth_resolution not in sizes:
        raise InputError(f"kinect_v1 depth_resolution must be one of {', '.join(sizes)}, got {depth_resolution!r}")
    s = sizes[depth_resolution]
    w, h = int(640 * s), int(480 * s)
    return _rgbd_sensor(name, "v1", eye, target, (w, h), 580.0 * s, ((w - 1) / 2, (h - 1) / 2), (640, 480), 525.0,
                        (319.5, 239.5), 0.025, (0.0, 0.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 0.0, 0.0), 0.075)
