"""The sequence fit's tracker weight from the noise of the data (issue 11, thirteenth capture pass): the tracker's
joints and the depth pairs each weighted by 1 / sigma^2, sigma estimated from the data (the tracker's second
differences, the depth pairs' robust spread), and the body rest-shape fit's own tracker weight."""

import numpy as np

from bodystudio.muscle.arm import ArmPose
from bodystudio.muscle.refine import (
    depth_residual_sigma_m,
    elbow_axes,
    elbow_rotvec,
    fit_arm_sequence_skeleton,
    noise_weighted_tracker_weight,
    posed_joints,
    skeleton_model_mesh,
    tracker_noise_sigma_m,
)
from tests.muscle.test_body_rest_shape import planted, space_2k  # noqa: F401  (the planted one-sided subject)
from tests.muscle.test_capture_analytic import Spies, scene  # noqa: F401  (the tiny capture scene)


def test_the_trackers_noise_is_read_from_its_own_second_differences():
    """A smooth 30 fps arm track (1 rad elbow swing, 3 s period) plus 10 mm per axis of white noise: the estimate is
    within 5 % of 10 mm; the smooth track alone reads near nothing (held at the 1 mm floor); halving the noise halves
    the estimate (the 1/6 of the second difference's variance is what scales it)."""
    rng = np.random.default_rng(0)
    t = np.arange(200) / 30.0
    a = 0.5 + 0.5 * np.sin(2 * np.pi * t / 3.0)
    smooth = np.stack([np.zeros((200, 3)),
                       np.c_[0.3 * np.sin(0.2 * a), -0.3 * np.cos(0.2 * a), np.zeros(200)],
                       np.c_[0.3 * np.sin(0.2 * a) + 0.25 * np.sin(a), -0.3 * np.cos(0.2 * a) - 0.25 * np.cos(a),
                             np.zeros(200)]], axis=1)
    noise = rng.normal(0.0, 1.0, smooth.shape)
    assert abs(tracker_noise_sigma_m(smooth + 0.010 * noise) - 0.010) < 0.0005
    assert abs(tracker_noise_sigma_m(smooth + 0.005 * noise) - 0.005) < 0.00025
    assert tracker_noise_sigma_m(smooth) == 0.001
    assert tracker_noise_sigma_m(smooth, floor_m=0.0) < 0.0005
    assert abs(noise_weighted_tracker_weight(0.002, 0.010) - 0.04) < 1e-12  # (sigma_d / sigma_t)^2


def _start(s, seed=3, sd_deg=1.0):
    """The planted subject's true poses (its true placement) and a start with every angle ``sd_deg`` (sd) off."""
    rng = np.random.default_rng(seed)
    rest, J = s.space.rest_and_joints(s.x_true, s.shoulder)
    h, _ = elbow_axes(J)
    truth, start = [], []
    for p in s.poses:
        root = p.root.copy()
        root[:3, 3] += s.offset
        truth.append(ArmPose(root, p.angles))
        d = rng.normal(0.0, np.radians(sd_deg), 4)
        start.append(ArmPose(root, np.stack([p.angles[0] + d[:3], elbow_rotvec(J, float(p.angles[1] @ h) + d[3], 0.0),
                                             p.angles[2]])))
    return rest, J, truth, start


def _mesh_err_mm(s, poses, rest, J):
    return float(np.median([1000 * np.linalg.norm(skeleton_model_mesh(s.model, p, rest, J, 0.5) - M, axis=1)[s.arm]
                            for p, M in zip(poses, s.meshes, strict=True)]))


