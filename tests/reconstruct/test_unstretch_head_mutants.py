"""``pose_init.neck_at_joint(..., unstretch_head=True)`` (rec15m) where test_unstretched_head.py does not reach it
(issue 17, mutation testing): the bundled rig's head has no child bone, so the loop that carries the head's children
with it (jaw, eyes of another rig) never ran. A stand-in skeleton of 8 bones whose head has two children and a
grandchild, and a sibling branch that must not move: every transform against the docstring's closed form
(the head's stretch ``s R (I + 0.3 u u^T)`` unstretched to ``s R`` about its midpoint; the children carried rigidly).
No body model; < 0.1 s."""
import functools
from types import SimpleNamespace as NS

import numpy as np

from bodystudio.body.skeleton import Skeleton
from bodystudio.reconstruct.pose_init import _descendants, neck_at_joint

NAMES = ("spine", "neck_01", "clavicle_l", "head", "jaw", "eye_l", "eyelid_l", "upperarm_l")
PARENTS = np.array([-1, 0, 0, 1, 3, 3, 5, 2])
HEADS = np.array([[0.0, 0.0, 0.0], [0.0, 0.4, 0.0], [0.02, 0.38, 0.0], [0.0, 0.5, 0.01], [0.0, 0.55, 0.05],
                  [0.03, 0.62, 0.08], [0.03, 0.63, 0.1], [0.15, 0.38, 0.0]])
TAILS = np.array([[0.0, 0.4, 0.0], [0.0, 0.5, 0.01], [0.15, 0.38, 0.0], [0.0, 0.72, 0.02], [0.0, 0.5, 0.11],
                  [0.03, 0.62, 0.1], [0.03, 0.64, 0.11], [0.4, 0.3, 0.0]])
SCALE = 1.1


def _rotation(axis, angle):
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def _transform(M, t):
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = M, t
    return T


@functools.cache
def _case():
    """The stand-in body and its transforms: rigid ones at the run's scale, the head stretched 1.3x along ``u``."""
    sk = Skeleton(NAMES, PARENTS, HEADS, TAILS, np.zeros(len(NAMES)))
    R = _rotation([0.2, 1.0, 0.3], 0.4)
    u = np.array([0.1, 0.9, 0.2]) / np.linalg.norm([0.1, 0.9, 0.2])
    T = np.stack([_transform(SCALE * _rotation([1.0, 0.2, -0.4], 0.1 * k), [0.01 * k, 0.02, -0.03 * k])
                  for k in range(len(NAMES))])
    M = SCALE * R @ (np.eye(3) + 0.3 * np.outer(u, u))
    T[3] = _transform(M, _apply(T[1], TAILS[1]) + [0.005, 0.01, 0.0] - M @ HEADS[3])  # just off the neck's end
    return NS(skeleton=sk), T, R


def _apply(T, p):
    return T[:3, :3] @ p + T[:3, 3]


def test_descendants_are_children_and_grandchildren_only():
    sk = _case()[0].skeleton
    assert sorted(_descendants(sk, 3)) == [4, 5, 6]
    assert sorted(_descendants(sk, 0)) == [1, 2, 3, 4, 5, 6, 7]
    assert _descendants(sk, 7) == []


def test_the_heads_children_follow_the_unstretched_head_and_the_rest_stays():
    body, T, R = _case()
    kept = T.copy()
    target = _apply(T[1], HEADS[1]) + [0.004, 0.02, 0.03]
    out = neck_at_joint(body, T, target, unstretch_head=True)
    np.testing.assert_array_equal(T, kept)
    mid = 0.5 * (HEADS[3] + TAILS[3])
    head = _transform(SCALE * R, _apply(T[3], mid) - SCALE * R @ mid)  # s R about the midpoint the fit placed
    np.testing.assert_allclose(out[3], head, atol=1e-12)
    change = head @ np.linalg.inv(T[3])
    assert np.abs(change - np.eye(4)).max() > 0.05
    for j in (4, 5, 6):  # jaw, eye and the eye's child: carried with the head
        np.testing.assert_allclose(out[j], change @ T[j], atol=1e-12)
    for j in (0, 2, 7):  # spine, clavicle and its arm: untouched
        np.testing.assert_array_equal(out[j], T[j])
    np.testing.assert_allclose(_apply(out[1], HEADS[1]), target, atol=1e-12)
    np.testing.assert_allclose(_apply(out[1], TAILS[1]), _apply(head, HEADS[3]), atol=1e-12)


def test_kept_stretch_and_a_rig_without_a_head_place_the_neck_only():
    body, T, _R = _case()
    target = _apply(T[1], HEADS[1]) + [0.004, 0.02, 0.03]
    plain = neck_at_joint(body, T, target)
    np.testing.assert_array_equal(np.delete(plain, 1, axis=0), np.delete(T, 1, axis=0))
    np.testing.assert_allclose(_apply(plain[1], TAILS[1]), _apply(T[1], TAILS[1]), atol=1e-12)
    sk = body.skeleton
    headless = NS(skeleton=Skeleton(tuple("skull" if n == "head" else n for n in NAMES), sk.parents, sk.heads,
                                    sk.tails, sk.rolls))
    np.testing.assert_array_equal(neck_at_joint(headless, T, target, unstretch_head=True), plain)
