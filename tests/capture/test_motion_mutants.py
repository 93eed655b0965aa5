"""Synthetic motions against independent references (issue 17, mutation testing of capture/motion.py).

A stand-in skeleton (the bones the motions drive, with rest rolls, a bent elbow and arms slightly forward, so that
rest frames are not the identity and no axis is trivial) replaces the 2k body: every test runs in milliseconds.
References: the rest frames' transposes applied bone by bone, rotations measured back from the directions they
move (angles between bones, elevation in the frontal plane), scipy's own RotationSpline on the world rotations, the
seed's draws taken in the documented order, the frame times written out (``k / n``, ``k / (n - 1)``,
``k / fps / period`` modulo 1: issue 12's rule that a motion plays at its frame rate, not stretched over the frames).
"""

from functools import cache

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, RotationSpline

from bodystudio.body.skeleton import Skeleton
from bodystudio.capture import motion
from bodystudio.capture.motion import (
    CYCLIC_MOTIONS,
    MOTION_PERIOD_S,
    MOTIONS,
    Keyframe,
    arm_elevation,
    elbow_flexion,
    keyframes_to_poses,
    motion_keyframes,
    motion_sequence,
    world_to_local_rotvecs,
)
from bodystudio.errors import InputError

X, Y, Z = np.eye(3)

# name, parent, head, tail (metres; y up, facing +z, left at +x)
_BONES = (
    ("Root", -1, (0, 0, 0), (0, 0, -0.2)),
    ("pelvis", 0, (0, 1.0, 0), (0, 1.1, 0.01)),
    ("spine_02", 1, (0, 1.1, 0.01), (0, 1.35, 0)),
    ("neck_01", 2, (0, 1.45, 0), (0, 1.55, 0.02)),
    ("head", 3, (0, 1.55, 0.02), (0, 1.75, 0.03)),
    ("clavicle_l", 2, (0.03, 1.4, 0.02), (0.17, 1.42, -0.01)),
    ("upperarm_l", 5, (0.17, 1.42, -0.01), (0.37, 1.17, 0.02)),
    ("lowerarm_l", 6, (0.37, 1.17, 0.02), (0.50, 0.94, 0.09)),
    ("hand_l", 7, (0.50, 0.94, 0.09), (0.54, 0.86, 0.10)),
    ("clavicle_r", 2, (-0.03, 1.4, 0.02), (-0.17, 1.42, -0.01)),
    ("upperarm_r", 9, (-0.17, 1.42, -0.01), (-0.35, 1.16, 0.03)),
    ("lowerarm_r", 10, (-0.35, 1.16, 0.03), (-0.49, 0.95, 0.11)),
    ("hand_r", 11, (-0.49, 0.95, 0.11), (-0.53, 0.87, 0.12)),
    ("thigh_l", 1, (0.1, 0.95, 0), (0.11, 0.52, 0.01)),
    ("calf_l", 13, (0.11, 0.52, 0.01), (0.12, 0.09, -0.02)),
    ("foot_l", 14, (0.12, 0.09, -0.02), (0.13, 0.02, 0.12)),
    ("thigh_r", 1, (-0.1, 0.95, 0), (-0.11, 0.52, 0.01)),
    ("calf_r", 16, (-0.11, 0.52, 0.01), (-0.12, 0.09, -0.02)),
    ("foot_r", 17, (-0.12, 0.09, -0.02), (-0.13, 0.02, 0.12)),
    ("extra", 0, (0.3, 0.1, 0.2), (0.3, 0.2, 0.4)),  # no motion drives it
)


@cache
def _skeleton() -> Skeleton:
    names = tuple(b[0] for b in _BONES)
    rolls = np.linspace(-0.7, 0.9, len(_BONES))  # non-zero rolls: rest frames that are not symmetric
    return Skeleton(names, np.array([b[1] for b in _BONES]), np.array([b[2] for b in _BONES], float),
                    np.array([b[3] for b in _BONES], float), rolls)


def _dir(sk, bone):
    j = sk.index(bone)
    d = sk.tails[j] - sk.heads[j]
    return d / np.linalg.norm(d)


