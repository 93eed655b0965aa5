"""Fast analytic tests of the body shape space (``model.BodyShapeSpace``, ``project_to_body_space``,
``body_parameters_of``, ``body_shape_space``) and of ``refine.fit_body_rest_shape`` on a tiny stand-in space (issue 17,
mutation testing of mus11c's body rest shape): a few rows, single-part macro targets whose MakeHuman weights are known
in closed form (``macrodetails/male`` = gender, ``maxweight`` = max(0, 2 weight - 1), ...), random local targets.
No body assets are read, so each test runs in milliseconds."""

from types import SimpleNamespace

import numpy as np
import pytest

from bodystudio.muscle import model as mm
from bodystudio.muscle.arm import ArmPose, part_transforms, pose_arm
from bodystudio.muscle.model import (
    BODY_LOCAL_PRIOR_SIGMA,
    BODY_MACRO_NAMES,
    BODY_MACRO_PRIOR,
    BodyShapeSpace,
    project_to_body_space,
)
from bodystudio.muscle.refine import fit_body_rest_shape, posed_joints

# single-part macro targets: their weight is one of Phenotype.macro_values() (Eq. of MakeHuman's human.py)
MACRO = ["macrodetails/male", "macrodetails/old", "macrodetails/maxmuscle", "macrodetails/maxweight",
         "macrodetails/minweight", "macrodetails/maxheight", "macrodetails/idealproportions",
         "macrodetails/african", "macrodetails/caucasian"]
N_V = 12  # template vertices; rows are these and the shoulder, elbow, wrist


def _expected_macro_weights(x):
    g, a, mu, w, h, p = np.clip(x[:6], 0, 1)
    eth = np.maximum(np.clip(x[6:9], 0, 1), 1e-3)
    eth = eth / eth.sum()
    return np.array([g, max(0.0, 2 * a - 1), max(0.0, 2 * mu - 1), max(0.0, 2 * w - 1), max(0.0, 1 - 2 * w),
                     max(0.0, 2 * h - 1), max(0.0, 2 * p - 1), eth[0], eth[2]])


def _space(n_local=3, seed=0, macro_scale=0.02):
    rng = np.random.default_rng(seed)
    t = np.linspace(0.02, 0.5, N_V)
    ang = np.arange(N_V) * 2.1
    verts = np.c_[t, 0.04 * np.cos(ang), 0.04 * np.sin(ang)]
    joints = np.array([[0.0, 0.0, 0.0], [0.28, 0.0, 0.0], [0.52, 0.0, 0.0]])
    base = np.r_[verts, joints] + np.array([0.1, 1.3, -0.2])  # not shoulder-centred: the space must move it
    return BodyShapeSpace(base, list(MACRO), macro_scale * rng.normal(size=(len(MACRO), N_V + 3, 3)),
                          [f"local/t{k}" for k in range(n_local)], 0.02 * rng.normal(size=(n_local, N_V + 3, 3)))


def _identifiable(x):
    """The parameters up to the ethnic mix's scale (MakeHuman normalises it by its sum)."""
    return np.r_[x[:6], x[6:9] / x[6:9].sum(), x[9:]]


X_MID = np.array([0.3, 0.7, 0.6, 0.65, 0.7, 0.62, 0.3, 0.5, 0.3, 0.4, -0.2, 0.1])  # macro in one linear piece each


def test_macro_weights_are_makehumans_blend_clipped_with_the_ethnic_floor():
    s = _space()
    np.testing.assert_allclose(s.macro_weights(X_MID), _expected_macro_weights(X_MID), atol=1e-12)
    x = np.array([1.5, -0.2, 0.4, 0.2, 1.2, 0.9, 0.0, 0.0, 0.0])  # clipped; ethnic all 0 -> floor -> thirds
    w = s.macro_weights(x)
    np.testing.assert_allclose(w, [1.0, 0.0, 0.0, 0.0, 0.6, 1.0, 0.8, 1 / 3, 1 / 3], atol=1e-12)
    np.testing.assert_allclose(s.macro_weights(np.r_[0.5, 0.5, 0.5, 0.5, 0.5, 0.5, 0.0, 0.0, 2.0]),
                               [0.5, 0, 0, 0, 0, 0, 0, 1e-3 / 1.002, 1 / 1.002], atol=1e-12)
    assert s.macro_weights(X_MID).shape == (len(MACRO),)
    assert s.n_parameters == len(BODY_MACRO_NAMES) + 3 and s.n_vertices == N_V


