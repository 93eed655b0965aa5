"""mus11v's prior weights of a captured row's body-space fit (``body_space_rest_mesh(weight_prior_weight=)``, the
``extend_arm_model`` defaults ``EXTENSION_ROW_PRIOR_WEIGHT`` 30 / ``EXTENSION_ROW_WEIGHT_PRIOR_WEIGHT`` 3 and their
pass-through; issue 17, mutation testing) where test_body_rest_extension_mutants.py does not reach them: the fit's
minimum with the weight macro's own prior written out (a stationary point of ``|B(x) + t - rest|^2 + sum_i lam_i
(x_i - mean_i)^2`` with ``lam`` 30 on every parameter but the weight's), the weight prior refused where the fit is
called directly, ``None`` (the old rows) through the extension and its record, and the captured mesh kept as the row
when only the shape form asks for the body space. The stand-in space and 12-vertex model of that file; < 2 s."""

import numpy as np
import pytest

from bodystudio.errors import InputError
from bodystudio.muscle import model as mm
from bodystudio.muscle.model import (
    BODY_MACRO_NAMES,
    EXTENSION_ROW_PRIOR_WEIGHT,
    EXTENSION_ROW_WEIGHT_PRIOR_WEIGHT,
    body_space_rest_mesh,
    extend_arm_model,
)
from tests.muscle.test_body_rest_extension_mutants import (
    N_V,
    SHAPE,
    T_TRUE,
    X_TRUE,
    _captured_base,
    _frames,
    _planted,
    _rel,
    _space,
    _stand_in,
    _tiny_model,
)

W = BODY_MACRO_NAMES.index("weight")


def _ridge(space, rest, lam):
    """The fit's minimum where the stand-in space is linear (macro targets male, maxmuscle = 2 mu - 1 and maxweight =
    2 w - 1 above 0.5): the normal equations of ``|J (x - mean) + B(mean) + t - rest|^2 + sum_i lam_i (x_i -
    mean_i)^2``, ``J`` by central differences of the space itself (exact on its linear piece)."""
    mean, _ = space.prior(SHAPE)
    P, h = len(mean), 1e-4
    J = np.stack([(_rel(space, mean + h * e) - _rel(space, mean - h * e)).ravel() / (2 * h) for e in np.eye(P)], 1)
    A = np.c_[J, np.tile(np.eye(3), (N_V, 1))]
    y = (rest - _rel(space, mean)).ravel()
    L = np.diag(np.r_[lam, np.zeros(3)])
    p = np.linalg.solve(A.T @ A + L, A.T @ y)
    return mean + p[:P], p[P:]


def _lam(space, prior_weight, weight_prior_weight):
    _, sigma = space.prior(SHAPE)
    w = np.full(len(sigma), prior_weight)
    w[W] = weight_prior_weight
    return w * N_V * 1e-6 / sigma ** 2


@pytest.mark.parametrize(("prior_weight", "weight_prior_weight"), [(30.0, 0.3), (3.0, 30.0), (30.0, None)])
def test_the_weight_macro_has_its_own_prior_weight_in_the_minimum(prior_weight, weight_prior_weight):
    """A heavy subject (weight 0.8 where the prior's mean is 0.55) on the stand-in's linear piece: the fit is the
    ridge solution whose weight term is ``weight_prior_weight``'s (None: ``prior_weight``'s), every other term
    ``prior_weight``'s."""
    space = _space(only=[0, 2, 3], macro_scale=0.05)
    x_true = np.r_[0.3, 0.6875, 0.85, 0.8, 0.5, 0.55, 1 / 3, 1 / 3, 1 / 3, 0.4, -0.3, 0.2]
    rest = _planted(space, x_true, T_TRUE)
    _, x, t = body_space_rest_mesh(space, rest, SHAPE, prior_weight=prior_weight,
                                   weight_prior_weight=weight_prior_weight)
    own = prior_weight if weight_prior_weight is None else weight_prior_weight
    x_want, t_want = _ridge(space, rest, _lam(space, prior_weight, own))
    assert x_want[W] > 0.55 and x_want[2] > 0.5  # on the linear piece
    np.testing.assert_allclose(x, x_want, atol=1e-8)
    np.testing.assert_allclose(t, t_want, atol=1e-9)
    x_all, _ = _ridge(space, rest, _lam(space, prior_weight, prior_weight))
    if weight_prior_weight is not None:  # the weight's own term moved it
        assert abs(x_all[W] - x_want[W]) > 0.005, (x_all[W], x_want[W])  # measured 0.010-0.011