def _angle_deg(a, b):
    a, b = a / np.linalg.norm(a), b / np.linalg.norm(b)
    return np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b)), np.dot(a, b)))


def _world(sk, pose):
    """World rotation vectors (B, 3) of a pose's local ones: ``R_rest w_local`` bone by bone."""
    return np.array([sk.rest_rotations[j] @ pose.rotations[j] for j in range(sk.n_bones)])


def _elevation_deg(d, side):
    """Elevation above the horizontal of direction ``d``'s frontal projection, on the arm's own side."""
    lateral = 1.0 if side == "l" else -1.0
    return np.degrees(np.arctan2(d[1], lateral * d[0]))


def _rotvec_close(r, expected, atol=1e-12):
    np.testing.assert_allclose(Rotation.from_rotvec(np.asarray(expected, float)).as_matrix(), r.as_matrix(), atol=atol)


# --- world_to_local_rotvecs / keyframes_to_poses ------------------------------------------------------------------

def test_world_to_local_is_the_rest_frames_transpose_bone_by_bone():
    sk = _skeleton()
    w = np.random.default_rng(0).normal(size=(sk.n_bones, 3))
    expected = np.array([sk.rest_rotations[j].T @ w[j] for j in range(sk.n_bones)])
    np.testing.assert_allclose(world_to_local_rotvecs(sk, w), expected, atol=1e-15)
    assert not np.allclose(expected, np.array([sk.rest_rotations[j] @ w[j] for j in range(sk.n_bones)]))


def _keys():
    """Three keyframes at times 0.2, 0.5, 0.8 (given out of order): thigh_l in all, calf_r only in the middle one."""
    a, b, c = Rotation.from_rotvec([0.1, 0.2, -0.3]), Rotation.from_rotvec([0.6, -0.1, 0.2]), \
        Rotation.from_rotvec([-0.2, 0.4, 0.5])
    return [Keyframe(0.8, {"thigh_l": c}, (0.3, -0.4, 1.0)),
            Keyframe(0.2, {"thigh_l": a}, (0.0, 0.1, -1.0)),
            Keyframe(0.5, {"thigh_l": b, "calf_r": Rotation.from_rotvec([0.0, 0.0, 0.7])}, (0.6, 0.1, 2.0))]


def _check_poses(sk, poses, t):
    """Poses against scipy's RotationSpline of the keys at times ``t`` and np.interp of each translation axis."""
    keys = sorted(_keys(), key=lambda k: k.time)
    times = [k.time for k in keys]
    thigh = RotationSpline(times, Rotation.concatenate([k.rotations["thigh_l"] for k in keys]))(t).as_rotvec()
    calf = RotationSpline(times, Rotation.concatenate([k.rotations.get("calf_r", Rotation.identity())
                                                       for k in keys]))(t).as_rotvec()
    trans = np.array([k.translation for k in keys])
    assert len(poses) == len(t)
    for f, p in enumerate(poses):
        world = _world(sk, p)
        np.testing.assert_allclose(world[sk.index("thigh_l")], thigh[f], atol=1e-12)
        np.testing.assert_allclose(world[sk.index("calf_r")], calf[f], atol=1e-12)
        others = np.delete(np.arange(sk.n_bones), [sk.index("thigh_l"), sk.index("calf_r")])
        assert np.all(p.rotations[others] == 0.0)
        np.testing.assert_allclose(p.translation, [np.interp(t[f], times, trans[:, d]) for d in range(3)],
                                   atol=1e-15)


def test_keyframes_sampled_over_their_time_range_end_inclusive():
    sk = _skeleton()
    poses = keyframes_to_poses(sk, _keys(), 7)
    t = 0.2 + 0.6 * np.arange(7) / 6
    _check_poses(sk, poses, t)
    # the keys are hit exactly at their times: frame 3 is t = 0.5
    np.testing.assert_allclose(_world(sk, poses[3])[sk.index("calf_r")], [0, 0, 0.7], atol=1e-12)
    np.testing.assert_allclose(poses[-1].translation, [0.3, -0.4, 1.0], atol=1e-15)
    np.testing.assert_allclose(poses[0].translation, [0.0, 0.1, -1.0], atol=1e-15)


