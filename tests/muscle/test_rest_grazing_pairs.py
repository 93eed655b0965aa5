"""The grazing pairs left out of the rest-shape fit (``refine.grazing_pairs``, ``DepthFrame.min_facing_cos``,
``CaptureOptions.body_rest_min_facing_cos``; issue 11, fourteenth pass, the rest arm).

Near a limb's silhouette the cleaned depth stops short of the surface (Sec. 4's filters and the thinned border), so a
grazing vertex's closest depth point is the last one kept, whose tangent plane the convex limb lies behind."""

from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial import cKDTree

from bodystudio.geometry.mesh import vertex_normals
from bodystudio.muscle.arm import ArmPose
from bodystudio.muscle.nicp import CorrespondenceFilters, vertex_neighbourhoods
from bodystudio.muscle.refine import DepthFrame, elbow_rotvec, fit_body_rest_shape, grazing_pairs, skeleton_model_mesh
from tests.muscle.test_body_rest_shape import EXTRA_LOCAL, space_2k  # noqa: F401  (the 2k body space)
from tests.muscle.test_capture_analytic import Spies, scene  # noqa: F401  (the tiny capture scene)


def test_grazing_pairs_are_the_vertices_seen_edge_on():
    """A ring of normals about a vertex column, the sensor along +z: the vertices whose normal is within
    arccos(0.3) of perpendicular to the ray (and those facing away) are grazing, the others not."""
    angles = np.radians(np.arange(0.0, 360.0, 5.0))
    N = np.c_[np.sin(angles), np.zeros_like(angles), np.cos(angles)]
    V = 0.04 * N
    sensor = np.array([0.0, 0.0, 1000.0])  # far: the ray is +z everywhere
    g = grazing_pairs(V, N, sensor, 0.3)
    np.testing.assert_array_equal(g, np.cos(angles) < 0.3)
    assert not grazing_pairs(V, N, sensor, 0.0)[np.cos(angles) > 1e-9].any()
    assert g.sum() > len(angles) / 2  # the back half and the two grazing bands


@pytest.fixture(scope="module")
def cut_short(arm_model_2k, space_2k):  # noqa: F811
    """Eight frames of a planted subject (population draw plus three unsampled local targets) seen from one side,
    the true poses held, whose depth stops short of the silhouette as the cleaned Kinect depth does: only the
    surface facing the sensor at cos > 0.45 is seen (12 points per face)."""
    from bodystudio.body.population import sample_subject
    from bodystudio.muscle.model import ArmShapeParams, body_parameters_of, model_joints

    model, space = arm_model_2k, space_2k
    phenotype, local = sample_subject(41)
    x_true = body_parameters_of(phenotype, {**local, **EXTRA_LOCAL}, space)
    shape = ArmShapeParams(24.0, phenotype.muscle, 1.75, 0.5, sex=phenotype.gender)
    shoulder = model_joints(model, shape)[0]
    rest, J = space.rest_and_joints(x_true, shoulder)
    F = np.asarray(model.faces, np.int64)
    adjacency = vertex_neighbourhoods(F, len(rest), rings=2)
    sensor = 0.5 * (J[0] + J[1]) + np.array([0.3, 0.1, 1.0])
    bary = np.random.default_rng(0).dirichlet(np.ones(3), size=12)
    arm_faces = np.repeat(model.arm_mask[F].all(axis=1), len(bary))
    poses, frames, meshes = [], [], []
    for k in range(8):
        pose = ArmPose(np.eye(4), np.stack([[0.0, 0.0, np.radians(5.0 + 4.0 * k)],
                                            elbow_rotvec(J, np.radians(15.0 + 14.0 * k), 0.0), np.zeros(3)]))
        M = skeleton_model_mesh(model, pose, rest, J, 0.5)
        N = vertex_normals(M, F)
        P = np.einsum("sb,fbd->fsd", bary, M[F]).reshape(-1, 3)  # dense as a depth image's pixels
        Q = np.einsum("sb,fbd->fsd", bary, N[F]).reshape(-1, 3)
        Q /= np.linalg.norm(Q, axis=1)[:, None]
        to_sensor = sensor - P
        cos = np.einsum("kd,kd->k", Q, to_sensor) / np.linalg.norm(to_sensor, axis=1)
        keep = arm_faces & (cos > 0.45)
        frames.append(DepthFrame(P[keep], Q[keep], cKDTree(P[keep]), sensor, model.arm_mask, adjacency,
                                 CorrespondenceFilters(), F))
        poses.append(pose)
        meshes.append(M)
    mean, sigma = space.prior(shape)
    return SimpleNamespace(model=model, space=space, x_true=x_true, shoulder=shoulder, poses=poses, frames=frames,
                           meshes=meshes, mean=mean, sigma=sigma, arm=model.arm_mask)


