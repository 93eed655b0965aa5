"""Fast analytic tests of the garment fit's step 4b (garment/shape_refine.py), for mutation testing (issue 17).

tests/garment/test_shape_refine.py refines a 2k MakeHuman body against three rendered frames (a minute per test);
here every test runs in well under a second, so each mutant of the module can be checked:

* ``silhouette_rows`` on hand-placed vertices: a rectangular matte, rim vertices 4 px outside its left edge and
  on its right edge, front-facing vertices inside and one front-facing decoy on the left outline. ``E_out`` is
  4 px per outside vertex, ``E_cover`` matches each outline sample to the nearest *rim* vertex (the decoy never),
  the rows are the residuals' derivative (a finite difference agrees), the clothing allowance equals moving the
  vertices out along their normals, the 30 px cap, the per-term means;
* the refinement on a stand-in body (``fit._shape_body`` monkeypatched): an ellipsoid whose semi-axes are known
  functions of the shape parameters, posed by a yaw and a shift, filmed by the fit's camera hypothesis. The
  refinement recovers planted semi-axes, holds the stature, a clothing allowance of 1 cm thins the fitted body by
  1 cm, the Gauss-Newton steps lower the energy, the step is capped, an unseen modifier returns to the prior.
"""

from dataclasses import dataclass, replace

import numpy as np
import pytest

W, H = 240, 320
DEPTH_M = 3.0


def _camera():
    from bodystudio.garment import fit as gf

    return gf.camera_hypothesis(W, H)


def _at_pixels(camera, uv: np.ndarray, depth: float = DEPTH_M) -> np.ndarray:
    """World points that project to ``uv`` at camera depth ``depth``."""
    K = camera.K
    Pc = np.c_[(uv[:, 0] - K[0, 2]) / K[0, 0] * depth, (uv[:, 1] - K[1, 2]) / K[1, 1] * depth, np.full(len(uv), depth)]
    return (Pc - camera.t) @ camera.R


# --- silhouette_rows on hand-placed vertices ------------------------------------------------------------

LEFT, RIGHT, TOP, BOTTOM = 100, 139, 80, 239  # the matte: columns 100..139, rows 80..239 (inclusive)
ROWS = np.arange(88, 233, 8)  # rim vertex rows, away from the matte's corners


def _matte():
    m = np.zeros((H, W), bool)
    m[TOP:BOTTOM + 1, LEFT:RIGHT + 1] = True
    return m


@pytest.fixture(scope="module")
def rect():
    """Vertices, normals and kinds: left rim 4 px outside, right rim on the outline, front inside, one decoy."""
    from bodystudio.garment.fit import silhouette_target

    cam = _camera()
    left = np.c_[np.full(len(ROWS), LEFT - 4.0), ROWS]
    right = np.c_[np.full(len(ROWS), float(RIGHT)), ROWS]
    front = np.c_[np.full(len(ROWS), 120.0), ROWS]
    decoy = np.array([[float(LEFT), 160.0]])
    uv = np.r_[left, right, front, decoy]
    V = _at_pixels(cam, uv)
    n = len(ROWS)
    N = np.r_[np.tile([-1.0, 0.0, 0.0], (n, 1)), np.tile([1.0, 0.0, 0.0], (n, 1)),
              np.tile([0.0, 0.0, 1.0], (n + 1, 1))]
    kind = np.r_[np.zeros(n, int), np.ones(n, int), np.full(n + 1, 2)]
    return dict(camera=cam, V=V, N=N, uv=uv, kind=kind, target=silhouette_target(_matte()), n=n)


def _expected_cover(r) -> np.ndarray:
    """Each outline sample against the nearest rim vertex within 25 px, along the rim's image normal (a loop)."""
    rim = np.flatnonzero(r["kind"] < 2)
    out = []
    for s in r["target"].samples:
        d = np.hypot(*(r["uv"][rim] - s).T)
        i = rim[np.argmin(d)]
        if d.min() <= 25.0:
            n2 = np.array([-1.0, 0.0]) if r["kind"][i] == 0 else np.array([1.0, 0.0])
            out.append(n2 @ (r["uv"][i] - s))
    return np.array(out)


