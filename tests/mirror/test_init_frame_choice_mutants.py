"""mir12w's ``frame_choice`` lines against hand-computed frame lists (docs/mutation/mirror-init.md): the stand-ins
of ``test_init_frame_choice.py`` without a fixture over ``monkeypatch`` (so the direct recheck can run them)."""

import numpy as np
import pytest

from bodystudio.errors import InputError
from bodystudio.mirror import init as init_mod
from bodystudio.mirror.init import MAX_FIT_FRAMES, MAX_POINTS, DefaultPoseCloud
from tests.mirror.test_init_frame_choice import _model_2k, _observations


def _fitted(monkeypatch, obs, **kwargs):
    def transform(P, joints, body, tracked=None, version="v2", details=False, **kw):
        n = len(P)
        return DefaultPoseCloud(np.asarray(P, float), np.arange(n) % len(body.vertices),
                                np.arange(len(body.vertices)), None, body)

    monkeypatch.setattr(init_mod, "transform_to_default_pose", transform)
    monkeypatch.setattr(init_mod, "fit_shape", lambda P, m, *a, **kw: (np.zeros(m.n_components), 0.01))
    return list(init_mod.initialise_from_observations(obs, _model_2k(), passes=1, **kwargs).frames_used)


def test_spread_is_the_rounded_even_spacing(monkeypatch):
    """28 usable frames, 15 fitted: indices round(27 i / 14) = 0 2 4 6 8 10 12 14 15 17 19 21 23 25 27 (13.5 rounds
    to 14, numpy's half to even), frame numbers 3 apart; the default ("first") the first 15 of the tied frames."""
    assert MAX_FIT_FRAMES == 15
    obs = _observations([MAX_POINTS + 100] * 28)
    idx = [0, 2, 4, 6, 8, 10, 12, 14, 15, 17, 19, 21, 23, 25, 27]
    assert _fitted(monkeypatch, obs, frame_choice="spread") == [3 * i for i in idx]
    assert _fitted(monkeypatch, obs) == [3 * i for i in range(15)]
    assert _fitted(monkeypatch, obs, frame_choice=None) == [3 * i for i in range(15)]
    assert _fitted(monkeypatch, obs[:15], frame_choice="spread") == [3 * i for i in range(15)]


@pytest.mark.parametrize("bad", ["most", "", "Spread", "XXspreadXX"])
def test_an_unknown_frame_choice_is_refused_by_name(bad):
    with pytest.raises(InputError, match=rf"^frame_choice must be 'first' or 'spread', got {bad!r}$"):
        init_mod.initialise_from_observations(_observations([MAX_POINTS] * 3), _model_2k(), passes=1,
                                              frame_choice=bad)


def test_first_ranks_by_point_count_then_by_order(monkeypatch):
    """5 frames of half MAX_POINTS, then 20 that reach it: "first" leaves out the 5 smaller ones and of the 20 tied
    ones keeps the first 15 (a stable ranking): frames 5..19."""
    obs = _observations([MAX_POINTS // 2] * 5 + [MAX_POINTS + 100] * 20)
    assert _fitted(monkeypatch, obs) == [3 * i for i in range(5, 20)]
