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
