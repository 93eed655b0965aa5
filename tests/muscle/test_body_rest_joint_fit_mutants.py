"""Fast analytic tests of mus11d's joint rest-shape fit (``refine.fit_body_rest_shape_and_poses``), its depth energy
(``refine.depth_energy_mm``) and the stop / switch of ``capture.sequence_stage`` (issue 17, mutation testing; branch
mutL). A tiny stand-in body shape space (tests/muscle/test_body_space_standin_mutants.py's, with a bent elbow whose
joints move in the arm's plane only, so the hinge axis is the same for every shape), Eq. 10's displacements stubbed,
depth frames that pair every vertex with two fixed planes. The joint fit is compared with a reference Gauss-Newton
written here from its docstring (dense, numerical Jacobian over all unknowns, the angles damped by
``angle_damping * 0.3^2``): no body assets are read, each test runs in well under a second."""

from types import SimpleNamespace

import numpy as np
import pytest

from bodystudio.muscle import model as mm
from bodystudio.muscle.arm import ArmPose, pose_arm
from bodystudio.muscle.model import BodyShapeSpace
from bodystudio.muscle.refine import (
    depth_energy_mm,
    elbow_rotvec,
    fit_body_rest_shape_and_poses,
    posed_joints,
    skeleton_model_mesh,
)
from tests.muscle.test_body_space_standin_mutants import MACRO, N_V, X_MID, _displacements, _weights

T = 5  # frames


