"""Analytic tests of the arm template and its pose type (bodystudio.muscle.arm, Sec. 6.1 of Arm-Muscle Capture).

The template's four-part weights and tracked mask on hand-set skin weights, the bone grouping of a made-up
skeleton, the ArmPose conversions and refusals, and ``with_vertices``.
"""

from types import SimpleNamespace

import numpy as np
import pytest

from bodystudio.errors import InputError
from bodystudio.muscle.arm import (
    JOINT_NAMES,
    ArmPose,
    _region,
    arm_bone_groups,
    arm_pose_from_body_pose,
    arm_template,
    body_pose_from_arm_pose,
)


@pytest.fixture(scope="module")
def plain_2k():
    from bodystudio.body import build_body

    return build_body(resolution="2k")


def _fake_body(body, weights):
    return SimpleNamespace(resolution=body.resolution, n_vertices=body.n_vertices, skeleton=body.skeleton,
                           weights=weights, vertices=body.vertices)


def test_bone_groups_of_a_made_up_skeleton():
    names = ("root", "spine", "clavicle_l", "upperarm_l", "lowerarm_l", "hand_l", "index_01_l", "thumb_02_l",
             "index_01_r", "hand_r", "upperarm_r", "lowerarm_r", "wrist_l", "ring_03_l")
    g = arm_bone_groups(names, "left")
    assert list(g) == ["torso", "upperarm", "forearm", "hand"]
    assert g["upperarm"] == [3] and g["forearm"] == [4] and g["hand"] == [5, 6, 7, 13]
    assert g["torso"] == [0, 1, 2, 8, 9, 10, 11, 12]
    r = arm_bone_groups(names, "right")
    assert r["upperarm"] == [10] and r["forearm"] == [11] and r["hand"] == [8, 9]
    with pytest.raises(InputError, match=r"^unknown arm side 'up'; valid: left, right$"):
        arm_bone_groups(names, "up")


def test_template_fields_and_default_side(plain_2k):
    T = arm_template(plain_2k)
    ids, faces = _region("2k", "left")
    assert T.side == "left" and T.resolution == "2k"
    np.testing.assert_array_equal(T.vertex_ids, ids)
    np.testing.assert_array_equal(T.faces, faces)
    np.testing.assert_array_equal(T.vertices, plain_2k.vertices[ids])
    names = plain_2k.skeleton.bone_names
    np.testing.assert_array_equal(T.joints, plain_2k.skeleton.heads[[names.index(b) for b in
                                                                     ("upperarm_l", "lowerarm_l", "hand_l")]])
    assert T.key.startswith(f"2k-left-{len(ids)}-")
    R = arm_template(plain_2k, "right")
    assert R.side == "right" and R.key.startswith("2k-right-")


def test_part_weights_are_normalised_and_the_mask_is_upper_plus_forearm_without_hand(plain_2k):
    names = plain_2k.skeleton.bone_names
    ids = _region("2k", "left")[0]
    W = plain_2k.weights.copy()
    col = {n: names.index(n) for n in ("spine_01", "upperarm_l", "lowerarm_l", "hand_l")}
    rows = {  # torso, upper arm, forearm, hand
        0: (0.7, 0.3, 0.0, 0.0),  # upper + fore exactly 0.3: tracked
        1: (0.5, 0.25, 0.25, 0.0),  # upper + fore 0.5: tracked
        2: (0.5, 0.0, 0.0, 0.5),  # hand
        3: (0.0, 0.5, 0.0, 0.5),  # hand weight exactly 0.5: not tracked
        4: (0.75, 0.0, 0.25, 0.0),  # forearm 0.25 only: not tracked
        5: (0.5, 0.0, 0.25, 0.25),
    }
    for k, w in rows.items():
        W[ids[k]] = 0.0
        for name, v in zip(("spine_01", "upperarm_l", "lowerarm_l", "hand_l"), w, strict=True):
            W[ids[k], col[name]] = v
    T = arm_template(_fake_body(plain_2k, W), "left")
    np.testing.assert_array_equal(T.part_weights[:6], np.array([rows[k] for k in range(6)]))
    assert T.arm_mask[:6].tolist() == [True, True, False, False, False, False]
    # skin weights that do not sum to 1 give the same, normalised, part weights
    T2 = arm_template(_fake_body(plain_2k, 2.0 * W), "left")
    np.testing.assert_allclose(T2.part_weights, T.part_weights, atol=1e-15)
    np.testing.assert_allclose(T2.part_weights.sum(axis=1), 1.0, atol=1e-15)


def test_a_body_with_too_few_vertices_is_refused(plain_2k):
    ids = _region("2k", "left")[0]
    small = SimpleNamespace(resolution="2k", n_vertices=int(ids.max()))
    with pytest.raises(InputError, match=rf"^body has {ids.max()} vertices; the 2k arm template needs more$"):
        arm_template(small, "left")


