"""The mirror run's reading, writing and timing (MIR12j): lossless PNG outputs written fast, CPU ms per step next to
the wall ms, and the frames per second end to end with and without reading and writing."""

import cv2
import numpy as np
import pytest

from bodystudio.mirror import run as run_mod
from bodystudio.mirror.evaluate import speed_scores
from bodystudio.mirror.image_case import cached_image_case
from bodystudio.mirror.run import MirrorInput, end_to_end, mirror_stream


def _decoded(data: bytes) -> np.ndarray:
    return cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)


def test_output_pngs_keep_every_pixel_and_stay_small():
    """The fast encoder settings are lossless (the same pixels back), the frames barely larger than libpng's
    adaptive filters gave (measured +4 % on session 43's output frames), the masks far smaller (1.7 vs 39 kB)."""
    case = cached_image_case()
    frame = case.rgb.copy()
    frame[case.true_mask] = case.target_rgb[case.true_mask]  # an output-like frame: a person over the plate
    data = run_mod._png(frame)
    assert np.array_equal(_decoded(data)[..., ::-1], frame)
    adaptive = cv2.imencode(".png", frame[..., ::-1], [cv2.IMWRITE_PNG_COMPRESSION, 1,
                                                       cv2.IMWRITE_PNG_STRATEGY,
                                                       cv2.IMWRITE_PNG_STRATEGY_HUFFMAN_ONLY])[1]
    assert len(data) <= 1.10 * len(adaptive)  # filtered and compressed, not stored
    for mask in (case.true_mask, case.player_mask, np.zeros_like(case.true_mask), np.ones_like(case.true_mask)):
        m = mask.astype(np.uint8) * 255
        data = run_mod._png(m)
        back = _decoded(data)
        assert back.dtype == np.uint8 and back.shape == m.shape and np.array_equal(back, m)
        assert len(data) < 12_000  # run-length coded (Huffman-only coding gave ~39 kB a mask)


def test_a_stream_books_cpu_ms_next_to_wall_ms_and_the_encoder(tmp_path):
    case = cached_image_case()
    inputs = [MirrorInput(0, case.background)] + [
        MirrorInput(1 + i, case.rgb, case.player_mask, None, case.depth_color, case.src_uv, case.dst_uv)
        for i in range(2)]
    doc = mirror_stream(inputs, tmp_path / "run", tmp_path / "out.mp4", side_by_side=False)
    s = doc["summary"]
    for f in doc["frames"]:
        assert set(f["cpu_ms"]) == set(f["ms"]) and "write" in f["cpu_ms"]
    for step in ("foreground", "warp_field", "warp", "compose", "background", "write"):
        assert s["cpu_ms_per_frame"][step] > 0
    # ffmpeg runs in its own process: its CPU is counted apart, after it ended
    assert s["encoder_cpu_ms_per_frame"] > 0
    e = s["end_to_end_cpu"]
    assert e["ms"] == pytest.approx(sum(s["cpu_ms_per_frame"].values()) + s["encoder_cpu_ms_per_frame"])
    assert e["ms_without_io"] == pytest.approx(sum(v for k, v in s["cpu_ms_per_frame"].items() if k != "write"))
    assert e["fps"] < e["fps_without_io"] and s["end_to_end_wall"]["fps"] < s["end_to_end_wall"]["fps_without_io"]
    assert s["cpu_s"] >= sum(sum(f["cpu_ms"].values()) for f in doc["frames"]) / 1e3 * 0.9
    without = mirror_stream(inputs[:1], tmp_path / "run2", None)["summary"]
    assert without["encoder_cpu_ms_per_frame"] is None


def test_end_to_end_adds_the_io_and_the_encoder():
    ms = {"read": 10.0, "register": 3.0, "ik": 2.0, "write": 15.0}
    e = end_to_end(ms, 5.0)
    assert e["ms"] == pytest.approx(35.0) and e["fps"] == pytest.approx(1e3 / 35.0)
    assert e["ms_without_io"] == pytest.approx(5.0) and e["fps_without_io"] == pytest.approx(200.0)
    assert end_to_end(ms)["ms"] == pytest.approx(30.0)


def test_eval_reads_both_speeds_and_an_old_run_has_no_cpu():
    summary = {"ms_per_frame": {"read": 10.0, "warp": 10.0, "write": 20.0},
               "cpu_ms_per_frame": {"read": 8.0, "warp": 9.0, "write": 5.0}, "encoder_cpu_ms_per_frame": 3.0}
    s = speed_scores(summary)
    assert s["fps_end_to_end_cpu"] == pytest.approx(1e3 / 25.0) and s["fps_without_io_cpu"] == pytest.approx(1e3 / 9)
    assert s["fps_end_to_end_wall"] == pytest.approx(25.0) and s["fps_without_io_wall"] == pytest.approx(100.0)
    old = speed_scores({"ms_per_frame": summary["ms_per_frame"]})
    assert old["fps_end_to_end_cpu"] is None and old["cpu_ms_per_frame"] is None
    assert old["fps_end_to_end_wall"] == pytest.approx(25.0)


def test_a_faster_video_preset_writes_the_same_frames(tmp_path):
    """``video_preset`` (``--video-preset``) changes x264's speed / size trade-off, not what the video shows: every
    frame is there and decodes close to the output frame (the default's PSNR, measured 33.7 vs 33.4 dB on 43)."""
    import imageio_ffmpeg

    case = cached_image_case()
    inputs = [MirrorInput(i, case.rgb, case.player_mask, None, case.depth_color, case.src_uv, case.dst_uv)
              for i in range(3)]
    psnr = {}
    for preset in ("veryfast", "ultrafast"):
        mirror_stream(inputs, tmp_path / preset, tmp_path / f"{preset}.mp4", side_by_side=False, video_preset=preset)
        out = cv2.imread(str(tmp_path / preset / "frames" / "00002.png"))[..., ::-1]
        reader = imageio_ffmpeg.read_frames(str(tmp_path / f"{preset}.mp4"))
        next(reader)
        frames = [np.frombuffer(f, np.uint8).reshape(480, 640, 3) for f in reader]
        assert len(frames) == 3
        psnr[preset] = cv2.PSNR(out, frames[2])
    assert psnr["ultrafast"] > psnr["veryfast"] - 1.0 and psnr["veryfast"] > 30
    with pytest.raises(Exception, match="--video-preset"):
        mirror_stream(inputs, tmp_path / "bad", tmp_path / "bad.mp4", video_preset="fastest")
    assert not (tmp_path / "bad").exists() and not (tmp_path / "bad.mp4").exists()
