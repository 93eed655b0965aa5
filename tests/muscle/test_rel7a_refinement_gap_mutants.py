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

    def tcc(vecs, valid, sigma, *deltas):
        windows.append(([float(v[0, 0]) for v in vecs], deltas[0] if deltas else None, sigma))
        assert deltas != (None,)  # the paper's window is called without offsets
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
    def never(*a, **k):
        raise AssertionError("called with its option off")

    stub.update(edge_on_pairs=never, unseen_hold_weights=never, model_visible_vertices=never)
    for name, fn in stub.items():
        monkeypatch.setattr(cap, name, fn)
    o = replace(cap.CaptureOptions(), refine_visible_only=False, refine_min_facing_cos=0.0, refine_unseen_hold=0.0,
                **options)
    meshes = [np.full((N_V, 3), float(p)) for p in (positions if numbers is None else numbers)]
    timer = SimpleNamespace(calls=[])
    timer.add = lambda *a: timer.calls.append(a)
    out = cap._refinement(meshes, [None] * len(meshes), [(None, None)] * len(meshes), [None] * len(meshes),
                          np.zeros((1, 3), int), np.zeros(3), None, None, None, o, timer,
                          positions=None if positions is None else np.asarray(positions))
    assert len(timer.calls) == 1 and timer.calls[0][0] == "refinement" and isinstance(timer.calls[0][1], float)
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


def test_window_edges_one_frame_three_frames_faster_rates_and_a_narrow_detail_sigma(monkeypatch):
    windows, out, _ = _run(monkeypatch, [5])  # one captured frame: no offsets, no average
    assert windows == [([5.0], None, 1.0)] and out == [5005.0]
    _, out, o = _run(monkeypatch, [0, 2, 3])  # three frames are enough for the detail average
    np.testing.assert_allclose(out, _reference_detail([0, 2, 3], o.detail_window_frames, o.detail_sigma_frames))
    windows, _, _ = _run(monkeypatch, None, numbers=[0, 1, 2, 3], refine_window_frames=2)  # faster than 30 fps
    assert [list(d) for _, d, _ in windows] == [[0, 1, 2], [-1, 0, 1, 2], [-2, -1, 0, 1], [-2, -1, 0]]
    _, out, _ = _run(monkeypatch, POSITIONS, detail_sigma_frames=0.75)
    np.testing.assert_allclose(out, _reference_detail(POSITIONS, 2, 0.75), rtol=1e-12)


