"""Analytic tests of the per-subject skeleton and rest shape of the whole-sequence fit (muscle/refine.py).

``skeleton_model_mesh`` is Eq. 12 of Arm-Muscle Capture skinned about given rest joints;
``fit_arm_sequence_skeleton`` solves the sequence's angles with the rest joints as shared unknowns;
``fit_rest_shape_correction`` is one linear least squares over the population eigenvectors of Eq. 8.
Fast and exact where the maths allows (issue 17: planted bugs must fail a fast test): the small 2k model is
built once per process (``_arm_model``), the frames are the model's own meshes, the solver's wiring is read
through a spy on scipy's ``least_squares`` and the linear rest-shape solve is compared with an independent
least squares built by finite differences of the skinned mesh.
"""

from functools import lru_cache
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.optimize import OptimizeResult
from scipy.optimize import least_squares as real_least_squares
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from bodystudio.muscle import refine
from bodystudio.muscle.arm import ArmPose, pose_arm

from .test_refine_analytic import _arm_model, _frame

OFFSET = np.array([[0.006, -0.004, 0.006], [0.008, 0.005, -0.005], [-0.006, 0.007, 0.005]])  # 9-11 mm each


@lru_cache(maxsize=1)
def _model_case():
    from bodystudio.muscle.model import model_joints, model_rest_vertices

    model, shape = _arm_model()
    return model, shape, model_joints(model, shape), model_rest_vertices(model, shape)


@lru_cache(maxsize=4)
def _sequence(n: int = 3, offset_scale: float = 1.0):
    """``n`` frames of a subject whose rest joints sit ``offset_scale`` x OFFSET from the regressed ones inside
    the model's rest mesh (the elbow flexing 25-65 deg, the shoulder abducting), the depth of each whole mesh,
    the exact tracker joints and a start on the regressed skeleton 3 deg (shoulder) / 4 deg (elbow) off."""
    model, shape, J, rest = _model_case()
    Jt = J + offset_scale * OFFSET
    sensor = 0.5 * (J[0] + J[1]) + np.array([0.3, 0.1, 1.0])
    truth, frames, start, tracker = [], [], [], []
    for k in range(n):
        shoulder = np.array([0.0, 0.0, np.radians(5.0 + 6.0 * k)])
        pose = ArmPose(np.eye(4), np.stack([shoulder, refine.elbow_rotvec(Jt, np.radians(25.0 + 20.0 * k), 0.0),
                                            np.zeros(3)]))
        M = refine.skeleton_model_mesh(model, pose, rest, Jt)
        frames.append(_frame(M, model.faces, model.arm_mask, sensor))
        truth.append(pose)
        tracker.append(refine.posed_joints(Jt, pose))
        start.append(ArmPose(np.eye(4), np.stack([shoulder + np.radians([3.0, 0.0, 0.0]),
                                                  refine.elbow_rotvec(J, np.radians(29.0 + 20.0 * k), 0.0),
                                                  np.zeros(3)])))
    return SimpleNamespace(model=model, shape=shape, J=J, Jt=Jt, rest=rest, truth=truth, frames=frames, start=start,
                           tracker=np.stack(tracker), sensor=sensor)


def _angle_errors_deg(poses, truth):
    """Largest shoulder and elbow rotation error (degrees) over the sequence."""
    err = [[np.degrees((Rotation.from_rotvec(p.angles[j]).inv() * Rotation.from_rotvec(t.angles[j])).magnitude())
            for j in range(2)] for p, t in zip(poses, truth, strict=True)]
    return np.max(err, axis=0)


def _spy(monkeypatch, run=True):
    """Record every ``least_squares`` call of refine.py (fun, start, options); ``run=False``: return the start."""
    calls = []

    def spy(fun, x0, **kw):
        x0 = np.array(x0, np.float64)
        calls.append(SimpleNamespace(fun=fun, x0=x0, kw=kw))
        return real_least_squares(fun, x0, **kw) if run else OptimizeResult(x=x0)

    monkeypatch.setattr(refine, "least_squares", spy)
    return calls


# --- Eq. 12 about a per-subject skeleton -----------------------------------------------------------------

def test_the_skeleton_model_mesh_is_eq_12_skinned_about_the_given_joints():
    from bodystudio.muscle.model import limit_displacement_norms, model_mesh, pose_displacements

    model, shape, J, rest = _model_case()
    Jt = J + OFFSET
    pose = ArmPose(np.eye(4), np.stack([[0.1, -0.2, 0.4], refine.elbow_rotvec(J, 0.9, 0.0), [0.0, 0.1, 0.0]]))
    d = pose_displacements(model, pose.angles)
    for limit in (0.0, 0.5, 1.0):
        want = pose_arm(rest + limit_displacement_norms(d, limit), model.part_weights, Jt, pose)
        np.testing.assert_allclose(refine.skeleton_model_mesh(model, pose, rest, Jt, limit), want, atol=1e-14)
    # the default limit is the model mesh's (0.9), and with the regressed joints it is the model mesh
    np.testing.assert_allclose(refine.skeleton_model_mesh(model, pose, rest, J), model_mesh(model, shape, pose),
                               atol=1e-14)
    assert np.abs(refine.skeleton_model_mesh(model, pose, rest, J, 1.0) - model_mesh(model, shape, pose)).max() > 1e-4
    # the rest joints are the centres the parts turn about: the elbow's own point goes where the chain takes it
    assert np.abs(refine.skeleton_model_mesh(model, pose, rest, Jt) - refine.skeleton_model_mesh(
        model, pose, rest, J)).max() > 1e-3


