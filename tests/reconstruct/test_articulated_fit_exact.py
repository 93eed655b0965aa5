"""The hull fit's Gauss-Newton loops (:mod:`bodystudio.reconstruct.articulated_fit`, Rapid Skin Sec. IV) on exact
data: the "hull" is the 2k template's own surface in a known pose (no voxels, no carving), so the fit must find that
pose from a start 7 cm (joints) away, to a fraction of a millimetre. Behaviour, not implementation: the recovered
joints, scale and surface, the step clamps (a step never longer than ``max_step_*``), the stop rule, the prior's
pull towards the start, the unfitted bones kept; ``refine_bone_transforms`` (the same step on the Eq. 11 bone
transforms) likewise. Each fit ~0.5-1 s; the carved-hull fits on rendered sessions are
tests/reconstruct/test_articulated_fit.py.
"""

from types import SimpleNamespace

import igl
import numpy as np
import pytest

from bodystudio.body.kinect import kinect_joints
from bodystudio.body.pose import Pose
from bodystudio.body.skinning import forward_kinematics, posed_joints
from bodystudio.errors import InputError
from bodystudio.reconstruct import articulated_fit as af
from bodystudio.reconstruct.pose_init import pose_template

TRUE = {"Root": [0.0, 0.2, 0.0], "spine_02": [0.05, 0.0, 0.03], "upperarm_l": [0.1, 0.2, 0.3],
        "lowerarm_r": [0.0, 0.3, 0.3], "thigh_l": [0.2, 0.0, 0.0], "calf_r": [0.3, 0.0, 0.0],
        "neck_01": [0.1, 0.0, 0.0], "hand_l": [0.0, 0.0, 0.4]}  # hand_l: not a fitted bone, its rotation is the start's


@pytest.fixture(scope="module")
def case():
    from bodystudio.body import build_body

    body = build_body(resolution="2k")
    skel = body.skeleton
    rot = np.zeros((skel.n_bones, 3))
    for k, v in TRUE.items():
        rot[skel.index(k)] = v
    true = Pose(rot, [0.1, 0.05, -0.2])
    V, _ = body.pose(true)
    fitted = np.isin(np.arange(skel.n_bones), af._fit_bone_indices(skel))[:, None]
    noise = np.random.default_rng(0).normal(scale=0.08, size=rot.shape)
    init = Pose(rot + np.where(fitted, noise, 0.0), true.translation + [0.03, -0.02, 0.02])
    h, t = posed_joints(skel, true)
    return SimpleNamespace(body=body, skel=skel, true=true, V=V, init=init,
                           joints=kinect_joints(skel, h, t, "v2"))


def _hull(body, V):
    """The surface ``V`` as a hull: its vertices, faces, outward normals and centroid."""
    return SimpleNamespace(vertices=V, faces=body.faces, normals=igl.per_vertex_normals(V, body.faces),
                           centroid=V.mean(axis=0))


def _joints(case, pose, scale=1.0):
    h, t = posed_joints(case.skel, pose)
    return scale * kinect_joints(case.skel, h, t, "v2")


def test_two_gauss_newton_steps_already_remove_nine_tenths_of_the_error(case):
    """Gauss-Newton on exact data converges fast: two steps leave 6.5 % of the start's joint error (one: 25 %), the
    refinement of the bone transforms 8.9 % of the surface error."""
    start = af.joint_error_m(_joints(case, case.init), case.joints)
    fit = af.articulated_fit(case.body, _hull(case.body, case.V), case.init, iterations=2)
    assert af.joint_error_m(fit.joints, case.joints) < 0.1 * start and abs(fit.scale - 1.0) < 0.002
    T0 = _transforms(case, case.init)
    T = af.refine_bone_transforms(case.body, T0, _hull(case.body, case.V), af.PoseRefineParams(iterations=2))
    assert _surface_error(case, T) < 0.12 * _surface_error(case, T0)


