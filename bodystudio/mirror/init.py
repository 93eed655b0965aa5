"""Source-body initialisation, §4 of Real-time Reshaping of Humans: the actor's shape from a few seconds of Kinect data.

Per frame (§4 "Transformation of point cloud into default pose"):

1. bone scaling: the default body ``B_0^D`` gets the bone lengths of the Kinect skeleton, each bone
   stretched along its axis about its head (vertex offsets scale along the bone with it);
2. IK down the chains (:func:`bodystudio.mirror.track.ik_pose`) poses ``B^D`` onto the Kinect joints;
3. each depth point takes the closest vertex of the posed ``B^D`` (among the vertices facing the
   sensor) as its correspondence and that vertex's skin weights;
4. the inverse of the blended bone transforms (inverse LBS) brings the point cloud to the default pose.

Then the statistical model's coefficients are fitted to the unposed cloud by Eq. 2 (point to
closest-vertex distances). Deviations from the paper, each measured (docs/mirror.md):

* Eq. 2 is solved exactly as linear least squares for fixed matches (with a global translation and a
  weak Gaussian prior on the coefficients) and re-matched 40/20 times, instead of gradient descent.
  The first matches are the closest vertices of the posed ``B^D`` (so points on the knee match knee
  vertices), later ones closest vertices in the default pose.
* The frames are combined by pooling their unposed clouds into one fit (the least-squares average of
  the per-frame problems) rather than averaging per-frame coefficients: closest-point fits converge
  slowly along directions that slide vertices along the surface (stature), and one well-converged
  pooled fit is cheaper than many per-frame ones.
* From the second pass on (``B^D`` := the first pass's shape, better matches and joint pivots), the
  tracked Kinect joints, unposed by the inverse transform of the bone carrying each, are matched too
  (weight :data:`JOINT_WEIGHT` per joint): only the front of the body is seen, and the joints pin the
  limb lengths and stature that the surface alone leaves loose.
* From the second pass on, each frame's IK pose is refined against the SDK's player mask in the depth image, the
  depth points and the joints (:func:`refined_init_pose`, one step of ``mirror.refine.refine_pose``) before the
  closest-vertex correspondences and the inverse LBS: the IK's trunk and root are degrees off, and the cloud
  unposed by them bends the shape fit; with 5 passes (the fit was still converging after 3) the posed vertex error
  falls from 11.1 to 7.5 mm on 9 sessions (MIR12i).
* Optionally (``bone_length_weight``, off by default; MIR12o) the SDK's joint distances (bone lengths, shoulder and
  hip width), averaged over the init frames, are matched too: pose-free, so without the unposing's error.
* Every pass fits every pooled point, weighted so the pool weighs as :data:`MAX_POOLED_POINTS` (not a fresh random
  subset per pass, whose draw moved the result), and from the third pass on the unposing holds the trunk at the
  subject's own posture (:data:`WEIGHTED_POOL`, :data:`UNPOSE_POSTURE_BONES`; the default since mir12y).
* Every pass also holds each leg's rest knee angle (the calf's splay against the thigh) at the one the SDK's hip, knee
  and ankle give over every frame of the init's window (:func:`sdk_knee_angle`, :func:`knee_angle_rows`): the unposing
  makes any rest calf self-consistent, and the population carries a splayed calf into the hips and the mass
  (:data:`KNEE_HINGE_FROM`; the default since mir12ac).

The skeleton is refitted by Eq. 3 (each joint moves with the mean displacement of the vertices around it).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from functools import cached_property, lru_cache
from pathlib import Path

import numpy as np
from numba import njit
from scipy.spatial import cKDTree

from bodystudio.body.kinect import KINECT_JOINT_SETS, kinect_joint_names
from bodystudio.body.kinect import kinect_joints as skeleton_kinect_joints
from bodystudio.body.model import BodyModel
from bodystudio.body.skeleton import Skeleton
from bodystudio.body.skinning import inverse_linear_blend_skinning, skinning_transforms
from bodystudio.body.statistical import StatisticalBodyModel
from bodystudio.errors import FileFormatError, InputError
from bodystudio.fileio import atomic_path
from bodystudio.mirror.track import UNTWIST_BONES, V1_NAMES, check_kinect_joints, ik_pose, skin_vertices, untwisted_pose

log = logging.getLogger(__name__)

SOURCE_BODY_VERSION = 1
DEFAULT_INIT_FRAMES = 90
#: Bones scaled to the Kinect skeleton: (bones, parent joint, child joint) by Kinect v2 names.
BONE_SCALE_SEGMENTS = (
    (("spine_01",), "SpineBase", "SpineMid"),
    (("spine_02", "spine_03"), "SpineMid", "SpineShoulder"),
    (("neck_01", "head"), "SpineShoulder", "Head"),
    (("clavicle_l",), "SpineShoulder", "ShoulderLeft"),
    (("clavicle_r",), "SpineShoulder", "ShoulderRight"),
    (("upperarm_l",), "ShoulderLeft", "ElbowLeft"),
    (("upperarm_r",), "ShoulderRight", "ElbowRight"),
    (("lowerarm_l",), "ElbowLeft", "WristLeft"),
    (("lowerarm_r",), "ElbowRight", "WristRight"),
    (("thigh_l",), "HipLeft", "KneeLeft"),
    (("thigh_r",), "HipRight", "KneeRight"),
    (("calf_l",), "KneeLeft", "AnkleLeft"),
    (("calf_r",), "KneeRight", "AnkleRight"),
    (("foot_l",), "AnkleLeft", "FootLeft"),
    (("foot_r",), "AnkleRight", "FootRight"),
)
_BONE_SCALE_RANGE = (0.75, 1.33)
#: A depth point farther than this from the posed body is not the actor (mask jitter, flying pixels).
MAX_CORRESPONDENCE_M = 0.08
#: Points kept per frame (a random subset, fixed seed): the fit needs no more.
MAX_POINTS = 2500
#: Fewer person points than this and the frame is not used.
MIN_POINTS = 300
#: collect_observations reads every this-many-th frame of the initialisation window.
INIT_FRAME_STRIDE = 3
#: At most this many frames enter the fit.
MAX_FIT_FRAMES = 15
#: Which MAX_FIT_FRAMES of more usable frames enter the fit. "first": the ones with the most person points after
#: each frame's cloud is cut to MAX_POINTS, which every frame of a walk-in reaches, so in practice the first ones (a
#: walk-in: all side-on); "spread": evenly spread over the usable frames, so a walk-in's side-on, turning and facing
#: views all enter (mir12w: the shape of session 57, 3.45 kg heavy from the side-on frames, 0.72 kg; docs/mirror.md).
INIT_FRAME_CHOICE = "first"
#: Points of all frames' default-pose clouds pooled into one Eq. 2 fit (a random subset).
MAX_POOLED_POINTS = 6000
#: Closest-point re-matchings of the Eq. 2 fit in the first and later passes (the fit converges
#: linearly along the shape directions that move vertices along the surface, e.g. stature).
ICP_ITERATIONS = (40, 20)
#: Passes of the initialisation (each redoes the transform to the default pose with the previous pass's shape, then
#: Eq. 2): the fit was still converging after 3 (MIR12i: the posed vertex error on 9 sessions 11.1 mm with 3 passes,
#: 9.8 with 4, 8.6 with 4 and the refined unposing, 7.5 with 5 and the refined unposing; docs/mirror.md).
INIT_PASSES = 5
#: From the second pass on, each frame's IK pose is refined by this many steps of ``refine.refine_pose`` against
#: the SDK player mask in the depth image, the depth and the joints before the correspondences and the inverse LBS
#: (:func:`refined_init_pose`; 0: the IK's pose, as the paper).
UNPOSE_REFINE_STEPS = 1
#: Weight of one unposed Kinect joint relative to one depth point in the shape fit (later passes).
JOINT_WEIGHT = 3.0
#: Per-coordinate noise (metres) that sets the weight of the shape prior in Eq. 2.
POINT_SIGMA_M = 0.01
#: Kinect joint pairs whose distance (a bone length, or the shoulder / hip width) the shape fit matches to the
#: SDK's, averaged over every init frame (:func:`kinect_bone_lengths`). A distance between two joints does not
#: depend on the pose, so unlike the unposed joints it carries no unposing error: on the walking sessions the
#: fitted body's shoulders came out 15 mm too wide (42) or 9 mm too narrow (46) while the SDK's mean over the
#: ~80 tracked frames of the init window was within 2 mm (42) / 5 mm (46) of the truth, over the every-third frames
#: the init reads within 8 mm (docs/mirror.md, MIR12o).
BONE_PAIRS = (("ShoulderLeft", "ShoulderRight"), ("ShoulderLeft", "ElbowLeft"), ("ElbowLeft", "WristLeft"),
              ("ShoulderRight", "ElbowRight"), ("ElbowRight", "WristRight"), ("HipLeft", "HipRight"),
              ("HipLeft", "KneeLeft"), ("KneeLeft", "AnkleLeft"), ("HipRight", "KneeRight"),
              ("KneeRight", "AnkleRight"), ("SpineBase", "SpineShoulder"), ("SpineShoulder", "Neck"),
              ("Neck", "Head"))
#: Weight of one frame's measured joint distance in the shape fit, in units of one depth point (whose noise is
#: POINT_SIGMA_M per coordinate): the mean over the n frames that measure a pair enters with n times this weight,
#: as the n frames' own residuals would (a session's init: 19-28 frames per pair). 0 (the default) leaves the distances
#: out; 1 is the option measured in docs/mirror.md (MIR12o): a better source shape on the walking sessions, but the
#: Eq. 4 target's displacement, steep in some source coefficient directions, lost a held-out session's
#: warp_iou (46: -0.003), so it stays off.
BONE_LENGTH_WEIGHT = 0.0
#: The pairs of :data:`BONE_PAIRS` that stand between the floor and the top of the head: thighs, shins, spine, neck and
#: head (mir12ad). A fit that leaves the stature to the depth points and the unposed joints can get a subject's shins
#: short (54: the fitted shins 12.9 mm short of the truth, the SDK's mean 1.8 / 4.0 mm; stature -10.5 mm), and these
#: distances carry no unposing error. With ``bone_length_weight=3.0`` (:data:`STATURE_BONE_LENGTH_WEIGHT`) on these
#: pairs alone the 16 synthetic sessions' Eq. 4 displacement error and rest error fall (docs/mirror.md, mir12ad).
STATURE_BONE_PAIRS = (("HipLeft", "KneeLeft"), ("KneeLeft", "AnkleLeft"), ("HipRight", "KneeRight"),
                      ("KneeRight", "AnkleRight"), ("SpineBase", "SpineShoulder"), ("SpineShoulder", "Neck"),
                      ("Neck", "Head"))
STATURE_BONE_LENGTH_WEIGHT = 3.0
#: Which pairs of :data:`BONE_PAIRS` the joint-distance term matches when ``bone_length_weight`` > 0 (None: all).
BONE_LENGTH_PAIRS: tuple | None = None
#: Outlier rejections of the initialisation, both measured from the *current shape estimate* (the mean body
#: in the first pass): a depth point farther than INIT_CORRESPONDENCE_M from the posed B^D is not used, and
#: in Eq. 2 a pair farther than FIT_TRIM_M after the first matching is dropped. With the tight values first
#: used (8 cm / 5 cm) the points of a body fuller than the estimate (belly, chest, buttocks of a heavy
#: subject) were the ones dropped, so the fit stayed near the mean: on the synthetic mirror sessions every
#: subject came out light, heavy ones by 3-4 kg. The player mask already separates the person from the room;
#: what remains (wall pixels where the mask overshoots, flying pixels) lies far behind the body and is still
#: rejected (docs/mirror.md, "Mass bias").
INIT_CORRESPONDENCE_M = 0.15
FIT_TRIM_M = 0.10
#: Init frames (evenly spread over the fitted ones) of the optional shape refinement against the silhouettes
#: (:mod:`bodystudio.mirror.shape_refine`, ``mirror init --silhouette-shape``): 6 cost ~2.5 s CPU.
SILHOUETTE_FRAMES = 6
#: Body vertices the depth camera sees more obliquely than acos(INIT_FACING_COS) = 75 degrees take no
#: depth points. The Kinect returns no depth beyond ~80 degrees (capture.kinect.KINECT_NOISE.grazing_angle_deg):
#: the sides of the torso and limbs are never measured, and when their vertices could still be matched,
#: points near the visible edge pulled them in and the body came out narrow (light).
INIT_FACING_COS = 0.26
#: SDK trunk joints :func:`refit_trunk_joints` moves the source skeleton's joints to (their mean position in the
#: default pose, each frame unposed by the refined pose of the fitted body), and the bone ends each one is:
#: ``mirror init --trunk-refit``, MIR12r. The statistical model's joint regressor puts the joints where the fitted
#: *surface* puts them, and a joint deep inside the trunk (SpineShoulder, the top of spine_03) is the one it places
#: worst against that surface: 5-9 mm forward of it on four of ten sessions, which leans the IK's upper spine back
#: (docs/mirror.md).
TRUNK_REFIT_JOINTS = {"SpineMid": (("spine_02", "head"), ("spine_01", "tail")),
                      "SpineShoulder": (("spine_03", "tail"),),
                      "Neck": (("neck_01", "head"),)}
#: Rounds of :func:`refit_trunk_joints` (each poses the body again on the moved joints before unposing them).
TRUNK_REFIT_ROUNDS = 2
#: Trunk bones whose E_trunk centre the refined unposing (:func:`refined_init_pose`) takes from the subject's own
#: static posture, the mean over the previous pass's refined poses (:func:`session_posture`), instead of the rest
#: pose; empty: the rest pose (the default). E_trunk at rest straightens a person's habitual stoop in every unposed
#: frame, and the shape fit takes up what is left of it: on 52 (a 5 degree stoop at spine_02) the fitted body's
#: chest came out 16 mm small and its hips 17 mm wide, and the Eq. 4 displacement of a -17 cm / -15 kg edit 4.6 mm
#: off the truth's (0.8 on 42, the same subject upright). ``mirror init --unpose-posture`` (mir12v, docs/mirror.md).
#: The default since mir12y, with :data:`WEIGHTED_POOL`: settled, the two lower the Eq. 4 displacement error below
#: main's expected value over 8 random draws (held out 1.79 -> 1.68 mm, 9 of 12 sessions lower; docs/mirror.md).
UNPOSE_POSTURE_BONES: tuple[str, ...] = ("spine_02", "neck_01", "head")
#: From the second pass on, the init's coefficients move this fraction of the way to each pass's Eq. 2 fit (1: the
#: fit itself, the paper's). mir12x, docs/mirror.md.
PASS_RELAXATION = 1.0
#: Every pass pools the same subset of each frame's depth points (False: a fresh random subset per pass). mir12x.
FIXED_POOL = False
#: Every pass pools every depth point, each weighted MAX_POOLED_POINTS / N (False: a fresh random subset per pass,
#: whose sampling noise moved the Eq. 4 displacement error 1-4 mm from pass to pass). On 16 sessions the error's range
#: over passes 4-8 1.60 / 1.06 -> 0.28 / 0.35 mm (tuning / held out), its mean 2.25 / 1.89 -> 1.82 / 1.72, warp_iou
#: +0.0011 on average; but it rises on 6 of 12 held-out sessions and the fit costs 2.2 -> 5.3 s CPU: off (mir12x,
#: docs/mirror.md). The default since mir12y, with :data:`UNPOSE_POSTURE_BONES`: the fit's matchings made cheap (the
#: init 1.7 s CPU on 52), and measured against main's init over 8 random draws per session instead of one (the held-out
#: displacement error 1.79 -> 1.68 mm; docs/mirror.md).
WEIGHTED_POOL = True
#: Seed of the fixed pool's per-point keys (with the frame number).
POOL_KEY_SEED = 0
#: The bones ``--unpose-posture`` centres (MIR12q's: the bones whose static bend the run's E_trunk shrinks).
POSTURE_BONES = ("spine_02", "neck_01", "head")
#: Lower legs :func:`leg_splay_basis` turns about each knee: (the calf bone, the bones below the knee it carries).
LEG_SPLAY_CHAINS = (("calf_l", ("calf_l", "foot_l", "ball_l")), ("calf_r", ("calf_r", "foot_r", "ball_r")))
#: Prior of the legs' free rest rotations in Eq. 2 (radians, each axis): ~6 degrees, twice the splay mir12z found.
LEG_SPLAY_SIGMA_RAD = 0.1
#: The legs' rest rotations solved with the shape as nuisance parameters (``initialise_from_observations``'s
#: ``leg_splay``; off, mir12ab).
LEG_SPLAY = False
#: Weight of each leg's knee-hinge row in Eq. 2 (:func:`knee_hinge_splay_rows`, :func:`knee_angle_rows`), in depth
#: points; 0: off. 3000 with ``KNEE_HINGE_FROM = "sdk"``: the default since mir12ac (docs/mirror.md).
KNEE_HINGE_WEIGHT = 3000.0
#: Where the knee hinge's rows come from (``initialise_from_observations``'s ``knee_hinge_from``): "refined" (each
#: pass's refined poses against that pass's body, :func:`knee_hinge_splay_rows`, mir12ab) or "sdk" (the rest knee
#: angle of the SDK's joints, :func:`sdk_knee_angle`, held in every pass, :func:`knee_angle_rows`, mir12ac).
KNEE_HINGE_FROM = "sdk"
#: ``knee_hinge_from="sdk"``: frames whose SDK knee bends more than this (degrees) are left out of the knee angle's
#: mean (the synthetic walk's knee is not a pure hinge: ~2 % of its flexion turns about the calf's forward axis).
KNEE_ANGLE_MAX_FLEXION_DEG = 20.0


@dataclass(frozen=True, eq=False)
class SourceBody:
    """B_0^S of §4: the actor in the default pose with its skeleton, as statistical-model coefficients."""

    coeffs: np.ndarray  # (k,) StatisticalBodyModel coefficients
    vertices: np.ndarray  # (n, 3) rest pose (model template topology)
    skeleton: Skeleton  # the statistical model's joints for ``coeffs`` (mirror init; its trunk joints moved onto the
    # SDK's with ``--trunk-refit``, :func:`refit_trunk_joints`); Eq. 3's refit in older files
    frames_used: tuple[int, ...]
    residual_mm: float  # median point-to-surface distance of the init fit
    weights: np.ndarray | None = None  # (n, B) skin weights (the model's); None until attached
    faces: np.ndarray | None = None

    def body(self) -> BodyModel:
        """A posable BodyModel of the source body (needs ``weights``)."""
        if self.weights is None:
            raise InputError("this source body carries no skin weights; load it with its statistical model")
        return BodyModel(self.vertices, self.faces, self.skeleton, self.weights, rig="game_engine")

    @cached_property
    def joint_neighbourhoods(self) -> tuple[np.ndarray, np.ndarray]:
        """Eq. 3 vertex sets around each bone head and tail of this body (for target skeletons)."""
        return joint_neighbourhoods(self.vertices, self.skeleton)


@dataclass(frozen=True, eq=False)
class InitObservation:
    """One frame's input to the initialisation: the actor's depth points and Kinect joints."""

    frame: int
    points: np.ndarray  # (N, 3) studio frame
    joints: np.ndarray  # (J, 3), NaN where not tracked
    tracked: np.ndarray  # (J,)
    version: str
    foreground: np.ndarray | None = None  # (H, W) bool, the player's refined foreground in the colour image
    others: np.ndarray | None = None  # (H, W) bool, other players' pixels there
    player_mask: np.ndarray | None = None  # (h, w) bool, the SDK's player mask of the actor in the depth image
    others_depth: np.ndarray | None = None  # (h, w) bool, other players' pixels in the depth image


@dataclass(frozen=True, eq=False)
class DefaultPoseCloud:
    """The result of :func:`transform_to_default_pose` with its by-products."""

    points: np.ndarray  # (N, 3) P_0, NaN rows for points that match no body vertex
    correspondence: np.ndarray  # (N,) closest vertex of the posed B^D, -1 where rejected
    candidates: np.ndarray  # vertex indices that faced the sensor
    pose: object  # the IK pose of B^D
    body: BodyModel  # B_0^D


# --- transformation to the default pose -----------------------------------------------------------

def _kinect_name(name: str, version: str) -> str:
    return V1_NAMES.get(name, name) if version == "v1" else name


def bone_scaled_body(body: BodyModel, joints: np.ndarray, tracked: np.ndarray | None = None,
                     version: str = "v2") -> BodyModel:
    """B_0^D of §4: ``body`` with each bone stretched along its axis to the Kinect skeleton's bone length.

    Vertex offsets from a bone's head scale along the bone with it (an affine map per bone, blended by
    the skin weights); bones whose Kinect joints are missing keep their length.
    """
    K, tracked = check_kinect_joints(joints, tracked, version)
    names = kinect_joint_names(version)
    index = {n: i for i, n in enumerate(names)}
    sk = body.skeleton
    rest = skeleton_kinect_joints(sk, sk.heads, sk.tails, version)
    usable = np.all(np.isfinite(K), axis=1) & tracked
    scale = np.ones(sk.n_bones)
    for bones, a, b in BONE_SCALE_SEGMENTS:
        ia, ib = index.get(_kinect_name(a, version)), index.get(_kinect_name(b, version))
        if ia is None or ib is None or not (usable[ia] and usable[ib]):
            continue
        s = np.linalg.norm(K[ib] - K[ia]) / max(np.linalg.norm(rest[ib] - rest[ia]), 1e-9)
        for bone in bones:
            scale[sk.index(bone)] = np.clip(s, *_BONE_SCALE_RANGE)
    H, T = sk.heads, sk.tails
    axes = (T - H) / np.maximum(sk.lengths, 1e-12)[:, None]
    A = np.tile(np.eye(4), (sk.n_bones, 1, 1))
    heads = H.copy()
    for j, p in enumerate(sk.parents):
        S = np.eye(3) + (scale[j] - 1.0) * np.outer(axes[j], axes[j])
        heads[j] = H[j] if p < 0 else A[p, :3, :3] @ H[j] + A[p, :3, 3]
        A[j, :3, :3] = S
        A[j, :3, 3] = heads[j] - S @ H[j]
    tails = np.einsum("bij,bj->bi", A[:, :3, :3], T) + A[:, :3, 3]
    V = skin_vertices(body.vertices, body.weights, sk, None, transforms=A)
    return BodyModel(V, body.faces, Skeleton(sk.bone_names, sk.parents, heads, tails, sk.rolls), body.weights,
                     body.resolution, body.rig, vertex_ids=body.vertex_ids)


def _vertex_normals(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    n = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    out = np.zeros_like(V)
    for c in range(3):
        np.add.at(out, F[:, c], n)
    return out / np.maximum(np.linalg.norm(out, axis=1), 1e-20)[:, None]


def transform_to_default_pose(points, kinect_joints, body: BodyModel, tracked=None, version: str = "v2",
                              view_point=None, scale_bones: bool = True, max_distance_m: float = MAX_CORRESPONDENCE_M,
                              details: bool = False, min_facing_cos: float = 0.0, pose=None):
    """P_in -> P_0 of §4: bone scaling, IK down the chains, closest-vertex correspondences, inverse LBS.

    ``points`` (N, 3) depth points of the actor in the studio frame; ``kinect_joints`` (J, 3) the SDK's
    joints of the same frame; ``body`` the default body (or the current shape estimate). With
    ``view_point`` (the depth camera centre) only body vertices facing it (the cosine between normal and
    viewing ray above ``min_facing_cos``) are matched. Returns P_0
    (N, 3) with NaN rows for points farther than ``max_distance_m`` from the posed body (not the actor);
    with ``details`` a :class:`DefaultPoseCloud`. ``pose``: the pose of the (bone-scaled) body to unpose by instead
    of the IK on the joints (:func:`refined_init_pose`'s).
    """
    P = np.asarray(points, dtype=np.float64)
    if P.ndim != 2 or P.shape[1] != 3:
        raise InputError(f"point cloud must be (N, 3), got {P.shape}")
    K, tracked = check_kinect_joints(kinect_joints, tracked, version)
    bodyD = bone_scaled_body(body, K, tracked, version) if scale_bones else body
    if pose is None:
        pose = ik_pose(bodyD.skeleton, K, tracked, version)
    S = skinning_transforms(bodyD.skeleton, pose)
    V = skin_vertices(bodyD.vertices, bodyD.weights, bodyD.skeleton, pose, transforms=S)
    candidates = np.arange(len(V))
    if view_point is not None:
        N = _vertex_normals(V, bodyD.faces)
        ray = np.asarray(view_point, float) - V
        facing = np.einsum("nd,nd->n", N, ray) > min_facing_cos * np.linalg.norm(ray, axis=1)
        candidates = np.flatnonzero(facing)
    dist, k = cKDTree(V[candidates]).query(P)
    k = candidates[k]
    keep = dist <= max_distance_m
    out = np.full_like(P, np.nan)
    if keep.any():
        out[keep] = inverse_linear_blend_skinning(P[keep], bodyD.weights[k[keep]], S)
    if not details:
        return out
    return DefaultPoseCloud(out, np.where(keep, k, -1), candidates, pose, bodyD)


#: Kinect joints the shape fit also matches (unposed into the default pose): trunk and limbs, not the
#: hands (the SDK's hand joints are the least reliable).
SHAPE_JOINTS = ("SpineBase", "SpineMid", "Neck", "Head", "ShoulderLeft", "ElbowLeft", "WristLeft", "ShoulderRight",
                "ElbowRight", "WristRight", "HipLeft", "KneeLeft", "AnkleLeft", "FootLeft", "HipRight", "KneeRight",
                "AnkleRight", "FootRight", "SpineShoulder")


def unposed_kinect_joints(joints, tracked, skeleton: Skeleton, pose, version: str = "v2") -> np.ndarray:
    """Tracked Kinect joints (J, 3) brought to the default pose by the inverse transform of the bone carrying each.

    Joints outside :data:`SHAPE_JOINTS`, untracked or missing are NaN.
    """
    K, tracked = check_kinect_joints(joints, tracked, version)
    S = skinning_transforms(skeleton, pose)
    names = kinect_joint_names(version)
    wanted = {_kinect_name(n, version) for n in SHAPE_JOINTS}
    out = np.full((len(names), 3), np.nan)
    for i, name in enumerate(names):
        if name not in wanted or not tracked[i] or not np.all(np.isfinite(K[i])):
            continue
        b = skeleton.index(KINECT_JOINT_SETS[version][name][0][0])
        out[i] = S[b, :3, :3].T @ (K[i] - S[b, :3, 3])
    return out


# --- Eq. 2 shape fit -------------------------------------------------------------------------------

def fit_shape(points_default, model: StatisticalBodyModel, init_coeffs=None, candidates=None,
              correspondence=None, joints_default=None, joint_weight: float = 0.0, version: str = "v2",
              iterations: int = 4, symmetric: bool = False, point_sigma_m: float = POINT_SIGMA_M, trim_m: float = 0.05,
              return_residual: bool = False, bone_lengths=None, bone_length_weight: float = 0.0,
              point_weight: float = 1.0, free_basis=None, free_joint_basis=None,
              free_sigma: float = LEG_SPLAY_SIGMA_RAD, coeff_rows=None):
    """Coefficients minimising Eq. 2, ``sum_i |p_i - v_k(i)(alpha)|^2``, for a cloud in the default pose.

    ``k(i)`` is the closest vertex (among ``candidates``, e.g. the vertices the sensor saw) and is
    re-matched ``iterations`` times; for fixed matches Eq. 2 is linear in the coefficients and is
    solved exactly, together with a global translation (the cloud's placement relative to the model's
    floor-standing rest pose is not known). A Gaussian prior ``(alpha_i / sigma_i)^2`` weighted by the
    point noise ``point_sigma_m^2`` keeps unobserved directions (the back) at the population's
    expectation. Pairs farther than ``trim_m`` after the first match are dropped as outliers. With
    ``return_residual`` also returns the median point-to-vertex distance (metres) of the final fit.
    ``bone_lengths`` (len(:data:`BONE_PAIRS`),) measured joint distances (NaN: not measured) are matched with
    ``bone_length_weight`` (one number, or one per pair) each (:func:`bone_length_rows`). ``point_weight``: the
    weight of one depth point (1: as the prior and the joints assume; a pool of N points weighted M / N weighs as M).
    ``free_basis`` (m, n, 3): m more displacement directions of the rest body solved with the coefficients (their
    Kinect joints' ``free_joint_basis`` (m, J, 3)), each with a Gaussian prior of ``free_sigma``, and left out of the
    returned coefficients: nuisance parameters the data may use instead of the shape (:func:`leg_splay_basis`).
    ``coeff_rows`` ``(A (r, k), b (r,))``: more weighted linear rows ``A c = b`` on the coefficients
    (:func:`knee_hinge_splay_rows`).
    """
    from bodystudio.mirror.refine import _one_blas_thread

    P = np.asarray(points_default, dtype=np.float64)
    finite = np.all(np.isfinite(P), axis=1)
    P = P[finite]
    given = None if correspondence is None else np.asarray(correspondence)[finite]
    if len(P) < 10:
        raise InputError(f"the shape fit needs at least 10 points in the default pose, got {len(P)}")
    k = model.n_components
    c = np.zeros(k) if init_coeffs is None else np.asarray(init_coeffs, dtype=np.float64).copy()
    cand = np.arange(len(model.mean)) if candidates is None else np.asarray(candidates)
    basis = model.basis  # (k, n, 3)
    gram = _vertex_gram(model)
    prior = point_sigma_m ** 2 / model.stddev ** 2
    t = np.zeros(3)
    residual = np.inf
    joint_rows = joint_design = None
    if joints_default is not None and joint_weight > 0:
        Jm, Jb = _model_kinect_joints(model, version)
        Jd = np.asarray(joints_default, dtype=np.float64).reshape(-1, len(Jm), 3)  # (frames, J, 3)
        f, j = np.nonzero(np.all(np.isfinite(Jd), axis=2))
        sw = np.sqrt(joint_weight)
        joint_rows = (sw * np.hstack([Jb[:, j].reshape(k, -1).T, np.tile(np.eye(3), (len(j), 1))]),
                      sw * (Jd[f, j] - Jm[j]).ravel())
        joint_design = joint_rows  # the rows themselves, for the free columns' cross terms (_with_free_columns)
        with _one_blas_thread():  # the joints' normal equations do not change between re-matchings: formed once
            joint_rows = (joint_rows[0].T @ joint_rows[0], joint_rows[0].T @ joint_rows[1])
    data_tree = cKDTree(P) if symmetric else None
    length_weights = None
    if bone_lengths is not None and np.any(np.asarray(bone_length_weight) > 0):
        length_weights = np.broadcast_to(np.asarray(bone_length_weight, dtype=np.float64), (len(BONE_PAIRS),))
    match_cache: dict = {}  # the closest-vertex query reused between the re-matchings (closest_vertex_matches)
    free = None if free_basis is None else np.asarray(free_basis, dtype=np.float64)
    if free is not None and (free.ndim != 3 or free.shape[1:] != model.mean.shape or not np.all(np.isfinite(free))):
        raise InputError(f"free_basis must be finite (m, {len(model.mean)}, 3) displacement columns of the model's "
                         f"rest vertices (leg_splay_basis), got shape {free.shape}")
    delta = np.zeros(0 if free is None else len(free))
    for it in range(iterations):
        V = model.vertices(c) if free is None else model.vertices(c) + np.tensordot(delta, free, axes=1)
        if it == 0 and given is not None:
            m = given
            keep = m >= 0
        else:
            d, m = closest_vertex_matches(P, V[cand] + t, match_cache)
            m = cand[m]
            keep = d <= (np.inf if it == 0 else trim_m)
        Pk, mk = P[keep], m[keep]
        if data_tree is not None:
            # model -> data: every vertex the sensor should see pulls toward its nearest point, so a
            # model part the data does not support (a too-tall head) is pulled in as well.
            d2, q = data_tree.query(V[cand] + t)
            near = d2 <= trim_m
            Pk, mk = np.concatenate([Pk, P[q[near]]]), np.concatenate([mk, cand[near]])
        # Normal equations of Eq. 2 accumulated per vertex (a vertex matched by several points adds
        # its k x k Gram matrix once per match), so no (3M, k) design matrix is formed.
        n = len(model.mean)
        counts = point_weight * np.bincount(mk, minlength=n).astype(np.float64)
        S = point_weight * np.stack([np.bincount(mk, col, minlength=n) for col in (Pk - model.mean[mk]).T], axis=1)
        AtA = np.zeros((k + 3, k + 3))
        with _one_blas_thread():  # (n,) @ (n, k * k) crosses OpenBLAS's threading threshold: its threads spin
            AtA[:k, :k] = (counts @ gram.reshape(n, -1)).reshape(k, k)
        AtA[:k, k:] = np.einsum("knd,n->kd", basis, counts)
        AtA[k:, :k] = AtA[:k, k:].T
        AtA[k:, k:] = counts.sum() * np.eye(3)
        Atb = np.concatenate([np.einsum("knd,nd->k", basis, S), S.sum(0)])
        if joint_rows is not None:
            AtA += joint_rows[0]
            Atb += joint_rows[1]
        if length_weights is not None:
            A_len, b_len, rows = bone_length_rows(model, c, bone_lengths, version)
            AtA[:k, :k] += (A_len.T * length_weights[rows]) @ A_len
            Atb[:k] += (A_len.T * length_weights[rows]) @ b_len
        AtA[np.arange(k), np.arange(k)] += prior
        if coeff_rows is not None:
            AtA[:k, :k] += coeff_rows[0].T @ coeff_rows[0]
            Atb[:k] += coeff_rows[0].T @ coeff_rows[1]
        if free is not None:
            AtA, Atb = _with_free_columns(AtA, Atb, basis, free, counts, S, joint_design, free_joint_basis,
                                          joints_default, joint_weight, len(Jm) if joint_rows is not None else 0,
                                          point_sigma_m ** 2 / free_sigma ** 2)
        x = np.linalg.solve(AtA, Atb)
        c, t, delta = x[:k], x[k:k + 3], x[k + 3:]
        if return_residual and it == iterations - 1:
            V = model.vertices(c) if free is None else model.vertices(c) + np.tensordot(delta, free, axes=1)
            residual = float(np.median(np.linalg.norm(P[keep] - t - V[m[keep]], axis=1)))
    return (c, residual) if return_residual else c


@njit(cache=True)
def _closest_of_kept(P, V, near):
    """Each point's closest vertex among its kept ones ``near`` (N, k): (distance, vertex index)."""
    d = np.empty(len(P))
    m = np.empty(len(P), dtype=near.dtype)
    for i in range(len(P)):
        best, arg = np.inf, near[i, 0]
        for j in range(near.shape[1]):
            v = near[i, j]
            e = (P[i, 0] - V[v, 0]) ** 2 + (P[i, 1] - V[v, 1]) ** 2 + (P[i, 2] - V[v, 2]) ** 2
            if e < best:
                best, arg = e, v
        d[i], m[i] = np.sqrt(best), arg
    return d, m


#: Candidate vertices kept per point between re-matchings of the Eq. 2 fit (:func:`closest_vertex_matches`).
MATCH_NEIGHBOURS = 4


def closest_vertex_matches(points, vertices, cache: dict | None = None, neighbours: int = MATCH_NEIGHBOURS):
    """Each point's closest vertex ``(distance, index)``, as ``cKDTree(vertices).query(points)``, Eq. 2's ``k(i)``.

    ``cache`` (a dict this function fills) carries the last full query between the re-matchings of one fit: a
    later call with as many vertices checks only each point's ``neighbours`` closest vertices of that query. A
    vertex outside them was at least ``reach`` (the distance to the farthest of them) away then, and is at least
    ``reach - moved`` now (``moved``: the most any vertex has moved since), so a point whose nearest kept vertex is
    no farther than that has it for its closest vertex (the same answer, up to ties); the other points are queried
    again, and when more than a quarter are, the whole query is redone and cached. mir12y: the weighted pool's ~35 000
    points re-matched 120 times cost 13 ms a query (docs/mirror.md).
    """
    P = np.asarray(points, dtype=np.float64)
    V = np.asarray(vertices, dtype=np.float64)
    if cache is not None and cache.get("vertices") is not None and len(cache["vertices"]) == len(V):
        moved = float(np.sqrt(((V - cache["vertices"]) ** 2).sum(axis=1).max()))
        d, m = _closest_of_kept(P, V, cache["near"])
        stale = d > cache["reach"] - moved
        if stale.sum() <= len(P) // 4:
            if stale.any():
                d[stale], m[stale] = cKDTree(V).query(P[stale])
            return d, m
    tree = cKDTree(V)
    if cache is None or neighbours < 2 or len(V) < neighbours:
        return tree.query(P)
    dk, near = tree.query(P, k=neighbours)
    cache.update(vertices=V.copy(), near=near, reach=dk[:, -1])
    return dk[:, 0], near[:, 0]


def _with_free_columns(AtA, Atb, basis, free, counts, S, joint_rows, free_joint_basis, joints_default,
                       joint_weight, n_joints, free_prior):
    """Eq. 2's normal equations (coefficients, translation) extended by the ``free`` displacement columns (m, n, 3)
    (:func:`fit_shape`'s ``free_basis``): the unknowns become (coefficients, translation, free amounts)."""
    k, m = len(basis), len(free)
    n_old = len(AtA)
    out = np.zeros((n_old + m, n_old + m))
    out[:n_old, :n_old] = AtA
    F_c = free * counts[None, :, None]
    out[:k, n_old:] = np.einsum("knd,mnd->km", basis, F_c)
    out[k:k + 3, n_old:] = F_c.sum(1).T
    out[n_old:, n_old:] = np.einsum("mnd,lnd->ml", free, F_c) + free_prior * np.eye(m)
    b = np.concatenate([Atb, np.einsum("mnd,nd->m", free, S)])
    if joint_rows is not None and free_joint_basis is not None:
        Jd = np.asarray(joints_default, dtype=np.float64).reshape(-1, n_joints, 3)
        _, j = np.nonzero(np.all(np.isfinite(Jd), axis=2))
        A_free = np.sqrt(joint_weight) * np.asarray(free_joint_basis, dtype=np.float64)[:, j].reshape(m, -1).T
        out[:n_old, n_old:] += joint_rows[0].T @ A_free
        out[n_old:, n_old:] += A_free.T @ A_free
        b[n_old:] += A_free.T @ joint_rows[1]
    out[n_old:, :n_old] = out[:n_old, n_old:].T
    return out, b


def leg_splay_basis(vertices: np.ndarray, weights: np.ndarray, skeleton: Skeleton, version: str = "v2",
                    chains=LEG_SPLAY_CHAINS) -> tuple[np.ndarray, np.ndarray]:
    """The rest body's lower legs turned about their knees, linearised: per leg two columns (about the body's forward
    axis z: the splay; about its sideways axis x: the calf forward / back), ``w(v) (a x (v - knee))`` with ``w`` the
    skin weight of the bones below the knee; returns the vertex columns (2L, n, 3) and the Kinect joints'
    (2L, J, 3) (the bone ends below the knee turned the same way).

    A rest calf splayed out and a posed calf turned in by the IK give the same posed surface (mir12z): with these
    columns free in Eq. 2 (:func:`fit_shape`'s ``free_basis``) the unposed cloud's splay is taken up by them rather
    than by the shape coefficients, whose population ties a wide splay to wide hips and mass."""
    V = np.asarray(vertices, dtype=np.float64)
    names = list(skeleton.bone_names)
    cols, joint_cols = [], []
    base = skeleton_kinect_joints(skeleton, skeleton.heads, skeleton.tails, version)
    for calf, below in chains:
        knee = skeleton.heads[names.index(calf)]
        idx = [names.index(b) for b in below]
        w = np.asarray(weights)[:, idx].sum(1)
        for axis in (np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0])):
            cols.append(w[:, None] * np.cross(axis, V - knee))
            heads, tails = skeleton.heads.copy(), skeleton.tails.copy()
            heads[idx] += np.cross(axis, heads[idx] - knee)
            tails[idx] += np.cross(axis, tails[idx] - knee)
            joint_cols.append(skeleton_kinect_joints(skeleton, heads, tails, version) - base)
    return np.array(cols), np.array(joint_cols)