# --- the whole-sequence fit with the subject's skeleton ---------------------------------------------------

def test_no_round_keeps_the_start_with_each_twist_about_the_new_forearm():
    """``rounds=0``: the poses are the start's, rebuilt as shoulder (3) + hinge flexion about the rest arm's plane
    normal + the start's twist about the rest forearm; the skeleton is the given one and the root the first's."""
    s = _sequence()
    h, f = refine.elbow_axes(s.J)
    start = [ArmPose(np.eye(4), np.stack([
        p.angles[0], (Rotation.from_rotvec(h * (0.3 + 0.2 * k)) * Rotation.from_rotvec(f * 0.1 * (k + 1))).as_rotvec(),
        [0.05, 0.0, 0.02 * k]])) for k, p in enumerate(s.start)]
    start[0].root[:3, 3] = [0.01, -0.02, 0.005]
    poses, joints = refine.fit_arm_sequence_skeleton(s.model, s.shape, start, s.frames, s.J, rounds=0,
                                                     fit_root=True)
    np.testing.assert_array_equal(joints, s.J)
    for k, (p, q) in enumerate(zip(poses, start, strict=True)):
        np.testing.assert_array_equal(p.root, start[0].root)
        np.testing.assert_array_equal(p.angles[0], q.angles[0])
        np.testing.assert_array_equal(p.angles[2], q.angles[2])
        want = refine.elbow_rotvec(s.J, float(q.angles[1] @ h), float(q.angles[1] @ f))
        np.testing.assert_allclose(p.angles[1], want, atol=1e-15)
        assert abs(float(q.angles[1] @ f) - 0.1 * (k + 1)) < 0.02  # the twist is there to keep


def test_the_skeleton_fit_recovers_offset_rest_joints_and_the_angles():
    """Depth and exact tracker joints of a subject whose joints sit 9-11 mm off the regression: the fitted rest
    joints land within 1.5 mm of them and the angles within 0.5 deg, where the regressed skeleton keeps ~10 mm
    (measured: 0.03 / 0.44 / 0.72 mm and 0.17 / 0.32 deg after 2 rounds of 20 evaluations)."""
    s = _sequence()
    kw = dict(tracker_joints=s.tracker, tracker_weight=100.0, smooth_weight=1.0, rounds=2, max_nfev=20,
              skeleton_prior_weight=1.0)
    poses, joints = refine.fit_arm_sequence_skeleton(s.model, s.shape, s.start, s.frames, s.J, **kw)
    err = 1000 * np.linalg.norm(joints - s.Jt, axis=1)
    assert 1000 * np.linalg.norm(s.J - s.Jt, axis=1).min() > 9.0
    assert err.max() < 1.5, err
    assert _angle_errors_deg(poses, s.truth).max() < 0.5
    assert all(np.array_equal(p.root, s.start[0].root) for p in poses)  # the placement is held by default
    held, J_held = refine.fit_arm_sequence_skeleton(s.model, s.shape, s.start, s.frames, s.J, fit_skeleton=False,
                                                    **kw)
    np.testing.assert_array_equal(J_held, s.J)
    assert _angle_errors_deg(held, s.truth).max() > _angle_errors_deg(poses, s.truth).max()


def test_only_the_free_joints_move_and_the_prior_holds_them():
    s = _sequence()
    kw = dict(tracker_joints=s.tracker, tracker_weight=30.0, smooth_weight=1.0, rounds=1, max_nfev=8)
    _, J_elbow = refine.fit_arm_sequence_skeleton(s.model, s.shape, s.start, s.frames, s.J,
                                                  skeleton_prior_weight=10.0, free_joints=(False, True, False), **kw)
    np.testing.assert_array_equal(J_elbow[[0, 2]], s.J[[0, 2]])
    assert np.linalg.norm(J_elbow[1] - s.Jt[1]) < 0.5 * np.linalg.norm(s.J[1] - s.Jt[1])
    _, J_held = refine.fit_arm_sequence_skeleton(s.model, s.shape, s.start, s.frames, s.J,
                                                 skeleton_prior_weight=1e9, **kw)
    assert np.abs(J_held - s.J).max() < 1e-5  # a stiff prior: the regression
    assert np.abs(J_held - s.J).max() > 0.0


def test_the_placement_is_fitted_when_asked():
    s = _sequence(offset_scale=0.0)
    off = np.eye(4)
    off[:3, 3] = [0.006, -0.005, 0.004]
    moved = [ArmPose(off, t.angles) for t in s.truth]
    poses, _ = refine.fit_arm_sequence_skeleton(s.model, s.shape, moved, s.frames, s.J, fit_root=True,
                                                fit_skeleton=False, smooth_weight=1.0, rounds=2, max_nfev=10)
    assert np.linalg.norm(poses[0].root[:3, 3]) < 0.1 * np.linalg.norm(off[:3, 3])
    np.testing.assert_array_equal(poses[0].root[:3, :3], off[:3, :3])
    assert all(np.array_equal(p.root, poses[0].root) for p in poses)


