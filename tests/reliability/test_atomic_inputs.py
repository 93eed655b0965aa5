"""Bad inputs for whole-run atomicity (issue 16): locks, `bodystudio recover`, and readers of mixed outputs.

Each case: the input, the command, the exit code or error and a phrase of its one-line message, and
that the previous complete output (or none) remains.
"""

import json
import os
import shutil
import socket
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from bodystudio.cli.main import main
from bodystudio.errors import BodyStudioError, FileFormatError, InputError, SessionError
from bodystudio.reconstruct.rapid_skin import RapidSkinParams
from bodystudio.reconstruct.sequence import (
    evaluate_session,
    read_reconstruction,
    reconstruct_session,
    reconstruction_layout,
)
from bodystudio.runfolder import OutputLockedError, RunLayout, RunWriter, recover

REPO = Path(__file__).resolve().parents[2]
FAST = RapidSkinParams(outer_iterations=1, inner_iterations=2)


def _one_line(capsys, code: int, argv: list[str], phrase: str) -> str:
    capsys.readouterr()
    assert main(argv) == code
    err = capsys.readouterr().err.strip()
    # one error line (progress-bar leftovers on a non-terminal stderr are the CLI catalogue's business)
    lines = [line for line in err.splitlines() if line.startswith("error:")]
    assert len(lines) == 1 and phrase in lines[0] and "Traceback" not in err, err
    return lines[0]


@pytest.fixture(scope="module")
def reconstructed(tmp_path_factory):
    from bodystudio.capture.synth import synth_session

    path = tmp_path_factory.mktemp("atomic") / "s"
    synth_session(path, n_cameras=2, n_frames=2, motion="walk", subject_seed=7, kinect="v2", resolution=(160, 120),
                  noise=False, template="2k")
    reconstruct_session(path, template="2k", refine_pose=False, score=False, params=FAST)
    return path


@pytest.fixture
def session(reconstructed, tmp_path):
    dst = tmp_path / "s"
    shutil.copytree(reconstructed, dst)
    return dst


@pytest.fixture
def foreign_lock(tmp_path):
    """Start a child process that holds the lock of a layout (as another command would) until killed."""
    procs = []

    def hold(layout: RunLayout, command: str) -> subprocess.Popen:
        script = textwrap.dedent(f"""
            import sys, time
            from pathlib import Path
            from bodystudio.runfolder import RunLayout, acquire_lock
            acquire_lock(RunLayout(Path({str(layout.root)!r}), {layout.manifest!r}, {layout.prefix!r},
                                   {layout.what!r}), {command!r})
            print("locked", flush=True)
            time.sleep(120)
        """)
        proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True,
                                env=dict(os.environ, PYTHONPATH=str(REPO)))
        procs.append(proc)
        assert proc.stdout.readline().strip() == "locked"
        return proc

    yield hold
    for proc in procs:
        proc.kill()
        proc.wait()


def _session_layout(path: Path) -> RunLayout:
    return RunLayout(path, "session.json", ".", str(path))


# ---------------------------------------------------------------------------------------------- locks

def test_second_reconstruct_is_refused_while_one_runs(session, foreign_lock, capsys):
    before = (session / "reconstruct" / "run.json").read_bytes()
    proc = foreign_lock(reconstruction_layout(session), "bodystudio reconstruct")
    err = _one_line(capsys, 2, ["reconstruct", str(session), "--template", "2k"], f"being written by pid {proc.pid}")
    assert "bodystudio reconstruct" in err
    _one_line(capsys, 2, ["eval", "reconstruct", str(session)], "being written by")
    _one_line(capsys, 2, ["recover", str(session)], "nothing to recover while it runs")
    assert (session / "reconstruct" / "run.json").read_bytes() == before
    proc.kill()
    proc.wait()
    # its process is gone: the lock is stale, readers and writers go on
    assert read_reconstruction(session)[0]["frames"] == [0, 1]
    reconstruct_session(session, template="2k", frames="0:1", refine_pose=False, score=False, params=FAST)
    assert read_reconstruction(session)[0]["frames"] == [0]
    assert not (session / "reconstruct" / ".lock").exists()


