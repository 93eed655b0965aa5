"""What a reader and a writer of a run folder rely on, pinned step by step (mutation round mutV, issue 17).

``bodystudio/runfolder.py`` protects every multi-file result: a complete result is read (or a batch unit
skipped), an interrupted one is refused or completed, never a mix. These cases drive its write/commit layer
(``apply_commit``, ``remove_staging``, ``recover_layout``, ``layouts_under``, ``check_readable``,
``verify_run_files``, ``RunWriter``) and its locks (``acquire_lock``, ``lock_is_stale``, ``lock_holder``,
``read_lock``, ``live_readers``, the read locks) on small folders in ``tmp_path``, with exact messages and
exact bytes. "Another live process" is this process's parent (alive, another pid, same host); no process is
spawned. Pure file-system work: the whole file runs in well under a second.
"""

from __future__ import annotations

import errno
import hashlib
import json
import logging
import os
import shutil
import socket
import time
from pathlib import Path

import numpy as np
import pytest

import bodystudio.runfolder as rf
from bodystudio.errors import FileFormatError, OutputSpaceError
from bodystudio.runfolder import (
    LOCK_GRACE_S,
    OutputLockedError,
    ReadLock,
    RunLayout,
    RunWriter,
    acquire_lock,
    apply_commit,
    check_readable,
    command_read_locks,
    hold_read_lock,
    layouts_under,
    live_readers,
    lock_holder,
    lock_is_stale,
    read_lock,
    recover,
    recover_layout,
    release_read_locks,
    remove_staging,
    remove_stale_staging,
    verify_run_files,
)

HOST = socket.gethostname()


def _layout(tmp_path: Path, prefix: str = ".", manifest: str = "run.json") -> RunLayout:
    return RunLayout(tmp_path / "out", manifest, prefix, "OUT")


def _other_live(command: str = "bodystudio other", since: str = "2026-01-01T00:00:00Z") -> dict:
    """A holder record of another live process of this host (the parent of this one)."""
    pid = os.getppid()
    return {"pid": pid, "host": HOST, "start": rf._process_start(pid), "command": command, "since": since}


def _dead_pid() -> int:
    pid = 4_000_000  # above Linux's pid_max (2^22): never a live process
    assert not rf._process_alive(pid)
    return pid


