"""``muscle capture`` on a recording whose body tracker lost the arm in some frames (adversarial pass 4).

A joints file may store a joint as null (NaN: not reported) and a frame may lack the arm's joints. Before: a null
shoulder / elbow / wrist stopped the shape fit with scipy's "Residuals are not finite" traceback, and an absent one
silently dropped the tracker from every frame, so the capture was refused by its self-check naming the Kinect
calibration and the arm side (or, with --accept-implausible, written from the depth alone). Now the gap is refused
before any work, in one line naming the first frame's joints file and the fix; OUT is not created."""

from __future__ import annotations

import json
import shutil

import pytest

from bodystudio.capture.faults import restamp
from tests.reliability.conftest import assert_clean_error, run_inprocess

ARM = ("ShoulderLeft", "ElbowLeft", "WristLeft")


@pytest.fixture(scope="module")
def arm_session(tmp_path_factory):
    from bodystudio.muscle.synthetic import synth_arm_session

    root = tmp_path_factory.mktemp("adv4gaps")
    synth_arm_session(root / "S", subject_seed=501, n_frames=3, resolution="2k")
    return root / "S"


def _plant(src, dest, frame: int, change) -> None:
    shutil.copytree(src, dest)
    rel = f"kinect/joints/{frame:05d}.json"
    data = json.loads((dest / rel).read_text())
    change(data)
    (dest / rel).write_text(json.dumps(data))
    restamp(dest, rel)


def _null_arm(data):
    for name in ARM:
        k = data["names"].index(name)
        data["positions"][k] = [None, None, None]
        data["tracked"][k] = False


def _drop_wrist(data):
    k = data["names"].index("WristLeft")
    for key in ("names", "positions", "tracked"):
        del data[key][k]


@pytest.mark.parametrize("change", [_null_arm, _drop_wrist], ids=["null", "absent"])
def test_arm_joints_lost_in_one_frame_are_refused(arm_session, tmp_path, capfd, change):
    """Since rel7a a bad frame is skipped (tests/reliability/test_rel7a_*.py); --no-skip-bad-frames keeps this
    refusal, and by default one bad frame of three is more than the 25 % the capture skips."""
    S, out = tmp_path / "S", tmp_path / "cap"
    _plant(arm_session, S, 1, change)
    result = run_inprocess(["muscle", "capture", S, "--out", out, "--no-model", "--no-skip-bad-frames"], capfd)
    assert_clean_error(result, 2, "missing or null in 1 of 3 frames")
    assert "kinect/joints/00001.json" in result.stderr and "--frames 1" in result.stderr
    assert not out.exists()
    result = run_inprocess(["muscle", "capture", S, "--out", out, "--no-model"], capfd)
    assert_clean_error(result, 2, "bad frames: 1 of 3, more than the 25% the capture skips")
    assert "kinect/joints/00001.json: frame 1 cannot be captured" in result.stderr and "--frames 1" in result.stderr
    assert not out.exists()


def test_frames_before_the_gap_still_capture_their_tracker(arm_session):
    """The API the capture uses: the tracked frames before the gap give the (T, 3, 3) tracker; a session with no
    tracked arm in any frame gives None (the capture fits the depth alone, as before)."""
    from bodystudio.capture.session import open_session
    from bodystudio.muscle.capture import session_arm_tracker

    session = open_session(arm_session)
    tracker = session_arm_tracker(session, session.frame_ids[:2], "left")
    assert tracker.shape == (2, 3, 3)
    first = session.frame(session.frame_ids[0]).kinect_joints
    assert tracker[0, 1] == pytest.approx(first["positions"][first["names"].index("ElbowLeft")])
    assert session_arm_tracker(session, session.frame_ids, "right") is not None


def _second_person(data, player_of_subject=2):
    """A bystander 0.8 m to the side enters with a lower player id than the subject's."""
    subject = {"player": player_of_subject, **{k: data[k] for k in ("names", "positions", "tracked")}}
    other = {"player": 1, "names": data["names"], "tracked": data["tracked"],
             "positions": [[x + 0.8, y, z - 0.3] for x, y, z in data["positions"]]}
    data.update({k: other[k] for k in ("names", "positions", "tracked")})
    data["bodies"] = [other, subject]


def test_a_second_person_entering_with_a_lower_player_id_is_not_followed(arm_session, tmp_path):
    """The subject is player 2 from the first frame; in frame 2 a bystander is tracked as player 1. Before, the
    capture took each frame's lowest player (the bystander's arm from frame 2 on: on an 8-frame session with a
    model, refused as "the fitted upperarm ... 300 mm from the depth points", blaming the Kinect calibration); it
    now follows the first frame's player, so the tracker and the self-check's figures are the clean session's."""
    from bodystudio.capture.session import open_session
    from bodystudio.muscle.capture import session_arm_tracker
    from bodystudio.muscle.plausibility import session_checks

    S = tmp_path / "S"
    shutil.copytree(arm_session, S)
    for frame in range(3):
        rel = f"kinect/joints/{frame:05d}.json"
        data = json.loads((S / rel).read_text())
        if frame < 2:
            data["bodies"] = [{"player": 2, **{k: data[k] for k in ("names", "positions", "tracked")}}]
        else:
            _second_person(data)
        (S / rel).write_text(json.dumps(data))
        restamp(S, rel)
    clean, planted = open_session(arm_session), open_session(S)
    assert planted.frame(2).kinect_joints["player"] == 1  # the frame's first body is the bystander
    ids = clean.frame_ids
    assert session_arm_tracker(planted, ids, "left") == pytest.approx(session_arm_tracker(clean, ids, "left"))
    assert session_checks(planted, ids, "left") == session_checks(clean, ids, "left")


def test_a_15_fps_recording_plays_at_15_fps(arm_session, tmp_path, capfd):
    """A session recorded at 15 fps (``metadata.fps``, which ``capture import`` now records): ``arm.glb`` was written
    at 30 fps (played twice as fast); its key times now follow the session's rate. The warning that the capture's
    temporal smoothing counts frames measured at 30 fps is gone with its cause: the filters are times now, scaled to
    the session's rate (round rel5b, tests/reliability/test_rel5b_muscle_frame_rate.py)."""
    import numpy as np

    from bodystudio.muscle.export import read_morph_glb

    S, out = tmp_path / "S", tmp_path / "cap"
    shutil.copytree(arm_session, S)
    manifest = json.loads((S / "session.json").read_text())
    manifest["metadata"]["fps"] = 15.0
    (S / "session.json").write_text(json.dumps(manifest))
    result = run_inprocess(["muscle", "capture", S, "--out", out, "--no-model", "--frames", "2"], capfd)
    assert_clean_error(result, 0, "")
    assert "fps" not in result.stderr
    np.testing.assert_allclose(read_morph_glb(out / "arm.glb").times, np.arange(2) / 15.0, atol=1e-6)
