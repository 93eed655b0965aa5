"""The Sec. 7 refinement's own depth clean-up and its rim filter (`refine_depth_median_px`,
`refine_depth_gaussian_sigma_px`, `refine_min_facing_cos`: the capture's defaults since docs/muscle.md "Capture,
fourteenth pass"; ``PIPELINE`` below is the refinement before it).

A planted case: a tube of 4 cm radius (an arm's cross-section) 1 m in front of a Kinect v2, its noise-free depth
rendered from a fine mesh. The Sec. 4 clean-up's Gaussian moves the samples of the convex surface behind the skin
(-0.13 mm where it faces the sensor); without it they sit on the skin (-0.002 mm). The refinement of a model mesh that
already is the tube follows them: with the pipeline's depth it sinks the seen side, with its own clean-up it stays.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from bodystudio.errors import InputError
from bodystudio.geometry.mesh import vertex_normals
from bodystudio.muscle import capture as cm
from bodystudio.muscle.arm import ArmPose
from bodystudio.muscle.depth import clean_depth, depth_point_cloud
from bodystudio.muscle.nicp import vertex_neighbourhoods
from bodystudio.muscle.refine import edge_on_pairs

CENTRE = np.array([0.0, 1.0, 0.0])
RADIUS = 0.04
UNFILTERED = {"refine_depth_median_px": 1, "refine_depth_gaussian_sigma_px": 0.0}
PIPELINE = {"refine_depth_median_px": None, "refine_depth_gaussian_sigma_px": None, "refine_min_facing_cos": 0.0}


def tube(radius=RADIUS, length=0.3, n_around=32, n_along=31):
    """An open tube along x around CENTRE (vertices, faces with outward normals)."""
    t = np.linspace(0.0, 2.0 * np.pi, n_around, endpoint=False)
    x = np.linspace(-length / 2, length / 2, n_along)
    V = np.array([[xi, radius * np.sin(ti), radius * np.cos(ti)] for xi in x for ti in t]) + CENTRE
    F = []
    for i in range(n_along - 1):
        for j in range(n_around):
            a, b = i * n_around + j, i * n_around + (j + 1) % n_around
            F += [[a, a + n_around, b], [b, a + n_around, b + n_around]]
    return V, np.array(F)


@pytest.fixture(scope="module")
def scene():
    from bodystudio.capture.kinect import simulate_kinect_depth
    from bodystudio.geometry.camera import kinect_v2

    V, F = tube(n_around=256)
    sensor = kinect_v2(eye=(0.0, 1.0, 1.0), target=(0.0, 1.0, 0.0))
    depth = simulate_kinect_depth(V, F, sensor, np.random.default_rng(0), noise=False)
    return sensor.depth, depth


def _cloud(scene, options):
    camera, depth = scene
    return depth_point_cloud(clean_depth(depth, cm.refinement_depth_options(options)), camera)


def _radial_bias_mm(P, camera, min_cos=0.75):
    """Mean signed distance (mm, + outside) of the cloud's points to the tube where its surface faces the camera."""
    radial = np.c_[np.zeros(len(P)), (P - CENTRE)[:, 1:]]
    r = np.linalg.norm(radial, axis=1)
    ray = (P - camera.center) / np.linalg.norm(P - camera.center, axis=1, keepdims=True)
    facing = np.abs(np.einsum("kd,kd->k", radial / r[:, None], ray)) >= min_cos
    middle = np.abs(P[:, 0]) < 0.1
    return 1000.0 * float(np.mean((r - RADIUS)[facing & middle]))


def test_the_pipelines_smoothing_moves_the_convex_surface_behind_the_skin_and_the_refinements_does_not(scene):
    camera, _ = scene
    pipeline = _radial_bias_mm(_cloud(scene, cm.CaptureOptions(**PIPELINE))[0], camera)
    own = _radial_bias_mm(_cloud(scene, cm.CaptureOptions(**UNFILTERED))[0], camera)
    default = _radial_bias_mm(_cloud(scene, cm.CaptureOptions())[0], camera)
    median3 = _radial_bias_mm(_cloud(scene, cm.CaptureOptions(refine_depth_median_px=3,
                                                              refine_depth_gaussian_sigma_px=0.0))[0], camera)
    assert pipeline < -0.08  # measured -0.128 mm
    assert abs(own) < 0.02 and abs(median3) < 0.02  # measured -0.002 mm both
    assert abs(default) < 0.5 * abs(pipeline)  # the capture's default (median off, Gaussian 0.5 px)


