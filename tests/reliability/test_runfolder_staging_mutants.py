"""Mutation tests of what ``runfolder.py`` stages and records (docs/mutation/runfolder.md, "mutBB: the whole module"):
where ``RunWriter.path_for`` stages a file (inside the root, beside it, a folder of files, on "another drive"), which
staged files ``staged_files`` publishes (never an atomic write's leftover temporary file; the files of a folder
staged for outside the root under their own keys, ``_external/1`` not mistaken for ``_external/10``), the run
block's and a read lock's records (UTC times, this process's start, the command line), the refusals' whole
lines, and ``recover`` of one file's layout. Every expectation is written out by hand (bytes, sha256 of known
bytes, keys); nothing here signals another process. Small folders in ``tmp_path``, < 1 s.
"""
from __future__ import annotations

import datetime as dt
import hashlib
import json
import os
import re
import socket
import sys
import time
from pathlib import Path

import numpy as np
import psutil
import pytest

import bodystudio.runfolder as rf
from bodystudio.errors import FileFormatError, InputError
from bodystudio.runfolder import RunLayout, RunWriter, command_read_locks, hold_read_lock, recover, recover_layout

HOST = socket.gethostname()
UTC = re.compile(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\dZ")


def _layout(tmp_path: Path) -> RunLayout:
    return RunLayout(tmp_path / "out", "run.json", ".", "OUT")


def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _is_utc_now(stamp: str) -> bool:
    """``stamp`` is now, in UTC, to the second (local time in Asia/Kolkata is 5 h 30 min off)."""
    if not UTC.fullmatch(stamp):
        return False
    then = dt.datetime.strptime(stamp, "%Y-%m-%dT%H:%M:%SZ").replace(tzinfo=dt.UTC)
    return abs((dt.datetime.now(dt.UTC) - then).total_seconds()) < 5


@pytest.fixture
def kolkata(monkeypatch):
    monkeypatch.setenv("TZ", "Asia/Kolkata")  # +05:30
    time.tzset()
    yield
    monkeypatch.delenv("TZ")
    time.tzset()


def _files(folder: Path) -> list[str]:
    return sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*") if p.is_file())


# ---------------------------------------------------------------------------------------------- staging

def test_nested_destinations_numpy_json_and_a_leftover_temporary_file(tmp_path):
    """``a/b/c.txt`` stages two new folders deep; JSON takes numpy values and paths; a ``.``-file in the staging
    folder (a killed atomic write's temporary file) is neither published nor listed."""
    lay = _layout(tmp_path)
    with RunWriter(lay, "t") as w:
        staged = w.path_for("a/b/c.txt")
        assert staged == lay.staging / "a" / "b" / "c.txt" and staged.parent.is_dir()
        w.write_bytes("a/b/c.txt", b"C")
        w.write_bytes("a/b/d.txt", b"D")  # the folder exists already
        w.write_json("m.json", {"x": np.float32(0.5), "v": np.arange(3), "p": Path("p/q")})
        (lay.staging / "a" / ".c.txt.x1y2.tmp").write_bytes(b"half")
        (lay.staging / ".m.json.tmp").write_bytes(b"half")
        manifest = w.commit({})
    m_json = b'{\n  "x": 0.5,\n  "v": [\n    0,\n    1,\n    2\n  ],\n  "p": "p/q"\n}\n'
    assert (lay.root / "m.json").read_bytes() == m_json
    assert manifest["run"]["files"] == {"a/b/c.txt": _sha(b"C"), "a/b/d.txt": _sha(b"D"), "m.json": _sha(m_json)}
    assert _files(lay.root) == ["a/b/c.txt", "a/b/d.txt", "m.json", "run.json"]


def test_a_folder_staged_for_outside_the_root_publishes_its_files_under_their_own_keys(tmp_path):
    """Eleven destinations beside the root: ``_external/1`` is a folder of two files, ``_external/10`` a file."""
    lay = _layout(tmp_path)
    with RunWriter(lay, "t") as w:
        for i in range(11):
            if i == 1:
                folder = w.path_for(tmp_path / "side")
                assert folder == lay.staging / "_external" / "1"
                (folder / "sub").mkdir(parents=True)
                (folder / "a.txt").write_bytes(b"A")
                (folder / "sub" / "b.txt").write_bytes(b"B")
            else:
                staged = w.path_for(tmp_path / f"e{i}.txt")
                assert staged == lay.staging / "_external" / str(i)
                staged.write_bytes(f"E{i}".encode())
        assert w.staged_files()["_external/1/sub/b.txt"] == "../side/sub/b.txt"
        assert w.staged_files()["_external/10"] == "../e10.txt"
        manifest = w.commit({})
    files = manifest["run"]["files"]
    expected = {f"../e{i}.txt": _sha(f"E{i}".encode()) for i in range(11) if i != 1}
    expected |= {"../side/a.txt": _sha(b"A"), "../side/sub/b.txt": _sha(b"B")}
    assert files == expected
    assert (tmp_path / "side" / "sub" / "b.txt").read_bytes() == b"B" and (tmp_path / "e10.txt").read_text() == "E10"
    assert rf.verify_run_files(lay, manifest["run"])


def test_a_destination_on_another_drive_is_recorded_by_its_absolute_path(tmp_path, monkeypatch):
    """Windows' ``relpath`` raises ValueError across drives: the key is the destination's absolute path."""
    lay = _layout(tmp_path)
    elsewhere = tmp_path / "drive" / "x.bin"

    def across_drives(path, start=None):
        raise ValueError("path is on mount 'D:', start on mount 'C:'")

    with RunWriter(lay, "t") as w:
        with monkeypatch.context() as m:
            m.setattr(rf.os.path, "relpath", across_drives)
            assert w._key(elsewhere) == str(elsewhere.resolve())
            staged = w.path_for(elsewhere)
        assert staged == lay.staging / "_external" / "0"
        staged.write_bytes(b"X")
        manifest = w.commit({})
    assert manifest["run"]["files"] == {str(elsewhere.resolve()): _sha(b"X")}
    assert elsewhere.read_bytes() == b"X"


def test_the_run_block_is_created_now_in_utc(tmp_path, kolkata):
    lay = _layout(tmp_path)
    with RunWriter(lay, "bodystudio t", {"k": 1}) as w:
        w.write_bytes("a", b"A")
        block = w.run_block()
        assert set(block) == {"run_id", "command", "producer", "files", "created"}
        manifest = w.commit({})
    assert _is_utc_now(block["created"]) and _is_utc_now(manifest["run"]["created"])
    assert json.loads(lay.manifest_path.read_text())["run"]["created"] == manifest["run"]["created"]


def test_a_first_run_whose_folder_gained_other_files_keeps_it(tmp_path):
    """The writer made the folder; something else wrote into it meanwhile: the abort leaves it (not empty)."""
    lay = _layout(tmp_path)
    w = RunWriter(lay, "t")
    (lay.root / "notes.txt").write_text("someone else's")
    w.abort()
    assert _files(lay.root) == ["notes.txt"] and not lay.lock.exists()


def test_a_destination_folder_is_refused_with_the_whole_line(tmp_path):
    lay = _layout(tmp_path)
    (lay.root / "a.txt").mkdir(parents=True)
    with RunWriter(lay, "t") as w:
        w.write_bytes("a.txt", b"A")
        with pytest.raises(InputError) as err:
            w.commit({})
    assert str(err.value) == f"output {lay.root / 'a.txt'}: is a folder; give a file path"
    with pytest.raises(InputError) as err:
        rf.check_output_destination(lay.root / "a.txt", "--bvh")
    assert str(err.value) == f"--bvh {lay.root / 'a.txt'}: is a folder; give a file path"


# ---------------------------------------------------------------------------------------------- read locks

@pytest.mark.parametrize("argv, expected", [
    (["/opt/venv/bin/bodystudio", "view", "S", "--screenshot", "x.png"], "bodystudio view S"),
    (["/opt/venv/bin/bodystudio", "report"], "bodystudio report"),
    (["/opt/venv/bin/bodystudio"], "bodystudio"),
    (["", "-c"], "python"),  # python -c: no script name
    ([], "python"),
])
def test_reader_command_is_the_command_lines_first_words(monkeypatch, argv, expected):
    monkeypatch.setattr(sys, "argv", argv)
    assert rf.reader_command() == expected


def test_a_read_lock_registration_names_this_process_its_start_and_the_utc_time(tmp_path, monkeypatch, kolkata):
    lay = _layout(tmp_path)
    lay.root.mkdir()
    monkeypatch.setattr(sys, "argv", ["/usr/bin/bodystudio", "eval", "rig", "A.glb", "--json"])
    with command_read_locks():
        lock = hold_read_lock(lay)
        record = json.loads(lock.path.read_bytes())
        assert lock.path.read_bytes().endswith(b"}\n")
    assert set(record) == {"pid", "host", "start", "command", "since"}
    assert (record["pid"], record["host"], record["command"]) == (os.getpid(), HOST, "bodystudio eval rig")
    ticks = (psutil.Process().create_time() - psutil.boot_time()) * os.sysconf("SC_CLK_TCK")
    assert abs(int(record["start"]) - ticks) <= 1.5  # a reused pid is told from this reader by it
    assert _is_utc_now(record["since"])


# ---------------------------------------------------------------------------------------------- recover

def test_recover_of_one_files_layout_refuses_a_record_naming_no_manifest(tmp_path):
    """``bodystudio recover a.glb`` knows no manifest name of its own: a record with a manifest but no
    ``manifest_name`` is refused, nothing is written."""
    out = tmp_path / "scans"
    lay = RunLayout(out, "", ".a.glb.", str(out / "a.glb"))
    (lay.staging).mkdir(parents=True)
    (lay.staging / "a.glb").write_bytes(b"new")
    (out / "a.glb").write_bytes(b"previous")
    lay.commit_record.write_text(json.dumps({"moves": ["a.glb"], "manifest": {"k": 1}}))
    with pytest.raises(FileFormatError) as err:
        recover(out / "a.glb")
    assert str(err.value) == (f"{lay.commit_record}: names no manifest to write; delete {lay.staging} to keep the "
                              "previous result")
    assert _files(out) == [".a.glb.staging/a.glb", ".a.glb.staging/commit.json", "a.glb"]


def test_recover_removes_a_lock_this_very_process_left(tmp_path):
    """A lock naming this process (a writer of this process that never released it) is no live writer to
    ``recover``: removed, like a dead process's."""
    lay = _layout(tmp_path)
    lay.root.mkdir()
    own = {"pid": os.getpid(), "host": HOST, "start": rf._process_start(os.getpid()), "command": "t", "since": "x"}
    lay.lock.write_text(json.dumps(own))
    assert rf.lock_holder(lay) is None
    assert recover_layout(lay) == "removed a stale lock"
    assert not lay.lock.exists() and not list(lay.root.iterdir())


def test_a_command_that_fails_releases_its_read_locks_and_library_use_registers_none_after(tmp_path):
    """``command_read_locks`` (decorated: planted by hand, docs/mutation/runfolder-plant.py): a command ending in an
    exception releases its read locks like one that ends well, and reads after the command (library use in the
    same process) register nothing."""
    lay = _layout(tmp_path)
    lay.root.mkdir()
    with pytest.raises(KeyError), command_read_locks():
        assert hold_read_lock(lay, "bodystudio view") is not None and lay.readers.is_dir()
        raise KeyError("the command failed")
    assert not lay.readers.exists() and rf._HELD == [] and rf._HOLDING == [False]
    with command_read_locks():
        hold_read_lock(lay, "bodystudio view")
    assert hold_read_lock(lay) is None and not lay.readers.exists() and rf._HOLDING == [False]


def test_the_manifest_is_written_after_every_move_and_delete_and_before_the_staging_goes(tmp_path, monkeypatch):
    """The commit's order is the scheme itself (module docstring, step 4): a process killed between two steps
    leaves either the previous manifest (the new one not yet written) or a complete result; never a new manifest
    over files not moved yet. Every rename is watched: the manifest's is the last but the staging folder's."""
    lay = _layout(tmp_path)
    (lay.root).mkdir()
    (lay.root / "old.txt").write_text("old")
    real_replace = os.replace
    renames = []

    def watched(src, dst):
        renames.append((Path(src), Path(dst), sorted(p.name for p in lay.root.iterdir() if not p.name.startswith("."))))
        return real_replace(src, dst)

    with RunWriter(lay, "t") as w:
        w.write_bytes("a.txt", b"A")
        w.write_bytes("sub/b.txt", b"B")
        monkeypatch.setattr(rf.os, "replace", watched)
        w.commit({}, deletes=["old.txt"])
        monkeypatch.setattr(rf.os, "replace", real_replace)
    targets = [dst for _, dst, _ in renames]
    record = targets.index(lay.commit_record)
    manifest = targets.index(lay.manifest_path)
    moved = [targets.index(lay.root / "a.txt"), targets.index(lay.root / "sub" / "b.txt")]
    assert record < min(moved) and max(moved) < manifest == len(renames) - 2  # record, moves, manifest, staging
    assert renames[-1][0] == lay.staging and ".stale." in renames[-1][1].name
    assert renames[manifest][2] == ["a.txt", "sub"]  # the old file deleted before the manifest, not after


def test_the_lock_is_held_while_the_commit_is_carried_out(tmp_path, monkeypatch):
    lay = _layout(tmp_path)
    real_apply = rf.apply_commit
    seen = []

    def watched(layout, plan):
        seen.append((layout.commit_record.is_file(), rf.read_lock(layout.lock)["pid"]))
        return real_apply(layout, plan)

    monkeypatch.setattr(rf, "apply_commit", watched)
    with RunWriter(lay, "t") as w:
        w.write_bytes("a.txt", b"A")
        w.commit({})
    assert seen == [(True, os.getpid())] and not lay.lock.exists()