def test_rows_residuals_are_the_outside_distance_and_the_rim_cover_gap(rect):
    from bodystudio.garment.shape_refine import silhouette_rows

    V, N, t = rect["V"], rect["N"], rect["target"]
    A, r = silhouette_rows(V, N, None, rect["camera"], t)
    n_out = rect["n"]
    assert A.shape[1] == 0
    # E_out: the left rim, 4 px outside; a mean over all vertices
    np.testing.assert_allclose(r[:n_out] * np.sqrt(len(V)), 4.0, atol=1e-6)
    cover = r[n_out:] * np.sqrt(len(t.samples))
    expected = _expected_cover(rect)
    assert len(cover) == len(expected) and len(expected) > 0.9 * len(t.samples)
    np.testing.assert_allclose(np.sort(cover), np.sort(expected), atol=1e-6)
    # the left edge's samples are 4 px inside the rim that covers them; the decoy on the outline is not a rim
    assert np.count_nonzero(np.isclose(cover, 4.0, atol=1e-6)) >= BOTTOM - TOP - 10


def test_rows_are_the_derivative_of_the_residuals(rect):
    from bodystudio.garment.shape_refine import silhouette_rows

    t, cam = rect["target"], rect["camera"]
    # and front-facing vertices 5 px above the matte's top edge: E_out with a vertical gradient
    top = _at_pixels(cam, np.c_[np.arange(108.0, 133.0, 4.0), np.full(7, TOP - 5.0)])
    V = np.r_[rect["V"], top]
    N = np.r_[rect["N"], np.tile([0.0, 0.0, 1.0], (len(top), 1))]
    J = np.zeros((len(V), 3, 3))
    J[:, 0, 0] = 1.0  # everything moves along +x
    J[np.flatnonzero(rect["kind"] == 0), 0, 1] = -1.0  # the left rim moves out
    J[:, 1, 2] = np.linspace(0.0, 1.0, len(V))  # a vertical shear
    A, r = silhouette_rows(V, N, J, cam, t)
    _, r0 = silhouette_rows(V, N, None, cam, t)
    np.testing.assert_allclose(r, r0)
    assert A.shape == (len(r), 3)
    n_out = rect["n"]
    # E_out's row along +x: the distance falls 1 px per px, u moves fx / z px per metre
    np.testing.assert_allclose(A[:n_out, 0] * np.sqrt(len(V)), -cam.fx / DEPTH_M, rtol=1e-6)
    # the top vertices' rows: no change along x, 1 px less per px down
    np.testing.assert_allclose(r[n_out:n_out + 7] * np.sqrt(len(V)), 5.0, atol=1e-6)
    np.testing.assert_allclose(A[n_out:n_out + 7, 0], 0.0, atol=1e-9)
    for k, dp in ((0, 2e-4), (1, 2e-4), (2, 1e-4)):
        _, r1 = silhouette_rows(V + dp * J[:, :, k], N, None, cam, t)
        assert len(r1) == len(r)
        np.testing.assert_allclose(r1 - r, A[:, k] * dp, atol=2e-3 * np.abs(A[:, k] * dp).max() + 1e-9)


def test_allowance_is_the_body_moved_out_along_its_normals(rect):
    from bodystudio.garment.shape_refine import silhouette_rows

    V, N, t, cam = rect["V"], rect["N"], rect["target"], rect["camera"]
    J = np.zeros((len(V), 3, 1))
    J[:, 0, 0] = 1.0
    for a in (0.005, 0.02):
        A, r = silhouette_rows(V, N, J, cam, t, allowance_m=a)
        A2, r2 = silhouette_rows(V + a * N, N, J, cam, t)
        np.testing.assert_allclose(r, r2, atol=1e-9)
        np.testing.assert_allclose(A, A2, atol=1e-9)
    # 2 cm at 3 m is fx * 0.02 / 3 ~ 2.9 px: the left rim is that much farther outside
    _, r = silhouette_rows(V, N, None, cam, t, allowance_m=0.02)
    np.testing.assert_allclose(r[:rect["n"]] * np.sqrt(len(V)), 4.0 + cam.fx * 0.02 / DEPTH_M, atol=0.02)


def test_outside_distance_is_capped_at_30_px_and_the_border_is_left_out():
    from bodystudio.garment.fit import silhouette_target
    from bodystudio.garment.shape_refine import silhouette_rows

    cam = _camera()
    t = silhouette_target(_matte())
    uv = np.array([[LEFT - 40.0, 160.0], [LEFT - 12.0, 161.0], [LEFT - 1.0, 170.0], [120.0, 160.0], [0.4, 160.0],
                   [W - 1.2, 160.0], [120.0, 0.5], [120.0, H - 1.5], [1.0, 150.0], [W - 2.5, 150.0], [120.0, 1.5],
                   [120.0, H - 2.5]])
    V = _at_pixels(cam, uv)
    N = np.tile([0.0, 0.0, 1.0], (len(V), 1))  # no rim: E_cover empty
    J = np.ones((len(V), 3, 2))
    A, r = silhouette_rows(V, N, J, cam, t)
    # the 40 px vertex counts 30 px, the 12 px one 12, the 1 px one 1, the one inside nothing, four in the image's
    # 1 px border band none; (1, 150) on the band's edge and the three 0.5 px inside it count (all over 30 px out)
    np.testing.assert_allclose(r * np.sqrt(len(V)), [30.0, 12.0, 1.0, 30.0, 30.0, 30.0, 30.0], atol=1e-4)
    assert A.shape == (7, 2)