def test_cyclic_keyframes_stop_one_step_short_of_the_end():
    sk = _skeleton()
    poses = keyframes_to_poses(sk, _keys(), 6, cyclic=True)
    _check_poses(sk, poses, 0.2 + 0.6 * np.arange(6) / 6)
    one = keyframes_to_poses(sk, _keys(), 1, cyclic=True)
    _check_poses(sk, one, np.array([0.2]))
    one = keyframes_to_poses(sk, _keys(), 1)
    _check_poses(sk, one, np.array([0.2]))


def test_given_times_are_sampled_there_clipped_to_the_keys():
    sk = _skeleton()
    times = np.array([0.5, 0.0, 0.35, 0.95, 0.8, 0.21])
    poses = keyframes_to_poses(sk, _keys(), 6, cyclic=True, times=times)  # times win over cyclic
    _check_poses(sk, poses, np.clip(times, 0.2, 0.8))
    poses = keyframes_to_poses(sk, _keys(), 2, times=[[0.3], [0.7]])  # any shape of n_frames values
    _check_poses(sk, poses, np.array([0.3, 0.7]))


def test_one_keyframe_holds_its_rotation_and_translation():
    sk = _skeleton()
    r = Rotation.from_rotvec([0.3, -0.2, 0.1])
    poses = keyframes_to_poses(sk, [Keyframe(0.4, {"head": r}, (1.0, 2.0, 3.0))], 3)
    for p in poses:
        np.testing.assert_allclose(_world(sk, p)[sk.index("head")], [0.3, -0.2, 0.1], atol=1e-12)
        np.testing.assert_allclose(p.translation, [1.0, 2.0, 3.0])
        assert p.rotations.shape == (sk.n_bones, 3)


def test_keyframe_refusals_word_for_word():
    sk = _skeleton()
    for n in (0, -2):
        with pytest.raises(InputError) as info:
            keyframes_to_poses(sk, _keys(), n)
        assert str(info.value) == f"a motion needs at least one frame, got n_frames={n}"
    same = [Keyframe(0.3), Keyframe(0.3, {"head": Rotation.identity()})]
    with pytest.raises(InputError) as info:
        keyframes_to_poses(sk, same, 4)
    assert str(info.value) == "motion keyframe times must be distinct"
    assert len(keyframes_to_poses(sk, [Keyframe(0.0)], 1)) == 1
    assert Keyframe(0.5).rotations == {} and Keyframe(0.5).translation == (0.0, 0.0, 0.0)


# --- the anatomical rotations ---------------------------------------------------------------------------------

def test_align_is_the_smallest_rotation_between_two_directions():
    a, b = np.array([0.6, 0.8, 0.0]), np.array([0.0, 0.28, 0.96])
    r = motion._align(a, b)
    np.testing.assert_allclose(r.apply(a), b, atol=1e-15)
    np.testing.assert_allclose(r.magnitude(), np.arccos(a @ b), atol=1e-15)
    np.testing.assert_allclose(np.cross(r.as_rotvec(), np.cross(a, b)), 0, atol=1e-15)  # about a x b
    assert motion._align(a, a).magnitude() == 0.0
    c = np.array([1.0, 0.0, 0.0])
    np.testing.assert_allclose(motion._align(c, np.array([0.0, -1.0, 0.0])).as_rotvec(), [0, 0, -np.pi / 2],
                               atol=1e-15)


def test_rot_takes_any_axis_length_and_degrees():
    np.testing.assert_allclose(motion._rot([0, 2.5, 0], 30.0).as_rotvec(), [0, np.radians(30), 0], atol=1e-15)
    np.testing.assert_allclose(motion._rot((3, 0, 4), -90.0).as_rotvec(), [-0.6 * np.pi / 2, 0, -0.8 * np.pi / 2],
                               atol=1e-15)


def test_direction_is_the_unit_head_to_tail():
    sk = _skeleton()
    np.testing.assert_allclose(motion._direction(sk, "foot_l"), np.array([0.01, -0.07, 0.14]) / np.sqrt(0.0246),
                               atol=1e-15)


