"""Rapid Skin's per-frame shape estimation: Algorithm 1 (§III.C) around the constraint solver.

Line 1 computes the delta coordinates of the initial (posed) template; each of the ``No`` outer
iterations recomputes normals, re-matches rim vertices with the silhouette contours (and, when asked,
vertices with Kinect depth points) and runs ``Ni`` inner iterations of the chosen solver. Solver and
matching times are kept apart, as in the paper's Fig. 9. Ours (issue 15): silhouette matches whose target
leaves the visual hull are dropped (:func:`hull_consistent_constraints`, ``hull_gate_m``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from bodystudio.errors import InputError
from bodystudio.geometry.laplacian import DeltaOperator, cotangent_delta_coordinates
from bodystudio.reconstruct.depth import DepthObservation, depth_constraints
from bodystudio.reconstruct.silhouette import (
    MatchSchedule,
    SilhouetteViews,
    area_weighted_normals,
    check_masks,
    silhouette_constraints,
)
from bodystudio.reconstruct.solver import (
    SOLVERS,
    ConstraintSet,
    DepthConstraints,
    LMESystem,
    SilhouetteConstraints,
    solve_constraints,
)
from bodystudio.reconstruct.tracking import SilhouetteFields

CONSTRAINT_KINDS = ("silhouette", "depth")
HOLD_REGIONS = ("all", "torso")


@dataclass(frozen=True)
class RapidSkinParams:
    """Algorithm 1 settings; defaults are the paper's for 640x480 images (§V.A)."""

    outer_iterations: int = 8
    inner_iterations: int = 8
    tau_px: float = 30.0
    alpha_px: float = 40.0
    rim_cos: float = 0.2
    solver: str = "gs"
    constraints: tuple[str, ...] = ("silhouette",)
    depth_sigma_m: float = 0.02
    depth_max_m: float = 0.05
    #: Depth pairs up to this far (m) for vertices that are the template's own front surface in the sensor's
    #: view, weighted with ``depth_reach_sigma_m`` (:func:`bodystudio.reconstruct.depth.depth_constraints`;
    #: issue 15's worst regions); 0: only up to ``depth_max_m``, as before.
    depth_reach_m: float = 0.10
    depth_reach_sigma_m: float = 0.05
    jacobi_iterations_factor: int = 4
    #: Drop a silhouette constraint whose target point leaves the visual hull by more than this (m) beyond
    #: where its vertex already is (:func:`hull_consistent_constraints`); 0 keeps every match (the paper).
    hull_gate_m: float = 0.001
    #: Cheaper matchings after the first outer iteration (issue 15's frame time; :class:`MatchSchedule`, exact
    #: by default).
    matching: MatchSchedule = MatchSchedule()
    #: Issue 15's outer-iteration drift: each vertex no depth pair reaches is kept near the tangent plane it
    #: had after outer iteration ``surface_hold_from`` (0: the start mesh) with this weight
    #: (:func:`surface_hold_constraints`); 0 (default): off, the paper's Algorithm 1.
    surface_hold_k: float = 0.0
    surface_hold_from: int = 1
    #: Which vertices the hold keeps: ``all``, or ``torso`` (the template's torso region, where the drift is;
    #: the caller passes the mask, :func:`deform_to_observations`' ``hold_vertices``).
    surface_hold_region: str = "all"

    def __post_init__(self):
        if isinstance(self.matching, dict):  # as ``asdict`` wrote it (a batch's options, run.json)
            object.__setattr__(self, "matching", MatchSchedule(**self.matching))
        if not isinstance(self.matching, MatchSchedule):
            raise InputError(f"matching must be a MatchSchedule, got {type(self.matching).__name__}")
        if self.surface_hold_region not in HOLD_REGIONS:
            raise InputError(f"unknown surface_hold_region {self.surface_hold_region!r}; valid: "
                             f"{', '.join(HOLD_REGIONS)}")
        if self.solver not in SOLVERS:
            raise InputError(f"unknown solver {self.solver!r}; valid: {', '.join(SOLVERS)}")
        bad = [c for c in self.constraints if c not in CONSTRAINT_KINDS]
        if bad or not self.constraints:
            raise InputError(f"constraints must be a non-empty subset of {', '.join(CONSTRAINT_KINDS)}, "
                             f"got {','.join(self.constraints) or 'nothing'}")
        for name, value, lo, hi, flag in (
                ("--outer", self.outer_iterations, 1, 100, "iterations"),
                ("--inner", self.inner_iterations, 1, 1000, "iterations"),
                ("--tau", self.tau_px, 1.0, 500.0, "pixels: the contour search range"),
                ("--alpha", self.alpha_px, 1.0, 1000.0, "pixels: the silhouette weight width"),
                ("rim_cos", self.rim_cos, 0.0, 0.99, "cosine"),
                ("depth_sigma_m", self.depth_sigma_m, 1e-4, 1.0, "metres"),
                ("depth_max_m", self.depth_max_m, 1e-3, 1.0, "metres"),
                ("depth_reach_m", self.depth_reach_m, 0.0, 1.0, "metres; 0 pairs depth only up to depth_max_m"),
                ("depth_reach_sigma_m", self.depth_reach_sigma_m, 1e-4, 1.0, "metres"),
                ("hull_gate_m", self.hull_gate_m, 0.0, 1.0, "metres; 0 turns the visual-hull gate off"),
                ("surface_hold_k", self.surface_hold_k, 0.0, 1.0, "weight; 0 turns the surface hold off"),
                ("surface_hold_from", self.surface_hold_from, 0, 100, "outer iteration")):
            if not np.isfinite(value) or not lo <= value <= hi:
                raise InputError(f"{name} {value:g} is out of range; use a value in [{lo:g}, {hi:g}] ({flag})")


