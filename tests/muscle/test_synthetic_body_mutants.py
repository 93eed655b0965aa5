"""Fast tests of the body-building and session functions of bodystudio.muscle.synthetic (issue 17; before, only the
end-to-end tests/muscle/test_synthetic.py reached them, so their mutants counted as "no tests"): the subject's
measured stature and BMI are the ones asked for, the macro solve and its refusal, the subject's body, the posed
ground truth, the sensor placement, and a tiny 2k arm session whose depth frames, tracker joints and ground truth
are recomputed here from the same subject (the depth: the posed truth seen by the Kinect model, exactly).
Small inputs (the 2k body, 1-2 frames); the functions under test are called inside each test, only inputs cached.
"""

import json
from functools import cache
from types import SimpleNamespace

import numpy as np
import pytest

from bodystudio.body import Phenotype, build_body, linear_blend_skinning, skinning_transforms
from bodystudio.errors import InputError
from bodystudio.muscle import synthetic as syn
from bodystudio.muscle.arm import ArmPose, arm_pose_from_body_pose, arm_template, body_pose_from_arm_pose, pose_arm


@cache
def _subject():
    """A population subject (seed 3), its 2k body and left arm template (inputs only)."""
    subject = syn._sample_arm_subject.__wrapped__(3, None, None, None, None)
    body = build_body(subject.phenotype, subject.local, resolution="2k")
    return subject, body, arm_template(body, "left")


@cache
def _phenotype():
    from bodystudio.body.population import sample_subject

    return sample_subject(5)


# --- the subject -------------------------------------------------------------------------------------------------

def test_measure_is_the_arm_shape_measurement_in_order():
    from bodystudio.muscle.model import measure_arm_shape

    phenotype, local = _phenotype()
    m = measure_arm_shape(phenotype, local)
    assert syn._measure(phenotype, local) == (m.bmi, m.height_m, m.arm_length_m)
    assert 1.3 < m.height_m < 2.1 and 14 < m.bmi < 40 and 0.3 < m.arm_length_m < 0.8


@pytest.mark.parametrize("name, index, target", [("height", 1, 1.71), ("weight", 0, 25.0)])
def test_the_macro_solve_hits_its_target_and_changes_only_that_macro(name, index, target):
    phenotype, local = _phenotype()
    solved = syn._solve_macro(phenotype, local, name, target, index)
    got = syn._measure(solved, local)[index]
    # brentq's xtol 1e-4 on the macro: well under 1 mm of stature / 0.02 BMI
    assert abs(got - target) < (5e-4 if index == 1 else 0.02), got
    before, after = phenotype.to_dict(), solved.to_dict()
    assert {k for k in before if before[k] != after[k]} == {name}
    assert 0.0 <= after[name] <= 1.0


def test_an_unreachable_macro_target_is_refused_with_the_body_models_range():
    phenotype, local = _phenotype()
    lo = syn._measure(Phenotype(**{**phenotype.to_dict(), "height": 0.0}), local)[1]
    hi = syn._measure(Phenotype(**{**phenotype.to_dict(), "height": 1.0}), local)[1]
    for target in (hi + 0.05, lo - 0.05):
        with pytest.raises(InputError, match=rf"^height target {target:.3g} is out of the body model's range "
                                             rf"\[{lo:.3g}, {hi:.3g}\] for this subject; choose a range inside it$"):
            syn._solve_macro(phenotype, local, "height", target, 1)
    # the ends of the range are reachable, exactly at the ends too (the macro at 0 / 1)
    assert abs(syn._measure(syn._solve_macro(phenotype, local, "height", hi - 1e-3, 1), local)[1] - (hi - 1e-3)) < 5e-4
    assert syn._solve_macro(phenotype, local, "height", lo, 1).height == 0.0
    assert syn._solve_macro(phenotype, local, "height", hi, 1).height == 1.0


