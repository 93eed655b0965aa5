"""A final shape refinement of §4.3 (Eq. 1-2) against every fitted frame's silhouette, the poses held.

§4.3 fits the shape by Nelder-Mead on a few reference frames with the distance form of Eq. 2 (each projected
vertex's distance outside the matte plus each outline sample's distance to the nearest projected vertex, any
vertex). That form is biased towards a larger body: a body a few pixels too large has vertices on both sides
of every outline sample and pays only through the few rim vertices outside (docs/garment.md, gar13c: the
fitted bodies cover 2-3 x more pixels outside the matte than they leave uncovered). Here the shape is refined
after the pose of every frame is known, by Gauss-Newton on the MakeHuman shape parameters (the macro
parameters and the local modifiers of :mod:`bodystudio.garment.fit`) with the poses held:

* ``E_out``: body vertices projecting outside the matte, their distance (px) along the distance field's gradient;
* ``E_cover``: each matte outline sample against the nearest *rim* vertex (normal nearly perpendicular to the
  viewing ray), along the rim's image normal, so the body's outline, not any vertex, has to reach the matte's;
* the stature held at the user's value, and the Gaussian prior of the local modifiers (``shape_prior_energy``).

``allowance_m`` is a clothing allowance: the body's rim is pushed out along its normals by that much before it
is compared with the matte, i.e. the matte is taken to be the body plus clothes that thick.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from bodystudio.geometry.camera import pinhole_projection_jacobian

log = logging.getLogger(__name__)

#: Rim vertices: |cos| between the vertex normal and the viewing ray below this.
RIM_COS = 0.3
#: Outline samples farther than this (px) from every rim vertex are left out of E_cover (another body part).
COVER_REACH_PX = 25.0
#: Finite-difference step of the shape parameters (their range is [0, 1] or [-1, 1]).
SHAPE_FD_STEP = 0.02
#: The stature's residual scale: a stature this far from the given one counts as one pixel of silhouette error.
STATURE_SCALE_M = 0.0005
#: No parameter moves by more than this per Gauss-Newton step.
MAX_STEP = 0.15
#: Clothing allowance of the default fit (m): the matte is taken to be the body plus this much clothing. Hidden
#: subjects 37 / 21 / 3 (docs/garment.md, gar13c), garment_iou after the §7 refinement: 0.930 / 0.912 / 0.914
#: without the shape refinement, 0.948 / 0.917 / 0.926 with it at 4 mm, 0.947 / 0.926 / 0.931 at 6 mm (kept at 4 mm:
#: 6 mm is closer to the synthetic worn shirt's own 8 mm; see docs/garment.md).
#: Half of the synthetic worn T-shirt's offset; a bare-skinned actor's fit comes out that much thin.
CLOTHING_ALLOWANCE_M = 0.004
#: Gauss-Newton steps of the fit's refinement (the energy changes < 1 % after the 5th on the hidden subjects).
REFINE_ITERATIONS = 5
#: Macro parameters refined beyond §4.3's first stage (:func:`refined_macro_parameters`).
REFINED_EXTRA_MACRO: tuple[str, ...] = ("age",)
#: Largest clothing allowance accepted (m).
MAX_CLOTHING_ALLOWANCE_M = 0.03


@dataclass(frozen=True)
class ShapeRefinement:
    """The refined shape and what the refinement measured (energies before and after each step)."""

    phenotype: dict
    local: dict
    energies: tuple
    iterations: int


def refined_macro_parameters() -> tuple[str, ...]:
    """The macro parameters refined: §4.3's first stage plus ``age`` (MakeHuman's age also sets the limb
    proportions: with it the elbows sit where the silhouettes of a flexing arm put them)."""
    from bodystudio.garment.fit import MACRO_PARAMETERS

    return MACRO_PARAMETERS + tuple(k for k in REFINED_EXTRA_MACRO if k not in MACRO_PARAMETERS)


def shape_parameters(phenotype: dict, local: dict) -> np.ndarray:
    """The parameter vector refined: :func:`refined_macro_parameters` then §4.3's local modifiers."""
    from bodystudio.garment.fit import LOCAL_PARAMETERS

    return np.array([float(phenotype[k]) for k in refined_macro_parameters()] + [float(local.get(k, 0.0))
                                                                                for k in LOCAL_PARAMETERS])


def _bounds() -> tuple[np.ndarray, np.ndarray]:
    from bodystudio.garment.fit import LOCAL_PARAMETERS

    lo = np.r_[np.zeros(len(refined_macro_parameters())), -np.ones(len(LOCAL_PARAMETERS))]
    return lo, np.ones(len(lo))