def _expected_sparsity(sizes, T, r0, s0):
    n0 = r0 + s0
    E = np.zeros((sum(sizes) + 4 * max(T - 2, 0) + s0, n0 + 4 * T), int)
    row = 0
    for k, n in enumerate(sizes):
        E[row:row + n, :n0] = 1
        E[row:row + n, n0 + 4 * k:n0 + 4 * k + 4] = 1
        row += n
    for k in range(1, T - 1):
        for c in range(4):
            E[row, [n0 + 4 * (k + d) + c for d in (-1, 0, 1)]] = 1
            row += 1
    for c in range(s0):
        E[row, r0 + c] = 1
        row += 1
    return E


@pytest.mark.parametrize("fit_root, free", [(False, (True, True, True)), (True, (True, False, True))])
def test_the_solver_sees_each_term_with_its_weight_and_a_sparsity_that_holds_the_jacobian(monkeypatch, fit_root,
                                                                                           free):
    """One round read through a spy: the residuals are the point-to-plane distances of the start's meshes, the
    tracker's joints times sqrt(w), the angles' second differences times sqrt(w) 0.3 m and the skeleton offsets
    times sqrt(prior); the declared sparsity is exactly the frame / neighbour / offset blocks and contains every
    non-zero of the finite-difference Jacobian; scales, method and evaluation cap as documented."""
    s = _sequence(4)
    model, T = s.model, 4
    calls = _spy(monkeypatch, run=False)
    poses, _ = refine.fit_arm_sequence_skeleton(s.model, s.shape, s.start, s.frames, s.J, norm_limit=0.7,
                                                tracker_joints=s.tracker, tracker_weight=20.0, smooth_weight=3.0,
                                                rounds=1, max_nfev=4, fit_root=fit_root, skeleton_prior_weight=50.0,
                                                free_joints=free)
    (c,) = calls
    r0, s0 = 3 * fit_root, 3 * sum(free)
    n0 = r0 + s0
    assert len(c.x0) == n0 + 4 * T
    np.testing.assert_array_equal(c.x0[:n0], 0.0)
    h, _ = refine.elbow_axes(s.J)
    for k, p in enumerate(s.start):
        np.testing.assert_allclose(c.x0[n0 + 4 * k:n0 + 4 * k + 4], np.r_[p.angles[0], p.angles[1] @ h], atol=1e-15)
    assert c.kw["method"] == "trf" and c.kw["max_nfev"] == 4 and "loss" not in c.kw
    np.testing.assert_array_equal(c.kw["x_scale"], np.r_[np.full(n0, 0.01), np.full(4 * T, 0.05)])
    # the residuals at a moved point
    rng = np.random.default_rng(3)
    x = c.x0 + rng.normal(0.0, 0.01, len(c.x0))
    res = c.fun(x)
    J = s.J.copy()
    J[np.flatnonzero(free)] += x[r0:n0].reshape(-1, 3)
    root = np.eye(4)
    root[:3, 3] = x[:3] if fit_root else 0.0
    a = x[n0:].reshape(T, 4)
    sizes, row = [], 0
    for k in range(T):
        twist = float(s.start[k].angles[1] @ refine.elbow_axes(s.J)[1])
        p = ArmPose(root, np.vstack([a[k, :3], refine.elbow_rotvec(J, a[k, 3], twist), s.start[k].angles[2]]))
        M0 = refine.skeleton_model_mesh(model, poses[k], s.rest, s.J, 0.7)  # the round's pairs: the start's meshes
        idx, q, nrm = s.frames[k].plane_pairs(M0)
        M = refine.skeleton_model_mesh(model, p, s.rest, J, 0.7)
        want = np.r_[np.einsum("kd,kd->k", M[idx] - q, nrm), np.sqrt(20.0) * (refine.posed_joints(J, p)
                                                                               - s.tracker[k]).ravel()]
        np.testing.assert_allclose(res[row:row + len(want)], want, atol=1e-12)
        row += len(want)
        sizes.append(len(want))
    second = (a[:-2] - 2 * a[1:-1] + a[2:]).ravel()
    np.testing.assert_allclose(res[row:row + len(second)], np.sqrt(3.0) * 0.3 * second, atol=1e-15)
    np.testing.assert_allclose(res[row + len(second):], np.sqrt(50.0) * x[r0:n0], atol=1e-15)
    assert len(res) == row + len(second) + s0
    # the sparsity: exactly the blocks, and it holds the Jacobian (forward differences at the start)
    E = _expected_sparsity(sizes, T, r0, s0)
    np.testing.assert_array_equal(c.kw["jac_sparsity"].toarray(), E)
    f0 = c.fun(c.x0)
    D = np.stack([c.fun(c.x0 + 1e-6 * np.eye(len(c.x0))[i]) - f0 for i in range(len(c.x0))], axis=1)
    assert not (np.abs(D) > 1e-12)[E == 0].any()


