"""The legs' rest rotations as nuisance columns of Eq. 2 (mir12ab: ``leg_splay_basis``, ``fit_shape``'s
``free_basis``, ``initialise_from_observations(leg_splay=True)``)."""

import numpy as np
import pytest

from bodystudio.errors import InputError
from bodystudio.mirror.init import fit_shape, initialise_from_observations, leg_splay_basis


@pytest.fixture(scope="module")
def planted(model_6k):
    """A body of the model's shape space with both calves splayed out by 3 degrees and turned 2 degrees back: a
    lower-leg configuration the coefficients alone do not hold."""
    rng = np.random.default_rng(5)
    c_true = rng.normal(0.0, 1.0, model_6k.n_components) * model_6k.stddev * 0.8
    V0 = model_6k.vertices(c_true)
    free, free_joints = leg_splay_basis(V0, model_6k.weights, model_6k.skeleton(c_true))
    delta = np.radians([3.0, 2.0, -3.0, 2.0])  # (left about z, left about x, right about z, right about x)
    return c_true, V0 + np.tensordot(delta, free, axes=1), free, free_joints, delta


def test_leg_splay_basis_moves_only_the_lower_legs(model_6k):
    c = np.zeros(model_6k.n_components)
    sk = model_6k.skeleton(c)
    free, joints = leg_splay_basis(model_6k.vertices(c), model_6k.weights, sk)
    assert free.shape == (4, len(model_6k.mean), 3) and joints.shape[0] == 4
    moved = np.linalg.norm(free, axis=2) > 0.01  # 1 cm a radian: the skin weights' stray 0.5 % left out
    # the left columns move left-leg vertices (x > 0) only, below the knee's height plus the skin's blend
    knee_y = sk.heads[sk.index("calf_l"), 1]
    V = model_6k.vertices(c)
    assert np.all(V[moved[0], 0] > 0) and np.all(V[moved[2], 0] < 0)
    assert np.all(V[moved[0], 1] < knee_y + 0.12)
    # a rotation about the forward axis moves the ankle sideways, about the sideways axis forward / back
    ankle = sk.tails[sk.index("calf_l")] - sk.heads[sk.index("calf_l")]
    np.testing.assert_allclose(np.cross([0.0, 0.0, 1.0], ankle)[2], 0.0)
    assert abs(joints[0]).max() > 0.3 and abs(joints[1]).max() > 0.3  # ~ the calf's length per radian


def test_free_columns_recover_shape_and_splay(model_6k, planted):
    c_true, V, free, free_joints, delta = planted
    c_free = fit_shape(V, model_6k, correspondence=np.arange(len(V)), iterations=2, free_basis=free)
    c_plain = fit_shape(V, model_6k, correspondence=np.arange(len(V)), iterations=2)
    err_free = np.linalg.norm(model_6k.vertices(c_free) - model_6k.vertices(c_true), axis=1).mean()
    err_plain = np.linalg.norm(model_6k.vertices(c_plain) - model_6k.vertices(c_true), axis=1).mean()
    # measured: the free columns take the splay and the shape comes back to 0.0x mm; the coefficients alone bend the
    # whole body to the splayed legs
    assert err_free < 2e-4, err_free
    assert err_plain > 5 * err_free and err_plain > 5e-4, err_plain


def test_bad_free_basis_is_refused(model_6k):
    V = model_6k.vertices(np.zeros(model_6k.n_components))
    with pytest.raises(InputError, match=r"free_basis must be finite \(m, 6002, 3\)"):
        fit_shape(V, model_6k, correspondence=np.arange(len(V)), iterations=1, free_basis=np.zeros((2, 10, 3)))


@pytest.mark.slow
def test_initialisation_with_leg_splay_still_recovers_stature_and_mass(walk_scene, model_6k):
    source = initialise_from_observations(walk_scene.observations, model_6k,
                                          view_point=walk_scene.sensor.depth.center, leg_splay=True)
    m = model_6k.measure(source.coeffs)
    # the default's bounds in test_init.py (6.4 mm, 1.1 kg measured there)
    assert abs(m["stature_m"] - walk_scene.truth["stature_m"]) < 0.0095
    assert abs(m["mass_kg"] - walk_scene.truth["mass_kg"]) < 2.0


def _hinge_poses(skeleton, eps_rad, flexions, rng):
    """Poses whose calves turn about their rest x axis (the knee's hinge) by ``flexions`` after a fixed abduction
    ``eps_rad`` about their z axis, the thighs and root turned at random."""
    from scipy.spatial.transform import Rotation

    from bodystudio.body.pose import Pose

    poses = []
    for theta in flexions:
        rot = np.zeros((skeleton.n_bones, 3))
        for bone in ("Root", "thigh_l", "thigh_r"):
            rot[skeleton.index(bone)] = rng.normal(0.0, 0.4, 3)
        calf = (Rotation.from_rotvec([theta, 0.0, 0.0]) * Rotation.from_rotvec([0.0, 0.0, eps_rad])).as_rotvec()
        rot[skeleton.index("calf_l")] = calf
        rot[skeleton.index("calf_r")] = calf
        poses.append(Pose(rot, np.zeros(3)))
    return poses


def test_knee_hinge_rows_measure_the_static_abduction_at_any_flexion(model_6k):
    from bodystudio.body.kinect import kinect_joint_names
    from bodystudio.mirror.init import _model_kinect_joints, knee_hinge_splay_rows

    sk = model_6k.skeleton(np.zeros(model_6k.n_components))
    Jm, _ = _model_kinect_joints(model_6k, "v2")
    names = kinect_joint_names("v2")
    rng = np.random.default_rng(3)
    for eps, flexions in ((0.05, (0.1, 0.6, 1.2)), (-0.03, (0.0, 0.9))):
        A, b = knee_hinge_splay_rows(model_6k, sk, _hinge_poses(sk, eps, flexions, rng), "v2", weight=4.0)
        assert A.shape == (2, model_6k.n_components)
        for row, (calf, knee, ankle) in enumerate((("calf_l", "KneeLeft", "AnkleLeft"),
                                                   ("calf_r", "KneeRight", "AnkleRight"))):
            i = sk.index(calf)
            axis = sk.rest_rotations[i][:, 0]
            target = b[row] / 2.0 + (Jm[names.index(ankle)] - Jm[names.index(knee)]) @ axis
            # the rest calf held at the abduction every frame shows, whatever the knee's flexion and the thigh's turn
            np.testing.assert_allclose(target, -np.sin(eps) * sk.lengths[i], atol=1e-9)
    assert knee_hinge_splay_rows(model_6k, sk, [], "v2", weight=4.0) is None
