"""bodystudio.capture.kinect cases the model tests leave open (issue 17, mutation testing): Eq. 13 at a depth
where Z^2 and 2 Z differ, the noise model's quantisation step and shadow tolerance reaching the simulation,
a hierarchy whose first bone is not the root, and tracker noise drawn per joint and axis."""

import numpy as np
import pytest

from bodystudio.capture.kinect import (
    KINECT_NOISE,
    KinectNoiseModel,
    _topological_order,
    simulate_kinect_depth,
)
from bodystudio.geometry.camera import kinect_v1

SENSOR = kinect_v1("640x480")


def _wall(z=2.0, half_size=3.0):
    c = np.array([0.0, 0.0, z])
    P = [c + half_size * np.array([sa, sb, 0.0]) for sa, sb in [(-1, -1), (1, -1), (1, 1), (-1, 1)]]
    return SENSOR.depth.camera_to_world(np.asarray(P)), np.array([[0, 1, 2], [0, 2, 3]])


def test_depth_resolution_is_quadratic_in_depth():
    fb = 580.0 * 0.075
    np.testing.assert_allclose(KINECT_NOISE.depth_resolution_m([1.0, 3.0], 580.0, 0.075),
                               [1.0 / 8.0 / fb, 9.0 / 8.0 / fb], rtol=1e-12)
    np.testing.assert_allclose(KINECT_NOISE.axial_sigma_m(3.0), 1.425e-3 * 9.0, rtol=1e-12)


def test_the_simulation_uses_the_models_disparity_step():
    """A noise-free model with a 1/2-pixel disparity step: every depth of a frontal wall is f b / d with d on
    the half-pixel grid (the default 1/8-pixel grid would give other depths)."""
    V, F = _wall(2.1)
    model = KinectNoiseModel(axial_sigma_coeff=0.0, disparity_step_px=0.5, flying_pixel_prob=0.0, hole_rate=0.0,
                             dropout_rate=0.0)
    depth = simulate_kinect_depth(V, F, SENSOR, np.random.default_rng(0), model=model)
    seen = depth[20:-20, 80:-20]
    assert (seen > 0).all()
    d = SENSOR.depth.fx * SENSOR.baseline_m / seen.astype(np.float64)
    np.testing.assert_allclose(d * 2, np.round(d * 2), atol=1e-4)
    fb = SENSOR.depth.fx * SENSOR.baseline_m
    assert round(fb / 2.1 * 2) / 2 != round(fb / 2.1 * 8) / 8  # the two grids give different depths here
    np.testing.assert_allclose(seen, fb / (round(fb / 2.1 * 2) / 2), rtol=1e-6)


def test_the_simulation_uses_the_models_shadow_tolerance():
    """Projector depths agree with the camera's to a fraction of a millimetre on a frontal wall: a zero
    tolerance lights nothing, so no pixel has depth."""
    V, F = _wall(2.0)
    base = dict(flying_pixel_prob=0.0, hole_rate=0.0, dropout_rate=0.0)
    lit = simulate_kinect_depth(V, F, SENSOR, np.random.default_rng(0), model=KinectNoiseModel(**base))
    assert (lit[20:-20, 80:-20] > 0).all()
    dark = simulate_kinect_depth(V, F, SENSOR, np.random.default_rng(0),
                                 model=KinectNoiseModel(shadow_tolerance_m=0.0, **base))
    assert not dark.any()


def test_topological_order_when_the_first_bone_is_a_child():
    assert _topological_order(np.array([2, 0, -1])) == [2, 0, 1]
    assert _topological_order(np.array([-1, 0, 0, 1])) == [0, 1, 2, 3]


def test_tracker_noise_is_drawn_per_joint_and_axis(body_2k):
    from bodystudio.body.kinect import kinect_joints
    from bodystudio.capture.kinect import simulate_tracker_joints

    sk = body_2k.skeleton
    truth = kinect_joints(sk, sk.heads, sk.tails, "v2")
    rng = np.random.default_rng(3)
    res = np.array([simulate_tracker_joints(sk.heads, sk.tails, sk, "v2", rng, bone_length_jitter=0.0)[0] - truth
                    for _ in range(100)])  # (frames, joints, 3)
    flat = res.reshape(len(res), -1)
    corr = np.corrcoef(flat.T)
    off = corr[~np.eye(len(corr), dtype=bool)]
    assert np.abs(off).max() < 0.5  # independent draws: |r| ~ 0.1 over 100 frames; one shared draw: r = 1
    assert res.std() == pytest.approx(0.01, rel=0.1)