def test_the_refinement_options_change_only_the_filters_they_name():
    base = cm.CaptureOptions(**PIPELINE)
    assert cm.refinement_depth_options(base) is base.depth
    o = cm.refinement_depth_options(cm.CaptureOptions(**{**PIPELINE, "refine_depth_median_px": 3}))
    assert (o.median_px, o.gaussian_sigma_px, o.thinning_px) == (3, base.depth.gaussian_sigma_px,
                                                                 base.depth.thinning_px)
    o = cm.refinement_depth_options(cm.CaptureOptions(**{**PIPELINE, "refine_depth_gaussian_sigma_px": 0.0}))
    assert (o.median_px, o.gaussian_sigma_px) == (base.depth.median_px, 0.0)
    o = cm.refinement_depth_options(cm.CaptureOptions())
    assert (o.median_px, o.gaussian_sigma_px, o.thinning_px) == (1, 0.5, base.depth.thinning_px)


def _refined(scene, options):
    """``capture._refinement`` of three frames of a model mesh that is the tube itself, paired with the cloud the
    options' clean-up makes."""
    camera = scene[0]
    V, F = tube()
    P, N = _cloud(scene, cm.CaptureOptions(**options))
    joints = np.array([[-1.0, 0, 0], [-0.9, 0, 0], [-0.8, 0, 0]])  # far away: no closeness-to-joint factor
    n = 3
    out = cm._refinement([V] * n, [ArmPose.rest()] * n, [(P, N)] * n, [cKDTree(P)] * n, F, camera.center,
                         np.ones(len(V), bool), vertex_neighbourhoods(F, len(V)), joints,
                         cm.CaptureOptions(**{**options, "detail_sigma_frames": 0.0}), cm._Timer())
    Nv = vertex_normals(V, F)
    ray = (V - camera.center) / np.linalg.norm(V - camera.center, axis=1, keepdims=True)
    facing = -np.einsum("kd,kd->k", Nv, ray) > 0.75
    middle = np.abs(V[:, 0]) < 0.1
    return 1000.0 * float(np.mean(np.einsum("kd,kd->k", out[1] - V, Nv)[facing & middle]))


def test_the_refinement_with_its_own_clean_up_keeps_a_right_model_on_the_skin(scene):
    sunk = _refined(scene, PIPELINE)
    kept = _refined(scene, {**UNFILTERED, "refine_min_facing_cos": 0.0})
    assert sunk < -0.08  # the pipeline's depth pulls the seen side in (measured -0.116 mm)
    assert abs(kept) < 0.03  # measured +0.009 mm


