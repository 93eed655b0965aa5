"""Ground truth for arm-muscle capture: arms that bulge, arm motions, Kinect arm sessions (issue 11 §1).

The muscle deformation model (our own construction, documented here; the statistical model of
:mod:`bodystudio.muscle.model` cannot express it exactly):

* **Anatomical regions** on each subject's rest arm (:class:`~bodystudio.muscle.arm.ArmTemplate`):
  with the upper-arm axis ``u`` (shoulder -> elbow), the forearm axis ``f`` and the anterior
  direction ``a`` (``f`` made orthogonal to ``u``: the side the elbow flexes towards), each vertex has
  a position ``t`` along the upper arm (0 shoulder, 1 elbow) and a radial direction ``r``. The biceps is
  ``exp(-((t - c_b) / s_b)^2) * max(0, r.a)^2`` (belly at ``c_b`` ~ 0.6), the triceps the same on the
  posterior side (``-a``, belly ~ 0.45), the deltoid a cap over the shoulder (``t`` ~ 0.1, lateral
  and upward radial directions).
* **Non-linear activation** of each muscle from the joint angles: ``smoothstep(x)^p`` with ``x`` the
  biceps' elbow flexion beyond ~35 deg (over 105 deg), the triceps' extension below ~60 deg, the
  deltoid's shoulder elevation beyond ~40 deg (``p`` ~ 0.8-1.3 per subject): slow onset, saturation,
  so the bulge is not linear in the rotation vectors.
* **Bulge** along the rest vertex normal, amplitude ``A0 * (0.2 + 0.8 m^1.3) / (1 + max(0, BMI - 21) / 7)``
  (``m`` muscularity; fat damps and widens the bulge); ``A0`` = 2 cm biceps, 1.2 cm triceps, 0.9 cm
  deltoid, so a muscular lean arm at full flexion bulges 1-2 cm.
* **Shortening and skin sliding**: the biceps belly moves towards the shoulder as it contracts and
  the skin over it slides along the bone towards the belly (tangential, up to ~5 mm).
* **Per-subject variation** (seeded by the subject): belly positions, widths, amplitudes, activation
  thresholds and exponents, and the anterior direction differ from person to person.
* **Forearm pronation** twists the forearm progressively (0 at the elbow, the whole angle at the wrist)
  instead of the rigid twist of the four-part skinning: the skin slides round the bones.

All displacements are rest-space correctives: the posed ground truth is
``skinning(v_rest + muscle_displacement(...))`` with the body's own skinning, which on the arm equals
:func:`~bodystudio.muscle.arm.pose_arm`.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np
from scipy.optimize import brentq
from scipy.spatial.transform import Rotation

from bodystudio.body import Phenotype, build_body, posed_joints
from bodystudio.body.population import sample_subject
from bodystudio.errors import InputError
from bodystudio.geometry.mesh import Mesh
from bodystudio.muscle.arm import (
    ArmPose,
    ArmTemplate,
    arm_pose_from_body_pose,
    arm_template,
    body_pose_from_arm_pose,
    pose_arm,
)

log = logging.getLogger(__name__)

ARM_MOTIONS = ("elbow_flex", "abduction", "pronation")
FPS = 30.0
#: the frame rates a synthetic arm session may be sampled at
MIN_SYNTH_FPS, MAX_SYNTH_FPS = 1.0, 240.0
# Peak bulge amplitudes (metres) of a fully active muscle of a maximally muscular lean arm.
BICEPS_AMPLITUDE_M = 0.020
TRICEPS_AMPLITUDE_M = 0.012
DELTOID_AMPLITUDE_M = 0.009
SKIN_SLIDE = 0.06  # tangential skin slide over the contracting biceps, per unit of upper-arm length


@dataclass(frozen=True)
class ArmSubject:
    """One synthetic person as the arm model sees them: body shape and the paper's shape parameters."""

    seed: int
    gender: float  # phenotype gender, 0 female .. 1 male
    phenotype: Phenotype
    local: dict = field(default_factory=dict)
    bmi: float = 22.0
    muscularity: float = 0.5  # phenotype muscle, 0..1
    height_m: float = 1.75
    arm_length_m: float = 0.55  # shoulder -> elbow -> wrist joint centres

    def summary(self) -> dict:
        """JSON-ready parameters (no phenotype object)."""
        return {"seed": self.seed, "gender": self.gender, "bmi": self.bmi, "muscularity": self.muscularity,
                "height_m": self.height_m, "arm_length_m": self.arm_length_m}

    def to_dict(self) -> dict:
        return {**self.summary(), "phenotype": self.phenotype.to_dict(), "local": dict(self.local)}


