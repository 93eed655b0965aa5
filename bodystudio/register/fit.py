"""Morphable model fitting, §4.3 of Avatar Reshaping (eq. 5): pose θ and shape β of the statistical model.

``argmin_{θ,β} sum_{(a,b) in C} || T(θ, v'_a(β)) - z_b ||^2`` over compatible closest-point pairs (the
normals agree within :data:`COMPATIBLE_COS`), a random subset per iteration (Masuda et al. 1996),
alternating a pose step and a shape step until the error stops improving.

* Pose step: non-linear least squares in the local axis-angle rotations of the body bones and the root
  translation; the residual and its exact Jacobian are casadi functions (casadi plays Ceres' role),
  minimised by Levenberg-Marquardt. The residuals are point-to-plane with a small tangential part
  (:data:`TANGENT_WEIGHT`: a twisting limb slides along itself), plus a range-of-motion prior
  (:data:`POSE_PRIOR_SIGMA`) annealed from :data:`PRIOR_ANNEAL_START` times its weight to 1.
* Shape step: with the bones' posed rotations fixed, every posed vertex and joint is affine in β
  (``T v = sum_j w_j (R_j (v - h_j) + h'_j)`` with rest heads ``h_j`` and posed heads ``h'_j`` both
  linear in β through the model's joint basis), so the step is a Tikhonov-regularised linear least
  squares with the PCA prior ``sum (β_i / σ_i)^2``.
Pairs run both ways (model vertex -> nearest compatible scan vertex, scan vertex -> closest compatible
model point), so holes in the scan and limbs the model misses both pull correctly. The scan -> model
pairs land on the model *surface* (closest point, barycentric in its triangle), not on the nearest model
vertex: the 6k template's vertices are ~2 cm apart and snapping to them pinned the limbs' twist about
their own axes wherever it started (measured: held-out-pose vertex error 20 -> 5-11 mm on A/T scans).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from bodystudio.body import Pose, Skeleton
from bodystudio.body.skinning import forward_kinematics, linear_blend_skinning, skinning_transforms
from bodystudio.errors import InputError
from bodystudio.geometry.mesh import Mesh, vertex_normals
from bodystudio.register.initial_pose import coarse_scan_skeleton, initial_pose

log = logging.getLogger(__name__)

COMPATIBLE_COS = 0.5  # normals within 60 degrees
SAMPLE_FRACTION = 0.1  # Masuda's random tenth
N_SAMPLES = 1500  # fixed size of the casadi residual (pairs drawn per iteration)
SURFACE_PAIRS = True  # scan -> model pairs on the model surface (barycentric), not at its nearest vertex
SURFACE_FROM = 0
# Speed: 40 outer iterations of 4 LM steps on 2 scan samples per model vertex fit the 100K scans as well
# as 8 LM steps on 4 samples (0.9-1.1 mm median) in half the time; the pipeline's restarts use the latter.
MAX_ITERATIONS = 40
# Masuda's random subset is drawn before pairing, not after: pairing all 6k model vertices and 12k scan
# samples to use a tenth of the pairs spent half of the fit's time in KD-tree and closest-point queries.
MODEL_SAMPLE = 1500
CONVERGENCE_WINDOW = 8
SCAN_SAMPLE_PER_MODEL_VERTEX = 2
LM_ITERATIONS = 4
# Pose prior of the LM (a MAP term ``sum (θ_j / σ_j)^2`` weighted by the pairs' residual variance): σ_j is
# the typical range of motion of bone j's local rotation, radians. It only keeps the weakly observed
# directions near rest (the clavicles and spine, which the surface barely sees); the limbs' ranges are wide so
# that the prior does not pull their twist. A uniform 0.05 rad prior pulled the forearms' twist ~15° toward
# rest on random poses (the forearm is nearly a cylinder, so the data hardly resists), which cost ~4 mm of
# held-out-pose error. The root bone is free.
POSE_PRIOR_SIGMA = {"pelvis": 0.3, "spine_01": 0.2, "spine_02": 0.2, "spine_03": 0.2, "neck_01": 0.3, "head": 0.3,
                    "clavicle_l": 0.15, "clavicle_r": 0.15, "upperarm_l": 1.0, "upperarm_r": 1.0,
                    "lowerarm_l": 1.0, "lowerarm_r": 1.0, "hand_l": 0.6, "hand_r": 0.6, "thigh_l": 0.6,
                    "thigh_r": 0.6, "calf_l": 0.6, "calf_r": 0.6, "foot_l": 0.4, "foot_r": 0.4}
TANGENT_WEIGHT = 0.1  # pose step: weight of the pairs' squared tangential residuals (normal part: 1)
PRIOR_ANNEAL_START = 100.0
PRIOR_ANNEAL_RATE = 0.5
RESIDUAL_STD_M = 0.002  # RMS of a converged fit's pair residuals (noise + model mismatch)
FREE_BONES = ("Root", "pelvis", "spine_01", "spine_02", "spine_03", "neck_01", "head", "clavicle_l", "clavicle_r",
              "upperarm_l", "upperarm_r", "lowerarm_l", "lowerarm_r", "hand_l", "hand_r", "thigh_l", "thigh_r",
              "calf_l", "calf_r", "foot_l", "foot_r")


@dataclass(frozen=True, eq=False)
class ModelFit:
    """The fitted morphable model M' = M(θ', β') (eq. 3) and how well it matches the scan."""

    coeffs: np.ndarray  # β'
    pose: Pose  # θ'
    skeleton: Skeleton  # rest skeleton of β'
    rest_vertices: np.ndarray  # V'(β')
    vertices: np.ndarray  # T(θ', V'(β')), the posed model
    faces: np.ndarray
    weights: np.ndarray
    fit_err_mm_median: float  # scan -> model surface distance
    fit_err_mm_p90: float
    iterations: int
    history: tuple[float, ...]

    @property
    def mesh(self) -> Mesh:
        return Mesh(self.vertices, self.faces)


