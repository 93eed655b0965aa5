"""``bodystudio mirror init`` as a hostile user runs it (adversarial pass, round 2).

Before: a second ``mirror init`` silently replaced the source body (a ``mirror run`` made from the old body
then no longer matched it), and ``--frames N`` beyond the session's frames initialised from fewer frames
than asked for, both with exit 0. Now the first needs ``--force`` and the second is refused with one line
naming the session's frame count; nothing is written in either case."""

from __future__ import annotations

import json

import pytest

from bodystudio.cli.main import main

from .conftest import assert_clean_error, run_inprocess

N_FRAMES = 12


@pytest.fixture(scope="module")
def mirror_session(tmp_path_factory):
    out = tmp_path_factory.mktemp("adv2mir") / "s"
    assert main(["synth", "mirror", str(out), "--subject-seed", "3", "--frames", str(N_FRAMES), "--no-walk-in",
                 "--taller", "0.1"]) == 0
    return out


def test_frames_beyond_the_session_are_refused(mirror_session, capfd):
    result = run_inprocess(["mirror", "init", mirror_session, "--resolution", "2k", "--frames", "50"], capfd)
    assert_clean_error(result, 2, f"has {N_FRAMES} frames")
    assert not (mirror_session / "mirror" / "source_body.npz").exists()


def test_a_second_init_needs_force(mirror_session, capfd):
    body = mirror_session / "mirror" / "source_body.npz"
    summary = mirror_session / "mirror" / "source_body.json"
    # the default (90 frames) on a shorter session: the whole session, no refusal
    assert run_inprocess(["mirror", "init", mirror_session, "--resolution", "2k"], capfd).rc == 0
    before, before_summary = body.read_bytes(), summary.read_bytes()
    result = run_inprocess(["mirror", "init", mirror_session, "--resolution", "6k", "--frames", "3"], capfd)
    assert_clean_error(result, 2, "pass --force to replace it")
    assert body.read_bytes() == before and summary.read_bytes() == before_summary
    assert run_inprocess(["mirror", "init", mirror_session, "--resolution", "6k", "--frames", "3", "--force"],
                         capfd).rc == 0
    assert body.read_bytes() != before
    assert json.loads(summary.read_text())["resolution"] == "6k"


def test_trunk_refit_with_too_few_frames_keeps_the_skeleton(mirror_session, tmp_path, capfd):
    """`mirror init --trunk-refit` (MIR12r) on a copy of the 12-frame session (the init reads one frame with the
    actor, fewer than the three a joint's mean needs): exit 0, the summary says so, and the body is the plain init's
    bit for bit (no joint moved on too few frames, no error). The moving case: tests/mirror/test_init_trunk_refit.py."""
    import shutil

    copy = tmp_path / "s"
    shutil.copytree(mirror_session, copy)
    shutil.rmtree(copy / "mirror", ignore_errors=True)
    bodies = {}
    for flag in ("--no-trunk-refit", "--trunk-refit"):
        result = run_inprocess(["mirror", "init", copy, "--resolution", "2k", flag, "--force"], capfd)
        assert_clean_error(result, 0, "")
        summary = json.loads((copy / "mirror" / "source_body.json").read_text())
        assert summary["trunk_refit"] is (flag == "--trunk-refit") and len(summary["frames_used"]) == 1
        bodies[flag] = (copy / "mirror" / "source_body.npz").read_bytes()
    assert bodies["--trunk-refit"] == bodies["--no-trunk-refit"]


def test_unpose_posture_with_one_actor_frame_writes_a_summary_that_says_so(mirror_session, tmp_path, capfd):
    """`mirror init --unpose-posture` (mir12v) on a copy of the 12-frame session (one actor frame read: the posture is
    that frame's own): exit 0, `unpose_posture: true` in the summary (false with `--no-unpose-posture`, true with
    neither: the default since mir12y), the body loads and is finite."""
    import shutil

    import numpy as np

    from bodystudio.mirror.init import load_source_body

    copy = tmp_path / "s"
    shutil.copytree(mirror_session, copy)
    shutil.rmtree(copy / "mirror", ignore_errors=True)
    for flag in ("--no-unpose-posture", "--unpose-posture", None):
        result = run_inprocess(["mirror", "init", copy, "--resolution", "2k", *([flag] if flag else []), "--force"],
                               capfd)
        assert_clean_error(result, 0, "")
        summary = json.loads((copy / "mirror" / "source_body.json").read_text())
        assert summary["unpose_posture"] is (flag != "--no-unpose-posture") and len(summary["frames_used"]) == 1
        body = load_source_body(copy / "mirror" / "source_body.npz")
        assert np.all(np.isfinite(body.vertices)) and np.all(np.isfinite(body.coeffs))


# The probe child records the 6k init's fit; the children killed at a file event replay it instead of fitting again
# (the source body's two files are the only file events, the same ones, checked against a fitting child).
RECORD_INIT = """
import pickle
import bodystudio.mirror.init as init
_initialise = init.initialise_source_body
def recorded(*args, **kwargs):
    source = _initialise(*args, **kwargs)
    open({path!r}, "wb").write(pickle.dumps(source))
    return source
init.initialise_source_body = recorded
"""
REPLAY_INIT = """
import pickle
import bodystudio.mirror.init as init
init.initialise_source_body = lambda *args, **kwargs: pickle.loads(open({path!r}, "rb").read())
"""


@pytest.mark.slow
def test_mirror_init_killed_around_its_commit_point(mirror_session, tmp_path, capfd):
    """source_body.npz and source_body.json are one unit: killed before the commit point the previous pair
    stays byte for byte; after it, `bodystudio recover` completes the new pair (before this pass the two were
    written one after the other, and a kill between them left the summary of another body)."""
    import shutil
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parent))
    from kill_harness import read_events, run_child

    base = tmp_path / "base"
    shutil.copytree(mirror_session, base / "s")
    assert run_inprocess(["mirror", "init", base / "s", "--resolution", "2k", "--frames", "1", "--force"],
                         capfd).rc == 0
    log = tmp_path / "events.json"
    probe = tmp_path / "probe"
    shutil.copytree(base, probe)
    new = ["--resolution", "6k", "--frames", "3", "--force"]
    record, replay = tmp_path / "record.py", tmp_path / "replay.py"
    record.write_text(RECORD_INIT.format(path=str(tmp_path / "source.pkl")))
    replay.write_text(REPLAY_INIT.format(path=str(tmp_path / "source.pkl")))
    assert run_child(["mirror", "init", str(probe / "s"), *new], probe, event_log=log, setup=record).returncode == 0
    events = read_events(log)
    commit = next(k + 1 for k, e in enumerate(events) if e.endswith("commit.json"))
    for kill_at in (1, commit, commit + 1):
        work = tmp_path / f"k{kill_at}"
        shutil.copytree(base, work)
        mirror = work / "s" / "mirror"
        before = {p: (mirror / p).read_bytes() for p in ("source_body.npz", "source_body.json")}
        assert run_child(["mirror", "init", str(work / "s"), *new], work, kill_at=kill_at,
                         setup=replay).returncode == -9
        if kill_at <= commit:
            assert {p: (mirror / p).read_bytes() for p in before} == before
        assert run_inprocess(["recover", mirror / "source_body.npz"], capfd).rc == 0
        summary = json.loads((mirror / "source_body.json").read_text())
        assert summary["resolution"] == ("2k" if kill_at <= commit else "6k")
        from bodystudio.fileio import sha256_file

        assert summary["run"]["files"]["source_body.npz"] == sha256_file(mirror / "source_body.npz")
