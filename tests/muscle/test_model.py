"""The statistical arm deformation model: learning, Eq. 12 with the norm limit, files, extension."""

import json

import numpy as np
import pytest

from bodystudio.errors import FileFormatError, InputError
from bodystudio.muscle.arm import ArmPose, arm_template, pose_arm
from bodystudio.muscle.model import (
    ArmSample,
    ArmShapeParams,
    extend_arm_model,
    learn_arm_model,
    limit_displacement_norms,
    load_arm_model,
    model_error_mm,
    model_mesh,
    save_arm_model,
    unpose_arm,
)
from bodystudio.muscle.synthetic import arm_pose_from_angles, sample_arm_subject, subject_arm_samples


def test_unpose_inverts_pose_arm(arm_template_2k):
    T = arm_template_2k
    ap = arm_pose_from_angles(T, 120, 80, 40)
    V = pose_arm(T.vertices, T.part_weights, T.joints, ap)
    np.testing.assert_allclose(unpose_arm(V, T.part_weights, T.joints, ap), T.vertices, atol=1e-9)


def test_model_reproduces_training_meshes(arm_model_2k, arm_training_2k):
    samples, subjects = arm_training_2k
    model = arm_model_2k
    assert [s["name"] for s in model.subjects] == [f"subject_{s.seed}" for s in subjects]
    err = model_error_mm(model, samples, norm_limit=0.0, use_sample_joints=True)
    # Plain skinning of the population mean arm: what the model starts from.
    mean_only = [pose_arm(model.base_vertices + s.joints[0], model.part_weights, s.joints, s.pose) for s in samples]
    start = np.mean([1000 * np.linalg.norm(V - s.vertices, axis=1)[model.arm_mask].mean()
                     for V, s in zip(mean_only, samples, strict=True)])
    assert err["mean_mm"] < 3.3  # measured 2.2
    assert start > 4 * err["mean_mm"]


def test_pose_term_carries_the_bulges_and_norm_limit_moves_toward_skinning(arm_model_2k, arm_training_2k):
    samples, _ = arm_training_2k
    flexed = [s for s in samples if np.abs(s.pose.angles).max() > 0.5]
    e = {nl: model_error_mm(arm_model_2k, flexed, nl, use_sample_joints=True)["mean_mm"] for nl in (0.0, 0.9, 1.0)}
    assert e[0.0] < e[0.9] < e[1.0]
    assert e[1.0] > 2.0 * e[0.0]  # measured 2.2 / 5.2 / 6.2 mm


def test_limit_displacement_norms():
    rng = np.random.default_rng(0)
    d = rng.normal(size=(50, 3))
    n = np.linalg.norm(d, axis=1)
    np.testing.assert_allclose(limit_displacement_norms(d, 0.0), d)
    assert np.abs(limit_displacement_norms(d, 1.0)).max() == 0.0
    lim = np.linalg.norm(limit_displacement_norms(d, 0.9), axis=1)
    np.testing.assert_allclose(lim.max(), 0.1 * n.max())
    small = n <= 0.1 * n.max()
    np.testing.assert_allclose(lim[small], n[small])
    with pytest.raises(InputError, match="norm_limit"):
        limit_displacement_norms(d, 1.5)


def test_save_load_round_trip_and_refusals(arm_model_2k, arm_template_2k, muscular_body_2k, tmp_path):
    path = tmp_path / "arm.npz"
    save_arm_model(path, arm_model_2k)
    loaded = load_arm_model(path, arm_template_2k)
    assert loaded.subjects == arm_model_2k.subjects and loaded.template_key == arm_model_2k.template_key
    subject = sample_arm_subject(1000)
    params = ArmShapeParams(subject.bmi, subject.muscularity, subject.height_m, subject.arm_length_m)
    ap = arm_pose_from_angles(arm_template_2k, 110, 60)
    np.testing.assert_allclose(model_mesh(loaded, params, ap), model_mesh(arm_model_2k, params, ap), atol=1e-12)
    with pytest.raises(InputError, match="template"):
        load_arm_model(path, arm_template(muscular_body_2k, "right"))
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"not a zip file")
    with pytest.raises(FileFormatError, match="junk.npz"):
        load_arm_model(junk)
    with pytest.raises(InputError, match="no such"):
        load_arm_model(tmp_path / "missing.npz")
    # Another format version, and a header without its template key.
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    for header in ({"format": "bodystudio-arm-model", "version": 99}, {"format": "bodystudio-arm-model", "version": 1}):
        bad = tmp_path / "bad.npz"
        np.savez(bad, **{**arrays, "header": np.array(json.dumps(header))})
        with pytest.raises(FileFormatError, match="bad.npz"):
            load_arm_model(bad)


