"""Model-based filtering and surface refinement, Sec. 6.2 and 7 of Arm-Muscle Capture (Robertini et al. 2013).

Model-based filtering projects the ARAP mesh of non-rigid ICP onto the statistical model: the joint
angles come from a per-part orthogonal Procrustes fit (Eq. 11), the shape parameters are fitted once
per sequence, and the model mesh of Eq. 12 (with the 90 % displacement-norm limit) replaces the ARAP
mesh. Refinement then pulls the model mesh towards the depth points with one more ARAP, driven by
correspondences averaged over frames i-1, i, i+1 (Eq. 13-14) and weighted by their agreement with the
vertex normals and the closeness of the vertex to a joint (Sec. 7.2).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from bodystudio.errors import InputError
from bodystudio.muscle.arm import ArmPose, part_transforms, pose_arm
from bodystudio.muscle.nicp import similarity_transform
from bodystudio.muscle.normal_equations import normal_matrix, normal_rhs, ordered_product, spd_solve

# --- Sec. 6.2 mesh projection -------------------------------------------------------------------


def procrustes_part_transforms(base: np.ndarray, deformed: np.ndarray, part_weights: np.ndarray,
                               vertex_weights: np.ndarray | None = None) -> np.ndarray:
    """Rigid transform (4, 4) per part mapping base to deformed vertices: orthogonal Procrustes, Eq. 11.

    ``min_{R,t} sum_i w_i ||(R p_i + t) - p'_i||^2`` with ``w_i`` the part's blending weight (times the
    optional per-vertex reliability ``vertex_weights``), solved in closed form by the weighted SVD
    (Kabsch). Parts with no weight get the identity.
    """
    P = np.asarray(base, np.float64)
    Q = np.asarray(deformed, np.float64)
    extra = np.ones(len(P)) if vertex_weights is None else np.asarray(vertex_weights, np.float64)
    T = np.tile(np.eye(4), (part_weights.shape[1], 1, 1))
    for k in range(part_weights.shape[1]):
        w = part_weights[:, k] * extra
        if w.sum() < 1e-9:
            continue
        _, T[k, :3, :3], T[k, :3, 3] = similarity_transform(P, Q, w, with_scale=False)
    return T


def arm_pose_from_part_transforms(transforms: np.ndarray) -> ArmPose:
    """Joint angles of Sec. 6.2 from per-part transforms: ``a_j = log(R_parent^T R_child)`` down the chain.

    ``arm.part_transforms`` composes ``T_child = T_parent Trans(c) R(a) Trans(-c)`` about the rest
    joint ``c``, so each rotation vector follows from the parts' rotations alone; the root is the
    torso's transform.
    """
    R = transforms[:, :3, :3]
    angles = np.stack([Rotation.from_matrix(R[k].T @ R[k + 1]).as_rotvec() for k in range(3)])
    return ArmPose(transforms[0], angles)


def _pose_vector(pose: ArmPose) -> np.ndarray:
    return np.concatenate([Rotation.from_matrix(pose.root[:3, :3]).as_rotvec(), pose.root[:3, 3],
                           pose.angles.ravel()])


def _pose_from_vector(x: np.ndarray) -> ArmPose:
    root = np.eye(4)
    root[:3, :3] = Rotation.from_rotvec(x[:3]).as_matrix()
    root[:3, 3] = x[3:6]
    return ArmPose(root, x[6:15].reshape(3, 3))


@dataclass(frozen=True, eq=False)
class DepthOutline:
    """One frame's raw depth map for :func:`outline_pairs`: the depth camera (world), the capture's similarity
    ``(s, R, t)`` (template space -> world) and the outline pairs' weight (per pair, 1 = a depth pair's); the rim
    vertices searched are those of ``candidates`` (the arm region)."""

    depth_m: np.ndarray
    camera: object
    similarity: tuple
    weight: float
    candidates: np.ndarray
    offset_m: float = 0.0
    near_m: float = 0.5
    far_m: float = 1.3

    def pairs(self, vertices: np.ndarray, normals: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:func:`outline_pairs` of template-space ``vertices`` / ``normals``, in template space; each target moved
        ``offset_m`` outwards (the contour's own bias: on the truth's rim it lies 0.4 mm inside; docs/muscle.md,
        sixteenth pass)."""
        from bodystudio.muscle.nicp import apply_similarity

        s, R, t = self.similarity
        Vw = apply_similarity(self.similarity, vertices)
        k, q, n = outline_pairs(Vw, np.asarray(normals) @ R.T, self.depth_m, self.camera, self.candidates,
                                near_m=self.near_m, far_m=self.far_m)
        q = q + self.offset_m * n
        return k, ((q - t) @ R) / s, n @ R


@dataclass(frozen=True, eq=False)
class DepthFrame:
    """One frame's depth data for the model fit: points, normals, their k-d tree, sensor, filters."""

    points: np.ndarray
    normals: np.ndarray
    tree: object
    sensor_center: np.ndarray
    arm_mask: np.ndarray
    adjacency: object
    filters: object
    faces: np.ndarray
    min_facing_cos: float = 0.0  # > 0: the grazing pairs are dropped too (:func:`grazing_pairs`)
    outline: DepthOutline | None = None  # the rest-shape fit's outline pairs (:func:`weighted_pairs`)

    def plane_pairs(self, vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Filtered closest-point pairs of ``vertices`` (Sec. 5.2): vertex ids, depth points, point normals.

        With ``min_facing_cos`` > 0 the grazing pairs (:func:`grazing_pairs`) are dropped as well: vertices whose
        normal makes less than this cosine with the direction to the sensor."""
        from bodystudio.geometry.mesh import vertex_normals
        from bodystudio.muscle.nicp import closest_point_correspondences, filter_correspondences

        normals = vertex_normals(vertices, self.faces)
        pairs = closest_point_correspondences(vertices, self.points, self.normals, self.tree)
        pairs = filter_correspondences(vertices, normals, pairs, self.sensor_center,
                                       self.arm_mask, self.adjacency, self.filters)
        kept = pairs.kept
        if self.min_facing_cos > 0:
            kept = kept & ~grazing_pairs(vertices, normals, self.sensor_center, self.min_facing_cos)
        k = np.flatnonzero(kept)
        return k, pairs.targets[k], pairs.target_normals[k]


def weighted_pairs(frame: DepthFrame, vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The frame's depth pairs (:meth:`DepthFrame.plane_pairs`) followed by its outline pairs (``frame.outline``,
    :func:`outline_pairs`) when it has them: vertex ids, targets, directions and each pair's weight (1 for a depth
    pair, ``frame.outline.weight`` for an outline pair). Any frame with ``plane_pairs`` will do (no ``outline``:
    none)."""
    idx, q, nrm = frame.plane_pairs(vertices)
    outline = getattr(frame, "outline", None)
    if outline is None or outline.weight <= 0:
        return idx, q, nrm, np.ones(len(idx))
    from bodystudio.geometry.mesh import vertex_normals

    ko, qo, no = outline.pairs(vertices, vertex_normals(vertices, frame.faces))
    return (np.r_[idx, ko], np.r_[q, qo], np.r_[nrm, no], np.r_[np.ones(len(idx)), np.full(len(ko), outline.weight)])


def grazing_pairs(vertices: np.ndarray, normals: np.ndarray, sensor_center: np.ndarray,
                  min_facing_cos: float) -> np.ndarray:
    """Vertices (n,) bool whose normal makes less than ``min_facing_cos`` with the direction to the sensor.

    Beyond Sec. 5.2 (whose Eq. 1 keeps every vertex facing the sensor at all): near the silhouette of a limb the
    cleaned depth (Sec. 4's median and Gaussian filters, the thinned border) stops short of the surface, and a
    grazing vertex's closest depth point is the last kept one, on whose tangent plane the convex limb lies behind:
    on 501 the truth's own grazing vertices (cos < 0.3) sit 4.6 mm (mean) behind their pairs' planes, the ones
    facing the sensor 0.2-0.5 mm in front (docs/muscle.md, fourteenth pass, rest arm)."""
    to_sensor = np.asarray(sensor_center, np.float64) - np.asarray(vertices, np.float64)
    cos = np.einsum("kd,kd->k", normals, to_sensor) / np.maximum(np.linalg.norm(to_sensor, axis=1), 1e-12)
    return cos < min_facing_cos


def outline_pairs(vertices: np.ndarray, normals: np.ndarray, depth_m: np.ndarray, camera, candidates: np.ndarray,
                  max_facing_cos: float = 0.3, search_px: float = 6.0, step_px: float = 0.25, jump_m: float = 0.03,
                  near_m: float = 0.5, far_m: float = 1.3) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Outline pairs of the limb's rim against the depth map's occluding contour, Eq. 6-7 of Rapid Skin (rim vertices
    searched along their normal's image direction, pulled to the contour's viewing ray) as point-to-plane pairs
    (world frame): vertex ids, targets, unit directions.

    Sec. 5.2 drops the rim (its depth is mixed with the background; the fourteenth pass's ``grazing_pairs``), so the
    fit never sees the limb's width in the image plane, which bounds its girth on the side the sensor does not see.
    Each candidate vertex seen edge-on (its normal's cosine with the direction to the sensor under
    ``max_facing_cos``) is searched along its normal's image direction, ``search_px`` either way in ``step_px``
    steps over the raw depth (segmented to [``near_m``, ``far_m``], no filter: a filter moves the border) for the
    contour: the step where the pixels stop being as near as the vertex (depth under the vertex's + ``jump_m``: the
    limb itself or something in front of it). The pair's target is the vertex moved by that signed distance (pixels
    times depth over the focal length) along its normal made perpendicular to the view ray, its direction that
    normal: a vertex whose contour lies outside it is pulled out. Dropped: vertices behind the sensor, a contour
    not found within the search, and one whose inner side is not the vertex's own surface (depth more than
    ``jump_m`` from the vertex's: something in front)."""
    V = np.asarray(vertices, np.float64)
    N = np.asarray(normals, np.float64)
    depth = np.asarray(depth_m, np.float64)
    H, W = depth.shape
    ray = V - camera.center
    ray /= np.maximum(np.linalg.norm(ray, axis=1, keepdims=True), 1e-12)
    cos = -np.einsum("kd,kd->k", N, ray)
    z = camera.world_to_camera(V)[:, 2]
    k = np.flatnonzero(np.asarray(candidates, bool) & (np.abs(cos) < max_facing_cos) & (z > 0.1))
    empty = (np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3)))
    if len(k) == 0:
        return empty
    n_perp = N[k] - np.einsum("kd,kd->k", N[k], ray[k])[:, None] * ray[k]
    n_perp /= np.maximum(np.linalg.norm(n_perp, axis=1, keepdims=True), 1e-12)
    uv = camera.project(V[k])
    m2 = camera.project(V[k] + 1e-3 * n_perp) - uv
    m2 /= np.maximum(np.linalg.norm(m2, axis=1, keepdims=True), 1e-12)
    t = np.arange(-search_px, search_px + 0.5 * step_px, step_px)
    P = uv[:, None, :] + t[None, :, None] * m2[:, None, :]
    cols, rows = np.rint(P[..., 0]).astype(np.int64), np.rint(P[..., 1]).astype(np.int64)
    inside = (cols >= 0) & (cols < W) & (rows >= 0) & (rows < H)
    d = np.where(inside, depth[np.clip(rows, 0, H - 1), np.clip(cols, 0, W - 1)], 0.0)
    valid = np.isfinite(d) & (d >= near_m) & (d <= far_m)
    near = valid & (d < z[k, None] + jump_m)
    c = len(t) // 2
    # the contour: the first step outward from the centre that is not near (centre near) or the last near step
    # inward (centre not near); its position halfway between the two steps
    out_first = np.where(~near[:, c:], np.arange(c, len(t))[None, :], len(t)).min(axis=1)
    in_last = np.where(near[:, :c + 1], np.arange(c + 1)[None, :], -1).max(axis=1)
    at_centre = near[:, c]
    edge_i = np.where(at_centre, out_first, in_last + 1)
    found = (edge_i > 0) & (edge_i < len(t))
    inner = np.clip(edge_i - 1, 0, len(t) - 1)
    d_in = d[np.arange(len(k)), inner]
    found &= np.abs(d_in - z[k]) < jump_m
    if not found.any():
        return empty
    edge_px = t[np.clip(edge_i, 0, len(t) - 1)] - 0.5 * step_px
    e_m = edge_px * z[k] / camera.fx
    k, e_m, n_perp = k[found], e_m[found], n_perp[found]
    return k, V[k] + e_m[:, None] * n_perp, n_perp