def test_arm_pose_converts_its_fields():
    p = ArmPose([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], list(range(9)))
    assert isinstance(p.root, np.ndarray) and p.root.dtype == np.float64 and p.root.shape == (4, 4)
    assert isinstance(p.angles, np.ndarray) and p.angles.dtype == np.float64 and p.angles.shape == (3, 3)
    np.testing.assert_array_equal(p.angles[2], [6.0, 7.0, 8.0])
    assert "XXrootXX" not in vars(p) and "ROOT" not in vars(p) and "ANGLES" not in vars(p)
    q = ArmPose.from_dict({"root": np.eye(4, dtype=int).tolist(), "shoulder": [1, 2, 3], "elbow": [0, 0, 1],
                           "wrist": [0, 0, 0]})
    assert q.root.dtype == np.float64 and q.angles.dtype == np.float64
    np.testing.assert_array_equal(q.angles[0], [1.0, 2.0, 3.0])
    # numbers written as strings (a hand-edited JSON) are read as numbers; other strings are refused
    s = ArmPose.from_dict({"root": [["1", "0", "0", "0"], ["0", "1", "0", "0"], ["0", "0", "1", "0"],
                                    ["0", "0", "0", "1"]], "shoulder": ["0", "0", "0.5"], "elbow": [0, 0, 0],
                           "wrist": [0, 0, 0]})
    np.testing.assert_array_equal(s.root, np.eye(4))
    np.testing.assert_array_equal(s.angles[0], [0.0, 0.0, 0.5])
    with pytest.raises(InputError, match=r"^arm pose: needs 'root' \(4x4\)"):
        ArmPose.from_dict({"root": [["a"] * 4] * 4, "shoulder": [0, 0, 0], "elbow": [0, 0, 0], "wrist": [0, 0, 0]})
    with pytest.raises(InputError, match=r"^arm pose: needs 'root' \(4x4\)"):
        ArmPose.from_dict({"root": np.eye(4).tolist(), "shoulder": ["x", 0, 0], "elbow": [0, 0, 0],
                           "wrist": [0, 0, 0]})
    d = p.to_dict()
    assert list(d) == ["root", *JOINT_NAMES] and d["elbow"] == [3.0, 4.0, 5.0]


@pytest.mark.parametrize("data, why", [
    ({"root": np.eye(4).tolist(), "shoulder": [0, 0, 0], "elbow": [0, 0, float("nan")], "wrist": [0, 0, 0]},
     "angles not finite"),
    ({"root": np.where(np.eye(4) > 0, np.inf, 0.0).tolist(), "shoulder": [0, 0, 0], "elbow": [0, 0, 0],
      "wrist": [0, 0, 0]},
     "root not finite"),
    ({"root": np.eye(4).tolist(), "shoulder": [0, 0], "elbow": [0, 0], "wrist": [0, 0]}, "joints not 3-vectors"),
    ({"root": np.eye(3).tolist(), "shoulder": [0, 0, 0], "elbow": [0, 0, 0], "wrist": [0, 0, 0]}, "root 3x3"),
])
def test_a_bad_pose_dict_is_refused(data, why):
    with pytest.raises(InputError, match=r"^arm pose: 'root' must be a finite 4x4 matrix and each joint a finite "
                                         r"3-vector$"):
        ArmPose.from_dict(data)
    with pytest.raises(InputError, match=r"^p.json: 'root' must be"):
        ArmPose.from_dict(data, "p.json")


def test_a_pose_dict_without_keys_names_the_source():
    with pytest.raises(InputError, match=r"^arm pose: needs 'root' \(4x4\) and shoulder/elbow/wrist rotation vectors"):
        ArmPose.from_dict({"root": np.eye(4).tolist()})


def test_body_pose_conversions_default_to_the_left_arm(muscular_body_2k):
    from bodystudio.body import Pose

    body = muscular_body_2k
    rot = np.zeros((body.skeleton.n_bones, 3))
    for b, v in (("upperarm_l", [0.3, 0.1, -0.2]), ("lowerarm_l", [0.0, 0.5, 0.1]), ("upperarm_r", [0.4, 0, 0])):
        rot[body.skeleton.index(b)] = v
    pose = Pose(rot, np.zeros(3))
    a = arm_pose_from_body_pose(body, pose)
    np.testing.assert_allclose(a.angles, arm_pose_from_body_pose(body, pose, "left").angles)
    assert not np.allclose(a.angles, arm_pose_from_body_pose(body, pose, "right").angles)
    back = body_pose_from_arm_pose(body, a)
    np.testing.assert_allclose(back.rotations[body.skeleton.index("upperarm_l")], [0.3, 0.1, -0.2], atol=1e-12)
    assert np.abs(back.rotations[body.skeleton.index("upperarm_r")]).max() == 0.0


def test_with_vertices_is_another_subject_on_the_same_template(arm_template_2k):
    T = arm_template_2k
    V = T.vertices + 0.1
    O = T.with_vertices(V.tolist())
    assert O.vertices.dtype == np.float64
    np.testing.assert_allclose(O.vertices, V)
    assert O.key == T.key and O.side == T.side and O.resolution == T.resolution and O.n_vertices == T.n_vertices
    assert O.vertex_ids is T.vertex_ids and O.faces is T.faces and O.part_weights is T.part_weights
    assert O.arm_mask is T.arm_mask and O.joints is T.joints
    Oi = T.with_vertices(np.ones(T.vertices.shape, dtype=int))
    assert Oi.vertices.dtype == np.float64
    J = np.arange(9)
    O2 = T.with_vertices(V, J)
    assert O2.joints.shape == (3, 3) and O2.joints.dtype == np.float64
    np.testing.assert_array_equal(O2.joints[1], [3.0, 4.0, 5.0])
    with pytest.raises(InputError, match=rf"^arm vertices have shape \(3, 3\); this template needs "
                                         rf"\({T.n_vertices}, 3\)$"):
        T.with_vertices(np.zeros((3, 3)))
