"""Motions: valid, deterministic poses whose joints bend the anatomical way."""

import numpy as np
import pytest

from bodystudio.body.skinning import posed_joints
from bodystudio.capture.motion import MOTIONS, motion_sequence
from bodystudio.errors import InputError


def _joint(sk, heads, name):
    return heads[sk.index(name)]


def _angle_deg(a, b):
    return np.degrees(np.arccos(np.clip(np.dot(a, b) / np.linalg.norm(a) / np.linalg.norm(b), -1, 1)))


@pytest.mark.parametrize("name", MOTIONS)
def test_motions_are_valid_standing_sequences(name, body_2k):
    sk = body_2k.skeleton
    poses = motion_sequence(name, 12, sk, seed=3)
    assert len(poses) == 12
    again = motion_sequence(name, 12, sk, seed=3)
    for p, q in zip(poses, again, strict=True):
        assert np.all(np.isfinite(p.rotations)) and p.rotations.shape == (sk.n_bones, 3)
        assert np.array_equal(p.rotations, q.rotations)
    for p in poses[::3]:
        V, heads = body_2k.pose(p)
        body_joints = np.delete(heads, sk.index("Root"), axis=0)  # the Root bone lies on the floor
        assert body_joints[:, 1].min() > 0.0, "a joint went below the floor"
        assert -0.03 < V[:, 1].min() < 0.06, "the standing body must touch the floor, not sink or float"
    if name != "a_pose":
        other = motion_sequence(name, 12, sk, seed=4)
        assert not np.allclose(other[6].rotations, poses[6].rotations)


def test_walk_bends_knees_forward(body_2k):
    sk = body_2k.skeleton
    poses = motion_sequence("walk", 33, sk, seed=0)
    lifts = []
    for p in poses:
        heads, _ = posed_joints(sk, p)
        hip, knee, ankle = (_joint(sk, heads, n) for n in ("thigh_l", "calf_l", "foot_l"))
        lifts.append(ankle[1])
        if ankle[1] > sk.heads[sk.index("foot_l"), 1] + 0.1:  # swing phase of the left leg
            assert knee[2] > hip[2] + 0.05, "hip flexion must bring the knee forward"
            assert ankle[2] < knee[2], "the knee must bend backwards (shank behind the knee)"
    assert max(lifts) > sk.heads[sk.index("foot_l"), 1] + 0.15  # the foot really leaves the floor


def test_arm_flex_elbow_range_and_direction(body_2k):
    sk = body_2k.skeleton
    poses = motion_sequence("arm_flex", 33, sk, seed=0)
    angles, wrist_z, elevations = [], [], []
    for p in poses:
        heads, _ = posed_joints(sk, p)
        sh, el, wr = (_joint(sk, heads, n) for n in ("upperarm_r", "lowerarm_r", "hand_r"))
        angles.append(_angle_deg(el - sh, wr - el))
        wrist_z.append(wr[2] - el[2])
        elevations.append(np.degrees(np.arcsin((el - sh)[1] / np.linalg.norm(el - sh))))
    angles, wrist_z = np.array(angles), np.array(wrist_z)
    assert angles.min() < 20 and angles.max() > 100  # extension to flexion
    flexed = angles > 60
    assert np.all(wrist_z[flexed] > 0.05), "elbow flexion brings the forearm forward, not backward"
    assert min(elevations) < -70 and max(elevations) > -15  # adduction to abduction


def test_t_pose_and_arms_raise_and_turn(body_2k):
    sk = body_2k.skeleton
    heads, _ = posed_joints(sk, motion_sequence("t_pose", 1, sk, seed=0)[0])
    for side in "lr":
        sh, el, wr = (_joint(sk, heads, f"{b}_{side}") for b in ("upperarm", "lowerarm", "hand"))
        assert abs(np.degrees(np.arcsin((wr - sh)[1] / np.linalg.norm(wr - sh)))) < 8  # horizontal arms
        assert _angle_deg(el - sh, wr - el) < 5  # straight elbows
    mid = motion_sequence("arms_raise", 9, sk, seed=0)[4]
    heads, _ = posed_joints(sk, mid)
    assert _joint(sk, heads, "hand_l")[1] > _joint(sk, heads, "head")[1]
    assert _joint(sk, heads, "hand_r")[1] > _joint(sk, heads, "head")[1]
    turn = motion_sequence("turn", 8, sk, seed=0)  # cyclic: frames at 0, 45, ..., 315 degrees
    hip_axis = []
    for p in (turn[0], turn[2], turn[4], turn[6]):
        heads, _ = posed_joints(sk, p)
        hip_axis.append(_joint(sk, heads, "thigh_l") - _joint(sk, heads, "thigh_r"))
    assert _angle_deg(hip_axis[0], hip_axis[1]) == pytest.approx(90, abs=5)
    assert _angle_deg(hip_axis[0], hip_axis[2]) == pytest.approx(180, abs=5)
    assert _angle_deg(hip_axis[0], hip_axis[3]) == pytest.approx(90, abs=5)


def test_short_cyclic_motions_show_distinct_poses(body_2k):
    for name in ("walk", "arm_flex", "turn"):
        for n in (2, 3, 5):
            poses = motion_sequence(name, n, body_2k.skeleton, seed=1)
            change = [np.abs(p.rotations - poses[0].rotations).max() for p in poses[1:]]
            assert min(change) > 0.2, (name, n, change)


def test_unknown_motion_is_a_user_error(body_2k):
    with pytest.raises(InputError, match="walk"):
        motion_sequence("moonwalk", 5, body_2k.skeleton)
    with pytest.raises(InputError):
        motion_sequence("walk", 0, body_2k.skeleton)
