"""Poses (:mod:`bodystudio.body.pose`) against hand-computed cases.

Mutation tests (issue 17, docs/mutation/body-pose.md): MPFB2's Blender XYZ Euler angles against the product
``Rz Ry Rx`` of the elementary rotations written out here, the pose transfer against a rest frame turned by a
quarter turn (the rotation axis read off by hand), every refusal by its text.
"""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bodystudio.body import pose as P
from bodystudio.errors import FileFormatError, InputError

BONES = ("root", "spine", "arm")


def _rx(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _ry(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _rz(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def test_pose_holds_float64_arrays_of_the_right_shape():
    p = P.Pose([1, 2, 3, 4, 5, 6], (7, 8, 9))
    assert p.rotations.shape == (2, 3) and p.rotations.dtype == np.float64
    assert p.translation.shape == (3,) and p.translation.dtype == np.float64
    np.testing.assert_array_equal(p.rotations, [[1, 2, 3], [4, 5, 6]])
    np.testing.assert_array_equal(p.translation, [7, 8, 9])
    r = P.Pose.rest(4)
    np.testing.assert_array_equal(r.rotations, np.zeros((4, 3)))
    np.testing.assert_array_equal(r.translation, np.zeros(3))
    with pytest.raises(ValueError):
        P.Pose(np.zeros((2, 3)), np.zeros(4))


def test_axis_angle_pose_from_dict():
    p = P.pose_from_dict({"rotations": {"arm": [0.1, -0.2, 0.3], "root": (1, 0, 0)},
                          "translation": [0.5, 1, -2]}, BONES)
    np.testing.assert_array_equal(p.rotations, [[1, 0, 0], [0, 0, 0], [0.1, -0.2, 0.3]])
    np.testing.assert_array_equal(p.translation, [0.5, 1.0, -2.0])
    p = P.pose_from_dict({"rotations": {}}, BONES)
    np.testing.assert_array_equal(p.rotations, np.zeros((3, 3)))
    np.testing.assert_array_equal(p.translation, np.zeros(3))


def test_mpfb2_euler_xyz_is_rz_ry_rx():
    ex, ey, ez = 0.3, -0.7, 1.1
    p = P.pose_from_dict({"bone_rotations": {"spine": [ex, ey, ez]}, "translation": [0, 0, 1]}, BONES)
    got = Rotation.from_rotvec(p.rotations[1]).as_matrix()
    np.testing.assert_allclose(got, _rz(ez) @ _ry(ey) @ _rx(ex), atol=1e-12)
    np.testing.assert_array_equal(p.rotations[[0, 2]], np.zeros((2, 3)))
    np.testing.assert_array_equal(p.translation, [0, 0, 1])
    # one angle alone is the axis-angle vector itself
    p = P.pose_from_dict({"bone_rotations": {"arm": [0.0, 0.4, 0.0]}}, BONES)
    np.testing.assert_allclose(p.rotations[2], [0.0, 0.4, 0.0], atol=1e-15)
    # a file with both tables: the Euler one is read
    p = P.pose_from_dict({"rotations": {"arm": [9, 9, 9]}, "bone_rotations": {"arm": [0.0, 0.0, 0.2]}}, BONES)
    np.testing.assert_allclose(p.rotations[2], [0.0, 0.0, 0.2], atol=1e-15)


@pytest.mark.parametrize("data, kind, text", [
    ([], FileFormatError, "src: a pose file needs a 'rotations' (axis-angle) or 'bone_rotations' (Euler XYZ) object "
                          "mapping bone names to 3 numbers"),
    ({"translation": [0, 0, 0]}, FileFormatError, "src: a pose file needs a 'rotations'"),
    ({"rotations": [[0, 0, 0]]}, FileFormatError, "src: 'rotations' must map bone names to [x, y, z]"),
    ({"bone_rotations": "x"}, FileFormatError, "src: 'rotations' must map bone names to [x, y, z]"),
    ({"rotations": {"leg": [0, 0, 0]}}, InputError, "src: unknown bone 'leg'; valid bones: root, spine, arm"),
    ({"rotations": {"arm": [0, 0]}}, FileFormatError, "src: rotation of arm must be 3 finite numbers, got [0, 0]"),
    ({"rotations": {"arm": [0, 0, 0, 0]}}, FileFormatError, "rotation of arm must be 3 finite numbers"),
    ({"rotations": {"arm": [0, True, 0]}}, FileFormatError, "got [0, True, 0]"),
    ({"rotations": {"arm": [0, "1", 0]}}, FileFormatError, "rotation of arm must be 3 finite numbers"),
    ({"rotations": {"arm": "abc"}}, FileFormatError, "got 'abc'"),
    ({"rotations": {"arm": [0, float("nan"), 0]}}, FileFormatError, "rotation of arm must be 3 finite numbers"),
    ({"bone_rotations": {"arm": [0, float("inf"), 0]}}, FileFormatError, "rotation of arm must be 3 finite"),
    ({"rotations": {}, "translation": [0, 0]}, FileFormatError,
     "src: 'translation' must be 3 finite numbers in metres, got [0, 0]"),
    ({"rotations": {}, "translation": [0, 0, float("inf")]}, FileFormatError, "'translation' must be 3 finite"),
    ({"rotations": {}, "translation": [0, False, 0]}, FileFormatError, "'translation' must be 3 finite"),
    ({"rotations": {}, "translation": None}, FileFormatError, "got None"),
])
def test_pose_from_dict_refusals(data, kind, text):
    with pytest.raises(kind) as err:
        P.pose_from_dict(data, BONES, "src")
    assert text in str(err.value)
    assert type(err.value) is kind


def test_pose_from_dict_names_the_pose_by_default():
    with pytest.raises(FileFormatError, match=r"^pose: a pose file needs"):
        P.pose_from_dict({}, BONES)


def test_load_pose_reads_a_file_and_refuses_by_path(tmp_path):
    f = tmp_path / "p.json"
    f.write_text(json.dumps({"rotations": {"spine": [0, 0.5, 0]}, "translation": [1, 2, 3]}))
    p = P.load_pose(str(f), BONES)
    np.testing.assert_array_equal(p.rotations, [[0, 0, 0], [0, 0.5, 0], [0, 0, 0]])
    np.testing.assert_array_equal(p.translation, [1, 2, 3])
    with pytest.raises(FileFormatError, match=rf"^{tmp_path / 'nope.json'}: pose file not found$"):
        P.load_pose(tmp_path / "nope.json", BONES)
    f.write_text("{rotations")
    with pytest.raises(FileFormatError, match=rf"^{f}: not valid JSON \(.*\); a pose file is JSON with a 'rot"):
        P.load_pose(f, BONES)
    f.write_bytes(b"\xff\xfe\xfa")
    with pytest.raises(FileFormatError, match=rf"^{f}: not valid JSON"):
        P.load_pose(f, BONES)
    f.write_text(json.dumps({"rotations": {"leg": [0, 0, 0]}}))
    with pytest.raises(InputError, match=rf"^{f}: unknown bone 'leg'"):
        P.load_pose(f, BONES)


def test_pose_to_dict_keeps_only_turned_bones_and_round_trips():
    pose = P.Pose([[0, 0, 0], [0, -0.25, 0], [1e-9, 0, 0]], [0.5, 0, 0])
    d = P.pose_to_dict(pose, BONES)
    assert d == {"rotations": {"spine": [0.0, -0.25, 0.0], "arm": [1e-9, 0.0, 0.0]}, "translation": [0.5, 0.0, 0.0]}
    back = P.pose_from_dict(json.loads(json.dumps(d)), BONES)
    np.testing.assert_array_equal(back.rotations, pose.rotations)
    np.testing.assert_array_equal(back.translation, pose.translation)


def test_transfer_pose_to_a_rest_frame_turned_a_quarter_about_z():
    # source rest frames: identity; target bone 1 turned +90 deg about z (its x axis is the world's y)
    Rs = np.tile(np.eye(3), (2, 1, 1))
    Rt = Rs.copy()
    Rt[1] = _rz(np.pi / 2)
    a = 0.6
    pose = P.Pose([[0.0, 0.0, 0.3], [a, 0.0, 0.0]], [1.0, 2.0, 3.0])
    out = P.transfer_pose(pose, SimpleNamespace(rest_rotations=Rs), SimpleNamespace(rest_rotations=Rt))
    # bone 0 unchanged; bone 1 turns about world x = the target frame's -y axis
    np.testing.assert_allclose(out.rotations, [[0.0, 0.0, 0.3], [0.0, -a, 0.0]], atol=1e-12)
    np.testing.assert_array_equal(out.translation, [1.0, 2.0, 3.0])
    # both frames turned: the world rotation R L R^T is what is kept
    Rs2 = np.stack([_rx(0.4), _ry(-1.0)])
    Rt2 = np.stack([_rz(0.9), _rx(2.0) @ _ry(0.3)])
    pose2 = P.Pose([[0.2, -0.1, 0.5], [-0.7, 0.3, 0.1]], np.zeros(3))
    out2 = P.transfer_pose(pose2, SimpleNamespace(rest_rotations=Rs2), SimpleNamespace(rest_rotations=Rt2))
    for b in range(2):
        Ls = Rotation.from_rotvec(pose2.rotations[b]).as_matrix()
        Lt = Rotation.from_rotvec(out2.rotations[b]).as_matrix()
        np.testing.assert_allclose(Rt2[b] @ Lt @ Rt2[b].T, Rs2[b] @ Ls @ Rs2[b].T, atol=1e-12)
