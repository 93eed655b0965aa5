"""Which init frames enter the source-body fit (mir12w): ``"first"`` (the default) and ``"spread"``.

Stand-in transform and Eq. 2 fit on the 2k model (fast): the frames handed to the fit are recorded. Each cloud is cut
to MAX_POINTS before frames are ranked by their point count, so under ``"first"`` a walk-in's frames, which all reach
it, tie and the first MAX_FIT_FRAMES win (on the mirror sessions: all side-on); ``"spread"`` takes them evenly over
the usable frames, the first and the last included.
"""

import functools

import numpy as np
import pytest

from bodystudio.body.kinect import kinect_joint_names
from bodystudio.errors import InputError
from bodystudio.mirror import init as init_mod
from bodystudio.mirror.init import INIT_FRAME_CHOICE, MAX_FIT_FRAMES, MAX_POINTS, InitObservation

J = len(kinect_joint_names("v2"))


@functools.lru_cache(maxsize=1)
def _model_2k():
    from bodystudio.body.statistical import load_statistical_model

    return load_statistical_model("2k", progress=False)


@pytest.fixture(scope="module")
def model():
    return _model_2k()


def _observations(counts):
    """One observation per point count (frame numbers 3 apart, as collect_observations reads them)."""
    rng = np.random.default_rng(0)
    return [InitObservation(3 * i, rng.normal(0.0, 0.3, (n, 3)) + [0.0, 1.0, 2.5], np.zeros((J, 3)),
                            np.ones(J, bool), "v2") for i, n in enumerate(counts)]


@pytest.fixture()
def fitted_frames(monkeypatch):
    """Runs the initialisation with stand-ins and returns the frame numbers whose clouds reached the fit."""
    from bodystudio.mirror.init import DefaultPoseCloud

    seen = []

    def transform(P, joints, body, tracked=None, version="v2", details=False, **kwargs):
        seen.append(len(seen))
        n = len(P)
        return DefaultPoseCloud(np.asarray(P, float), np.arange(n) % len(body.vertices),
                                np.arange(len(body.vertices)), None, body)

    def fit(P, model, *args, **kwargs):
        return (np.zeros(model.n_components), 0.01)

    monkeypatch.setattr(init_mod, "transform_to_default_pose", transform)
    monkeypatch.setattr(init_mod, "fit_shape", fit)

    def run(model, obs, **kwargs):
        source = init_mod.initialise_from_observations(obs, model, passes=1, **kwargs)
        assert len(seen) == len(source.frames_used)  # each fitted frame transformed once in the one pass
        seen.clear()
        return list(source.frames_used)

    return run


def test_first_takes_the_first_frames_of_a_walk_in(model, fitted_frames):
    """28 frames that all reach MAX_POINTS (a walk-in: fewer raw points side-on, more facing the sensor) tie after
    the cut, so the default keeps the first 15: the later, fuller frames never enter (what the mirror sessions do)."""
    assert INIT_FRAME_CHOICE == "first"
    counts = [MAX_POINTS + 100] * 14 + [3 * MAX_POINTS] * 14
    obs = _observations(counts)
    assert fitted_frames(model, obs) == [3 * i for i in range(MAX_FIT_FRAMES)]
    assert fitted_frames(model, obs, frame_choice="first") == [3 * i for i in range(MAX_FIT_FRAMES)]
    # below the cut the count still ranks: the frames with fewer points are the ones left out
    small = _observations([MAX_POINTS // 2] * 5 + [MAX_POINTS + 100] * 20)
    assert fitted_frames(model, small) == [3 * i for i in range(5, 5 + MAX_FIT_FRAMES)]


def test_spread_takes_frames_evenly_over_the_usable_ones(model, fitted_frames):
    obs = _observations([MAX_POINTS + 100] * 14 + [3 * MAX_POINTS] * 14)
    got = fitted_frames(model, obs, frame_choice="spread")
    assert len(got) == MAX_FIT_FRAMES
    assert got[0] == 0 and got[-1] == 3 * 27  # the first and the last usable frame
    steps = np.diff(got) // 3
    assert set(steps) <= {1, 2} and steps.sum() == 27  # no gap wider than two reads
    assert sum(f >= 3 * 14 for f in got) >= 7  # half of them from the later (facing) half
    # a frame with too few points is not usable and is not counted in the spread
    obs[27] = _observations([10])[0]
    got = fitted_frames(model, obs, frame_choice="spread")
    assert 3 * 27 not in got and got[-1] == 3 * 26 and len(got) == MAX_FIT_FRAMES


def test_spread_with_no_more_frames_than_fitted_takes_them_all(model, fitted_frames):
    obs = _observations([MAX_POINTS] * 6)
    assert fitted_frames(model, obs, frame_choice="spread") == fitted_frames(model, obs) == [0, 3, 6, 9, 12, 15]


@pytest.mark.parametrize("bad", ["most", "", "Spread"])
def test_an_unknown_frame_choice_is_refused(model, bad):
    obs = _observations([MAX_POINTS] * 3)
    with pytest.raises(InputError, match="frame_choice must be 'first' or 'spread'"):
        init_mod.initialise_from_observations(obs, model, passes=1, frame_choice=bad)
