"""The last per-frame pose refit on the fitted rest arm (``refine.refit_arm_poses_to_depth``; issue 11, eleventh pass):
each frame's shoulder and elbow angles (and, optionally, its root translation) fitted to its own depth points with the
rest arm and skeleton held."""

import numpy as np

from bodystudio.muscle.arm import ArmPose
from bodystudio.muscle.refine import elbow_axes, elbow_rotvec, refit_arm_poses_to_depth, skeleton_model_mesh
from tests.muscle.test_body_rest_shape import planted, space_2k  # noqa: F401  (the planted one-sided subject)
from tests.muscle.test_capture_analytic import scene  # noqa: F401  (the tiny capture scene)


def _start(s, seed=3, sd_deg=2.5, shift=np.zeros(3)):
    """The planted subject's true poses (its true placement) with every angle a few degrees off, the root ``shift``
    off; the true rest arm and skeleton."""
    rng = np.random.default_rng(seed)
    rest, J = s.space.rest_and_joints(s.x_true, s.shoulder)
    h, _ = elbow_axes(J)
    truth, start = [], []
    for p in s.poses:
        root = p.root.copy()
        root[:3, 3] += s.offset
        truth.append(ArmPose(root, p.angles))
        d = rng.normal(0.0, np.radians(sd_deg), 4)
        moved = root.copy()
        moved[:3, 3] += shift
        start.append(ArmPose(moved, np.stack([p.angles[0] + d[:3], elbow_rotvec(J, float(p.angles[1] @ h) + d[3], 0.0),
                                              p.angles[2]])))
    return rest, J, truth, start


def _angle_err_deg(poses, truth):
    return max(np.degrees(np.linalg.norm(p.angles[:2] - q.angles[:2], axis=1)).max()
               for p, q in zip(poses, truth, strict=True))


def _mesh_err_mm(s, poses, rest, J):
    """Median distance (mm) of the posed model meshes from the planted ones, over the arm, every frame."""
    return float(np.median([1000 * np.linalg.norm(skeleton_model_mesh(s.model, p, rest, J, 0.5) - M, axis=1)[s.arm]
                            for p, M in zip(poses, s.meshes, strict=True)]))


def test_the_pose_refit_recovers_each_frames_angles_from_its_depth(planted):  # noqa: F811
    """Start angles 2.5 deg (sd) off per coordinate (up to ~6 deg): the refit against each frame's one-sided depth
    brings them back to a fraction of a degree and the meshes onto the planted ones; the input returned unchanged,
    or one Gauss-Newton step fewer than needed, stays far off."""
    s = planted
    rest, J, truth, start = _start(s)
    kw = dict(norm_limit=0.5, huber_m=0.0, prior_weight=1e-3)
    out = refit_arm_poses_to_depth(s.model, start, s.frames, rest, J, iterations=4, **kw)
    one = refit_arm_poses_to_depth(s.model, start, s.frames, rest, J, iterations=1, **kw)
    before, after = _angle_err_deg(start, truth), _angle_err_deg(out, truth)
    assert before > 4.0, before
    assert after < 0.3, after
    assert _mesh_err_mm(s, out, rest, J) < 0.3 < 3.0 < _mesh_err_mm(s, start, rest, J)
    assert _angle_err_deg(one, truth) > after  # the iterations count
    # the twist and the wrist are held, the root untouched without fit_translation
    for p, q in zip(out, start, strict=True):
        np.testing.assert_array_equal(p.root, q.root)
        np.testing.assert_array_equal(p.angles[2], q.angles[2])


def test_the_pose_refit_with_the_translation_recovers_a_shifted_placement(planted):  # noqa: F811
    """The roots 4 mm off too: with ``fit_translation`` the frame's translation comes back within 0.5 mm and the
    angles within 0.5 deg; without it the angles cannot absorb the shift (the meshes stay > 1 mm off)."""
    s = planted
    shift = np.array([0.004, -0.003, 0.002])
    rest, J, truth, start = _start(s, shift=shift)
    kw = dict(norm_limit=0.5, huber_m=0.0, prior_weight=1e-3, iterations=5)
    free = refit_arm_poses_to_depth(s.model, start, s.frames, rest, J, fit_translation=True,
                                    translation_weight=1e-3, **kw)
    held = refit_arm_poses_to_depth(s.model, start, s.frames, rest, J, **kw)
    for p, q in zip(free, truth, strict=True):
        assert np.linalg.norm(p.root[:3, 3] - q.root[:3, 3]) < 5e-4
    assert _angle_err_deg(free, truth) < 0.5
    assert _mesh_err_mm(s, free, rest, J) < 0.5 < 1.0 < _mesh_err_mm(s, held, rest, J)


def test_the_tracker_and_the_prior_hold_the_angles(planted):  # noqa: F811
    """A dominant prior keeps the start; the tracker's joints at a high weight pull the posed joints onto them."""
    s = planted
    rest, J, truth, start = _start(s)
    held = refit_arm_poses_to_depth(s.model, start, s.frames, rest, J, 0.5, 0.0, prior_weight=1e9)
    assert _angle_err_deg(held, truth) > 0.99 * _angle_err_deg(start, truth)
    from bodystudio.muscle.refine import posed_joints

    tracked = np.stack([posed_joints(J, p) for p in truth])
    pulled = refit_arm_poses_to_depth(s.model, start, s.frames, rest, J, 0.5, 0.0,
                                      tracker_joints=tracked, tracker_weight=1e7, prior_weight=1e-3)
    err = max(np.abs(posed_joints(J, p) - t).max() for p, t in zip(pulled, tracked, strict=True))
    assert err < 2e-4, err


