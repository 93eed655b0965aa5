"""Analytic tests of model-based filtering and refinement, Sec. 6.2 and 7 of Arm-Muscle Capture (muscle/refine.py).

Each test checks what the maths fixes exactly: Procrustes (Eq. 11) of rigidly moved parts, the joint angles of
part transforms, the tracker start carrying the rest joints onto tracked ones, the Gaussian windows of
Eq. 13-14, the Sec. 7.2 weights, the shape-fit bounds, the twist refinement and the root fit recovering a
known pose / placement from the model's own mesh (issue 17: planted bugs must fail a fast test).
"""

from functools import lru_cache

import numpy as np
import pytest
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from bodystudio.errors import InputError
from bodystudio.geometry.mesh import vertex_normals
from bodystudio.muscle import refine
from bodystudio.muscle.arm import ArmPose, part_transforms, pose_arm
from bodystudio.muscle.nicp import CorrespondenceFilters, vertex_neighbourhoods


@lru_cache(maxsize=1)
def _arm_model():
    """The conftest's small 2k arm model (5 subjects, population 12) and one training shape, built once per
    process: refine.py takes the model as input, and mutation testing forks per mutant from a process that
    has built it already (the model is not under test here)."""
    from bodystudio.muscle.arm import arm_template
    from bodystudio.muscle.model import learn_arm_model
    from bodystudio.muscle.synthetic import subject_body, training_dataset

    samples, subjects = training_dataset("2k", n_subjects=5, n_shapes=2, n_poses=8)
    template = arm_template(subject_body(subjects[0], "2k"), "left")
    return learn_arm_model(samples, template, population_size=12), samples[0].shape


JOINTS = np.array([[0.2, 1.4, 0.0], [0.35, 1.2, -0.02], [0.47, 1.05, 0.05]])


def _pose(seed=0, scale=0.4, root_shift=(0.01, -0.02, 0.03)):
    rng = np.random.default_rng(seed)
    root = np.eye(4)
    root[:3, :3] = Rotation.from_rotvec(rng.normal(0, 0.1, 3)).as_matrix()
    root[:3, 3] = root_shift
    return ArmPose(root, rng.normal(0, scale, (3, 3)))


# --- Sec. 6.2 ------------------------------------------------------------------------------------------

def test_procrustes_recovers_each_parts_rigid_motion_exactly():
    """Eq. 11 on one-hot part weights: the weighted Kabsch fit of each part is its transform, to round-off."""
    rng = np.random.default_rng(1)
    V = rng.normal(0, 0.1, (80, 3)) + JOINTS[1]
    W = np.eye(4)[rng.integers(0, 3, 80)]  # the hand part (3) gets no vertex
    pose = _pose()
    T = part_transforms(JOINTS, pose)
    Q = pose_arm(V, W, JOINTS, pose)
    out = refine.procrustes_part_transforms(V, Q, W)
    np.testing.assert_allclose(out[:3], T[:3], atol=1e-12)
    np.testing.assert_array_equal(out[3], np.eye(4))
    # Per-vertex reliability 0 removes corrupted vertices from the fit.
    Q2 = Q.copy()
    Q2[:10] += rng.normal(0, 0.05, (10, 3))
    rel = np.r_[np.zeros(10), np.ones(70)]
    np.testing.assert_allclose(refine.procrustes_part_transforms(V, Q2, W, rel)[:3], T[:3], atol=1e-12)
    assert np.abs(refine.procrustes_part_transforms(V, Q2, W)[:3] - T[:3]).max() > 1e-3


def test_joint_angles_of_part_transforms_invert_the_chain():
    for seed in range(3):
        pose = _pose(seed)
        back = refine.arm_pose_from_part_transforms(part_transforms(JOINTS, pose))
        np.testing.assert_allclose(back.angles, pose.angles, atol=1e-12)
        np.testing.assert_allclose(back.root, pose.root, atol=1e-15)


def test_pose_vector_round_trip():
    pose = _pose(2)
    x = refine._pose_vector(pose)
    assert x.shape == (15,)
    np.testing.assert_allclose(x[3:6], pose.root[:3, 3])
    back = refine._pose_from_vector(x)
    np.testing.assert_allclose(back.root, pose.root, atol=1e-12)
    np.testing.assert_allclose(back.angles, pose.angles, atol=1e-15)


def test_elbow_axes_and_the_two_dof_elbow():
    h, f = refine.elbow_axes(JOINTS)
    s, e, w = JOINTS
    np.testing.assert_allclose([np.linalg.norm(h), np.linalg.norm(f)], 1.0)
    np.testing.assert_allclose(f, (w - e) / np.linalg.norm(w - e))
    assert abs(h @ (e - s)) < 1e-12 and abs(h @ f) < 1e-12
    assert np.cross(e - s, w - e) @ h > 0  # the right-handed normal of the arm plane
    np.testing.assert_allclose(refine.elbow_rotvec(JOINTS, 0.7, 0.0), 0.7 * h, atol=1e-12)
    np.testing.assert_allclose(refine.elbow_rotvec(JOINTS, 0.0, -0.4), -0.4 * f, atol=1e-12)
    # Flexion after the twist: R = R_h(flex) R_f(twist).
    R = Rotation.from_rotvec(refine.elbow_rotvec(JOINTS, 0.7, 0.3)).as_matrix()
    want = Rotation.from_rotvec(0.7 * h).as_matrix() @ Rotation.from_rotvec(0.3 * f).as_matrix()
    np.testing.assert_allclose(R, want, atol=1e-12)
    # A straight arm has no plane: the axis is not a unit vector, but finite.
    straight = np.array([[0.0, 0, 0], [0.0, -0.3, 0], [0.0, -0.6, 0]])
    assert np.isfinite(refine.elbow_axes(straight)[0]).all()


