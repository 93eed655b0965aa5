"""A tracked run's first and re-initialised frames re-match ``TrackParams.initial_outer_iterations`` times (issue 15's
worst regions, rec15m: the upper back drifts outwards over the later of the run's 8 re-matchings, walk 31 frame 0
40.3 -> 27.2 mm with 3), never more than the run's ``No``; tracked frames and the per-frame mode are unchanged.
On the stand-ins of test_sequence_tracked_mutants (the run's wiring; the effect: docs/reconstruct.md)."""

from dataclasses import replace

import pytest

from bodystudio.reconstruct.rapid_skin import RapidSkinParams
from bodystudio.reconstruct.tracking import TrackParams
from tests.reconstruct.test_sequence_tracked_mutants import EXPECTED_TRACK, OUTSIDE_PX, _run, _stand_ins


@pytest.mark.parametrize(("run_no", "initial", "first_no"), [(8, 3, 3), (2, 3, 2), (8, 0, 8), (8, 5, 5)])
def test_the_initialised_frames_take_the_smaller_count(monkeypatch, tmp_path, run_no, initial, first_no):
    rec = _stand_ins(monkeypatch)
    params = RapidSkinParams(outer_iterations=run_no)
    # the sweeps of those frames held at the run's (rec15n's initial_inner_iterations: test_tracked_sweeps.py)
    track = TrackParams(outside_px=OUTSIDE_PX, initial_outer_iterations=initial, initial_inner_iterations=0)
    _run(rec, tmp_path, params=params, track=track)
    deform = rec.calls["deform"]
    assert len(deform) == len(EXPECTED_TRACK)
    for d, t in zip(deform, EXPECTED_TRACK, strict=True):
        if t == "tracked":  # the tracked frame's own settings, as before
            assert d["params"] == replace(params, outer_iterations=min(run_no, track.outer_iterations),
                                          matching=track.matching, tau_px=min(params.tau_px, track.tau_px),
                                          inner_iterations=track.inner_iterations)
        elif initial:  # first, silhouette, joint_jump, energy_jump: only the count changes
            assert d["params"] == replace(params, outer_iterations=first_no)
        else:
            assert d["params"] is params


def test_the_default_and_the_per_frame_mode(monkeypatch, tmp_path):
    assert TrackParams().initial_outer_iterations == 3
    rec = _stand_ins(monkeypatch)
    params = RapidSkinParams(outer_iterations=8)
    _run(rec, tmp_path, params=params, tracking=False, track=TrackParams(outside_px=OUTSIDE_PX))
    assert rec.calls["deform"] and all(d["params"] is params for d in rec.calls["deform"])