def test_edge_on_pairs_are_the_rim_seen_edge_on():
    sensor = np.array([0.0, 0.0, -1.0])
    V = np.zeros((4, 3))
    N = np.array([[0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [np.sqrt(0.5), 0.0, -np.sqrt(0.5)], [0.0, 0.3, -np.sqrt(0.91)]])
    np.testing.assert_array_equal(edge_on_pairs(V, N, sensor, 0.5), [False, True, False, False])
    np.testing.assert_array_equal(edge_on_pairs(V, N, sensor, 0.75), [False, True, True, False])
    assert not edge_on_pairs(V, N, sensor, 0.0).any()


def test_the_refinement_drops_the_rim_pairs_only_when_asked(scene, monkeypatch):
    seen = []
    real = cm.time_consistent_correspondences

    def spy(vectors, valid, sigma):
        seen.append(int(np.asarray(valid[0]).sum()))
        return real(vectors, valid, sigma)

    monkeypatch.setattr(cm, "time_consistent_correspondences", spy)
    _refined(scene, {"refine_min_facing_cos": 0.0})
    everything = seen[0]
    seen.clear()
    _refined(scene, {"refine_min_facing_cos": 0.8})
    assert 0 < seen[0] < everything
    seen.clear()
    _refined(scene, {})
    assert seen[0] < everything  # on by default


@pytest.mark.parametrize("field, value", [("refine_depth_median_px", 4), ("refine_depth_median_px", 0),
                                          ("refine_depth_gaussian_sigma_px", -1.0),
                                          ("refine_depth_gaussian_sigma_px", float("nan")),
                                          ("refine_min_facing_cos", 1.0), ("refine_min_facing_cos", -0.1)])
def test_the_options_are_validated(field, value):
    with pytest.raises(InputError, match=field):
        cm.CaptureOptions(**{field: value})


@pytest.fixture(scope="module")
def arm_scene(tiny_arm_model_path):
    """The tiny model's own mesh in three poses, 1 m in front of a Kinect v2 (noisy depth)."""
    from bodystudio.body import build_body
    from bodystudio.capture.kinect import simulate_kinect_depth
    from bodystudio.geometry.camera import kinect_v2
    from bodystudio.muscle.arm import arm_template
    from bodystudio.muscle.model import ArmShapeParams, load_arm_model, model_joints, model_mesh
    from bodystudio.muscle.refine import _shape_bounds

    template = arm_template(build_body(resolution="2k"), "left")
    model = load_arm_model(tiny_arm_model_path, template)
    shape = ArmShapeParams.from_vector(_shape_bounds(model, None)[2])
    s, e, _ = model_joints(model, shape)
    target = 0.5 * (s + e) + np.array([0.0, 0.0, 0.05])
    sensor = kinect_v2(eye=tuple(target + np.array([0.0, 0.1, 1.0])), target=tuple(target))
    axis = np.cross(e - s, [0.0, 0.0, 1.0])
    axis /= np.linalg.norm(axis)
    depths = [simulate_kinect_depth(model_mesh(model, shape, ArmPose(np.eye(4), np.stack(
        [np.zeros(3), np.radians(deg) * axis, np.zeros(3)]))), template.faces, sensor, np.random.default_rng(k))
              for k, deg in enumerate((0.0, 10.0, 20.0))]
    return model, template, sensor.depth, depths


def _capture_clouds(arm_scene, monkeypatch, **options):
    """The clouds ``capture_arm_frames`` hands its Sec. 7 refinement (world points), and the pipeline's own."""
    from bodystudio.muscle.nicp import NicpOptions, apply_similarity

    model, template, camera, depths = arm_scene
    handed = []

    def spy(model_meshes, poses, clouds_t, trees, *args, similarity=None, **kwargs):
        handed.append([apply_similarity(similarity, P) for P, _ in clouds_t])
        return model_meshes

    monkeypatch.setattr(cm, "_refinement", spy)
    fast = dict(shape_frames=1, shape_rounds=1, first_frame_nicp_iterations=1, sequence_rounds=0,
                nicp=NicpOptions(iterations=1), pose_refit=False, body_rest_shape=False, pose_sigma_frames=0.0)
    cm.capture_arm_frames(depths, camera, template, model, cm.CaptureOptions(**fast, **options))
    return handed[0] if handed else None


def test_the_capture_pairs_its_refinement_with_the_refinements_own_clean_up(arm_scene, monkeypatch):
    _, _, camera, depths = arm_scene
    handed = _capture_clouds(arm_scene, monkeypatch, **UNFILTERED)
    own = [depth_point_cloud(clean_depth(d, cm.refinement_depth_options(cm.CaptureOptions(**UNFILTERED))), camera)[0]
           for d in depths]
    pipeline = [depth_point_cloud(clean_depth(d, cm.CaptureOptions().depth), camera)[0] for d in depths]
    by_default = [depth_point_cloud(clean_depth(d, cm.refinement_depth_options(cm.CaptureOptions())), camera)[0]
                  for d in depths]
    assert len(handed) == 3
    for got, want, other in zip(handed, own, pipeline, strict=True):
        assert got.shape == want.shape
        np.testing.assert_allclose(got, want, atol=1e-9)
        assert got.shape != other.shape or np.abs(got - other).max() > 1e-4
    for got, want in zip(_capture_clouds(arm_scene, monkeypatch), by_default, strict=True):
        np.testing.assert_allclose(got, want, atol=1e-9)
    for got, want in zip(_capture_clouds(arm_scene, monkeypatch, **PIPELINE), pipeline, strict=True):
        np.testing.assert_allclose(got, want, atol=1e-9)
    assert _capture_clouds(arm_scene, monkeypatch, mode="model", **UNFILTERED) is None
