"""Synthetic mirror sessions (§3 input of Real-time Reshaping of Humans) with the ground truth of the edits.

One Kinect (colour 640x480; depth 320x240 for v1, 512x424 for v2) faces a furnished room: walls,
a wooden floor, a bookshelf, a cabinet, a picture and a plant, textured and shaded once into the colour
camera and part of the depth scene (the background plate is seen by the depth camera too). The first
:data:`N_BACKGROUND_FRAMES` frames show the empty room (the paper's background recording); then each
actor (1 or 2 MakeHuman subjects, dressed by body part) walks in from the side, turns to the mirror
2.4-2.9 m from the sensor and moves (``motion``, played at its natural speed sampled at 30 fps).

Per frame the session holds what the Kinect SDK delivers: the colour image (with sensor noise), the depth
(Khoshelham noise, projector shadows, flying pixels, holes: ``capture.kinect``), the tracked bodies
(SDK joint sets with the tracker noise model; a body is reported once enough of its joints are inside the
depth image) and the player mask on the depth image, which follows the true segmentation but jitters at
its edges (a smooth random field of ~1.5 px moves the boundary every frame) and is empty where the depth
is missing, as the paper describes the SDK's mask.

Ground truth (``gt/``): each actor's subject (``gt/phenotype.json``), rest meshes in the statistical
model's template, source and target coefficients and skeletons (``gt/mirror/actors.npz``), per frame the
true person labels in colour (``gt/person``), posed source and target vertices, true Kinect joints and the
pose (``gt/mirror/NNNNN.npz``), and for the edits the TARGET render (``gt/target/rgb``, ``gt/target/person``):
the same frame with every actor's body edited by Eq. 4 (:func:`target_rest_body`), same pose, same
background, same sensor noise.
"""

from __future__ import annotations

import logging
import os
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from scipy import ndimage

from bodystudio.body.kinect import kinect_joint_names, kinect_joints
from bodystudio.body.model import BodyModel
from bodystudio.body.pose import Pose, transfer_pose
from bodystudio.body.skeleton import Skeleton
from bodystudio.body.skinning import posed_joints
from bodystudio.capture.kinect import (
    KINECT_NOISE,
    flying_pixels,
    grazing_mask,
    projector_shadow_mask,
    quantized_disparity_depth,
    random_holes,
    simulate_tracker_joints,
)
from bodystudio.capture.motion import motion_sequence, world_to_local_rotvecs
from bodystudio.capture.render import RenderResult, lambert_shading, render, render_rgb
from bodystudio.errors import InputError
from bodystudio.geometry.camera import Camera, RGBDSensor
from bodystudio.mirror.frames import depth_ray_table
from bodystudio.mirror.reshape import check_edits, target_coeffs

log = logging.getLogger(__name__)

FPS = 30.0
#: Empty-room frames at the start of every session (the paper's background recording).
N_BACKGROUND_FRAMES = 10
#: Colour sensor noise (0..255 grey levels), as the studio cameras of ``capture.synth``.
SENSOR_NOISE_STD = 2.0
#: Where the Kinect stands (studio frame, metres) and where it looks: the actors face it (+z).
KINECT_EYE = (0.0, 1.0, 3.0)
KINECT_TARGET = (0.0, 0.9, 0.0)
#: Statistical-model template the actors are built in (the mirror's source body lives in it).
TEMPLATE = "6k"
WALK_SPEED_M_S = 1.2
TURN_S = 0.5
#: Standing spots (x, z) and entry sides of actor 1 and actor 2 (2.4-2.9 m from the sensor).
STAND_SPOTS = {1: ((0.0, 0.4),), 2: ((-0.45, 0.5), (0.5, 0.1))}
ENTRY_SIDE = (-1.0, 1.0)
ENTRY_X_M = 2.35
MIRROR_MOTIONS = ("arms_raise", "walk", "turn", "arm_flex", "a_pose", "t_pose")

# ---------------------------------------------------------------------------------------------- the sensor

def mirror_sensor(version: str = "v2") -> RGBDSensor:
    """The mirror's Kinect: v1 with 320x240 depth or v2 with 512x424 depth, colour 640x480 for both.

    The v2's 1920x1080 colour is the centre 1440x1080 scaled to 640x480 (fx 1060 / 2.25), as the paper
    works on 640x480 colour.
    """
    from bodystudio.geometry.camera import kinect_v1, kinect_v2

    if version == "v1":
        return kinect_v1("320x240", eye=KINECT_EYE, target=KINECT_TARGET)
    if version != "v2":
        raise InputError(f"--kinect {version!r} is not a Kinect version; valid: v1, v2")
    s = kinect_v2(eye=KINECT_EYE, target=KINECT_TARGET)
    c = s.color
    K = np.array([[c.fx / 2.25, 0.0, 319.5], [0.0, c.fy / 2.25, 239.5], [0.0, 0.0, 1.0]])
    color = Camera(c.name, K, c.dist, c.R, c.t, 640, 480)
    return RGBDSensor(s.name, s.version, s.depth, color, s.depth_to_color, s.baseline_m, s.depth_range_m)


# ---------------------------------------------------------------------------------------------- the room

