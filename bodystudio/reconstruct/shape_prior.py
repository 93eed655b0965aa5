"""A body-shape prior for the surfaces no view sees (issue 15's crotch, neck and lower back).

Rapid Skin's smoothness constraints (Eq. 9) keep the delta coordinates (Eq. 8) of the posed generic
template wherever no silhouette or depth constraint reaches, so there the result is the template's shape:
the crotch under the fitted pelvis, the chin crease, the lumbar curve behind a hanging arm. The statistical
body model (:mod:`bodystudio.body.statistical`, the PCA shape space of Avatar Reshaping §4.1 / Real-time
Reshaping §3) couples those surfaces to the ones the cameras do see. Here the deformed mesh of a first pass
is brought back to the rest pose with the frame's bone transforms (the inverse of Eq. 12), the shape space's
coefficients are fitted to it by robust, ridge-regularised least squares (:func:`fit_shape_coefficients`),
and the fitted shape, posed with the same transforms (Eq. 12), is both the start and the smoothness
reference of a second pass of Algorithm 1 (:func:`shape_prior_mesh`; ``shape_prior="frame"`` of
:func:`bodystudio.reconstruct.sequence.reconstruct_session`). With ``shape_prior="run"`` the first frame
does so and every later frame starts from (and is regularised towards) the mean of the coefficients fitted
to the frames before it, in one pass: the subject's shape does not change over a run.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from bodystudio.errors import InputError
from bodystudio.reconstruct.pose_init import pose_template, unpose


def fit_shape_coefficients(model, rest_vertices: np.ndarray, ridge: float = 1e-4, robust_m: float = 0.02,
                           iterations: int = 3) -> np.ndarray:
    """Shape-space coefficients ``c`` of ``rest_vertices`` ``(n, 3)``: min sum_i w_i |v_i - (mean + B c)_i|^2
    + ridge sum_k (c_k / sigma_k)^2, the PCA space of Avatar Reshaping §4.1 (Eq. 1 there, ``M = M_mean +
    sum beta_k B_k``) with each component's population spread ``sigma_k`` as its prior.

    Vertices off by more than ``robust_m`` after a fit get the weight ``robust_m / d`` in the next of the
    ``iterations`` (Huber's), so the regions a first deformation got wrong (the crotch it did not see,
    fingers it matched to the next finger) do not bend the whole body's shape towards them.
    """
    V = np.asarray(rest_vertices, dtype=np.float64)
    if V.shape != model.mean.shape:
        raise InputError(f"shape prior: {V.shape} vertices for a {model.resolution} shape space of "
                         f"{model.mean.shape[0]}; use the template of the shape space's resolution")
    B = model.basis.reshape(model.n_components, -1).T  # (3n, k)
    y = (V - model.mean).ravel()
    prior = ridge / np.square(model.stddev)
    w = np.ones(len(V))
    c = np.zeros(model.n_components)
    for _ in range(max(1, int(iterations))):
        wr = np.repeat(w, 3)
        c = np.linalg.solve(B.T @ (wr[:, None] * B) + np.diag(prior), B.T @ (wr * y))
        d = np.linalg.norm((y - B @ c).reshape(-1, 3), axis=1)
        w = np.minimum(1.0, robust_m / np.maximum(d, 1e-12))
    return c


def deformed_shape_coefficients(model, body, deformed: np.ndarray, bone_transforms: np.ndarray,
                                ridge: float = 1e-4, robust_m: float = 0.02) -> np.ndarray:
    """Shape-space coefficients of a deformed mesh: Algorithm 1's result for the template ``body`` posed by
    ``bone_transforms`` (Eq. 12), un-skinned with them and fitted by :func:`fit_shape_coefficients`."""
    rest = unpose(np.asarray(deformed, dtype=np.float64), body.weights, bone_transforms)
    return fit_shape_coefficients(model, rest, ridge, robust_m)


def region_shape(model, body, coeffs: np.ndarray, region_weights: np.ndarray | None = None) -> np.ndarray:
    """The rest shape the prior poses: the shape space's ``coeffs`` where ``region_weights`` ``(n,)`` is 1, the
    template ``body``'s own rest shape where it is 0, blended between (None: the shape space's everywhere)."""
    shape = model.vertices(coeffs)
    if region_weights is None:
        return shape
    w = np.asarray(region_weights, dtype=np.float64)[:, None]
    return body.vertices + w * (shape - body.vertices)


def region_blend_weights(body, regions: np.ndarray, names: tuple[str, ...], falloff_rings: int = 4) -> np.ndarray:
    """Per-vertex weight ``(n,)`` of the shape prior restricted to the ``regions`` named ``names``
    (:func:`bodystudio.reconstruct.evaluate.vertex_regions`' labels, and ``lower_torso``: the torso's vertices
    below the top of the ``spine_02`` bone in the rest pose): 1 inside, falling to 0 over ``falloff_rings`` rings
    of the mesh outside (the region's mean over each vertex's one-ring, repeated), so the blended rest shape has
    no step at the region's border for the smoothness constraints (Eq. 9) to keep."""
    regions = np.asarray(regions, dtype=object)
    inside = np.zeros(len(regions), dtype=bool)
    for name in names:
        if name == "lower_torso":
            skel = body.skeleton
            top = skel.tails[skel.bone_names.index("spine_02")][1]
            inside |= (regions == "torso") & (body.vertices[:, 1] < top)
        else:
            inside |= regions == name
    A = one_ring(body.faces, len(regions))
    mean = sp.diags(1.0 / np.asarray(A.sum(axis=1)).ravel()) @ A
    w = inside.astype(np.float64)
    for _ in range(int(falloff_rings)):
        w = np.maximum(mean @ w, inside)
    return w