def test_a_macro_target_the_phenotype_gives_no_weight_gets_zero():
    s = _space()
    x = np.r_[0.3, 0.7, 0.6, 0.3, 0.7, 0.62, 0.3, 0.5, 0.3]  # weight 0.3 < 0.5: maxweight absent from the blend
    assert s.macro_weights(x)[3] == 0.0 and s.macro_weights(x)[4] == pytest.approx(0.4)


def test_shaped_rows_add_the_weighted_macro_and_local_targets_and_rest_and_joints_sit_at_the_shoulder():
    s = _space()
    R = s.shaped_rows(X_MID)
    want = (s.base + np.einsum("m,mrd->rd", _expected_macro_weights(X_MID), s.macro_deltas)
            + np.einsum("l,lrd->rd", X_MID[9:], s.local_deltas))
    np.testing.assert_allclose(R, want, atol=1e-12)
    rest, J = s.rest_and_joints(X_MID)
    assert rest.shape == (N_V, 3) and J.shape == (3, 3)
    np.testing.assert_allclose(np.r_[rest, J], want - want[-3], atol=1e-12)
    shoulder = np.array([0.2, -0.1, 1.0])
    rest2, J2 = s.rest_and_joints(X_MID, shoulder)
    np.testing.assert_allclose(J2[0], shoulder, atol=1e-12)
    np.testing.assert_allclose(np.r_[rest2, J2], want - want[-3] + shoulder, atol=1e-12)


def test_the_jacobian_is_the_shoulder_relative_derivative_one_sided_into_the_unit_interval():
    s = _space()

    def rel(x):
        R = s.shaped_rows(x)
        return R - R[-3]

    D = s.jacobian(X_MID)
    assert D.shape == (12, N_V + 3, 3)
    for k in range(12):
        e = np.zeros(12)
        e[k] = 1e-6
        # exact on the linear pieces; the ethnic blend (normalised by its sum) to the one-sided step's error
        np.testing.assert_allclose(D[k], (rel(X_MID + e) - rel(X_MID - e)) / 2e-6, atol=1e-7 if k not in (6, 7, 8)
                                   else 1e-5)
    np.testing.assert_allclose(D[:, -3], 0.0, atol=1e-15)
    # at the kink weight = 0.5 the forward difference (slope of max(0, 2w - 1): 2) is taken, at 1.0 the backward one
    x = X_MID.copy()
    x[3] = 0.5
    np.testing.assert_allclose(s.jacobian(x)[3], 2 * (s.macro_deltas[3] - s.macro_deltas[3, -3]), atol=1e-9)
    x[3] = 1.0
    np.testing.assert_allclose(s.jacobian(x)[3], 2 * (s.macro_deltas[3] - s.macro_deltas[3, -3]), atol=1e-9)
    x[3] = 1.0 - 0.5e-4  # a forward step of 1e-4 would leave the interval
    np.testing.assert_allclose(s.jacobian(x)[3], 2 * (s.macro_deltas[3] - s.macro_deltas[3, -3]), atol=1e-9)
    x[3] = 0.5 - 0.5e-2  # the step is the argument: a step of 1e-2 crosses the kink (mean slopes 1 and -1)
    d = s.macro_deltas[3] - s.macro_deltas[4]
    np.testing.assert_allclose(s.jacobian(x, step=1e-2)[3], d - d[-3], atol=1e-9)
    np.testing.assert_allclose(s.jacobian(x, step=1e-2)[0], s.macro_deltas[0] - s.macro_deltas[0, -3], atol=1e-9)