def test_the_defaults_are_the_documented_ones(monkeypatch):
    """Default call = two rounds of 8 evaluations, no robust loss, the three joints free under a prior of 100, the
    placement held, the smoothness 10 and the 0.9 norm limit, the model's rest mesh."""
    s = _sequence()
    calls = _spy(monkeypatch, run=False)
    refine.fit_arm_sequence_skeleton(s.model, s.shape, s.start, s.frames, s.J)
    assert len(calls) == 2
    explicit = _spy(monkeypatch, run=False)
    refine.fit_arm_sequence_skeleton(s.model, s.shape, s.start, s.frames, s.J, 0.9, None, 0.0, 10.0, 2, 8, 0.0,
                                     False, True, 100.0, False, rest=s.rest, free_joints=(True, True, True))
    x = calls[0].x0 + np.random.default_rng(1).normal(0.0, 0.01, len(calls[0].x0))
    for c, e in zip(calls, explicit, strict=True):
        assert c.kw["max_nfev"] == 8 and "loss" not in c.kw
        np.testing.assert_array_equal(c.x0, e.x0)
        np.testing.assert_array_equal(c.fun(x), e.fun(x))
        np.testing.assert_array_equal(c.kw["x_scale"], e.kw["x_scale"])
    assert len(calls[0].x0) == 9 + 4 * 3


def test_huber_acts_on_every_residual_or_on_the_depth_pairs_alone(monkeypatch):
    """``huber_m`` alone: scipy's Huber loss on all residuals. ``depth_huber_only``: no scipy loss, each depth pair's
    residual weighted by sqrt(min(1, huber_m / |r|)) of its distance at the round's start (IRLS), the tracker and
    prior terms as without it."""
    s = _sequence()
    kw = dict(tracker_joints=s.tracker, tracker_weight=20.0, rounds=1, max_nfev=3)
    calls = _spy(monkeypatch, run=False)
    refine.fit_arm_sequence_skeleton(s.model, s.shape, s.start, s.frames, s.J, **kw)
    refine.fit_arm_sequence_skeleton(s.model, s.shape, s.start, s.frames, s.J, huber_m=0.002, **kw)
    refine.fit_arm_sequence_skeleton(s.model, s.shape, s.start, s.frames, s.J, huber_m=0.002,
                                     depth_huber_only=True, **kw)
    refine.fit_arm_sequence_skeleton(s.model, s.shape, s.start, s.frames, s.J, huber_m=0.0,
                                     depth_huber_only=True, **kw)
    plain, huber, irls, irls_off = calls
    assert plain.kw.get("loss") is None and irls.kw.get("loss") is None and irls_off.kw.get("loss") is None
    assert huber.kw["loss"] == "huber" and huber.kw["f_scale"] == 0.002
    r = plain.fun(plain.x0)
    np.testing.assert_array_equal(huber.fun(huber.x0), r)
    np.testing.assert_array_equal(irls_off.fun(irls_off.x0), r)
    got = irls.fun(irls.x0)
    depth = np.ones(len(r), bool)
    row = 0
    for k in range(3):
        n = len(s.frames[k].plane_pairs(refine.skeleton_model_mesh(
            s.model, refine.fit_arm_sequence_skeleton(s.model, s.shape, s.start, s.frames, s.J, rounds=0)[0][k],
            s.rest, s.J))[0])
        depth[row + n:row + n + 9] = False
        row += n + 9
    depth[row:] = False
    want = np.sign(r) * np.sqrt(np.minimum(r ** 2, 0.002 * np.abs(r)))
    np.testing.assert_allclose(got[depth], want[depth], atol=1e-15)
    np.testing.assert_array_equal(got[~depth], r[~depth])
    assert (np.abs(r[depth]) > 0.002).any() and (np.abs(r[depth]) < 0.002).any()  # both sides of the kink seen


def test_a_personal_rest_mesh_is_the_one_posed():
    s = _sequence()
    bigger = s.J[0] + 1.02 * (s.rest - s.J[0])
    calls = []

    def spy(fun, x0, **kw):
        calls.append(fun(np.asarray(x0, np.float64)))
        return OptimizeResult(x=np.asarray(x0, np.float64))

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(refine, "least_squares", spy)
        refine.fit_arm_sequence_skeleton(s.model, s.shape, s.start, s.frames, s.J, rounds=1, rest=bigger)
        refine.fit_arm_sequence_skeleton(s.model, s.shape, s.start, s.frames, s.J, rounds=1, rest=s.rest)
        refine.fit_arm_sequence_skeleton(s.model, s.shape, s.start, s.frames, s.J, rounds=1)
    assert len(calls[0]) != len(calls[1]) or np.abs(calls[0] - calls[1]).max() > 1e-3
    np.testing.assert_array_equal(calls[1], calls[2])


# --- the per-subject rest shape ---------------------------------------------------------------------------

