"""A writer killed while deleting its staging folder, after the manifest was written, leaves a complete result.

CI of stop 30: a batch client was killed while a chunk's worker was deleting its staging folder; the folder
survived empty beside the complete ``unit.json``, read as an interrupted write, and the re-run redid that
chunk (tests/batch/test_batch_reconstruct.py::test_killed_client_rerun_redoes_nothing_done). The staging
folder now disappears in one rename before it is deleted; a killed delete leaves only a ``.stale.`` folder
that the next writer (or ``bodystudio recover``) removes.
"""

from __future__ import annotations

import json
import os
import shutil
import socket
from pathlib import Path

import pytest

from bodystudio.batch import _UnitWriter, unit_is_complete, unit_layout
from bodystudio.runfolder import RunLayout, RunWriter, check_readable, recover, release_lock


class _Killed(BaseException):
    """Stands for SIGKILL: nothing after it runs."""


def _rmtree_killed_halfway(monkeypatch):
    """``shutil.rmtree`` that deletes the files of an existing folder, then dies (the folder stays)."""
    real = shutil.rmtree

    def fake(path, ignore_errors=False, **kw):
        p = Path(path)
        if not p.exists():
            return real(path, ignore_errors=ignore_errors, **kw)
        for f in sorted(p.rglob("*"), reverse=True):
            if f.is_file():
                f.unlink()
        raise _Killed

    monkeypatch.setattr(shutil, "rmtree", fake)


def _commit_killed_in_cleanup(monkeypatch, writer: RunWriter, manifest: dict) -> None:
    with monkeypatch.context() as m:
        _rmtree_killed_halfway(m)
        with pytest.raises(_Killed):
            writer.commit(manifest)
    release_lock(writer.layout)  # the killed process's lock is stale


def _stale(root: Path) -> list[str]:
    return sorted(p.name for p in root.iterdir() if ".stale." in p.name)


def test_killed_cleanup_leaves_a_readable_result_and_the_next_writer_tidies(monkeypatch, tmp_path):
    layout = RunLayout(tmp_path / "out", "run.json", ".", "out")
    w = RunWriter(layout, "test")
    w.write_bytes("a.txt", b"first")
    _commit_killed_in_cleanup(monkeypatch, w, {"n": 1})
    assert layout.manifest_path.is_file() and (layout.root / "a.txt").read_bytes() == b"first"
    assert not layout.staging.exists()
    assert check_readable(layout) is None  # no "interrupted write" note: the result is complete
    assert _stale(layout.root) == [f".staging.stale.{os.getpid()}"]
    with RunWriter(layout, "test") as w2:
        w2.write_bytes("a.txt", b"second")
        w2.commit({"n": 2})
    assert _stale(layout.root) == [] and (layout.root / "a.txt").read_bytes() == b"second"


def test_recover_removes_a_stale_leftover(monkeypatch, tmp_path):
    layout = RunLayout(tmp_path / "out", "run.json", ".", str(tmp_path / "out"))
    w = RunWriter(layout, "test")
    w.write_bytes("a.txt", b"x")
    _commit_killed_in_cleanup(monkeypatch, w, {})
    assert _stale(layout.root)
    assert recover(layout.root) == [f"{layout.root}: removed the leftover of a finished write"]
    assert _stale(layout.root) == [] and (layout.root / "a.txt").read_bytes() == b"x"
    assert recover(layout.root) == [f"{layout.root}: nothing to recover"]


def test_batch_unit_killed_in_cleanup_is_skipped(monkeypatch, tmp_path):
    layout = unit_layout(tmp_path / "chunks" / "00000-00001")
    w = _UnitWriter(layout, "bodystudio reconstruct (batch unit)", {}, {"inputs_sha256": "abc"})
    w.write_bytes("meshes/00000.ply", b"ply")
    _commit_killed_in_cleanup(monkeypatch, w, {"frames": [0, 1]})
    assert unit_is_complete(layout, "abc")
    assert not unit_is_complete(layout, "another input")


def test_batch_unit_killed_past_its_commit_point_is_finished_not_redone(monkeypatch, tmp_path):
    """Killed after the commit record, before any move: the client's check finishes the write (a skip)."""
    import bodystudio.runfolder as runfolder

    layout = unit_layout(tmp_path / "chunks" / "00000-00001")
    w = _UnitWriter(layout, "bodystudio reconstruct (batch unit)", {}, {"inputs_sha256": "abc"})
    w.write_bytes("meshes/00000.ply", b"ply")

    def killed(*a, **kw):
        raise _Killed

    with monkeypatch.context() as m:
        m.setattr(runfolder, "apply_commit", killed)
        with pytest.raises(_Killed):
            w.commit({"frames": [0, 1]})
    assert layout.commit_record.is_file() and not layout.manifest_path.exists()
    worker = {"pid": os.getppid(), "host": socket.gethostname(), "start": runfolder._process_start(os.getppid()),
              "command": "bodystudio reconstruct (batch unit)", "since": "now"}
    layout.lock.write_text(json.dumps(worker))  # a live worker (another process) still holds the unit
    assert not unit_is_complete(layout, "abc")
    assert layout.commit_record.is_file() and not layout.manifest_path.exists()  # not touched
    layout.lock.unlink()  # the worker dies (its lock stale or gone)
    assert unit_is_complete(layout, "abc")
    assert not layout.staging.exists() and (layout.root / "meshes" / "00000.ply").read_bytes() == b"ply"