def _rodrigues(ca, r):
    theta = ca.sqrt(ca.dot(r, r) + 1e-16)
    k = r / theta
    K = ca.vertcat(ca.horzcat(0, -k[2], k[1]), ca.horzcat(k[2], 0, -k[0]), ca.horzcat(-k[1], k[0], 0))
    return ca.MX.eye(3) + ca.sin(theta) * K + (1 - ca.cos(theta)) * (K @ K)


@lru_cache(maxsize=8)
def bone_transform_function(parents: tuple[int, ...], free: tuple[int, ...]):
    """casadi ``(x, fixed_rot, C, A_inv) -> (S, dS/dx)``: the skinning transforms ``S_j = M_j A_j^-1`` of all
    bones (rows of the top 3x4 blocks, stacked) and their exact Jacobian w.r.t. the pose parameters.

    ``x`` = free bones' axis-angle (3 each) + root translation; ``C`` stacks ``A_parent^-1 A_j`` (B 4x4
    blocks side by side), ``A_inv`` the inverse rest frames. The residuals of eq. 5 are linear in the
    ``S_j`` (``r_i = sum_j w_ij S_j [v_i; 1] - z_i``), so the chain rule to the residuals is a product.
    """
    import casadi as ca

    B = len(parents)
    x = ca.MX.sym("x", 3 * len(free) + 3)
    fixed = ca.MX.sym("fixed_rot", 3, B)
    C = ca.MX.sym("C", 4, 4 * B)
    A_inv = ca.MX.sym("A_inv", 4, 4 * B)
    slot = {j: i for i, j in enumerate(free)}
    t = x[3 * len(free):]
    M: list = [None] * B
    blocks = []
    for j in range(B):
        r = x[3 * slot[j]: 3 * slot[j] + 3] if j in slot else fixed[:, j]
        Rj = _rodrigues(ca, r)
        L = ca.vertcat(ca.horzcat(Rj, ca.MX.zeros(3, 1)), ca.horzcat(ca.MX.zeros(1, 3), ca.MX.ones(1, 1)))
        Cj = C[:, 4 * j: 4 * j + 4]
        if parents[j] < 0:
            T = ca.vertcat(ca.horzcat(ca.MX.eye(3), t), ca.horzcat(ca.MX.zeros(1, 3), ca.MX.ones(1, 1)))
            M[j] = T @ Cj @ L
        else:
            M[j] = M[parents[j]] @ Cj @ L
        S = M[j] @ A_inv[:, 4 * j: 4 * j + 4]
        blocks.append(ca.vec(S[:3, :].T))  # row-major 3x4
    S_all = ca.vertcat(*blocks)
    return ca.Function("bone_transforms", [x, fixed, C, A_inv], [S_all, ca.jacobian(S_all, x)])