def test_posed_joints_follow_the_parts_above_them():
    pose = _pose(3)
    one_hot = np.array([[1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, 1.0, 0]])
    np.testing.assert_allclose(refine.posed_joints(JOINTS, pose), pose_arm(JOINTS, one_hot, JOINTS, pose), atol=1e-14)
    np.testing.assert_allclose(refine.posed_joints(JOINTS, ArmPose.rest()), JOINTS, atol=1e-15)


def test_initial_pose_carries_the_rest_joints_onto_tracked_ones():
    """Tracked joints of a twist-free pose with the same bone lengths: the start pose puts the rest
    joints exactly on them; the wrist angle is zero."""
    h, f = refine.elbow_axes(JOINTS)
    u = (JOINTS[1] - JOINTS[0]) / np.linalg.norm(JOINTS[1] - JOINTS[0])
    side = np.cross(u, h)
    root = np.eye(4)
    root[:3, 3] = [0.02, -0.01, 0.03]
    truth = ArmPose(root, np.stack([0.5 * side, 0.9 * h, [0.3, 0.1, 0.0]]))
    tracked = refine.posed_joints(JOINTS, truth)
    p0 = refine.initial_arm_pose_from_joints(JOINTS, tracked)
    np.testing.assert_allclose(refine.posed_joints(JOINTS, p0), tracked, atol=1e-12)
    np.testing.assert_allclose(p0.root, root, atol=1e-15)
    np.testing.assert_array_equal(p0.angles[2], 0.0)
    # Bones already along the tracked directions: no rotation at all.
    same = refine.initial_arm_pose_from_joints(JOINTS, JOINTS + 0.1)
    np.testing.assert_allclose(same.angles, 0.0, atol=1e-15)
    np.testing.assert_allclose(same.root[:3, 3], 0.1)


def test_smooth_arm_poses_is_a_normalised_gaussian_window():
    a = np.zeros((7, 3, 3))
    a[3, 1, 0] = 1.0  # one spike
    poses = [ArmPose(np.eye(4), x) for x in a]
    out = np.array([p.angles[1, 0] for p in refine.smooth_arm_poses(poses, 1.0, radius=2)])
    g = np.exp(-np.arange(-2, 3) ** 2 / 2.0)
    np.testing.assert_allclose(out[2:5], g[1:4] / g.sum(), atol=1e-15)  # interior frames: the full window
    g1 = np.exp(-np.arange(-1, 3) ** 2 / 2.0)  # frame 1 sees frames 0-3 only: renormalised
    np.testing.assert_allclose(out[[1, 5]], g1[3] / g1.sum(), atol=1e-15)
    assert out[0] == 0.0 and out[6] == 0.0  # beyond the radius
    # Default radius max(2, ceil(2 sigma)) = 3 for sigma 1.5; a frame at the border renormalises.
    out = np.array([p.angles[1, 0] for p in refine.smooth_arm_poses(poses, 1.5)])
    g = np.exp(-np.arange(-3, 4) ** 2 / 4.5)
    np.testing.assert_allclose(out[3], g[3] / g.sum(), atol=1e-15)
    g0 = np.exp(-np.arange(0, 4) ** 2 / 4.5)
    np.testing.assert_allclose(out[0], g0[3] / g0.sum(), atol=1e-15)
    moving = [ArmPose(np.r_[np.c_[np.eye(3), [i, 0, 0]], [[0, 0, 0, 1]]], x) for i, x in enumerate(a)]
    np.testing.assert_array_equal(refine.smooth_arm_poses(moving, 1.5)[2].root, moving[2].root)  # roots as they are
    assert refine.smooth_arm_poses(poses[:2], 1.5) == poses[:2]  # fewer than 3 frames: unchanged
    g = np.exp(-np.arange(-2, 3) ** 2 / (2 * 0.3 ** 2))  # a narrow window: radius 2 still
    np.testing.assert_allclose(refine.smooth_arm_poses(poses, 0.3)[3].angles[1, 0], 1.0 / g.sum(), rtol=1e-14)


def test_time_consistent_correspondences_at_a_sequence_end_and_with_one_frame():
    c = [np.array([[1.0, 0, 0], [0, 2.0, 0]]), np.array([[3.0, 0, 0], [0, 4.0, 0]])]
    v = [np.array([True, True]), np.array([True, False])]
    out, ok = refine.time_consistent_correspondences(c, v, sigma_frames=2.0)
    w = np.exp(-1 / 8)
    np.testing.assert_allclose(out[0], [(1 + 3 * w) / (1 + w), 0, 0])
    np.testing.assert_allclose(out[1], [0, 2.0, 0])  # the neighbour's pair is invalid
    assert ok.all()
    out, ok = refine.time_consistent_correspondences(c[::-1], v[::-1])  # current frame invalid for vertex 1
    assert ok.tolist() == [True, False] and out[1].tolist() == [0, 0, 0]
    one, ok1 = refine.time_consistent_correspondences(c[:1], [np.array([1, 0])])
    np.testing.assert_array_equal(one, c[0])
    assert ok1.dtype == bool and ok1.tolist() == [True, False]


