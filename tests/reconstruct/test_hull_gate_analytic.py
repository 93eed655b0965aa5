"""The visual-hull gate (:func:`hull_consistent_constraints`) on hulls whose distance is known in closed form:
the rule ``hull(q) <= max(hull(v), 0) + gate_m`` checked at its boundary, per constraint, on rays in any
direction; and Algorithm 1's use of it (``hull_gate_m`` = 0 turns it off, given fields are used as they are)."""

import numpy as np

from bodystudio.reconstruct import rapid_skin
from bodystudio.reconstruct.rapid_skin import RapidSkinParams, deform_to_observations, hull_consistent_constraints
from bodystudio.reconstruct.silhouette import area_weighted_normals, silhouette_constraints
from bodystudio.reconstruct.solver import SilhouetteConstraints
from bodystudio.reconstruct.tracking import SilhouetteFields


class _HalfSpaceHull:
    """A visual hull ``x <= 1``: ``hull(p) = p_x - 1`` metres (> 0 outside), exact in floating point for the
    dyadic coordinates used here. Stands in for :class:`SilhouetteFields` (only ``implicit_hull`` is read)."""

    def __init__(self):
        self.calls = 0

    def implicit_hull(self, X):
        self.calls += 1
        X = np.asarray(X, float)
        return X[:, 0] - 1.0, np.tile([1.0, 0.0, 0.0], (len(X), 1))


class _BallHull:
    """A visual hull that is a ball of radius ``R`` at the origin: ``hull(p) = |p| - R``."""

    def __init__(self, R):
        self.R = R

    def implicit_hull(self, X):
        X = np.asarray(X, float)
        n = np.linalg.norm(X, axis=1)
        return n - self.R, X / n[:, None]


GATE = 0.125
# vertex 0 inside (hull -0.5), vertex 1 outside (hull +0.25), vertex 2 deep inside (hull -0.875)
V3 = np.array([[0.5, 0.0, 0.0], [1.25, 0.0, 0.0], [0.125, 0.0, 0.0]])


def _y_rays(vertex, qx):
    """Constraints whose rays run along +y through ``(qx, *, 0)``: the point of each ray nearest its vertex
    (all vertices have y = z = 0) is exactly ``q = (qx, 0, 0)``."""
    vertex, qx = np.asarray(vertex, np.int64), np.asarray(qx, float)
    m = len(vertex)
    origin = np.stack([qx, np.full(m, -4.0), np.zeros(m)], axis=1)
    direction = np.tile([0.0, 1.0, 0.0], (m, 1))
    return SilhouetteConstraints(vertex, origin, direction, np.linspace(0.1, 0.9, m), np.arange(m) % 3,
                                 np.arange(m) + 0.5)


def test_the_gate_boundary_is_kept_and_just_beyond_is_dropped_per_constraint():
    """Kept: ``hull(q) <= max(hull(v), 0) + gate``. Vertex 0 (inside) may have targets up to the hull + gate
    (x = 1.125), vertex 1 (0.25 outside) up to its own hull distance + gate (x = 1.375); each of a vertex's
    matches (several views) is judged on its own; the order of the constraints is kept."""
    just = np.nextafter
    vertex = [1, 0, 2, 0, 1, 0, 2, 1, 0, 2, 1]
    qx = [1.375, 1.125, 1.125, just(1.125, 2.0), just(1.375, 2.0), 0.75, 1.25, 1.0, 1.375, 0.5, 1.28125]
    keep = np.array([True, True, True, False, False, True, False, True, False, True, True])
    sil = _y_rays(vertex, qx)
    hull = _HalfSpaceHull()
    kept = hull_consistent_constraints(V3, sil, hull, GATE)
    np.testing.assert_array_equal(kept.vertex, sil.vertex[keep])
    np.testing.assert_array_equal(kept.origin, sil.origin[keep])
    np.testing.assert_array_equal(kept.direction, sil.direction[keep])
    np.testing.assert_array_equal(kept.k, sil.k[keep])
    np.testing.assert_array_equal(kept.camera, sil.camera[keep])
    np.testing.assert_array_equal(kept.pixel_distance, sil.pixel_distance[keep])
    # a smaller gate moves both boundaries in: vertex 0's x = 1.125 target goes, vertex 1's x = 1.375 too
    tight = hull_consistent_constraints(V3, sil, _HalfSpaceHull(), 0.0625)
    np.testing.assert_array_equal(tight.k, sil.k[[5, 7, 9, 10]])
    # gate 0 on this function: no step further out than the vertex already is (inside: not out at all)
    zero = hull_consistent_constraints(V3, sil, _HalfSpaceHull(), 0.0)
    np.testing.assert_array_equal(zero.k, sil.k[[5, 7, 9]])
    assert hull.calls == 2  # one hull evaluation for the vertices (once each), one for the targets


def test_a_vertex_already_outside_keeps_targets_up_to_its_own_hull_distance_plus_the_gate():
    """Vertex 1 sits 0.25 outside; a target 0.25 + gate out is kept, one step further is not. Vertex 0 inside
    gets no such allowance: its target at the same x is dropped."""
    sil = _y_rays([1, 1, 0], [1.375, 1.376, 1.375])
    kept = hull_consistent_constraints(V3, sil, _HalfSpaceHull(), GATE)
    np.testing.assert_array_equal(kept.vertex, [1])
    np.testing.assert_array_equal(kept.origin, sil.origin[:1])