def _space_bent(seed=0):
    """The stand-in space with a bent elbow; the joint rows' deltas lie in the arm's plane (z = 0)."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.02, 0.5, N_V)
    ang = np.arange(N_V) * 2.1
    verts = np.c_[t, 0.04 * np.cos(ang), 0.04 * np.sin(ang)]
    joints = np.array([[0.0, 0.0, 0.0], [0.28, 0.0, 0.0], [0.5, 0.09, 0.0]])
    base = np.r_[verts, joints] + np.array([0.1, 1.3, -0.2])
    macro = 0.02 * rng.normal(size=(len(MACRO), N_V + 3, 3))
    local = 0.02 * rng.normal(size=(3, N_V + 3, 3))
    macro[:, -3:, 2] = 0.0
    local[:, -3:, 2] = 0.0
    return BodyShapeSpace(base, list(MACRO), macro, ["local/t0", "local/t1", "local/t2"], local)


class _Planes:
    """Every vertex paired twice, with two fixed planes through its planted posed position (``offset`` moves the
    planes along their normals: noise); ``keep`` limits the paired vertices."""

    def __init__(self, truth, normals, offset=None, keep=None):
        self.truth, self.normals = truth, normals
        self.offset = np.zeros(len(normals)) if offset is None else offset
        self.keep = np.arange(N_V) if keep is None else np.asarray(keep)
        self.single = False  # each kept vertex paired once (with its first plane)

    def plane_pairs(self, M):
        assert M.shape == self.truth.shape and np.abs(M - self.truth).max() < 0.2
        idx = self.keep if self.single else np.r_[self.keep, self.keep]
        sel = self.keep if self.single else np.r_[self.keep, self.keep + N_V]
        n = self.normals[sel]
        return idx, self.truth[idx] + self.offset[sel, None] * n, n


def _true_angles(J):
    out = []
    for k in range(T):
        a = np.zeros((3, 3))
        a[0] = [0.15 * k, 0.3 - 0.05 * k, -0.1 * k]
        a[1] = elbow_rotvec(J, 0.3 + 0.25 * k, 0.0)
        a[2] = [0.0, 0.1 * k, 0.05]
        out.append(a)
    return out


def _case(monkeypatch, noise=0.0, seed=5, x_true=X_MID, extra=None):
    """The planted subject ``x_true`` (its rest rows moved by ``extra``: a subject outside the space) seen in
    ``T`` frames, the placement 3.7 mm off the start's, the start's angles a few degrees off."""
    seen = {}
    monkeypatch.setattr(mm, "pose_displacements", _displacements)

    def limit(d, lim):
        seen.setdefault("limits", []).append(lim)
        return d

    monkeypatch.setattr(mm, "limit_displacement_norms", limit)
    s = _space_bent()
    model = SimpleNamespace(part_weights=_weights())
    shoulder = np.array([0.05, 1.2, 0.3])
    rest, J = s.rest_and_joints(x_true, shoulder)
    if extra is not None:
        rest, J = rest + extra[:-3], J + extra[-3:]
    true_shift = np.array([0.002, -0.003, 0.001])
    rng = np.random.default_rng(seed)
    roots, frames, true_poses = [], [], []
    for k, a in enumerate(_true_angles(J)):
        root = np.eye(4)
        root[:3, 3] = [0.01 * k, 0.0, 0.02]
        roots.append(root)
        tr = root.copy()
        tr[:3, 3] += true_shift
        p = ArmPose(tr, a)
        true_poses.append(p)
        M = pose_arm(rest + _displacements(model, a), model.part_weights, J, p)
        n = rng.normal(size=(2 * N_V, 3))
        frames.append(_Planes(M, n / np.linalg.norm(n, axis=1, keepdims=True), noise * rng.normal(size=2 * N_V)))
    # the start: the angles a few degrees off (shoulder 3, elbow flexion), the wrist as it is
    start = []
    for k, (root, a) in enumerate(zip(roots, _true_angles(J), strict=True)):
        d = np.radians(3.0) * rng.normal(size=4)
        b = a.copy()
        b[0] = a[0] + d[:3]
        b[1] = elbow_rotvec(J, 0.3 + 0.25 * k + d[3], 0.0)
        start.append(ArmPose(root, b))
    mean, sigma = s.prior()
    x0 = mean.copy()  # the macro values inside the truth's linear pieces (away from MakeHuman's kinks at 0.5)
    x0[:6] = X_MID[:6] + np.array([0.05, -0.05, 0.05, -0.05, 0.05, -0.05])
    return SimpleNamespace(space=s, model=model, shoulder=shoulder, J=J, rest=rest, shift=true_shift, frames=frames,
                           poses=start, true_poses=true_poses, mean=mean, sigma=sigma, x0=x0, seen=seen, rng=rng)


def _identifiable(x):
    return np.r_[x[:6], x[6:9] / x[6:9].sum(), x[9:]]


# --- the reference: one dense Gauss-Newton over (x, placement, every frame's four angles) --------------------------


def _unpack(c, z):
    n = c.space.n_parameters
    return z[:n], z[n:n + 3], z[n + 3:].reshape(T, 4)


def _poses_of(c, z, J):
    _, shift, A = _unpack(c, z)
    out = []
    for p, a in zip(c.poses, A, strict=True):
        root = p.root.copy()
        root[:3, 3] += shift
        out.append(ArmPose(root, np.vstack([a[:3], elbow_rotvec(J, a[3], 0.0), p.angles[2]])))
    return out


def _residuals(c, z, kw):
    """Pair residuals (per frame), tracker residuals, prior and arm-length rows: the energy's square roots."""
    x, _, _ = _unpack(c, z)
    rest, J = c.space.rest_and_joints(x, c.shoulder)
    pairs, track = [], []
    for k, (p, fr) in enumerate(zip(_poses_of(c, z, J), c.frames, strict=True)):
        M = pose_arm(rest + _displacements(c.model, p.angles), c.model.part_weights, J, p)
        idx, q, n = fr.plane_pairs(M)
        pairs.append(np.einsum("kd,kd->k", M[idx] - q, n))
        if kw.get("tracker_joints") is not None:
            track.append(np.sqrt(kw["tracker_weight"]) * (posed_joints(J, p) - kw["tracker_joints"][k]).ravel())
    lam = kw["prior_weight"] * T * 1e-6
    other = [np.sqrt(lam) * (x - c.mean) / c.sigma]
    if kw.get("arm_length_m") is not None:
        L = np.linalg.norm(np.diff(J, axis=0), axis=1).sum()
        other.append(np.sqrt(kw["arm_length_weight"] * T) * np.atleast_1d(L - kw["arm_length_m"]))
    return pairs, np.concatenate(track + other)