def test_learning_refuses_bad_training_data(arm_template_2k, arm_training_2k):
    samples, _ = arm_training_2k
    posed_only = [s for s in samples if np.abs(s.pose.angles).max() > 0.5][:3]
    with pytest.raises(InputError, match="base pose"):
        learn_arm_model(posed_only, arm_template_2k, population_size=12)
    wrong = [ArmSample("x", samples[0].shape, samples[0].vertices[:-1], ArmPose.rest(), None)]
    with pytest.raises(InputError, match="template"):
        learn_arm_model(wrong, arm_template_2k, population_size=12)
    with pytest.raises(InputError, match="already"):
        extend_arm_model(learn_arm_model(samples[:10], arm_template_2k, population_size=12), samples[:10])


def test_extension_lowers_out_of_range_error(arm_model_2k):
    """Dataset extension (issue §4): adding short / thin subjects helps another short, thin subject."""
    kw = dict(gender="female", bmi_range=(16.0, 18.0), height_range_m=(1.48, 1.56))
    captured = [s for seed in (301, 302) for s in subject_arm_samples(sample_arm_subject(seed, **kw), "2k", 1, 6)]
    test = subject_arm_samples(sample_arm_subject(310, **kw), "2k", 1, 6, seed=3)
    extended = extend_arm_model(arm_model_2k, captured)
    assert len(extended.subjects) == len(arm_model_2k.subjects) + 2
    before = model_error_mm(arm_model_2k, test, 0.0, use_sample_joints=True)["mean_mm"]
    after = model_error_mm(extended, test, 0.0, use_sample_joints=True)["mean_mm"]
    assert after < 0.8 * before  # measured 18.8 -> 11.3 mm
    # The captured subjects' joints also refine the joint regression.
    before = model_error_mm(arm_model_2k, test, 0.0)["mean_mm"]
    after = model_error_mm(extended, test, 0.0)["mean_mm"]
    assert after < 0.85 * before  # measured 27.7 -> 20.3 mm
    # Most of the regressed joints' error is where the shoulder sits, which a root translation absorbs.
    aligned = model_error_mm(extended, test, 0.0, fit_translation=True)["mean_mm"]
    assert aligned < 0.5 * after  # measured 6.5 mm


def test_capture_samples_undo_the_similarity(arm_training_2k):
    from types import SimpleNamespace

    from bodystudio.muscle.model import capture_samples

    samples, _ = arm_training_2k
    R = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    s, t = 1.05, np.array([0.1, -0.2, 0.3])
    frames = np.stack([s * x.vertices @ R.T + t for x in samples[:4]])
    capture = SimpleNamespace(vertices=frames, poses=[x.pose for x in samples[:3]] + [None],
                              shape=samples[0].shape, similarity=(s, R, t))
    out = capture_samples(capture, "cap", stride=1)
    assert len(out) == 3 and all(o.subject == "cap" and o.shape == samples[0].shape for o in out)
    np.testing.assert_allclose(out[1].vertices, samples[1].vertices, atol=1e-12)
    assert len(capture_samples(capture, "cap", stride=2)) == 2
    with pytest.raises(InputError, match="shape"):
        capture_samples(SimpleNamespace(**{**capture.__dict__, "shape": None}), "cap")
    with pytest.raises(InputError, match="joint angles"):
        capture_samples(SimpleNamespace(**{**capture.__dict__, "poses": [None] * 4}), "cap")


def test_tikhonov_least_squares_shrinks_slopes_not_the_intercept():
    from bodystudio.muscle.model import tikhonov_least_squares

    rng = np.random.default_rng(1)
    Z = rng.normal(size=(30, 3))
    X = np.c_[np.ones(30), Z]
    W_true = np.array([[5.0], [1.0], [-2.0], [0.5]])
    Y = X @ W_true + rng.normal(0, 0.01, (30, 1))
    np.testing.assert_allclose(tikhonov_least_squares(X, Y, 0.0), np.linalg.lstsq(X, Y, rcond=None)[0], atol=1e-10)
    W = tikhonov_least_squares(X, Y, 10.0)
    # The closed form of Eq. 9's penalty on the slopes only.
    P = np.diag([0.0, 100.0, 100.0, 100.0])
    np.testing.assert_allclose(W, np.linalg.solve(X.T @ X + P, X.T @ Y), atol=1e-12)
    assert np.abs(W[1:]).sum() < 0.9 * np.abs(W_true[1:]).sum()
    assert abs(W[0, 0] - 5.0) < 0.3
