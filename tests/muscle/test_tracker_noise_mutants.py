"""mus11k's noise-weighted tracker, case by case (issue 17, mutation round mutR): ``refine.tracker_noise_sigma_m``,
``depth_residual_sigma_m``, ``noise_weighted_tracker_weight``, ``capture.sequence_tracker_weight`` and
``sequence_stage``'s ``body_rest_tracker_weight`` line.

``test_sequence_tracker_noise_weight.py`` checks the effect on the planted 2k subject (seconds a test); these cases
pin the formulas on analytic tracks and stand-in frames (an exactly known second difference, residuals of a known
median, the frame stride), and the wiring with every fit stubbed (``test_sequence_stage_stop_mutants.py``'s stage).
"""

import logging
from types import SimpleNamespace

import numpy as np
import pytest

from bodystudio.errors import InputError
from bodystudio.muscle import capture as cap
from bodystudio.muscle import refine as rf
from bodystudio.muscle.capture import CaptureOptions
from tests.muscle.test_sequence_stage_stop_mutants import _stage


def test_the_trackers_noise_of_a_track_with_a_known_second_difference():
    """``X_t = c t^2 / 2`` per coordinate has the second difference ``c`` in every frame: sigma = c / sqrt(6)."""
    t = np.arange(7.0)
    c = np.array([0.006, -0.003, 0.0])
    X = (0.5 * t[:, None, None] ** 2) * np.tile(c, (1, 2, 1)) + np.array([[0.1, 0.2, 0.3], [0.4, 0.5, 0.6]])
    expected = np.sqrt(np.mean(np.tile(c, 2) ** 2) / 6.0)
    assert rf.tracker_noise_sigma_m(X, floor_m=0.0) == pytest.approx(expected, rel=1e-12)
    assert rf.tracker_noise_sigma_m(X.reshape(7, 6), floor_m=0.0) == pytest.approx(expected, rel=1e-12)  # (T, 3J)
    assert rf.tracker_noise_sigma_m(X[:3], floor_m=0.0) == pytest.approx(expected, rel=1e-12)  # 3 frames: enough
    assert isinstance(rf.tracker_noise_sigma_m(X), float)
    # a noise-free (linear) track: the floor, by default 1 mm
    lin = t[:, None, None] * np.ones((1, 3, 3)) * 0.01
    assert rf.tracker_noise_sigma_m(lin) == 0.001
    assert rf.tracker_noise_sigma_m(lin, floor_m=0.004) == 0.004
    assert rf.tracker_noise_sigma_m(X, floor_m=1.0) == 1.0
    assert rf.tracker_noise_sigma_m(X) == pytest.approx(max(expected, 0.001), rel=1e-12)
    # a single-precision track is read in double precision (its second differences are not rounded to float32)
    X32 = (X + 0.37).astype(np.float32)
    assert rf.tracker_noise_sigma_m(X32, floor_m=0.0) == rf.tracker_noise_sigma_m(X32.astype(np.float64), floor_m=0.0)


def test_white_noise_reads_as_its_own_sigma():
    rng = np.random.default_rng(2)
    X = 0.012 * rng.standard_normal((3000, 3, 3))
    assert rf.tracker_noise_sigma_m(X) == pytest.approx(0.012, rel=0.02)


@pytest.mark.parametrize("frames", [0, 1, 2])  # 0: an empty track, refused before the reshape
def test_the_trackers_noise_needs_three_frames(frames):
    with pytest.raises(InputError, match=rf"^the tracker's noise needs at least 3 frames of joints, got {frames}$"):
        rf.tracker_noise_sigma_m(np.zeros((frames, 3, 3)))