def _write(path: Path, data: bytes | str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(data.encode() if isinstance(data, str) else data)
    return path


def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _names(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


# ---------------------------------------------------------------------------------------------- apply_commit

def test_apply_commit_moves_deletes_and_writes_the_manifest_last_with_its_indent(tmp_path):
    lay = _layout(tmp_path)
    _write(lay.root / "old.txt", "old")
    _write(lay.root / "keep.txt", "keep")
    _write(lay.staging / "a.txt", "A")
    _write(lay.staging / "deep/er/b.txt", "B")
    _write(lay.staging / "_external/0", "C")
    _write(lay.root / "deep/other.txt", "D")  # ... or do
    _write(lay.staging / "deep/c.txt", "E")
    plan = {"moves": ["a.txt", ["deep/er/b.txt", "new/er/b.txt"], ["_external/0", "../beside.txt"],
                      ["deep/c.txt", "deep/c.txt"], "gone.txt"],
            "deletes": ["old.txt", "never-there.txt"],
            "manifest": {"n": np.int64(3), "arr": np.arange(2)}, "manifest_name": "m.json", "indent": 3}
    apply_commit(lay, plan)
    assert (lay.root / "a.txt").read_text() == "A" and (lay.root / "new/er/b.txt").read_text() == "B"  # new folders
    assert (lay.root / "deep/c.txt").read_text() == "E" and (lay.root / "deep/other.txt").read_text() == "D"
    assert (tmp_path / "beside.txt").read_text() == "C"
    assert not (lay.root / "gone.txt").exists()  # a move whose staged file is gone already happened
    assert not (lay.root / "old.txt").exists() and (lay.root / "keep.txt").read_text() == "keep"
    assert (lay.root / "m.json").read_bytes() == (json.dumps({"n": 3, "arr": [0, 1]}, indent=3) + "\n").encode()
    assert not lay.manifest_path.exists()  # the plan's manifest name, not the layout's
    assert not lay.staging.exists() and not any(".stale." in n for n in _names(lay.root))


def test_apply_commit_default_indent_and_manifest_name_and_a_text_manifest(tmp_path):
    lay = _layout(tmp_path)
    _write(lay.staging / "a.txt", "A")
    apply_commit(lay, {"moves": ["a.txt"], "manifest": {"k": [1, 2]}})
    assert lay.manifest_path.read_bytes() == b'{\n "k": [\n  1,\n  2\n ]\n}\n'  # indent 1 when the plan has none
    _write(lay.staging / "b.txt", "B")
    apply_commit(lay, {"moves": ["b.txt"], "manifest": '{"raw": true}'})
    assert lay.manifest_path.read_bytes() == b'{"raw": true}'  # a text manifest is written as it is
    _write(lay.staging / "c.txt", "C")
    apply_commit(lay, {"moves": ["c.txt"]})  # no manifest: the files only
    assert (lay.root / "c.txt").read_text() == "C" and lay.manifest_path.read_bytes() == b'{"raw": true}'


def test_apply_commit_refuses_a_record_naming_no_manifest(tmp_path):
    lay = _layout(tmp_path, manifest="")
    _write(lay.staging / "a.txt", "A")
    with pytest.raises(FileFormatError) as err:
        apply_commit(lay, {"moves": ["a.txt"], "manifest": {"k": 1}})
    assert str(err.value) == (f"{lay.commit_record}: names no manifest to write; delete {lay.staging} to keep the "
                              "previous result")
    assert not (lay.root / "a.txt").exists() and (lay.staging / "a.txt").is_file()  # nothing moved
    with pytest.raises(FileFormatError, match="names no manifest"):
        apply_commit(_layout(tmp_path), {"moves": [], "manifest": {"k": 1}, "manifest_name": ""})
    apply_commit(lay, {"moves": ["a.txt"], "manifest": None, "manifest_name": ""})  # no manifest to write: fine
    assert (lay.root / "a.txt").read_text() == "A"


def _replace_failing_for_staged(monkeypatch, lay: RunLayout, code: int) -> None:
    real = os.replace

    def fake(src, dst, *a, **kw):
        if Path(src).is_relative_to(lay.staging) and Path(src) != lay.staging:  # a staged file, not the folder
            raise OSError(code, os.strerror(code))
        return real(src, dst, *a, **kw)

    monkeypatch.setattr(rf.os, "replace", fake)


def test_apply_commit_copies_across_file_systems(tmp_path, monkeypatch):
    lay = _layout(tmp_path)
    _write(lay.staging / "sub/a.bin", b"\x00data")
    _replace_failing_for_staged(monkeypatch, lay, errno.EXDEV)
    apply_commit(lay, {"moves": [["sub/a.bin", "x/a.bin"]], "manifest": {"k": 1}})
    assert (lay.root / "x/a.bin").read_bytes() == b"\x00data"
    assert not lay.staging.exists()
    assert json.loads(lay.manifest_path.read_text()) == {"k": 1}


def test_apply_commit_stops_before_the_manifest_on_another_move_error(tmp_path, monkeypatch):
    lay = _layout(tmp_path)
    _write(lay.root / "run.json", "previous")
    _write(lay.staging / "a.txt", "A")
    _replace_failing_for_staged(monkeypatch, lay, errno.EACCES)
    with pytest.raises(PermissionError):
        apply_commit(lay, {"moves": ["a.txt"], "manifest": {"k": 1}})
    assert lay.manifest_path.read_text() == "previous" and (lay.staging / "a.txt").is_file()


# ---------------------------------------------------------------------------------------------- staging

def test_remove_staging_renames_then_deletes_and_clears_an_old_tomb_of_this_pid(tmp_path):
    lay = _layout(tmp_path)
    tomb = lay.root / f".staging.stale.{os.getpid()}"
    _write(tomb / "left.txt", "left by a killed delete of an earlier writer with this pid")
    _write(lay.staging / "a/b.txt", "B")
    remove_staging(lay)
    assert _names(lay.root) == []
    remove_staging(lay)  # no staging: nothing to do, no tomb made
    assert _names(lay.root) == []


def test_remove_staging_of_a_rig_layout_names_its_tomb_after_its_staging(tmp_path, monkeypatch):
    lay = _layout(tmp_path, prefix=".a.glb.")
    _write(lay.staging / "a.glb", "G")
    seen = []
    real = shutil.rmtree
    monkeypatch.setattr(rf.shutil, "rmtree", lambda p, **kw: (seen.append((Path(p).name, kw)), real(p, **kw)))
    remove_staging(lay)
    tomb = f".a.glb.staging.stale.{os.getpid()}"
    assert seen == [(tomb, {"ignore_errors": True}), (tomb, {"ignore_errors": True})]
    assert _names(lay.root) == []


def test_a_staging_folder_that_cannot_be_fully_deleted_does_not_fail_the_commit(tmp_path, monkeypatch):
    """rmtree's ``ignore_errors``: a file that will not go (NFS silly-rename, a scanner holding it) leaves a
    ``.stale.`` folder for the next writer, not an exception after the result was committed."""
    lay = _layout(tmp_path)

    def stubborn(path, ignore_errors=False, **kw):
        if Path(path).exists() and not ignore_errors:
            raise OSError(errno.EBUSY, "busy", str(path))

    _write(lay.root / ".staging.stale.5" / "f", "left by a killed delete")
    monkeypatch.setattr(rf.shutil, "rmtree", stubborn)
    with RunWriter(lay, "test") as w:
        w.write_bytes("a.txt", b"A")
        w.commit({"k": 1})
    assert (lay.root / "a.txt").read_text() == "A" and not lay.staging.exists()
    assert check_readable(lay) is None


def test_remove_stale_staging_counts_and_removes_only_its_own_leftovers(tmp_path):
    lay = _layout(tmp_path, prefix=".a[1].glb.")  # glob characters in the name: matched literally
    for name in (".a[1].glb.staging.stale.11", ".a[1].glb.staging.stale.12"):
        _write(lay.root / name / "f", "x")
    for name in (".a1.glb.staging.stale.13", ".b.glb.staging.stale.14", ".a[1].glb.staging"):
        _write(lay.root / name / "f", "x")
    assert remove_stale_staging(lay) == 2
    assert _names(lay.root) == [".a1.glb.staging.stale.13", ".a[1].glb.staging", ".b.glb.staging.stale.14"]
    assert remove_stale_staging(lay) == 0


# ---------------------------------------------------------------------------------------------- recover

def _record(lay: RunLayout, plan: dict | str) -> None:
    _write(lay.commit_record, plan if isinstance(plan, str) else json.dumps(plan))


def test_recover_completes_a_committed_write(tmp_path):
    lay = _layout(tmp_path)
    _write(lay.root / "old.txt", "old")
    _write(lay.staging / "a.txt", "A")
    _write(lay.staging / "b.txt", "B")
    _record(lay, {"moves": ["a.txt", ["b.txt", "sub/b.txt"]], "deletes": ["old.txt"], "manifest": {"k": 2},
                  "manifest_name": "run.json", "indent": 2})
    _write(lay.lock, json.dumps({"pid": _dead_pid(), "host": HOST, "command": "killed"}))
    assert recover_layout(lay) == "completed the interrupted write (2 files)"
    assert (lay.root / "sub/b.txt").read_text() == "B" and not (lay.root / "old.txt").exists()
    assert lay.manifest_path.read_text() == json.dumps({"k": 2}, indent=2) + "\n"
    assert _names(lay.root) == ["a.txt", "run.json", "sub"]  # staging and the stale lock gone
    assert recover_layout(lay) is None


def test_recover_discards_an_uncommitted_write_and_keeps_the_previous_result(tmp_path):
    lay = _layout(tmp_path)
    _write(lay.manifest_path, "previous")
    _write(lay.staging / "a.txt", "A")
    _write(lay.staging / "d/b.txt", "B")
    _write(lay.staging / "d/e/c.txt", "C")
    assert recover_layout(lay) == "discarded an uncommitted write (3 files); the previous result stays"
    assert _names(lay.root) == ["run.json"] and lay.manifest_path.read_text() == "previous"


@pytest.mark.parametrize("leftover, message", [
    ("tomb", "removed the leftover of a finished write"),
    ("lock", "removed a stale lock"),
    ("both", "removed the leftover of a finished write"),
])
def test_recover_tidies_leftovers_of_a_finished_write(tmp_path, leftover, message):
    lay = _layout(tmp_path)
    _write(lay.manifest_path, "result")
    if leftover in ("tomb", "both"):
        _write(lay.root / ".staging.stale.77" / "f", "x")
    if leftover in ("lock", "both"):
        _write(lay.lock, json.dumps({"pid": _dead_pid(), "host": HOST, "command": "killed"}))
    assert recover_layout(lay) == message
    assert _names(lay.root) == ["run.json"]


def test_recover_message_of_a_discard_wins_over_the_tidying(tmp_path):
    lay = _layout(tmp_path)
    _write(lay.staging / "a.txt", "A")
    _write(lay.root / ".staging.stale.77" / "f", "x")
    _write(lay.lock, json.dumps({"pid": _dead_pid(), "host": HOST, "command": "killed"}))
    assert recover_layout(lay) == "discarded an uncommitted write (1 files); the previous result stays"
    assert _names(lay.root) == []


def test_recover_refuses_while_a_writer_lives(tmp_path):
    lay = _layout(tmp_path)
    _write(lay.staging / "a.txt", "A")
    _write(lay.lock, json.dumps(_other_live("bodystudio reconstruct")))
    with pytest.raises(OutputLockedError) as err:
        recover_layout(lay)
    assert str(err.value) == (f"OUT: being written by pid {os.getppid()} on {HOST} (bodystudio reconstruct, since "
                              f"2026-01-01T00:00:00Z); wait for it to finish or run `bodystudio recover OUT`; "
                              "nothing to recover while it runs")
    assert (lay.staging / "a.txt").is_file() and lay.lock.is_file()


@pytest.mark.parametrize("what", ["staging", "record"])
def test_recover_refuses_while_another_process_reads_an_interrupted_write(tmp_path, what):
    lay = _layout(tmp_path)
    _write(lay.staging / "a.txt", "A")
    if what == "record":
        _record(lay, {"moves": ["a.txt"]})
        shutil.rmtree(lay.staging / "a.txt", ignore_errors=True)
        _write(lay.staging / "a.txt", "A")
    _write(lay.readers / "h.1.1", json.dumps(_other_live("bodystudio view")))
    with pytest.raises(OutputLockedError) as err:
        recover_layout(lay)
    assert str(err.value) == (f"OUT: being read by pid {os.getppid()} (bodystudio view); recover it when that has "
                              "finished")
    assert (lay.staging / "a.txt").is_file()


def test_recover_with_a_reader_and_nothing_interrupted_goes_on(tmp_path):
    lay = _layout(tmp_path)
    _write(lay.readers / "h.1.1", json.dumps(_other_live("bodystudio view")))
    _write(lay.root / ".staging.stale.5" / "f", "x")
    assert recover_layout(lay) == "removed the leftover of a finished write"


@pytest.mark.parametrize("record, why", [
    ("{ garbage", "Expecting property name"),
    ("[]", "(no moves)"),
    ('{"moves": {"a": 1}}', "(no moves)"),
    ('{"moves": [1]}', "bad move 1"),
    ('{"moves": [["a"]]}', "bad move ['a']"),
    ('{"moves": [["a", "b", "c"]]}', "bad move ['a', 'b', 'c']"),
    ('{"moves": [["a", 2]]}', "bad move ['a', 2]"),
])
def test_recover_refuses_an_unreadable_record_and_touches_nothing(tmp_path, record, why):
    lay = _layout(tmp_path)
    _write(lay.manifest_path, "previous")
    _record(lay, record)
    with pytest.raises(FileFormatError) as err:
        recover_layout(lay)
    msg = str(err.value)
    assert msg.startswith(f"{lay.commit_record}: unreadable commit record (") and why in msg
    assert msg.endswith(f"); delete {lay.staging} to keep the previous result")
    assert lay.commit_record.is_file() and lay.manifest_path.read_text() == "previous"


def test_recover_accepts_both_move_forms(tmp_path):
    lay = _layout(tmp_path)
    _write(lay.staging / "a", "A")
    _write(lay.staging / "b", "B")
    _record(lay, {"moves": ["a", ["b", "c"]], "manifest": {"k": 1}, "manifest_name": "run.json"})
    assert recover_layout(lay) == "completed the interrupted write (2 files)"
    assert (lay.root / "c").read_text() == "B"


def test_recover_of_a_path(tmp_path):
    out = tmp_path / "scans"
    _write(out / ".a.glb.staging" / "a.glb", "G")
    assert recover(out / "a.glb") == [f"{out / 'a.glb'}: discarded an uncommitted write (1 files); the previous "
                                      "result stays"]
    assert recover(out) == [f"{out}: nothing to recover"]
    with pytest.raises(FileFormatError, match="no such file or folder"):
        recover(tmp_path / "none" / "x.glb")


# ---------------------------------------------------------------------------------------------- layouts_under

def test_layouts_under_finds_every_interrupted_write_one_level_deep(tmp_path):
    root = tmp_path / "r"
    _write(root / ".lock", "{}")
    _write(root / ".staging" / "x", "x")
    _write(root / ".a.glb.staging.stale.12" / "x", "x")  # a killed delete's leftover names its layout
    _write(root / ".lock.stale.99", "{}")  # a lock being taken over: no layout
    _write(root / ".b.glb.lock", "{}")
    _write(root / "plain.txt", "x")
    _write(root / "sub" / ".staging" / "x", "x")
    _write(root / "sub" / ".c.glb.lock", "{}")
    _write(root / "sub" / "deeper" / ".lock", "{}")  # two levels down: not looked at
    _write(root / ".staging" / ".lock", "{}")  # inside a staging folder: not looked at
    _write(root / "x.staging" / ".lock", "{}")
    _write(root / "y.stale.3" / ".lock", "{}")
    _write(root / "nolock" / "lock", "{}")  # not a hidden name
    _write(root / "nolock" / ".notes", "{}")
    found = sorted((str(lay.root.relative_to(tmp_path)), lay.manifest, lay.prefix,
                    str(Path(lay.what).relative_to(tmp_path))) for lay in layouts_under(root))
    assert found == [
        ("r", "", ".a.glb.", "r/a.glb"),
        ("r", "", ".b.glb.", "r/b.glb"),
        ("r", "session.json", ".", "r"),
        ("r/sub", "", ".c.glb.", "r/sub/c.glb"),
        ("r/sub", "session.json", ".", "r/sub"),
    ]
    assert len(layouts_under(root)) == 5  # the root's lock and staging are one layout
    _write(tmp_path / "alone" / ".lock.stale.99", "{}")  # a lock being taken over, alone: nothing to recover
    _write(tmp_path / "alone" / ".a.glb.lock.stale.98", "{}")
    assert layouts_under(tmp_path / "alone") == []


def test_recover_of_a_folder_finds_an_avatar_with_stale_in_its_name(tmp_path):
    """``.stale.`` inside a user's file name is no leftover: ``recover DIR`` said "nothing to recover" for an
    interrupted ``a.stale.glb`` (its lock and staging were skipped), while ``recover DIR/a.stale.glb`` worked."""
    out = tmp_path / "avatars"
    _write(out / ".a.stale.glb.staging" / "a.stale.glb", "G")
    _write(out / ".b.stale.glb.staging.stale.12" / "b.stale.glb", "G")
    _write(out / ".c.stale.glb.lock", json.dumps({"pid": _dead_pid(), "host": HOST, "command": "killed"}))
    _write(out / "v2.stale.glb" / ".staging" / "x", "x")  # a user's sub-folder with .stale. in its name
    assert sorted(lay.prefix for lay in layouts_under(out)) == [".", ".a.stale.glb.", ".b.stale.glb.", ".c.stale.glb."]
    assert sorted(recover(out)) == [
        f"{out / 'a.stale.glb'}: discarded an uncommitted write (1 files); the previous result stays",
        f"{out / 'b.stale.glb'}: removed the leftover of a finished write",
        f"{out / 'c.stale.glb'}: removed a stale lock",
        f"{out / 'v2.stale.glb'}: discarded an uncommitted write (1 files); the previous result stays"]
    assert _names(out) == ["v2.stale.glb"]


# ---------------------------------------------------------------------------------------------- readers

def test_check_readable_refuses_a_committed_unfinished_write(tmp_path):
    lay = _layout(tmp_path)
    _record(lay, {"moves": []})
    with pytest.raises(OutputLockedError) as err:
        check_readable(lay)
    assert str(err.value) == ("OUT: a write was interrupted while committing; run `bodystudio recover OUT` to "
                              "finish it")


def test_check_readable_notes_an_uncommitted_leftover_and_reads_the_previous_result(tmp_path, caplog):
    lay = _layout(tmp_path)
    _write(lay.manifest_path, "previous")
    _write(lay.staging / "a", "A")
    _write(lay.staging / "d/b", "B")
    (lay.staging / "empty").mkdir()
    with caplog.at_level(logging.WARNING, logger="bodystudio.runfolder"):
        note = check_readable(lay)
    assert note == f"{lay.staging}: an interrupted write left 2 uncommitted files"
    assert caplog.messages == [f"{note}; showing the last complete result (run `bodystudio recover OUT` to "
                               "discard it)"]
    shutil.rmtree(lay.staging)
    assert check_readable(lay) is None


def test_check_readable_refuses_a_live_writer(tmp_path):
    lay = _layout(tmp_path)
    _write(lay.manifest_path, "previous")
    _write(lay.lock, json.dumps(_other_live("bodystudio rig")))
    with pytest.raises(OutputLockedError, match=f"being written by pid {os.getppid()} on "):
        check_readable(lay)


def _run(files: dict) -> dict:
    return {"run_id": "r1", "files": files}


def test_verify_run_files_accepts_the_listed_files_and_returns_the_block(tmp_path):
    lay = _layout(tmp_path)
    _write(lay.root / "a.txt", b"A")
    _write(tmp_path / "beside.txt", b"C")
    run = _run({"a.txt": _sha(b"A"), str(tmp_path / "beside.txt"): _sha(b"C")})
    assert verify_run_files(lay, run) is run


@pytest.mark.parametrize("run", [None, [], {"files": {}}, {"run_id": "", "files": {}},
                                 {"run_id": "r", "files": []}, {"run_id": "r"}])
def test_verify_run_files_refuses_a_manifest_without_a_run_block(tmp_path, run):
    lay = _layout(tmp_path)
    with pytest.raises(FileFormatError) as err:
        verify_run_files(lay, run)
    assert str(err.value) == (f"{lay.manifest_path}: records no run id and checksums (written by an older "
                              "bodystudio or by hand); re-run the command that produced it")


def test_verify_run_files_refuses_a_missing_or_foreign_part(tmp_path):
    lay = _layout(tmp_path)
    _write(lay.root / "a.txt", b"A")
    _write(lay.root / "b.txt", b"B, of another run")
    (lay.root / "dir.txt").mkdir()
    with pytest.raises(FileFormatError) as err:
        verify_run_files(lay, _run({"a.txt": _sha(b"A"), "gone.txt": _sha(b"G")}))
    assert str(err.value) == (f"{lay.root / 'gone.txt'}: missing, but {lay.manifest_path} lists it (run r1); the "
                              "output is incomplete, re-run the command that produced it")
    with pytest.raises(FileFormatError, match="dir.txt: missing"):  # a folder in a file's place
        verify_run_files(lay, _run({"dir.txt": _sha(b"")}))
    with pytest.raises(FileFormatError) as err:
        verify_run_files(lay, _run({"a.txt": _sha(b"A"), "b.txt": _sha(b"B")}))
    assert str(err.value) == (f"{lay.root / 'b.txt'}: does not belong to run r1 of {lay.manifest_path} (sha256 "
                              "differs); the output mixes two runs or was edited, re-run the command that produced it")
    only = ("a.txt",)  # a reader of part of a run checks that part
    assert verify_run_files(lay, _run({"a.txt": _sha(b"A"), "b.txt": _sha(b"B"), "gone.txt": "0"}), only)
    with pytest.raises(FileFormatError, match="gone.txt: missing"):  # ... every file of that part
        verify_run_files(lay, _run({"b.txt": _sha(b"B"), "a.txt": _sha(b"A"), "gone.txt": "0"}), ("a.txt", "gone.txt"))


# ---------------------------------------------------------------------------------------------- RunWriter

def test_writer_publishes_a_whole_run_and_its_manifest_lists_every_file(tmp_path):
    lay = _layout(tmp_path)
    _write(lay.root / "old.ply", "old")
    _write(lay.root / "kept.ply", "old kept")
    producer = {"template": "2k"}
    with RunWriter(lay, "bodystudio test", producer) as w:
        producer["template"] = "changed after the start"
        assert w.producer == {"template": "2k"} and len(w.run_id) == 16 and int(w.run_id, 16) >= 0
        assert lay.lock.is_file() and lay.staging.is_dir() and not w.committed
        assert read_lock(lay.lock)["command"] == "bodystudio test"  # named to a second writer
        w.write_bytes("meshes/0.ply", b"M0")
        w.write_json("frames.json", {"f": [1]})
        w.write_bytes(tmp_path / "beside.txt", b"X")
        manifest = w.commit({"solver": "gs"}, deletes=["old.ply", "meshes/0.ply", "run.json"], indent=3)
        assert w.committed and not lay.lock.exists()
    run = manifest["run"]
    assert manifest["solver"] == "gs" and run["run_id"] == w.run_id and run["command"] == "bodystudio test"
    assert run["producer"] == {"template": "2k"}
    assert run["files"] == {"meshes/0.ply": _sha(b"M0"), "frames.json": _sha(b'{\n  "f": [\n    1\n  ]\n}\n'),
                            "../beside.txt": _sha(b"X")}
    assert lay.manifest_path.read_bytes() == (json.dumps(manifest, indent=3) + "\n").encode()
    assert (lay.root / "meshes/0.ply").read_bytes() == b"M0" and (tmp_path / "beside.txt").read_bytes() == b"X"
    assert not (lay.root / "old.ply").exists() and (lay.root / "kept.ply").read_text() == "old kept"
    assert _names(lay.root) == ["frames.json", "kept.ply", "meshes", "run.json"]
    assert verify_run_files(lay, json.loads(lay.manifest_path.read_text())["run"])


class _Killed(BaseException):
    """Stands for SIGKILL: nothing after it runs."""


def test_a_commit_killed_after_its_record_is_completed_by_recover_of_the_folder(tmp_path, monkeypatch):
    """The record names the manifest (``recover DIR`` finds a rig's layout without its manifest name) and holds
    numpy values of the manifest; recovered, the result is the one the writer would have published."""
    from bodystudio.rig.export import rig_layout

    glb = tmp_path / "out" / "a.glb"
    lay = rig_layout(glb)
    _write(glb, "previous")
    w = RunWriter(lay, "bodystudio rig")
    w.write_bytes(glb, b"glTF new")
    w.write_bytes(tmp_path / "out" / "a.tex.png", b"png")
    with monkeypatch.context() as m:
        m.setattr(rf, "apply_commit", lambda layout, plan: (_ for _ in ()).throw(_Killed()))
        with pytest.raises(_Killed):
            w.commit({"fit_err_mm": np.float64(1.5), "bones": np.arange(2)})
    rf.release_lock(lay)  # the killed process's lock is stale
    assert lay.commit_record.read_bytes().endswith(b"}\n")
    assert glb.read_text() == "previous"
    assert recover(tmp_path / "out") == [f"{glb}: completed the interrupted write (2 files)"]
    manifest = json.loads(lay.manifest_path.read_text())
    assert manifest["fit_err_mm"] == 1.5 and manifest["bones"] == [0, 1]
    assert glb.read_bytes() == b"glTF new" and verify_run_files(lay, manifest["run"])
    assert _names(tmp_path / "out") == ["a.glb", "a.rig.json", "a.tex.png"]


def test_writer_commit_default_indent_is_two(tmp_path):
    lay = _layout(tmp_path)
    with RunWriter(lay, "t") as w:
        w.write_bytes("a", b"A")
        manifest = w.commit({"k": 1})
    assert lay.manifest_path.read_bytes() == (json.dumps(manifest, indent=2) + "\n").encode()


def test_writer_commit_refuses_a_destination_folder_before_the_commit_point(tmp_path):
    lay = _layout(tmp_path)
    _write(lay.manifest_path, "previous")
    (lay.root / "a.txt").mkdir()
    with RunWriter(lay, "t") as w:
        w.write_bytes("a.txt", b"A")
        with pytest.raises(Exception, match="a.txt"):
            w.commit({"k": 1})
        assert not lay.commit_record.exists()
    assert lay.manifest_path.read_text() == "previous" and not lay.staging.exists() and not lay.lock.exists()


def test_writer_left_without_commit_keeps_the_previous_result(tmp_path):
    lay = _layout(tmp_path)
    _write(lay.manifest_path, "previous")
    with pytest.raises(KeyError), RunWriter(lay, "t") as w:
        w.write_bytes("a.txt", b"A")
        raise KeyError("stop")
    assert _names(lay.root) == ["run.json"] and w.committed
    w2 = RunWriter(lay, "t")  # free again
    w2.abort()
    assert _names(lay.root) == ["run.json"]


def test_a_first_run_that_fails_leaves_no_output_folder(tmp_path):
    lay = _layout(tmp_path)
    w = RunWriter(lay, "t")
    w.write_bytes("a", b"A")
    w.abort()
    assert not lay.root.exists()
    _write(lay.root / "x", "x")
    w = RunWriter(lay, "t")  # an existing folder is never removed
    w.abort()
    assert _names(lay.root) == ["x"]


@pytest.mark.parametrize("left", ["record", "staging"])
def test_writer_refuses_an_interrupted_write_and_releases_its_lock(tmp_path, left):
    lay = _layout(tmp_path)
    _write(lay.manifest_path, "previous")
    if left == "record":
        _record(lay, {"moves": []})
        msg = "OUT: a write was interrupted while committing; run `bodystudio recover OUT` to finish it"
    else:
        _write(lay.staging / "a", "A")
        msg = ("OUT: a previous write was interrupted before its commit; run `bodystudio recover OUT` first (the "
               "previous result stays)")
    with pytest.raises(OutputLockedError) as err:
        RunWriter(lay, "t")
    assert str(err.value) == msg
    assert not lay.lock.exists() and lay.manifest_path.read_text() == "previous"
    assert (lay.staging / "a").is_file() if left == "staging" else lay.commit_record.is_file()


def test_writer_refusal_in_a_new_folder_removes_that_folder(tmp_path, monkeypatch):
    lay = _layout(tmp_path)
    monkeypatch.setattr(rf, "remove_stale_staging", lambda layout: (_ for _ in ()).throw(OSError("boom")))
    with pytest.raises(OSError, match="boom"):
        RunWriter(lay, "t")
    assert not lay.root.exists()


def test_writer_tidies_stale_tombs_at_its_start(tmp_path):
    lay = _layout(tmp_path)
    _write(lay.root / ".staging.stale.3" / "f", "x")
    with RunWriter(lay, "t") as w:
        assert _names(lay.root) == [".lock", ".staging"]
        w.abort()


# ---------------------------------------------------------------------------------------------- locks

def test_read_lock_reads_only_a_holder_record(tmp_path):
    p = tmp_path / "lock"
    assert read_lock(p) is None
    for bad in ("", "{ garbage", "[1]", '{"pid": "12"}', '{"host": "h"}', '"x"'):
        p.write_text(bad)
        assert read_lock(p) is None, bad
    p.write_text('{"pid": 12, "host": "h"}')
    assert read_lock(p) == {"pid": 12, "host": "h"}
    (tmp_path / "dir").mkdir()
    assert read_lock(tmp_path / "dir") is None


def test_lock_is_stale(tmp_path):
    p = _write(tmp_path / "lock", "")
    assert lock_is_stale(None, tmp_path / "missing")
    assert not lock_is_stale(None, p)  # unreadable and fresh: being written
    old = time.time() - LOCK_GRACE_S - 2
    os.utime(p, (old, old))
    assert lock_is_stale(None, p)
    almost = time.time() - LOCK_GRACE_S + 3
    os.utime(p, (almost, almost))
    assert not lock_is_stale(None, p)
    live = _other_live()
    assert not lock_is_stale(live, p)
    assert not lock_is_stale({**live, "host": "another-host", "pid": _dead_pid()}, p)
    assert not lock_is_stale({k: v for k, v in live.items() if k != "host"} | {"host": None}, p)
    assert lock_is_stale({**live, "pid": _dead_pid()}, p)
    assert lock_is_stale({**live, "start": "1"}, p)  # the pid was reused
    assert not lock_is_stale({**live, "start": None}, p)  # an older lock without a start time
    assert not lock_is_stale({k: v for k, v in live.items() if k != "start"}, p)


def test_a_zombie_is_not_alive():
    import subprocess
    import sys

    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    for _ in range(200):
        time.sleep(0.01)
        if Path(f"/proc/{proc.pid}/stat").read_text().split(") ")[1].startswith("Z"):
            break
    assert not rf._process_alive(proc.pid) and rf._process_alive(os.getppid())
    proc.wait()
    assert not rf._process_alive(proc.pid)


def test_lock_holder(tmp_path):
    lay = _layout(tmp_path)
    assert lock_holder(lay) is None  # no folder, no lock
    live = _other_live()
    _write(lay.lock, json.dumps(live))
    assert lock_holder(lay) == live
    _write(lay.lock, json.dumps({**live, "pid": os.getpid(), "start": rf._process_start(os.getpid())}))
    assert lock_holder(lay) is None  # this process's own lock
    _write(lay.lock, json.dumps({**live, "pid": os.getpid(), "host": "another-host"}))
    assert lock_holder(lay)["host"] == "another-host"  # the same pid on another machine is another process
    _write(lay.lock, json.dumps({**live, "pid": _dead_pid()}))
    assert lock_holder(lay) is None
    _write(lay.lock, "")  # being written by a starting writer
    assert lock_holder(lay) == {"pid": "?", "host": "?", "command": "unknown command", "since": "just now"}


def _utc_now() -> str:
    """Now in UTC, in the lock's ``since`` format."""
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())


def test_acquire_lock_records_this_process_and_release_removes_only_its_own(tmp_path):
    lay = _layout(tmp_path)
    before = _utc_now()
    acquire_lock(lay, "bodystudio x")
    after = _utc_now()
    holder = read_lock(lay.lock)
    assert set(holder) == {"pid", "host", "start", "command", "since"}
    assert (holder["pid"], holder["host"], holder["command"]) == (os.getpid(), HOST, "bodystudio x")
    assert holder["start"] == rf._process_start(os.getpid()) is not None
    assert before <= holder["since"] <= after  # the acquisition's UTC time, to the second (ISO strings sort as times)
    assert lay.lock.read_text().endswith("}\n")
    umask = os.umask(0)
    os.umask(umask)
    assert lay.lock.stat().st_mode & 0o777 == 0o644 & ~umask  # a plain file others can read to name the writer
    with pytest.raises(OutputLockedError, match="being written by pid"):  # not re-entrant: a second writer
        acquire_lock(lay, "again")
    rf.release_lock(lay)
    assert not lay.lock.exists()
    _write(lay.lock, json.dumps(_other_live()))
    rf.release_lock(lay)  # another process's lock stays
    assert lay.lock.exists()


def test_acquire_lock_since_is_utc_whatever_the_time_zone(tmp_path, monkeypatch):
    monkeypatch.setenv("TZ", "Asia/Kolkata")  # +05:30
    time.tzset()
    try:
        lay = _layout(tmp_path)
        before = _utc_now()
        acquire_lock(lay, "t")
        after = _utc_now()
        assert before <= read_lock(lay.lock)["since"] <= after  # local time would read 5 h 30 min later
    finally:
        monkeypatch.delenv("TZ")
        time.tzset()


def test_acquire_lock_refuses_a_live_writer_with_one_line(tmp_path):
    lay = _layout(tmp_path)
    _write(lay.lock, json.dumps(_other_live("bodystudio calibrate")))
    with pytest.raises(OutputLockedError) as err:
        acquire_lock(lay, "t")
    assert str(err.value) == (f"OUT: being written by pid {os.getppid()} on {HOST} (bodystudio calibrate, since "
                              "2026-01-01T00:00:00Z); wait for it to finish or run `bodystudio recover OUT`")
    _write(lay.lock, json.dumps({**_other_live("c"), "host": "farm-7"}))
    with pytest.raises(OutputLockedError) as err:
        acquire_lock(lay, "t")
    assert str(err.value) == (f"OUT: being written by pid {os.getppid()} on farm-7 (c, since 2026-01-01T00:00:00Z); "
                              f"wait for it to finish (if that process is gone, delete {lay.lock})")
    _write(lay.lock, "")  # fresh and unreadable: a writer starting right now
    with pytest.raises(OutputLockedError) as err:
        acquire_lock(lay, "t")
    assert str(err.value) == ("OUT: being written by pid ? on ? (unknown command, since just now); wait for it to "
                              f"finish (if that process is gone, delete {lay.lock})")


def test_acquire_lock_takes_over_a_stale_lock(tmp_path, caplog):
    lay = _layout(tmp_path)
    _write(lay.lock, json.dumps({"pid": _dead_pid(), "host": HOST, "command": "killed cmd"}))
    with caplog.at_level(logging.WARNING, logger="bodystudio.runfolder"):
        acquire_lock(lay, "mine")
    assert read_lock(lay.lock)["command"] == "mine" and _names(lay.root) == [".lock"]
    assert caplog.messages == [f"OUT: taking over the stale lock of pid {_dead_pid()} (killed cmd)"]
    caplog.clear()
    _write(lay.lock, "")
    old = time.time() - 100
    os.utime(lay.lock, (old, old))
    with caplog.at_level(logging.WARNING, logger="bodystudio.runfolder"):
        acquire_lock(lay, "mine")
    assert caplog.messages == ["OUT: taking over the stale lock of pid ? (unreadable)"]
    assert _names(lay.root) == [".lock"]


def test_acquire_lock_gives_up_when_another_writer_keeps_taking_it(tmp_path, monkeypatch):
    lay = _layout(tmp_path)
    attempts = []
    real_open = os.open

    def always_there(path, flags, *a):
        if Path(path) == lay.lock:
            attempts.append(1)
            raise FileExistsError(errno.EEXIST, "exists")
        return real_open(path, flags, *a)

    monkeypatch.setattr(rf.os, "open", always_there)
    monkeypatch.setattr(rf, "read_lock", lambda p: None)
    monkeypatch.setattr(rf, "lock_is_stale", lambda h, p: True)
    with pytest.raises(OutputLockedError) as err:
        acquire_lock(lay, "t")
    assert str(err.value) == (f"OUT: could not take the lock {lay.lock}; another writer keeps taking it, retry when "
                              "it is done")
    assert len(attempts) == 3


def test_acquire_lock_refuses_bad_output_places(tmp_path, monkeypatch):
    _write(tmp_path / "file", "x")
    with pytest.raises(FileFormatError) as err:
        acquire_lock(RunLayout(tmp_path / "file", "m", ".", "F"), "t")
    assert str(err.value) == f"{tmp_path / 'file'}: is a file, not a folder; choose another output path"
    with pytest.raises(FileFormatError) as err:
        acquire_lock(RunLayout(tmp_path / "file" / "sub", "m", ".", "F"), "t")
    assert str(err.value).startswith(f"{tmp_path / 'file' / 'sub'}: cannot create the output folder (")
    assert str(err.value).endswith("); choose another output path")
    lay = _layout(tmp_path)
    real_open = os.open

    def denied(path, flags, *a):
        if Path(path) == lay.lock:
            raise PermissionError(errno.EACCES, "denied")
        return real_open(path, flags, *a)

    monkeypatch.setattr(rf.os, "open", denied)
    with pytest.raises(FileFormatError) as err:
        acquire_lock(lay, "t")
    assert str(err.value) == f"{lay.root}: not writable, cannot write OUT there; choose another output path"


@pytest.mark.parametrize("where", ["open", "write"])
def test_acquire_lock_on_a_full_disk_leaves_no_lock_and_no_new_folder(tmp_path, monkeypatch, where):
    lay = _layout(tmp_path)
    real_open, real_fsync = os.open, os.fsync

    def full_open(path, flags, *a):
        if Path(path) == lay.lock:
            raise OSError(errno.ENOSPC, "No space left on device")
        return real_open(path, flags, *a)

    def full_fsync(fd):
        raise OSError(errno.ENOSPC, "No space left on device")

    if where == "open":
        monkeypatch.setattr(rf.os, "open", full_open)
    else:
        monkeypatch.setattr(rf.os, "fsync", full_fsync)
    with pytest.raises(OutputSpaceError) as err:
        acquire_lock(lay, "t")
    assert str(err.value).startswith(f"{lay.lock}: No space left on device while writing it;")
    assert not lay.root.exists()
    monkeypatch.setattr(rf.os, "open", real_open)
    monkeypatch.setattr(rf.os, "fsync", real_fsync)
    _write(lay.root / "x", "x")  # an existing folder stays
    monkeypatch.setattr(rf.os, "open" if where == "open" else "fsync", full_open if where == "open" else full_fsync)
    with pytest.raises(OutputSpaceError):
        acquire_lock(lay, "t")
    assert _names(lay.root) == ["x"]


@pytest.mark.parametrize("where", ["open", "write"])
def test_acquire_lock_on_a_full_disk_without_a_reason_and_a_folder_that_will_not_go(tmp_path, monkeypatch, where):
    lay = _layout(tmp_path)
    real_open = os.open
    bare = OSError()
    bare.errno = errno.ENOSPC  # an errno and no strerror (some FUSE file systems)

    def full_open(path, flags, *a):
        if Path(path) == lay.lock:
            raise bare
        return real_open(path, flags, *a)

    if where == "open":
        monkeypatch.setattr(rf.os, "open", full_open)
    else:
        monkeypatch.setattr(rf.os, "fsync", lambda fd: (_ for _ in ()).throw(bare))
    monkeypatch.setattr(Path, "rmdir", lambda self: (_ for _ in ()).throw(OSError(errno.ENOTEMPTY, "not empty")))
    with pytest.raises(OutputSpaceError) as err:
        acquire_lock(lay, "t")
    assert str(err.value).startswith(f"{lay.lock}: no space left on device while writing it;")


@pytest.mark.parametrize("where", ["open", "write"])
def test_acquire_lock_passes_on_other_errors(tmp_path, monkeypatch, where):
    lay = _layout(tmp_path)
    real_open = os.open

    def io_error(path, flags, *a):
        if Path(path) == lay.lock:
            raise OSError(errno.EIO, "I/O error")
        return real_open(path, flags, *a)

    if where == "open":
        monkeypatch.setattr(rf.os, "open", io_error)
    else:
        monkeypatch.setattr(rf.os, "fsync", lambda fd: (_ for _ in ()).throw(OSError(errno.EIO, "I/O error")))
    with pytest.raises(OSError) as err:
        acquire_lock(lay, "t")
    assert err.value.errno == errno.EIO and not isinstance(err.value, OutputSpaceError)
    assert not lay.lock.exists()


def test_acquire_lock_refuses_while_others_read_and_leaves_no_lock(tmp_path):
    lay = _layout(tmp_path)
    _write(lay.readers / "a.1.1", json.dumps(_other_live("bodystudio view", "S1")))
    with pytest.raises(OutputLockedError) as err:
        acquire_lock(lay, "t")
    assert str(err.value) == f"OUT: being read by pid {os.getppid()} (bodystudio view, since S1); wait for it to finish"
    assert not lay.lock.exists()
    _write(lay.readers / "b.1.2", json.dumps(_other_live("bodystudio eval", "S2")))
    with pytest.raises(OutputLockedError) as err:
        acquire_lock(lay, "t")
    assert "and 1 more (" in str(err.value)
    assert not lay.lock.exists()


def test_live_readers(tmp_path):
    lay = _layout(tmp_path)
    assert live_readers(lay) == []  # no readers folder
    live = _other_live("bodystudio view")
    _write(lay.readers / "a", json.dumps(live))
    _write(lay.readers / ".tmp-being-written", "")  # atomic_write's temporary file
    _write(lay.readers / "dead", json.dumps({**live, "pid": _dead_pid()}))
    _write(lay.readers / "mine", json.dumps({**live, "pid": os.getpid(), "start": rf._process_start(os.getpid())}))
    _write(lay.readers / "mine-elsewhere", json.dumps({**live, "pid": os.getpid(), "host": "farm-2"}))
    _write(lay.readers / "starting", "")
    out = live_readers(lay)
    assert sorted(map(json.dumps, out)) == sorted(map(json.dumps, [
        live, {**live, "pid": os.getpid(), "host": "farm-2"},
        {"pid": "?", "command": "a reader starting", "since": "just now"}]))
    assert _names(lay.readers) == [".tmp-being-written", "a", "mine", "mine-elsewhere", "starting"]  # dead one gone


def test_two_writers_clearing_the_same_dead_reader(tmp_path, monkeypatch):
    """Another writer removes the dead reader's file between this one's read and its delete."""
    lay = _layout(tmp_path)
    _write(lay.readers / "dead", json.dumps({"pid": _dead_pid(), "host": HOST, "command": "killed"}))
    real = rf.read_lock

    def read_then_gone(path):
        holder = real(path)
        path.unlink()
        return holder

    monkeypatch.setattr(rf, "read_lock", read_then_gone)
    assert live_readers(lay) == []


def test_a_reader_whose_registration_was_deleted_by_hand_ends_cleanly(tmp_path):
    lay = _layout(tmp_path)
    lay.root.mkdir()
    lock = ReadLock(lay, "t")
    shutil.rmtree(lay.readers)
    lock.release()
    assert lock.path is None


def test_read_lock_registers_and_releases(tmp_path):
    lay = _layout(tmp_path)
    assert ReadLock(lay, "t").path is None and not lay.root.exists()  # nothing to read: no registration
    lay.root.mkdir()
    n = ReadLock._count
    with ReadLock(lay, "bodystudio view") as lock:
        assert lock.path == lay.readers / f"{HOST}.{os.getpid()}.{n + 1}"
        rec = json.loads(lock.path.read_text())
        assert (rec["pid"], rec["host"], rec["command"]) == (os.getpid(), HOST, "bodystudio view")
        with ReadLock(lay, "second") as second:
            assert second.path.name == f"{HOST}.{os.getpid()}.{n + 2}"
        assert lock.path.is_file() and not second.path  # the second released, the first held
        assert live_readers(lay) == []  # this process's own
    assert not lay.readers.exists() and lock.path is None
    lock.release()  # twice: nothing


def test_read_lock_refuses_a_live_writer_and_unregisters(tmp_path):
    lay = _layout(tmp_path)
    _write(lay.lock, json.dumps(_other_live("bodystudio rig")))
    with pytest.raises(OutputLockedError, match=f"OUT: being written by pid {os.getppid()} on {HOST} "):
        ReadLock(lay, "t")
    assert not lay.readers.exists()


def test_read_lock_in_a_read_only_folder_reads(tmp_path, monkeypatch):
    lay = _layout(tmp_path)
    lay.root.mkdir()
    monkeypatch.setattr(Path, "mkdir", lambda self, *a, **kw: (_ for _ in ()).throw(PermissionError(13, "ro")))
    lock = ReadLock(lay, "t")
    assert lock.path is None
    lock.release()


def test_read_lock_release_keeps_a_readers_folder_others_use(tmp_path):
    lay = _layout(tmp_path)
    _write(lay.readers / "other", json.dumps(_other_live()))
    lock = ReadLock(lay, "t")
    lock.release()
    assert _names(lay.readers) == ["other"]


def test_hold_read_lock_inside_and_outside_a_command(tmp_path):
    lay = _layout(tmp_path)
    lay.root.mkdir()
    assert hold_read_lock(lay) is None and not lay.readers.exists()  # library use: no registration
    with command_read_locks():
        lock = hold_read_lock(lay, "bodystudio eval")
        assert json.loads(lock.path.read_text())["command"] == "bodystudio eval"
        with command_read_locks():  # nested: the outer command keeps its locks
            hold_read_lock(lay)
        assert len(rf._HELD) == 2 and lock.path.is_file()
    assert rf._HELD == [] and not lay.readers.exists()
    _write(lay.lock, json.dumps(_other_live("w")))
    with pytest.raises(OutputLockedError, match="being written by pid"):
        hold_read_lock(lay)


def test_release_read_locks_releases_all(tmp_path):
    lay = _layout(tmp_path)
    lay.root.mkdir()
    rf._HOLDING[0] = True
    try:
        locks = [hold_read_lock(lay, "c") for _ in range(3)]
    finally:
        rf._HOLDING[0] = False
    assert len(_names(lay.readers)) == 3
    release_read_locks()
    assert rf._HELD == [] and all(lock.path is None for lock in locks) and not lay.readers.exists()