def test_the_prior_is_the_populations_with_the_measured_sex_and_muscularity():
    s = _space(n_local=2)
    mean, sigma = s.prior()
    np.testing.assert_allclose(mean, [BODY_MACRO_PRIOR[n][0] for n in BODY_MACRO_NAMES] + [0, 0])
    np.testing.assert_allclose(sigma, [BODY_MACRO_PRIOR[n][1] for n in BODY_MACRO_NAMES] + [0.25, 0.25])
    assert BODY_LOCAL_PRIOR_SIGMA == 0.25 and mean[1] == pytest.approx(0.6875) and sigma[3] == 0.15
    for sex, want in ((1.0, 0.95), (0.0, 0.05), (0.3, 0.3)):
        m, sg = s.prior(SimpleNamespace(sex=sex, muscularity=0.8))
        assert m[0] == pytest.approx(want) and m[2] == pytest.approx(0.8)
        np.testing.assert_allclose(np.delete(m, [0, 2]), np.delete(mean, [0, 2]))
        np.testing.assert_allclose(sg, sigma)


def test_the_projection_recovers_a_planted_point_from_a_moved_rest_mesh():
    s = _space()
    mean, sigma = s.prior()
    rows = s.shaped_rows(X_MID) + np.array([0.3, -0.2, 0.5])  # anywhere: only shoulder-relative rows count
    x = project_to_body_space(s, rows[:-3], rows[-3:], mean, sigma, prior_weight=1e-9)
    np.testing.assert_allclose(_identifiable(x), _identifiable(X_MID), atol=1e-7)
    np.testing.assert_allclose(project_to_body_space(s, rows[:-3], rows[-3:], mean, sigma, iterations=0), mean)
    # one Gauss-Newton step from the prior is not enough (the ethnic blend is not linear)
    x1 = project_to_body_space(s, rows[:-3], rows[-3:], mean, sigma, prior_weight=1e-9, iterations=1)
    assert np.abs(_identifiable(x1) - _identifiable(X_MID)).max() > 5e-6


def test_the_projections_prior_is_ridge_regression_with_weight_per_vertex_in_mm():
    # macro targets without effect: the local weights are a ridge regression, closed form
    s = _space(macro_scale=0.0)
    mean, sigma = s.prior()
    mean[9:] = [0.1, -0.1, 0.05]
    sigma[9:] = [0.25, 0.1, 0.5]
    rng = np.random.default_rng(3)
    target = s.shaped_rows(np.r_[mean[:9], 0.5, -0.3, 0.2]) + 0.003 * rng.normal(size=(N_V + 3, 3))
    for pw in (1e-3, 30.0):
        x = project_to_body_space(s, target[:-3], target[-3:], mean, sigma, prior_weight=pw)
        D = (s.local_deltas - s.local_deltas[:, -3:-2]).reshape(3, -1).T
        t = (target - target[-3] - (s.base - s.base[-3])).ravel()
        lam = pw * (N_V + 3) * 1e-6 / sigma[9:] ** 2
        want = np.linalg.solve(D.T @ D + np.diag(lam), D.T @ t + lam * mean[9:])
        np.testing.assert_allclose(x[9:], want, atol=1e-9)
        np.testing.assert_allclose(x[:9], mean[:9], atol=1e-9)
    # the macro parameters are clipped to MakeHuman's unit interval after each step
    s2 = _space()
    m2, sg2 = s2.prior()
    far = s2.shaped_rows(np.r_[X_MID[:3], 1.0, X_MID[4:]]) + 3 * (s2.macro_deltas[3] - s2.macro_deltas[3, -3])
    xf = project_to_body_space(s2, far[:-3], far[-3:], m2, sg2, prior_weight=1e-9)
    assert xf[3] == 1.0 and np.all(xf[:9] >= 0.0) and np.all(xf[:9] <= 1.0)


