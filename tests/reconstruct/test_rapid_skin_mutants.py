"""Algorithm 1 of Rapid Skin (§III.C) on a sphere seen by three small cameras, with the solver and matchers
observed: every outer iteration re-matches and solves with the documented settings, the timings add up,
the smoothness reference is the one asked for, and every parameter's range is enforced at its bounds."""

import numpy as np
import pytest

from bodystudio.errors import InputError
from bodystudio.geometry.laplacian import cotangent_delta_coordinates
from bodystudio.reconstruct import rapid_skin
from bodystudio.reconstruct.rapid_skin import RapidSkinParams, deform_to_observations
from bodystudio.reconstruct.solver import DepthConstraints, LMESystem


def test_a_sphere_grows_to_its_silhouettes(sphere_scene):
    """Analytic target: every view shows a sphere 5 % larger (15 mm); the rims must move out to it."""
    V, F, cams, masks = sphere_scene
    r = deform_to_observations(V, F, cams, masks, RapidSkinParams(outer_iterations=4))
    radius = np.linalg.norm(r.vertices, axis=1)
    # measured (4 outer iterations): mean radius 0.3132 m from 0.300 (target 0.315), median |radius - 0.315|
    # 1.7 mm from 15 mm at the start (3 outer: 0.3126 m, 1.7 mm; 8 outer: 0.3148 m, 2.0 mm)
    assert 0.312 < radius.mean() < 0.3165
    assert np.median(np.abs(radius - 0.315)) < 0.0026
    assert len(r.n_silhouette) == 4 and min(r.n_silhouette) > 50 and r.n_depth == [0, 0, 0, 0]


class _Recorder:
    """Stands in for the solver: records what Algorithm 1 hands it and moves the mesh a little."""

    def __init__(self):
        self.calls = []

    def __call__(self, V, cs, solver, inner, lme):
        self.calls.append(dict(V=V.copy(), cs=cs, solver=solver, inner=inner, lme=lme))
        return V * 1.001


@pytest.mark.parametrize("solver, inner, expect_inner", [("gs", 8, 8), ("jacobi", 8, 32), ("jacobi", 3, 12),
                                                          ("cholesky", 5, 5), ("cg", 6, 6)])
def test_every_outer_iteration_rematches_and_solves(sphere_scene, monkeypatch, solver, inner, expect_inner):
    V, F, cams, masks = sphere_scene
    rec = _Recorder()
    monkeypatch.setattr(rapid_skin, "solve_constraints", rec)
    seen = []
    r = deform_to_observations(V, F, cams, masks, RapidSkinParams(outer_iterations=3, inner_iterations=inner,
                                                                  solver=solver),
                               callback=lambda o, X: seen.append((o, X.copy())))
    assert [c["solver"] for c in rec.calls] == [solver] * 3
    assert [c["inner"] for c in rec.calls] == [expect_inner] * 3  # Jacobi runs jacobi_iterations_factor x Ni
    if solver in ("cholesky", "cg"):
        assert isinstance(rec.calls[0]["lme"], LMESystem) and all(c["lme"] is rec.calls[0]["lme"] for c in rec.calls)
    else:
        assert all(c["lme"] is None for c in rec.calls)
    # each solve starts where the previous one ended; the callback sees every outer iteration's result
    for k in range(3):
        np.testing.assert_allclose(rec.calls[k]["V"], V * 1.001**k, rtol=1e-12)
    assert [o for o, _ in seen] == [1, 2, 3]
    np.testing.assert_allclose(seen[1][1], V * 1.001**2, rtol=1e-12)
    np.testing.assert_allclose(r.vertices, V * 1.001**3, rtol=1e-12)
    # the silhouettes are re-matched on the moved mesh, the smoothness reference stays V_init
    assert r.n_silhouette == [len(c["cs"].silhouette) for c in rec.calls] and min(r.n_silhouette) > 50
    assert r.n_depth == [0, 0, 0]
    _, rest = cotangent_delta_coordinates(V, F)
    for c in rec.calls:
        np.testing.assert_allclose(c["cs"].delta_rest, rest, atol=1e-14)
        assert c["cs"].k_sm == 1.0 and len(c["cs"].depth) == 0
    assert not np.array_equal(rec.calls[0]["cs"].silhouette.vertex, rec.calls[2]["cs"].silhouette.vertex) or \
        not np.allclose(rec.calls[0]["cs"].silhouette.origin, rec.calls[2]["cs"].silhouette.origin) or \
        not np.allclose(rec.calls[0]["cs"].silhouette.k, rec.calls[2]["cs"].silhouette.k)


