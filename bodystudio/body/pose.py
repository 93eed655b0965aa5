"""Poses: per-bone local rotations (axis-angle, in each bone's rest frame) plus a root translation.

Pose files are JSON in one of two layouts:

* ours: ``{"rotations": {"lowerarm_l": [rx, ry, rz], ...}, "translation": [x, y, z]}`` with
  axis-angle vectors in radians;
* MPFB2's (``poses/*_fk/*.json`` in the MakeHuman assets): ``{"bone_rotations": {bone: [ex, ey, ez]}}``
  with Blender XYZ Euler angles in radians.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from bodystudio.errors import FileFormatError, InputError


@dataclass(frozen=True, eq=False)
class Pose:
    """Local bone rotations ``(B, 3)`` axis-angle (radians) and root translation ``(3,)`` (metres)."""

    rotations: np.ndarray
    translation: np.ndarray

    def __post_init__(self):
        object.__setattr__(self, "rotations", np.asarray(self.rotations, dtype=np.float64).reshape(-1, 3))
        object.__setattr__(self, "translation", np.asarray(self.translation, dtype=np.float64).reshape(3))

    @classmethod
    def rest(cls, n_bones: int) -> Pose:
        return cls(np.zeros((n_bones, 3)), np.zeros(3))


def pose_from_dict(data: dict, bone_names: tuple[str, ...], source: str = "pose") -> Pose:
    """Build a Pose from a parsed pose file; unknown bones or malformed values raise one-line errors."""
    if not isinstance(data, dict) or not ({"rotations", "bone_rotations"} & set(data)):
        raise FileFormatError(f"{source}: a pose file needs a 'rotations' (axis-angle) or 'bone_rotations' "
                              f"(Euler XYZ) object mapping bone names to 3 numbers")
    euler = "bone_rotations" in data
    table = data["bone_rotations" if euler else "rotations"]
    if not isinstance(table, dict):
        raise FileFormatError(f"{source}: 'rotations' must map bone names to [x, y, z]")
    rot = np.zeros((len(bone_names), 3))
    index = {b: i for i, b in enumerate(bone_names)}
    for bone, value in table.items():
        if bone not in index:
            raise InputError(f"{source}: unknown bone {bone!r}; valid bones: {', '.join(bone_names)}")
        v = np.asarray(value, dtype=float) if _is_triplet(value) else None
        if v is None or not np.all(np.isfinite(v)):
            raise FileFormatError(f"{source}: rotation of {bone} must be 3 finite numbers, got {value!r}")
        rot[index[bone]] = Rotation.from_euler("xyz", v).as_rotvec() if euler else v
    trans = data.get("translation", [0.0, 0.0, 0.0])
    if not _is_triplet(trans) or not np.all(np.isfinite(np.asarray(trans, dtype=float))):
        raise FileFormatError(f"{source}: 'translation' must be 3 finite numbers in metres, got {trans!r}")
    return Pose(rot, np.asarray(trans, dtype=float))


def _is_triplet(value) -> bool:
    return (isinstance(value, (list, tuple)) and len(value) == 3
            and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in value))


def load_pose(path: str | Path, bone_names: tuple[str, ...]) -> Pose:
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise FileFormatError(f"{path}: pose file not found") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise FileFormatError(f"{path}: not valid JSON ({exc}); "
                              "a pose file is JSON with a 'rotations' object") from None
    return pose_from_dict(data, bone_names, str(path))


def pose_to_dict(pose: Pose, bone_names: tuple[str, ...]) -> dict:
    return {"rotations": {b: pose.rotations[i].tolist() for i, b in enumerate(bone_names)
                          if np.any(pose.rotations[i] != 0)},
            "translation": pose.translation.tolist()}


def transfer_pose(pose: Pose, source, target) -> Pose:
    """The same pose for a reshaped skeleton (``source``, ``target``: Skeletons of one rig): every bone turns
    by the same rotation in world axes, which is what the posed surface sees.

    A Pose holds rotations in each bone's rest frame, and a reshape can turn a rest frame a lot where the
    bone direction is near the roll convention's singularity (the short ``Root`` and ``ball`` bones
    point forward): ``L_T = R_T^T (R_S L_S R_S^T) R_T`` keeps ``R L R^T``, which is all skinning sees.
    """
    L = Rotation.from_rotvec(pose.rotations).as_matrix()
    Rs, Rt = source.rest_rotations, target.rest_rotations
    world = np.einsum("bij,bjk,blk->bil", Rs, L, Rs)
    local = np.einsum("bji,bjk,bkl->bil", Rt, world, Rt)
    return Pose(Rotation.from_matrix(local).as_rotvec(), pose.translation)