def _measure(phenotype: Phenotype, local: dict) -> tuple[float, float, float]:
    """(BMI, stature m, arm length m) of a subject (``model.measure_arm_shape``: 6k body, mass from volume)."""
    from bodystudio.muscle.model import measure_arm_shape

    p = measure_arm_shape(phenotype, local)
    return p.bmi, p.height_m, p.arm_length_m


def _solve_macro(phenotype: Phenotype, local: dict, name: str, target: float, index: int) -> Phenotype:
    """Phenotype with macro ``name`` set so that measurement ``index`` of :func:`_measure` hits ``target``."""
    def value(x):
        return _measure(Phenotype(**{**phenotype.to_dict(), name: float(x)}), local)[index] - target

    f_lo, f_hi = value(0.0), value(1.0)
    if not f_lo <= 0.0 <= f_hi:
        raise InputError(f"{name} target {target:.3g} is out of the body model's range "
                         f"[{f_lo + target:.3g}, {f_hi + target:.3g}] for this subject; choose a range inside it")
    x = brentq(value, 0.0, 1.0, xtol=1e-4, rtol=1e-6, maxiter=30)
    return Phenotype(**{**phenotype.to_dict(), name: float(x)})


@lru_cache(maxsize=256)
def _sample_arm_subject(seed: int, gender, bmi_range, muscularity_range, height_range_m) -> ArmSubject:
    rng = np.random.default_rng([seed, 11])
    phenotype, local = sample_subject(seed)
    values = phenotype.to_dict()
    if gender is not None:
        g = {"male": 1.0, "female": 0.0}.get(gender, gender)
        if not isinstance(g, (int, float)) or not 0 <= g <= 1:
            raise InputError(f"gender {gender!r} is not male, female or a value in [0, 1]")
        values["gender"] = float(g)
    if muscularity_range is not None:
        values["muscle"] = float(rng.uniform(*muscularity_range))
    phenotype = Phenotype(**values)
    if height_range_m is not None:
        phenotype = _solve_macro(phenotype, local, "height", float(rng.uniform(*height_range_m)), 1)
    if bmi_range is not None:
        target = float(rng.uniform(*bmi_range))
        # MakeHuman's weight macro spans a narrow BMI range at average muscle: very high or very low BMI
        # needs a less muscular body (as it does in people), unless the muscularity was asked for.
        factors = (1.0,) if muscularity_range is not None else (1.0, 0.6, 0.3, 0.0)
        for k, factor in enumerate(factors):
            try:
                trial = Phenotype(**{**phenotype.to_dict(), "muscle": phenotype.muscle * factor})
                phenotype = _solve_macro(trial, local, "weight", target, 0)
                break
            except InputError:
                if k == len(factors) - 1:
                    raise
    bmi, stature, arm_length = _measure(phenotype, local)
    return ArmSubject(seed, phenotype.gender, phenotype, dict(local), float(bmi), phenotype.muscle, float(stature),
                      float(arm_length))


def sample_arm_subject(seed: int, gender: str | float | None = None, bmi_range: tuple[float, float] | None = None,
                       muscularity_range: tuple[float, float] | None = None,
                       height_range_m: tuple[float, float] | None = None) -> ArmSubject:
    """A seeded arm subject: a population person, optionally forced into a gender and ranges.

    BMI and stature are reached by solving MakeHuman's weight and height macros (measured on the 6k
    body, mass from its volume); the same arguments always give the same person.
    """
    if int(seed) < 0:
        raise InputError(f"subject seed {seed} must be >= 0")
    for name, rng_ in (("bmi_range", bmi_range), ("muscularity_range", muscularity_range),
                       ("height_range_m", height_range_m)):
        if rng_ is not None and (len(rng_) != 2 or not rng_[0] <= rng_[1]):
            raise InputError(f"{name} must be (low, high) with low <= high, got {rng_!r}")
    if muscularity_range is not None and not 0 <= muscularity_range[0] <= muscularity_range[1] <= 1:
        raise InputError(f"muscularity_range {muscularity_range!r} must lie in [0, 1]")
    def pair(r):
        return None if r is None else (float(r[0]), float(r[1]))

    return _sample_arm_subject(int(seed), gender, pair(bmi_range), pair(muscularity_range), pair(height_range_m))


