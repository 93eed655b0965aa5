"""The shoulder-arm template and its four-part kinematics (§6.1 and Eq. 12 of Arm-Muscle Capture).

The paper's template is "the arm and part of the chest encompassing biceps, triceps, deltoid and
pectoralis muscles", with a hand attached for display but not tracked. Ours is cut from the MakeHuman
body at one resolution: the vertices skinned to the arm chain (clavicle, upper arm, forearm, hand and
fingers) plus the chest and back within ``CHEST_RADIUS_M`` of the shoulder joint, on the arm's side
only. The cut is made once per (resolution, side) on the default body, so every subject's arm has
the same topology (``ArmTemplate.key``) and a model learned on one template refuses another.

Parts (``PARTS``): torso (every bone outside the arm chain, clavicle included), upper arm, forearm,
hand (hand + fingers). ``part_weights`` sums the body's skin weights per part.

An :class:`ArmPose` is a rigid ``root`` (the clavicle's skinning transform: the torso's motion that
carries the shoulder) and three rotation vectors (shoulder, elbow, wrist) in rest-pose world axes,
each about its rest joint centre and composed down the chain:

    T_torso = root,  T_upper = T_torso Rot(shoulder),  T_fore = T_upper Rot(elbow),
    T_hand = T_fore Rot(wrist),   Rot(j) = Trans(c_j) R(a_j) Trans(-c_j).

With the body's ``Pose`` (local axis-angle ``theta_j`` in bone ``j``'s rest frame ``A_j``) the arm
angles are ``a_j = R_Aj theta_j``, so :func:`pose_arm` with :func:`arm_pose_from_body_pose` reproduces
``body.pose()`` exactly on the arm, up to finger motion (hand part) and clavicle motion relative to
the spine (torso part).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial.transform import Rotation

from bodystudio.body import Phenotype, Pose, build_body, skinning_transforms
from bodystudio.errors import InputError

PARTS = ("torso", "upperarm", "forearm", "hand")
SIDES = {"left": "_l", "right": "_r"}
JOINT_NAMES = ("shoulder", "elbow", "wrist")
# Chest and back kept around the shoulder joint: reaches the pectoralis and the scapular region.
CHEST_RADIUS_M = 0.17
# Vertices with at least this much arm-chain weight belong to the arm region.
ARM_WEIGHT_MIN = 0.02
FINGERS = ("index", "middle", "pinky", "ring", "thumb")


def _side_suffix(side: str) -> str:
    if side not in SIDES:
        raise InputError(f"unknown arm side {side!r}; valid: {', '.join(SIDES)}")
    return SIDES[side]


def arm_bone_groups(bone_names: tuple[str, ...], side: str) -> dict[str, list[int]]:
    """Bone indices of each part: the arm chain of ``side``; every other bone is torso."""
    s = _side_suffix(side)
    groups = {"upperarm": [bone_names.index(f"upperarm{s}")], "forearm": [bone_names.index(f"lowerarm{s}")],
              "hand": [i for i, n in enumerate(bone_names)
                       if n == f"hand{s}" or (n.endswith(s) and n.split("_")[0] in FINGERS)]}
    taken = {i for g in groups.values() for i in g}
    groups["torso"] = [i for i in range(len(bone_names)) if i not in taken]
    return {p: groups[p] for p in PARTS}


@dataclass(frozen=True, eq=False)
class ArmTemplate:
    """The shoulder-arm region of one body: topology, rest vertices, four-part weights and joints."""

    vertex_ids: np.ndarray  # (n,) rows of the body template this region was cut from
    faces: np.ndarray  # (m, 3) over 0..n-1
    vertices: np.ndarray  # (n, 3) rest (base pose) positions, metres
    part_weights: np.ndarray  # (n, 4) per PARTS, rows sum to 1
    joints: np.ndarray  # (3, 3) rest shoulder, elbow, wrist centres
    arm_mask: np.ndarray  # (n,) bool: upper arm + forearm (+ shoulder): tracked and modelled
    side: str = "left"
    resolution: str = "6k"

    @property
    def n_vertices(self) -> int:
        return len(self.vertices)

    @property
    def key(self) -> str:
        """Topology identifier (resolution, side, vertex count, hash of ids and faces)."""
        h = hashlib.sha1(np.ascontiguousarray(self.vertex_ids, dtype=np.int64).tobytes())
        h.update(np.ascontiguousarray(self.faces, dtype=np.int64).tobytes())
        return f"{self.resolution}-{self.side}-{self.n_vertices}-{h.hexdigest()[:12]}"

    def with_vertices(self, vertices: np.ndarray, joints: np.ndarray | None = None) -> ArmTemplate:
        """The same template with other rest vertices (and joints): another subject's arm."""
        V = np.asarray(vertices, dtype=np.float64)
        if V.shape != self.vertices.shape:
            raise InputError(f"arm vertices have shape {V.shape}; this template needs {self.vertices.shape}")
        J = self.joints if joints is None else np.asarray(joints, dtype=np.float64).reshape(3, 3)
        return ArmTemplate(self.vertex_ids, self.faces, V, self.part_weights, J, self.arm_mask, self.side,
                           self.resolution)


