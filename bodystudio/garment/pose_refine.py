"""The per-frame poses of §4.4 (Eq. 4-6) refined once more after the shape refinement, with the rim-based
silhouette term of step 4b.

The pose step (§4.4) tracks every frame's pose on the body of §4.3's Nelder-Mead shape, with the distance form of
Eq. 2; step 4b then changes that shape with the poses held (:mod:`bodystudio.garment.shape_refine`). The poses
were therefore fitted to another body, and the distance form prefers a body too large in the image (any vertex
covers an outline sample), which a pose can get by stepping towards the camera or spreading the limbs. Here each
frame's pose is refined on the refined body by Gauss-Newton with:

* Eq. 2 with the rim, as step 4b (``shape_refine.silhouette_rows``: vertices outside the matte along the distance
  field's gradient, each outline sample against the nearest rim vertex along its image normal, the rim pushed
  out by the clothing allowance), linearised in the pose parameters;
* Eq. 5's temporal term against both neighbours (the clip is known now; each at half of ``beta``, so a frame
  between two neighbours is pulled as strongly as the tracked frame was by one), the neighbours held at their
  values of the previous sweep;
* Eq. 6's interpenetration term and our anatomical prior, exactly as in the pose step
  (:func:`bodystudio.garment.fit.pose_residuals`).

The parameters are the pose step's (:class:`bodystudio.garment.fit.PoseSpace`: the global rotation, the
translation and the fitted bones); the other bones keep their values.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

log = logging.getLogger(__name__)

#: Gauss-Newton steps per frame and sweep of the pose refinement.
POSE_REFINE_STEPS = 3
#: Sweeps over the clip (each frame sees its neighbours' poses of the previous sweep). Hidden subjects 37 / 21 / 3,
#: garment_iou after §7: 2 sweeps 0.955 / 0.935 / 0.925, 4 sweeps 0.956 / 0.935 / 0.929, 6 sweeps 0.956 / 0.935 / -
#: (docs/garment.md).
POSE_REFINE_SWEEPS = 4
#: Finite-difference step of the pose parameters (rad for rotations, m for the translation).
POSE_FD_STEP = 1e-3
#: No rotation parameter moves by more than this (rad), the translation by more than a tenth of it (m), per step.
MAX_POSE_STEP = 0.1


@dataclass(frozen=True)
class PoseRefinement:
    """The refined per-frame pose parameters ``X`` (n, k) of the :class:`PoseSpace` and each frame's energy
    before and after (``energies`` (n, 2))."""

    X: np.ndarray
    energies: np.ndarray


def _other_residuals(x: np.ndarray, space, spheres, camera, neighbours: list[np.ndarray]) -> np.ndarray:
    """Eq. 5 against each neighbour (half ``beta`` each when there are two), Eq. 6 and the anatomical prior,
    weighted as in :func:`bodystudio.garment.fit.pose_residuals`."""
    from bodystudio.garment.fit import (
        BETA_TEMPORAL,
        GAMMA_INTERPENETRATION,
        interpenetration_residuals,
        pose_prior_residuals,
        temporal_residuals,
    )

    beta = BETA_TEMPORAL / max(len(neighbours), 1)
    parts = [temporal_residuals(x, nb, beta=beta) for nb in neighbours]
    parts.append(pose_prior_residuals(x, space))
    T = space.transforms(x)
    centre = space.vertices(x, space.sample_ids, T).mean(0, keepdims=True)
    px_per_m = camera.fx / max(float(camera.world_to_camera(centre)[0, 2]), 0.1)
    depth = interpenetration_residuals(space.vertices(x, spheres.probe_ids, T), T, spheres)
    parts.append(np.sqrt(GAMMA_INTERPENETRATION) * px_per_m * depth / np.sqrt(len(spheres.probe_ids)))
    return np.concatenate(parts)


def pose_refinement_energy(x: np.ndarray, space, spheres, camera, target, neighbours: list[np.ndarray],
                           allowance_m) -> float:
    """One frame's energy: the rim-based Eq. 2 of step 4b plus :func:`_other_residuals`, squared and summed."""
    from bodystudio.garment.shape_refine import silhouette_rows
    from bodystudio.geometry.mesh import vertex_normals

    V = space.vertices(x)
    N = vertex_normals(V, space.body.faces)
    r = silhouette_rows(V, N, None, camera, target, allowance_m)[1]
    return float(np.sum(r ** 2) + np.sum(_other_residuals(x, space, spheres, camera, neighbours) ** 2))


