"""Refinement of the source body's shape against the person's silhouettes in the init frames (issue 12, MIR12c).

§4 of Real-time Reshaping of Humans fits the shape to the depth point cloud only (Eq. 2, :mod:`mirror.init`). The
Kinect sees the front of the body, and its sides at a grazing angle, so the depth leaves the body's *outline*
loose, and the outline is what the image warp of §5.4 needs: it maps the projected source body onto the projected
target. This optional step (``mirror init --silhouette-shape``) adds the silhouettes of a few init frames: Gauss-Newton
over the statistical model's coefficients ``c`` of

``E(c) = 1/F sum_f [ w_sil (E_out + E_cover) + w_depth E_depth ](c, pose_f) + w_prior sum_i (c_i / sigma_i)^2
+ (stature(c) - stature_0)^2 / s_st^2 + (mass(c) - mass_0)^2 / s_m^2``

with the terms of the pose refinement (:mod:`mirror.refine`) read as functions of the shape: ``E_out`` pulls every
projected body point that lands outside the frame's foreground mask down the mask's distance transform,
``E_cover`` pulls the mask's outline pixels onto the nearest projected rim vertex (along the rim's image normal),
``E_depth`` is the point-to-plane distance of the depth points to their nearest vertex facing the sensor (Eq. 2 in
the posed frame). Before every step each frame's pose is re-estimated for the current shape (the IK of §5.2 on its
skeleton, then :func:`mirror.refine.refine_pose`), and within the step each frame's pose change (root and swings,
the parameters of ``refine_pose``) is solved *jointly* with the shape and eliminated by its Schur complement:
re-posing alone lets the pose absorb the shape's error (a planted 20 mm shape error: 17 mm after three steps
without the joint solve, 5 mm with it). The stature and the mass of the depth and joint fit are held (the
silhouette sees neither the body's thickness nor, with the pose free, its height reliably: without the holds the
sessions' bodies came out 1-2 kg lighter and up to 10 mm shorter). The derivatives of the posed vertices with
respect to ``c`` (vertices *and* joints move with the coefficients) are finite differences of the skinning, taken
only for the vertices that carry a residual; the mass's is the divergence theorem's.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from bodystudio.body.skinning import skinning_transforms
from bodystudio.body.statistical import StatisticalBodyModel
from bodystudio.geometry.camera import pinhole_projection_jacobian
from bodystudio.geometry.mesh import vertex_normals
from bodystudio.mirror.refine import (
    RIM_COS,
    _sample,
    mask_outline,
    nearest_within,
    refine_plan,
    refine_pose,
    silhouette_distance,
)
from bodystudio.mirror.track import ik_pose, skin_vertices

log = logging.getLogger(__name__)

#: Gauss-Newton steps of the shape (each after re-estimating every frame's pose).
SHAPE_ITERATIONS = 3
#: Every ``VERTEX_STRIDE``-th vertex enters E_out and E_depth.
VERTEX_STRIDE = 2


@dataclass(frozen=True)
class ShapeWeights:
    """Residual scales (a residual divided by its scale counts 1) and term weights of the shape energy."""

    sil_px: float = 2.0
    depth_m: float = 0.01
    sil_weight: float = 1.0
    depth_weight: float = 1.0
    prior: float = 0.005  # weight of (c_i / sigma_i)^2 against one frame's normalised data terms (their mean)
    stature_mm: float = 2.0  # the stature (the model's linear map) may leave the start's by about this (0: free)
    mass_kg: float = 0.3  # the same for the mass (enclosed volume x density; 0: free)
    min_facing_cos: float = 0.26  # vertices seen more obliquely take no depth points (mirror.init.INIT_FACING_COS)
    sil_samples: int = 800  # mask outline pixels of E_cover per frame
    depth_samples: int = 600  # depth points of E_depth per frame
    joint_pose: bool = True  # each frame's pose change (root, swings) solved jointly with the shape step
    pose_prior_m: float = 1.0  # damping of the frames' pose change in the joint step (refine_pose's prior)
    pose_prior_rad: float = 3.0
    max_step_sigma: float = 1.0  # a step changes no coefficient by more than this many population sigmas


@dataclass(frozen=True, eq=False)
class SilhouetteView:
    """One init frame for the shape refinement: the person's foreground in the colour image and the frame's data."""

    foreground: np.ndarray  # (H, W) bool, the refined foreground (graph cut) of the player
    others: np.ndarray | None  # (H, W) bool, other players' pixels (a body point there may be occluded)
    points: np.ndarray  # (N, 3) the player's depth points, studio frame
    joints: np.ndarray  # (J, 3) Kinect joints
    tracked: np.ndarray  # (J,)
    version: str


def posed_shape_jacobian(model: StatisticalBodyModel, coeffs: np.ndarray, pose, ids: np.ndarray,
                         step: float = 1e-3) -> tuple[np.ndarray, np.ndarray]:
    """Posed vertices ``ids`` of the shape ``coeffs`` under ``pose`` (n, 3) and their derivative with respect to
    the coefficients (n, 3, k): forward differences of step ``step`` sigma per coefficient, the vertices and the
    skeleton (the pose's local rotations and root translation held) moving together."""
    c = np.asarray(coeffs, float)
    V_rest = model.vertices(c)
    V0 = skin_vertices(V_rest, model.weights, model.skeleton(c), pose, subset=ids)
    J = np.empty((len(ids), 3, len(c)))
    for k in range(len(c)):
        h = step * model.stddev[k]
        ck = c.copy()
        ck[k] += h
        T = skinning_transforms(model.skeleton(ck), pose)
        Vk = skin_vertices(V_rest + h * model.basis[k], model.weights, None, None, subset=ids, transforms=T)
        J[:, :, k] = (Vk - V0) / h
    return V0, J


def pose_jacobian(plan, skeleton, pose, V: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """(n, 3, 6 + 2S) derivative of posed vertices ``V`` (skin weights ``weights`` (n, B)) with respect to the pose
    parameters of :func:`mirror.refine.refine_pose`: root translation, root rotation (about its head), two swing
    angles per plan bone: ``s_j(v) e x (v - h_j)``, ``s_j`` the vertex's weight on bone ``j``'s subtree."""
    from bodystudio.mirror.refine import _bone_frames, _descendants, _forward_kinematics

    M, _ = _forward_kinematics(plan, skeleton.parents, pose)
    _, heads, axes = _bone_frames(M, np.ascontiguousarray(skeleton.rest_rotations), plan.bones)
    parents = np.asarray(skeleton.parents)
    inside = np.stack([_descendants(parents, j) for j in plan.bones], axis=1).astype(float)
    s = np.asarray(weights, float) @ inside  # (n, 1 + S)
    n, S = len(V), len(plan.bones) - 1
    J = np.zeros((n, 3, 6 + 2 * S))
    J[:, :, :3] = s[:, 0, None, None] * np.eye(3)
    d = V - heads[0]
    for a in range(3):
        e = np.zeros(3)
        e[a] = 1.0
        J[:, :, 3 + a] = s[:, 0, None] * np.cross(e, d)
    for b in range(S):
        d = V - heads[b + 1]
        for a in range(2):
            J[:, :, 6 + 2 * b + a] = s[:, b + 1, None] * np.cross(axes[b, a], d)
    return J


def mass_and_gradient(model: StatisticalBodyModel, coeffs: np.ndarray) -> tuple[float, np.ndarray]:
    """Mass (kg, the enclosed volume of the template's surface x the body density of ``body.measure``; the open
    boundary loops are not closed, a constant offset) of the shape ``coeffs`` and its gradient (k,): the volume's
    derivative by a face's vertex is a sixth of the cross product of the other two (divergence theorem)."""
    from bodystudio.body.measure import BODY_DENSITY_KG_M3

    V, F = model.vertices(coeffs), model.faces
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    volume = np.einsum("ij,ij->", a, np.cross(b, c)) / 6.0
    dV = np.zeros_like(V)
    np.add.at(dV, F[:, 0], np.cross(b, c))
    np.add.at(dV, F[:, 1], np.cross(c, a))
    np.add.at(dV, F[:, 2], np.cross(a, b))
    grad = np.einsum("nd,knd->k", dV / 6.0, model.basis)
    return BODY_DENSITY_KG_M3 * volume, BODY_DENSITY_KG_M3 * grad



def silhouette_shape_rows(model: StatisticalBodyModel, coeffs: np.ndarray, pose, camera, view: SilhouetteView,
                          weights: ShapeWeights = ShapeWeights(), seed: int = 0,
                          plan=None) -> tuple[np.ndarray, np.ndarray]:
    """Rows ``A`` (m, k) and residuals ``r`` (m,) of one frame's E_out, E_cover and E_depth, linearised in the
    coefficients at ``coeffs`` (each term normalised by its sample count, as in :func:`mirror.refine.refine_pose`).
    """
    rng = np.random.default_rng(seed)
    V_rest = model.vertices(coeffs)
    sk = model.skeleton(coeffs)
    V = skin_vertices(V_rest, model.weights, sk, pose)
    N = vertex_normals(V, model.faces)
    uv, _ = camera.project_with_depth(V)
    ray = V - camera.center
    cos = np.einsum("ij,ij->i", N, ray) / np.linalg.norm(ray, axis=1)
    with np.errstate(invalid="ignore"):
        ok = (uv[:, 0] >= 1) & (uv[:, 0] <= camera.width - 2) & (uv[:, 1] >= 1) & (uv[:, 1] <= camera.height - 2)
    fg = np.asarray(view.foreground, bool)
    allowed = fg if view.others is None else fg | view.others
    dist, origin = silhouette_distance(allowed, 40)
    subset = np.zeros(len(V), bool)
    subset[::VERTEX_STRIDE] = True
    # E_out: body points projecting outside the silhouette
    local = uv - origin
    with np.errstate(invalid="ignore"):
        in_box = np.flatnonzero(subset & ok & (local[:, 0] >= 1) & (local[:, 1] >= 1)
                                & (local[:, 0] < dist.shape[1] - 2) & (local[:, 1] < dist.shape[0] - 2))
    # (none inside the box, or none of them outside the mask: no E_out rows; OpenCV cannot sample zero points)
    d = _sample(dist, local[in_box]) if len(in_box) else np.zeros(0)
    out = in_box[d > 0.5]
    d_out = np.minimum(d[d > 0.5], 30.0)
    grad = np.zeros((0, 2))
    if len(out):
        steps = np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]])
        around = _sample(dist, (local[out][None] + steps[:, None]).reshape(-1, 2)).reshape(4, -1)
        grad = np.c_[around[0] - around[1], around[2] - around[3]] / 2.0
    # E_cover: outline pixels onto the nearest projected rim vertex, along the rim's image normal
    outline = mask_outline(fg, view.others)
    if len(outline) > weights.sil_samples:
        outline = outline[rng.choice(len(outline), weights.sil_samples, replace=False)]
    rim = np.flatnonzero(ok & (np.abs(cos) < RIM_COS))
    cover_ids, cover_px = np.zeros(0, int), np.zeros((0, 2))
    if len(rim) >= 3 and len(outline):
        dd, nearest = nearest_within(uv[rim], outline, 25.0)
        keep = np.isfinite(dd)
        cover_ids, cover_px = rim[nearest[keep]], outline[keep]
    # E_depth: point-to-plane to the nearest front-facing vertex within 5 cm
    depth_ids, depth_pts = np.zeros(0, int), np.zeros((0, 3))
    pts = np.asarray(view.points, float)
    if len(pts) > weights.depth_samples:
        pts = pts[rng.choice(len(pts), weights.depth_samples, replace=False)]
    front = np.flatnonzero(subset & (cos < -weights.min_facing_cos))
    if len(pts) and len(front):
        dd, nearest = nearest_within(V[front], pts, 0.05)
        keep = np.isfinite(dd)
        depth_ids, depth_pts = front[nearest[keep]], pts[keep]
    ids, inverse = np.unique(np.r_[out, cover_ids, depth_ids], return_inverse=True)
    k = model.n_components + (0 if plan is None else 4 + 2 * len(plan.bones))
    if not len(ids):
        return np.zeros((0, k)), np.zeros(0)
    Vi, Ji = posed_shape_jacobian(model, coeffs, pose, ids)
    if plan is not None:  # the pose's columns: root translation and rotation, two swings per plan bone (MIR12b)
        Ji = np.concatenate([Ji, pose_jacobian(plan, sk, pose, Vi, model.weights[ids])], axis=2)
    Ji_uv = pinhole_projection_jacobian(camera, Vi, Ji)
    a, b = 0, len(out)
    rows, res = [], []
    n_sil = max(len(out), len(outline), 1)
    s = weights.sil_weight ** 0.5 / (weights.sil_px * n_sil ** 0.5)
    if len(out):
        rows.append(s * np.einsum("nd,ndk->nk", grad, Ji_uv[inverse[a:b]]))
        res.append(s * d_out)
    a, b = b, b + len(cover_ids)
    if len(cover_ids):
        # the rim's image normal: the projection of its 3D normal, a pixel step
        n2 = camera.project(V[cover_ids] + 0.01 * N[cover_ids]) - uv[cover_ids]
        n2 /= np.maximum(np.linalg.norm(n2, axis=1, keepdims=True), 1e-12)
        s = weights.sil_weight ** 0.5 / (weights.sil_px * max(len(outline), 1) ** 0.5)
        rows.append(s * np.einsum("nd,ndk->nk", n2, Ji_uv[inverse[a:b]]))
        res.append(s * np.einsum("nd,nd->n", n2, uv[cover_ids] - cover_px))
    a, b = b, b + len(depth_ids)
    if len(depth_ids):
        n3 = N[depth_ids]
        s = weights.depth_weight ** 0.5 / (weights.depth_m * len(pts) ** 0.5)
        rows.append(s * np.einsum("nd,ndk->nk", n3, Ji[inverse[a:b]]))
        res.append(s * np.einsum("nd,nd->n", n3, V[depth_ids] - depth_pts))
    return np.concatenate(rows), np.concatenate(res)


