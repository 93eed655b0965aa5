"""The tracked and re-initialised frames' iteration counts kept apart (issue 17, mutation testing of rec15m / rec15n's
lines of ``reconstruct_frames``): with the tracked frame's own counts at 0 (the run's) and the first frames' set, a
tracked frame must run the run's ``No`` x ``Ni``, not the re-initialised frames' 3 x 24; the files before only set the
first frames' counts with the tracked ones non-zero, whose ``replace(params, ...)`` hid a tracked frame taking them.
On the stand-ins of test_sequence_tracked_mutants (no template, no solve); < 0.5 s."""

from dataclasses import replace

from bodystudio.reconstruct.rapid_skin import RapidSkinParams
from bodystudio.reconstruct.tracking import TrackParams
from tests.reconstruct.test_sequence_tracked_mutants import EXPECTED_TRACK, OUTSIDE_PX, _run, _stand_ins


def test_a_tracked_frame_with_the_runs_counts_does_not_take_the_first_frames(monkeypatch, tmp_path):
    rec = _stand_ins(monkeypatch)
    params = RapidSkinParams(outer_iterations=5, inner_iterations=8)
    track = TrackParams(outside_px=OUTSIDE_PX, outer_iterations=0, inner_iterations=0, initial_outer_iterations=3,
                        initial_inner_iterations=24)
    _run(rec, tmp_path, params=params, track=track)
    seen = [(d["params"].outer_iterations, d["params"].inner_iterations) for d in rec.calls["deform"]]
    assert seen == [(5, 8) if t == "tracked" else (3, 24) for t in EXPECTED_TRACK]
    for d, t in zip(rec.calls["deform"], EXPECTED_TRACK, strict=True):
        if t == "tracked":  # the run's settings with the tracked frame's matching and search range only
            assert d["params"] == replace(params, matching=track.matching, tau_px=track.tau_px)
        else:
            assert d["params"] == replace(params, outer_iterations=3, inner_iterations=24)