def _median_mm(s, x, shift):
    rest, J = s.space.rest_and_joints(x, s.shoulder)
    d = []
    for p, M in zip(s.poses, s.meshes, strict=True):
        root = p.root.copy()
        root[:3, 3] += shift
        d.append(np.linalg.norm(skeleton_model_mesh(s.model, ArmPose(root, p.angles), rest, J, 0.5) - M,
                                axis=1)[s.arm])
    return 1000.0 * float(np.median(d))


def test_the_rest_shape_fit_without_the_grazing_pairs_is_not_pulled_outwards(cut_short):
    """The depth cut short of the silhouette, the fit started at the planted subject (the prior centred there, weak):
    with every pair the grazing vertices pull the arm off it onto planes the limb lies behind; without them
    (cos < 0.3 dropped) it stays at half the distance, and only the grazing pairs are dropped."""
    s = cut_short
    common = dict(prior_weight=1.0, norm_limit=0.5, huber_m=0.0, iterations=5)
    M0 = s.meshes[3]
    k_all = s.frames[3].plane_pairs(M0)[0]
    k_cut = replace(s.frames[3], min_facing_cos=0.3).plane_pairs(M0)[0]
    graze = grazing_pairs(M0, vertex_normals(M0, np.asarray(s.model.faces)), s.frames[3].sensor_center, 0.3)
    np.testing.assert_array_equal(k_cut, k_all[~graze[k_all]])
    assert 0 < len(k_all) - len(k_cut) < len(k_all) / 2
    # started at the truth, the prior centred there too (weakly): what the data alone moves it by
    every = _median_mm(s, *fit_body_rest_shape(s.space, s.model, s.poses, s.frames, s.x_true, s.shoulder, s.x_true,
                                               s.sigma, **common))
    frames = [replace(f, min_facing_cos=0.3) for f in s.frames]
    cut = _median_mm(s, *fit_body_rest_shape(s.space, s.model, s.poses, frames, s.x_true, s.shoulder, s.x_true,
                                             s.sigma, **common))
    assert every > 2.0 and cut < 0.6 * every, (cut, every)  # measured: 2.70 -> 1.30 mm


def test_the_capture_drops_the_grazing_pairs_of_the_fits_the_options_name(monkeypatch, scene):  # noqa: F811
    """``body_rest_min_facing_cos`` reaches the rest-shape fit's frames, ``sequence_min_facing_cos`` the sequence
    fit's and the pose refit's (each its own value)."""
    from bodystudio.muscle.capture import CaptureOptions, capture_arm_frames
    from bodystudio.muscle.nicp import NicpOptions

    s = scene
    spies = Spies(monkeypatch, ("fit_body_rest_shape_and_poses", "fit_arm_sequence_skeleton",
                                "refit_arm_poses_to_depth"))
    o = CaptureOptions(mode="model", shape_frames=2, shape_rounds=1, first_frame_nicp_iterations=3,
                       sequence_rounds=1, sequence_max_nfev=3, nicp=NicpOptions(iterations=2), pose_sigma_frames=0.0,
                       body_rest_rounds=1, body_rest_frame_stride=2, body_rest_iterations=1, body_rest_keep_best=False,
                       body_rest_min_facing_cos=0.3, sequence_min_facing_cos=0.25)
    capture_arm_frames(s.depths, s.camera, s.template, s.model, o, tracker_joints=s.tracker, known_shape=s.shape)
    (rest_call,) = spies["fit_body_rest_shape_and_poses"]
    assert {f.min_facing_cos for f in rest_call.args[3]} == {0.3}
    assert len(spies["fit_arm_sequence_skeleton"]) == 2
    for call in spies["fit_arm_sequence_skeleton"]:
        assert {f.min_facing_cos for f in call.args[3]} == {0.25}
    (refit_call,) = spies["refit_arm_poses_to_depth"]
    assert {f.min_facing_cos for f in refit_call.args[2]} == {0.25}