def test_a_subject_has_the_stature_and_bmi_it_was_asked_for():
    """Zero-width ranges: exactly this stature and BMI (the BMI solved after the stature), measured on the body."""
    s = syn._sample_arm_subject.__wrapped__(7, "female", (23.0, 23.0), None, (1.66, 1.66))
    assert s.gender == 0.0 and s.phenotype.gender == 0.0
    bmi, height, arm = syn._measure(s.phenotype, s.local)
    assert (s.bmi, s.height_m, s.arm_length_m) == (bmi, height, arm)
    assert abs(s.bmi - 23.0) < 0.02 and abs(s.height_m - 1.66) < 0.005, (s.bmi, s.height_m)


def test_sample_arm_subject_passes_its_ranges_as_float_pairs(monkeypatch):
    seen = []
    monkeypatch.setattr(syn, "_sample_arm_subject", lambda *a: seen.append(a) or "S")
    assert syn.sample_arm_subject(4.0) == "S"
    assert syn.sample_arm_subject(5, "male", [20, 21], (0, 1), (1, 2)) == "S"
    assert syn.sample_arm_subject(6, muscularity_range=(0.2, 0.2)) == "S"
    assert seen == [(4, None, None, None, None), (5, "male", (20.0, 21.0), (0.0, 1.0), (1.0, 2.0)),
                    (6, None, None, (0.2, 0.2), None)]
    assert all(type(v) is float for v in seen[1][2] + seen[1][3] + seen[1][4]) and type(seen[0][0]) is int
    assert syn.sample_arm_subject(0) == "S"


@pytest.mark.parametrize("kwargs, message", [
    ({"seed": -1}, r"^subject seed -1 must be >= 0$"),
    ({"seed": 1, "bmi_range": (30, 20)}, r"^bmi_range must be \(low, high\) with low <= high, got \(30, 20\)$"),
    ({"seed": 1, "bmi_range": (20, 25, 30)}, r"^bmi_range must be \(low, high\) with low <= high, got \(20, 25, 30\)$"),
    ({"seed": 1, "height_range_m": (1.9, 1.8)}, r"^height_range_m must be \(low, high\)"),
    ({"seed": 1, "muscularity_range": (0.5,)}, r"^muscularity_range must be \(low, high\)"),
    ({"seed": 1, "muscularity_range": (-0.1, 0.5)}, r"^muscularity_range \(-0.1, 0.5\) must lie in \[0, 1\]$"),
    ({"seed": 1, "muscularity_range": (0.5, 1.1)}, r"^muscularity_range \(0.5, 1.1\) must lie in \[0, 1\]$"),
])
def test_sample_arm_subject_refuses_bad_ranges(kwargs, message, monkeypatch):
    monkeypatch.setattr(syn, "_sample_arm_subject", lambda *a: "S")
    with pytest.raises(InputError, match=message):
        syn.sample_arm_subject(**kwargs)


def test_edge_ranges_are_accepted(monkeypatch):
    monkeypatch.setattr(syn, "_sample_arm_subject", lambda *a: "S")
    assert syn.sample_arm_subject(0, muscularity_range=(0.0, 1.0), bmi_range=(22, 22), height_range_m=(1.7, 1.7)) \
        == "S"


def test_summary_and_to_dict():
    s, _, _ = _subject()
    assert s.summary() == {"seed": 3, "gender": s.gender, "bmi": s.bmi, "muscularity": s.muscularity,
                           "height_m": s.height_m, "arm_length_m": s.arm_length_m}
    d = s.to_dict()
    assert d == {**s.summary(), "phenotype": s.phenotype.to_dict(), "local": s.local}
    assert d["local"] is not s.local and json.dumps(d)


def test_subject_body_is_the_subjects_phenotype_at_the_resolution():
    s, body, _ = _subject()
    b = syn.subject_body(s, "2k")
    assert b.n_vertices == body.n_vertices == 2502
    np.testing.assert_array_equal(b.vertices, body.vertices)
    other = build_body(resolution="2k")
    assert np.abs(b.vertices - other.vertices).max() > 0.01  # not the default person
    assert syn.subject_body(s).n_vertices == build_body(s.phenotype, s.local, resolution="6k").n_vertices > 2502


# --- the posed ground truth ----------------------------------------------------------------------------------------

