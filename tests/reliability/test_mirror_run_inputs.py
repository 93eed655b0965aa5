"""Bad input to ``bodystudio mirror run``: one-line errors (exit 2), nothing written, no traceback."""

from __future__ import annotations

from pathlib import Path

import pytest

from .conftest import assert_clean_error, run_inprocess


@pytest.fixture(scope="module")
def sessions(tmp_path_factory) -> dict[str, Path]:
    from bodystudio.cli.main import main

    root = tmp_path_factory.mktemp("mirror_inputs")
    plain, kinect = root / "plain", root / "kinect"
    common = ["--cameras", "1", "--frames", "1", "--resolution", "160x120", "--template", "2k", "--seed", "1"]
    assert main(["synth", "session", str(plain), *common, "--kinect", "none"]) == 0
    assert main(["synth", "session", str(kinect), *common, "--kinect", "v1"]) == 0
    return {"plain": plain, "kinect": kinect, "root": root}


CASES = [
    # --run onto a folder of other files (a session, a reconstruction): run.json, frames/ and masks/ were
    # written over it (adversarial pass, round 2)
    ("run-onto-a-session", ["{kinect}", "--out", "{t}/o.mp4", "--run", "{plain}"], "not a mirror run"),
    ("run-onto-a-folder-of-files", ["{kinect}", "--out", "{t}/o.mp4", "--run", "{t}"], "not a mirror run"),
    ("missing-session", ["{t}/nope", "--out", "{t}/o.mp4"], "no such session folder"),
    ("not-mp4", ["{kinect}", "--out", "{t}/o.avi"], ".mp4"),
    ("out-is-folder", ["{kinect}", "--out", "{t}/dir.mp4"], "is a folder"),
    ("out-under-a-file", ["{kinect}", "--out", "{t}/file/o.mp4"], "is a file, not a folder"),
    ("bad-warp", ["{kinect}", "--out", "{t}/o.mp4", "--warp", "bilinear"], "--warp"),
    ("bad-correspondence", ["{kinect}", "--out", "{t}/o.mp4", "--correspondence", "sparse"], "--correspondence"),
    ("bad-video-preset", ["{kinect}", "--out", "{t}/o.mp4", "--video-preset", "fastest"], "--video-preset 'fastest'"),
    ("empty-video-preset", ["{kinect}", "--out", "{t}/o.mp4", "--video-preset", ""], "--video-preset ''"),
    ("bad-player", ["{kinect}", "--out", "{t}/o.mp4", "--player", "9"], "--player"),
    ("bad-ramp", ["{kinect}", "--out", "{t}/o.mp4", "--ramp-frames", "-1"], "--ramp-frames"),
    ("bad-live-timeout", ["{kinect}", "--out", "{t}/o.mp4", "--live-timeout", "0"], "--live-timeout"),
    ("no-kinect", ["{plain}", "--out", "{t}/o.mp4"], "not a Kinect session"),
    ("no-source-body", ["{kinect}", "--out", "{t}/o.mp4", "--taller", "0.05"], "mirror init"),
    ("refine-pose-no-source-body", ["{kinect}", "--out", "{t}/o.mp4", "--refine-pose"], "mirror init"),
    ("refine-pose-no-kinect", ["{plain}", "--out", "{t}/o.mp4", "--refine-pose"], "not a Kinect session"),
    ("no-refine-pose-no-source-body", ["{kinect}", "--out", "{t}/o.mp4", "--no-refine-pose"], "mirror init"),
    ("no-refine-pose-no-kinect", ["{plain}", "--out", "{t}/o.mp4", "--no-refine-pose"], "not a Kinect session"),
    ("source-missing", ["{kinect}", "--out", "{t}/o.mp4", "--source", "{t}/none.npz"], "source body not found"),
    ("live-device", ["{kinect}", "--out", "{t}/o.mp4", "--live", "/dev/video0"], "Kinect SDK bridge"),
    ("live-folder-missing", ["{kinect}", "--out", "{t}/o.mp4", "--live", "{t}/nothing"], "no such folder"),
    ("live-no-calibration", ["{kinect}", "--out", "{t}/o.mp4", "--live", "{t}/dir.mp4"], "calibration.json"),
    ("not-a-session", ["{t}", "--out", "{t}/o.mp4"], "session.json"),
    # several players (--player repeated, MIRFAST3)
    ("player-twice", ["{kinect}", "--out", "{t}/o.mp4", "--player", "2", "--player", "2"], "given twice"),
    ("bad-second-player", ["{kinect}", "--out", "{t}/o.mp4", "--player", "1", "--player", "7"], "--player 7"),
    ("source-per-player", ["{kinect}", "--out", "{t}/o.mp4", "--player", "1", "--player", "2", "--source",
                           "{t}/none.npz"], "one --source per --player"),
    ("no-body-of-player-2", ["{kinect}", "--out", "{t}/o.mp4", "--player", "2"],
     "source_body_player2.npz: source body not found; run 'bodystudio mirror init"),
    ("no-bodies-of-two-players", ["{kinect}", "--out", "{t}/o.mp4", "--player", "1", "--player", "2"],
     "source body not found"),
]


