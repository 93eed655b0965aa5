"""``capture import --videos`` on what webcams and phones record (adversarial pass 5: real recordings).

Before: a 15 fps video imported without ``metadata.fps`` (every reader then assumed 30: the arm capture's filters
twice as wide in seconds, the mirror video twice as fast); a 10 fps and a 15 fps camera, or a variable-rate phone
video and a steady camera, were paired by frame index with exit 0 (frames recorded up to 0.5 s apart in one session
frame); a good variable-rate Matroska video (header count 17 = duration x rate, 10 frames) and a recording whose last
frame was cut off were refused as "truncated or damaged", the second without the ``--frames`` that imports it; a
phone video's 90-degree rotation flag gave a size error that did not say why. Now the frames are counted and timed by
decoding, the rate is recorded, index pairing of unequal or uneven rates is refused naming ``--timestamps``."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from tests.reliability.conftest import assert_clean_error, run_inprocess

W, H = 64, 48


def _frame(k: int) -> np.ndarray:
    image = np.full((H, W, 3), (20 * k + 10) % 256, np.uint8)
    image[:8, :16] = (255, 0, 0)
    return image


def _ffmpeg(*args) -> None:
    import imageio_ffmpeg

    subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-y", "-loglevel", "error", *map(str, args)], check=True)


def _encode(path: Path, fps: float, out_args=("-c:v", "ffv1"), n: int = 10) -> Path:
    import imageio_ffmpeg

    proc = subprocess.Popen([imageio_ffmpeg.get_ffmpeg_exe(), "-y", "-loglevel", "error", "-f", "rawvideo",
                             "-pix_fmt", "rgb24", "-s", f"{W}x{H}", "-r", str(fps), "-i", "-", *out_args, str(path)],
                            stdin=subprocess.PIPE)
    for k in range(n):
        proc.stdin.write(_frame(k).tobytes())
    proc.stdin.close()
    assert proc.wait() == 0
    return path


@pytest.fixture(scope="module")
def clips(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("adv5_clips")
    _encode(root / "fps10.mkv", 10)
    _encode(root / "fps15.mkv", 15)
    _encode(root / "mjpeg.avi", 10, ("-c:v", "mjpeg", "-q:v", "2"))
    data = (root / "mjpeg.avi").read_bytes()
    (root / "cut.avi").write_bytes(data[: len(data) - 600])  # the index and part of the last frame lost
    # a phone's variable rate: frames 0-5 every 0.1 s, then every 0.3 s (the header estimates 17 frames)
    _ffmpeg("-i", root / "fps10.mkv", "-vf", "setpts='if(lt(N,5),N*0.1,0.5+(N-5)*0.3)/TB'", "-fps_mode", "vfr",
            "-c:v", "ffv1", root / "vfr.mkv")
    _encode(root / "upright.mp4", 10, ("-c:v", "libx264", "-qp", "0", "-pix_fmt", "yuv444p"))
    _ffmpeg("-display_rotation:v:0", "90", "-i", root / "upright.mp4", "-c", "copy", root / "rot90.mp4")
    return root


def _import(tmp_path, capfd, clips, videos: dict[str, str], *extra):
    from bodystudio.geometry.camera import Camera, CameraRig, save_cameras_json

    folder = tmp_path / "videos"
    folder.mkdir(parents=True)
    for cam, name in videos.items():
        shutil.copy(clips / name, folder / f"{cam}{Path(name).suffix}")
    K = np.array([[50.0, 0, W / 2], [0, 50.0, H / 2], [0, 0, 1]])
    rig = CameraRig({cam: Camera(cam, K, np.zeros(5), np.eye(3), np.array([0, 0, 3.0 + i]), W, H)
                     for i, cam in enumerate(videos)})
    save_cameras_json(tmp_path / "cameras.json", rig)
    out = tmp_path / "S"
    result = run_inprocess(["capture", "import", out, "--cameras", tmp_path / "cameras.json", "--videos", folder,
                            *extra], capfd)
    return result, out, folder


def _metadata(out: Path) -> dict:
    return json.loads((out / "session.json").read_text())["metadata"]


@pytest.mark.parametrize(("clip", "fps"), [("fps15.mkv", 15.0), ("fps10.mkv", 10.0)])
def test_the_videos_frame_rate_is_recorded(tmp_path, capfd, clips, clip, fps):
    """Before: no metadata.fps (read as 30). Matroska's millisecond times put 15 fps at 14.925 by the median period:
    the rate is the frames over their span."""
    result, out, _ = _import(tmp_path, capfd, clips, {"cam_a": clip})
    assert_clean_error(result, 0, "")
    assert _metadata(out)["fps"] == pytest.approx(fps, abs=1e-3)


def test_cameras_at_different_rates_are_not_paired_by_index(tmp_path, capfd, clips):
    """Before: 10 frames each, exit 0, session frame 9 = 0.9 s of one camera with 0.6 s of the other."""
    result, out, folder = _import(tmp_path, capfd, clips, {"cam_a": "fps10.mkv", "cam_b": "fps15.mkv"})
    assert_clean_error(result, 2, f"{folder / 'cam_b.mkv'}: 15 fps but {folder / 'cam_a.mkv'} is 10 fps")
    assert "--timestamps" in result.stderr and not out.exists()


def test_a_variable_rate_video_alone_imports_and_is_not_paired_with_another(tmp_path, capfd, clips):
    """Before: refused as "truncated or damaged" (the header's 17 frames), and after ``--frames 10`` paired by index
    with a steady camera (frame 9: 1.7 s with 0.9 s)."""
    result, out, _ = _import(tmp_path / "one", capfd, clips, {"cam_a": "vfr.mkv"})
    assert_clean_error(result, 0, "")
    assert _metadata(out)["fps"] == pytest.approx(10.0, abs=1e-3)  # the median period: the steady part
    frames = sorted((out / "cam_a" / "rgb").glob("*.png"))
    assert len(frames) == 10  # each decoded frame once: none dropped, none held
    from bodystudio.fileio import read_image

    grey = [int(np.median(read_image(f)[30:, 30:])) for f in frames]
    assert grey == [20 * k + 10 for k in range(10)]
    for extra in ((), ("--frames", "10")):
        result, out, folder = _import(tmp_path / f"two{len(extra)}", capfd, clips,
                                      {"cam_a": "vfr.mkv", "cam_b": "fps10.mkv"}, *extra)
        assert_clean_error(result, 2, f"{folder / 'cam_a.mkv'}: variable frame rate (frame 6 comes 300 ms after")
        assert not out.exists()
    # the steady first six frames pair
    result, out, _ = _import(tmp_path / "steady", capfd, clips, {"cam_a": "vfr.mkv", "cam_b": "fps10.mkv"},
                             "--frames", "6")
    assert_clean_error(result, 0, "")


def test_a_cut_off_last_frame_imports_the_frames_that_decode(tmp_path, capfd, caplog, clips):
    """Alone: the 8 whole frames with a warning naming the file; beside a whole recording: the ``--frames 8`` that
    pairs them (before: refused, "frame 8 cannot be decoded", no fix)."""
    result, out, folder = _import(tmp_path / "one", capfd, clips, {"cam_a": "cut.avi"})
    assert_clean_error(result, 0, "")
    assert "cam_a.avi: 8 frames decode but the header says 10" in caplog.text
    assert len(list((out / "cam_a" / "rgb").glob("*.png"))) == 8
    result, out, folder = _import(tmp_path / "two", capfd, clips, {"cam_a": "cut.avi", "cam_b": "mjpeg.avi"})
    assert_clean_error(result, 2, "--frames 8")


def test_a_rotated_phone_video_says_it_is_turned(tmp_path, capfd, clips):
    result, out, folder = _import(tmp_path, capfd, clips, {"cam_a": "rot90.mp4"})
    assert_clean_error(result, 2, f"{folder / 'cam_a.mp4'} frame 0: image is 48x64, turned 90 degrees")
    assert not out.exists()


@pytest.mark.parametrize("kind", ["audio", "no_frames"])
def test_a_video_without_frames_is_one_line(tmp_path, capfd, clips, kind):
    """An audio-only file and a video stream with no frames: one error line (before: FFmpeg's demuxer chatter too)."""
    clip = tmp_path / "clip.mkv"
    if kind == "audio":
        _ffmpeg("-f", "lavfi", "-i", "sine=d=1", "-c:a", "flac", clip)
    else:
        _ffmpeg("-i", clips / "fps10.mkv", "-frames:v", "0", "-c:v", "ffv1", clip)
    shutil.copy(clip, clips / f"{kind}.mkv")
    result, out, folder = _import(tmp_path, capfd, clips, {"cam_a": f"{kind}.mkv"})
    assert_clean_error(result, 2, f"{folder / 'cam_a.mkv'}: ")
    assert not out.exists()


def test_a_frame_ffmpeg_complains_about_is_named(tmp_path, capfd, caplog, clips):
    """An MJPEG frame with a damaged scan decodes (partly grey) with no error: the import passes it on with a warning
    naming the frame (before: nothing said; a damaged still image is refused, but a video frame cannot be left out
    without shifting its camera against the others)."""
    import imageio_ffmpeg

    rng = np.random.default_rng(0)  # noise frames: big JPEG scans, so the damage lands in one (frame 2)
    proc = subprocess.Popen([imageio_ffmpeg.get_ffmpeg_exe(), "-y", "-loglevel", "error", "-f", "rawvideo", "-pix_fmt",
                             "rgb24", "-s", f"{W}x{H}", "-r", "10", "-i", "-", "-c:v", "mjpeg", "-q:v", "2",
                             str(tmp_path / "noise.avi")], stdin=subprocess.PIPE)
    for _ in range(10):
        proc.stdin.write(rng.integers(0, 256, (H, W, 3), dtype=np.uint8).tobytes())
    proc.stdin.close()
    assert proc.wait() == 0
    data = bytearray((tmp_path / "noise.avi").read_bytes())
    at = int(0.3 * len(data))
    data[at:at + 200] = bytes(200)  # FFmpeg says nothing about most damage (zeros are valid entropy codes)
    (clips / "damaged.avi").write_bytes(bytes(data))
    result, out, folder = _import(tmp_path, capfd, clips, {"cam_a": "damaged.avi"})
    assert_clean_error(result, 0, "")
    assert f"{folder / 'cam_a.avi'}: FFmpeg reported" in caplog.text and "decoding frame 2;" in caplog.text
