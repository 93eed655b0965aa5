"""MIR12e's speed changes of the mirror's session side (per frame, per actor), each pinned to the output it replaced."""

import numpy as np
import pytest

from bodystudio.body.pose import Pose, transfer_pose
from bodystudio.body.skinning import forward_kinematics, skinning_transforms
from bodystudio.body.statistical import load_statistical_model
from bodystudio.mirror.init import SourceBody
from bodystudio.mirror.reshape import posed_source_and_target, target_coeffs, target_skeleton
from bodystudio.mirror.track import posed_frames, rest_chain, skin_vertices


@pytest.fixture(scope="module")
def reshaped():
    """A 6k source body of a random shape, its +10 cm / +15 kg target (rest vertices and rig)."""
    model = load_statistical_model("6k", progress=False)
    c = np.random.default_rng(1).normal(size=len(model.stddev)) * 0.5 * model.stddev
    body = SourceBody(c, model.vertices(c), model.skeleton(c), (), 0.0, model.weights, model.faces)
    ct = target_coeffs(model, c, {"taller": 0.1, "heavier": 15})
    Vt = model.vertices(ct)
    return body, Vt, target_skeleton(body, Vt, model, ct)


def test_posed_frames_are_the_forward_kinematics():
    model = load_statistical_model("6k", progress=False)
    sk = model.skeleton(np.zeros(len(model.stddev)))
    pose = Pose(np.random.default_rng(2).normal(0, 0.6, (sk.n_bones, 3)), np.array([0.3, 0.9, 2.1]))
    from scipy.spatial.transform import Rotation

    M, T = posed_frames(*rest_chain(sk), Rotation.from_rotvec(pose.rotations).as_matrix(), pose.translation,
                        np.asarray(sk.parents, np.int64))
    np.testing.assert_allclose(M, forward_kinematics(sk, pose), atol=1e-13)
    np.testing.assert_allclose(T, skinning_transforms(sk, pose)[:, :3], atol=1e-13)


@pytest.mark.parametrize("seed", [3, 4])
def test_source_and_target_in_one_pass_are_the_two_skinnings(reshaped, seed):
    """posed_source_and_target's one pass (MIR12e) against what it replaced: skin_vertices of the source by the
    pose and of the target by transfer_pose's rotation vectors (their round trip is the ~1e-13 m)."""
    body, Vt, rig = reshaped
    rng = np.random.default_rng(seed)
    pose = Pose(rng.normal(0, 0.5, (body.skeleton.n_bones, 3)), rng.normal(0, 1, 3))
    Vs_got, Vt_got = posed_source_and_target(body, Vt, pose, rig)
    Vs_want = skin_vertices(body.vertices, body.weights, body.skeleton, pose)
    Vt_want = skin_vertices(Vt, body.weights, rig, transfer_pose(pose, body.skeleton, rig))
    np.testing.assert_allclose(Vs_got, Vs_want, rtol=0, atol=1e-12)
    np.testing.assert_allclose(Vt_got, Vt_want, rtol=0, atol=1e-11)
    assert np.abs(Vt_got - Vs_got).max() > 0.05  # the target is its own body, not the source's
    # the subset path is the two skinnings' rows
    sub = np.arange(0, len(Vt), 7)
    Vs_sub, Vt_sub = posed_source_and_target(body, Vt, pose, rig, subset=sub)
    np.testing.assert_allclose(Vs_sub, Vs_want[sub], rtol=0, atol=1e-12)
    np.testing.assert_allclose(Vt_sub, Vt_want[sub], rtol=0, atol=1e-11)
