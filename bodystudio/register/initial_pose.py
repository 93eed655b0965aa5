"""Automatic initial pose, §4.3 of Avatar Reshaping: scan orientation, a coarse scan skeleton, and
hierarchical bone alignment of the model skeleton to it (the role of Pinocchio + Feng et al. 2013).

The scan is already canonical (y up, facing +z; :func:`bodystudio.register.scan.detect_orientation`).
The coarse skeleton is the one a standing scan shows without any model: floor, top of the head, the two
feet and the two hand tips (the surface points farthest out on each side above the hips) and a
pelvis centre. Hierarchical alignment then walks the model's chains root first: translation puts the
model's pelvis over the scan's, and each limb's root bone (upper arm, thigh) is rotated so that the
model's chain end (finger tip, toe) points where the scan's does.

The arms bend at the elbow and wrist, so a straight arm aimed at the hand tip leaves the fit to find the
bend, and it often twisted the arm into a wrong basin instead (random poses: upper arm 40-80° off).
The limb chains therefore go one bone at a time through rings of equal geodesic distance from the hand
(toe) tip: geodesic distance along a limb hardly changes with pose, so the ring at the distance of the
model's elbow (wrist, knee, ankle) is the scan's cross-section there, and its centroid a joint centre. The model's own
rings, taken the same way on its rest mesh, are aligned to the scan's, so the rings' bias (a ring near
the wrist also cuts the thumb) cancels.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import dijkstra
from scipy.spatial.transform import Rotation

from bodystudio.body import Pose, Skeleton
from bodystudio.body.skinning import forward_kinematics, linear_blend_skinning, skinning_transforms
from bodystudio.errors import InputError
from bodystudio.geometry.mesh import vertex_areas

# (limb root bone, which side: +1 = +x = left, -1 = right, end effector kind)
LIMB_CHAINS = (("upperarm_l", 1.0, "hand"), ("upperarm_r", -1.0, "hand"),
               ("thigh_l", 1.0, "foot"), ("thigh_r", -1.0, "foot"))
# Limb bones aligned one at a time, each to the ring at its child joint (the last one: to the tip).
LIMB_BONES = {"hand": (("upperarm", "lowerarm"), ("lowerarm", "hand"), ("hand", None)),
              "foot": (("thigh", "calf"), ("calf", "foot"), ("foot", None))}
RING_HALF_WIDTH_M = 0.008


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


def weighted_median(x: np.ndarray, w: np.ndarray) -> float:
    """The value splitting the total weight ``w`` of the samples ``x`` in half (``x`` must not be empty)."""
    if len(x) == 0:
        raise ValueError("weighted_median of no samples")
    order = np.argsort(x)
    c = np.cumsum(w[order])
    return float(x[order][np.searchsorted(c, 0.5 * c[-1])])


def coarse_scan_skeleton(V: np.ndarray, F: np.ndarray | None = None) -> CoarseSkeleton:
    """Floor, head top, pelvis centre, hand tips and toe tips of a canonical standing scan."""
    floor = float(V[:, 1].min())
    top = V[np.argmax(V[:, 1])]
    h = float(V[:, 1].max() - floor)
    # The pelvis: centre of the slice at about 52 % of stature (hip joint height of adults). Medians weighted
    # by surface area: hands hanging at that height carry many small triangles (finger detail), and an
    # unweighted median followed them (pelvis 15 cm off on a random pose).
    # The slice is centred on the body's median plane first (that of the whole surface, which limbs on both
    # sides hardly move), which keeps hands beside the hips out of it.
    area = vertex_areas(V, F) if F is not None else np.ones(len(V))
    band = np.abs(V[:, 1] - (floor + 0.52 * h)) < 0.02 * h
    upper, lower = V[:, 1] > floor + 0.35 * h, V[:, 1] < floor + 0.08 * h
    if not band.any() or not upper.any() or not lower.any():
        raise InputError(f"the scan has no surface points at hip height or near the feet ({len(V)} vertices over "
                         f"{h:.2f} m): too coarse, or not a person standing upright; give a body scan with "
                         "vertices every few centimetres (remesh it)")
    core = band & (np.abs(V[:, 0] - weighted_median(V[:, 0], area)) < 0.12 * h)
    core = core if core.any() else band
    pelvis = np.array([weighted_median(V[core, 0], area[core]), floor + 0.52 * h,
                       weighted_median(V[core, 2], area[core])])
    hands, feet = {}, {}
    for side in (1.0, -1.0):
        s = upper & (side * (V[:, 0] - pelvis[0]) > 0.05 * h)
        cand = V[s] if s.any() else V[upper]
        hands[side] = cand[np.argmax(side * (cand[:, 0] - pelvis[0]) - 0.3 * np.maximum(cand[:, 1] - pelvis[1], 0))]
        f = lower & (side * (V[:, 0] - pelvis[0]) > 0)
        cand = V[f] if f.any() else V[lower]
        feet[side] = cand[np.argmax(cand[:, 2])]
    return CoarseSkeleton(floor, top, pelvis, hands, feet)


def edge_length_graph(V: np.ndarray, F: np.ndarray) -> sp.csr_matrix:
    """Sparse symmetric graph of the mesh edges weighted by their lengths (for geodesic distances)."""
    E = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    length = np.linalg.norm(V[E[:, 0]] - V[E[:, 1]], axis=1) + 1e-12
    G = sp.coo_matrix((length, (E[:, 0], E[:, 1])), shape=(len(V), len(V))).tocsr()
    return G.maximum(G.T)


def limb_tips(V: np.ndarray, F: np.ndarray, coarse: CoarseSkeleton) -> dict:
    """``(kind, side) -> vertex``: per side, the vertex geodesically farthest from the chest above the crotch
    (``"hand"``: the longest finger's tip) and below it (``"foot"``: the toe tip); -1 where the surface is not
    connected."""
    h = coarse.stature_m
    band = np.abs(V[:, 1] - (coarse.floor_y + 0.72 * h)) < 0.03 * h
    front = band & (np.abs(V[:, 0] - coarse.pelvis[0]) < 0.05 * h)
    chest = int(np.flatnonzero(front)[np.argmax(V[front, 2])]) if front.any() else int(np.argmax(V[:, 2]))
    graph = edge_length_graph(V, F)
    g = dijkstra(graph, indices=chest)
    above = (V[:, 1] > coarse.floor_y + 0.45 * h) & (g < np.inf)
    tips = {}
    for side in (1.0, -1.0):
        # Above the crotch (about 45 % of stature) the farthest points are the finger tips, about 0.4 statures
        # from the chest; a hand cut off by a hole leaves only nearer points (shoulder, hip): no tip.
        arm = above & (side * (V[:, 0] - coarse.pelvis[0]) > 0.05 * h)
        far = np.flatnonzero(arm)[np.argmax(g[arm])] if arm.any() else -1
        tips["hand", side] = int(far) if far >= 0 and g[far] > 0.3 * h else -1
    # Below the crotch the toes, 0.7 statures from the chest: the farthest point, then the point farthest from
    # both the chest and that one (a foot can cross the midline, so x does not tell the feet apart). The foot
    # whose thigh (the ring 0.4 statures up the leg) lies further to +x is the left one.
    legs = ~above & (g < np.inf)
    tips["foot", 1.0] = tips["foot", -1.0] = -1
    if legs.sum() < 2:
        return tips
    first = int(np.flatnonzero(legs)[np.argmax(g[legs])])
    g_first = dijkstra(graph, indices=first)
    second = int(np.flatnonzero(legs)[np.argmax(np.minimum(g, g_first)[legs])])
    g_second = dijkstra(graph, indices=second, limit=0.5 * h)
    if min(g[first], g[second]) < 0.3 * h:
        return tips
    thigh_x = [V[np.abs(d - 0.4 * h) < 0.01 * h, 0].mean() if (np.abs(d - 0.4 * h) < 0.01 * h).any() else V[t, 0]
               for d, t in ((g_first, first), (g_second, second))]
    left, right = (first, second) if thigh_x[0] > thigh_x[1] else (second, first)
    tips["foot", 1.0], tips["foot", -1.0] = left, right
    return tips


def geodesic_rings(V: np.ndarray, F: np.ndarray, tip: int, distances_m: np.ndarray) -> list[np.ndarray]:
    """Vertex sets at geodesic distance ``distances_m`` (± :data:`RING_HALF_WIDTH_M`) from vertex ``tip``."""
    g = dijkstra(edge_length_graph(V, F), indices=tip, limit=float(np.max(distances_m)) + 2 * RING_HALF_WIDTH_M)
    return [np.flatnonzero(np.abs(g - d) < RING_HALF_WIDTH_M) for d in distances_m]


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


def _rotate_bone_towards(skeleton: Skeleton, pose: Pose, j: int, d_model: np.ndarray, d_scan: np.ndarray,
                         max_angle: float = np.pi) -> Pose:
    """``pose`` with bone ``j``'s local rotation turned by the smallest world rotation taking ``d_model`` to
    ``d_scan`` (at most ``max_angle``)."""
    axis = np.cross(d_model, d_scan)
    if np.linalg.norm(axis) < 1e-9 * np.linalg.norm(d_model) * np.linalg.norm(d_scan):
        return pose
    angle = min(np.arctan2(np.linalg.norm(axis), d_model @ d_scan), max_angle)
    R_delta = Rotation.from_rotvec(axis / np.linalg.norm(axis) * angle).as_matrix()
    G = forward_kinematics(skeleton, pose)[j, :3, :3]  # rotate the bone by R_delta in world axes
    rot = pose.rotations.copy()
    rot[j] = Rotation.from_matrix(Rotation.from_rotvec(rot[j]).as_matrix() @ (G.T @ R_delta @ G)).as_rotvec()
    return Pose(rot, pose.translation)


def align_limb(skeleton: Skeleton, weights: np.ndarray, rest_vertices: np.ndarray, faces: np.ndarray,
               scan_vertices: np.ndarray, scan_faces: np.ndarray, pose: Pose, kind: str, side: str, model_tip: int,
               scan_tip: int) -> Pose:
    """Hierarchical alignment of one limb (upper arm, forearm, hand; thigh, calf, foot) through geodesic rings
    from its tip: each bone turns so that the model's ring centroid at its child joint points at the scan's."""
    bones = LIMB_BONES[kind]
    children = [skeleton.index(f"{c}_{side}") for _, c in bones if c is not None]
    g = dijkstra(edge_length_graph(rest_vertices, faces), indices=model_tip)
    # The geodesic distance of a joint from the tip: that of the model vertices nearest to it.
    joint_d = np.array([np.median(g[np.argsort(np.linalg.norm(rest_vertices - skeleton.heads[c], axis=1))[:20]])
                        for c in children])
    model_rings = [np.flatnonzero(np.abs(g - d) < RING_HALF_WIDTH_M) for d in joint_d]
    scan_rings = geodesic_rings(scan_vertices, scan_faces, scan_tip, joint_d)
    if any(len(r) < 3 for r in model_rings + scan_rings):
        return pose
    targets = [scan_vertices[r].mean(0) for r in scan_rings] + [scan_vertices[scan_tip]]
    for k, (bone, _) in enumerate(bones):
        j = skeleton.index(f"{bone}_{side}")
        ring = model_rings[k] if k < len(model_rings) else np.array([model_tip])
        posed = linear_blend_skinning(rest_vertices[ring], weights[ring], skinning_transforms(skeleton, pose))
        origin = forward_kinematics(skeleton, pose)[j, :3, 3]
        pose = _rotate_bone_towards(skeleton, pose, j, posed.mean(0) - origin, targets[k] - origin)
    return pose


def initial_pose(skeleton: Skeleton, weights: np.ndarray, rest_vertices: np.ndarray, scan_vertices: np.ndarray,
                 coarse: CoarseSkeleton | None = None, faces: np.ndarray | None = None,
                 scan_faces: np.ndarray | None = None) -> Pose:
    """Initial θ of the model (rest vertices + skeleton + weights) for a canonical scan (§4.3). With the
    model's and the scan's ``faces``, the limbs are aligned bone by bone (:func:`align_limb`)."""
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
    if faces is None or scan_faces is None:
        return pose
    model_coarse = coarse_scan_skeleton(rest_vertices, faces)
    model_tips, scan_tips = limb_tips(rest_vertices, faces, model_coarse), limb_tips(scan_vertices, scan_faces, coarse)
    for kind in LIMB_BONES:
        for side, name in ((1.0, "l"), (-1.0, "r")):
            if model_tips[kind, side] >= 0 and scan_tips[kind, side] >= 0:
                pose = align_limb(skeleton, weights, rest_vertices, faces, scan_vertices, scan_faces, pose, kind,
                                  name, model_tips[kind, side], scan_tips[kind, side])
    return pose
