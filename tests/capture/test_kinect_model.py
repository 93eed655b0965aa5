"""Kinect depth model statistics with closed-form answers: grazing-angle dropout, holes and dropouts."""

import numpy as np
import pytest
import trimesh
from scipy import ndimage

from bodystudio.capture.kinect import KINECT_NOISE, KinectNoiseModel, random_holes, simulate_kinect_depth
from bodystudio.geometry.camera import kinect_v1

SENSOR = kinect_v1("640x480")
CLEAN = KinectNoiseModel(hole_rate=0.0, dropout_rate=0.0, flying_pixel_prob=0.0)


def _in_depth_frame(P):
    return SENSOR.depth.camera_to_world(np.asarray(P, dtype=np.float64))


def _tilted_quad(tilt_deg, center_z=2.0, half_size=0.15):
    """A square at ``center_z`` on the optical axis whose normal is ``tilt_deg`` from the viewing direction."""
    t = np.radians(tilt_deg)
    a, b = np.array([np.cos(t), 0.0, np.sin(t)]), np.array([0.0, 1.0, 0.0])
    c = np.array([0.0, 0.0, center_z])
    P = [c + half_size * (sa * a + sb * b) for sa, sb in [(-1, -1), (1, -1), (1, 1), (-1, 1)]]
    return _in_depth_frame(P), np.array([[0, 1, 2], [0, 2, 3]])


def _seen(V, F):
    return simulate_kinect_depth(V, F, SENSOR, None, noise=False) > 0


@pytest.mark.parametrize("tilt_deg, kept", [(0, True), (45, True), (70, True), (86, False), (88, False)])
def test_surfaces_seen_beyond_80_degrees_return_no_depth(tilt_deg, kept):
    V, F = _tilted_quad(tilt_deg)
    seen = _seen(V, F)
    assert seen.sum() > 20  # the renderer sees the quad, even edge-on
    depth = simulate_kinect_depth(V, F, SENSOR, np.random.default_rng(0), model=CLEAN)
    inner = ndimage.binary_erosion(seen, iterations=2)  # away from the quad's outline (projector shadow)
    valid = (depth > 0)[inner]
    assert valid.all() if kept else not valid.any(), valid.mean()


def test_grazing_angle_and_range_follow_the_model_and_sensor():
    V, F = _tilted_quad(70)
    strict = KinectNoiseModel(hole_rate=0.0, dropout_rate=0.0, flying_pixel_prob=0.0, grazing_angle_deg=60.0)
    inner = ndimage.binary_erosion(_seen(V, F), iterations=2)
    assert not (simulate_kinect_depth(V, F, SENSOR, np.random.default_rng(0), model=strict) > 0)[inner].any()
    for z in (0.45, 4.8):  # outside 0.5-4.5 m: nothing, with or without noise
        Vz, Fz = _tilted_quad(0.0, center_z=z, half_size=0.2 * z)
        assert not simulate_kinect_depth(Vz, Fz, SENSOR, None, noise=False).any()


def test_grazing_dropout_on_a_sphere_is_the_rim_annulus():
    """A sphere seen from 2.5 m: the incidence angle exceeds 80 degrees on the outer annulus of the disc,
    1 - sin^2(80 deg) = 3.0 % of it in orthographic view (a perspective view sees slightly less of the rim)."""
    sphere = trimesh.creation.icosphere(subdivisions=5, radius=0.3)
    V = _in_depth_frame(sphere.vertices + [0.0, 0.0, 2.5])
    seen = _seen(V, sphere.faces)
    depth = simulate_kinect_depth(V, sphere.faces, SENSOR, np.random.default_rng(0), model=CLEAN)
    # the projector shadow takes a crescent on the far side of the baseline: count the dropout on the near half
    cx = int(np.round(np.mean(np.nonzero(seen)[1])))
    half = np.zeros_like(seen)
    half[:, :cx] = True
    dropped = (seen & (depth == 0) & half).sum() / (seen & half).sum()
    expected = 1.0 - np.sin(np.radians(80.0)) ** 2
    print("sphere: dropped", dropped, "expected", expected)
    assert 0.8 * expected < dropped < 1.25 * expected, (dropped, expected)
    # ... and it is a rim: no dropped pixel more than 3 px inside the outline
    deep = ndimage.binary_erosion(seen, iterations=4)
    assert (depth[deep & half] > 0).all()