def subject_body(subject: ArmSubject, resolution: str = "6k"):
    """The subject's rigged body (BodyModel) at ``resolution``."""
    return build_body(subject.phenotype, subject.local, resolution=resolution)


# --- the muscle deformation model -------------------------------------------------------------------

@dataclass(frozen=True)
class MuscleVariation:
    """Per-subject anatomy and activation (drawn from the subject's seed)."""

    biceps_center: float = 0.6
    triceps_center: float = 0.45
    deltoid_center: float = 0.1
    width_scale: float = 1.0
    amplitudes: tuple = (1.0, 1.0, 1.0)  # biceps, triceps, deltoid factors
    thresholds_deg: tuple = (35.0, 60.0, 40.0)  # flexion onset, extension onset, elevation onset
    exponents: tuple = (1.7, 1.7, 1.7)
    anterior_twist_rad: float = 0.0
    slide: float = 1.0

    @classmethod
    def from_seed(cls, seed: int) -> MuscleVariation:
        rng = np.random.default_rng([seed, 2013])
        return cls(biceps_center=float(0.6 + rng.normal(0, 0.04)),
                   triceps_center=float(0.45 + rng.normal(0, 0.04)),
                   deltoid_center=float(0.1 + rng.normal(0, 0.03)),
                   width_scale=float(rng.uniform(0.85, 1.15)),
                   amplitudes=tuple(float(a) for a in rng.uniform(0.85, 1.15, 3)),
                   thresholds_deg=tuple(float(t) for t in np.array([35.0, 60.0, 40.0]) + rng.normal(0, 6.0, 3)),
                   exponents=tuple(float(e) for e in rng.uniform(1.3, 2.2, 3)),
                   anterior_twist_rad=float(rng.normal(0, np.deg2rad(8))),
                   slide=float(rng.uniform(0.5, 1.0)))


@dataclass(frozen=True)
class ArmAngles:
    """Anatomical angles of an ArmPose (degrees): elbow flexion, shoulder elevation, forearm twist."""

    flexion_deg: float
    elevation_deg: float
    pronation_deg: float


def _unit(x):
    return x / np.linalg.norm(x)


def _rest_axes(template: ArmTemplate):
    s, e, w = template.joints
    u = _unit(e - s)
    f = _unit(w - e)
    a = _unit(f - (f @ u) * u)
    return u, f, a


def anatomical_angles(template: ArmTemplate, pose: ArmPose) -> ArmAngles:
    """Elbow flexion (0 = straight), shoulder elevation from hanging (torso frame), forearm twist (same sign
    convention on both sides, as :func:`arm_pose_from_angles` takes it)."""
    u, f, _ = _rest_axes(template)
    R_s = Rotation.from_rotvec(pose.angles[0])
    R_e = Rotation.from_rotvec(pose.angles[1])
    flexion = np.degrees(np.arccos(np.clip(u @ R_e.apply(f), -1, 1)))
    elevation = np.degrees(np.arccos(np.clip(-R_s.apply(u)[1], -1, 1)))
    # Swing-twist: the twist of the elbow rotation about the rest forearm axis.
    q = R_e.as_quat()  # x, y, z, w
    proj = (q[:3] @ f) * f
    twist = 2 * np.arctan2(np.linalg.norm(proj) * np.sign(q[:3] @ f), q[3]) if np.linalg.norm(proj) > 0 else 0.0
    twist = (twist + np.pi) % (2 * np.pi) - np.pi
    sign = 1.0 if template.side == "left" else -1.0  # mirrored arms pronate the mirrored way
    return ArmAngles(float(flexion), float(elevation), float(sign * np.degrees(twist)))


def muscle_activations(angles: ArmAngles, variation: MuscleVariation) -> np.ndarray:
    """Non-linear activations (3,) in [0, 1] of biceps, triceps and deltoid from the joint angles."""
    tb, tt, td = variation.thresholds_deg
    x = np.array([(angles.flexion_deg - tb) / 105.0, (tt - angles.flexion_deg) / 60.0,
                  (angles.elevation_deg - td) / 60.0])
    x = np.clip(x, 0.0, 1.0)
    # Smoothstep: slow onset, saturation near the end of the range; the exponent varies per person.
    return (x * x * (3.0 - 2.0 * x)) ** (np.asarray(variation.exponents) / 1.7)