def _reference(c, kw, iterations):
    """The fit's Gauss-Newton written densely: Huber weights from the step's start residuals, the angles damped
    towards the step's start by ``angle_damping * 0.3^2``, the macro parameters clipped to [0, 1]."""
    n = c.space.n_parameters
    _, J0 = c.space.rest_and_joints(c.x0, c.shoulder)
    h = np.cross(J0[1] - J0[0], J0[2] - J0[1])
    h /= np.linalg.norm(h)
    A0 = np.array([np.r_[p.angles[0], p.angles[1] @ h] for p in c.poses])
    z = np.r_[c.x0, np.zeros(3), A0.ravel()]
    huber = kw["huber_m"]

    def stacked(z, w=None):
        pairs, other = _residuals(c, z, kw)
        r = np.concatenate(pairs)
        if w is None:
            w = np.minimum(1.0, huber / np.maximum(np.abs(r), 1e-12)) if huber > 0 else np.ones(len(r))
        return np.r_[np.sqrt(w) * r, other], w

    for _ in range(iterations):
        r0, w = stacked(z)
        Jac = np.stack([(stacked(z + e, w)[0] - stacked(z - e, w)[0]) / 2e-7 for e in 1e-7 * np.eye(len(z))], axis=1)
        D = np.zeros(len(z))
        D[n + 3:] = kw["angle_damping"] * 0.3 ** 2
        step = np.linalg.solve(Jac.T @ Jac + np.diag(D), -Jac.T @ r0)
        z = z + step
        z[:9] = np.clip(z[:9], 0.0, 1.0)
    x, shift, _ = _unpack(c, z)
    _, J = c.space.rest_and_joints(x, c.shoulder)
    return x, shift, _poses_of(c, z, J)


def _fit(c, **kw):
    return fit_body_rest_shape_and_poses(c.space, c.model, c.poses, c.frames, c.x0, c.shoulder, c.mean, c.sigma,
                                         **kw)


def _full_kw(**kw):
    out = dict(prior_weight=1.0, norm_limit=0.9, huber_m=0.0, iterations=3, arm_length_m=None,
               arm_length_weight=0.0, tracker_joints=None, tracker_weight=0.0, angle_damping=1.0)
    out.update(kw)
    return out


def _assert_same(got, want, atol_x=2e-5, atol_t=1e-6, atol_a=2e-5):
    """The fit against the reference: they differ by the finite differences (the space's one-sided 1e-4 step on
    the ethnic blend, the angles' 1e-5 step), measured <= 4e-6; a mutant moves them by 1e-4 .. 1e-2."""
    np.testing.assert_allclose(_identifiable(got[0]), _identifiable(want[0]), atol=atol_x)
    np.testing.assert_allclose(got[1], want[1], atol=atol_t)
    for p, q in zip(got[2], want[2], strict=True):
        np.testing.assert_allclose(p.root, q.root, atol=atol_t)
        np.testing.assert_allclose(p.angles, q.angles, atol=atol_a)


# --- fit_body_rest_shape_and_poses ------------------------------------------------------------------------------


def test_the_joint_fit_recovers_the_shape_the_placement_and_the_angles_exactly(monkeypatch):
    c = _case(monkeypatch)
    x, shift, poses = _fit(c, prior_weight=1e-9, huber_m=0.0, iterations=10, angle_damping=1e-3, norm_limit=0.6)
    np.testing.assert_allclose(_identifiable(x), _identifiable(X_MID), atol=1e-6)
    np.testing.assert_allclose(shift, c.shift, atol=1e-8)
    for p, q, s in zip(poses, c.true_poses, c.poses, strict=True):
        np.testing.assert_allclose(p.angles, q.angles, atol=1e-7)
        np.testing.assert_allclose(p.root, q.root, atol=1e-8)
        np.testing.assert_array_equal(p.angles[2], s.angles[2])  # the wrist held
    assert set(c.seen["limits"]) == {0.6}
    # the start was off (so the angles did move) and the inputs are not changed
    assert max(np.abs(p.angles[:2] - q.angles[:2]).max() for p, q in zip(c.poses, c.true_poses, strict=True)) > 0.02
    assert all(np.all(p.root[:3, 3] == [0.01 * k, 0.0, 0.02]) for k, p in enumerate(c.poses))
    # Huber weights on: the same answer (the pairs end on their planes)
    x2, shift2, _ = _fit(c, prior_weight=1e-9, huber_m=0.004, iterations=10, angle_damping=1e-3)
    np.testing.assert_allclose(_identifiable(x2), _identifiable(X_MID), atol=1e-6)
    np.testing.assert_allclose(shift2, c.shift, atol=1e-8)


