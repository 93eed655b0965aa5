"""Shape and pose of the actor in a monocular video, §4 of Garment Replacement in Monocular Video.

* Camera (§4.1): the paper lets the user set the camera's distance, tilt and aperture. We assume a
  static pinhole camera with the principal point at the image centre, square pixels, no distortion and
  no roll, looking horizontally from 1 m above the floor; its focal length is ``focal_px`` (default:
  a 40 deg vertical field of view, :data:`DEFAULT_VFOV_DEG`). The actor's distance, tilt and position
  relative to it are the global part of the body pose, solved with the body; the user-given stature
  fixes the scale. The effect of a wrong focal length is measured in docs/garment.md.
* Shape (§4.3, Eq. 1-3): Nelder-Mead over the macro parameters, then over the local modifiers, on
  several reference frames, alternating with the pose of those frames. The silhouette term ``E_s`` of
  Eq. 2 is used in its distance-transform form (smooth for the solvers; the XOR/IoU is reported), the
  height term ``E_h`` of Eq. 3 as written, plus the user-given stature.
* Pose (§4.4, Eq. 4-6): per frame, in order, warm-started from the previous frame: the silhouette
  term, the temporal term of Eq. 5 (in a smooth form, :func:`temporal_residuals`), the interpenetration
  term of Eq. 6 (penetration depth into spheres inscribed in the torso and legs) and optional soft
  user constraints (2D joint positions at keyframes).
"""

from __future__ import annotations

import json
import logging
import os
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import scipy.optimize
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from bodystudio.errors import FileFormatError, InputError

log = logging.getLogger(__name__)

DEFAULT_VFOV_DEG = 40.0
CAMERA_HEIGHT_M = 1.0
#: The bone whose rotation carries the actor's global orientation (with ``Pose.translation``).
GLOBAL_BONE = "Root"
#: Bones whose rotations the pose solve estimates (the others keep the standing prior).
FIT_BONES = ("spine_02", "thigh_l", "thigh_r", "calf_l", "calf_r", "upperarm_l", "upperarm_r",
             "lowerarm_l", "lowerarm_r")
#: Macro parameters of the first Nelder-Mead stage (§4.3: "height, weight, gender, and tone").
MACRO_PARAMETERS = ("gender", "muscle", "weight", "height", "proportions")
#: Local modifiers of the second stage (left and right share one value, §4.2).
LOCAL_PARAMETERS = ("upperarm-fat-decr-incr", "upperarm-muscle-decr-incr", "lowerarm-fat-decr-incr",
                    "upperleg-fat-decr-incr", "upperleg-muscle-decr-incr", "lowerleg-fat-decr-incr",
                    "torso-scale-depth-decr-incr", "torso-scale-horiz-decr-incr", "hip-scale-horiz-decr-incr",
                    "stomach-pregnant-decr-incr", "buttocks-volume-decr-incr", "neck-scale-horiz-decr-incr")
#: Eq. 1's weight of the height term (the paper's alpha = 30 on pixel counts; ours on a per-pixel mean).
ALPHA_HEIGHT = 0.3
#: Weight of the user-given stature, per cm of difference (our addition: the stature is an input).
STATURE_WEIGHT = 2.0
#: Shape prior (our addition to Eq. 1): ``SHAPE_PRIOR_WEIGHT * sum((v / LOCAL_PRIOR_SD)^2)`` over the local
#: modifiers, in Eq. 1's units (squared px per silhouette sample). A modifier the silhouettes cannot see (the
#: stomach or torso depth of a body facing the camera) otherwise drifts free: subject 37 (arm_flex) was fitted
#: with ``stomach-pregnant`` at its bound 1.0 for an energy gain of 0.001, a belly whose normals are 30-40 deg
#: off and a dominant light 19.7 deg off (docs/garment.md).
SHAPE_PRIOR_WEIGHT = 0.005
LOCAL_PRIOR_SD = 0.3
#: Eq. 4's weights (the paper's beta = 2.5, gamma = 500 on pixel sums; ours on per-pixel means).
BETA_TEMPORAL = 2.5
GAMMA_INTERPENETRATION = 4.0
#: Eq. 5's delta (1/rad).
DELTA_TEMPORAL = 4.0
KEYFRAME_WEIGHT = 0.5
#: Pose prior (our addition, the monocular ambiguity of §4.4 that the paper leaves to the user): ridge
#: towards the standing pose per rad, and anatomical limits (hip extension, hinge knees) per rad beyond them.
PRIOR_RIDGE = 0.4
PRIOR_SPINE = 2.0
PRIOR_UPRIGHT = 4.0
PRIOR_LIMITS = 10.0
HIP_EXTENSION_LIMIT = 0.1
KNEE_HYPEREXTENSION_LIMIT = 0.05
SILHOUETTE_SAMPLES = 500
#: L1 penalty on the clip's Eq. 7 lights (``solve_lights``' ``sparsity``, squared pixel units per row per unit
#: light power): 3e-5 / 1e-4 / 3e-4 / 1e-3 measured on hidden subjects in docs/garment.md.
LIGHT_SPARSITY = 1e-4


# --- camera (§4.1) -----------------------------------------------------------------------------------

def focal_from_vfov(height_px: int, vfov_deg: float = DEFAULT_VFOV_DEG) -> float:
    """Focal length in pixels of a vertical field of view."""
    return 0.5 * height_px / np.tan(np.radians(vfov_deg) / 2)


def camera_hypothesis(width: int, height: int, focal_px: float | None = None):
    """The assumed camera of §4.1: principal point at the centre, ``focal_px``, 1 m high, looking along -z."""
    from bodystudio.geometry.camera import Camera

    f = focal_from_vfov(height) if focal_px is None else float(focal_px)
    if not (0.2 * height <= f <= 20 * max(width, height)):
        raise InputError(f"--focal-px {f:g}: implausible for a {width}x{height} video; use a value in "
                         f"[{0.2 * height:g}, {20 * max(width, height):g}] or leave it out")
    eye = np.array([0.0, CAMERA_HEIGHT_M, 0.0])
    return Camera.look_at("cam_00", eye, eye + [0.0, 0.0, -1.0], fx=f, width=width, height=height)


