"""rec15g's surface hold (``RapidSkinParams.surface_hold_k`` / ``surface_hold_from`` / ``surface_hold_region``) in
:mod:`bodystudio.reconstruct.rapid_skin` and its wiring in :func:`bodystudio.reconstruct.sequence.reconstruct_frames`,
on stand-ins (issue 17).

Algorithm 1's loop runs with depth constraints only, a stand-in depth matching (fixed pairs) and a stand-in solve that
records the plane constraints it is given and moves the mesh by a known step per outer iteration, so the hold's
planes at every iteration are exact: the iterate ``surface_hold_from``'s vertices and unit area-weighted normals,
weight ``k``, none on a depth-paired vertex or outside ``hold_vertices``, after the depth pairs. Each test < 1 s.
"""
from __future__ import annotations

from types import SimpleNamespace as NS

import numpy as np
import pytest

import bodystudio.reconstruct.rapid_skin as rs
import bodystudio.reconstruct.sequence as seq
from bodystudio.errors import InputError
from bodystudio.reconstruct.rapid_skin import RapidSkinParams, surface_hold_constraints
from bodystudio.reconstruct.silhouette import area_weighted_normals
from bodystudio.reconstruct.solver import DepthConstraints

# an octahedron, stretched so its normals' lengths differ
OCT_V = np.array([[1, 0, 0], [-1, 0, 0], [0, 2, 0], [0, -2, 0], [0, 0, 3], [0, 0, -3]], float)
OCT_F = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])
DEP = DepthConstraints(np.array([1, 4], np.int64), np.array([[-1.0, 0.0, 0.1], [0.0, 0.1, 3.0]]),
                       np.array([[-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]), np.array([0.7, 0.8]))
STEP = np.array([0.01, -0.02, 0.03])


def _step(outer):
    """The stand-in solve's move at outer iteration ``outer``: a translation and a stretch (normals' lengths)."""
    return lambda V: V * (1.0 + 0.1 * (outer + 1)) + STEP * (outer + 1)


def _loop(monkeypatch, params, hold_vertices=None):
    planes = []

    def solve(V, cs, solver, inner, lme):
        planes.append(cs.depth)
        return _step(len(planes) - 1)(np.asarray(V))

    monkeypatch.setattr(rs, "depth_constraints", lambda V, N, depth, *a, **k: DEP)
    monkeypatch.setattr(rs, "solve_constraints", solve)
    rs.deform_to_observations(OCT_V, OCT_F, [], None, params, depth=object(), hold_vertices=hold_vertices)
    return planes


def _iterates(n):
    V, out = OCT_V.copy(), [OCT_V.copy()]
    for outer in range(n):
        V = _step(outer)(V)
        out.append(V)
    return out


def _params(**kw):
    return RapidSkinParams(constraints=("depth",), solver="gs", outer_iterations=4, inner_iterations=1, **kw)


def _same(a: DepthConstraints, b: DepthConstraints):
    assert a.vertex.dtype == np.int64 and b.vertex.dtype == np.int64
    np.testing.assert_array_equal(a.vertex, b.vertex)
    for x, y in ((a.point, b.point), (a.normal, b.normal), (a.k, b.k)):
        np.testing.assert_allclose(x, y, rtol=0, atol=1e-13)


@pytest.mark.parametrize(("hold_from", "k"), [(0, 0.3), (1, 0.25), (2, 1.0)])
def test_hold_planes_per_outer_iteration(monkeypatch, hold_from, k):
    planes = _loop(monkeypatch, _params(surface_hold_k=k, surface_hold_from=hold_from))
    Vs = _iterates(4)
    assert len(planes) == 4
    N = area_weighted_normals(Vs[hold_from], OCT_F)
    N = N / np.linalg.norm(N, axis=1, keepdims=True)
    keep = np.array([0, 2, 3, 5])  # not the depth-paired 1 and 4
    want = DepthConstraints(np.concatenate([DEP.vertex, keep]), np.vstack([DEP.point, Vs[hold_from][keep]]),
                            np.vstack([DEP.normal, N[keep]]), np.concatenate([DEP.k, np.full(4, k)]))
    for outer, p in enumerate(planes):
        _same(p, want if outer >= hold_from else DEP)


def test_hold_vertices_limit_the_hold_and_no_hold_when_off(monkeypatch):
    mask = np.array([True, True, False, True, True, True])
    planes = _loop(monkeypatch, _params(surface_hold_k=0.5, surface_hold_from=0), hold_vertices=mask)
    N = area_weighted_normals(OCT_V, OCT_F)
    N = N / np.linalg.norm(N, axis=1, keepdims=True)
    keep = np.array([0, 3, 5])
    for p in planes:
        _same(p, DepthConstraints(np.concatenate([DEP.vertex, keep]), np.vstack([DEP.point, OCT_V[keep]]),
                                  np.vstack([DEP.normal, N[keep]]), np.concatenate([DEP.k, np.full(3, 0.5)])))
    # a list mask is read as booleans
    planes = _loop(monkeypatch, _params(surface_hold_k=0.5, surface_hold_from=0), hold_vertices=[1, 1, 0, 1, 1, 1])
    np.testing.assert_array_equal(planes[0].vertex, np.concatenate([DEP.vertex, keep]))
    for off in (_params(), _params(surface_hold_k=0.0, surface_hold_from=0)):
        for p in _loop(monkeypatch, off):
            _same(p, DEP)


def test_hold_normals_of_a_degenerate_vertex_stay_finite(monkeypatch):
    """A vertex without area (all its faces collapsed) gets a zero normal, not NaN (the 1e-12 floor)."""
    V = OCT_V.copy()
    N = area_weighted_normals(V, OCT_F)
    c = surface_hold_constraints(V, np.vstack([N[:5] / np.linalg.norm(N[:5], axis=1, keepdims=True), [0, 0, 0]]),
                                 0.2)
    assert np.all(np.isfinite(c.normal))
    V[:] = 0.0  # every face collapsed: the hold's normals are all zero
    monkeypatch.setattr(rs, "depth_constraints", lambda *a, **k: DepthConstraints.empty())
    seen = []
    monkeypatch.setattr(rs, "solve_constraints", lambda V, cs, *a: seen.append(cs.depth) or V)
    rs.deform_to_observations(V, OCT_F, [], None, _params(surface_hold_k=0.2, surface_hold_from=0), depth=object())
    assert np.all(seen[0].normal == 0.0) and len(seen[0]) == 6


def test_surface_hold_constraints_exclude_and_dtypes():
    V = np.arange(18, dtype=float).reshape(6, 3)
    N = np.tile([0.0, 0.0, 1.0], (6, 1))
    c = surface_hold_constraints(V, N, 0.4, exclude=np.array([4, 1]))
    np.testing.assert_array_equal(c.vertex, [0, 2, 3, 5])
    assert c.vertex.dtype == np.int64 and c.k.dtype == np.float64
    np.testing.assert_array_equal(c.point, V[[0, 2, 3, 5]])
    np.testing.assert_array_equal(c.normal, N[[0, 2, 3, 5]])
    assert c.point.flags.c_contiguous and c.normal.flags.c_contiguous
    np.testing.assert_array_equal(c.k, [0.4] * 4)
    for exclude in (None, np.array([], np.int64), []):
        np.testing.assert_array_equal(surface_hold_constraints(V, N, 1, exclude=exclude).vertex, np.arange(6))
    assert surface_hold_constraints(V, N, 1).k.dtype == np.float64
    # exclude as a list of ints indexes (not a boolean mask)
    np.testing.assert_array_equal(surface_hold_constraints(V, N, 1, exclude=[1, 0]).vertex, [2, 3, 4, 5])


@pytest.mark.parametrize(("kw", "message"), [
    (dict(surface_hold_region="legs"), r"^unknown surface_hold_region 'legs'; valid: all, torso$"),
    (dict(surface_hold_k=-0.01), r"^surface_hold_k -0.01 is out of range; use a value in \[0, 1\] \(weight; 0 turns "
                                  r"the surface hold off\)$"),
    (dict(surface_hold_k=1.01), r"^surface_hold_k 1.01 is out of range"),
    (dict(surface_hold_k=float("nan")), r"^surface_hold_k nan is out of range"),
    (dict(surface_hold_from=-1), r"^surface_hold_from -1 is out of range; use a value in \[0, 100\] \(outer "
                                 r"iteration\)$"),
    (dict(surface_hold_from=101), r"^surface_hold_from 101 is out of range"),
])
def test_hold_settings_refused(kw, message):
    with pytest.raises(InputError, match=message):
        RapidSkinParams(**kw)


def test_hold_settings_range_ends_and_defaults():
    for kw in (dict(surface_hold_k=0.0), dict(surface_hold_k=1.0), dict(surface_hold_from=0),
               dict(surface_hold_from=100), dict(surface_hold_region="torso"), dict(surface_hold_region="all")):
        RapidSkinParams(**kw)
    p = RapidSkinParams()
    assert (p.surface_hold_k, p.surface_hold_from, p.surface_hold_region) == (0.0, 1, "all")


# --- reconstruct_frames' wiring: the template's region mask handed to Algorithm 1 -------------------------------

def _frames_run(monkeypatch, tmp_path, params, shape_prior="off"):
    from tests.reconstruct.test_sequence_tracked_mutants import BODIES, Writer, _session, _stand_ins

    rec = _stand_ins(monkeypatch)
    got = []

    def deform(V, F, cameras, masks, params, **kw):
        got.append(kw)
        return NS(vertices=np.asarray(V), solver_s=0.0, matching_s=0.0, n_silhouette=[1], n_depth=[0])

    labels = np.array(["torso", "arm", "torso", "leg"])
    calls = []
    monkeypatch.setattr(seq, "deform_to_observations", deform)
    monkeypatch.setattr(seq, "vertex_regions", lambda body: calls.append(body) or labels)
    import bodystudio.body.statistical as statistical

    monkeypatch.setattr(statistical, "load_statistical_model", lambda resolution, progress=True: "space")
    monkeypatch.setattr(seq, "shape_prior_mesh", lambda model, body, V, T, scale=1.0: np.asarray(V) + 0.001)
    seq.reconstruct_frames(_session(), Writer(tmp_path), [10, 11], [NS(name="c0")], NS(depth="depth-camera"), params,
                           "gs", "6k", "tracker", None, False, False, False, False, tracking=False,
                           bone_lengths="frame", shape_prior=shape_prior)
    assert all(b is BODIES["6k"] for b in calls)
    return got, calls, rec


@pytest.mark.parametrize("shape_prior", ["off", "frame"])
@pytest.mark.parametrize(("kw", "mask"), [
    (dict(surface_hold_k=0.3, surface_hold_region="torso"), [True, False, True, False]),
    (dict(surface_hold_k=0.3), None),
    (dict(surface_hold_region="torso"), None),
])
def test_reconstruct_frames_hands_the_torso_mask(monkeypatch, tmp_path, kw, mask, shape_prior):
    """Both passes of a frame (the shape prior's second one too) get the template's torso mask."""
    got, calls, _rec = _frames_run(monkeypatch, tmp_path, RapidSkinParams(**kw), shape_prior)
    assert len(got) == (2 if shape_prior == "off" else 4)
    for g in got:
        if mask is None:
            assert "hold_vertices" not in g
        else:
            np.testing.assert_array_equal(g["hold_vertices"], mask)
            assert g["hold_vertices"].dtype == bool
    assert len(calls) == (1 if mask is not None else 0)