def _one_sided(s, subject):
    """Frames of ``subject`` (a rest mesh) in the true poses, seen from the sensor side only."""
    from bodystudio.geometry.mesh import vertex_normals
    from bodystudio.muscle.nicp import CorrespondenceFilters, vertex_neighbourhoods

    F = np.asarray(s.model.faces, np.int64)
    adjacency = vertex_neighbourhoods(F, len(subject), rings=2)
    frames, meshes = [], []
    for pose in s.truth:
        M = refine.skeleton_model_mesh(s.model, pose, subject, s.Jt)
        N = vertex_normals(M, F)
        seen = s.model.arm_mask & (np.einsum("kd,kd->k", N, s.sensor - M) > 0)
        frames.append(refine.DepthFrame(M[seen], N[seen], cKDTree(M[seen]), s.sensor, s.model.arm_mask, adjacency,
                                        CorrespondenceFilters(), F))
        meshes.append(M)
    return frames, meshes


@lru_cache(maxsize=1)
def _planted_shape():
    s = _sequence()
    E = s.model.length_basis
    c = np.zeros(len(E))
    c[:3] = [0.15, -0.12, 0.10]
    subject = s.rest + (c @ E).reshape(-1, 3)
    frames, meshes = _one_sided(s, subject)
    return s, subject, frames, meshes


def _independent_rest_solve(s, frames, rest, basis, prior_weight, norm_limit, huber_m):
    """The correction by a least squares built from the skinned mesh itself: the posed mesh is affine in the rest
    coefficients, so each column is the change of the point-to-plane residuals for one unit coefficient."""
    E = np.asarray(basis)
    G, r, w = [], [], []
    for p, fr in zip(s.truth, frames, strict=True):
        M0 = refine.skeleton_model_mesh(s.model, p, rest, s.Jt, norm_limit)
        idx, q, n = fr.plane_pairs(M0)
        r0 = np.einsum("kd,kd->k", M0[idx] - q, n)
        cols = [np.einsum("kd,kd->k", refine.skeleton_model_mesh(s.model, p, rest + e.reshape(-1, 3), s.Jt,
                                                                 norm_limit)[idx] - q, n) - r0 for e in E]
        G.append(np.stack(cols, axis=1))
        r.append(r0)
        w.append(np.minimum(1.0, huber_m / np.abs(r0)) if huber_m > 0 else np.ones(len(r0)))
    G, r, w = np.vstack(G), np.concatenate(r), np.concatenate(w)
    c = np.linalg.solve(G.T @ (w[:, None] * G) + prior_weight * len(frames) * np.eye(len(E)), -G.T @ (w * r))
    return rest + (c @ E).reshape(-1, 3)


@pytest.mark.parametrize("prior, limit, huber", [(0.05, 0.9, 0.004), (0.2, 0.5, 0.0005), (1e-4, 0.0, 0.0)])
def test_the_rest_shape_correction_is_the_weighted_least_squares_of_the_depth(prior, limit, huber):
    s, _, frames, _ = _planted_shape()
    got = refine.fit_rest_shape_correction(s.model, s.shape, s.truth, frames, s.rest, s.Jt, prior_weight=prior,
                                           norm_limit=limit, huber_m=huber)
    want = _independent_rest_solve(s, frames, s.rest, s.model.length_basis, prior, limit, huber)
    np.testing.assert_allclose(got, want, atol=1e-9)
    assert np.abs(got - s.rest).max() > 1e-4


def test_the_rest_shape_correction_recovers_a_planted_population_shape():
    """About 5 mm of population shape, seen from one side: three rounds bring every posed arm vertex (the unseen
    side included) to < 0.3 mm of the truth; the truth itself gets no correction; the default weights are the
    documented 0.05 / 0.9 / 4 mm; the prior counts per frame (the same frames twice: the same answer)."""
    s, subject, frames, meshes = _planted_shape()

    def err_mm(r):
        return 1000 * np.median([np.linalg.norm(refine.skeleton_model_mesh(s.model, p, r, s.Jt) - M,
                                                axis=1)[s.model.arm_mask] for p, M in zip(s.truth, meshes,
                                                                                           strict=True)])

    got = s.rest
    for _ in range(3):
        got = refine.fit_rest_shape_correction(s.model, s.shape, s.truth, frames, got, s.Jt, prior_weight=1e-4,
                                               huber_m=0.0)
    assert err_mm(s.rest) > 3.0
    assert err_mm(got) < 0.3, err_mm(got)
    same = refine.fit_rest_shape_correction(s.model, s.shape, s.truth, frames, subject, s.Jt)
    np.testing.assert_allclose(same, subject, atol=1e-9)
    default = refine.fit_rest_shape_correction(s.model, s.shape, s.truth, frames, s.rest, s.Jt)
    explicit = refine.fit_rest_shape_correction(s.model, s.shape, s.truth, frames, s.rest, s.Jt, 0.05, 0.9, 0.004,
                                                s.model.length_basis)
    np.testing.assert_array_equal(default, explicit)
    twice = refine.fit_rest_shape_correction(s.model, s.shape, s.truth * 2, frames * 2, s.rest, s.Jt)
    np.testing.assert_allclose(twice, default, atol=1e-12)