def test_body_shape_space_is_cached_per_resolution_and_side(monkeypatch):
    calls = []
    monkeypatch.setattr(mm, "_body_shape_space", lambda res, side: calls.append((res, side)) or "space")
    assert mm.body_shape_space(SimpleNamespace(resolution="6k", side="right")) == "space"
    assert calls == [("6k", "right")]


def test_body_parameters_of_lists_the_macro_values_then_the_spaces_local_weights(monkeypatch):
    import bodystudio.body.makehuman as mh
    import bodystudio.body.phenotype as ph

    seen = {}
    monkeypatch.setattr(mh, "load_base", lambda: SimpleNamespace(vertices=np.zeros((7, 3)), data_dir="DATA"))
    monkeypatch.setattr(mh, "load_targets", lambda n: seen.setdefault("n", n) and SimpleNamespace(names=["a", "b"]))

    def weights(local, data_dir, names):
        seen["args"] = (dict(local), data_dir, list(names))
        return {"local/t0": 0.4, "local/t2": -0.7, "other": 0.9}

    monkeypatch.setattr(ph, "local_target_weights", weights)
    pheno = SimpleNamespace(**{n: 0.1 * (k + 1) for k, n in enumerate(BODY_MACRO_NAMES)})
    x = mm.body_parameters_of(pheno, {"m": 0.5}, _space())
    np.testing.assert_allclose(x, [0.1 * (k + 1) for k in range(9)] + [0.4, 0.0, -0.7])
    assert seen == {"n": 7, "args": ({"m": 0.5}, "DATA", ["a", "b"])}
    mm.body_parameters_of(pheno, None, _space())
    assert seen["args"][0] == {}


# --- fit_body_rest_shape on the stand-in space ----------------------------------------------------------------


class _Frame:
    """Depth frame stand-in: every vertex paired with its true posed position and a fixed normal (point-to-plane
    pairs of a known surface); ``drop`` vertices unpaired, ``outlier`` one pair moved along its normal."""

    def __init__(self, truth, normals, keep=None, outlier=None):
        self.truth, self.normals = truth, normals
        self.keep = np.arange(len(truth)) if keep is None else np.asarray(keep)
        self.outlier = outlier

    def plane_pairs(self, M):
        assert M.shape == self.truth.shape
        assert np.abs(M - self.truth).max() < 0.2  # the posed mesh is near its pairs
        q = self.truth[self.keep].copy()
        if self.outlier is not None:
            q[0] += self.outlier * self.normals[self.keep[0]]
        return self.keep, q, self.normals[self.keep]


def _displacements(model, angles):
    """Stand-in for Eq. 10's pose displacements: a few mm, depending on the elbow angle."""
    assert model.part_weights.shape == (N_V, 4)
    return 0.004 * np.sin(np.arange(N_V * 3).reshape(N_V, 3) + 3 * np.asarray(angles)[1, 2])


def _weights():
    t = np.linspace(0.02, 0.5, N_V)
    W = np.zeros((N_V, 4))
    W[:, 1] = np.clip((0.3 - t) / 0.06 + 0.5, 0, 1)
    W[:, 2] = np.clip(1 - W[:, 1] - np.clip((t - 0.52) / 0.03 + 0.5, 0, 1), 0, 1)
    W[:, 3] = 1 - W[:, 1] - W[:, 2]
    W[0, :] = [0.3, 0.7, 0.0, 0.0]  # a torso share too
    return W


def _poses(shift=np.zeros(3)):
    out = []
    for k in range(4):
        root = np.eye(4)
        root[:3, 3] = [0.01 * k, 0.0, 0.02] + shift
        ang = np.zeros((3, 3))
        ang[0] = [0.2 * k, 0.3, -0.1 * k]
        ang[1] = [0.0, 0.05, 0.3 + 0.25 * k]
        ang[2] = [0.0, 0.1 * k, 0.0]
        out.append(ArmPose(root, ang))
    return out