def _model_residuals(mesh: np.ndarray, pairs, deformed: np.ndarray | None, nicp_weight: float) -> np.ndarray:
    """Point-to-plane distances of the paired model vertices to the depth points, plus a weak pull to the NICP mesh."""
    k, q, n = pairs
    r = [np.einsum("kd,kd->k", mesh[k] - q, n)]
    if deformed is not None and nicp_weight > 0:
        r.append(np.sqrt(nicp_weight) * (mesh - deformed).ravel())
    return np.concatenate(r)


def elbow_axes(joints: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The elbow's hinge axis (normal of the rest arm's plane) and the rest forearm axis, unit vectors."""
    s, e, w = np.asarray(joints, np.float64)
    u = (e - s) / np.linalg.norm(e - s)
    f = (w - e) / np.linalg.norm(w - e)
    h = np.cross(u, f)
    return h / max(np.linalg.norm(h), 1e-12), f


def elbow_rotvec(joints: np.ndarray, flexion_rad: float, twist_rad: float) -> np.ndarray:
    """Elbow rotation (rotation vector) as a hinge flexion followed by the forearm's twist: 2 DoF."""
    h, f = elbow_axes(joints)
    return (Rotation.from_rotvec(h * flexion_rad) * Rotation.from_rotvec(f * twist_rad)).as_rotvec()


def refine_arm_pose(pose: ArmPose, mesh_of_pose, frame: DepthFrame, deformed: np.ndarray | None,
                    joints: np.ndarray, nicp_weight: float = 0.05, rounds: int = 2, max_nfev: int = 20,
                    fit_twist: bool = False, tracker: np.ndarray | None = None, tracker_weight: float = 0.0,
                    model_joints: np.ndarray | None = None, previous: ArmPose | None = None,
                    smooth_weight: float = 0.0, huber_m: float = 0.0) -> ArmPose:
    """Twist refinement of Sec. 6.2: Gauss-Newton on the shoulder (3) and elbow hinge (1) angles.

    The paper refines the Procrustes transforms "iteratively by using the theory of rigid-body motion
    and the twist representation" against the ARAP mesh. Our NICP mesh is only reliable along the
    normals (its vertices slide on the surface), so the angles are fitted to the depth points
    themselves, point-to-plane over the filtered pairs (re-paired each round), with a weak pull
    (``nicp_weight`` per coordinate) to the ARAP mesh that holds the unseen side.
    Constraints, all measured to matter on a 24-frame sequence: the root (torso) stays where the
    sequence fit put it and the wrist as given (the subject sits still and keeps a fist, Sec. 8.1;
    the hand has no depth pairs: a free wrist drifted 48 deg); the elbow is a hinge about the rest
    arm's plane normal (a 3-DoF elbow let the upper arm roll about its own, nearly cylindrical, axis
    by 20 deg); the forearm's twist (pronation) is as unobservable on a near-cylinder and drifted
    40 deg when free, so it stays 0 unless ``fit_twist`` (the paper cannot capture pronation either).
    ``tracker`` (3, 3): the body tracker's shoulder, elbow, wrist in this frame, compared with the
    posed ``model_joints`` at ``tracker_weight`` per coordinate (1 per depth pair): they pin the
    forearm's direction, which the short, partly hand-blended forearm surface alone does not.
    ``previous`` (the last frame's pose) adds ``smooth_weight`` per joint-angle coordinate times a
    0.3 m lever arm: quasi-static motion (Sec. 3), against the tracker's frame-to-frame noise.
    """
    wrist = pose.angles[2].copy()
    h, f = elbow_axes(joints)
    twist0 = float(pose.angles[1] @ f) if fit_twist else 0.0

    def pose_of(x):
        twist = x[4] if fit_twist else twist0
        return ArmPose(pose.root, np.vstack([x[:3], elbow_rotvec(joints, x[3], twist), wrist]))

    x = np.r_[pose.angles[0], pose.angles[1] @ h] if not fit_twist else \
        np.r_[pose.angles[0], pose.angles[1] @ h, twist0]
    for _ in range(rounds):
        pairs = frame.plane_pairs(mesh_of_pose(pose_of(x)))

        def fun(x, pairs=pairs):
            p = pose_of(x)
            r = _model_residuals(mesh_of_pose(p), pairs, deformed, nicp_weight)
            if tracker is not None and tracker_weight > 0:
                r = np.r_[r, np.sqrt(tracker_weight) * (posed_joints(model_joints, p) - tracker).ravel()]
            if previous is not None and smooth_weight > 0:
                r = np.r_[r, np.sqrt(smooth_weight) * 0.3 * (p.angles[:2] - previous.angles[:2]).ravel()]
            return r

        robust = dict(method="trf", loss="huber", f_scale=huber_m) if huber_m > 0 else dict(method="lm")
        x = least_squares(fun, x, max_nfev=max_nfev, **robust).x
    return pose_of(x)


def posed_joints(joints: np.ndarray, pose: ArmPose) -> np.ndarray:
    """Shoulder, elbow and wrist centres (3, 3) carried by the parts above them in ``pose``."""
    T = part_transforms(np.asarray(joints, np.float64), pose)
    return np.stack([T[k, :3, :3] @ joints[k] + T[k, :3, 3] for k in range(3)])


def initial_arm_pose_from_joints(joints_rest: np.ndarray, tracked: np.ndarray) -> ArmPose:
    """Arm pose that carries the rest shoulder/elbow/wrist onto tracked ones (the Kinect body tracker).

    The root translates the rest shoulder onto the tracked one (no torso rotation: the subject faces
    the sensor, Sec. 8.1); the shoulder and elbow get the smallest rotations that align the rest bone
    directions with the tracked ones (their twist is left to the registration). Used to start the
    first frame when the subject is not in the base pose that Sec. 5.1 asks for.
    """
    J0 = np.asarray(joints_rest, np.float64)
    J = np.asarray(tracked, np.float64)
    root = np.eye(4)
    root[:3, 3] = J[0] - J0[0]

    def align(a, b):
        a, b = a / np.linalg.norm(a), b / np.linalg.norm(b)
        axis = np.cross(a, b)
        s = np.linalg.norm(axis)
        if s < 1e-12:
            return np.eye(3)
        return Rotation.from_rotvec(axis / s * np.arctan2(s, a @ b)).as_matrix()

    R_s = align(J0[1] - J0[0], J[1] - J[0])
    R_f = align(R_s @ (J0[2] - J0[1]), J[2] - J[1]) @ R_s
    angles = np.stack([Rotation.from_matrix(R_s).as_rotvec(), Rotation.from_matrix(R_s.T @ R_f).as_rotvec(),
                       np.zeros(3)])
    return ArmPose(root, angles)


