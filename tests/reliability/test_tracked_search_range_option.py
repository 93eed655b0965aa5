"""``TrackParams(tau_px=...)`` and ``TrackParams(neck_joint=...)`` (rec15l): the tracked frame's contour search range,
15 px by default, 0 for the run's, out-of-range values one-line errors naming the setting and its range; the neck
on the tracked Neck joint, on by default. Wiring and effect: tests/reconstruct/test_tracked_search_range.py and
test_neck_at_joint.py."""

import pytest

from bodystudio.errors import InputError
from bodystudio.reconstruct.rapid_skin import RapidSkinParams
from bodystudio.reconstruct.tracking import TrackParams


def test_the_default_and_the_refusals():
    assert TrackParams().tau_px == 15.0
    assert RapidSkinParams().tau_px == 30.0  # the per-frame path keeps the paper's
    for ok in (0.0, 500.0):
        TrackParams(tau_px=ok)
    for bad in (-1.0, 500.5, float("nan")):
        with pytest.raises(InputError, match=r"^tracking tau_px .* is out of range; use a value in \[0, 500\]$"):
            TrackParams(tau_px=bad)
    assert TrackParams(tau_px=0).tau_px == 0


def test_the_neck_placement_is_on_by_default_and_recorded():
    """``TrackParams(neck_joint=...)`` (rec15l): on by default, off by ``False``; run.json's ``track_params`` (the
    dataclass as a dict) records both new settings."""
    from dataclasses import asdict

    assert TrackParams().neck_joint is True
    assert TrackParams(neck_joint=False).neck_joint is False
    rec = asdict(TrackParams(tau_px=12.5, neck_joint=False))
    assert rec["tau_px"] == 12.5 and rec["neck_joint"] is False


def test_the_unstretched_head_is_on_by_default_and_recorded():
    """``TrackParams(unstretch_head=...)`` (rec15m): on by default, off by ``False`` (the head keeps Eq. 11's segment
    stretch, rec15l's placement); run.json's ``track_params`` records it; ``--accurate`` keeps the stretch. Effect:
    test_unstretched_head.py."""
    from dataclasses import asdict

    from bodystudio.reconstruct.presets import ACCURATE_SETTINGS

    assert TrackParams().unstretch_head is True
    assert asdict(TrackParams(unstretch_head=False))["unstretch_head"] is False
    # --accurate keeps the head's stretch (measured worse there: p90 higher on 5 of 7 sessions), its tracker otherwise
    # the default's
    assert ACCURATE_SETTINGS["track_params"] == TrackParams(unstretch_head=False)


def test_the_initialised_frames_outer_count_default_range_and_record():
    """``TrackParams(initial_outer_iterations=...)`` (rec15m): 3 by default, 0 for the run's ``No``, out-of-range
    values a one-line error naming the setting and its range; run.json records it. Wiring:
    tests/reconstruct/test_initial_outer_iterations.py."""
    from dataclasses import asdict

    assert TrackParams().initial_outer_iterations == 3
    for ok in (0, 100):
        TrackParams(initial_outer_iterations=ok)
    for bad in (-1, 101, float("nan")):
        with pytest.raises(InputError, match=r"^tracking initial_outer_iterations .* is out of range; use a value in "
                                             r"\[0, 100\]$"):
            TrackParams(initial_outer_iterations=bad)
    assert asdict(TrackParams(initial_outer_iterations=0))["initial_outer_iterations"] == 0