def test_the_capture_refits_the_sequence_stages_poses_when_asked(monkeypatch, scene):  # noqa: F811
    """``CaptureOptions(pose_refit=True)``: the sequence stage's poses, rest arm and skeleton go to
    ``refit_arm_poses_to_depth`` with the tracker in the template's space and :data:`capture.POSE_REFIT`; its poses
    are the capture's (no smoothing here). Off: never called; on by default since the eleventh pass."""
    from bodystudio.muscle.capture import POSE_REFIT, CaptureOptions, capture_arm_frames
    from bodystudio.muscle.nicp import NicpOptions
    from tests.muscle.test_capture_analytic import Spies

    s = scene
    fast = dict(shape_frames=2, shape_rounds=1, first_frame_nicp_iterations=3, sequence_rounds=1,
                sequence_max_nfev=3, nicp=NicpOptions(iterations=2), pose_sigma_frames=0.0, mode="model")
    spies = Spies(monkeypatch, ("refit_arm_poses_to_depth", "sequence_stage"))
    assert CaptureOptions().pose_refit
    off = capture_arm_frames(s.depths, s.camera, s.template, s.model, CaptureOptions(pose_refit=False, **fast),
                             s.tracker, known_shape=s.shape)
    assert spies["refit_arm_poses_to_depth"] == []
    on = capture_arm_frames(s.depths, s.camera, s.template, s.model, CaptureOptions(pose_refit=True, **fast),
                            s.tracker, known_shape=s.shape)
    (call,) = spies["refit_arm_poses_to_depth"]
    # the sequence stage's result (its last sequence fit may be a rest-shape round the stop undid)
    seq = spies["sequence_stage"][-1].out
    for p, q in zip(call.args[1], seq[0], strict=True):
        np.testing.assert_allclose(p.angles, q.angles, atol=1e-12)
    np.testing.assert_allclose(call.args[3], seq[1], atol=1e-12)  # the rest arm
    np.testing.assert_allclose(call.args[4], seq[2], atol=1e-12)  # the skeleton
    assert call.args[5:7] == (CaptureOptions().norm_limit, CaptureOptions().sequence_huber_m)
    np.testing.assert_allclose(call.args[7] + on.similarity[2], s.tracker, atol=1e-9)  # template space (a shift)
    assert call.args[8] == POSE_REFIT["tracker_weight"]
    assert {k: call.kwargs[k] for k in ("prior_weight", "iterations")} == {
        k: POSE_REFIT[k] for k in ("prior_weight", "iterations")}
    for p, q in zip(on.poses, call.out, strict=True):
        np.testing.assert_allclose(p.angles, q.angles, atol=1e-12)
    assert "pose_refit" in on.timings_ms and "pose_refit" not in off.timings_ms
    assert max(np.abs(p.angles - q.angles).max() for p, q in zip(on.poses, off.poses, strict=True)) > 1e-6


def test_at_the_capture_weight_the_refit_follows_the_depth_not_the_trackers_noise(planted):  # noqa: F811
    """Pass 11's reason for :data:`capture.POSE_REFIT`'s tracker weight: the tracker's joints 10 mm off per axis
    (the simulated Kinect tracker's per-frame noise) against the exact one-sided depth. At the sequence fit's weight
    (30 per coordinate) the angles follow the tracker's noise by degrees and the meshes are millimetres off; at
    POSE_REFIT's they follow the depth."""
    from bodystudio.muscle.capture import POSE_REFIT
    from bodystudio.muscle.refine import posed_joints

    s = planted
    rest, J, truth, start = _start(s, sd_deg=1.0)
    rng = np.random.default_rng(5)
    tracked = np.stack([posed_joints(J, p) for p in truth]) + rng.normal(0.0, 0.010, (len(truth), 3, 3))
    kw = dict(norm_limit=0.5, huber_m=0.004, tracker_joints=tracked, prior_weight=POSE_REFIT["prior_weight"],
              iterations=POSE_REFIT["iterations"])
    ours = refit_arm_poses_to_depth(s.model, start, s.frames, rest, J, tracker_weight=POSE_REFIT["tracker_weight"],
                                    **kw)
    heavy = refit_arm_poses_to_depth(s.model, start, s.frames, rest, J, tracker_weight=30.0, **kw)
    m_ours, m_heavy = _mesh_err_mm(s, ours, rest, J), _mesh_err_mm(s, heavy, rest, J)
    # measured (tracker 0.03, prior 0.1): 0.08 mm, 0.38 deg at worst; at 30: 4.86 mm, 6.3 deg (start: 3.4 deg)
    assert m_ours < 0.3 and m_heavy > 3.0, (m_ours, m_heavy)
    assert _angle_err_deg(ours, truth) < 1.0 < 3.0 < _angle_err_deg(heavy, truth)