def test_cover_leaves_out_samples_beyond_reach_and_needs_three_rim_vertices():
    from bodystudio.garment.fit import silhouette_target
    from bodystudio.garment.shape_refine import silhouette_rows

    cam = _camera()
    t = silhouette_target(_matte())
    # three rim vertices 3 px left of the outline's middle: only samples within 25 px of them count, 3 px each
    uv = np.array([[LEFT - 3.0, 150.0], [LEFT - 3.0, 160.0], [LEFT - 3.0, 170.0]])
    V = _at_pixels(cam, uv)
    N = np.tile([-1.0, 0.0, 0.0], (3, 1))
    _, r = silhouette_rows(V, N, None, cam, t)
    near = np.min(np.hypot(*(t.samples[:, None] - uv[None]).transpose(2, 0, 1)), axis=1) < 25.0
    assert 40 < np.count_nonzero(near) < 80
    np.testing.assert_allclose(r[3:] * np.sqrt(len(t.samples)), t.samples[near, 0] - (LEFT - 3.0), atol=1e-6)
    np.testing.assert_allclose(r[:3] * np.sqrt(3), 3.0, atol=1e-6)  # E_out of the three
    # 8 m away a 1 cm normal step is under a pixel in the image: the rim's image normal is still a unit vector
    _, r8 = silhouette_rows(_at_pixels(cam, uv, 8.0), N, None, cam, t)
    np.testing.assert_allclose(r8, r, atol=1e-6)
    # two rim vertices are not a rim: no E_cover at all
    _, r2 = silhouette_rows(V[:2], N[:2], None, cam, t)
    assert len(r2) == 2
    # nor is there one without outline samples
    _, r3 = silhouette_rows(V, N, None, cam, replace(t, samples=np.zeros((0, 2))))
    assert len(r3) == 3


def test_rim_is_where_the_normal_is_nearly_perpendicular_to_the_ray(rect):
    from bodystudio.garment.fit import silhouette_target
    from bodystudio.garment.shape_refine import RIM_COS, silhouette_rows

    cam = _camera()
    t = silhouette_target(_matte())
    uv = np.array([[float(LEFT) - 3, 150.0], [float(LEFT) - 3, 160.0], [float(LEFT) - 3, 170.0]])
    V = _at_pixels(cam, uv)
    ray = V - cam.center
    ray /= np.linalg.norm(ray, axis=1, keepdims=True)
    side = np.cross(ray, [0.0, 1.0, 0.0])
    side /= np.linalg.norm(side, axis=1, keepdims=True)
    for c, rim in ((RIM_COS - 0.02, True), (RIM_COS + 0.02, False), (-(RIM_COS - 0.02), True),
                   (-(RIM_COS + 0.02), False)):
        N = c * ray + np.sqrt(1 - c * c) * side  # |cos| between the normal and the viewing ray = |c|
        _, r = silhouette_rows(V, N, None, cam, t)
        assert (len(r) > 3) == rim, (c, len(r))


# --- the refinement on a stand-in body ------------------------------------------------------------------

def _unit_sphere():
    import trimesh

    s = trimesh.creation.icosphere(subdivisions=3)
    return np.asarray(s.vertices, float), np.asarray(s.faces, np.int64)


U, F = _unit_sphere()


def _axes(ph: dict, loc: dict) -> np.ndarray:
    """The stand-in body's semi-axes (m) from the shape parameters (the stature 2 a_y is not linear in height)."""
    h = ph["height"]
    ax = 0.16 + 0.10 * ph["weight"] + 0.02 * ph["muscle"] + 0.04 * loc.get("torso-scale-horiz-decr-incr", 0.0)
    ay = 0.70 + 0.25 * h + 0.08 * h * h + 0.03 * ph["proportions"] + 0.02 * ph["age"]
    az = 0.10 + 0.06 * ph["gender"] + 0.04 * loc.get("torso-scale-depth-decr-incr", 0.0)
    return np.array([ax, ay, az])