def _case(monkeypatch):
    """The stand-in space, model and a planted subject's frames (true poses, the placement 3 mm off the start's);
    built per test (the tests change its frames), a plain function so the direct recheck builds it afresh too."""
    seen = {}
    monkeypatch.setattr(mm, "pose_displacements", _displacements)

    def limit(d, lim):
        seen.setdefault("limits", []).append(lim)
        return d

    monkeypatch.setattr(mm, "limit_displacement_norms", limit)
    s = _space()
    model = SimpleNamespace(part_weights=_weights())
    shoulder = np.array([0.05, 1.2, 0.3])
    x_true = X_MID.copy()
    true_shift = np.array([0.002, -0.003, 0.001])
    rest, J = s.rest_and_joints(x_true, shoulder)
    rng = np.random.default_rng(5)
    frames = []
    for p in _poses(true_shift):
        M = pose_arm(rest + _displacements(model, p.angles), model.part_weights, J, p)
        n = rng.normal(size=(N_V, 3))
        frames.append(_Frame(M, n / np.linalg.norm(n, axis=1, keepdims=True)))
    mean, sigma = s.prior()
    x0 = mean.copy()
    x0[3:6] = [0.6, 0.6, 0.6]  # inside the pieces the truth lies in
    return SimpleNamespace(space=s, model=model, shoulder=shoulder, x_true=x_true, shift=true_shift, frames=frames,
                           mean=mean, sigma=sigma, x0=x0, seen=seen, J=J)


def _fit(c, **kw):
    args = dict(prior_weight=1e-9, huber_m=0.0, iterations=8)
    args.update(kw)
    x0 = args.pop("x0", c.x0)
    sigma = args.pop("sigma", c.sigma)
    return fit_body_rest_shape(c.space, c.model, _poses(), c.frames, x0, c.shoulder, c.mean, sigma, **args)


def test_the_body_rest_shape_and_placement_are_recovered_from_point_to_plane_pairs(monkeypatch):
    case = _case(monkeypatch)
    x, shift = _fit(case, norm_limit=0.7)
    np.testing.assert_allclose(_identifiable(x), _identifiable(case.x_true), atol=1e-5)
    np.testing.assert_allclose(shift, case.shift, atol=1e-7)
    assert case.seen["limits"] == [0.7] * 4
    # with Huber weights on (pairs within 4 mm of their plane at the start count fully) the same answer
    x, shift = _fit(case, huber_m=0.004)
    np.testing.assert_allclose(_identifiable(x), _identifiable(case.x_true), atol=1e-5)


def test_without_placement_the_shift_is_zero_and_the_shape_absorbs_what_it_can(monkeypatch):
    case = _case(monkeypatch)
    x, shift = _fit(case, fit_placement=False)
    assert shift.shape == (3,) and np.all(shift == 0.0)
    assert np.abs(_identifiable(x) - _identifiable(case.x_true)).max() > 1e-3
    x0, s0 = _fit(case, iterations=0)
    np.testing.assert_allclose(x0, case.x0)
    assert np.all(s0 == 0.0)


def test_the_fits_prior_holds_the_population_when_it_outweighs_the_pairs(monkeypatch):
    case = _case(monkeypatch)
    x, _ = _fit(case, prior_weight=1e12)
    np.testing.assert_allclose(x[9:], case.mean[9:], atol=1e-6)
    # a moderate prior lands in between: the local weights pulled toward 0 by an amount that grows with the weight
    errs = [np.abs(_fit(case, prior_weight=pw)[0][9:] - case.x_true[9:]).max() for pw in (1e-9, 1.0, 100.0)]
    assert errs[0] < 1e-5 < errs[1] < errs[2]


def test_huber_weights_cap_an_outlier_pairs_pull(monkeypatch):
    case = _case(monkeypatch)
    case.frames[0].outlier = 0.05
    err_huber = np.abs(_identifiable(_fit(case, huber_m=0.004)[0]) - _identifiable(case.x_true)).max()
    err_plain = np.abs(_identifiable(_fit(case, huber_m=0.0)[0]) - _identifiable(case.x_true)).max()
    assert err_huber < 0.5 * err_plain