def refine_frame_pose(x0: np.ndarray, space, spheres, camera, target, neighbours: list[np.ndarray],
                      allowance_m, steps: int = POSE_REFINE_STEPS) -> tuple[np.ndarray, float, float]:
    """Levenberg-damped Gauss-Newton on one frame's pose from ``x0``: the silhouette rows linearised with the
    posed vertices' finite-difference Jacobian, the other terms with their own. A step is kept only if it lowers
    :func:`pose_refinement_energy`. Returns ``(x, energy before, energy after)``."""
    from bodystudio.garment.shape_refine import silhouette_rows
    from bodystudio.geometry.mesh import vertex_normals

    x = np.asarray(x0, dtype=np.float64).copy()
    k = len(x)
    limit = np.full(k, MAX_POSE_STEP)
    limit[3:6] = 0.1 * MAX_POSE_STEP
    energy = start = pose_refinement_energy(x, space, spheres, camera, target, neighbours, allowance_m)
    damping = 1e-3
    for _ in range(max(0, int(steps))):
        V = space.vertices(x)
        N = vertex_normals(V, space.body.faces)
        r_other = _other_residuals(x, space, spheres, camera, neighbours)
        J = np.empty((len(V), 3, k))
        J_other = np.empty((len(r_other), k))
        for j in range(k):
            q = x.copy()
            q[j] += POSE_FD_STEP
            J[:, :, j] = (space.vertices(q) - V) / POSE_FD_STEP
            J_other[:, j] = (_other_residuals(q, space, spheres, camera, neighbours) - r_other) / POSE_FD_STEP
        A, r = silhouette_rows(V, N, J, camera, target, allowance_m)
        H = A.T @ A + J_other.T @ J_other
        g = A.T @ r + J_other.T @ r_other
        accepted = False
        for _ in range(4):
            delta = -np.linalg.solve(H + damping * np.diag(np.diag(H) + 1e-9), g)
            over = np.max(np.abs(delta) / limit)
            if over > 1.0:
                delta /= over
            e = pose_refinement_energy(x + delta, space, spheres, camera, target, neighbours, allowance_m)
            if e < energy:
                x, energy, accepted = x + delta, e, True
                damping = max(damping / 3.0, 1e-6)
                break
            damping *= 10.0
        if not accepted:
            break
    return x, start, energy


def refine_poses_to_silhouettes(body, poses, masks, camera, allowance_m, sweeps: int = POSE_REFINE_SWEEPS,
                                steps: int = POSE_REFINE_STEPS) -> tuple[list, PoseRefinement]:
    """Every frame's pose refined on ``body`` (the refined shape) against its matte: ``sweeps`` passes over the
    clip, each frame by :func:`refine_frame_pose` with its neighbours held at the previous pass's poses.

    ``poses``: the tracked :class:`bodystudio.body.pose.Pose` per frame (their non-fitted bones are kept).
    Returns the refined poses and a :class:`PoseRefinement`."""
    from bodystudio.body.pose import Pose
    from bodystudio.garment.fit import penetration_spheres, pose_space, silhouette_target

    poses = list(poses)
    space = pose_space(body)
    spheres = penetration_spheres(body)
    targets = [silhouette_target(m) for m in masks]
    X = np.stack([space.x_from_pose(p) for p in poses])
    n = len(poses)
    energies = np.zeros((n, 2))
    for sweep in range(max(0, int(sweeps))):
        previous = X.copy()
        for i in range(n):
            neighbours = [previous[j] for j in (i - 1, i + 1) if 0 <= j < n]
            X[i], e0, e1 = refine_frame_pose(X[i], space, spheres, camera, targets[i], neighbours, allowance_m, steps)
            if sweep == 0:
                energies[i, 0] = e0
            energies[i, 1] = e1
        log.info("pose refinement sweep %d: mean energy %.4f", sweep + 1, energies[:, 1].mean())
    out = []
    for p, x in zip(poses, X, strict=True):
        rot = np.asarray(p.rotations, dtype=np.float64).copy()
        fitted = space.pose(x)
        ids = np.r_[body.skeleton.index("Root"), space.bone_ids]
        rot[ids] = np.asarray(fitted.rotations)[ids]
        out.append(Pose(rot, np.asarray(fitted.translation, dtype=np.float64)))
    return out, PoseRefinement(X, energies)
