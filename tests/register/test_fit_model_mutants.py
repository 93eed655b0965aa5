"""The scan fit's loop (:func:`bodystudio.register.fit.fit_model`, eq. 5 alternating θ and β) on a stand-in body.

Mutation tests (issue 17, docs/mutation/register-fit.md). The stand-in: four ellipsoids (one per bone of a
4-bone chain, 162 vertices each, skinned rigidly) in a 3-coefficient shape space that moves each bone's
ellipsoid and joints; the scan is that body posed at a known pose and shape, with 1 mm of noise. The §4.3
initial pose and coarse skeleton (which need a human scan) are replaced by stand-ins: the start is half the
true pose, the stature a number (its coefficients 0.8 of the true shape at the default 1.6 m). Ground truth:
the known pose and shape, and the posed body recomputed here by numpy skinning. One fit is shared by the tests
(functools.cache); the file runs in a few seconds.
"""

from __future__ import annotations

import os
from functools import cache
from types import SimpleNamespace

import numpy as np
import pytest
import trimesh

from bodystudio.body import Pose, Skeleton
from bodystudio.body.skinning import linear_blend_skinning, skinning_transforms
from bodystudio.geometry.mesh import Mesh
from bodystudio.register import fit as F

NAMES = ("pelvis", "spine_01", "clavicle_l", "tool")  # "tool" is not among FREE_BONES: held at the start
PARENTS = np.array([-1, 0, 1, 1])
HEADS = np.array([[0.0, 0.0, 0.0], [0.0, 0.3, 0.05], [0.05, 0.6, 0.0], [-0.1, 0.55, 0.1]])
TAILS = np.array([[0.0, 0.3, 0.05], [0.05, 0.6, 0.0], [0.35, 0.65, 0.05], [-0.1, 0.6, 0.45]])
ROLLS = np.array([0.1, -0.3, 0.0, 0.5])
C_TRUE = np.array([0.6, -0.4, 0.3])
TRUE_POSE = Pose([[0.1, -0.05, 0.08], [0.15, 0.1, -0.05], [-0.2, 0.1, 0.25], [0.0, 0.0, 0.0]], [0.02, -0.01, 0.03])
START_POSE = Pose(TRUE_POSE.rotations * 0.5, TRUE_POSE.translation * 0.5)  # the stand-in "initial pose"


@cache
def _model():
    rng = np.random.default_rng(21)
    sk = Skeleton(NAMES, PARENTS, HEADS, TAILS, ROLLS)
    sphere = trimesh.creation.icosphere(subdivisions=2)
    V, Fc, W, owner = [], [], [], []
    for j in range(4):
        L = np.linalg.norm(TAILS[j] - HEADS[j])
        local = sphere.vertices * [0.05, L / 2 + 0.03, 0.04]
        R = sk.rest_rotations[j]
        Fc.append(sphere.faces + sum(len(v) for v in V))
        V.append(local @ R.T + (HEADS[j] + TAILS[j]) / 2)
        w = np.zeros((len(local), 4))
        w[:, j] = 1.0
        W.append(w)
        owner.append(np.full(len(local), j))
    V, Fc, W, owner = np.concatenate(V), np.concatenate(Fc), np.concatenate(W), np.concatenate(owner)
    joint_basis = rng.normal(0, 0.02, (3, 4, 3))
    basis = joint_basis[:, owner, :]  # each ellipsoid moves with its bone

    def skeleton(c):
        d = np.tensordot(c, joint_basis, axes=1)
        return Skeleton(NAMES, PARENTS, HEADS + d, TAILS + d, ROLLS)

    def vertices(c):
        return V + np.tensordot(np.asarray(c, np.float64), basis, axes=1)

    return SimpleNamespace(n_components=3, attribute_names=("stature_m",), faces=Fc, weights=W,
                           basis=basis, joint_basis_heads=joint_basis, stddev=np.array([1.0, 1.0, 1.0]),
                           skeleton=skeleton, vertices=vertices,
                           attributes_to_coeffs=lambda a: C_TRUE * a["stature_m"] / 2.0)


def _posed(model, c, pose):
    return linear_blend_skinning(model.vertices(c), model.weights, skinning_transforms(model.skeleton(c), pose))


