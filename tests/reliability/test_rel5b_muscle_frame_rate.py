"""``muscle capture`` of a recording at another frame rate than 30 fps (reliability round rel5b).

The capture's temporal filters counted frames tuned at 30 fps (Eq. 13-14's sigma and window, the refinement
detail's, the pose smoothing, the per-frame fit's previous-frame prior, the sequence fit's second-difference prior,
the rest-shape fit's frame stride); a 15 fps recording (``metadata.fps``) was only warned about: every filter spanned
twice the time. They are now times (frames at 30 fps) scaled to the session's rate by
``capture.options_at_frame_rate``, the same options object at 30 fps (the measured capture, unchanged), and a rate
the filters cannot serve (below 10 fps; or no frame rate at all) is refused in one line naming the session, before
any work, OUT not created. ``synth arm --fps`` samples the same motion at another rate (docs/muscle.md, "Frame
rate")."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from bodystudio.errors import InputError
from bodystudio.muscle.arm import ArmPose
from bodystudio.muscle.capture import EXTENSION_CAPTURE, CaptureOptions, capture_frame_rate, options_at_frame_rate
from bodystudio.muscle.refine import smooth_arm_poses, time_consistent_correspondences
from bodystudio.muscle.synthetic import arm_angle_sequence
from tests.reliability.conftest import assert_clean_error, run_inprocess


@pytest.fixture(scope="module")
def slow_session(tmp_path_factory):
    """A 3-frame 2k arm session sampled at 8 fps (``metadata.fps`` 8)."""
    from bodystudio.muscle.synthetic import synth_arm_session

    root = tmp_path_factory.mktemp("rel5b_fps")
    synth_arm_session(root / "S8", subject_seed=501, n_frames=3, resolution="2k", fps=8.0)
    return root / "S8"


def _with_fps(src, dest, fps):
    shutil.copytree(src, dest)
    manifest = json.loads((dest / "session.json").read_text())
    manifest["metadata"]["fps"] = fps
    (dest / "session.json").write_text(json.dumps(manifest))
    return dest


# ---------------------------------------------------------------------------------------------- the options

@pytest.mark.parametrize("options", [CaptureOptions(), CaptureOptions(**EXTENSION_CAPTURE)], ids=["default", "ext"])
def test_at_30_fps_the_capture_gets_its_options_unchanged(options):
    """The measured capture, bit for bit: the very same options object (no field re-computed), the paper's
    i-1, i, i+1 window and the +-2 frames of the refinement detail as before."""
    assert options_at_frame_rate(options, 30.0) is options
    assert (options.refine_window_frames, options.detail_window_frames) == (1, 2)


def test_every_temporal_field_follows_the_rate():
    o = CaptureOptions()
    half, double = options_at_frame_rate(o, 15.0), options_at_frame_rate(o, 60.0)
    assert (half.sigma_frames, half.refine_window_frames) == (0.5, 1)
    assert (half.detail_sigma_frames, half.detail_window_frames) == (0.75, 1)
    assert (half.pose_sigma_frames, half.smooth_weight) == (2.5, 5.0)
    assert half.sequence_smooth_weight == pytest.approx(10.0 / 16)  # a spline's width goes as weight^(1/4)
    assert half.body_rest_frame_stride == 2
    assert (double.sigma_frames, double.refine_window_frames, double.detail_window_frames) == (2.0, 2, 4)
    assert (double.pose_sigma_frames, double.smooth_weight, double.body_rest_frame_stride) == (10.0, 20.0, 8)
    assert double.sequence_smooth_weight == pytest.approx(160.0)
    assert half.shape_frames == o.shape_frames  # a count of depth frames for the shape fit, not a filter
    changed = {k for k in o.__dataclass_fields__ if getattr(o, k) != getattr(half, k)}
    assert changed == {"sigma_frames", "detail_sigma_frames", "detail_window_frames", "pose_sigma_frames",
                       "smooth_weight", "sequence_smooth_weight", "body_rest_frame_stride"}


def test_the_pose_filters_per_frame_option_keeps_only_the_pose_filters_in_frames():
    """``pose_filters_per_frame`` (off by default; measured better at 15 fps on 501 and 504, docs/muscle.md): the pose
    smoothing and the two pose priors keep their frame values, the refinement's windows and the stride still scale."""
    o = CaptureOptions(pose_filters_per_frame=True)
    half = options_at_frame_rate(o, 15.0)
    assert (half.pose_sigma_frames, half.smooth_weight, half.sequence_smooth_weight) == (5.0, 10.0, 10.0)
    assert (half.sigma_frames, half.detail_sigma_frames, half.body_rest_frame_stride) == (0.5, 0.75, 2)
    assert options_at_frame_rate(o, 30.0) is o and not CaptureOptions().pose_filters_per_frame