def fit_shape_parameters(model, meshes: list[np.ndarray], poses: list[ArmPose], frames: list[DepthFrame],
                         initial=None, nicp_weight: float = 0.0, rounds: int = 2,
                         tracker_joints: np.ndarray | None = None, tracker_weight: float = 1.0,
                         fixed_shape: bool = False, arm_length: float | None = None,
                         arm_length_weight: float = 0.0, huber_m: float = 0.0,
                         prior: tuple | None = None) -> tuple:
    """Shape parameters (BMI, muscularity, height, arm length) of the sequence, fitted once (Sec. 6.2).

    Least squares over the given frames of the model mesh ``model_mesh(model, shape, pose_k)`` against
    the depth points (point-to-plane over the filtered pairs, re-paired each round) and, weakly, the
    NICP meshes ``meshes``; the joint angles stay fixed and one root translation (the torso placement;
    its rotation stays that of ``poses[0]``: the subject faces the sensor) shared by all frames is
    fitted alongside: the model's rest mesh moves with height, so shape and placement
    are only separable together. Bounds: the training range widened by its span on each side.
    Point-to-plane pairs leave the arm free to slide along itself, so the arm length is poorly seen
    by the depth alone: ``tracker_joints`` (frames, 3, 3), the body tracker's shoulder, elbow and
    wrist, add ``tracker_weight`` times their distance to the model's posed joints, and ``arm_length``
    (the tracker's chain length averaged over the sequence) holds the arm-length parameter with
    ``arm_length_weight``. With
    ``fixed_shape`` (measured parameters in ``initial``) only the root is fitted (three unknowns, no bounds).
    ``prior`` ``(mean (4,), sigma (4,), weight)`` (:func:`population_shape_prior`; the paper fits none) adds
    ``sqrt(weight) (x - mean) / sigma`` for each parameter of finite ``sigma``.
    Returns ``(ArmShapeParams, root (4, 4))``.
    """
    from bodystudio.muscle.model import ArmShapeParams, model_joints, model_mesh

    if not meshes:
        raise InputError("fit_shape_parameters needs at least one registered frame")
    lo, hi, x0 = _shape_bounds(model, initial)
    root0 = poses[0].root
    sex = 1.0 if initial is None else initial.sex  # given, never fitted (the paper's Table 1)

    def root_of(x):
        T = root0.copy()
        T[:3, 3] = root0[:3, 3] + x[4:7]
        return T

    def meshes_of(x):
        shape, root = ArmShapeParams.from_vector(x[:4], sex), root_of(x)
        return [model_mesh(model, shape, ArmPose(root, p.angles)) for p in poses]

    x = np.r_[x0, np.zeros(3)]
    big = np.full(3, np.inf)
    if fixed_shape:  # measured parameters are used as given, never clipped to the training range
        x[:4] = np.asarray(initial.as_vector(), np.float64)
    for _ in range(rounds):
        pairs = [f.plane_pairs(M) for f, M in zip(frames, meshes_of(x), strict=True)]

        def fun(x, pairs=pairs):
            r = [_model_residuals(M, pr, d, nicp_weight) for M, pr, d in zip(meshes_of(x), pairs, meshes, strict=True)]
            if tracker_joints is not None and tracker_weight > 0:
                shape, root = ArmShapeParams.from_vector(x[:4], sex), root_of(x)
                J = model_joints(model, shape)
                for p, tj in zip(poses, tracker_joints, strict=True):
                    T = part_transforms(J, ArmPose(root, p.angles))
                    posed = np.stack([T[k, :3, :3] @ J[k] + T[k, :3, 3] for k in range(3)])
                    r.append(np.sqrt(tracker_weight) * (posed - tj).ravel())
            if arm_length is not None and arm_length_weight > 0:
                r.append(np.sqrt(arm_length_weight) * np.atleast_1d(x[3] - arm_length))
            if prior is not None:
                mean, sigma, weight = prior
                held = np.isfinite(sigma)
                r.append(np.sqrt(weight) * (x[:4][held] - mean[held]) / sigma[held])
            return np.concatenate(r)

        loss = dict(loss="huber", f_scale=huber_m) if huber_m > 0 else {}
        if fixed_shape:  # only the root: no degenerate bounds on the shape (scipy warned on x0 +- 1e-9)
            x[4:] = least_squares(lambda t, fun=fun, s=x[:4].copy(): fun(np.r_[s, t]), x[4:], x_scale=np.full(3, 0.01),
                                  max_nfev=30, **loss).x
            continue
        x = least_squares(fun, x, bounds=(np.r_[lo, -big], np.r_[hi, big]),
                          x_scale=np.r_[np.maximum(hi - lo, 1e-3) / 4, np.full(3, 0.01)], max_nfev=30, **loss).x
    return ArmShapeParams.from_vector(x[:4], sex), root_of(x)


def population_shape_prior(model, sex: float, arm_length_m: float | None) -> tuple[np.ndarray, np.ndarray]:
    """The Sec. 6.2 shape fit's prior from the model's training population (the paper's fit has none): the mean and
    spread of the BMI and muscularity of the training subjects of ``sex`` (rounded; all of them when fewer than two
    are of it), and their height as the height-to-arm-length ratio's mean and spread times ``arm_length_m`` (the body
    tracker's arm length: a person's height follows the arm's, 3.57-3.60 x on the synthetic women, which the arm's
    depth does not show; without it the height's own mean and spread). The arm length gets no prior (sigma inf: the
    tracker holds it), and nothing does with fewer than two training subjects (no spread to take). Returns
    ``(mean (4,), sigma (4,))``."""
    rows = np.unique(np.asarray(model.shape_rows, np.float64), axis=0)
    if rows.shape[1] > 4:
        same = np.abs(rows[:, 4] - round(float(sex))) < 0.5
        rows = rows[same] if same.sum() >= 2 else rows
    if len(rows) < 2:
        return np.full(4, np.nan), np.full(4, np.inf)
    mean = np.r_[rows[:, :3].mean(axis=0), np.nan]
    sigma = np.r_[rows[:, :3].std(axis=0, ddof=1), np.inf]
    if arm_length_m is not None:
        ratio = rows[:, 2] / rows[:, 3]
        mean[2], sigma[2] = ratio.mean() * arm_length_m, ratio.std(ddof=1) * arm_length_m
    return mean, np.maximum(sigma, 1e-6)


def _shape_bounds(model, initial):
    """Bounds and start of the shape fit: the training range widened by its span on each side.

    Captured subjects may lie outside the training range (the paper's Table 1); the start is the
    population centre of the model's parameter normalisation.
    """
    from bodystudio.muscle.model import SHAPE_NAMES

    rng = model.shape_range() if getattr(model, "subjects", None) else {}
    lo, hi = [], []
    for i, k in enumerate(SHAPE_NAMES):
        c, sc = float(model.param_center[i]), float(model.param_scale[i])
        a, b = rng.get(k, (c - sc, c + sc))
        span = max(b - a, sc)
        lo.append(a - span)
        hi.append(b + span)
    lo, hi = np.array(lo), np.array(hi)
    lo[1], hi[1] = max(lo[1], 0.0), min(hi[1], 1.0)  # muscularity is a fraction
    x0 = np.asarray(model.param_center, float) if initial is None else initial.as_vector()
    return lo, hi, np.clip(x0, lo + 1e-9, hi - 1e-9)


def model_based_filtering(model, shape, root: np.ndarray, deformed: np.ndarray, base: np.ndarray,
                          part_weights: np.ndarray, vertex_weights: np.ndarray, frame: DepthFrame,
                          joints: np.ndarray, norm_limit: float = 0.9, refine_pose: bool = True,
                          tracker: np.ndarray | None = None, tracker_weight: float = 0.0,
                          previous: ArmPose | None = None, smooth_weight: float = 0.0,
                          huber_m: float = 0.0) -> tuple[np.ndarray, ArmPose]:
    """Mesh projection of Sec. 6.2: joint angles by Procrustes (Eq. 11), then the model mesh of Eq. 12.

    ``deformed`` is the ARAP mesh of non-rigid ICP, ``base`` the model's rest mesh for ``shape`` and
    ``root`` the sequence's torso placement (see ``fit_shape_parameters``). The Procrustes angles are
    refined on the model mesh against the depth points (``refine_arm_pose``); returns the model mesh
    (with the ``norm_limit`` displacement limit) and the pose.
    """
    from bodystudio.muscle.model import model_mesh

    w = vertex_weights + 0.05  # vertices without data still carry their part's rigid motion a little
    T = procrustes_part_transforms(base, deformed, part_weights, w)
    angles = arm_pose_from_part_transforms(T).angles
    angles[2] = 0.0  # the wrist: a fist held still (Sec. 8.1), no depth pairs on the hand
    pose = ArmPose(root, angles)
    if refine_pose:
        pose = refine_arm_pose(pose, lambda p: model_mesh(model, shape, p, norm_limit=norm_limit), frame, deformed,
                               joints, tracker=tracker, tracker_weight=tracker_weight, model_joints=joints,
                               previous=previous, smooth_weight=smooth_weight, huber_m=huber_m)
    return model_mesh(model, shape, pose, norm_limit=norm_limit), pose


