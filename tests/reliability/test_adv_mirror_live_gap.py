"""``mirror run --live FOLDER`` when the recorder dropped a frame (adversarial pass): the run waited on the
missing frame until --live-timeout and stopped there with exit 0, silently dropping every later frame. It now
skips the missing frame (a warning names it) once a later frame has arrived complete."""

import os
import time

from bodystudio.capture.session import stream_path
from bodystudio.mirror.run import live_frame_ids


def recorder_folder(root, frames, missing=()):
    """Empty stand-ins for the kinect colour / depth / player files of ``frames``, written a while ago."""
    old = time.time() - 10
    for i in frames:
        for stream in ("kinect_rgb", "kinect_depth", "kinect_player", "kinect_joints"):
            if (stream, i) in missing:
                continue
            path = root / stream_path(stream, i)
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_bytes(b"")
            os.utime(path, (old, old))
    return root


def test_a_dropped_frame_is_skipped_not_the_end(tmp_path):
    folder = recorder_folder(tmp_path, range(6), missing={("kinect_rgb", 2), ("kinect_depth", 4)})
    assert list(live_frame_ids(folder, timeout_s=0.5, settle_s=0.1)) == [0, 1, 3, 5]


def test_frames_in_order_are_all_given(tmp_path):
    folder = recorder_folder(tmp_path, range(4))
    assert list(live_frame_ids(folder, timeout_s=0.3, settle_s=0.1)) == [0, 1, 2, 3]