@cache
def _scan():
    model = _model()
    noise = np.random.default_rng(3).normal(0, 0.001, (len(model.faces) // 320 * 162, 3))  # 1 mm
    return Mesh(_posed(model, C_TRUE, TRUE_POSE) + noise, model.faces)


class _Stand:
    """The §4.3 stand-ins: a coarse skeleton of the given stature, the rest pose as the initial pose."""

    def __init__(self, stature_m):
        self.stature_m = stature_m
        self.initial_calls = []

    def coarse(self, V, faces):
        assert faces is not None and len(V) == len(faces) * 0 + len(V)
        return SimpleNamespace(stature_m=self.stature_m)

    def initial(self, skeleton, weights, Vr, Zv, coarse, faces, scan_faces):
        self.initial_calls.append((skeleton, Vr.copy(), coarse))
        self.initial_args = (weights, Zv, faces, scan_faces)
        return START_POSE


def _fit(stature_m=1.6, scan=None, **kw):
    stand = _Stand(stature_m)
    mp = pytest.MonkeyPatch()
    mp.setattr(F, "coarse_scan_skeleton", stand.coarse)
    mp.setattr(F, "initial_pose", stand.initial)
    try:
        return F.fit_model(_model(), _scan() if scan is None else scan, **kw), stand
    finally:
        mp.undo()


def _fit_default():
    return _fit_default_in(os.getpid())


@cache
def _fit_default_in(pid):
    """The shared fit, once per process: a forked mutation run (mutmut, recheck_direct) fits its own code."""
    seen = []
    fit, stand = _fit(progress=lambda it, err: seen.append((it, err)))
    return fit, stand, seen


def test_the_fit_recovers_the_known_pose_and_shape():
    fit, _, _ = _fit_default()
    np.testing.assert_allclose(fit.pose.rotations[:3], TRUE_POSE.rotations[:3], atol=0.01)
    np.testing.assert_allclose(fit.pose.rotations[3], 0.0)  # not a free bone
    np.testing.assert_allclose(fit.pose.translation, TRUE_POSE.translation, atol=0.003)
    np.testing.assert_allclose(fit.coeffs, C_TRUE, atol=0.05)
    assert fit.fit_err_mm_median < 1.0, fit.fit_err_mm_median  # the noise's normal part: ~0.67 mm
    assert fit.fit_err_mm_p90 < 2.0, fit.fit_err_mm_p90
    # the start is off: the first pair error is several mm
    assert fit.history[0] > 5.0 and fit.history[-1] < 2.0


def test_the_fit_returns_its_own_body_consistently():
    fit, _, _ = _fit_default()
    model = _model()
    np.testing.assert_allclose(fit.rest_vertices, model.vertices(fit.coeffs), atol=1e-12)
    np.testing.assert_allclose(fit.skeleton.heads, model.skeleton(fit.coeffs).heads, atol=1e-12)
    np.testing.assert_allclose(fit.vertices, _posed(model, fit.coeffs, fit.pose), atol=1e-12)
    assert fit.faces is model.faces and fit.weights is model.weights
    # the reported errors are the scan's distances to this posed surface (all 648 scan vertices sampled)
    d = F.surface_distance_mm(_scan().vertices, fit.vertices, model.faces)
    assert fit.fit_err_mm_median == pytest.approx(float(np.median(d)), rel=1e-9)
    assert fit.fit_err_mm_p90 == pytest.approx(float(np.percentile(d, 90)), rel=1e-9)


def test_iterations_history_progress_and_the_convergence_window():
    fit, _, seen = _fit_default()
    assert fit.iterations == len(fit.history)
    # progress after each iteration's steps: the converged one (no steps) is not reported
    assert [it for it, _ in seen] == list(range(fit.iterations - 1))
    assert [e for _, e in seen] == list(fit.history[:-1])
    # 1 mm noise: the error stops improving before the 40 iterations, not before two windows of 8
    w = F.CONVERGENCE_WINDOW
    assert (w, F.MAX_ITERATIONS) == (8, 40)
    for tol, h in ((1e-3, fit.history), (0.01, _fit(tolerance=0.01)[0].history)):
        assert 2 * w + 1 <= len(h) < F.MAX_ITERATIONS
        assert np.mean(h[-w:]) > np.mean(h[-2 * w:-w]) * (1 - tol)
        for n in range(2 * w + 1, len(h)):  # it did not stop earlier
            assert np.mean(h[n - w:n]) <= np.mean(h[n - 2 * w:n - w]) * (1 - tol), (tol, n)
        np.testing.assert_allclose(h, fit.history[:len(h)], rtol=1e-9)  # the same run, cut short
    # fewer iterations allowed than the window needs: all of them run
    seen12 = []
    assert _fit(max_iterations=12, progress=lambda it, e: seen12.append(it))[0].iterations == 12
    assert seen12 == list(range(12))


def test_max_iterations_and_the_stature_start():
    fit0, stand = _fit(max_iterations=0, stature_m=1.5)
    assert fit0.iterations == 0 and fit0.history == ()
    np.testing.assert_allclose(fit0.coeffs, C_TRUE * 0.75)  # attributes_to_coeffs at 1.5 m
    np.testing.assert_array_equal(fit0.pose.rotations, START_POSE.rotations)
    sk, Vr, coarse = stand.initial_calls[0]
    np.testing.assert_allclose(Vr, _model().vertices(C_TRUE * 0.75))
    assert coarse.stature_m == 1.5
    for stature in (1.0, 2.3, 0.5):  # outside (1.0, 2.3): the population mean
        fit0, _ = _fit(max_iterations=0, stature_m=stature)
        np.testing.assert_array_equal(fit0.coeffs, np.zeros(3))
    fit0, _ = _fit(max_iterations=0, stature_m=2.29)
    np.testing.assert_allclose(fit0.coeffs, C_TRUE * 1.145)
    fit3, _ = _fit(max_iterations=3)
    assert fit3.iterations == 3 and len(fit3.history) == 3
    # the shape step starts at the third iteration: two iterations leave the start's shape
    fit2, _ = _fit(max_iterations=2)
    np.testing.assert_array_equal(fit2.coeffs, C_TRUE * 0.8)
    assert np.abs(fit3.coeffs - C_TRUE * 0.8).max() > 1e-3


def test_the_tolerance_ends_the_fit_at_the_first_window():
    fit, _ = _fit(tolerance=1.0)  # any mean error above 0 times the earlier one: stop at the first check
    assert fit.iterations == 2 * F.CONVERGENCE_WINDOW + 1


def test_the_seed_draws_other_samples():
    a, _ = _fit(max_iterations=3, seed=0)
    b, _ = _fit(max_iterations=3, seed=1)
    c, _ = _fit(max_iterations=3, seed=0)
    assert a.history != b.history
    assert a.history == c.history


def test_the_initial_pose_gets_the_models_skeleton_weights_and_both_meshes():
    _, stand = _fit(max_iterations=0)
    sk, Vr, _ = stand.initial_calls[0]
    weights, Zv, faces, scan_faces = stand.initial_args
    model, scan = _model(), _scan()
    np.testing.assert_allclose(sk.heads, model.skeleton(C_TRUE * 0.8).heads)
    assert weights is model.weights and faces is model.faces
    np.testing.assert_array_equal(Zv, scan.vertices)
    np.testing.assert_array_equal(scan_faces, scan.faces)


def test_the_first_error_is_the_rms_over_every_compatible_pair_of_the_start():
    # 648 model and 648 scan vertices sampled without replacement out of 648: every vertex, in some order; the
    # first iteration's reach is 0.25 m, its scan -> model pairs on the surface (SURFACE_FROM = 0)
    from scipy.spatial import cKDTree

    from bodystudio.geometry.mesh import vertex_normals

    model, scan = _model(), _scan()
    posed = _posed(model, C_TRUE * 0.8, START_POSE)
    everyone = np.arange(len(posed))
    corners, bary, Zp, _ = F.compatible_pairs(posed, model.faces, vertex_normals(posed, model.faces), scan.vertices,
                                              scan.vertex_normals, cKDTree(scan.vertices), 0.25, everyone,
                                              surface=True, model_sample=everyone)
    rms_mm = 1000.0 * np.sqrt(np.mean(np.sum((np.einsum("nk,nki->ni", bary, posed[corners]) - Zp) ** 2, axis=1)))
    fit, _, _ = _fit_default()
    assert fit.history[0] == pytest.approx(rms_mm, rel=1e-9)
    # vertex pairs from the first iteration (surface_from past it): another first error
    assert _fit(max_iterations=1, surface_from=1)[0].history[0] != pytest.approx(rms_mm, rel=1e-6)


def test_seed_lm_iterations_defaults_and_a_scan_out_of_reach():
    a, _ = _fit(max_iterations=3)
    b, _ = _fit(max_iterations=3, seed=0)
    assert a.history == b.history
    c, _ = _fit(max_iterations=3, lm_iterations=1)
    assert c.history[1] != pytest.approx(a.history[1], rel=1e-6)
    far = Mesh(_scan().vertices + [10.0, 0.0, 0.0], _scan().faces)
    fit, _ = _fit(max_iterations=5, scan=far)  # no pair within reach: no iteration, the start returned
    assert fit.iterations == 0 and fit.history == ()
    np.testing.assert_array_equal(fit.coeffs, C_TRUE * 0.8)
    np.testing.assert_array_equal(fit.pose.rotations, START_POSE.rotations)


def test_the_fit_logs_its_iterations_and_median_distance(caplog):
    import logging

    with caplog.at_level(logging.INFO, logger="bodystudio.register.fit"):
        fit, _ = _fit(max_iterations=2)
    want = f"model fit: 2 iterations, median scan-model distance {fit.fit_err_mm_median:.2f} mm"
    assert [r.getMessage() for r in caplog.records if r.name == "bodystudio.register.fit"] == [want]


def test_the_scan_sample_factor_sets_the_scan_sample():
    # a scan of twice the model's vertices (each twice): factor 2 samples all 1296, factor 1 half of them
    scan = _scan()
    double = Mesh(np.r_[scan.vertices, scan.vertices], np.r_[scan.faces, scan.faces + len(scan.vertices)])
    a = _fit(max_iterations=1, scan=double)[0].history[0]
    b = _fit(max_iterations=1, scan=double, scan_sample_factor=2)[0].history[0]
    c = _fit(max_iterations=1, scan=double, scan_sample_factor=1)[0].history[0]
    assert a == b and c != pytest.approx(a, rel=1e-6)
    assert F.SCAN_SAMPLE_PER_MODEL_VERTEX == 2


def test_clutter_beyond_the_reach_is_never_paired():
    # a 5 cm ball 0.3 m behind the body (clutter, a second object): the reach (0.25 m, shrinking to 0.03 m) keeps
    # its points out of every pair, so the fit is the clean scan's
    scan = _scan()
    ball = trimesh.creation.icosphere(subdivisions=2, radius=0.05)
    cluttered = Mesh(np.r_[scan.vertices, ball.vertices + [0.0, 0.3, -0.45]],
                     np.r_[scan.faces, ball.faces + len(scan.vertices)])
    body = _posed(_model(), C_TRUE, TRUE_POSE)
    gap = np.linalg.norm(body[:, None] - (ball.vertices + [0.0, 0.3, -0.45])[None], axis=2).min()
    assert 0.25 < gap < 0.5
    fit, _ = _fit(scan=cluttered)
    np.testing.assert_allclose(fit.pose.rotations[:3], TRUE_POSE.rotations[:3], atol=0.01)
    np.testing.assert_allclose(fit.pose.translation, TRUE_POSE.translation, atol=0.003)
    np.testing.assert_allclose(fit.coeffs, C_TRUE, atol=0.05)
    assert fit.history[-1] < 2.0


def test_each_iteration_anneals_the_pose_prior_and_samples_the_model_vertices():
    # spies on the two steps' calls: the prior's scale max(1, 100 * 0.5^it) (the module docstring's anneal), and
    # Masuda's sample of min(n, 1500) model vertices drawn without replacement (here all 648, in some order)
    seen_scales, seen_samples = [], []
    real_pose_step, real_pairs = F.fit_pose_step, F.compatible_pairs

    def pose_step(*args, **kw):
        seen_scales.append(kw.get("prior_scale", "default"))
        return real_pose_step(*args, **kw)

    def pairs(*args, **kw):
        seen_samples.append(kw.get("model_sample"))
        return real_pairs(*args, **kw)

    mp = pytest.MonkeyPatch()
    mp.setattr(F, "fit_pose_step", pose_step)
    mp.setattr(F, "compatible_pairs", pairs)
    try:
        _fit(max_iterations=10)
    finally:
        mp.undo()
    assert (F.PRIOR_ANNEAL_START, F.PRIOR_ANNEAL_RATE, F.MODEL_SAMPLE) == (100.0, 0.5, 1500)
    np.testing.assert_allclose(seen_scales, [100, 50, 25, 12.5, 6.25, 3.125, 1.5625, 1.0, 1.0, 1.0])
    assert len(seen_samples) == 10
    for s in seen_samples:
        assert s is not None and sorted(s.tolist()) == list(range(648))
