"""The articulated fit's compiled rotation bookkeeping (issue 15's frame time, rec15j) against scipy's ``Rotation``
and the numpy update it replaces: the rotation vector <-> matrix kernels bit for bit on every branch (small-angle
series, Markley's four quaternion formulas), the compiled segment update and prior gradient to rounding."""

import numpy as np
from scipy.spatial.transform import Rotation

from bodystudio.reconstruct.articulated_fit import (
    PoseRefineParams,
    quaternion_rotation_matrices,
    refine_bone_transforms,
    rotation_vectors_of_matrices,
)


def _rotvecs(rng):
    """Axes at every scale, through the 1e-3 switch of the series, zero and angles up to pi."""
    axes = rng.normal(size=(400, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = np.concatenate([np.geomspace(1e-9, np.pi, 300), 1e-3 + np.linspace(-1e-9, 1e-9, 50), np.zeros(1),
                             np.pi - np.geomspace(1e-9, 1e-2, 49)])
    return axes * angles[:, None]


def test_quaternion_matrices_equal_scipys_bit_for_bit():
    w = _rotvecs(np.random.default_rng(0))
    assert np.array_equal(quaternion_rotation_matrices(w), Rotation.from_rotvec(w).as_matrix())


def test_rotation_vectors_equal_scipys_bit_for_bit_on_every_branch():
    rng = np.random.default_rng(1)
    w = _rotvecs(rng)
    # products of rotations, as the fit's relative rotations Q_p^T Q_j are
    M = Rotation.from_rotvec(w).as_matrix()
    M = M @ Rotation.from_rotvec(rng.normal(size=(len(w), 3)) * 1e-3).as_matrix()
    choice = np.argmax(np.concatenate([np.diagonal(M, axis1=1, axis2=2), np.trace(M, axis1=1, axis2=2)[:, None]],
                                      axis=1), axis=1)
    assert set(choice) == {0, 1, 2, 3}  # each of Markley's formulas is exercised
    assert np.array_equal(rotation_vectors_of_matrices(M), Rotation.from_matrix(M).as_rotvec())
    # ties go to the first of (m00, m11, m22, trace), as scipy's argmax: quarter turns about x and y (m00 or m11
    # equal to the trace, 1) and a half turn about z
    ties = np.array([[[1.0, 0, 0], [0, 0, -1], [0, 1, 0]], [[0, 0, 1], [0, 1.0, 0], [-1, 0, 0]],
                     [[-1.0, 0, 0], [0, -1, 0], [0, 0, 1]]])
    assert np.array_equal(rotation_vectors_of_matrices(ties), Rotation.from_matrix(ties).as_rotvec())


def _fit_inputs(body):
    """A pose refinement of ``body`` towards its own vertices under a known bone perturbation (point-to-plane)."""
    from bodystudio.body.pose import Pose

    rng = np.random.default_rng(2)
    rot = body.rest_pose().rotations.copy()
    target_rot = rot + rng.normal(scale=0.15, size=rot.shape)
    target, _ = body.pose(Pose(target_rot, np.zeros(3)))
    from bodystudio.body.skinning import skinning_transforms

    T0 = skinning_transforms(body.skeleton, Pose(rot, np.zeros(3)))

    def term(V, N):
        r = np.einsum("ij,ij->i", V - target, N)
        return np.arange(len(V)), r, np.ones(len(V)), N

    return T0, term


def test_compiled_segment_update_is_the_numpy_one_to_rounding(body_2k):
    """``compiled_rotations``: the same fit as the numpy / scipy bookkeeping up to the products' rounding (a fit
    without the prior's gradient is 1e-6 off or more, so the bound sees a compiled prior that drops it)."""
    T0, term = _fit_inputs(body_2k)
    params = PoseRefineParams(iterations=4, prior_weight=0.5)
    T_ref = refine_bone_transforms(body_2k, T0, None, params, data_term=term)
    T_com = refine_bone_transforms(body_2k, T0, None, PoseRefineParams(iterations=4, prior_weight=0.5,
                                                                      compiled_rotations=True), data_term=term)
    assert np.abs(T_ref - T0).max() > 1e-2  # the fit moved the bones
    np.testing.assert_allclose(T_com, T_ref, rtol=0, atol=1e-12)
    T_no_prior = refine_bone_transforms(body_2k, T0, None, PoseRefineParams(iterations=4, prior_weight=0.0),
                                        data_term=term)
    assert np.abs(T_no_prior - T_ref).max() > 1e-6
