"""Fast analytic tests of the garment fit's step 4c (garment/pose_refine.py), for mutation testing (issue 17).

tests/garment/test_garment_pose_refine.py refines a 2k MakeHuman body over three rendered frames (tens of seconds
per test); here a stand-in pose space (an ellipsoid turned by ``x[:3]``, moved by ``x[3:6]`` and stretched by one
"bone" parameter ``x[6]``) is filmed by the fit's camera hypothesis, and the prior and Eq. 6 are stand-ins with
known values (``fit.pose_prior_residuals`` / ``fit.interpenetration_residuals`` monkeypatched), so each test
runs in about a second:

* ``_other_residuals``: Eq. 5 at full ``beta`` against one neighbour, half against two; the prior; Eq. 6 scaled
  by sqrt(gamma) * px per metre (fx over the sample centre's depth, at least 0.1 m) / sqrt(probes);
* ``pose_refinement_energy``: the rim rows of step 4b (with the allowance) plus the other terms, squared;
* ``refine_frame_pose``: recovers a planted pose on the stand-in; the first system is H + 1e-3 diag(H) of the
  finite-difference Jacobian; damping / 3 after an accepted step (not below 1e-6), x 10 after a refused one, four
  refusals end it; the step capped at 0.1 rad and 0.01 m; equal energy refused; no steps return the start;
* ``refine_poses_to_silhouettes``: sweeps over the clip with the neighbours of the previous sweep, the energies
  of the first and the last sweep, the non-fitted bones kept.
"""

from types import SimpleNamespace

import numpy as np
import pytest

W, H = 240, 320
SEMI = np.array([0.25, 0.8, 0.15])
X_TRUE = np.array([0.0, 0.3, 0.0, 0.02, 0.0, -3.0, 0.0])


def _ellipsoid():
    import trimesh

    s = trimesh.creation.icosphere(subdivisions=3)
    return np.asarray(s.vertices, float) * SEMI + [0.0, 1.0, 0.0], np.asarray(s.faces, np.int64)


class _Space:
    """Stands in for :class:`fit.PoseSpace`: rotation ``x[:3]`` about the origin, translation ``x[3:6]``, the
    height scaled by ``1 + x[6]``."""

    def __init__(self):
        self.V0, F = _ellipsoid()
        self.body = SimpleNamespace(faces=F)
        self.sample_ids = np.arange(0, len(self.V0), 5)
        self.n_params = 7

    def transforms(self, x):
        return np.asarray(x, float) * 2.0 + 1.0  # a recognisable stand-in for the bone transforms

    def vertices(self, x, ids=None, T=None):
        from scipy.spatial.transform import Rotation

        R = Rotation.from_rotvec(x[:3]).as_matrix()
        V = (self.V0 * [1.0, 1.0 + x[6], 1.0]) @ R.T + x[3:6]
        return V if ids is None else V[ids]


def _stub_terms(monkeypatch, state):
    """The prior 0.2 * x[6]; Eq. 6 ``state.depth`` per probe, its calls recorded in ``state.calls``."""
    from bodystudio.garment import fit as gf

    def prior(x, space):
        state.prior_spaces.append(space)
        return np.array([0.2 * x[6]])

    def inter(V, T, spheres):
        state.calls.append((V.copy(), np.asarray(T).copy()))
        state.spheres.append(spheres)
        return np.full(len(V), state.depth)

    monkeypatch.setattr(gf, "pose_prior_residuals", prior)
    monkeypatch.setattr(gf, "interpenetration_residuals", inter)


@pytest.fixture()
def stand_ins():
    """The stand-in space filmed at its true pose ``X_TRUE`` (the matte), the probes, the stubs' state."""
    from bodystudio.garment import fit as gf

    space = _Space()
    cam = gf.camera_hypothesis(W, H)
    spheres = SimpleNamespace(probe_ids=np.arange(3, len(space.V0), 11))
    mask = gf.model_silhouette(space.vertices(X_TRUE), space.body.faces, cam)
    return SimpleNamespace(space=space, camera=cam, spheres=spheres, target=gf.silhouette_target(mask),
                           state=SimpleNamespace(depth=0.0, calls=[], prior_spaces=[], spheres=[]))


