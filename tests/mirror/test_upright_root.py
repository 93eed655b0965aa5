"""The root's tilt, a gauge of the posed source that turns the target (bodystudio.mirror.track.upright_root, MIR12s).

The game_engine rig's Root (the floor anchor) carries no skin weight and has one child, so a tilt of it moved into
the pelvis with the translation making up for it leaves the posed source as it was; the target (the source's joints
moved by the reshape, posed by the same world rotations and translation) turns the reshape's change of the pelvis
height by the tilt. ``upright_root`` keeps the root's turn about the vertical only.
"""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bodystudio.body.pose import Pose
from bodystudio.body.skeleton import Skeleton
from bodystudio.body.skinning import posed_joints
from bodystudio.errors import InputError
from bodystudio.mirror.init import SourceBody, refit_skeleton
from bodystudio.mirror.reshape import posed_source_and_target, target_coeffs, target_skeleton
from bodystudio.mirror.track import skin_vertices, upright_root


@pytest.fixture(scope="module")
def reshaped(model_6k):
    """A source body with the model's joints and its -10 cm / -10 kg Eq. 4 target (rest vertices and skeleton)."""
    from bodystudio.body import build_body
    from bodystudio.body.population import sample_population

    c = model_6k.project(build_body(*sample_population(1, seed=5)[0], resolution="6k").vertices)
    source = SourceBody(c, model_6k.vertices(c), refit_skeleton(model_6k, c), (0,), 0.0, model_6k.weights,
                        model_6k.faces)
    c_t = target_coeffs(model_6k, c, {"taller": -0.1, "heavier": -10.0})
    Vt_rest = model_6k.vertices(c_t)
    return source, Vt_rest, target_skeleton(source, Vt_rest, model_6k, c_t)


def _world(skeleton, pose, j):
    Rr = skeleton.rest_rotations[j]
    return Rr @ Rotation.from_rotvec(pose.rotations[j]).as_matrix() @ Rr.T


def _tilted(skeleton, pose, tilt):
    """The same posed source with the root turned by ``tilt`` (world axes) and the pelvis turned back (the gauge)."""
    rv, t = pose.rotations.copy(), pose.translation.copy()
    W_root = _world(skeleton, pose, 0)
    W_new = tilt @ W_root
    Rr = skeleton.rest_rotations
    rv[0] = Rotation.from_matrix(Rr[0].T @ W_new @ Rr[0]).as_rotvec()
    L_pelvis = Rr[1] @ Rotation.from_rotvec(rv[1]).as_matrix() @ Rr[1].T
    rv[1] = Rotation.from_matrix(Rr[1].T @ (W_new.T @ W_root @ L_pelvis) @ Rr[1]).as_rotvec()
    offset = skeleton.heads[1] - skeleton.heads[0]
    return Pose(rv, t + (W_root - W_new) @ offset)


def test_the_rig_root_is_a_weightless_anchor_with_one_child(reshaped):
    source, _, _ = reshaped
    sk = source.skeleton
    assert list(sk.parents).count(-1) == 1 and sk.bone_names[0] == "Root" and list(sk.parents).count(0) == 1
    assert np.asarray(source.weights)[:, 0].max() == 0.0


def test_upright_root_keeps_the_posed_source_and_drops_the_tilt(reshaped):
    """Random limbs, a root turned 70 degrees about the vertical and tilted 6: every skinned vertex and every joint
    but the root's head stays to 1e-9 m, the root's world rotation is the 70 degree turn alone."""
    source, _, _ = reshaped
    sk = source.skeleton
    rng = np.random.default_rng(2)
    yaw = Rotation.from_euler("y", 70, degrees=True).as_matrix()
    upright = Pose(rng.normal(0.0, 0.15, (sk.n_bones, 3)), np.array([0.3, 0.02, 0.4]))
    upright.rotations[0] = Rotation.from_matrix(sk.rest_rotations[0].T @ yaw @ sk.rest_rotations[0]).as_rotvec()
    axis = np.array([np.cos(0.3), 0.0, np.sin(0.3)])  # a horizontal axis: a tilt, no turn about the vertical
    tilt = Rotation.from_rotvec(np.radians(6.0) * axis).as_matrix()
    pose = _tilted(sk, upright, tilt)
    assert np.degrees(Rotation.from_matrix(_world(sk, pose, 0) @ yaw.T).magnitude()) > 5.0
    fixed = upright_root(sk, pose)
    np.testing.assert_allclose(_world(sk, fixed, 0), yaw, atol=1e-12)
    V0 = skin_vertices(source.vertices, source.weights, sk, pose)
    np.testing.assert_allclose(skin_vertices(source.vertices, source.weights, sk, fixed), V0, atol=1e-9)
    h0, t0 = posed_joints(sk, pose)
    h1, t1 = posed_joints(sk, fixed)
    np.testing.assert_allclose(h1[1:], h0[1:], atol=1e-9)
    np.testing.assert_allclose(t1[1:], t0[1:], atol=1e-9)
    np.testing.assert_allclose(upright_root(sk, fixed).rotations, fixed.rotations, atol=1e-9)  # idempotent


def test_the_target_no_longer_turns_with_the_roots_tilt(reshaped):
    """The truth's pose has an upright root; the same posed source with 5 degrees of the root's tilt moved out of
    the pelvis poses the -10 cm target ~2 mm off (the pelvis's drop turned by 5 degrees); upright, to 1e-9 m."""
    source, Vt_rest, rig = reshaped
    sk = source.skeleton
    rng = np.random.default_rng(4)
    yaw = Rotation.from_euler("y", -80, degrees=True).as_matrix()
    truth = Pose(rng.normal(0.0, 0.1, (sk.n_bones, 3)), np.array([-0.2, 0.0, 0.3]))
    truth.rotations[0] = Rotation.from_matrix(sk.rest_rotations[0].T @ yaw @ sk.rest_rotations[0]).as_rotvec()
    Vs_true, Vt_true = posed_source_and_target(source, Vt_rest, truth, rig)
    pose = _tilted(sk, truth, Rotation.from_euler("x", 5.0, degrees=True).as_matrix())
    Vs, Vt = posed_source_and_target(source, Vt_rest, pose, rig)
    np.testing.assert_allclose(Vs, Vs_true, atol=1e-9)  # the source cannot tell
    off = np.linalg.norm(Vt - Vt_true, axis=1).mean()
    assert 1e-3 < off < 1e-2, off
    Vs_up, Vt_up = posed_source_and_target(source, Vt_rest, upright_root(sk, pose), rig)
    np.testing.assert_allclose(Vs_up, Vs_true, atol=1e-9)
    np.testing.assert_allclose(Vt_up, Vt_true, atol=1e-9)


def test_a_root_whose_children_sit_apart_is_refused(reshaped):
    source, _, _ = reshaped
    sk = source.skeleton
    parents = np.array(sk.parents)
    parents[sk.bone_names.index("thigh_l")] = 0  # a second child of the root, at the hip
    odd = Skeleton(sk.bone_names, parents, sk.heads, sk.tails, sk.rolls)
    with pytest.raises(InputError, match="^upright_root: the root 'Root' has children at different rest heads"):
        upright_root(odd, Pose(np.zeros((sk.n_bones, 3)), np.zeros(3)))
