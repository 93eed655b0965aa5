"""Ground-truth muscle bulges, arm motions and Kinect arm sessions (bodystudio.muscle.synthetic)."""

import numpy as np
import pytest

from bodystudio.errors import InputError
from bodystudio.geometry.mesh import Mesh
from bodystudio.muscle.arm import ArmPose, arm_template, pose_arm
from bodystudio.muscle.synthetic import (
    ArmSubject,
    anatomical_angles,
    arm_angle_sequence,
    arm_pose_from_angles,
    muscle_displacement,
    posed_ground_truth,
    sample_arm_subject,
    session_arm_template,
    subject_body,
    synth_arm_session,
)


@pytest.fixture(scope="module")
def muscular():
    """A lean, very muscular man and his 2k arm."""
    subject = sample_arm_subject(8, gender="male", bmi_range=(22, 23), muscularity_range=(0.95, 1.0))
    body = subject_body(subject, "2k")
    return subject, body, arm_template(body, "left")


def _peak_normal_mm(template, subject, flexion, elevation=45.0, **kw):
    d = muscle_displacement(template, subject, arm_pose_from_angles(template, flexion, elevation), **kw)
    N = Mesh(template.vertices, template.faces).vertex_normals
    return 1000 * (d * N).sum(axis=1).max()


def test_biceps_bulge_in_range_and_grows_with_flexion(muscular):
    subject, _, T = muscular
    peaks = [_peak_normal_mm(T, subject, f) for f in (45, 70, 100, 120, 140)]
    assert 10.0 <= peaks[-1] <= 20.0  # 1-2 cm at full flexion for a muscular arm
    assert np.all(np.diff(peaks) > 0.5)
    assert peaks[0] < 2.0
    # The bulge sits on the anterior upper arm: the biceps, not the forearm or the chest.
    d = muscle_displacement(T, subject, arm_pose_from_angles(T, 140, 45))
    top = np.argmax(np.linalg.norm(d, axis=1))
    assert T.part_weights[top, 1] > 0.5


def test_bulge_scales_with_muscularity_and_fat(muscular):
    subject, _, T = muscular
    base = _peak_normal_mm(T, subject, 140)
    weak = ArmSubject(**{**subject.__dict__, "muscularity": 0.2})
    fat = ArmSubject(**{**subject.__dict__, "bmi": 33.0})
    assert _peak_normal_mm(T, weak, 140) < 0.5 * base
    assert _peak_normal_mm(T, fat, 140) < 0.7 * base


def test_triceps_with_extension_and_deltoid_with_abduction(muscular):
    subject, _, T = muscular
    assert _peak_normal_mm(T, subject, 5) > 3.0 > _peak_normal_mm(T, subject, 60)
    assert _peak_normal_mm(T, subject, 60, elevation=95) > 3.0 + _peak_normal_mm(T, subject, 60, elevation=30)


def test_ground_truth_is_not_linear_in_the_joint_angles(muscular):
    """Non-linear activation: the mid-flexion bulge is not the mean of the two ends (a linear model's)."""
    subject, _, T = muscular
    flexion = np.arange(10.0, 141.0, 10.0)
    D = np.stack([muscle_displacement(T, subject, arm_pose_from_angles(T, f, 45)).ravel() for f in flexion])
    X = np.c_[np.ones_like(flexion), flexion]
    residual = D - X @ np.linalg.lstsq(X, D, rcond=None)[0]
    assert np.sqrt((residual ** 2).sum() / (D ** 2).sum()) > 0.15  # measured 0.24
    d = [D[-1].reshape(-1, 3)]
    # Another person with the same shape parameters bulges differently (per-subject variation).
    other = ArmSubject(**{**subject.__dict__, "seed": subject.seed + 1})
    d_other = muscle_displacement(T, other, arm_pose_from_angles(T, 140, 45))
    assert np.abs(d_other - d[0]).max() > 1e-3


def test_pronation_twists_the_forearm_progressively(muscular):
    subject, body, T = muscular
    ap = arm_pose_from_angles(T, 90, 45, pronation_deg=70)
    assert abs(anatomical_angles(T, ap).pronation_deg - 70) < 1e-6
    _, _, V_gt = posed_ground_truth(body, T, subject, ap)
    V_rigid = pose_arm(T.vertices, T.part_weights, T.joints, ap)
    e, w = T.joints[1], T.joints[2]
    s = (T.vertices - e) @ (w - e) / np.linalg.norm(w - e) ** 2
    fore = T.part_weights[:, 2] > 0.9
    gap = np.linalg.norm(V_gt - V_rigid, axis=1)
    near_elbow, near_wrist = fore & (s > 0.1) & (s < 0.3), fore & (s > 0.85) & (s < 1.0)
    assert gap[near_elbow].mean() > 3 * gap[near_wrist].mean() + 0.005