def test_other_residuals_terms(stand_ins, monkeypatch):
    from bodystudio.garment import fit as gf
    from bodystudio.garment.pose_refine import _other_residuals

    s = stand_ins
    _stub_terms(monkeypatch, s.state)
    s.state.depth = 0.004
    x = X_TRUE + [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.1]
    a, b = x + 0.05, x - 0.1
    r2 = _other_residuals(x, s.space, s.spheres, s.camera, [a, b])
    nt = len(gf.temporal_residuals(x, a))
    np.testing.assert_allclose(r2[:nt], gf.temporal_residuals(x, a, beta=gf.BETA_TEMPORAL / 2))
    np.testing.assert_allclose(r2[nt:2 * nt], gf.temporal_residuals(x, b, beta=gf.BETA_TEMPORAL / 2))
    np.testing.assert_allclose(r2[2 * nt], 0.2 * x[6])
    centre = s.space.vertices(x, s.space.sample_ids).mean(0, keepdims=True)
    z = float(s.camera.world_to_camera(centre)[0, 2])
    assert 2.9 < z < 3.1
    n = len(s.spheres.probe_ids)
    want = np.sqrt(gf.GAMMA_INTERPENETRATION) * s.camera.fx / z * 0.004 / np.sqrt(n)
    np.testing.assert_allclose(r2[2 * nt + 1:], np.full(n, want), rtol=1e-12)
    assert len(r2) == 2 * nt + 1 + n
    V, T = s.state.calls[-1]
    np.testing.assert_allclose(V, s.space.vertices(x, s.spheres.probe_ids))
    np.testing.assert_allclose(T, s.space.transforms(x))
    assert s.state.spheres[-1] is s.spheres and s.state.prior_spaces[-1] is s.space
    r1 = _other_residuals(x, s.space, s.spheres, s.camera, [a])
    np.testing.assert_allclose(r1[:nt], gf.temporal_residuals(x, a))
    np.testing.assert_allclose(r1[nt:], r2[2 * nt:])
    r0 = _other_residuals(x, s.space, s.spheres, s.camera, [])
    np.testing.assert_allclose(r0, r2[2 * nt:])
    # a centre closer than 0.1 m in front of the camera (or behind it) counts as 0.1 m
    near = x.copy()
    near[5] = -0.05  # the centre 5 cm in front of the camera
    zn = float(s.camera.world_to_camera(s.space.vertices(near, s.space.sample_ids).mean(0, keepdims=True))[0, 2])
    assert zn < 0.1
    rn = _other_residuals(near, s.space, s.spheres, s.camera, [])
    np.testing.assert_allclose(rn[1:], np.sqrt(gf.GAMMA_INTERPENETRATION) * s.camera.fx / 0.1 * 0.004 / np.sqrt(n))


def test_energy_is_rim_rows_plus_other_terms(stand_ins, monkeypatch):
    from bodystudio.garment.pose_refine import _other_residuals, pose_refinement_energy
    from bodystudio.garment.shape_refine import silhouette_rows
    from bodystudio.geometry.mesh import vertex_normals

    s = stand_ins
    _stub_terms(monkeypatch, s.state)
    s.state.depth = 0.003
    x = X_TRUE + [0.0, 0.1, 0.0, 0.02, 0.0, 0.0, 0.05]
    nb = [X_TRUE]
    for allowance in (0.0, 0.02):
        V = s.space.vertices(x)
        r = silhouette_rows(V, vertex_normals(V, s.space.body.faces), None, s.camera, s.target, allowance)[1]
        other = _other_residuals(x, s.space, s.spheres, s.camera, nb)
        want = np.sum(r ** 2) + np.sum(other ** 2)
        got = pose_refinement_energy(x, s.space, s.spheres, s.camera, s.target, nb, allowance)
        assert np.sum(r ** 2) > 1.0 and np.sum(other ** 2) > 1.0
        np.testing.assert_allclose(got, want, rtol=1e-12)
    assert pose_refinement_energy(x, s.space, s.spheres, s.camera, s.target, nb, 0.02) != \
        pose_refinement_energy(x, s.space, s.spheres, s.camera, s.target, nb, 0.0)