def test_the_noise_weighted_tracker_weight_is_the_ratio_of_variances():
    assert rf.noise_weighted_tracker_weight(0.002, 0.012) == pytest.approx((2.0 / 12.0) ** 2, rel=1e-14)
    assert rf.noise_weighted_tracker_weight(0.003, 0.001) == pytest.approx(9.0, rel=1e-14)
    assert rf.noise_weighted_tracker_weight(0.001, 0.0) == pytest.approx(1e12, rel=1e-12)  # sigma floored at 1e-9
    assert rf.noise_weighted_tracker_weight(0.001, 2e-9) == pytest.approx(0.25e12, rel=1e-12)
    assert type(rf.noise_weighted_tracker_weight(np.float32(0.002), 0.012)) is float


class _Frame:
    """A depth frame whose point-to-plane pairs give the residuals ``r`` on any mesh (vertex k, normal z)."""

    def __init__(self, r):
        self.r = np.asarray(r, float)

    def plane_pairs(self, M):
        k = np.arange(len(self.r))
        return k, M[k] - self.r[:, None] * np.array([0.0, 0.0, 1.0]), np.tile([0.0, 0.0, 1.0], (len(k), 1))


def _residual_sigma(monkeypatch, residuals, **kw):
    seen = []

    def mesh(model, p, rest, joints, norm_limit):
        seen.append((model, p, rest, joints, norm_limit))
        return np.full((8, 3), float(p))  # the mesh's offset cancels in M[k] - q

    monkeypatch.setattr(rf, "skeleton_model_mesh", mesh)
    frames = [_Frame(r) for r in residuals]
    out = rf.depth_residual_sigma_m("model", list(range(len(frames))), frames, "rest", "joints", **kw)
    return out, seen


def test_the_depth_residuals_spread_is_their_scaled_median_absolute_value(monkeypatch):
    # frames 0 and 2 (stride 2): residuals -3, 1, 2 and 5, -4 mm -> |r| median 3 mm; frame 1's 100 mm are not read
    out, seen = _residual_sigma(monkeypatch, [[-0.003, 0.001, 0.002], [0.1, 0.1], [0.005, -0.004]], stride=2,
                                norm_limit=0.7)
    assert out == pytest.approx(1.4826 * 0.003, rel=1e-12) and isinstance(out, float)
    assert [s[1] for s in seen] == [0, 2] and all(s[0] == "model" and s[2:] == ("rest", "joints", 0.7) for s in seen)
    out, seen = _residual_sigma(monkeypatch, [[0.002]] * 10 + [[0.2]] * 3)  # the default stride 10: frames 0, 10
    assert [s[1] for s in seen] == [0, 10] and out == pytest.approx(1.4826 * 0.101, rel=1e-12)
    assert seen[0][4] == 0.9  # the default norm limit
    assert _residual_sigma(monkeypatch, [])[0] == 0.0
    with pytest.raises(ValueError, match="zip"):  # poses and frames must pair up
        rf.depth_residual_sigma_m("model", [0, 1, 2], [_Frame([0.001])] * 2, "rest", "joints", stride=1)
    assert _residual_sigma(monkeypatch, [[]])[0] == 0.0  # a frame without pairs


def test_the_sequence_fits_tracker_weight_is_the_option_or_the_noise_weighted_one(monkeypatch, caplog):
    calls = []
    monkeypatch.setattr(cap, "depth_residual_sigma_m", lambda *a: calls.append(("depth", a)) or 0.0123)
    monkeypatch.setattr(cap, "tracker_noise_sigma_m", lambda t: calls.append(("tracker", t)) or 0.012)
    args = ("model", "poses", "frames", "rest", "joints")
    tracker = np.zeros((4, 3, 3))
    assert cap.sequence_tracker_weight(CaptureOptions(sequence_tracker_weight=3.5), *args, tracker) == 3.5
    assert cap.sequence_tracker_weight(CaptureOptions(sequence_tracker_weight=0.0), *args, tracker) == 0.0
    assert cap.sequence_tracker_weight(CaptureOptions(sequence_tracker_weight=None), *args, None) == 0.0
    assert calls == []
    o = CaptureOptions(sequence_tracker_weight=None, norm_limit=0.6)
    with caplog.at_level(logging.INFO, logger=cap.__name__):
        w = cap.sequence_tracker_weight(o, *args, tracker)
    assert w == pytest.approx((12.3 / 12.0) ** 2, rel=1e-14)
    assert calls[0] == ("depth", (*args, 0.6)) and calls[1][0] == "tracker" and calls[1][1] is tracker
    assert [r.getMessage() for r in caplog.records] == ["the sequence fit's tracker weight 1.0506 (depth 12.30 mm)"]


