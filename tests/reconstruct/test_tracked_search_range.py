"""The tracked frame's contour search range (``TrackParams.tau_px``, issue 15's worst regions, rec15l): a tracked
frame searches at most ``tau_px`` for its contours, never more than the run's ``tau``, and a re-initialised frame
keeps the run's; on stand-ins (the run's wiring) and on a head beside a raised 'arm' (the cause: a rim vertex whose
outward search reaches another part's contour far out)."""

from dataclasses import replace

import numpy as np
import pytest

from bodystudio.reconstruct.rapid_skin import RapidSkinParams
from bodystudio.reconstruct.tracking import TrackParams
from tests.reconstruct.test_sequence_tracked_mutants import EXPECTED_TRACK, OUTSIDE_PX, _run, _stand_ins


@pytest.mark.parametrize(("run_tau", "track_tau", "tracked_tau"), [(30.0, 15.0, 15.0), (12.0, 15.0, 12.0),
                                                                   (30.0, 0.0, 30.0), (30.0, 22.5, 22.5)])
def test_tracked_frames_search_the_nearer_range(monkeypatch, tmp_path, run_tau, track_tau, tracked_tau):
    rec = _stand_ins(monkeypatch)
    params = RapidSkinParams(outer_iterations=5, tau_px=run_tau)
    track = TrackParams(outside_px=OUTSIDE_PX, tau_px=track_tau)
    _run(rec, tmp_path, params=params, track=track)
    deform = rec.calls["deform"]
    assert [d["params"].tau_px for d in deform] == [tracked_tau if t == "tracked" else run_tau
                                                    for t in EXPECTED_TRACK]
    for d, t in zip(deform, EXPECTED_TRACK, strict=True):
        if t == "tracked":  # nothing else of the run's settings changes with it
            assert d["params"] == replace(params, outer_iterations=track.outer_iterations, matching=track.matching,
                                          tau_px=tracked_tau, inner_iterations=track.inner_iterations)
        else:  # a re-initialised frame: the tracker's first-frame sweeps (rec15n), the run's search range
            assert d["params"] == replace(params, outer_iterations=track.initial_outer_iterations,
                                          inner_iterations=track.initial_inner_iterations)


@pytest.fixture(scope="module")
def head_touching_arm():
    """The template 'head' sphere (exact: a tracked frame starts a few mm off) and an 'arm' sphere 1 cm beside it
    that only the images show; six ring cameras 320x240 (f 500 px, 3 m): in most views the two merge."""
    from bodystudio.geometry.camera import Camera
    from bodystudio.reconstruct.silhouette import silhouette_mask
    from tests.reconstruct.test_hull_gate import ARM_R, HEAD_R, _sphere

    V, F = _sphere(HEAD_R)
    Va, Fa = _sphere(ARM_R, (HEAD_R + 0.01 + ARM_R, 0.0, 0.0))
    scene_V, scene_F = np.vstack([V, Va]), np.vstack([F, Fa + len(V)])
    cams = [Camera.look_at(f"c{i}", (3 * np.sin(a), 0.4, 3 * np.cos(a)), (0, 0, 0), fx=500.0, width=320, height=240)
            for i, a in enumerate(np.linspace(0.0, 2 * np.pi, 6, endpoint=False) + 0.3)]
    return V, F, cams, {c.name: silhouette_mask(scene_V, scene_F, c) for c in cams}


def test_far_crossings_are_the_other_parts_and_the_nearer_range_drops_them(head_touching_arm):
    """With the visual-hull gate on (the default), the paper's 30 px reach the arm's far contour from head rim
    vertices inside the merged silhouettes, and the gate keeps some of those pulls (their targets lie inside the
    loose six-view hull): a spike 40 mm off the head. The tracked frame's 15 px do not reach it."""
    from bodystudio.reconstruct.rapid_skin import deform_to_observations
    from tests.reconstruct.test_hull_gate import _radial_error_mm

    V, F, cams, masks = head_touching_arm
    err = {tau: _radial_error_mm(deform_to_observations(V, F, cams, masks, RapidSkinParams(
        outer_iterations=3, inner_iterations=8, tau_px=tau)).vertices) for tau in (30.0, TrackParams().tau_px)}
    assert err[30.0].max() > 30.0  # measured 39.8 mm
    assert err[15.0].max() < 20.0  # measured 15.3 mm
    assert np.median(err[15.0]) < 1.5  # measured 0.9 mm (both)
