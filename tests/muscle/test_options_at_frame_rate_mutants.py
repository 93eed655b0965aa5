"""Mutation tests of rel5b's ``muscle.capture.options_at_frame_rate`` (docs/mutation/muscle-capture.md, "rel5b's frame
rate"): every temporal field of options with distinct values against its scaling written by hand, the windows'
rounding and their floor of one frame, both bounds of the accepted rates and each refusal's whole message. The
options only (no capture, < 0.1 s); tests/reliability/test_rel5b_muscle_frame_rate.py runs the capture paths."""
import dataclasses

import pytest

from bodystudio.errors import InputError
from bodystudio.muscle.capture import CaptureOptions, options_at_frame_rate

BASE = dict(sigma_frames=1.3, refine_window_frames=3, detail_sigma_frames=1.7, detail_window_frames=5,
            pose_sigma_frames=4.1, smooth_weight=7.0, sequence_smooth_weight=11.0, body_rest_frame_stride=5)
POSE = ("pose_sigma_frames", "smooth_weight", "sequence_smooth_weight")


def _changed(a, b):
    return {f.name for f in dataclasses.fields(a) if getattr(a, f.name) != getattr(b, f.name)}


@pytest.mark.parametrize("per_frame", [False, True])
def test_each_temporal_field_scales_by_its_own_power_of_the_rate(per_frame):
    o = CaptureOptions(**BASE, pose_filters_per_frame=per_frame)
    at12 = options_at_frame_rate(o, 12.0)  # s = 0.4
    assert at12.sigma_frames == pytest.approx(0.52, rel=1e-12)
    assert at12.detail_sigma_frames == pytest.approx(0.68, rel=1e-12)
    assert (at12.refine_window_frames, at12.detail_window_frames, at12.body_rest_frame_stride) == (1, 2, 2)
    at45 = options_at_frame_rate(o, 45)  # s = 1.5: 4.5 -> 4, 7.5 -> 8 (round half to even)
    assert (at45.refine_window_frames, at45.detail_window_frames, at45.body_rest_frame_stride) == (4, 8, 8)
    assert at45.sigma_frames == pytest.approx(1.95, rel=1e-12)
    if per_frame:
        assert all(getattr(at12, k) == getattr(o, k) for k in POSE) and all(
            getattr(at45, k) == getattr(o, k) for k in POSE)
    else:
        assert at12.pose_sigma_frames == pytest.approx(1.64, rel=1e-12)
        assert at12.smooth_weight == pytest.approx(2.8, rel=1e-12)
        assert at12.sequence_smooth_weight == pytest.approx(11.0 * 0.4**4, rel=1e-12)
        assert at45.sequence_smooth_weight == pytest.approx(11.0 * 1.5**4, rel=1e-12)
    scaled = {"sigma_frames", "refine_window_frames", "detail_sigma_frames", "detail_window_frames",
              "body_rest_frame_stride"} | (set() if per_frame else set(POSE))
    assert _changed(o, at45) == scaled


def test_the_windows_keep_at_least_one_frame_and_30_fps_is_the_options_themselves():
    o = CaptureOptions(**{**BASE, "refine_window_frames": 1, "detail_window_frames": 1, "body_rest_frame_stride": 1})
    low = options_at_frame_rate(o, 10.0)  # the lowest rate accepted: one third of a frame rounds to 0
    assert (low.refine_window_frames, low.detail_window_frames, low.body_rest_frame_stride) == (1, 1, 1)
    assert low.sigma_frames == pytest.approx(1.3 / 3.0, rel=1e-12)
    high = options_at_frame_rate(o, 240.0)  # the highest
    assert (high.refine_window_frames, high.detail_window_frames, high.body_rest_frame_stride) == (8, 8, 8)
    assert options_at_frame_rate(o, 30) is o and options_at_frame_rate(o, 30.0, "S") is o


LOW = ("below the 10 fps the arm capture's temporal filters need (Eq. 13-14's window, the pose smoothing and the "
       "model-based tracking span 1/30 s and more); record at 15 fps or more")
HIGH = ("not a depth camera's rate (10-240 fps); fix the session's metadata.fps (bodystudio capture import records "
        "it from the frame times)")


@pytest.mark.parametrize("fps, shown, why", [(9.99, "9.99", LOW), (-3.0, "-3", LOW), (240.5, "240.5", HIGH),
                                             (float("inf"), "inf", HIGH), (float("-inf"), "-inf", HIGH),
                                             (float("nan"), "nan", HIGH)])
def test_each_refusal_is_one_whole_line(fps, shown, why):
    with pytest.raises(InputError) as exc:
        options_at_frame_rate(CaptureOptions(), fps, "sessions/S7")
    assert str(exc.value) == f"sessions/S7: recorded at {shown} fps, {why}"
    with pytest.raises(InputError) as exc:
        options_at_frame_rate(CaptureOptions(), fps)
    assert str(exc.value).startswith(f"the recording: recorded at {shown} fps, ")
