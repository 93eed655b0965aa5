"""The pose oracle of benchmarks/mirror_pose_oracle.py (issue 12: what the IK's twist costs the warp).

A planted forearm twist is measured as twist (not swing), a planted swing as swing (not twist); the oracle
that keeps the IK's bone directions and takes the true twist gives back the true bone rotation when only
the twist was wrong, and leaves the planted swing in place when the swing was wrong; world rotations and
poses convert into each other exactly. The shape oracle's parts (MIR12c): the signed silhouette distance of a
disc, the rim distances of a sphere seen by a camera (the rim lies on the outline; a sphere 2 % too small lies
inside it by that fraction of its radius in pixels), the region of a vertex by its dominant bone. MIR12g's
temporal filters of the refined poses: on a ramp the centred mean is exact away from the ends, the EMA lags by
(1 - a) / a steps of the slope and the alpha-beta filter catches up with it; on noise about a constant each smooths.
"""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from benchmarks.mirror_pose_oracle import (
    REGIONS,
    _rim_distances,
    filter_sequence,
    oracle_swing,
    oracle_twist,
    pose_from_world,
    signed_distance_px,
    swing_twist_errors,
    vertex_regions,
    world_rotations,
)
from bodystudio.body import Phenotype, Pose, build_body
from bodystudio.body.skinning import posed_joints


@pytest.fixture(scope="module")
def skeleton():
    return build_body(Phenotype(), resolution="2k").skeleton


def _pose(skeleton, seed=0):
    rng = np.random.default_rng(seed)
    return Pose(rng.normal(0, 0.3, (skeleton.n_bones, 3)), np.array([0.1, 0.0, 2.5]))


def _planted(skeleton, pose, bone, local_axis, angle_rad):
    """``pose`` with ``bone`` turned further by ``angle_rad`` about its rest frame's ``local_axis``
    (1 = along the bone: a twist)."""
    rot = pose.rotations.copy()
    j = skeleton.index(bone)
    axis = np.zeros(3)
    axis[local_axis] = angle_rad
    rot[j] = (Rotation.from_rotvec(rot[j]) * Rotation.from_rotvec(axis)).as_rotvec()
    return Pose(rot, pose.translation)


def test_world_rotations_and_poses_round_trip(skeleton):
    pose = _pose(skeleton)
    back = pose_from_world(skeleton, world_rotations(skeleton, pose), pose.translation)
    for a, b in zip(posed_joints(skeleton, pose), posed_joints(skeleton, back), strict=True):
        np.testing.assert_allclose(a, b, atol=1e-10)


def test_a_planted_forearm_twist_is_twist_and_the_oracle_restores_it(skeleton):
    ik = _pose(skeleton, 1)
    true = _planted(skeleton, ik, "lowerarm_l", 1, np.radians(12.0))
    W_ik, W_true = world_rotations(skeleton, ik), world_rotations(skeleton, true)
    j = skeleton.index("lowerarm_l")
    swing, twist = swing_twist_errors(skeleton, W_ik, W_true, [j])
    assert swing[0] < 1e-6 and abs(twist[0] - 12.0) < 1e-6
    # the twist does not move a joint: the IK (joints only) cannot see it
    for a, b in zip(posed_joints(skeleton, ik), posed_joints(skeleton, true), strict=True):
        assert np.abs(a[j] - b[j]).max() < 1e-12
    W = oracle_twist(skeleton, W_ik, W_true, [j])
    np.testing.assert_allclose(W[j], W_true[j], atol=1e-10)
    others = np.arange(skeleton.n_bones) != j
    np.testing.assert_allclose(W[others], W_ik[others], atol=1e-12)
    # the child (the hand) inherited the twist in the true pose; the oracle keeps the IK's world rotation there
    hand = skeleton.index("hand_l")
    assert np.abs(W_true[hand] - W_ik[hand]).max() > 0.05


