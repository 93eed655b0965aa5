"""Shared read locks (issue 16): a reader of a folder a live process is writing is refused at its start with
one line naming the writer, and a writer is refused while another process reads -- tested with a real
second process. A killed reader blocks nobody."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from bodystudio.capture.session import SessionWriter, open_session, session_layout
from bodystudio.errors import SessionError
from bodystudio.runfolder import live_readers

from .conftest import CODE_ROOT, Studio, assert_clean_error, cli_env, run_inprocess

READER = """
import sys
from bodystudio.capture.session import open_session
from bodystudio.runfolder import command_read_locks
with command_read_locks():  # what every CLI command runs in
    s = open_session(sys.argv[1])
    print("ready", flush=True)
    sys.stdin.read()
"""

WRITER = """
import sys
from bodystudio.capture.session import SessionWriter
with SessionWriter(sys.argv[1], update=True, command="bodystudio capture silhouettes") as w:
    print("ready", flush=True)
    sys.stdin.read()
"""


def _start(code: str, session: Path) -> subprocess.Popen:
    proc = subprocess.Popen([sys.executable, "-c", code, str(session)], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True, env=cli_env(), cwd=CODE_ROOT)
    assert proc.stdout.readline().strip() == "ready"
    return proc


def _stop(proc: subprocess.Popen) -> None:
    proc.stdin.close()
    assert proc.wait(timeout=30) == 0


@pytest.fixture
def session(studio: Studio, tmp_path: Path) -> Path:
    return Path(shutil.copytree(studio.session, tmp_path / "S"))


def test_writer_is_refused_while_another_process_reads(session, capfd):
    reader = _start(READER, session)
    try:
        res = run_inprocess(["capture", "silhouettes", str(session)], capfd)
        assert_clean_error(res, 2, f"being read by pid {reader.pid}")
        with pytest.raises(SessionError, match=f"being read by pid {reader.pid}"):
            SessionWriter(session, update=True, command="test")
    finally:
        _stop(reader)
    assert not live_readers(session_layout(session))  # released at the reader's exit
    with SessionWriter(session, update=True, command="test"):  # free again
        pass


def test_reader_is_refused_at_its_start_while_another_process_writes(session, capfd):
    writer = _start(WRITER, session)
    try:
        for args in (["reconstruct", str(session)], ["capture", "verify", str(session)],
                     ["eval", "silhouettes", str(session)]):
            res = run_inprocess(args, capfd)
            assert_clean_error(res, 2, f"being written by pid {writer.pid} on")
            assert "(bodystudio capture silhouettes" in res.stderr and "bodystudio recover" in res.stderr
        assert not (session / "reconstruct").exists()
    finally:
        _stop(writer)
    open_session(session)  # readable again


def test_a_killed_reader_blocks_no_writer(session):
    reader = _start(READER, session)
    os.kill(reader.pid, signal.SIGKILL)
    reader.wait(timeout=30)
    assert any(session_layout(session).readers.iterdir())  # its registration is left behind
    with SessionWriter(session, update=True, command="test"):  # ... but names a dead pid
        pass
    assert not live_readers(session_layout(session))


def test_read_locks_end_with_the_command(session, capfd):
    res = run_inprocess(["capture", "verify", str(session)], capfd)
    assert res.rc == 0, res.stderr
    assert not session_layout(session).readers.exists()


def test_library_reads_outside_a_command_hold_no_lock(session):
    """A notebook or test that keeps a session open does not block writers of other processes; it still
    meets a live writer at its start."""
    s = open_session(session)
    assert not session_layout(session).readers.exists()
    assert s.frame_ids
