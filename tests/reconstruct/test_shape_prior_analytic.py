"""The shape prior's maths on tiny stand-ins (issue 17's standard for bodystudio.reconstruct.shape_prior).

A shape space of four non-orthogonal components over a few hundred vertices, a planted robust-fit case (inliers
with millimetre noise, a fifth of the vertices 5-30 cm off), the un-skin / re-pose round trip on a two-bone bar,
and the 2.5K template posed by random bone transforms. Each result is compared with an independent reference:
the Huber-reweighted ridge solution written out with dense weight matrices, and the dense LBS blend
sum_b w_ib T_b v_i (Eq. 12). Runs in about a second.
"""

from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bodystudio.errors import InputError
from bodystudio.reconstruct.shape_prior import (
    deformed_shape_coefficients,
    fit_shape_coefficients,
    posed_shape,
    shape_prior_mesh,
)

STDDEV = np.array([0.5, 0.3, 0.2, 0.1])


def _space(mean: np.ndarray, seed: int = 0):
    """A shape space of four components over ``mean``: random, not orthogonal, each column about unit norm."""
    rng = np.random.default_rng(seed)
    n = len(mean)
    basis = rng.normal(0, 1.0 / np.sqrt(3 * n), (len(STDDEV), n, 3))
    basis[1] += 0.3 * basis[0]  # not orthogonal: a transposed or diagonal-only normal matrix shows
    return SimpleNamespace(mean=mean, basis=basis, stddev=STDDEV.copy(), n_components=len(STDDEV),
                           resolution="toy", vertices=lambda c: mean + np.tensordot(np.asarray(c), basis, axes=1))


def _reference_fit(model, V, ridge, robust_m, iterations):
    """Eq. 1 of Avatar Reshaping's space fitted by iteratively reweighted ridge least squares, written out on
    rows scaled by the weights' square roots, with Huber's weights (1 within ``robust_m``, ``robust_m / d`` beyond)."""
    n = len(V)
    B = np.stack([b.ravel() for b in model.basis], axis=1)
    y = (V - model.mean).ravel()
    w = np.ones(n)
    for _ in range(iterations):
        s = np.sqrt(np.repeat(w, 3))
        Bs, ys = s[:, None] * B, s * y
        c = np.linalg.solve(Bs.T @ Bs + np.diag(ridge / model.stddev ** 2), Bs.T @ ys)
        d = np.sqrt(np.sum((y - B @ c).reshape(n, 3) ** 2, axis=1))
        w = np.where(d > robust_m, robust_m / np.where(d > 0, d, 1.0), 1.0)
    return c


def _observed(model, c_true, seed=1, outlier_fraction=0.2):
    """The shape ``c_true`` with 1 mm noise, a fifth of its vertices moved 5-30 cm up (the region a first pass
    got wrong); returns the vertices and the outliers' mask."""
    rng = np.random.default_rng(seed)
    V = model.vertices(c_true) + rng.normal(0, 0.001, model.mean.shape)
    out = rng.random(len(V)) < outlier_fraction
    V[out, 1] += rng.uniform(0.05, 0.3, out.sum())  # one way, as a sagging crotch: it pulls a plain fit
    return V, out


@pytest.fixture(scope="module")
def toy():
    rng = np.random.default_rng(5)
    model = _space(rng.normal(0, 0.3, (300, 3)))
    c_true = STDDEV * np.array([1.5, -1.0, 0.8, 2.0])
    V, out = _observed(model, c_true)
    return model, c_true, V, out


def test_fit_recovers_a_shape_of_the_space_exactly(toy):
    model, c_true, _, _ = toy
    c = fit_shape_coefficients(model, model.vertices(c_true), ridge=1e-14)
    np.testing.assert_allclose(c, c_true, rtol=0, atol=1e-10)
    # lists and float32 are accepted as vertices
    c32 = fit_shape_coefficients(model, model.vertices(c_true).tolist(), ridge=1e-14)
    np.testing.assert_allclose(c32, c_true, rtol=0, atol=1e-10)


