"""Fast analytic tests of mus11g's last per-frame pose refit (``refine.refit_arm_poses_to_depth``; issue 17, mutation
testing; branch mutP). The stand-in case of tests/muscle/test_body_rest_joint_fit_mutants.py (a 12-vertex bent arm,
Eq. 10's displacements stubbed, every vertex paired with two fixed planes through its planted posed position), the rest
arm and skeleton the planted ones. The refit is compared with a reference Gauss-Newton written here from its docstring
(per frame: the shoulder rotation vector, the elbow hinge flexion and, with ``fit_translation``, the root translation;
central-difference Jacobian of the point-to-plane residuals and of the tracker's joints; Huber weights of the step's
start residuals; each coordinate held to its start by ``prior_weight * 0.3^2`` (angles) or ``translation_weight``
(translation); the forearm twist and the wrist held). No body assets are read; the file runs in about a second."""

import numpy as np
import pytest

from bodystudio.muscle import refine as rf
from bodystudio.muscle.arm import ArmPose, pose_arm
from bodystudio.muscle.refine import elbow_rotvec, posed_joints, refit_arm_poses_to_depth
from tests.muscle.test_body_rest_joint_fit_mutants import T, _case
from tests.muscle.test_body_space_standin_mutants import _displacements


def _axes(J):
    """The hinge axis (normal of the rest arm's plane) and the rest forearm axis, written out."""
    h = np.cross(J[1] - J[0], J[2] - J[1])
    f = (J[2] - J[1]) / np.linalg.norm(J[2] - J[1])
    return h / np.linalg.norm(h), f


def _start(c, twist=0.0, shifted=True):
    """Each frame's start: the case's angles (a few degrees off the truth) with the forearm ``twist`` (rad); the
    planted roots (``shifted``) or the case's roots, 3.7 mm off them."""
    out = []
    for p, q in zip(c.poses, c.true_poses, strict=True):
        flex = float(p.angles[1] @ _axes(c.J)[0])
        a = np.vstack([p.angles[0], elbow_rotvec(c.J, flex, twist), p.angles[2]])
        out.append(ArmPose((q if shifted else p).root.copy(), a))
    return out


def _reference(c, poses, norm_limit=0.9, huber_m=0.004, tracker_joints=None, tracker_weight=0.0, prior_weight=1.0,
               iterations=3, fit_translation=False, translation_weight=1.0):
    """The refit written densely from its docstring, frame by frame."""
    J, rest = c.J, c.rest
    h, f = _axes(J)
    out = []
    for k, (p, fr) in enumerate(zip(poses, c.frames, strict=True)):
        twist = float(p.angles[1] @ f)
        n = 7 if fit_translation else 4
        a0 = np.r_[p.angles[0], p.angles[1] @ h, np.zeros(n - 4)]
        D = np.r_[np.full(4, prior_weight * 0.09), np.full(n - 4, translation_weight)]

        def pose_of(a, p=p, twist=twist, n=n):
            root = p.root.copy()
            if n == 7:
                root[:3, 3] = root[:3, 3] + a[4:]
            return ArmPose(root, np.vstack([a[:3], elbow_rotvec(J, a[3], twist), p.angles[2]]))

        def mesh(a):
            q = pose_of(a)
            return pose_arm(rest + _displacements(c.model, q.angles), c.model.part_weights, J, q)

        a = a0.copy()
        for _ in range(iterations):
            M = mesh(a)
            idx, q, nrm = fr.plane_pairs(M)
            H, g = np.diag(D), D * (a - a0)
            if len(idx):
                r = np.sum((M[idx] - q) * nrm, axis=1)
                w = np.minimum(1.0, huber_m / np.maximum(np.abs(r), 1e-12)) if huber_m > 0 else np.ones(len(r))
                G = np.stack([np.sum((mesh(a + e)[idx] - mesh(a - e)[idx]) * nrm, axis=1) / 2e-7
                              for e in 1e-7 * np.eye(n)], axis=1)
                H, g = H + G.T @ (w[:, None] * G), g + G.T @ (w * r)
            if tracker_joints is not None and tracker_weight > 0:
                PJ = posed_joints(J, pose_of(a)).ravel()
                Gj = np.stack([(posed_joints(J, pose_of(a + e)) - posed_joints(J, pose_of(a - e))).ravel() / 2e-7
                               for e in 1e-7 * np.eye(n)], axis=1)
                H, g = H + tracker_weight * Gj.T @ Gj, g + tracker_weight * Gj.T @ (PJ - tracker_joints[k].ravel())
            a = a - np.linalg.solve(H, g)
        out.append(pose_of(a))
    return out