def smooth_arm_poses(poses: list[ArmPose], sigma_frames: float = 1.5, radius: int | None = None,
                     degree: int = 0, shoulder_degree: int | None = None,
                     positions: np.ndarray | None = None) -> list[ArmPose]:
    """Joint angles averaged over neighbouring frames with Gaussian weights (the Eq. 13-14 window on poses).

    Arm motion is quasi-static (Sec. 3), so frame-to-frame changes beyond a smooth trajectory are
    depth and tracker noise; rotation vectors of one joint change little within a few frames and average
    linearly. The window is symmetric (no lag on a steady motion, unlike the previous-frame prior of
    ``refine_arm_pose``) and reaches ``radius`` frames each side (default ``max(2, ceil(2 sigma))``).

    ``degree`` 0 is the weighted mean; ``degree`` 2 fits a quadratic in time to each angle over the same
    Gaussian-weighted window and takes its value at the frame (a local polynomial, Savitzky-Golay with
    Gaussian weights), which keeps a motion's turning points: the mean cuts each extreme by about
    ``sigma^2 / 2`` times the angle's second difference (0.6-0.8 deg of elbow flexion at sigma 2.5 on the
    benchmark's 3.3 s flexion cycle; docs/muscle.md "Capture, fifteenth pass"). At the sequence's ends the
    window is cut short; a window of fewer than ``degree + 2`` frames falls back to the mean.
    ``shoulder_degree`` (None: ``degree``) is the shoulder rotation's own degree: the shoulder moves slowly, so the
    mean's bias is small there and its lower noise wins (the fifteenth pass).
    ``positions`` (T,) ints: each pose's frame number in the recording when frames were skipped (rel7a: a bad frame
    is no pose); the window and its weights are then in recorded frames, so a neighbour across a gap counts as far
    as it lies in time. None: consecutive frames.
    """
    if sigma_frames <= 0 or len(poses) < 3:
        return list(poses)
    radius = max(2, int(np.ceil(2.0 * sigma_frames))) if radius is None else radius
    A = np.stack([p.angles for p in poses])
    if positions is not None and np.any(np.diff(np.asarray(positions)) != 1):
        return _smooth_arm_poses_at(poses, A, sigma_frames, radius, degree, shoulder_degree,
                                    np.asarray(positions, np.int64))
    degrees = (degree if shoulder_degree is None else shoulder_degree, degree, degree)

    def window_row(k, w, d):
        if d > 0 and len(k) >= d + 2:
            # weighted least squares of the angles on 1, k, ..., k^d; the value at k = 0 is a fixed linear
            # combination of the window's frames (the first row of the hat matrix)
            V = np.vander(k.astype(np.float64), d + 1, increasing=True)
            return np.linalg.solve(V.T @ (w[:, None] * V), (V * w[:, None]).T)[0]
        return w / w.sum()

    out = []
    for i, p in enumerate(poses):
        lo, hi = max(0, i - radius), min(len(poses), i + radius + 1)
        k = np.arange(lo, hi) - i
        w = np.exp(-(k ** 2) / (2.0 * sigma_frames ** 2))
        rows = {d: window_row(k, w, d) for d in set(degrees)}
        out.append(ArmPose(p.root, np.stack([rows[d] @ A[lo:hi, j] for j, d in enumerate(degrees)])))
    return out


def _smooth_arm_poses_at(poses, A, sigma_frames, radius, degree, shoulder_degree, positions):
    """:func:`smooth_arm_poses` over poses at recorded frame ``positions`` with gaps: the window holds the poses
    within ``radius`` recorded frames, each weighted by its distance in frames."""
    degrees = (degree if shoulder_degree is None else shoulder_degree, degree, degree)
    out = []
    for i, p in enumerate(poses):
        lo = int(np.searchsorted(positions, positions[i] - radius, "left"))
        hi = int(np.searchsorted(positions, positions[i] + radius, "right"))
        k = (positions[lo:hi] - positions[i]).astype(np.float64)
        w = np.exp(-(k ** 2) / (2.0 * sigma_frames ** 2))
        rows = {}
        for d in set(degrees):
            if d > 0 and len(k) >= d + 2:
                V = np.vander(k, d + 1, increasing=True)
                rows[d] = np.linalg.solve(V.T @ (w[:, None] * V), (V * w[:, None]).T)[0]
            else:
                rows[d] = w / w.sum()
        out.append(ArmPose(p.root, np.stack([rows[d] @ A[lo:hi, j] for j, d in enumerate(degrees)])))
    return out


def skeleton_model_mesh(model, pose: ArmPose, rest: np.ndarray, joints: np.ndarray,
                        norm_limit: float = 0.9) -> np.ndarray:
    """Eq. 12 with a per-subject skeleton: ``skinning(v_rest + d_rho)`` about ``joints``, the rest mesh held.

    ``rest`` is ``model_rest_vertices(model, shape)`` (``v_base + d_l + d_theta`` placed at the regressed
    shoulder); ``joints`` (3, 3) are the subject's rest shoulder, elbow and wrist centres, which may sit
    apart from the regressed ones inside the same skin. With the regressed joints it equals ``model_mesh``.
    """
    from bodystudio.muscle.model import limit_displacement_norms, pose_displacements

    d_rho = limit_displacement_norms(pose_displacements(model, pose.angles), norm_limit)
    return pose_arm(rest + d_rho, model.part_weights, joints, pose)


def fit_arm_sequence(model, shape, poses: list[ArmPose], frames: list[DepthFrame], joints: np.ndarray,
                     norm_limit: float = 0.9, tracker_joints: np.ndarray | None = None, tracker_weight: float = 0.0,
                     smooth_weight: float = 10.0, rounds: int = 2, max_nfev: int = 8,
                     huber_m: float = 0.0, fit_root: bool = True) -> list[ArmPose]:
    """Model-based tracking of the whole sequence: the torso placement and every frame's joint angles at once.

    Sec. 6.2 fits the angles frame by frame (Procrustes, Eq. 11, then ``refine_arm_pose``) under a torso
    placement found once on the first frames; root and angle errors then compensate each other (the
    error decomposition of docs/muscle.md). Here one Gauss-Newton over the model mesh of Eq. 12 (shape
    held) solves the shared root translation and each frame's shoulder rotation (3) and elbow hinge
    flexion (1) together against every frame's depth points (point-to-plane over the filtered pairs of
    Sec. 5.2, re-paired each round), the body tracker's joints (``tracker_weight`` per coordinate, as in
    ``refine_arm_pose``) and a second-difference prior on the angles (``smooth_weight`` per coordinate
    times a 0.3 m lever: quasi-static motion, Sec. 3, with no lag, unlike a previous-frame prior). The
    forearm twist and the wrist keep their values (unobservable, see ``refine_arm_pose``). ``huber_m``
    > 0: Huber loss on every residual with that scale (metres), against pairs on the wrong surface.
    The Jacobian is sparse (a frame's angles touch its own residuals and its neighbours' priors), so the
    finite differences are grouped (scipy's ``jac_sparsity``). ``fit_root=False`` holds the torso placement
    and solves the angles alone. Returns the poses (with the new root); the skeleton stays the model's
    (:func:`fit_arm_sequence_skeleton` fits it too).
    """
    return fit_arm_sequence_skeleton(model, shape, poses, frames, joints, norm_limit, tracker_joints, tracker_weight,
                                     smooth_weight, rounds, max_nfev, huber_m, fit_root, fit_skeleton=False)[0]