def test_hole_and_dropout_statistics():
    """3x3 holes around seeds at rate h and isolated dropouts at rate d: a pixel is missing with probability
    1 - (1 - h)^9 (1 - d); holes are 3x3 blocks, dropouts single pixels."""
    shape = (480, 640)
    h, d = 0.004, 0.01
    model = KinectNoiseModel(hole_rate=h, dropout_rate=d)
    missing = random_holes(shape, np.random.default_rng(0), model)
    expected = 1.0 - (1.0 - h) ** 9 * (1.0 - d)
    print("holes: missing", missing.mean(), "expected", expected)
    assert abs(missing.mean() / expected - 1.0) < 0.05, (missing.mean(), expected)
    only_holes = random_holes(shape, np.random.default_rng(1), KinectNoiseModel(hole_rate=h, dropout_rate=0.0))
    assert abs(only_holes.mean() / (1.0 - (1.0 - h) ** 9) - 1.0) < 0.05
    labels, n = ndimage.label(only_holes, structure=np.ones((3, 3)))
    sizes = ndimage.sum(only_holes, labels, np.arange(1, n + 1))
    inner = np.ones(n, bool)  # blobs cut by the image border are smaller
    for k, sl in enumerate(ndimage.find_objects(labels)):
        inner[k] = sl[0].start > 0 and sl[1].start > 0 and sl[0].stop < shape[0] and sl[1].stop < shape[1]
    assert sizes[inner].min() >= 9 and np.median(sizes[inner]) == 9
    only_drop = random_holes(shape, np.random.default_rng(2), KinectNoiseModel(hole_rate=0.0, dropout_rate=d))
    assert abs(only_drop.mean() / d - 1.0) < 0.05
    _, n_drop = ndimage.label(only_drop, structure=np.ones((3, 3)))
    assert n_drop > 0.9 * only_drop.sum()  # isolated pixels
    assert not random_holes(shape, np.random.default_rng(3), KinectNoiseModel(hole_rate=0.0, dropout_rate=0.0)).any()


def test_simulated_depth_of_a_wall_has_the_models_holes():
    """A frontal wall: no grazing, no flying pixels away from its edges; what is missing inside are the holes."""
    V, F = _tilted_quad(0.0, center_z=2.0, half_size=3.0)
    rng = np.random.default_rng(5)
    depth = simulate_kinect_depth(V, F, SENSOR, rng)
    missing = (depth[20:-20, 80:-20] == 0).mean()  # the projector does not light the left band (f b / z = 22 px)
    h, d = KINECT_NOISE.hole_rate, KINECT_NOISE.dropout_rate
    expected = 1.0 - (1.0 - h) ** 9 * (1.0 - d)
    print("wall: missing", missing, "expected", expected)
    assert abs(missing / expected - 1.0) < 0.15, (missing, expected)
    no_holes = simulate_kinect_depth(V, F, SENSOR, rng, model=KinectNoiseModel(hole_rate=0.0, dropout_rate=0.0))
    assert (no_holes[20:-20, 80:-20] > 0).all()


def test_khoshelham_formulas():
    """Eq. 12 (sigma_Z = 1.425e-3 Z^2), Eq. 13 (resolution Z^2 step / (f b)) and sigma_d = coeff f b."""
    m = KINECT_NOISE
    np.testing.assert_allclose(m.axial_sigma_m([1.0, 2.0, 4.0]), [1.425e-3, 5.7e-3, 22.8e-3])
    np.testing.assert_allclose(m.depth_resolution_m(2.0, 580.0, 0.075), 4.0 / 8.0 / 43.5)
    assert m.disparity_sigma_px(580.0, 0.075) == pytest.approx(1.425e-3 * 43.5)


def test_quantized_disparity_without_noise_is_on_the_eighth_pixel_grid():
    from bodystudio.capture.kinect import quantized_disparity_depth

    fb = 580.0 * 0.075
    depth = np.array([[0.0, 1.0, 2.0, 3.0, 4.4]])
    out = quantized_disparity_depth(depth, 580.0, 0.075, None)
    assert out[0, 0] == 0.0
    d = fb / out[0, 1:]
    np.testing.assert_allclose(d * 8, np.round(d * 8), atol=1e-9)
    np.testing.assert_allclose(d, fb / depth[0, 1:], atol=1.0 / 16 + 1e-12)  # within half a quantum


