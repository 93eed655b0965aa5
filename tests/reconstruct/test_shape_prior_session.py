"""reconstruct_session's shape prior (issue 15): the passes each mode runs, what run.json records, the accuracy
it keeps on a small session, and the one-line errors."""

import json

import pytest

from bodystudio.errors import InputError
from bodystudio.reconstruct.rapid_skin import RapidSkinParams
from bodystudio.reconstruct.sequence import reconstruct_session


@pytest.fixture(scope="module")
def small_session(tmp_path_factory):
    from bodystudio.capture.synth import synth_session

    out = tmp_path_factory.mktemp("sp") / "walk"
    return synth_session(out, n_cameras=4, n_frames=2, motion="walk", subject_seed=23, resolution=(320, 240),
                         template="2k", noise=False)


def _run(session, **kw):
    summary = reconstruct_session(session.path, template="2k", params=RapidSkinParams(outer_iterations=3), **kw)
    frames = json.loads((session.path / "reconstruct" / "frames.json").read_text())["frames"]
    run = json.loads((session.path / "reconstruct" / "run.json").read_text())
    return summary, frames, run


def test_shape_prior_passes_and_record(small_session):
    off, frames_off, run_off = _run(small_session)
    assert run_off["shape_prior"] == "off" and [len(f["n_silhouette"]) for f in frames_off] == [3, 3]
    frame, frames, run = _run(small_session, shape_prior="frame", shape_prior_outer=2)
    # every frame: the first pass (No = 3) then the second from the fitted shape (2)
    assert run["shape_prior"] == "frame" and run["shape_prior_outer"] == 2
    assert [len(f["n_silhouette"]) for f in frames] == [5, 5]
    _, frames_short, run_short = _run(small_session, shape_prior="frame", shape_prior_outer=2,
                                      shape_prior_first_outer=1)
    # the pass the shape space is fitted to stopped after one matching
    assert run_short["shape_prior_first_outer"] == 1 and [len(f["n_silhouette"]) for f in frames_short] == [3, 3]
    whole, frames_run, _ = _run(small_session, shape_prior="run")
    # the run's shape: two passes at the first frame, one from the fitted shape after it
    assert [len(f["n_silhouette"]) for f in frames_run] == [6, 3]
    # 4 cameras at 320x240 (a pixel ~1.5 cm): the prior keeps the deformation's accuracy
    for s in (frame, whole):
        assert s["median_mm"] < off["median_mm"] + 0.5
        assert s["p90_mm"] < off["p90_mm"] + 1.5


def test_shape_prior_errors(small_session):
    with pytest.raises(InputError, match="unknown shape prior 'pca'"):
        reconstruct_session(small_session.path, template="2k", shape_prior="pca")
    with pytest.raises(InputError, match="shape_prior_outer"):
        reconstruct_session(small_session.path, template="2k", shape_prior="frame", shape_prior_outer=-1)
    with pytest.raises(InputError, match="shape_prior_first_outer"):
        reconstruct_session(small_session.path, template="2k", shape_prior="frame", shape_prior_first_outer=101)