# --- fast posing --------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class PoseSpace:
    """The pose parameters of §4.4 for one body: ``x = [global rotvec, translation, FIT_BONES rotvecs]``.

    ``base`` (B, 3) is the standing prior the other bones keep. Skinning uses each vertex's four largest
    weights (renormalised), which is what makes a finite-difference Jacobian affordable.
    """

    body: object
    base: np.ndarray
    bone_ids: np.ndarray
    skin_idx: np.ndarray
    skin_w: np.ndarray
    parent_to_child: np.ndarray  # (B, 4, 4) A_parent^-1 A_j (the root: A_root)
    rest_inverse: np.ndarray  # (B, 4, 4) A_j^-1
    sample_ids: np.ndarray  # vertices the silhouette term projects

    @property
    def n_params(self) -> int:
        return 6 + 3 * len(self.bone_ids)

    def pose(self, x: np.ndarray):
        from bodystudio.body.pose import Pose

        rot = self.base.copy()
        rot[self.body.skeleton.index(GLOBAL_BONE)] = x[:3]
        rot[self.bone_ids] = np.asarray(x[6:]).reshape(-1, 3)
        return Pose(rot, np.asarray(x[3:6], dtype=np.float64))

    def x_from_pose(self, pose) -> np.ndarray:
        rot = np.asarray(pose.rotations)
        return np.concatenate([rot[self.body.skeleton.index(GLOBAL_BONE)], pose.translation,
                               rot[self.bone_ids].ravel()])

    def transforms(self, x: np.ndarray) -> np.ndarray:
        """Skinning transforms ``S_j`` (B, 4, 4), as :func:`bodystudio.body.skinning_transforms` (test)."""
        pose = self.pose(x)
        R = np.tile(np.eye(4), (len(self.base), 1, 1))
        R[:, :3, :3] = Rotation.from_rotvec(pose.rotations).as_matrix()
        local = self.parent_to_child @ R
        M = np.empty_like(local)
        for j, p in enumerate(self.body.skeleton.parents):
            if p < 0:
                M[j] = local[j]
                M[j, :3, 3] += pose.translation
            else:
                M[j] = M[p] @ local[j]
        return M @ self.rest_inverse

    def vertices(self, x: np.ndarray, ids: np.ndarray | None = None, T: np.ndarray | None = None) -> np.ndarray:
        """Posed vertices (n, 3) (or those of ``ids``) with the four-weight skinning."""
        T = self.transforms(x) if T is None else T
        ids = slice(None) if ids is None else ids
        V = self.body.vertices[ids]
        M = np.einsum("nk,nkij->nij", self.skin_w[ids], T[self.skin_idx[ids]][:, :, :3])
        return np.einsum("nij,nj->ni", M[:, :, :3], V) + M[:, :, 3]

    def joints(self, x: np.ndarray) -> np.ndarray:
        """Posed bone heads (B, 3)."""
        from bodystudio.body.skinning import posed_joints

        return posed_joints(self.body.skeleton, self.pose(x))[0]


def standing_prior(body) -> np.ndarray:
    """(B, 3) local rotations of a person standing with the arms hanging (the start of §4.3's user pose)."""
    from bodystudio.capture.motion import arm_elevation, world_to_local_rotvecs

    world = np.zeros((body.skeleton.n_bones, 3))
    for side in ("l", "r"):
        world[body.skeleton.index(f"upperarm_{side}")] = arm_elevation(body.skeleton, side, -72.0).as_rotvec()
    return world_to_local_rotvecs(body.skeleton, world)