def test_reconstruct_during_silhouettes_says_who_writes_not_corrupted(session, foreign_lock, capsys):
    foreign_lock(_session_layout(session), "bodystudio capture silhouettes")
    err = _one_line(capsys, 2, ["reconstruct", str(session), "--template", "2k"], "session is being written by")
    assert "bodystudio capture silhouettes" in err and "corrupted" not in err and "regenerate" not in err


def test_mask_rewritten_after_open_is_not_called_corrupted(session):
    from bodystudio.capture.session import SessionWriter, open_session

    s = open_session(session)
    with SessionWriter(session, update=True, command="bodystudio capture silhouettes") as w:
        w.write_mask("cam_00", 0, np.zeros((120, 160), bool))
    with pytest.raises(SessionError, match="changed while being read") as err:
        s.frame(0).masks["cam_00"]
    assert "corrupted" not in str(err.value)


def test_lock_from_another_host_is_refused_with_advice(tmp_path):
    layout = RunLayout(tmp_path / "out", "run.json", ".", str(tmp_path / "out"))
    layout.root.mkdir()
    layout.lock.write_text(json.dumps({"pid": 1, "host": "render-node-7", "command": "bodystudio reconstruct",
                                       "since": "2026-01-01T00:00:00Z"}))
    with pytest.raises(OutputLockedError, match=r"render-node-7 .*delete .*\.lock"):
        RunWriter(layout, "test")


@pytest.mark.parametrize("content, age_s, stale", [
    ("", 60.0, True),  # an empty lock left long ago by a process killed while creating it
    ("{not json", 60.0, True),
    ("", 0.0, False),  # just being created by another writer: wait
])
def test_unreadable_lock_is_stale_only_when_old(tmp_path, content, age_s, stale):
    layout = RunLayout(tmp_path / "out", "run.json", ".", str(tmp_path / "out"))
    layout.root.mkdir()
    layout.lock.write_text(content)
    t = time.time() - age_s
    os.utime(layout.lock, (t, t))
    if stale:
        with RunWriter(layout, "test") as w:
            w.write_json("a.json", {"a": 1})
            w.commit({"kind": "test"})
        assert "a.json" in json.loads(layout.manifest_path.read_text())["run"]["files"]
        assert not layout.lock.exists()
    else:
        with pytest.raises(OutputLockedError, match="being written by pid \\?"):
            RunWriter(layout, "test")


def test_lock_of_a_reused_pid_is_stale(tmp_path):
    layout = RunLayout(tmp_path / "out", "run.json", ".", str(tmp_path / "out"))
    layout.root.mkdir()
    # this very pid, but another process start time: the writer that held it is gone
    layout.lock.write_text(json.dumps({"pid": os.getpid(), "host": socket.gethostname(), "start": "1",
                                       "command": "bodystudio rig", "since": "then"}))
    with RunWriter(layout, "test") as w:
        w.commit({})
    assert not layout.lock.exists()


# ---------------------------------------------------------------------------------------------- recover

def test_recover_bad_paths(tmp_path, capsys):
    _one_line(capsys, 2, ["recover", str(tmp_path / "nowhere" / "x")], "no such file or folder")
    capsys.readouterr()
    assert main(["recover", str(tmp_path)]) == 0
    assert "nothing to recover" in capsys.readouterr().out


@pytest.mark.parametrize("record", ["{ garbage", '{"moves": [1, ["a"]]}', "[]"])
def test_recover_refuses_an_unreadable_commit_record(session, capsys, record):
    staging = session / "reconstruct" / ".staging"
    staging.mkdir()
    (staging / "commit.json").write_text(record)
    _one_line(capsys, 2, ["eval", "reconstruct", str(session)], "interrupted while committing; run `bodystudio recover")
    err = _one_line(capsys, 2, ["recover", str(session)], "unreadable commit record")
    assert "delete" in err and ".staging" in err
    shutil.rmtree(staging)
    assert read_reconstruction(session)[0]["frames"] == [0, 1]  # the previous run, untouched