@pytest.mark.parametrize("iterations", [0, 1, 2, 3, 4])
def test_fit_is_the_huber_reweighted_ridge_solution(toy, iterations):
    model, _, V, _ = toy
    c = fit_shape_coefficients(model, V, ridge=3e-4, robust_m=0.03, iterations=iterations)
    ref = _reference_fit(model, V, 3e-4, 0.03, max(1, iterations))
    np.testing.assert_allclose(c, ref, rtol=1e-9, atol=1e-12)
    # the reference is sensitive: one reweighting more or less moves the coefficients
    other = _reference_fit(model, V, 3e-4, 0.03, max(1, iterations) + 1)
    assert np.abs(other - ref).max() > 1e-7  # measured: 4e-2, 8e-4, 1.5e-5, 2.7e-7 after 1, 2, 3, 4 fits


def test_fit_defaults_are_ridge_1e4_huber_2cm_three_fits(toy):
    model, _, V, _ = toy
    c = fit_shape_coefficients(model, V)
    np.testing.assert_allclose(c, _reference_fit(model, V, 1e-4, 0.02, 3), rtol=1e-9, atol=1e-12)
    for changed in [(2e-4, 0.02, 3), (1e-4, 0.03, 3), (1e-4, 0.02, 2), (1e-4, 0.02, 4)]:
        assert np.abs(_reference_fit(model, V, *changed) - c).max() > 1e-7, changed


def test_robust_fit_keeps_the_wrong_fifth_out(toy):
    """Planted: 20 % of the vertices 5-30 cm off. Plain least squares (one fit) is pulled far off; three
    Huber fits land within a few percent of a standard deviation of the truth."""
    model, c_true, V, _ = toy
    err = np.abs(fit_shape_coefficients(model, V, ridge=1e-8) - c_true) / STDDEV
    plain = np.abs(fit_shape_coefficients(model, V, ridge=1e-8, iterations=1) - c_true) / STDDEV
    # measured: plain max 0.25 sigma, robust 0.031 sigma
    assert plain.max() > 0.15
    assert err.max() < 0.05
    # the ridge pulls towards the mean shape in units of each component's spread: a huge ridge gives the mean
    assert np.abs(fit_shape_coefficients(model, V, ridge=1e9)).max() < 1e-6


def test_fit_refuses_vertices_of_another_resolution(toy):
    model, _, V, _ = toy
    with pytest.raises(InputError, match=r"^shape prior: \(299, 3\) vertices for a toy shape space of 300; use the "
                                         r"template of the shape space's resolution$"):
        fit_shape_coefficients(model, V[:-1])


def _bar(n=240):
    """A bar along x with two bones: bone 0 holds x < 0.4, bone 1 x > 0.6, a linear blend between."""
    rng = np.random.default_rng(7)
    x = np.linspace(0.0, 1.0, n)
    rest = np.c_[x, 0.05 * rng.normal(size=n), 0.05 * rng.normal(size=n)]
    w1 = np.clip((x - 0.4) / 0.2, 0.0, 1.0)
    return rest, np.c_[1.0 - w1, w1]


def _transforms(rotvecs, translations, pivots):
    T = np.tile(np.eye(4), (len(rotvecs), 1, 1))
    R = Rotation.from_rotvec(rotvecs).as_matrix()
    T[:, :3, :3] = R
    T[:, :3, 3] = np.asarray(pivots) - np.einsum("bij,bj->bi", R, pivots) + np.asarray(translations)
    return T


def _lbs(V, weights, T):
    """Eq. 12 written out: sum_b w_ib (R_b v_i + t_b)."""
    return np.einsum("nb,bni->ni", weights, np.einsum("bij,nj->bni", T[:, :3, :3], V) + T[:, None, :3, 3])


