"""Depth in the pose refinement (issue 15's neck front, :mod:`bodystudio.reconstruct.pose_depth`): the Kinect's
point-to-plane residuals alone bring a pose whose neck and head are pitched and whose body stands back from the
sensor onto the depth map's surface."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bodystudio.body.kinect import kinect_joint_names
from bodystudio.reconstruct.articulated_fit import REFINE_BONES_WITH_HEAD, PoseRefineParams, refine_bone_transforms
from bodystudio.reconstruct.pose_depth import combined_data_term, depth_data_term
from bodystudio.reconstruct.pose_init import initialise_pose, pose_template

NAMES = kinect_joint_names("v2")
HEAD_JOINTS = [NAMES.index(n) for n in ("Neck", "Head")]


@pytest.fixture(scope="module")
def scene(body_2k, synthetic_capture):
    """The 2.5K template posed by the synthetic capture's joints (the truth), its depth map in a front Kinect
    v2, and a start whose neck and head are pitched 0.35 rad forward about SpineShoulder and whose whole
    body stands 4 cm further from the sensor."""
    from bodystudio.capture.render import render_depth
    from bodystudio.geometry.camera import kinect_v2
    from bodystudio.reconstruct.depth import depth_observation

    J = synthetic_capture["joints"]
    truth = initialise_pose(body_2k, J)
    sensor = kinect_v2().depth
    obs = depth_observation(render_depth(truth.vertices, body_2k.faces, sensor), sensor)
    Jp = J.copy()
    pivot = Jp[NAMES.index("SpineShoulder")]
    R = Rotation.from_rotvec((0.35, 0.0, 0.0)).as_matrix()  # about x: the face forward-down (subject faces +z)
    Jp[HEAD_JOINTS] = (Jp[HEAD_JOINTS] - pivot) @ R.T + pivot
    Jp[:, 2] -= 0.04
    return truth, initialise_pose(body_2k, Jp), obs


def _head_error_mm(joints, truth_joints):
    return float(1000 * np.max(np.linalg.norm(joints[HEAD_JOINTS] - truth_joints[HEAD_JOINTS], axis=1)))


def _front_error_mm(V, V_truth, sensor_z=2.6):
    front = V_truth[:, 2] > np.percentile(V_truth[:, 2], 50)  # the half the sensor sees
    return float(1000 * np.percentile(np.linalg.norm(V[front] - V_truth[front], axis=1), 90))


def test_depth_term_alone_brings_the_pitched_head_and_the_body_onto_the_depth(body_2k, scene):
    truth, start, obs = scene
    params = PoseRefineParams(bones=REFINE_BONES_WITH_HEAD, iterations=15)
    T = refine_bone_transforms(body_2k, start.bone_transforms, None, params,
                               data_term=depth_data_term(obs, body_2k.faces))
    fitted = pose_template(body_2k, T, start.global_scale)
    e0, e1 = _head_error_mm(start.joints, truth.joints), _head_error_mm(fitted.joints, truth.joints)
    f0, f1 = _front_error_mm(start.vertices, truth.vertices), _front_error_mm(fitted.vertices, truth.vertices)
    # measured: Neck / Head (the worse) 73.2 -> 17.3 mm, front-half vertices p90 91.5 -> 10.5 mm
    assert e0 > 60.0 and e1 < 25.0
    assert f0 > 80.0 and f1 < 16.0


def test_depth_term_residuals_are_point_to_plane_of_paired_vertices(body_2k, scene):
    truth, start, obs = scene
    from bodystudio.geometry.mesh import vertex_normals

    V = truth.vertices
    rows, r, w, G = depth_data_term(obs, body_2k.faces)(V, vertex_normals(V, body_2k.faces))
    # on the truth itself the depth map is the mesh's own raster: many pairs, all within the raster's facets
    assert len(rows) > 500
    assert np.percentile(np.abs(r), 90) < 0.004
    assert np.all((w > 0) & (w <= 1.0))
    np.testing.assert_allclose(np.linalg.norm(G, axis=1), 1.0, atol=1e-6)
    # a vertex moved 2 cm along its pair's normal has that residual
    V2 = V.copy()
    V2[rows] += 0.02 * G
    rows2, r2, _, _ = depth_data_term(obs, body_2k.faces)(V2, vertex_normals(V2, body_2k.faces))
    common, i1, i2 = np.intersect1d(rows, rows2, return_indices=True)
    assert len(common) > 0.5 * len(rows)  # measured 485 of 765
    assert np.median(r2[i2] - r[i1]) == pytest.approx(0.02, abs=0.003)


def test_combined_term_stacks_its_parts(body_2k, scene):
    truth, _, obs = scene
    from bodystudio.geometry.mesh import vertex_normals

    V = truth.vertices
    N = vertex_normals(V, body_2k.faces)
    one = depth_data_term(obs, body_2k.faces)
    rows, r, w, G = combined_data_term(one, one)(V, N)
    rows1, r1, w1, G1 = one(V, N)
    assert len(rows) == 2 * len(rows1)
    np.testing.assert_array_equal(rows[len(rows1):], rows1)
    np.testing.assert_allclose(w[:len(rows1)], w1)
    assert G.shape == (2 * len(rows1), 3)


def test_vertex_mask_keeps_only_the_neck_and_head_rows(body_2k, scene):
    from bodystudio.geometry.mesh import vertex_normals
    from bodystudio.reconstruct.pose_depth import DEPTH_BONES, bone_vertices

    truth, _, obs = scene
    V = truth.vertices
    N = vertex_normals(V, body_2k.faces)
    mask = bone_vertices(body_2k, DEPTH_BONES)
    rows_all = depth_data_term(obs, body_2k.faces)(V, N)[0]
    rows = depth_data_term(obs, body_2k.faces, vertices=mask)(V, N)[0]
    assert 0 < len(rows) < 0.3 * len(rows_all)  # the face and the front of the neck only
    np.testing.assert_array_equal(rows, rows_all[mask[rows_all]])
    names = list(body_2k.skeleton.bone_names)
    assert set(np.unique(np.argmax(body_2k.weights[rows], axis=1))) <= {names.index(b) for b in DEPTH_BONES}