def _assert_same(got, want, atol=2e-7):
    """The refit against the reference: they differ by the finite differences (one-sided 1e-6 against central
    1e-7), measured <= 2e-8; a mutant moves them by 1e-5 .. 1e-1."""
    assert len(got) == len(want)
    for p, q in zip(got, want, strict=True):
        np.testing.assert_allclose(p.root, q.root, atol=atol)
        np.testing.assert_allclose(p.angles, q.angles, atol=atol)


def _refit(c, poses, *args, **kw):
    return refit_arm_poses_to_depth(c.model, poses, c.frames, c.rest, c.J, *args, **kw)


def _tracked(c, sd=0.004):
    return np.stack([posed_joints(c.J, p) for p in c.true_poses]) + sd * c.rng.normal(size=(T, 3, 3))


def test_the_refit_recovers_each_frames_angles_and_holds_the_rest(monkeypatch):
    c = _case(monkeypatch)
    start = _start(c)
    out = _refit(c, start, 0.6, 0.0, prior_weight=1e-9, iterations=6)
    assert isinstance(out, list) and len(out) == T
    for p, q, s in zip(out, c.true_poses, start, strict=True):
        np.testing.assert_allclose(p.angles, q.angles, atol=1e-9)
        np.testing.assert_array_equal(p.root, s.root)  # no translation without fit_translation
        np.testing.assert_array_equal(p.angles[2], s.angles[2])  # the wrist held
    assert set(c.seen["limits"]) == {0.6}
    # the start was off, and one step fewer than needed leaves it off; the inputs are not changed
    assert max(np.abs(s.angles[:2] - q.angles[:2]).max() for s, q in zip(start, c.true_poses, strict=True)) > 0.02
    one = _refit(c, start, 0.6, 0.0, prior_weight=1e-9, iterations=1)
    assert max(np.abs(p.angles - q.angles).max() for p, q in zip(one, c.true_poses, strict=True)) > 1e-7
    fresh = _start(c)
    for s, t in zip(start, fresh, strict=True):
        np.testing.assert_array_equal(s.angles, t.angles)
        np.testing.assert_array_equal(s.root, t.root)
    # Huber weights on: the same answer (the pairs end on their planes)
    hub = _refit(c, start, 0.6, 0.004, prior_weight=1e-9, iterations=6)
    for p, q in zip(hub, c.true_poses, strict=True):
        np.testing.assert_allclose(p.angles, q.angles, atol=1e-9)


@pytest.mark.parametrize("iterations", [1, 2])
def test_each_step_is_the_dense_gauss_newton_step_with_huber_weights_and_the_prior(monkeypatch, iterations):
    """Noisy planes (2 mm against a 3 mm Huber threshold, so some pairs are down-weighted), a forearm twist held,
    the prior at 0.5 per coordinate times a 0.3 m lever."""
    c = _case(monkeypatch, noise=0.004)
    start = _start(c, twist=0.2)
    kw = dict(norm_limit=0.7, huber_m=0.003, prior_weight=0.5, iterations=iterations)
    got = _refit(c, start, **kw)
    _assert_same(got, _reference(c, start, **kw))
    f = _axes(c.J)[1]
    for p, s in zip(got, start, strict=True):  # the twist held: a hinge flexion after the start's twist (read as
        tw = float(s.angles[1] @ f)  # the refit reads it: the rotation vector's forearm component)
        assert abs(tw) > 0.1
        np.testing.assert_allclose(p.angles[1], elbow_rotvec(c.J, _flexion_of(c.J, p.angles[1], tw), tw), atol=1e-12)
    # the prior acts (a weight 100 times larger holds the start closer) and the Huber threshold acts
    held = _refit(c, start, **{**kw, "prior_weight": 50.0})
    far = lambda ps: max(np.abs(p.angles - s.angles).max() for p, s in zip(ps, start, strict=True))  # noqa: E731
    assert far(held) < 0.5 * far(got)
    plain = _refit(c, start, **{**kw, "huber_m": 0.0})
    assert max(np.abs(p.angles - q.angles).max() for p, q in zip(plain, got, strict=True)) > 1e-5


