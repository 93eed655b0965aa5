"""Depth's reach (rec15b), analytically: the near / far pairing of :func:`depth_constraints`, its weights and
bounds, and :func:`model_front_vertices` on a fronto-parallel grid with a 'limb' quad in front of it, against a
hand-built :class:`DepthObservation` (each vertex's pixel holds exactly the point, normal and depth we chose)."""

import numpy as np

from bodystudio.geometry.camera import Camera
from bodystudio.reconstruct.depth import (
    MODEL_FRONT_M,
    OCCLUSION_M,
    DepthObservation,
    depth_constraints,
    model_front_vertices,
)

UP = np.array([0.0, 0.0, 1.0])  # towards the sensor


def _scene():
    """A 21x21 grid (2 cm, z = 0, 2 px apart) seen from 0.9 m, and a 10 cm 'limb' quad at z = 0.1 in front of
    its centre; grid normals face the sensor, the limb's face away (it never pairs itself)."""
    cam = Camera.look_at("d", (0.0, 0.0, 0.9), (0.0, 0.0, 0.0), fx=90.0, width=101, height=81)
    g = np.arange(-10, 11) * 0.02
    X, Y = np.meshgrid(g, g)
    V = np.c_[X.ravel(), Y.ravel(), np.zeros(X.size)]
    a = (np.arange(20)[:, None] * 21 + np.arange(20)[None, :]).ravel()
    F = np.r_[np.c_[a, a + 1, a + 21], np.c_[a + 1, a + 22, a + 21]]
    limb = np.array([[-0.05, -0.05, 0.1], [0.05, -0.05, 0.1], [0.05, 0.05, 0.1], [-0.05, 0.05, 0.1]])
    F = np.r_[F, [[441, 442, 443], [441, 443, 444]]].astype(np.int64)
    V = np.r_[V, limb]
    N = np.r_[np.tile(UP, (441, 1)), np.tile(-UP, (4, 1))]
    return cam, V, F, N


def _vid(i, j):
    """The grid vertex ``i`` steps right and ``j`` steps up of the centre."""
    return (j + 10) * 21 + (i + 10)


def _obs(cam, V, entries):
    """entries: vertex id -> (offset of the observed point towards the sensor, its normal, observed depth or None
    for the point's own depth)."""
    uv, z = cam.project_with_depth(V)
    px = np.round(uv).astype(np.int64)
    shape = (cam.height, cam.width)
    P, Nq, D, valid = np.zeros(shape + (3,)), np.zeros(shape + (3,)), np.zeros(shape), np.zeros(shape, bool)
    for i, (off, n, depth) in entries.items():
        r, c = px[i, 1], px[i, 0]
        P[r, c] = V[i] + off * UP
        Nq[r, c] = n
        D[r, c] = z[i] - off if depth is None else depth
        valid[r, c] = True
    return DepthObservation(cam, P, Nq, D, valid)


def _pairs(dep):
    return dict(zip(dep.vertex.tolist(), dep.k.tolist(), strict=True))


def test_near_and_far_pairs_are_gaussians_of_their_own_sigma():
    """Eq. 10's weight in 3D, ``k = exp(-d^2 / 2 sigma^2)``: near pairs (within ``max_distance_m``, not hidden
    by the observation) with ``sigma_m``, far pairs (the template's own front, up to ``reach_m``) with
    ``reach_sigma_m``; targets and normals are the observed pixel's."""
    cam, V, F, N = _scene()
    _, z = cam.project_with_depth(V)
    a, b, c, e = _vid(6, 6), _vid(-7, 5), _vid(5, -8), _vid(-6, -6)
    obs = _obs(cam, V, {a: (0.01, UP, None), b: (0.07, UP, None), c: (0.03, UP, None),
                        e: (0.01, UP, z[e] - 0.06)})  # e: 1 cm away but hidden by the observation (6 cm closer)
    g = lambda d, s: float(np.exp(-d * d / (2 * s * s)))  # noqa: E731
    dep = depth_constraints(V, N, obs, sigma_m=0.02, max_distance_m=0.05, F=F, reach_m=0.10, reach_sigma_m=0.04)
    assert dep.vertex.dtype == np.int64 and dep.vertex.tolist() == sorted([a, b, c, e])
    want = {a: g(0.01, 0.02), b: g(0.07, 0.04), c: g(0.03, 0.02), e: g(0.01, 0.04)}
    got = _pairs(dep)
    for i in want:
        assert abs(got[i] - want[i]) < 1e-12, (i, got[i], want[i])
    off = {a: 0.01, b: 0.07, c: 0.03, e: 0.01}
    shift = np.array([off[i] for i in dep.vertex.tolist()])
    np.testing.assert_array_equal(dep.point, V[dep.vertex] + shift[:, None] * UP)
    np.testing.assert_array_equal(dep.normal, np.tile(UP, (4, 1)))
    # the defaults: sigma 2 cm, reach_sigma 5 cm, and reach 0 (no far pair at all, even with the faces)
    assert _pairs(depth_constraints(V, N, obs)) == {a: g(0.01, 0.02), c: g(0.03, 0.02)}
    assert _pairs(depth_constraints(V, N, obs, F=F)) == {a: g(0.01, 0.02), c: g(0.03, 0.02)}
    got = _pairs(depth_constraints(V, N, obs, F=F, reach_m=0.10))
    assert abs(got[b] - g(0.07, 0.05)) < 1e-12 and abs(got[e] - g(0.01, 0.05)) < 1e-12
    assert abs(got[a] - g(0.01, 0.02)) < 1e-12
    # without the faces there is no far pair whatever the reach
    assert _pairs(depth_constraints(V, N, obs, F=None, reach_m=0.10)) == {a: g(0.01, 0.02), c: g(0.03, 0.02)}


