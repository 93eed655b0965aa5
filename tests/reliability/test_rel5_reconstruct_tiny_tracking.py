"""``reconstruct --tracking`` on a tiny session (rel5, found by adv4, docs/plausibility.md).

4 cameras at 160x120, 3 frames of subject 7 (Kinect v1, silhouettes + depth): the tracked frames lose both arms
inside the visual hull (p90 77-78 mm, Hausdorff 209-211 mm against 14-15 mm per frame) while every silhouette IoU
stays >= 0.86 and the depth agrees, so the run ended with exit 0 and a passing self-check. The fitted pose's limb
joints then lie 315-321 mm from the tracker's joints of the same frame (good runs, per frame, tracked and
accurate, 10 cameras at 640x480: <= 58 mm): the self-check now refuses a run whose tracked frames are that far
(:data:`bodystudio.reconstruct.plausibility.TRACKER_JOINT_FAR_MM`), naming the cause and the fix, and writes
nothing; the same session reconstructed per frame passes unwarned.

rec15r: the tracker now re-initialises such a frame from its joints (``limbs_far``: a limb joint of the tracking
fit's pose over ``TrackParams.limbs_far_mm`` = 80 mm from the tracker's), so ``--tracking`` on this session fits
every frame well and passes; the refusal stays for a run whose check is off (or a drift under 80 mm per frame)."""

from __future__ import annotations

import json
import shutil

import pytest

from tests.reliability.conftest import assert_clean_error, run_inprocess

RUN = ["--template", "2k", "--constraints", "silhouette,depth"]


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """adv4's tiny session (read-only: copy to run)."""
    from bodystudio.capture.synth import synth_session

    path = tmp_path_factory.mktemp("rel5tiny") / "S"
    synth_session(path, n_cameras=4, n_frames=3, resolution=(160, 120), template="2k", kinect="v1", seed=1)
    return path


def test_tracking_that_lost_the_limbs_is_refused(tiny, tmp_path):
    """With the lost-track check's ``limbs_far`` off the tracked frames keep the lost arms (315-321 mm, p90 78-84
    mm): the self-check refuses the run and writes nothing."""
    from bodystudio.errors import ImplausibleResultError
    from bodystudio.reconstruct.sequence import reconstruct_session
    from bodystudio.reconstruct.tracking import TrackParams

    S = tmp_path / "S"
    shutil.copytree(tiny, S)
    with pytest.raises(ImplausibleResultError, match="the tracking lost the limbs: 2 of 2 tracked frames") as err:
        reconstruct_session(S, template="2k", constraints=("silhouette", "depth"), tracking=True,
                            track_params=TrackParams(limbs_far_mm=0.0))
    assert "reconstruct without --tracking" in str(err.value) and "kinect/joints" in str(err.value)
    assert not (S / "reconstruct" / "run.json").exists() and not (S / "reconstruct" / "meshes").exists()


def test_tracking_reinitialises_the_frame_whose_limbs_left_the_joints(tiny, tmp_path, capfd):
    """rec15r: frame 1's tracking fit puts WristRight 315 mm from the tracker's: the frame is re-initialised from
    its joints (``limbs_far``), frame 2 tracks from there (48 mm); run p90 60.7 -> 13.6 mm, Hausdorff 209 -> 98 mm,
    refused -> passes. Fails with the check dropped (the run is refused)."""
    S = tmp_path / "S"
    shutil.copytree(tiny, S)
    result = run_inprocess(["reconstruct", S, *RUN, "--tracking"], capfd)
    assert_clean_error(result, 0, "")
    run = json.loads((S / "reconstruct" / "run.json").read_text())
    assert run["track_params"]["limbs_far_mm"] == 80.0
    assert run["plausibility"]["ok"] and run["plausibility"]["warnings"] == []
    frames = json.loads((S / "reconstruct" / "frames.json").read_text())["frames"]
    assert [f["track"] for f in frames] == ["first", "limbs_far", "tracked"]
    assert frames[1]["track_check"]["limb_joint_mm"] > 250.0
    assert frames[2]["track_check"]["limb_joint_mm"] < 80.0
    assert max(f["plausibility"]["tracker_joint_residual"]["max_mm"] for f in frames) < 80.0
    assert max(f["metrics"]["p90_mm"] for f in frames) <= 16.0