def fit_arm_sequence_skeleton(model, shape, poses: list[ArmPose], frames: list[DepthFrame], joints: np.ndarray,
                              norm_limit: float = 0.9, tracker_joints: np.ndarray | None = None,
                              tracker_weight: float = 0.0, smooth_weight: float = 10.0, rounds: int = 2,
                              max_nfev: int = 8, huber_m: float = 0.0, fit_root: bool = False,
                              fit_skeleton: bool = True, skeleton_prior_weight: float = 100.0,
                              depth_huber_only: bool = False, rest: np.ndarray | None = None,
                              free_joints: tuple[bool, bool, bool] = (True, True, True),
                              start_joints: np.ndarray | None = None, torso_pair_weight: float = 1.0,
                              tracker_placement_weight: float | None = None,
                              positions: np.ndarray | None = None,
                              ) -> tuple[list[ArmPose], np.ndarray]:
    """:func:`fit_arm_sequence` with the subject's skeleton as shared unknowns of the whole sequence.

    The model's rest joints are regressed from the shape parameters (Sec. 6.1); a subject outside the
    training range has its shoulder, elbow and wrist elsewhere inside the same skin, and a per-frame fit
    can absorb that only in wrong angles. With ``fit_skeleton`` the three rest joint centres (9 unknowns,
    offsets from ``joints`` with the rest mesh held: :func:`skeleton_model_mesh`) are solved once per
    sequence together with every frame's angles; the elbow hinge axis is the normal of the fitted joints'
    plane (:func:`elbow_axes`), so it is fitted with them. The depth pairs see where the limb bends, the
    tracker's joints (noisy per frame, unbiased) average over the sequence onto the joint centres, and a
    weak prior (``skeleton_prior_weight`` per coordinate, 1 per depth pair) holds them to the regression.
    Two rest-joint moves are invisible to the depth of a skinned limb: the elbow along its own hinge axis
    and the wrist (its angle is held), so the tracker's joints carry them; a Huber loss on the tracker's
    residuals (scipy's ``loss`` acts on every residual) cuts their pull to a constant beyond ``huber_m``.
    ``depth_huber_only``: the Huber weights act on the depth pairs alone, as iteratively reweighted least
    squares (weights ``min(1, huber_m / |r|)`` of each pair's distance at the start of each round), and the
    tracker, prior and skeleton terms stay quadratic.
    ``free_joints``: which of shoulder, elbow, wrist are fitted (the others stay the regressed ones).
    ``rest``: the subject's rest mesh (default ``model_rest_vertices(model, shape)``; a personalised one
    from :func:`fit_rest_shape_correction`).
    ``start_joints``: the skeleton the fit starts from (default ``joints``; the prior stays at ``joints``), e.g.
    the subject's true joints, to check whether the truth is a minimum of this energy (docs/muscle.md, fifth pass).
    ``torso_pair_weight``: the chest's (torso part's) depth pairs count this much (1: as the arm's): a model
    whose chest does not match the subject's drags the placement through them.
    ``tracker_placement_weight``: None: the tracker's joints are absolute observations every frame (each frame's
    noise pulls the placement). A number: each frame's tracker joints count relative to the tracker's
    sequence-mean shoulder (their positions minus it, against the fit's joints minus the fit's posed shoulder:
    the per-frame noise informs the angles and bones only), and the placement is tied to the tracker's
    sequence-mean shoulder by one prior of this weight per coordinate (:func:`tracker_placement_prior_weight`
    gives it from the tracker's measured noise).
    ``positions`` (T,) ints: each pose's recorded frame when frames were skipped (rel7a); the second-difference
    prior is then the second divided difference over the real frame spacing (h1, h2), scaled by
    ``2 / (h1 + h2) * sqrt((h1 + h2) / 2)`` (the spline's energy over the span), which is the plain
    ``a[k-1] - 2 a[k] + a[k+1]`` for consecutive frames. None: consecutive frames.
    Returns the poses and the fitted rest joints (3, 3); the forearm twist of each frame is kept about the
    new forearm axis.
    """
    from scipy.sparse import lil_matrix

    from bodystudio.muscle.model import model_rest_vertices

    T = len(poses)
    J0 = np.asarray(joints, np.float64)
    J_start = J0 if start_joints is None or not fit_skeleton else np.asarray(start_joints, np.float64)
    h, f = elbow_axes(J_start)
    twist = np.array([float(p.angles[1] @ f) for p in poses])
    root0 = poses[0].root
    rest = model_rest_vertices(model, shape) if rest is None else np.asarray(rest, np.float64)

    torso = np.asarray(model.part_weights)[:, 0] > 0.5  # vertices of the chest (the torso part)
    r0 = 3 if fit_root else 0  # parameters before the angles
    free = np.flatnonzero(np.asarray(free_joints, bool)) if fit_skeleton else np.zeros(0, int)
    s0 = 3 * len(free)  # skeleton offsets after the root
    n0 = r0 + s0

    def skeleton(x):
        if not s0:
            return J0
        J = J0.copy()
        J[free] += x[r0:n0].reshape(-1, 3)
        return J

    def unpack(x):
        root = root0.copy()
        root[:3, 3] = root0[:3, 3] + x[:r0] if fit_root else root0[:3, 3]
        J = skeleton(x)
        a = x[n0:].reshape(T, 4)
        return [ArmPose(root, np.vstack([a[k, :3], elbow_rotvec(J, a[k, 3], twist[k]), poses[k].angles[2]]))
                for k in range(T)]

    def mesh(p, J):
        return skeleton_model_mesh(model, p, rest, J, norm_limit)

    x = np.r_[np.zeros(r0), (J_start - J0)[free].ravel(), np.concatenate([np.r_[p.angles[0], p.angles[1] @ h]
                                                                           for p in poses])]
    lever = np.sqrt(smooth_weight) * 0.3
    use_tracker = tracker_joints is not None and tracker_weight > 0
    mean_prior = use_tracker and tracker_placement_weight is not None
    if mean_prior:
        tracker_mean_shoulder = np.asarray(tracker_joints, np.float64)[:, 0].mean(axis=0)
        tracker_rel = np.asarray(tracker_joints, np.float64) - tracker_mean_shoulder
        n_mean = 3
    else:
        n_mean = 0
    for _ in range(rounds):
        J = skeleton(x)
        meshes = [mesh(p, J) for p in unpack(x)]
        pairs = [fr.plane_pairs(M) for fr, M in zip(frames, meshes, strict=True)]
        irls = depth_huber_only and huber_m > 0
        if irls:  # Huber weights of the depth pairs at this round's start (IRLS)
            pairs = [(k, q, n * np.sqrt(np.minimum(1.0, huber_m / np.maximum(
                np.abs(np.einsum("kd,kd->k", M[k] - q, n)), 1e-12)))[:, None]) for M, (k, q, n) in zip(
                meshes, pairs, strict=True)]
        if torso_pair_weight != 1.0:  # the chest's pairs scaled (after the Huber weights, which use metres)
            pairs = [(k, q, n * np.where(torso[k], np.sqrt(torso_pair_weight), 1.0)[:, None]) for k, q, n in pairs]
        sizes = [len(k) + (9 if use_tracker else 0) for k, _, _ in pairs]
        n_prior = 4 * max(T - 2, 0)
        Jac = lil_matrix((sum(sizes) + n_prior + s0 + n_mean, len(x)), dtype=int)
        row = 0
        for k, n in enumerate(sizes):
            Jac[row:row + n, :n0] = 1
            Jac[row:row + n, n0 + 4 * k:n0 + 4 + 4 * k] = 1
            row += n
        for k in range(1, T - 1):
            for c in range(4):
                Jac[row, [n0 + 4 * (k - 1) + c, n0 + 4 * k + c, n0 + 4 * (k + 1) + c]] = 1
                row += 1
        for c in range(s0):
            Jac[row, r0 + c] = 1
            row += 1
        Jac[row:row + n_mean, :n0] = 1

        def fun(x, pairs=pairs):
            ps, J = unpack(x), skeleton(x)
            r = []
            tracked = tracker_rel if mean_prior else tracker_joints if use_tracker else [None] * T
            for p, (k, q, n), tj in zip(ps, pairs, tracked, strict=True):
                M = mesh(p, J)
                r.append(np.einsum("kd,kd->k", M[k] - q, n))
                if use_tracker:
                    P = posed_joints(J, p)
                    if mean_prior:
                        r.append(np.sqrt(tracker_weight) * ((P - P[0]) - tj).ravel())
                    else:
                        r.append(np.sqrt(tracker_weight) * (P - tj).ravel())
            a = x[n0:].reshape(T, 4)
            if T > 2:
                r.append(lever * second_differences(a, positions).ravel())
            if s0:
                r.append(np.sqrt(skeleton_prior_weight) * x[r0:n0])
            if mean_prior:  # the fit's posed shoulder (shared root: the same in every frame) vs the tracker's mean
                r.append(np.sqrt(tracker_placement_weight) * (posed_joints(J, ps[0])[0] - tracker_mean_shoulder))
            return np.concatenate(r)

        loss = dict(loss="huber", f_scale=huber_m) if huber_m > 0 and not irls else {}
        scale = np.r_[np.full(r0, 0.01), np.full(s0, 0.01), np.full(4 * T, 0.05)]
        x = least_squares(fun, x, jac_sparsity=Jac, method="trf", x_scale=scale, max_nfev=max_nfev, **loss).x
    return unpack(x), skeleton(x)


def second_differences(a: np.ndarray, positions: np.ndarray | None = None) -> np.ndarray:
    """The sequence fit's second differences of per-frame values ``a`` (T, ...): ``a[k-1] - 2 a[k] + a[k+1]``
    (T - 2, ...). ``positions`` (T,) the frames' recorded numbers when frames were skipped (rel7a): the second divided
    difference over the real spacing h1, h2 times ``2 / (h1 + h2) * sqrt((h1 + h2) / 2)`` (a smoothing spline's
    energy over the span), which is the plain one where the frames are consecutive; zero on a motion linear in time
    across a gap, which the plain one would count as a kink."""
    a = np.asarray(a, np.float64)
    if positions is None or not np.any(np.diff(np.asarray(positions)) != 1):
        return a[:-2] - 2 * a[1:-1] + a[2:]
    h = np.diff(np.asarray(positions, np.float64)).reshape(-1, *([1] * (a.ndim - 1)))
    h1, h2 = h[:-1], h[1:]
    return 2.0 / (h1 + h2) * np.sqrt((h1 + h2) / 2.0) * ((a[2:] - a[1:-1]) / h2 - (a[1:-1] - a[:-2]) / h1)


def tracker_placement_prior_weight(tracker_joints: np.ndarray, length_m: float) -> float:
    """Weight per coordinate of the placement prior of :func:`fit_arm_sequence_skeleton`: ``(length_m / SE)^2``.

    ``SE`` is the standard error of the tracker's sequence-mean shoulder, ``sqrt(mean_c var_c / T)`` with
    ``var_c`` the per-coordinate variance of the tracked shoulder over the ``T`` frames (the tracker's measured
    per-frame noise; the shoulder barely moves in an arm sequence). A placement one standard error off the mean
    costs as much as one depth pair ``length_m`` off its plane (the depth pairs weigh 1), so a longer or steadier
    track (smaller SE) ties the placement harder to the tracker's mean and a short noisy one leaves it to the depth.
    """
    se = tracker_mean_standard_error(tracker_joints)
    return float(length_m ** 2 / max(se * se, 1e-12))


def tracker_mean_standard_error(tracker_joints: np.ndarray) -> float:
    """Standard error (m) of the tracker's sequence-mean shoulder: ``sqrt(mean_c var_c / T)``, ``var_c`` the
    per-coordinate variance of the tracked shoulder (``tracker_joints[:, 0]``) over the ``T`` frames.

    The shoulder barely moves in an arm sequence, so its scatter is the tracker's per-frame noise (10-12 mm per
    coordinate on the Kinect v2 sessions: SE 1.9-2.6 mm over 24 frames, 1.0-1.1 over 120, 0.8 over 200): how well
    the sequence pins the torso placement that the whole-sequence fit shares across frames."""
    S = np.asarray(tracker_joints, np.float64).reshape(len(tracker_joints), -1, 3)[:, 0]
    return float(np.sqrt(np.mean(S.var(axis=0)) / len(S)))


def tracker_noise_sigma_m(tracker_joints: np.ndarray, floor_m: float = 0.001) -> float:
    """The body tracker's per-coordinate noise (m), estimated from its own track: ``sqrt(mean(d2^2) / 6)`` over every
    joint and coordinate, ``d2`` the frame-to-frame second difference of the tracked joints (T, J, 3), at least
    ``floor_m`` (a noise-free synthetic track would otherwise get an unbounded weight).

    White noise of standard deviation sigma has a second difference of variance 6 sigma^2; the arm's own motion at
    30 fps adds little to it (an elbow swinging 1 rad over a 3 s period: ~5 mrad per frame^2, ~1.5 mm at the wrist,
    against 11-13 mm of the Kinect v2's per-frame noise and bone-length jitter). No ground truth: the track itself."""
    if len(tracker_joints) < 3:  # before the reshape: an empty track cannot be reshaped to (0, -1, 3)
        raise InputError(f"the tracker's noise needs at least 3 frames of joints, got {len(tracker_joints)}")
    X = np.asarray(tracker_joints, np.float64).reshape(len(tracker_joints), -1, 3)
    d2 = X[:-2] - 2.0 * X[1:-1] + X[2:]
    return max(float(np.sqrt(np.mean(d2 * d2) / 6.0)), floor_m)


def depth_residual_sigma_m(model, poses: list[ArmPose], frames: list[DepthFrame], rest: np.ndarray,
                           joints: np.ndarray, norm_limit: float = 0.9, stride: int = 10) -> float:
    """Robust standard deviation (m) of the depth pairs' point-to-plane residuals (the filtered pairs of Sec. 5.2 of
    the model meshes of Eq. 12 on ``rest`` and ``joints``), every ``stride``-th frame: 1.4826 x the median absolute
    residual (the pairs on the wrong surface, which the fits' Huber weights cut, do not inflate it)."""
    r = []
    for p, fr in zip(poses[::stride], frames[::stride], strict=True):
        M = skeleton_model_mesh(model, p, rest, joints, norm_limit)
        k, q, n = fr.plane_pairs(M)
        r.append(np.einsum("kd,kd->k", M[k] - q, n))
    r = np.concatenate(r) if r else np.zeros(0)
    return float(1.4826 * np.median(np.abs(r))) if len(r) else 0.0


