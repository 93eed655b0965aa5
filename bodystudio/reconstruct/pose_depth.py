"""Depth in the pose refinement (issue 15's neck front): the Kinect's point-to-plane residuals as a data term
of the articulated fit, beside the silhouettes' implicit visual hull.

The refinement (:func:`bodystudio.reconstruct.articulated_fit.refine_bone_transforms`) fits the segments'
rotations to the silhouettes only, and silhouettes do not see a concave front such as the neck under the chin:
the head's and neck's pitch from the tracker's Neck and Head joints (1 cm noise over a 10 cm neck) is left as
it is, and Algorithm 1's smoothness keeps the template's neck where the pose put it (35-45 mm inside the truth on
the walk). The depth map does see that front. Here each template vertex that pairs with a depth pixel (the
projective association of :func:`bodystudio.reconstruct.depth.depth_constraints`, with its reach for the
template's own front surface) adds the residual ``C_d = n . (v - q)`` with gradient ``n`` (our extension of
Rapid Skin §VI to the articulated fit of §IV.A).
"""

from __future__ import annotations

import numpy as np

from bodystudio.reconstruct.depth import DepthObservation, depth_constraints


def depth_data_term(obs: DepthObservation, F: np.ndarray, weight: float = 1.0, robust_m: float = 0.03,
                    sigma_m: float = 0.02, max_distance_m: float = 0.05, reach_m: float = 0.10,
                    reach_sigma_m: float = 0.05, vertices: np.ndarray | None = None):
    """Point-to-plane depth residuals ``C_d = n . (v - q)`` as a ``data_term(V, N) -> (rows, r, w, G)`` of the
    articulated fit: ``G = n`` (the residual's gradient in ``v``), ``w = weight * k * huber(r)`` with the depth
    constraint's own weight ``k`` (Eq. 10's scheme in 3D) and a Huber threshold ``robust_m``. ``vertices`` (a
    boolean mask) keeps only those vertices' rows (:func:`bone_vertices`: the neck and head)."""
    F = np.ascontiguousarray(F, dtype=np.int64)

    def term(V: np.ndarray, N: np.ndarray):
        dc = depth_constraints(V, N, obs, sigma_m, max_distance_m, F=F, reach_m=reach_m, reach_sigma_m=reach_sigma_m)
        if vertices is not None:
            keep = vertices[dc.vertex]
            dc = type(dc)(dc.vertex[keep], dc.point[keep], dc.normal[keep], dc.k[keep])
        r = np.einsum("ij,ij->i", V[dc.vertex] - dc.point, dc.normal)
        a = np.abs(r)
        huber = np.where(a <= robust_m, 1.0, robust_m / np.maximum(a, 1e-12))
        return dc.vertex, r, weight * dc.k * huber, dc.normal

    return term


#: The segments whose vertices' depth residuals the refinement uses by default: the neck and the head, the
#: surface the silhouettes do not place (the whole body's residuals worsened the turn and arm_flex: the depth
#: sensor sees a turning torso's side and the raised arms at grazing angles).
DEPTH_BONES = ("neck_01", "head")


def bone_vertices(body, bones=DEPTH_BONES) -> np.ndarray:
    """Boolean mask of the template vertices whose largest skinning weight is one of ``bones``."""
    names = list(body.skeleton.bone_names)
    ids = [names.index(b) for b in bones]
    return np.isin(np.argmax(body.weights, axis=1), ids)


def combined_data_term(*terms):
    """Several ``data_term(V, N) -> (rows, r, w, G)`` as one (their rows side by side; a vertex may appear in
    more than one)."""

    def term(V: np.ndarray, N: np.ndarray):
        parts = [t(V, N) for t in terms]
        return tuple(np.concatenate([np.asarray(p[i]) if i != 2 else np.broadcast_to(p[2], np.shape(p[1]))
                                     for p in parts]) for i in range(4))

    return term