@dataclass(frozen=True)
class _Pose:
    yaw: float
    x: float


class _Ellipsoid:
    """Stands in for a MakeHuman body: ``vertices`` (rest, feet on the floor), ``faces``, ``pose(p) -> (V, _)``."""

    def __init__(self, axes):
        self.axes = np.asarray(axes, float)
        self.faces = F
        self.vertices = U * self.axes + [0.0, self.axes[1], 0.0]

    def pose(self, pose):
        c, s = np.cos(pose.yaw), np.sin(pose.yaw)
        R = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
        return (U * self.axes) @ R.T + [pose.x, self.axes[1], -DEPTH_M], None


def _shape_body(values, names, phenotype, local, template):
    assert template == "toy", template  # the refinement hands its template on to every body it builds
    ph, loc = dict(phenotype), dict(local)
    for n, v in zip(names, values, strict=True):
        if n in ph:
            ph[n] = float(np.clip(v, 0.0, 1.0))
        else:
            loc[n] = float(np.clip(v, -1.0, 1.0))
    return _Ellipsoid(_axes(ph, loc)), ph, loc


TRUTH_PH = {"gender": 0.5, "muscle": 0.5, "weight": 0.5, "height": 0.5, "proportions": 0.5, "age": 0.5}
POSES = (_Pose(0.0, 0.0), _Pose(0.7, 0.12), _Pose(-0.6, -0.1))


def _toy(monkeypatch) -> dict:
    """The stand-in scene, with ``fit._shape_body`` building the ellipsoid (a function, not a fixture: the direct
    recheck of docs/mutation gives tests a fresh ``monkeypatch`` but builds fixtures once)."""
    from bodystudio.garment import fit as gf

    monkeypatch.setattr(gf, "_shape_body", _shape_body)
    return _scene()


def _scene_cache():
    cache = {}

    def scene():
        if not cache:
            from bodystudio.garment import fit as gf

            cam = _camera()
            body = _Ellipsoid(_axes(TRUTH_PH, {}))
            masks = [gf.model_silhouette(body.pose(p)[0], F, cam) for p in POSES]
            cache.update(camera=cam, masks=masks, stature=float(2 * body.axes[1]), axes=body.axes)
        return cache
    return scene


_scene = _scene_cache()


def _refine(toy, ph, loc, **kw):
    from bodystudio.garment.shape_refine import refine_shape_to_silhouettes

    return refine_shape_to_silhouettes(ph, loc, "toy", POSES, toy["masks"], toy["camera"], toy["stature"], **kw)


def test_parameter_vector_and_bounds():
    from bodystudio.garment.fit import LOCAL_PARAMETERS, MACRO_PARAMETERS
    from bodystudio.garment.shape_refine import _bounds, refined_macro_parameters, shape_parameters

    names = refined_macro_parameters()
    assert names == MACRO_PARAMETERS + ("age",)
    ph = {k: 0.1 * (i + 1) for i, k in enumerate(names)}
    loc = {LOCAL_PARAMETERS[2]: -0.4, LOCAL_PARAMETERS[-1]: 0.7, "not-refined": 0.9}
    p = shape_parameters(ph, loc)
    expected = np.zeros(len(names) + len(LOCAL_PARAMETERS))
    expected[:len(names)] = 0.1 * np.arange(1, len(names) + 1)
    expected[len(names) + 2], expected[-1] = -0.4, 0.7
    np.testing.assert_allclose(p, expected)
    lo, hi = _bounds()
    np.testing.assert_array_equal(lo, np.r_[np.zeros(len(names)), -np.ones(len(LOCAL_PARAMETERS))])
    np.testing.assert_array_equal(hi, np.ones(len(p)))


def test_prior_rows_are_the_local_modifiers_gaussian_prior():
    from bodystudio.garment.fit import LOCAL_PARAMETERS, LOCAL_PRIOR_SD, SHAPE_PRIOR_WEIGHT, shape_prior_energy
    from bodystudio.garment.shape_refine import _prior_rows, refined_macro_parameters

    m = len(refined_macro_parameters())
    rng = np.random.default_rng(1)
    p = rng.uniform(-1, 1, m + len(LOCAL_PARAMETERS))
    A, r = _prior_rows(p)
    assert A.shape == (len(LOCAL_PARAMETERS), len(p))
    np.testing.assert_array_equal(A[:, :m], 0.0)
    np.testing.assert_allclose(A[:, m:], np.eye(len(LOCAL_PARAMETERS)) * np.sqrt(SHAPE_PRIOR_WEIGHT) / LOCAL_PRIOR_SD)
    np.testing.assert_allclose(r, A @ p)
    np.testing.assert_allclose(np.sum(r ** 2), shape_prior_energy(dict(zip(LOCAL_PARAMETERS, p[m:], strict=True))))