def test_frames_without_pairs_are_skipped_and_the_tracker_holds_the_skeleton(monkeypatch):
    case = _case(monkeypatch)
    for f in case.frames:
        f.keep = np.zeros(0, int)
    tracked = np.stack([posed_joints(case.J, ArmPose(p.root.copy(), p.angles)) for p in _poses(case.shift)])
    x, shift = _fit(case, tracker_joints=tracked, tracker_weight=1.0, prior_weight=1e-6)
    rest, J = case.space.rest_and_joints(x, case.shoulder)
    got = np.stack([posed_joints(J, ArmPose(p.root + np.pad(shift[:, None], ((0, 1), (3, 0))), p.angles))
                    for p in _poses()])
    np.testing.assert_allclose(got, tracked, atol=2e-5)
    # no tracker, no pairs: only the prior acts, the start's local weights move to the prior mean
    # (the placement is then not determined: it is left out)
    x2, s2 = _fit(case, prior_weight=1.0, fit_placement=False)
    np.testing.assert_allclose(x2, case.mean, atol=1e-9)
    np.testing.assert_allclose(s2, 0.0, atol=1e-12)
    x3, _ = _fit(case, tracker_joints=tracked, tracker_weight=0.0, prior_weight=1.0, fit_placement=False)
    np.testing.assert_allclose(x3, case.mean, atol=1e-9)


def test_the_measured_arm_length_holds_the_chain(monkeypatch):
    case = _case(monkeypatch)
    for f in case.frames:
        f.keep = np.zeros(0, int)
    _, J0 = case.space.rest_and_joints(case.mean, case.shoulder)
    L0 = np.linalg.norm(np.diff(J0, axis=0), axis=1).sum()
    target = L0 + 0.01
    x, _ = _fit(case, prior_weight=1.0, arm_length_m=target, arm_length_weight=1e6,
             fit_placement=False)
    _, J = case.space.rest_and_joints(x, case.shoulder)
    assert np.linalg.norm(np.diff(J, axis=0), axis=1).sum() == pytest.approx(target, abs=2e-5)
    x, _ = _fit(case, prior_weight=1.0, arm_length_m=target, arm_length_weight=0.0,
             fit_placement=False)
    _, J = case.space.rest_and_joints(x, case.shoulder)
    assert np.linalg.norm(np.diff(J, axis=0), axis=1).sum() == pytest.approx(L0, abs=1e-3)


def test_the_poses_are_held_and_their_part_transforms_used(monkeypatch):
    case = _case(monkeypatch)
    # the fit uses the given poses: fitting with wrong poses gives a wrong shape
    wrong = [ArmPose(p.root, p.angles * 1.3) for p in _poses()]
    x, _ = fit_body_rest_shape(case.space, case.model, wrong, case.frames, case.x0, case.shoulder, case.mean,
                               case.sigma, 1e-9, 0.9, 0.0, 8)
    assert np.abs(_identifiable(x) - _identifiable(case.x_true)).max() > 1e-3
    assert part_transforms(case.J, _poses()[0]).shape == (4, 4, 4)


def test_integer_parameters_are_read_as_floats():
    # x given as integers (0 / 1 macro values, whole local weights): the ethnic floor and the Jacobian's steps stay
    s = _space()
    xi = [1, 0, 1, 0, 1, 0, 0, 0, 0, 1, 0, -1]
    xf = np.array(xi, float)
    np.testing.assert_allclose(s.macro_weights(xi), s.macro_weights(xf), atol=0)
    assert np.isclose(s.macro_weights(xi)[7:], 1 / 3).all()
    np.testing.assert_allclose(s.jacobian(np.array(xi)), s.jacobian(xf), atol=1e-12)
    mean, sigma = s.prior()
    rows = s.shaped_rows(X_MID)
    got = project_to_body_space(s, rows[:-3], rows[-3:], np.round(mean).astype(int), sigma, prior_weight=1e-9)
    want = project_to_body_space(s, rows[:-3], rows[-3:], np.round(mean), sigma, prior_weight=1e-9)
    np.testing.assert_allclose(got, want, atol=1e-12)


