"""``TrackParams(tau_px=...)`` (rec15l): the tracked frame's contour search range, 15 px by default, 0 for the run's;
out-of-range values are one-line errors naming the setting and its range. Its wiring and its effect:
tests/reconstruct/test_tracked_search_range.py."""

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