def noise_weighted_tracker_weight(depth_sigma_m: float, tracker_sigma_m: float) -> float:
    """The tracker's weight per coordinate against 1 per depth pair when every term is weighted by 1 / sigma^2 (the
    maximum-likelihood weighting of independent Gaussian residuals): ``(depth_sigma_m / tracker_sigma_m)^2``.

    The sequence fit of Sec. 6.2 had the tracker's joints at a fixed 30 per coordinate: with the Kinect v2's ~12 mm
    per coordinate and ~2 mm per depth pair, ~1000 times what their noise warrants (docs/muscle.md, capture passes
    eleven and thirteen)."""
    return float((depth_sigma_m / max(tracker_sigma_m, 1e-9)) ** 2)


def fit_rest_shape_correction(model, shape, poses: list[ArmPose], frames: list[DepthFrame], rest: np.ndarray,
                              joints: np.ndarray, prior_weight: float = 0.05, norm_limit: float = 0.9,
                              huber_m: float = 0.004, basis: np.ndarray | None = None) -> np.ndarray:
    """Per-subject rest shape: ``rest + sum_j c_j e_j`` fitted to every frame's depth with the poses held.

    The model's rest mesh (Eq. 5-9, ``v_base + d_l + d_theta``) is a regression from four parameters; a
    subject's own arm differs from it. With the poses and skeleton of the sequence held, the posed mesh of
    Eq. 12 is linear in the rest vertices (the skinning is), so the coefficients ``c`` of the population's
    PCA eigenvectors ``e_j`` (``basis``, default ``model.length_basis``: the Hasler-style population of
    Eq. 8) follow from one linear least squares over all frames' point-to-plane pairs (Sec. 5.2 filters),
    with Huber weights (``huber_m``, on each pair's distance before the fit) and a Tikhonov prior
    ``prior_weight`` per frame on ``|c|^2`` (``|c|`` is the correction's norm over all coordinates).
    The unseen side follows the seen one through the population's eigenvectors. Returns the new rest mesh.
    """
    E = np.asarray(model.length_basis if basis is None else basis, np.float64)
    k = len(E)
    Ev = E.reshape(k, -1, 3)
    rest = np.asarray(rest, np.float64)
    GtG, Gtb = np.zeros((k, k)), np.zeros(k)
    for p, fr in zip(poses, frames, strict=True):
        M = skeleton_model_mesh(model, p, rest, joints, norm_limit)
        idx, q, n = fr.plane_pairs(M)
        T = part_transforms(np.asarray(joints, np.float64), p)
        A = np.einsum("np,pij->nij", model.part_weights[idx], T[:, :3, :3])  # blended rotation per paired vertex
        r = np.einsum("kd,kd->k", M[idx] - q, n)
        w = np.minimum(1.0, huber_m / np.maximum(np.abs(r), 1e-12)) if huber_m > 0 else np.ones(len(r))
        An = np.einsum("kij,ki->kj", A, n)  # n^T A
        G = np.einsum("kj,ckj->kc", An, Ev[:, idx, :])
        GtG += normal_matrix(G, w)
        Gtb -= normal_rhs(G, r, w)
    c = spd_solve(GtG + prior_weight * len(poses) * np.eye(k), Gtb)
    return rest + np.einsum("k,kn->n", c, E).reshape(-1, 3)