def _body(p: np.ndarray, phenotype: dict, local: dict, template: str):
    from bodystudio.garment.fit import LOCAL_PARAMETERS, _shape_body

    return _shape_body(p, refined_macro_parameters() + LOCAL_PARAMETERS, phenotype, local, template)



def _sample(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    from bodystudio.garment.fit import _bilinear

    return _bilinear(image, uv)


def silhouette_rows(V: np.ndarray, N: np.ndarray, J: np.ndarray | None, camera, target, allowance_m: float = 0.0
                    ) -> tuple[np.ndarray, np.ndarray]:
    """One frame's ``E_out`` and ``E_cover`` (Eq. 2 with the rim), linearised: rows ``(m, k)`` and residuals
    ``(m,)`` in px, each term divided by the square root of its sample count (a mean, as ``silhouette_residuals``).

    ``V`` (n, 3) posed vertices, ``N`` their unit normals, ``J`` (n, 3, k) their derivative in the shape
    parameters (None: residuals only, rows of zero width), ``target`` a :class:`fit.SilhouetteTarget`."""
    P = V + allowance_m * N
    uv = camera.project(P)
    ray = P - camera.center
    cos = np.einsum("ij,ij->i", N, ray) / np.linalg.norm(ray, axis=1)
    h, w = target.outside_px.shape
    inside = (uv[:, 0] >= 1) & (uv[:, 0] <= w - 2) & (uv[:, 1] >= 1) & (uv[:, 1] <= h - 2)
    d = _sample(target.outside_px, uv)
    out = np.flatnonzero(inside & (d > 0.5))
    rim = np.flatnonzero(np.abs(cos) < RIM_COS)
    cover_ids, cover_px = np.zeros(0, int), np.zeros((0, 2))
    if len(rim) >= 3 and len(target.samples):
        dd, nearest = cKDTree(uv[rim]).query(target.samples, distance_upper_bound=COVER_REACH_PX)
        keep = np.isfinite(dd)
        cover_ids, cover_px = rim[nearest[keep]], target.samples[keep]
    k = 0 if J is None else J.shape[2]
    rows, res = [np.zeros((0, k))], [np.zeros(0)]
    J_uv = None
    if J is not None:
        ids = np.r_[out, cover_ids]
        J_uv = np.zeros((len(V), 2, k))
        J_uv[ids] = pinhole_projection_jacobian(camera, P[ids], J[ids])
    if len(out):
        s = 1.0 / np.sqrt(len(V))
        res.append(s * np.minimum(d[out], 30.0))
        if J is not None:
            steps = np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]])
            around = _sample(target.outside_px, (uv[out][None] + steps[:, None]).reshape(-1, 2)).reshape(4, -1)
            grad = np.c_[around[0] - around[1], around[2] - around[3]] / 2.0
            rows.append(s * np.einsum("nd,ndk->nk", grad, J_uv[out]))
    if len(cover_ids):
        s = 1.0 / np.sqrt(len(target.samples))
        n2 = camera.project(P[cover_ids] + 0.01 * N[cover_ids]) - uv[cover_ids]
        n2 /= np.maximum(np.linalg.norm(n2, axis=1, keepdims=True), 1e-12)
        res.append(s * np.einsum("nd,nd->n", n2, uv[cover_ids] - cover_px))
        if J is not None:
            rows.append(s * np.einsum("nd,ndk->nk", n2, J_uv[cover_ids]))
    return np.concatenate(rows), np.concatenate(res)


def _posed(body, poses) -> list[tuple[np.ndarray, np.ndarray]]:
    from bodystudio.geometry.mesh import vertex_normals

    out = []
    for pose in poses:
        V, _ = body.pose(pose)
        out.append((V, vertex_normals(V, body.faces)))
    return out


