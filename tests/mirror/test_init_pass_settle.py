"""The init's passes made to settle (mir12x): each pass's Eq. 2 fit pooled over the same depth points
(``fixed_pool``, ``pooled_points``) and the coefficients relaxed towards each pass's fit (``pass_relaxation``).
A fresh random subset of the pooled points per pass moved 52's Eq. 4 displacement error 1-4 mm from pass to pass
(docs/mirror.md, mir12x)."""

import dataclasses

import numpy as np
import pytest

from bodystudio.errors import InputError
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
    pooled = []

    def unposed(P, *args, **kw):
        cloud = original(P, *args, **kw)
        return dataclasses.replace(cloud, points=np.array(P), correspondence=np.arange(len(P)) % len(model.mean))

    def fit(P0, m, coeffs, **kw):
        pooled.append(np.array(P0))
        return np.full(m.n_components, 0.1 * len(pooled)) * m.stddev, 0.004

    monkeypatch.setattr(init_mod, "transform_to_default_pose", unposed)
    monkeypatch.setattr(init_mod, "fit_shape", fit)
    body = initialise_from_observations(obs, model, view_point=eye, passes=4, floor_y=None, **options)
    return body.coeffs / model.stddev, pooled


def test_defaults_are_the_papers_passes():
    assert init_mod.PASS_RELAXATION == 1.0 and init_mod.FIXED_POOL is False


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


@pytest.mark.parametrize("options, message", [
    (dict(pass_relaxation=0.0), r"pass_relaxation must be in \(0, 1\]"),
    (dict(pass_relaxation=float("nan")), r"pass_relaxation must be in \(0, 1\]"),
    (dict(pooled_points=0), r"pooled_points must be an integer >= 1"),
])
def test_bad_settling_options_are_refused(frames, options, message):
    model, eye, obs = frames
    with pytest.raises(InputError, match=message):
        initialise_from_observations(obs, model, view_point=eye, **options)