@pytest.mark.parametrize("w", [0.0, -3.0, np.nan, np.inf])
def test_a_bad_weight_prior_weight_is_refused_by_the_fit_itself(w):
    with pytest.raises(InputError, match=rf"^weight_prior_weight={w} must be > 0 \(or None: prior_weight's\)$"):
        body_space_rest_mesh(_space(), np.zeros((N_V, 3)), SHAPE, prior_weight=3.0, weight_prior_weight=w)


def test_weight_prior_weights_below_one_are_taken(monkeypatch):
    space = _space(only=[0, 2, 3], macro_scale=0.05)
    rest = _planted(space, X_TRUE, T_TRUE)
    for w in (1e-3, 0.5, 1.0):
        body_space_rest_mesh(space, rest, SHAPE, prior_weight=3.0, weight_prior_weight=w)
    _stand_in(monkeypatch)
    model = _tiny_model()
    extend_arm_model(model, _frames(model, rest), captured_rest="body", weight_prior_weight=0.5)


def test_the_extension_defaults_and_none_for_the_old_rows(monkeypatch):
    assert (EXTENSION_ROW_PRIOR_WEIGHT, EXTENSION_ROW_WEIGHT_PRIOR_WEIGHT) == (30.0, 3.0)
    space, _ = _stand_in(monkeypatch)
    model = _tiny_model()
    rest = _planted(space, X_TRUE + np.r_[np.zeros(len(BODY_MACRO_NAMES)), 0.3, 0.1, -0.2], T_TRUE, noise=0.003)
    frames = _frames(model, rest)
    base = _captured_base(model, frames)
    expected = model.base_vertices + mm.length_displacements(model, SHAPE)
    rows = {}
    for label, kw in (("default", {}), ("none", {"weight_prior_weight": None}),
                      ("given", {"prior_weight": 5.0, "weight_prior_weight": 0.25})):
        ext = extend_arm_model(model, frames, captured_rest="body", **kw)
        rows[label] = ext.shape_residuals[3]
        if label == "none":
            want = body_space_rest_mesh(space, base, SHAPE, 30.0)[0]
            assert ext.subjects[-1]["rest"] == "body space (prior weight 30)"
        elif label == "given":
            want = body_space_rest_mesh(space, base, SHAPE, 5.0, weight_prior_weight=0.25)[0]
            assert ext.subjects[-1]["rest"] == "body space (prior weight 5, weight macro 0.25)"
        else:
            want = body_space_rest_mesh(space, base, SHAPE, 30.0, weight_prior_weight=3.0)[0]
            assert ext.subjects[-1]["rest"] == "body space (prior weight 30, weight macro 3)"
        np.testing.assert_allclose(rows[label], (want - expected).ravel(), atol=1e-12)
    assert np.abs(rows["default"] - rows["none"]).max() > 1e-6  # the weight's own prior changed the row


def test_a_mesh_row_stays_the_captured_mesh_when_the_shape_form_is_body(monkeypatch):
    """``captured_rest="mesh"`` with ``shape_form="body"``: the body space is built for the shape form, but the
    captured subject's row is its captured base mesh, not the space's fit of it (the shape term's form is learned from
    that row)."""
    space, calls = _stand_in(monkeypatch)
    model = _tiny_model()
    rest = _planted(space, X_TRUE + np.r_[np.zeros(len(BODY_MACRO_NAMES)), 0.3, 0.1, -0.2], T_TRUE, noise=0.003)
    frames = _frames(model, rest)
    # the body form's own fit needs MakeHuman's targets: the stand-in model keeps its form (the shape term is not
    # what this checks)
    monkeypatch.setattr(mm, "with_shape_form", lambda m, form, body_weight=None: m)
    ext = extend_arm_model(model, frames, captured_rest="mesh", shape_form="body")
    assert calls  # the space was built
    expected = model.base_vertices + mm.length_displacements(model, SHAPE)
    np.testing.assert_allclose(ext.shape_residuals[3], (_captured_base(model, frames) - expected).ravel(), atol=1e-12)
    assert "rest" not in ext.subjects[-1]