def test_smooth_reference_and_given_delta(sphere_scene, monkeypatch):
    V, F, cams, masks = sphere_scene
    rec = _Recorder()
    monkeypatch.setattr(rapid_skin, "solve_constraints", rec)
    ref = 0.9 * V
    deform_to_observations(V, F, cams, masks, RapidSkinParams(outer_iterations=1), smooth_reference=ref)
    _, rest = cotangent_delta_coordinates(ref, F)
    np.testing.assert_allclose(rec.calls[0]["cs"].delta_rest, rest, atol=1e-14)
    # a precomputed operator is used as given: its delta coordinates of the reference are the rest
    delta, _ = cotangent_delta_coordinates(1.2 * V, F)
    deform_to_observations(V, F, cams, masks, RapidSkinParams(outer_iterations=1), delta=delta, smooth_reference=ref)
    assert rec.calls[1]["cs"].delta is delta
    np.testing.assert_allclose(rec.calls[1]["cs"].delta_rest, delta.apply(ref), atol=1e-14)
    deform_to_observations(V, F, cams, masks, RapidSkinParams(outer_iterations=1), delta=delta)
    np.testing.assert_allclose(rec.calls[2]["cs"].delta_rest, delta.apply(V), atol=1e-14)
    # an LME system handed in is used as it is
    lme = LMESystem(delta)
    deform_to_observations(V, F, cams, masks, RapidSkinParams(outer_iterations=1, solver="cg"), delta=delta, lme=lme)
    assert rec.calls[3]["lme"] is lme


def test_silhouette_settings_reach_the_matcher(sphere_scene, monkeypatch):
    V, F, cams, masks = sphere_scene
    monkeypatch.setattr(rapid_skin, "solve_constraints", _Recorder())
    seen = []
    real = rapid_skin.silhouette_constraints

    def spy(V_, F_, N_, cameras, masks_, tau, alpha, rim_cos, views=None):
        seen.append((tau, alpha, rim_cos, views, N_))
        return real(V_, F_, N_, cameras, masks_, tau, alpha, rim_cos, views=views)

    monkeypatch.setattr(rapid_skin, "silhouette_constraints", spy)
    deform_to_observations(V, F, cams, masks, RapidSkinParams(outer_iterations=2, tau_px=12.0, alpha_px=25.0,
                                                              rim_cos=0.3))
    assert [s[:3] for s in seen] == [(12.0, 25.0, 0.3)] * 2
    assert seen[0][3] is not None and seen[0][3] is seen[1][3]  # masks prepared once for all outer iterations
    # the normals are the current mesh's unit area-weighted normals (outward on the sphere)
    N = seen[0][4]
    np.testing.assert_allclose(np.linalg.norm(N, axis=1), 1.0, atol=1e-12)
    assert np.all(np.sum(N * V, axis=1) > 0.29)


def test_depth_only_needs_no_masks(sphere_scene, monkeypatch):
    V, F, cams, _ = sphere_scene
    rec = _Recorder()
    monkeypatch.setattr(rapid_skin, "solve_constraints", rec)
    dep = DepthConstraints(np.array([0, 1]), V[:2] * 1.1, V[:2] / 0.3, np.array([0.5, 0.5]))
    seen = []

    def fake_depth(V_, N_, obs, sigma, max_m, F=None, reach_m=None, reach_sigma_m=None):
        seen.append((obs, sigma, max_m, F.shape, reach_m, reach_sigma_m))
        meshes.append((np.array(V_), np.array(N_)))
        return dep

    meshes = []

    monkeypatch.setattr(rapid_skin, "depth_constraints", fake_depth)
    obs = object()
    r = deform_to_observations(V, F, cams, None, RapidSkinParams(outer_iterations=2, constraints=("depth",),
                                                                 depth_sigma_m=0.03, depth_max_m=0.07,
                                                                 depth_reach_m=0.12, depth_reach_sigma_m=0.06),
                               depth=obs)
    assert seen == [(obs, 0.03, 0.07, F.shape, 0.12, 0.06)] * 2
    # the depth matcher sees the current mesh and its unit normals (outward on the sphere)
    for (Vd, Nd), call in zip(meshes, rec.calls, strict=True):
        np.testing.assert_array_equal(Vd, call["V"])
        np.testing.assert_allclose(np.linalg.norm(Nd, axis=1), 1.0, atol=1e-12)
        assert np.all(np.sum(Nd * Vd, axis=1) > 0.29)
    assert r.n_depth == [2, 2] and r.n_silhouette == [0, 0]
    assert all(c["cs"].depth is dep and len(c["cs"].silhouette) == 0 for c in rec.calls)
    with pytest.raises(InputError, match="^silhouette constraints need masks$"):
        deform_to_observations(V, F, cams, None, RapidSkinParams())
    with pytest.raises(InputError, match=r"^depth constraints need a Kinect depth observation; the session has "
                                         r"none \(use --constraints silhouette\)$"):
        deform_to_observations(V, F, cams, None, RapidSkinParams(constraints=("depth",)))