@pytest.mark.parametrize("fps, why", [(9.9, "below the 10 fps"), (0.0, "below the 10 fps"),
                                      (float("nan"), "not a depth camera's rate"),
                                      (500.0, "not a depth camera's rate")])
def test_a_rate_the_filters_cannot_serve_is_refused(fps, why):
    with pytest.raises(InputError, match=why) as exc:
        options_at_frame_rate(CaptureOptions(), fps, "S")
    assert str(exc.value).startswith("S: recorded at") and "\n" not in str(exc.value)


def _flexion_poses(fps: float, n: int) -> tuple[list[ArmPose], np.ndarray]:
    flexion = np.deg2rad(arm_angle_sequence("elbow_flex", n, seed=0, fps=fps)[:, 0])
    return [ArmPose(np.eye(4), np.array([[0.0, 0.0, 0.0], [f, 0.0, 0.0], [0.0, 0.0, 0.0]])) for f in flexion], flexion


def _smoothing_error_deg(fps: float, n: int, sigma_frames: float) -> float:
    poses, truth = _flexion_poses(fps, n)
    smoothed = smooth_arm_poses(poses, sigma_frames, degree=CaptureOptions().pose_smoothing_degree)
    inner = slice(n // 8, n - n // 8)  # the ends' cut windows aside
    return float(np.degrees(np.abs(np.array([p.angles[1, 0] for p in smoothed]) - truth)[inner].max()))


def test_the_pose_smoothing_keeps_its_width_in_seconds():
    """The benchmark's 6.7 s flexion motion at 30 fps (200 frames) and at 15 fps (100 frames), no noise: the local
    quadratic's bias at the turning points. The scaled sigma keeps the 30 fps bias (within 20 %); the frames counted
    at 30 fps (the old capture at 15 fps: a sigma of 1/3 s, twice the time) cut the turning points several times
    more."""
    o = CaptureOptions()
    at30 = _smoothing_error_deg(30.0, 200, o.pose_sigma_frames)
    at15 = _smoothing_error_deg(15.0, 100, options_at_frame_rate(o, 15.0).pose_sigma_frames)
    unscaled = _smoothing_error_deg(15.0, 100, o.pose_sigma_frames)
    assert 0.01 < at30 and at15 < 1.2 * at30  # 0.032 and 0.036 deg
    assert unscaled > 4 * at30  # 0.49 deg


def test_the_refinement_window_with_offsets_is_eq_14():
    """The wider window of a fast recording (offsets given) weighs each frame as Eq. 14 does; with the offsets -1, 0,
    1 it is the paper's three-frame window bit for bit."""
    rng = np.random.default_rng(5)
    vectors = [rng.normal(size=(4, 3)) for _ in range(5)]
    valid = [np.ones(4, bool), np.array([1, 0, 1, 1], bool), np.ones(4, bool), np.ones(4, bool),
             np.array([0, 1, 1, 1], bool)]
    three, ok3 = time_consistent_correspondences(vectors[1:4], valid[1:4], 1.0)
    same, ok = time_consistent_correspondences(vectors[1:4], valid[1:4], 1.0, [-1, 0, 1])
    assert np.array_equal(three, same) and np.array_equal(ok3, ok)
    five, ok5 = time_consistent_correspondences(vectors, valid, 2.0, [-2, -1, 0, 1, 2])
    w = np.exp(-np.array([-2, -1, 0, 1, 2]) ** 2 / 8.0)[:, None] * np.array(valid, float)
    expected = np.einsum("fv,fvd->vd", w, np.array(vectors)) / w.sum(axis=0)[:, None]
    np.testing.assert_allclose(five, expected, rtol=1e-12)
    assert ok5.tolist() == valid[2].tolist()
    with pytest.raises(InputError, match="exactly one 0"):
        time_consistent_correspondences(vectors[:2], valid[:2], 1.0, [1, 2])


# ---------------------------------------------------------------------------------------------- sessions, CLI

def test_the_session_rate_is_read_and_checked(slow_session, tmp_path):
    from bodystudio.capture.session import open_session

    assert open_session(slow_session).metadata["fps"] == 8.0
    assert capture_frame_rate(open_session(_with_fps(slow_session, tmp_path / "S15", 15))) == 15.0
    with pytest.raises(InputError, match="below the 10 fps"):
        capture_frame_rate(open_session(slow_session))
    with pytest.raises(InputError, match="metadata.fps 'fast' is not a frame rate"):
        capture_frame_rate(open_session(_with_fps(slow_session, tmp_path / "Sx", "fast")))
    unknown = _with_fps(slow_session, tmp_path / "Sn", None)
    assert capture_frame_rate(open_session(unknown)) == 30.0  # none recorded: the 30 fps readers assume


def test_capture_of_an_8_fps_recording_is_refused_in_one_line(slow_session, tmp_path, capfd):
    out = tmp_path / "cap"
    result = run_inprocess(["muscle", "capture", slow_session, "--out", out, "--no-model"], capfd)
    assert_clean_error(result, 2, "recorded at 8 fps, below the 10 fps")
    assert str(slow_session) in result.stderr and "record at 15 fps or more" in result.stderr
    assert not out.exists()


def test_a_batch_with_one_8_fps_recording_is_refused_before_it_starts(slow_session, tmp_path, capfd):
    ok = _with_fps(slow_session, tmp_path / "S30", 30.0)
    out = tmp_path / "batch"
    result = run_inprocess(["muscle", "capture", ok, slow_session, "--out", out, "--no-model"], capfd)
    assert_clean_error(result, 2, "recorded at 8 fps")
    assert not out.exists()


def test_synth_arm_samples_the_same_motion_at_another_rate(tmp_path, capfd):
    """Frame k at 15 fps is frame 2k at 30 fps (the motion in seconds); a rate no camera has is refused."""
    np.testing.assert_array_equal(arm_angle_sequence("elbow_flex", 50, 3, fps=15.0),
                                  arm_angle_sequence("elbow_flex", 100, 3)[::2])
    out = tmp_path / "S"
    result = run_inprocess(["synth", "arm", out, "--subject-seed", "1", "--fps", "0"], capfd)
    assert_clean_error(result, 2, "--fps 0.0: must be in [1, 240]")
    assert not out.exists()


def _tube(radius=0.04, n_around=24, n_along=13):
    t = np.linspace(0.0, 2.0 * np.pi, n_around, endpoint=False)
    x = np.linspace(-0.15, 0.15, n_along)
    V = np.array([[xi, 1.0 + radius * np.sin(ti), radius * np.cos(ti)] for xi in x for ti in t])
    F = []
    for i in range(n_along - 1):
        for j in range(n_around):
            a, b = i * n_around + j, i * n_around + (j + 1) % n_around
            F += [[a, a + n_around, b], [b, a + n_around, b + n_around]]
    return V, np.array(F)


def test_the_refinement_at_60_fps_averages_over_the_same_time(monkeypatch):
    """``capture._refinement`` at 60 fps: Eq. 13's window is frames i-2..i+2 (the same +-1/30 s), cut at the ends,
    and the detail's +-4 frames; on five identical frames (a tube, its depth points 1 mm outside it) every window
    gives the 30 fps result."""
    from scipy.spatial import cKDTree

    from bodystudio.geometry.mesh import vertex_normals
    from bodystudio.muscle import capture as cm
    from bodystudio.muscle.nicp import vertex_neighbourhoods

    V, F = _tube()
    N = vertex_normals(V, F)
    P = V + 0.001 * N
    seen = []
    real = cm.time_consistent_correspondences

    def spy(vectors, valid, sigma, deltas=None):
        seen.append(None if deltas is None else list(deltas))
        return real(vectors, valid, sigma, deltas)

    monkeypatch.setattr(cm, "time_consistent_correspondences", spy)
    joints = np.array([[-1.0, 0, 0], [-0.9, 0, 0], [-0.8, 0, 0]])

    def refined(fps):
        o = options_at_frame_rate(CaptureOptions(refine_min_facing_cos=0.0), fps)
        return np.stack(cm._refinement([V] * 5, [ArmPose.rest()] * 5, [(P, N)] * 5, [cKDTree(P)] * 5, F,
                                       np.array([0.0, 1.0, 1.0]), np.ones(len(V), bool),
                                       vertex_neighbourhoods(F, len(V)), joints, o, cm._Timer()))

    at30 = refined(30.0)
    assert seen == [None] * 5
    seen.clear()
    at60 = refined(60.0)
    assert seen == [[0, 1, 2], [-1, 0, 1, 2], [-2, -1, 0, 1, 2], [-2, -1, 0, 1], [-2, -1, 0]]
    assert np.abs(at30 - V).max() > 2e-4  # the refinement moved the seen side towards its points
    np.testing.assert_allclose(at60, at30, atol=1e-9)


@pytest.mark.parametrize("fps", ["0", "nan", "500"])
def test_muscle_sequences_refuses_a_bad_rate_before_any_work(fps, tmp_path, capsys):
    from benchmarks.muscle_sequences import main

    with pytest.raises(SystemExit) as exc:
        main(["--work", str(tmp_path / "w"), "--session", "501:0", "--frames", "4", "--fps", fps])
    assert exc.value.code == 2 and "--fps" in capsys.readouterr().err
    assert not (tmp_path / "w").exists()