@pytest.fixture(scope="module")
def bar():
    rest, weights = _bar()
    model = _space(rest, seed=3)
    body = SimpleNamespace(weights=weights)
    T = _transforms([[0, 0, 0.3], [0.2, 0.4, 1.1]], [[0.1, 0.0, -0.2], [0.1, 0.05, -0.2]], [[0, 0, 0], [0.5, 0, 0]])
    c_true = STDDEV * np.array([-1.2, 0.7, 1.9, -0.5])
    return model, body, T, c_true


def test_deformed_coefficients_unskin_then_fit(bar):
    model, body, T, c_true = bar
    posed = _lbs(model.vertices(c_true), body.weights, T)
    np.testing.assert_allclose(deformed_shape_coefficients(model, body, posed, T, ridge=1e-14), c_true, atol=1e-10)
    # fitted in the rest pose: the posed mesh fitted as it is would not give the shape
    assert np.abs(fit_shape_coefficients(model, posed, ridge=1e-14) - c_true).max() > 0.01
    rest_observed, _ = _observed(model, c_true, seed=4)
    deformed = _lbs(rest_observed, body.weights, T)
    np.testing.assert_allclose(deformed_shape_coefficients(model, body, deformed.tolist(), T, 3e-4, 0.03),
                               _reference_fit(model, rest_observed, 3e-4, 0.03, 3), rtol=1e-8, atol=1e-11)
    np.testing.assert_allclose(deformed_shape_coefficients(model, body, deformed, T),
                               _reference_fit(model, rest_observed, 1e-4, 0.02, 3), rtol=1e-8, atol=1e-11)


@pytest.fixture(scope="module")
def template(body_2k):
    rng = np.random.default_rng(11)
    model = _space(body_2k.vertices, seed=9)
    nb = body_2k.weights.shape[1]
    T = _transforms(rng.normal(0, 0.3, (nb, 3)), rng.normal(0, 0.05, (nb, 3)), body_2k.skeleton.heads)
    c_true = STDDEV * np.array([0.9, -1.4, 1.1, 1.6])
    return model, body_2k, T, c_true


def test_posed_shape_is_the_lbs_of_the_spaces_rest_shape(template):
    model, body, T, c_true = template
    expected = _lbs(model.vertices(c_true), body.weights, T)
    np.testing.assert_allclose(posed_shape(model, body, c_true, T), expected, rtol=0, atol=1e-10)
    np.testing.assert_allclose(posed_shape(model, body, c_true, T, 1.3), expected, rtol=0, atol=1e-10)
    assert np.abs(_lbs(body.vertices, body.weights, T) - expected).max() > 0.01  # not the template's own shape


def test_shape_prior_mesh_restores_the_region_a_first_pass_got_wrong(template):
    """Eq. 12 inverted, the robust fit, Eq. 12 again: the posed truth comes back where the deformed mesh was
    5-30 cm off (a fifth of the vertices), within millimetres."""
    model, body, T, c_true = template
    rest_observed, out = _observed(model, c_true, seed=2)
    deformed = _lbs(rest_observed, body.weights, T)
    truth = _lbs(model.vertices(c_true), body.weights, T)
    prior = shape_prior_mesh(model, body, deformed, T, 1.0, 1e-8, 0.02)
    err_mm = 1000 * np.linalg.norm(prior - truth, axis=1)
    assert 1000 * np.linalg.norm(deformed - truth, axis=1)[out].min() > 40.0
    # measured: max 0.6 mm, outliers and all (the fit's residual of the 1 mm noise)
    assert err_mm[out].max() < 1.5 and err_mm.max() < 1.5
    for args, (ridge, robust_m) in [((), (1e-4, 0.02)), ((1.0, 3e-4, 0.03), (3e-4, 0.03))]:
        expected = _lbs(model.vertices(_reference_fit(model, rest_observed, ridge, robust_m, 3)), body.weights, T)
        np.testing.assert_allclose(shape_prior_mesh(model, body, deformed, T, *args), expected, rtol=0, atol=1e-9)