def test_a_step_that_lands_on_one_is_taken_forward():
    s = _space()
    x = X_MID.copy()
    x[3] = 0.5  # forward to 1.0: maxweight slope 2, minweight 0; backward to 0.0 would give minweight slope -2
    d = 2 * s.macro_deltas[3]
    np.testing.assert_allclose(s.jacobian(x, step=0.5)[3], d - d[-3], atol=1e-12)


def test_the_projections_defaults_and_its_lower_clip():
    s = _space()
    mean, sigma = s.prior()
    rng = np.random.default_rng(8)
    rows = s.shaped_rows(X_MID) + 0.004 * rng.normal(size=(N_V + 3, 3))
    np.testing.assert_array_equal(project_to_body_space(s, rows[:-3], rows[-3:], mean, sigma),
                                  project_to_body_space(s, rows[:-3], rows[-3:], mean, sigma, 1e-3, 6))
    # a subject "more female than female": gender (weight of macrodetails/male) held at 0
    low = s.shaped_rows(np.r_[0.0, X_MID[1:]]) - 0.5 * (s.macro_deltas[0] - s.macro_deltas[0, -3])
    x = project_to_body_space(s, low[:-3], low[-3:], mean, sigma, prior_weight=1e-9)
    assert x[0] == 0.0 and np.all(x[:9] >= 0.0)


def test_single_precision_inputs_are_projected_in_double_precision():
    # a float32 rest mesh (e.g. read from a PLY) and float32 spreads: subtracted and squared in float64
    s = _space()
    mean, sigma = s.prior()
    rows = s.shaped_rows(X_MID)
    rows = (rows - rows[-3] + np.array([0.0031, -0.0027, 0.0013])).astype(np.float32)  # float32 differences inexact
    s32 = sigma.astype(np.float32)
    got = project_to_body_space(s, rows[:-3], rows[-3:], mean, s32, prior_weight=10.0)
    want = project_to_body_space(s, rows[:-3].astype(float), rows[-3:].astype(float), mean, s32.astype(float),
                                 prior_weight=10.0)
    np.testing.assert_array_equal(got, want)


def test_the_fits_defaults_and_frames_with_few_pairs(monkeypatch):
    case = _case(monkeypatch)
    c = case
    a = fit_body_rest_shape(c.space, c.model, _poses(), c.frames, c.x0, c.shoulder, c.mean, c.sigma)
    b = fit_body_rest_shape(c.space, c.model, _poses(), c.frames, c.x0, c.shoulder, c.mean, c.sigma, 1.0, 0.9, 0.004,
                            3, True, None, 0.0, None, 0.0)
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])
    assert c.seen["limits"][:4] == [0.9] * 4
    # integer start (0 / 1 macros, whole local weights) read as floats
    xi = np.r_[[0, 1, 1, 1, 1, 1, 0, 1, 0], [0, 0, 0]]
    np.testing.assert_allclose(_fit(c, x0=xi.astype(int))[0], _fit(c, x0=xi.astype(float))[0], atol=1e-12)
    # Huber weights never above 1: a threshold no residual reaches is the plain fit
    np.testing.assert_allclose(_fit(c, huber_m=1e3, prior_weight=1.0)[0], _fit(c, huber_m=0.0, prior_weight=1.0)[0],
                               atol=1e-12)
    # a first frame without pairs is skipped, the others still count
    c.frames[0].keep = np.zeros(0, int)
    x, shift = _fit(c)
    np.testing.assert_allclose(_identifiable(x), _identifiable(c.x_true), atol=1e-5)
    np.testing.assert_allclose(shift, c.shift, atol=1e-7)
    # frames with a single pair each still pull the shape off the prior
    for f in c.frames:
        f.keep = np.array([5])
    x1, _ = _fit(c, prior_weight=1.0, fit_placement=False, iterations=1)
    assert np.abs(x1[9:] - c.mean[9:]).max() > 1e-4


