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


def test_flying_pixels_only_at_jumps_and_never_in_empty_space():
    """A 1 mm/px ramp has no 5 cm jump: nothing flies even with probability 1 (a window's far + near is
    always above 5 cm, its far - near never). Pixels whose whole window is empty stay empty. At the edge of a
    block in front of a wall about half the candidates fly at probability 0.5, each drawn on its own."""
    from bodystudio.capture.kinect import flying_pixels

    ramp = 2.0 + 0.001 * np.arange(40)[None, :] * np.ones((30, 1))
    ramp[:, 30:] = 0.0  # and an empty band
    out = flying_pixels(ramp, np.random.default_rng(0), KinectNoiseModel(flying_pixel_prob=1.0))
    np.testing.assert_array_equal(out[:, :29], ramp[:, :29])
    np.testing.assert_array_equal(out[:, 31:], 0.0)
    wall = np.full((60, 60), 3.0)
    wall[:, 30:] = 2.0  # a 1 m step: the two columns either side of it are candidates
    out = flying_pixels(wall, np.random.default_rng(1), KinectNoiseModel(flying_pixel_prob=0.5))
    moved = (out != wall)[:, 29:31]
    assert 0.35 < moved.mean() < 0.65
    assert ((out[:, 29:31] >= 2.0) & (out[:, 29:31] <= 3.0)).all()


def test_grazing_mask_default_is_80_degrees():
    from bodystudio.capture.kinect import grazing_mask
    from bodystudio.capture.render import render

    t = np.radians(80.5)
    a, b, c = np.array([np.cos(t), 0.0, np.sin(t)]), np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 2.0])
    P = [c + 0.15 * (sa * a + sb * b) for sa, sb in [(-1, -1), (1, -1), (1, 1), (-1, 1)]]
    V, F = SENSOR.depth.camera_to_world(np.asarray(P)), np.array([[0, 1, 2], [0, 2, 3]])
    result = render(V, F, SENSOR.depth)
    assert result.mask.sum() > 50
    bad = grazing_mask(V, F, result, SENSOR)  # incidence 79.8-81.2 degrees across the quad
    np.testing.assert_array_equal(bad, grazing_mask(V, F, result, SENSOR, 80.0))
    assert bad[result.mask].sum() > grazing_mask(V, F, result, SENSOR, 81.0)[result.mask].sum() + 50


def test_messages_and_dtypes():
    from bodystudio.capture.kinect import depth_to_millimetres, millimetres_to_depth, simulate_tracker_joints
    from bodystudio.errors import InputError

    V, F = _wall(2.0, 0.5)
    with pytest.raises(InputError) as e:
        simulate_kinect_depth(V, F, SENSOR.depth, np.random.default_rng(0))
    assert str(e.value) == ("simulate_kinect_depth needs an RGBDSensor (kinect_v1() / kinect_v2()), "
                            f"got {type(SENSOR.depth).__name__}")
    with pytest.raises(InputError) as e:
        simulate_tracker_joints(None, None, None, "v2", np.random.default_rng(0), dropout=2.0)
    assert str(e.value) == "tracker noise_m and bone_length_jitter must be >= 0 and dropout in [0, 1]"
    assert simulate_kinect_depth(V, F, SENSOR, None, noise=False).dtype == np.float32
    assert simulate_kinect_depth(V, F, SENSOR, np.random.default_rng(0)).dtype == np.float32
    # float32 metres are converted in float64: float32(1.2345) is 1.23450005 m, i.e. 1235 mm (not 1234.5 -> 1234)
    assert depth_to_millimetres(np.array([1.2345], np.float32)).tolist() == [1235]
    assert millimetres_to_depth(np.array([1234, 0])).dtype == np.float32