@pytest.mark.parametrize("side", ["l", "r"])
@pytest.mark.parametrize("degrees", [0.0, 30.0, 90.0, 120.0])
def test_elbow_flexion_bends_the_forearm_to_the_angle_in_the_arms_plane(side, degrees):
    sk = _skeleton()
    upper, lower = _dir(sk, f"upperarm_{side}"), _dir(sk, f"lowerarm_{side}")
    rest = _angle_deg(upper, lower)
    assert 10 < rest < 30
    moved = elbow_flexion(sk, side, degrees).apply(lower)
    assert _angle_deg(upper, moved) == pytest.approx(degrees, abs=1e-9)
    normal = np.cross(upper, lower)
    assert abs(moved @ normal) < 1e-12  # stays in the plane of the rest arm
    if degrees > 0:  # bent the same way as the rest bend: the forearm turns towards the rest side of the upper arm
        assert np.dot(np.cross(upper, moved), normal) > 0
    assert elbow_flexion(sk, side, rest).magnitude() == pytest.approx(0.0, abs=1e-12)


@pytest.mark.parametrize("side", ["l", "r"])
@pytest.mark.parametrize("degrees", [-90.0, -60.0, 0.0, 45.0, 70.0])
def test_arm_elevation_in_the_frontal_plane(side, degrees):
    sk = _skeleton()
    d = _dir(sk, f"upperarm_{side}")
    r = arm_elevation(sk, side, degrees)
    np.testing.assert_allclose(np.cross(r.as_rotvec(), Z), 0, atol=1e-15)  # about z only
    moved = r.apply(d)
    assert _elevation_deg(moved, side) == pytest.approx(degrees, abs=1e-9)
    assert moved[2] == pytest.approx(d[2], abs=1e-15)  # the rest forward component kept
    rest = motion._rest_arm_elevation(sk, side)
    assert rest == pytest.approx(_elevation_deg(d, side), abs=1e-12)
    assert arm_elevation(sk, side, rest).magnitude() == pytest.approx(0.0, abs=1e-12)


def test_straight_arm_pose_and_clavicles():
    sk = _skeleton()
    rot = motion._straight_arm_pose(sk, 20.0, 35.0, 12.0)
    assert set(rot) == {f"{b}_{s}" for b in ("upperarm", "lowerarm", "clavicle") for s in "lr"}
    for side, sign in (("l", 1.0), ("r", -1.0)):
        assert _elevation_deg(rot[f"upperarm_{side}"].apply(_dir(sk, f"upperarm_{side}")), side) == \
            pytest.approx(20.0, abs=1e-9)
        assert _angle_deg(_dir(sk, f"upperarm_{side}"), rot[f"lowerarm_{side}"].apply(_dir(sk, f"lowerarm_{side}"))) \
            == pytest.approx(35.0, abs=1e-9)
        _rotvec_close(rot[f"clavicle_{side}"], Z * sign * np.radians(12.0))
    rot = motion._straight_arm_pose(sk, -10.0)
    assert set(rot) == {f"{b}_{s}" for b in ("upperarm", "lowerarm") for s in "lr"}
    assert _angle_deg(_dir(sk, "upperarm_l"), rot["lowerarm_l"].apply(_dir(sk, "lowerarm_l"))) == \
        pytest.approx(0.0, abs=1e-6)


def test_compose_applies_later_rotations_after_earlier_ones():
    a, b, c = Rotation.from_rotvec([0.5, 0, 0]), Rotation.from_rotvec([0, 0.7, 0]), Rotation.from_rotvec([0, 0, 0.2])
    out = motion._compose({"x": a, "y": c}, {"x": b}, {})
    np.testing.assert_allclose(out["x"].as_matrix(), b.as_matrix() @ a.as_matrix(), atol=1e-15)
    assert out["y"] is c and set(out) == {"x", "y"}