def muscle_amplitude_m(subject: ArmSubject) -> float:
    """Bulge scale factor of a subject: muscularity raises it, fat (BMI above 21) damps it."""
    return (0.2 + 0.8 * subject.muscularity ** 1.3) / (1.0 + max(0.0, subject.bmi - 21.0) / 7.0)


def muscle_displacement(template: ArmTemplate, subject: ArmSubject, arm_pose: ArmPose,
                        variation: MuscleVariation | None = None) -> np.ndarray:
    """Ground-truth rest-space muscle displacements (n, 3) of ``subject``'s arm in ``arm_pose`` (issue 11 §1).

    ``template`` is the subject's own arm (its rest vertices and joints). Add the result to the rest
    vertices before skinning.
    """
    var = variation or MuscleVariation.from_seed(subject.seed)
    V = template.vertices
    s, e, w = template.joints
    u, f, a = _rest_axes(template)
    a = Rotation.from_rotvec(u * var.anterior_twist_rad).apply(a)
    L_u = np.linalg.norm(e - s)
    rel = V - s
    t = rel @ u / L_u
    radial = rel - np.outer(rel @ u, u)
    r = radial / np.maximum(np.linalg.norm(radial, axis=1, keepdims=True), 1e-9)
    sign = 1.0 if template.side == "left" else -1.0
    lateral = _unit(np.array([sign, 1.0, 0.0]) - (np.array([sign, 1.0, 0.0]) @ u) * u)
    N = Mesh(V, template.faces).vertex_normals
    pw = template.part_weights
    limb = pw[:, 1] + pw[:, 2]
    angles = anatomical_angles(template, arm_pose)
    act = muscle_activations(angles, var)
    fat = max(0.0, subject.bmi - 21.0) / 10.0
    width = var.width_scale * (1.0 + 0.3 * fat)
    amp = muscle_amplitude_m(subject) * np.asarray(var.amplitudes)
    # Biceps: belly shortens towards the shoulder as it contracts.
    c_b = var.biceps_center - 0.06 * act[0]
    g_b = np.exp(-((t - c_b) / (0.22 * width)) ** 2) * np.clip(r @ a, 0, None) ** 2 * limb
    g_t = np.exp(-((t - var.triceps_center) / (0.25 * width)) ** 2) * np.clip(-(r @ a), 0, None) ** 2 * limb
    g_d = (np.exp(-((t - var.deltoid_center) / (0.2 * width)) ** 2) * np.clip(r @ lateral, 0, None) ** 1.5
           * (1.0 - pw[:, 3]))
    d = N * (BICEPS_AMPLITUDE_M * amp[0] * act[0] * g_b + TRICEPS_AMPLITUDE_M * amp[1] * act[1] * g_t
             + DELTOID_AMPLITUDE_M * amp[2] * act[2] * g_d)[:, None]
    # Skin sliding along the bone towards the contracting biceps belly (tangential).
    env = np.exp(-((t - c_b) / 0.4) ** 2) * np.clip(r @ a, 0, None) * limb
    d -= np.outer(SKIN_SLIDE * var.slide * act[0] * (t - c_b) * L_u * env * muscle_amplitude_m(subject), u)
    d += _pronation_slide(template, angles.pronation_deg)
    return d


def _pronation_slide(template: ArmTemplate, pronation_deg: float) -> np.ndarray:
    """Rest-space counter-twist so the forearm twists progressively (0 at the elbow, all at the wrist)."""
    if abs(pronation_deg) < 1e-6:
        return np.zeros_like(template.vertices)
    _, e, w = template.joints
    f = _unit(w - e)
    V = template.vertices
    s = np.clip((V - e) @ f / np.linalg.norm(w - e), 0.0, 1.0)
    # Skinning twists forearm-weighted points by the whole angle; undo (1 - s) of it at position s.
    world_deg = pronation_deg if template.side == "left" else -pronation_deg
    back = -np.deg2rad(world_deg) * (1.0 - s) * template.part_weights[:, 2]
    R = Rotation.from_rotvec(back[:, None] * f)
    return (R.apply(V - e) + e) - V


