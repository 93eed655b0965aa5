"""The feet's twist in the run's IK (mir12aa): the IK, warm-started frame to frame, turns each foot by the smallest
rotation onto its new direction (ankle to FootLeft / FootRight), so a foot swinging round a loop gathers twist as the
limbs did before MIR12p; ``run.UNTWIST_FEET`` (on by default) untwists the feet too (``track.UNTWIST_FEET_BONES``)."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bodystudio.body import Pose, build_body
from bodystudio.body.population import sample_population
from bodystudio.body.skinning import forward_kinematics, posed_joints
from bodystudio.mirror import run as run_mod
from bodystudio.mirror.track import UNTWIST_BONES, UNTWIST_FEET_BONES, ik_pose, posed_kinect_joints, untwisted_pose


@pytest.fixture(scope="module")
def skeleton():
    phenotype, local = sample_population(1, seed=5)[0]
    return build_body(phenotype, local, resolution="2k").skeleton


def _world(skeleton, pose):
    return forward_kinematics(skeleton, pose)[:, :3, :3] @ np.transpose(skeleton.rest_rotations, (0, 2, 1))


def _twist_deg(skeleton, W_a, W_b, bone):
    j = skeleton.index(bone)
    d = skeleton.tails[j] - skeleton.heads[j]
    axis = W_a[j] @ (d / np.linalg.norm(d))
    return float(np.degrees(Rotation.from_matrix(W_a[j] @ W_b[j].T).as_rotvec() @ axis))


def _foot_loop(skeleton, side="l", cone_deg=20.0, loops=3, frames=91):
    """True poses: the knee bent 40 degrees, the foot's tip round a cone about its rest direction, no twist."""
    foot = skeleton.index(f"foot_{side}")
    d = skeleton.tails[foot] - skeleton.heads[foot]
    d /= np.linalg.norm(d)
    a = np.cross(d, [1.0, 0.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(d, a)
    bones = UNTWIST_BONES + UNTWIST_FEET_BONES
    truth = []
    for phase in np.linspace(0.0, 2 * loops * np.pi, frames):
        c, s = np.cos(np.radians(cone_deg)), np.sin(np.radians(cone_deg))
        direction = c * d + s * (np.cos(phase) * a + np.sin(phase) * b)
        rv = np.zeros((skeleton.n_bones, 3))
        rv[skeleton.index(f"calf_{side}")] = [0.7, 0.0, 0.0]
        W = _world(skeleton, Pose(rv, np.zeros(3)))
        p = skeleton.parents[foot]
        L = Rotation.align_vectors([W[p] @ direction], [d])[0].as_matrix()  # onto the direction in the calf's frame
        Rr = skeleton.rest_rotations[foot]
        rv[foot] = Rotation.from_matrix(Rr.T @ W[p].T @ L @ Rr).as_rotvec()
        truth.append(untwisted_pose(skeleton, Pose(rv, np.zeros(3)), bones))
    return truth


def test_the_run_untwists_the_feet_by_default(monkeypatch):
    assert UNTWIST_FEET_BONES == ("foot_l", "foot_r")
    assert run_mod.UNTWIST_FEET is True and run_mod.UNTWIST_BONES == UNTWIST_BONES
    assert run_mod.untwist_bones() == UNTWIST_BONES + ("foot_l", "foot_r")
    monkeypatch.setattr(run_mod, "UNTWIST_FEET", False)  # the run before mir12aa
    assert run_mod.untwist_bones() == UNTWIST_BONES


def test_untwisting_the_feet_moves_no_joint_and_keeps_the_toes(skeleton):
    rng = np.random.default_rng(3)
    pose = Pose(rng.normal(0.0, 0.35, (skeleton.n_bones, 3)), rng.normal(0.0, 0.2, 3))
    out = untwisted_pose(skeleton, pose, UNTWIST_FEET_BONES)
    for a, b in zip(posed_joints(skeleton, out), posed_joints(skeleton, pose), strict=True):
        np.testing.assert_allclose(a, b, atol=1e-9)
    W0, W1 = _world(skeleton, pose), _world(skeleton, out)
    for toe in ("ball_l", "ball_r"):
        np.testing.assert_allclose(W1[skeleton.index(toe)], W0[skeleton.index(toe)], atol=1e-9)
    assert min(abs(_twist_deg(skeleton, W1, W0, f)) for f in UNTWIST_FEET_BONES) > 1.0  # the random pose had twist
    for f in UNTWIST_FEET_BONES:  # none left against the calf
        j = skeleton.index(f)
        d = skeleton.tails[j] - skeleton.heads[j]
        L = W1[skeleton.parents[j]].T @ W1[j]
        assert abs(Rotation.from_matrix(L).as_rotvec() @ (d / np.linalg.norm(d))) < 1e-9


def test_a_warm_started_ik_gathers_no_foot_twist_with_the_feet_untwisted(skeleton):
    """Three loops of the left foot: the run's IK untwisted at the limbs only ends with the foot's twist tens of
    degrees off the truth's; with the feet untwisted too, within half a degree."""
    truth = _foot_loop(skeleton)
    drift = {}
    for bones in (UNTWIST_BONES, UNTWIST_BONES + UNTWIST_FEET_BONES):
        previous = None
        worst = 0.0
        for pose in truth:
            K = posed_kinect_joints(skeleton, pose)
            est = ik_pose(skeleton, K, np.ones(len(K), bool), "v2", previous=previous)
            previous = untwisted_pose(skeleton, est, bones)
            worst = max(worst, abs(_twist_deg(skeleton, _world(skeleton, previous), _world(skeleton, pose), "foot_l")))
        drift[len(bones)] = worst
    assert drift[len(UNTWIST_BONES) + 2] < 0.5
    assert drift[len(UNTWIST_BONES)] > 10.0