def _frames_blocks(skeleton: Skeleton) -> tuple[np.ndarray, np.ndarray]:
    A = skeleton.rest_frames
    C = np.empty_like(A)
    for j, p in enumerate(skeleton.parents):
        C[j] = A[j] if p < 0 else np.linalg.solve(A[p], A[j])
    A_inv = np.linalg.inv(A)
    return np.concatenate(list(C), axis=1), np.concatenate(list(A_inv), axis=1)


def fit_pose_step(skeleton: Skeleton, pose: Pose, V: np.ndarray, W: np.ndarray, Z: np.ndarray,
                  free: tuple[int, ...], lm_iterations: int | None = None,
                  residual_std_m: float = RESIDUAL_STD_M, prior_scale: float = 1.0,
                  normals: np.ndarray | None = None, tangent_weight: float | None = None) -> Pose:
    """Levenberg-Marquardt on the pose part of eq. 5, exact Jacobian (casadi kinematics + chain rule), with the
    range-of-motion prior :data:`POSE_PRIOR_SIGMA` on the local rotations.

    With the scan ``normals`` at the pairs, the residuals' tangential parts are down-weighted by
    ``tangent_weight`` (point-to-plane, Chen & Medioni): closest-point pairs resist a surface sliding along
    itself as much as moving off it, which froze a limb's twist about its own axis (a near-cylinder slides
    when it twists) wherever the first iterations left it."""
    tangent_weight = TANGENT_WEIGHT if tangent_weight is None else tangent_weight
    lm_iterations = LM_ITERATIONS if lm_iterations is None else lm_iterations
    B = skeleton.n_bones
    f = bone_transform_function(tuple(int(p) for p in skeleton.parents), free)
    C, A_inv = _frames_blocks(skeleton)
    fixed = pose.rotations.T.copy()
    x = np.concatenate([pose.rotations[list(free)].ravel(), pose.translation])
    Vh = np.c_[V, np.ones(len(V))]
    Ws = sp.csr_matrix(np.where(W > 1e-9, W, 0.0))  # a point has a handful of bones: sparse chain rule
    sigma = np.array([POSE_PRIOR_SIGMA.get(skeleton.bone_names[j], np.inf) for j in free])
    reg = prior_scale * np.r_[np.repeat(residual_std_m ** 2 / sigma ** 2, 3), np.zeros(3)]
    if normals is None:
        P = np.broadcast_to(np.eye(3), (len(V), 3, 3))
    else:
        nnT = normals[:, :, None] * normals[:, None, :]
        P = nnT + np.sqrt(tangent_weight) * (np.eye(3) - nnT)

    def cost(xv):
        S, dS = f(xv, fixed, C, A_inv)
        S = np.asarray(S).reshape(B, 3, 4)
        dS = np.asarray(dS).reshape(B, 3, 4, len(xv))
        moved = (Vh @ S.reshape(3 * B, 4).T).reshape(len(W), B, 3)
        r = np.einsum("nij,nj->ni", P, np.einsum("nb,nbi->ni", W, moved) - Z).ravel()
        dSw = (Ws @ dS.reshape(B, -1)).reshape(len(W), 3, 4, len(xv))
        J = np.einsum("nij,njx->nix", P, (dSw * Vh[:, None, :, None]).sum(2)).reshape(-1, len(xv))
        return r, J, float(r @ r + (reg * xv) @ xv)

    r, J, e = cost(x)
    lam = 1e-3
    for _ in range(lm_iterations):
        H = J.T @ J + np.diag(reg)
        g = J.T @ r + reg * x
        step = -np.linalg.solve(H + lam * (np.diag(np.diag(H)) + 1e-9 * np.eye(len(x))), g)
        r2, J2, e2 = cost(x + step)
        if e2 < e:
            x, r, J, e, lam = x + step, r2, J2, e2, lam * 0.3
            if np.linalg.norm(step) < 1e-6:
                break
        else:
            lam *= 10.0
    rot = pose.rotations.copy()
    rot[list(free)] = x[:-3].reshape(-1, 3)
    return Pose(rot, x[-3:].copy())