def test_correspondence_weights_are_the_cosine_times_the_joint_gain():
    n = np.tile([0.0, 0.0, 1.0], (5, 1))
    a = np.radians(60)
    c = np.array([[0, 0, 0.004], [0.004 * np.sin(a), 0, 0.004 * np.cos(a)], [0, 0, 0.0005], [0.004, 0, 0],
                  [0, 0, -0.004]])
    J = np.zeros((3, 3))
    V = np.array([[0.0, 0, 0], [0.03, 0, 0], [1.0, 0, 0], [0.0, 0.03, 0], [0.0, 0, 0.045]])
    w = refine.correspondence_weights(c, n, V, J, np.array([1, 1, 1, 1, 0], bool))
    # d = 0: 1 + 1; d = 3 cm of 6: 1.5; far: 1; short vector: no direction, agrees.
    np.testing.assert_allclose(w, [2.0, 0.5 * 1.5, 1.0, 0.0, 0.0], atol=1e-12)
    w = refine.correspondence_weights(c, n, V, J, np.ones(5, bool), joint_radius_m=0.09, joint_gain=2.0,
                                      min_length_m=1e-4)
    np.testing.assert_allclose(w, [3.0, 0.5 * (1 + 2 / 3 * 2), 1.0, 0.0, 2.0], atol=1e-12)


def _tube(n_ring=12, n_len=10, r=0.04, length=0.3):
    V = np.array([[r * np.cos(2 * np.pi * j / n_ring), r * np.sin(2 * np.pi * j / n_ring), length * i / (n_len - 1)]
                  for i in range(n_len) for j in range(n_ring)])
    F = []
    for i in range(n_len - 1):
        for j in range(n_ring):
            a, b = i * n_ring + j, i * n_ring + (j + 1) % n_ring
            F += [[a, b, a + n_ring], [b, b + n_ring, a + n_ring]]
    return V, np.array(F)


def test_refine_surface_follows_a_translation_and_keeps_the_model_without_data():
    V, F = _tube()
    v = np.tile([0.002, -0.001, 0.003], (len(V), 1))
    np.testing.assert_allclose(refine.refine_surface(V, F, v, np.ones(len(V))), V + v, atol=1e-12)
    np.testing.assert_array_equal(refine.refine_surface(V, F, v, np.zeros(len(V))), V)
    # A bump on one ring: pulled out where the data are, more with more weight.
    bump = np.zeros_like(V)
    ring = slice(4 * 12, 5 * 12)
    bump[ring] = 0.004 * np.c_[np.cos(np.arange(12) * np.pi / 6), np.sin(np.arange(12) * np.pi / 6), np.zeros(12)]
    w = np.zeros(len(V))
    w[ring] = 1.0
    weak = refine.refine_surface(V, F, bump, w, data_weight=0.2)
    strong = refine.refine_surface(V, F, bump, w, data_weight=5.0)
    err = [np.abs(X - V - bump)[ring].max() for X in (V, weak, strong)]
    assert err[2] < 0.5 * err[1] < 0.5 * err[0]


def test_model_residuals_are_point_to_plane_plus_the_weak_pull():
    mesh = np.array([[0.0, 0, 0.01], [1.0, 0, 0], [2.0, 0, -0.02]])
    pairs = (np.array([0, 2]), np.zeros((2, 3)), np.tile([0.0, 0, 1], (2, 1)))
    np.testing.assert_allclose(refine._model_residuals(mesh, pairs, None, 1.0), [0.01, -0.02])
    np.testing.assert_allclose(refine._model_residuals(mesh, pairs, mesh, 0.0), [0.01, -0.02])
    r = refine._model_residuals(mesh, pairs, mesh - 0.1, 0.25)
    np.testing.assert_allclose(r, np.r_[0.01, -0.02, np.full(9, 0.05)])


def test_shape_bounds_are_the_training_range_widened_by_its_span():
    from bodystudio.muscle.model import ArmShapeParams

    model = _arm_model()[0]
    lo, hi, x0 = refine._shape_bounds(model, None)
    r = model.shape_range()
    for i, k in enumerate(("bmi", "height_m", "arm_length_m")):
        j = (0, 2, 3)[i]
        a, b = r[k]
        span = max(b - a, model.param_scale[j])
        assert (lo[j], hi[j]) == pytest.approx((a - span, b + span), rel=1e-12), k
    assert lo[1] >= 0.0 and hi[1] <= 1.0
    np.testing.assert_allclose(x0, np.clip(model.param_center, lo + 1e-9, hi - 1e-9))
    far = ArmShapeParams(60.0, 0.5, 1.8, 0.55)
    assert refine._shape_bounds(model, far)[2][0] == pytest.approx(hi[0] - 1e-9)
    from dataclasses import replace

    bare = replace(model, subjects=[])
    lo, hi, _ = refine._shape_bounds(bare, None)
    c, s = model.param_center, model.param_scale
    # No subjects: the range is the centre +- one scale, widened by its span (2 scales) on each side.
    np.testing.assert_allclose(lo[[0, 2, 3]], (c - 3 * s)[[0, 2, 3]], rtol=1e-12)
    np.testing.assert_allclose(hi[[0, 2, 3]], (c + 3 * s)[[0, 2, 3]], rtol=1e-12)


# --- fits against the model's own meshes ------------------------------------------------------------------