# --- arm motions ------------------------------------------------------------------------------------

def _elbow_rotvec(template: ArmTemplate, flexion_deg: float, pronation_deg: float) -> np.ndarray:
    u, f, _ = _rest_axes(template)
    axis = _unit(np.cross(u, f))
    rest_flex = np.degrees(np.arccos(np.clip(u @ f, -1, 1)))
    sign = 1.0 if template.side == "left" else -1.0
    R = Rotation.from_rotvec(axis * np.deg2rad(flexion_deg - rest_flex)) * \
        Rotation.from_rotvec(f * np.deg2rad(sign * pronation_deg))
    return R.as_rotvec()


def _shoulder_rotvec(template: ArmTemplate, elevation_deg: float, forward_deg: float = 0.0) -> np.ndarray:
    """Elevation in the frontal plane (abduction about +z for the left arm) plus a little forward flexion."""
    u, _, _ = _rest_axes(template)
    rest_elev = np.degrees(np.arccos(np.clip(-u[1], -1, 1)))
    sign = 1.0 if template.side == "left" else -1.0
    R = Rotation.from_rotvec(np.array([-1.0, 0.0, 0.0]) * np.deg2rad(forward_deg)) * \
        Rotation.from_rotvec(np.array([0.0, 0.0, sign]) * np.deg2rad(elevation_deg - rest_elev))
    return R.as_rotvec()


def arm_angle_sequence(motion: str, n_frames: int, seed: int = 0, fps: float = FPS) -> np.ndarray:
    """(n_frames, 4) elbow flexion, shoulder elevation, forearm pronation, forward flexion (degrees) at ``fps``
    (frame ``k`` shows time ``k / fps``: the same motion sampled at another rate).

    ``elbow_flex``: flexion 15-140 deg with abduction/adduction 30-70 deg (the paper's sequences);
    ``abduction``: elevation 20-95 deg, elbow slightly bent; ``pronation``: elbow at ~90 deg, forearm
    twist -30..+75 deg. One cycle per ~3.3 s; the seed varies phases and amplitudes.
    """
    if motion not in ARM_MOTIONS:
        raise InputError(f"unknown arm motion {motion!r}; valid: {', '.join(ARM_MOTIONS)}")
    if n_frames < 1:
        raise InputError(f"need at least one frame, got {n_frames}")
    if not (np.isfinite(fps) and MIN_SYNTH_FPS <= fps <= MAX_SYNTH_FPS):
        raise InputError(f"fps {fps}: must be in [{MIN_SYNTH_FPS:g}, {MAX_SYNTH_FPS:g}] (a depth camera's rate)")
    rng = np.random.default_rng([seed, 30])
    t = np.arange(n_frames) / float(fps)
    period = 3.3 * rng.uniform(0.9, 1.1)
    ph = rng.uniform(0, 2 * np.pi, 3)
    amp = rng.uniform(0.9, 1.0, 3)

    def wave(lo, hi, period_s, phase):
        return lo + (hi - lo) * (1 - np.cos(2 * np.pi * t / period_s + phase)) / 2

    out = np.zeros((n_frames, 4))
    out[:, 3] = 10.0 + 5.0 * np.sin(2 * np.pi * t / 7.0 + ph[2])
    if motion == "elbow_flex":
        out[:, 0] = wave(15.0, 15.0 + 125.0 * amp[0], period, 0.0)
        out[:, 1] = wave(30.0, 30.0 + 40.0 * amp[1], 2.1 * period, ph[1])
    elif motion == "abduction":
        out[:, 0] = 30.0 + 5.0 * np.sin(2 * np.pi * t / period + ph[0])
        out[:, 1] = wave(20.0, 20.0 + 75.0 * amp[1], period, 0.0)
    else:
        out[:, 0] = 90.0 + 5.0 * np.sin(2 * np.pi * t / 5.0 + ph[0])
        out[:, 1] = 40.0 + 5.0 * np.sin(2 * np.pi * t / 6.0 + ph[1])
        out[:, 2] = wave(-30.0, -30.0 + 105.0 * amp[2], period, 0.0)
    return out


