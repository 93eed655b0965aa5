"""The shape-space prior for surfaces no view sees (bodystudio.reconstruct.shape_prior, issue 15's crotch)."""

import numpy as np
import pytest

from bodystudio.errors import InputError
from bodystudio.reconstruct.shape_prior import fit_shape_coefficients, shape_prior_mesh


@pytest.fixture(scope="module")
def unseen_crotch():
    """A subject posed by the template's bone transforms; its 'deformed' mesh right (to 2 mm noise) everywhere
    but the crotch, which keeps the posed template's shape there, as a deformation no view constrains does."""
    from bodystudio.body import build_body
    from bodystudio.body.population import sample_subject
    from bodystudio.body.statistical import load_statistical_model
    from bodystudio.reconstruct.evaluate import vertex_regions
    from bodystudio.reconstruct.pose_init import initialise_pose, pose_template

    body = build_body(resolution="2k")
    model = load_statistical_model("2k", progress=False)
    phenotype, local = sample_subject(31)
    subject = build_body(phenotype, local, resolution="2k")
    init = initialise_pose(body, pose_template(subject, np.tile(np.eye(4), (subject.skeleton.n_bones, 1, 1))).joints)
    T = init.bone_transforms
    truth = pose_template(body, T, rest_vertices=subject.vertices).vertices
    crotch = vertex_regions(body) == "crotch"
    template = pose_template(body, T).vertices
    # the template's crotch placed where the subject's surrounding surface is (its mean offset removed)
    ring = ~crotch & (np.linalg.norm(body.vertices - body.vertices[crotch].mean(0), axis=1) < 0.12)
    deformed = truth + np.random.default_rng(0).normal(0, 0.002, truth.shape)
    deformed[crotch] = template[crotch] + (truth[ring] - template[ring]).mean(0)
    return body, model, T, truth, deformed, crotch


def _p90_mm(a, b):
    return float(1000 * np.percentile(np.linalg.norm(a - b, axis=1), 90))


def test_shape_prior_restores_the_unseen_crotch(unseen_crotch):
    body, model, T, truth, deformed, crotch = unseen_crotch
    prior = shape_prior_mesh(model, body, deformed, T)
    before, after = _p90_mm(deformed[crotch], truth[crotch]), _p90_mm(prior[crotch], truth[crotch])
    # Measured (2.5K, subject 31, 53 crotch vertices): crotch p90 23.0 -> 2.5 mm; the rest 5.0 -> 1.9 mm (the
    # shape space averages the 2 mm noise out); ridge 1e-2 instead of 1e-4: crotch 5.6 mm, ridge 100: 91 mm
    assert before > 15.0
    assert after < 3.5
    assert _p90_mm(prior[~crotch], truth[~crotch]) < 3.0


def test_robust_weights_keep_the_wrong_region_out(unseen_crotch):
    """With one plain least-squares fit (no Huber reweighting) a crotch 8 cm off pulls the shape towards it."""
    body, model, T, truth, deformed, crotch = unseen_crotch
    from bodystudio.reconstruct.pose_init import unpose

    far = deformed.copy()
    far[crotch, 1] -= 0.08
    rest = unpose(far, body.weights, T)
    rest_truth = unpose(truth, body.weights, T)
    robust = model.vertices(fit_shape_coefficients(model, rest))
    plain = model.vertices(fit_shape_coefficients(model, rest, iterations=1))
    # Measured: crotch p90 4.1 mm robust, 11.6 mm plain; the rest of the body 2.8 / 6.1 mm
    assert _p90_mm(robust[crotch], rest_truth[crotch]) < 6.0 < 0.6 * _p90_mm(plain[crotch], rest_truth[crotch])
    assert _p90_mm(robust[~crotch], rest_truth[~crotch]) < 4.0 < _p90_mm(plain[~crotch], rest_truth[~crotch])


def test_shape_prior_wrong_resolution(unseen_crotch):
    body, model, T, truth, deformed, crotch = unseen_crotch
    with pytest.raises(InputError, match="shape prior"):
        fit_shape_coefficients(model, deformed[:100])