def _stage_weights(monkeypatch, **opts):
    """sequence_stage with every fit stubbed, ``sequence_tracker_weight`` giving 7, 8, 9, ... per round; what the
    weight's calls saw and the weights the sequence fit and the rest-shape fit got."""
    seen = SimpleNamespace(weight=[], seq_tw=[], seq_args=[], seq_out=[])

    def weight(o, model, poses, frames, rest, joints, tracker):
        seen.weight.append(SimpleNamespace(o=o, model=model, poses=poses, frames=frames, rest=rest, joints=joints,
                                           tracker=tracker))
        stub = cap.fit_arm_sequence_skeleton  # _stage's stub, set by now: record the weight it gets
        if not getattr(stub, "recording", False):
            def rec(*a, **k):
                seen.seq_tw.append(a[7])
                seen.seq_args.append(a)
                seen.seq_out.append(stub(*a, **k))
                return seen.seq_out[-1]

            rec.recording = True
            monkeypatch.setattr(cap, "fit_arm_sequence_skeleton", rec)
        return 7.0 + len(seen.weight) - 1

    monkeypatch.setattr(cap, "sequence_tracker_weight", weight)
    out, stage, o, poses, frames, tracker, J = _stage(monkeypatch, energies=[3.0, 2.0, 1.0, 0.5], **opts)
    seen.poses = poses
    return seen, stage, o, tracker, J


@pytest.mark.parametrize("fit_poses", [False, True])
def test_the_rest_shape_fit_gets_the_sequence_weight_or_its_own(monkeypatch, fit_poses):
    seen, stage, o, tracker, J = _stage_weights(monkeypatch, body_rest_fit_poses=fit_poses)
    assert len(seen.weight) == 4 and seen.seq_tw == [7.0, 8.0, 9.0, 10.0]
    assert all(w.o is o and w.tracker is tracker and w.model == "model" for w in seen.weight)
    assert all(w.frames == [f"frame{k}" for k in range(11)] for w in seen.weight)
    # each round's weight at the poses the round starts from: the stage's, then the last sequence fit's
    assert seen.weight[0].poses is seen.poses
    assert all(w.poses is out[0] for w, out in zip(seen.weight[1:], seen.seq_out, strict=False))
    for a in seen.seq_args:  # the sequence fit's arguments around the weight
        assert a[:2] == ("model", "shape") and a[3] == seen.weight[0].frames and a[6] is tracker
        assert a[5] == o.norm_limit and a[8] == o.sequence_smooth_weight and a[9:12] == (
            o.sequence_rounds, o.sequence_max_nfev, o.sequence_huber_m)
    # round 0 on the projected rest arm's joints, then the sequence's
    np.testing.assert_array_equal(seen.weight[0].joints, stage.space.calls[0][1] + np.ones((3, 3)))
    np.testing.assert_array_equal(seen.weight[0].rest, np.full((4, 3), 1.0))
    np.testing.assert_array_equal(seen.weight[1].joints, stage.seq[0].J + 0.001)
    fits = stage.joint if fit_poses else stage.held
    assert [f.args[-2 if fit_poses else -1] for f in fits] == [8.0, 9.0, 10.0]  # None: the round's sequence weight
    monkeypatch.undo()
    seen, stage, *_ = _stage_weights(monkeypatch, body_rest_fit_poses=fit_poses, body_rest_tracker_weight=2.5)
    fits = stage.joint if fit_poses else stage.held
    assert [f.args[-2 if fit_poses else -1] for f in fits] == [2.5] * 3 and seen.seq_tw == [7.0, 8.0, 9.0, 10.0]
