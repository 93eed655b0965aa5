"""MIR12r: ``mirror init --trunk-refit`` moves the source skeleton's trunk joints (SpineMid, SpineShoulder, Neck) onto
the SDK's, each frame unposed by the refined pose of the fitted body (init.refit_trunk_joints)."""

import numpy as np
import pytest

from bodystudio.body.model import BodyModel
from bodystudio.body.skeleton import Skeleton
from bodystudio.mirror import init as init_mod
from bodystudio.mirror.init import TRUNK_REFIT_JOINTS, TRUNK_REFIT_ROUNDS, refit_trunk_joints

#: The bone ends the three joints are (SpineMid is two: spine_02's head and spine_01's tail).
ENDS = [(bone, end) for ends in TRUNK_REFIT_JOINTS.values() for bone, end in ends]
PLANT_M = 0.015


def _planted(body, forward_m: float) -> BodyModel:
    """``body`` with every trunk refit joint moved ``forward_m`` forward (+z) and up."""
    sk = body.skeleton
    heads, tails = sk.heads.copy(), sk.tails.copy()
    for bone, end in ENDS:
        (heads if end == "head" else tails)[sk.index(bone), 1:] += forward_m
    return BodyModel(body.vertices, body.faces, Skeleton(sk.bone_names, sk.parents, heads, tails, sk.rolls),
                     body.weights, body.resolution, body.rig, vertex_ids=body.vertex_ids)


def _end(sk, bone, end):
    return (sk.heads if end == "head" else sk.tails)[sk.index(bone)]


@pytest.fixture(scope="module")
def refits(walk_scene):
    """The walk scene's true body with its own skeleton and with the trunk joints planted 15 mm forward and up,
    each refit against its six frames (1 cm SDK joint noise, 3 % bone jitter)."""
    frames = [(o, o.points) for o in walk_scene.observations]
    true = walk_scene.body
    return {"true": refit_trunk_joints(true, frames, walk_scene.sensor.depth),
            "planted": refit_trunk_joints(_planted(true, PLANT_M), frames, walk_scene.sensor.depth),
            "planted, one round": refit_trunk_joints(_planted(true, PLANT_M), frames, walk_scene.sensor.depth,
                                                     rounds=1)}


def test_planted_trunk_joints_come_back_to_where_the_sdk_sees_them(walk_scene, refits):
    """Planted 15 mm forward and 15 mm up (21 mm): measured, the refit lands within 0.1-0.2 mm of the true skeleton's
    (the result does not depend on where the joints started), SpineShoulder 0.6 mm and the Neck 2.3 mm from the truth
    in depth (six noisy frames: SpineMid 9 mm); one round 2.3-5.7 mm from the true skeleton's refit. The planted
    joints returned unchanged (21 mm off), or moved by half, fail."""
    assert TRUNK_REFIT_ROUNDS == 2
    truth = walk_scene.body.skeleton
    for bone, end in ENDS:
        a, b = _end(refits["planted"], bone, end), _end(refits["true"], bone, end)
        assert np.linalg.norm(a - b) < 0.0015, (bone, end)
        assert np.linalg.norm(_end(refits["planted, one round"], bone, end) - b) < 0.008, (bone, end)
    assert abs(_end(refits["planted"], "spine_03", "tail")[2] - _end(truth, "spine_03", "tail")[2]) < 0.003
    assert abs(_end(refits["planted"], "neck_01", "head")[2] - _end(truth, "neck_01", "head")[2]) < 0.005


def test_only_the_trunk_joints_move_and_across_the_body_they_stay(walk_scene, refits):
    """Every other bone end is the input's bit for bit; the moved ones keep their x (the midline); SpineMid stays one
    joint (spine_02's head is spine_01's tail)."""
    before, after = _planted(walk_scene.body, PLANT_M).skeleton, refits["planted"]
    moved_heads = np.zeros(before.n_bones, bool)
    moved_tails = np.zeros(before.n_bones, bool)
    for bone, end in ENDS:
        (moved_heads if end == "head" else moved_tails)[before.index(bone)] = True
    np.testing.assert_array_equal(after.heads[~moved_heads], before.heads[~moved_heads])
    np.testing.assert_array_equal(after.tails[~moved_tails], before.tails[~moved_tails])
    np.testing.assert_array_equal(after.heads[moved_heads, 0], before.heads[moved_heads, 0])
    np.testing.assert_array_equal(after.tails[moved_tails, 0], before.tails[moved_tails, 0])
    assert np.all(np.abs(after.heads[moved_heads] - before.heads[moved_heads]).max(axis=1) > 1e-3)
    np.testing.assert_array_equal(_end(after, "spine_02", "head"), _end(after, "spine_01", "tail"))
    assert after.bone_names == before.bone_names and np.array_equal(after.parents, before.parents)


def test_a_subset_of_joints_and_no_rounds(walk_scene):
    """``joints=("SpineShoulder",)`` moves spine_03's tail alone; no rounds, no frames or no joints give the input."""
    planted = _planted(walk_scene.body, PLANT_M)
    frames = [(o, o.points) for o in walk_scene.observations[:3]]
    one = refit_trunk_joints(planted, frames, walk_scene.sensor.depth, joints=("SpineShoulder",), rounds=1)
    i = one.index("spine_03")
    changed = np.flatnonzero(np.any(one.tails != planted.skeleton.tails, axis=1))
    assert list(changed) == [i] and np.array_equal(one.heads, planted.skeleton.heads)
    for kwargs in ({"rounds": 0}, {"joints": ()}):
        assert refit_trunk_joints(planted, frames, walk_scene.sensor.depth, **kwargs) is planted.skeleton
    assert refit_trunk_joints(planted, [], walk_scene.sensor.depth) is planted.skeleton


def test_the_init_refits_the_trunk_only_when_asked(walk_scene, model_6k, monkeypatch):
    """``initialise_from_observations(trunk_refit=True)`` hands the refit the fitted body, the fitted frames with their
    points, the depth camera and the unposing steps, and keeps its skeleton; by default it is not called."""
    calls = []

    def recording(body, frames, depth_camera, unpose_refine_steps):
        calls.append((body, list(frames), depth_camera, unpose_refine_steps))
        sk = body.skeleton
        return Skeleton(sk.bone_names, sk.parents, sk.heads + 1.0, sk.tails, sk.rolls)

    monkeypatch.setattr(init_mod, "refit_trunk_joints", recording)
    obs = walk_scene.observations[:2]
    kw = dict(view_point=walk_scene.sensor.depth.center, depth_camera=walk_scene.sensor.depth, passes=1)
    plain = init_mod.initialise_from_observations(obs, model_6k, **kw)
    assert not calls
    refit = init_mod.initialise_from_observations(obs, model_6k, trunk_refit=True, unpose_refine_steps=2, **kw)
    assert len(calls) == 1
    body, frames, camera, steps = calls[0]
    assert camera is walk_scene.sensor.depth and steps == 2
    assert [o.frame for o, _ in frames] == [o.frame for o in obs] and all(len(P) > 300 for _, P in frames)
    np.testing.assert_array_equal(body.vertices, plain.vertices)
    np.testing.assert_array_equal(body.skeleton.heads, plain.skeleton.heads)
    np.testing.assert_array_equal(refit.skeleton.heads, plain.skeleton.heads + 1.0)
    np.testing.assert_array_equal(refit.coeffs, plain.coeffs)