def test_the_fit_finds_the_pose_of_an_exact_hull(case):
    start = af.joint_error_m(_joints(case, case.init), case.joints)
    assert start > 0.06
    fit = af.articulated_fit(case.body, _hull(case.body, case.V), case.init)
    err = af.joint_error_m(fit.joints, case.joints)
    assert err < 0.0015 and err < 0.03 * start  # measured 0.69 mm from 73 mm
    assert fit.converged and 3 <= fit.iterations < 40
    assert fit.fit_error_m < 0.001  # 0.36 mm
    assert abs(fit.scale - 1.0) < 0.001
    np.testing.assert_allclose(fit.pose.translation, case.true.translation, atol=0.005)
    # the joints are those of the template scaled by ``scale`` in the returned pose
    h, t = posed_joints(af.scaled_body(case.body, fit.scale).skeleton, fit.pose)
    np.testing.assert_allclose(fit.joints, kinect_joints(case.skel, h, t, "v2"), atol=1e-9)
    # the error is the symmetric surface distance of the fitted template
    V, _ = af.scaled_body(case.body, fit.scale).pose(fit.pose)
    assert fit.fit_error_m == pytest.approx(af.symmetric_hull_distance(V, case.body.faces,
                                                                       _hull(case.body, case.V)), rel=1e-9)
    # unfitted bones keep the start's rotation
    hand = case.skel.index("hand_l")
    np.testing.assert_array_equal(fit.pose.rotations[hand], case.init.rotations[hand])
    unfitted = ~np.isin(np.arange(case.skel.n_bones), af._fit_bone_indices(case.skel))
    np.testing.assert_array_equal(fit.pose.rotations[unfitted], case.init.rotations[unfitted])


def test_the_fit_finds_the_scale_of_a_larger_subject(case):
    """The hull 8 % larger (about the origin): the template scale comes out 1.08 and the returned pose poses the
    template scaled by it onto the hull."""
    hull = _hull(case.body, case.V * 1.08)
    fit = af.articulated_fit(case.body, hull, case.init)
    assert fit.scale == pytest.approx(1.08, abs=0.002)
    assert af.joint_error_m(fit.joints, case.joints * 1.08) < 0.0015
    V, _ = af.scaled_body(case.body, fit.scale).pose(fit.pose)
    assert np.linalg.norm(V - case.V * 1.08, axis=1).mean() < 0.0015  # 1.07 mm
    np.testing.assert_allclose(fit.pose.translation, case.true.translation * 1.08, atol=0.005)
    # started from a scale: the pose given poses the template at that scale
    start = Pose(case.true.rotations, case.true.translation * 1.05)
    fit = af.articulated_fit(case.body, hull, start, scale=1.05)
    assert fit.scale == pytest.approx(1.08, abs=0.002) and af.joint_error_m(fit.joints, case.joints * 1.08) < 0.0015
    # without fit_scale the scale stays and the fit cannot explain the hull
    fixed = af.articulated_fit(case.body, hull, case.init, af.ArticulatedFitParams(fit_scale=False))
    assert fixed.scale == 1.0 and fixed.fit_error_m > 0.005


def test_steps_are_clamped(case):
    """From the true pose, an 8 % larger hull: the first step is the log-scale clamp, exactly exp(0.03); from the
    perturbed start, three steps move the root by at most 3 x max_step_m and a bone by at most 3 x max_step_rad."""
    fit = af.articulated_fit(case.body, _hull(case.body, case.V * 1.08), case.true, iterations=1)
    assert fit.scale == pytest.approx(np.exp(0.03), rel=1e-12) and fit.iterations == 1 and not fit.converged
    fit = af.articulated_fit(case.body, _hull(case.body, case.V * 1.08), case.true,
                             af.ArticulatedFitParams(max_step_log_scale=0.01), iterations=2)
    assert fit.scale == pytest.approx(np.exp(0.02), rel=1e-12)
    hull = _hull(case.body, case.V)
    fit = af.articulated_fit(case.body, hull, case.init, af.ArticulatedFitParams(max_step_m=0.001), iterations=3)
    moved = np.linalg.norm(fit.pose.translation - case.init.translation)
    assert 0.002 < moved <= 0.003 + 1e-9
    fit = af.articulated_fit(case.body, hull, case.init, af.ArticulatedFitParams(max_step_rad=0.004), iterations=3)
    turned = np.linalg.norm(fit.pose.rotations - case.init.rotations, axis=1).max()
    assert 0.008 < turned <= 0.012 + 1e-6


def test_the_stop_rule_and_the_iteration_counts(case):
    hull = _hull(case.body, case.V)
    fit = af.articulated_fit(case.body, hull, case.init, af.ArticulatedFitParams(tolerance=0.0, iterations=12))
    assert fit.iterations == 12 and not fit.converged
    fit = af.articulated_fit(case.body, hull, case.init, af.ArticulatedFitParams(iterations=3))
    assert fit.iterations == 3 and not fit.converged
    fit = af.articulated_fit(case.body, hull, case.init, af.ArticulatedFitParams(iterations=3), iterations=5)
    assert fit.iterations == 5
    # a loose tolerance stops early
    fit = af.articulated_fit(case.body, hull, case.init, af.ArticulatedFitParams(tolerance=0.01))
    assert fit.converged and fit.iterations < 10