def test_all_kept_empty_and_reportless_sets():
    hull = _HalfSpaceHull()
    inside = _y_rays([0, 2, 1, 0], [0.25, 0.5, 0.75, 1.0])
    got = hull_consistent_constraints(V3, inside, hull, GATE)
    assert len(got) == 4
    np.testing.assert_array_equal(got.vertex, inside.vertex)
    np.testing.assert_array_equal(got.k, inside.k)
    empty = hull_consistent_constraints(V3, SilhouetteConstraints.empty(), hull, GATE)
    assert len(empty) == 0 and len(empty.origin) == 0
    # constraints without the report columns (camera, pixel distance) keep them absent
    s = _y_rays([0, 1, 2, 0], [1.0, 2.0, 1.0, 3.0])
    bare = SilhouetteConstraints(s.vertex, s.origin, s.direction, s.k)
    got = hull_consistent_constraints(V3, bare, hull, GATE)
    assert got.camera is None and got.pixel_distance is None
    np.testing.assert_array_equal(got.vertex, [0, 2])
    np.testing.assert_array_equal(got.k, s.k[[0, 2]])


def test_the_ray_point_is_the_one_nearest_the_vertex_for_rays_in_any_direction():
    """Oblique rays built around a chosen target ``q``: vertex ``P = q + s n`` (n perpendicular to the ray),
    origin ``q - t d``. The ball hull (R = 0.5) keeps exactly the targets with ``|q| <= 0.5 + gate`` (vertices
    inside the ball, or as far outside it as their vertex plus the gate)."""
    rng = np.random.default_rng(7)
    m = 40
    d = rng.normal(size=(m, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    u = rng.normal(size=(m, 3))
    q_dir = u / np.linalg.norm(u, axis=1, keepdims=True)
    radius = np.where(np.arange(m) % 2 == 0, rng.uniform(0.30, 0.50, m), rng.uniform(0.51, 0.70, m))
    q = q_dir * radius[:, None]
    n = np.cross(d, rng.normal(size=(m, 3)))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    P = q + rng.uniform(0.01, 0.05, (m, 1)) * n
    inside = np.linalg.norm(P, axis=1) < 0.5
    origin = q - rng.uniform(1.0, 3.0, (m, 1)) * d
    sil = SilhouetteConstraints(np.arange(m), origin, d, np.full(m, 0.5), np.zeros(m, np.int64), np.ones(m))
    kept = hull_consistent_constraints(P, sil, _BallHull(0.5), 0.005)
    h_v = np.maximum(np.linalg.norm(P, axis=1) - 0.5, 0.0)
    expect = radius - 0.5 <= h_v + 0.005
    # both kinds present (measured: 20 vertices inside, 33 of 40 kept; the nearest target 2.5 mm from its bound)
    assert inside.sum() > 10 and 5 < expect.sum() < m - 5
    assert np.abs(radius - 0.5 - (h_v + 0.005)).min() > 0.002
    np.testing.assert_array_equal(kept.vertex, np.flatnonzero(expect))


# --- Algorithm 1's use of the gate --------------------------------------------------------------------------


class _Recorder:
    def __init__(self):
        self.calls = []

    def __call__(self, V, cs, solver, inner, lme):
        self.calls.append(cs)
        return V


class _AllOutside:
    """Fields whose hull puts every vertex on the boundary and every ray target 1 m outside (the gate drops
    everything): ``hull_consistent_constraints`` asks for the vertices first, then the targets."""

    def __init__(self):
        self.calls = 0

    def implicit_hull(self, X):
        self.calls += 1
        return np.full(len(X), 0.0 if self.calls % 2 else 1.0), np.zeros((len(X), 3))


def test_hull_gate_zero_keeps_every_match_and_given_fields_are_used(sphere_scene, monkeypatch):
    V, F, cams, masks = sphere_scene
    rec = _Recorder()
    monkeypatch.setattr(rapid_skin, "solve_constraints", rec)
    ungated = len(silhouette_constraints(V, F, area_weighted_normals(V, F), cams, masks))
    assert ungated > 50
    fields = _AllOutside()
    r = deform_to_observations(V, F, cams, masks, RapidSkinParams(outer_iterations=2, hull_gate_m=0.0),
                               fields=fields)
    assert r.n_silhouette == [ungated, ungated] and fields.calls == 0  # gate off: the fields are not read
    r = deform_to_observations(V, F, cams, masks, RapidSkinParams(outer_iterations=2, hull_gate_m=0.001),
                               fields=fields)
    assert r.n_silhouette == [0, 0] and fields.calls == 4  # the given fields gate both outer iterations
    assert all(len(cs.silhouette) == 0 for cs in rec.calls[2:])
    # without fields the frame's own are computed from the masks: the same count as gating by hand
    expect = len(hull_consistent_constraints(V, silhouette_constraints(V, F, area_weighted_normals(V, F), cams, masks),
                                             SilhouetteFields(cams, masks), 0.001))
    r = deform_to_observations(V, F, cams, masks, RapidSkinParams(outer_iterations=1, hull_gate_m=0.001))
    assert r.n_silhouette == [expect] and len(rec.calls[-1].silhouette) == expect
    assert expect < ungated  # measured 349 of 385 (the coarse sphere's facets: 381 at 5 mm, all at 1 cm)