#: The bones whose skin is the middle of the back (rec15p: where turn 66's and the walks' maxima sit).
BACK_BONES = ("spine_02", "spine_03")


def back_patch(body) -> np.ndarray:
    """Boolean ``(n,)``: the template's middle of the back, the vertices skinned mostly to :data:`BACK_BONES` whose
    rest-pose normal faces backwards (``n_z < -0.5``; the rest pose faces +z). The surface where the walks'
    side-view rims carry the back out and a stout subject's back, reached by no rim, stays inside (issue 15,
    rec15p / rec15q)."""
    import igl

    names = body.skeleton.bone_names
    dominant = np.argmax(body.weights, axis=1)
    N = igl.per_vertex_normals(np.asarray(body.vertices, dtype=np.float64), np.asarray(body.faces))
    return np.isin(dominant, [names.index(b) for b in BACK_BONES if b in names]) & (N[:, 2] < -0.5)


def rim_reach(silhouette_vertices: np.ndarray | None, patch: np.ndarray) -> float:
    """The share (0..1) of the ``patch``'s vertices that have a silhouette constraint (Rapid Skin Eq. 10's rim
    pairs, ``silhouette_vertices`` of the deformation's last outer iteration): how much of it the rims reach."""
    n = int(np.count_nonzero(patch))
    if n == 0 or silhouette_vertices is None:
        return 0.0
    hit = np.zeros(len(patch), dtype=bool)
    hit[np.asarray(silhouette_vertices, dtype=np.int64)] = True
    return float(np.count_nonzero(hit & patch)) / n


def one_ring(faces: np.ndarray, n_vertices: int) -> sp.csr_matrix:
    """``(n, n)`` 0/1 adjacency of the mesh's edges with the diagonal set (each vertex and its one-ring)."""
    F = np.asarray(faces)
    i = np.concatenate([F[:, 0], F[:, 1], F[:, 2]])
    j = np.concatenate([F[:, 1], F[:, 2], F[:, 0]])
    A = sp.coo_matrix((np.ones(2 * len(i)), (np.concatenate([i, j]), np.concatenate([j, i]))),
                      shape=(n_vertices, n_vertices)).tocsr()
    A = A + sp.identity(n_vertices, format="csr")
    A.data[:] = 1.0
    return A


def posed_shape(model, body, coeffs: np.ndarray, bone_transforms: np.ndarray, global_scale: float = 1.0,
                region_weights: np.ndarray | None = None) -> np.ndarray:
    """The shape space's rest shape ``coeffs`` skinned (Eq. 12) with ``body``'s weights and ``bone_transforms``
    (``region_weights``: only there, :func:`region_shape`)."""
    return pose_template(body, bone_transforms, global_scale,
                         rest_vertices=region_shape(model, body, coeffs, region_weights)).vertices


def shape_prior_mesh(model, body, deformed: np.ndarray, bone_transforms: np.ndarray, global_scale: float = 1.0,
                     ridge: float = 1e-4, robust_m: float = 0.02, region_weights: np.ndarray | None = None
                     ) -> np.ndarray:
    """The shape space's fit to a deformed mesh, posed as it: ``(n, 3)`` world vertices
    (:func:`deformed_shape_coefficients` then :func:`posed_shape` with the same transforms)."""
    c = deformed_shape_coefficients(model, body, deformed, bone_transforms, ridge, robust_m)
    return posed_shape(model, body, c, bone_transforms, global_scale, region_weights)
