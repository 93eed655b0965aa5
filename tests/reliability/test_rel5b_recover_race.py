"""``recover`` and a writer taking a stale lock over at the same moment (reliability round rel5b).

``recover_layout`` read the lock as stale (``lock_holder``) and at its end unlinked whatever lock file was there
without reading it again (mutV's note in docs/MUTATION.md): a writer that took the stale lock over in between lost
its lock while it wrote, and a third writer could then start beside it. ``acquire_lock``'s own takeover renamed the
lock to ``<lock>.stale.<pid>`` and unlinked the renamed file unread: the same race between two writers taking one
stale lock over. Both now go through ``runfolder.remove_stale_lock``: rename, read what was renamed, remove it only
when it is still stale, else put it back. The races are planted by a ``read_lock`` that lets "another writer" take
the lock right after the stale reading; "another live process" is this process's parent (no process spawned).
"""

from __future__ import annotations

import json
import logging
import os
import socket

import pytest

import bodystudio.runfolder as rf
from bodystudio.runfolder import OutputLockedError, RunLayout, acquire_lock, recover_layout, remove_stale_lock

HOST = socket.gethostname()
DEAD_PID = 4_000_000  # above Linux's pid_max (2^22): never a live process


def _layout(tmp_path) -> RunLayout:
    root = tmp_path / "out"
    root.mkdir()
    return RunLayout(root, "run.json", ".", "OUT")


def _live(command: str) -> bytes:
    pid = os.getppid()
    return json.dumps({"pid": pid, "host": HOST, "start": rf._process_start(pid), "command": command,
                       "since": "2026-01-01T00:00:00Z"}).encode()


STALE = json.dumps({"pid": DEAD_PID, "host": HOST, "command": "killed"}).encode()


def _taken_over_after_first_read(monkeypatch, lock, live: bytes):
    """``read_lock``: its first call reads the stale lock, then another writer takes the lock over (writes its own);
    later calls read the file as it is."""
    real = rf.read_lock
    calls = []

    def racing(path):
        holder = real(path)
        if not calls:
            lock.write_bytes(live)  # the second writer's O_EXCL after the stale lock's removal, its info written
        calls.append(path)
        return holder

    monkeypatch.setattr(rf, "read_lock", racing)
    return calls


def _no_leftovers(root) -> bool:
    return not any(".stale." in p.name for p in root.iterdir())


def test_recover_leaves_a_lock_a_writer_took_over_after_the_stale_check(tmp_path, monkeypatch):
    lay = _layout(tmp_path)
    (lay.root / "run.json").write_text("result")
    lay.lock.write_bytes(STALE)
    live = _live("bodystudio reconstruct")
    calls = _taken_over_after_first_read(monkeypatch, lay.lock, live)
    assert recover_layout(lay) is None  # nothing was removed: the lock is the live writer's now
    assert len(calls) >= 2  # the lock was read again before its removal
    assert lay.lock.read_bytes() == live and _no_leftovers(lay.root)
    with pytest.raises(OutputLockedError, match=f"being written by pid {os.getppid()}"):
        acquire_lock(lay, "a third writer")  # ... and it still keeps a third writer out


def test_recover_still_removes_a_lock_that_stays_stale(tmp_path):
    lay = _layout(tmp_path)
    (lay.root / "run.json").write_text("result")
    lay.lock.write_bytes(STALE)
    assert recover_layout(lay) == "removed a stale lock"
    assert sorted(p.name for p in lay.root.iterdir()) == ["run.json"]


def test_two_writers_taking_one_stale_lock_over_do_not_both_write(tmp_path, monkeypatch):
    """The first writer takes the stale lock over between the second's stale reading and its rename: the second
    renamed the first's live lock and unlinked it, then took the lock itself (two writers). It is now refused."""
    lay = _layout(tmp_path)
    lay.lock.write_bytes(STALE)
    live = _live("bodystudio calibrate")
    _taken_over_after_first_read(monkeypatch, lay.lock, live)
    with pytest.raises(OutputLockedError) as err:
        acquire_lock(lay, "second writer")
    assert str(err.value).startswith(f"OUT: being written by pid {os.getppid()} on {HOST} (bodystudio calibrate")
    assert lay.lock.read_bytes() == live and _no_leftovers(lay.root)


def test_remove_stale_lock_compares_what_it_renamed(tmp_path, monkeypatch, caplog):
    lay = _layout(tmp_path)
    assert remove_stale_lock(lay.lock) is False  # none there
    lay.lock.write_bytes(STALE)
    assert remove_stale_lock(lay.lock) is True and not lay.lock.exists()
    live = _live("w")
    lay.lock.write_bytes(live)
    assert remove_stale_lock(lay.lock) is False and lay.lock.read_bytes() == live  # live: put back, same bytes
    mine = json.dumps({"pid": os.getpid(), "host": HOST, "start": rf._process_start(os.getpid()),
                       "command": "me"}).encode()
    lay.lock.write_bytes(mine)
    assert remove_stale_lock(lay.lock) is False and lay.lock.read_bytes() == mine  # a writer's own lock is live
    assert remove_stale_lock(lay.lock, own_is_stale=True) is True  # ... but not to recover in this process
    # a live lock renamed while a third writer creates a new one: the third's stays, the renamed copy goes
    lay.lock.write_bytes(live)
    third = _live("third")
    real = rf.read_lock

    def third_writer(path):
        lay.lock.write_bytes(third)
        return real(path)

    monkeypatch.setattr(rf, "read_lock", third_writer)
    with caplog.at_level(logging.WARNING, logger="bodystudio.runfolder"):
        assert remove_stale_lock(lay.lock) is False
    assert lay.lock.read_bytes() == third and _no_leftovers(lay.root)
    assert "was live" in caplog.text