def test_leftover_staging_must_be_recovered_before_a_new_run(session, capsys):
    (session / "reconstruct" / ".staging" / "meshes").mkdir(parents=True)
    (session / "reconstruct" / ".staging" / "meshes" / "00000.ply").write_bytes(b"half")
    assert read_reconstruction(session)[0]["frames"] == [0, 1]  # the previous complete result stays readable
    _one_line(capsys, 2, ["reconstruct", str(session), "--template", "2k"], "run `bodystudio recover")
    assert any("discarded an uncommitted write (1 files)" in line for line in recover(session))
    assert not (session / "reconstruct" / ".staging").exists()


def test_output_destination_that_is_a_folder_is_refused_before_the_commit(tmp_path):
    layout = RunLayout(tmp_path / "out", "run.json", ".", str(tmp_path / "out"))
    (tmp_path / "out" / "a.json").mkdir(parents=True)
    with pytest.raises(InputError, match="a.json: is a folder"):
        with RunWriter(layout, "test") as w:
            w.write_json("a.json", {})
            w.commit({})
    assert not layout.staging.exists() and not layout.lock.exists() and not layout.manifest_path.exists()


# ---------------------------------------------------------------------------------------------- readers

def test_failed_rerun_keeps_the_previous_result(session, capsys):
    """Issue 16 defect 1: a re-run with another template that stops at a corrupted mask left a mix."""
    before = {p: p.read_bytes() for p in (session / "reconstruct").rglob("*") if p.is_file()}
    mask = session / "cam_01" / "mask" / "00001.png"
    mask.write_bytes(mask.read_bytes()[:-40])
    _one_line(capsys, 2, ["reconstruct", str(session), "--template", "6k", "--outer", "1", "--no-refine-pose"],
              "corrupted")
    after = {p: p.read_bytes() for p in (session / "reconstruct").rglob("*") if p.is_file()}
    assert after == before
    assert evaluate_session(session)["frames"] == 2


def test_mesh_from_another_run_is_refused(session, reconstructed, tmp_path, capsys):
    other = tmp_path / "other"
    shutil.copytree(reconstructed, other)
    reconstruct_session(other, template="2k", frames="0:1", refine_pose=False, score=False,
                        params=RapidSkinParams(outer_iterations=2, inner_iterations=1))
    shutil.copy(other / "reconstruct" / "meshes" / "00000.ply", session / "reconstruct" / "meshes" / "00000.ply")
    _one_line(capsys, 2, ["eval", "reconstruct", str(session)], "does not belong to run")
    with pytest.raises(BodyStudioError, match="mixes two runs"):
        from bodystudio.viewer.views import reconstructed_mesh_path

        reconstructed_mesh_path(session, 0)


def test_reconstruction_without_run_record_is_refused(session, capsys):
    (session / "reconstruct" / "run.json").unlink()
    _one_line(capsys, 2, ["eval", "reconstruct", str(session)], "run.json: missing (a reconstruction by an older")


def test_run_record_without_checksums_is_refused(session, capsys):
    path = session / "reconstruct" / "run.json"
    run = json.loads(path.read_text())
    del run["run"]
    path.write_text(json.dumps(run))
    _one_line(capsys, 2, ["eval", "reconstruct", str(session)], "records no run id and checksums")


@pytest.fixture(scope="module")
def avatar(body_2k):
    from bodystudio.rig.avatar import Avatar
    from bodystudio.rig.weights import limit_influences

    sk = body_2k.skeleton
    colors = (np.abs(np.sin(body_2k.vertices * 20.0)) * 255).astype(np.uint8)
    return Avatar(body_2k.vertices, body_2k.faces, colors, sk.bone_names, sk.parents, None, sk.rest_rotations,
                  sk.rest_rotations, sk.lengths, limit_influences(body_2k.weights), np.zeros(3),
                  loaded_heads=sk.heads.copy())


def _write_rig(glb: Path, avatar, texture=False):
    from bodystudio.rig.export import rig_layout, write_rig

    with RunWriter(rig_layout(glb), "bodystudio rig") as w:
        return write_rig(w, glb, avatar, texture)


def test_glb_and_rig_json_from_different_runs_are_refused(avatar, tmp_path, capsys):
    _write_rig(tmp_path / "a" / "x.glb", avatar, texture=False)
    _write_rig(tmp_path / "b" / "x.glb", avatar, texture=True)
    shutil.copy(tmp_path / "b" / "x.glb", tmp_path / "a" / "x.glb")
    _one_line(capsys, 2, ["view", str(tmp_path / "a" / "x.glb"), "--screenshot", str(tmp_path / "v.png")],
              "does not belong to run")
    from bodystudio.rig.evaluate import load_avatar

    with pytest.raises(FileFormatError, match="does not belong to run"):
        load_avatar(tmp_path / "a" / "x.glb")
    assert not (tmp_path / "v.png").exists()