def posed_affine_in_shape(model, coeffs: np.ndarray, pose: Pose) -> tuple[np.ndarray, np.ndarray]:
    """Posed model vertices ``P0 (n, 3)`` and their exact derivative ``D (n, 3, k)`` w.r.t. β at fixed posed
    bone rotations: ``T v = sum_j w_j (R_j (v - h_j) + h'_j)``, ``h'_j = h'_p + R_p (h_j - h_p)``."""
    sk = model.skeleton(coeffs)
    S = skinning_transforms(sk, pose)
    R = S[:, :3, :3]
    Hb = model.joint_basis_heads.transpose(1, 2, 0)  # (B, 3, k)
    dposed = np.empty_like(Hb)
    for j, p in enumerate(sk.parents):
        dposed[j] = Hb[j] if p < 0 else dposed[p] + R[p] @ (Hb[j] - Hb[p])
    Vb = model.basis.transpose(1, 2, 0)  # (n, 3, k)
    Wm = model.weights
    Ws = sp.csr_matrix(np.where(Wm > 1e-9, Wm, 0.0))  # a vertex has a handful of bones: sparse blends
    B, k = len(R), Hb.shape[2]
    Rblend = (Ws @ R.reshape(B, 9)).reshape(-1, 3, 3)
    offsets = (Ws @ (dposed - np.einsum("bij,bjk->bik", R, Hb)).reshape(B, 3 * k)).reshape(-1, 3, k)
    D = np.einsum("nij,njk->nik", Rblend, Vb) + offsets
    P0 = linear_blend_skinning(model.vertices(coeffs), Wm, S)
    return P0, D


def fit_shape_step(model, coeffs: np.ndarray, pose: Pose, idx: np.ndarray, bary: np.ndarray, Z: np.ndarray,
                   residual_std_m: float = 0.005) -> np.ndarray:
    """The shape part of eq. 5: linear least squares in β at fixed posed rotations, PCA prior.

    The prior is the Gaussian one of the PCA, ``sum (β_i / σ_i)^2``, weighted against the squared
    residuals by the pairs' expected residual variance (``residual_std_m``^2)."""
    P0, D = posed_affine_in_shape(model, coeffs, pose)
    P = np.einsum("nk,nki->ni", bary, P0[idx])
    Dp = np.einsum("nk,nkil->nil", bary, D[idx])  # (s, 3, k)
    A = Dp.reshape(-1, Dp.shape[2])
    b = (Z - P).ravel()
    reg = residual_std_m ** 2 / np.maximum(model.stddev, 1e-9) ** 2
    delta = np.linalg.solve(A.T @ A + np.diag(reg), A.T @ b - reg * coeffs)
    return coeffs + delta