def frame_pose(model: StatisticalBodyModel, coeffs: np.ndarray, camera, view: SilhouetteView, previous=None,
               plan=None):
    """The pose of ``view`` for the shape ``coeffs``: the IK (§5.2) on its skeleton, refined against the frame's
    silhouette, depth and joints (:func:`mirror.refine.refine_pose`, two steps)."""
    sk = model.skeleton(coeffs)
    pose = ik_pose(sk, view.joints, view.tracked, view.version, previous=previous)
    if plan is None:
        plan = refine_plan(model.vertices(coeffs), model.faces, model.weights, sk, view.version)
    return refine_pose(plan, sk, pose, camera, view.foreground, view.joints, view.tracked, view.points, view.others,
                       view.version, iterations=2)


def refine_shape_to_silhouettes(model: StatisticalBodyModel, coeffs: np.ndarray, views, camera,
                                iterations: int = SHAPE_ITERATIONS,
                                weights: ShapeWeights = ShapeWeights()) -> np.ndarray:
    """The coefficients ``coeffs`` (the depth fit of Eq. 2) refined against the silhouettes and depth of ``views``
    (:class:`SilhouetteView`, one per init frame) by ``iterations`` Gauss-Newton steps of the module's energy.

    Before each step every frame's pose is re-estimated for the current shape (:func:`frame_pose`); within the
    step each frame's pose change is solved jointly with the shape (``weights.joint_pose``) and eliminated; the
    start's stature and mass are held (``weights.stature_mm``, ``weights.mass_kg``; 0 frees them); no
    coefficient moves by more than ``weights.max_step_sigma`` population sigmas per step."""
    c = np.asarray(coeffs, float).copy()
    views = list(views)
    if not views:
        return c
    sigma = model.stddev
    c0 = c.copy()
    stature = model.coeffs_to_attribute_map[:-1, model.attribute_names.index("stature_m")] if weights.stature_mm \
        else None
    mass0 = mass_and_gradient(model, c0)[0] if weights.mass_kg else None
    poses: list = [None] * len(views)
    for it in range(max(0, int(iterations))):
        plan = refine_plan(model.vertices(c), model.faces, model.weights, model.skeleton(c), views[0].version)
        H = np.zeros((len(c), len(c)))
        g = np.zeros(len(c))
        for f, view in enumerate(views):
            poses[f] = frame_pose(model, c, camera, view, previous=poses[f], plan=plan)
            A, r = silhouette_shape_rows(model, c, poses[f], camera, view, weights, seed=f,
                                         plan=plan if weights.joint_pose else None)
            k = len(c)
            Ac, Ap = A[:, :k], A[:, k:]
            H_f, g_f = Ac.T @ Ac, Ac.T @ r
            if weights.joint_pose:  # the frame's pose change eliminated (Schur complement): shape and pose jointly
                damping = np.r_[np.full(3, weights.pose_prior_m ** -2),
                                np.full(Ap.shape[1] - 3, weights.pose_prior_rad ** -2)]
                X = np.linalg.solve(Ap.T @ Ap + np.diag(damping), Ap.T @ np.c_[Ac, r])
                H_f -= (Ac.T @ Ap) @ X[:, :k]
                g_f -= (Ac.T @ Ap) @ X[:, k]
            H += H_f / len(views)
            g += g_f / len(views)
        H[np.diag_indices(len(c))] += weights.prior / sigma**2
        g += weights.prior * c / sigma**2
        if stature is not None:  # the stature of the depth and joint fit is held (the silhouette alone shrinks it)
            w = 1.0 / (1e-3 * weights.stature_mm) ** 2
            H += w * np.outer(stature, stature)
            g += w * stature * (stature @ (c - c0))
        if weights.mass_kg:  # the mass of the depth fit is held: the silhouette sees no thickness
            mass, grad = mass_and_gradient(model, c)
            w = 1.0 / weights.mass_kg ** 2
            H += w * np.outer(grad, grad)
            g += w * grad * (mass - mass0)
        delta = -np.linalg.solve(H, g)
        largest = np.max(np.abs(delta) / sigma)
        if largest > weights.max_step_sigma:
            delta *= weights.max_step_sigma / largest
        c = c + delta
        log.debug("shape step %d: largest change %.2f sigma", it, largest)
    return c