@dataclass
class DeformResult:
    """Deformed vertices plus timings (seconds) and per-outer-iteration constraint counts; ``silhouette_vertices``:
    the vertices with a silhouette constraint in the last outer iteration (each once or more, one per pair)."""

    vertices: np.ndarray
    solver_s: float = 0.0
    matching_s: float = 0.0
    n_silhouette: list = field(default_factory=list)
    n_depth: list = field(default_factory=list)
    silhouette_vertices: np.ndarray | None = None


def deform_to_observations(V_init: np.ndarray, F: np.ndarray, cameras, masks: dict | None,
                           params: RapidSkinParams = RapidSkinParams(), depth: DepthObservation | None = None,
                           delta: DeltaOperator | None = None, lme: LMESystem | None = None,
                           smooth_reference: np.ndarray | None = None, callback=None,
                           fields: SilhouetteFields | None = None,
                           hold_vertices: np.ndarray | None = None) -> DeformResult:
    """Algorithm 1 of Rapid Skin: deform ``V_init`` until its rims match the silhouettes in ``masks``.

    ``cameras`` is an iterable of ``Camera``; ``masks`` maps camera names to ``(H, W)`` silhouettes.
    ``depth`` adds point-to-plane constraints when ``"depth"`` is in ``params.constraints``.
    ``smooth_reference`` is the mesh whose delta coordinates the smoothness constraints keep
    (default ``V_init``, Algorithm 1 line 1); ``delta`` may carry its precomputed cotangent weights.
    ``callback(outer, V)`` sees the mesh after every outer iteration. ``fields`` (the frame's
    :class:`SilhouetteFields`, computed here when not given) gate the matches by the visual hull
    (``params.hull_gate_m``). ``hold_vertices`` (a boolean mask) limits ``params.surface_hold_k``'s hold to
    those vertices.
    """
    cameras = list(cameras)
    use_sil = "silhouette" in params.constraints
    use_depth = "depth" in params.constraints
    if use_sil:
        if masks is None:
            raise InputError("silhouette constraints need masks")
        check_masks(masks, cameras)
    if use_depth and depth is None:
        raise InputError("depth constraints need a Kinect depth observation; the session has none "
                         "(use --constraints silhouette)")
    V = np.array(V_init, dtype=np.float64)
    reference = V if smooth_reference is None else np.asarray(smooth_reference, dtype=np.float64)
    if delta is None:
        delta, delta_rest = cotangent_delta_coordinates(reference, F)
    else:
        delta_rest = delta.apply(reference)
    if params.solver in ("cholesky", "cg") and lme is None:
        t0 = time.perf_counter()
        lme = LMESystem(delta)
        solver_s = time.perf_counter() - t0
    else:
        solver_s = 0.0
    result = DeformResult(V)
    result.solver_s = solver_s
    F = np.ascontiguousarray(F, dtype=np.int64)
    t0 = time.perf_counter()
    views = SilhouetteViews(cameras, masks, F) if use_sil else None  # masks prepared once for all No matchings
    gate = use_sil and params.hull_gate_m > 0
    if gate and fields is None:
        fields = SilhouetteFields(cameras, masks)
    # the gate reads its vertices' fields at the matching's projections when both use the same cameras
    share = gate and isinstance(fields, SilhouetteFields) and views.packed is not None and _same_cameras(fields, views)
    result.matching_s += time.perf_counter() - t0
    # the gate's decisions per (camera, vertex): 0 undecided, 1 kept, 2 dropped (MatchSchedule.gate "reuse")
    gate_memo = np.zeros(len(cameras) * len(V), np.int8) if gate and params.matching.gate == "reuse" else None
    inner = params.inner_iterations
    if params.solver == "jacobi":
        inner *= params.jacobi_iterations_factor
    hold = None
    for outer in range(params.outer_iterations):
        t0 = time.perf_counter()
        N = area_weighted_normals(V, F)
        if params.surface_hold_k > 0 and outer == params.surface_hold_from:
            hold = (V.copy(), N / np.maximum(np.linalg.norm(N, axis=1, keepdims=True), 1e-12))
        sil = (silhouette_constraints(V, F, N, cameras, masks, params.tau_px, params.alpha_px, params.rim_cos,
                                      views=views, **params.matching.matching_args(outer, params.outer_iterations,
                                                                                       len(cameras)))
               if use_sil else SilhouetteConstraints.empty())
        gate_mode = params.matching.gate_at(outer, params.outer_iterations) if gate else "off"
        if gate_mode != "off":
            sil = hull_consistent_constraints(V, sil, fields, params.hull_gate_m,
                                              projected=views.projection(V) if share else None,
                                              memo=gate_memo, reuse=gate_mode == "reuse")
        dep = (depth_constraints(V, N, depth, params.depth_sigma_m, params.depth_max_m, F=F,
                                  reach_m=params.depth_reach_m, reach_sigma_m=params.depth_reach_sigma_m)
               if use_depth else DepthConstraints.empty())
        planes = dep
        if hold is not None:
            exclude = dep.vertex
            if hold_vertices is not None:
                exclude = np.union1d(exclude, np.flatnonzero(~np.asarray(hold_vertices, bool)))
            planes = _concat_depth(dep, surface_hold_constraints(hold[0], hold[1], params.surface_hold_k,
                                                                 exclude=exclude))
        t1 = time.perf_counter()
        cs = ConstraintSet(delta, delta_rest, sil, planes)
        V = solve_constraints(V, cs, params.solver, inner, lme)
        t2 = time.perf_counter()
        result.matching_s += t1 - t0
        result.solver_s += t2 - t1
        result.n_silhouette.append(len(sil))
        result.silhouette_vertices = sil.vertex
        result.n_depth.append(len(dep))
        if callback is not None:
            callback(outer + 1, V)
    result.vertices = V
    return result