def test_the_same_session_per_frame_passes_unwarned(tiny, tmp_path, capfd):
    """No false alarm: per frame the fitted limbs stay within the tracker's noise of its joints, and the fit is
    the good one the check lets through (p90 <= 16 mm; measured 13.8-15.2 mm)."""
    S = tmp_path / "S"
    shutil.copytree(tiny, S)
    result = run_inprocess(["reconstruct", S, *RUN], capfd)
    assert_clean_error(result, 0, "")
    run = json.loads((S / "reconstruct" / "run.json").read_text())
    assert run["plausibility"]["ok"] and run["plausibility"]["warnings"] == []
    figures = run["plausibility"]["tracker_joints"]
    assert figures["frames_far"] == 0 and figures["tracked_frames"] == 0 and figures["max_mm"] < 80.0
    frames = json.loads((S / "reconstruct" / "frames.json").read_text())["frames"]
    assert max(f["metrics"]["p90_mm"] for f in frames) <= 16.0
    assert all(not f["plausibility"]["tracker_joint_residual"]["tracked"] for f in frames)


def _frame(max_mm: float, tracked: bool, frame: int = 0) -> dict:
    return {"tracker_joint_residual": {"max_mm": max_mm, "median_mm": max_mm / 2, "joint": "WristRight",
                                       "frame": frame, "tracked": tracked}}


def test_the_verdict_counts_the_tracked_frames_that_lost_the_limbs():
    """A tenth of the tracked frames far (at least one): refused; fewer, or far frames the joints initialised: a
    warning; none: ok. Runs without the figure (hull joints, older runs) keep the old verdict."""
    from bodystudio.reconstruct.plausibility import TRACKER_JOINT_FAR_MM, run_plausibility, tracker_joint_residual

    far, near = TRACKER_JOINT_FAR_MM + 1.0, TRACKER_JOINT_FAR_MM - 1.0
    refused = run_plausibility([_frame(40.0, False), _frame(far, True, 1)] + [_frame(near, True, 2)] * 9, "S")
    assert not refused["ok"] and refused["problems"][0].startswith("the tracking lost the limbs: 1 of 10 tracked")
    assert "frame 1" in refused["problems"][0] and "(S/kinect/joints" in refused["problems"][0]
    assert refused["tracker_joints"]["tracked_frames_far"] == 1
    warned = run_plausibility([_frame(40.0, False), _frame(far, True, 1)] + [_frame(near, True)] * 10)
    assert warned["ok"] and warned["warnings"][0].startswith("1 of 12 frames put a limb joint over 150 mm")
    per_frame = run_plausibility([_frame(far, False), _frame(far, False)])
    assert per_frame["ok"] and "2 of 2 frames" in per_frame["warnings"][0]
    clean = run_plausibility([_frame(near, True), _frame(near, False)])
    assert clean["ok"] and clean["warnings"] == [] and clean["tracker_joints"]["max_mm"] == near
    assert "tracker_joints" not in run_plausibility([{}])

    import numpy as np

    from bodystudio.body.kinect import kinect_joint_names

    names = kinect_joint_names("v2")
    tracker = np.zeros((len(names), 3))
    fitted = tracker.copy()
    fitted[names.index("WristLeft")] = [0.0, 0.3, 0.4]  # 500 mm
    fitted[names.index("KneeRight")] = [0.01, 0.0, 0.0]
    tracker[names.index("AnkleLeft")] = np.nan  # untracked: not compared
    fitted[names.index("AnkleLeft")] = [9.0, 9.0, 9.0]
    got = tracker_joint_residual(fitted, tracker)
    assert got["max_mm"] == pytest.approx(500.0) and got["joint"] == "WristLeft"
    assert got["median_mm"] == pytest.approx(0.0)  # 7 joints: 0 x 5, 10, 500
    assert tracker_joint_residual(None, tracker) is None and tracker_joint_residual(fitted, np.full_like(tracker,
                                                                                                     np.nan)) is None