def test_posture_noise_is_the_seeds_draws_in_degrees():
    rng = np.random.default_rng(5)
    out = motion._posture_noise(rng, 3.0)
    ref = np.random.default_rng(5)
    assert list(out) == ["spine_02", "neck_01", "head"]
    for bone in out:
        _rotvec_close(out[bone], np.radians(ref.normal(0.0, 3.0, 3)))
    out = motion._posture_noise(np.random.default_rng(5))  # default 2 degrees
    ref = np.random.default_rng(5)
    for bone in out:
        _rotvec_close(out[bone], np.radians(ref.normal(0.0, 2.0, 3)))


# --- the motions' keyframes -------------------------------------------------------------------------------------

def _posture(ref, scale=2.0):
    return {b: Rotation.from_rotvec(np.radians(ref.normal(0.0, scale, 3))) for b in ("spine_02", "neck_01", "head")}


def _check_posture(key, posture):
    for bone, r in posture.items():
        np.testing.assert_allclose(key.rotations[bone].as_matrix(), r.as_matrix(), atol=1e-12)


def _arm(sk, key, side):
    """(elevation of the posed upper arm, elbow angle) of a keyframe."""
    up = key.rotations[f"upperarm_{side}"].apply(_dir(sk, f"upperarm_{side}"))
    lower = key.rotations[f"lowerarm_{side}"].apply(_dir(sk, f"lowerarm_{side}"))
    elbow = _angle_deg(_dir(sk, f"upperarm_{side}"), lower)
    return _elevation_deg(up, side), elbow


def test_a_pose_and_t_pose_keys():
    sk = _skeleton()
    keys = motion_keyframes("a_pose", sk, seed=4)
    assert len(keys) == 1 and keys[0].time == 0.0 and keys[0].rotations == {}
    keys = motion_keyframes("t_pose", sk, seed=4)
    ref = np.random.default_rng(4)
    posture = _posture(ref)
    elevation = ref.normal(0.0, 2.0)
    assert len(keys) == 1 and keys[0].time == 0.0
    _check_posture(keys[0], posture)
    for side in "lr":
        e, elbow = _arm(sk, keys[0], side)
        assert e == pytest.approx(elevation, abs=1e-9) and elbow == pytest.approx(0.0, abs=1e-6)
    assert "clavicle_l" not in keys[0].rotations


def test_arms_raise_keys():
    sk = _skeleton()
    keys = motion_keyframes("arms_raise", sk, seed=6)
    ref = np.random.default_rng(6)
    posture = _posture(ref)
    top = 70.0 + ref.normal(0.0, 4.0)
    rest = motion._rest_arm_elevation(sk, "l")
    assert [k.time for k in keys] == [0.0, 0.25, 0.5, 0.75, 1.0]
    for k in (keys[0], keys[-1]):
        assert set(k.rotations) == set(posture)
        _check_posture(k, posture)
    for k, frac in zip(keys[1:4], (0.5, 1.0, 0.5), strict=True):
        _check_posture(k, posture)
        for side, sign in (("l", 1.0), ("r", -1.0)):
            e, elbow = _arm(sk, k, side)
            assert e == pytest.approx(rest + frac * (top - rest), abs=1e-9)
            assert elbow == pytest.approx(20.0 * (1 - frac), abs=1e-6)
            _rotvec_close(k.rotations[f"clavicle_{side}"], Z * sign * np.radians(15.0 * frac))