def test_the_prior_holds_the_limbs_to_the_start(case):
    """A strong prior keeps the joints near the start (40 mm of its 73); without one the exact data are met to
    0.05 mm."""
    hull = _hull(case.body, case.V)
    held = af.articulated_fit(case.body, hull, case.init, af.ArticulatedFitParams(prior_weight=1e3))
    assert af.joint_error_m(held.joints, case.joints) > 0.025
    free = af.articulated_fit(case.body, hull, case.init, af.ArticulatedFitParams(prior_weight=0.0))
    assert af.joint_error_m(free.joints, case.joints) < 0.0003


def test_fit_body_to_hull_from_the_a_pose_on_exact_data(case):
    """No start: the yaw and arm hypotheses from the A-pose at the hull find the pose (a mild one)."""
    rot = np.zeros((case.skel.n_bones, 3))
    rot[case.skel.index("lowerarm_l")] = [0.0, 0.0, 0.3]
    rot[case.skel.index("upperarm_r")] = [0.0, 0.0, 0.2]
    pose = Pose(rot, [0.0, 0.02, 0.1])
    V, _ = case.body.pose(pose)
    params = af.ArticulatedFitParams(iterations=20, coarse_iterations=6, arm_raise_candidates_deg=(45.0,),
                                     yaw_candidates_deg=(180.0, 0.0))
    fit = af.fit_body_to_hull(case.body, _hull(case.body, V), params=params)
    assert af.joint_error_m(fit.joints, _joints(case, pose)) < 0.005


# --- refine_bone_transforms on exact data ---------------------------------------------------------------------------

def _transforms(case, pose):
    return forward_kinematics(case.skel, pose) @ np.linalg.inv(case.skel.rest_frames)


def _surface_error(case, T):
    return float(np.linalg.norm(pose_template(case.body, T).vertices - case.V, axis=1).mean())


def test_refine_bone_transforms_fits_the_exact_hull(case):
    T0 = _transforms(case, case.init)
    start = _surface_error(case, T0)
    assert start > 0.07
    T = af.refine_bone_transforms(case.body, T0, _hull(case.body, case.V))
    assert _surface_error(case, T) < 0.003 and _surface_error(case, T) < 0.04 * start  # 1.8 mm from 81 mm
    np.testing.assert_array_equal(T0, _transforms(case, case.init))  # the input is left alone
    # the bones keep their lengths: each transform stays a rotation plus a translation
    np.testing.assert_allclose(np.einsum("bji,bjk->bik", T[:, :3, :3], T[:, :3, :3]),
                               np.tile(np.eye(3), (len(T), 1, 1)), atol=1e-9)
    # no iteration: the start, as a copy
    T1 = af.refine_bone_transforms(case.body, T0, _hull(case.body, case.V), af.PoseRefineParams(iterations=0))
    np.testing.assert_array_equal(T1, T0)
    assert T1 is not T0


def test_refine_prior_tolerance_and_anchors(case):
    T0 = _transforms(case, case.init)
    hull = _hull(case.body, case.V)
    held = af.refine_bone_transforms(case.body, T0, hull, af.PoseRefineParams(prior_weight=1e4))
    free = af.refine_bone_transforms(case.body, T0, hull, af.PoseRefineParams(prior_weight=0.0))
    assert _surface_error(case, held) > 2 * _surface_error(case, free)
    assert _surface_error(case, free) < 0.003
    # a step clamp: one iteration moves the root by at most max_step_m
    one = af.refine_bone_transforms(case.body, T0, hull, af.PoseRefineParams(iterations=1, max_step_m=0.002))
    root = case.skel.index("Root")
    assert np.linalg.norm(one[root, :3, 3] - T0[root, :3, 3]) <= 0.002 + 1e-9
    # pelvis anchors at the true pelvis joints pull the pelvis there even with a weak data term
    T_true = _transforms(case, case.true)
    anchors = af.pelvis_anchors(case.body, T_true, weight=1e6)
    pel = anchors[0]
    fit = af.refine_bone_transforms(case.body, T0, hull, af.PoseRefineParams(iterations=10), anchors=anchors)
    X = np.einsum("mij,mj->mi", fit[pel, :3, :3], anchors[1]) + fit[pel, :3, 3]
    X0 = np.einsum("mij,mj->mi", T0[pel, :3, :3], anchors[1]) + T0[pel, :3, 3]
    assert np.abs(X - anchors[2]).max() < 0.1 * np.abs(X0 - anchors[2]).max()
    with pytest.raises(InputError, match=r"^pose refinement: the template has no bone\(s\) tail_01$"):
        af.refine_bone_transforms(case.body, T0, hull, af.PoseRefineParams(bones=("pelvis", "tail_01")))