def arm_pose_from_angles(template: ArmTemplate, flexion_deg: float, elevation_deg: float,
                         pronation_deg: float = 0.0, forward_deg: float = 0.0,
                         root: np.ndarray | None = None) -> ArmPose:
    """The ArmPose with the given anatomical angles (degrees) for this arm's rest joints."""
    angles = np.stack([_shoulder_rotvec(template, elevation_deg, forward_deg),
                       _elbow_rotvec(template, flexion_deg, pronation_deg), np.zeros(3)])
    return ArmPose(np.eye(4) if root is None else root, angles)


def arm_motion(template: ArmTemplate, motion: str, n_frames: int = 200, seed: int = 0,
               fps: float = FPS) -> list[ArmPose]:
    """ArmPoses of ``motion`` (sampled at ``fps``) for this arm (torso still)."""
    return [arm_pose_from_angles(template, *row[:3], forward_deg=row[3])
            for row in arm_angle_sequence(motion, n_frames, seed, fps)]


# --- ground-truth frames and the Kinect arm session ----------------------------------------------------

def posed_ground_truth(body, template: ArmTemplate, subject: ArmSubject, arm_pose: ArmPose,
                       variation: MuscleVariation | None = None):
    """Whole posed body (V, pose) with muscle bulges, and its arm vertices ``(n, 3)`` (the truth)."""
    side = template.side
    pose = body_pose_from_arm_pose(body, arm_pose, side)
    d = muscle_displacement(template, subject, arm_pose, variation)
    V_rest = body.vertices.copy()
    V_rest[template.vertex_ids] += d
    from bodystudio.body import linear_blend_skinning, skinning_transforms

    V = linear_blend_skinning(V_rest, body.weights, skinning_transforms(body.skeleton, pose))
    return V, pose, V[template.vertex_ids]


def arm_sensor(template: ArmTemplate, kinect: str = "v2", distance_m: float = 1.0, yaw_deg: float = 25.0):
    """Kinect placed ``distance_m`` from the middle of the upper arm, in front, turned towards the arm's side."""
    from bodystudio.geometry.camera import kinect_v1, kinect_v2

    if not 0.5 <= distance_m <= 4.0:
        raise InputError(f"distance_m={distance_m} is outside the Kinect's working range; use 0.8-1.2 m")
    s, e, _ = template.joints
    target = 0.5 * (s + e) + np.array([0.0, 0.0, 0.05])
    sign = 1.0 if template.side == "left" else -1.0
    yaw = np.deg2rad(yaw_deg)
    eye = target + distance_m * np.array([sign * np.sin(yaw), 0.1, np.cos(yaw)]) / np.linalg.norm([1.0, 0.1])
    if kinect == "v2":
        return kinect_v2(eye=tuple(eye), target=tuple(target))
    if kinect == "v1":
        return kinect_v1(eye=tuple(eye), target=tuple(target))
    raise InputError(f"kinect {kinect!r} is not a Kinect version; valid: v1, v2")