def surface_hold_constraints(V_hold: np.ndarray, N_hold: np.ndarray, k: float,
                             exclude: np.ndarray | None = None) -> DepthConstraints:
    """Point-to-plane constraints ``n_h . (v_i - v_h) = 0`` keeping each vertex near the tangent plane it had in
    ``V_hold`` (unit normals ``N_hold``), weight ``k``: a membrane hold in the form of the depth constraint
    (Rapid Skin §VI's extension, ``C_d`` of the solver) for issue 15's outer-iteration drift, where rim matches
    of one side camera pull the upper back outwards step by step. Tangential sliding stays free; vertices in
    ``exclude`` (those a depth pair reaches) get none.
    """
    keep = np.ones(len(V_hold), bool)
    if exclude is not None and len(exclude):
        keep[np.asarray(exclude, dtype=np.int64)] = False
    ids = np.flatnonzero(keep).astype(np.int64)
    return DepthConstraints(ids, np.ascontiguousarray(V_hold[ids]), np.ascontiguousarray(N_hold[ids]),
                            np.full(len(ids), float(k)))


def _concat_depth(a: DepthConstraints, b: DepthConstraints) -> DepthConstraints:
    return DepthConstraints(np.concatenate([a.vertex, b.vertex]), np.concatenate([a.point, b.point]),
                            np.concatenate([a.normal, b.normal]), np.concatenate([a.k, b.k]))


def _same_cameras(fields: SilhouetteFields, views: SilhouetteViews) -> bool:
    """The fields' cameras are the views' packed ones, in the same order (rotations, translations,
    intrinsics, distortion and image sizes equal)."""
    _, _, Rs, ts, Ks, dists, _, _, w, h = views.packed
    return (len(fields.cameras) == len(Rs) and np.array_equal(fields._R, Rs) and np.array_equal(fields._t, ts)
            and np.array_equal(fields._K, Ks) and np.array_equal(fields._dist, dists)
            and bool(np.all(fields._size == (w, h))))


