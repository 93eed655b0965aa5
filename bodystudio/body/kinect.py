"""Joint maps from our skeleton (MakeHuman ``game_engine`` rig) to the Kinect body-tracker joint sets.

Each Kinect joint is a weighted sum of bone heads/tails, so it follows any shape and pose. Kinect's
"Left" is the tracked person's left, as is MakeHuman's ``_l``.
"""

from __future__ import annotations

import numpy as np

from bodystudio.body.skeleton import Skeleton
from bodystudio.errors import InputError

# (bone, end, weight); end is "head" or "tail".
_HAND_L = [("hand_l", "head", 0.5), ("middle_01_l", "head", 0.5)]
_HAND_R = [("hand_r", "head", 0.5), ("middle_01_r", "head", 0.5)]
_HEAD = [("head", "head", 0.5), ("head", "tail", 0.5)]

# Joints both SDKs track, by their Kinect v2 names, in v2 order.
_LIMBS: dict[str, list[tuple[str, str, float]]] = {
    "ShoulderLeft": [("upperarm_l", "head", 1.0)],
    "ElbowLeft": [("lowerarm_l", "head", 1.0)],
    "WristLeft": [("hand_l", "head", 1.0)],
    "HandLeft": _HAND_L,
    "ShoulderRight": [("upperarm_r", "head", 1.0)],
    "ElbowRight": [("lowerarm_r", "head", 1.0)],
    "WristRight": [("hand_r", "head", 1.0)],
    "HandRight": _HAND_R,
    "HipLeft": [("thigh_l", "head", 1.0)],
    "KneeLeft": [("calf_l", "head", 1.0)],
    "AnkleLeft": [("foot_l", "head", 1.0)],
    "FootLeft": [("ball_l", "head", 1.0)],
    "HipRight": [("thigh_r", "head", 1.0)],
    "KneeRight": [("calf_r", "head", 1.0)],
    "AnkleRight": [("foot_r", "head", 1.0)],
    "FootRight": [("ball_r", "head", 1.0)],
}

KINECT_V1_JOINTS: dict[str, list[tuple[str, str, float]]] = {
    "HipCenter": [("pelvis", "head", 1.0)],
    "Spine": [("spine_02", "head", 1.0)],
    "ShoulderCenter": [("spine_03", "tail", 1.0)],
    "Head": _HEAD,
    **_LIMBS,
}

KINECT_V2_JOINTS: dict[str, list[tuple[str, str, float]]] = {
    "SpineBase": [("pelvis", "head", 1.0)],
    "SpineMid": [("spine_02", "head", 1.0)],
    "Neck": [("neck_01", "head", 1.0)],
    "Head": _HEAD,
    **_LIMBS,
    "SpineShoulder": [("spine_03", "tail", 1.0)],
    "HandTipLeft": [("middle_03_l", "tail", 1.0)],
    "ThumbLeft": [("thumb_03_l", "tail", 1.0)],
    "HandTipRight": [("middle_03_r", "tail", 1.0)],
    "ThumbRight": [("thumb_03_r", "tail", 1.0)],
}

KINECT_JOINT_SETS = {"v1": KINECT_V1_JOINTS, "v2": KINECT_V2_JOINTS}


def kinect_joint_names(version: str) -> list[str]:
    if version not in KINECT_JOINT_SETS:
        raise InputError(f"unknown Kinect version {version!r}; valid: v1, v2")
    return list(KINECT_JOINT_SETS[version])


def kinect_joints(skeleton: Skeleton, heads: np.ndarray, tails: np.ndarray, version: str = "v2") -> np.ndarray:
    """Kinect joint positions ``(J, 3)`` from (posed) bone heads and tails of a game_engine skeleton."""
    names = kinect_joint_names(version)
    out = np.zeros((len(names), 3))
    for k, name in enumerate(names):
        for bone, end, w in KINECT_JOINT_SETS[version][name]:
            if bone not in skeleton.bone_names:
                raise InputError(f"Kinect joint maps need the game_engine rig; bone {bone!r} is missing")
            j = skeleton.bone_names.index(bone)
            out[k] += w * (heads[j] if end == "head" else tails[j])
    return out
