"""mir12y: the Eq. 2 fit's closest-vertex query reused between re-matchings (``init.closest_vertex_matches``) gives
the full query's answer exactly, whichever way the vertices moved."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from bodystudio.mirror import init


def _cloud(seed: int = 3):
    rng = np.random.default_rng(seed)
    return rng, rng.random((400, 3)), rng.random((3000, 3))


def test_small_moves_reuse_the_query_and_match_exactly():
    rng, V, P = _cloud()
    cache: dict = {}
    d, m = init.closest_vertex_matches(P, V, cache)
    d0, m0 = cKDTree(V).query(P)
    assert np.array_equal(m, m0) and np.allclose(d, d0, rtol=0, atol=1e-12)
    near = cache["near"]
    assert near.shape == (len(P), init.MATCH_NEIGHBOURS)
    moved = V + rng.normal(0, 0.01, V.shape)
    # the kept vertices alone miss some points' closest vertex: those must be queried again
    kept_d, kept_m = init._closest_of_kept(P, moved, near)
    truth_d, truth_m = cKDTree(moved).query(P)
    assert (kept_m != truth_m).sum() >= 3
    d, m = init.closest_vertex_matches(P, moved, cache)
    assert cache["near"] is near  # reused, not redone (~20 % of the points queried again)
    assert np.array_equal(m, truth_m)
    assert np.allclose(d, truth_d, rtol=0, atol=1e-12)


def test_a_large_move_redoes_the_query():
    rng, V, P = _cloud(4)
    cache: dict = {}
    init.closest_vertex_matches(P, V, cache)
    near = cache["near"]
    for _ in range(3):
        V = V + rng.normal(0, 0.04, V.shape)
        d, m = init.closest_vertex_matches(P, V, cache)
        d0, m0 = cKDTree(V).query(P)
        assert np.array_equal(m, m0) and np.allclose(d, d0, rtol=0, atol=1e-12)
    assert cache["near"] is not near
    assert np.array_equal(cache["vertices"], V)


def test_no_cache_or_too_few_vertices_is_the_plain_query():
    _, V, P = _cloud(5)
    d, m = init.closest_vertex_matches(P, V)
    assert np.array_equal(m, cKDTree(V).query(P)[1])
    cache: dict = {}
    d, m = init.closest_vertex_matches(P, V[:3], cache)
    assert np.array_equal(m, cKDTree(V[:3]).query(P)[1]) and not cache