@pytest.mark.parametrize("cycles", [1, 2, 3])
def test_walk_keys(cycles):
    sk = _skeleton()
    keys = motion_keyframes("walk", sk, seed=8, cycles=cycles)
    ref = np.random.default_rng(8)
    posture = _posture(ref)
    hip, knee = 40.0 * ref.uniform(0.85, 1.15), 70.0 * ref.uniform(0.85, 1.15)
    swing_deg, arms_down = 25.0 * ref.uniform(0.8, 1.2), -75.0 + ref.normal(0.0, 3.0)
    steps = 8 * cycles
    assert [k.time for k in keys] == [k / steps for k in range(steps + 1)]
    for k, key in enumerate(keys):
        s = np.sin(2 * np.pi * k / 8 + np.pi / 2)  # k = 0: mid-stride, left knee up
        lift = {"l": max(0.0, s), "r": max(0.0, -s)}
        if k % 8 == 0:
            assert lift == {"l": 1.0, "r": 0.0}
        for side in "lr":
            _rotvec_close(key.rotations[f"thigh_{side}"], -X * np.radians(hip * lift[side]))
            _rotvec_close(key.rotations[f"calf_{side}"], X * np.radians(knee * lift[side]))
            _rotvec_close(key.rotations[f"foot_{side}"], X * np.radians(15.0 * lift[side]))
            swing = -s if side == "l" else s
            expected = Rotation.from_rotvec(-X * np.radians(swing_deg * swing)) * arm_elevation(sk, side, arms_down)
            np.testing.assert_allclose(key.rotations[f"upperarm_{side}"].as_matrix(), expected.as_matrix(),
                                       atol=1e-12)
            elbow = _angle_deg(_dir(sk, f"upperarm_{side}"),
                               key.rotations[f"lowerarm_{side}"].apply(_dir(sk, f"lowerarm_{side}")))
            assert elbow == pytest.approx(20.0 + 10.0 * max(0.0, swing), abs=1e-6)
        _rotvec_close(key.rotations["pelvis"], Y * np.radians(4.0 * s))
        _check_posture(key, posture)


def test_turn_keys_turn_a_full_circle_either_way():
    sk = _skeleton()
    directions = set()
    for seed in range(6):
        keys = motion_keyframes("turn", sk, seed=seed)
        ref = np.random.default_rng(seed)
        posture = _posture(ref)
        direction = 1.0 if ref.random() < 0.5 else -1.0
        elevation = -60.0 + ref.normal(0.0, 3.0)
        directions.add(direction)
        assert [k.time for k in keys] == [k / 8 for k in range(9)]
        for k, key in enumerate(keys):
            _rotvec_close(key.rotations["Root"], Rotation.from_rotvec(Y * np.radians(direction * 45.0 * k)).as_rotvec())
            _check_posture(key, posture)
            for side in "lr":
                e, elbow = _arm(sk, key, side)
                assert e == pytest.approx(elevation, abs=1e-9) and elbow == pytest.approx(15.0, abs=1e-6)
    assert directions == {1.0, -1.0}


@pytest.mark.parametrize("cycles", [1, 2])
def test_arm_flex_keys(cycles):
    sk = _skeleton()
    keys = motion_keyframes("arm_flex", sk, seed=9, cycles=cycles)
    ref = np.random.default_rng(9)
    posture = _posture(ref, 1.0)
    flex_max, abduct_max = 120.0 * ref.uniform(0.9, 1.05), 80.0 * ref.uniform(0.9, 1.1)
    steps = 8 * cycles
    assert [k.time for k in keys] == [k / steps for k in range(steps + 1)]
    for k, key in enumerate(keys):
        phase = 2 * np.pi * k / 8
        flex = 10.0 + (flex_max - 10.0) * 0.5 * (1 - np.cos(phase))
        elevation = -80.0 + 0.5 * (1 - np.cos(phase / 2)) * abduct_max
        _check_posture(key, posture)
        for side in "lr":
            e, elbow = _arm(sk, key, side)
            assert e == pytest.approx(elevation, abs=1e-9) and elbow == pytest.approx(flex, abs=1e-6)
    assert _arm(sk, keys[4], "l")[1] == pytest.approx(flex_max, abs=1e-6)  # mid cycle: full flexion
    assert _arm(sk, keys[8], "r")[0] == pytest.approx(-80.0 + abduct_max, abs=1e-9)  # full abduction


def test_unknown_motion_refused_word_for_word():
    with pytest.raises(InputError) as info:
        motion_keyframes("moonwalk", _skeleton())
    assert str(info.value) == ("unknown motion 'moonwalk'; valid motions: a_pose, t_pose, arms_raise, walk, turn, "
                               "arm_flex")
    with pytest.raises(InputError) as info:
        motion_sequence("moonwalk", 3, _skeleton(), fps=30.0)
    assert "unknown motion 'moonwalk'" in str(info.value)