def _frame(mesh, faces, arm_mask, sensor):
    return refine.DepthFrame(mesh, vertex_normals(mesh, faces), cKDTree(mesh), sensor, arm_mask,
                             vertex_neighbourhoods(faces, len(mesh)), CorrespondenceFilters(), faces)


@pytest.fixture(scope="module")
def model_case():
    """The model's own mesh of a training subject in a flexed pose, seen from the front-side sensor."""
    model, shape = _arm_model()
    from bodystudio.muscle.model import model_joints, model_mesh

    J = model_joints(model, shape)
    h, _ = refine.elbow_axes(J)
    truth = ArmPose(np.eye(4), np.stack([[0.1, -0.05, 0.15], 1.0 * h, np.zeros(3)]))

    mesh = model_mesh(model, shape, truth)
    sensor = J[1] + np.array([0.3, 0.2, 1.0])
    return model, shape, J, truth, mesh, sensor


def test_plane_pairs_are_the_filtered_closest_points(model_case):
    model, shape, J, truth, mesh, sensor = model_case
    frame = _frame(mesh, model.faces, model.arm_mask, sensor)
    k, q, n = frame.plane_pairs(mesh)
    assert 50 < len(k) < model.arm_mask.sum()
    assert model.arm_mask[k].all()
    np.testing.assert_allclose(q, mesh[k], atol=1e-15)  # the data are the mesh itself
    np.testing.assert_allclose(n, vertex_normals(mesh, model.faces)[k], atol=1e-15)


def test_twist_refinement_recovers_the_shoulder_and_elbow_angles(model_case):
    """Depth = the model's mesh in the true pose: Gauss-Newton from a pose 6 deg off returns to it."""
    from bodystudio.muscle.model import model_mesh

    model, shape, J, truth, mesh, sensor = model_case
    frame = _frame(mesh, model.faces, model.arm_mask, sensor)
    h, _ = refine.elbow_axes(J)
    start = ArmPose(truth.root, truth.angles + np.stack([[0.06, 0.05, -0.06], 0.1 * h, np.zeros(3)]))

    def mesh_of(p):
        return model_mesh(model, shape, p)

    out = refine.refine_arm_pose(start, mesh_of, frame, None, J, rounds=3)
    np.testing.assert_allclose(out.angles, truth.angles, atol=2e-3)  # measured < 1e-5 rad
    np.testing.assert_array_equal(out.root, truth.root)
    one = refine.refine_arm_pose(start, mesh_of, frame, None, J, rounds=1, max_nfev=2)
    assert np.abs(one.angles - truth.angles).max() > 2e-3  # fewer rounds and evaluations: not there yet
    # A tracker at the true joints and the previous frame at the truth only help.
    tracker = refine.posed_joints(J, truth)
    out = refine.refine_arm_pose(start, mesh_of, frame, mesh, J, rounds=2, tracker=tracker, tracker_weight=1.0,
                                 model_joints=J, previous=truth, smooth_weight=1.0)
    np.testing.assert_allclose(out.angles, truth.angles, atol=2e-3)


def test_refinement_towards_a_wrong_tracker_moves_the_pose(model_case):
    from bodystudio.muscle.model import model_mesh

    model, shape, J, truth, mesh, sensor = model_case
    frame = _frame(mesh, model.faces, model.arm_mask, sensor)
    wrong = refine.posed_joints(J, truth) + [0.0, 0.05, 0.0]
    free = refine.refine_arm_pose(truth, lambda p: model_mesh(model, shape, p), frame, None, J, rounds=1)
    pulled = refine.refine_arm_pose(truth, lambda p: model_mesh(model, shape, p), frame, None, J, rounds=1,
                                    tracker=wrong, tracker_weight=1e4, model_joints=J)
    assert np.abs(free.angles - truth.angles).max() < 1e-3 < np.abs(pulled.angles - truth.angles).max()
    prev = ArmPose(truth.root, truth.angles + 0.3)
    held = refine.refine_arm_pose(truth, lambda p: model_mesh(model, shape, p), frame, None, J, rounds=1,
                                  previous=prev, smooth_weight=1e4)
    assert np.abs(held.angles[:2] - truth.angles[:2]).max() > 0.05


def test_model_based_filtering_without_refinement_is_the_model_mesh_of_the_procrustes_pose(model_case):
    from bodystudio.muscle.model import model_mesh, model_rest_vertices

    model, shape, J, truth, mesh, sensor = model_case
    frame = _frame(mesh, model.faces, model.arm_mask, sensor)
    base = model_rest_vertices(model, shape)
    out, pose = refine.model_based_filtering(model, shape, truth.root, mesh, base, model.part_weights,
                                             np.ones(len(mesh)), frame, J, refine_pose=False)
    assert np.all(pose.angles[2] == 0.0)
    np.testing.assert_allclose(out, model_mesh(model, shape, pose), atol=1e-15)
    np.testing.assert_allclose(pose.angles[:2], truth.angles[:2], atol=0.05)  # Procrustes of a blended mesh
    refined, rpose = refine.model_based_filtering(model, shape, truth.root, mesh, base, model.part_weights,
                                                  np.ones(len(mesh)), frame, J)
    assert np.abs(rpose.angles - truth.angles).max() < 0.5 * np.abs(pose.angles - truth.angles).max()
    limited, _ = refine.model_based_filtering(model, shape, truth.root, mesh, base, model.part_weights,
                                              np.ones(len(mesh)), frame, J, norm_limit=0.0, refine_pose=False)
    np.testing.assert_allclose(limited, model_mesh(model, shape, pose, norm_limit=0.0), atol=1e-15)


