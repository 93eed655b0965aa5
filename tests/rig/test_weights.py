"""Skin weight transfer: barycentric baseline, harmonic (eq. 7), influence limit."""

import numpy as np
import trimesh

from bodystudio.body import build_body
from bodystudio.rig.weights import barycentric_weight_transfer, harmonic_weight_transfer, limit_influences


def test_limit_influences_keeps_four_largest_and_normalises():
    W = np.array([[0.1, 0.2, 0.3, 0.15, 0.25], [1.0, 0, 0, 0, 0]])
    L = limit_influences(W)
    assert ((L > 0).sum(1) <= 4).all()
    np.testing.assert_allclose(L.sum(1), 1.0)
    assert L[0, 0] == 0.0


def test_transfer_from_2k_to_full_body_recovers_its_weights(body_2k):
    full = build_body(resolution="full")
    true = limit_influences(full.weights)
    bary = barycentric_weight_transfer(full.vertices, body_2k.vertices, body_2k.faces, body_2k.weights)
    harm = harmonic_weight_transfer(full.vertices, full.faces, body_2k.vertices, body_2k.faces, body_2k.weights)
    for W in (bary, harm):
        assert ((W > 0).sum(1) <= 4).all()
        np.testing.assert_allclose(W.sum(1), 1.0, atol=1e-9)
    l1_bary = np.abs(bary - true).sum(1).mean()
    l1_harm = np.abs(harm - true).sum(1).mean()
    assert l1_bary < 0.15, l1_bary
    # Harmonic keeps the model's interpolated weights wherever the correspondence is compatible, so it is
    # as accurate as barycentric here (0.0837 vs 0.0834); pinning only the model vertices' images and
    # filling the rest harmonically was 0.096.
    assert l1_harm < l1_bary + 0.002, (l1_harm, l1_bary)


def _torso_and_arm(subdivisions, torso_radius_m, arm_x_m):
    """A torso and an arm (ellipsoids), the arm's weights blending upper arm -> forearm along its length."""
    sphere = trimesh.creation.icosphere(subdivisions=subdivisions)
    torso = sphere.vertices * [torso_radius_m, 0.3, torso_radius_m]
    arm = sphere.vertices * [0.04, 0.25, 0.04] + [arm_x_m, 0.0, 0.0]
    V = np.vstack([torso, arm])
    F = np.vstack([sphere.faces, sphere.faces + len(torso)])
    W = np.zeros((len(V), 3))
    W[:len(torso), 0] = 1.0
    elbow = np.clip((arm[:, 1] + 0.1) / 0.2, 0.0, 1.0)
    W[len(torso):, 1] = 1.0 - elbow
    W[len(torso):, 2] = elbow
    return V, F, W


def test_harmonic_fills_in_where_the_closest_model_point_is_on_the_other_limb():
    # Scan: arm 1 cm from the torso. Fitted model: torso 1 cm too thin, arm 8 mm too close, so the scan's
    # torso vertices facing the arm are 2 mm from the model's arm and 1 cm from the model's torso.
    scan_V, scan_F, truth = _torso_and_arm(4, 0.12, 0.12 + 0.01 + 0.04)
    model_V, model_F, model_W = _torso_and_arm(2, 0.11, 0.12 + 0.002 + 0.04)
    bary = barycentric_weight_transfer(scan_V, model_V, model_F, model_W)
    harm = harmonic_weight_transfer(scan_V, scan_F, model_V, model_F, model_W)
    l1_bary = np.abs(bary - truth).sum(1)
    l1_harm = np.abs(harm - truth).sum(1)
    on_wrong_limb = l1_bary > 1.0
    assert on_wrong_limb.sum() > 20  # barycentric gives torso vertices the arm's weights
    assert l1_harm[on_wrong_limb].max() < 0.05, l1_harm[on_wrong_limb].max()
    assert l1_harm.mean() < 0.01 and l1_harm.max() < 0.25, (l1_harm.mean(), l1_harm.max())


def test_block_conjugate_gradient_matches_direct_solve(body_2k):
    import igl
    import scipy.sparse as sp
    from scipy.sparse.linalg import spsolve

    from bodystudio.rig.weights import block_conjugate_gradient

    L = -igl.cotmatrix(body_2k.vertices, body_2k.faces)
    A = (L + 1e-3 * sp.identity(L.shape[0])).tocsr()
    B = np.random.default_rng(0).normal(size=(A.shape[0], 3))
    X = block_conjugate_gradient(A, B, np.zeros_like(B), rtol=1e-10, max_iterations=5000)
    exact = np.column_stack([spsolve(A.tocsc(), B[:, k]) for k in range(3)])
    assert np.abs(X - exact).max() < 1e-6 * np.abs(exact).max()
