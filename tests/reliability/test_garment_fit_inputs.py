"""Bad input to ``bodystudio garment fit`` / ``eval garment``: one-line errors, exit 2, nothing written.

And a fit killed while writing its folder leaves either nothing or a folder that readers refuse (no
half-written fit is ever loaded).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from bodystudio.errors import InputError

from .conftest import assert_clean_error, run_inprocess

sys.path.insert(0, str(Path(__file__).parent))
from kill_harness import read_events, run_child  # noqa: E402


@pytest.fixture(scope="module")
def tiny_session(tmp_path_factory):
    from bodystudio.garment.synthetic import synth_garment_session

    out = tmp_path_factory.mktemp("gfit_in") / "s"
    synth_garment_session(out, subject_seed=2, n_frames=3, resolution=(96, 128), template="2k", texture_size=32,
                          shadows=False)
    return out


def _video(path: Path, frames: list[np.ndarray], fps: float = 10.0) -> Path:
    import imageio_ffmpeg

    h, w = frames[0].shape[:2]
    writer = imageio_ffmpeg.write_frames(str(path), (w, h), fps=fps, macro_block_size=1, quality=9)
    writer.send(None)
    for f in frames:
        writer.send(np.ascontiguousarray(f))
    writer.close()
    return path


def test_missing_video(tmp_path, capfd):
    r = run_inprocess(["garment", "fit", tmp_path / "nope.mp4", "--stature", "1.7", "--out", tmp_path / "o"], capfd)
    assert_clean_error(r, 2, "no such video file or session folder")
    assert not (tmp_path / "o").exists()


def test_unreadable_video(tmp_path, capfd):
    bad = tmp_path / "clip.mp4"
    bad.write_bytes(b"this is not a video" * 100)
    r = run_inprocess(["garment", "fit", bad, "--stature", "1.7", "--out", tmp_path / "o"], capfd)
    assert_clean_error(r, 2, "unreadable video")
    assert not (tmp_path / "o").exists()


def test_video_without_a_person(tmp_path, capfd):
    rng = np.random.default_rng(0)
    plate = rng.integers(40, 200, (64, 48, 3)).astype(np.uint8)
    clip = _video(tmp_path / "empty.mp4", [plate] * 8)
    r = run_inprocess(["garment", "fit", clip, "--stature", "1.7", "--out", tmp_path / "o"], capfd)
    assert_clean_error(r, 2, "no person found")
    assert not (tmp_path / "o").exists()


def test_video_of_noise_is_not_a_person(tmp_path, capfd):
    """A clip whose every pixel changes (sensor noise, a moving camera) is refused before any fit: its
    "moving region" floods the image (it used to reach the pose fit and crash there on NaN pixels)."""
    rng = np.random.default_rng(1)
    clip = _video(tmp_path / "noise.mp4", [rng.integers(0, 255, (64, 48, 3)).astype(np.uint8) for _ in range(8)])
    r = run_inprocess(["garment", "fit", clip, "--stature", "1.7", "--out", tmp_path / "o"], capfd)
    assert_clean_error(r, 2, "not an actor")
    assert not (tmp_path / "o").exists()


def test_reversed_frame_range_of_a_video(tmp_path, capfd):
    """``--frames 5:2`` on a video: refused for its order, not reported as a 2-frame video."""
    plate = np.full((32, 32, 3), 90, np.uint8)
    clip = _video(tmp_path / "c.mp4", [plate] * 8)
    r = run_inprocess(["garment", "fit", clip, "--stature", "1.7", "--out", tmp_path / "o", "--frames", "5:2"], capfd)
    assert_clean_error(r, 2, "below END")
    assert not (tmp_path / "o").exists()


def test_video_person_masks_follow_a_moving_blob(tmp_path):
    """The plain-video path: the temporal-median background finds a moving person-sized region."""
    from bodystudio.garment.person import person_frames

    rng = np.random.default_rng(0)
    plate = rng.integers(60, 90, (96, 64, 3)).astype(np.uint8)
    frames, truth = [], []
    for k in range(10):
        f = plate.copy()
        m = np.zeros(plate.shape[:2], bool)
        m[20:80, 4 + 5 * k:16 + 5 * k] = True
        f[m] = (200, 60, 40)
        frames.append(f)
        truth.append(m)
    pf = person_frames(_video(tmp_path / "blob.mp4", frames))
    assert pf.images.shape == (10, 96, 64, 3)
    iou = [np.count_nonzero(a & b) / np.count_nonzero(a | b) for a, b in zip(pf.masks, truth, strict=True)]
    assert min(iou) > 0.8, iou


@pytest.mark.parametrize("stature, phrase", [
    (None, "--stature is required"), ("0.3", "between 0.5 and 2.5"), ("3.1", "between 0.5 and 2.5"),
    ("nan", "between 0.5 and 2.5"),
])
def test_stature_missing_or_absurd(tiny_session, tmp_path, capfd, stature, phrase):
    args = ["garment", "fit", tiny_session, "--out", tmp_path / "o"]
    if stature is not None:
        args += ["--stature", stature]
    r = run_inprocess(args, capfd)
    assert_clean_error(r, 2, phrase)
    assert not (tmp_path / "o").exists()


def test_output_folder_exists(tiny_session, tmp_path, capfd):
    out = tmp_path / "o"
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    r = run_inprocess(["garment", "fit", tiny_session, "--stature", "1.7", "--out", out], capfd)
    assert_clean_error(r, 2, "exists and is not empty")
    assert [p.name for p in out.iterdir()] == ["keep.txt"]


@pytest.mark.parametrize("frames, phrase", [("2:9", "out of range"), ("5:3", "below END"),
                                            ("a:b", "use START:END"), ("1:2:3", "use START:END")])
def test_frames_out_of_range(tiny_session, tmp_path, capfd, frames, phrase):
    r = run_inprocess(["garment", "fit", tiny_session, "--stature", "1.7", "--out", tmp_path / "o",
                       "--frames", frames], capfd)
    assert_clean_error(r, 2, phrase)
    assert not (tmp_path / "o").exists()


def test_focal_and_template_refused(tiny_session, tmp_path, capfd):
    r = run_inprocess(["garment", "fit", tiny_session, "--stature", "1.7", "--out", tmp_path / "o",
                       "--focal-px", "1"], capfd)
    assert_clean_error(r, 2, "--focal-px 1: implausible")
    r = run_inprocess(["garment", "fit", tiny_session, "--stature", "1.7", "--out", tmp_path / "o",
                       "--template", "50k"], capfd)
    assert_clean_error(r, 2, "--template '50k'")
    assert not (tmp_path / "o").exists()


def test_bad_keyframes_file(tiny_session, tmp_path, capfd):
    keys = tmp_path / "keys.json"
    keys.write_text("{not json")
    r = run_inprocess(["garment", "fit", tiny_session, "--stature", "1.7", "--out", tmp_path / "o",
                       "--keyframes", keys], capfd)
    assert_clean_error(r, 2, "unreadable keyframe constraints")
    r = run_inprocess(["garment", "fit", tiny_session, "--stature", "1.7", "--out", tmp_path / "o",
                       "--keyframes", tmp_path / "missing.json"], capfd)
    assert_clean_error(r, 2, "--keyframes")
    assert not (tmp_path / "o").exists()


def test_eval_garment_bad_folder(tmp_path, capfd):
    r = run_inprocess(["eval", "garment", tmp_path / "nofit"], capfd)
    assert_clean_error(r, 2, "not found")


# A short fit (one shape round skipped, one solver step per frame): the write protocol is what is tested.
QUICK_FIT = """
import functools
import bodystudio.garment.fit as f
f.estimate_shape = functools.partial(f.estimate_shape, n_reference=1, rounds=0)
_ffp = f.fit_frame_pose
f.fit_frame_pose = lambda x0, problem, max_nfev=1: _ffp(x0, problem, max_nfev=1)
_app = f.estimate_appearance
f.estimate_appearance = functools.partial(_app, max_frames=1, iterations=1)
import bodystudio.garment.shape_refine as sr
sr.refine_shape_to_silhouettes = functools.partial(sr.refine_shape_to_silhouettes, iterations=1)
"""


# The first (complete) run records its fit; the runs killed at a file event replay it into their folder instead of
# fitting again: the fit's files are its only file events (the same ones, checked against a fitting child).
RECORD_FIT = """
import pickle
_fit_video = f.fit_garment_video
def recorded(*args, **kwargs):
    fit = _fit_video(*args, **kwargs)
    open({path!r}, "wb").write(pickle.dumps(fit))
    return fit
