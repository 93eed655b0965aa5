"""One set of bone lengths per sequence (issue 15): the tracker's per-frame length jitter moves the pelvis."""

import numpy as np
import pytest

from bodystudio.body.kinect import kinect_joint_names
from bodystudio.capture.kinect import simulate_tracker_joints
from bodystudio.errors import InputError
from bodystudio.reconstruct.articulated_fit import refine_bone_transforms
from bodystudio.reconstruct.pose_init import (
    initialise_pose,
    pose_template,
    sequence_bone_lengths,
    tracked_bone_lengths,
    with_bone_lengths,
)

NAMES = kinect_joint_names("v2")
PELVIS = [NAMES.index(n) for n in ("SpineBase", "HipLeft", "HipRight")]
LEG_ENDS = [NAMES.index(n) for n in ("AnkleLeft", "AnkleRight", "FootLeft", "FootRight")]


def _tracker_frames(joints: np.ndarray, n: int, seed: int, noise_m: float = 0.0) -> list[np.ndarray]:
    """``n`` frames of a simulated Kinect (3 % bone-length jitter per frame) watching a person stand still."""
    from bodystudio.capture import kinect as kinect_mod

    rng = np.random.default_rng(seed)
    real = kinect_mod.kinect_joints
    kinect_mod.kinect_joints = lambda *a, **k: joints  # the posed skeleton's joints are given
    try:
        return [simulate_tracker_joints(None, None, None, "v2", rng, noise_m=noise_m)[0] for _ in range(n)]
    finally:
        kinect_mod.kinect_joints = real


def test_sequence_lengths_undo_the_jitter(synthetic_capture):
    truth = synthetic_capture["joints"]
    frames = _tracker_frames(truth, 15, seed=3)
    L_true = tracked_bone_lengths(truth)
    L_seq = sequence_bone_lengths(frames)
    child = np.isfinite(L_true)
    frame_err = np.abs(np.array([tracked_bone_lengths(J)[child] for J in frames]) / L_true[child] - 1)
    seq_err = np.abs(L_seq[child] / L_true[child] - 1)
    # 15 frames of 3 % jitter: the median is off by ~1 % (measured mean 0.7 %, max 2.6 %), one frame by
    # 2.4 % on average (max 9 %)
    assert seq_err.max() < 0.035 and seq_err.mean() < 0.01
    assert seq_err.mean() < 0.5 * frame_err.mean()
    # without joint noise the frame's directions are exact, so the true lengths give back the true joints
    rebuilt = with_bone_lengths(frames[0], L_true)
    assert np.abs(rebuilt - truth).max() < 1e-9
    leg_ends_frame = 1000 * np.linalg.norm(frames[0][LEG_ENDS] - truth[LEG_ENDS], axis=1).max()
    leg_ends_seq = 1000 * np.linalg.norm(with_bone_lengths(frames[0], L_seq)[LEG_ENDS] - truth[LEG_ENDS],
                                         axis=1).max()
    assert leg_ends_seq < 15.0 < leg_ends_frame


def test_untracked_bones_keep_their_offsets():
    J = np.arange(75, dtype=float).reshape(25, 3) * 0.01
    L = np.full(25, np.nan)
    assert np.allclose(with_bone_lengths(J, L), J)
    J_nan = J.copy()
    J_nan[NAMES.index("KneeLeft")] = np.nan
    L_seq = sequence_bone_lengths([J, J_nan])
    assert np.isfinite(L_seq[NAMES.index("KneeLeft")])  # the other frame tracked it
    with pytest.raises(InputError, match="bone lengths need 25"):
        with_bone_lengths(J[:3], L)
    with pytest.raises(InputError, match="at least one frame"):
        sequence_bone_lengths([])