def test_the_posed_truth_is_the_displaced_rest_body_skinned():
    s, body, T = _subject()
    ap = syn.arm_pose_from_angles(T, 100.0, 60.0, 30.0, 10.0)
    v = syn.MuscleVariation.from_seed(11)
    V, pose, V_arm = syn.posed_ground_truth(body, T, s, ap, v)
    d = syn.muscle_displacement(T, s, ap, v)
    assert np.abs(d).max() > 1e-3
    rest = body.vertices.copy()
    rest[T.vertex_ids] += d
    want = linear_blend_skinning(rest, body.weights, skinning_transforms(body.skeleton, pose))
    np.testing.assert_allclose(V, want, atol=1e-12)
    np.testing.assert_array_equal(V_arm, V[T.vertex_ids])
    ref = body_pose_from_arm_pose(body, ap, "left")
    np.testing.assert_allclose(np.asarray(pose.rotations), np.asarray(ref.rotations), atol=1e-12)
    # the arm's truth is the model's arm posing of the displaced template (the session test's identity)
    np.testing.assert_allclose(V_arm, pose_arm(T.vertices + d, T.part_weights, T.joints, ap), atol=1e-6)
    assert np.abs(body.vertices - _subject()[1].vertices).max() == 0.0  # the body is not modified
    # without a variation: the subject seed's own
    V2, _, _ = syn.posed_ground_truth(body, T, s, ap)
    V3, _, _ = syn.posed_ground_truth(body, T, s, ap, syn.MuscleVariation.from_seed(s.seed))
    np.testing.assert_array_equal(V2, V3)


def test_the_posed_truth_at_rest_is_the_rest_body_plus_the_bulge():
    s, body, T = _subject()
    ap = ArmPose.rest()
    V, _, V_arm = syn.posed_ground_truth(body, T, s, ap)
    d = syn.muscle_displacement(T, s, ap)
    np.testing.assert_allclose(V_arm, body.vertices[T.vertex_ids] + d, atol=1e-9)
    others = np.setdiff1d(np.arange(body.n_vertices), T.vertex_ids)
    np.testing.assert_allclose(V[others], body.vertices[others], atol=1e-9)


def test_the_right_arms_truth_uses_the_right_side():
    s, body, _ = _subject()
    T = arm_template(body, "right")
    ap = syn.arm_pose_from_angles(T, 90.0, 40.0)
    V, pose, V_arm = syn.posed_ground_truth(body, T, s, ap)
    ref = body_pose_from_arm_pose(body, ap, "right")
    np.testing.assert_allclose(np.asarray(pose.rotations), np.asarray(ref.rotations), atol=1e-12)
    d = syn.muscle_displacement(T, s, ap)
    np.testing.assert_allclose(V_arm, pose_arm(T.vertices + d, T.part_weights, T.joints, ap), atol=1e-6)


# --- the sensor ----------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("side", ["left", "right"])
def test_the_sensor_looks_at_the_upper_arm_from_the_given_distance_and_yaw(side):
    _, body, _ = _subject()
    T = arm_template(body, side)
    s, e, _ = T.joints
    target = 0.5 * (s + e) + [0.0, 0.0, 0.05]
    sign = 1.0 if side == "left" else -1.0
    for distance, yaw in ((1.0, 25.0), (0.5, 0.0), (4.0, 40.0), (1.3, 25.0)):
        cam = (syn.arm_sensor(T, distance_m=distance, yaw_deg=yaw) if yaw != 25.0
               else syn.arm_sensor(T, "v2", distance)).depth
        off = cam.center - target
        assert abs(np.linalg.norm(off) - distance) < 1e-9
        y = np.deg2rad(yaw)
        np.testing.assert_allclose(off / distance, np.array([sign * np.sin(y), 0.1, np.cos(y)]) / np.sqrt(1.01),
                                   atol=1e-9)
        # looking at the target
        uv = cam.project(target[None])[0]
        np.testing.assert_allclose(uv, cam.K[:2, 2], atol=1e-6)
    default = syn.arm_sensor(T).depth
    assert abs(np.linalg.norm(default.center - target) - 1.0) < 1e-9
    np.testing.assert_allclose((default.center - target)[[0, 2]], np.array([sign * np.sin(np.deg2rad(25.0)),
                                                                             np.cos(np.deg2rad(25.0))]) / np.sqrt(1.01),
                               atol=1e-9)


