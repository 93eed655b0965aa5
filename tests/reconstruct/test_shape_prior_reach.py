"""The carried shape prior gated by the rims' reach on the back (issue 15, rec15q; ``shape_prior_reach`` of
:func:`bodystudio.reconstruct.sequence.reconstruct_session`).

``back_patch`` on the 2K template (the backward-facing skin of ``spine_02`` / ``spine_03``), ``rim_reach`` as the
exact share of a patch's vertices with a silhouette pair, ``DeformResult.silhouette_vertices`` as the last outer
iteration's pairs, and the wiring on the tracked path's stand-ins: an initialised frame whose back the rims reach
(share >= the setting) fits no coefficients, one they do not reach does, and the tracked frames start from the mean
of the kept fits only. Under a few seconds in all (the 2K body is the session's fixture).
"""
from __future__ import annotations

from types import SimpleNamespace as NS

import numpy as np

import bodystudio.reconstruct.sequence as seq
from bodystudio.reconstruct.shape_prior import back_patch, rim_reach
from tests.reconstruct.test_sequence_tracked_mutants import EXPECTED_TRACK
from tests.reconstruct.test_shape_prior_carried import _carried_run


def test_back_patch_is_the_backward_facing_skin_of_the_middle_spine(body_2k):
    patch = back_patch(body_2k)
    names = body_2k.skeleton.bone_names
    dominant = np.argmax(body_2k.weights, axis=1)
    spine = np.isin(dominant, [names.index("spine_02"), names.index("spine_03")])
    assert patch.dtype == bool and 40 < patch.sum() < 0.5 * spine.sum()  # measured 2k: a third of the spine's skin
    assert np.all(spine[patch])
    V = body_2k.vertices
    assert np.all(V[patch, 2] < np.median(V[spine, 2]))  # behind the spine's middle: the back, not the chest
    front = spine & ~patch
    assert np.mean(V[front, 2]) > np.mean(V[patch, 2]) + 0.05


def test_rim_reach_is_the_share_of_the_patch_with_a_pair():
    patch = np.zeros(10, dtype=bool)
    patch[[1, 3, 5, 7]] = True
    assert rim_reach(np.array([1, 1, 3, 2, 9]), patch) == 0.5  # duplicates (two cameras) and off-patch ignored
    assert rim_reach(np.array([], dtype=np.int64), patch) == 0.0
    assert rim_reach(np.array([1, 3, 5, 7]), patch) == 1.0
    assert rim_reach(None, patch) == 0.0
    assert rim_reach(np.array([1]), np.zeros(10, dtype=bool)) == 0.0


def test_deform_result_keeps_the_last_outer_iterations_silhouette_vertices():
    from bodystudio.reconstruct import rapid_skin
    from bodystudio.reconstruct.silhouette import SilhouetteConstraints

    calls = []

    def constraints(V, F, N, cameras, masks, *a, **k):
        calls.append(len(calls))
        ids = np.array([len(calls), 7, 7])
        return SilhouetteConstraints(ids, V[ids], np.zeros((3, 3)), np.ones(3), None, None)

    import pytest

    mp = pytest.MonkeyPatch()
    mp.setattr(rapid_skin, "silhouette_constraints", constraints)
    try:
        V = np.random.default_rng(0).normal(size=(12, 3))
        F = np.array([[0, 1, 2], [2, 3, 4], [4, 5, 6], [6, 7, 8], [8, 9, 10], [9, 10, 11]])
        out = rapid_skin.deform_to_observations(V, F, [], {}, rapid_skin.RapidSkinParams(outer_iterations=3,
                                                                                        inner_iterations=1,
                                                                                        hull_gate_m=0.0))
    finally:
        mp.undo()
    assert len(calls) == 3
    np.testing.assert_array_equal(out.silhouette_vertices, [3, 7, 7])


def test_a_reached_back_fits_no_shape_and_the_tracked_frames_take_the_kept_fits_mean(monkeypatch, tmp_path):
    """Initialised frames (EXPECTED_TRACK: 0, 2, 3, 4, 5) reach 0.6, 0.2, 0.7, 0.1, 0.3 of the back; at 0.4 frames
    0 and 3 are reached: 3 fits (numbered 1, 2, 3 by the stand-in), tracked frame 1 has none before it (the posed
    template, no shape) and frames 6 and 7 start from their mean 2.0."""
    reaches = iter([0.6, 0.2, 0.7, 0.1, 0.3])
    seen = []

    def reach(vertices, patch):
        assert patch is PATCH
        seen.append(vertices)
        return next(reaches)

    PATCH = np.array([True, False, True, False])
    monkeypatch.setattr(seq, "back_patch", lambda body: PATCH)
    monkeypatch.setattr(seq, "rim_reach", reach)
    rec, fits, poses, writer = _carried_run(monkeypatch, tmp_path, reach=0.4)
    assert [v.tolist() for v in seen] == [[0], [2], [3], [4], [5]]  # each initialised frame's own pass's pairs
    assert len(fits) == 3
    assert [float(p[0][0]) for p in poses] == [2.0, 2.0]
    tracked = [k for k, t in enumerate(EXPECTED_TRACK) if t == "tracked"]
    deform = rec.calls["deform"]
    np.testing.assert_allclose(deform[tracked[0]]["reference"], deform[tracked[0]]["V"])  # no shape yet
    frames = writer.json["frames.json"]
    frames = frames["frames"] if isinstance(frames, dict) else frames
    got = [f.get("back_rim_reach") for f in frames]
    assert got == [0.6, None, 0.2, 0.7, 0.1, 0.3, None, None]
    assert writer.meta["shape_prior_reach"] == 0.4


def test_reach_one_keeps_every_fit_as_carried_alone(monkeypatch, tmp_path):
    monkeypatch.setattr(seq, "back_patch", lambda body: np.ones(4, dtype=bool))
    monkeypatch.setattr(seq, "rim_reach", lambda vertices, patch: 0.99)
    _rec, fits, poses, _w = _carried_run(monkeypatch, tmp_path, reach=1.0)
    assert len(fits) == 5 and [float(p[0][0]) for p in poses] == [1.0, 3.0, 3.0]


def test_no_gate_reads_no_reach(monkeypatch, tmp_path):
    monkeypatch.setattr(seq, "rim_reach", lambda *a: NS()._fail)  # any call raises AttributeError
    _rec, fits, _p, writer = _carried_run(monkeypatch, tmp_path)
    assert len(fits) == 5 and writer.meta["shape_prior_reach"] == 0.0
