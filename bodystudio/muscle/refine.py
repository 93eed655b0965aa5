"""Model-based filtering and surface refinement, Sec. 6.2 and 7 of Arm-Muscle Capture (Robertini et al. 2013).

Model-based filtering projects the ARAP mesh of non-rigid ICP onto the statistical model: the joint
angles come from a per-part orthogonal Procrustes fit (Eq. 11), the shape parameters are fitted once
per sequence, and the model mesh of Eq. 12 (with the 90 % displacement-norm limit) replaces the ARAP
mesh. Refinement then pulls the model mesh towards the depth points with one more ARAP, driven by
correspondences averaged over frames i-1, i, i+1 (Eq. 13-14) and weighted by their agreement with the
vertex normals and the closeness of the vertex to a joint (Sec. 7.2).
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from bodystudio.errors import InputError
from bodystudio.muscle.arm import ArmPose, pose_arm

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
        w = w / w.sum()
        mp, mq = w @ P, w @ Q
        H = ((P - mp) * w[:, None]).T @ (Q - mq)
        U, _, Vt = np.linalg.svd(H)
        D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T)) or 1.0])
        R = Vt.T @ D @ U.T
        T[k, :3, :3] = R
        T[k, :3, 3] = mq - R @ mp
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


def refine_arm_pose(pose: ArmPose, residual_mesh, target: np.ndarray, vertex_weights: np.ndarray,
                    max_nfev: int = 30) -> ArmPose:
    """Twist refinement of Sec. 6.2: Gauss-Newton on the 15 pose coordinates of ``residual_mesh(pose)``.

    The paper refines the Procrustes transforms "iteratively by using the theory of rigid-body motion
    and the twist representation"; we refine the joint angles and root of the model mesh itself
    against ``target`` (weighted per vertex), so the pose that is kept is the one the model needs.
    """
    sw = np.sqrt(np.asarray(vertex_weights, np.float64))[:, None]

    def fun(x):
        return ((residual_mesh(_pose_from_vector(x)) - target) * sw).ravel()

    sol = least_squares(fun, _pose_vector(pose), method="lm", max_nfev=max_nfev, x_scale="jac")
    return _pose_from_vector(sol.x)


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


def fit_shape_parameters(model, meshes: list[np.ndarray], poses: list[ArmPose], vertex_weights: list[np.ndarray],
                         initial=None):
    """Shape parameters (BMI, muscularity, height, arm length) of the sequence, fitted once (Sec. 6.2).

    Least squares of ``model_mesh(model, shape, pose_k) - mesh_k`` over the given frames, each vertex
    weighted by ``vertex_weights`` (the registered, sensor-facing arm vertices), with the poses fixed,
    bounded to twice the model's training range. Returns an ``ArmShapeParams``.
    """
    from bodystudio.muscle.model import ArmShapeParams, model_mesh

    if not meshes:
        raise InputError("fit_shape_parameters needs at least one registered frame")
    lo, hi, x0 = _shape_bounds(model, initial)
    sw = [np.sqrt(w)[:, None] for w in vertex_weights]

    def fun(x):
        shape = ArmShapeParams(*x)
        return np.concatenate([((model_mesh(model, shape, p) - m) * s).ravel()
                               for m, p, s in zip(meshes, poses, sw, strict=True)])

    sol = least_squares(fun, x0, bounds=(lo, hi), x_scale=np.maximum(hi - lo, 1e-3) / 4, max_nfev=40)
    return ArmShapeParams(*sol.x)


def _shape_bounds(model, initial):
    """Bounds and start for the shape fit from the model's training subjects (wide, around their range)."""
    from bodystudio.muscle.model import ArmShapeParams

    keys = ("bmi", "muscularity", "height_m", "arm_length_m")
    defaults = {"bmi": (15.0, 40.0, 23.0), "muscularity": (0.0, 1.0, 0.5), "height_m": (1.4, 2.1, 1.75),
                "arm_length_m": (0.45, 0.9, 0.6)}
    subjects = getattr(model, "subjects", None) or []
    lo, hi, x0 = [], [], []
    for k in keys:
        vals = [float(s[k]) for s in subjects if isinstance(s, dict) and k in s]
        dlo, dhi, d0 = defaults[k]
        if vals:
            span = max(max(vals) - min(vals), 1e-3)
            dlo, dhi, d0 = min(vals) - span, max(vals) + span, float(np.mean(vals))
        if k == "muscularity":
            dlo, dhi = max(dlo, 0.0), min(dhi, 1.0)
        lo.append(dlo)
        hi.append(dhi)
        x0.append(d0)
    if initial is not None:
        x0 = list(np.asarray(ArmShapeParams.as_vector(initial), float))
    lo, hi = np.array(lo), np.array(hi)
    return lo, hi, np.clip(np.array(x0), lo + 1e-9, hi - 1e-9)


