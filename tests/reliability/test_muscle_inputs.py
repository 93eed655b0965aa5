"""Bad input to the muscle commands (synth arm, muscle capture / model, eval muscle): one line, exit 2, nothing written.

Each case: the command line, a phrase of the one-line message, and that the output path does not exist
afterwards (no half-written folder, no staging leftovers beside it).
"""

import shutil

import numpy as np
import pytest

from bodystudio.cli.main import main


def run_bad(args, capsys, phrase):
    code = main([str(a) for a in args])
    err = capsys.readouterr().err.strip()
    assert code == 2, err
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert phrase in err, err
    return err


def nothing_beside(folder, allowed=()):
    left = sorted(p.name for p in folder.iterdir() if p.name not in allowed)
    assert left == [], left


@pytest.fixture(scope="module")
def arm_session(tmp_path_factory):
    out = tmp_path_factory.mktemp("arm") / "session"
    assert main(["synth", "arm", str(out), "--subject-seed", "5", "--frames", "3", "--resolution", "2k"]) == 0
    return out


def rewrite_depth(session_path, tmp_path, make):
    """A copy of the session with every depth frame replaced by ``make(depth)``."""
    from bodystudio.capture.session import SessionWriter, open_session

    copy = tmp_path / "bad_session"
    shutil.copytree(session_path, copy)
    s = open_session(copy)
    depths = {fid: s.frame(fid).kinect_depth_m for fid in s.frame_ids}
    with SessionWriter(copy, update=True) as w:
        for fid, d in depths.items():
            w.write_kinect_depth(fid, make(d))
    return copy


@pytest.mark.parametrize("args, phrase", [
    (["--motion", "wave"], "--motion 'wave': valid: elbow_flex, abduction, pronation"),
    (["--kinect", "v3"], "--kinect 'v3': valid: v1, v2"),
    (["--frames", "0"], "--frames 0: must be in [1, 2000]"),
    (["--frames", "5000"], "--frames 5000: must be in [1, 2000]"),
    (["--distance", "0.1"], "--distance 0.1: must be in [0.5, 3] m"),
    (["--distance", "nan"], "--distance nan: must be in"),
    (["--distance", "12"], "--distance 12.0: must be in"),
    (["--resolution", "13k"], "--resolution '13k': valid: 6k, 2k, full"),
    (["--subject-seed", "-1"], "--subject-seed -1: must be in"),
])
def test_synth_arm_bad_options(tmp_path, capsys, args, phrase):
    out = tmp_path / "s"
    run_bad(["synth", "arm", out, *(["--subject-seed", "1"] if "--subject-seed" not in args else []), *args],
            capsys, phrase)
    nothing_beside(tmp_path)


def test_synth_arm_onto_existing_output(tmp_path, capsys):
    (tmp_path / "taken").write_text("x")
    run_bad(["synth", "arm", tmp_path / "taken", "--subject-seed", "1"], capsys, "already exists")
    assert (tmp_path / "taken").read_text() == "x"
    (tmp_path / "folder").mkdir()
    run_bad(["synth", "arm", tmp_path / "folder", "--subject-seed", "1"], capsys, "already exists")


def test_synth_arm_unwritable_output(capsys):
    run_bad(["synth", "arm", "/sys/arm_session", "--subject-seed", "1"], capsys, "cannot write in /sys")


@pytest.mark.parametrize("args, phrase", [
    ([], "needs --model MODEL.npz"),
    (["--no-model", "--no-refine"], "choose one"),
    (["--model", "missing.npz"], "no such file"),
    (["--no-model", "--resolution", "13k"], "--resolution '13k': valid"),
    (["--no-model", "--side", "middle"], "--side 'middle': valid: left, right"),
    (["--no-model", "--frames", "0"], "--frames 0: must be in"),
])
def test_capture_bad_options(arm_session, tmp_path, capsys, args, phrase):
    out = tmp_path / "cap"
    run_bad(["muscle", "capture", arm_session, "--out", out, *args], capsys, phrase)
    nothing_beside(tmp_path)


def test_capture_onto_existing_or_unwritable_output(arm_session, tmp_path, capsys):
    (tmp_path / "cap").mkdir()
    (tmp_path / "cap" / "keep.txt").write_text("previous")
    run_bad(["muscle", "capture", arm_session, "--out", tmp_path / "cap", "--no-model"], capsys, "already exists")
    assert (tmp_path / "cap" / "keep.txt").read_text() == "previous"
    run_bad(["muscle", "capture", arm_session, "--out", "/sys/cap", "--no-model"], capsys, "cannot write in /sys")


def test_capture_of_a_missing_session(tmp_path, capsys):
    run_bad(["muscle", "capture", tmp_path / "nope", "--out", tmp_path / "cap", "--no-model"], capsys, "nope")
    nothing_beside(tmp_path)


@pytest.mark.parametrize("make, phrase", [
    (lambda d: np.zeros_like(d), "no arm in range"),  # empty depth
    (lambda d: np.where(d > 0, d + 3.0, 0.0), "no arm in range"),  # everything 3 m farther: out of range
    (lambda d: d[::2, ::2], "but the depth camera"),  # wrong resolution for the calibration
])
def test_capture_of_unusable_depth(arm_session, tmp_path, capsys, make, phrase):
    bad = rewrite_depth(arm_session, tmp_path, make)
    out = tmp_path / "cap"
    run_bad(["muscle", "capture", bad, "--out", out, "--no-model"], capsys, phrase)
    nothing_beside(tmp_path, allowed=("bad_session",))