def test_root_fit_with_a_fixed_shape_recovers_the_torso_placement(model_case):
    from bodystudio.muscle.model import model_mesh

    model, shape, J, truth, mesh, sensor = model_case
    offset = np.array([0.006, -0.004, 0.005])
    moved = ArmPose(truth.root.copy(), truth.angles)
    moved.root[:3, 3] += offset
    data = model_mesh(model, shape, moved)
    frame = _frame(data, model.faces, model.arm_mask, sensor)
    got, root = refine.fit_shape_parameters(model, [mesh], [truth], [frame], initial=shape, fixed_shape=True,
                                            rounds=3)
    np.testing.assert_allclose(got.as_vector(), shape.as_vector(), atol=1e-8)
    np.testing.assert_allclose(root[:3, 3], offset, atol=5e-4)
    np.testing.assert_array_equal(root[:3, :3], truth.root[:3, :3])
    with pytest.raises(InputError, match="at least one registered frame"):
        refine.fit_shape_parameters(model, [], [], [])


# --- the survivors of the first mutation run (docs/mutation/muscle-refine.md) -----------------------------

def test_time_consistent_correspondences_over_three_frames_eq13():
    c = [np.full((3, 3), v) for v in (1.0, 2.0, 4.0)]
    v = [np.array([1, 1, 0], bool), np.array([1, 1, 1], bool), np.array([1, 0, 0], bool)]
    out, ok = refine.time_consistent_correspondences(c, v, sigma_frames=1.5)
    w = np.exp(-1 / 4.5)
    np.testing.assert_allclose(out[0], (w * 1 + 2 + w * 4) / (1 + 2 * w))
    np.testing.assert_allclose(out[1], (w * 1 + 2) / (1 + w))
    np.testing.assert_allclose(out[2], 2.0)
    assert ok.all()
    v[1] = np.array([1, 0, 1], bool)  # the current frame decides validity
    out, ok = refine.time_consistent_correspondences(c, v)
    assert ok.tolist() == [True, False, True] and np.all(out[1] == 0)
    w = np.exp(-0.5)  # default sigma 1 frame
    np.testing.assert_allclose(out[0], (w * 1 + 2 + w * 4) / (1 + 2 * w))


def test_procrustes_fits_rotation_and_translation_only_and_skips_only_empty_parts():
    rng = np.random.default_rng(2)
    V = rng.normal(0, 0.1, (60, 3)) + JOINTS[1]
    W = np.zeros((60, 4))
    W[:30, 1] = 1.0
    W[30:, 2] = 1.0
    W[0, 3] = 0.5  # a part with little weight (0.5) is still fitted
    W[0, 1] = 0.5
    pose = _pose(4)
    T = part_transforms(JOINTS, pose)
    Q = pose_arm(V, W, JOINTS, pose)
    out = refine.procrustes_part_transforms(V, Q, W)
    np.testing.assert_array_equal(out[0], np.eye(4))  # the empty torso first: skipped, the rest still fitted
    np.testing.assert_allclose(out[2], T[2], atol=1e-12)
    assert np.abs(out[3] - np.eye(4)).max() > 1e-3
    # A uniformly scaled copy: the rigid fit keeps R and t of the scale-free Kabsch solution.
    c = W[:, 1] @ V / W[:, 1].sum()  # the part's weighted centroid
    S = 1.2 * (V - c) + c
    fit = refine.procrustes_part_transforms(V, S, W)[1]
    np.testing.assert_allclose(fit[:3, :3], np.eye(3), atol=1e-12)
    np.testing.assert_allclose(fit[:3, 3], 0.0, atol=1e-12)


def test_skin_template_is_four_part_lbs():
    rng = np.random.default_rng(5)
    V = rng.normal(0, 0.1, (20, 3)) + JOINTS[1]
    W = rng.dirichlet(np.ones(4), 20)
    pose = _pose(5)
    np.testing.assert_allclose(refine.skin_template(V, W, JOINTS, pose), pose_arm(V, W, JOINTS, pose))
    assert np.abs(refine.skin_template(V, W, JOINTS, pose) - V).max() > 0.01


def test_smoothing_radius_minimum_and_three_frames():
    a = np.zeros((9, 3, 3))
    a[4, 1, 0] = 1.0
    poses = [ArmPose(np.eye(4), x) for x in a]
    one = np.array([p.angles[1, 0] for p in refine.smooth_arm_poses(poses, 1.0, radius=1)])
    assert one[2] == 0.0 and one[3] > 0  # the given radius, not the default 2
    default = np.array([p.angles[1, 0] for p in refine.smooth_arm_poses(poses, 1.0)])
    g = np.exp(-np.arange(-2, 3) ** 2 / 2.0)
    assert default[1] == 0.0 and default[2] == pytest.approx(g[0] / g.sum(), rel=1e-12)  # radius max(2, 2)
    three = refine.smooth_arm_poses(poses[3:6], 1.0)
    assert three[0].angles[1, 0] > 0  # three frames are smoothed
    assert refine.smooth_arm_poses(poses, 0.0)[4].angles[1, 0] == 1.0  # sigma 0: off