@pytest.mark.parametrize("iterations", [1, 2])
def test_each_step_is_the_dense_gauss_newton_step_with_the_angles_damped(monkeypatch, iterations):
    c = _case(monkeypatch, noise=0.002)
    kw = _full_kw(prior_weight=30.0, huber_m=0.003, iterations=iterations, angle_damping=2.0)
    _assert_same(_fit(c, **kw), _reference(c, kw, iterations))


def test_the_tracker_and_the_arm_length_enter_the_step_as_the_held_pose_fits_terms(monkeypatch):
    c = _case(monkeypatch, noise=0.001)
    tracked = np.stack([posed_joints(c.J, p) for p in c.true_poses]) + 0.004 * c.rng.normal(size=(T, 3, 3))
    _, J0 = c.space.rest_and_joints(c.x0, c.shoulder)
    L = np.linalg.norm(np.diff(J0, axis=0), axis=1).sum() + 0.01
    kw = _full_kw(prior_weight=5.0, iterations=2, tracker_joints=tracked, tracker_weight=3.0, arm_length_m=L,
                  arm_length_weight=50.0, angle_damping=0.5)
    _assert_same(_fit(c, **kw), _reference(c, kw, 2))
    # a weight under 1 still counts
    kw_small = {**kw, "arm_length_weight": 0.5, "tracker_weight": 0.0}
    small = _fit(c, **kw_small)
    _assert_same(small, _reference(c, {**kw_small, "tracker_joints": None}, 2))
    assert np.abs(small[0] - _fit(c, **{**kw_small, "arm_length_m": None})[0]).max() > 5e-5
    # each term acts: without it the answer moves
    base = _fit(c, **kw)
    for drop in (dict(tracker_weight=0.0), dict(tracker_joints=None), dict(arm_length_weight=0.0),
                 dict(arm_length_m=None)):
        other = _fit(c, **{**kw, **drop})
        assert np.abs(other[0] - base[0]).max() > 1e-5, drop


def test_frames_without_pairs_keep_their_tracker_and_damping_and_the_defaults_are_the_documented_ones(monkeypatch):
    c = _case(monkeypatch, noise=0.001)
    c.frames[1].keep = np.zeros(0, int)
    c.frames[3].keep = np.array([4])
    tracked = np.stack([posed_joints(c.J, p) for p in c.true_poses])
    kw = _full_kw(prior_weight=2.0, iterations=2, tracker_joints=tracked, tracker_weight=1.0, angle_damping=0.3)
    _assert_same(_fit(c, **kw), _reference(c, kw, 2))
    # the defaults: prior 1, norm limit 0.9, Huber 4 mm, 3 steps, no length, no tracker, damping 1
    c2 = _case(monkeypatch, noise=0.001)
    got = _fit(c2)
    _assert_same(got, _reference(c2, _full_kw(huber_m=0.004), 3))
    assert set(c2.seen["limits"]) == {0.9}


def test_the_macro_parameters_are_clipped_to_the_unit_interval(monkeypatch):
    for bound, sign in ((1.0, 1.0), (0.0, -1.0)):  # a subject beyond the space's range in gender, both ways
        s = _space_bent()
        d = s.macro_deltas[0] - s.macro_deltas[0, -3]
        xb = X_MID.copy()
        xb[0] = bound
        xb[9] = -0.3
        c = _case(monkeypatch, x_true=xb, extra=sign * 0.5 * d)
        c.x0[0] = 0.5 + 0.3 * sign
        x, _, _ = _fit(c, prior_weight=1e-9, huber_m=0.0, iterations=4, angle_damping=1e-3)
        assert x[0] == bound and np.all(x[:9] >= 0.0) and np.all(x[:9] <= 1.0), x
        assert x[9] < -0.1  # the local weights are not clipped
    # zero steps: the start returned, the placement unmoved, the poses rebuilt from their angles
    xz, sz, pz = _fit(c, iterations=0)
    np.testing.assert_array_equal(xz, c.x0)
    assert np.all(sz == 0.0)
    for p, q in zip(pz, c.poses, strict=True):
        np.testing.assert_allclose(p.angles, q.angles, atol=1e-12)
        np.testing.assert_array_equal(p.root, q.root)


# --- depth_energy_mm ---------------------------------------------------------------------------------------------


