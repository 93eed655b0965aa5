"""Mutation tests of ``runfolder._process_alive`` and ``_process_start`` (docs/mutation/runfolder.md, "mutBB: the
whole module"): who holds a lock is decided by these two, a wrong answer takes a live writer's lock over (two
writers in one folder) or keeps a dead one's forever.

"A live process" here is a child this file starts (``sleep``), never this process's parent: a mutant of
``os.kill(pid, 0)`` that sends a real signal (``os.kill(pid, 1)``: SIGHUP) killed the mutation tool itself when
the other test files used the parent as the live process. The child must still be alive after being asked about.
The start time is checked against psutil's own reading of the process's creation (an independent parser of
``/proc/PID/stat``, in seconds since boot) on a child whose command name holds ``)`` and spaces. < 1 s.
"""
from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import psutil
import pytest

import bodystudio.runfolder as rf

DEAD = 4_000_000  # above Linux's pid_max (2^22): never a live process
TICKS = os.sysconf("SC_CLK_TCK")


@pytest.fixture(scope="module")
def child():
    """A live child whose command name (``comm``) is ``a) Z 1 (b``: an rfind of ")" finds the real end."""
    code = ("import sys, time; open('/proc/self/comm', 'w').write('a) Z 1 (b'); sys.stdout.write('ok\\n'); "
            "sys.stdout.flush(); time.sleep(120)")
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE)
    assert proc.stdout.readline() == b"ok\n"
    yield proc
    proc.kill()
    proc.wait()


def _still_running(proc: subprocess.Popen) -> bool:
    try:
        proc.wait(timeout=0.2)
    except subprocess.TimeoutExpired:
        return True
    return False


def test_a_live_child_is_alive_and_asking_sends_it_no_signal(child):
    assert Path(f"/proc/{child.pid}/comm").read_text() == "a) Z 1 (b\n"
    assert rf._process_alive(child.pid) is True
    assert _still_running(child)  # os.kill(pid, 1) would have hung it up


def test_a_dead_pid_and_a_zombie_are_not_alive():
    assert rf._process_alive(DEAD) is False
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    for _ in range(300):
        time.sleep(0.01)
        if psutil.Process(proc.pid).status() == psutil.STATUS_ZOMBIE:
            break
    assert psutil.Process(proc.pid).status() == psutil.STATUS_ZOMBIE
    assert rf._process_alive(proc.pid) is False
    proc.wait()
    assert rf._process_alive(proc.pid) is False


def test_another_users_process_is_alive(monkeypatch):
    """``kill(pid, 0)`` on another user's process is refused (EPERM): it exists."""
    def refused(pid, sig):
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(rf.os, "kill", refused)
    assert rf._process_alive(DEAD) is True


def test_a_process_gone_between_the_signal_and_the_read_counts_as_alive(monkeypatch):
    """The signal found it, ``/proc`` no longer has it (it exited meanwhile): alive, the next look sees it gone."""
    monkeypatch.setattr(rf.os, "kill", lambda pid, sig: None)
    assert not Path(f"/proc/{DEAD}").exists()
    assert rf._process_alive(DEAD) is True


def test_process_start_is_the_kernels_start_time_in_ticks(child):
    start = rf._process_start(child.pid)
    assert isinstance(start, str) and start.isdigit()
    expected = (psutil.Process(child.pid).create_time() - psutil.boot_time()) * TICKS
    assert abs(int(start) - expected) <= 1.5, (start, expected)
    own = rf._process_start(os.getpid())
    assert abs(int(own) - (psutil.Process().create_time() - psutil.boot_time()) * TICKS) <= 1.5
    assert int(own) < int(start)  # this process started before its child
    assert rf._process_start(DEAD) is None


def test_process_start_of_a_short_stat_line_is_none(monkeypatch):
    """A ``stat`` line with fewer than 20 fields after the name (not Linux's): no start time, not an IndexError."""
    line = "7 (x) " + " ".join(str(i) for i in range(19))
    monkeypatch.setattr(rf.Path, "read_text", lambda self, *a, **k: line)
    assert rf._process_start(7) is None
    monkeypatch.setattr(rf.Path, "read_text", lambda self, *a, **k: line + " 19")
    assert rf._process_start(7) == "19"
