"""``reconstruct_session(..., shape_prior="carried", shape_prior_region=...)`` (issue 15, rec15p): the shape prior
fitted to a tracked run's (re-)initialised frames and carried into its tracked frames, optionally only in named
regions. Off by default (``shape_prior="off"``, ``shape_prior_region="all"``); ``carried`` without tracking and an
unknown or empty region name are one-line errors naming the setting and the fix, raised before any frame is
deformed. Wiring and effect: tests/reconstruct/test_shape_prior_carried.py."""

import inspect

import pytest

import bodystudio.reconstruct.sequence as seq
from bodystudio.errors import InputError
from tests.reconstruct.test_shape_prior_carried import _carried_run


def test_the_defaults_are_auto():
    """'auto': the gated carried prior with tracking (TRACKED_SHAPE_PRIOR, rec15q), off without."""
    for fn in (seq.reconstruct_session, seq.reconstruct_frames):
        params = inspect.signature(fn).parameters
        assert params["shape_prior"].default == "auto"
        assert params["shape_prior_region"].default is None
    assert seq.resolve_shape_prior(False) == ("off", 0.0, "all")
    assert seq.resolve_shape_prior(True)[0] == "carried"
    assert "carried" in seq.SHAPE_PRIORS
    assert seq.SHAPE_PRIOR_REGIONS == ("head", "torso", "lower_torso", "crotch", "arms", "hands", "legs", "feet")


def test_carried_needs_tracking(monkeypatch, tmp_path):
    with pytest.raises(InputError, match=r"^shape prior 'carried' carries the initialised frames' shape into the "
                                         r"tracked frames; use it with tracking, or shape_prior 'run' / 'frame'$"):
        _carried_run(monkeypatch, tmp_path, tracking=False)


@pytest.mark.parametrize("bad", ["back", "crotch+", "", "crotch+Legs", "+"])
def test_unknown_regions_are_refused_before_any_frame(monkeypatch, tmp_path, bad):
    with pytest.raises(InputError, match=r"^shape_prior_region .*: give all or region names joined by \+ "
                                         r"\(head, torso, lower_torso, crotch, arms, hands, legs, feet\)$"):
        _carried_run(monkeypatch, tmp_path, region=bad)


@pytest.mark.parametrize("ok", ["crotch", "crotch+legs", "lower_torso+crotch", "all"])
def test_region_names_accepted_and_recorded(monkeypatch, tmp_path, ok):
    _rec, _fits, _poses, writer = _carried_run(monkeypatch, tmp_path, region=ok)
    assert writer.meta["shape_prior_region"] == ok