def test_a_planted_swing_is_swing_and_the_twist_oracle_keeps_it(skeleton):
    ik = _pose(skeleton, 2)
    true = _planted(skeleton, ik, "upperarm_r", 0, np.radians(7.0))
    W_ik, W_true = world_rotations(skeleton, ik), world_rotations(skeleton, true)
    j = skeleton.index("upperarm_r")
    swing, twist = swing_twist_errors(skeleton, W_ik, W_true, [j])
    assert abs(swing[0] - 7.0) < 1e-6 and twist[0] < 1e-6
    np.testing.assert_allclose(oracle_twist(skeleton, W_ik, W_true, [j])[j], W_ik[j], atol=1e-10)
    np.testing.assert_allclose(oracle_swing(skeleton, W_ik, W_true, [j])[j], W_true[j], atol=1e-10)


def test_signed_distance_of_a_disc():
    yy, xx = np.mgrid[:101, :101]
    disc = (xx - 50) ** 2 + (yy - 50) ** 2 <= 30**2
    sd = signed_distance_px(disc)
    assert abs(sd[50, 90] - 10.0) < 0.6 and abs(sd[50, 70] + 10.0) < 0.6  # 10 px outside / inside
    assert abs(sd[50, 80]) <= 1.0


def test_rim_distances_of_a_sphere_lie_on_its_outline_and_a_shrunk_one_inside():
    import trimesh

    from bodystudio.capture.render import render
    from bodystudio.geometry.camera import Camera

    camera = Camera(name="c", K=np.array([[500.0, 0, 160], [0, 500.0, 120], [0, 0, 1]]), dist=np.zeros(5), R=np.eye(3),
                    t=np.zeros(3), width=320, height=240)
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=0.3)
    V, F = np.asarray(sphere.vertices) + [0, 0, 2.0], np.asarray(sphere.faces)  # a 30 cm sphere 2 m away: ~75 px radius
    sd = signed_distance_px(render(V, F, camera).mask)
    others = np.zeros((240, 320), bool)
    d, rim = _rim_distances(V, F, camera, sd, others)
    assert rim.sum() > 20 and abs(np.mean(d)) < 1.5
    centre = np.array([0, 0, 2.0])
    d_small, _ = _rim_distances(centre + 0.98 * (V - centre), F, camera, sd, others)
    assert np.mean(d_small) < np.mean(d) - 1.0  # 2 % of ~75 px further inside


def test_vertex_regions_by_dominant_bone(skeleton):
    names = skeleton.bone_names
    W = np.zeros((3, len(names)))
    W[0, names.index("thigh_l")] = 0.7
    W[0, names.index("spine_01")] = 0.3
    W[1, names.index("head")] = 1.0
    W[2, names.index("hand_r")] = 1.0
    assert list(vertex_regions(W, names)) == ["thighs", "head, neck", "other"]
    assert all(b in names for bones in REGIONS.values() for b in bones)


def test_the_temporal_filters_of_the_refined_poses():
    t = np.arange(60.0)
    ramp = np.c_[0.01 * t, -0.02 * t]
    assert np.allclose(filter_sequence(ramp, "none", None), ramp)
    assert np.allclose(filter_sequence(ramp, "centred", 2)[2:-2], ramp[2:-2])
    ema = filter_sequence(ramp, "ema", 0.5)
    assert np.allclose(ramp[-1] - ema[-1], (1 - 0.5) / 0.5 * np.array([0.01, -0.02]), atol=1e-9)
    ab = filter_sequence(ramp, "alpha-beta", (0.5, 0.1))
    assert np.abs(ab[-1] - ramp[-1]).max() < 1e-3 < np.abs(ab[5] - ramp[5]).max()  # starts at rest, catches up
    noise = np.random.default_rng(0).normal(0.0, 1.0, (400, 3))
    for kind, param in (("centred", 2), ("ema", 0.5), ("alpha-beta", (0.5, 0.1))):
        assert filter_sequence(noise, kind, param)[20:].std() < 0.85 * noise[20:].std(), kind