def test_the_sensor_versions_and_refusals():
    from bodystudio.geometry.camera import kinect_v1, kinect_v2

    _, _, T = _subject()
    v1, v2 = syn.arm_sensor(T, "v1"), syn.arm_sensor(T, "v2")
    s, e, _ = T.joints
    for cam in (v1.depth, v2.depth):  # both look at the middle of the upper arm
        np.testing.assert_allclose(cam.project((0.5 * (s + e) + [0.0, 0.0, 0.05])[None])[0], cam.K[:2, 2], atol=1e-6)
    assert (v1.depth.width, v1.depth.height) == (kinect_v1().depth.width, kinect_v1().depth.height)
    assert (v2.depth.width, v2.depth.height) == (kinect_v2().depth.width, kinect_v2().depth.height)
    assert (v1.depth.width, v1.depth.height) != (v2.depth.width, v2.depth.height)
    np.testing.assert_allclose(v1.depth.center, v2.depth.center, atol=1e-12)
    assert (syn.arm_sensor(T).depth.width, syn.arm_sensor(T).depth.height) == (v2.depth.width, v2.depth.height)
    with pytest.raises(InputError, match=r"^kinect 'v3' is not a Kinect version; valid: v1, v2$"):
        syn.arm_sensor(T, "v3")
    for d in (0.49, 4.01):
        with pytest.raises(InputError, match=rf"^distance_m={d} is outside the Kinect's working range; use 0.8-1.2 m$"):
            syn.arm_sensor(T, distance_m=d)


# --- the session ---------------------------------------------------------------------------------------------------

def _expected_frames(subject, body, T, sensor, motion, n, seed, kinect, noise):
    """Depth, tracker joints and truth of each frame, recomputed with the session's rng order."""
    from bodystudio.body import posed_joints
    from bodystudio.capture.kinect import simulate_kinect_depth, simulate_tracker_joints

    rng = np.random.default_rng([seed, subject.seed, 4242])
    variation = syn.MuscleVariation.from_seed(subject.seed)
    out = []
    for ap in syn.arm_motion(T, motion, n, seed):
        V, pose, V_arm = syn.posed_ground_truth(body, T, subject, ap, variation)
        depth = simulate_kinect_depth(V, body.faces, sensor, rng, noise=noise)
        heads, tails = posed_joints(body.skeleton, pose)
        kw = {} if noise else {"noise_m": 0.0, "bone_length_jitter": 0.0}
        joints, tracked = simulate_tracker_joints(heads, tails, body.skeleton, kinect, rng, **kw)
        out.append(SimpleNamespace(depth=depth, joints=joints, tracked=tracked, V_arm=V_arm, pose=pose,
                                   arm_pose=arm_pose_from_body_pose(body, pose, T.side)))
    return out


def _check_session(session, subject, body, T, motion, n, seed, kinect, distance, noise, resolution="2k"):
    from bodystudio.body.kinect import kinect_joint_names

    sensor = syn.arm_sensor(T, kinect, distance)
    assert session.metadata == {"generator": "bodystudio synth arm", "subject_seed": subject.seed, "motion": motion,
                                "seed": seed, "kinect": kinect, "template": resolution, "side": T.side,
                                "fps": syn.FPS, "distance_m": distance, "arm_template_key": T.key, "noise": noise}
    assert session.source == "synthetic" and session.camera_names == [] and session.frame_ids == list(range(n))
    gt = session.gt_subject
    assert gt["phenotype"] == subject.phenotype.to_dict() and gt["local"] == subject.local
    assert gt["arm"] == {"side": T.side, "resolution": resolution, "template_key": T.key,
                         "subject": subject.summary()}
    assert gt["template"] == resolution and gt["n_vertices"] == body.n_vertices
    assert gt["bone_names"] == list(body.skeleton.bone_names) and gt["rig"] == body.rig
    np.testing.assert_allclose(session.kinect.depth.center, sensor.depth.center, atol=1e-9)
    np.testing.assert_allclose(session.kinect.depth.K, sensor.depth.K, atol=1e-9)
    names = kinect_joint_names(kinect)
    for i, want in enumerate(_expected_frames(subject, body, T, sensor, motion, n, seed, kinect, noise)):
        f = session.frame(i)
        assert (want.depth > 0).sum() > 500  # the arm is in view
        np.testing.assert_allclose(f.kinect_depth_m, want.depth, atol=5.01e-4)  # stored as whole millimetres
        j = f.kinect_joints
        assert j["names"] == list(names) and j["joint_set"] == kinect
        np.testing.assert_allclose(j["positions"], want.joints, atol=1e-6)
        np.testing.assert_array_equal(j["tracked"], want.tracked)
        np.testing.assert_allclose(f.gt_arm_mesh.vertices, want.V_arm, atol=1e-6)
        np.testing.assert_array_equal(f.gt_arm_mesh.faces, T.faces)
        got = ArmPose.from_dict(f.gt_arm_pose)
        np.testing.assert_allclose(got.angles, want.arm_pose.angles, atol=1e-9)
        np.testing.assert_allclose(got.root, want.arm_pose.root, atol=1e-9)
        np.testing.assert_allclose(np.asarray(f.gt_pose.rotations), np.asarray(want.pose.rotations), atol=1e-9)