def test_timings_add_up(sphere_scene, monkeypatch):
    """A clock that ticks 1 s per reading: matching and solving times are exact sums over the iterations."""
    V, F, cams, masks = sphere_scene
    monkeypatch.setattr(rapid_skin, "solve_constraints", _Recorder())
    ticks = iter(range(100, 1000))  # not from 0: a start time of 0 would hide t1 + t0 for t1 - t0
    monkeypatch.setattr(rapid_skin.time, "perf_counter", lambda: float(next(ticks)))
    r = deform_to_observations(V, F, cams, masks, RapidSkinParams(outer_iterations=3))
    # readings: mask preparation (2), then per outer iteration t0, t1, t2
    assert r.matching_s == 1.0 + 3 * 1.0 and r.solver_s == 3 * 1.0
    ticks = iter(range(100, 1000))
    r = deform_to_observations(V, F, cams, masks, RapidSkinParams(outer_iterations=2, solver="cholesky"))
    # the LME set-up (2 readings) counts as solver time
    assert r.solver_s == 1.0 + 2 * 1.0 and r.matching_s == 1.0 + 2 * 1.0
    assert isinstance(r, rapid_skin.DeformResult) and r.vertices.dtype == np.float64


def test_input_vertices_are_not_modified_and_any_dtype_is_widened(sphere_scene):
    V, F, cams, masks = sphere_scene
    V_in = V.copy()
    p = RapidSkinParams(outer_iterations=1, inner_iterations=2)
    ref = deform_to_observations(V_in, F, cams, masks, p).vertices
    assert np.array_equal(V_in, V)
    V32 = V.astype(np.float32)
    got = deform_to_observations(V32, F.astype(np.int32), cams, masks, p).vertices
    assert got.dtype == np.float64
    np.testing.assert_allclose(got, deform_to_observations(V32.astype(float), F, cams, masks, p).vertices,
                               rtol=0, atol=1e-15)
    assert np.abs(got - ref).max() < 1e-6


def test_default_params_are_the_papers():
    p = RapidSkinParams()
    assert (p.outer_iterations, p.inner_iterations, p.tau_px, p.alpha_px, p.rim_cos, p.solver, p.constraints,
            p.depth_sigma_m, p.depth_max_m, p.jacobi_iterations_factor) == \
        (8, 8, 30.0, 40.0, 0.2, "gs", ("silhouette",), 0.02, 0.05, 4)
    assert p.hull_gate_m == 0.001  # ours (issue 15): the visual-hull gate, 1 mm
    assert (p.depth_reach_m, p.depth_reach_sigma_m) == (0.10, 0.05)  # ours (issue 15): depth's far pairs


_RANGES = [("outer_iterations", "--outer", 1, 100, "iterations"),
           ("inner_iterations", "--inner", 1, 1000, "iterations"),
           ("tau_px", "--tau", 1.0, 500.0, "pixels: the contour search range"),
           ("alpha_px", "--alpha", 1.0, 1000.0, "pixels: the silhouette weight width"),
           ("rim_cos", "rim_cos", 0.0, 0.99, "cosine"),
           ("depth_sigma_m", "depth_sigma_m", 1e-4, 1.0, "metres"),
           ("depth_max_m", "depth_max_m", 1e-3, 1.0, "metres"),
           ("depth_reach_m", "depth_reach_m", 0.0, 1.0, "metres; 0 pairs depth only up to depth_max_m"),
           ("depth_reach_sigma_m", "depth_reach_sigma_m", 1e-4, 1.0, "metres"),
           ("hull_gate_m", "hull_gate_m", 0.0, 1.0, "metres; 0 turns the visual-hull gate off")]


@pytest.mark.parametrize("field, name, lo, hi, unit", _RANGES)
def test_every_parameter_range_is_enforced_at_its_bounds(field, name, lo, hi, unit):
    RapidSkinParams(**{field: lo})
    RapidSkinParams(**{field: hi})
    integer = isinstance(lo, int)
    for bad in ((lo - 1, hi + 1) if integer else (lo * 0.999 if lo else -1e-6, hi * 1.001)) + \
            (() if integer else (float("nan"), float("inf"))):
        msg = f"{name} {bad:g} is out of range; use a value in [{lo:g}, {hi:g}] ({unit})"
        with pytest.raises(InputError) as exc:
            RapidSkinParams(**{field: bad})
        assert str(exc.value) == msg


def test_solver_and_constraint_kinds_are_checked():
    with pytest.raises(InputError) as exc:
        RapidSkinParams(solver="lu")
    assert str(exc.value) == "unknown solver 'lu'; valid: gs, jacobi, cholesky, cg"
    for kinds, shown in (((), "nothing"), (("shading",), "shading"), (("silhouette", "normals"), "silhouette,normals")):
        with pytest.raises(InputError) as exc:
            RapidSkinParams(constraints=kinds)
        assert str(exc.value) == f"constraints must be a non-empty subset of silhouette, depth, got {shown}"
    for kinds in (("silhouette",), ("depth",), ("silhouette", "depth")):
        RapidSkinParams(constraints=kinds)
    for solver in ("gs", "jacobi", "cholesky", "cg"):
        RapidSkinParams(solver=solver)
