"""``eval garment DIR --session S`` refuses a session that is not the fit's recording (a score against another
recording's ground truth would be meaningless with exit 0); the fit's own session, moved, still scores."""

import dataclasses
import shutil

import pytest

from .conftest import assert_clean_error, run_inprocess


@pytest.fixture(scope="module")
def two_sessions(tmp_path_factory):
    """Two 2-frame 120x160 synthetic garment sessions (subjects 3 and 4), a 96x128 one, and the oracle fit of
    the first, saved once as a fit of a session (with its frames' fingerprint) and once as a fit of a video
    (no fingerprint)."""
    from bodystudio.capture.session import open_session, stream_fingerprint
    from bodystudio.garment.composite import ground_truth_fit
    from bodystudio.garment.fitfile import save_garment_fit
    from bodystudio.garment.synthetic import synth_garment_session

    root = tmp_path_factory.mktemp("gsrc")
    kw = dict(n_frames=2, template="2k", texture_size=32, seed=2, shadows=False)
    a = synth_garment_session(root / "a", subject_seed=3, resolution=(120, 160), **kw)
    synth_garment_session(root / "b", subject_seed=4, resolution=(120, 160), **kw)
    synth_garment_session(root / "small", subject_seed=3, resolution=(96, 128), **kw)
    fit = ground_truth_fit(a)
    s = open_session(root / "a")
    fp = stream_fingerprint(s, "rgb", fit.frame_ids, s.camera_names[0])
    assert fp is not None
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