def test_correspondence_weights_of_short_vectors_and_off_origin_joints():
    n = np.tile([0.0, 0.0, 1.0], (2, 1))
    c = np.array([[0.0005, 0, 0], [0.004, 0, 0]])  # both perpendicular to the normal; the first shorter than 1 mm
    J = np.array([[1.0, 2.0, 3.0], [5.0, 5.0, 5.0], [9.0, 9.0, 9.0]])
    V = np.array([[1.0, 2.0, 3.03], [1.0, 2.0, 3.0]])
    w = refine.correspondence_weights(c, n, V, J, np.ones(2, bool))
    np.testing.assert_allclose(w, [1.5, 0.0], atol=1e-12)


def test_shape_bounds_clip_muscularity_to_a_fraction_and_the_start_into_the_box():
    model = _arm_model()[0]
    lo, hi, _ = refine._shape_bounds(model, None)
    a, b = model.shape_range()["muscularity"]
    span = max(b - a, model.param_scale[1])
    assert lo[1] == max(a - span, 0.0) and hi[1] == min(b + span, 1.0)
    from bodystudio.muscle.model import ArmShapeParams

    low = refine._shape_bounds(model, ArmShapeParams(1.0, -1.0, 0.5, 0.1))[2]
    np.testing.assert_allclose(low, lo + 1e-9, rtol=0, atol=1e-15)
    high = refine._shape_bounds(model, ArmShapeParams(99.0, 2.0, 3.0, 2.0))[2]
    np.testing.assert_allclose(high, hi - 1e-9, rtol=0, atol=1e-15)


def _no_data_frame(model_case_):
    model, shape, J, truth, mesh, sensor = model_case_
    return _frame(mesh + 5.0, model.faces, model.arm_mask, sensor)  # every pair beyond max_distance


def test_shape_fit_from_tracker_joints_alone_recovers_shape_and_placement(model_case):
    """No depth pairs: the tracker's joints (the model's posed joints of a known shape and placement, two
    poses) determine the four shape parameters and the root translation through the joint regression."""
    from bodystudio.muscle.model import ArmShapeParams, model_joints

    model, shape, J, truth, mesh, sensor = model_case
    frame = _no_data_frame(model_case)
    target = ArmShapeParams(shape.bmi + 1.5, shape.muscularity, shape.height_m + 0.03, shape.arm_length_m - 0.01)
    offset = np.array([0.01, -0.005, 0.004])
    poses = [truth, ArmPose(truth.root, truth.angles * 0.5)]
    Jt = model_joints(model, target)
    tracked = []
    for p in poses:
        root = p.root.copy()
        root[:3, 3] += offset
        tracked.append(refine.posed_joints(Jt, ArmPose(root, p.angles)))
    got, root = refine.fit_shape_parameters(model, [mesh, mesh], poses, [frame, frame], initial=shape,
                                            tracker_joints=np.stack(tracked), tracker_weight=1.0, rounds=1)
    fitted = np.stack([refine.posed_joints(model_joints(model, got), ArmPose(root, p.angles)) for p in poses])
    np.testing.assert_allclose(fitted, np.stack(tracked), atol=2e-4)  # measured < 1e-6 m
    np.testing.assert_allclose(root[:3, 3], offset, atol=2e-3)
    # The arm-length prior holds x[3] where the tracker's chain says (a large weight wins).
    got2, _ = refine.fit_shape_parameters(model, [mesh, mesh], poses, [frame, frame], initial=shape,
                                          tracker_joints=np.stack(tracked), rounds=1, arm_length=0.46,
                                          arm_length_weight=1e6)
    assert got2.arm_length_m == pytest.approx(0.46, abs=1e-4)
    assert abs(got.arm_length_m - 0.46) > 0.03


def test_shape_fit_pulled_by_the_nicp_meshes_alone(model_case):
    """No depth pairs, no tracker: the weak pull to the NICP meshes fits shape and root to them."""
    from bodystudio.muscle.model import ArmShapeParams, model_mesh

    model, shape, J, truth, mesh, sensor = model_case
    frame = _no_data_frame(model_case)
    target = ArmShapeParams(shape.bmi + 1.0, shape.muscularity, shape.height_m, shape.arm_length_m)
    nicp_mesh = model_mesh(model, target, truth)
    got, root = refine.fit_shape_parameters(model, [nicp_mesh], [truth], [frame], initial=shape, nicp_weight=1.0,
                                            rounds=1)
    np.testing.assert_allclose(model_mesh(model, got, ArmPose(root, truth.angles)), nicp_mesh, atol=1e-4)
    same, _ = refine.fit_shape_parameters(model, [nicp_mesh], [truth], [frame], initial=shape, rounds=1)
    np.testing.assert_allclose(same.as_vector(), shape.as_vector(), atol=1e-9)  # no term at all: the start


