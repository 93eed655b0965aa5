"""Mutation survivors of mir12x's settling options (docs/mutation/mirror-init.md, "mir12x's settling options"):
the random pool draws without replacement, a pool of exactly ``pooled_points`` points is taken whole and in order,
and the boundaries of the two values the initialisation accepts (``pass_relaxation`` 1, ``pooled_points`` 1).
Stand-in transform and Eq. 2 fit on the 2k model, as ``test_init_pass_settle.py`` (fast)."""

import numpy as np

from tests.mirror.test_init_pass_settle import _run, frames  # noqa: F401  (the module fixture)


def test_the_random_pool_draws_each_point_at_most_once(monkeypatch, frames):  # noqa: F811
    """Without ``fixed_pool``, 300 of the two frames' points per pass: 300 distinct rows of the pooled points (a draw
    with replacement repeats some: of N ~ 1000 points, 300 draws repeat one with probability > 1 - 1e-15)."""
    model, eye, obs = frames
    every = np.concatenate([np.asarray(o.points, float) for o in obs])
    _, pooled = _run(monkeypatch, frames, pooled_points=300)
    for p in pooled:
        assert len(p) == 300 and len(np.unique(p, axis=0)) == 300
        assert {tuple(r) for r in p} <= {tuple(r) for r in every}


def test_a_pool_of_exactly_pooled_points_is_taken_whole_and_in_order(monkeypatch, frames):  # noqa: F811
    """N points and ``pooled_points`` = N: every point, in the frames' order (no draw), weight 1, with or without
    ``fixed_pool`` / ``weighted_pool``."""
    model, eye, obs = frames
    every = np.concatenate([np.asarray(o.points, float) for o in obs])
    n = len(every)
    for options in ({}, dict(fixed_pool=True), dict(weighted_pool=True)):
        _, pooled = _run(monkeypatch, frames, pooled_points=n, **options)
        for p in pooled:
            np.testing.assert_array_equal(p, every)
        assert _run.weights == [1.0] * 4


def test_the_boundary_values_are_accepted(monkeypatch, frames):  # noqa: F811
    """``pass_relaxation`` 1 (each pass its own fit: the last fit, 0.4) and ``pooled_points`` 1 (one point a pass)
    lie inside the accepted ranges."""
    c, pooled = _run(monkeypatch, frames, pass_relaxation=1.0, pooled_points=1)
    np.testing.assert_allclose(c, 0.4, atol=1e-12)
    assert [len(p) for p in pooled] == [1] * 4
