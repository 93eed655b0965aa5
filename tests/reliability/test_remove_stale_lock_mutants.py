"""Mutation tests of rel5b's ``runfolder.remove_stale_lock`` (docs/mutation/runfolder.md, "rel5b's compare-and-remove"):
an unreadable (empty) lock judged by its age on the renamed file, the warning's whole line, and a file system
without hard links (``os.link`` raising OSError: the renamed live lock goes back by rename unless a lock was created
meanwhile). No process spawned; "a live process" is this process's parent (< 0.1 s)."""
from __future__ import annotations

import json
import logging
import os
import socket
import time

import bodystudio.runfolder as rf
from bodystudio.runfolder import remove_stale_lock

HOST = socket.gethostname()


def _live(command: str) -> bytes:
    pid = os.getppid()
    return json.dumps({"pid": pid, "host": HOST, "start": rf._process_start(pid), "command": command}).encode()


def _leftovers(root) -> list[str]:
    return sorted(p.name for p in root.iterdir() if ".stale." in p.name)


def test_an_unreadable_lock_is_judged_by_the_age_of_the_renamed_file(tmp_path):
    lock = tmp_path / ".lock"
    lock.write_bytes(b"")  # a writer between its O_EXCL and writing its info
    assert remove_stale_lock(lock) is False and lock.read_bytes() == b"" and not _leftovers(tmp_path)
    old = time.time() - rf.LOCK_GRACE_S - 5.0
    os.utime(lock, (old, old))
    assert remove_stale_lock(lock) is True and not lock.exists() and not _leftovers(tmp_path)


def test_the_warning_names_the_lock_and_the_live_pid_or_a_question_mark(tmp_path, monkeypatch, caplog):
    lock = tmp_path / ".lock"
    real = rf.read_lock
    third = _live("third")

    def third_writer(path):
        lock.write_bytes(third)
        return real(path)

    monkeypatch.setattr(rf, "read_lock", third_writer)
    for content, pid in ((_live("second"), str(os.getppid())), (b"", "?")):
        lock.write_bytes(content)
        caplog.clear()
        with caplog.at_level(logging.WARNING, logger="bodystudio.runfolder"):
            assert remove_stale_lock(lock) is False
        assert lock.read_bytes() == third and not _leftovers(tmp_path)
        assert [r.getMessage() for r in caplog.records] == [
            f"{lock}: a lock renamed as stale was live (pid {pid}) and another lock was taken meanwhile"]


def test_without_hard_links_a_live_lock_goes_back_by_rename_unless_one_was_taken(tmp_path, monkeypatch):
    lock = tmp_path / ".lock"

    def no_link(src, dst):
        raise OSError(95, "Operation not supported")

    monkeypatch.setattr(rf.os, "link", no_link)
    live = _live("writer")
    lock.write_bytes(live)
    assert remove_stale_lock(lock) is False and lock.read_bytes() == live and not _leftovers(tmp_path)
    real = rf.read_lock
    third = _live("third")

    def third_writer(path):
        lock.write_bytes(third)
        return real(path)

    monkeypatch.setattr(rf, "read_lock", third_writer)
    lock.write_bytes(live)
    assert remove_stale_lock(lock) is False and lock.read_bytes() == third and not _leftovers(tmp_path)
