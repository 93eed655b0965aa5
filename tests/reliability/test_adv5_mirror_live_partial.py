"""``mirror run --live FOLDER`` reading a frame the recorder is still writing (adversarial pass 5).

Before: a colour PNG read half-written failed to decode, the frame was "unreadable" and the previous frame's colour
was shown in its place (a frozen frame, a warning), though the file was complete 0.1 s later. Now a live frame that
fails while one of its files was modified within ``LIVE_WRITE_SETTLE_S`` is read again; a file quiet that long and
still damaged keeps its error (no wait for ever)."""

from __future__ import annotations

import json
import os
import threading
import time

import numpy as np
import pytest

from bodystudio.capture.session import depth_to_png_mm, encode_png, stream_path


def _camera(w: int, h: int, t_x: float) -> dict:
    return {"K": [[20.0, 0, w / 2], [0, 20.0, h / 2], [0, 0, 1]], "dist": [0] * 5, "R": np.eye(3).tolist(),
            "t": [t_x, 0, 0], "width": w, "height": h}


@pytest.fixture
def recorder(tmp_path):
    """A live folder with frame 0's depth and player mask written, and frame 0's colour PNG to write."""
    (tmp_path / "kinect").mkdir()
    (tmp_path / "kinect" / "calibration.json").write_text(json.dumps(
        {"version": "v2", "depth": _camera(16, 12, 0.0), "color": _camera(32, 24, -0.05)}))
    for stream, data in (("kinect_depth", encode_png(depth_to_png_mm(np.full((12, 16), 2.0)))),
                         ("kinect_player", encode_png(np.zeros((12, 16), np.uint8)))):
        path = tmp_path / stream_path(stream, 0)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(data)
    rgb = np.random.default_rng(0).integers(0, 256, (24, 32, 3), dtype=np.uint8)
    return tmp_path, rgb, encode_png(rgb)


def test_a_frame_still_being_written_is_read_once_complete(recorder):
    from bodystudio.mirror.run import live_session, read_arriving_frame

    folder, rgb, png = recorder
    path = folder / stream_path("kinect_rgb", 0)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(png[: len(png) // 2])  # the recorder's first write

    def finish():
        time.sleep(0.1)
        with open(path, "ab") as f:
            f.write(png[len(png) // 2:])

    writer = threading.Thread(target=finish)
    writer.start()
    try:
        frame = read_arriving_frame(live_session(folder), 0, settle_s=0.3, poll_s=0.01)
    finally:
        writer.join()
    assert np.array_equal(frame.rgb, rgb)


def test_a_damaged_frame_quiet_for_the_settle_time_keeps_its_error(recorder):
    from bodystudio.errors import BodyStudioError
    from bodystudio.mirror.run import live_session, read_arriving_frame

    folder, _, png = recorder
    path = folder / stream_path("kinect_rgb", 0)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(png[: len(png) // 2])
    old = time.time() - 10
    os.utime(path, (old, old))
    for stream in ("kinect_depth", "kinect_player"):
        os.utime(folder / stream_path(stream, 0), (old, old))
    with pytest.raises(BodyStudioError, match="00000.png"):
        read_arriving_frame(live_session(folder), 0, settle_s=0.3, poll_s=0.01)
