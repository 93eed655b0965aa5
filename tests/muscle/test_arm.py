"""The arm template and its four-part kinematics reproduce the body's skinning (bodystudio.muscle.arm)."""

import numpy as np
import pytest

from bodystudio.body import Pose
from bodystudio.errors import InputError
from bodystudio.muscle.arm import (
    PARTS,
    ArmPose,
    arm_pose_from_body_pose,
    arm_template,
    body_pose_from_arm_pose,
    part_transforms,
    pose_arm,
)


def _random_pose(body, seed, bones=("upperarm_l", "lowerarm_l", "hand_l", "spine_01", "pelvis")):
    rng = np.random.default_rng(seed)
    rot = np.zeros((body.skeleton.n_bones, 3))
    for name in bones:
        rot[body.skeleton.index(name)] = rng.normal(0, 0.5, 3)
    return Pose(rot, rng.normal(0, 0.2, 3))


def test_template_is_an_arm_with_chest(arm_template_2k, muscular_body_2k):
    T = arm_template_2k
    assert T.part_weights.shape == (T.n_vertices, len(PARTS))
    np.testing.assert_allclose(T.part_weights.sum(axis=1), 1.0)
    assert T.faces.min() == 0 and T.faces.max() == T.n_vertices - 1
    # Every part has vertices of its own; the tracked mask holds neither hand nor chest.
    assert (T.part_weights.argmax(axis=1)[:, None] == np.arange(4)).sum(axis=0).min() > 20
    assert 100 < T.arm_mask.sum() < T.n_vertices
    assert (T.part_weights[T.arm_mask, 3] < 0.5).all() and (T.part_weights[T.arm_mask, 0] < 0.7).all()
    # The left arm lies at +x; the right template mirrors it.
    assert T.vertices[T.arm_mask, 0].min() > 0.05
    R = arm_template(muscular_body_2k, "right")
    assert R.vertices[R.arm_mask, 0].max() < -0.05
    assert R.key != T.key
    # Same topology for another subject, different positions.
    from bodystudio.body import Phenotype, build_body

    other = arm_template(build_body(Phenotype(gender=0.0, weight=0.9), resolution="2k"), "left")
    assert other.key == T.key and np.abs(other.vertices - T.vertices).max() > 0.01


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_pose_arm_reproduces_body_skinning(arm_template_2k, muscular_body_2k, seed):
    body, T = muscular_body_2k, arm_template_2k
    pose = _random_pose(body, seed)
    V_body, heads = body.pose(pose)
    ap = arm_pose_from_body_pose(body, pose, "left")
    V_arm = pose_arm(T.vertices, T.part_weights, T.joints, ap)
    err = np.linalg.norm(V_arm - V_body[T.vertex_ids], axis=1)
    assert err[T.arm_mask].max() < 1e-9  # the arm chain is exact
    assert err.max() < 1e-3  # sub-mm on the chest while the clavicle does not move
    # The posed joint centres are where the body's bone heads go.
    P = part_transforms(T.joints, ap)
    names = body.skeleton.bone_names
    for k, bone in enumerate(("upperarm_l", "lowerarm_l", "hand_l")):
        np.testing.assert_allclose(P[k + 1, :3, :3] @ T.joints[k] + P[k + 1, :3, 3], heads[names.index(bone)],
                                   atol=1e-9)


def test_arm_pose_round_trips(muscular_body_2k):
    body = muscular_body_2k
    pose = _random_pose(body, 5)
    ap = arm_pose_from_body_pose(body, pose, "left")
    back = body_pose_from_arm_pose(body, ap, "left", base=pose)
    np.testing.assert_allclose(back.rotations, pose.rotations, atol=1e-12)
    again = ArmPose.from_dict(ap.to_dict())
    np.testing.assert_allclose(again.angles, ap.angles)
    np.testing.assert_allclose(again.root, ap.root)


def test_rest_arm_pose_is_identity(arm_template_2k):
    T = arm_template_2k
    np.testing.assert_allclose(pose_arm(T.vertices, T.part_weights, T.joints, ArmPose.rest()), T.vertices, atol=1e-12)


def test_bad_side_and_bad_pose_dict(muscular_body_2k):
    with pytest.raises(InputError, match="side"):
        arm_template(muscular_body_2k, "middle")
    with pytest.raises(InputError, match="root"):
        ArmPose.from_dict({"shoulder": [0, 0, 0]})