def knee_hinge_splay_rows(model: StatisticalBodyModel, skeleton: Skeleton, poses, version: str = "v2",
                          weight: float = KNEE_HINGE_WEIGHT, legs=(("calf_l", "KneeLeft", "AnkleLeft"),
                                                                  ("calf_r", "KneeRight", "AnkleRight"))):
    """Eq. 2 rows holding each rest calf's component along its knee's hinge axis at the one the frames measure.

    A knee turns about one axis fixed in the thigh (the rig's: the calf bone's rest x axis), so the calf's direction
    brought back by the thigh's transform alone, ``S_thigh^-1 S_calf d``, has the same component along that axis in
    every frame whatever the flexion: the rest calf's own. ``poses`` (the frames' refined poses of ``skeleton``) aim
    each calf at the SDK's ankle, so the mean of that component over the frames measures the true rest splay, which
    the unposing of one frame cannot tell from a pose (mir12z). Returns ``(A, b)`` with one row per leg,
    ``sqrt(weight) a . (Ankle(c) - Knee(c)) = sqrt(weight) m L`` (the model's Kinect joints are linear in c; ``L`` the
    calf's current length), for :func:`fit_shape`'s ``coeff_rows``."""
    Jm, Jb = _model_kinect_joints(model, version)
    names = kinect_joint_names(version)
    rows, rhs = [], []
    for calf, knee_name, ankle_name in legs:
        b = skeleton.index(calf)
        thigh = int(skeleton.parents[b])
        axis = skeleton.rest_rotations[b][:, 0]
        d = (skeleton.tails[b] - skeleton.heads[b]) / max(skeleton.lengths[b], 1e-9)
        measured = []
        for pose in poses:
            S = skinning_transforms(skeleton, pose)
            u = S[thigh, :3, :3].T @ (S[b, :3, :3] @ d)
            measured.append(float(axis @ u))
        if not measured:
            continue
        ka, kk = names.index(_kinect_name(ankle_name, version)), names.index(_kinect_name(knee_name, version))
        rows.append(np.sqrt(weight) * (Jb[:, ka] - Jb[:, kk]) @ axis)
        rhs.append(np.sqrt(weight) * (np.median(measured) * skeleton.lengths[b] - (Jm[ka] - Jm[kk]) @ axis))
    if not rows:
        return None
    return np.array(rows), np.array(rhs)


