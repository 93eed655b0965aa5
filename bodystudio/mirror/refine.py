"""Per-frame refinement of the IK pose against the frame's silhouette, depth and Kinect joints (MIR12).

The IK of §5.2 (:mod:`bodystudio.mirror.track`) fits bone directions to the Kinect joints only, and the
joints of the SDK are centimetres off the body's surface. What the warp of §5.4 needs is that the *projected
source body covers the person's silhouette* in the image, since the warp maps the source's projection onto the
target's. This step refines the root (translation and rotation) and the swing of the spine, neck, head,
clavicles, limbs, hands and feet (not their twist, which an oracle measured to cost the warp nothing:
docs/mirror.md "MIR12") by a few Gauss-Newton steps of the energy

``E = w_sil (E_out + E_cover) + w_depth E_depth + w_joint E_joint + E_prior``

* ``E_out``: the distance outside the foreground mask of every projected (subsampled) source vertex: a body
  point projecting outside the person's silhouette is wrong whatever occludes it (the distance-transform
  silhouette term of Rapid Skin / the garment fit, one-sided);
* ``E_cover``: every outline pixel of the mask pulled onto the nearest projected rim vertex (along the rim's
  image normal): the mask's outline must be drawn by the body's outline;
* ``E_depth``: point-to-plane distance of the player's depth points to their nearest front-facing vertex;
* ``E_joint``: the Kinect joints as soft targets (the IK's objective, tracked joints weighted up);
* ``E_prior``: Tikhonov damping of the change from the IK pose.

Every residual is linear in the parameters to first order through the skinning: a vertex ``v`` moves by
``dt + w x (v - h_root)`` for the root and ``s_j(v) (e_j x (v - h_j))`` for bone ``j``'s swing about the axes
``e_j`` perpendicular to the posed bone, where ``s_j(v)`` is the skin weight of ``v`` on ``j``'s subtree.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from bodystudio.body.kinect import KINECT_JOINT_SETS, kinect_joint_names
from bodystudio.body.pose import Pose
from bodystudio.body.skeleton import Skeleton
from bodystudio.errors import InputError

#: Bones whose swing is refined (their twist is the IK's); the Root gets its full rotation and translation.
#: spine_03, head, hands and feet added to the first set: warp_iou +0.003 / +0.005 / +0.001 on MIR-SYNTH
#: 41 / 42 / 43 for 1.8 ms more per frame (one core; docs/mirror.md, MIR12b).
SWING_BONES = ("spine_01", "spine_02", "spine_03", "neck_01", "head", "clavicle_l", "clavicle_r", "upperarm_l",
               "upperarm_r", "lowerarm_l", "lowerarm_r", "hand_l", "hand_r", "thigh_l", "thigh_r", "calf_l", "calf_r",
               "foot_l", "foot_r")
#: The first set (MIR12b's oracle compares it).
TRUNK_AND_LIMB_BONES = ("spine_01", "spine_02", "neck_01", "clavicle_l", "clavicle_r", "upperarm_l", "upperarm_r",
                        "lowerarm_l", "lowerarm_r", "thigh_l", "thigh_r", "calf_l", "calf_r")
#: Gauss-Newton steps per frame: on MIR-SYNTH 41 / 42 one step scores the warp as well as two or three
#: (warp_iou 0.913 / 0.894 against 0.913 / 0.894 / 0.912 / 0.894) at half the cost (docs/mirror.md).
ITERATIONS = 1
#: Every ``VERTEX_STRIDE``-th vertex enters the silhouette and depth terms.
VERTEX_STRIDE = 2
#: Rim vertices: ``|cos|`` of the (skinned) normal and the viewing ray below this.
RIM_COS = 0.3


@dataclass(frozen=True)
class RefineWeights:
    """Residual scales of the energy (a residual divided by its scale counts 1): pixels, metres, radians."""

    sil_px: float = 2.0  # silhouette residuals (E_out, E_cover)
    depth_m: float = 0.01  # point-to-plane
    joint_m: float = 0.04  # Kinect joints (tracked; inferred ones count 1/4)
    # damping of the change from the IK pose; a tight prior (0.15 rad, 5 cm) kept half the gain on MIR-SYNTH 41
    # (warp_iou 0.894 -> 0.899, 0.5 rad / 20 cm 0.906, these 0.913): the silhouette and depth know better
    prior_rad: float = 3.0  # change of a rotation from the IK
    prior_m: float = 1.0  # change of the root translation from the IK
    sil_samples: int = 600  # mask outline pixels of E_cover
    depth_samples: int = 400  # depth points of E_depth
    sil_weight: float = 1.0  # relative weights of the terms (their sums are normalised per sample)
    depth_weight: float = 1.0
    joint_weight: float = 1.0


@dataclass(frozen=True, eq=False)
class _RefinePlan:
    """Per-body data: the vertex subset, its rest positions/normals, its skin weights and subtree weights."""

    subset: np.ndarray
    rest_vertices: np.ndarray
    rest_normals: np.ndarray
    weight_idx: np.ndarray  # (n, k) bones of the k largest skin weights
    weight_val: np.ndarray  # (n, k)
    subtree_weight: np.ndarray  # (n, 1 + S): weight on the root's subtree (1) and on each swing bone's subtree
    bones: np.ndarray  # (1 + S,) the root, then the swing bones
    joint_moves: np.ndarray  # (J, 1 + S) how much Kinect joint k moves with bone j's rotation (0..1)
    rest_relative: np.ndarray  # (B, 4, 4) A_parent^-1 A_j (the root: A_root), for the forward kinematics
    rest_inverse: np.ndarray  # (B, 4, 4) A_j^-1


def _descendants(parents, j) -> np.ndarray:
    inside = np.zeros(len(parents), bool)
    inside[j] = True
    for b in range(len(parents)):  # parents come before children
        if parents[b] >= 0 and inside[parents[b]]:
            inside[b] = True
    return inside


def refine_plan(vertices_rest: np.ndarray, faces: np.ndarray, weights: np.ndarray, skeleton: Skeleton,
                version: str = "v2", stride: int = VERTEX_STRIDE,
                swing_bones: tuple[str, ...] = SWING_BONES) -> _RefinePlan:
    """The per-body data of :func:`refine_pose` (computed once per source body); ``swing_bones`` the bones
    whose swing is refined."""
    from bodystudio.geometry.mesh import vertex_normals

    names = skeleton.bone_names
    missing = [b for b in ("Root", *swing_bones) if b not in names]
    if missing:
        raise InputError(f"pose refinement needs the game_engine rig; bone {missing[0]!r} is missing")
    parents = np.asarray(skeleton.parents)
    root = int(np.flatnonzero(parents < 0)[0])
    bones = np.array([root] + [names.index(b) for b in swing_bones])
    subset = np.arange(0, len(vertices_rest), max(1, int(stride)))
    W = np.asarray(weights, float)[subset]
    inside = np.stack([_descendants(parents, j) for j in bones], axis=1).astype(float)  # (B, 1 + S)
    subtree = W @ inside
    k = min(6, W.shape[1])
    idx = np.argsort(-W, axis=1)[:, :k]
    val = np.take_along_axis(W, idx, 1)
    val = val / np.maximum(val.sum(1, keepdims=True), 1e-12)
    N = vertex_normals(np.asarray(vertices_rest, float), np.asarray(faces))[subset]
    moves = np.zeros((len(kinect_joint_names(version)), len(bones)))
    for kj, name in enumerate(kinect_joint_names(version)):
        for b_name, end, w in KINECT_JOINT_SETS[version][name]:
            b = names.index(b_name)
            for c, j in enumerate(bones):
                # a bone's tail turns with the bone and its ancestors, its head only with the ancestors
                if inside[b, c] and (end == "tail" or b != j):
                    moves[kj, c] += w
    A = skeleton.rest_frames
    rel = np.array([A[j] if p < 0 else np.linalg.solve(A[p], A[j]) for j, p in enumerate(parents)])
    return _RefinePlan(subset, np.asarray(vertices_rest, float)[subset], N, idx, val, subtree, bones, moves, rel,
                       np.linalg.inv(A))


def _forward_kinematics(plan: _RefinePlan, parents, pose: Pose) -> np.ndarray:
    """Posed bone frames (B, 4, 4): :func:`bodystudio.body.skinning.forward_kinematics` with the rest-frame
    products cached in the plan."""
    local = np.tile(np.eye(4), (len(parents), 1, 1))
    local[:, :3, :3] = Rotation.from_rotvec(pose.rotations).as_matrix()
    M = plan.rest_relative @ local
    for j, p in enumerate(parents):  # parents come before children
        if p < 0:
            M[j, :3, 3] += pose.translation
        else:
            M[j] = M[p] @ M[j]
    return M


def _skin(plan: _RefinePlan, transforms: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Skinned subset vertices and (unnormalised) normals by the blended LBS matrices."""
    M = np.einsum("nk,nkij->nij", plan.weight_val, transforms[plan.weight_idx][:, :, :3, :])
    V = np.einsum("nij,nj->ni", M[:, :, :3], plan.rest_vertices) + M[:, :, 3]
    N = np.einsum("nij,nj->ni", M[:, :, :3], plan.rest_normals)
    return V, N / np.maximum(np.linalg.norm(N, axis=1, keepdims=True), 1e-12)