def test_the_noise_weighted_sequence_fit_follows_the_depth_not_the_trackers_noise(planted):  # noqa: F811
    """The planted one-sided subject (true rest arm and skeleton), start angles 1 deg off, the tracker's joints 10 mm
    off per axis per frame (the simulated Kinect's noise). At the old fixed weight (30 per coordinate) the sequence
    fit's angles follow the tracker's noise and the meshes end millimetres off; weighted by the noise the data shows
    (depth spread at the start vs the tracker's second differences) they follow the exact depth."""
    s = planted
    rest, J, truth, start = _start(s)
    rng = np.random.default_rng(5)
    tracked = np.stack([posed_joints(J, p) for p in truth]) + rng.normal(0.0, 0.010, (len(truth), 3, 3))
    sigma_t = tracker_noise_sigma_m(tracked)
    sigma_d = depth_residual_sigma_m(s.model, start, s.frames, rest, J, 0.5, stride=1)
    w = noise_weighted_tracker_weight(sigma_d, sigma_t)
    assert 0.006 < sigma_t < 0.016, sigma_t  # 8 frames: 54 second differences
    assert 0.0 < w < 0.5, (w, sigma_d, sigma_t)

    def fit(weight):
        return fit_arm_sequence_skeleton(s.model, None, start, s.frames, J, 0.5, tracked, weight, 10.0, 3, 15, 0.004,
                                         False, False, rest=rest)[0]

    m_start, m_noise, m_fixed = (_mesh_err_mm(s, p, rest, J) for p in (start, fit(w), fit(30.0)))
    # measured: start 3.68 mm, noise-weighted 0.22 mm, fixed 30 1.55 mm
    assert m_noise < 0.4 < 1.0 < m_fixed, (m_start, m_noise, m_fixed)
    assert m_noise < 0.1 * m_start


def test_the_capture_weights_the_sequence_fits_tracker_by_the_noise_and_the_rest_fit_by_its_own(
        monkeypatch, scene):  # noqa: F811
    """``sequence_tracker_weight=None``: every sequence fit gets ``noise_weighted_tracker_weight`` of the depth's
    spread at the poses it starts from and the tracker's (template-space) noise; ``body_rest_tracker_weight`` goes to
    the rest-shape fit alone (None: the sequence fit's)."""
    from bodystudio.muscle import refine as refine_mod
    from bodystudio.muscle.capture import CaptureOptions, capture_arm_frames
    from bodystudio.muscle.nicp import NicpOptions

    s = scene
    fast = dict(shape_frames=2, shape_rounds=1, first_frame_nicp_iterations=3, sequence_rounds=1, sequence_max_nfev=3,
                pose_sigma_frames=0.0, mode="model", pose_refit=False, nicp=NicpOptions(iterations=2),
                body_rest_rounds=1, body_rest_frame_stride=1, body_rest_iterations=1, body_rest_keep_best=False)
    names = ("fit_arm_sequence_skeleton", "fit_body_rest_shape_and_poses", "noise_weighted_tracker_weight",
             "depth_residual_sigma_m", "tracker_noise_sigma_m")
    spies = Spies(monkeypatch, names)
    o = CaptureOptions(sequence_tracker_weight=None, body_rest_tracker_weight=7.0, **fast)
    capture_arm_frames(s.depths, s.camera, s.template, s.model, o, s.tracker, known_shape=s.shape)
    seq, rest, weights = (spies[n] for n in names[:3])
    assert len(seq) == 2 and len(weights) == 2  # one weight before each sequence fit (rounds 0 and 1)
    for call, wc, dc, tc in zip(seq, weights, spies["depth_residual_sigma_m"], spies["tracker_noise_sigma_m"],
                                strict=True):
        assert call.args[7] == wc.out != 30.0
        assert wc.args == (dc.out, tc.out)
        np.testing.assert_allclose(tc.args[0], call.args[6], atol=0)  # the template-space tracker
    # the depth spread is taken at the poses each sequence fit starts from
    for call, dc in zip(seq, spies["depth_residual_sigma_m"], strict=True):
        for p, q in zip(dc.args[1], call.args[2], strict=True):
            np.testing.assert_array_equal(p.angles, q.angles)
    (rc,) = rest
    assert rc.args[15] == 7.0  # the rest-shape fit's own weight
    assert refine_mod.tracker_noise_sigma_m(s.tracker) == 0.001  # the scene's exact tracker: held at the floor

    spies = Spies(monkeypatch, names)
    o = CaptureOptions(sequence_tracker_weight=None, body_rest_tracker_weight=None, **fast)
    capture_arm_frames(s.depths, s.camera, s.template, s.model, o, s.tracker, known_shape=s.shape)
    (rc,) = spies["fit_body_rest_shape_and_poses"]
    assert rc.args[15] == spies["noise_weighted_tracker_weight"][1].out  # None: the sequence fit's weight
    spies = Spies(monkeypatch, names)
    capture_arm_frames(s.depths, s.camera, s.template, s.model, CaptureOptions(sequence_tracker_weight=4.0, **fast),
                       s.tracker, known_shape=s.shape)
    assert not spies["noise_weighted_tracker_weight"]
    assert [c.args[7] for c in spies["fit_arm_sequence_skeleton"]] == [4.0, 4.0]