def _knee_angle(hip, knee, ankle, lateral, side: float) -> float:
    """The knee's varus / valgus angle (radians, + the calf further out than the thigh): the calf direction's
    component along the lateral axis made normal to the thigh, ``asin(a . c)``; ``side`` +1 for the left leg (the
    body's left is ``lateral``), -1 for the right."""
    t = (knee - hip) / max(np.linalg.norm(knee - hip), 1e-12)
    c = (ankle - knee) / max(np.linalg.norm(ankle - knee), 1e-12)
    a = lateral - (lateral @ t) * t
    a /= max(np.linalg.norm(a), 1e-12)
    return side * float(np.arcsin(np.clip(a @ c, -1.0, 1.0)))


#: The legs of the knee angle: (side, Kinect hip, knee, ankle); side +1 for the body's left (+x at rest).
KNEE_ANGLE_LEGS = ((1.0, "HipLeft", "KneeLeft", "AnkleLeft"), (-1.0, "HipRight", "KneeRight", "AnkleRight"))


def sdk_knee_angle(observations, version: str, max_flexion_deg: float = KNEE_ANGLE_MAX_FLEXION_DEG):
    """The subject's rest knee angle (radians) from the SDK's joints of every observation, and its standard error.

    Per frame and leg: the calf's (knee to ankle) component along the pelvis's lateral axis (HipRight to HipLeft)
    made normal to the thigh (hip to knee), ``asin`` of it: a knee turns about one axis across the thigh, so this
    angle is the rest one at any flexion, from the joints alone (no body's rest calf in it, unlike the hinge measured
    with a body's poses, :func:`knee_hinge_splay_rows`; docs/mirror.md, mir12ac). The mean over both legs and the
    frames whose knee bends less than ``max_flexion_deg`` (the SDK's 1 cm per joint gives ~3.5 degrees per frame; the
    synthetic walk's flexed knee also turns a little about the calf's forward axis). None, None when no frame tracks
    both legs."""
    names = kinect_joint_names(version)
    values = []
    for o in observations:
        if o.version != version:
            continue
        K = np.asarray(o.joints, dtype=np.float64)
        ok = np.asarray(o.tracked, bool) & np.all(np.isfinite(K), axis=1)
        idx = [[names.index(_kinect_name(n, version)) for n in leg[1:]] for leg in KNEE_ANGLE_LEGS]
        if not all(ok[i] for leg in idx for i in leg):
            continue
        lateral = K[idx[0][0]] - K[idx[1][0]]
        lateral /= max(np.linalg.norm(lateral), 1e-12)
        for (side, *_), (h, k, a) in zip(KNEE_ANGLE_LEGS, idx, strict=True):
            t, c = K[k] - K[h], K[a] - K[k]
            flexion = np.degrees(np.arccos(np.clip(t @ c / max(np.linalg.norm(t) * np.linalg.norm(c), 1e-12), -1, 1)))
            if flexion < max_flexion_deg:
                values.append(_knee_angle(K[h], K[k], K[a], lateral, side))
    if not values:
        return None, None
    v = np.asarray(values)
    return float(v.mean()), float(v.std() / np.sqrt(len(v)))