@dataclass(frozen=True, eq=False)
class Room:
    """The static scene: triangles, a material per triangle (index into :data:`MATERIALS`)."""

    vertices: np.ndarray  # (n, 3)
    faces: np.ndarray  # (m, 3)
    material: np.ndarray  # (m,) int


MATERIALS = ("floor", "wall", "shelf", "cabinet", "picture", "plant")


def _box(lo, hi) -> tuple[np.ndarray, np.ndarray]:
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    V = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    F = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                  [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    return V, F


def _quad(a, b, c, d, n: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """A planar quad a-b-c-d split into an n x n grid (big planes in pieces keep the rasteriser's depth exact)."""
    a, b, c, d = (np.asarray(p, float) for p in (a, b, c, d))
    s, t = np.meshgrid(np.linspace(0, 1, n + 1), np.linspace(0, 1, n + 1), indexing="ij")
    s, t = s.ravel()[:, None], t.ravel()[:, None]
    V = (1 - s) * (1 - t) * a + s * (1 - t) * b + s * t * c + (1 - s) * t * d
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    F = []
    for i in range(n):
        for j in range(n):
            F += [[idx[i, j], idx[i + 1, j], idx[i + 1, j + 1]], [idx[i, j], idx[i + 1, j + 1], idx[i, j + 1]]]
    return V, np.array(F)


def mirror_room() -> Room:
    """The furnished room in front of the Kinect (floor y = 0; back wall 4.3 m from the sensor)."""
    # the room stops 1.5 m in front of the sensor: its big triangles stay where straight edges between distorted
    # vertices are close to the lens's curves. Its ceiling's near corners still lie beyond the v2 colour lens's
    # monotonic radius (60 degrees off the axis); the renderer drops the triangles there (mir12t; before, they
    # folded back into the colour images as grey wedges at the top corners)
    parts = [
        (_quad((-2.8, 0, -1.3), (2.8, 0, -1.3), (2.8, 0, 1.5), (-2.8, 0, 1.5), 10), "floor"),
        (_quad((-2.8, 0, -1.3), (2.8, 0, -1.3), (2.8, 2.8, -1.3), (-2.8, 2.8, -1.3), 6), "wall"),
        (_quad((-2.8, 0, -1.3), (-2.8, 0, 1.5), (-2.8, 2.8, 1.5), (-2.8, 2.8, -1.3), 6), "wall"),
        (_quad((2.8, 0, -1.3), (2.8, 0, 1.5), (2.8, 2.8, 1.5), (2.8, 2.8, -1.3), 6), "wall"),
        (_quad((-2.8, 2.8, -1.3), (2.8, 2.8, -1.3), (2.8, 2.8, 1.5), (-2.8, 2.8, 1.5), 6), "wall"),
        (_box((-1.95, 0, -1.3), (-1.05, 1.9, -0.95)), "shelf"),
        (_box((1.0, 0, -1.3), (2.0, 0.8, -0.8)), "cabinet"),
        (_box((-0.35, 1.25, -1.3), (0.45, 1.85, -1.27)), "picture"),
        (_box((1.25, 0.8, -1.15), (1.55, 1.35, -0.9)), "plant"),
    ]
    V, F, M = [], [], []
    offset = 0
    for (v, f), material in parts:
        V.append(v)
        F.append(f + offset)
        M.append(np.full(len(f), MATERIALS.index(material)))
        offset += len(v)
    return Room(np.concatenate(V), np.concatenate(F), np.concatenate(M))


def _lattice_noise(P2: np.ndarray, cell_m: float, rng: np.random.Generator, size: int = 96) -> np.ndarray:
    """Smooth value noise in [-1, 1] at 2-D points (K, 2) in metres, one lattice cell per ``cell_m``."""
    lattice = rng.uniform(-1.0, 1.0, (size, size))
    coords = (P2 / cell_m) % (size - 1)
    return ndimage.map_coordinates(lattice, coords.T, order=3, mode="grid-wrap")


def room_albedo(P: np.ndarray, material: np.ndarray, seed: int) -> np.ndarray:
    """Albedo (K, 3) in [0, 1] of room surface points ``P`` (K, 3) by material: planks, paint, books, ..."""
    rng = np.random.default_rng([seed, 77])
    out = np.zeros((len(P), 3))
    x, y, z = P[:, 0], P[:, 1], P[:, 2]
    # floor: oak planks along z, 14 cm wide, a tone per plank, grain and dark seams
    m = material == MATERIALS.index("floor")
    plank = np.floor((x[m] + 10.0) / 0.14).astype(np.int64)
    tone = np.random.default_rng([seed, 1]).uniform(0.8, 1.15, 200)[plank % 200]
    grain = 0.06 * np.sin(z[m] * 35.0 + 6.0 * _lattice_noise(np.c_[x[m], z[m]], 0.3, rng))
    seam = np.abs(((x[m] + 10.0) / 0.14) % 1.0 - 0.5) > 0.46
    out[m] = np.array([0.62, 0.45, 0.28]) * (tone + grain)[:, None]
    out[m & np.isin(np.arange(len(P)), np.flatnonzero(m)[seam])] *= 0.45
    # walls: warm paint with mottling, a darker dado below 0.9 m
    m = material == MATERIALS.index("wall")
    mottle = 1.0 + 0.06 * _lattice_noise(np.c_[x[m] + z[m], y[m]], 0.25, rng)
    paint = np.where((y[m] < 0.9)[:, None], [0.45, 0.52, 0.47], [0.86, 0.82, 0.74])
    out[m] = paint * mottle[:, None]
    # shelf: dark wood frame, rows of book spines of random colours
    m = material == MATERIALS.index("shelf")
    spine = np.floor((x[m] + 10.0) / 0.035).astype(np.int64)
    palette = np.random.default_rng([seed, 2]).uniform(0.1, 0.85, (500, 3))
    books = palette[(spine + 37 * np.floor(y[m] / 0.38).astype(np.int64)) % 500]
    board = ((y[m] % 0.38) < 0.03) | (y[m] > 1.85)
    out[m] = np.where(board[:, None], [0.30, 0.20, 0.12], books)
    # cabinets: blue-grey paint, door seams
    m = material == MATERIALS.index("cabinet")
    out[m] = np.array([0.36, 0.42, 0.52]) * (1.0 + 0.05 * _lattice_noise(np.c_[x[m], y[m] + z[m]], 0.1, rng))[:, None]
    out[m & np.isin(np.arange(len(P)), np.flatnonzero(m)[np.abs((x[m] % 0.5) - 0.25) < 0.006])] *= 0.5
    # picture: a colourful abstract print
    m = material == MATERIALS.index("picture")
    hue = np.c_[_lattice_noise(np.c_[x[m], y[m]], 0.05, rng), _lattice_noise(np.c_[x[m], y[m]], 0.07, rng),
                _lattice_noise(np.c_[x[m], y[m]], 0.04, rng)]
    out[m] = 0.5 + 0.45 * hue
    # plant: leafy greens
    m = material == MATERIALS.index("plant")
    leaf = _lattice_noise(np.c_[x[m] + z[m], y[m]], 0.03, rng)
    out[m] = np.c_[0.15 + 0.08 * leaf, 0.45 + 0.2 * leaf, 0.15 + 0.05 * leaf]
    return np.clip(out, 0.0, 1.0)


def room_plate(room: Room, camera: Camera, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """The empty room seen by ``camera``: clean colour (H, W, 3) uint8 and camera-z depth (H, W) (0 = none)."""
    result = render(room.vertices, room.faces, camera)
    P, rc = result.surface_points(room.vertices, room.faces)
    tri = result.triangle_id[rc[:, 0], rc[:, 1]]
    material = room.material[tri]
    V, F = room.vertices, room.faces[tri]
    n = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    n *= -np.sign(np.einsum("kd,kd->k", n, P - camera.center))[:, None]  # towards the camera
    # indoor light: a ceiling lamp above the actors plus ambient, falling off towards the back of the room
    shade = lambert_shading(n, lights=(((0.0, 1.0, 0.4), 0.55), ((0.3, 0.4, 1.0), 0.3)), ambient=0.35)
    shade *= 1.0 - 0.08 * np.clip(-(P[:, 2] + 1.3) / 4.8 + 1.0, 0.0, 1.0)
    image = np.zeros((camera.height, camera.width, 3))
    image[rc[:, 0], rc[:, 1]] = room_albedo(P, material, seed) * shade[:, None]
    return np.clip(np.round(image * 255.0), 0, 255).astype(np.uint8), result.depth.astype(np.float64)


# ---------------------------------------------------------------------------------------------- the actors

#: Dominant skin-weight bone -> clothing part; every other bone is skin.
_CLOTHING = {"shirt": ("spine_01", "spine_02", "spine_03", "clavicle_l", "clavicle_r", "upperarm_l",
                       "upperarm_r"),
             "trousers": ("pelvis", "thigh_l", "thigh_r", "calf_l", "calf_r"),
             "shoes": ("foot_l", "foot_r", "ball_l", "ball_r")}
_SHIRTS = ((0.70, 0.12, 0.12), (0.15, 0.35, 0.65), (0.85, 0.75, 0.25), (0.20, 0.50, 0.30), (0.90, 0.90, 0.88),
           (0.35, 0.25, 0.45), (0.95, 0.55, 0.20))
_TROUSERS = ((0.12, 0.16, 0.30), (0.20, 0.20, 0.20), (0.45, 0.38, 0.28), (0.30, 0.32, 0.36), (0.55, 0.50, 0.42))
_SKINS = ((0.87, 0.68, 0.57), (0.72, 0.53, 0.40), (0.50, 0.35, 0.25), (0.93, 0.76, 0.65))
_HAIR = ((0.10, 0.07, 0.05), (0.35, 0.22, 0.10), (0.70, 0.55, 0.30), (0.20, 0.18, 0.17))


def clothing_albedo(body: BodyModel, seed: int) -> np.ndarray:
    """Per-vertex albedo (n, 3) of a dressed actor: striped shirt, trousers, shoes, skin and hair."""
    rng = np.random.default_rng([seed, 5])
    names = body.skeleton.bone_names
    dominant = np.asarray(np.argmax(body.weights, axis=1)).ravel()
    part = np.full(body.n_vertices, "skin", dtype=object)
    for name, bones in _CLOTHING.items():
        ids = [names.index(b) for b in bones if b in names]
        part[np.isin(dominant, ids)] = name
    V = body.vertices
    colour = np.empty((body.n_vertices, 3))
    shirt, stripe = np.asarray(_SHIRTS[rng.integers(len(_SHIRTS))]), np.asarray(_SHIRTS[rng.integers(len(_SHIRTS))])
    in_shirt = part == "shirt"
    stripes = (np.floor(V[:, 1] / 0.045) % 2 == 0) & in_shirt
    colour[in_shirt] = shirt
    colour[stripes] = 0.6 * shirt + 0.4 * stripe
    colour[part == "trousers"] = _TROUSERS[rng.integers(len(_TROUSERS))]
    colour[part == "shoes"] = (0.08, 0.08, 0.09)
    colour[part == "skin"] = _SKINS[rng.integers(len(_SKINS))]
    head = names.index("head")
    top = V[:, 1].max()
    hair = (dominant == head) & ((V[:, 1] > top - 0.07) | ((V[:, 1] > top - 0.2) & (V[:, 2] < np.median(
        V[dominant == head, 2]))))
    colour[hair] = _HAIR[rng.integers(len(_HAIR))]
    colour *= rng.uniform(0.94, 1.06, (body.n_vertices, 1))  # fabric and skin texture
    return np.clip(colour, 0.0, 1.0)


def target_rest_body(model, body: BodyModel, edits: dict[str, float]) -> tuple[BodyModel, np.ndarray, np.ndarray]:
    """The edited actor (Eq. 4): ``(target body, source coefficients, target coefficients)``.

    The actor's rest mesh is projected into the statistical model (``c_S``), the edit applied to the
    coefficients (``c_T``, :meth:`StatisticalBodyModel.edit`) and the model's change
    ``B(c_T) - B(c_S)`` (vertices and joints) added to the actor's own mesh and skeleton, so a zero edit
    gives the actor back (the same object) and the target keeps the actor's details outside the model's span.
    """
    c_s = model.project(body.vertices)
    if not any(check_edits(edits).values()):
        return body, c_s, c_s.copy()
    c_t = target_coeffs(model, c_s, edits)
    dV = model.vertices(c_t) - model.vertices(c_s)
    sk_s, sk_t = model.skeleton(c_s), model.skeleton(c_t)
    skel = body.skeleton
    target_skeleton = Skeleton(skel.bone_names, skel.parents, skel.heads + sk_t.heads - sk_s.heads,
                               skel.tails + sk_t.tails - sk_s.tails, skel.rolls)
    target = BodyModel(body.vertices + dV, body.faces, target_skeleton, body.weights, body.resolution, body.rig,
                       vertex_ids=body.vertex_ids)
    return target, c_s, c_t


def _yaw(skeleton: Skeleton, pose: Pose, yaw_rad: float, translation) -> Pose:
    """``pose`` turned by ``yaw_rad`` about the vertical through the root and moved to ``translation``."""
    from scipy.spatial.transform import Rotation

    rot = pose.rotations.copy()
    root = int(np.flatnonzero(skeleton.parents < 0)[0])
    world = np.zeros((skeleton.n_bones, 3))
    world[root] = (0.0, yaw_rad, 0.0)
    local_yaw = Rotation.from_rotvec(world_to_local_rotvecs(skeleton, world)[root])
    rot[root] = (local_yaw * Rotation.from_rotvec(rot[root])).as_rotvec()
    return Pose(rot, np.asarray(translation, float))


def actor_poses(skeleton: Skeleton, n_frames: int, enter_frame: int, stand_xz, side: float, motion: str,
                seed: int, fps: float = FPS, walk_in: bool = True) -> tuple[list[Pose | None], int]:
    """The actor's pose per frame (None before it enters) and the frame it stands still at its spot.

    A walk in from ``side`` (-1: from -x) to the standing spot at :data:`WALK_SPEED_M_S`, a turn to face
    the Kinect, then ``motion`` at its natural speed. Without ``walk_in`` the actor stands at the spot from
    ``enter_frame`` on (short test sessions).
    """
    start = np.array([side * ENTRY_X_M, stand_xz[1] - 0.3])
    stand = np.asarray(stand_xz, float)
    walk_frames = int(np.ceil(np.linalg.norm(stand - start) / WALK_SPEED_M_S * fps))
    turn_frames = int(round(TURN_S * fps))
    n_walk = max(0, min(walk_frames + turn_frames, n_frames - enter_frame)) if walk_in else 0
    gait = motion_sequence("walk", max(n_walk, 1), skeleton, seed, fps=fps)
    n_stand = max(0, n_frames - enter_frame - n_walk)
    standing = motion_sequence(motion, max(n_stand, 1), skeleton, seed, fps=fps)
    heading = float(np.arctan2(*(stand - start)))  # yaw taking +z (the body's front) to the walk direction
    poses: list[Pose | None] = [None] * min(enter_frame, n_frames)
    for k in range(n_walk):
        s = min(1.0, (k + 1) / walk_frames)
        ease = 1.0 - (1.0 - s) ** 2 if s > 0.7 else s  # slow down over the last steps
        xz = start + min(1.0, ease) * (stand - start)
        # the gait fades out and the body turns to the mirror over the last TURN_S
        fade = float(np.clip((walk_frames + turn_frames - k) / (1.5 * turn_frames), 0.0, 1.0))
        turn = float(np.clip((k - walk_frames + turn_frames) / turn_frames, 0.0, 1.0))
        g = Pose(gait[k].rotations * fade, np.zeros(3))
        poses.append(_yaw(skeleton, g, heading * (1.0 - turn), (xz[0], 0.0, xz[1])))
    for k in range(n_stand):
        poses.append(_yaw(skeleton, standing[k], 0.0, (stand[0], 0.0, stand[1])))
    return poses[:n_frames], enter_frame + n_walk


# ---------------------------------------------------------------------------------------------- the SDK

def sdk_player_mask(labels: np.ndarray, depth_m: np.ndarray, rng: np.random.Generator,
                    jitter_px: float = 1.5) -> np.ndarray:
    """The SDK's player mask (H, W) uint8 from the true labels on the depth image: edges jitter, holes empty.

    Each player's boundary moves by a smooth random field of amplitude ``jitter_px`` (new every frame,
    correlated over ~8 px along the contour), thresholding its signed distance; pixels without depth
    carry no player.
    """
    out = np.zeros(labels.shape, dtype=np.uint8)
    H, W = labels.shape
    coarse = rng.normal(0.0, 1.0, (H // 8 + 2, W // 8 + 2, int(labels.max(initial=0)) + 1))
    for k in np.unique(labels[labels > 0]):
        m = (labels == k).astype(np.uint8)
        inside = cv2.distanceTransform(m, cv2.DIST_L2, 3)
        outside = cv2.distanceTransform(1 - m, cv2.DIST_L2, 3)
        signed = np.where(m > 0, inside - 0.5, 0.5 - outside)
        field = cv2.resize(coarse[..., k], (W, H), interpolation=cv2.INTER_CUBIC)
        jittered = (signed + jitter_px * field) > 0
        out[jittered & (out == 0)] = k
    out[depth_m <= 0] = 0
    return out


def tracked_joints(truth: np.ndarray, sensor: RGBDSensor, heads, tails, skeleton, version: str,
                   rng: np.random.Generator, min_visible: float = 0.7):
    """The tracker's report of one body: ``(positions, tracked)`` or None when too little of it is in view.

    Joints outside the depth image (or its range) are inferred: reported with the inferred noise, not tracked.
    """
    uv, z = sensor.depth.project_with_depth(truth)
    lo, hi = sensor.depth_range_m
    inside = sensor.depth.in_image(np.nan_to_num(uv, nan=-1.0)) & (z >= lo) & (z <= hi)
    if inside.mean() < min_visible:
        return None
    positions, tracked = simulate_tracker_joints(heads, tails, skeleton, version, rng)
    return positions, tracked & inside


@dataclass(frozen=True, eq=False)
class StaticDepth:
    """The empty room seen by the depth camera and the projector, computed once per session."""

    depth: np.ndarray  # (h, w) ideal camera-z depth of the room, 0 = none
    projector_depth: np.ndarray  # (h, w) the room's depth seen from the projector
    missing: np.ndarray  # (h, w) bool: grazing surfaces and projector shadows of the room itself


def static_room_depth(room: Room, sensor: RGBDSensor) -> StaticDepth:
    result = render(room.vertices, room.faces, sensor.depth)
    missing = grazing_mask(room.vertices, room.faces, result, sensor, KINECT_NOISE.grazing_angle_deg)
    missing |= projector_shadow_mask(room.vertices, room.faces, sensor, result, KINECT_NOISE.shadow_tolerance_m)
    proj = render(room.vertices, room.faces, sensor.projector).depth.astype(np.float64)
    return StaticDepth(result.depth.astype(np.float64), proj, missing)


def kinect_depth_frame(static: StaticDepth, V: np.ndarray, F: np.ndarray, sensor: RGBDSensor,
                       rng: np.random.Generator, band_px: int = 8):
    """Kinect depth (h, w) of the room with the actors' mesh ``(V, F)`` in it, and the depth render of the actors.

    The noise model of :func:`bodystudio.capture.kinect.simulate_kinect_depth` in the same order (grazing
    dropouts and projector shadows, flying pixels, disparity noise and quantisation, range, holes), with the
    room's share computed once: only the pixels within ``band_px`` of the actors are re-tested for shadows
    (the projector's parallax moves a shadow a few pixels at most).
    """
    h, w = static.depth.shape
    if len(V) == 0:
        body = RenderResult(np.zeros((h, w), bool), np.zeros((h, w), np.float32), np.full((h, w), -1, np.int32),
                            np.zeros((h, w, 3), np.float32))
    else:
        body = render(V, F, sensor.depth)
    in_front = body.mask & ((body.depth < static.depth) | (static.depth <= 0))
    depth = np.where(in_front, body.depth, static.depth).astype(np.float64)
    missing = np.where(in_front, False, static.missing)
    if in_front.any():
        missing |= grazing_mask(V, F, body, sensor, KINECT_NOISE.grazing_angle_deg) & in_front
        band = cv2.dilate(body.mask.astype(np.uint8), np.ones((2 * band_px + 1, 2 * band_px + 1), np.uint8)) > 0
        band &= depth > 0
        seen_by_projector = render(V, F, sensor.projector)
        proj = np.minimum(np.where(static.projector_depth > 0, static.projector_depth, np.inf),
                          np.where(seen_by_projector.mask, seen_by_projector.depth, np.inf))
        rows, cols = np.nonzero(band)
        xy = depth_ray_table(sensor.depth)[rows, cols]
        z = depth[rows, cols]
        P = sensor.depth.camera_to_world(np.c_[xy * z[:, None], z])
        uv, zp = sensor.projector.project_with_depth(P)
        pc, pr = np.round(uv[:, 0]).astype(np.int64), np.round(uv[:, 1]).astype(np.int64)
        lit = np.zeros(len(P), bool)
        for dr in (-1, 0, 1):
            for dc in (-1, 0, 1):
                r, c = pr + dr, pc + dc
                ok = (r >= 0) & (r < h) & (c >= 0) & (c < w)
                seen = np.full(len(P), np.inf)
                seen[ok] = proj[r[ok], c[ok]]
                lit |= ok & (np.abs(seen - zp) < KINECT_NOISE.shadow_tolerance_m)
        missing[rows[~lit], cols[~lit]] = True
    depth = flying_pixels(depth, rng)
    depth[missing] = 0.0
    depth = quantized_disparity_depth(depth, sensor.depth.fx, sensor.baseline_m, rng)
    lo, hi = sensor.depth_range_m
    depth[(depth < lo) | (depth > hi)] = 0.0
    depth[random_holes(depth.shape, rng)] = 0.0
    return depth, body, in_front


# ---------------------------------------------------------------------------------------------- the session

def _labelled_render(meshes: list[tuple[np.ndarray, np.ndarray]], camera: Camera, room_depth: np.ndarray):
    """Render actors' meshes together: the result with pixels behind the room removed, and actor labels."""
    V = np.concatenate([m[0] for m in meshes])
    offsets = np.cumsum([0] + [len(m[0]) for m in meshes])
    F = np.concatenate([m[1] + offsets[i] for i, m in enumerate(meshes)])
    face_actor = np.concatenate([np.full(len(m[1]), i + 1, np.uint8) for i, m in enumerate(meshes)])
    r = render(V, F, camera)
    visible = r.mask & ((r.depth < room_depth) | (room_depth <= 0))
    tri = np.where(visible, r.triangle_id, -1).astype(np.int32)
    labels = np.where(visible, face_actor[np.maximum(r.triangle_id, 0)], 0).astype(np.uint8)
    return RenderResult(visible, np.where(visible, r.depth, 0).astype(np.float32), tri, r.barycentric), labels, V, F


def synth_mirror_session(out: str | os.PathLike, subject_seed: int, n_frames: int = 120, actors: int = 1,
                         edits: dict[str, float] | None = None, version: str = "v2", motion: str = "arms_raise",
                         seed: int = 0, progress: bool = False, model=None, edited_players: tuple[int, ...] = (1,),
                         walk_in: bool = True, timings: dict | None = None):
    """Write a synthetic mirror session of ``actors`` subjects (``subject_seed``, ``subject_seed + 1``)
    into the new folder ``out``, with the ground truth of ``edits`` (names of
    :data:`bodystudio.mirror.reshape.EDIT_NAMES`, validated by its ``check_edits``: one source of truth).

    The target render reshapes the actors in ``edited_players`` (player ids; default the first actor, whom
    ``bodystudio mirror run`` reshapes by default); the others appear unchanged in it. ``walk_in=False``:
    the actors appear at their spots instead of walking in (short sessions for tests). ``timings``, a dict,
    receives the wall and CPU seconds of the setup (model, room, bodies, edits) and of the frames.

    The same arguments always give the same files. ``model``: the statistical model (default the cached
    6k one). Returns the opened :class:`~bodystudio.capture.session.Session`.
    """
    from bodystudio.body import build_body
    from bodystudio.body.measure import measure_attributes
    from bodystudio.body.population import sample_subject
    from bodystudio.body.statistical import load_statistical_model
    from bodystudio.capture.session import SessionWriter, open_session, progress_bar
    from bodystudio.geometry.camera import CameraRig

    out = Path(out)
    edits = check_edits(edits)
    if actors not in (1, 2):
        raise InputError(f"--actors {actors}: a mirror session has 1 or 2 actors")
    if type(n_frames) is not int or not N_BACKGROUND_FRAMES + 1 <= n_frames <= 99999:
        raise InputError(f"--frames {n_frames}: need {N_BACKGROUND_FRAMES + 1}..99999 (the first "
                         f"{N_BACKGROUND_FRAMES} show the empty room)")
    if motion not in MIRROR_MOTIONS:
        raise InputError(f"unknown motion {motion!r}; valid: {', '.join(MIRROR_MOTIONS)}")
    edited_players = tuple(sorted({int(p) for p in edited_players}))
    if not edited_players or not set(edited_players) <= set(range(1, actors + 1)):
        raise InputError(f"edited players {list(edited_players)}: choose among the actors' players "
                         f"1..{actors}")
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise InputError(f"{out}: output exists and is not an empty folder; choose a new folder")
    sensor = mirror_sensor(version)
    model = load_statistical_model(TEMPLATE, progress=progress) if model is None else model
    rng = np.random.default_rng([seed, subject_seed, actors])
    t0, c0 = time.perf_counter(), time.process_time()

    room = mirror_room()
    plate, room_depth_color = room_plate(room, sensor.color, seed)
    static = static_room_depth(room, sensor)
    cast = []
    for k in range(1, actors + 1):
        phenotype, local = sample_subject(subject_seed + k - 1)
        body = build_body(phenotype, local, resolution=model.resolution, rig=model.rig)
        target, c_s, c_t = target_rest_body(model, body, edits if k in edited_players else {})
        spot = STAND_SPOTS[actors][k - 1]
        enter = N_BACKGROUND_FRAMES + ((k - 1) * 15 if walk_in else 0)
        poses, stand_frame = actor_poses(body.skeleton, n_frames, enter, spot, ENTRY_SIDE[k - 1], motion,
                                         seed + 101 * k, walk_in=walk_in)
        measured = measure_attributes(body.vertices, body.faces, vertex_ids=body.vertex_ids,
                                      muscularity=phenotype.muscle)
        cast.append({"player": k, "subject_seed": subject_seed + k - 1, "phenotype": phenotype, "local": local,
                     "body": body, "target": target, "c_s": c_s, "c_t": c_t, "poses": poses,
                     "albedo": clothing_albedo(body, subject_seed + k - 1), "measured": measured,
                     "enter_frame": enter, "stand_frame": stand_frame,
                     "target_measured": model.measure(c_t) if edits and k in edited_players else None})
    names = kinect_joint_names(sensor.version)
    faces = cast[0]["body"].faces
    metadata = {"generator": "bodystudio synth mirror", "subject_seed": subject_seed, "actors": actors,
                "fps": FPS, "kinect": sensor.version, "seed": seed, "motion": motion, "edits": edits,
                "edited_players": list(edited_players) if edits else [], "template": model.resolution,
                "background_frames": N_BACKGROUND_FRAMES, "noise_std": SENSOR_NOISE_STD, "walk_in": walk_in,
                "actor_frames": [{"player": a["player"], "enter_frame": a["enter_frame"],
                                  "stand_frame": a["stand_frame"]} for a in cast]}
    setup_s, setup_cpu_s = time.perf_counter() - t0, time.process_time() - c0
    with progress_bar(progress) as bar:
        task = bar.add_task("synth mirror", total=n_frames)
        with SessionWriter(out, CameraRig([]), source="synthetic", metadata=metadata,
                           command="bodystudio synth mirror") as writer:
            first = cast[0]
            writer.write_gt_subject(first["phenotype"].to_dict(), first["local"], template=model.resolution,
                                    rig=model.rig, n_vertices=first["body"].n_vertices,
                                    bone_names=list(first["body"].skeleton.bone_names),
                                    stature_m=first["measured"]["stature_m"], mass_kg=first["measured"]["mass_kg"],
                                    actors=[_actor_record(a) for a in cast])
            writer.write_kinect_calibration(sensor)
            writer.write_gt_mirror_actors(_actor_arrays(cast, faces))
            for i in range(n_frames):
                _write_frame(writer, i, cast, static, sensor, plate, room_depth_color, names, bool(edits), rng)
                bar.advance(task)
    session = open_session(out)
    total_s, total_cpu_s = time.perf_counter() - t0, time.process_time() - c0
    if timings is not None:
        timings.update(setup_s=setup_s, setup_cpu_s=setup_cpu_s, frames_s=total_s - setup_s,
                       frames_cpu_s=total_cpu_s - setup_cpu_s, ms_per_frame_cpu=1e3 * (total_cpu_s - setup_cpu_s)
                       / n_frames, n_frames=n_frames)
    log.info("wrote %s: %d frames, %d actor(s), setup %.1f s, total %.1f s", out, n_frames, actors, setup_s, total_s)
    return session


def time_synth_mirror(folder: str | os.PathLike, n_frames: int = 40, actors: int = 1, version: str = "v2") -> dict:
    """Benchmark helper (``benchmarks/bench_mirror.py``): seconds to synthesise a mirror session into the new
    ``folder`` with a +10 cm edit, setup and frames apart, wall and CPU (run with ``NUMBA_NUM_THREADS=1``)."""
    timings: dict = {}
    synth_mirror_session(folder, subject_seed=3, n_frames=n_frames, actors=actors, edits={"taller": 0.1},
                         version=version, timings=timings)
    return timings


def _actor_record(a: dict) -> dict:
    rec = {"player": a["player"], "subject_seed": a["subject_seed"], "phenotype": a["phenotype"].to_dict(),
           "local": a["local"], "measured": a["measured"], "enter_frame": a["enter_frame"],
           "stand_frame": a["stand_frame"]}
    if a["target_measured"] is not None:
        rec["target_measured_model"] = a["target_measured"]
    return rec


def _actor_arrays(cast: list[dict], faces: np.ndarray) -> dict[str, np.ndarray]:
    return {"players": np.array([a["player"] for a in cast]), "faces": faces,
            "source_rest_vertices": np.stack([a["body"].vertices for a in cast]),
            "target_rest_vertices": np.stack([a["target"].vertices for a in cast]),
            "source_coeffs": np.stack([a["c_s"] for a in cast]), "target_coeffs": np.stack([a["c_t"] for a in cast]),
            "source_heads": np.stack([a["body"].skeleton.heads for a in cast]),
            "source_tails": np.stack([a["body"].skeleton.tails for a in cast]),
            "target_heads": np.stack([a["target"].skeleton.heads for a in cast]),
            "target_tails": np.stack([a["target"].skeleton.tails for a in cast]),
            "albedo": np.stack([a["albedo"] for a in cast])}


def _write_frame(writer, i, all_cast, static, sensor, plate, room_depth_color, names, edited, rng) -> None:
    present = [a for a in all_cast if a["poses"][i] is not None]
    version = sensor.version
    noise = rng.normal(0.0, SENSOR_NOISE_STD, plate.shape).astype(np.float32)

    def noisy(image):
        return np.clip(np.round(image.astype(np.float32) + noise), 0, 255).astype(np.uint8)

    posed, posed_target, truth_joints, bodies = [], [], [], []
    for a in present:
        pose = a["poses"][i]
        V, _ = a["body"].pose(pose)
        heads, tails = posed_joints(a["body"].skeleton, pose)
        posed.append(V)
        posed_target.append(a["target"].pose(transfer_pose(pose, a["body"].skeleton, a["target"].skeleton))[0]
                            if edited and a["target"] is not a["body"] else V)
        truth = kinect_joints(a["body"].skeleton, heads, tails, version)
        truth_joints.append(truth)
        report = tracked_joints(truth, sensor, heads, tails, a["body"].skeleton, version, rng)
        if report is not None:
            bodies.append({"player": a["player"], "names": names, "positions": report[0], "tracked": report[1]})
    # depth: the room and the actors together (flying pixels and shadows at every edge)
    faces = all_cast[0]["body"].faces
    V_b = np.concatenate(posed) if posed else np.zeros((0, 3))
    F_b = np.concatenate([faces + j * len(V_j) for j, V_j in enumerate(posed)]) if posed else \
        np.zeros((0, 3), np.int64)
    depth, body_render, in_front = kinect_depth_frame(static, V_b, F_b, sensor, rng)
    face_actor = np.concatenate([np.full(len(faces), a["player"], np.uint8) for a in present]) if present else \
        np.zeros(1, np.uint8)
    labels = np.where(in_front, face_actor[np.maximum(body_render.triangle_id, 0)], 0)
    reported = [b["player"] for b in bodies]
    labels[~np.isin(labels, reported)] = 0  # the SDK segments only the bodies it tracks
    writer.write_kinect_depth(i, depth)
    writer.write_kinect_player(i, sdk_player_mask(labels, depth, rng))
    writer.write_kinect_bodies(i, bodies, joint_set=version)
    # colour: the actors over the room plate
    if present:
        res, person, V, F = _labelled_render([(v, faces) for v in posed], sensor.color, room_depth_color)
        albedo = np.concatenate([a["albedo"] for a in present])
        rgb = render_rgb(V, F, sensor.color, vertex_colors=albedo, background=plate, result=res)
        person = _player_labels(person, present)
    else:
        rgb, person = plate, np.zeros(plate.shape[:2], np.uint8)
    writer.write_kinect_rgb(i, noisy(rgb))
    writer.write_gt_person(i, person)
    n_vertices, n_bones = all_cast[0]["body"].n_vertices, all_cast[0]["body"].skeleton.n_bones
    gt = {"players": np.array([a["player"] for a in present], dtype=np.int64),
          "source_vertices": np.array(posed, dtype=np.float32).reshape(len(present), n_vertices, 3),
          "kinect_joints": np.array(truth_joints, dtype=np.float64).reshape(len(present), len(names), 3),
          "pose_rotations": np.array([a["poses"][i].rotations for a in present]).reshape(len(present), n_bones, 3),
          "pose_translations": np.array([a["poses"][i].translation for a in present]).reshape(len(present), 3),
          "reported": np.array([a["player"] in reported for a in present], dtype=bool)}
    if edited:
        gt["target_vertices"] = np.array(posed_target, dtype=np.float32).reshape(len(present), n_vertices, 3)
        if present:
            res, tperson, V, F = _labelled_render([(v, faces) for v in posed_target], sensor.color, room_depth_color)
            trgb = render_rgb(V, F, sensor.color, vertex_colors=albedo, background=plate, result=res)
            tperson = _player_labels(tperson, present)
        else:
            trgb, tperson = plate, person
        writer.write_gt_target_rgb(i, noisy(trgb))
        writer.write_gt_person(i, tperson, target=True)
    writer.write_gt_mirror(i, gt)


def _player_labels(labels: np.ndarray, present: list[dict]) -> np.ndarray:
    """Render order labels (1..len(present)) -> the actors' player ids."""
    lut = np.zeros(len(present) + 1, np.uint8)
    lut[1:] = [a["player"] for a in present]
    return lut[labels]