def test_refine_prior_holds_a_leg_to_the_pelvis(case):
    """Only the left thigh off by 0.3 rad (its refined parent is the root segment, the pelvis): a strong prior keeps
    it there (40 mm surface error from 31 mm), none lets the exact data set it (0.14 mm)."""
    rot = case.true.rotations.copy()
    rot[case.skel.index("thigh_l")] += [0.3, 0.0, 0.0]
    T0 = _transforms(case, Pose(rot, case.true.translation))
    start = _surface_error(case, T0)
    hull = _hull(case.body, case.V)
    held = af.refine_bone_transforms(case.body, T0, hull, af.PoseRefineParams(prior_weight=1e4))
    free = af.refine_bone_transforms(case.body, T0, hull, af.PoseRefineParams(prior_weight=0.0))
    assert _surface_error(case, held) > 0.5 * start and _surface_error(case, free) < 0.1 * start


def test_refine_damping_rotation_clamp_and_a_translation_already_right(case):
    """Heavy Levenberg damping (1e3 x the mean diagonal) keeps three steps near the start (98 %), none converges
    (4 %); with a loose translation limit the rotation clamp holds the root segment's first turn to max_step_rad;
    with the translation already right, a loose tolerance does not stop the rotations after one step (9 % left
    against 24 %); missing bones are named."""
    from scipy.spatial.transform import Rotation

    hull = _hull(case.body, case.V)
    T0 = _transforms(case, case.init)
    start = _surface_error(case, T0)
    heavy = af.refine_bone_transforms(case.body, T0, hull, af.PoseRefineParams(iterations=3, damping=1e3))
    none = af.refine_bone_transforms(case.body, T0, hull, af.PoseRefineParams(iterations=3, damping=0.0))
    assert _surface_error(case, heavy) > 0.9 * start and _surface_error(case, none) < 0.1 * start
    one = af.refine_bone_transforms(case.body, T0, hull, af.PoseRefineParams(iterations=1, max_step_m=1.0,
                                                                             max_step_rad=0.01))
    turned = Rotation.from_matrix(one[:, :3, :3] @ T0[:, :3, :3].transpose(0, 2, 1)).magnitude()
    assert turned[case.skel.index("pelvis")] <= 0.01 + 1e-9 and 0.005 < turned.max() < 0.05
    Ti = _transforms(case, Pose(case.init.rotations, case.true.translation))
    loose = af.refine_bone_transforms(case.body, Ti, hull, af.PoseRefineParams(tolerance=0.01))
    assert _surface_error(case, loose) < 0.15 * _surface_error(case, Ti)
    with pytest.raises(InputError, match=r"^pose refinement: the template has no bone\(s\) tail_01, wing_l$"):
        af.refine_bone_transforms(case.body, T0, hull, af.PoseRefineParams(bones=("pelvis", "tail_01", "wing_l")))


def test_refined_segments_stay_joined(case):
    """Each segment turns about its placed head with its subtree (leaves first, so an ancestor's turn does not move a
    head before its own turn about it): after refining, every bone's head placed by its own transform is where its
    parent's transform puts that point, as in the start (to 1e-9 m)."""
    sk = case.skel
    T = af.refine_bone_transforms(case.body, _transforms(case, case.init), _hull(case.body, case.V),
                                  af.PoseRefineParams(iterations=3))
    for b in range(sk.n_bones):
        p = sk.parents[b]
        if p >= 0:
            own = T[b, :3, :3] @ sk.heads[b] + T[b, :3, 3]
            np.testing.assert_allclose(own, T[p, :3, :3] @ sk.heads[b] + T[p, :3, 3], atol=1e-9)