def test_motions_cover_the_paper_ranges():
    flex = arm_angle_sequence("elbow_flex", 200)
    assert flex[:, 0].min() < 20 and flex[:, 0].max() > 125
    assert flex[:, 1].max() - flex[:, 1].min() > 25  # abduction / adduction alongside
    assert arm_angle_sequence("abduction", 200)[:, 1].max() > 85
    assert np.ptp(arm_angle_sequence("pronation", 200)[:, 2]) > 90
    np.testing.assert_array_equal(arm_angle_sequence("elbow_flex", 50, seed=3), arm_angle_sequence("elbow_flex", 50, 3))
    with pytest.raises(InputError, match="motion"):
        arm_angle_sequence("jump", 10)


def test_out_of_range_subjects_hit_their_ranges():
    s = sample_arm_subject(21, gender="female", bmi_range=(16.0, 18.0))
    assert s.gender == 0.0 and 16.0 <= s.bmi <= 18.1
    tall = sample_arm_subject(22, height_range_m=(1.93, 1.97))
    assert 1.92 <= tall.height_m <= 1.98
    with pytest.raises(InputError, match="range"):
        sample_arm_subject(23, bmi_range=(30, 20))


def test_synth_arm_session_ground_truth_and_depth(tmp_path):
    session = synth_arm_session(tmp_path / "arm", subject_seed=3, n_frames=3, resolution="2k", kinect="v1")
    assert session.camera_names == [] and len(session) == 3
    arm = session.gt_subject["arm"]
    subject = sample_arm_subject(3)
    body = subject_body(subject, "2k")
    T = arm_template(body, "left")
    assert arm["template_key"] == T.key and abs(arm["subject"]["bmi"] - subject.bmi) < 1e-9
    f = session.frame(2)
    ap = ArmPose.from_dict(f.gt_arm_pose)
    d = muscle_displacement(T, subject, ap)
    np.testing.assert_allclose(f.gt_arm_mesh.vertices, pose_arm(T.vertices + d, T.part_weights, T.joints, ap),
                               atol=1e-6)
    np.testing.assert_array_equal(f.gt_arm_mesh.faces, T.faces)
    # The arm is 0.8-1.2 m away and the depth sees it, within Kinect noise.
    cam = session.kinect.depth
    uv, z = cam.project_with_depth(f.gt_arm_mesh.vertices[T.arm_mask])
    assert 0.7 < np.median(z) < 1.3
    depth = f.kinect_depth_m
    px = np.round(uv).astype(int)
    ok = cam.in_image(uv)
    measured = depth[px[ok, 1], px[ok, 0]]
    front = (measured > 0) & (np.abs(measured - z[ok]) < 0.05)
    assert front.sum() > 0.3 * T.arm_mask.sum()
    assert np.median(np.abs(measured[front] - z[ok][front])) < 0.01
    assert session.frame(0).kinect_joints is not None
    rebuilt = session_arm_template(session)
    assert rebuilt.key == T.key and np.abs(rebuilt.vertices - T.vertices).max() < 1e-12


def test_synth_arm_session_is_deterministic_and_refuses_bad_input(tmp_path):
    a = synth_arm_session(tmp_path / "a", subject_seed=4, n_frames=2, resolution="2k", motion="pronation")
    b = synth_arm_session(tmp_path / "b", subject_seed=4, n_frames=2, resolution="2k", motion="pronation")
    assert a.files == b.files
    with pytest.raises(InputError, match="not empty"):
        synth_arm_session(tmp_path / "a", subject_seed=4, n_frames=2, resolution="2k")
    with pytest.raises(InputError, match="distance"):
        synth_arm_session(tmp_path / "c", subject_seed=4, n_frames=2, resolution="2k", distance_m=9.0)
    with pytest.raises(InputError, match="kinect"):
        synth_arm_session(tmp_path / "d", subject_seed=4, n_frames=2, resolution="2k", kinect="v3")
    with pytest.raises(InputError, match="seed"):
        synth_arm_session(tmp_path / "e", subject_seed=-1, n_frames=2, resolution="2k")
    with pytest.raises(InputError, match="frame"):
        synth_arm_session(tmp_path / "f", subject_seed=4, n_frames=0, resolution="2k")
    assert not (tmp_path / "d").exists() and not (tmp_path / "e").exists() and not (tmp_path / "f").exists()
    from bodystudio.capture.synth import synth_session

    studio = synth_session(tmp_path / "studio", n_cameras=1, n_frames=1, resolution=(64, 48), kinect=None,
                           template="2k", n_background=1)
    with pytest.raises(InputError, match="not an arm session"):
        session_arm_template(studio)


def test_right_arm_mirrors_the_left(muscular):
    subject, body, left = muscular
    right = arm_template(body, "right")
    for flexion, elevation, pronation in ((140, 45, 0), (20, 95, 0), (90, 45, 60)):
        peaks = []
        for T in (left, right):
            ap = arm_pose_from_angles(T, flexion, elevation, pronation)
            a = anatomical_angles(T, ap)
            assert abs(a.flexion_deg - flexion) < 1e-6 and abs(a.pronation_deg - pronation) < 1e-6
            peaks.append(np.linalg.norm(posed_ground_truth(body, T, subject, ap)[2]
                                        - pose_arm(T.vertices, T.part_weights, T.joints, ap), axis=1).max())
        assert abs(peaks[0] - peaks[1]) < 0.15 * peaks[0]