@lru_cache(maxsize=8)
def _region(resolution: str, side: str) -> tuple[np.ndarray, np.ndarray]:
    """Vertex ids and faces of the arm region on the default body (shape-independent topology)."""
    body = build_body(Phenotype(), resolution=resolution)
    names = body.skeleton.bone_names
    s = _side_suffix(side)
    groups = arm_bone_groups(names, side)
    chain = groups["upperarm"] + groups["forearm"] + groups["hand"] + [names.index(f"clavicle{s}")]
    w_arm = body.weights[:, chain].sum(axis=1)
    shoulder = body.skeleton.heads[names.index(f"upperarm{s}")]
    sign = 1.0 if side == "left" else -1.0
    V = body.vertices
    near = (np.linalg.norm(V - shoulder, axis=1) < CHEST_RADIUS_M) & (sign * V[:, 0] > 0.03)
    keep = (w_arm >= ARM_WEIGHT_MIN) | near
    # No head or neck: nothing above the top of the shoulder.
    keep &= V[:, 1] < shoulder[1] + 0.08
    F = body.faces
    Fk = F[keep[F].all(axis=1)]
    ids = np.flatnonzero(keep)
    remap = -np.ones(len(V), dtype=np.int64)
    remap[ids] = np.arange(len(ids))
    Fl = remap[Fk]
    # The largest connected piece (drops stray islands the cut left).
    n = len(ids)
    A = coo_matrix((np.ones(Fl.size), (Fl.ravel(), Fl[:, [1, 2, 0]].ravel())), shape=(n, n))
    _, label = connected_components(A, directed=False)
    main = np.bincount(label[Fl[:, 0]]).argmax()
    inside = label == main
    Fl = Fl[inside[Fl[:, 0]]]
    ids2 = ids[inside]
    remap2 = -np.ones(n, dtype=np.int64)
    remap2[np.flatnonzero(inside)] = np.arange(inside.sum())
    return ids2, remap2[Fl]


def arm_template(body, side: str = "left") -> ArmTemplate:
    """The shoulder-arm region of ``body`` (a BodyModel) as an :class:`ArmTemplate` (§6.1)."""
    ids, faces = (a.copy() for a in _region(body.resolution, side))
    if body.n_vertices <= ids.max():
        raise InputError(f"body has {body.n_vertices} vertices; the {body.resolution} arm template needs more")
    groups = arm_bone_groups(body.skeleton.bone_names, side)
    W = body.weights[ids]
    part_weights = np.stack([W[:, groups[p]].sum(axis=1) for p in PARTS], axis=1)
    part_weights /= part_weights.sum(axis=1, keepdims=True)
    s = _side_suffix(side)
    names = body.skeleton.bone_names
    joints = body.skeleton.heads[[names.index(f"upperarm{s}"), names.index(f"lowerarm{s}"), names.index(f"hand{s}")]]
    arm_mask = (part_weights[:, 1] + part_weights[:, 2] >= 0.3) & (part_weights[:, 3] < 0.5)
    return ArmTemplate(ids, faces.copy(), body.vertices[ids].copy(), part_weights, joints.copy(), arm_mask,
                       side, body.resolution)