def test_the_rest_shape_correction_stays_in_the_given_basis():
    s, _, frames, _ = _planted_shape()
    E = s.model.length_basis[:2]
    got = refine.fit_rest_shape_correction(s.model, s.shape, s.truth, frames, s.rest, s.Jt, prior_weight=1e-3,
                                           basis=E)
    c, *_ = np.linalg.lstsq(E.T, (got - s.rest).ravel(), rcond=None)
    np.testing.assert_allclose(c @ E, (got - s.rest).ravel(), atol=1e-12)
    assert np.abs(c).max() > 1e-3
    np.testing.assert_allclose(got, _independent_rest_solve(s, frames, s.rest, E, 1e-3, 0.9, 0.004), atol=1e-9)


def test_fit_arm_sequence_is_the_skeleton_fit_with_the_models_skeleton_and_the_placement_fitted(monkeypatch):
    """``fit_arm_sequence`` (the sequence fit before the per-subject skeleton): every argument passed on, the
    skeleton held, and by default the root fitted (3 + 4 T unknowns), 2 rounds of 8 evaluations, no robust loss."""
    s = _sequence()
    calls = _spy(monkeypatch, run=False)
    poses = refine.fit_arm_sequence(s.model, s.shape, s.start, s.frames, s.J)
    assert len(calls) == 2 and len(calls[0].x0) == 3 + 4 * 3
    assert calls[0].kw["max_nfev"] == 8 and "loss" not in calls[0].kw
    explicit = _spy(monkeypatch, run=False)
    want, J = refine.fit_arm_sequence_skeleton(s.model, s.shape, s.start, s.frames, s.J, 0.9, None, 0.0, 10.0, 2, 8,
                                               0.0, True, fit_skeleton=False)
    x = calls[0].x0 + np.random.default_rng(2).normal(0.0, 0.01, len(calls[0].x0))
    np.testing.assert_array_equal(calls[0].fun(x), explicit[0].fun(x))
    assert [p.angles.tolist() for p in poses] == [p.angles.tolist() for p in want]
    calls = _spy(monkeypatch, run=False)
    refine.fit_arm_sequence(s.model, s.shape, s.start, s.frames, s.J, 0.5, s.tracker, 7.0, 2.0, 1, 3, 0.003, False)
    (c,) = calls
    assert len(c.x0) == 4 * 3 and c.kw["max_nfev"] == 3 and c.kw["loss"] == "huber" and c.kw["f_scale"] == 0.003
    explicit = _spy(monkeypatch, run=False)
    refine.fit_arm_sequence_skeleton(s.model, s.shape, s.start, s.frames, s.J, 0.5, s.tracker, 7.0, 2.0, 1, 3, 0.003,
                                     False, fit_skeleton=False)
    np.testing.assert_array_equal(c.fun(x[3:]), explicit[0].fun(x[3:]))


def test_fit_arm_sequences_tracker_weight_defaults_to_zero(monkeypatch):
    """A tracker given without a weight is not used (``tracker_weight`` 0 by default, as in the skeleton fit)."""
    s = _sequence()
    calls = _spy(monkeypatch, run=False)
    refine.fit_arm_sequence(s.model, s.shape, s.start, s.frames, s.J, rounds=1)
    refine.fit_arm_sequence(s.model, s.shape, s.start, s.frames, s.J, tracker_joints=s.tracker, rounds=1)
    refine.fit_arm_sequence(s.model, s.shape, s.start, s.frames, s.J, tracker_joints=s.tracker, tracker_weight=1.0,
                            rounds=1)
    plain, given, weighted = (c.fun(c.x0) for c in calls)
    np.testing.assert_array_equal(given, plain)
    assert len(weighted) == len(plain) + 9 * 3


def test_the_shape_fit_keeps_the_given_sex_and_a_start_without_one_is_male():
    """``fit_shape_parameters``: the sex is an input (the paper's Table 1), never fitted: a woman's meshes are built
    with her sex in every round (a model whose sex column is not zero: the small model, learned from men only, has a
    zero one, so its sex row is set here), and a fit without a start is male. The root of a fixed-shape fit against
    the woman's own mesh is exact only with her sex (a male mesh is ~1 mm off)."""
    from dataclasses import replace

    from bodystudio.muscle.model import ArmShapeParams, model_mesh

    model, shape = _arm_model()
    C = model.shape_coeffs.copy()
    C[-1] = np.random.default_rng(4).normal(0.0, 0.004, C.shape[1])
    fmodel = replace(model, shape_coeffs=C)
    J = _model_case()[2]
    h, _ = refine.elbow_axes(J)
    truth = ArmPose(np.eye(4), np.stack([[0.1, -0.05, 0.15], 1.0 * h, np.zeros(3)]))
    female = ArmShapeParams(shape.bmi, shape.muscularity, shape.height_m, shape.arm_length_m, sex=0.0)
    mesh = model_mesh(fmodel, female, truth)
    male = model_mesh(fmodel, replace(female, sex=1.0), truth)
    assert np.linalg.norm(mesh - male, axis=1).max() > 1e-3
    sensor = J[1] + np.array([0.3, 0.2, 1.0])
    frame = _frame(mesh, model.faces, model.arm_mask, sensor)
    got, root = refine.fit_shape_parameters(fmodel, [mesh], [truth], [frame], initial=female, fixed_shape=True)
    assert got.sex == 0.0 and np.abs(root[:3, 3]).max() < 1e-5
    free, _ = refine.fit_shape_parameters(fmodel, [mesh], [truth], [frame], initial=female, rounds=1)
    assert free.sex == 0.0
    men, _ = refine.fit_shape_parameters(model, [male], [truth], [_frame(male, model.faces, model.arm_mask, sensor)],
                                         rounds=1)
    assert men.sex == 1.0