@dataclass(frozen=True, eq=False)
class KinectJointFrame:
    """One frame's SDK joints of the actor without its depth: the knee angle's frames (:func:`knee_joint_frames`)."""

    frame: int
    joints: np.ndarray  # (J, 3), NaN where not tracked
    tracked: np.ndarray  # (J,)
    version: str


#: :func:`knee_joint_frames`: a body is the actor's when its joints lie within this (median, metres) of the joints of
#: the observation nearest in time (a person walks ~5 cm a frame; another person stands further off).
KNEE_FRAME_REACH_M = 0.25


def knee_joint_frames(session, observations, reach_m: float = KNEE_FRAME_REACH_M) -> list[KinectJointFrame]:
    """The actor's SDK joints in every frame from the first observation's to the last's, for :func:`sdk_knee_angle`:
    the observations read every :data:`INIT_FRAME_STRIDE`-th frame for the depth, the joints files of the frames
    between cost little, and the SDK's noise is drawn afresh every frame (mir12ac: the knee angle's error over the
    16 sessions 0.60 -> 0.26 degrees rms). In each frame the body nearest (median joint distance) to the joints of
    the observation nearest in time, within ``reach_m``, whatever its player id (the SDK renumbers, rel6a)."""
    obs = sorted(observations, key=lambda o: o.frame)
    if not obs:
        return []
    when = np.array([o.frame for o in obs])
    out = []
    for i in session.frame_ids:
        if i < when[0] or i > when[-1]:
            continue
        near = obs[int(np.argmin(np.abs(when - i)))]
        best, best_d = None, reach_m
        for body in session.frame(i).kinect_bodies or []:
            P = np.asarray(body["positions"], dtype=np.float64)
            if P.shape != np.shape(near.joints):
                continue
            d = np.linalg.norm(P - near.joints, axis=1)
            d = d[np.isfinite(d)]
            if len(d) and np.median(d) < best_d:
                best, best_d = body, float(np.median(d))
        if best is not None:
            P = np.asarray(best["positions"], dtype=np.float64)
            out.append(KinectJointFrame(int(i), P, np.asarray(best["tracked"], bool) & np.all(np.isfinite(P), axis=1),
                                        near.version))
    return out