def hull_consistent_constraints(V: np.ndarray, sil: SilhouetteConstraints, fields: SilhouetteFields,
                                gate_m: float, projected: tuple[np.ndarray, np.ndarray] | None = None,
                                memo: np.ndarray | None = None, reuse: bool = True) -> SilhouetteConstraints:
    """The silhouette constraints (Eq. 7 of Rapid Skin) whose target stays inside the visual hull.

    A constraint pulls its vertex onto the viewing ray of the contour pixel it matched, i.e. to the point
    ``q`` of the ray nearest the vertex. A true rim point lies inside every silhouette, so ``q`` of a
    right match is at most on the hull's boundary; a rim vertex whose outward search crossed another
    body part's silhouette (the head against a raised arm, the upper back against the shoulder) gets a
    ``q`` in empty space beside it, which the other cameras see outside their silhouettes. Kept: the
    constraints with ``hull(q) <= max(hull(v), 0) + gate_m`` (``hull`` the implicit visual hull of
    ``fields``, metres, > 0 outside): a step may not take a vertex further out of the hull than it is.
    ``projected``: ``V`` in the fields' cameras as the matching projected it
    (:meth:`bodystudio.reconstruct.silhouette.SilhouetteViews.projection`), so ``hull(v)`` is not projected
    again (the same decisions). ``memo`` (int8, ``cameras * len(V)``; needs ``sil.camera``): decisions of earlier
    calls by (camera, vertex), 1 kept and 2 dropped, reused as they are (``reuse``; otherwise all pairs are gated
    anew); only undecided pairs are gated, and their decisions written in (issue 15's frame time: inexact, the
    target has moved with its vertex since).
    """
    if not len(sil):
        return sil
    if memo is not None and sil.camera is not None and isinstance(fields, SilhouetteFields):
        # the memo's bookkeeping, the gate and the kept constraints in one compiled pass (rec15i: ~0.6 ms of
        # Python a pass), the same decisions and arrays as the path below
        keep = fields.hull_gate_memo(V, sil.vertex, sil.camera, sil.origin, sil.direction, gate_m, memo, reuse,
                                     projected)
        return _kept(sil, keep)
    if memo is not None and sil.camera is not None:
        slot = sil.camera * len(V) + sil.vertex
        known = memo[slot] if reuse else np.zeros(len(slot), np.int8)
        todo = known == 0
        keep = known == 1
        if todo.any():
            # all undecided (every pass but a reusing one): the constraints as they are, not a copy of them
            part = sil if todo.all() else SilhouetteConstraints(sil.vertex[todo], sil.origin[todo],
                                                                sil.direction[todo], sil.k[todo])
            new = _gate_keep(V, part, fields, gate_m, projected)
            keep[todo] = new
            memo[slot[todo]] = np.where(new, 1, 2)
        return _kept(sil, keep)
    keep = _gate_keep(V, sil, fields, gate_m, projected)
    return _kept(sil, keep)


def _gate_keep(V, sil, fields, gate_m, projected):
    o, d = sil.origin, sil.direction
    if isinstance(fields, SilhouetteFields):
        return fields.hull_gate(V, sil.vertex, o, d, gate_m, projected)  # one compiled pass, the same decisions
    return hull_gate_reference(V, sil, fields, gate_m)  # any object with ``implicit_hull`` (the tests' hulls)


def _kept(sil: SilhouetteConstraints, keep: np.ndarray) -> SilhouetteConstraints:
    o, d = sil.origin, sil.direction
    if keep.all():
        return sil
    # the kept rows' ids once and ``take`` (rec15j): six boolean selections counted the mask six times (a gate's
    # ~12K constraints 0.37 -> 0.23 ms); the same rows in the same order
    rows = np.flatnonzero(keep)
    return SilhouetteConstraints(sil.vertex.take(rows), o.take(rows, axis=0), d.take(rows, axis=0), sil.k.take(rows),
                                 None if sil.camera is None else sil.camera.take(rows),
                                 None if sil.pixel_distance is None else sil.pixel_distance.take(rows))


def hull_gate_reference(V: np.ndarray, sil: SilhouetteConstraints, fields, gate_m: float) -> np.ndarray:
    """Keep mask of :func:`hull_consistent_constraints` by two :meth:`implicit_hull` evaluations (targets and
    unique rim vertices): the vectorised path the compiled :meth:`SilhouetteFields.hull_gate` replaced, kept
    for hulls that only have ``implicit_hull`` and as the equality test's reference."""
    o, d = sil.origin, sil.direction
    P = V[sil.vertex]
    q = o + np.sum((P - o) * d, axis=1, keepdims=True) * d
    vertices, slot = np.unique(sil.vertex, return_inverse=True)  # a rim vertex has a match in several views
    h_v, _ = fields.implicit_hull(V[vertices])
    h_q, _ = fields.implicit_hull(q)
    return ~(h_q > np.maximum(h_v[slot], 0.0) + gate_m)
