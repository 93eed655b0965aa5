"""Mutation tests of MIR12s's ``mirror.track.upright_root`` (docs/mutation/mirror-track.md, "MIR12s's upright root"):
a stand-in skeleton (a childless root first, then a root with two children at one head, a grandchild) against the
swing-twist decomposition written with scipy's quaternions, for a tilted, non-unit ``up``, a root turned by 0, by
pi about a horizontal axis (no twist at all), by 0.55 rad and by 1.07 rad. < 0.1 s."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bodystudio.body.pose import Pose
from bodystudio.body.skeleton import Skeleton
from bodystudio.mirror.track import upright_root


def _skeleton():
    heads = np.array([[2.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.1, 0.9, 0.05], [0.1, 0.9, 0.05], [0.1, 1.3, 0.0]])
    tails = np.array([[2.0, 0.1, 0.0], [0.0, 0.1, 0.3], [0.1, 1.2, 0.1], [0.3, 0.8, 0.0], [0.1, 1.5, 0.1]])
    return Skeleton(("spare", "Root", "spine", "thigh", "neck"), np.array([-1, -1, 1, 1, 2]), heads, tails,
                    np.array([0.0, 0.2, -0.1, 0.3, 0.0]))


def _world(sk, rv, j):
    Rr = sk.rest_rotations[j]
    return Rr @ Rotation.from_rotvec(rv[j]).as_matrix() @ Rr.T


def _twist(W, up):
    x, y, z, w = Rotation.from_matrix(W).as_quat()
    v = np.dot([x, y, z], up) * up
    q = np.array([*v, w])
    if np.linalg.norm(q) < 1e-12:
        return np.eye(3)
    return Rotation.from_quat(q / np.linalg.norm(q)).as_matrix()


@pytest.mark.parametrize("root_turn", ["none", "half_turn_about_a_horizontal_axis", "general", "under_a_radian"])
def test_the_root_keeps_its_twist_about_up_and_the_children_their_world_rotations(root_turn):
    sk = _skeleton()
    up_given = np.array([0.6, 2.0, 0.4])  # tilted and not of unit length
    up = up_given / np.linalg.norm(up_given)
    rng = np.random.default_rng(2)
    rv = rng.normal(scale=0.4, size=(5, 3))
    W0 = {"none": np.eye(3), "under_a_radian": Rotation.from_rotvec([0.2, 0.5, 0.1]).as_matrix(),
          "general": Rotation.from_rotvec([0.5, 0.9, -0.3]).as_matrix(),
          "half_turn_about_a_horizontal_axis": Rotation.from_rotvec(np.pi * np.cross(up, [0.0, 0.0, 1.0])
                                                                    / np.linalg.norm(np.cross(up, [0, 0, 1.0])))
          .as_matrix()}[root_turn]
    Rr = sk.rest_rotations
    rv[1] = Rotation.from_matrix(Rr[1].T @ W0 @ Rr[1]).as_rotvec()
    pose = Pose(rv.copy(), np.array([0.3, -0.2, 1.0]))
    out = upright_root(sk, pose, up=tuple(up_given))
    W = _world(sk, rv, 1)
    W_up = _twist(W, up)
    np.testing.assert_allclose(_world(sk, out.rotations, 1), W_up, atol=1e-9)
    np.testing.assert_allclose(W_up @ up, up, atol=1e-12)
    for j in (2, 3):  # each child's world rotation kept: W_up L_j' = W L_j
        np.testing.assert_allclose(W_up @ _world(sk, out.rotations, j), W @ _world(sk, rv, j), atol=1e-9)
    np.testing.assert_allclose(out.rotations[[0, 4]], rv[[0, 4]], atol=0)  # the childless root, the grandchild
    d = sk.heads[2] - sk.heads[1]
    np.testing.assert_allclose(out.translation, pose.translation + (W - W_up) @ d, atol=1e-9)
    if root_turn != "none":
        assert np.abs(W - W_up).max() > 0.04  # the tilt is really dropped
