"""rel7a: the Sec. 7 refinement's two time windows across a skipped frame, in recorded frames (mutOO; < 1 s).

``capture._refinement`` with its per-frame steps replaced by stand-ins (the correspondences, weights and ARAP
solve), so what is left is its bookkeeping: which frames each Eq. 13 window pairs and at which offsets
(``time_consistent_correspondences``' ``deltas``), and the Eq. 13-14 detail average over +-2 recorded frames. Each
frame's mesh and detail carry its recorded number, so the windows can be read off and compared with a reference
written here from the docstrings (the offsets that land on a captured frame; beyond an end, the end). A bug that
counts captured frames instead of recorded ones shifts both.
"""

from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

N_V = 3
POSITIONS = [0, 1, 2, 4, 5, 8, 9]  # frames 3, 6 and 7 skipped


def _run(monkeypatch, positions, numbers=None, **options):
    import bodystudio.muscle.capture as cap

    windows = []

    def tcc(vecs, valid, sigma, deltas=None):
        windows.append(([float(v[0, 0]) for v in vecs], deltas, sigma))
        return np.zeros((N_V, 3)), np.ones(N_V, bool)

    stub = {
        "vertex_normals": lambda M, F: np.zeros_like(M),
        "closest_point_correspondences": lambda M, P, N, tree: SimpleNamespace(kept=np.ones(N_V, bool)),
        "filter_correspondences": lambda M, Nv, pairs, C, arm, adjacency, filters: pairs,
        "plane_targets": lambda M, pairs: 2.0 * M,  # each frame's correspondence vector is its mesh: its number
        "hold_seen_vertices": lambda *a: np.ones(N_V, bool),
        "time_consistent_correspondences": tcc,
        "posed_joints": lambda joints, pose: None,
        "correspondence_weights": lambda *a: np.ones(N_V),
        "refine_surface": lambda M, F, c, w, data_weight, iterations, hold=None: M + 1000.0 * M[0, 0],
    }
    for name, fn in stub.items():
        monkeypatch.setattr(cap, name, fn)
    o = replace(cap.CaptureOptions(), refine_visible_only=False, refine_min_facing_cos=0.0, refine_unseen_hold=0.0,
                **options)
    meshes = [np.full((N_V, 3), float(p)) for p in (positions if numbers is None else numbers)]
    timer = SimpleNamespace(add=lambda *a: None)
    out = cap._refinement(meshes, [None] * len(meshes), [(None, None)] * len(meshes), [None] * len(meshes),
                          np.zeros((1, 3), int), np.zeros(3), None, None, None, o, timer,
                          positions=None if positions is None else np.asarray(positions))
    return windows, [float(X[0, 0]) for X in out], o


def _reference_windows(positions, r):
    """Eq. 13's window of each captured frame: its captured neighbours i-1..i+1 (r = 1: at an end the frame and its
    one neighbour) or those within r recorded frames, at their offsets in recorded frames."""
    out = []
    n = len(positions)
    for i in range(n):
        idx = list(range(max(i - r, 0), min(i + r, n - 1) + 1))
        if r != 1:
            idx = [j for j in idx if abs(positions[j] - positions[i]) <= r]
        out.append(([float(positions[j]) for j in idx], [positions[j] - positions[i] for j in idx]))
    return out


def _reference_detail(positions, w, sigma):
    """Eq. 13-14's detail average: each frame's detail (here 1000 x its number) averaged with Gaussian weights over
    the offsets -w..w that land on a captured frame, an offset beyond the sequence's ends taken at the end."""
    out = []
    for p in positions:
        num = den = 0.0
        for k in range(-w, w + 1):
            at = min(max(p + k, positions[0]), positions[-1])
            if at in positions:
                g = np.exp(-k * k / (2 * sigma ** 2))
                num += g * 1000.0 * at
                den += g
        out.append(p + num / den)
    return out


def test_the_correspondence_window_pairs_captured_neighbours_at_their_recorded_offsets(monkeypatch):
    windows, _, o = _run(monkeypatch, POSITIONS)
    assert [(v, list(d)) for v, d, _ in windows] == _reference_windows(POSITIONS, 1)
    assert windows[2][1] == [-1, 0, 2] and windows[5][1] == [-3, 0, 1]  # across the gaps
    assert all(s == o.sigma_frames for _, _, s in windows)


def test_a_wider_window_keeps_the_frames_within_its_recorded_reach(monkeypatch):
    windows, _, _ = _run(monkeypatch, POSITIONS, refine_window_frames=2)
    assert [(v, list(d)) for v, d, _ in windows] == _reference_windows(POSITIONS, 2)
    assert windows[3][0] == [2.0, 4.0, 5.0]  # frame 4: 1 (3 back) dropped, 8 not among its captured neighbours


def test_the_detail_average_is_over_recorded_frames(monkeypatch):
    _, out, o = _run(monkeypatch, POSITIONS)
    want = _reference_detail(POSITIONS, o.detail_window_frames, o.detail_sigma_frames)
    np.testing.assert_allclose(out, want, rtol=1e-12)
    # counted as consecutive captured frames the averages differ (the bug this guards against)
    counted = _reference_detail(list(range(len(POSITIONS))), o.detail_window_frames, o.detail_sigma_frames)
    shifted = [p + (c - k) * 1000.0 for p, c, k in zip(POSITIONS, counted, range(len(POSITIONS)), strict=True)]
    assert np.abs(np.asarray(shifted) - want).max() > 100.0


def test_without_a_gap_the_windows_are_the_papers(monkeypatch):
    consecutive = list(range(5))
    windows, out, o = _run(monkeypatch, None, numbers=consecutive)  # the paper's i-1, i, i+1; at an end two frames
    assert [(v, d) for v, d, _ in windows] == [([0.0, 1.0], None), ([0.0, 1.0, 2.0], None), ([1.0, 2.0, 3.0], None),
                                               ([2.0, 3.0, 4.0], None), ([4.0, 3.0], None)]
    np.testing.assert_allclose(out, _reference_detail(consecutive, o.detail_window_frames, o.detail_sigma_frames),
                               rtol=1e-12)
    windows, out, o = _run(monkeypatch, consecutive)
    assert [list(d) for _, d, _ in windows] == [[0, 1], [-1, 0, 1], [-1, 0, 1], [-1, 0, 1], [-1, 0]]
    np.testing.assert_allclose(out, _reference_detail(consecutive, o.detail_window_frames, o.detail_sigma_frames),
                               rtol=1e-12)


@pytest.mark.parametrize("sigma", [0.0])
def test_no_detail_average_when_it_is_off(monkeypatch, sigma):
    _, out, _ = _run(monkeypatch, POSITIONS, detail_sigma_frames=sigma)
    np.testing.assert_allclose(out, [p + 1000.0 * p for p in POSITIONS])