def test_pelvis_stays_with_sequence_lengths(body_2k, synthetic_capture):
    """The refinement keeps each frame's bone lengths, so a leg the tracker made too long or short is fitted
    to its silhouette by moving the whole pelvis; with the sequence's lengths the pelvis stays."""
    from bodystudio.reconstruct.tracking import SilhouetteFields, TrackParams, silhouette_data_term

    cap = synthetic_capture
    truth = cap["joints"]
    frames = _tracker_frames(truth, 15, seed=3, noise_m=0.003)
    L_seq = sequence_bone_lengths(frames)
    term = silhouette_data_term(SilhouetteFields(cap["rig"], cap["masks"]), TrackParams())
    errors = {"frame": [], "sequence": []}
    init = initialise_pose(body_2k, truth)
    reference = pose_template(body_2k, refine_bone_transforms(body_2k, init.bone_transforms, None, data_term=term),
                              init.global_scale).joints[PELVIS]
    for J in frames[:6]:
        for mode, Jm in (("frame", J), ("sequence", with_bone_lengths(J, L_seq))):
            init = initialise_pose(body_2k, Jm)
            T = refine_bone_transforms(body_2k, init.bone_transforms, None, data_term=term)
            pelvis = pose_template(body_2k, T, init.global_scale).joints[PELVIS]
            errors[mode].append(1000 * np.linalg.norm(pelvis - reference, axis=1).mean())
    # Pelvis joints' distance to where the refinement puts them from the true joints, 6 frames (4 cameras,
    # 2.5K, 3 mm joint noise): measured 2.3-4.2 mm with the sequence's lengths, 2.8-9.2 mm with each frame's.
    assert max(errors["sequence"]) < 6.0 < max(errors["frame"])
    assert np.mean(errors["sequence"]) < np.mean(errors["frame"])


def test_joint_smoothing_averages_the_noise_and_keeps_the_motion():
    from bodystudio.reconstruct.pose_init import smooth_joint_track

    rng = np.random.default_rng(5)
    frames = np.arange(30)
    start, velocity = rng.normal(0, 0.3, (25, 3)), rng.normal(0, 0.05, (25, 3))  # up to ~10 cm per frame
    truth = start[None] + frames[:, None, None] * velocity[None]
    # a joint moving at constant velocity is reproduced exactly, at the ends too
    assert np.abs(smooth_joint_track(frames, truth, 2) - truth).max() < 1e-9
    noisy = truth + rng.normal(0, 0.01, truth.shape)  # the tracker's 1 cm per axis
    err_raw = np.linalg.norm(noisy - truth, axis=2)[2:-2].mean()
    err_smooth = np.linalg.norm(smooth_joint_track(frames, noisy, 2) - truth, axis=2)[2:-2].mean()
    # a line through 5 frames: the intercept's spread is sqrt(1/5) of one frame's (measured ratio 0.45)
    assert err_smooth < 0.55 * err_raw
    assert np.array_equal(smooth_joint_track(frames, noisy, 0), noisy)
    # gaps in the frame numbers are time, not positions in the list
    every_other = smooth_joint_track(frames[::2], truth[::2], 2)
    assert np.abs(every_other - truth[::2]).max() < 1e-9
    # an untracked joint stays untracked and does not disturb the others
    holed = noisy.copy()
    holed[10, 3] = np.nan
    out = smooth_joint_track(frames, holed, 2)
    assert np.all(np.isnan(out[10, 3])) and np.all(np.isfinite(np.delete(out.reshape(-1, 3), 10 * 25 + 3, 0)))
    assert np.abs(out[11, 3] - truth[11, 3]).max() < 0.03
    # a 0.5 m jump (a tracking glitch or a cut) is not smeared over the frames beside it
    jumped = noisy.copy()
    jumped[15:] += (0.5, 0.0, 0.0)
    assert np.abs(smooth_joint_track(frames, jumped, 2)[13:17] - jumped[13:17]).max() < 0.04
    assert np.abs(smooth_joint_track(frames, jumped, 2, break_m=None)[13:17] - jumped[13:17]).max() > 0.08
    with pytest.raises(InputError, match="joint smoothing needs"):
        smooth_joint_track(frames[:3], noisy, 2)
    with pytest.raises(InputError, match=">= 0"):
        smooth_joint_track(frames, noisy, -1)