def test_the_arm_length_term_and_the_prior_are_the_energys_gauss_newton(monkeypatch):
    # no pairs: the fit minimises prior_weight T 1e-6 |(x - mean) / sigma|^2 + w T (chain length - measured)^2;
    # at its result the energy's gradient (central differences over the local weights) vanishes
    c = _case(monkeypatch)
    for f in c.frames:
        f.keep = np.zeros(0, int)
    _, J0 = c.space.rest_and_joints(c.mean, c.shoulder)
    target = np.linalg.norm(np.diff(J0, axis=0), axis=1).sum() + 0.01
    pw, w, T = 2.0, 0.3, 4

    def energy(x):
        _, J = c.space.rest_and_joints(x, c.shoulder)
        L = np.linalg.norm(np.diff(J, axis=0), axis=1).sum()
        return pw * T * 1e-6 * np.sum(((x - c.mean) / c.sigma) ** 2) + w * T * (L - target) ** 2

    def grad(x):
        out = []
        for k in range(9, 12):
            e = np.zeros(12)
            e[k] = 1e-6
            out.append((energy(x + e) - energy(x - e)) / 2e-6)
        return np.array(out)

    x, _ = _fit(c, prior_weight=pw, arm_length_m=target, arm_length_weight=w, fit_placement=False, iterations=12)
    g0 = np.abs(grad(c.mean)).max()
    assert g0 > 1e-4 and np.abs(grad(x)).max() < 1e-3 * g0
    assert np.abs(x[9:] - c.mean[9:]).max() > 1e-3  # both terms act
    # a measured length without weight, or a weight without a measured length: no term
    np.testing.assert_allclose(_fit(c, prior_weight=pw, arm_length_m=None, arm_length_weight=w,
                                    fit_placement=False)[0], c.mean, atol=1e-12)


def test_the_fits_inputs_are_checked_and_read_in_double_precision(monkeypatch):
    c = _case(monkeypatch)
    with pytest.raises(ValueError):  # one frame per pose
        fit_body_rest_shape(c.space, c.model, _poses(), c.frames[:3], c.x0, c.shoulder, c.mean, c.sigma)
    # a measured length or tracker joints without their weight (default 0) are no term
    tracked = np.zeros((4, 3, 3))
    plain = _fit(c, prior_weight=1.0)[0]
    np.testing.assert_array_equal(_fit(c, prior_weight=1.0, arm_length_m=0.1)[0], plain)
    np.testing.assert_array_equal(_fit(c, prior_weight=1.0, tracker_joints=tracked)[0], plain)
    # a tracker weight without tracker joints is no tracker term
    np.testing.assert_array_equal(_fit(c, tracker_weight=1.0, prior_weight=1.0)[0], _fit(c, prior_weight=1.0)[0])
    s32 = c.sigma.astype(np.float32)
    np.testing.assert_array_equal(_fit(c, prior_weight=5.0, sigma=s32)[0],
                                  _fit(c, prior_weight=5.0, sigma=s32.astype(float))[0])


def test_the_fitted_macro_parameters_stay_in_the_unit_interval(monkeypatch):
    c = _case(monkeypatch)
    for sign, bound in ((-1.0, 0.0), (1.0, 1.0)):  # a subject beyond the model's range in gender, both ways
        xb = c.x_true.copy()
        xb[0] = bound
        rest, J = c.space.rest_and_joints(xb, c.shoulder)
        d = c.space.macro_deltas[0] - c.space.macro_deltas[0, -3]
        rest = rest + sign * 0.5 * d[:-3]
        J = J + sign * 0.5 * d[-3:]
        for f, p in zip(c.frames, _poses(c.shift), strict=True):
            f.truth = pose_arm(rest + _displacements(c.model, p.angles), c.model.part_weights, J, p)
        x, _ = _fit(c)
        assert x[0] == bound and np.all(x[:9] >= 0.0) and np.all(x[:9] <= 1.0)
