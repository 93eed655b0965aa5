"""``TrackParams(inner_iterations=..., initial_outer_iterations=..., initial_inner_iterations=...)`` (rec15n):
the tracked frame's Gauss-Seidel sweeps per outer iteration, 40 by default with 2 outer iterations (was the run's 8
with 3), and a tracked run's re-initialised frames' 3 x 40 (was the run's 8 x 8); 0 for the run's, out-of-range
values one-line errors naming the setting and its range. Wiring and effect: tests/reconstruct/test_tracked_sweeps.py."""

from dataclasses import asdict

import pytest

from bodystudio.errors import InputError
from bodystudio.reconstruct.rapid_skin import RapidSkinParams
from bodystudio.reconstruct.tracking import TrackParams


def test_the_default_and_the_refusals():
    assert TrackParams().inner_iterations == 40 and TrackParams().outer_iterations == 2
    assert RapidSkinParams().inner_iterations == 8  # the per-frame path keeps the paper's
    for ok in (0, 1000):
        TrackParams(inner_iterations=ok)
    for bad in (-1, 1001, float("nan")):
        with pytest.raises(InputError, match=r"^tracking inner_iterations .* is out of range; use a value in "
                                             r"\[0, 1000\]$"):
            TrackParams(inner_iterations=bad)
    assert asdict(TrackParams(inner_iterations=12))["inner_iterations"] == 12  # run.json's track_params


def test_the_first_frames_default_and_refusals():
    assert (TrackParams().initial_outer_iterations, TrackParams().initial_inner_iterations) == (3, 64)  # rec15p
    assert (RapidSkinParams().outer_iterations, RapidSkinParams().inner_iterations) == (8, 8)  # per-frame: the paper's
    for name, hi in (("initial_outer_iterations", 100), ("initial_inner_iterations", 1000)):
        TrackParams(**{name: 0})
        TrackParams(**{name: hi})
        for bad in (-1, hi + 1, float("nan")):
            with pytest.raises(InputError, match=rf"^tracking {name} .* is out of range; use a value in \[0, {hi}\]$"):
                TrackParams(**{name: bad})
