"""The numpy reference of :func:`bodystudio.mirror.refine.refine_pose` (MIR12b, before issue 12's speed-up).

It forms the whole Jacobian ``J`` (one row per residual, 44 columns) and ``J^T J`` from it, outlines the mask over
the whole image and projects every vertex's Jacobian: the implementation the run used until MIRFAST. Kept here, as a
test helper, so that tests/mirror/test_pose_refine_fast.py can pin the fast implementation to it. MIR12g's E_trunk
is added here from the pose's local rotations (the fast one takes it from the posed frames). MIR12h's root pivot
(the body's centroid) and twist entries are added the same way as in the fast one.
"""

import cv2
import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from bodystudio.body.pose import Pose
from bodystudio.errors import InputError
from bodystudio.mirror.refine import (
    RIM_COS,
    TRUNK_BONES,
    _one_blas_thread,
    _sample,
    silhouette_distance,
)


def refine_pose_reference(plan, skeleton, pose, camera, foreground, kinect_positions=None, tracked=None,
                          depth_points=None, others=None, version="v2", iterations=1, weights=None):
    """:func:`bodystudio.mirror.refine.refine_pose` as MIR12b wrote it (all numpy, ``J`` formed)."""
    from bodystudio.mirror.refine import RefineWeights

    weights = RefineWeights() if weights is None else weights
    with _one_blas_thread():
        return _refine_pose(plan, skeleton, pose, camera, foreground, kinect_positions, tracked, depth_points,
                            others, version, iterations, weights)


def _forward_kinematics(plan, parents, pose: Pose) -> np.ndarray:
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


def _skin(plan, transforms: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Skinned subset vertices and (unnormalised) normals by the blended LBS matrices."""
    M = np.einsum("nk,nkij->nij", plan.weight_val, transforms[plan.weight_idx][:, :, :3, :])
    V = np.einsum("nij,nj->ni", M[:, :, :3], plan.rest_vertices) + M[:, :, 3]
    N = np.einsum("nij,nj->ni", M[:, :, :3], plan.rest_normals)
    return V, N / np.maximum(np.linalg.norm(N, axis=1, keepdims=True), 1e-12)


def apply_update(skeleton, pose: Pose, delta: np.ndarray, bones: np.ndarray, axes: np.ndarray,
                 world: np.ndarray) -> Pose:
    """The pose turned by ``delta`` (root translation, root rotation vector in world axes, two swing angles per
    bone about ``axes``); ``world`` (B, 3, 3) the pose's world rotations (rest-world to posed-world)."""
    Rr = skeleton.rest_rotations[bones]
    parents = np.asarray(skeleton.parents)[bones]
    rotvecs = pose.rotations.copy()
    turns = np.vstack([delta[3:6], delta[6::2, None] * axes[:, 0] + delta[7::2, None] * axes[:, 1]])
    # a bone listed twice (its swing, then its twist: MIR12h) turns by both
    turns = np.array([turns[bones == b].sum(0) for b in bones])
    Wp = np.where((parents < 0)[:, None, None], np.eye(3), world[np.maximum(parents, 0)])
    # W_j' = W_p' L_j' with L_j' = W_p^T exp(w) W_j: first order the same turn of j's subtree in world axes
    L_new = np.transpose(Wp, (0, 2, 1)) @ Rotation.from_rotvec(turns).as_matrix() @ world[bones]
    rotvecs[bones] = Rotation.from_matrix(np.transpose(Rr, (0, 2, 1)) @ L_new @ Rr).as_rotvec()
    return Pose(rotvecs, pose.translation + delta[:3])


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


def mask_outline_reference(mask: np.ndarray, keep_out: np.ndarray | None = None) -> np.ndarray:
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


def _refine_pose(plan, skeleton, pose, camera, foreground, kinect_positions, tracked, depth_points, others,
                 version, iterations, weights):
    fg = np.asarray(foreground, bool)
    if fg.shape != (camera.height, camera.width):
        raise InputError(f"refine_pose: foreground {fg.shape} is not the camera's ({camera.height}, {camera.width})")
    allowed = fg if others is None else fg | others
    dist_out, origin = silhouette_distance(allowed)
    outline = mask_outline_reference(fg, others)
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
        n_twist = getattr(plan, "n_twist", 0)
        if n_twist:  # MIR12h: the last entries turn about the bone itself (one column, the other unused)
            axes[len(axes) - n_twist:, 0] = directions[len(axes) - n_twist:]
            axes[len(axes) - n_twist:, 1] = 0.0
        transforms = M @ plan.rest_inverse
        V, N = _skin(plan, transforms)
        # MIR12h: the root turns about the body's centroid (its head is on the floor), the translation makes up
        root_head, heads[0] = heads[0].copy(), V.mean(axis=0)
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
        if weights.trunk_rad is not None:  # E_trunk (MIR12g): each trunk bone's swing off the rest pose
            swing_entries = bones[1:len(bones) - getattr(plan, "n_twist", 0)]  # not the twist entries (MIR12h)
            for n, name in enumerate(skeleton.bone_names[j] for j in swing_entries):
                if name not in TRUNK_BONES:
                    continue
                j = bones[1 + n]
                y = np.array([0.0, 1.0, 0.0])  # the bone's axis in its own frame
                Ly = Rotation.from_rotvec(pose.rotations[j]).apply(y)
                c = np.cross(y, Ly)
                bend_local = c / max(np.linalg.norm(c), 1e-12) * np.arctan2(np.linalg.norm(c), y @ Ly)
                bend = world[parents[j]] @ skeleton.rest_rotations[j] @ bend_local
                row = np.zeros((2, n_par))
                row[0, 6 + 2 * n] = row[1, 7 + 2 * n] = 1.0 / weights.trunk_rad
                rows.append(row)
                res.append(axes[n] @ bend / weights.trunk_rad)
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
        turn = Rotation.from_rotvec(delta[3:6]).as_matrix()
        pose = Pose(pose.rotations, pose.translation + (turn - np.eye(3)) @ (root_head - heads[0]))
    return pose if np.all(np.isfinite(pose.rotations)) else start