def test_recovers_a_planted_pose(stand_ins, monkeypatch):
    from bodystudio.garment.pose_refine import pose_refinement_energy, refine_frame_pose

    s = stand_ins
    _stub_terms(monkeypatch, s.state)
    x0 = X_TRUE + [0.0, 0.0, 0.05, 0.02, 0.0, 0.0, 0.0]
    x, e0, e1 = refine_frame_pose(x0, s.space, s.spheres, s.camera, s.target, [], 0.0, steps=12)
    np.testing.assert_allclose(e0, pose_refinement_energy(x0, s.space, s.spheres, s.camera, s.target, [], 0.0))
    np.testing.assert_allclose(e1, pose_refinement_energy(x, s.space, s.spheres, s.camera, s.target, [], 0.0))
    # the roll and the sideways shift are what a silhouette at 3 m pins down (the depth, the height and a pitch
    # trade against each other on an ellipsoid): both mostly removed, the energy too
    err0, err = np.abs(x0 - X_TRUE), np.abs(x - X_TRUE)
    assert e1 < 0.1 * e0, (e0, e1)
    assert err[2] < 0.3 * err0[2] and err[3] < 0.3 * err0[3], (err0, err)
    # no steps: the start and its energy
    xs, a, b = refine_frame_pose(x0, s.space, s.spheres, s.camera, s.target, [], 0.0, steps=0)
    np.testing.assert_array_equal(xs, x0)
    assert a == b == e0
    # the default number of steps is POSE_REFINE_STEPS (3): more than one step's reach, less than twelve steps'
    x3, _, e3 = refine_frame_pose(x0, s.space, s.spheres, s.camera, s.target, [], 0.0)
    x1, _, e1s = refine_frame_pose(x0, s.space, s.spheres, s.camera, s.target, [], 0.0, steps=1)
    x3b, _, e3b = refine_frame_pose(x0, s.space, s.spheres, s.camera, s.target, [], 0.0, steps=3)
    np.testing.assert_array_equal(x3, x3b)
    assert e1 <= e3 < e1s < e0


class _SolveSpy:
    def __init__(self):
        self.calls = []

    def __call__(self, M, g):
        self.calls.append((M.copy(), g.copy()))
        return np.linalg.inv(M) @ g