def pose_space(body, base: np.ndarray | None = None, max_samples: int = 900) -> PoseSpace:
    """The :class:`PoseSpace` of ``body`` (four largest skin weights per vertex; about ``max_samples``
    evenly spaced vertices carry the silhouette term)."""
    W = body.weights
    idx = np.argsort(-W, axis=1)[:, :4]
    w = np.take_along_axis(W, idx, axis=1)
    w /= w.sum(1, keepdims=True)
    bones = np.array([body.skeleton.index(b) for b in FIT_BONES])
    A = body.skeleton.rest_frames
    rel = np.stack([A[j] if p < 0 else np.linalg.solve(A[p], A[j]) for j, p in enumerate(body.skeleton.parents)])
    step = max(1, len(body.vertices) // max_samples)
    return PoseSpace(body, standing_prior(body) if base is None else base, bones, idx, w, rel, np.linalg.inv(A),
                     np.arange(0, len(body.vertices), step))


# --- silhouette terms (Eq. 2, 3) ---------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class SilhouetteTarget:
    """One frame's person matte prepared for Eq. 2: the distance (px) outside it, samples of its outline."""

    mask: np.ndarray
    outside_px: np.ndarray
    samples: np.ndarray
    y_min: float
    y_max: float


def silhouette_target(mask: np.ndarray, n_samples: int = SILHOUETTE_SAMPLES, seed: int = 0) -> SilhouetteTarget:
    """Distance transform of the background and ``n_samples`` points of the matte's outline (+ interior)."""
    m = np.asarray(mask, bool)
    outside = cv2.distanceTransform((~m).astype(np.uint8), cv2.DIST_L2, 5).astype(np.float32)
    contours, _ = cv2.findContours(m.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    outline = np.concatenate([c.reshape(-1, 2) for c in contours]).astype(np.float64) if contours else np.zeros((0, 2))
    rng = np.random.default_rng(seed)
    if len(outline) > n_samples:
        outline = outline[np.sort(rng.choice(len(outline), n_samples, replace=False))]
    rows = np.flatnonzero(m.any(1))
    return SilhouetteTarget(m, outside, outline, float(rows.min()), float(rows.max()))


def _bilinear(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    h, w = image.shape
    x = np.clip(uv[:, 0], 0, w - 1)
    y = np.clip(uv[:, 1], 0, h - 1)
    beyond = np.hypot(uv[:, 0] - x, uv[:, 1] - y)
    s = cv2.remap(image, x.astype(np.float32)[None], y.astype(np.float32)[None], cv2.INTER_LINEAR)[0]
    return s.astype(np.float64) + beyond


def silhouette_residuals(uv: np.ndarray, target: SilhouetteTarget) -> np.ndarray:
    """E_s of Eq. 2 in distance form: each projected vertex's distance (px) outside the matte, and each
    outline sample's distance to the nearest projected vertex; scaled so the squares sum to a mean."""
    outside = _bilinear(target.outside_px, uv) / np.sqrt(len(uv))
    if len(target.samples):
        d, _ = cKDTree(uv).query(target.samples)
        cover = d / np.sqrt(len(target.samples))
    else:
        cover = np.zeros(0)
    return np.concatenate([outside, cover])


def height_residuals(uv: np.ndarray, target: SilhouetteTarget) -> np.ndarray:
    """E_h of Eq. 3: the matte's top and bottom rows minus the projected body's (px)."""
    return np.array([uv[:, 1].min() - target.y_min, uv[:, 1].max() - target.y_max])


def model_silhouette(V: np.ndarray, F: np.ndarray, camera) -> np.ndarray:
    """(H, W) bool: the projected body (the P(B) of Eq. 2), capture's z-buffer rasteriser."""
    from bodystudio.capture.render import render

    return render(V, F, camera).mask.astype(bool)


def silhouette_iou(V: np.ndarray, F: np.ndarray, camera, mask: np.ndarray) -> float:
    """Intersection over union of the projected body and the person matte (1 - normalised Eq. 2)."""
    s = model_silhouette(V, F, camera)
    union = np.count_nonzero(s | mask)
    return float(np.count_nonzero(s & mask) / union) if union else 0.0


# --- pose terms (Eq. 4-6) ----------------------------------------------------------------------------

def temporal_residuals(x: np.ndarray, x_neighbour: np.ndarray, beta: float = BETA_TEMPORAL,
                       delta: float = DELTA_TEMPORAL) -> np.ndarray:
    """E_t of Eq. 5 on the joint angles (translation excluded) in a smooth form.

    ``2 sqrt(beta) sinh(delta d / 2)`` squares to ``2 beta (cosh(delta d) - 1)``: exponential in large
    jumps as the paper's ``exp(delta |d|) - 1``, but quadratic rather than kinked at zero (least squares).
    """
    d = np.concatenate([x[:3] - x_neighbour[:3], x[6:] - x_neighbour[6:]])
    return 2.0 * np.sqrt(beta) * np.sinh(0.5 * delta * d)


@dataclass(frozen=True, eq=False)
class PenetrationSpheres:
    """Spheres inscribed in the torso and legs (rest pose) and the limb vertices tested against them."""

    centers: np.ndarray  # (K, 3) rest
    radii: np.ndarray  # (K,)
    bones: np.ndarray  # (K,) bone carrying each sphere
    group: np.ndarray  # (K,) 0 torso, 1 left leg, 2 right leg
    probe_ids: np.ndarray  # (P,) vertex ids
    probe_excluded: np.ndarray  # (P,) the sphere group a probe may not be tested against (its own leg)


def penetration_spheres(body, per_segment: int = 4) -> PenetrationSpheres:
    """The proxy geometry of Eq. 6: spheres along the spine and each leg, radius the distance to the
    nearest vertex of that segment (inscribed); probes are the forearm/hand and calf vertices."""
    sk = body.skeleton
    dominant = np.argmax(body.weights, axis=1)
    segments = [("pelvis", "neck_01", ("pelvis", "spine_01", "spine_02", "spine_03"), 0),
                ("thigh_l", "calf_l", ("thigh_l",), 1), ("calf_l", "foot_l", ("calf_l",), 1),
                ("thigh_r", "calf_r", ("thigh_r",), 2), ("calf_r", "foot_r", ("calf_r",), 2)]
    centers, radii, bones, group = [], [], [], []
    for a, b, owners, g in segments:
        ha, hb = sk.heads[sk.index(a)], sk.heads[sk.index(b)]
        own = np.isin(dominant, [sk.index(o) for o in owners])
        tree = cKDTree(body.vertices[own])
        for s in (np.arange(per_segment) + 0.5) / per_segment:
            c = ha + s * (hb - ha)
            r, _ = tree.query(c)
            centers.append(c)
            radii.append(0.9 * r)
            owner_ids = np.array([sk.index(o) for o in owners])
            nearest = owner_ids[np.argmin([np.linalg.norm(c - sk.heads[i]) for i in owner_ids])]
            bones.append(nearest if g == 0 else sk.index(a))
            group.append(g)
    probe_bones = {"lowerarm_l": 0, "lowerarm_r": 0, "hand_l": 0, "hand_r": 0, "calf_l": 1, "calf_r": 2}
    ids, excl = [], []
    rng = np.random.default_rng(0)
    for name, g in probe_bones.items():
        vid = np.flatnonzero(dominant == sk.index(name))
        vid = vid[np.sort(rng.choice(len(vid), min(40, len(vid)), replace=False))] if len(vid) else vid
        ids.append(vid)
        excl.append(np.full(len(vid), g if g else -1))
    return PenetrationSpheres(np.array(centers), np.array(radii), np.array(bones), np.array(group),
                              np.concatenate(ids), np.concatenate(excl))


def interpenetration_residuals(V: np.ndarray, T: np.ndarray, spheres: PenetrationSpheres) -> np.ndarray:
    """E_i of Eq. 6: each probe vertex's penetration depth (m) into the spheres it may not enter.

    Arms are tested against the torso and the legs, each calf against the other leg (not its own)."""
    C = np.einsum("kij,kj->ki", T[spheres.bones][:, :3, :3], spheres.centers) + T[spheres.bones][:, :3, 3]
    P = V if len(V) == len(spheres.probe_ids) else V[spheres.probe_ids]
    depth = spheres.radii[None] - np.linalg.norm(P[:, None] - C[None], axis=2)
    depth[spheres.probe_excluded[:, None] == spheres.group[None]] = 0.0
    return np.clip(depth, 0.0, None).max(1)


def pose_prior_residuals(x: np.ndarray, space: PoseSpace) -> np.ndarray:
    """Soft anatomical prior that resolves the front/back ambiguity of a monocular silhouette (knees that
    bend backwards look like knees raised forwards): hips extend at most :data:`HIP_EXTENSION_LIMIT`,
    knees are hinges that do not over-extend, the body stays upright, and every fitted joint is pulled
    weakly towards the standing pose. Angles are about the rest-pose world axes (x: left-right)."""
    sk = space.body.skeleton
    local = np.asarray(x[6:]).reshape(-1, 3)
    world = np.einsum("bij,bj->bi", sk.rest_rotations[space.bone_ids], local)
    names = [sk.bone_names[i] for i in space.bone_ids]
    limits = []
    for side in ("l", "r"):
        thigh = world[names.index(f"thigh_{side}")]
        calf = world[names.index(f"calf_{side}")]
        limits += [max(0.0, thigh[0] - HIP_EXTENSION_LIMIT), max(0.0, -calf[0] - KNEE_HYPEREXTENSION_LIMIT),
                   calf[1], calf[2]]
    ridge = local - space.base[space.bone_ids]
    weight = np.where(np.array(names) == "spine_02", PRIOR_SPINE, PRIOR_RIDGE)[:, None]
    return np.concatenate([PRIOR_LIMITS * np.array(limits), (weight * ridge).ravel(), PRIOR_UPRIGHT * x[[0, 2]]])


@dataclass(frozen=True)
class KeyframeConstraints:
    """Soft user constraints of §4.4: frame id -> {bone name: (u, v) pixel of the bone's head}."""

    points: dict

    @classmethod
    def load(cls, path: str | os.PathLike, bone_names, size: tuple[int, int] | None = None,
             frame_ids=None) -> KeyframeConstraints:
        """Read ``{"frames": {"12": {"hand_l": [u, v], ...}, ...}}``; refuses unknown bones or bad values.

        ``size`` (width, height): a point outside the image is refused. ``frame_ids`` (the fitted frames):
        constraints on other frames are left out with a warning, and refused when none is left.
        """
        path = Path(path)
        try:
            doc = json.loads(path.read_text())
            frames = doc["frames"]
            points = {}
            for fid, joints in frames.items():
                entry = {}
                for name, uv in joints.items():
                    if name not in bone_names:
                        raise FileFormatError(f"{path}: unknown joint {name!r} at frame {fid}; use bone names "
                                              f"such as hand_l, calf_r")
                    uv = np.asarray(uv, dtype=np.float64)
                    if uv.shape != (2,) or not np.all(np.isfinite(uv)):
                        raise FileFormatError(f"{path}: joint {name} at frame {fid} must be [u, v] pixels")
                    if size is not None and not (0 <= uv[0] <= size[0] and 0 <= uv[1] <= size[1]):
                        raise FileFormatError(f"{path}: joint {name} at frame {fid}: [{uv[0]:g}, {uv[1]:g}] is "
                                              f"outside the {size[0]}x{size[1]} image; give pixels inside it")
                    entry[name] = uv
                points[int(fid)] = entry
        except FileFormatError:
            raise
        except (OSError, ValueError, KeyError, TypeError, AttributeError) as exc:
            raise FileFormatError(f"{path}: unreadable keyframe constraints ({type(exc).__name__}); write "
                                  f'{{"frames": {{"FRAME": {{"BONE": [u, v]}}}}}}') from None
        if frame_ids is not None:
            fitted = {int(f) for f in frame_ids}
            outside = sorted(set(points) - fitted)
            if points and len(outside) == len(points):
                raise FileFormatError(f"{path}: no keyframe is on a fitted frame (keyframes on {outside[:5]}, fitted "
                                      f"{min(fitted)}..{max(fitted)}); fix the frame numbers or --frames")
            if outside:
                log.warning("%s: keyframes on frames %s are outside the fitted frames; left out", path, outside)
                points = {f: v for f, v in points.items() if f in fitted}
        return cls(points)


def keyframe_residuals(joints: np.ndarray, camera, constraints: dict, bone_names) -> np.ndarray:
    """Soft user constraints (§4.4): projected bone heads minus the user's 2D positions (px)."""
    if not constraints:
        return np.zeros(0)
    ids = [bone_names.index(n) for n in constraints]
    uv = camera.project(joints[ids])
    return (uv - np.array(list(constraints.values()))).ravel()


@dataclass
class PoseProblem:
    """Everything Eq. 4 needs for one frame."""

    space: PoseSpace
    camera: object
    target: SilhouetteTarget
    spheres: PenetrationSpheres
    neighbour: np.ndarray | None = None
    constraints: dict | None = None
    with_height: bool = False


def finite_projection(camera, V: np.ndarray, image_shape: tuple[int, int]) -> np.ndarray:
    """Pixels of ``V`` where a vertex behind (or within 5 cm of) the camera, whose projection is undefined,
    lands far outside the image (four image diagonals beyond the centre), so a trial step of the optimiser
    that carries the body through the camera costs a large, finite residual instead of NaN."""
    uv, z = camera.project_with_depth(V)
    bad = (z < 0.05) | ~np.isfinite(uv).all(1)
    if bad.any():
        h, w = image_shape
        uv[bad] = (-3.0 * w, -3.0 * h)
    return uv


def pose_residuals(x: np.ndarray, p: PoseProblem) -> np.ndarray:
    """Eq. 4: silhouette + beta temporal + gamma interpenetration (+ soft user constraints), stacked, plus
    our anatomical prior (:func:`pose_prior_residuals`)."""
    T = p.space.transforms(x)
    V = p.space.vertices(x, p.space.sample_ids, T)
    uv = finite_projection(p.camera, V, p.target.outside_px.shape)
    parts = [silhouette_residuals(uv, p.target)]
    if p.with_height:
        parts.append(np.sqrt(ALPHA_HEIGHT) * height_residuals(uv, p.target) / 10.0)
    if p.neighbour is not None:
        parts.append(temporal_residuals(x, p.neighbour))
    parts.append(pose_prior_residuals(x, p.space))
    px_per_m = p.camera.fx / max(float(p.camera.world_to_camera(V.mean(0, keepdims=True))[0, 2]), 0.1)
    depth = interpenetration_residuals(p.space.vertices(x, p.spheres.probe_ids, T), T, p.spheres)
    parts.append(np.sqrt(GAMMA_INTERPENETRATION) * px_per_m * depth / np.sqrt(len(p.spheres.probe_ids)))
    if p.constraints:
        joints = p.space.joints(x)
        parts.append(np.sqrt(KEYFRAME_WEIGHT) * keyframe_residuals(joints, p.camera, p.constraints,
                                                                   list(p.space.body.skeleton.bone_names)))
    return np.concatenate(parts)


def fit_frame_pose(x0: np.ndarray, problem: PoseProblem, max_nfev: int = 6) -> np.ndarray:
    """Minimise Eq. 4 for one frame from ``x0`` (trust-region least squares, finite-difference Jacobian)."""
    scale = np.concatenate([np.full(3, 0.3), np.full(3, 0.1), np.full(len(x0) - 6, 0.3)])
    res = scipy.optimize.least_squares(pose_residuals, x0, args=(problem,), method="trf", x_scale=scale,
                                       diff_step=1e-3, max_nfev=max_nfev, loss="linear")
    return res.x


def initial_placement(space: PoseSpace, camera, target: SilhouetteTarget) -> np.ndarray:
    """Global pose that puts the standing body over the matte: depth from its image height, position
    from its top row and centre column, facing the camera (the paper's user-set reference pose)."""
    x = np.zeros(space.n_params)
    x[6:] = space.base[space.bone_ids].ravel()
    V = space.vertices(x)
    height_m = V[:, 1].max() - V[:, 1].min()
    height_px = max(target.y_max - target.y_min, 1.0)
    depth = camera.fx * height_m / height_px
    cols = np.flatnonzero(target.mask.any(0))
    u_c, v_top = 0.5 * (cols.min() + cols.max()), target.y_min
    cx, cy = camera.K[0, 2], camera.K[1, 2]
    x_world = (u_c - cx) / camera.fx * depth
    top_world = CAMERA_HEIGHT_M - (v_top - cy) / camera.fy * depth
    x[3:6] = [x_world, top_world - V[:, 1].max(), -depth]
    return x


def initial_placements(space: PoseSpace, camera, target: SilhouetteTarget) -> list[np.ndarray]:
    """Starts of the reference-frame pose (the user's click-and-drag pose of §4.3, automated): standing,
    and either knee raised forward (a silhouette cannot tell a raised knee from a leg bent backwards)."""
    x0 = initial_placement(space, camera, target)
    sk = space.body.skeleton
    names = [sk.bone_names[i] for i in space.bone_ids]
    out = [x0]
    for side in ("l", "r"):
        x = x0.copy()
        for bone, angle in ((f"thigh_{side}", -0.6), (f"calf_{side}", 1.0)):
            k = names.index(bone)
            R = sk.rest_rotations[space.bone_ids[k]]
            x[6 + 3 * k: 9 + 3 * k] = R.T @ np.array([angle, 0.0, 0.0])
        out.append(x)
    return out


# --- shape (§4.3, Eq. 1) -----------------------------------------------------------------------------

def body_stature(body) -> float:
    """Stature (m) of a body in its rest pose: top of the head to the soles."""
    return float(body.vertices[:, 1].max() - body.vertices[:, 1].min())


def _shape_body(values: np.ndarray, names, phenotype: dict, local: dict, template: str):
    from bodystudio.body import build_body
    from bodystudio.body.phenotype import Phenotype

    ph, loc = dict(phenotype), dict(local)
    for n, v in zip(names, values, strict=True):
        if n in MACRO_PARAMETERS or n in ph:  # a phenotype value (macro), else a local modifier
            ph[n] = float(np.clip(v, 0.0, 1.0))
        else:
            loc[n] = float(np.clip(v, -1.0, 1.0))
    return build_body(Phenotype.from_dict(ph), loc, resolution=template), ph, loc


def shape_energy(body, xs: list[np.ndarray], camera, targets: list[SilhouetteTarget], stature_m: float,
                 base: np.ndarray) -> float:
    """E_Shape of Eq. 1 over the reference frames: E_s + alpha E_h, plus the user stature term (per cm)."""
    space = pose_space(body, base)
    e = 0.0
    for x, t in zip(xs, targets, strict=True):
        uv = camera.project(space.vertices(x, space.sample_ids))
        e += float(np.sum(silhouette_residuals(uv, t) ** 2))
        e += ALPHA_HEIGHT * float(np.sum((height_residuals(uv, t) / 10.0) ** 2))
    e /= len(xs)
    return e + STATURE_WEIGHT * ((body_stature(body) - stature_m) * 100.0) ** 2


def shape_prior_energy(local: dict, weight: float | None = None, sd: float | None = None) -> float:
    """Our Gaussian prior on the local modifiers of Eq. 1's second stage: ``weight * sum((v / sd)^2)`` over
    :data:`LOCAL_PARAMETERS` (MakeHuman's neutral body at 0). Silhouettes of a body seen from the front do not
    constrain modifiers that act along the viewing ray; the prior keeps those near neutral while the
    silhouette terms move the ones they see (measured in docs/garment.md). ``weight``/``sd`` default to
    :data:`SHAPE_PRIOR_WEIGHT` / :data:`LOCAL_PRIOR_SD`."""
    weight = SHAPE_PRIOR_WEIGHT if weight is None else float(weight)
    sd = LOCAL_PRIOR_SD if sd is None else float(sd)
    v = np.array([float(local.get(k, 0.0)) for k in LOCAL_PARAMETERS])
    return float(weight * np.sum((v / sd) ** 2))


def nelder_mead_shape(names, start: np.ndarray, phenotype: dict, local: dict, xs, camera, targets, stature_m: float,
                      template: str, base: np.ndarray, max_evals: int) -> tuple[dict, dict]:
    """One Nelder-Mead stage of §4.3 over the parameters ``names`` (bounded by clipping): Eq. 1's
    :func:`shape_energy` plus :func:`shape_prior_energy` of the local modifiers."""
    def energy(v):
        body, _, loc = _shape_body(v, names, phenotype, local, template)
        return shape_energy(body, xs, camera, targets, stature_m, base) + shape_prior_energy(loc)

    simplex = [start] + [start + np.eye(len(start))[i] * (0.15 if names[i] in MACRO_PARAMETERS else 0.3)
                         for i in range(len(start))]
    res = scipy.optimize.minimize(energy, start, method="Nelder-Mead",
                                  options={"maxfev": max_evals, "initial_simplex": np.array(simplex),
                                           "xatol": 1e-3, "fatol": 1e-4})
    _, ph, loc = _shape_body(res.x, names, phenotype, local, template)
    log.info("shape stage %s: energy %.4f after %d evaluations", names[0], res.fun, res.nfev)
    return ph, loc


def _stature_matched_height(phenotype: dict, local: dict, stature_m: float, template: str) -> dict:
    """MakeHuman's height parameter giving ``stature_m`` for this shape (bisection; stature grows with it)."""
    from bodystudio.body import build_body
    from bodystudio.body.phenotype import Phenotype

    lo, hi = 0.0, 1.0
    for _ in range(14):
        mid = 0.5 * (lo + hi)
        s = body_stature(build_body(Phenotype.from_dict({**phenotype, "height": mid}), local, resolution=template))
        lo, hi = (mid, hi) if s < stature_m else (lo, mid)
    return {**phenotype, "height": 0.5 * (lo + hi)}


@dataclass
class ShapeFit:
    phenotype: dict
    local: dict
    body: object
    reference: np.ndarray  # indices of the reference frames
    xs: list


def estimate_shape(masks: np.ndarray, camera, stature_m: float, template: str = "2k", n_reference: int = 4,
                   rounds: int = 2, macro_evals: int = 80, local_evals: int = 100) -> ShapeFit:
    """Body shape of §4.3 (Eq. 1): Nelder-Mead over the macro parameters, then the local ones, over
    ``n_reference`` frames spread over the clip, alternating with those frames' poses (Eq. 4 without
    the temporal term)."""
    from bodystudio.body import build_body
    from bodystudio.body.phenotype import Phenotype

    n = len(masks)
    reference = np.unique(np.linspace(0, n - 1, min(n_reference, n)).round().astype(int))
    targets = [silhouette_target(masks[i]) for i in reference]
    phenotype = _stature_matched_height(Phenotype().to_dict(), {}, stature_m, template)
    local: dict = {}
    body = build_body(Phenotype.from_dict(phenotype), local, resolution=template)
    space = pose_space(body)
    base = space.base
    spheres = penetration_spheres(body)
    xs = []
    for t in targets:
        problem = PoseProblem(space, camera, t, spheres, with_height=True)
        starts = [fit_frame_pose(x, problem, max_nfev=12) for x in initial_placements(space, camera, t)]
        xs.append(min(starts, key=lambda x: float(np.sum(pose_residuals(x, problem) ** 2))))
    for _ in range(rounds):
        phenotype, local = nelder_mead_shape(MACRO_PARAMETERS, np.array([phenotype[k] for k in MACRO_PARAMETERS]),
                                             phenotype, local, xs, camera, targets, stature_m, template, base,
                                             macro_evals)
        phenotype, local = nelder_mead_shape(LOCAL_PARAMETERS, np.array([local.get(k, 0.0) for k in LOCAL_PARAMETERS]),
                                             phenotype, local, xs, camera, targets, stature_m, template, base,
                                             local_evals)
        body = build_body(Phenotype.from_dict(phenotype), local, resolution=template)
        space = pose_space(body, base)
        spheres = penetration_spheres(body)
        xs = [fit_frame_pose(x, PoseProblem(space, camera, t, spheres, with_height=True), max_nfev=8)
              for x, t in zip(xs, targets, strict=True)]
    return ShapeFit(phenotype, local, body, reference, xs)


def refine_fit_shape(shape: ShapeFit, poses: list, masks: np.ndarray, camera, stature_m: float, template: str,
                     allowance_m: float) -> ShapeFit:
    """Step 4b of the fit (ours): ``shape`` refined against every frame's silhouette with the frames' ``poses``
    held (:func:`bodystudio.garment.shape_refine.refine_shape_to_silhouettes`, clothing allowance
    ``allowance_m``); the reference frames and their poses are kept."""
    from bodystudio.body import build_body
    from bodystudio.body.phenotype import Phenotype
    from bodystudio.garment.shape_refine import refine_shape_to_silhouettes

    refined = refine_shape_to_silhouettes(shape.phenotype, shape.local, template, poses, masks, camera, stature_m,
                                          allowance_m=allowance_m)
    body = build_body(Phenotype.from_dict(refined.phenotype), refined.local, resolution=template)
    return ShapeFit(refined.phenotype, refined.local, body, shape.reference, shape.xs)


def refine_fit_poses(body, poses: list, masks: np.ndarray, camera, allowance_m: float) -> list:
    """Step 4c of the fit (ours): every frame's pose refined on the refined ``body`` with step 4b's rim-based
    silhouette term, the temporal term against both neighbours, Eq. 6 and the anatomical prior
    (:func:`bodystudio.garment.pose_refine.refine_poses_to_silhouettes`, clothing allowance ``allowance_m``)."""
    from bodystudio.garment.pose_refine import refine_poses_to_silhouettes

    return refine_poses_to_silhouettes(body, poses, masks, camera, allowance_m)[0]


def refine_fit_shape_and_poses(shape: ShapeFit, poses: list, masks: np.ndarray, camera, stature_m: float,
                               template: str, allowance_m: float, pose_refinement: bool = True,
                               timings: dict | None = None) -> tuple[ShapeFit, list]:
    """Steps 4b-4c: the shape refined with the tracked poses held (:func:`refine_fit_shape`); then, with
    ``pose_refinement``, the poses refined on that shape (:func:`refine_fit_poses`). Returns the shape and the
    poses; ``timings`` (when given) gets ``shape_refinement`` and ``pose_refinement`` in ms per frame. (Refining
    the shape once more with the new poses held was measured and not kept: garment_iou 37 / 21 / 3 0.956 / 0.936 /
    0.919 against 0.956 / 0.935 / 0.929 without it, docs/garment.md.)"""
    timings = {} if timings is None else timings
    t0 = time.perf_counter()
    shape = refine_fit_shape(shape, poses, masks, camera, stature_m, template, allowance_m)
    timings["shape_refinement"] = (time.perf_counter() - t0) * 1e3 / len(poses)
    if pose_refinement:
        t0 = time.perf_counter()
        poses = refine_fit_poses(shape.body, poses, masks, camera, allowance_m)
        timings["pose_refinement"] = (time.perf_counter() - t0) * 1e3 / len(poses)
    return shape, poses


# --- pose over the clip (§4.4) -----------------------------------------------------------------------

def track_poses(space: PoseSpace, camera, masks: np.ndarray, start: int, x_start: np.ndarray,
                constraints: dict | None = None, progress=None, frame_ids=None) -> np.ndarray:
    """Eq. 4 for every frame: forward from the reference frame ``start``, then backward (Φ_{t-1} exchanged
    for Φ_{t+1} in Eq. 5), each frame warm-started from its neighbour's pose."""
    n = len(masks)
    spheres = penetration_spheres(space.body)
    X = np.zeros((n, space.n_params))
    frame_ids = np.arange(n) if frame_ids is None else frame_ids
    constraints = constraints or {}

    def solve(i, neighbour, x0):
        problem = PoseProblem(space, camera, silhouette_target(masks[i]), spheres, neighbour,
                              constraints.get(int(frame_ids[i])))
        X[i] = fit_frame_pose(x0, problem)
        if progress is not None:
            progress()

    solve(start, None, x_start)
    for i in range(start + 1, n):
        solve(i, X[i - 1], X[i - 1])
    for i in range(start - 1, -1, -1):
        solve(i, X[i + 1], X[i + 1])
    return X


# --- appearance (§5) ---------------------------------------------------------------------------------

def mean_lighting(lights: list):
    """One :class:`Lighting` for the clip: every frame's lights, each at 1/n of its power (the average)."""
    from bodystudio.garment.lighting import Lighting

    n = len(lights)
    dirs = np.concatenate([lt.directions for lt in lights]) if n else np.zeros((0, 3))
    cols = np.concatenate([lt.colors for lt in lights]) / max(n, 1) if n else np.zeros((0, 3))
    amb = np.mean([lt.ambient for lt in lights], axis=0) if n else np.zeros(3)
    return Lighting(dirs, cols, amb)


def clip_lighting(images: list, masks: list, posed: list, F: np.ndarray, camera, albedo: np.ndarray,
                  samples_per_frame: int = 1500, erode_px: int = 3, sparsity: float = 0.0):
    """Eq. 7 with the rows of several frames stacked: one set of lights for a static scene.

    Each frame gives ``samples_per_frame`` body pixels (``surface_samples``) inside both the fitted body
    (eroded by ``erode_px``) and the person matte; pooling frames averages out the normal errors of any one
    frame's fitted pose (measured in docs/garment.md against per-frame lights). ``sparsity``: the L1
    penalty on the directional lights of ``solve_lights`` (:data:`LIGHT_SPARSITY` in the fit).
    """
    from bodystudio.garment.lighting import estimate_lighting, surface_samples

    rows = [surface_samples(img, V, F, camera, albedo, samples_per_frame, erode_px, seed=k, pixel_mask=m)
            for k, (img, V, m) in enumerate(zip(images, posed, masks, strict=True))]
    P, N, A, B = (np.concatenate([r[i] for r in rows]) for i in range(4))
    centre = np.mean([V.mean(0) for V in posed], axis=0)
    axis = camera.center - centre
    return estimate_lighting(P, N, A, B, axis / np.linalg.norm(axis), sparsity=sparsity)


def _albedo_ratio(observations: list, posed: list, F: np.ndarray, lighting, labels: np.ndarray | None,
                  n_out: int) -> tuple[np.ndarray, np.ndarray]:
    """``sum_t I S`` and ``sum_t S^2`` (§5.1's least-squares albedo given the lights) per vertex, or per
    group of ``labels`` (vertices labelled -1 left out) when given."""
    from bodystudio.garment.lighting import vertex_shading

    num, den = np.zeros((n_out, 3)), np.zeros((n_out, 3))
    for (ids, colors), V in zip(observations, posed, strict=True):
        S = vertex_shading(V, F, lighting)[ids]
        if labels is None:
            num[ids] += colors * S
            den[ids] += S * S
        else:
            lab = labels[ids]
            ok = lab >= 0
            np.add.at(num, lab[ok], colors[ok] * S[ok])
            np.add.at(den, lab[ok], S[ok] ** 2)
    return num, den


def estimate_appearance(images: np.ndarray, masks: np.ndarray, posed: list[np.ndarray], F: np.ndarray, camera,
                        max_frames: int = 8, iterations: int = 4, grouped: bool = True,
                        sparsity: float | None = None):
    """§5 on the fitted body: albedo (§5.1) and one lighting for the clip (Eq. 7), alternated.

    Starts from the mean colour over time (``estimate_albedo``, §5.1). With ``grouped`` (default) the
    vertices are split into materials by the chromaticity of that colour (``chromaticity_groups``:
    §5.1's assumption that shading changes intensity, not chromaticity) and each round solves the
    clip's lights (:func:`clip_lighting`) with ONE albedo per material, then each material's albedo as
    ``sum I S / sum S^2`` over its vertices and frames; the shading left inside one material then
    pins the light direction. The per-vertex albedo is solved last with the final lights. Without
    ``grouped``, the per-vertex albedo is alternated with the lights (the first version: a body that
    barely turns keeps its shading in the mean colour and the lights go flat; docs/garment.md).
    ``sparsity`` (default :data:`LIGHT_SPARSITY`): the L1 penalty on the lights. Up to ``max_frames``
    frames spread over the clip. Returns ``(albedo (V, 3), Lighting)``.
    """
    from bodystudio.garment.lighting import chromaticity_groups, estimate_albedo, visible_vertex_colors

    sparsity = LIGHT_SPARSITY if sparsity is None else float(sparsity)
    pick = np.unique(np.linspace(0, len(images) - 1, min(max_frames, len(images))).round().astype(int))
    imgs, Vs, ms = [images[i] for i in pick], [posed[i] for i in pick], [masks[i] for i in pick]
    albedo, count = estimate_albedo(imgs, Vs, F, camera)
    seen = count > 0
    anchor = albedo[seen].mean(0)
    observations = visible_vertex_colors(imgs, Vs, F, camera)
    labels = chromaticity_groups(albedo, seen) if grouped else None
    n_out = int(labels.max()) + 1 if grouped else len(albedo)
    if grouped:
        material = np.stack([albedo[labels == g].mean(0) for g in range(n_out)])
        albedo[seen] = material[labels[seen]]
    lighting = clip_lighting(imgs, ms, Vs, F, camera, albedo, sparsity=sparsity)
    for _ in range(iterations):
        num, den = _albedo_ratio(observations, Vs, F, lighting, labels, n_out)
        if grouped:
            ok = np.all(den > 1e-12, axis=1)
            material[ok] = num[ok] / den[ok]
            albedo[seen] = material[labels[seen]]
        else:
            ok = seen & np.all(den > 1e-12, axis=1)
            albedo[ok] = num[ok] / den[ok]
        # albedo and light share one scale (and the sparsity penalty would drift it): keep the mean colour's mean
        albedo = np.clip(albedo * anchor / np.maximum(albedo[seen].mean(0), 1e-12), 0.0, None)
        if grouped:
            material = np.stack([albedo[labels == g].mean(0) for g in range(n_out)])
        lighting = clip_lighting(imgs, ms, Vs, F, camera, albedo, sparsity=sparsity)
    if grouped:
        num, den = _albedo_ratio(observations, Vs, F, lighting, None, len(albedo))
        ok = seen & np.all(den > 1e-12, axis=1)
        albedo[ok] = num[ok] / den[ok]
    return albedo, lighting


def fit_warnings(stature_fit: float, stature_m: float, ious: np.ndarray) -> list[str]:
    """The fit's warnings: a fitted stature over 1 cm from the given one, frames with a silhouette IoU below 0.8."""
    warnings = []
    if abs(stature_fit - stature_m) > 0.01:
        warnings.append(f"fitted stature {stature_fit:.3f} m differs from the given {stature_m:.3f} m by over 1 cm")
    bad = int(np.count_nonzero(np.asarray(ious) < 0.8))
    if bad:
        warnings.append(f"{bad} of {len(ious)} frames have a silhouette IoU below 0.80")
    return warnings


def refine_garment_fit(fit, images: np.ndarray, stature_m: float, allowance_m: float | None = None,
                       pose_refinement: bool = True):
    """Steps 4b-4c applied to a finished fit (one made with ``shape_refinement=False``): the shape refined with the
    fit's poses held, then (``pose_refinement``) the poses on that shape (:func:`refine_fit_shape_and_poses`),
    then §5's appearance re-estimated on the refined body from ``images`` (the fitted frames) when the fit has one.
    The result equals what :func:`fit_garment_video` gives with the refinements on; the benchmark scores both from
    one pose fit."""
    from dataclasses import replace

    from bodystudio.garment.shape_refine import CLOTHING_ALLOWANCE_M

    allowance = CLOTHING_ALLOWANCE_M if allowance_m is None else float(allowance_m)
    poses = [fit.pose(i) for i in range(len(fit.frame_ids))]
    steps: dict[str, float] = {}
    shape, poses = refine_fit_shape_and_poses(ShapeFit(fit.phenotype, fit.local, fit.body(), np.zeros(0, int), []),
                                              poses, fit.masks, fit.camera, stature_m, fit.template, allowance,
                                              pose_refinement, steps)
    timings = dict(fit.timings_ms)
    timings.update({k: round(v, 1) for k, v in steps.items()})
    posed = [shape.body.pose(p)[0] for p in poses]
    ious = np.array([silhouette_iou(V, shape.body.faces, fit.camera, m) for V, m in zip(posed, fit.masks, strict=True)])
    albedo, lighting = fit.albedo, fit.lighting
    if lighting is not None:
        t0 = time.perf_counter()
        albedo, lighting = estimate_appearance(images, fit.masks, posed, shape.body.faces, fit.camera)
        timings["appearance"] = round((time.perf_counter() - t0) * 1e3 / len(poses), 1)
    stature_fit = body_stature(shape.body)
    return replace(fit, phenotype=shape.phenotype, local=shape.local, stature_m=stature_fit, silhouette_iou=ious,
                   rotations=np.stack([p.rotations for p in poses]),
                   translations=np.stack([p.translation for p in poses]),
                   albedo=albedo, lighting=lighting, timings_ms=timings,
                   warnings=tuple(fit_warnings(stature_fit, stature_m, ious)))


# --- the whole fit -----------------------------------------------------------------------------------

def fit_garment_video(source: str | os.PathLike, stature_m: float, out_dir: str | os.PathLike | None = None,
                      frames: str | None = None, template: str = "2k", focal_px: float | None = None,
                      keyframes: str | os.PathLike | None = None, appearance: bool = True,
                      progress: bool = False, background: str | os.PathLike | None = None,
                      shape_refinement: bool = True, clothing_allowance_m: float | None = None,
                      pose_refinement: bool = True):
    """§4-5 on a video file or session folder: shape, pose per frame, albedo and lighting.

    Writes the fit through :func:`save_garment_fit` into ``out_dir`` (a new folder) when given and
    returns the :class:`GarmentFit`. ``stature_m`` is the actor's stature given by the user. With
    ``shape_refinement`` (default) the shape is refined against every frame's silhouette once the poses are
    known (:func:`bodystudio.garment.shape_refine.refine_shape_to_silhouettes`, the poses held), taking the
    matte to be the body plus ``clothing_allowance_m`` of clothes (default
    :data:`~bodystudio.garment.shape_refine.CLOTHING_ALLOWANCE_M`). With ``pose_refinement`` too (default), the
    poses are then refined on the refined shape (:func:`refine_fit_shape_and_poses`).
    """
    from bodystudio.body.model import RESOLUTIONS
    from bodystudio.capture.session import progress_bar
    from bodystudio.fileio import check_output_folder
    from bodystudio.garment.fitfile import GarmentFit, save_garment_fit
    from bodystudio.garment.person import person_frames

    if stature_m is None or not np.isfinite(stature_m) or not 0.5 <= stature_m <= 2.5:
        raise InputError(f"--stature {stature_m}: give the actor's stature in metres, between 0.5 and 2.5")
    if template not in RESOLUTIONS:
        raise InputError(f"--template {template!r}: valid: {', '.join(RESOLUTIONS)}")
    from bodystudio.garment.shape_refine import CLOTHING_ALLOWANCE_M, MAX_CLOTHING_ALLOWANCE_M

    allowance = CLOTHING_ALLOWANCE_M if clothing_allowance_m is None else clothing_allowance_m
    if not (np.isfinite(allowance) and 0.0 <= allowance <= MAX_CLOTHING_ALLOWANCE_M):
        raise InputError(f"--clothing-mm {1e3 * allowance:g}: give the worn clothes' thickness in mm, between 0 and "
                         f"{1e3 * MAX_CLOTHING_ALLOWANCE_M:g}")
    if out_dir is not None:
        check_output_folder(out_dir, "fit folder", new=True)
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    pf = person_frames(source, frames, background)
    n = len(pf.frame_ids)
    timings["masks"] = (time.perf_counter() - t0) * 1e3 / n
    width, height = pf.size
    camera = camera_hypothesis(width, height, focal_px)
    constraints = None
    if keyframes is not None:  # refused before the minutes of the shape fit, not after
        from bodystudio.body import build_body

        constraints = KeyframeConstraints.load(keyframes, build_body(resolution=template).skeleton.bone_names,
                                               (width, height), pf.frame_ids).points
    with progress_bar(progress) as bar:
        t0 = time.perf_counter()
        task = bar.add_task("garment fit: shape", total=None)
        shape = estimate_shape(pf.masks, camera, stature_m, template)
        timings["shape"] = (time.perf_counter() - t0) * 1e3 / n
        bar.update(task, description="garment fit: pose", total=n, completed=0)
        t0 = time.perf_counter()
        space = pose_space(shape.body)
        X = track_poses(space, camera, pf.masks, int(shape.reference[0]), shape.xs[0], constraints,
                        progress=lambda: bar.advance(task), frame_ids=pf.frame_ids)
        timings["pose"] = (time.perf_counter() - t0) * 1e3 / n
        poses = [space.pose(x) for x in X]
        if shape_refinement:
            bar.update(task, description="garment fit: shape refinement")
            shape, poses = refine_fit_shape_and_poses(shape, poses, pf.masks, camera, stature_m, template, allowance,
                                                      pose_refinement, timings)
        posed = [shape.body.pose(p)[0] for p in poses]
        ious = np.array([silhouette_iou(V, shape.body.faces, camera, m) for V, m in zip(posed, pf.masks, strict=True)])
        albedo = lighting = None
        if appearance:
            bar.update(task, description="garment fit: appearance")
            t0 = time.perf_counter()
            albedo, lighting = estimate_appearance(pf.images, pf.masks, posed, shape.body.faces, camera)
            timings["appearance"] = (time.perf_counter() - t0) * 1e3 / n
    stature_fit = body_stature(shape.body)
    warnings = fit_warnings(stature_fit, stature_m, ious)
    # absolute: a relative path is the user's working directory at fit time, which render, eval and view
    # (run from elsewhere) cannot know; they reported the source "gone"
    fit = GarmentFit(source=str(Path(source).absolute()), fps=pf.fps, frame_ids=pf.frame_ids,
                     camera=camera, template=template,
                     bone_names=tuple(shape.body.skeleton.bone_names), phenotype=shape.phenotype,
                     local=shape.local, stature_m=stature_fit,
                     rotations=np.stack([p.rotations for p in poses]),
                     translations=np.stack([p.translation for p in poses]), silhouette_iou=ious, masks=pf.masks,
                     lighting=lighting, albedo=albedo, timings_ms={k: round(v, 1) for k, v in timings.items()},
                     warnings=tuple(warnings), source_fingerprint=pf.fingerprint)
    if out_dir is not None:
        save_garment_fit(out_dir, fit)
    return fit