def test_flying_pixels_lie_between_foreground_and_background():
    from bodystudio.capture.kinect import flying_pixels

    depth = np.full((20, 20), 3.0)
    depth[:, :10] = 1.0
    depth[0:3, 15:18] = 0.0  # a hole in the background: flying pixels reach 0.3 m behind the near side
    model = KinectNoiseModel(flying_pixel_prob=1.0)
    out = flying_pixels(depth, np.random.default_rng(0), model)
    edge = np.zeros_like(depth, bool)
    edge[:, 9:11] = True
    assert (out[edge] >= 1.0).all() and (out[edge] <= 3.0).all() and (out[edge] != depth[edge]).mean() > 0.9
    near_hole = np.zeros_like(edge)
    near_hole[0:4, 14:19] = True
    near_hole &= depth > 0
    assert (out[near_hole] >= 3.0).all() and (out[near_hole] <= 3.3 + 1e-12).all()
    assert (out[near_hole] > 3.0).mean() > 0.9
    assert np.array_equal(out[~edge & ~near_hole & (depth > 0)], depth[~edge & ~near_hole & (depth > 0)])
    assert (out[depth == 0] >= 0).all()
    none = flying_pixels(depth, np.random.default_rng(0), KinectNoiseModel(flying_pixel_prob=0.0))
    assert np.array_equal(none, depth)


def test_bad_inputs_are_refused(tmp_path):
    import cv2

    from bodystudio.capture.kinect import read_depth_png, simulate_tracker_joints
    from bodystudio.errors import FileFormatError, InputError

    V, F = _tilted_quad(0.0)
    with pytest.raises(InputError, match="RGBDSensor"):
        simulate_kinect_depth(V, F, SENSOR.depth, np.random.default_rng(0))
    with pytest.raises(FileFormatError, match="not found"):
        read_depth_png(tmp_path / "missing.png")
    cv2.imwrite(str(tmp_path / "eight.png"), np.zeros((4, 4), np.uint8))
    with pytest.raises(FileFormatError, match="16-bit"):
        read_depth_png(tmp_path / "eight.png")
    for kwargs in ({"noise_m": -0.01}, {"bone_length_jitter": -1.0}, {"dropout": 1.5}, {"dropout": -0.1}):
        with pytest.raises(InputError, match="dropout"):
            simulate_tracker_joints(None, None, None, "v2", np.random.default_rng(0), **kwargs)


def test_tracker_noise_is_unbiased_and_every_bone_jitters(body_2k):
    from bodystudio.body.kinect import kinect_joints
    from bodystudio.capture.kinect import kinect_parent_indices, simulate_tracker_joints

    sk = body_2k.skeleton
    truth = kinect_joints(sk, sk.heads, sk.tails, "v2")
    parents = kinect_parent_indices("v2")
    child = np.flatnonzero(parents >= 0)
    rest = np.linalg.norm(truth[child] - truth[parents[child]], axis=1)
    rng = np.random.default_rng(8)
    ratios = np.array([np.linalg.norm(J[child] - J[parents[child]], axis=1) / rest for J, _ in
                       (simulate_tracker_joints(sk.heads, sk.tails, sk, "v2", rng, noise_m=0.0) for _ in range(300))])
    np.testing.assert_allclose(ratios.std(0), 0.03, rtol=0.3)  # each bone, the root's children too (default 3 %)
    res = np.array([simulate_tracker_joints(sk.heads, sk.tails, sk, "v2", rng, bone_length_jitter=0.0)[0] - truth
                    for _ in range(300)])
    assert np.abs(res.mean(0)).max() < 0.004 and abs(res.std() / 0.01 - 1) < 0.05  # default 1 cm, unbiased
    out = [simulate_tracker_joints(sk.heads, sk.tails, sk, "v2", rng, bone_length_jitter=0.0, dropout=1.0)
           for _ in range(50)]
    assert not np.array([t for _, t in out]).any()  # dropout 1: nothing tracked
    err = np.array([j - truth for j, _ in out])
    assert abs(err.std() / 0.03 - 1) < 0.1  # inferred joints: 3x the noise


def test_millimetre_conversion_edges_and_tracker_hierarchy():
    from bodystudio.capture.kinect import (
        _topological_order,
        depth_to_millimetres,
        kinect_parent_indices,
        millimetres_to_depth,
    )

    mm = depth_to_millimetres(np.array([np.nan, -0.5, 0.0, 1.2344, 1.2346, 70.0]))
    assert mm.dtype == np.uint16 and mm.tolist() == [0, 0, 0, 1234, 1235, 65535]
    back = millimetres_to_depth(np.array([0, 1, 65535], np.uint16))
    assert back.dtype == np.float32 and back.tolist() == pytest.approx([0.0, 0.001, 65.535])
    for version in ("v1", "v2"):
        parents = kinect_parent_indices(version)
        assert (parents == -1).sum() == 1 and parents[0] == -1 and (parents < len(parents)).all()
        order = _topological_order(parents)
        assert sorted(order) == list(range(len(parents)))
        position = {j: k for k, j in enumerate(order)}
        assert all(position[p] < position[j] for j, p in enumerate(parents) if p >= 0)
    assert _topological_order(np.array([2, -1, 1])) == [1, 2, 0]
