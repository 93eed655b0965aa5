"""adv5's ``mirror.run.read_arriving_frame``: a frame read again while its files are still being written (mutOO).

``read_mirror_frame`` replaced by a stand-in that fails a given number of times, the clock and sleep by a fake
(times exact in binary), the frame's files given modification times by ``os.utime``: read again while the newest of
its four files is within ``settle_s`` of now (inclusive), the error raised as it was once they are quiet longer.
"""

from __future__ import annotations

import os
from types import SimpleNamespace

import pytest

from bodystudio.errors import FileFormatError


class _Clock:
    def __init__(self, times):
        self.times, self.slept = list(times), []

    def time(self):
        return self.times.pop(0)

    def sleep(self, s):
        self.slept.append(s)


def _setup(monkeypatch, tmp_path, fails, times, mtimes):
    import bodystudio.mirror.frames as mf
    import bodystudio.mirror.run as mr
    from bodystudio.capture.session import stream_path

    for stream, t in mtimes.items():
        p = tmp_path / stream_path(stream, 3)
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_bytes(b"x")
        os.utime(p, (t, t))
    errors = [FileFormatError(f"frame 3 unreadable ({k})") for k in range(fails)]
    calls, sessions = [], []

    def read(session, i):
        calls.append(i)
        sessions.append(session)
        if errors:
            raise errors.pop(0)
        return "frame"

    monkeypatch.setattr(mf, "read_mirror_frame", read)
    clock = _Clock(times)
    monkeypatch.setattr(mr, "time", clock)
    session = SimpleNamespace(path=str(tmp_path))
    session.read_by = sessions
    return mr, session, calls, clock


def test_a_frame_read_whole_at_once(monkeypatch, tmp_path):
    mr, s, calls, clock = _setup(monkeypatch, tmp_path, 0, [], {})
    assert mr.read_arriving_frame(s, 3) == "frame" and calls == [3] and clock.slept == []
    assert s.read_by == [s]


def test_a_frame_still_written_is_read_again_until_it_decodes(monkeypatch, tmp_path):
    # the colour file is old, the joints file new: the newest counts; the depth and player files are missing
    mr, s, calls, clock = _setup(monkeypatch, tmp_path, 2, [100.25, 100.5],
                                 {"kinect_rgb": 50.0, "kinect_joints": 100.25})
    assert mr.read_arriving_frame(s, 3, settle_s=0.25, poll_s=0.125) == "frame"
    assert calls == [3, 3, 3] and clock.slept == [0.125, 0.125]  # 0 s, then 0.25 s (inclusive) since the write


def test_a_quiet_damaged_frame_raises_its_own_error(monkeypatch, tmp_path):
    mr, s, calls, clock = _setup(monkeypatch, tmp_path, 5, [100.5, 100.75],
                                 {"kinect_rgb": 100.0, "kinect_depth": 100.25, "kinect_player": 50.0})
    with pytest.raises(FileFormatError, match=r"^frame 3 unreadable \(1\)$"):
        mr.read_arriving_frame(s, 3, settle_s=0.25, poll_s=0.0625)
    assert calls == [3, 3] and clock.slept == [0.0625]
    mr, s, calls, clock = _setup(monkeypatch, tmp_path / "none", 1, [0.5], {})  # no files at all: quiet
    with pytest.raises(FileFormatError, match=r"\(0\)"):
        mr.read_arriving_frame(s, 3, settle_s=0.25)
    assert clock.slept == []


def test_the_defaults(monkeypatch, tmp_path):
    import bodystudio.mirror.run as mr

    mr_, s, calls, clock = _setup(monkeypatch, tmp_path, 1, [100.0 + mr.LIVE_WRITE_SETTLE_S], {"kinect_rgb": 100.0})
    assert mr_.read_arriving_frame(s, 3) == "frame" and clock.slept == [0.02]


def test_other_errors_are_not_retried(monkeypatch, tmp_path):
    import bodystudio.mirror.frames as mf
    import bodystudio.mirror.run as mr

    def read(session, i):
        raise ValueError("bug")

    monkeypatch.setattr(mf, "read_mirror_frame", read)
    with pytest.raises(ValueError):
        mr.read_arriving_frame(SimpleNamespace(path=str(tmp_path)), 0)