def _flexion_of(J, rotvec, twist):
    """The hinge flexion of an elbow rotation vector made by ``elbow_rotvec(J, flexion, twist)``."""
    from scipy.spatial.transform import Rotation

    h, f = _axes(J)
    R = Rotation.from_rotvec(rotvec) * Rotation.from_rotvec(f * twist).inv()
    return float(R.as_rotvec() @ h)


def test_the_tracker_enters_at_its_weight_per_coordinate(monkeypatch):
    c = _case(monkeypatch, noise=0.001)
    start = _start(c, twist=-0.1)
    tracked = _tracked(c)
    kw = dict(norm_limit=0.9, huber_m=0.0, tracker_joints=tracked, tracker_weight=0.4, prior_weight=0.2,
              iterations=2)
    got = _refit(c, start, **kw)
    _assert_same(got, _reference(c, start, **kw))
    # without it (no joints, or a zero or negative weight) the answer is the one without the term, and it differs
    bare = _refit(c, start, **{**kw, "tracker_joints": None})
    _assert_same(bare, _reference(c, start, **{**kw, "tracker_joints": None}))
    assert max(np.abs(p.angles - q.angles).max() for p, q in zip(bare, got, strict=True)) > 1e-5
    for w in (0.0, -1.0):
        other = _refit(c, start, **{**kw, "tracker_weight": w})
        for p, q in zip(other, bare, strict=True):
            np.testing.assert_array_equal(p.angles, q.angles)
    # a weight under 1 is not clipped up: 0.4 and 1.0 differ
    one = _refit(c, start, **{**kw, "tracker_weight": 1.0})
    assert max(np.abs(p.angles - q.angles).max() for p, q in zip(one, got, strict=True)) > 1e-6


def test_the_translation_is_refitted_when_asked(monkeypatch):
    """The roots 3.7 mm off the planted ones: with ``fit_translation`` the shift comes back; its step is the
    reference's seven-coordinate one with ``translation_weight`` on the translation."""
    c = _case(monkeypatch)
    start = _start(c, shifted=False)
    free = _refit(c, start, 0.9, 0.0, prior_weight=1e-9, iterations=6, fit_translation=True,
                  translation_weight=1e-9)
    for p, q, s in zip(free, c.true_poses, start, strict=True):
        np.testing.assert_allclose(p.root, q.root, atol=1e-9)
        np.testing.assert_allclose(p.angles, q.angles, atol=1e-8)
        np.testing.assert_array_equal(p.root[:3, :3], s.root[:3, :3])
    noisy = _case(monkeypatch, noise=0.003)
    start = _start(noisy, twist=0.15, shifted=False)
    kw = dict(norm_limit=0.8, huber_m=0.002, prior_weight=0.3, iterations=2, fit_translation=True,
              translation_weight=0.4, tracker_joints=_tracked(noisy), tracker_weight=0.3)
    got = _refit(noisy, start, **kw)
    _assert_same(got, _reference(noisy, start, **kw))
    moved = max(np.abs(p.root - s.root).max() for p, s in zip(got, start, strict=True))
    assert moved > 1e-3
    held = _refit(noisy, start, **{**kw, "translation_weight": 1e6})
    assert max(np.abs(p.root - s.root).max() for p, s in zip(held, start, strict=True)) < 1e-3 * moved


def test_frames_without_pairs_keep_their_start_or_follow_the_tracker(monkeypatch):
    c = _case(monkeypatch, noise=0.001)
    c.frames[1].keep = np.zeros(0, int)
    c.frames[3].keep = np.array([4])
    start = _start(c)
    got = _refit(c, start, 0.9, 0.0, prior_weight=0.5, iterations=2)
    _assert_same(got, _reference(c, start, 0.9, 0.0, prior_weight=0.5, iterations=2))
    np.testing.assert_allclose(got[1].angles, start[1].angles, atol=1e-12)  # nothing pulls it
    tracked = _tracked(c)
    kw = dict(norm_limit=0.9, huber_m=0.0, tracker_joints=tracked, tracker_weight=2.0, prior_weight=0.5,
              iterations=2)
    got = _refit(c, start, **kw)
    _assert_same(got, _reference(c, start, **kw))
    assert np.abs(got[1].angles - start[1].angles).max() > 1e-3