def test_first_system_and_the_step_cap(stand_ins, monkeypatch):
    from bodystudio.garment import pose_refine as pr
    from bodystudio.garment.shape_refine import silhouette_rows
    from bodystudio.geometry.mesh import vertex_normals

    s = stand_ins
    _stub_terms(monkeypatch, s.state)
    s.state.depth = 0.002
    x0 = X_TRUE + [0.0, 0.15, 0.0, 0.03, 0.0, -0.04, -0.08]
    nb = [X_TRUE + 0.01]
    spy = _SolveSpy()
    tried = []
    real = pr.pose_refinement_energy

    def energy(x, *a):
        tried.append(np.array(x, float))
        return real(x, *a)

    with monkeypatch.context() as m:
        m.setattr(pr.np.linalg, "solve", spy)
        m.setattr(pr, "pose_refinement_energy", energy)
        pr.refine_frame_pose(x0, s.space, s.spheres, s.camera, s.target, nb, 0.01, steps=1)
    # H and g written out: the rim rows through the vertices' forward-difference Jacobian, the other terms' own
    k = len(x0)
    V = s.space.vertices(x0)
    J = np.empty((len(V), 3, k))
    ro = pr._other_residuals(x0, s.space, s.spheres, s.camera, nb)
    Jo = np.empty((len(ro), k))
    for j in range(k):
        q = x0.copy()
        q[j] += 1e-3
        J[:, :, j] = (s.space.vertices(q) - V) / 1e-3
        Jo[:, j] = (pr._other_residuals(q, s.space, s.spheres, s.camera, nb) - ro) / 1e-3
    A, r = silhouette_rows(V, vertex_normals(V, s.space.body.faces), J, s.camera, s.target, 0.01)
    Hm = A.T @ A + Jo.T @ Jo
    g = A.T @ r + Jo.T @ ro
    M, g_seen = spy.calls[0]
    np.testing.assert_allclose(g_seen, g, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(M, Hm + 1e-3 * np.diag(np.diag(Hm) + 1e-9), rtol=1e-9, atol=1e-9)
    # the step tried: -M^-1 g, scaled so that no rotation moves more than 0.1 rad, the translation 0.01 m
    delta = -np.linalg.solve(M, g)
    limit = np.array([0.1, 0.1, 0.1, 0.01, 0.01, 0.01, 0.1])
    over = np.max(np.abs(delta) / limit)
    assert over > 1.0
    np.testing.assert_allclose(tried[1] - x0, delta / over, rtol=1e-9, atol=1e-12)
    assert np.isclose(np.max(np.abs(tried[1] - x0) / limit), 1.0)


def _damping_run(monkeypatch, stand_ins, energies, steps):
    """refine_frame_pose with fixed rows (the rim rows A, r; no other terms), so H = A^T A in every step, and the
    energy played back from ``energies``; the damping read off each solve's diagonal."""
    from bodystudio.garment import pose_refine as pr
    from bodystudio.garment import shape_refine as sr

    s = stand_ins
    rng = np.random.default_rng(3)
    A = rng.normal(size=(12, 7))
    r = rng.normal(size=12)
    spy = _SolveSpy()
    seq = iter(energies)
    x0 = X_TRUE + [0.0, 0.05, 0.0, 0.0, 0.0, 0.0, 0.0]
    with monkeypatch.context() as m:
        m.setattr(pr.np.linalg, "solve", spy)
        m.setattr(pr, "pose_refinement_energy", lambda x, *a: next(seq))
        m.setattr(sr, "silhouette_rows", lambda V, N, J, *a: (A, r))
        m.setattr(pr, "_other_residuals", lambda x, *a: np.zeros(2))
        out = pr.refine_frame_pose(x0, s.space, s.spheres, s.camera, s.target, [], 0.0, steps=steps)
    Hm = A.T @ A
    for M, g in spy.calls:
        np.testing.assert_allclose(g, A.T @ r)
        np.testing.assert_allclose(M - np.diag(np.diag(M)), Hm - np.diag(np.diag(Hm)), atol=1e-12)
    damp = [float(np.mean((np.diag(M) - np.diag(Hm)) / (np.diag(Hm) + 1e-9))) for M, _ in spy.calls]
    return out, x0, np.array(damp), spy


def test_refusals_raise_the_damping_and_four_end_it(stand_ins, monkeypatch):
    (x, e0, e1), x0, damp, spy = _damping_run(monkeypatch, stand_ins, [5.0] * 20, steps=3)
    assert len(spy.calls) == 4  # equal energy is refused; four refusals end the refinement
    np.testing.assert_array_equal(x, x0)
    assert e0 == e1 == 5.0
    np.testing.assert_allclose(damp, [1e-3, 1e-2, 1e-1, 1.0], rtol=1e-6)


def test_accepted_steps_lower_the_damping_to_a_floor(stand_ins, monkeypatch):
    energies = [10.0 - 0.5 * i for i in range(12)]
    (x, e0, e1), x0, damp, spy = _damping_run(monkeypatch, stand_ins, energies, steps=9)
    assert len(spy.calls) == 9 and e0 == 10.0 and e1 == 10.0 - 0.5 * 9
    np.testing.assert_allclose(damp, np.maximum(1e-3 / 3.0 ** np.arange(9), 1e-6), rtol=1e-6)
    # each accepted step moves x by -M^-1 g (capped): the sum of the steps
    total = sum(-np.linalg.inv(M) @ g for M, g in spy.calls)
    assert not np.allclose(x, x0)
    assert np.all(np.abs(total) > 0)
    # a refusal after accepted steps: x stays at the last accepted one, the damping rises from there
    energies = [10.0, 9.0, 9.5, 8.0] + [8.0] * 10
    (x, e0, e1), x0, damp, spy = _damping_run(monkeypatch, stand_ins, energies, steps=2)
    np.testing.assert_allclose(damp, [1e-3, 1e-3 / 3, 1e-3 / 3 * 10], rtol=1e-6)
    assert e1 == 8.0


def test_sweeps_use_the_previous_sweeps_neighbours(monkeypatch, caplog):
    import logging

    from bodystudio.garment import fit as gf
    from bodystudio.garment import pose_refine as pr

    class Sp:
        bone_ids = np.array([2])

        def x_from_pose(self, p):
            return np.r_[p.rotations[0], p.translation, p.rotations[2]]

        def pose(self, x):
            rot = np.full((4, 3), 9.0)
            rot[0], rot[2] = x[:3], x[6:9]
            return SimpleNamespace(rotations=rot, translation=x[3:6])

    sp = Sp()
    body = SimpleNamespace(skeleton=SimpleNamespace(index=lambda name: {"Root": 0}[name]))
    monkeypatch.setattr(gf, "pose_space", lambda b: sp if b is body else None)
    monkeypatch.setattr(gf, "penetration_spheres", lambda b: "spheres" if b is body else None)
    monkeypatch.setattr(gf, "silhouette_target", lambda m: ("target", float(m[0, 0])))
    calls = []

    def frame(x, space, spheres, camera, target, neighbours, allowance, steps):
        assert space is sp and spheres == "spheres" and camera == "cam" and allowance == 0.02
        calls.append((x.copy(), target, [n.copy() for n in neighbours], steps))
        c = len(calls)
        return x + 1.0, 100.0 * c + 1.0, 100.0 * c + 2.0

    monkeypatch.setattr(pr, "refine_frame_pose", frame)
    from bodystudio.body.pose import Pose

    rng = np.random.default_rng(0)
    poses = [Pose(rng.normal(size=(4, 3)), rng.normal(size=3)) for _ in range(3)]
    masks = np.arange(3, dtype=float)[:, None, None] * np.ones((3, 2, 2))
    X0 = np.stack([sp.x_from_pose(p) for p in poses])
    with caplog.at_level(logging.INFO, logger="bodystudio.garment.pose_refine"):
        out, info = pr.refine_poses_to_silhouettes(body, poses, masks, "cam", 0.02, sweeps=2, steps=7)
    assert len(calls) == 6 and all(c[3] == 7 for c in calls)
    assert [c[1][1] for c in calls] == [0.0, 1.0, 2.0] * 2
    # sweep 1: frame 1 sees frames 0 and 2 as they were before the sweep (not frame 0 already refined)
    np.testing.assert_allclose(calls[1][2][0], X0[0])
    np.testing.assert_allclose(calls[1][2][1], X0[2])
    assert len(calls[0][2]) == 1 and len(calls[2][2]) == 1
    np.testing.assert_allclose(calls[0][2][0], X0[1])
    np.testing.assert_allclose(calls[2][2][0], X0[1])
    # sweep 2: the neighbours after sweep 1
    np.testing.assert_allclose(calls[4][2][0], X0[0] + 1.0)
    np.testing.assert_allclose(calls[4][2][1], X0[2] + 1.0)
    np.testing.assert_allclose(calls[3][0], X0[0] + 1.0)
    np.testing.assert_allclose(info.X, X0 + 2.0)
    np.testing.assert_allclose(info.energies[:, 0], [101.0, 201.0, 301.0])
    np.testing.assert_allclose(info.energies[:, 1], [402.0, 502.0, 602.0])
    for p, q, x in zip(out, poses, info.X, strict=True):
        assert isinstance(p, Pose)
        np.testing.assert_allclose(p.rotations[[1, 3]], q.rotations[[1, 3]])
        np.testing.assert_allclose(p.rotations[0], x[:3])
        np.testing.assert_allclose(p.rotations[2], x[6:9])
        np.testing.assert_allclose(p.translation, x[3:6])
    assert "pose refinement sweep 2: mean energy 502.0000" in caplog.text
    assert [r.getMessage() for r in caplog.records if r.name == "bodystudio.garment.pose_refine"][-1] == \
        "pose refinement sweep 2: mean energy 502.0000"
    assert info.energies.shape == (3, 2)
    assert "pose refinement sweep 1: mean energy 202.0000" in caplog.text
    # the defaults: POSE_REFINE_SWEEPS sweeps of POSE_REFINE_STEPS steps; no sweeps return the input
    calls.clear()
    pr.refine_poses_to_silhouettes(body, poses, masks, "cam", 0.02)
    assert len(calls) == 3 * pr.POSE_REFINE_SWEEPS == 12 and all(c[3] == pr.POSE_REFINE_STEPS == 3 for c in calls)
    calls.clear()
    out0, info0 = pr.refine_poses_to_silhouettes(body, poses, masks, "cam", 0.02, sweeps=0)
    assert not calls
    np.testing.assert_allclose(info0.X, X0)
    np.testing.assert_array_equal(info0.energies, 0.0)


def test_step_cap_per_parameter(stand_ins, monkeypatch):
    """H = I: the undamped step is -r / 1.001; rotations are capped at 0.1 rad, the translation at 0.01 m, the
    stretch (a bone parameter) at 0.1: a step 1.5 times the translation's cap is scaled by 1 / 1.5."""
    from bodystudio.garment import pose_refine as pr
    from bodystudio.garment import shape_refine as sr

    s = stand_ins
    want = np.array([0.05, 0.0, 0.0, 0.015, 0.0, 0.0, 0.12])
    r = -want * (1.0 + 1e-3)
    tried = []

    def energy(x, *a):
        tried.append(np.array(x, float))
        return 1.0 if len(tried) == 1 else 0.5

    with monkeypatch.context() as m:
        m.setattr(pr, "pose_refinement_energy", energy)
        m.setattr(sr, "silhouette_rows", lambda V, N, J, *a: (np.eye(7), r))
        m.setattr(pr, "_other_residuals", lambda x, *a: np.zeros(1))
        x, e0, e1 = pr.refine_frame_pose(X_TRUE, s.space, s.spheres, s.camera, s.target, [], 0.0, steps=1)
    np.testing.assert_allclose(x - X_TRUE, want / 1.5, rtol=1e-6, atol=1e-12)
    assert (e0, e1) == (1.0, 0.5)


def test_a_parameter_the_rows_do_not_see_stays_solvable(stand_ins, monkeypatch):
    """A zero column of the rows (H_ii = 0): the damping adds damping * 1e-9 (positive) to that diagonal entry."""
    from bodystudio.garment import pose_refine as pr
    from bodystudio.garment import shape_refine as sr

    s = stand_ins
    A = np.random.default_rng(1).normal(size=(12, 7))
    A[:, 6] = 0.0
    spy = _SolveSpy()
    with monkeypatch.context() as m:
        m.setattr(pr.np.linalg, "solve", spy)
        m.setattr(pr, "pose_refinement_energy", lambda x, *a: 1.0)
        m.setattr(sr, "silhouette_rows", lambda V, N, J, *a: (A, np.ones(12)))
        m.setattr(pr, "_other_residuals", lambda x, *a: np.zeros(1))
        pr.refine_frame_pose(X_TRUE, s.space, s.spheres, s.camera, s.target, [], 0.0, steps=1)
    np.testing.assert_allclose([M[6, 6] for M, _ in spy.calls], [1e-12, 1e-11, 1e-10, 1e-9], rtol=1e-6)


def test_an_integer_start_is_a_float_start(stand_ins, monkeypatch):
    from bodystudio.garment.pose_refine import refine_frame_pose

    s = stand_ins
    _stub_terms(monkeypatch, s.state)
    x0 = np.array([0, 0, 0, 0, 0, -3, 0])
    xi, ei0, ei1 = refine_frame_pose(x0, s.space, s.spheres, s.camera, s.target, [], 0.0, steps=2)
    xf, ef0, ef1 = refine_frame_pose(x0.astype(float), s.space, s.spheres, s.camera, s.target, [], 0.0, steps=2)
    assert ei1 < ei0
    np.testing.assert_allclose(xi, xf)
    assert (ei0, ei1) == (ef0, ef1)


def test_constants():
    from bodystudio.garment import pose_refine as pr

    assert pr.POSE_FD_STEP == 1e-3 and pr.MAX_POSE_STEP == 0.1


def test_fit_wiring_of_steps_4b_and_4c(monkeypatch):
    """``fit.refine_fit_shape_and_poses``: step 4b's shape, then (with ``pose_refinement``) every pose refined on
    that shape's body by ``refine_fit_poses`` (= ``refine_poses_to_silhouettes(...)[0]``); timings in ms per frame."""
    from bodystudio.garment import fit as gf
    from bodystudio.garment import pose_refine as pr

    calls = []
    shape_out = SimpleNamespace(body="body-4b")

    def shape_step(shape, poses, masks, camera, stature, template, allowance):
        calls.append(("4b", shape, list(poses), masks, camera, stature, template, allowance))
        return shape_out

    def pose_step(body, poses, masks, camera, allowance):
        calls.append(("4c", body, list(poses), masks, camera, allowance))
        return ["p1", "p2", "p3", "p4"], "info"

    monkeypatch.setattr(gf, "refine_fit_shape", shape_step)
    monkeypatch.setattr(pr, "refine_poses_to_silhouettes", pose_step)
    assert gf.refine_fit_poses("b", ["a"], "m", "c", 0.02) == ["p1", "p2", "p3", "p4"]
    assert calls.pop() == ("4c", "b", ["a"], "m", "c", 0.02)
    timings = {"pose": 1.0}
    poses = ["q1", "q2", "q3", "q4"]
    shape, out = gf.refine_fit_shape_and_poses("s0", poses, "masks", "cam", 1.7, "2k", 0.01, timings=timings)
    assert shape is shape_out and out == ["p1", "p2", "p3", "p4"]
    assert calls == [("4b", "s0", poses, "masks", "cam", 1.7, "2k", 0.01), ("4c", "body-4b", poses, "masks", "cam",
                                                                             0.01)]
    assert set(timings) == {"pose", "shape_refinement", "pose_refinement"} and timings["pose"] == 1.0
    assert 0.0 <= timings["shape_refinement"] < 1e3 and 0.0 <= timings["pose_refinement"] < 1e3
    # the time per frame: a clock that advances 8 s per call over 4 frames reads 2000 ms per frame
    clock = iter(np.arange(0.0, 80.0, 8.0))
    monkeypatch.setattr(gf.time, "perf_counter", lambda: float(next(clock)))
    t2 = {}
    gf.refine_fit_shape_and_poses("s0", poses, "masks", "cam", 1.7, "2k", 0.01, timings=t2)
    assert t2 == {"shape_refinement": 2000.0, "pose_refinement": 2000.0}
    calls.clear()
    t3 = {}
    shape, out = gf.refine_fit_shape_and_poses("s0", poses, "masks", "cam", 1.7, "2k", 0.01, pose_refinement=False,
                                               timings=t3)
    assert out is poses and [c[0] for c in calls] == ["4b"] and set(t3) == {"shape_refinement"}
    shape, out = gf.refine_fit_shape_and_poses("s0", poses, "masks", "cam", 1.7, "2k", 0.01)  # no timings given
    assert out == ["p1", "p2", "p3", "p4"]
