"""The rest knee angle from the SDK's joints and the Eq. 2 rows holding the model's at it (mir12ac: ``sdk_knee_angle``,
``model_knee_angles``, ``knee_angle_rows``, ``initialise_from_observations(knee_hinge_from="sdk")``)."""

from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bodystudio.body.kinect import kinect_joint_names
from bodystudio.mirror import init as init_mod
from bodystudio.mirror.init import knee_angle_rows, model_knee_angles, sdk_knee_angle

NAMES = kinect_joint_names("v2")


def _leg(side, thigh_out, knee_angle, hip_flexion, knee_flexion):
    """Hip-to-knee and knee-to-ankle unit directions of one leg in the pelvis frame (x the body's left, y up, z
    forward): the thigh ``thigh_out`` outward from the vertical, the calf ``knee_angle`` further out (the rest knee
    angle), the knee bent about its hinge (the lateral axis made normal to the thigh) and the hip about x."""
    t0 = np.array([side * np.sin(thigh_out), -np.cos(thigh_out), 0.0])
    outward = np.array([side * np.cos(thigh_out), np.sin(thigh_out), 0.0])  # in the frontal plane, normal to t0
    c0 = np.cos(knee_angle) * t0 + np.sin(knee_angle) * outward
    calf = Rotation.from_rotvec(outward * knee_flexion).apply(c0)
    hip = Rotation.from_rotvec([hip_flexion, 0.0, 0.0])
    return hip.apply(t0), hip.apply(calf)


def _frame(knee_angle, flexions, rng, extra_abduction=0.0):
    """One frame of SDK joints: the pelvis turned at random about the vertical and placed at random, both legs with
    the rest ``knee_angle`` bent by ``flexions`` (left, right) at the knee and at random at the hip."""
    K = np.zeros((len(NAMES), 3))
    yaw = Rotation.from_rotvec([0.0, rng.uniform(-np.pi, np.pi), 0.0])
    centre = rng.normal(0.0, 1.0, 3)
    for side, (hip, knee, ankle), flexion in ((1.0, ("HipLeft", "KneeLeft", "AnkleLeft"), flexions[0]),
                                             (-1.0, ("HipRight", "KneeRight", "AnkleRight"), flexions[1])):
        t, c = _leg(side, 0.09, knee_angle + extra_abduction, rng.uniform(-0.6, 0.6), flexion)
        h = np.array([side * 0.1, 0.0, 0.0])
        K[NAMES.index(hip)] = centre + yaw.apply(h)
        K[NAMES.index(knee)] = centre + yaw.apply(h + 0.44 * t)
        K[NAMES.index(ankle)] = centre + yaw.apply(h + 0.44 * t + 0.41 * c)
    return SimpleNamespace(joints=K, tracked=np.ones(len(NAMES), bool), version="v2")


@pytest.mark.parametrize("knee_angle_deg", [-2.0, 0.5, 3.2])
def test_sdk_knee_angle_is_the_rest_one_at_any_flexion_and_pelvis_turn(knee_angle_deg):
    rng = np.random.default_rng(7)
    kappa = np.radians(knee_angle_deg)
    frames = [_frame(kappa, rng.uniform(0.0, np.radians(19.0), 2), rng) for _ in range(12)]
    # knees bent further than the limit carry 4 degrees more (the synthetic walk's flexed knee is not a pure hinge):
    # they are left out
    frames += [_frame(kappa, np.radians([45.0, 70.0]), rng, extra_abduction=np.radians(4.0)) for _ in range(6)]
    angle, se = sdk_knee_angle(frames, "v2")
    np.testing.assert_allclose(angle, kappa, atol=1e-9)
    assert se < 1e-9
    with_flexed, _ = sdk_knee_angle(frames, "v2", max_flexion_deg=90.0)
    assert abs(np.degrees(with_flexed - kappa)) > 1.0


def test_sdk_knee_angle_skips_frames_without_the_legs():
    rng = np.random.default_rng(1)
    frame = _frame(0.02, (0.1, 0.1), rng)
    frame.tracked = frame.tracked.copy()
    frame.tracked[NAMES.index("AnkleRight")] = False
    assert sdk_knee_angle([frame], "v2") == (None, None)
    other = _frame(0.02, (0.1, 0.1), rng)
    other.version = "v1"
    assert sdk_knee_angle([other], "v2") == (None, None)


def test_model_knee_angles_read_the_rest_skeleton(model_6k):
    c = np.zeros(model_6k.n_components)
    sk = model_6k.skeleton(c)

    def frontal(b):
        d = sk.tails[sk.index(b)] - sk.heads[sk.index(b)]
        return np.arctan2(d[0], -d[1])

    # the regressor's Kinect knee / ankle are the calf's head / the foot's head: in the frontal plane the knee angle
    # is the calf's angle minus the thigh's (the legs lean a little forward, so not to the last digit)
    k = model_knee_angles(model_6k, c)
    np.testing.assert_allclose(k[0], frontal("calf_l") - frontal("thigh_l"), atol=np.radians(0.3))
    np.testing.assert_allclose(k[1], -(frontal("calf_r") - frontal("thigh_r")), atol=np.radians(0.3))