def test_the_depth_energy_is_the_root_mean_huber_residual_in_mm(monkeypatch):
    c = _case(monkeypatch)
    rest, J = c.space.rest_and_joints(X_MID, c.shoulder)
    assert depth_energy_mm(c.model, c.true_poses, c.frames, rest, J) == pytest.approx(0.0, abs=1e-9)
    # planes moved by known amounts: below and above the Huber scale
    offs = []
    for k, fr in enumerate(c.frames):
        fr.offset = np.full(2 * N_V, 0.001 * (k + 1)) * np.where(np.arange(2 * N_V) % 2, 1.0, -1.0)
        offs.append(np.abs(fr.offset))
    r = np.concatenate(offs)
    for hub in (0.004, 0.0025, 0.5):
        rho = np.where(r < hub, 0.5 * r * r, hub * (r - 0.5 * hub))
        want = 1000 * np.sqrt(2 * rho.sum() / len(r))
        got = depth_energy_mm(c.model, c.true_poses, c.frames, rest, J, 0.7, hub)
        assert got == pytest.approx(want, rel=1e-9), hub
    assert c.seen["limits"][-1] == 0.7
    default = depth_energy_mm(c.model, c.true_poses, c.frames, rest, J)
    assert c.seen["limits"][-1] == 0.9
    assert default == depth_energy_mm(c.model, c.true_poses, c.frames, rest, J, 0.9, 0.004)
    # the meshes are Eq. 12's on the given rest mesh and joints
    M = skeleton_model_mesh(c.model, c.true_poses[0], rest, J, 0.9)
    np.testing.assert_allclose(M, c.frames[0].truth, atol=1e-12)
    # frames without pairs count nothing (and no pairs at all is 0, not a division by zero)
    for fr in c.frames[1:]:
        fr.keep = np.zeros(0, int)
    r0 = offs[0]
    want = 1000 * np.sqrt(2 * np.where(r0 < 0.004, 0.5 * r0 * r0, 0.004 * (r0 - 0.002)).sum() / len(r0))
    assert depth_energy_mm(c.model, c.true_poses, c.frames, rest, J) == pytest.approx(want, rel=1e-9)
    c.frames[0].single = True  # one pair in all: its own residual (1 mm, under the Huber scale)
    c.frames[0].keep = np.array([3])
    assert depth_energy_mm(c.model, c.true_poses, c.frames, rest, J) == pytest.approx(1.0, rel=1e-9)
    c.frames[0].keep = np.zeros(0, int)
    assert depth_energy_mm(c.model, c.true_poses, c.frames, rest, J) == 0.0
    with pytest.raises(ValueError):  # one frame per pose
        depth_energy_mm(c.model, c.true_poses[:2], c.frames, rest, J)


def test_the_inputs_are_checked_and_read_in_double_precision_and_lone_terms_without_weight_are_none(monkeypatch):
    c = _case(monkeypatch, noise=0.001)
    with pytest.raises(ValueError):  # one frame per pose
        fit_body_rest_shape_and_poses(c.space, c.model, c.poses, c.frames[:4], c.x0, c.shoulder, c.mean, c.sigma)
    plain = _fit(c, prior_weight=3.0)
    # a measured length or tracker joints without their weight (default 0) are no term
    np.testing.assert_array_equal(_fit(c, prior_weight=3.0, arm_length_m=0.3)[0], plain[0])
    tracked = np.zeros((T, 3, 3))
    np.testing.assert_array_equal(_fit(c, prior_weight=3.0, tracker_joints=tracked)[0], plain[0])
    # float32 spreads are read in double precision; an integer start is read as floats
    s32 = c.sigma.astype(np.float32)
    a = fit_body_rest_shape_and_poses(c.space, c.model, c.poses, c.frames, c.x0, c.shoulder, c.mean, s32, 5.0)
    b = fit_body_rest_shape_and_poses(c.space, c.model, c.poses, c.frames, c.x0, c.shoulder, c.mean,
                                      s32.astype(float), 5.0)
    np.testing.assert_array_equal(a[0], b[0])
    xi = np.r_[[1, 1, 1, 1, 1, 1, 0, 1, 0], [0, 0, 0]]
    got = fit_body_rest_shape_and_poses(c.space, c.model, c.poses, c.frames, xi, c.shoulder, c.mean, c.sigma,
                                        iterations=1)
    want = fit_body_rest_shape_and_poses(c.space, c.model, c.poses, c.frames, xi.astype(float), c.shoulder, c.mean,
                                         c.sigma, iterations=1)
    np.testing.assert_array_equal(got[0], want[0])
