"""Bad input to `synth mirror` and `eval mirror`: one line, exit 2, nothing written.

Each case: the command line and a phrase of the one-line message; a refused `synth mirror` leaves no output
folder behind.
"""

import json
import shutil

import pytest

from bodystudio.cli.main import main
from tests.mirror.synth_case import small_mirror_session, write_fake_run

from .conftest import run_bad


@pytest.mark.parametrize("args, phrase", [
    (["--actors", "3"], "--actors 3: a mirror session has 1 or 2 actors"),
    (["--actors", "0"], "--actors 0"),
    # the edit ranges and messages are mirror.reshape's (check_edits), shared with `mirror run`
    (["--taller", "0.5"], "edit taller=0.5 is out of range: use -0.3 to +0.3 m"),
    (["--heavier", "-41"], "edit heavier=-41.0 is out of range: use -40.0 to +40.0 kg"),
    (["--muscular", "0.9"], "edit muscular=0.9 is out of range"),
    (["--waist", "nan"], "--waist nan: must be a finite number"),
    (["--hips", "inf"], "--hips inf: must be a finite number"),
    (["--frames", "5"], "--frames 5: must be in [11, 9000]"),
    (["--frames", "100000"], "--frames 100000: must be in"),
    (["--kinect", "v3"], "--kinect 'v3': valid: v1, v2"),
    (["--motion", "dance"], "--motion 'dance': valid:"),
    # in range but not reachable for subject 3 with the other measurements held (body.statistical's edit)
    (["--taller", "-0.3"], "edit (stature_m -0.3) is not reachable for this body"),
    (["--subject-seed", "-1"], "--subject-seed -1: must be in"),
    (["--seed", "-3"], "--seed -3: must be in"),
])
def test_synth_mirror_bad_options(tmp_path, capsys, args, phrase):
    out = tmp_path / "session"
    base = ["synth", "mirror", out, "--subject-seed", "3"]
    if "--subject-seed" in args:
        base = ["synth", "mirror", out]
    run_bad(base + args, capsys, phrase)
    assert not out.exists()


def test_synth_mirror_unknown_edit_is_a_usage_error(tmp_path, capsys):
    code = main(["synth", "mirror", str(tmp_path / "s"), "--subject-seed", "1", "--slimmer", "3"])
    assert code == 2 and "--slimmer" in capsys.readouterr().err
    assert not (tmp_path / "s").exists()


def test_synth_mirror_existing_output(tmp_path, capsys):
    out = tmp_path / "taken"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    run_bad(["synth", "mirror", out, "--subject-seed", "3"], capsys, "exists and is not empty")
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt"]
    afile = tmp_path / "afile"
    afile.write_text("x")
    run_bad(["synth", "mirror", afile, "--subject-seed", "3"], capsys, "is a file, not a folder")


def test_synth_mirror_api_refuses_unknown_edits(tmp_path):
    from bodystudio.errors import InputError
    from bodystudio.mirror.synthetic import synth_mirror_session

    with pytest.raises(InputError, match="unknown edit 'slimmer'; valid edits: taller, heavier"):
        synth_mirror_session(tmp_path / "s", 1, edits={"slimmer": 0.1})
    with pytest.raises(InputError, match="edit hips=0.31 is out of range"):
        synth_mirror_session(tmp_path / "s", 1, edits={"hips": 0.31})
    with pytest.raises(InputError, match="edited players"):
        synth_mirror_session(tmp_path / "s", 1, edited_players=(2,))
    assert not (tmp_path / "s").exists()


def test_synth_mirror_uses_the_reshape_stage_edits():
    """One source of truth: the ground truth's edit names, ranges and Eq. 4 map are mirror.reshape's."""
    from bodystudio.mirror import reshape, synthetic

    assert synthetic.check_edits is reshape.check_edits
    assert synthetic.target_coeffs is reshape.target_coeffs
    for name in ("EDIT_ATTRIBUTES", "EDIT_RANGES", "EDIT_UNITS"):
        assert not hasattr(synthetic, name)


def test_eval_mirror_of_a_non_mirror_session(small_synth_session, capsys):
    run_bad(["eval", "mirror", small_synth_session], capsys, "not a synthetic mirror session")


def test_eval_mirror_of_a_missing_session(tmp_path, capsys):
    run_bad(["eval", "mirror", tmp_path / "nope"], capsys, "no such session folder")


@pytest.fixture(scope="module")
def mirror_copy(tmp_path_factory):
    """A writable copy of the small mirror session (no source body: `mirror init` never ran)."""
    from bodystudio.capture.session import open_session

    path = tmp_path_factory.mktemp("mirror") / "session"
    shutil.copytree(small_mirror_session(), path)
    return open_session(path)


def test_eval_mirror_without_a_run(mirror_copy, capsys):
    run_bad(["eval", "mirror", mirror_copy.path], capsys, "no such run folder")
    run_bad(["eval", "mirror", mirror_copy.path, "--run", mirror_copy.path / "nope"], capsys, "no such run folder")


def test_eval_mirror_without_a_source_body(mirror_copy, tmp_path, capsys):
    run = write_fake_run(mirror_copy, tmp_path / "run", lambda f: f.gt_target_rgb, lambda f: f.gt_person == 1,
                         lambda f: f.gt_target_person == 1)
    run_bad(["eval", "mirror", mirror_copy.path, "--run", run], capsys, "run `bodystudio mirror init")


def test_eval_mirror_of_a_foreign_or_broken_run(mirror_copy, tmp_path, capsys):
    session = mirror_copy
    run = write_fake_run(session, tmp_path / "foreign", lambda f: f.kinect_rgb, lambda f: f.gt_person == 1,
                         lambda f: f.gt_person == 1, session_path=tmp_path / "another_session")
    run_bad(["eval", "mirror", session.path, "--run", run], capsys, "this run was made from session")
    run = write_fake_run(session, tmp_path / "edits", lambda f: f.kinect_rgb, lambda f: f.gt_person == 1,
                         lambda f: f.gt_person == 1, edits={"heavier": 10.0})
    run_bad(["eval", "mirror", session.path, "--run", run], capsys, "differ from the ground truth")
    run = write_fake_run(session, tmp_path / "gone", lambda f: f.kinect_rgb, lambda f: f.gt_person == 1,
                         lambda f: f.gt_person == 1)
    (run / "frames" / "00013.png").unlink()
    run_bad(["eval", "mirror", session.path, "--run", run], capsys, "the output is incomplete")
    (run / "run.json").write_text(json.dumps({"format": "something else"}))
    run_bad(["eval", "mirror", session.path, "--run", run], capsys, "not a mirror run manifest")
    (run / "run.json").write_text("{broken")
    run_bad(["eval", "mirror", session.path, "--run", run], capsys, "run.json")