def test_the_defaults_and_the_work_per_step(monkeypatch):
    """Defaults: norm limit 0.9, Huber 4 mm, no tracker, prior 1, 3 steps, no translation (weight 1). Each step
    poses the mesh once plus once per coordinate (the one-sided differences) on a frame with pairs."""
    c = _case(monkeypatch, noise=0.006)
    start = _start(c, twist=0.1)
    calls = []
    inner = rf.skeleton_model_mesh

    def counted(*args, **kw):
        calls.append(1)
        return inner(*args, **kw)

    monkeypatch.setattr(rf, "skeleton_model_mesh", counted)
    got = refit_arm_poses_to_depth(c.model, start, c.frames, c.rest, c.J)
    _assert_same(got, _reference(c, start))
    assert set(c.seen["limits"]) == {0.9}
    assert len(calls) == T * 3 * (1 + 4)
    calls.clear()
    _refit(c, start, fit_translation=True, iterations=2)
    assert len(calls) == T * 2 * (1 + 7)
    _assert_same(_refit(c, start, fit_translation=True), _reference(c, start, fit_translation=True))
    # the defaults' own values: each differs from a neighbour
    for kw in (dict(huber_m=0.0), dict(prior_weight=2.0), dict(iterations=4), dict(iterations=2)):
        other = _refit(c, start, **kw)
        assert max(np.abs(p.angles - q.angles).max() for p, q in zip(other, got, strict=True)) > 1e-9, kw
    free = _refit(c, _start(c, twist=0.1, shifted=False), fit_translation=True)
    _assert_same(free, _reference(c, _start(c, twist=0.1, shifted=False), fit_translation=True))
    assert max(np.abs(p.root - q.root).max() for p, q in zip(free, _start(c, shifted=False), strict=True)) > 1e-4


def test_zero_steps_return_the_start_and_the_lists_must_match(monkeypatch):
    c = _case(monkeypatch)
    start = _start(c, twist=0.3)
    zero = _refit(c, start, iterations=0, fit_translation=True)
    h, f = _axes(c.J)
    for p, s in zip(zero, start, strict=True):
        np.testing.assert_array_equal(p.root, s.root)
        np.testing.assert_array_equal(p.angles[[0, 2]], s.angles[[0, 2]])
        # the elbow rebuilt from its rotation vector's hinge and forearm components (the module's convention, as
        # the sequence fits read it: exact without a twist, ~2 mrad off the start's at a 0.3 rad twist)
        np.testing.assert_allclose(p.angles[1], elbow_rotvec(c.J, s.angles[1] @ h, s.angles[1] @ f), atol=1e-12)
    for p, s in zip(_refit(c, _start(c), iterations=0), _start(c), strict=True):
        np.testing.assert_allclose(p.angles, s.angles, atol=1e-12)
    with pytest.raises(ValueError):
        _refit(c, start[:-1])
    with pytest.raises(ValueError):
        _refit(c, start, tracker_joints=_tracked(c)[:-1], tracker_weight=1.0)


def test_the_trackers_joints_need_a_positive_weight_and_the_skeleton_is_read_in_double_precision(monkeypatch):
    """Joints given without a weight (the default 0), or with weight 0 where the tracker lost a frame (NaN), are
    not used; joints in single precision are read as doubles (the hinge axis from them is the same)."""
    c = _case(monkeypatch, noise=0.002)
    start = _start(c, twist=0.1)
    bare = _refit(c, start, iterations=2)
    tracked = _tracked(c)
    lost = tracked.copy()
    lost[2] = np.nan
    for kw in (dict(tracker_joints=tracked), dict(tracker_joints=lost, tracker_weight=0.0)):
        for p, q in zip(_refit(c, start, iterations=2, **kw), bare, strict=True):
            np.testing.assert_array_equal(p.angles, q.angles)
    J32 = c.J.astype(np.float32)
    single = refit_arm_poses_to_depth(c.model, start, c.frames, c.rest, J32, iterations=2)
    double = refit_arm_poses_to_depth(c.model, start, c.frames, c.rest, J32.astype(np.float64), iterations=2)
    for p, q in zip(single, double, strict=True):
        np.testing.assert_allclose(p.angles, q.angles, rtol=0, atol=1e-13)