def _flexed_arm_case():
    """The small model's arm with the elbow flexed 1 rad about its hinge, its mesh, and one depth frame of it from a
    sensor at the elbow + (0.3, 0.2, 1.0) m: (model, shape, rest joints, pose, mesh, frame)."""
    from bodystudio.muscle.model import model_mesh

    model, shape = _arm_model()
    J = _model_case()[2]
    h, _ = refine.elbow_axes(J)
    truth = ArmPose(np.eye(4), np.stack([[0.1, -0.05, 0.15], 1.0 * h, np.zeros(3)]))
    mesh = model_mesh(model, shape, truth)
    frame = _frame(mesh, model.faces, model.arm_mask, J[1] + np.array([0.3, 0.2, 1.0]))
    return model, shape, J, truth, mesh, frame


@pytest.mark.parametrize("fixed", [False, True])
def test_the_shape_fits_huber_loss_acts_only_when_asked(monkeypatch, fixed):
    """``fit_shape_parameters(huber_m=...)``: scipy's Huber loss with that scale (metres) in each round, for the
    free and the fixed-shape (root only) fit; none by default."""
    model, shape, J, truth, mesh, frame = _flexed_arm_case()
    calls = _spy(monkeypatch, run=False)
    refine.fit_shape_parameters(model, [mesh], [truth], [frame], initial=shape, fixed_shape=fixed, huber_m=0.003)
    refine.fit_shape_parameters(model, [mesh], [truth], [frame], initial=shape, fixed_shape=fixed)
    assert len(calls) == 4
    assert all(c.kw["loss"] == "huber" and c.kw["f_scale"] == 0.003 for c in calls[:2])
    assert all("loss" not in c.kw and "f_scale" not in c.kw for c in calls[2:])


def test_the_skeleton_fits_tracker_term_needs_both_joints_and_a_weight(monkeypatch):
    """The tracker's joints enter only with a positive weight (default 0, any weight in (0, 1] counts) and a weight
    without joints is ignored (no tracker rows, no error)."""
    s = _sequence()
    calls = _spy(monkeypatch, run=False)
    kw = dict(rounds=1, fit_skeleton=False)
    refine.fit_arm_sequence_skeleton(s.model, s.shape, s.start, s.frames, s.J, **kw)
    refine.fit_arm_sequence_skeleton(s.model, s.shape, s.start, s.frames, s.J, tracker_joints=s.tracker, **kw)
    refine.fit_arm_sequence_skeleton(s.model, s.shape, s.start, s.frames, s.J, tracker_weight=5.0, **kw)
    refine.fit_arm_sequence_skeleton(s.model, s.shape, s.start, s.frames, s.J, tracker_joints=s.tracker,
                                     tracker_weight=0.5, **kw)
    plain, no_weight, no_joints, half = (c.fun(c.x0) for c in calls)
    np.testing.assert_array_equal(no_weight, plain)
    np.testing.assert_array_equal(no_joints, plain)
    assert len(half) == len(plain) + 9 * 3


@pytest.mark.parametrize("n", [1, 2])
def test_a_sequence_of_one_or_two_frames_has_no_smoothness_rows(n):
    """Fewer than three frames have no second difference: the fit runs (the declared sparsity matches the residuals)
    and still moves the angles towards the truth."""
    s = _sequence()
    start, truth, frames = s.start[:n], s.truth[:n], s.frames[:n]
    poses, joints = refine.fit_arm_sequence_skeleton(s.model, s.shape, start, frames, s.J, tracker_joints=s.tracker[:n],
                                                     tracker_weight=30.0, rounds=1, max_nfev=5)
    assert len(poses) == n and joints.shape == (3, 3)
    assert _angle_errors_deg(poses, truth)[1] < _angle_errors_deg(start, truth)[1]


def test_the_twist_refinements_huber_loss_acts_only_when_asked(monkeypatch):
    """``refine_arm_pose(huber_m=...)``: scipy's trust-region solver with the Huber loss of that scale in each round;
    by default Levenberg-Marquardt on the squares; ``model_based_filtering`` passes its ``huber_m`` on."""
    from bodystudio.muscle.model import model_mesh, model_rest_vertices

    model, shape, J, truth, mesh, frame = _flexed_arm_case()
    calls = _spy(monkeypatch, run=False)
    refine.refine_arm_pose(truth, lambda p: model_mesh(model, shape, p), frame, mesh, J, huber_m=0.002, max_nfev=4)
    refine.refine_arm_pose(truth, lambda p: model_mesh(model, shape, p), frame, mesh, J, max_nfev=4)
    assert len(calls) == 4 and all(c.kw["max_nfev"] == 4 for c in calls)
    assert all((c.kw["method"], c.kw["loss"], c.kw["f_scale"]) == ("trf", "huber", 0.002) for c in calls[:2])
    assert all(c.kw == {"max_nfev": 4, "method": "lm"} for c in calls[2:])
    calls.clear()
    rest = model_rest_vertices(model, shape)
    ones = np.ones(len(mesh))
    refine.model_based_filtering(model, shape, truth.root, mesh, rest, model.part_weights, ones, frame, J,
                                 huber_m=0.003)
    refine.model_based_filtering(model, shape, truth.root, mesh, rest, model.part_weights, ones, frame, J)
    assert [c.kw.get("f_scale") for c in calls] == [0.003, 0.003, None, None]