def _prior_rows(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    from bodystudio.garment.fit import LOCAL_PARAMETERS, LOCAL_PRIOR_SD, SHAPE_PRIOR_WEIGHT

    k = len(p)
    m = len(refined_macro_parameters())
    A = np.zeros((len(LOCAL_PARAMETERS), k))
    A[:, m:] = np.eye(len(LOCAL_PARAMETERS)) * np.sqrt(SHAPE_PRIOR_WEIGHT) / LOCAL_PRIOR_SD
    return A, A @ p


def refinement_energy(p: np.ndarray, phenotype: dict, local: dict, template: str, poses, camera, targets,
                      stature_m: float, allowance_m: float = 0.0) -> float:
    """The refinement's energy at ``p``: the frames' mean ``E_out + E_cover``, the stature and the prior."""
    from bodystudio.garment.fit import body_stature

    body, _, _ = _body(p, phenotype, local, template)
    e = 0.0
    for (V, N), t in zip(_posed(body, poses), targets, strict=True):
        e += float(np.sum(silhouette_rows(V, N, None, camera, t, allowance_m)[1] ** 2))
    e /= len(targets)
    e += ((body_stature(body) - stature_m) / STATURE_SCALE_M) ** 2
    return e + float(np.sum(_prior_rows(p)[1] ** 2))


def _restore_stature(p: np.ndarray, phenotype: dict, local: dict, template: str, stature_m: float) -> np.ndarray:
    """``p`` with MakeHuman's ``height`` moved (secant steps) so the body's stature is ``stature_m`` again: the
    stature is far from linear in the other parameters, and a linearised step that holds it to first order
    misses it by millimetres, which the stature term (0.5 mm scale) then refuses."""
    from bodystudio.garment.fit import body_stature

    i = refined_macro_parameters().index("height")
    q = p.copy()

    def miss(x: float) -> float:
        q[i] = x
        return body_stature(_body(q, phenotype, local, template)[0]) - stature_m

    x0 = float(q[i])
    s0 = miss(x0)
    best = (abs(s0), x0)
    x1 = float(np.clip(x0 - np.sign(s0) * 0.01, 0.0, 1.0))
    for _ in range(6):
        if best[0] < 5e-5 or x1 == x0:
            break
        s1 = miss(x1)
        best = min(best, (abs(s1), x1))
        if abs(s1 - s0) < 1e-12:
            break
        x0, s0, x1 = x1, s1, float(np.clip(x1 - s1 * (x1 - x0) / (s1 - s0), 0.0, 1.0))
    q[i] = best[1]
    return q


def refine_shape_to_silhouettes(phenotype: dict, local: dict, template: str, poses, masks, camera, stature_m: float,
                                iterations: int = REFINE_ITERATIONS,
                                allowance_m: float = CLOTHING_ALLOWANCE_M) -> ShapeRefinement:
    """Gauss-Newton on §4.3's shape parameters against the silhouettes of every frame, the ``poses`` held.

    Each step linearises :func:`silhouette_rows` of every frame (finite differences of the posed vertices in
    each parameter), the stature (held at ``stature_m``) and the local modifiers' prior, and takes the
    Levenberg-damped step if it lowers :func:`refinement_energy` (else it raises the damping, up to three
    times, then stops). Returns the refined phenotype and local modifiers."""
    from bodystudio.garment.fit import body_stature, silhouette_target

    poses = list(poses)
    targets = [silhouette_target(m) for m in masks]
    lo, hi = _bounds()
    p = np.clip(shape_parameters(phenotype, local), lo, hi)
    energy = refinement_energy(p, phenotype, local, template, poses, camera, targets, stature_m, allowance_m)
    energies = [energy]
    damping = 1e-3
    done = 0
    for _ in range(max(0, int(iterations))):
        body, _, _ = _body(p, phenotype, local, template)
        base = _posed(body, poses)
        stature = body_stature(body)
        k = len(p)
        J = [np.zeros((len(V), 3, k)) for V, _ in base]
        dstature = np.zeros(k)
        for j in range(k):
            step = SHAPE_FD_STEP if p[j] + SHAPE_FD_STEP <= hi[j] else -SHAPE_FD_STEP
            q = p.copy()
            q[j] += step
            body_j, _, _ = _body(q, phenotype, local, template)
            for f, (V, _) in enumerate(_posed(body_j, poses)):
                J[f][:, :, j] = (V - base[f][0]) / step
            dstature[j] = (body_stature(body_j) - stature) / step
        H = np.zeros((k, k))
        g = np.zeros(k)
        for (V, N), Jf, t in zip(base, J, targets, strict=True):
            A, r = silhouette_rows(V, N, Jf, camera, t, allowance_m)
            H += A.T @ A / len(targets)
            g += A.T @ r / len(targets)
        a = dstature / STATURE_SCALE_M
        H += np.outer(a, a)
        g += a * (stature - stature_m) / STATURE_SCALE_M
        A, r = _prior_rows(p)
        H += A.T @ A
        g += A.T @ r
        accepted = False
        for _ in range(4):
            delta = -np.linalg.solve(H + damping * np.diag(np.diag(H) + 1e-9), g)
            largest = np.max(np.abs(delta))
            if largest > MAX_STEP:
                delta *= MAX_STEP / largest
            q = _restore_stature(np.clip(p + delta, lo, hi), phenotype, local, template, stature_m)
            e = refinement_energy(q, phenotype, local, template, poses, camera, targets, stature_m, allowance_m)
            if e < energy:
                p, energy, accepted = q, e, True
                damping = max(damping / 3.0, 1e-6)
                break
            damping *= 10.0
        energies.append(energy)
        if not accepted:
            break
        done += 1
        log.info("shape refinement step %d: energy %.4f", done, energy)
    _, ph, loc = _body(p, phenotype, local, template)
    return ShapeRefinement(ph, loc, tuple(energies), done)
