"""``muscle capture`` skips a bad frame instead of refusing the recording (rel7a; docs/muscle.md "Bad frames skipped").

Before, one truncated depth PNG, one null elbow or one frame with the arm out of the depth window refused the whole
capture (rel6b: "a frame is never skipped"), so a real recording with one dropped frame could not be captured. Now
such a frame is skipped with a warning naming the file, the frame and why; ``params.json`` lists it
(``skipped_frames``), its mesh file is absent (``manifest.json`` ``missing_meshes``), ``arm.glb`` keys the captured
frames at their recorded times, ``eval muscle`` names it; more than 25 % of the frames, or more than 5 in a row at
30 fps, is refused in one line naming the frames and ``--frames N``; ``--no-skip-bad-frames`` refuses as before.
The temporal filters weigh neighbours by their recorded distance across a gap (the pose smoothing, the sequence
fit's second differences). rel7a's 8-frame 2k arm session and its planted copy (``conftest.rel7a_arm``, shared with
``test_rel7a_follower_jump.py``), captured without the model.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from bodystudio.errors import SessionError
from tests.reliability.conftest import assert_clean_error, run_inprocess

FRAMES = 8
GOOD = [0, 1, 3, 4, 6, 7]  # the planted session's frames 2 (depth truncated) and 5 (the subject lost) are bad


def _capture(folder):
    from bodystudio.muscle.capture import load_arm_capture

    return load_arm_capture(folder)


def test_a_truncated_depth_png_is_skipped_named_and_has_no_mesh(rel7a_arm):
    """Before: exit 2, "unreadable image ... PNG input buffer is incomplete", nothing captured."""
    cap_dir = rel7a_arm.cap_planted
    params = json.loads((cap_dir / "params.json").read_text())
    assert params["frame_ids"] == GOOD and params["frame_positions"] == GOOD
    depth, joints = params["skipped_frames"]
    assert depth["frame"] == 2 and depth["position"] == 2 and joints["frame"] == 5
    assert depth["file"].endswith("P/kinect/depth/00002.png") and "unreadable image" in depth["why"]
    assert joints["file"].endswith("P/kinect/joints/00005.json")
    assert sorted(p.name for p in (cap_dir / "meshes").iterdir()) == [f"{k:05d}.ply" for k in GOOD]
    manifest = json.loads((cap_dir / "manifest.json").read_text())
    assert manifest["n_frames"] == 6 and manifest["missing_meshes"] == [2, 5]
    from bodystudio.muscle.export import read_morph_glb

    glb = read_morph_glb(cap_dir / "arm.glb")
    np.testing.assert_allclose(glb.times, np.array(GOOD) / 30.0, atol=1e-6)
    assert glb.target_names[2] == "frame_00003"
    back = _capture(cap_dir)
    assert back.frame_ids == GOOD and back.skipped == [depth, joints] and back.n_frames == 6
    assert "P/kinect/depth/00002.png: frame 2 skipped (unreadable image" in rel7a_arm.planted_stderr


def test_the_good_frames_are_captured_as_well_as_the_clean_recordings(rel7a_arm):
    """The mesh of each good frame against the truth: within 0.5 mm (median) of the clean capture's on the same
    frames; no good frame's mesh is a copy of its neighbour's (frame 3 is not frame 1)."""
    from bodystudio.capture.session import open_session
    from bodystudio.muscle.evaluate import session_ground_truth
    from bodystudio.muscle.synthetic import session_arm_template

    clean, bad = _capture(rel7a_arm.cap_clean), _capture(rel7a_arm.cap_planted)
    s = open_session(rel7a_arm.clean)
    template = session_arm_template(s)
    G = session_ground_truth(s, template, list(range(FRAMES)))[0]

    def err(V):
        return 1000.0 * np.median(np.linalg.norm(V - G[GOOD], axis=2)[:, template.arm_mask], axis=1)

    e_bad, e_clean = err(bad.vertices), err(clean.vertices[GOOD])
    assert np.median(e_bad) < 15.0  # the no-model capture's scale
    assert abs(np.median(e_bad) - np.median(e_clean)) < 0.5, (e_bad, e_clean)
    assert np.abs(e_bad - e_clean).max() < 2.0, (e_bad, e_clean)
    assert not np.allclose(bad.vertices[GOOD.index(3)], bad.vertices[GOOD.index(1)], atol=1e-4)


def test_eval_muscle_names_the_skipped_frames(rel7a_arm, capfd):
    result = run_inprocess(["eval", "muscle", rel7a_arm.cap_planted], capfd)
    assert_clean_error(result, 0, "")
    scores = json.loads(result.stdout)
    assert scores["n_frames"] == 6 and scores["n_skipped"] == 2 and scores["skipped_frames"] == [2, 5]
    assert scores["median_mm"] < 15.0
    clean = run_inprocess(["eval", "muscle", rel7a_arm.cap_clean], capfd)
    assert "n_skipped" not in json.loads(clean.stdout)


def test_no_skip_bad_frames_refuses_as_before(rel7a_arm, tmp_path, capfd):
    """``--no-skip-bad-frames``: the first bad frame refuses the capture (rel6b's behaviour); nothing written."""
    result = run_inprocess(["muscle", "capture", rel7a_arm.planted, "--out", tmp_path / "d", "--no-model",
                            "--no-skip-bad-frames"], capfd)
    assert_clean_error(result, 2, "kinect/depth/00002.png: unreadable image")
    assert not (tmp_path / "d").exists()


def _skipped(frames):
    return [{"frame": 100 + p, "position": p, "file": f"S/kinect/depth/{100 + p:05d}.png", "why": "no arm"}
            for p in frames]


def test_too_many_or_a_long_run_of_bad_frames_is_refused():
    """The bounds (``capture.MAX_SKIPPED_FRACTION`` 25 %, ``MAX_SKIPPED_RUN_S`` 5 frames at 30 fps): one line naming
    the first bad frame's file, the bad frames and the first frames that keep within them (``--frames N``)."""
    from bodystudio.muscle.capture import check_skipped_frames

    check_skipped_frames(_skipped([10, 11, 12, 13, 14]), 40, 30.0, "S")  # a run of 5: bridged
    check_skipped_frames(_skipped([0, 5, 9, 20]), 40, 30.0, "S")  # 10 %, the first frame too
    with pytest.raises(SessionError, match=r"^S/kinect/depth/00110.png: frame 110 cannot be captured \(no arm\), nor "
                       r"5 more of the 40 frames \(frames 110-115\); 6 bad frames in a row from frame 110, more than "
                       r"the 5 \(167 ms\) the temporal filters bridge: capture the first 10 frames \(--frames 10\), "
                       r"or re-export the bad frames$"):
        check_skipped_frames(_skipped(range(10, 16)), 40, 30.0, "S")
    # at 60 fps the same 167 ms are 10 frames
    check_skipped_frames(_skipped(range(10, 16)), 40, 60.0, "S")
    with pytest.raises(SessionError, match=r"bad frames: 11 of 40, more than the 25% the capture skips: capture the "
                       r"first 36 frames \(--frames 36\)"):
        check_skipped_frames(_skipped([0, 4, 8, 12, 16, 20, 24, 28, 32, 36, 38]), 40, 30.0, "S")
    with pytest.raises(SessionError, match=r"no frame of S can be captured$"):
        check_skipped_frames(_skipped(range(3)), 3, 30.0, "S")


def test_the_pose_filters_weigh_neighbours_by_their_recorded_distance():
    """Across a gap the pose smoothing and the sequence fit's second-difference prior measure time in recorded
    frames: a motion linear in time is left as it is (degree 1) and costs no prior; counted as consecutive frames
    (the skipped frame ignored) the same motion is bent."""
    from bodystudio.muscle.arm import ArmPose
    from bodystudio.muscle.refine import second_differences, smooth_arm_poses

    positions = np.array([0, 1, 2, 3, 5, 6, 7, 8, 9, 12, 13, 14])
    angles = 0.02 * positions[:, None, None] * np.ones((1, 3, 3))
    poses = [ArmPose(np.eye(4), a) for a in angles]
    kept = np.stack([p.angles for p in smooth_arm_poses(poses, 2.5, degree=1, positions=positions)])
    np.testing.assert_allclose(kept, angles, atol=1e-12)
    bent = np.stack([p.angles for p in smooth_arm_poses(poses, 2.5, degree=1)])
    assert np.abs(bent - angles).max() > 1e-3
    np.testing.assert_allclose(second_differences(angles, positions), 0.0, atol=1e-12)
    assert np.abs(second_differences(angles)).max() > 0.01
    # consecutive frames: the plain second difference, bit for bit
    a = np.random.default_rng(0).normal(size=(6, 4))
    np.testing.assert_array_equal(second_differences(a, np.arange(6)), a[:-2] - 2 * a[1:-1] + a[2:])
