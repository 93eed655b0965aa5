"""``garment fit`` of a session or video whose frame rate is no camera's (reliability round rel5b audit).

A session's ``metadata.fps`` of 0, NaN or 1e6 (a hand-edited or foreign session) went into the fit and its fit.json:
the fit ran its minutes and exited 0, and ``garment render`` then refused the fit.json ("fps 0.0 is not a frame rate
in 1..240") naming the fit, not the session; a text rate stopped the fit with a ValueError. A video whose container
reports 0.5 or 300 fps did the same. Both are now refused before any work in one line naming the session's
session.json (or the video) and the fix; a 25 fps portrait video, a camera's real rate, is read as it is."""

from __future__ import annotations

import json

import numpy as np
import pytest

from bodystudio.errors import InputError
from bodystudio.garment.person import checked_fps, read_video
from tests.reliability.conftest import assert_clean_error, run_inprocess


def _video(path, fps: float, size=(48, 64)):
    import imageio_ffmpeg

    writer = imageio_ffmpeg.write_frames(str(path), size, fps=fps, macro_block_size=1, quality=9)
    writer.send(None)
    for k in range(3):
        writer.send(np.full((size[1], size[0], 3), 40 * k, np.uint8))
    writer.close()
    return path


@pytest.mark.parametrize("fps", [0, "fast", None, 1e6], ids=["zero", "text", "null", "huge"])
def test_a_session_without_a_camera_rate_is_refused_before_the_fit(studio, tmp_path, capfd, fps):
    """The reliability suite's shared 2-camera session (rgb and masks), its rate edited."""
    S, out = studio.copy_session(tmp_path / "S"), tmp_path / "fit"
    manifest = json.loads((S / "session.json").read_text())
    manifest["metadata"]["fps"] = fps
    (S / "session.json").write_text(json.dumps(manifest))
    result = run_inprocess(["garment", "fit", S, "--stature", "1.7", "--out", out], capfd)
    assert_clean_error(result, 2, f"frame rate {fps!r} is not one in 1..240 fps")
    assert f"{S / 'session.json'} (metadata.fps)" in result.stderr and "re-import the session" in result.stderr
    assert not out.exists()


@pytest.mark.parametrize("fps", [0.5, 300.0])
def test_a_video_reporting_no_camera_rate_is_refused(tmp_path, fps):
    clip = _video(tmp_path / "clip.mp4", fps)
    with pytest.raises(InputError, match=f"frame rate {fps!r} is not one in 1..240 fps") as exc:
        read_video(clip)
    assert str(exc.value).startswith(str(clip)) and "\n" not in str(exc.value)


def test_a_25_fps_portrait_video_keeps_its_rate_and_shape(tmp_path):
    images, fps = read_video(_video(tmp_path / "portrait.mp4", 25.0, size=(48, 64)))
    assert fps == 25.0 and images.shape == (3, 64, 48, 3)  # height 64 > width 48: not turned or padded


def test_checked_fps_takes_numbers_in_range_only():
    assert checked_fps(30, "s", "fix") == 30.0 and checked_fps("24", "s", "fix") == 24.0
    for bad in (True, float("nan"), float("inf"), -30, 0.99, 240.5):
        with pytest.raises(InputError, match="^s: frame rate"):
            checked_fps(bad, "s", "fix")