def test_pairing_bounds_are_strict():
    """``d < max_distance_m``, ``observed > z - OCCLUSION_M``, ``d < reach_m`` and far pairs only when
    ``reach_m > max_distance_m``: each at its exact bound (sqrt(x^2) == x in floating point)."""
    cam, V, F, N = _scene()
    _, z = cam.project_with_depth(V)
    at_max, below_max = _vid(6, 6), _vid(-6, 6)
    hidden, seen = _vid(6, -6), _vid(-6, -6)
    obs = _obs(cam, V, {at_max: (0.05, UP, z[at_max]), below_max: (0.0499, UP, z[below_max]),
                        hidden: (0.01, UP, z[hidden] - OCCLUSION_M), seen: (0.01, UP, z[seen] - 0.039)})
    assert np.linalg.norm((V[at_max] + 0.05 * UP) - V[at_max]) == 0.05  # d is exactly the bound
    assert sorted(_pairs(depth_constraints(V, N, obs))) == sorted([below_max, seen])
    # with reach == max_distance no far pair: the hidden one (1 cm away) would be one
    assert sorted(_pairs(depth_constraints(V, N, obs, F=F, reach_m=0.05))) == sorted([below_max, seen])
    assert sorted(_pairs(depth_constraints(V, N, obs, F=F, reach_m=0.0501))) == sorted([below_max, seen, at_max,
                                                                                          hidden])
    # the far bound: 10 cm away is out at reach 10 cm, 9.99 cm is in
    far, farish = _vid(8, 0), _vid(-8, 0)
    obs = _obs(cam, V, {far: (0.10, UP, None), farish: (0.0999, UP, None)})
    assert sorted(_pairs(depth_constraints(V, N, obs, F=F, reach_m=0.10))) == [farish]


def test_far_pairs_need_agreeing_normals_and_the_templates_own_front():
    """A far candidate pairs only where its normal agrees with the observed one (dot > ``min_normal_dot``) and it
    is its own front surface in the template (the grid behind the limb is not); near pairs take the observation's
    visibility only, so behind the limb a near pair still pairs."""
    cam, V, F, N = _scene()
    tilt = lambda cos: np.array([np.sqrt(1 - cos * cos), 0.0, cos])  # noqa: E731
    behind_far, behind_near = _vid(0, 0), _vid(1, 1)
    agree, disagree = _vid(6, 7), _vid(-7, 6)
    near_agree, near_disagree = _vid(7, -6), _vid(-6, -7)
    obs = _obs(cam, V, {behind_far: (0.07, UP, None), behind_near: (0.01, UP, None),
                        agree: (0.07, tilt(0.51), None), disagree: (0.07, tilt(0.5), None),
                        near_agree: (0.01, tilt(0.51), None), near_disagree: (0.01, tilt(0.5), None)})
    got = _pairs(depth_constraints(V, N, obs, F=F, reach_m=0.10))
    assert sorted(got) == sorted([behind_near, agree, near_agree])
    got = _pairs(depth_constraints(V, N, obs, F=F, reach_m=0.10, min_normal_dot=0.6))
    assert sorted(got) == [behind_near]
    # the default min_normal_dot is 0.5
    assert sorted(_pairs(depth_constraints(V, N, obs))) == sorted([behind_near, near_agree])