def _biased_tracker(s, bias=(0.006, -0.004, 0.0), noise_m=0.002):
    """The exact tracker joints moved by a common ``bias`` (a short sequence's sample-mean error) plus noise."""
    return s.tracker + np.asarray(bias) + np.random.default_rng(0).normal(0.0, noise_m, s.tracker.shape)


def test_a_tracker_placement_prior_keeps_the_placement_on_the_depth_where_the_trackers_mean_is_off():
    """Exact depth, the tracker's joints 7 mm off on average (plus 2 mm of noise per frame) and the placement fitted:
    with the tracker's joints as absolute observations every frame (weight 30, the old behaviour) the placement
    follows their mean (measured 4.6 mm off); with the per-frame joints relative to the tracker's mean shoulder
    and the placement tied to that mean by a weak prior (3) it stays on the depth (measured 0.3 mm); a stiff prior
    follows the tracker's mean shoulder (measured 6.6 mm, the bias plus the noise's mean)."""
    s = _sequence(4, 0.0)
    tracker = _biased_tracker(s)
    kw = dict(tracker_joints=tracker, tracker_weight=30.0, smooth_weight=1.0, rounds=2, max_nfev=10, fit_root=True,
              fit_skeleton=False)

    def placement_mm(weight):
        poses, _ = refine.fit_arm_sequence_skeleton(s.model, s.shape, s.truth, s.frames, s.J,
                                                    tracker_placement_weight=weight, **kw)
        return 1000 * np.linalg.norm(poses[0].root[:3, 3])

    assert placement_mm(None) > 3.5
    assert placement_mm(3.0) < 0.8
    stiff = placement_mm(1e6)
    assert abs(stiff - 1000 * np.linalg.norm(tracker[:, 0].mean(axis=0) - s.tracker[:, 0].mean(axis=0))) < 0.5


def test_the_tracker_placement_prior_residuals_and_sparsity(monkeypatch):
    """With ``tracker_placement_weight``: each frame's tracker rows are sqrt(w) ((posed joints - posed shoulder) -
    (tracker joints - the tracker's mean shoulder)), then sqrt(prior) (posed shoulder - the tracker's mean shoulder)
    after the other rows; the declared sparsity holds the Jacobian (the prior touches the placement and skeleton)."""
    s = _sequence(3, 0.0)
    tracker = _biased_tracker(s)
    calls = _spy(monkeypatch, run=False)
    refine.fit_arm_sequence_skeleton(s.model, s.shape, s.start, s.frames, s.J, tracker_joints=tracker,
                                     tracker_weight=20.0, smooth_weight=3.0, rounds=1, max_nfev=4, fit_root=True,
                                     tracker_placement_weight=7.0)
    (c,) = calls
    x = c.x0 + np.random.default_rng(3).normal(0.0, 0.01, len(c.x0))
    res = c.fun(x)
    J = s.J + x[3:12].reshape(3, 3)
    root = np.eye(4)
    root[:3, 3] = x[:3]
    a = x[12:].reshape(3, 4)
    mean_shoulder = tracker[:, 0].mean(axis=0)
    row = 0
    for k in range(3):
        twist = float(s.start[k].angles[1] @ refine.elbow_axes(s.J)[1])
        p = ArmPose(root, np.vstack([a[k, :3], refine.elbow_rotvec(J, a[k, 3], twist), s.start[k].angles[2]]))
        n = len(s.frames[k].plane_pairs(refine.skeleton_model_mesh(s.model, s.start[k], s.rest, s.J))[0])
        P = refine.posed_joints(J, p)
        want = np.sqrt(20.0) * ((P - P[0]) - (tracker[k] - mean_shoulder)).ravel()
        np.testing.assert_allclose(res[row + n:row + n + 9], want, atol=1e-12)
        row += n + 9
    np.testing.assert_allclose(res[-3:], np.sqrt(7.0) * (P[0] - mean_shoulder), atol=1e-12)
    assert len(res) == row + 4 + 9 + 3
    E = c.kw["jac_sparsity"].toarray()
    assert E.shape == (len(res), len(x))
    np.testing.assert_array_equal(E[-3:], np.r_[np.ones(12), np.zeros(12)][None].repeat(3, 0))
    f0 = c.fun(c.x0)
    D = np.stack([c.fun(c.x0 + 1e-6 * np.eye(len(c.x0))[i]) - f0 for i in range(len(c.x0))], axis=1)
    assert not (np.abs(D) > 1e-12)[E == 0].any()
    assert (np.abs(D[-3:, :3]) > 0).any()