@dataclass(frozen=True, eq=False)
class ArmPose:
    """Rigid torso transform ``root`` (4, 4) and shoulder/elbow/wrist rotation vectors ``angles`` (3, 3)."""

    root: np.ndarray
    angles: np.ndarray

    def __post_init__(self):
        object.__setattr__(self, "root", np.asarray(self.root, dtype=np.float64).reshape(4, 4))
        object.__setattr__(self, "angles", np.asarray(self.angles, dtype=np.float64).reshape(3, 3))

    @classmethod
    def rest(cls) -> ArmPose:
        return cls(np.eye(4), np.zeros((3, 3)))

    def to_dict(self) -> dict:
        return {"root": self.root.tolist(), **{n: self.angles[i].tolist() for i, n in enumerate(JOINT_NAMES)}}

    @classmethod
    def from_dict(cls, data: dict, source: str = "arm pose") -> ArmPose:
        try:
            root = np.asarray(data["root"], dtype=np.float64)
            angles = np.asarray([data[n] for n in JOINT_NAMES], dtype=np.float64)
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"{source}: needs 'root' (4x4) and shoulder/elbow/wrist rotation vectors ({exc})") \
                from None
        finite = np.isfinite(root).all() and np.isfinite(angles).all()
        if root.shape != (4, 4) or angles.shape != (3, 3) or not finite:
            raise InputError(f"{source}: 'root' must be a finite 4x4 matrix and each joint a finite 3-vector")
        return cls(root, angles)


def _rotation_about(center: np.ndarray, rotvec: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    R = Rotation.from_rotvec(rotvec).as_matrix()
    T[:3, :3] = R
    T[:3, 3] = center - R @ center
    return T


def part_transforms(joints: np.ndarray, pose: ArmPose) -> np.ndarray:
    """Global rigid transform of each of ``PARTS`` (4, 4, 4): the chain above, applied to rest points."""
    T = np.empty((4, 4, 4))
    T[0] = pose.root
    for k in range(3):
        T[k + 1] = T[k] @ _rotation_about(joints[k], pose.angles[k])
    return T


def pose_arm(vertices: np.ndarray, part_weights: np.ndarray, joints: np.ndarray, pose: ArmPose) -> np.ndarray:
    """Linear blend skinning with the four parts, the ``skinning()`` of Eq. 12 of Arm-Muscle Capture."""
    T = part_transforms(np.asarray(joints, dtype=np.float64), pose)
    R = np.einsum("np,pij->nij", part_weights, T[:, :3, :3])
    t = part_weights @ T[:, :3, 3]
    return np.einsum("nij,nj->ni", R, vertices) + t


def arm_pose_from_body_pose(body, pose: Pose, side: str = "left") -> ArmPose:
    """Ground-truth :class:`ArmPose` of a body ``Pose``: clavicle motion as root, world-axis joint angles."""
    s = _side_suffix(side)
    names = body.skeleton.bone_names
    S = skinning_transforms(body.skeleton, pose)
    root = S[names.index(f"clavicle{s}")]
    chain = [names.index(f"{b}{s}") for b in ("upperarm", "lowerarm", "hand")]
    RA = body.skeleton.rest_rotations
    angles = np.stack([RA[j] @ pose.rotations[j] for j in chain])
    return ArmPose(root, angles)


def body_pose_from_arm_pose(body, arm_pose: ArmPose, side: str = "left", base: Pose | None = None) -> Pose:
    """A body ``Pose`` whose arm chain has ``arm_pose``'s joint angles (the inverse of the map above).

    Only the joint angles are set (``theta_j = R_Aj^T a_j``); the torso (root) motion comes from ``base``.
    """
    s = _side_suffix(side)
    names = body.skeleton.bone_names
    base = base or body.rest_pose()
    rot = base.rotations.copy()
    RA = body.skeleton.rest_rotations
    for k, b in enumerate(("upperarm", "lowerarm", "hand")):
        j = names.index(f"{b}{s}")
        rot[j] = RA[j].T @ arm_pose.angles[k]
    return Pose(rot, base.translation.copy())