def model_based_filtering(model, shape, deformed: np.ndarray, base: np.ndarray, part_weights: np.ndarray,
                          joints: np.ndarray, vertex_weights: np.ndarray, norm_limit: float = 0.9,
                          refine_pose: bool = True) -> tuple[np.ndarray, ArmPose]:
    """Mesh projection of Sec. 6.2: pose by Procrustes (Eq. 11), then the model mesh of Eq. 12.

    ``deformed`` is the ARAP mesh of non-rigid ICP; ``base`` the template's base-pose vertices and
    ``joints`` its rest joints. The Procrustes pose is refined on the model mesh itself (see
    ``refine_arm_pose``); returns the model mesh (with the ``norm_limit`` displacement limit) and the pose.
    """
    from bodystudio.muscle.model import model_mesh

    T = procrustes_part_transforms(base, deformed, part_weights, vertex_weights + 0.05)
    pose = arm_pose_from_part_transforms(T)
    if refine_pose:
        pose = refine_arm_pose(pose, lambda p: model_mesh(model, shape, p, norm_limit=norm_limit), deformed,
                               vertex_weights + 0.05)
    return model_mesh(model, shape, pose, norm_limit=norm_limit), pose


def skin_template(base: np.ndarray, part_weights: np.ndarray, joints: np.ndarray, pose: ArmPose) -> np.ndarray:
    """The template posed by four-part LBS (Eq. 12 without the model's displacements)."""
    return pose_arm(base, part_weights, joints, pose)


# --- Sec. 7 refinement --------------------------------------------------------------------------


def time_consistent_correspondences(vectors: list[np.ndarray], valid: list[np.ndarray],
                                    sigma_frames: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Correspondence vectors averaged over frames i-1, i, i+1 with Gaussian weights, Eq. 13-14.

    ``vectors``/``valid`` hold the (n, 3) correspondence vectors and (n,) validity of frames
    i-1, i, i+1 (pass two at a sequence end, with the current frame first or last as it is). Each
    vertex averages the frames where its pair is valid with ``w_{i+delta} = exp(-delta^2 / 2 sigma^2)``;
    returns the averaged vectors and the vertices valid in the current frame.
    """
    if len(vectors) == 3:
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


def refine_surface(model_vertices: np.ndarray, faces: np.ndarray, vectors: np.ndarray, weights: np.ndarray,
                   data_weight: float = 1.0, iterations: int = 4) -> np.ndarray:
    """The last ARAP deformation of Sec. 7: the model mesh pulled along the weighted, averaged correspondences.

    The model mesh is both the ARAP rest shape and the start, so the refinement adds only the surface
    detail the depth points support (Sec. 7: "slightly beyond the deformation space" of the model).
    """
    from bodystudio.muscle.nicp import arap_deformation, arap_system

    M = np.asarray(model_vertices, np.float64)
    system = arap_system(M, faces)
    return arap_deformation(system, M, M + vectors, weights, data_weight, iterations)