def test_energy_is_the_frames_mean_plus_stature_plus_prior(monkeypatch):
    toy = _toy(monkeypatch)
    from bodystudio.garment.fit import LOCAL_PARAMETERS, silhouette_target
    from bodystudio.garment.shape_refine import STATURE_SCALE_M, refinement_energy, shape_parameters, silhouette_rows
    from bodystudio.geometry.mesh import vertex_normals

    cam, masks = toy["camera"], toy["masks"]
    targets = [silhouette_target(m) for m in masks]
    ph = {**TRUTH_PH, "weight": 0.7}
    p = shape_parameters(ph, {})
    body = _Ellipsoid(_axes(ph, {}))
    frames = []
    for pose, t in zip(POSES, targets, strict=True):
        V, _ = body.pose(pose)
        frames.append(np.sum(silhouette_rows(V, vertex_normals(V, F), None, cam, t, 0.004)[1] ** 2))
    assert np.ptp(frames) > 0.05 * np.mean(frames)  # the frames differ: a sum or one frame would not do
    e = refinement_energy(p, ph, {}, "toy", POSES, cam, targets, toy["stature"], 0.004)
    np.testing.assert_allclose(e, np.mean(frames), rtol=1e-9)
    # the stature: 1 mm off is (1 / 0.5)^2 = 4
    e1 = refinement_energy(p, ph, {}, "toy", POSES, cam, targets, toy["stature"] + 0.001, 0.004)
    np.testing.assert_allclose(e1 - e, (0.001 / STATURE_SCALE_M) ** 2, rtol=1e-6)
    # an unseen modifier costs its prior only: 0.005 (0.3 / 0.3)^2
    q = p.copy()
    q[len(p) - len(LOCAL_PARAMETERS) + LOCAL_PARAMETERS.index("stomach-pregnant-decr-incr")] = 0.3
    e2 = refinement_energy(q, ph, {}, "toy", POSES, cam, targets, toy["stature"], 0.004)
    np.testing.assert_allclose(e2 - e, 0.005, rtol=1e-6)
    # the allowance reaches the frames; none by default
    e3 = refinement_energy(p, ph, {}, "toy", POSES, cam, targets, toy["stature"], 0.0)
    assert abs(e3 - e) > 1e-3 * e
    assert refinement_energy(p, ph, {}, "toy", POSES, cam, targets, toy["stature"]) == e3
    with pytest.raises(ValueError):  # a pose for every matte
        refinement_energy(p, ph, {}, "toy", POSES, cam, targets[:2], toy["stature"])


def test_restore_stature_moves_height_only(monkeypatch):
    _toy(monkeypatch)
    from bodystudio.garment.shape_refine import _restore_stature, refined_macro_parameters, shape_parameters

    i = refined_macro_parameters().index("height")
    builds = []
    count = {"n": 0}

    def counted(*a):
        count["n"] += 1
        return _shape_body(*a)

    monkeypatch.setattr("bodystudio.garment.fit._shape_body", counted)
    for start_h, target in ((0.3, 1.74), (0.9, 1.60), (0.5, 1.90), (0.52, 1.74), (0.45, 1.74)):
        ph = {**TRUTH_PH, "height": start_h, "weight": 0.3}
        p = shape_parameters(ph, {"torso-scale-horiz-decr-incr": 0.2})
        count["n"] = 0
        q = _restore_stature(p, ph, {}, "toy", target)
        builds.append(count["n"])
        np.testing.assert_array_equal(np.delete(q, i), np.delete(p, i))
        assert p[i] == start_h  # the input is not changed
        stature = 2 * _axes({**ph, "height": q[i]}, {})[1]
        assert abs(stature - target) < 5e-5, (start_h, target, stature - target)
    # secant steps from a first probe 0.01 towards the stature, stopping once within 0.05 mm: each probe is a
    # MakeHuman body build (measured 5, 6, 5, 3, 4)
    assert builds[:3] == [5, 6, 5] and max(builds[3:]) <= 4, builds


