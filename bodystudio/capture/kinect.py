"""Kinect depth and body-tracker simulation.

Depth follows Khoshelham & Elberink (2012), "Accuracy and resolution of Kinect depth data": a
structured-light sensor measures disparity ``d = f b / Z`` between the IR camera and the projector
(baseline ``b`` ~ 7.5 cm along x), with random disparity error that gives the axial depth error
``sigma_Z = (Z^2 / (f b)) sigma_d = 1.425e-3 Z^2`` m (their Eq. 12 fit), and disparity quantised to
1/8 pixel (depth resolution ``Z^2 / (8 f b)``, their Eq. 13). The valid range is 0.5-4.5 m. Points
seen by the IR camera but not lit by the projector (the projector "shadow") return no depth, as do
grazing surfaces and random small holes; at depth discontinuities the sensor mixes foreground and
background into "flying pixels". The Kinect v2 (time of flight) is simulated with the same model and
its own focal length, as the depth input of Richter et al. and Robertini et al. needs no more.

The body tracker returns the Kinect SDK joint set (``bodystudio.body.kinect``) with Gaussian joint
noise, per-frame bone-length jitter (the SDK does not enforce constant bone lengths) and dropouts
(joints reported as "inferred" rather than "tracked").
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import cv2
import numpy as np
from scipy import ndimage

from bodystudio.body.kinect import kinect_joint_names, kinect_joints
from bodystudio.capture.render import RenderResult, render
from bodystudio.errors import FileFormatError, InputError
from bodystudio.fileio import atomic_write
from bodystudio.geometry.camera import RGBDSensor


@dataclass(frozen=True)
class KinectNoiseModel:
    """Parameters of the Kinect depth error model (defaults: Khoshelham & Elberink 2012)."""

    axial_sigma_coeff: float = 1.425e-3  # sigma_Z = coeff * Z^2 (m)
    disparity_step_px: float = 1.0 / 8.0  # disparity quantisation
    flying_pixel_prob: float = 0.5  # chance that a pixel at a depth discontinuity is a flying pixel
    discontinuity_m: float = 0.05  # depth jump within a 3x3 window that counts as a discontinuity
    flying_empty_spread_m: float = 0.3  # how far behind the foreground flying pixels reach over empty space
    hole_rate: float = 5e-4  # seeds per pixel of 3x3 holes
    dropout_rate: float = 2e-3  # isolated missing pixels
    grazing_angle_deg: float = 80.0  # surfaces seen more obliquely return no depth
    shadow_tolerance_m: float = 0.02  # depth agreement that counts as lit by the projector

    def disparity_sigma_px(self, focal_px: float, baseline_m: float) -> float:
        """Disparity noise that yields ``sigma_Z = coeff Z^2``: ``sigma_d = coeff f b`` (Khoshelham Eq. 12)."""
        return self.axial_sigma_coeff * focal_px * baseline_m

    def axial_sigma_m(self, depth_m):
        """Axial random error ``sigma_Z = 1.425e-3 Z^2`` (Khoshelham & Elberink 2012, Eq. 12 fit)."""
        return self.axial_sigma_coeff * np.asarray(depth_m, dtype=np.float64) ** 2

    def depth_resolution_m(self, depth_m, focal_px: float, baseline_m: float):
        """Depth step of one disparity quantum, ``Z^2 step / (f b)`` (Khoshelham & Elberink 2012, Eq. 13)."""
        return np.asarray(depth_m, dtype=np.float64) ** 2 * self.disparity_step_px / (focal_px * baseline_m)


KINECT_NOISE = KinectNoiseModel()


def projector_shadow_mask(V: np.ndarray, F: np.ndarray, sensor: RGBDSensor,
                          result: RenderResult | None = None, tolerance_m: float = 0.02) -> np.ndarray:
    """Depth pixels (H, W) that the IR camera sees but the projector does not light (no depth there).

    The scene is rendered from the projector (``baseline_m`` along the depth camera's x axis); a
    surface point is lit when some projector pixel in the 3x3 window around its projection sees a
    surface within ``tolerance_m`` of the point's projector depth.
    """
    result = render(V, F, sensor.depth) if result is None else result
    projector = sensor.projector
    proj_depth = render(V, F, projector).depth.astype(np.float64)
    P, rc = result.surface_points(np.asarray(V, np.float64), np.asarray(F, np.int64))
    uv, z = projector.project_with_depth(P)
    cols = np.round(uv[:, 0]).astype(np.int64)
    rows = np.round(uv[:, 1]).astype(np.int64)
    lit = np.zeros(len(P), dtype=bool)
    H, W = projector.height, projector.width
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            r, c = rows + dr, cols + dc
            inside = (r >= 0) & (r < H) & (c >= 0) & (c < W)
            zp = np.zeros(len(P))
            zp[inside] = proj_depth[r[inside], c[inside]]
            lit |= inside & (zp > 0) & (np.abs(zp - z) < tolerance_m)
    shadow = np.zeros(result.mask.shape, dtype=bool)
    shadow[rc[~lit, 0], rc[~lit, 1]] = True
    return shadow


def grazing_mask(V: np.ndarray, F: np.ndarray, result: RenderResult, sensor: RGBDSensor,
                 max_angle_deg: float = 80.0) -> np.ndarray:
    """Depth pixels whose surface is seen at more than ``max_angle_deg`` from its normal (no IR return)."""
    V = np.asarray(V, np.float64)
    F = np.asarray(F, np.int64)
    rows, cols = np.nonzero(result.mask)
    tri = F[result.triangle_id[rows, cols]]
    n = np.cross(V[tri[:, 1]] - V[tri[:, 0]], V[tri[:, 2]] - V[tri[:, 0]])
    P, _ = result.surface_points(V, F)
    view = P - sensor.depth.center
    cos = np.abs(np.einsum("kd,kd->k", n, view)) / np.maximum(
        np.linalg.norm(n, axis=1) * np.linalg.norm(view, axis=1), 1e-20)
    out = np.zeros(result.mask.shape, dtype=bool)
    bad = cos < np.cos(np.radians(max_angle_deg))
    out[rows[bad], cols[bad]] = True
    return out


def flying_pixels(depth_m: np.ndarray, rng: np.random.Generator,
                  model: KinectNoiseModel = KINECT_NOISE) -> np.ndarray:
    """Depth (H, W) with flying pixels: at discontinuities, mixtures of foreground and background depth.

    Pixels whose 3x3 window spans a depth jump above ``discontinuity_m`` (empty counts as far) take,
    with probability ``flying_pixel_prob``, a depth uniformly between the window's nearest and
    farthest surface (``flying_empty_spread_m`` behind the nearest where the far side is empty).
    """
    depth = np.asarray(depth_m, dtype=np.float64)
    valid = depth > 0
    big = 1e6
    near = ndimage.minimum_filter(np.where(valid, depth, big), size=3, mode="nearest")
    far_valid = ndimage.maximum_filter(np.where(valid, depth, -big), size=3, mode="nearest")
    has_empty = ndimage.minimum_filter(valid.astype(np.uint8), size=3, mode="nearest") == 0
    far = np.where(has_empty, near + model.flying_empty_spread_m, np.maximum(far_valid, near))
    candidate = (near < big) & (far - near > model.discontinuity_m)
    flying = candidate & (rng.random(depth.shape) < model.flying_pixel_prob)
    out = depth.copy()
    u = rng.random(int(flying.sum()))
    out[flying] = near[flying] + u * (far[flying] - near[flying])
    return out


def quantized_disparity_depth(depth_m: np.ndarray, focal_px: float, baseline_m: float, rng: np.random.Generator | None,
                              model: KinectNoiseModel = KINECT_NOISE) -> np.ndarray:
    """Measured depth from noisy, 1/8-pixel quantised disparity ``d = f b / Z`` (Khoshelham Eqs. 3, 12, 13).

    Gaussian disparity noise ``sigma_d = coeff f b`` gives the axial error ``coeff Z^2``; zeros stay zero.
    """
    depth = np.asarray(depth_m, dtype=np.float64)
    valid = depth > 0
    fb = focal_px * baseline_m
    d = np.zeros_like(depth)
    d[valid] = fb / depth[valid]
    if rng is not None:
        d[valid] += rng.normal(0.0, model.disparity_sigma_px(focal_px, baseline_m), int(valid.sum()))
    step = model.disparity_step_px
    d_q = np.round(d / step) * step
    out = np.zeros_like(depth)
    ok = valid & (d_q > 0)
    out[ok] = fb / d_q[ok]
    return out


def random_holes(shape: tuple[int, int], rng: np.random.Generator,
                 model: KinectNoiseModel = KINECT_NOISE) -> np.ndarray:
    """Mask of missing pixels: 3x3 blobs around random seeds plus isolated dropouts."""
    seeds = (rng.random(shape) < model.hole_rate).astype(np.uint8)
    blobs = cv2.dilate(seeds, np.ones((3, 3), np.uint8)) > 0
    return blobs | (rng.random(shape) < model.dropout_rate)


def simulate_kinect_depth(V: np.ndarray, F: np.ndarray, sensor: RGBDSensor, rng: np.random.Generator,
                          noise: bool = True, model: KinectNoiseModel = KINECT_NOISE,
                          result: RenderResult | None = None) -> np.ndarray:
    """Kinect depth image (H, W) float32 in metres (0 = no data) of mesh ``(V, F)``.

    With ``noise=False`` the ideal camera-z depth inside the valid range is returned. Otherwise, in
    order: grazing-angle dropouts, projector shadow, flying pixels at discontinuities, Gaussian
    disparity noise with 1/8-pixel quantisation (axial sigma 1.425e-3 Z^2), the 0.5-4.5 m range, holes.
    """
    if not isinstance(sensor, RGBDSensor):
        raise InputError("simulate_kinect_depth needs an RGBDSensor (kinect_v1() / kinect_v2()), "
                         f"got {type(sensor).__name__}")
    result = render(V, F, sensor.depth) if result is None else result
    depth = result.depth.astype(np.float64)
    lo, hi = sensor.depth_range_m
    if not noise:
        return np.where((depth >= lo) & (depth <= hi), depth, 0.0).astype(np.float32)
    missing = grazing_mask(V, F, result, sensor, model.grazing_angle_deg)
    missing |= projector_shadow_mask(V, F, sensor, result, model.shadow_tolerance_m)
    depth = flying_pixels(depth, rng, model)
    depth[missing] = 0.0
    depth = quantized_disparity_depth(depth, sensor.depth.fx, sensor.baseline_m, rng, model)
    depth[(depth < lo) | (depth > hi)] = 0.0
    depth[random_holes(depth.shape, rng, model)] = 0.0
    return depth.astype(np.float32)


# --- 16-bit millimetre depth images ---------------------------------------------------------------

def depth_to_millimetres(depth_m: np.ndarray) -> np.ndarray:
    """Depth in metres (0 = missing) as the Kinect's 16-bit millimetre image (uint16, 0 = missing)."""
    depth = np.asarray(depth_m, dtype=np.float64)
    mm = np.round(np.nan_to_num(depth, nan=0.0) * 1000.0)
    return np.clip(mm, 0, 65535).astype(np.uint16)


def millimetres_to_depth(depth_mm: np.ndarray) -> np.ndarray:
    """16-bit millimetre depth image as float32 metres (0 stays 0 = missing)."""
    return np.asarray(depth_mm, dtype=np.float32) / np.float32(1000.0)


def write_depth_png(path: str | os.PathLike, depth_m: np.ndarray) -> None:
    """Write depth (metres) as a 16-bit millimetre PNG, atomically."""
    ok, buf = cv2.imencode(".png", depth_to_millimetres(depth_m))
    if not ok:
        raise InputError(f"{path}: could not encode the depth image as PNG")
    with atomic_write(path, "wb") as f:
        f.write(buf.tobytes())


def read_depth_png(path: str | os.PathLike) -> np.ndarray:
    """Read a 16-bit millimetre depth PNG as float32 metres; a wrong file raises FileFormatError."""
    data = np.fromfile(str(path), dtype=np.uint8) if os.path.exists(path) else None
    if data is None:
        raise FileFormatError(f"{path}: depth image not found")
    from bodystudio.fileio import decode_image

    img = decode_image(data.tobytes(), path, cv2.IMREAD_UNCHANGED)
    if img.dtype != np.uint16 or img.ndim != 2:
        raise FileFormatError(f"{path}: not a 16-bit single-channel millimetre depth PNG; re-export the depth")
    return millimetres_to_depth(img)


# --- body tracker ---------------------------------------------------------------------------------

#: Kinect SDK joint hierarchies (child -> parent), used to jitter bone lengths along the chain.
KINECT_PARENTS = {
    "v1": {"Spine": "HipCenter", "ShoulderCenter": "Spine", "Head": "ShoulderCenter",
           "ShoulderLeft": "ShoulderCenter", "ElbowLeft": "ShoulderLeft", "WristLeft": "ElbowLeft",
           "HandLeft": "WristLeft", "ShoulderRight": "ShoulderCenter", "ElbowRight": "ShoulderRight",
           "WristRight": "ElbowRight", "HandRight": "WristRight", "HipLeft": "HipCenter", "KneeLeft": "HipLeft",
           "AnkleLeft": "KneeLeft", "FootLeft": "AnkleLeft", "HipRight": "HipCenter", "KneeRight": "HipRight",
           "AnkleRight": "KneeRight", "FootRight": "AnkleRight"},
    "v2": {"SpineMid": "SpineBase", "SpineShoulder": "SpineMid", "Neck": "SpineShoulder", "Head": "Neck",
           "ShoulderLeft": "SpineShoulder", "ElbowLeft": "ShoulderLeft", "WristLeft": "ElbowLeft",
           "HandLeft": "WristLeft", "HandTipLeft": "HandLeft", "ThumbLeft": "WristLeft",
           "ShoulderRight": "SpineShoulder", "ElbowRight": "ShoulderRight", "WristRight": "ElbowRight",
           "HandRight": "WristRight", "HandTipRight": "HandRight", "ThumbRight": "WristRight",
           "HipLeft": "SpineBase", "KneeLeft": "HipLeft", "AnkleLeft": "KneeLeft", "FootLeft": "AnkleLeft",
           "HipRight": "SpineBase", "KneeRight": "HipRight", "AnkleRight": "KneeRight", "FootRight": "AnkleRight"},
}


def kinect_parent_indices(version: str) -> np.ndarray:
    """Parent joint index (J,) of each Kinect joint in ``kinect_joint_names(version)`` order; -1 for the root."""
    names = kinect_joint_names(version)
    parents = KINECT_PARENTS[version]
    return np.array([names.index(parents[n]) if n in parents else -1 for n in names])


def _topological_order(parents: np.ndarray) -> list[int]:
    order, placed = [], set()
    while len(order) < len(parents):
        for j, p in enumerate(parents):
            if j not in placed and (p < 0 or p in placed):
                order.append(j)
                placed.add(j)
    return order


def simulate_tracker_joints(heads: np.ndarray, tails: np.ndarray, skeleton, version: str,
                            rng: np.random.Generator, noise_m: float = 0.01, bone_length_jitter: float = 0.03,
                            dropout: float = 0.0, inferred_noise_factor: float = 3.0) -> tuple[np.ndarray, np.ndarray]:
    """One frame of Kinect SDK body tracking: joints (J, 3) and the tracked mask (J,).

    Ground-truth joints come from the posed bones (``kinect_joints``). Each Kinect bone is scaled by
    ``1 + N(0, bone_length_jitter)`` drawn afresh every frame, applied down the SDK hierarchy; every
    joint then gets isotropic Gaussian noise of ``noise_m`` per axis. With probability ``dropout`` a
    joint is not tracked: it is still reported ("inferred"), with ``inferred_noise_factor`` times the noise.
    """
    if noise_m < 0 or bone_length_jitter < 0 or not 0 <= dropout <= 1:
        raise InputError("tracker noise_m and bone_length_jitter must be >= 0 and dropout in [0, 1]")
    truth = kinect_joints(skeleton, heads, tails, version)
    parents = kinect_parent_indices(version)
    scale = 1.0 + rng.normal(0.0, bone_length_jitter, len(parents))
    joints = truth.copy()
    for j in _topological_order(parents):
        p = parents[j]
        if p >= 0:
            joints[j] = joints[p] + scale[j] * (truth[j] - truth[p])
    tracked = rng.random(len(parents)) >= dropout
    sigma = np.where(tracked, noise_m, noise_m * inferred_noise_factor)
    joints += rng.normal(0.0, 1.0, joints.shape) * sigma[:, None]
    return joints, tracked