def synth_arm_session(out: str | os.PathLike, subject_seed: int = 0, motion: str = "elbow_flex", n_frames: int = 200,
                      kinect: str = "v2", distance_m: float = 1.0, seed: int = 0, resolution: str = "6k",
                      side: str = "left", noise: bool = True, subject: ArmSubject | None = None, fps: float = FPS):
    """Write a Kinect-only arm session (depth, tracker joints, calibration) with per-frame ground truth.

    Ground truth: ``gt/arm/NNNNN.ply`` (arm mesh in the ArmTemplate topology), ``gt/arm_pose/NNNNN.json``
    (ArmPose), ``gt/pose`` (body pose), ``gt/phenotype.json`` (subject, arm template key). ``subject``
    overrides ``subject_seed`` (e.g. an out-of-range subject from :func:`sample_arm_subject`). ``fps``: the rate the
    motion is sampled at (recorded as ``metadata.fps``; the motion's speed in seconds is the same at every rate).
    """
    from bodystudio.body.kinect import kinect_joint_names
    from bodystudio.capture.kinect import simulate_kinect_depth, simulate_tracker_joints
    from bodystudio.capture.session import SessionWriter, open_session
    from bodystudio.geometry.camera import CameraRig

    out = Path(out)
    if out.exists() and any(out.iterdir()):
        raise InputError(f"{out}: output folder exists and is not empty; choose a new folder")
    if seed < 0:
        raise InputError(f"seed {seed} must be >= 0")
    subject = subject or sample_arm_subject(subject_seed)
    body = subject_body(subject, resolution)
    template = arm_template(body, side)
    poses = arm_motion(template, motion, n_frames, seed, fps)
    sensor = arm_sensor(template, kinect, distance_m)
    rng = np.random.default_rng([seed, subject.seed, 4242])
    variation = MuscleVariation.from_seed(subject.seed)
    metadata = {"generator": "bodystudio synth arm", "subject_seed": subject.seed, "motion": motion, "seed": seed,
                "kinect": kinect, "template": resolution, "side": side, "fps": float(fps), "distance_m": distance_m,
                "arm_template_key": template.key, "noise": noise}
    with SessionWriter(out, CameraRig([]), source="synthetic", metadata=metadata) as writer:
        writer.write_gt_subject(subject.phenotype.to_dict(), subject.local, template=resolution, rig=body.rig,
                                n_vertices=body.n_vertices, bone_names=list(body.skeleton.bone_names),
                                arm={"side": side, "resolution": resolution, "template_key": template.key,
                                     "subject": subject.summary()})
        writer.write_kinect_calibration(sensor)
        for i, arm_pose in enumerate(poses):
            V, pose, V_arm = posed_ground_truth(body, template, subject, arm_pose, variation)
            writer.write_kinect_depth(i, simulate_kinect_depth(V, body.faces, sensor, rng, noise=noise))
            heads, tails = posed_joints(body.skeleton, pose)
            kw = {} if noise else {"noise_m": 0.0, "bone_length_jitter": 0.0}
            joints, tracked = simulate_tracker_joints(heads, tails, body.skeleton, kinect, rng, **kw)
            writer.write_kinect_joints(i, kinect_joint_names(kinect), joints, tracked, joint_set=kinect)
            writer.write_gt_arm_mesh(i, V_arm, template.faces)
            writer.write_gt_arm_pose(i, arm_pose_from_body_pose(body, pose, side).to_dict())
            writer.write_gt_pose(i, pose, body.skeleton.bone_names)
    log.info("wrote arm session %s: %d frames of %s", out, n_frames, motion)
    return open_session(out)


def session_arm_subject(session) -> dict:
    """The ``arm`` block of an arm session's ``gt/phenotype.json`` (side, resolution, template key, subject)."""
    gt = session.gt_subject or {}
    if "arm" not in gt:
        raise InputError(f"{session.path}: not an arm session (gt/phenotype.json has no 'arm'); "
                         "make one with `bodystudio synth arm`")
    return gt["arm"]


def session_arm_template(session) -> ArmTemplate:
    """The subject's own arm template of an arm session, rebuilt from ``gt/phenotype.json``."""
    arm = session_arm_subject(session)
    gt = session.gt_subject
    try:
        body = build_body(Phenotype.from_dict(gt["phenotype"]), gt.get("local") or {}, resolution=arm["resolution"])
        template = arm_template(body, arm["side"])
    except (KeyError, TypeError) as exc:
        raise InputError(f"{session.path}: gt/phenotype.json has no usable subject ({exc}); "
                         "regenerate the session with `bodystudio synth arm`") from None
    if arm.get("template_key") not in (None, template.key):
        raise InputError(f"{session.path}: session arm template {arm['template_key']} differs from the one rebuilt "
                         f"here ({template.key}); regenerate the session with this bodystudio")
    return template


__all__ = [
    "ARM_MOTIONS", "FPS", "ArmAngles", "ArmSubject", "MuscleVariation", "anatomical_angles", "arm_motion",
    "arm_angle_sequence", "arm_pose_from_angles", "arm_sensor", "muscle_activations", "muscle_amplitude_m",
    "muscle_displacement", "posed_ground_truth", "sample_arm_subject", "session_arm_subject", "session_arm_template",
    "subject_body", "synth_arm_session", "training_dataset", "subject_arm_samples", "random_arm_poses"
]


# --- the "previous high-fidelity dataset" ------------------------------------------------------------------

TRAINING_BMI_RANGE = (20.0, 28.0)
# The training women's BMI (``training_dataset(n_women=K)``): the population's women (``body.population``), 5-95 % of
# 143 of them measured as the subjects are (17.6-23.2; its men 19.7-24.4), rounded out to half units. The paper's
# dataset has no women; this is a range a user's model should know (docs/muscle.md, "Women in the capture").
TRAINING_BMI_RANGE_WOMEN = (17.5, 23.5)
# First seed of the training women (``WOMEN_SEED_BASE + 17 * seed + i``): their own seeds, apart from the men's
# 1000-1099 and the held-out subjects' 5xx-7xx.
WOMEN_SEED_BASE = 3000