def test_twist_refinement_with_free_twist_and_without_data(model_case):
    from bodystudio.muscle.model import model_mesh

    model, shape, J, truth, mesh, sensor = model_case
    h, f = refine.elbow_axes(J)
    frame = _frame(mesh, model.faces, model.arm_mask, sensor)
    twisted = ArmPose(truth.root, np.stack([truth.angles[0], refine.elbow_rotvec(J, 1.0, 0.3), np.zeros(3)]))
    # fit_twist keeps the start's twist as a free parameter; without it the twist is set to 0.
    # (no depth pairs: the previous pose, the twisted one, is the only term)
    free = refine.refine_arm_pose(twisted, lambda p: model_mesh(model, shape, p), _no_data_frame(model_case),
                                  None, J, fit_twist=True, previous=twisted, smooth_weight=1.0)
    np.testing.assert_allclose(free.angles, twisted.angles, atol=1e-7)
    fixed = refine.refine_arm_pose(twisted, lambda p: model_mesh(model, shape, p), _no_data_frame(model_case),
                                   None, J, previous=twisted, smooth_weight=1.0)
    np.testing.assert_allclose(np.cross(fixed.angles[1], h), 0.0, atol=1e-12)  # a pure hinge: no twist
    assert np.abs(fixed.angles[1] - twisted.angles[1]).max() > 0.05
    # The ARAP mesh alone (no depth pairs) pulls the angles to the pose it shows.
    start = ArmPose(truth.root, truth.angles + np.stack([[0.05, 0.0, 0.05], 0.1 * h, np.zeros(3)]))
    out = refine.refine_arm_pose(start, lambda p: model_mesh(model, shape, p), _no_data_frame(model_case),
                                 mesh, J, rounds=2)
    np.testing.assert_allclose(out.angles, truth.angles, atol=1e-4)
    # A tracker below weight 1 still counts; absent trackers and previous poses with weights are ignored.
    wrong = refine.posed_joints(J, truth) + [0.0, 0.05, 0.0]
    pulled = refine.refine_arm_pose(truth, lambda p: model_mesh(model, shape, p), frame, None, J, rounds=1,
                                    tracker=wrong, tracker_weight=0.5, model_joints=J)
    assert np.abs(pulled.angles - truth.angles).max() > 1e-3
    same = refine.refine_arm_pose(truth, lambda p: model_mesh(model, shape, p), frame, None, J, rounds=1,
                                  tracker_weight=5.0, smooth_weight=5.0)
    np.testing.assert_allclose(same.angles, truth.angles, atol=1e-6)
    prev = ArmPose(truth.root, truth.angles + 0.3)
    held = refine.refine_arm_pose(truth, lambda p: model_mesh(model, shape, p), frame, None, J, rounds=1,
                                  previous=prev, smooth_weight=0.5 * 1e4)
    assert np.abs(held.angles[:2] - truth.angles[:2]).max() > 0.01


def test_model_based_filtering_passes_its_inputs_through(model_case):
    from bodystudio.muscle.model import model_rest_vertices

    model, shape, J, truth, mesh, sensor = model_case
    frame = _frame(mesh, model.faces, model.arm_mask, sensor)
    base = model_rest_vertices(model, shape)
    rng = np.random.default_rng(8)
    deformed = mesh.copy()
    bad = rng.random(len(mesh)) < 0.3
    deformed[bad] += rng.normal(0, 0.01, (bad.sum(), 3))
    vw = (~bad).astype(float)
    _, pose = refine.model_based_filtering(model, shape, truth.root, deformed, base, model.part_weights, vw, frame, J,
                                           refine_pose=False)
    T = refine.procrustes_part_transforms(base, deformed, model.part_weights, vw + 0.05)
    want = refine.arm_pose_from_part_transforms(T).angles
    np.testing.assert_allclose(pose.angles[:2], want[:2], atol=1e-12)
    # The tracker, the previous pose and the ARAP mesh reach the refinement.
    wrong = refine.posed_joints(J, truth) + [0.0, 0.05, 0.0]
    base_pose = refine.model_based_filtering(model, shape, truth.root, mesh, base, model.part_weights,
                                             np.ones(len(mesh)), frame, J)[1]
    for kw in ({"tracker": wrong, "tracker_weight": 1e4}, {"previous": ArmPose(truth.root, truth.angles + 0.3),
                                                           "smooth_weight": 1e4}):
        moved = refine.model_based_filtering(model, shape, truth.root, mesh, base, model.part_weights,
                                             np.ones(len(mesh)), frame, J, **kw)[1]
        assert np.abs(moved.angles - base_pose.angles).max() > 0.01, kw
    far = _no_data_frame(model_case)
    start_off = refine.model_based_filtering(model, shape, truth.root, mesh, base, model.part_weights,
                                             np.ones(len(mesh)), far, J)[1]
    np.testing.assert_allclose(start_off.angles[:2], truth.angles[:2], atol=1e-3)  # the ARAP mesh's pull


def test_refine_surface_sweeps_are_passed_through():
    V, F = _tube()
    bump = np.zeros_like(V)
    ring = slice(4 * 12, 5 * 12)
    bump[ring] = 0.004 * np.c_[np.cos(np.arange(12) * np.pi / 6), np.sin(np.arange(12) * np.pi / 6), np.zeros(12)]
    w = np.zeros(len(V))
    w[ring] = 1.0
    one = refine.refine_surface(V, F, bump, w, iterations=1)
    many = refine.refine_surface(V, F, bump, w, iterations=8)
    assert np.abs(one - many).max() > 1e-6