def test_no_far_candidate_needs_no_raster(monkeypatch):
    """No vertex beyond the near pairs: the template is not rendered (d140571)."""
    import bodystudio.capture.render as render

    cam, V, F, N = _scene()
    a = _vid(3, 3)
    obs = _obs(cam, V, {a: (0.01, UP, None)})

    def boom(*args):
        raise AssertionError("rendered")

    monkeypatch.setattr(render, "render_depth", boom)
    assert list(_pairs(depth_constraints(V, N, obs, F=F, reach_m=0.10))) == [a]


def test_model_front_vertices_against_the_templates_raster():
    """True iff the raster covers the pixel and ``z <= raster + MODEL_FRONT_M`` (both bounds exact)."""
    from bodystudio.capture.render import render_depth

    cam, V, F, N = _scene()
    uv, z = cam.project_with_depth(V)
    px = np.round(uv).astype(np.int64)
    raster = render_depth(V, F, cam)  # float32: the bound is float32 arithmetic
    plane, behind = _vid(9, 3), _vid(0, 0)  # plane: row != column; swapped, it is off the grid
    own = raster[px[[plane, behind], 1], px[[plane, behind], 0]]
    assert abs(own[0] - 0.9) < 1e-6 and abs(own[1] - 0.8) < 1e-6  # the plane's and the limb's depth
    P = px[[plane, plane, plane, behind, behind]]
    bound = float(own[0] + MODEL_FRONT_M)
    zz = np.array([bound, np.nextafter(bound, 1.0), own[0] - 0.3, z[behind], own[1] + 0.005])
    assert model_front_vertices(V, F, cam, zz, P).tolist() == [True, False, True, False, True]
    # an empty pixel is nobody's front, however close
    empty = np.array([[2, 2], [px[plane, 1], px[plane, 0]]])  # the second: the plane pixel's row/column swapped
    assert raster[2, 2] == 0 and raster[empty[1, 1], empty[1, 0]] == 0
    assert not model_front_vertices(V, F, cam, np.array([0.005, 0.005]), empty).any()


def _facing(u, cos):
    """A unit normal at angle ``arccos(cos)`` from the unit direction ``u``, tilted in the x-z plane's normal."""
    w = np.cross(u, [0.0, 1.0, 0.0])
    w /= np.linalg.norm(w)
    return cos * u + np.sqrt(1.0 - cos * cos) * w


def test_only_vertices_facing_the_sensor_inside_its_image_pair():
    """The candidates: ``n . (c - v) > 0.2 |c - v|`` (facing, strict: exactly 0.2 is out) and a pixel inside the
    image (columns 0 .. W-1, rows 0 .. H-1; -1 would wrap to the far border, W or H would not index)."""
    cam, *_ = _scene()
    C = cam.center
    s = np.sign(cam.project(np.array([[0.0, 0.1, 0.0]]))[0, 1] - 40.0)  # image rows per world y
    pts = np.array([[0.0, 0.0, 0.0],  # facing exactly at the bound: out
                    [0.1, 0.1, 0.0],  # facing with cos 0.22: in
                    [0.18, 0.0, 0.0],  # grazing (cos ~0.004): out
                    [-0.5, 0.05, 0.0], [-0.51, 0.05, 0.0], [0.51, 0.05, 0.0],  # columns 0, -1, W
                    [0.05, -0.4 * s, 0.0], [0.05, -0.41 * s, 0.0], [0.05, 0.41 * s, 0.0]])  # rows 0, -1, H
    px = np.round(cam.project(pts)).astype(int)
    assert px[3:6, 0].tolist() == [0, -1, cam.width] and px[6:9, 1].tolist() == [0, -1, cam.height]
    N = np.tile(UP, (len(pts), 1))
    N[0] = [np.sqrt(1.0 - 0.04), 0.0, 0.2]
    assert np.sum(N[0] * (C - pts[0])) == 0.2 * np.linalg.norm(C - pts[0])  # exactly the bound
    N[1] = _facing((C - pts[1]) / np.linalg.norm(C - pts[1]), 0.22)
    N[2] = np.array([0.98, 0.0, 0.2]) / np.linalg.norm([0.98, 0.0, 0.2])
    entries = {i: (0.01, N[i], None) for i in range(6) if i != 5}  # the observed normal agrees with the vertex's
    entries.update({6: (0.01, UP, None), 7: (0.01, UP, None)})
    obs = _obs(cam, pts, entries)
    assert sorted(_pairs(depth_constraints(pts, N, obs))) == [1, 3, 6]
    # one candidate is enough
    assert list(_pairs(depth_constraints(pts[[3]], N[[3]], obs))) == [0]
