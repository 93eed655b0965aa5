"""Automatic initial pose, §4.3 of Avatar Reshaping: scan orientation, a coarse scan skeleton, and
hierarchical bone alignment of the model skeleton to it (the role of Pinocchio + Feng et al. 2013).

The scan is already canonical (y up, facing +z; :func:`bodystudio.register.scan.detect_orientation`).
The coarse skeleton is the one a standing scan shows without any model: floor, top of the head, the two
feet and the two hand tips (the surface points farthest out on each side above the hips) and a
pelvis centre. Hierarchical alignment then walks the model's chains root first: translation puts the
model's pelvis over the scan's, and each limb's root bone (upper arm, thigh) is rotated so that the
model's chain end (finger tip, toe) points where the scan's does.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from bodystudio.body import Pose, Skeleton
from bodystudio.body.skinning import forward_kinematics, linear_blend_skinning, skinning_transforms

# (limb root bone, which side: +1 = +x = left, -1 = right, end effector kind)
LIMB_CHAINS = (("upperarm_l", 1.0, "hand"), ("upperarm_r", -1.0, "hand"),
               ("thigh_l", 1.0, "foot"), ("thigh_r", -1.0, "foot"))


@dataclass(frozen=True)
class CoarseSkeleton:
    """End effectors of a standing scan (metres, canonical frame)."""

    floor_y: float
    head_top: np.ndarray
    pelvis: np.ndarray
    hand_tips: dict  # side (+1/-1) -> (3,)
    foot_tips: dict  # side -> (3,)

    @property
    def stature_m(self) -> float:
        return float(self.head_top[1] - self.floor_y)


def coarse_scan_skeleton(V: np.ndarray) -> CoarseSkeleton:
    """Floor, head top, pelvis centre, hand tips and toe tips of a canonical standing scan."""
    floor = float(V[:, 1].min())
    top = V[np.argmax(V[:, 1])]
    h = float(V[:, 1].max() - floor)
    # The pelvis: centre of the slice at about 52 % of stature (hip joint height of adults).
    band = np.abs(V[:, 1] - (floor + 0.52 * h)) < 0.02 * h
    core = band & (np.abs(V[:, 0] - np.median(V[band, 0])) < 0.2 * h)
    pelvis = np.array([np.median(V[core, 0]), floor + 0.52 * h, np.median(V[core, 2])])
    hands, feet = {}, {}
    upper = V[:, 1] > floor + 0.35 * h
    lower = V[:, 1] < floor + 0.08 * h
    for side in (1.0, -1.0):
        s = upper & (side * (V[:, 0] - pelvis[0]) > 0.05 * h)
        cand = V[s] if s.any() else V[upper]
        hands[side] = cand[np.argmax(side * (cand[:, 0] - pelvis[0]) - 0.3 * np.maximum(cand[:, 1] - pelvis[1], 0))]
        f = lower & (side * (V[:, 0] - pelvis[0]) > 0)
        cand = V[f] if f.any() else V[lower]
        feet[side] = cand[np.argmax(cand[:, 2])]
    return CoarseSkeleton(floor, top, pelvis, hands, feet)


def _chain_end_vertex(skeleton: Skeleton, weights: np.ndarray, V: np.ndarray, root: str, kind: str) -> int:
    """Model vertex at the end of a limb chain: farthest from the limb root among the hand/foot's vertices."""
    side = root[-2:]
    end_bones = [i for i, b in enumerate(skeleton.bone_names)
                 if (b.endswith(side) and (b.startswith(("hand", "index", "middle", "ring", "pinky", "thumb"))
                                           if kind == "hand" else b.startswith(("foot", "ball"))))]
    owned = np.flatnonzero(weights[:, end_bones].sum(1) > 0.5)
    head = skeleton.heads[skeleton.index(root)]
    if kind == "hand":
        return int(owned[np.argmax(np.linalg.norm(V[owned] - head, axis=1))])
    return int(owned[np.argmax(V[owned, 2])])


def initial_pose(skeleton: Skeleton, weights: np.ndarray, rest_vertices: np.ndarray, scan_vertices: np.ndarray,
                 coarse: CoarseSkeleton | None = None) -> Pose:
    """Initial θ of the model (rest vertices + skeleton + weights) for a canonical scan (§4.3)."""
    coarse = coarse or coarse_scan_skeleton(scan_vertices)
    B = skeleton.n_bones
    rot = np.zeros((B, 3))
    pelvis = skeleton.index("pelvis")
    # Root translation: the model's pelvis head over the scan's pelvis centre, feet on the scan's floor.
    floor_model = rest_vertices[:, 1].min()
    translation = np.array([coarse.pelvis[0] - skeleton.heads[pelvis][0], coarse.floor_y - floor_model,
                            coarse.pelvis[2] - skeleton.heads[pelvis][2]])
    pose = Pose(rot.copy(), translation)
    for root, side, kind in LIMB_CHAINS:
        j = skeleton.index(root)
        end = _chain_end_vertex(skeleton, weights, rest_vertices, root, kind)
        M = forward_kinematics(skeleton, pose)
        posed = linear_blend_skinning(rest_vertices[[end]], weights[[end]], skinning_transforms(skeleton, pose))[0]
        origin = M[j, :3, 3]
        target = (coarse.hand_tips if kind == "hand" else coarse.foot_tips)[side]
        d_model, d_scan = posed - origin, target - origin
        if np.linalg.norm(d_model) < 1e-6 or np.linalg.norm(d_scan) < 1e-6:
            continue
        axis = np.cross(d_model, d_scan)
        angle = np.arctan2(np.linalg.norm(axis), d_model @ d_scan)
        if kind == "foot":  # legs: only swing sideways/forwards a little; the fit does the rest
            angle = min(angle, 0.35)
        if np.linalg.norm(axis) < 1e-9:
            continue
        R_delta = Rotation.from_rotvec(axis / np.linalg.norm(axis) * angle).as_matrix()
        G = M[j, :3, :3]  # global rotation of the bone now; rotate it by R_delta in world axes
        local = Rotation.from_rotvec(rot[j]).as_matrix() @ (G.T @ R_delta @ G)
        rot[j] = Rotation.from_matrix(local).as_rotvec()
        pose = Pose(rot.copy(), translation)
    return pose