def test_shape_fit_from_depth_recovers_the_shape_and_a_fixed_shape_stays_fixed(model_case):
    """Depth = the model's mesh of another shape (BMI +1, height +2 cm): the free fit finds that shape and no
    root offset (measured 1e-6); with ``fixed_shape`` the given shape is kept exactly, only the root moves."""
    from bodystudio.muscle.model import ArmShapeParams, model_mesh

    model, shape, J, truth, mesh, sensor = model_case
    target = ArmShapeParams(shape.bmi + 1.0, shape.muscularity, shape.height_m + 0.02, shape.arm_length_m)
    frame = _frame(model_mesh(model, target, truth), model.faces, model.arm_mask, sensor)
    got, root = refine.fit_shape_parameters(model, [mesh], [truth], [frame], initial=shape)
    np.testing.assert_allclose(got.as_vector(), target.as_vector(), atol=1e-4)
    np.testing.assert_allclose(root[:3, 3], 0.0, atol=1e-5)
    kept, root = refine.fit_shape_parameters(model, [mesh], [truth], [frame], initial=shape, fixed_shape=True)
    np.testing.assert_allclose(kept.as_vector(), shape.as_vector(), atol=1e-8)
    assert np.linalg.norm(root[:3, 3]) > 1e-3
    lower = ArmShapeParams(shape.bmi - 1.0, shape.muscularity, shape.height_m - 0.02, shape.arm_length_m)
    frame = _frame(model_mesh(model, lower, truth), model.faces, model.arm_mask, sensor)
    kept, _ = refine.fit_shape_parameters(model, [mesh], [truth], [frame], initial=shape, fixed_shape=True)
    np.testing.assert_allclose(kept.as_vector(), shape.as_vector(), atol=1e-8)  # pulled down: still fixed
    with pytest.raises(InputError, match="^fit_shape_parameters needs at least one registered frame$"):
        refine.fit_shape_parameters(model, [], [], [])


def test_the_arm_length_prior_needs_a_length_and_counts_below_weight_one(model_case):
    model, shape, J, truth, mesh, sensor = model_case
    frame = _frame(mesh, model.faces, model.arm_mask, sensor)
    none, _ = refine.fit_shape_parameters(model, [mesh], [truth], [frame], initial=shape, arm_length_weight=1.0)
    np.testing.assert_allclose(none.as_vector(), shape.as_vector(), atol=1e-4)  # no length given: no prior
    weak, _ = refine.fit_shape_parameters(model, [mesh], [truth], [frame], initial=shape, arm_length=0.4,
                                          arm_length_weight=0.5)
    assert weak.arm_length_m < shape.arm_length_m - 1e-3


def test_shape_bounds_keep_a_low_muscularity_range_below_one():
    from dataclasses import replace

    model = _arm_model()[0]
    subjects = [{"name": n, "shape": {"bmi": 22.0, "muscularity": m, "height_m": 1.75, "arm_length_m": 0.55}}
                for n, m in (("a", 0.1), ("b", 0.2))]
    lo, hi, _ = refine._shape_bounds(replace(model, subjects=subjects), None)
    span = max(0.1, model.param_scale[1])
    assert hi[1] == pytest.approx(min(0.2 + span, 1.0)) and hi[1] < 1.0 and lo[1] == 0.0


def test_plane_pairs_use_the_frames_filters(model_case):
    model, shape, J, truth, mesh, sensor = model_case
    every = refine.DepthFrame(mesh, vertex_normals(mesh, model.faces), cKDTree(mesh), sensor, model.arm_mask,
                              vertex_neighbourhoods(model.faces, len(mesh)),
                              CorrespondenceFilters(arm_only=False, front_only=False, normals=False), model.faces)
    k, _, _ = every.plane_pairs(mesh)
    assert len(k) == len(mesh)  # the data are the mesh: with these filters off every vertex keeps its pair


def test_model_based_filtering_refines_with_its_norm_limit(model_case):
    from bodystudio.muscle.model import model_mesh, model_rest_vertices

    model, shape, J, truth, mesh, sensor = model_case
    frame = _frame(mesh, model.faces, model.arm_mask, sensor)
    base = model_rest_vertices(model, shape)
    ones = np.ones(len(mesh))
    start = refine.model_based_filtering(model, shape, truth.root, mesh, base, model.part_weights, ones, frame, J,
                                         norm_limit=0.0, refine_pose=False)[1]
    want = refine.refine_arm_pose(start, lambda p: model_mesh(model, shape, p, norm_limit=0.0), frame, mesh, J,
                                  model_joints=J)
    got = refine.model_based_filtering(model, shape, truth.root, mesh, base, model.part_weights, ones, frame, J,
                                       norm_limit=0.0)[1]
    np.testing.assert_allclose(got.angles, want.angles, atol=1e-12)


def test_a_fixed_shape_fits_only_the_root_without_a_scipy_warning(model_case):
    """``fixed_shape``: the root alone is solved (the shape bounds x0 +- 1e-9 made scipy warn); the shape is
    returned exactly as given and the planted root offset is found as before (measured to 1e-7 m)."""
    import warnings

    from bodystudio.muscle.model import ArmShapeParams, model_mesh

    model, shape, J, truth, mesh, sensor = model_case
    offset = np.array([-0.005, 0.004, 0.003])
    moved = ArmPose(truth.root.copy(), truth.angles)
    moved.root[:3, 3] += offset
    given = ArmShapeParams(shape.bmi + 15.0, shape.muscularity, shape.height_m, shape.arm_length_m)  # out of range
    frame = _frame(model_mesh(model, given, moved), model.faces, model.arm_mask, sensor)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        got, root = refine.fit_shape_parameters(model, [mesh], [truth], [frame], initial=given, fixed_shape=True,
                                                rounds=3)
    assert got == given
    np.testing.assert_allclose(root[:3, 3], offset, atol=2e-4)
