"""E_trunk's bend (MIR12g, :func:`bodystudio.mirror.refine.trunk_bends`) on exact frames (issue 17, branch mutI).

A bone ``j`` whose world rotation is its parent's turned by a swing ``w`` (perpendicular to the bone's rest direction
carried by the parent) and twisted about its own rest direction has the bend ``w``: the rotation vector taking the rest
direction (turned with the parent) onto the posed one, read on the two swing ``axes``. Built here from random rest
rotations, parent rotations, swing angles up to 170 degrees and twists, the function must give ``axes @ w`` to
round-off;
a bone at rest has the bend 0 exactly (the guard on the cross product's norm)."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bodystudio.mirror.refine import trunk_bends

#: bone -> parent: a root, a chain of two, a second child of the root
PARENTS = (-1, 0, 1, 0)


def _frames(angles_deg, seed=0, twist=True):
    """Posed frames M (4, 4, 4), world rotations, rest rotations, and the swing rotation vector (world axes) of
    bones 1-3, each swung by ``angles_deg[i]`` about a random axis perpendicular to its carried rest direction."""
    rng = np.random.default_rng(seed)
    rest = Rotation.random(4, random_state=rng).as_matrix()
    world = np.empty((4, 3, 3))
    world[0] = Rotation.random(random_state=rng).as_matrix()
    swings = np.zeros((3, 3))
    for j in (1, 2, 3):
        q = world[PARENTS[j]] @ rest[j][:, 1]  # the rest direction turned with the parent
        a = np.cross(q, rng.normal(size=3))
        w = np.radians(angles_deg[j - 1]) * a / np.linalg.norm(a)
        swings[j - 1] = w
        spin = Rotation.from_rotvec(rng.uniform(-1.0, 1.0) * rest[j][:, 1]).as_matrix() if twist else np.eye(3)
        world[j] = Rotation.from_rotvec(w).as_matrix() @ world[PARENTS[j]] @ spin
    M = np.zeros((4, 4, 4))
    M[:, :3, :3] = world @ rest
    M[:, :3, 3] = rng.normal(size=(4, 3))  # heads anywhere: the bend is a direction's
    M[:, 3, 3] = 1.0
    return M, world, rest, swings


@pytest.mark.parametrize("angles", [(30.0, 12.0, 55.0), (170.0, 1.0, 90.0), (0.5, 120.0, 5.0)])
def test_the_bend_is_the_swing_off_the_parent_whatever_the_twist(angles):
    M, world, rest, swings = _frames(angles)
    rng = np.random.default_rng(1)
    bones = np.array([1, 2, 3])
    axes = rng.normal(size=(3, 2, 3))  # any two directions per bone: the bend is read on them
    bend = trunk_bends(M, world, rest, PARENTS, bones, axes)
    assert bend.shape == (3, 2)
    expected = np.einsum("nkj,nj->nk", axes, swings)
    np.testing.assert_allclose(bend, expected, atol=1e-9)
    # the bones in another order (and a list of parents' own order) read the same rows
    again = trunk_bends(M, world, rest, list(PARENTS), np.array([3, 1]), axes[[2, 0]])
    np.testing.assert_allclose(again, expected[[2, 0]], atol=1e-9)


def test_the_bend_reads_each_of_the_two_axes_apart():
    M, world, rest, swings = _frames((40.0, 25.0, 60.0), seed=3)
    axes = np.zeros((3, 2, 3))
    axes[:, 0] = [1.0, 0.0, 0.0]
    axes[:, 1] = [0.0, 0.0, 2.0]
    bend = trunk_bends(M, world, rest, PARENTS, np.array([1, 2, 3]), axes)
    np.testing.assert_allclose(bend[:, 0], swings[:, 0], atol=1e-9)
    np.testing.assert_allclose(bend[:, 1], 2.0 * swings[:, 2], atol=1e-9)


def test_a_bone_at_rest_against_its_parent_has_no_bend_however_its_parent_turned():
    M, world, rest, _ = _frames((0.0, 0.0, 0.0), seed=5)
    axes = np.random.default_rng(2).normal(size=(3, 2, 3))
    bend = trunk_bends(M, world, rest, PARENTS, np.array([1, 2, 3]), axes)
    assert np.all(np.isfinite(bend))
    np.testing.assert_allclose(bend, 0.0, atol=1e-12)
    # a tiny bend is still its own size (no guard swallowing it)
    M, world, rest, swings = _frames((1e-4, 2e-4, 3e-4), seed=5)
    bend = trunk_bends(M, world, rest, PARENTS, np.array([1, 2, 3]), axes)
    np.testing.assert_allclose(bend, np.einsum("nkj,nj->nk", axes, swings), rtol=1e-5, atol=1e-14)