def compatible_pairs(model_V: np.ndarray, model_F: np.ndarray, model_N: np.ndarray, scan_V: np.ndarray,
                     scan_N: np.ndarray, scan_tree: cKDTree, max_dist: float, scan_sample: np.ndarray,
                     k: int = 8, surface: bool = True,
                     model_sample: np.ndarray | None = None
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Compatible closest-point pairs both ways: ``(model triangle corners (s, 3), barycentrics (s, 3),
    scan points (s, 3), their scan vertex indices (s,))``. A pair counts when the normals agree within 60° and
    the points are within ``max_dist``; model vertices (all, or those of ``model_sample``) map to scan
    vertices, scan vertices (``scan_sample``) to the closest compatible point of the model. ``k``: how many nearest
    points each side looks among for a compatible one (1: the nearest only; the fit uses 8)."""
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 1:
        raise InputError(f"compatible_pairs: k = {k!r}; give how many nearest points to look among, an integer >= 1")
    # a list of ranks keeps cKDTree's (n, k) result for k = 1 too (a plain k = 1 gives (n,) and einsum failed, mutZ)
    k = list(range(1, int(k) + 1))
    model_sample = np.arange(len(model_V)) if model_sample is None else model_sample
    d, nn = scan_tree.query(model_V[model_sample], k=k, distance_upper_bound=max_dist)
    ok = np.isfinite(d)
    nn_safe = np.where(ok, nn, 0)
    compat = ok & (np.einsum("nkc,nc->nk", scan_N[nn_safe], model_N[model_sample]) > COMPATIBLE_COS)
    first = np.argmax(compat, axis=1)
    has = compat[np.arange(len(model_sample)), first]
    a1 = model_sample[has]
    b1 = nn_safe[has, first[has]]
    mtree = cKDTree(model_V)
    Zs = scan_V[scan_sample]
    d2, nn2 = mtree.query(Zs, k=k, distance_upper_bound=max_dist)
    ok2 = np.isfinite(d2)
    nn2_safe = np.where(ok2, nn2, 0)
    compat2 = ok2 & (np.einsum("nkc,nc->nk", model_N[nn2_safe], scan_N[scan_sample]) > COMPATIBLE_COS)
    first2 = np.argmax(compat2, axis=1)
    has2 = compat2[np.arange(len(Zs)), first2]
    a2 = nn2_safe[has2, first2[has2]]
    n1 = len(a1)
    corners = np.concatenate([a1, a2])[:, None].repeat(3, axis=1)
    bary = np.zeros((len(corners), 3))
    bary[:, 0] = 1.0
    scan_index = np.concatenate([b1, scan_sample[has2]])
    Z = scan_V[scan_index]
    if surface and len(a2):
        # Scan -> model pairs go to the closest point of the model *surface*, not its nearest vertex: the
        # template's vertices are ~2 cm apart, and snapping to them biases the tangential (twist) direction.
        import igl

        _, tri, Cp = igl.point_mesh_squared_distance(Zs[has2], model_V, model_F)
        T = model_V[model_F[tri]]
        lam = igl.barycentric_coordinates(Cp, T[:, 0].copy(), T[:, 1].copy(), T[:, 2].copy())
        lam = np.clip(np.nan_to_num(lam, nan=1.0 / 3.0), 0.0, 1.0)
        lam /= np.maximum(lam.sum(1, keepdims=True), 1e-12)
        tn = np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0])
        tn /= np.maximum(np.linalg.norm(tn, axis=1, keepdims=True), 1e-12)
        ok_n = np.einsum("nc,nc->n", tn, scan_N[scan_sample][has2]) > COMPATIBLE_COS
        corners[n1:][ok_n] = model_F[tri[ok_n]]
        bary[n1:][ok_n] = lam[ok_n]
    return corners, bary, Z, scan_index


def surface_distance_mm(points: np.ndarray, V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Distance of each point to the triangle mesh (V, F), millimetres."""
    import igl

    d2, _, _ = igl.point_mesh_squared_distance(points, V, F)
    return 1000.0 * np.sqrt(d2)


def fit_model(model, scan: Mesh, max_iterations: int | None = None, seed: int = 0, tolerance: float = 1e-3,
              progress=None, surface_from: int | None = None, scan_sample_factor: int | None = None,
              lm_iterations: int | None = None) -> ModelFit:
    """Fit the statistical model to a canonical scan: initial pose (§4.3), then eq. 5 alternating θ and β."""
    max_iterations = MAX_ITERATIONS if max_iterations is None else max_iterations
    surface_from = SURFACE_FROM if surface_from is None else surface_from
    rng = np.random.default_rng(seed)
    Zv = scan.vertices
    Zn = scan.vertex_normals
    tree = cKDTree(Zv)
    coarse = coarse_scan_skeleton(Zv, scan.faces)
    coeffs = np.zeros(model.n_components)
    # Start from the population's typical body of the scan's stature (scans in A/T pose stand upright).
    if "stature_m" in model.attribute_names and 1.0 < coarse.stature_m < 2.3:
        coeffs = model.attributes_to_coeffs({"stature_m": coarse.stature_m})
    skeleton = model.skeleton(coeffs)
    Vr = model.vertices(coeffs)
    pose = initial_pose(skeleton, model.weights, Vr, Zv, coarse, model.faces, scan.faces)
    names = skeleton.bone_names
    free = tuple(names.index(b) for b in FREE_BONES if b in names)
    F = model.faces
    history: list[float] = []
    factor = SCAN_SAMPLE_PER_MODEL_VERTEX if scan_sample_factor is None else scan_sample_factor
    n_model_sample = min(len(Vr), MODEL_SAMPLE)
    n_scan_sample = min(len(Zv), factor * n_model_sample)
    for it in range(max_iterations):
        skeleton = model.skeleton(coeffs)
        Vr = model.vertices(coeffs)
        posed = linear_blend_skinning(Vr, model.weights, skinning_transforms(skeleton, pose))
        max_dist = max(0.25 * 0.8 ** it, 0.03)
        scan_sample = rng.choice(len(Zv), n_scan_sample, replace=False)
        model_sample = rng.choice(len(Vr), n_model_sample, replace=False)
        corners, bary, Zp, zi = compatible_pairs(posed, F, vertex_normals(posed, F), Zv, Zn, tree, max_dist,
                                                 scan_sample, surface=SURFACE_PAIRS and it >= surface_from,
                                                 model_sample=model_sample)
        if len(Zp) == 0:
            break
        err = float(np.mean(np.sum((np.einsum("nk,nki->ni", bary, posed[corners]) - Zp) ** 2, axis=1)))
        history.append(1000.0 * np.sqrt(err))
        # Converged when the last iterations' mean error no longer improves on that of the ones before: each
        # error is over a fresh random sample of pairs (noise ~0.1 mm), and against the best single one a few
        # lucky samples stopped fits at 24 of 40 iterations.
        w = CONVERGENCE_WINDOW
        if it >= 2 * w and np.mean(history[-w:]) > np.mean(history[-2 * w:-w]) * (1 - tolerance):
            break
        # Masuda: a random tenth of the pairs (at least enough to constrain every limb).
        n_use = min(len(Zp), max(int(SAMPLE_FRACTION * len(Zp)), N_SAMPLES))
        pick = rng.choice(len(Zp), n_use, replace=False)
        V = np.einsum("nk,nki->ni", bary[pick], Vr[corners[pick]])
        W = np.einsum("nk,nkb->nb", bary[pick], model.weights[corners[pick]])
        pose = fit_pose_step(skeleton, pose, V, W, Zp[pick], free, lm_iterations,
                             prior_scale=max(1.0, PRIOR_ANNEAL_START * PRIOR_ANNEAL_RATE ** it), normals=Zn[zi[pick]])
        if it >= 2:
            coeffs = fit_shape_step(model, coeffs, pose, corners[pick], bary[pick], Zp[pick])
        if progress is not None:
            progress(it, history[-1])
    skeleton = model.skeleton(coeffs)
    Vr = model.vertices(coeffs)
    posed = linear_blend_skinning(Vr, model.weights, skinning_transforms(skeleton, pose))
    sample = rng.choice(len(Zv), min(len(Zv), 20000), replace=False)
    d = surface_distance_mm(Zv[sample], posed, F)
    log.info("model fit: %d iterations, median scan-model distance %.2f mm", len(history), np.median(d))
    return ModelFit(coeffs, pose, skeleton, Vr, posed, F, model.weights, float(np.median(d)),
                    float(np.percentile(d, 90)), len(history), tuple(history))


def posed_frames(fit: ModelFit) -> np.ndarray:
    """Posed bone frames ``(B, 4, 4)`` of the fitted model."""
    return forward_kinematics(fit.skeleton, fit.pose)


def rotation_angle_deg(R: np.ndarray) -> np.ndarray:
    return np.degrees(np.linalg.norm(Rotation.from_matrix(R).as_rotvec(), axis=-1))