def test_each_frame_hands_its_own_inputs_to_the_steps(monkeypatch):
    """The per-frame plumbing with every option on: each step gets the frame's mesh, cloud, tree, the sensor centre,
    the options' values; the visible-only, edge-on and unseen-hold masks combine as the docstring says."""
    import bodystudio.muscle.capture as cap

    F, C, arm, adjacency, joints, camera, S = (np.zeros((1, 3), int), np.array([0.0, 0.0, -1.0]), object(), object(),
                                               object(), object(), object())
    n = 3
    meshes = [np.full((N_V, 3), float(k)) for k in range(n)]
    clouds = [(f"P{k}", f"N{k}") for k in range(n)]
    trees = [f"T{k}" for k in range(n)]
    poses = [f"pose{k}" for k in range(n)]
    o = replace(cap.CaptureOptions(), refine_visible_only=True, refine_min_facing_cos=0.25, refine_unseen_hold=0.5,
                detail_sigma_frames=0.0)
    log = []
    frame = {id(m): k for k, m in enumerate(meshes)}

    def k_of(M):
        return int(M[0, 0]) if id(M) not in frame else frame[id(M)]

    def normals(M, F_):
        assert F_ is F
        return np.full((N_V, 3), 10.0 + k_of(M))

    def cpc(M, P, N, tree):
        k = k_of(M)
        assert (P, N, tree) == (f"P{k}", f"N{k}", f"T{k}")
        return SimpleNamespace(kept=np.array([True, True, True]), k=k)

    def filt(M, Nv, pairs, C_, arm_, adj_, filters):
        assert M is meshes[pairs.k] and C_ is C and arm_ is arm and adj_ is adjacency and filters is o.nicp.filters
        assert Nv[0, 0] == 10.0 + pairs.k
        return pairs

    def visible(V, F_, camera_):
        assert F_ is F and camera_ is camera and V == ("similar", k_of_mesh[0])
        return np.array([True, True, False])

    k_of_mesh = [None]

    def similarity(S_, M):
        assert S_ is S
        k_of_mesh[0] = k_of(M)
        return ("similar", k_of(M))

    def edge_on(M, Nv, C_, cos):
        assert C_ is C and cos == 0.25 and Nv[0, 0] == 10.0 + k_of(M)
        return np.array([True, False, False])

    def seen(M, Nv, C_, kept, vis):
        log.append(("seen", k_of(M), kept.tolist(), None if vis is None else vis.tolist()))
        assert C_ is C and Nv[0, 0] == 10.0 + k_of(M)
        return np.array([False, False, True])

    def tcc(vecs, valid, sigma, *deltas):
        log.append(("valid", [v.tolist() for v in valid], sigma))
        for v, ok in zip(vecs, valid, strict=True):  # the point-to-plane vector where a pair is kept, 0 elsewhere
            assert v.dtype == np.float64 and v[:, 0].tolist() == ok.astype(float).tolist() and ok.any()
        return np.full((N_V, 3), 7.0), np.array([True, False, False])

    def weights(c, Nv, M, pj, ok, radius, gain):
        assert c[0, 0] == 7.0 and Nv[0, 0] == 10.0 + k_of(M) and pj == ("posed", f"pose{k_of(M)}")
        assert ok.tolist() == [True, False, False] and (radius, gain) == (o.joint_radius_m, o.joint_gain)
        return np.full(N_V, 0.5)

    def hold_w(M, mask, strength, band):
        assert M is meshes[k_of(M)] and mask.tolist() == [True, False, True]
        assert (strength, band) == (0.5, o.refine_unseen_band_m)
        return "hold"

    def solve(M, F_, c, w, data_weight, iterations, hold=None):
        assert F_ is F and c[0, 0] == 7.0 and w[0] == 0.5 and hold == "hold"
        assert (data_weight, iterations) == (o.refine_data_weight, o.refine_iterations)
        return M + 100.0

    for name, fn in {"vertex_normals": normals, "closest_point_correspondences": cpc, "filter_correspondences": filt,
                     "model_visible_vertices": visible, "apply_similarity": similarity, "edge_on_pairs": edge_on,
                     "plane_targets": lambda M, pairs: M + 1.0 + 0 * pairs.k, "hold_seen_vertices": seen,
                     "time_consistent_correspondences": tcc,
                     "correspondence_weights": weights, "unseen_hold_weights": hold_w, "refine_surface": solve}.items():
        monkeypatch.setattr(cap, name, fn)
    monkeypatch.setattr(cap, "posed_joints", lambda j, p: (j is joints) and ("posed", p))
    timer = SimpleNamespace(add=lambda *a: None)
    out = cap._refinement(meshes, poses, clouds, trees, F, C, arm, adjacency, joints, o, timer, camera=camera,
                          similarity=S)
    np.testing.assert_allclose([X[0, 0] for X in out], [100.0, 101.0, 102.0])
    # visible: [T, T, F]; edge-on drops the first: kept [F, T, F] in every frame
    assert [e for e in log if e[0] == "seen"] == [("seen", k, [False, True, False], [True, True, False])
                                                   for k in range(n)]
    assert all(v == [[False, True, False]] * len(v) for _, v, _ in [e for e in log if e[0] == "valid"])
    # without a camera, no visibility test
    log.clear()
    cap._refinement(meshes, poses, clouds, trees, F, C, arm, adjacency, joints, o, timer, camera=None, similarity=S)
    assert [e[2:] for e in log if e[0] == "seen"][0] == ([False, True, True], None)