f.fit_garment_video = recorded
"""
REPLAY_FIT = """
import pickle
import bodystudio.garment.fit as f
from bodystudio.garment.fitfile import save_garment_fit
def replayed(source, stature_m, out_dir=None, **kwargs):
    fit = pickle.loads(open({path!r}, "rb").read())
    save_garment_fit(out_dir, fit)
    return fit
f.fit_garment_video = replayed
"""


def test_killed_fit_leaves_no_half_written_folder(tiny_session, tmp_path):
    from bodystudio.errors import BodyStudioError
    from bodystudio.garment.fitfile import load_garment_fit

    recorded = tmp_path / "fit.pkl"
    setup, replay = tmp_path / "quick.py", tmp_path / "replay.py"
    setup.write_text(QUICK_FIT + RECORD_FIT.format(path=str(recorded)))
    replay.write_text(REPLAY_FIT.format(path=str(recorded)))
    work = tmp_path / "w"
    work.mkdir()
    log = tmp_path / "events.json"
    args = ["garment", "fit", str(tiny_session), "--stature", "1.7", "--out", "fit"]
    done = run_child(args, work, event_log=log, setup=setup)
    assert done.returncode == 0, done.stderr[-1500:]
    full = load_garment_fit(work / "fit")
    events = [e for e in read_events(log) if "readers/" not in e]
    assert len(events) >= 4
    for k in sorted({1, 2, len(events) // 2, len(events) - 1, len(events)}):
        w = tmp_path / f"k{k}"
        w.mkdir()
        r = run_child(args, w, kill_at=k, setup=replay)
        assert r.returncode == -9
        out = w / "fit"
        if k == len(events):  # killed at the very last rename: the fit is complete or refused, never mixed
            try:
                back = load_garment_fit(out)
            except BodyStudioError:
                continue
            np.testing.assert_allclose(back.rotations, full.rotations)
            continue
        with pytest.raises(BodyStudioError):  # unfinished (FileFormatError) or mid-commit (OutputLockedError)
            load_garment_fit(out)


def test_background_plate_errors(tiny_session, tmp_path, capfd):
    """--background: missing image, another size than the video, given with a session: one line, no output."""
    import cv2

    frames = [cv2.imread(str(p))[..., ::-1] for p in sorted((tiny_session / "cam_00" / "rgb").glob("*.png"))]
    clip = _video(tmp_path / "clip.mp4", frames)
    small = tmp_path / "small.png"
    cv2.imwrite(str(small), np.zeros((10, 12, 3), np.uint8))
    for args, phrase in ((["--background", tmp_path / "nope.png"], "no such image"),
                         (["--background", small], "12x10 but the video is 96x128")):
        r = run_inprocess(["garment", "fit", clip, "--stature", "1.7", "--out", tmp_path / "o", *args], capfd)
        assert_clean_error(r, 2, phrase)
        assert not (tmp_path / "o").exists()
    r = run_inprocess(["garment", "fit", tiny_session, "--stature", "1.7", "--out", tmp_path / "o",
                       "--background", small], capfd)
    assert_clean_error(r, 2, "is a session with its own masks")
    assert not (tmp_path / "o").exists()


def test_a_clean_plate_finds_an_actor_the_temporal_median_cannot(tiny_session, tmp_path):
    """An actor who stays on the spot is part of the video's temporal median (no person found); against the
    set's clean plate the mattes match the session's true masks."""
    import cv2

    from bodystudio.garment.person import person_frames

    frames = [cv2.imread(str(p))[..., ::-1] for p in sorted((tiny_session / "cam_00" / "rgb").glob("*.png"))]
    clip = _video(tmp_path / "still.mp4", [frames[0]] * 6)
    with pytest.raises(InputError, match="--background PLATE.png"):
        person_frames(clip)
    plate = tiny_session / "cam_00" / "background" / "00000.png"
    pf = person_frames(clip, background=plate)
    truth = cv2.imread(str(tiny_session / "cam_00" / "mask" / "00000.png"), cv2.IMREAD_GRAYSCALE) > 127
    iou = (pf.masks[0] & truth).sum() / (pf.masks[0] | truth).sum()
    assert iou > 0.75, iou  # 0.81 measured at 96x128 through H.264 (the temporal median gives no person at all)