def test_knee_angle_rows_move_the_model_to_the_target(model_6k):
    rng = np.random.default_rng(2)
    c0 = rng.normal(0.0, 0.5, model_6k.n_components) * model_6k.stddev
    k0 = model_knee_angles(model_6k, c0)
    target = k0.mean() + np.radians(2.5)
    A, b = knee_angle_rows(model_6k, c0, target, "v2", weight=9.0)
    assert A.shape == (2, model_6k.n_components)
    # at c0 each row says the angle is short of the target by the difference times the calf's length (~0.4 m; x 3:
    # sqrt(9)), an ankle's sideways metres
    ratio = (A @ c0 - b) / (3.0 * (k0 - target))
    assert np.all((ratio > 0.3) & (ratio < 0.5)), ratio
    # the least change of the coefficients (in standard deviations) that meets the rows brings the model's knee
    # angle to the target (the rows are linearised: to a hundredth of a degree)
    S = np.diag(model_6k.stddev)
    dz = np.linalg.lstsq(A @ S, b - A @ c0, rcond=None)[0]
    c = c0 + S @ dz
    np.testing.assert_allclose(model_knee_angles(model_6k, c).mean(), target, atol=np.radians(0.01))


@pytest.mark.slow
def test_initialisation_holds_the_sdk_knee_angle(walk_scene, model_6k, monkeypatch):
    seen = []
    rows = init_mod.knee_angle_rows

    def spy(model, coeffs, target, version, weight):
        seen.append(target)
        return rows(model, coeffs, target, version, weight)

    monkeypatch.setattr(init_mod, "knee_angle_rows", spy)
    knee_frames = walk_scene.observations[1::2]  # the frames the angle is measured on, when given
    source = init_mod.initialise_from_observations(walk_scene.observations, model_6k,
                                                   view_point=walk_scene.sensor.depth.center,
                                                   knee_hinge_weight=3000.0, knee_hinge_from="sdk",
                                                   knee_frames=knee_frames)
    target, _ = sdk_knee_angle(knee_frames, "v2")
    assert target != sdk_knee_angle(walk_scene.observations, "v2")[0]
    assert len(seen) == init_mod.INIT_PASSES and np.allclose(seen, target)  # every pass, the first too
    np.testing.assert_allclose(model_knee_angles(model_6k, source.coeffs).mean(), target, atol=np.radians(0.1))
    m = model_6k.measure(source.coeffs)
    assert abs(m["stature_m"] - walk_scene.truth["stature_m"]) < 0.0095
    assert abs(m["mass_kg"] - walk_scene.truth["mass_kg"]) < 2.0


class _Frame:
    def __init__(self, bodies):
        self.kinect_bodies = bodies


class _Session:
    """Joints files only: frame ``i`` holds ``bodies[i]`` (None: no joints file)."""

    def __init__(self, bodies):
        self.bodies = bodies
        self.frame_ids = list(range(len(bodies)))

    def frame(self, i):
        return _Frame(self.bodies[i])


def test_knee_joint_frames_follow_the_actor_through_every_frame_of_the_window():
    rng = np.random.default_rng(4)
    actor = [_frame(0.01, (0.1, 0.2), rng).joints for _ in range(12)]
    walk = np.linspace(0.0, 0.3, 12)  # 3 cm a frame
    tracked = np.ones(len(NAMES), bool)
    bodies = []
    for i in range(12):
        A = actor[i] - actor[i][0] + [walk[i], 0.0, 2.0]
        other = A + [1.0, 0.0, 0.0]  # another person a metre off, who takes the actor's id from frame 6 (rel6a)
        ids = (1, 2) if i < 6 else (2, 1)
        bodies.append([{"player": ids[0], "positions": A, "tracked": tracked},
                       {"player": ids[1], "positions": other, "tracked": tracked}])
    bodies[8] = None  # a frame without a joints file
    obs = [SimpleNamespace(frame=f, joints=bodies[f][0]["positions"], tracked=tracked, version="v2")
           for f in (2, 5, 9)]
    frames = init_mod.knee_joint_frames(_Session(bodies), obs)
    # frames 2-9 (the observations' window) but 8; each the actor's joints, whichever id it has
    assert [f.frame for f in frames] == [2, 3, 4, 5, 6, 7, 9]
    for f in frames:
        np.testing.assert_array_equal(f.joints, bodies[f.frame][0]["positions"])
        assert f.version == "v2" and f.tracked.all()
    assert init_mod.knee_joint_frames(_Session(bodies), []) == []