def _point_jacobian(P: np.ndarray, s: np.ndarray, heads: np.ndarray, axes: np.ndarray) -> np.ndarray:
    """``(n, 3, 3 + 3 + 2 S)`` derivative of points ``P`` by the parameters (root translation, root rotation in
    world axes, two swing axes per bone); ``s`` (n, 1 + S) their weights on each rotated subtree."""
    n, S = len(P), len(heads) - 1
    J = np.zeros((n, 3, 6 + 2 * S))
    J[:, :, :3] = np.eye(3) * s[:, :1, None]
    d = (P - heads[0]) * s[:, :1]
    # w x d = -[d]_x w
    J[:, 0, 4], J[:, 0, 5] = d[:, 2], -d[:, 1]
    J[:, 1, 3], J[:, 1, 5] = -d[:, 2], d[:, 0]
    J[:, 2, 3], J[:, 2, 4] = d[:, 1], -d[:, 0]
    r = (P[:, None, :] - heads[None, 1:]) * s[:, 1:, None]  # (n, S, 3)
    J[:, :, 6::2] = np.cross(axes[None, :, 0], r).transpose(0, 2, 1)
    J[:, :, 7::2] = np.cross(axes[None, :, 1], r).transpose(0, 2, 1)
    return J


def _projection_jacobian(camera, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixels (n, 2) of world points and the (n, 2, 3) derivative of the (undistorted) projection."""
    uv, _ = camera.project_with_depth(P)
    Pc = camera.world_to_camera(P)
    z = np.maximum(Pc[:, 2], 1e-6)
    fx, fy = camera.fx, camera.fy
    D = np.zeros((len(P), 2, 3))
    D[:, 0, 0], D[:, 0, 2] = fx / z, -fx * Pc[:, 0] / z**2
    D[:, 1, 1], D[:, 1, 2] = fy / z, -fy * Pc[:, 1] / z**2
    return uv, D @ camera.R


def _sample(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear samples of a float32 image at pixels (n, 2) (clamped at the border)."""
    m = cv2.remap(image, uv[:, :1].astype(np.float32), uv[:, 1:].astype(np.float32), cv2.INTER_LINEAR,
                  borderMode=cv2.BORDER_REPLICATE)
    return m.ravel().astype(np.float64)


def silhouette_distance(mask: np.ndarray, margin_px: int = 40) -> tuple[np.ndarray, np.ndarray]:
    """Distance (pixels, float32) outside ``mask`` to it, 0 inside: the data of ``E_out``, over the mask's
    bounding box grown by ``margin_px`` only (a 640x480 transform costs ~2 ms); returns it and the box's
    ``(x0, y0)`` origin."""
    m = np.asarray(mask, bool)
    ys, xs = np.nonzero(m.any(1))[0], np.nonzero(m.any(0))[0]
    if not len(ys):
        return np.full((1, 1), np.float32(margin_px)), np.zeros(2)
    y0, x0 = max(ys[0] - margin_px, 0), max(xs[0] - margin_px, 0)
    y1, x1 = min(ys[-1] + margin_px + 1, m.shape[0]), min(xs[-1] + margin_px + 1, m.shape[1])
    crop = (~m[y0:y1, x0:x1]).astype(np.uint8)
    return cv2.distanceTransform(crop, cv2.DIST_L2, cv2.DIST_MASK_5), np.array([x0, y0], float)


def mask_outline(mask: np.ndarray, keep_out: np.ndarray | None = None) -> np.ndarray:
    """(m, 2) pixel centres ``(x, y)`` of the outline of ``mask`` (inside pixels with an outside 4-neighbour),
    without those next to ``keep_out`` (another player occluding the person) or the image border."""
    m = np.asarray(mask, np.uint8)
    outline = (m > 0) & (cv2.erode(m, np.ones((3, 3), np.uint8), borderType=cv2.BORDER_CONSTANT, borderValue=0) == 0)
    outline[[0, -1], :] = False
    outline[:, [0, -1]] = False
    if keep_out is not None and keep_out.any():
        outline &= cv2.dilate(keep_out.astype(np.uint8), np.ones((5, 5), np.uint8)) == 0
    y, x = np.nonzero(outline)
    return np.c_[x, y].astype(np.float64)


def apply_update(skeleton: Skeleton, pose: Pose, delta: np.ndarray, bones: np.ndarray, axes: np.ndarray,
                 world: np.ndarray) -> Pose:
    """The pose turned by ``delta`` (root translation, root rotation vector in world axes, two swing angles per
    bone about ``axes``); ``world`` (B, 3, 3) the pose's world rotations (rest-world to posed-world)."""
    Rr = skeleton.rest_rotations[bones]
    parents = np.asarray(skeleton.parents)[bones]
    rotvecs = pose.rotations.copy()
    turns = np.vstack([delta[3:6], delta[6::2, None] * axes[:, 0] + delta[7::2, None] * axes[:, 1]])
    Wp = np.where((parents < 0)[:, None, None], np.eye(3), world[np.maximum(parents, 0)])
    # W_j' = W_p' L_j' with L_j' = W_p^T exp(w) W_j: first order the same turn of j's subtree in world axes
    L_new = np.transpose(Wp, (0, 2, 1)) @ Rotation.from_rotvec(turns).as_matrix() @ world[bones]
    rotvecs[bones] = Rotation.from_matrix(np.transpose(Rr, (0, 2, 1)) @ L_new @ Rr).as_rotvec()
    return Pose(rotvecs, pose.translation + delta[:3])


_BLAS = None


def _one_blas_thread():
    """A context holding BLAS to one thread: the normal equations (a few thousand rows by ~44 columns) cross
    OpenBLAS's threading threshold, and its threads spinning on a loaded machine made the step cost 150-300 ms
    wall instead of ~10 (mirror run on MIR-SYNTH, load 30); the context itself costs ~0.01 ms."""
    global _BLAS
    if _BLAS is None:
        from threadpoolctl import ThreadpoolController

        _BLAS = ThreadpoolController()
    return _BLAS.limit(limits=1, user_api="blas")


def refine_pose(plan: _RefinePlan, skeleton: Skeleton, pose: Pose, camera, foreground: np.ndarray,
                kinect_positions=None, tracked=None, depth_points=None, others: np.ndarray | None = None,
                version: str = "v2", iterations: int = ITERATIONS,
                weights: RefineWeights = RefineWeights()) -> Pose:
    """The IK ``pose`` refined by Gauss-Newton so that the projected body fits ``foreground`` (the person's
    refined mask in the colour image of ``camera``), the player's ``depth_points`` (N, 3) and the Kinect joints.

    ``others``: pixels of other players (a body point projecting there may be occluded, not outside).
    Root translation/rotation and the swing of the plan's bones (:data:`SWING_BONES` by default) change;
    every other rotation, and every twist, is the IK's. ``iterations`` Gauss-Newton steps from ``pose``.
    """
    with _one_blas_thread():
        return _refine_pose(plan, skeleton, pose, camera, foreground, kinect_positions, tracked, depth_points,
                            others, version, iterations, weights)


def _refine_pose(plan, skeleton, pose, camera, foreground, kinect_positions, tracked, depth_points, others,
                 version, iterations, weights) -> Pose:
    fg = np.asarray(foreground, bool)
    if fg.shape != (camera.height, camera.width):
        raise InputError(f"refine_pose: foreground {fg.shape} is not the camera's ({camera.height}, {camera.width})")
    allowed = fg if others is None else fg | others
    dist_out, origin = silhouette_distance(allowed)
    outline = mask_outline(fg, others)
    rng = np.random.default_rng(0)
    if len(outline) > weights.sil_samples:
        outline = outline[rng.choice(len(outline), weights.sil_samples, replace=False)]
    K = T = None
    if kinect_positions is not None:
        from bodystudio.mirror.track import check_kinect_joints

        K, T = check_kinect_joints(kinect_positions, tracked, version)
        jw = np.where(np.all(np.isfinite(K), axis=1), np.where(T, 1.0, 0.25), 0.0)
        K = np.nan_to_num(K)
    pts = None
    if depth_points is not None and len(depth_points):
        pts = np.asarray(depth_points, float)
        if len(pts) > weights.depth_samples:
            pts = pts[rng.choice(len(pts), weights.depth_samples, replace=False)]
    bones = plan.bones
    S = len(bones) - 1
    n_par = 6 + 2 * S
    prior_scale = np.r_[np.full(3, weights.prior_m), np.full(n_par - 3, weights.prior_rad)]
    start = pose
    total = np.zeros(n_par)
    eye = camera.center
    parents = skeleton.parents
    for _ in range(max(0, int(iterations))):
        M = _forward_kinematics(plan, parents, pose)
        world = M[:, :3, :3] @ np.transpose(skeleton.rest_rotations, (0, 2, 1))
        heads = M[bones, :3, 3]
        directions = M[bones[1:], :3, 1]
        helper = np.where(np.abs(directions[:, :1]) < 0.9, [1.0, 0.0, 0.0], [0.0, 0.0, 1.0])
        a = np.cross(directions, helper)
        a /= np.linalg.norm(a, axis=1, keepdims=True)
        axes = np.stack([a, np.cross(directions, a)], axis=1)  # (S, 2, 3): two axes perpendicular to each bone
        transforms = M @ plan.rest_inverse
        V, N = _skin(plan, transforms)
        rows, res = [], []
        uv, Dp = _projection_jacobian(camera, V)
        ok = np.all(np.isfinite(uv), axis=1) & (uv[:, 0] >= 0) & (uv[:, 0] <= camera.width - 1) \
            & (uv[:, 1] >= 0) & (uv[:, 1] <= camera.height - 1)
        # E_out: projected body points outside the silhouette, pulled down the distance transform
        # (points beyond the box are more than its margin out; they have no gradient there and are left out)
        local = uv - origin
        in_box = ok & np.all(local >= 1, axis=1) & (local[:, 0] < dist_out.shape[1] - 2) \
            & (local[:, 1] < dist_out.shape[0] - 2)
        d_out = np.zeros(len(V))
        d_out[in_box] = _sample(dist_out, local[in_box])
        out = np.flatnonzero(in_box & (d_out > 0.5))
        if len(out):
            lo = local[out]
            g = np.c_[_sample(dist_out, lo + [1, 0]) - _sample(dist_out, lo - [1, 0]),
                      _sample(dist_out, lo + [0, 1]) - _sample(dist_out, lo - [0, 1])] / 2.0
            Jv = _point_jacobian(V[out], plan.subtree_weight[out], heads, axes)
            scale = weights.sil_weight ** 0.5 / (weights.sil_px * max(len(out), len(outline), 1) ** 0.5)
            rows.append(scale * np.einsum("ni,nij,njk->nk", g, Dp[out], Jv))
            res.append(scale * np.minimum(d_out[out], 30.0))
        # E_cover: the mask's outline pixels onto the nearest projected rim vertex, along its image normal
        ray = V - eye
        cos = np.einsum("ij,ij->i", N, ray) / np.linalg.norm(ray, axis=1)
        rim = np.flatnonzero(ok & (np.abs(cos) < RIM_COS))
        if len(rim) >= 3 and len(outline):
            dist, nearest = cKDTree(uv[rim]).query(outline, distance_upper_bound=25.0)
            keep = np.isfinite(dist)
            r_ids = rim[nearest[keep]]
            n2 = np.einsum("nij,nj->ni", Dp[r_ids], N[r_ids])
            n2 /= np.maximum(np.linalg.norm(n2, axis=1, keepdims=True), 1e-9)
            r = np.einsum("ij,ij->i", n2, uv[r_ids] - outline[keep])
            Jv = _point_jacobian(V[r_ids], plan.subtree_weight[r_ids], heads, axes)
            scale = weights.sil_weight ** 0.5 / (weights.sil_px * max(len(outline), 1) ** 0.5)
            rows.append(scale * np.einsum("ni,nij,njk->nk", n2, Dp[r_ids], Jv))
            res.append(scale * r)
        # E_depth: point-to-plane to the nearest front-facing vertex (within 5 cm)
        if pts is not None:
            front = np.flatnonzero(cos < 0)
            dist, nearest = cKDTree(V[front]).query(pts, distance_upper_bound=0.05)
            keep = np.isfinite(dist)
            if keep.any():
                v_ids = front[nearest[keep]]
                n3 = N[v_ids]
                r = np.einsum("ij,ij->i", n3, V[v_ids] - pts[keep])
                Jv = _point_jacobian(V[v_ids], plan.subtree_weight[v_ids], heads, axes)
                scale = weights.depth_weight ** 0.5 / (weights.depth_m * len(pts) ** 0.5)
                rows.append(scale * np.einsum("ni,nij->nj", n3, Jv))
                res.append(scale * r)
        # E_joint: the Kinect joints as soft targets
        if K is not None and jw.any():
            from bodystudio.body.kinect import kinect_joints

            heads_all = M[:, :3, 3]
            tails_all = heads_all + M[:, :3, 1] * skeleton.lengths[:, None]
            P = kinect_joints(skeleton, heads_all, tails_all, version)
            use = np.flatnonzero(jw > 0)
            Jv = _point_jacobian(P[use], plan.joint_moves[use], heads, axes)
            scale = (weights.joint_weight * jw[use] / jw[use].sum()) ** 0.5 / weights.joint_m
            rows.append((scale[:, None, None] * Jv).reshape(-1, n_par))
            res.append((scale[:, None] * (P[use] - K[use])).ravel())
        if not rows:
            break
        A = np.vstack(rows)
        b = np.concatenate(res)
        # E_prior on the total change from the IK pose (``total``): (total + delta) / scale
        H = A.T @ A + np.diag(1.0 / prior_scale**2)
        grad = A.T @ b + total / prior_scale**2
        try:
            delta = -np.linalg.solve(H, grad)
        except np.linalg.LinAlgError:
            return start
        total = total + delta
        pose = apply_update(skeleton, pose, delta, bones, axes, world)
    return pose if np.all(np.isfinite(pose.rotations)) else start