def test_a_scaled_start_a_free_root_and_a_loose_tolerance(case):
    """The start's translation is the scaled template's (from the truth at scale 1.05, one step is exact); the
    translation clamp is a world distance at any scale; the prior leaves the root free (a 0.3 rad yaw corrected under
    a strong prior); with the translation already right a loose tolerance still lets the rotations converge (8 %
    left, one step: 23 %)."""
    hull = _hull(case.body, case.V * 1.05)
    fit = af.articulated_fit(case.body, hull, Pose(case.true.rotations, case.true.translation * 1.05), iterations=1,
                             scale=1.05)
    assert af.joint_error_m(fit.joints, case.joints * 1.05) < 1e-6
    start = Pose(case.init.rotations, case.init.translation * 1.5)
    fit = af.articulated_fit(case.body, _hull(case.body, case.V * 1.5), start,
                             af.ArticulatedFitParams(max_step_m=0.001), iterations=3, scale=1.5)
    assert 0.002 < np.linalg.norm(fit.pose.translation - start.translation) <= 0.003 + 1e-9
    hull = _hull(case.body, case.V)
    rot = case.true.rotations.copy()
    rot[case.skel.index("Root")] += [0.0, 0.3, 0.0]
    fit = af.articulated_fit(case.body, hull, Pose(rot, case.true.translation),
                             af.ArticulatedFitParams(prior_weight=1e3))
    assert af.joint_error_m(fit.joints, case.joints) < 1e-4
    init = Pose(case.init.rotations, case.true.translation)
    fit = af.articulated_fit(case.body, hull, init, af.ArticulatedFitParams(tolerance=0.01))
    assert af.joint_error_m(fit.joints, case.joints) < 0.15 * af.joint_error_m(_joints(case, init), case.joints)


def test_template_points_inside_the_hull_count_less(case):
    """A hull that bulges 2 cm above the left arm (a superset of the body, as a carved hull is): the hull -> template
    term lifts the arm towards the bulge, the template points inside the hull resist it with ``inside_weight``; the
    elbow rises 12.6 / 12.4 / 12.2 mm with inside weights 0 / 0.5 / 1."""
    from bodystudio.body.kinect import kinect_joint_names

    sk = case.skel
    N = igl.per_vertex_normals(case.V, case.body.faces)
    arm = case.body.weights[:, [sk.index("upperarm_l"), sk.index("lowerarm_l")]].sum(axis=1) > 0.5
    Vh = case.V + 0.02 * (arm & (N[:, 1] > 0.3))[:, None] * N
    hull = _hull(case.body, Vh)
    elbow = kinect_joint_names("v2").index("ElbowLeft")
    lift = [af.articulated_fit(case.body, hull, case.true, af.ArticulatedFitParams(inside_weight=w, fit_scale=False))
            .joints[elbow, 1] - case.joints[elbow, 1] for w in (0.0, 0.5, 1.0)]
    assert 0.005 < lift[2] and lift[0] < 0.02
    assert lift[0] - lift[1] > 0.0001 and lift[1] - lift[2] > 0.0001


def test_hull_samples_is_how_many_hull_points_are_matched(case, monkeypatch):
    """``hull_samples``: every k-th hull surface point (from the first) is matched to the template, k the hull's size
    over ``hull_samples`` (at least 1): 2502 points -> all for 3000, every 5th (501) for 500, 2 for 2, 1 for 1 or 0."""
    from scipy.spatial import cKDTree

    queried = []

    class Tree(cKDTree):
        def query(self, x, *a, **k):
            queried.append(np.array(x, copy=True))
            return super().query(x, *a, **k)

    monkeypatch.setattr(af, "cKDTree", Tree)
    hull = _hull(case.body, case.V)
    n = len(case.V)
    for samples, want in ((3000, np.arange(n)), (500, np.arange(0, n, 5)), (2, np.array([0, n // 2])),
                          (1, np.array([0])), (0, np.array([0]))):
        queried.clear()
        af.articulated_fit(case.body, hull, case.init, af.ArticulatedFitParams(hull_samples=samples), iterations=1)
        # per iteration: template -> hull (the template's points), then hull -> template (the sampled hull points)
        assert len(queried) == 2 and len(queried[0]) == n
        np.testing.assert_array_equal(queried[1], case.V[want])


def test_refine_prior_leaves_the_root_segment_free(case):
    """The prior holds each segment relative to its refined parent; the root segment (the pelvis) has none: the
    whole body turned at the pelvis by 0.22 rad is corrected even under a strong prior (45 mm -> 0.03 mm)."""
    rot = case.true.rotations.copy()
    rot[case.skel.index("pelvis")] += [0.0, 0.2, 0.1]
    T0 = _transforms(case, Pose(rot, case.true.translation))
    T = af.refine_bone_transforms(case.body, T0, _hull(case.body, case.V), af.PoseRefineParams(prior_weight=1e4))
    assert _surface_error(case, T0) > 0.03 and _surface_error(case, T) < 0.001
