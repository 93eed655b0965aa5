"""The init's passes made to settle (mir12x): each pass's Eq. 2 fit pooled over the same depth points
(``fixed_pool``, ``pooled_points``) and the coefficients relaxed towards each pass's fit (``pass_relaxation``).
A fresh random subset of the pooled points per pass moved 52's Eq. 4 displacement error 1-4 mm from pass to pass
(docs/mirror.md, mir12x)."""

import dataclasses

import numpy as np
import pytest

from bodystudio.mirror import init as init_mod
from bodystudio.mirror.init import initialise_from_observations
from tests.mirror.test_init_unposing_wiring import _frame, _model_2k, _pose


@pytest.fixture(scope="module")
def frames():
    model = _model_2k()
    eye = np.array([0.0, 1.0, 3.0])
    n_bones = model.body(np.zeros(model.n_components)).skeleton.n_bones
    return model, eye, [_frame(model, _pose(n_bones, 3), eye, frame=0), _frame(model, _pose(n_bones, 4), eye, frame=1)]


def _run(monkeypatch, frames, **options):
    """Four passes with a stand-in Eq. 2 fit (pass k's fit: 0.1 k standard deviations in every direction) and the
    unposing's points replaced by the frame's own (so the pooled rows are comparable between passes)."""
    model, eye, obs = frames
    original = init_mod.transform_to_default_pose
    pooled, weights = [], []

    def unposed(P, *args, **kw):
        cloud = original(P, *args, **kw)
        return dataclasses.replace(cloud, points=np.array(P), correspondence=np.arange(len(P)) % len(model.mean))

    def fit(P0, m, coeffs, **kw):
        pooled.append(np.array(P0))
        weights.append(kw["point_weight"])
        return np.full(m.n_components, 0.1 * len(pooled)) * m.stddev, 0.004

    monkeypatch.setattr(init_mod, "transform_to_default_pose", unposed)
    monkeypatch.setattr(init_mod, "fit_shape", fit)
    options.setdefault("weighted_pool", False)  # the subsets' options (the weighted pool is the default since mir12y)
    body = initialise_from_observations(obs, model, view_point=eye, passes=4, floor_y=None, **options)
    _run.weights = weights
    return body.coeffs / model.stddev, pooled


def test_defaults_are_the_papers_passes():
    assert init_mod.PASS_RELAXATION == 1.0 and init_mod.FIXED_POOL is False
    assert init_mod.WEIGHTED_POOL is True  # the default since mir12y


def test_relaxation_moves_the_coefficients_part_of_the_way(monkeypatch, frames):
    """Fits 0.1, 0.2, 0.3, 0.4: relaxed by 0.5 from the second pass on, 0.1 -> 0.15 -> 0.225 -> 0.3125; by 1 the
    last fit itself."""
    c, _ = _run(monkeypatch, frames, pass_relaxation=0.5)
    np.testing.assert_allclose(c, 0.3125, atol=1e-12)
    c, _ = _run(monkeypatch, frames)
    np.testing.assert_allclose(c, 0.4, atol=1e-12)


def test_the_fixed_pool_takes_the_same_points_every_pass(monkeypatch, frames):
    """200 of the two frames' points pooled: with ``fixed_pool`` the same rows in every pass, without a fresh
    random subset per pass (the rows differ)."""
    _, pooled = _run(monkeypatch, frames, fixed_pool=True, pooled_points=200)
    assert len(pooled) == 4 and all(len(p) == 200 for p in pooled)
    for p in pooled[1:]:
        np.testing.assert_array_equal(p, pooled[0])
    _, pooled = _run(monkeypatch, frames, pooled_points=200)
    assert all(len(p) == 200 for p in pooled)
    assert not np.array_equal(pooled[1], pooled[2])
    _, pooled = _run(monkeypatch, frames, fixed_pool=True, pooled_points=10 ** 6)
    assert len(pooled[0]) == sum(len(o.points) for o in frames[2])
    assert _run.weights == [1.0] * 4


def test_the_weighted_pool_fits_every_point_weighted_as_the_subset(monkeypatch, frames):
    """``weighted_pool``: every point of both frames in every pass, each weighted 200 / N (so the pool weighs
    against the prior as 200 points); fewer points than ``pooled_points``: weight 1."""
    n = sum(len(o.points) for o in frames[2])
    _, pooled = _run(monkeypatch, frames, weighted_pool=True, pooled_points=200)
    assert [len(p) for p in pooled] == [n] * 4
    np.testing.assert_allclose(_run.weights, 200 / n, rtol=1e-12)
    _run(monkeypatch, frames, weighted_pool=True, pooled_points=10 ** 6)
    assert _run.weights == [1.0] * 4


def test_point_weight_is_the_points_multiplicity(frames):
    """Eq. 2 on a noisy cloud of a known body, with the shape prior and the joints: every point given twice and
    weighted 0.5 is the fit of the points given once (to 1e-9 of a standard deviation); weighted 1 it is not (the
    prior then weighs half as much)."""
    model = frames[0]
    rng = np.random.default_rng(3)
    truth = rng.normal(0.0, 1.0, model.n_components) * model.stddev
    ids = rng.choice(len(model.mean), 400, replace=False)
    P = model.vertices(truth)[ids] + rng.normal(0.0, 0.01, (400, 3))
    once = init_mod.fit_shape(P, model, correspondence=ids, iterations=2)
    twice = init_mod.fit_shape(np.vstack([P, P]), model, correspondence=np.concatenate([ids, ids]), iterations=2,
                               point_weight=0.5)
    np.testing.assert_allclose(twice / model.stddev, once / model.stddev, atol=1e-9)
    plain = init_mod.fit_shape(np.vstack([P, P]), model, correspondence=np.concatenate([ids, ids]), iterations=2)
    assert np.abs(plain - once).max() / model.stddev.max() > 1e-4