def test_restore_stature_keeps_the_best_within_the_bounds(monkeypatch):
    _toy(monkeypatch)
    from bodystudio.garment.shape_refine import _restore_stature, refined_macro_parameters, shape_parameters

    i = refined_macro_parameters().index("height")
    ph = {**TRUTH_PH, "height": 0.5}
    p = shape_parameters(ph, {})
    # unreachable: taller than height 1.0 gives; the best is the bound
    q = _restore_stature(p, ph, {}, "toy", 2.6)
    assert q[i] == 1.0
    q = _restore_stature(p, ph, {}, "toy", 1.0)
    assert q[i] == 0.0
    # from the bound itself the probe stays within [0, 1]
    low = {**ph, "height": 0.0}
    assert _restore_stature(shape_parameters(low, {}), low, {}, "toy", 1.0)[i] == 0.0
    high = {**ph, "height": 1.0}
    assert _restore_stature(shape_parameters(high, {}), high, {}, "toy", 2.6)[i] == 1.0
    # from either bound the first probe goes inwards: a reachable stature is restored
    for bound in (0.0, 1.0):
        start = {**ph, "height": bound}
        q = _restore_stature(shape_parameters(start, {}), start, {}, "toy", 1.74)
        assert abs(2 * _axes({**ph, "height": q[i]}, {})[1] - 1.74) < 5e-5, (bound, q[i])
    # already there: unchanged
    exact = 2 * _axes(ph, {})[1]
    np.testing.assert_array_equal(_restore_stature(p, ph, {}, "toy", exact), p)


def test_restore_stature_gives_up_when_height_does_not_move_the_stature(monkeypatch):
    from bodystudio.garment import fit as gf
    from bodystudio.garment.shape_refine import _restore_stature, refined_macro_parameters, shape_parameters

    def flat(values, names, phenotype, local, template):
        body, ph, loc = _shape_body(values, names, phenotype, local, template)
        return _Ellipsoid(_axes({**ph, "height": 0.5}, loc)), ph, loc

    monkeypatch.setattr(gf, "_shape_body", flat)
    ph = {**TRUTH_PH, "height": 0.4}
    p = shape_parameters(ph, {})
    q = _restore_stature(p, ph, {}, "toy", 1.9)
    i = refined_macro_parameters().index("height")
    assert q[i] in (0.39, 0.4) and np.array_equal(np.delete(q, i), np.delete(p, i))


def test_refinement_recovers_a_planted_shape_and_holds_the_stature(monkeypatch):
    toy = _toy(monkeypatch)
    ph = {**TRUTH_PH, "weight": 0.8, "gender": 0.15}
    r = _refine(toy, ph, {}, iterations=8, allowance_m=0.0)
    before = _axes(ph, {}) - toy["axes"]
    after = _axes(r.phenotype, r.local) - toy["axes"]
    assert abs(before[0]) > 0.025 and abs(before[2]) > 0.02
    # a pixel is 6.8 mm at 3 m; from the truth itself the refinement settles 3.7 mm thin in x
    assert np.all(np.abs(after) < 0.0045), after
    assert abs(2 * _axes(r.phenotype, r.local)[1] - toy["stature"]) < 2e-4
    e = np.array(r.energies)
    assert len(e) == r.iterations + 1 and r.iterations >= 3
    assert np.all(np.diff(e) <= 0) and e[-1] < 0.2 * e[0], e
    assert set(r.phenotype) == set(ph) and r.phenotype["muscle"] == pytest.approx(r.phenotype["muscle"])


def test_one_step_lowers_the_energy_and_is_capped(monkeypatch):
    toy = _toy(monkeypatch)
    from bodystudio.garment.shape_refine import MAX_STEP, refined_macro_parameters, shape_parameters

    ph = {**TRUTH_PH, "weight": 1.0}
    r = _refine(toy, ph, {}, iterations=1, allowance_m=0.0)
    # measured 31.9 -> 23.8
    assert r.iterations == 1 and len(r.energies) == 2 and r.energies[1] < 0.85 * r.energies[0], r.energies
    p0, p1 = shape_parameters(ph, {}), shape_parameters(r.phenotype, r.local)
    i = refined_macro_parameters().index("height")
    moved = np.abs(np.delete(p1 - p0, i))
    assert moved.max() <= MAX_STEP + 1e-9 and moved.max() > 0.5 * MAX_STEP, moved