def test_rig_json_without_checksums_must_match_the_glb(avatar, tmp_path):
    from bodystudio.fileio import write_json
    from bodystudio.rig.evaluate import load_avatar
    from bodystudio.rig.export import rig_description, rig_json_path, write_glb

    glb = tmp_path / "y.glb"
    write_glb(glb, avatar, texture=True)  # API user: glb and a description of the untextured avatar
    write_json(rig_json_path(glb), rig_description(avatar))
    with pytest.raises(FileFormatError, match="from different runs"):
        load_avatar(glb)


def test_rig_onto_an_avatar_being_written_is_refused(avatar, tmp_path, foreign_lock, capsys):
    from bodystudio.rig.export import rig_layout

    glb = tmp_path / "z.glb"
    foreign_lock(rig_layout(glb), "bodystudio rig")
    _one_line(capsys, 2, ["rig", str(tmp_path / "missing.ply"), "--out", str(glb)], "being written by")


def test_calibration_exports_onto_a_file_write_nothing(tmp_path, capsys):
    from bodystudio.calib.board import CharucoBoardSpec, save_board_json

    save_board_json(tmp_path / "cap" / "board.json", CharucoBoardSpec())
    (tmp_path / "emc").write_text("a file")
    _one_line(capsys, 2, ["calibrate", str(tmp_path / "cap"), "--out", str(tmp_path / "o" / "cameras.json"),
                          "--easymocap", str(tmp_path / "emc")], "--easymocap")
    assert not (tmp_path / "o").exists()


def test_calibration_report_and_cameras_from_different_runs_are_refused(tmp_path, capsys):
    from bodystudio.calib.io import calibration_layout
    from bodystudio.geometry.camera import ring_rig, save_cameras_json

    est = tmp_path / "cameras.json"
    with RunWriter(calibration_layout(est), "bodystudio calibrate") as w:
        save_cameras_json(w.path_for("cameras.json"), ring_rig(3))
        w.commit({"cameras": {}})
    save_cameras_json(tmp_path / "gt.json", ring_rig(3))
    save_cameras_json(est, ring_rig(3, width=320, height=240))  # another run's cameras, same report
    _one_line(capsys, 2, ["eval", "calib", str(est), str(tmp_path / "gt.json")], "does not belong to run")


def test_files_outside_the_root_are_committed_and_recovered(tmp_path, monkeypatch):
    """An export beside the output folder (`calibrate --easymocap ../x`, `rig --bvh ../b.bvh`) is staged,
    recorded relative to the root, and moved by a recovery after a commit killed halfway."""
    import bodystudio.runfolder as rf

    layout = RunLayout(tmp_path / "out", "report.json", ".c.json.", str(tmp_path / "out" / "c.json"))
    real = os.replace
    moves = []

    def dying_replace(src, dst):
        if ".staging" in str(src) and "commit.json" not in str(dst):
            moves.append(dst)
            if len(moves) == 2:
                raise KeyboardInterrupt("killed while moving")
        return real(src, dst)

    w = RunWriter(layout, "test")
    w.write_json("c.json", {"c": 1})
    w.write_json(tmp_path / "exports" / "x.json", {"x": 2})
    monkeypatch.setattr(rf.os, "replace", dying_replace)
    with pytest.raises(KeyboardInterrupt):
        w.commit({})
    monkeypatch.setattr(rf.os, "replace", real)
    with pytest.raises(OutputLockedError, match="run `bodystudio recover"):
        rf.check_readable(layout)
    assert any("completed the interrupted write (2 files)" in line for line in recover(tmp_path / "out" / "c.json"))
    run = json.loads(layout.manifest_path.read_text())["run"]
    assert set(run["files"]) == {"c.json", "../exports/x.json"}
    rf.verify_run_files(layout, run)
    assert json.loads((tmp_path / "exports" / "x.json").read_text()) == {"x": 2}