def fit_body_rest_shape(space, model, poses: list[ArmPose], frames: list[DepthFrame], x0: np.ndarray,
                        shoulder: np.ndarray, prior_mean: np.ndarray, prior_sigma: np.ndarray,
                        prior_weight: float = 1.0, norm_limit: float = 0.9, huber_m: float = 0.004,
                        iterations: int = 3, fit_placement: bool = True, arm_length_m: float | None = None,
                        arm_length_weight: float = 0.0, tracker_joints: np.ndarray | None = None,
                        tracker_weight: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Per-subject rest shape in the body model's own shape space: replaces Eq. 6-9 (``v_base + d_l + d_theta``
    and the joint regression) of Arm-Muscle Capture by the subject's MakeHuman parameters fitted to the depth.

    ``space`` (:func:`bodystudio.muscle.model.body_shape_space`) gives the rest arm and its shoulder, elbow and wrist
    as functions of the macro parameters (gender, age, muscle, weight, height, proportions, ethnic mix) and the
    weights of the local targets that move the region; the rest mesh sits with its shoulder at ``shoulder`` (the
    capture's placement frame). With every frame's pose held, the posed mesh of Eq. 12 (``skinning(v_rest + d_rho)``,
    Eq. 10's pose term with the norm limit on top) is affine in the rest vertices and the joints (the skinning's
    translations are linear in the joint centres), so each Gauss-Newton step is one linear least squares over all
    frames' point-to-plane pairs (Sec. 5.2 filters; re-paired each step; Huber weights ``huber_m`` on each pair's
    distance at the step's start) with a Tikhonov prior towards the population: ``prior_weight`` per frame on
    ``|(x - prior_mean) / prior_sigma|^2`` in units of (1 mm)^2, so one standard deviation costs a frame as much as
    ``prior_weight`` pairs 1 mm off their planes. The macro parameters enter through MakeHuman's piecewise
    multilinear blend (linearised each step), the local weights linearly. ``fit_placement``: the shared torso
    translation (the placement, which trades with the shoulder's place in the skin) is solved too.
    ``arm_length_m`` (measured; the paper's Table 1): the rest chain's length held to it with ``arm_length_weight``
    per frame (point-to-plane pairs let the arm slide along itself). ``tracker_joints`` (frames, 3, 3): the body
    tracker's shoulder, elbow and wrist, compared with the posed rest joints at ``tracker_weight`` per coordinate (1
    per depth pair), as in the sequence fit: noisy per frame but unbiased, they hold the skeleton where the held
    poses' errors would move it. The unseen side follows the seen one through
    the body model. Returns ``(x, translation (3,))``: the parameters and the placement change to add to every
    pose's root.
    """
    from bodystudio.muscle.model import limit_displacement_norms, pose_displacements

    x = np.asarray(x0, np.float64).copy()
    W = np.asarray(model.part_weights, np.float64)
    m = 9  # macro parameters, clipped to MakeHuman's unit interval
    n_t = 3 if fit_placement else 0
    d_rho = [limit_displacement_norms(pose_displacements(model, p.angles), norm_limit) for p in poses]
    mean, sigma = np.asarray(prior_mean, np.float64), np.asarray(prior_sigma, np.float64)
    T_frames = len(poses)
    shift = np.zeros(3)
    tracked = [None] * T_frames if tracker_joints is None or tracker_weight <= 0 else np.asarray(tracker_joints)
    for _ in range(iterations):
        rest, J = space.rest_and_joints(x, shoulder)
        D = space.jacobian(x)  # (P, n + 3, 3)
        Dv, DJ = D[:, :-3], D[:, -3:].reshape(len(D), 9)
        P = len(x) + n_t
        GtG, Gtr = np.zeros((P, P)), np.zeros(P)
        for p, fr, dr, tj in zip(poses, frames, d_rho, tracked, strict=True):
            pose = ArmPose(p.root.copy(), p.angles)
            pose.root[:3, 3] += shift
            Tp = part_transforms(J, pose)
            if tj is not None:  # posed joints, linear in the rest joints (and the placement) with the pose held
                PJ = posed_joints(J, pose)
                dPJ = np.stack([(posed_joints(J + e.reshape(3, 3), pose) - PJ).ravel() for e in np.eye(9)], axis=1)
                Gj = ordered_product(dPJ, DJ.T)
                if n_t:
                    Gj = np.c_[Gj, np.tile(np.eye(3), (3, 1))]
                GtG += tracker_weight * normal_matrix(Gj)
                Gtr += tracker_weight * normal_rhs(Gj, (PJ - tj).ravel())
            M = pose_arm(rest + dr, W, J, pose)
            idx, q, nrm, wp = weighted_pairs(fr, M)
            if len(idx) == 0:
                continue
            r = np.einsum("kd,kd->k", M[idx] - q, nrm)
            w = wp * (np.minimum(1.0, huber_m / np.maximum(np.abs(r), 1e-12)) if huber_m > 0 else 1.0)
            A = np.einsum("kp,pij->kij", W[idx], Tp[:, :3, :3])
            An = np.einsum("kij,ki->kj", A, nrm)  # n^T A per paired vertex
            # d t / d J: the parts' translations are linear in the joint centres (exact differences)
            dT = np.stack([(part_transforms(J + e.reshape(3, 3), pose)[:, :3, 3] - Tp[:, :3, 3])
                           for e in np.eye(9)])  # (9, parts, 3)
            dtJ = np.einsum("kp,cpd,kd->kc", W[idx], dT, nrm)  # (k, 9)
            G = np.einsum("kj,Pkj->kP", An, Dv[:, idx, :]) + ordered_product(dtJ, DJ.T)
            if n_t:
                G = np.c_[G, nrm]
            GtG += normal_matrix(G, w)
            Gtr += normal_rhs(G, r, w)
        lam = prior_weight * T_frames * 1e-6
        reg = np.zeros(P)
        reg[:len(x)] = lam / sigma ** 2
        rhs = -Gtr
        rhs[:len(x)] -= reg[:len(x)] * (x - mean)
        H = GtG + np.diag(reg)
        if arm_length_m is not None and arm_length_weight > 0:
            bones = np.diff(J, axis=0)
            lengths = np.linalg.norm(bones, axis=1)
            u = bones / lengths[:, None]
            DJ3 = DJ.reshape(len(D), 3, 3)
            g = np.einsum("bd,Pbd->P", u, DJ3[:, 1:] - DJ3[:, :-1])  # d(chain length)/dx
            a = arm_length_weight * T_frames
            H[:len(x), :len(x)] += a * np.outer(g, g)
            rhs[:len(x)] -= a * g * (lengths.sum() - arm_length_m)
        step = spd_solve(H, rhs)
        x += step[:len(x)]
        x[:m] = np.clip(x[:m], 0.0, 1.0)
        if n_t:
            shift += step[len(x):]
    return x, shift



def depth_energy_mm(model, poses: list[ArmPose], frames: list[DepthFrame], rest: np.ndarray, joints: np.ndarray,
                    norm_limit: float = 0.9, huber_m: float = 0.004) -> float:
    """The data energy of the model meshes (Eq. 12 on ``rest`` and ``joints``) against the depth: the root mean
    Huber point-to-plane residual (``huber_m`` scale) over the filtered pairs of Sec. 5.2, in mm.

    A data-side figure (no ground truth) for choosing between rounds of the rest-shape fit (docs/muscle.md, ninth
    pass): the sequence fit and the rest-shape fit each lower their own energy, the alternation need not."""
    total, count = 0.0, 0
    for p, fr in zip(poses, frames, strict=True):
        M = skeleton_model_mesh(model, p, rest, joints, norm_limit)
        k, q, n = fr.plane_pairs(M)
        r = np.abs(np.einsum("kd,kd->k", M[k] - q, n))
        total += float(np.where(r < huber_m, 0.5 * r * r, huber_m * (r - 0.5 * huber_m)).sum())
        count += len(r)
    return 1000.0 * float(np.sqrt(2.0 * total / max(count, 1)))


def fit_body_rest_shape_and_poses(space, model, poses: list[ArmPose], frames: list[DepthFrame], x0: np.ndarray,
                                  shoulder: np.ndarray, prior_mean: np.ndarray, prior_sigma: np.ndarray,
                                  prior_weight: float = 1.0, norm_limit: float = 0.9, huber_m: float = 0.004,
                                  iterations: int = 3, arm_length_m: float | None = None,
                                  arm_length_weight: float = 0.0, tracker_joints: np.ndarray | None = None,
                                  tracker_weight: float = 0.0, angle_damping: float = 1.0,
                                  ) -> tuple[np.ndarray, np.ndarray, list[ArmPose]]:
    """:func:`fit_body_rest_shape` with every given frame's joint angles as unknowns too: one Gauss-Newton over the
    body parameters, the shared placement and each frame's shoulder rotation (3) and elbow hinge flexion (1) of
    Sec. 6.2 (the forearm twist and the wrist held, as in :func:`fit_arm_sequence_skeleton`).

    With the poses held, a pose error of the capture is absorbed by the rest shape (docs/muscle.md, ninth pass).
    Here the posed mesh of Eq. 12 is linearised in each frame's four angles as well (finite differences of
    :func:`skeleton_model_mesh` over the paired vertices, the pose term of Eq. 10 included) and the angles are
    eliminated per frame by a Schur complement (a 4 x 4 block each), so a step costs little more than the held-pose
    fit's. Each frame's angles are damped towards their value at the step's start by ``angle_damping`` per coordinate
    times a 0.3 m lever (Levenberg), in the units of the depth pairs. The energy, the prior, the tracker and the arm
    length are :func:`fit_body_rest_shape`'s. Returns ``(x, translation (3,), poses)``: the poses with the placement
    change added to their roots.
    """
    from bodystudio.muscle.model import limit_displacement_norms, pose_displacements

    x = np.asarray(x0, np.float64).copy()
    W = np.asarray(model.part_weights, np.float64)
    m = 9
    n_x = len(x)
    P = n_x + 3
    mean, sigma = np.asarray(prior_mean, np.float64), np.asarray(prior_sigma, np.float64)
    T_frames = len(poses)
    shift = np.zeros(3)
    tracked = [None] * T_frames if tracker_joints is None or tracker_weight <= 0 else np.asarray(tracker_joints)
    _, J = space.rest_and_joints(x, shoulder)
    h, f = elbow_axes(J)
    twist = [float(p.angles[1] @ f) for p in poses]
    angles = [np.r_[p.angles[0], p.angles[1] @ h] for p in poses]
    lever2 = angle_damping * 0.3 ** 2
    eps = 1e-5

    def pose_of(k, a, J):
        root = poses[k].root.copy()
        root[:3, 3] += shift
        return ArmPose(root, np.vstack([a[:3], elbow_rotvec(J, a[3], twist[k]), poses[k].angles[2]]))

    def mesh_of(pose, rest, J):
        d_rho = limit_displacement_norms(pose_displacements(model, pose.angles), norm_limit)
        return pose_arm(rest + d_rho, W, J, pose)

    for _ in range(iterations):
        rest, J = space.rest_and_joints(x, shoulder)
        D = space.jacobian(x)
        Dv, DJ = D[:, :-3], D[:, -3:].reshape(len(D), 9)
        H_ss, g_s = np.zeros((P, P)), np.zeros(P)
        blocks = []
        for k, (fr, tj) in enumerate(zip(frames, tracked, strict=True)):
            a = angles[k]
            pose = pose_of(k, a, J)
            Tp = part_transforms(J, pose)
            H_sa, H_aa, g_a = np.zeros((P, 4)), lever2 * np.eye(4), np.zeros(4)
            M = mesh_of(pose, rest, J)
            idx, q, nrm, wp = weighted_pairs(fr, M)
            if tj is not None:
                PJ = posed_joints(J, pose)
                dPJ = np.stack([(posed_joints(J + e.reshape(3, 3), pose) - PJ).ravel() for e in np.eye(9)], axis=1)
                Gj = np.c_[ordered_product(dPJ, DJ.T), np.tile(np.eye(3), (3, 1))]
                Aj = np.stack([(posed_joints(J, pose_of(k, a + eps * e, J)) - PJ).ravel() / eps for e in np.eye(4)],
                              axis=1)
                rj = (PJ - tj).ravel()
                H_ss += tracker_weight * normal_matrix(Gj)
                g_s += tracker_weight * normal_rhs(Gj, rj)
                H_sa += tracker_weight * normal_rhs(Gj, Aj)
                H_aa += tracker_weight * normal_matrix(Aj)
                g_a += tracker_weight * normal_rhs(Aj, rj)
            if len(idx):
                r = np.einsum("kd,kd->k", M[idx] - q, nrm)
                w = wp * (np.minimum(1.0, huber_m / np.maximum(np.abs(r), 1e-12)) if huber_m > 0 else 1.0)
                A = np.einsum("kp,pij->kij", W[idx], Tp[:, :3, :3])
                An = np.einsum("kij,ki->kj", A, nrm)
                dT = np.stack([(part_transforms(J + e.reshape(3, 3), pose)[:, :3, 3] - Tp[:, :3, 3])
                               for e in np.eye(9)])
                dtJ = np.einsum("kp,cpd,kd->kc", W[idx], dT, nrm)
                G = np.c_[np.einsum("kj,Pkj->kP", An, Dv[:, idx, :]) + ordered_product(dtJ, DJ.T), nrm]
                Ga = np.stack([np.einsum("kd,kd->k", mesh_of(pose_of(k, a + eps * e, J), rest, J)[idx] - M[idx], nrm)
                               / eps for e in np.eye(4)], axis=1)
                H_ss += normal_matrix(G, w)
                g_s += normal_rhs(G, r, w)
                H_sa += normal_rhs(G, Ga, w)
                H_aa += normal_matrix(Ga, w)
                g_a += normal_rhs(Ga, r, w)
            blocks.append((H_sa, H_aa, g_a))
        lam = prior_weight * T_frames * 1e-6
        H = H_ss.copy()
        rhs = -g_s
        H[np.arange(n_x), np.arange(n_x)] += lam / sigma ** 2
        rhs[:n_x] -= lam / sigma ** 2 * (x - mean)
        if arm_length_m is not None and arm_length_weight > 0:
            bones = np.diff(J, axis=0)
            lengths = np.linalg.norm(bones, axis=1)
            u = bones / lengths[:, None]
            DJ3 = DJ.reshape(len(D), 3, 3)
            g = np.einsum("bd,Pbd->P", u, DJ3[:, 1:] - DJ3[:, :-1])
            c = arm_length_weight * T_frames
            H[:n_x, :n_x] += c * np.outer(g, g)
            rhs[:n_x] -= c * g * (lengths.sum() - arm_length_m)
        for H_sa, H_aa, g_a in blocks:  # the frames' angles eliminated (Schur complement)
            K = spd_solve(H_aa, H_sa.T)
            H -= ordered_product(H_sa, K)
            rhs += ordered_product(K.T, g_a)
        step = spd_solve(0.5 * (H + H.T), rhs)
        for k, (H_sa, H_aa, g_a) in enumerate(blocks):
            angles[k] = angles[k] + spd_solve(H_aa, -g_a - ordered_product(H_sa.T, step))
        x += step[:n_x]
        x[:m] = np.clip(x[:m], 0.0, 1.0)
        shift += step[n_x:]
    _, J = space.rest_and_joints(x, shoulder)
    return x, shift, [pose_of(k, angles[k], J) for k in range(T_frames)]


def skin_template(base: np.ndarray, part_weights: np.ndarray, joints: np.ndarray, pose: ArmPose) -> np.ndarray:
    """The template posed by four-part LBS (Eq. 12 without the model's displacements)."""
    return pose_arm(base, part_weights, joints, pose)


# --- Sec. 7 refinement --------------------------------------------------------------------------


def time_consistent_correspondences(vectors: list[np.ndarray], valid: list[np.ndarray],
                                    sigma_frames: float = 1.0, deltas: list[int] | None = None,
                                    ) -> tuple[np.ndarray, np.ndarray]:
    """Correspondence vectors averaged over frames i-1, i, i+1 with Gaussian weights, Eq. 13-14.

    ``vectors``/``valid`` hold the (n, 3) correspondence vectors and (n,) validity of frames
    i-1, i, i+1 (pass two at a sequence end, with the current frame first or last as it is). Each
    vertex averages the frames where its pair is valid with ``w_{i+delta} = exp(-delta^2 / 2 sigma^2)``;
    returns the averaged vectors and the vertices valid in the current frame. ``deltas``: each frame's offset
    from frame i (one of them 0) for a wider window (a recording faster than 30 fps: the same time span).
    """
    if deltas is not None:
        deltas = [int(d) for d in deltas]
        if len(deltas) != len(vectors) or deltas.count(0) != 1:
            raise InputError(f"deltas {deltas}: one offset per frame and exactly one 0 (the current frame)")
        cur = deltas.index(0)
    elif len(vectors) == 3:
        deltas = (-1, 0, 1)
        cur = 1
    elif len(vectors) == 2:
        deltas, cur = (0, 1), 0  # caller orders (current, neighbour)
    else:
        return np.asarray(vectors[0], np.float64), np.asarray(valid[0], bool)
    num = np.zeros_like(np.asarray(vectors[cur], np.float64))
    den = np.zeros(len(num))
    for d, c, v in zip(deltas, vectors, valid, strict=True):
        w = np.exp(-(d ** 2) / (2.0 * sigma_frames ** 2)) * np.asarray(v, np.float64)
        num += w[:, None] * c
        den += w
    ok = np.asarray(valid[cur], bool) & (den > 0)
    out = np.zeros_like(num)
    out[ok] = num[ok] / den[ok, None]
    return out, ok


def correspondence_weights(vectors: np.ndarray, normals: np.ndarray, vertices: np.ndarray, joints: np.ndarray,
                           valid: np.ndarray, joint_radius_m: float = 0.06, joint_gain: float = 1.0,
                           min_length_m: float = 1e-3) -> np.ndarray:
    """Reliability weight of each correspondence, Sec. 7.2.

    ``|cos|`` of the angle between the correspondence vector and the vertex normal (bulges and dimples
    along the normal are trusted, sliding and shearing are not; vectors shorter than ``min_length_m``
    have no direction and count as agreeing), scaled by ``1 + joint_gain (1 - d / joint_radius_m)``
    for vertices within ``joint_radius_m`` of a joint so the skin around joints deforms more freely.
    """
    c = np.asarray(vectors, np.float64)
    length = np.linalg.norm(c, axis=1)
    cos = np.abs(np.einsum("kd,kd->k", c, normals)) / np.maximum(length, 1e-12)
    agree = np.where(length < min_length_m, 1.0, cos)
    d = np.min(np.linalg.norm(vertices[:, None, :] - np.asarray(joints)[None], axis=2), axis=1)
    near = 1.0 + joint_gain * np.clip(1.0 - d / joint_radius_m, 0.0, 1.0)
    return np.where(valid, agree * near, 0.0)


def edge_on_pairs(vertices: np.ndarray, normals: np.ndarray, sensor_center: np.ndarray, min_cos: float) -> np.ndarray:
    """Vertices (n,) bool whose normal meets the sensor's ray at ``|cos| < min_cos``: the rim of the seen side, where
    the depth's samples lie off the surface (the Kinect's grazing-angle mixtures and the border pixels' normals). The
    Sec. 7 refinement's rim filter; :func:`grazing_pairs` (the pose and rest fits') also drops the vertices facing
    away."""
    ray = np.asarray(vertices, np.float64) - np.asarray(sensor_center, np.float64)
    cos = np.einsum("kd,kd->k", normals, ray) / np.maximum(np.linalg.norm(ray, axis=1), 1e-12)
    return np.abs(cos) < min_cos


def unseen_hold_weights(vertices: np.ndarray, seen: np.ndarray, hold_weight: float, band_m: float) -> np.ndarray:
    """Weight (n,) holding each vertex the sensor does not see to the model mesh in the last ARAP of Sec. 7.

    ``hold_weight`` times ``min(1, d / band_m)``, ``d`` the distance from the vertex to the nearest ``seen`` vertex
    (one with a correspondence, or one the model mesh itself shows to the sensor): 0 on the seen surface, rising over
    a band of ``band_m`` around it, full on the side the sensor does not see. Without it the unseen vertices carry no
    data term and the ARAP carries them with the seen side's pull as a rigid piece (the back of the arm moved 0.9 mm
    on 501, away from the truth; docs/muscle.md, twelfth pass), where the paper's refinement adds "the surface detail
    the depth points support" and the back has none.
    """
    V = np.asarray(vertices, np.float64)
    ok = np.asarray(seen, bool)
    if hold_weight <= 0 or not ok.any():
        return np.where(ok, 0.0, max(hold_weight, 0.0))
    from scipy.spatial import cKDTree

    d, _ = cKDTree(V[ok]).query(V)
    ramp = np.ones(len(V)) if band_m <= 0 else np.clip(d / band_m, 0.0, 1.0)
    return hold_weight * np.where(ok, 0.0, ramp)


def refine_surface(model_vertices: np.ndarray, faces: np.ndarray, vectors: np.ndarray, weights: np.ndarray,
                   data_weight: float = 1.0, iterations: int = 4, hold: np.ndarray | None = None) -> np.ndarray:
    """The last ARAP deformation of Sec. 7: the model mesh pulled along the weighted, averaged correspondences.

    The model mesh is both the ARAP rest shape and the start, so the refinement adds only the surface
    detail the depth points support (Sec. 7: "slightly beyond the deformation space" of the model).
    ``hold`` (n,): per-vertex weights of a soft constraint to the model mesh itself (:func:`unseen_hold_weights`:
    the vertices without correspondences), on the same scale as ``weights``; a vertex with both gets their sum,
    pulled to the weighted mean of its target and its model position.
    """
    from bodystudio.muscle.nicp import arap_deformation, arap_system

    M = np.asarray(model_vertices, np.float64)
    c = np.asarray(vectors, np.float64)
    w = np.asarray(weights, np.float64)
    if hold is not None:
        total = w + np.asarray(hold, np.float64)
        c = c * np.divide(w, total, out=np.zeros_like(total), where=total > 0)[:, None]
        w = total
    system = arap_system(M, faces)
    return arap_deformation(system, M, M + c, w, data_weight, iterations)


# --- a last per-frame pose refit (beyond the paper) ----------------------------------------------


def refit_arm_poses_to_depth(model, poses: list[ArmPose], frames: list[DepthFrame], rest: np.ndarray,
                             joints: np.ndarray, norm_limit: float = 0.9, huber_m: float = 0.004,
                             tracker_joints: np.ndarray | None = None, tracker_weight: float = 0.0,
                             prior_weight: float = 1.0, iterations: int = 3, fit_translation: bool = False,
                             translation_weight: float = 1.0) -> list[ArmPose]:
    """Each frame's shoulder rotation (3) and elbow hinge flexion (1) refitted against its own depth points, with the
    rest arm and skeleton held (Gauss-Newton, Huber weights on the point-to-plane pairs as iteratively reweighted
    least squares, re-paired each step); ``fit_translation``: the frame's root translation too.

    Goes beyond the paper: Sec. 6.2 fits the angles once per frame against the ARAP mesh, before the subject's rest
    arm is known; here they are fitted last, on the rest arm and skeleton the sequence stage settled on (Eq. 12 with
    the pose term of Eq. 10), so the angles and the rest arm agree. Each frame's angles are held to their start (the
    sequence fit's, which carries the tracker and the temporal prior) by ``prior_weight`` per coordinate times a
    0.3 m lever, the translation by ``translation_weight`` per coordinate, and the tracker's joints (``tracker_joints``
    (T, 3, 3)) enter at ``tracker_weight`` per coordinate (1 per depth pair). The forearm twist and the wrist are
    held (unobservable, :func:`refine_arm_pose`). The Jacobian is by finite differences of
    :func:`skeleton_model_mesh` on the paired vertices.
    """
    J = np.asarray(joints, np.float64)
    rest = np.asarray(rest, np.float64)
    h, f = elbow_axes(J)
    n_a = 7 if fit_translation else 4
    eps = 1e-6
    prior = np.r_[np.full(4, prior_weight * 0.3 ** 2), np.full(n_a - 4, translation_weight)]
    tracked = [None] * len(poses) if tracker_joints is None or tracker_weight <= 0 else np.asarray(tracker_joints)
    out = []
    for p, fr, tj in zip(poses, frames, tracked, strict=True):
        twist = float(p.angles[1] @ f)
        a0 = np.r_[p.angles[0], p.angles[1] @ h, np.zeros(n_a - 4)]

        def pose_of(a, p=p, twist=twist):
            root = p.root.copy()
            root[:3, 3] += a[4:7] if n_a == 7 else 0.0
            return ArmPose(root, np.vstack([a[:3], elbow_rotvec(J, a[3], twist), p.angles[2]]))

        a = a0.copy()
        for _ in range(iterations):
            pose = pose_of(a)
            M = skeleton_model_mesh(model, pose, rest, J, norm_limit)
            idx, q, nrm = fr.plane_pairs(M)
            H = np.diag(prior)
            g = prior * (a - a0)
            if len(idx):
                r = np.einsum("kd,kd->k", M[idx] - q, nrm)
                w = np.minimum(1.0, huber_m / np.maximum(np.abs(r), 1e-12)) if huber_m > 0 else np.ones(len(r))
                G = np.stack([np.einsum("kd,kd->k", skeleton_model_mesh(model, pose_of(a + eps * e), rest, J,
                                                                        norm_limit)[idx] - M[idx], nrm) / eps
                              for e in np.eye(n_a)], axis=1)
                H += G.T @ (w[:, None] * G)
                g += G.T @ (w * r)
            if tj is not None:
                PJ = posed_joints(J, pose)
                Gj = np.stack([(posed_joints(J, pose_of(a + eps * e)) - PJ).ravel() / eps for e in np.eye(n_a)],
                              axis=1)
                H += tracker_weight * Gj.T @ Gj
                g += tracker_weight * Gj.T @ (PJ - tj).ravel()
            a = a - np.linalg.solve(H, g)
        out.append(pose_of(a))
    return out