def test_a_noise_free_session_is_the_posed_truth_seen_by_the_kinect_model(tmp_path):
    s, body, T = _subject()
    session = syn.synth_arm_session(tmp_path / "a", subject=s, motion="abduction", n_frames=2, kinect="v2",
                                    distance_m=1.1, seed=2, resolution="2k", noise=False)
    _check_session(session, s, body, T, "abduction", 2, 2, "v2", 1.1, False)


def test_a_noisy_right_arm_v1_session_replays_the_same_random_draws(tmp_path):
    s, body, _ = _subject()
    T = arm_template(body, "right")
    session = syn.synth_arm_session(tmp_path / "b", subject=s, motion="pronation", n_frames=2, kinect="v1",
                                    seed=1, resolution="2k", side="right")
    _check_session(session, s, body, T, "pronation", 2, 1, "v1", 1.0, True)


def test_the_session_defaults_and_the_subject_seed(tmp_path, monkeypatch):
    """Defaults: elbow_flex, 200 frames (asked of the motion, here cut to 1), Kinect v2 at 1 m, seed 0, the 6k
    body (here the 2k one stands in), left arm, noise; ``subject_seed`` picks the subject."""
    s, body, T = _subject()
    asked = {}
    real_motion = syn.arm_motion
    monkeypatch.setattr(syn, "sample_arm_subject", lambda seed: asked.setdefault("subject", seed) is None or s)
    monkeypatch.setattr(syn, "subject_body", lambda subject, resolution: asked.update(body=(subject, resolution))
                        or body)
    monkeypatch.setattr(syn, "arm_motion", lambda template, motion, n, seed, fps=syn.FPS: asked.update(
        motion=(motion, n, seed, fps)) or real_motion(template, motion, 1, seed, fps))
    session = syn.synth_arm_session(tmp_path / "c", subject_seed=3)
    assert asked == {"subject": 3, "body": (s, "6k"), "motion": ("elbow_flex", 200, 0, 30.0)}
    assert session.metadata == {"generator": "bodystudio synth arm", "subject_seed": 3, "motion": "elbow_flex",
                                "seed": 0, "kinect": "v2", "template": "6k", "side": "left", "fps": syn.FPS,
                                "distance_m": 1.0, "arm_template_key": T.key, "noise": True}
    np.testing.assert_allclose(session.kinect.depth.center, syn.arm_sensor(T).depth.center, atol=1e-9)
    assert session.frame_ids == [0]
    asked.clear()
    syn.synth_arm_session(tmp_path / "c0", n_frames=1)
    assert asked["subject"] == 0
    # with noise the depth differs from the ideal one (and the tracker from the posed joints)
    ideal = _expected_frames(s, body, T, syn.arm_sensor(T), "elbow_flex", 1, 0, "v2", False)[0]
    noisy = _expected_frames(s, body, T, syn.arm_sensor(T), "elbow_flex", 1, 0, "v2", True)[0]
    np.testing.assert_allclose(session.frame(0).kinect_depth_m, noisy.depth, atol=5.01e-4)
    assert np.abs(session.frame(0).kinect_joints["positions"] - ideal.joints).max() > 1e-3