def model_knee_angles(model: StatisticalBodyModel, coeffs, version: str = "v2") -> np.ndarray:
    """The rest knee angle (radians) of each leg of :data:`KNEE_ANGLE_LEGS` of the model's Kinect joints at
    ``coeffs`` (the body's left +x)."""
    Jm, Jb = _model_kinect_joints(model, version)
    P = Jm + np.tensordot(np.asarray(coeffs, dtype=np.float64), Jb, axes=1)
    names = kinect_joint_names(version)
    lateral = np.array([1.0, 0.0, 0.0])
    return np.array([_knee_angle(*(P[names.index(_kinect_name(n, version))] for n in leg[1:]), lateral, leg[0])
                     for leg in KNEE_ANGLE_LEGS])


def knee_angle_rows(model: StatisticalBodyModel, coeffs, target_rad: float, version: str = "v2",
                    weight: float = KNEE_HINGE_WEIGHT, step_m: float = 1e-5):
    """Eq. 2 rows holding each leg's rest knee angle of the model's Kinect joints at ``target_rad``, linearised at
    ``coeffs``: ``sqrt(weight) L g . (c - c0) = sqrt(weight) L (target - k(c0))`` with ``g`` the angle's gradient
    (the joints are linear in the coefficients; the angle's derivative by the joints numerically) and ``L`` the
    calf's length, so that ``weight`` counts as :func:`knee_hinge_splay_rows`' (an ankle's sideways metres)."""
    Jm, Jb = _model_kinect_joints(model, version)
    c0 = np.asarray(coeffs, dtype=np.float64)
    P = Jm + np.tensordot(c0, Jb, axes=1)
    names = kinect_joint_names(version)
    lateral = np.array([1.0, 0.0, 0.0])
    rows, rhs = [], []
    for side, *leg in KNEE_ANGLE_LEGS:
        idx = [names.index(_kinect_name(n, version)) for n in leg]
        k0 = _knee_angle(*P[idx], lateral, side)
        grad = np.zeros(len(c0))
        for j, i in enumerate(idx):
            for d in range(3):
                Q = P[idx].copy()
                Q[j, d] += step_m
                grad += (_knee_angle(*Q, lateral, side) - k0) / step_m * Jb[:, i, d]
        length = float(np.linalg.norm(P[idx[2]] - P[idx[1]]))
        rows.append(np.sqrt(weight) * length * grad)
        rhs.append(np.sqrt(weight) * length * (target_rad - k0 + grad @ c0))
    return np.array(rows), np.array(rhs)


@lru_cache(maxsize=4)
def _vertex_gram(model: StatisticalBodyModel) -> np.ndarray:
    """Per-vertex Gram matrices ``basis[:, v] basis[:, v]^T`` (n, k, k) of the shape basis."""
    return np.einsum("knd,lnd->nkl", model.basis, model.basis)


@lru_cache(maxsize=8)
def _model_kinect_joints(model: StatisticalBodyModel, version: str) -> tuple[np.ndarray, np.ndarray]:
    """Kinect joints of the model as ``mean (J, 3) + coeffs @ basis (k, J, 3)`` (they are linear in the shape)."""
    sk = _default_skeleton(model)
    mean = skeleton_kinect_joints(sk, model.joint_mean_heads, model.joint_mean_tails, version)
    basis = np.stack([skeleton_kinect_joints(sk, h, t, version) for h, t in zip(model.joint_basis_heads,
                                                                         model.joint_basis_tails, strict=True)])
    return mean, basis


def selected_bone_pairs(pairs) -> np.ndarray:
    """(len(:data:`BONE_PAIRS`),) bool: which pairs the joint-distance term matches, from ``pairs`` (None: all; else
    pairs of Kinect joint names, each one of :data:`BONE_PAIRS` in either order; an unknown pair is an InputError)."""
    if pairs is None:
        return np.ones(len(BONE_PAIRS), bool)
    known = {frozenset(p): i for i, p in enumerate(BONE_PAIRS)}
    keep = np.zeros(len(BONE_PAIRS), bool)
    for p in pairs:
        if isinstance(p, str) or len(tuple(p)) != 2 or frozenset(p) not in known:
            raise InputError(f"bone_length_pairs: {p!r} is not a pair of init.BONE_PAIRS; use pairs such as "
                             f"{BONE_PAIRS[6]} (init.STATURE_BONE_PAIRS) or None for all")
        keep[known[frozenset(p)]] = True
    return keep


def bone_pair_indices(version: str) -> np.ndarray:
    """(len(BONE_PAIRS), 2) joint indices of each pair in ``version``'s joint set, -1 where it has no such joint
    (Kinect v1 has no Neck)."""
    index = {n: i for i, n in enumerate(kinect_joint_names(version))}
    return np.array([(index.get(_kinect_name(a, version), -1), index.get(_kinect_name(b, version), -1))
                     for a, b in BONE_PAIRS])


def kinect_bone_lengths(observations, version: str) -> tuple[np.ndarray, np.ndarray]:
    """The SDK's joint distances of :data:`BONE_PAIRS` (metres) and the number of frames behind each: the mean over
    the frames that track both joints after dropping the frames more than 3 median absolute deviations off its
    median; NaN (and 0 frames) where fewer than three frames track the pair. Pose-free: the distance of two joints
    is the same in every frame up to the SDK's noise (1 cm per joint, 3 % bone-length jitter per frame), which the
    mean over ~30 frames takes to ~3 mm."""
    pairs = bone_pair_indices(version)
    lengths = [[] for _ in pairs]
    for o in observations:
        if o.version != version:
            continue
        K = np.asarray(o.joints, dtype=np.float64)
        ok = np.asarray(o.tracked, bool) & np.all(np.isfinite(K), axis=1)
        for n, (a, b) in enumerate(pairs):
            if a >= 0 and b >= 0 and ok[a] and ok[b]:
                lengths[n].append(float(np.linalg.norm(K[a] - K[b])))
    out, counts = np.full(len(pairs), np.nan), np.zeros(len(pairs), dtype=np.int64)
    for n, values in enumerate(lengths):
        v = np.asarray(values)
        if len(v) >= 3:
            med = np.median(v)
            kept = v[np.abs(v - med) <= 3.0 * max(np.median(np.abs(v - med)), 1e-3)]
            out[n], counts[n] = float(kept.mean()), len(kept)
    return out, counts


