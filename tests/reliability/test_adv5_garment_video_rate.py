"""``garment fit VIDEO`` / ``garment render`` on a phone's variable-rate clip (adversarial pass 5).

Before: FFmpeg's pipe was constant-rate, so a clip of 10 frames over 1.7 s (every 0.1 s, then every 0.3 s) was read
as 19 frames, the held ones repeated, at the stream's nominal rate, and the fit's video played at that rate, exit 0.
Now every decoded frame is read once, by the fit and by the render alike, and the rate comes from the frames' times
(frames over their span when steady, the median period when not, with a warning)."""

from __future__ import annotations

import subprocess
from types import SimpleNamespace

import numpy as np
import pytest

W, H = 64, 48


def _encode(path, fps: float, n: int = 10):
    import imageio_ffmpeg

    proc = subprocess.Popen([imageio_ffmpeg.get_ffmpeg_exe(), "-y", "-loglevel", "error", "-f", "rawvideo",
                             "-pix_fmt", "rgb24", "-s", f"{W}x{H}", "-r", str(fps), "-i", "-", "-c:v", "ffv1",
                             str(path)], stdin=subprocess.PIPE)
    for k in range(n):
        proc.stdin.write(np.full((H, W, 3), 20 * k + 10, np.uint8).tobytes())
    proc.stdin.close()
    assert proc.wait() == 0
    return path


@pytest.fixture(scope="module")
def clips(tmp_path_factory):
    import imageio_ffmpeg

    root = tmp_path_factory.mktemp("adv5_garment_clips")
    _encode(root / "fps15.mkv", 15)
    _encode(root / "fps10.mkv", 10)
    subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-y", "-loglevel", "error", "-i", str(root / "fps10.mkv"),
                    "-vf", "setpts='if(lt(N,5),N*0.1,0.5+(N-5)*0.3)/TB'", "-fps_mode", "vfr", "-c:v", "ffv1",
                    str(root / "vfr.mkv")], check=True)
    return root


def _grey(images):
    return [int(np.median(image)) for image in images]


def test_a_variable_rate_clip_is_read_frame_by_frame(clips, caplog):
    from bodystudio.garment.composite import source_frames
    from bodystudio.garment.person import read_video

    images, fps = read_video(clips / "vfr.mkv")
    assert _grey(images) == [20 * k + 10 for k in range(10)]  # before: 19 frames, held ones repeated
    assert fps == pytest.approx(10.0, abs=1e-3)  # before: the nominal 30
    assert "vfr.mkv: variable frame rate (frame periods 100-30" in caplog.text
    # the render reads the same numbering: the fitted frames 6 and 9 are the clip's 6th and 9th
    fit = SimpleNamespace(source=str(clips / "vfr.mkv"), frame_ids=[6, 9], source_fingerprint=None)
    assert _grey(source_frames(fit)) == [130, 190]


@pytest.mark.parametrize(("clip", "fps"), [("fps15.mkv", 15.0), ("fps10.mkv", 10.0)])
def test_a_steady_clip_keeps_its_frames_and_rate(clips, caplog, clip, fps):
    from bodystudio.garment.person import read_video

    images, rate = read_video(clips / clip)
    assert _grey(images) == [20 * k + 10 for k in range(10)] and rate == pytest.approx(fps, abs=1e-3)
    assert "variable frame rate" not in caplog.text
    images, rate = read_video(clips / clip, "2:5")
    assert _grey(images) == [50, 70, 90] and rate == pytest.approx(fps, abs=1e-3)