def test_a_start_outside_the_bounds_starts_at_the_bound(monkeypatch):
    toy = _toy(monkeypatch)
    for key, out, bound in (("weight", 1.3, 1.0), ("torso-scale-horiz-decr-incr", -1.3, -1.0)):
        ph, loc = ({**TRUTH_PH, key: out}, {}) if key in TRUTH_PH else (dict(TRUTH_PH), {key: out})
        ph_b, loc_b = ({**TRUTH_PH, key: bound}, {}) if key in TRUTH_PH else (dict(TRUTH_PH), {key: bound})
        r = _refine(toy, ph, loc, iterations=1, allowance_m=0.0)
        rb = _refine(toy, ph_b, loc_b, iterations=1, allowance_m=0.0)
        assert r.phenotype == rb.phenotype and r.local == rb.local and r.energies == rb.energies, key


def test_one_gauss_newton_step_removes_most_of_a_small_error(monkeypatch):
    toy = _toy(monkeypatch)
    r = _refine(toy, {**TRUTH_PH, "weight": 0.6}, {}, iterations=1, allowance_m=0.0)
    assert r.energies[1] < 0.4 * r.energies[0], r.energies  # measured 2.05 -> 0.65


def test_no_iterations_returns_the_start(monkeypatch):
    toy = _toy(monkeypatch)
    ph = {**TRUTH_PH, "weight": 0.8}
    r = _refine(toy, ph, {"torso-scale-horiz-decr-incr": 0.1}, iterations=0)
    assert r.iterations == 0 and len(r.energies) == 1
    assert r.phenotype == ph and r.local["torso-scale-horiz-decr-incr"] == 0.1


def test_clothing_allowance_thins_the_fitted_body_by_its_thickness(monkeypatch):
    toy = _toy(monkeypatch)
    r0 = _refine(toy, dict(TRUTH_PH), {}, iterations=4, allowance_m=0.0)
    r1 = _refine(toy, dict(TRUTH_PH), {}, iterations=4, allowance_m=0.01)
    a0, a1 = _axes(r0.phenotype, r0.local), _axes(r1.phenotype, r1.local)
    # measured: from the truth the fit settles 3.7 mm thin in x, 0.4 mm thick in z; with 1 cm of clothing
    # 12.1 and 12.0 mm thinner than that
    np.testing.assert_allclose(a0[[0, 2]], toy["axes"][[0, 2]], atol=0.005)
    np.testing.assert_allclose(a0[[0, 2]] - a1[[0, 2]], 0.01, atol=0.004)
    assert abs(2 * a1[1] - toy["stature"]) < 2e-4  # the stature held


def test_unseen_modifier_returns_to_its_prior(monkeypatch):
    toy = _toy(monkeypatch)
    from bodystudio.garment.shape_refine import REFINE_ITERATIONS

    r = _refine(toy, dict(TRUTH_PH), {"stomach-pregnant-decr-incr": 0.6}, iterations=REFINE_ITERATIONS)
    assert abs(r.local["stomach-pregnant-decr-incr"]) < 0.05, r.local


def test_defaults_are_the_documented_fit(monkeypatch):
    import bodystudio.garment.shape_refine as sr

    toy = _toy(monkeypatch)
    seen = {}
    real = sr.refinement_energy

    def spy(p, phenotype, local, template, poses, camera, targets, stature_m, allowance_m=0.0):
        seen.setdefault("allowance", set()).add(allowance_m)
        return real(p, phenotype, local, template, poses, camera, targets, stature_m, allowance_m)

    monkeypatch.setattr(sr, "refinement_energy", spy)
    r = _refine(toy, {**TRUTH_PH, "weight": 0.7}, {})
    assert seen["allowance"] == {sr.CLOTHING_ALLOWANCE_M} and sr.CLOTHING_ALLOWANCE_M == 0.004
    assert r.iterations == sr.REFINE_ITERATIONS == 5


def _stand_in_normal_equations(toy, p, ph, loc, allowance_m):
    """Gauss-Newton's H and g at ``p`` written out: the frames' mean silhouette rows (forward differences of the
    posed vertices, SHAPE_FD_STEP), the stature row at STATURE_SCALE_M and the local modifiers' prior."""
    from bodystudio.garment.fit import silhouette_target
    from bodystudio.garment.shape_refine import (
        SHAPE_FD_STEP,
        STATURE_SCALE_M,
        _prior_rows,
        refined_macro_parameters,
        silhouette_rows,
    )
    from bodystudio.geometry.mesh import vertex_normals

    names = refined_macro_parameters() + tuple(k for k in _local_names())

    def body(x):
        return _shape_body(x, names, ph, loc, "toy")[0]

    b0 = body(p)
    k = len(p)
    H, g = np.zeros((k, k)), np.zeros(k)
    for pose, m in zip(POSES, toy["masks"], strict=True):
        V = b0.pose(pose)[0]
        J = np.zeros((len(V), 3, k))
        for j in range(k):
            q = p.copy()
            q[j] += SHAPE_FD_STEP
            J[:, :, j] = (body(q).pose(pose)[0] - V) / SHAPE_FD_STEP
        A, r = silhouette_rows(V, vertex_normals(V, F), J, toy["camera"], silhouette_target(m), allowance_m)
        H += A.T @ A / len(POSES)
        g += A.T @ r / len(POSES)
    a = np.array([2 * (_axes_of(body, p, j) - b0.axes[1]) / SHAPE_FD_STEP for j in range(k)]) / STATURE_SCALE_M
    H += np.outer(a, a)
    g += a * (2 * b0.axes[1] - toy["stature"]) / STATURE_SCALE_M
    P, rp = _prior_rows(p)
    return H + P.T @ P, g + P.T @ rp