def random_arm_poses(template: ArmTemplate, n_poses: int, seed: int, pronation: bool = True) -> list[ArmPose]:
    """``n_poses`` seeded poses over the captured range: flexion 10-145, elevation 15-100, twist -20..60 deg."""
    rng = np.random.default_rng([seed, 77])
    return [arm_pose_from_angles(template, rng.uniform(10, 145), rng.uniform(15, 100),
                                 rng.uniform(-20, 60) if pronation else 0.0, rng.uniform(-10, 30))
            for _ in range(n_poses)]


def subject_arm_samples(subject: ArmSubject, resolution: str = "6k", n_shapes: int = 3, n_poses: int = 24,
                        seed: int = 0, side: str = "left", name: str | None = None) -> list:
    """Ground-truth training meshes (``model.ArmSample``) of one subject: base-pose shapes + posed meshes.

    The ``n_shapes`` base-pose meshes differ by a few degrees of joint angle (as the paper's meshes
    "in the same pose as the base mesh" do); the posed meshes follow :func:`random_arm_poses`.
    """
    from bodystudio.muscle.model import ArmSample, ArmShapeParams

    body = subject_body(subject, resolution)
    T = arm_template(body, side)
    shape = ArmShapeParams(subject.bmi, subject.muscularity, subject.height_m, subject.arm_length_m,
                           sex=subject.gender)
    variation = MuscleVariation.from_seed(subject.seed)
    rng = np.random.default_rng([seed, subject.seed, 5])
    poses = [ArmPose(np.eye(4), rng.normal(0, np.deg2rad(2.0), (3, 3))) for _ in range(n_shapes)]
    poses += random_arm_poses(T, n_poses, seed * 1000 + subject.seed, pronation=True)
    name = name or f"subject_{subject.seed}"
    out = []
    for ap in poses:
        V = pose_arm(T.vertices + muscle_displacement(T, subject, ap, variation), T.part_weights, T.joints, ap)
        out.append(ArmSample(name, shape, V, ap, T.joints.copy()))
    return out


def training_dataset(resolution: str = "6k", n_subjects: int = 10, n_shapes: int = 3, n_poses: int = 24,
                     seed: int = 0, side: str = "left", n_women: int = 0) -> tuple[list, list[ArmSubject]]:
    """The paper's "previous high-fidelity dataset" as ground-truth meshes (§6.1, issue 11 §1).

    ``n_subjects`` men with BMI in 20-28 (seeds 1000 + 17 seed + i), each with ``n_shapes`` base-pose meshes and
    ``n_poses`` posed meshes; then ``n_women`` women drawn the same way from their own seeds
    (``WOMEN_SEED_BASE + 17 seed + i``) with the population's women's BMI (:data:`TRAINING_BMI_RANGE_WOMEN`). The
    paper's set is men only (``n_women=0``, the default): the model's sex column (Eq. 6's ``1 - sex``) stays zero and
    a woman's capture gets a man's arm (docs/muscle.md, "Capture, seventeenth pass"). The men are the same whatever
    ``n_women`` is. Returns (samples, subjects).
    """
    if int(n_subjects) < 0 or int(n_women) < 0:
        raise InputError(f"training_dataset: n_subjects={n_subjects} and n_women={n_women} must be >= 0")
    if int(n_subjects) + int(n_women) < 2:
        raise InputError(f"training_dataset: {n_subjects} men and {n_women} women; the arm model needs at least "
                         "two training subjects")
    subjects = [sample_arm_subject(1000 + 17 * seed + i, gender="male", bmi_range=TRAINING_BMI_RANGE)
                for i in range(n_subjects)]
    subjects += [sample_arm_subject(WOMEN_SEED_BASE + 17 * seed + i, gender="female",
                                    bmi_range=TRAINING_BMI_RANGE_WOMEN) for i in range(n_women)]
    samples = [s for subj in subjects for s in subject_arm_samples(subj, resolution, n_shapes, n_poses, seed, side)]
    return samples, subjects