def test_the_session_refusals_write_nothing(tmp_path):
    s, _, _ = _subject()
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "x").write_text("x")
    with pytest.raises(InputError, match=r"^.*full: output folder exists and is not empty; choose a new folder$"):
        syn.synth_arm_session(tmp_path / "full", subject=s, n_frames=1, resolution="2k")
    with pytest.raises(InputError, match=r"^seed -1 must be >= 0$"):
        syn.synth_arm_session(tmp_path / "neg", subject=s, n_frames=1, resolution="2k", seed=-1)
    assert not (tmp_path / "neg").exists()
    (tmp_path / "empty").mkdir()  # an empty folder is fine
    session = syn.synth_arm_session(tmp_path / "empty", subject=s, n_frames=1, resolution="2k", noise=False)
    assert session.frame_ids == [0]


# --- reading an arm session back -----------------------------------------------------------------------------------

def test_session_arm_subject_and_template(tmp_path):
    s, body, T = _subject()
    gt = {"phenotype": s.phenotype.to_dict(), "local": s.local,
          "arm": {"side": "left", "resolution": "2k", "template_key": T.key}}
    session = SimpleNamespace(path="/p", gt_subject=gt)
    assert syn.session_arm_subject(session) is gt["arm"]
    rebuilt = syn.session_arm_template(session)
    assert rebuilt.key == T.key and rebuilt.side == "left"
    np.testing.assert_array_equal(rebuilt.vertices, T.vertices)
    right = syn.session_arm_template(SimpleNamespace(path="/p", gt_subject={**gt, "arm": {**gt["arm"], "side": "right",
                                                                                          "template_key": None}}))
    assert right.side == "right" and right.key == arm_template(body, "right").key
    # without a key nothing is compared; without "local" the population's default body
    plain = syn.session_arm_template(SimpleNamespace(path="/p", gt_subject={
        "phenotype": s.phenotype.to_dict(), "arm": {"side": "left", "resolution": "2k"}}))
    assert plain.key == arm_template(build_body(s.phenotype, {}, resolution="2k"), "left").key


@pytest.mark.parametrize("gt, message", [
    (None, r"^/p: not an arm session \(gt/phenotype.json has no 'arm'\); make one with `bodystudio synth arm`$"),
    ({"phenotype": {}}, r"^/p: not an arm session"),
    ({"arm": {"side": "left", "resolution": "2k"}},
     r"^/p: gt/phenotype.json has no usable subject \('phenotype'\); regenerate the session with `bodystudio synth "
     r"arm`$"),
    ({"arm": {"side": "left"}, "phenotype": {}}, r"^/p: gt/phenotype.json has no usable subject \('resolution'\)"),
    ("KEY", r"^/p: session arm template 2k-left-0-bad differs from the one rebuilt here \(.+\); regenerate the "
            r"session with this bodystudio$"),
])
def test_session_arm_template_refusals(gt, message):
    s, _, _ = _subject()
    if gt == "KEY":
        gt = {"phenotype": s.phenotype.to_dict(), "local": s.local,
              "arm": {"side": "left", "resolution": "2k", "template_key": "2k-left-0-bad"}}
    with pytest.raises(InputError, match=message):
        syn.session_arm_template(SimpleNamespace(path="/p", gt_subject=gt))
    if gt is None or "arm" not in gt:
        with pytest.raises(InputError, match=message):
            syn.session_arm_subject(SimpleNamespace(path="/p", gt_subject=gt))


# --- the training samples ---------------------------------------------------------------------------------------

