"""``track.untwisted_pose`` (MIR12p) where the limbs' test file does not reach it (issue 17, mutation testing):
the root bone and a child of the root untwisted (the root's world rotation is then not a common factor that cancels),
the unknown-bone refusal's whole text, and ``init.time_init_and_track`` handing the IK pose, the fitted skeleton and
the run's limbs to it and warm-starting the next frame by the untwisted pose. One 2k skeleton, built once; ~2 s."""
from __future__ import annotations

import functools
import re
from types import SimpleNamespace as NS

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import bodystudio.mirror.track as track_mod
from bodystudio.body import Pose, build_body
from bodystudio.body.population import sample_population
from bodystudio.body.skinning import forward_kinematics, posed_joints
from bodystudio.errors import InputError
from bodystudio.mirror import init as init_mod
from bodystudio.mirror.track import UNTWIST_BONES, untwisted_pose


@functools.cache
def _skeleton():
    phenotype, local = sample_population(1, seed=5)[0]
    return build_body(phenotype, local, resolution="2k").skeleton


def _world(skeleton, pose):
    """(B, 3, 3) rest-world to posed-world rotation of each bone."""
    return forward_kinematics(skeleton, pose)[:, :3, :3] @ np.transpose(skeleton.rest_rotations, (0, 2, 1))


def _direction(skeleton, pose):
    h, t = posed_joints(skeleton, pose)
    d = t - h
    return d / np.linalg.norm(d, axis=1, keepdims=True)


@pytest.mark.parametrize("bones", [("Root",), ("pelvis",), ("pelvis", "thigh_l", "calf_l")])
def test_the_root_and_its_children_untwist_keeping_every_other_bones_world_rotation(bones):
    """Untwisting the root or a child of the root: each listed bone keeps its posed direction and has no twist left
    against its parent (the root: against the world), every other bone keeps its world rotation; the root's own
    rotation (1 rad about a tilted axis) is part of every bone's world rotation."""
    sk = _skeleton()
    rng = np.random.default_rng(11)
    rv = rng.normal(0.0, 0.35, (sk.n_bones, 3))
    rv[0] = [0.6, 0.5, -0.6]  # the root turned ~1 rad
    pose = Pose(rv, np.array([0.1, -0.2, 0.3]))
    out = untwisted_pose(sk, pose, bones)
    W0, W1 = _world(sk, pose), _world(sk, out)
    listed = [sk.index(b) for b in bones]
    others = np.setdiff1d(np.arange(sk.n_bones), listed)
    np.testing.assert_allclose(W1[others], W0[others], atol=1e-9)
    np.testing.assert_allclose(_direction(sk, out)[listed], _direction(sk, pose)[listed], atol=1e-9)
    np.testing.assert_array_equal(out.translation, pose.translation)
    for j in listed:
        p = sk.parents[j]
        L = W1[j] if p < 0 else W1[p].T @ W1[j]
        d = sk.tails[j] - sk.heads[j]
        assert abs(Rotation.from_matrix(L).as_rotvec() @ (d / np.linalg.norm(d))) < 1e-9
        # the pose had twist there: the bone's world rotation changed
        assert np.abs(W1[j] - W0[j]).max() > 1e-3


def test_an_unknown_bone_is_refused_naming_it_and_the_runs_list():
    sk = _skeleton()
    pose = Pose(np.zeros((sk.n_bones, 3)), np.zeros(3))
    msg = (f"untwisted_pose: no bone 'forearm_l' in the skeleton ({sk.n_bones} bones); name bones of its rig, "
           "e.g. track.UNTWIST_BONES")
    with pytest.raises(InputError, match="^" + re.escape(msg) + "$"):
        untwisted_pose(sk, pose, ("upperarm_l", "forearm_l"))


def test_time_init_and_track_untwists_each_ik_pose_and_warm_starts_by_it(monkeypatch):
    """The benchmark's tracking loop is the run's: every IK pose untwisted on the fitted skeleton with the run's
    limbs, the next frame's IK warm-started by the untwisted pose, the untwisted poses skinned."""
    source = NS(vertices=np.zeros((3, 3)), weights=np.ones((3, 1)), skeleton="skeleton", frames_used=(0,))
    monkeypatch.setattr(init_mod, "initialise_from_observations", lambda obs, m, **kw: source)
    ik, untwist, skinned = [], [], []

    def ik_pose(sk, joints, tracked, version, previous=None):
        ik.append((sk, joints, tracked, version, previous))
        return "ik" + joints

    def untwisted(sk, pose, bones):
        untwist.append((sk, pose, bones))
        return "u" + pose

    monkeypatch.setattr(init_mod, "ik_pose", ik_pose)
    monkeypatch.setattr(init_mod, "untwisted_pose", untwisted)
    monkeypatch.setattr(init_mod, "skin_vertices", lambda V, W, sk, pose: skinned.append(pose))
    monkeypatch.setattr(track_mod, "skin_source_and_target", lambda *a: None)
    obs = [NS(joints="J0", tracked="T0", version="v2"), NS(joints="J1", tracked="T1", version="v2")]
    init_mod.time_init_and_track(obs, "model", track_frames=3)
    assert ik == [("skeleton", "J0", "T0", "v2", None), ("skeleton", "J1", "T1", "v2", "uikJ0"),
                  ("skeleton", "J0", "T0", "v2", "uikJ1")]
    assert untwist == [("skeleton", "ikJ0", UNTWIST_BONES), ("skeleton", "ikJ1", UNTWIST_BONES),
                       ("skeleton", "ikJ0", UNTWIST_BONES)]
    assert init_mod.UNTWIST_BONES is track_mod.UNTWIST_BONES
    assert skinned == ["uikJ0", "uikJ1", "uikJ0"]