def _local_names():
    from bodystudio.garment.fit import LOCAL_PARAMETERS

    return LOCAL_PARAMETERS


def _axes_of(body, p, j):
    from bodystudio.garment.shape_refine import SHAPE_FD_STEP

    q = p.copy()
    q[j] += SHAPE_FD_STEP
    return body(q).axes[1]


def test_gauss_newton_system_and_levenberg_damping(monkeypatch):
    """The first step solves (H + 1e-3 diag(H)) delta = -g with H, g of the silhouette rows, the stature row and
    the prior; later solves divide the damping by 3 after an accepted step and multiply it by 10 after a refused
    one; four refusals in a row end the refinement."""
    from bodystudio.garment.fit import LOCAL_PARAMETERS, LOCAL_PRIOR_SD, SHAPE_PRIOR_WEIGHT
    from bodystudio.garment.shape_refine import refined_macro_parameters, shape_parameters

    toy = _toy(monkeypatch)
    ph = {**TRUTH_PH, "weight": 0.62, "gender": 0.3, "height": 0.53}  # the stature 1.7 cm off: g's stature term
    solves = []
    real_solve = np.linalg.solve

    def spy(M, b):
        solves.append((M.copy(), b.copy()))
        return real_solve(M, b)

    monkeypatch.setattr(np.linalg, "solve", spy)
    r = _refine(toy, ph, {}, iterations=12, allowance_m=0.0)
    monkeypatch.undo()
    toy = _toy(monkeypatch)
    p0 = shape_parameters(ph, {})
    H, g = _stand_in_normal_equations(toy, p0, ph, {}, 0.0)
    M0, g0 = solves[0]
    np.testing.assert_allclose(g0, g, rtol=1e-6, atol=1e-9 * np.abs(g).max())
    np.testing.assert_allclose(M0, H + 1e-3 * np.diag(np.diag(H) + 1e-9), rtol=1e-6, atol=1e-9 * np.abs(H).max())
    # the damping of every solve, read off an unseen modifier's diagonal (its H is the prior's alone)
    i = len(refined_macro_parameters()) + LOCAL_PARAMETERS.index("stomach-pregnant-decr-incr")
    h = SHAPE_PRIOR_WEIGHT / LOCAL_PRIOR_SD ** 2
    d = np.array([(M[i, i] - h) / (h + 1e-9) for M, _ in solves])
    ratios = d[1:] / d[:-1]
    assert np.allclose(d[0], 1e-3, rtol=1e-6)
    kinds = [("down" if np.isclose(x, 1 / 3, rtol=1e-6) else "up" if np.isclose(x, 10.0, rtol=1e-6) else x)
             for x in ratios]
    assert set(kinds) == {"down", "up"}, kinds
    assert r.iterations < 12 and len(r.energies) == r.iterations + 2  # stopped: the last step found no lower energy
    assert kinds.count("down") == r.iterations and kinds[-3:] == ["up", "up", "up"], kinds
    assert len(d) - 1 - kinds[::-1].index("down") == len(d) - 4  # the last accepted solve, then four refused ones


def test_each_accepted_step_is_logged(monkeypatch, caplog):
    import logging

    toy = _toy(monkeypatch)
    with caplog.at_level(logging.INFO, logger="bodystudio.garment.shape_refine"):
        r = _refine(toy, {**TRUTH_PH, "weight": 0.6}, {}, iterations=2, allowance_m=0.0)
    lines = [rec.getMessage() for rec in caplog.records if "shape refinement" in rec.getMessage()]
    assert lines == [f"shape refinement step {i + 1}: energy {e:.4f}" for i, e in enumerate(r.energies[1:])]
