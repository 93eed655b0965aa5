"""``eval garment DIR --session S`` refuses a session that is not the fit's recording (a score against another
recording's ground truth would be meaningless with exit 0); the fit's own session, moved, still scores.
``garment render`` refuses a source that changed since the fit (another clip at the same path)."""

import dataclasses
import shutil

import pytest

from .conftest import assert_clean_error, run_inprocess


@pytest.fixture(scope="module")
def two_sessions(tmp_path_factory):
    """Two 2-frame 120x160 synthetic garment sessions (subjects 3 and 4), a 96x128 one, and the oracle fit of
    the first, saved once as a fit of a session (with its frames' fingerprint) and once as a fit of a video
    (no fingerprint)."""
    from bodystudio.capture.session import open_session
    from bodystudio.garment.composite import ground_truth_fit
    from bodystudio.garment.fitfile import save_garment_fit
    from bodystudio.garment.person import source_fingerprint
    from bodystudio.garment.synthetic import synth_garment_session

    root = tmp_path_factory.mktemp("gsrc")
    kw = dict(n_frames=2, template="2k", texture_size=32, seed=2, shadows=False)
    a = synth_garment_session(root / "a", subject_seed=3, resolution=(120, 160), **kw)
    synth_garment_session(root / "b", subject_seed=4, resolution=(120, 160), **kw)
    synth_garment_session(root / "small", subject_seed=3, resolution=(96, 128), **kw)
    fit = ground_truth_fit(a)
    s = open_session(root / "a")
    fp = source_fingerprint(s, fit.frame_ids)
    assert fp.startswith("session:")
    save_garment_fit(root / "fit_session", dataclasses.replace(fit, source_fingerprint=fp), "test")
    save_garment_fit(root / "fit_video", dataclasses.replace(fit, source=str(root / "clip.mp4")), "test")
    return root


def test_a_fit_of_a_session_is_refused_against_another_recording(two_sessions, tmp_path, capfd):
    root = two_sessions
    r = run_inprocess(["eval", "garment", root / "fit_session", "--session", root / "b"], capfd)
    assert_clean_error(r, 2, "fitted on another recording than")
    moved = tmp_path / "moved"
    shutil.copytree(root / "a", moved)
    r = run_inprocess(["eval", "garment", root / "fit_session", "--session", moved], capfd)
    assert_clean_error(r, 0, "")
    assert '"stature_err_mm"' in r.stdout


def test_a_fit_of_a_video_needs_the_sessions_frames_and_size(two_sessions, capfd):
    root = two_sessions
    r = run_inprocess(["eval", "garment", root / "fit_video", "--session", root / "small"], capfd)
    assert_clean_error(r, 2, "the fit's frames are 120x160")
    r = run_inprocess(["eval", "garment", root / "fit_video", "--session", root / "a"], capfd)
    assert_clean_error(r, 0, "")


def test_render_refuses_a_source_that_changed_since_the_fit(two_sessions, tmp_path, capfd):
    """A fit of a video whose file was replaced by another clip of the same size and length: the garment would
    be composited onto frames it was not fitted to. Refused before anything is written; the session fit whose
    folder was replaced by another recording likewise."""
    from dataclasses import replace

    import imageio_ffmpeg
    import numpy as np

    from bodystudio.capture.session import open_session
    from bodystudio.garment.fitfile import load_garment_fit, save_garment_fit
    from bodystudio.garment.person import source_fingerprint

    root = two_sessions
    fit = load_garment_fit(root / "fit_session")

    def clip(path, session):
        w = imageio_ffmpeg.write_frames(str(path), (120, 160), fps=30, macro_block_size=8, ffmpeg_log_level="error")
        w.send(None)
        for i in range(2):
            w.send(np.ascontiguousarray(open_session(session).frame(i).images["cam_00"]))
        w.close()

    video = tmp_path / "actor.mp4"
    clip(video, root / "a")
    d = tmp_path / "fit"
    save_garment_fit(d, replace(fit, source=str(video), source_fingerprint=source_fingerprint(video, fit.frame_ids)),
                     "test")
    clip(video, root / "b")  # another actor at the same path
    r = run_inprocess(["garment", "render", d, "--out", tmp_path / "o.mp4"], capfd)
    assert_clean_error(r, 2, "not the recording the fit was made from")
    assert not (d / "render").exists() and not (tmp_path / "o.mp4").exists()
    clip(video, root / "a")  # restored: renders
    r = run_inprocess(["garment", "render", d, "--out", tmp_path / "o.mp4", "--no-flow", "--no-rbf"], capfd)
    assert_clean_error(r, 0, "")
    # a session fit whose folder now holds another recording
    moved = tmp_path / "sess"
    import shutil

    shutil.copytree(root / "b", moved)
    d2 = tmp_path / "fit2"
    save_garment_fit(d2, replace(fit, source=str(moved)), "test")
    r = run_inprocess(["garment", "render", d2, "--out", tmp_path / "o2.mp4"], capfd)
    assert_clean_error(r, 2, "not the recording the fit was made from")
