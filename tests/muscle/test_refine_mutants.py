"""Fast tests of the whole-sequence fit's options added since refine.py's mutation row (issue 17,
docs/mutation/muscle-refine.md): ``start_joints`` (the fit's start, the prior kept at the regressed joints) and
``torso_pair_weight`` (the chest's depth rows scaled), read through the residual function and start that
``fit_arm_sequence_skeleton`` hands scipy's ``least_squares`` (the spy of test_sequence_fit_analytic.py), on the
small 2k model's own meshes.
"""

import numpy as np
import pytest

from bodystudio.muscle import refine
from bodystudio.muscle.arm import ArmPose

from .test_sequence_fit_analytic import OFFSET, _sequence, _spy


def _wide_frames(s):
    """The sequence's frames with every vertex pairable (the chest included): the torso's rows exist."""
    from bodystudio.muscle.nicp import CorrespondenceFilters

    out = []
    for f in s.frames:
        out.append(refine.DepthFrame(f.points, f.normals, f.tree, f.sensor_center, np.ones_like(f.arm_mask),
                                     f.adjacency, CorrespondenceFilters(), f.faces))
    return out


@pytest.mark.parametrize("free", [(True, True, True), (False, True, True)])
def test_the_fit_starts_from_the_given_skeleton_and_keeps_its_prior_at_the_regressed_one(monkeypatch, free):
    s = _sequence(3, 1.0)
    calls = _spy(monkeypatch, run=False)
    refine.fit_arm_sequence_skeleton(s.model, s.shape, s.start, s.frames, s.J, rounds=1, max_nfev=2, fit_root=True,
                                     skeleton_prior_weight=100.0, free_joints=free, start_joints=s.Jt)
    (c,) = calls
    idx = np.flatnonzero(free)
    n0 = 3 + 3 * len(idx)
    np.testing.assert_array_equal(c.x0[:3], 0.0)
    np.testing.assert_allclose(c.x0[3:n0], (s.Jt - s.J)[idx].ravel(), atol=1e-15)
    h_start = refine.elbow_axes(s.Jt)[0]
    a = c.x0[n0:].reshape(3, 4)
    for k in range(3):
        np.testing.assert_allclose(a[k, :3], s.start[k].angles[0], atol=1e-15)
        assert a[k, 3] == pytest.approx(float(s.start[k].angles[1] @ h_start), abs=1e-15)
    # the skeleton prior pulls towards the regressed joints, not the start: its rows at the start are the offset
    np.testing.assert_allclose(c.fun(c.x0)[-3 * len(idx):], 10.0 * (s.Jt - s.J)[idx].ravel(), atol=1e-12)
    assert np.abs(s.Jt - s.J).max() > 0.005


def test_without_the_skeleton_fit_the_start_joints_are_ignored(monkeypatch):
    s = _sequence(3, 1.0)
    calls = _spy(monkeypatch, run=False)
    kw = dict(rounds=1, max_nfev=2, fit_root=False, fit_skeleton=False)
    refine.fit_arm_sequence_skeleton(s.model, s.shape, s.start, s.frames, s.J, start_joints=s.Jt, **kw)
    refine.fit_arm_sequence_skeleton(s.model, s.shape, s.start, s.frames, s.J, **kw)
    with_start, plain = calls
    np.testing.assert_array_equal(with_start.x0, plain.x0)
    h = refine.elbow_axes(s.J)[0]
    assert with_start.x0[3] == pytest.approx(float(s.start[0].angles[1] @ h), abs=1e-15)
    np.testing.assert_array_equal(with_start.fun(with_start.x0), plain.fun(plain.x0))


def test_a_fit_started_on_the_true_skeleton_returns_it_when_the_prior_is_weak():
    """Exact depth and tracker of an offset skeleton: started there with a negligible prior, the fit stays on it."""
    s = _sequence(3, 1.0)
    _, J = refine.fit_arm_sequence_skeleton(s.model, s.shape, s.truth, s.frames, s.J, tracker_joints=s.tracker,
                                            rounds=1, max_nfev=3, skeleton_prior_weight=1e-6, start_joints=s.Jt)
    assert np.abs(J - s.Jt).max() < 5e-4, np.abs(J - s.Jt).max()
    assert np.abs(OFFSET).min() > 0.003


