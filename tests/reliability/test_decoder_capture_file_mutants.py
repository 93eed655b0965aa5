"""Mutation test of rec15i's stderr capture file of the image decoder (issue 17, branch mutT;
docs/mutation/fileio.md): one file per process, made on the first decode and handed out again after it; a forked child
(another pid) makes its own. ``_native_stderr_captured`` itself is a ``contextmanager``-decorated generator, which
mutmut does not mutate; test_image_decoder.py's ``test_the_reused_capture_file_carries_nothing_to_the_next_image``
pins what it captures."""

from bodystudio import fileio


def test_one_capture_file_per_process(monkeypatch):
    monkeypatch.setattr(fileio, "_capture_file", [None, None])
    first = fileio._stderr_capture_file()
    assert first is not None and first.fileno() >= 0
    assert fileio._stderr_capture_file() is first
    assert fileio._capture_file[0] == fileio.os.getpid()
    monkeypatch.setattr(fileio.os, "getpid", lambda: -7)  # a forked child
    child = fileio._stderr_capture_file()
    assert child is not first and fileio._stderr_capture_file() is child
    assert fileio._capture_file == [-7, child]
    child.close()
    first.close()
