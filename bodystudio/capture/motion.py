"""Ground-truth motions: pose sequences from joint-angle keyframes, interpolated with rotation splines.

Keyframes are written anatomically, as rotations of each bone about axes of the rest-pose world frame
(y up, subject facing +z, left at +x): hip flexion is a rotation about -x, shoulder abduction of the
left arm about +z, and so on; elbow flexion uses the hinge axis measured from the subject's own rest
skeleton. Each keyframe rotation ``W`` of bone ``j`` becomes the local (Blender) rotation
``R_rest_j^T W R_rest_j`` of the Pose, so the motions work for any body shape. Keyframes are joined
by C2 quaternion splines (scipy ``RotationSpline``).

The motions are those the capture papers record: a static A-pose and T-pose (model initialisation of
Richter et al.), raising the arms, walking and turning on the spot (Rapid Skin's studio sequences),
and elbow flexion/extension with shoulder abduction/adduction (Robertini et al., Sec. 8.1).
A seed varies amplitudes, phases and posture slightly, so each synthetic subject moves a little
differently; the same seed always gives the same sequence.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation, RotationSpline

from bodystudio.body.pose import Pose
from bodystudio.body.skeleton import Skeleton
from bodystudio.errors import InputError

MOTIONS = ("a_pose", "t_pose", "arms_raise", "walk", "turn", "arm_flex")

X, Y, Z = np.eye(3)


@dataclass(frozen=True)
class Keyframe:
    """Bone rotations in rest-pose world axes at normalised time ``time`` in [0, 1], plus root translation."""

    time: float
    rotations: dict = field(default_factory=dict)  # bone name -> scipy Rotation (rest world axes)
    translation: tuple = (0.0, 0.0, 0.0)


def world_to_local_rotvecs(skeleton: Skeleton, world_rotvecs: np.ndarray) -> np.ndarray:
    """Local axis-angle (B, 3) of rotations given about rest-pose world axes (B, 3): ``R_rest^T w``."""
    return np.einsum("bji,bj->bi", skeleton.rest_rotations, world_rotvecs)


def keyframes_to_poses(skeleton: Skeleton, keyframes: list[Keyframe], n_frames: int,
                       cyclic: bool = False, times: np.ndarray | None = None) -> list[Pose]:
    """Sample ``n_frames`` poses uniformly over [0, 1] from keyframes joined by rotation splines.

    A ``cyclic`` motion ends where it starts, so its last sample stops one step short of the end
    (otherwise short sequences would repeat the first pose). ``times`` (n_frames,) in the keyframes'
    time range samples there instead (fps-based sampling, :func:`motion_sequence`).
    """
    if n_frames < 1:
        raise InputError(f"a motion needs at least one frame, got n_frames={n_frames}")
    keyframes = sorted(keyframes, key=lambda k: k.time)
    times_k = np.array([k.time for k in keyframes], dtype=np.float64)
    if np.any(np.diff(times_k) <= 0):
        raise InputError("motion keyframe times must be distinct")
    if times is None:
        t = np.linspace(times_k[0], times_k[-1], n_frames, endpoint=not cyclic or n_frames == 1)
    else:
        t = np.clip(np.asarray(times, dtype=np.float64).reshape(n_frames), times_k[0], times_k[-1])
    bones = sorted({b for k in keyframes for b in k.rotations})
    world = np.zeros((n_frames, skeleton.n_bones, 3))
    for bone in bones:
        j = skeleton.index(bone)
        keys = Rotation.concatenate([k.rotations.get(bone, Rotation.identity()) for k in keyframes])
        if len(keyframes) == 1:
            world[:, j] = keys.as_rotvec()[0]
        else:
            world[:, j] = RotationSpline(times_k, keys)(t).as_rotvec()
    trans = np.array([k.translation for k in keyframes], dtype=np.float64)
    translations = np.stack([np.interp(t, times_k, trans[:, d]) for d in range(3)], axis=1)
    R_rest = skeleton.rest_rotations
    return [Pose(np.einsum("bji,bj->bi", R_rest, world[f]), translations[f]) for f in range(n_frames)]


# --- anatomical joint rotations measured on the subject's skeleton ------------------------------------

def _direction(skeleton: Skeleton, bone: str) -> np.ndarray:
    j = skeleton.index(bone)
    d = skeleton.tails[j] - skeleton.heads[j]
    return d / np.linalg.norm(d)


def _align(a: np.ndarray, b: np.ndarray) -> Rotation:
    """Smallest rotation taking unit direction ``a`` onto ``b``."""
    axis = np.cross(a, b)
    s, c = np.linalg.norm(axis), float(np.dot(a, b))
    if s < 1e-12:
        return Rotation.identity()
    return Rotation.from_rotvec(axis / s * np.arctan2(s, c))


def _rot(axis, degrees: float) -> Rotation:
    axis = np.asarray(axis, dtype=np.float64)
    return Rotation.from_rotvec(axis / np.linalg.norm(axis) * np.radians(degrees))


def elbow_flexion(skeleton: Skeleton, side: str, degrees: float) -> Rotation:
    """Lower-arm rotation (rest world axes) giving ``degrees`` of elbow flexion from a straight arm.

    The hinge axis is the normal of the plane of the rest upper and lower arm; 0 degrees straightens
    the arm, the rest bend gives the identity.
    """
    upper, lower = _direction(skeleton, f"upperarm_{side}"), _direction(skeleton, f"lowerarm_{side}")
    axis = np.cross(lower, upper)
    rest_flexion = np.degrees(np.arctan2(np.linalg.norm(axis), np.dot(lower, upper)))
    return Rotation.from_rotvec(axis / np.linalg.norm(axis) * np.radians(rest_flexion - degrees))


def arm_elevation(skeleton: Skeleton, side: str, degrees: float) -> Rotation:
    """Upper-arm abduction in the frontal plane to ``degrees`` above the horizontal (-90 hangs down)."""
    d = _direction(skeleton, f"upperarm_{side}")
    lateral = 1.0 if side == "l" else -1.0
    a = np.radians(degrees)
    target = np.array([lateral * np.cos(a), np.sin(a), 0.0])
    d_frontal = np.array([d[0], d[1], 0.0]) / np.linalg.norm(d[:2])
    # abduct within the frontal plane (rotation about z), keeping the small rest forward component
    angle = np.arctan2(np.cross(d_frontal, target)[2], np.dot(d_frontal, target))
    return Rotation.from_rotvec(Z * angle)


def _straight_arm_pose(skeleton: Skeleton, elevation_deg: float, elbow_deg: float = 0.0,
                       clavicle_deg: float = 0.0) -> dict:
    rot = {}
    for side, sign in (("l", 1.0), ("r", -1.0)):
        rot[f"upperarm_{side}"] = arm_elevation(skeleton, side, elevation_deg)
        rot[f"lowerarm_{side}"] = elbow_flexion(skeleton, side, elbow_deg)
        if clavicle_deg:
            rot[f"clavicle_{side}"] = _rot(Z * sign, clavicle_deg)
    return rot


def _rest_arm_elevation(skeleton: Skeleton, side: str) -> float:
    d = _direction(skeleton, f"upperarm_{side}")
    return float(np.degrees(np.arctan2(d[1], abs(d[0]))))


# --- the motions ----------------------------------------------------------------------------------

def _posture_noise(rng: np.random.Generator, scale_deg: float = 2.0) -> dict:
    """Small static posture differences (spine, neck, head) of a subject."""
    return {bone: Rotation.from_rotvec(np.radians(rng.normal(0.0, scale_deg, 3)))
            for bone in ("spine_02", "neck_01", "head")}


def _compose(*dicts: dict) -> dict:
    out: dict = {}
    for d in dicts:
        for bone, r in d.items():
            out[bone] = r * out[bone] if bone in out else r
    return out


def _t_pose_keys(skeleton, rng) -> list[Keyframe]:
    posture = _posture_noise(rng)
    elevation = rng.normal(0.0, 2.0)
    return [Keyframe(0.0, _compose(_straight_arm_pose(skeleton, elevation), posture))]


def _arms_raise_keys(skeleton, rng) -> list[Keyframe]:
    posture = _posture_noise(rng)
    top = 70.0 + rng.normal(0.0, 4.0)  # arms raised to ~70 degrees above horizontal
    rest_l = _rest_arm_elevation(skeleton, "l")
    keys = [Keyframe(0.0, posture)]
    for time, elevation_frac in ((0.25, 0.5), (0.5, 1.0), (0.75, 0.5)):
        elevation = rest_l + elevation_frac * (top - rest_l)
        elbow = 20.0 * (1 - elevation_frac)
        clav = 15.0 * elevation_frac
        keys.append(Keyframe(time, _compose(_straight_arm_pose(skeleton, elevation, elbow, clav), posture)))
    keys.append(Keyframe(1.0, posture))
    return keys


def _walk_keys(skeleton, rng, cycles: int = 2) -> list[Keyframe]:
    """Marching on the spot: alternate hip and knee flexion with counter-swinging arms."""
    posture = _posture_noise(rng)
    hip = 40.0 * rng.uniform(0.85, 1.15)
    knee = 70.0 * rng.uniform(0.85, 1.15)
    arm_swing = 25.0 * rng.uniform(0.8, 1.2)
    arms_down = -75.0 + rng.normal(0.0, 3.0)  # arms hang near the body while walking
    keys = []
    steps = 8 * cycles
    for k in range(steps + 1):
        phase = 2 * np.pi * k / 8 + np.pi / 2  # start mid-stride (left knee up): no two half-cycles look alike
        lift_l, lift_r = max(0.0, np.sin(phase)), max(0.0, -np.sin(phase))
        rot = {
            "thigh_l": _rot(-X, hip * lift_l), "calf_l": _rot(X, knee * lift_l), "foot_l": _rot(X, 15 * lift_l),
            "thigh_r": _rot(-X, hip * lift_r), "calf_r": _rot(X, knee * lift_r), "foot_r": _rot(X, 15 * lift_r),
            "pelvis": _rot(Y, 4.0 * np.sin(phase)),
        }
        for side, swing in (("l", -np.sin(phase)), ("r", np.sin(phase))):
            rot[f"upperarm_{side}"] = _rot(-X, arm_swing * swing) * arm_elevation(skeleton, side, arms_down)
            rot[f"lowerarm_{side}"] = elbow_flexion(skeleton, side, 20.0 + 10.0 * max(0.0, swing))
        keys.append(Keyframe(k / steps, _compose(rot, posture)))
    return keys


def _turn_keys(skeleton, rng) -> list[Keyframe]:
    """A full turn on the spot about the vertical axis (root rotation about world y)."""
    posture = _posture_noise(rng)
    direction = 1.0 if rng.random() < 0.5 else -1.0
    arms = _straight_arm_pose(skeleton, -60.0 + rng.normal(0.0, 3.0), 15.0)
    keys = []
    for k in range(9):
        rot = _compose(arms, posture)
        rot["Root"] = _rot(Y, direction * 45.0 * k)
        keys.append(Keyframe(k / 8, rot))
    return keys


def _arm_flex_keys(skeleton, rng, cycles: int = 2) -> list[Keyframe]:
    """Elbow flexion/extension with shoulder abduction/adduction (Robertini et al., Sec. 8.1)."""
    posture = _posture_noise(rng, 1.0)
    flex_max = 120.0 * rng.uniform(0.9, 1.05)
    abduct_max = 80.0 * rng.uniform(0.9, 1.1)
    keys = []
    steps = 8 * cycles
    for k in range(steps + 1):
        phase = 2 * np.pi * k / 8
        flex = 10.0 + (flex_max - 10.0) * 0.5 * (1 - np.cos(phase))  # elbow: extension -> flexion -> extension
        abduct = 0.5 * (1 - np.cos(phase / 2))  # shoulder: adduction -> abduction over two elbow cycles
        elevation = -80.0 + abduct * abduct_max
        rot = {}
        for side in ("l", "r"):
            rot[f"upperarm_{side}"] = arm_elevation(skeleton, side, elevation)
            rot[f"lowerarm_{side}"] = elbow_flexion(skeleton, side, flex)
        keys.append(Keyframe(k / steps, _compose(rot, posture)))
    return keys


CYCLIC_MOTIONS = ("walk", "turn", "arm_flex")


def motion_keyframes(name: str, skeleton: Skeleton, seed: int = 0, cycles: int = 2) -> list[Keyframe]:
    """The keyframes of motion ``name`` (one of MOTIONS) for ``skeleton``, varied by ``seed``.

    ``cycles`` is the number of strides of ``walk`` and elbow cycles of ``arm_flex``.
    """
    if name not in MOTIONS:
        raise InputError(f"unknown motion {name!r}; valid motions: {', '.join(MOTIONS)}")
    rng = np.random.default_rng(seed)
    if name == "a_pose":
        return [Keyframe(0.0)]
    if name in ("walk", "arm_flex"):
        return {"walk": _walk_keys, "arm_flex": _arm_flex_keys}[name](skeleton, rng, cycles)
    return {"t_pose": _t_pose_keys, "arms_raise": _arms_raise_keys, "turn": _turn_keys}[name](skeleton, rng)


#: Seconds one pass through a motion's keyframes takes at natural speed (two gait cycles of ``walk``: a
#: stride of ~1.1 s; two elbow cycles of ``arm_flex``), for sampling at a frame rate.
MOTION_PERIOD_S = {"a_pose": 1.0, "t_pose": 1.0, "arms_raise": 4.0, "walk": 2.2, "turn": 8.0, "arm_flex": 5.0}


def motion_sequence(name: str, n_frames: int, skeleton: Skeleton, seed: int = 0,
                    fps: float | None = None) -> list[Pose]:
    """Ground-truth pose sequence of ``n_frames`` frames for motion ``name`` (see MOTIONS).

    ``a_pose`` is the static rest pose; ``t_pose`` a static T-pose; ``arms_raise``, ``walk`` (on the
    spot), ``turn`` (a full turn about the vertical) and ``arm_flex`` span the whole sequence. Walks
    and arm flexions shorter than 60 frames make one cycle, so even a few frames show distinct poses.

    With ``fps`` the motion plays at its natural speed instead (:data:`MOTION_PERIOD_S`), sampled at
    that frame rate: frame ``k`` shows time ``k / fps``, and the motion repeats (every motion starts
    and ends in the same posture) for as long as the frames last.
    """
    if fps is not None:
        if not np.isfinite(fps) or fps <= 0:
            raise InputError(f"fps must be a positive frame rate, got {fps}")
        if n_frames < 1:
            raise InputError(f"a motion needs at least one frame, got n_frames={n_frames}")
        keys = motion_keyframes(name, skeleton, seed, 2)
        phase = (np.arange(n_frames) / float(fps) / MOTION_PERIOD_S[name]) % 1.0
        return keyframes_to_poses(skeleton, keys, n_frames, times=phase)
    cycles = 1 if n_frames < 60 else 2
    keys = motion_keyframes(name, skeleton, seed, cycles)
    return keyframes_to_poses(skeleton, keys, n_frames, cyclic=name in CYCLIC_MOTIONS)