@pytest.mark.parametrize("huber", [0.0, 0.003])
def test_the_chests_depth_rows_are_scaled_by_the_root_of_the_torso_pair_weight(monkeypatch, huber):
    s = _sequence(3, 0.0)
    frames = _wide_frames(s)
    torso = np.asarray(s.model.part_weights)[:, 0] > 0.5
    calls = _spy(monkeypatch, run=False)
    kw = dict(rounds=1, max_nfev=2, fit_root=True, huber_m=huber, depth_huber_only=huber > 0,
              tracker_joints=s.tracker, tracker_weight=10.0)
    for w in (1.0, 0.25, 0.0, 2.0):
        refine.fit_arm_sequence_skeleton(s.model, s.shape, s.start, frames, s.J, torso_pair_weight=w, **kw)
    one, quarter, zero, two = calls
    x = one.x0 + np.random.default_rng(1).normal(0.0, 0.005, len(one.x0))
    r1, rq, r0, r2 = one.fun(x), quarter.fun(x), zero.fun(x), two.fun(x)
    assert len(r1) == len(rq) == len(r0) == len(r2)
    row, n_torso = 0, 0
    for k in range(3):
        mesh = refine.skeleton_model_mesh(s.model, s.start[k], s.rest, s.J)
        ids = frames[k].plane_pairs(mesh)[0]
        t = torso[ids]
        n_torso += t.sum()
        np.testing.assert_allclose(rq[row:row + len(ids)][t], 0.5 * r1[row:row + len(ids)][t], atol=1e-15)
        np.testing.assert_array_equal(r0[row:row + len(ids)][t], 0.0)
        np.testing.assert_allclose(r2[row:row + len(ids)][t], np.sqrt(2.0) * r1[row:row + len(ids)][t], atol=1e-15)
        np.testing.assert_array_equal(rq[row:row + len(ids)][~t], r1[row:row + len(ids)][~t])
        row += len(ids)
        np.testing.assert_array_equal(rq[row:row + 9], r1[row:row + 9])  # the tracker's rows unchanged
        row += 9
    np.testing.assert_array_equal(rq[row:], r1[row:])
    assert n_torso > 20 and np.abs(r1).max() > 1e-4


def test_the_default_chest_weight_is_one(monkeypatch):
    s = _sequence(3, 0.0)
    frames = _wide_frames(s)
    calls = _spy(monkeypatch, run=False)
    refine.fit_arm_sequence_skeleton(s.model, s.shape, s.start, frames, s.J, rounds=1, max_nfev=2)
    refine.fit_arm_sequence_skeleton(s.model, s.shape, s.start, frames, s.J, rounds=1, max_nfev=2,
                                     torso_pair_weight=1.0)
    a, b = calls
    x = a.x0 + 0.003
    np.testing.assert_array_equal(a.fun(x), b.fun(x))


def test_the_placement_prior_weight_is_the_squared_length_over_the_standard_error():
    """(L / SE)^2, SE^2 = mean over x, y, z of the shoulder's variance / T; the other joints do not count; a
    still shoulder gives the 1e-12 floor."""
    tracker = np.zeros((5, 3, 3))
    tracker[:, 0, 0] = [0.001, 0.002, 0.003, 0.004, 0.005]  # var 2e-6
    tracker[:, 0, 2] = [0.0, 0.0, 0.0, 0.0, 0.01]  # var 1.6e-5
    tracker[:, 2] = np.random.default_rng(0).normal(0.0, 0.1, (5, 3))
    se2 = (2e-6 + 1.6e-5) / 3 / 5
    assert refine.tracker_placement_prior_weight(tracker, 0.02) == pytest.approx(0.02 ** 2 / se2, rel=1e-12)
    assert isinstance(refine.tracker_placement_prior_weight(tracker, 0.02), float)
    still = np.zeros((4, 3, 3))
    assert refine.tracker_placement_prior_weight(still, 0.01) == pytest.approx(0.01 ** 2 / 1e-12, rel=1e-12)
    assert refine.tracker_placement_prior_weight(tracker.tolist(), 0.02) == pytest.approx(0.02 ** 2 / se2, rel=1e-12)


def test_the_placement_prior_needs_the_tracker(monkeypatch):
    """Without a tracker (or with its weight 0) the placement prior has no rows: the residuals are the plain ones."""
    s = _sequence(3, 0.0)
    calls = _spy(monkeypatch, run=False)
    kw = dict(rounds=1, max_nfev=2, fit_root=True)
    refine.fit_arm_sequence_skeleton(s.model, s.shape, s.start, s.frames, s.J, **kw)
    refine.fit_arm_sequence_skeleton(s.model, s.shape, s.start, s.frames, s.J, tracker_placement_weight=5.0, **kw)
    refine.fit_arm_sequence_skeleton(s.model, s.shape, s.start, s.frames, s.J, tracker_joints=s.tracker,
                                     tracker_weight=0.0, tracker_placement_weight=5.0, **kw)
    a, b, c = calls
    np.testing.assert_array_equal(a.fun(a.x0), b.fun(b.x0))
    np.testing.assert_array_equal(a.fun(a.x0), c.fun(c.x0))
    assert a.kw["jac_sparsity"].shape == b.kw["jac_sparsity"].shape == c.kw["jac_sparsity"].shape


def test_the_placement_prior_pulls_the_shared_root_to_the_trackers_mean_shoulder(monkeypatch):
    s = _sequence(3, 0.0)
    tracker = s.tracker + np.array([0.004, 0.0, -0.002])
    calls = _spy(monkeypatch, run=False)
    refine.fit_arm_sequence_skeleton(s.model, s.shape, s.truth, s.frames, s.J, tracker_joints=tracker,
                                     tracker_weight=4.0, rounds=1, max_nfev=2, fit_root=True, fit_skeleton=False,
                                     tracker_placement_weight=9.0)
    (c,) = calls
    x = c.x0.copy()
    x[:3] = [0.001, -0.002, 0.003]
    r = c.fun(x)
    shoulder = refine.posed_joints(s.J, ArmPose(np.eye(4), s.truth[0].angles))[0] + x[:3]
    np.testing.assert_allclose(r[-3:], 3.0 * (shoulder - tracker[:, 0].mean(axis=0)), atol=1e-9)