def test_default_seed_and_cycles():
    sk = _skeleton()
    assert len(motion._walk_keys(sk, np.random.default_rng(0))) == 17  # two strides
    assert len(motion._arm_flex_keys(sk, np.random.default_rng(0))) == 17  # two elbow cycles
    for name in ("walk", "arm_flex"):
        a, b = motion_keyframes(name, sk), motion_keyframes(name, sk, seed=0, cycles=2)
        assert len(a) == 17
        for ka, kb in zip(a, b, strict=True):
            assert all(np.allclose(ka.rotations[n].as_matrix(), kb.rotations[n].as_matrix()) for n in ka.rotations)


# --- motion_sequence: frame count vs frame rate -------------------------------------------------------------------

def _same(poses, expected):
    assert len(poses) == len(expected)
    for p, q in zip(poses, expected, strict=True):
        np.testing.assert_allclose(p.rotations, q.rotations, atol=1e-12)
        np.testing.assert_allclose(p.translation, q.translation, atol=1e-15)


@pytest.mark.parametrize("name", MOTIONS)
def test_sequence_over_the_frames(name):
    sk = _skeleton()
    for n in (1, 5, 59, 60):
        cycles = 1 if n < 60 else 2
        keys = motion_keyframes(name, sk, 3, cycles)
        cyclic = name in ("walk", "turn", "arm_flex")
        t = np.arange(n) / (n if cyclic or n == 1 else n - 1)
        _same(motion_sequence(name, n, sk, seed=3), keyframes_to_poses(sk, keys, n, times=t))
    assert set(CYCLIC_MOTIONS) == {"walk", "turn", "arm_flex"}


@pytest.mark.parametrize("name", MOTIONS)
def test_sequence_at_a_frame_rate_plays_at_natural_speed(name):
    """Frame k shows time k / fps, one pass of the keys every MOTION_PERIOD_S seconds (issue 12)."""
    sk = _skeleton()
    keys = motion_keyframes(name, sk, 5, 2)
    for n, fps in ((1, 30.0), (7, 4), (50, 12.5), (3, 0.5), (2, 1.0)):
        phase = np.array([(k / fps / MOTION_PERIOD_S[name]) % 1.0 for k in range(n)])
        _same(motion_sequence(name, n, sk, seed=5, fps=fps), keyframes_to_poses(sk, keys, n, times=phase))
    # the default seed is 0, at a frame rate and over the frames
    _same(motion_sequence(name, 4, sk, fps=10.0), motion_sequence(name, 4, sk, seed=0, fps=10.0))
    _same(motion_sequence(name, 4, sk), motion_sequence(name, 4, sk, seed=0))
    assert MOTION_PERIOD_S == {"a_pose": 1.0, "t_pose": 1.0, "arms_raise": 4.0, "walk": 2.2, "turn": 8.0,
                               "arm_flex": 5.0}


def test_a_short_fps_sequence_is_the_start_of_a_long_one_and_repeats():
    sk = _skeleton()
    long = motion_sequence("turn", 250, sk, seed=1, fps=30.0)
    _same(motion_sequence("turn", 3, sk, seed=1, fps=30.0), long[:3])
    _same(long[240:243], long[:3])  # 8 s at 30 fps
    # frame 30 at 30 fps is one second in: an eighth of the turn, 45 degrees about y
    root = _world(sk, long[30])[sk.index("Root")]
    assert np.linalg.norm(root) == pytest.approx(np.radians(45.0), abs=1e-9)


@pytest.mark.parametrize("fps", [0.0, -5.0, float("nan"), float("inf")])
def test_bad_fps_refused_word_for_word(fps):
    with pytest.raises(InputError) as info:
        motion_sequence("walk", 4, _skeleton(), fps=fps)
    assert str(info.value) == f"fps must be a positive frame rate, got {fps}"


@pytest.mark.parametrize("n", [0, -1])
def test_no_frames_refused_at_a_frame_rate(n):
    with pytest.raises(InputError) as info:
        motion_sequence("walk", n, _skeleton(), fps=30.0)
    assert str(info.value) == f"a motion needs at least one frame, got n_frames={n}"
    with pytest.raises(InputError) as info:
        motion_sequence("walk", n, _skeleton())
    assert str(info.value) == f"a motion needs at least one frame, got n_frames={n}"