def test_a_subjects_samples_are_the_base_shapes_then_the_random_poses(tmp_path):
    from bodystudio.muscle.model import ArmShapeParams

    s, body, T = _subject()
    samples = syn.subject_arm_samples(s, "2k", n_shapes=2, n_poses=2, seed=1)
    assert len(samples) == 4 and all(x.subject == "subject_3" for x in samples)
    shape = ArmShapeParams(s.bmi, s.muscularity, s.height_m, s.arm_length_m, sex=s.gender)
    assert all(x.shape == shape for x in samples)
    rng = np.random.default_rng([1, s.seed, 5])
    base = [rng.normal(0, np.deg2rad(2.0), (3, 3)) for _ in range(2)]
    posed = syn.random_arm_poses(T, 2, 1000 + s.seed, pronation=True)
    v = syn.MuscleVariation.from_seed(s.seed)
    for x, want in zip(samples, [ArmPose(np.eye(4), a) for a in base] + posed, strict=True):
        np.testing.assert_allclose(x.pose.angles, want.angles, atol=1e-12)
        np.testing.assert_array_equal(x.pose.root, want.root)
        V = pose_arm(T.vertices + syn.muscle_displacement(T, s, want, v), T.part_weights, T.joints, want)
        np.testing.assert_allclose(x.vertices, V, atol=1e-12)
        np.testing.assert_array_equal(x.joints, T.joints)
        assert x.joints is not T.joints
    assert np.abs(samples[0].pose.angles).max() < np.deg2rad(8.0) < np.abs(samples[2].pose.angles).max()
    right = syn.subject_arm_samples(s, "2k", n_shapes=1, n_poses=0, side="right", name="r")
    Tr = arm_template(body, "right")
    assert len(right) == 1 and right[0].subject == "r"
    np.testing.assert_array_equal(right[0].joints, Tr.joints)
    # the defaults: seed 0, 3 base shapes and 24 poses, the left arm
    d = syn.subject_arm_samples(s, "2k")
    assert len(d) == 27
    rng = np.random.default_rng([0, s.seed, 5])
    np.testing.assert_allclose(d[0].pose.angles, rng.normal(0, np.deg2rad(2.0), (3, 3)), atol=1e-12)
    np.testing.assert_allclose(d[3].pose.angles, syn.random_arm_poses(T, 1, s.seed)[0].angles, atol=1e-12)
    np.testing.assert_array_equal(d[0].joints, T.joints)


def test_subject_arm_samples_default_resolution_is_6k(monkeypatch):
    s, body, _ = _subject()
    asked = []
    monkeypatch.setattr(syn, "subject_body", lambda subject, resolution: asked.append(resolution) or body)
    syn.subject_arm_samples(s, n_shapes=1, n_poses=0)
    assert asked == ["6k"]


def test_the_training_dataset_is_men_in_the_bmi_range_with_their_samples(monkeypatch):
    calls = []
    monkeypatch.setattr(syn, "sample_arm_subject", lambda seed, gender=None, bmi_range=None: calls.append(
        (seed, gender, bmi_range)) or SimpleNamespace(seed=seed))
    monkeypatch.setattr(syn, "subject_arm_samples", lambda subj, *a: [(subj.seed, *a), (subj.seed, "second")])
    samples, subjects = syn.training_dataset("2k", n_subjects=3, n_shapes=2, n_poses=5, seed=2, side="right")
    assert calls == [(1034, "male", (20.0, 28.0)), (1035, "male", (20.0, 28.0)), (1036, "male", (20.0, 28.0))]
    assert [s.seed for s in subjects] == [1034, 1035, 1036]
    assert samples == [x for k in (1034, 1035, 1036) for x in ((k, "2k", 2, 5, 2, "right"), (k, "second"))]
    calls.clear()
    samples, subjects = syn.training_dataset()
    assert [c[0] for c in calls] == list(range(1000, 1010)) and len(subjects) == 10
    assert samples[0] == (1000, "6k", 3, 24, 0, "left")
    assert syn.TRAINING_BMI_RANGE == (20.0, 28.0)


def test_the_session_writer_logs_what_it_wrote(tmp_path, caplog):
    import logging

    s, _, _ = _subject()
    with caplog.at_level(logging.INFO, logger="bodystudio.muscle.synthetic"):
        syn.synth_arm_session(tmp_path / "log", subject=s, n_frames=1, resolution="2k", noise=False,
                              motion="abduction")
    messages = [r.getMessage() for r in caplog.records if r.name == "bodystudio.muscle.synthetic"]
    assert messages[-1] == f"wrote arm session {tmp_path / 'log'}: 1 frames of abduction"