@pytest.mark.parametrize("case_id, args, phrase", CASES, ids=[c[0] for c in CASES])
def test_mirror_run_bad_input(case_id, args, phrase, sessions, tmp_path, capfd):
    (tmp_path / "dir.mp4").mkdir()
    (tmp_path / "file").write_text("x")
    before = sorted(p.name for p in tmp_path.iterdir())
    fmt = {"t": tmp_path, **{k: v for k, v in sessions.items()}}
    argv = ["mirror", "run", *[a.format(**fmt) for a in args]]
    result = run_inprocess(argv, capfd)
    assert_clean_error(result, 2, phrase)
    assert sorted(p.name for p in tmp_path.iterdir()) == before  # no video, no run folder left behind
    for session in (sessions["plain"], sessions["kinect"]):
        assert not (session / "mirror").exists()


def test_nan_edit_is_refused():
    from bodystudio.errors import InputError
    from bodystudio.mirror.run import check_edits

    with pytest.raises(InputError, match="finite"):
        check_edits({"taller": float("nan")})


@pytest.mark.parametrize("switch", ["--refine-pose", "--no-refine-pose"])
def test_refine_pose_takes_no_value(switch, sessions, tmp_path, capfd):
    """``--refine-pose`` / ``--no-refine-pose`` (the default is on) are switches: a value is click's one-line error
    (exit 2), nothing written."""
    argv = ["mirror", "run", str(sessions["kinect"]), "--out", str(tmp_path / "o.mp4"), f"{switch}=yes"]
    result = run_inprocess(argv, capfd)
    assert result.rc == 2 and result.crashed is None and not result.hung
    assert result.stderr.strip().count("\n") == 0 and f"'{switch}' does not take a value" in result.stderr
    assert not any(tmp_path.iterdir()) and not (sessions["kinect"] / "mirror").exists()


def test_refine_pose_is_on_by_default():
    """``mirror run`` refines the pose unless ``--no-refine-pose`` (MIRFAST): the CLI's and the API's default."""
    import inspect

    from bodystudio.cli.mirror_run import mirror_run
    from bodystudio.mirror.run import run_mirror

    assert inspect.signature(run_mirror).parameters["refine_pose"].default is True
    assert inspect.signature(mirror_run).parameters["refine_pose"].default.default is True


def test_a_player_is_never_paired_with_another_players_body(sessions, tmp_path, capfd):
    """Each player's source body is its own file that records the player (``mirror init --player N``): a body of
    player 2 given to player 1 (as --source or as player 1's file), or a second player without a body, is a
    one-line error (exit 2) and nothing is written."""
    import shutil

    import numpy as np

    session = tmp_path / "s"
    shutil.copytree(sessions["kinect"], session)
    (session / "mirror").mkdir()
    np.savez(session / "mirror" / "source_body.npz", player=np.array(2))  # player 2's body where player 1's goes
    np.savez(tmp_path / "p1.npz", player=np.array(1))
    out = tmp_path / "o.mp4"
    cases = [(["--player", "1"], "source_body.npz: the source body of player 2, not of player 1; run 'bodystudio "
                                 "mirror init SESSION --player 1'"),
             (["--source", str(session / "mirror" / "source_body.npz")],
              "the source body of player 2, not of player 1"),
             (["--player", "2", "--source", str(tmp_path / "p1.npz")], "p1.npz: the source body of player 1, not of "
                                                                        "player 2"),
             (["--player", "1", "--player", "2", "--source", str(tmp_path / "p1.npz"), "--source",
               str(tmp_path / "p1.npz")], "the source body of player 1, not of player 2"),
             (["--player", "2", "--player", "3", "--source", str(session / "mirror" / "source_body.npz"), "--source",
               str(tmp_path / "p1.npz")], "the source body of player 1, not of player 3")]
    for extra, phrase in cases:
        result = run_inprocess(["mirror", "run", str(session), "--out", str(out), *extra], capfd)
        assert_clean_error(result, 2, phrase)
        assert sorted(p.name for p in (session / "mirror").iterdir()) == ["source_body.npz"]
        assert not out.exists()


def test_a_posture_of_the_wrong_shape_is_a_one_line_error():
    """MIR12q: ``refine_pose(posture=)`` (E_trunk's centre, one direction per bone) refuses another shape before any
    work, naming the shape it wants; the run's option (``run.POSTURE_BONES``) is on by default since mir12ae."""
    from types import SimpleNamespace

    import numpy as np

    from bodystudio.errors import InputError
    from bodystudio.mirror import run
    from bodystudio.mirror.refine import refine_pose

    skeleton = SimpleNamespace(n_bones=53)
    with pytest.raises(InputError, match=r"\(53, 3\)"):
        refine_pose(None, skeleton, None, None, np.zeros((4, 4), bool), posture=np.zeros((52, 3)))
    assert run.POSTURE_BONES == ("spine_02", "neck_01", "head")  # on since mir12ae
