"""``initialise_from_observations(pool_seed=)`` (mir12y): the seed of the random depth-point subsets, so main's init
can be measured over several draws. 0 is ``mirror init``'s draw; the weighted pool draws nothing."""

import numpy as np

from tests.mirror.test_init_pass_settle import _run, frames  # noqa: F401  (the module fixture)


def test_the_seed_picks_the_subsets(monkeypatch, frames):  # noqa: F811
    _, default = _run(monkeypatch, frames, pooled_points=200)
    _, zero = _run(monkeypatch, frames, pooled_points=200, pool_seed=0)
    _, other = _run(monkeypatch, frames, pooled_points=200, pool_seed=3)
    for a, b in zip(default, zero, strict=True):
        np.testing.assert_array_equal(a, b)
    assert len(other[0]) == 200
    assert all(not np.array_equal(a, b) for a, b in zip(default, other, strict=True))


def test_the_weighted_pool_draws_nothing(monkeypatch, frames):  # noqa: F811
    _, a = _run(monkeypatch, frames, weighted_pool=True, pooled_points=200)
    _, b = _run(monkeypatch, frames, weighted_pool=True, pooled_points=200, pool_seed=5)
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x, y)