def bone_length_rows(model: StatisticalBodyModel, coeffs, bone_lengths,
                     version: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Linearised rows ``A c = b`` of the joint-distance term: ``u^T (J_a(c) - J_b(c)) = L_ab`` with ``u`` the pair's
    current direction (the model's Kinect joints are linear in ``c``, so the row is exact along ``u`` and the
    distance is matched to first order; it is re-linearised at every re-matching of Eq. 2). Pairs with a NaN
    length (or a joint the version lacks) give no row; the third array says which pairs gave one."""
    Jm, Jb = _model_kinect_joints(model, version)
    pairs = bone_pair_indices(version)
    L = np.asarray(bone_lengths, dtype=np.float64)
    keep = np.isfinite(L) & np.all(pairs >= 0, axis=1)
    a, b = pairs[keep, 0], pairs[keep, 1]
    D_mean, D_basis = Jm[a] - Jm[b], Jb[:, a] - Jb[:, b]  # (P, 3), (k, P, 3)
    d = D_mean + np.tensordot(np.asarray(coeffs, float), D_basis, axes=1)
    u = d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-9)
    A = np.einsum("kpd,pd->pk", D_basis, u)
    return A, L[keep] - np.einsum("pd,pd->p", D_mean, u), keep


# --- Eq. 3 skeleton refit --------------------------------------------------------------------------

def joint_neighbourhoods(vertices: np.ndarray, skeleton: Skeleton,
                         n_vertices: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """The ``n_vertices`` vertices nearest each bone head and tail (B, n) of a rest body: Eq. 3's sets."""
    tree = cKDTree(vertices)
    return tree.query(skeleton.heads, n_vertices)[1], tree.query(skeleton.tails, n_vertices)[1]


def refit_skeleton_from_vertices(reference_vertices: np.ndarray, reference_skeleton: Skeleton,
                                 vertices: np.ndarray, neighbourhoods=None) -> Skeleton:
    """Eq. 3: ``J_i^S = J_i^0 + mean_a (v_a^S - v_a^0)`` over the vertices near each joint."""
    heads_nb, tails_nb = joint_neighbourhoods(reference_vertices, reference_skeleton) \
        if neighbourhoods is None else neighbourhoods
    D = np.asarray(vertices, float) - np.asarray(reference_vertices, float)
    heads = reference_skeleton.heads + D[heads_nb].mean(1)
    tails = reference_skeleton.tails + D[tails_nb].mean(1)
    return Skeleton(reference_skeleton.bone_names, reference_skeleton.parents, heads, tails, reference_skeleton.rolls)


@lru_cache(maxsize=4)
def _default_body_neighbourhoods(model: StatisticalBodyModel):
    return joint_neighbourhoods(model.mean, _default_skeleton(model))


@lru_cache(maxsize=4)
def _default_skeleton(model: StatisticalBodyModel) -> Skeleton:
    return Skeleton(model.bone_names, model.parents, model.joint_mean_heads, model.joint_mean_tails, model.rolls)


def refit_skeleton(model: StatisticalBodyModel, coeffs) -> Skeleton:
    """Eq. 3 of Real-time Reshaping: the source skeleton from the default body's joints and the vertex displacements."""
    return refit_skeleton_from_vertices(model.mean, _default_skeleton(model), model.vertices(coeffs),
                                        _default_body_neighbourhoods(model))


# --- the whole initialisation ----------------------------------------------------------------------

def check_model(model) -> StatisticalBodyModel:
    """The model the mirror needs: a StatisticalBodyModel on the game_engine rig (the Kinect joint maps)."""
    if not isinstance(model, StatisticalBodyModel):
        raise InputError(f"the mirror needs a StatisticalBodyModel (body.statistical.load_statistical_model), "
                         f"got {type(model).__name__}")
    if model.rig != "game_engine":
        raise InputError(f"the mirror needs a statistical model on the game_engine rig (Kinect joints), "
                         f"got rig {model.rig!r}; load_statistical_model(rig='game_engine')")
    return model


def _subsample(P: np.ndarray, n: int, seed: int) -> np.ndarray:
    if len(P) <= n:
        return P
    return P[np.random.default_rng(seed).choice(len(P), n, replace=False)]


def initialise_from_observations(observations, model: StatisticalBodyModel, view_point=None, passes: int = INIT_PASSES,
                                 floor_y: float | None = 0.0, floor_margin_m: float = 0.02,
                                 joint_weight: float = JOINT_WEIGHT, max_frames: int = MAX_FIT_FRAMES,
                                 max_distance_m: float = INIT_CORRESPONDENCE_M,
                                 trim_m: float = FIT_TRIM_M, min_facing_cos: float = INIT_FACING_COS,
                                 camera=None, silhouette_frames: int = 0,
                                 point_sigma_m: float = POINT_SIGMA_M, depth_camera=None,
                                 unpose_refine_steps: int = UNPOSE_REFINE_STEPS,
                                 bone_length_weight: float = BONE_LENGTH_WEIGHT,
                                 trunk_refit: bool = False,
                                 unpose_posture_bones=UNPOSE_POSTURE_BONES,
                                 frame_choice: str | None = None,
                                 pass_relaxation: float = PASS_RELAXATION,
                                 fixed_pool: bool = FIXED_POOL,
                                 pooled_points: int = MAX_POOLED_POINTS,
                                 weighted_pool: bool = WEIGHTED_POOL, pool_seed: int = 0,
                                 leg_splay: bool = LEG_SPLAY,
                                 knee_hinge_weight: float = KNEE_HINGE_WEIGHT,
                                 bone_length_pairs=BONE_LENGTH_PAIRS,
                                 knee_hinge_from: str = KNEE_HINGE_FROM, knee_frames=None) -> SourceBody:
    """§4 over several frames: per-frame transform + pooled Eq. 2 fit; ``passes`` - 1 refinements; Eq. 3.

    ``observations`` are :class:`InitObservation`; points within ``floor_margin_m`` of the floor
    plane ``y = floor_y`` are dropped (the player mask reaches onto the floor at the feet; None keeps them).
    Of more than ``max_frames`` usable frames, ``frame_choice`` (None: :data:`INIT_FRAME_CHOICE`) picks which are used:
    ``"first"`` the ``max_frames`` with the most person points once each cloud is cut to :data:`MAX_POINTS` (so in
    practice the first ones), ``"spread"`` ``max_frames`` evenly spread over them (consecutive frames add little).
    ``max_distance_m`` and ``trim_m`` are the outlier rejections (see :data:`INIT_CORRESPONDENCE_M`);
    only vertices facing the depth camera by more than ``min_facing_cos`` take points (:data:`INIT_FACING_COS`).
    With ``silhouette_frames`` > 0 and the colour ``camera``, the shape is then refined against the silhouettes
    (``foreground``) of that many fitted frames, evenly spread, with their depth and joints, stature and mass held
    (:func:`bodystudio.mirror.shape_refine.refine_shape_to_silhouettes`; docs/mirror.md, MIR12c).
    With the ``depth_camera`` (the Kinect's depth camera) and observations that carry the SDK's ``player_mask``, the
    passes after the first unpose each frame with the IK pose refined by ``unpose_refine_steps`` steps against the
    mask, the depth and the joints (:func:`refined_init_pose`; 0: the IK's). ``point_sigma_m``: the shape prior's
    point noise (:func:`fit_shape`). ``bone_length_weight`` > 0: the fit also matches the SDK's joint distances of
    :data:`BONE_PAIRS`, averaged over every observation (:func:`kinect_bone_lengths`), each with that weight per
    frame behind it (:data:`BONE_LENGTH_WEIGHT`). ``trunk_refit``: the skeleton's trunk joints then moved onto the SDK's
    (:func:`refit_trunk_joints` over the fitted frames; MIR12r). ``unpose_posture_bones`` (names): from the third
    pass on, the refined unposing holds those trunk bones at the subject's static posture, the mean of the previous
    pass's refined poses (:func:`session_posture`), instead of at rest (:data:`UNPOSE_POSTURE_BONES`).
    ``pass_relaxation`` (0, 1]: from the second pass on, the coefficients move only this fraction of the way to the
    pass's Eq. 2 fit (:data:`PASS_RELAXATION`; 1: the fit itself). ``fixed_pool``: every pass pools the same depth
    points of each frame (a fixed random key per point) instead of a fresh random subset (:data:`FIXED_POOL`);
    ``pooled_points``: how many (:data:`MAX_POOLED_POINTS`). ``weighted_pool``: every pass pools every point instead,
    each weighted ``pooled_points`` / N, so the fit weighs its data against the prior and the joints as the subset
    did, without the subset's sampling noise (:data:`WEIGHTED_POOL`). ``pool_seed``: the seed of the random subsets
    (0, the default: ``mirror init``'s; other seeds measure how much the fit owes to the draw, mir12y). ``leg_splay``:
    each pass's Eq. 2 also solves a small rest rotation of each lower leg about its knee (:func:`leg_splay_basis`),
    dropped from the result, so that the unposed cloud's calf splay is not fitted by the shape coefficients
    (:data:`LEG_SPLAY`; mir12ab). ``knee_hinge_weight`` > 0: from the second pass on, each leg's rest splay is also
    held at what the knee's hinge measures over the previous pass's refined poses (:func:`knee_hinge_splay_rows`,
    :data:`KNEE_HINGE_WEIGHT`; mir12ab). ``bone_length_pairs``: which of :data:`BONE_PAIRS` the joint-distance term
    matches (None: all; :data:`STATURE_BONE_PAIRS`: the thighs, shins, spine, neck and head, mir12ad).
    ``knee_hinge_from="sdk"``: those rows instead hold each leg's rest knee angle
    at the one the SDK's hip, knee and ankle give over every observation (:func:`sdk_knee_angle`), in every pass from
    the first (:func:`knee_angle_rows`, :data:`KNEE_HINGE_FROM`; mir12ac); ``knee_frames``: the frames of SDK joints
    that angle is measured on instead (:func:`knee_joint_frames`: every frame of the init's window).
    """
    model = check_model(model)
    if not (np.isfinite(pass_relaxation) and 0.0 < pass_relaxation <= 1.0):
        raise InputError(f"pass_relaxation must be in (0, 1] (1: each pass takes its own fit), got {pass_relaxation!r}")
    if isinstance(pooled_points, bool) or not isinstance(pooled_points, (int, np.integer)) or pooled_points < 1:
        raise InputError(f"pooled_points must be an integer >= 1 (the depth points of one Eq. 2 fit), "
                         f"got {pooled_points!r}")
    if isinstance(pool_seed, bool) or not isinstance(pool_seed, (int, np.integer)) or pool_seed < 0:
        raise InputError(f"pool_seed must be an integer >= 0 (the seed of the random depth-point subsets), "
                         f"got {pool_seed!r}")
    if isinstance(knee_hinge_weight, bool) or not isinstance(knee_hinge_weight, (int, float, np.integer, np.floating)) \
            or not (np.isfinite(knee_hinge_weight) and knee_hinge_weight >= 0):
        raise InputError(f"knee_hinge_weight must be a finite number >= 0 (0: no knee-hinge splay rows), "
                         f"got {knee_hinge_weight!r}")
    if knee_hinge_from not in ("refined", "sdk"):
        raise InputError(f"knee_hinge_from must be 'refined' (the previous pass's refined poses) or 'sdk' (the SDK "
                         f"joints' knee angle), got {knee_hinge_from!r}")
    if knee_frames is not None:
        try:
            knee_frames = list(knee_frames)
        except TypeError:
            knee_frames = [knee_frames]
        bad = [f for f in knee_frames if not all(hasattr(f, a) for a in ("joints", "tracked", "version"))]
        if bad:
            raise InputError(f"knee_frames must be frames of SDK joints with joints, tracked and version "
                             f"(knee_joint_frames(session, observations)), got a {type(bad[0]).__name__}")
    if not isinstance(leg_splay, (bool, np.bool_)):
        raise InputError(f"leg_splay must be True or False (the legs' rest rotations solved with the shape), "
                         f"got {leg_splay!r}")
    unpose_posture_bones = tuple(unpose_posture_bones)
    unknown = sorted(set(unpose_posture_bones) - set(model.bone_names))
    if unknown:
        raise InputError(f"unpose_posture_bones: unknown bone(s) {unknown}; use trunk bones such as "
                         f"{', '.join(POSTURE_BONES)}")
    frame_choice = INIT_FRAME_CHOICE if frame_choice is None else frame_choice
    if frame_choice not in ("first", "spread"):
        raise InputError(f"frame_choice must be 'first' or 'spread', got {frame_choice!r}")
    if not (np.isfinite(bone_length_weight) and bone_length_weight >= 0):
        raise InputError(f"bone_length_weight must be a finite number >= 0 (0: no joint distances), "
                         f"got {bone_length_weight!r}")
    keep_pairs = selected_bone_pairs(bone_length_pairs)
    observations = list(observations)
    obs = []
    for o in observations:
        P = np.asarray(o.points, dtype=np.float64)
        P = P[np.all(np.isfinite(P), axis=1)]
        if floor_y is not None:
            P = P[P[:, 1] > floor_y + floor_margin_m]
        if len(P) >= MIN_POINTS:
            obs.append((o, _subsample(P, MAX_POINTS, o.frame)))
    if not obs:
        raise InputError(f"no frame with at least {MIN_POINTS} depth points on the person: "
                         "the actor must stand fully in view of the Kinect during initialisation")
    if len(obs) > max_frames:
        if frame_choice == "spread":
            best = np.unique(np.linspace(0, len(obs) - 1, max_frames).round().astype(int))
        else:
            best = sorted(np.argsort([-len(P) for _, P in obs], kind="stable")[:max_frames])
        obs = [obs[i] for i in best]
    body = model.body(np.zeros(model.n_components))
    coeffs = np.zeros(model.n_components)
    rng = np.random.default_rng(pool_seed)
    bone_lengths, length_weight = None, 0.0
    if bone_length_weight > 0:
        bone_lengths, n_frames = kinect_bone_lengths(observations, obs[0][0].version)
        bone_lengths = np.where(keep_pairs, bone_lengths, np.nan)  # a NaN pair gives no row
        length_weight = bone_length_weight * np.where(keep_pairs, n_frames, 0)
    knee_target = None  # knee_hinge_from "sdk": the SDK's rest knee angle, the rows re-linearised every pass
    if knee_hinge_weight > 0 and knee_hinge_from == "sdk":
        knee_target, _ = sdk_knee_angle(observations if knee_frames is None else knee_frames, obs[0][0].version)
    residual = np.nan
    refined_poses: list = []  # the previous pass's refined poses: the subject's static posture
    for pass_ in range(max(1, passes)):
        posture = session_posture(body.skeleton, refined_poses, unpose_posture_bones) \
            if unpose_posture_bones and refined_poses else None
        refined_poses = []
        pooled, matches, seen, joints0, keys = [], [], [], [], []
        plan = None
        if pass_ > 0 and unpose_refine_steps > 0 and depth_camera is not None:
            from bodystudio.mirror.refine import refine_plan

            plan = refine_plan(body.vertices, body.faces, body.weights, body.skeleton, obs[0][0].version)
        for o, P in obs:
            pose = None
            if plan is not None and o.player_mask is not None:
                pose = refined_init_pose(plan, body, o, P, depth_camera, unpose_refine_steps) if posture is None \
                    else refined_init_pose(plan, body, o, P, depth_camera, unpose_refine_steps, posture=posture)
                refined_poses.append(pose)
            cloud = transform_to_default_pose(P, o.joints, body, o.tracked, o.version, view_point=view_point,
                                              scale_bones=pass_ == 0, max_distance_m=max_distance_m, details=True,
                                              min_facing_cos=min_facing_cos, pose=pose)
            ok = cloud.correspondence >= 0
            if ok.sum() >= MIN_POINTS:
                pooled.append(cloud.points[ok])
                matches.append(cloud.correspondence[ok])
                if fixed_pool:  # each point's fixed key (the option's; off: no keys drawn)
                    keys.append(np.random.default_rng([POOL_KEY_SEED, int(o.frame)]).random(len(ok))[ok])
                seen.append(cloud.candidates)
                if pass_ > 0 and o.version == obs[0][0].version:
                    joints0.append(unposed_kinect_joints(o.joints, o.tracked, cloud.body.skeleton, cloud.pose,
                                                         o.version))
        if not pooled:
            raise InputError("no frame's depth points lie on a body fitted to the Kinect joints: "
                             "check that the depth and the joints come from the same sensor calibration")
        P0, k0 = np.concatenate(pooled), np.concatenate(matches)
        point_weight = 1.0
        if len(P0) > pooled_points and weighted_pool:
            point_weight = pooled_points / len(P0)
        elif len(P0) > pooled_points:
            pick = np.sort(np.argsort(np.concatenate(keys), kind="stable")[:pooled_points]) if fixed_pool \
                else rng.choice(len(P0), pooled_points, replace=False)
            P0, k0 = P0[pick], k0[pick]
        hinge_rows = None if knee_target is None else \
            knee_angle_rows(model, coeffs, knee_target, obs[0][0].version, knee_hinge_weight)
        free = (None, None)
        if leg_splay:
            free = leg_splay_basis(body.vertices, model.weights, body.skeleton, obs[0][0].version, LEG_SPLAY_CHAINS)
        fitted, residual = fit_shape(P0, model, coeffs, candidates=np.unique(np.concatenate(seen)), correspondence=k0,
                                     iterations=ICP_ITERATIONS[min(pass_, len(ICP_ITERATIONS) - 1)],
                                     joints_default=np.array(joints0) if joints0 else None,
                                     joint_weight=joint_weight, version=obs[0][0].version, trim_m=trim_m,
                                     point_sigma_m=point_sigma_m, return_residual=True, bone_lengths=bone_lengths,
                                     bone_length_weight=length_weight, point_weight=point_weight,
                                     free_basis=free[0], free_joint_basis=free[1], free_sigma=LEG_SPLAY_SIGMA_RAD,
                                     coeff_rows=hinge_rows if knee_hinge_from == "sdk" else
                                     knee_hinge_splay_rows(model, body.skeleton, refined_poses,
                                                           obs[0][0].version, knee_hinge_weight)
                                     if knee_hinge_weight > 0 and refined_poses else None)
        coeffs = coeffs + pass_relaxation * (fitted - coeffs) if pass_ > 0 else fitted
        skeleton = refit_skeleton(model, coeffs)
        body = BodyModel(model.vertices(coeffs), model.faces, skeleton, model.weights, model.resolution, model.rig,
                         vertex_ids=model.vertex_ids)
    residuals = [residual]
    views = [(o, P) for o, P in obs if o.foreground is not None]
    if silhouette_frames > 0 and camera is not None and views:
        from bodystudio.mirror.shape_refine import SilhouetteView, refine_shape_to_silhouettes

        pick = np.unique(np.linspace(0, len(views) - 1, min(silhouette_frames, len(views))).round().astype(int))
        coeffs = refine_shape_to_silhouettes(model, coeffs, [
            SilhouetteView(views[i][0].foreground, views[i][0].others, views[i][1], views[i][0].joints,
                           views[i][0].tracked, views[i][0].version) for i in pick], camera)
        body = model.body(coeffs)
    # tracked with the model's own joints (its joint regressor), not Eq. 3's nearest-vertex means: the target's
    # joints then move by the same regressor (reshape.target_skeleton), warp_iou +0.002 / +0.011 (docs/mirror.md)
    skeleton = model.skeleton(coeffs)
    if trunk_refit:
        skeleton = refit_trunk_joints(BodyModel(body.vertices, model.faces, skeleton, model.weights, model.resolution,
                                                model.rig, vertex_ids=model.vertex_ids), obs, depth_camera,
                                      unpose_refine_steps=unpose_refine_steps)
    return SourceBody(coeffs, body.vertices, skeleton, tuple(int(o.frame) for o, _ in obs),
                      1000.0 * float(np.median(residuals)), model.weights, model.faces)


def refined_init_pose(plan, body: BodyModel, observation: InitObservation, points: np.ndarray, depth_camera,
                      steps: int = UNPOSE_REFINE_STEPS, posture: np.ndarray | None = None):
    """The pose of the current shape estimate ``body`` in one init frame for §4's inverse LBS: the IK on the frame's
    Kinect joints (§5.2), refined by ``steps`` Gauss-Newton steps of :func:`bodystudio.mirror.refine.refine_pose`
    against the SDK's player mask in the depth image (``depth_camera``), the depth ``points`` and the joints.

    The IK alone is 5-12 degrees off on the trunk and the root (docs/mirror.md, MIR12g), and a pose that is off
    unposes the cloud wrongly: the shape fit then absorbs the error (MIR12i). ``posture`` (B, 3): E_trunk's centre
    (``refine_pose``'s; :func:`session_posture`), None: the rest pose."""
    from bodystudio.mirror.refine import refine_pose

    pose = ik_pose(body.skeleton, observation.joints, observation.tracked, observation.version)
    return refine_pose(plan, body.skeleton, pose, depth_camera, observation.player_mask, observation.joints,
                       observation.tracked, points, observation.others_depth, observation.version, iterations=steps,
                       posture=posture)


def session_posture(skeleton: Skeleton, poses, bones) -> np.ndarray:
    """A subject's static posture as E_trunk's centre (``refine.refine_pose``'s ``posture``, MIR12q's): for each of
    ``bones`` (names) the mean over ``poses`` of its direction in its parent's frame
    (:func:`bodystudio.mirror.refine.posture_directions`, on ``skeleton``: poses of an earlier shape estimate carry
    their bends over by their local rotations), every other bone its rest direction.

    A person's habitual stoop or nod is the same in every frame, so the mean over frames keeps it while E_trunk
    still pulls each frame's noise towards it; the IK and the data alone hold the bend the mean starts from."""
    from bodystudio.mirror.refine import posture_directions

    poses = list(poses)
    rest = skeleton.rest_rotations[:, :, 1].copy()
    if not poses:
        return rest
    d = np.mean([posture_directions(skeleton, p) for p in poses], axis=0)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    keep = ~np.isin(np.asarray(skeleton.bone_names), list(bones))
    d[keep] = rest[keep]
    return d


def refit_trunk_joints(body: BodyModel, frames, depth_camera=None, joints=tuple(TRUNK_REFIT_JOINTS),
                       rounds: int = TRUNK_REFIT_ROUNDS, unpose_refine_steps: int = UNPOSE_REFINE_STEPS) -> Skeleton:
    """The fitted ``body``'s skeleton with its trunk joints moved onto the SDK's (§4's unposing applied to the joints).

    ``frames``: (:class:`InitObservation`, depth points) pairs of the init. Per round, each frame's pose of the body
    (the IK on the SDK joints, refined by :func:`refined_init_pose` against the player mask and the depth when the
    ``depth_camera`` and the frame's ``player_mask`` are there) brings the SDK's ``joints`` (names of
    :data:`TRUNK_REFIT_JOINTS`) to the default pose by the inverse transform of the bone carrying each
    (:func:`unposed_kinect_joints`); the bone ends each joint is move to the joint's mean over the frames (values
    more than 3 median absolute deviations from the median dropped, per axis) in height and depth; across the body
    they stay on the skeleton's midline. A joint seen in fewer than three frames, or missing from the frames'
    Kinect version (v1 has no Neck), stays. The pose is fitted to the depth and the mask as well as to the joints, so
    a joint that the skeleton places off the surface around it comes back where the SDK sees it against that surface;
    the next round poses the body on the moved joints."""
    from bodystudio.mirror.refine import refine_plan

    frames = list(frames)
    unknown = [j for j in joints if j not in TRUNK_REFIT_JOINTS]
    if unknown:
        raise InputError(f"refit_trunk_joints: unknown trunk joint {unknown[0]!r}; valid: "
                         f"{', '.join(TRUNK_REFIT_JOINTS)}")
    sk = body.skeleton
    if not frames or not joints:
        return sk
    version = frames[0][0].version
    names = kinect_joint_names(version)
    for _ in range(max(int(rounds), 0)):
        posed = BodyModel(body.vertices, body.faces, sk, body.weights, body.resolution, body.rig,
                          vertex_ids=body.vertex_ids)
        plan = None
        if depth_camera is not None and unpose_refine_steps > 0:
            plan = refine_plan(posed.vertices, posed.faces, posed.weights, sk, version)
        unposed = []
        for o, P in frames:
            if o.version != version:
                continue
            pose = (refined_init_pose(plan, posed, o, P, depth_camera, unpose_refine_steps)
                    if plan is not None and o.player_mask is not None else ik_pose(sk, o.joints, o.tracked, o.version))
            unposed.append(unposed_kinect_joints(o.joints, o.tracked, sk, pose, o.version))
        U = np.array(unposed)
        heads, tails = sk.heads.copy(), sk.tails.copy()
        for joint in joints:
            name = _kinect_name(joint, version)
            if name not in names or len(U) == 0:
                continue
            values = U[:, names.index(name)]
            values = values[np.all(np.isfinite(values), axis=1)]
            if len(values) < 3:
                continue
            med = np.median(values, axis=0)
            spread = 3.0 * np.maximum(np.median(np.abs(values - med), axis=0), 1e-3)
            mean = np.array([values[np.abs(values[:, a] - med[a]) <= spread[a], a].mean() for a in range(3)])
            for bone, end in TRUNK_REFIT_JOINTS[joint]:
                ends = heads if end == "head" else tails
                ends[sk.index(bone), 1:] = mean[1:]
        sk = Skeleton(sk.bone_names, sk.parents, heads, tails, sk.rolls)
    return sk


def _session_version(names) -> str:
    for version in ("v2", "v1"):
        if list(names) == kinect_joint_names(version):
            return version
    raise InputError(f"Kinect joints named {list(names)[:3]}... match neither the v1 nor the v2 joint set")


def collect_observations(session, frames=None, player: int = 1, n_frames: int = DEFAULT_INIT_FRAMES,
                         stride: int = INIT_FRAME_STRIDE, silhouettes: bool = False):
    """InitObservations of ``player``: every ``stride``-th frame of the ``n_frames`` frames from the first
    one in which the player is seen (about 3 s at 30 fps), or exactly the given ``frames``.

    Neighbouring frames add little (at most :data:`MAX_FIT_FRAMES` are fitted), so reading every third
    frame saves two thirds of the decoding. Frames without the player, without joints or without depth
    are skipped; when none remains the InputError says which of those it was. With ``silhouettes`` each
    observation also carries the player's refined foreground in the colour image (the run's graph cut, with a
    background model learnt from the frames before the player appears) and the other players' pixels.
    """
    sensor = session.kinect
    if sensor is None:
        raise InputError(f"{session.path}: no Kinect calibration (kinect/calibration.json); "
                         "the mirror needs a Kinect RGB-D session")
    from bodystudio.capture.subject import session_follower
    from bodystudio.mirror.compose import update_background
    from bodystudio.mirror.foreground import refine_foreground
    from bodystudio.mirror.frames import point_cloud, read_mirror_frame, register_depth_to_color

    ids = list(session.frame_ids) if frames is None else [int(f) for f in frames]
    if not ids:
        raise InputError(f"{session.path}: no frames to initialise from")
    missing = sorted(set(ids) - set(session.frame_ids))
    if missing:
        raise InputError(f"{session.path}: frame(s) {missing[:5]} not in the session (it has "
                         f"{len(session.frame_ids)} frames)")
    out, why = [], {"no person": 0, "no joints": 0, "no depth": 0}
    first = None
    background = None
    # the actor is ``player`` where first tracked, then followed by its joints over the frames read (a person moves
    # step_m a frame, ``stride`` frames between two reads): the SDK renumbers a person it lost, crossing actors swap
    # ids, and the init must not fit the person who holds the id after a swap (rel6a)
    follower = session_follower(session, player, stride)
    for i in ids:
        if frames is None and first is not None:
            if i >= first + n_frames:
                break
            if (i - first) % max(int(stride), 1):
                continue
        frame = read_mirror_frame(session, i)
        subject = follower.follow([{"player": b.player, "names": b.names, "positions": b.positions}
                                   for b in frame.bodies])
        pid = player if subject is None else int(subject["player"])
        bodies = [b for b in frame.bodies if b.player == pid] if subject is not None else []
        if not bodies:
            why["no person" if not frame.bodies else "no joints"] += 1
            if silhouettes and first is None and frame.depth_m is not None:
                _, players_c = register_depth_to_color(frame.depth_m, frame.player, sensor)
                background = update_background(background, frame.rgb, players_c > 0)
            continue
        body = bodies[0]
        if not np.any(np.all(np.isfinite(body.positions), axis=1) & body.tracked):
            why["no joints"] += 1
            continue
        if frame.depth_m is None or not np.any(frame.depth_m > 0):
            why["no depth"] += 1
            continue
        points = point_cloud(frame, sensor, pid)
        if len(points) < MIN_POINTS:
            why["no person"] += 1
            continue
        foreground = others = None
        if silhouettes:
            depth_c, players_c = register_depth_to_color(frame.depth_m, frame.player, sensor)
            foreground = refine_foreground(frame.rgb, players_c == pid, depth_c, background=background)
            others = (players_c > 0) & (players_c != pid)
        out.append(InitObservation(i, points, body.positions, body.tracked, _session_version(body.names),
                                   foreground, others, frame.player == pid,
                                   (frame.player != 0) & (frame.player != pid)))
        first = i if first is None else first
    if not out:
        reason = max(why, key=why.get)
        detail = {"no person": f"player {player} is in none of the frames (no tracked body or too few depth "
                               "pixels in its player mask)",
                  "no joints": f"no frame has tracked Kinect joints for player {player}",
                  "no depth": "no frame has depth measurements"}[reason]
        raise InputError(f"{session.path}: cannot initialise the source body: {detail}; "
                         "record the actor standing in view, or pick --frames/--player")
    return out, sensor


def initialise_source_body(session, model: StatisticalBodyModel | None = None, frames=None, player: int = 1,
                           n_frames: int = DEFAULT_INIT_FRAMES, passes: int = INIT_PASSES,
                           silhouette_shape: bool = False,
                           bone_length_weight: float = BONE_LENGTH_WEIGHT, trunk_refit: bool = False,
                           unpose_posture: bool | None = None, bone_length_pairs=BONE_LENGTH_PAIRS) -> SourceBody:
    """§4 on a mirror session: the source body of ``player`` from up to ``n_frames`` frames (~3 s at 30 fps);
    ``silhouette_shape``: then refined against :data:`SILHOUETTE_FRAMES` frames' silhouettes (MIR12c);
    ``bone_length_weight`` > 0: the SDK's joint distances enter the fit (:data:`BONE_LENGTH_WEIGHT`, MIR12o);
    ``trunk_refit``: the skeleton's trunk joints moved onto the SDK's (:func:`refit_trunk_joints`, MIR12r);
    ``unpose_posture``: the refined unposing holds :data:`POSTURE_BONES` at the subject's own static posture
    (:func:`session_posture`, mir12v), False: the rest pose; None: :data:`UNPOSE_POSTURE_BONES` (on since mir12y);
    ``bone_length_pairs``: which joint distances (None: all; :data:`STATURE_BONE_PAIRS`, mir12ad)."""
    if model is None:
        from bodystudio.body.statistical import load_statistical_model

        model = load_statistical_model("6k", progress=False)
    model = check_model(model)
    obs, sensor = collect_observations(session, frames, player, n_frames, silhouettes=silhouette_shape)
    knee_frames = knee_joint_frames(session, obs) if KNEE_HINGE_FROM == "sdk" and KNEE_HINGE_WEIGHT > 0 else None
    return initialise_from_observations(obs, model, view_point=sensor.depth.center, passes=passes,
                                        depth_camera=sensor.depth, camera=sensor.color if silhouette_shape else None,
                                        silhouette_frames=SILHOUETTE_FRAMES if silhouette_shape else 0,
                                        bone_length_weight=bone_length_weight, trunk_refit=trunk_refit,
                                        unpose_posture_bones=UNPOSE_POSTURE_BONES if unpose_posture is None
                                        else POSTURE_BONES if unpose_posture else (),
                                        bone_length_pairs=bone_length_pairs, knee_frames=knee_frames)


# --- persistence -----------------------------------------------------------------------------------

def save_source_body(path: str | Path, body: SourceBody, player: int | None = None) -> None:
    """Write a source body as one versioned ``.npz`` (atomically); ``player``: the Kinect player it was fitted to,
    recorded so that ``mirror run`` never pairs it with another player (``run.check_source_player``)."""
    sk = body.skeleton
    arrays = dict(version=np.array(SOURCE_BODY_VERSION), coeffs=body.coeffs, vertices=body.vertices,
                  bone_names=np.array(sk.bone_names), parents=sk.parents, heads=sk.heads, tails=sk.tails,
                  rolls=sk.rolls, frames_used=np.array(body.frames_used, dtype=np.int64),
                  residual_mm=np.array(body.residual_mm))
    if player is not None:
        arrays["player"] = np.array(int(player), dtype=np.int64)
    with atomic_path(path, suffix=".npz") as tmp:
        np.savez(tmp, **arrays)


def source_fingerprint(body) -> str:
    """A short hash of a source body's coefficients, rest vertices and bone heads: which body a mirror run
    used, so that ``eval mirror`` does not score one body's run with another body's init errors."""
    import hashlib

    h = hashlib.sha256()
    for a in (body.coeffs, body.vertices, body.skeleton.heads):
        h.update(np.ascontiguousarray(a, np.float64).tobytes())
    return h.hexdigest()[:16]


def source_body_layout(path: str | Path):
    """The run layout ``mirror init`` writes the source body ``DIR/NAME.npz`` with: the summary ``NAME.json``
    as manifest (written last), lock and staging ``.NAME.npz.lock`` / ``.NAME.npz.staging`` beside them."""
    from bodystudio.runfolder import RunLayout

    path = Path(path)
    return RunLayout(path.parent, path.with_suffix(".json").name, f".{path.name}.", str(path))


def load_source_body(path: str | Path, model: StatisticalBodyModel | None = None) -> SourceBody:
    """Read :func:`save_source_body`'s file; with ``model``, check it is that model's and attach its skin weights."""
    import zipfile

    from bodystudio.runfolder import check_readable

    path = Path(path)
    # mirror init writes the body with its summary as one unit: a live write, or one killed after its commit
    # point (the body moved in, the summary not yet, or the reverse), is refused, not read half-replaced
    check_readable(source_body_layout(path))
    if not path.is_file():
        raise FileFormatError(f"{path}: source body not found; run 'bodystudio mirror init SESSION' first")
    try:
        with np.load(path, allow_pickle=False) as z:
            if int(z["version"]) != SOURCE_BODY_VERSION:
                raise FileFormatError(f"{path}: source body version {int(z['version'])}, expected "
                                      f"{SOURCE_BODY_VERSION}; rerun 'bodystudio mirror init'")
            sk = Skeleton(tuple(str(b) for b in z["bone_names"]), z["parents"].astype(np.int64),
                          z["heads"].astype(np.float64), z["tails"].astype(np.float64), z["rolls"].astype(np.float64))
            body = SourceBody(z["coeffs"].astype(np.float64), z["vertices"].astype(np.float64), sk,
                              tuple(int(f) for f in z["frames_used"]), float(z["residual_mm"]))
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:
        raise FileFormatError(f"{path}: not a readable source body ({exc}); rerun 'bodystudio mirror init'") from None
    n, B = len(body.vertices), sk.n_bones
    if (body.vertices.ndim != 2 or body.vertices.shape[1] != 3 or sk.heads.shape != (B, 3)
            or sk.tails.shape != (B, 3) or len(sk.parents) != B or len(sk.rolls) != B
            or not all(np.all(np.isfinite(a)) for a in (body.vertices, body.coeffs, sk.heads, sk.tails, sk.rolls))
            or not np.all((sk.parents >= -1) & (sk.parents < B))):
        raise FileFormatError(f"{path}: source body arrays are inconsistent or not finite; "
                              "rerun 'bodystudio mirror init'")
    if model is None:
        return body
    model = check_model(model)
    if len(body.coeffs) != model.n_components or n != len(model.mean) or sk.bone_names != model.bone_names:
        raise InputError(f"{path}: source body was fitted with another statistical model ({len(body.coeffs)} "
                         f"coefficients, {n} vertices; this model has {model.n_components} and "
                         f"{len(model.mean)}); rerun 'bodystudio mirror init' or load the same model")
    return SourceBody(body.coeffs, body.vertices, sk, body.frames_used, body.residual_mm, model.weights, model.faces)


# --- timing for benchmarks/bench_mirror.py ---------------------------------------------------------

def time_init_and_track(observations, model: StatisticalBodyModel, view_point=None, track_frames: int = 90,
                        passes: int = INIT_PASSES, depth_camera=None, untwist_bones=UNTWIST_BONES) -> dict:
    """Timings of the initialisation over ``observations`` and of the per-frame tracking, for benchmarks/.

    Returns wall-clock and CPU (``time.process_time``, immune to other processes on a shared machine)
    seconds of :func:`initialise_from_observations`, and per-frame milliseconds of ``ik_pose`` with
    ``untwisted_pose`` at ``untwist_bones`` as the run calls them (the run's: ``run.untwist_bones()``; warm-started
    on the fitted skeleton, the observations' joints cycled to ``track_frames`` frames), of skinning the source body,
    and of posing the source and target body in one pass
    (the run's ``posed_source_and_target``): ``{"init_s", "init_cpu_s", "init_frames", "ik_ms", "ik_cpu_ms", "skin_ms",
    "skin_cpu_ms", "bodies_ms", "bodies_cpu_ms"}`` (the per-frame figures are means over the frames).
    """
    w0, c0 = time.perf_counter(), time.process_time()
    source = initialise_from_observations(observations, model, view_point=view_point, passes=passes,
                                          depth_camera=depth_camera)
    init_s, init_cpu_s = time.perf_counter() - w0, time.process_time() - c0
    frames = [observations[i % len(observations)] for i in range(track_frames)]
    poses = []
    w0, c0 = time.perf_counter(), time.process_time()
    previous = None
    for o in frames:  # as the run: its limbs untwisted, the next frame warm-started by that (MIR12p)
        previous = untwisted_pose(source.skeleton, ik_pose(source.skeleton, o.joints, o.tracked, o.version, previous),
                                  untwist_bones)
        poses.append(previous)
    ik_s, ik_cpu_s = time.perf_counter() - w0, time.process_time() - c0
    w0, c0 = time.perf_counter(), time.process_time()
    for pose in poses:
        skin_vertices(source.vertices, source.weights, source.skeleton, pose)
    skin_s, skin_cpu_s = time.perf_counter() - w0, time.process_time() - c0
    from bodystudio.mirror.track import skin_source_and_target

    if poses:  # the numba kernels' compile (or cache load) outside the timer, as a running mirror has it behind it
        skin_source_and_target(source.vertices, source.vertices, source.weights, source.skeleton, source.skeleton,
                               poses[0])
    w0, c0 = time.perf_counter(), time.process_time()
    for pose in poses:  # what the run does per actor: the source and the target body in one pass (MIR12e); the
        # target's rest shape and rig do not change the cost, the source's stand in for them
        skin_source_and_target(source.vertices, source.vertices, source.weights, source.skeleton,
                               source.skeleton, pose)
    bodies_s, bodies_cpu_s = time.perf_counter() - w0, time.process_time() - c0
    n = max(track_frames, 1)
    return {"init_s": init_s, "init_cpu_s": init_cpu_s, "init_frames": len(source.frames_used),
            "ik_ms": 1000 * ik_s / n, "ik_cpu_ms": 1000 * ik_cpu_s / n,
            "skin_ms": 1000 * skin_s / n, "skin_cpu_ms": 1000 * skin_cpu_s / n,
            "bodies_ms": 1000 * bodies_s / n, "bodies_cpu_ms": 1000 * bodies_cpu_s / n}
