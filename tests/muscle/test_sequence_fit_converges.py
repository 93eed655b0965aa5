"""The capture's sequence fit (``refine.fit_arm_sequence_skeleton`` with ``CaptureOptions``' defaults) converges:
a 1e-12 m change of its input moves its result by far less than a micrometre (docs/muscle.md "Capture, the
thread count"; ``benchmarks/muscle_sequence_stability.py`` on a whole capture)."""

import dataclasses

import numpy as np
import pytest
from scipy.spatial import cKDTree

from bodystudio.geometry.mesh import vertex_normals
from bodystudio.muscle.arm import ArmPose
from bodystudio.muscle.capture import CaptureOptions
from bodystudio.muscle.nicp import CorrespondenceFilters, vertex_neighbourhoods
from bodystudio.muscle.refine import DepthFrame, elbow_rotvec, fit_arm_sequence_skeleton, skeleton_model_mesh


@pytest.fixture(scope="module")
def noisy_offset_sequence(arm_model_2k):
    """Six frames of a subject whose rest joints sit ~1 cm from the model's regressed ones, seen as point clouds
    with 1.5 mm depth noise and 3 % outliers (2 cm), the tracker's joints with 2 mm noise, and a start on the
    regressed skeleton with the shoulder 3 deg and the elbow 4 deg off."""
    from bodystudio.muscle.model import ArmShapeParams, model_joints, model_rest_vertices
    from bodystudio.muscle.refine import posed_joints

    model = arm_model_2k
    shape = ArmShapeParams(24.0, 0.5, 1.78, 0.5)
    J = model_joints(model, shape)
    Jt = J + np.array([[0.006, -0.004, 0.006], [0.008, 0.005, -0.005], [-0.006, 0.007, 0.005]])
    rest = model_rest_vertices(model, shape)
    F = np.asarray(model.faces, np.int64)
    adjacency = vertex_neighbourhoods(F, len(rest), rings=2)
    sensor = 0.5 * (J[0] + J[1]) + np.array([0.3, 0.1, 1.0])
    rng = np.random.default_rng(11)
    frames, start, tracker = [], [], []
    for k in range(6):
        shoulder = np.array([0.0, 0.0, np.radians(5.0 + 4.0 * k)])
        pose = ArmPose(np.eye(4), np.stack([shoulder, elbow_rotvec(Jt, np.radians(15.0 + 12.0 * k), 0.0),
                                            np.zeros(3)]))
        M = skeleton_model_mesh(model, pose, rest, Jt)
        P, N = M[model.arm_mask], vertex_normals(M, F)[model.arm_mask]
        P = P + N * rng.normal(0.0, 0.0015, (len(P), 1))
        outliers = rng.random(len(P)) < 0.03
        P[outliers] += N[outliers] * 0.02
        frames.append(DepthFrame(P, N, cKDTree(P), sensor, model.arm_mask, adjacency, CorrespondenceFilters(), F))
        tracker.append(posed_joints(Jt, pose) + rng.normal(0.0, 0.002, (3, 3)))
        start.append(ArmPose(np.eye(4), np.stack([shoulder + np.radians([3.0, 0.0, 0.0]),
                                                  elbow_rotvec(J, np.radians(19.0 + 12.0 * k), 0.0), np.zeros(3)])))
    return model, shape, J, rest, frames, start, np.stack(tracker)


def _capture_sequence_fit(case, options: CaptureOptions, eps: float):
    """The sequence fit as the capture calls it (``capture.sequence_stage``) with ``options``' sequence fields,
    its rest mesh and depth points moved by ``eps`` (uniform, seeded). Returns every frame's mesh (T, V, 3)."""
    model, shape, J, rest, frames, start, tracker = case
    rng = np.random.default_rng(0)
    rest = rest + eps * rng.uniform(-1.0, 1.0, rest.shape)
    frames = [dataclasses.replace(fr, points=fr.points + eps * rng.uniform(-1.0, 1.0, fr.points.shape))
              for fr in frames]
    o = options
    poses, J_fit = fit_arm_sequence_skeleton(
        model, shape, start, frames, J, o.norm_limit, tracker, o.sequence_tracker_weight, o.sequence_smooth_weight,
        o.sequence_rounds, o.sequence_max_nfev, o.sequence_huber_m, o.sequence_fit_root, True,
        o.sequence_skeleton_prior_weight, o.sequence_depth_huber_only, rest=rest, free_joints=o.sequence_free_joints,
        torso_pair_weight=o.sequence_torso_pair_weight)
    return np.stack([skeleton_model_mesh(model, p, rest, J_fit, o.norm_limit) for p in poses])


def test_the_default_sequence_fit_does_not_amplify_a_rounding_sized_input_change(noisy_offset_sequence):
    """Measured: the default (IRLS Huber on the depth pairs; ftol stops after 5, 4, 3 evaluations) moves by 2e-9 m;
    scipy's Huber loss on every residual with 15 evaluations (the default before) stops at its evaluation limit in
    every round and moves by 5.3e-4 m."""
    options = CaptureOptions()
    a = _capture_sequence_fit(noisy_offset_sequence, options, 0.0)
    b = _capture_sequence_fit(noisy_offset_sequence, options, 1e-12)
    assert np.abs(a - b).max() < 1e-6
    # the fit did something: the result is not the start (a fit that returned its input would pass the above)
    model, shape, J, rest, frames, start, tracker = noisy_offset_sequence
    start_meshes = np.stack([skeleton_model_mesh(model, p, rest, J, options.norm_limit) for p in start])
    assert np.abs(a - start_meshes).max() > 5e-3
