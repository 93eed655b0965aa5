"""Fast tests of the dataset-extension code added since muscle/model.py's mutation row (issue 17,
docs/mutation/muscle-model.md): ``unposed_sample`` (unposed about the sample's skeleton, centred on its
``rest_origin``), a captured sequence's one shape row (the frames' mean minus the prior's pose term) in
``_subject_rows``, and ``capture_samples``' ``centre`` (fitted / regressed / by sex). Stand-ins for the model's
joint regression and pose term, so each number is known in closed form.
"""

from types import SimpleNamespace

import numpy as np
import pytest

from bodystudio.errors import InputError
from bodystudio.muscle import model as M
from bodystudio.muscle.arm import ArmPose
from bodystudio.muscle.model import unpose_arm

SHAPE = M.ArmShapeParams(24.0, 0.5, 1.78, 0.52)  # a man (sex 1)
WOMAN = M.ArmShapeParams(21.0, 0.4, 1.62, 0.48, sex=0.0)
J_FIT = np.array([[0.10, 1.40, 0.00], [0.40, 1.38, 0.01], [0.65, 1.37, 0.02]])


def _arm(n=12, seed=0):
    """A small arm: vertices along x from the shoulder to past the wrist and part weights blending at the elbow."""
    rng = np.random.default_rng(seed)
    x = np.linspace(0.08, 0.7, n)
    V = np.c_[x, 1.39 + 0.02 * rng.normal(size=n), 0.02 * rng.normal(size=n)]
    up = np.clip((0.45 - x) / 0.1, 0.0, 1.0)
    W = np.c_[np.zeros(n), up, 1.0 - up, np.zeros(n)]  # torso, upper arm, forearm, hand
    return V, W


def _pose(seed):
    return ArmPose(np.eye(4), np.random.default_rng(seed).normal(0.0, 0.4, (3, 3)))


def test_unposed_sample_uses_the_samples_skeleton_and_centres_on_its_shoulder():
    V, W = _arm()
    pose = _pose(1)
    s = M.ArmSample("a", SHAPE, V, pose, J_FIT)
    asked = []
    got = M.unposed_sample(s, W, lambda shape: asked.append(shape) or J_FIT + 1.0)
    np.testing.assert_allclose(got, unpose_arm(V, W, J_FIT, pose) - J_FIT[0], atol=1e-15)
    assert asked == []  # its own joints: the regression is not asked


def test_unposed_sample_without_joints_uses_the_regression():
    V, W = _arm()
    pose = _pose(2)
    J_reg = J_FIT + np.array([0.01, -0.02, 0.005])
    asked = []
    s = M.ArmSample("a", SHAPE, V, pose)
    got = M.unposed_sample(s, W, lambda shape: asked.append(shape) or J_reg)
    np.testing.assert_allclose(got, unpose_arm(V, W, J_reg, pose) - J_reg[0], atol=1e-15)
    assert asked == [SHAPE]


@pytest.mark.parametrize("origin", [[0.2, 1.3, 0.1], np.array([[0.2, 1.3, 0.1]])])
def test_unposed_sample_centres_on_the_rest_origin_when_given(origin):
    V, W = _arm()
    pose = _pose(3)
    s = M.ArmSample("a", SHAPE, V, pose, J_FIT, origin)
    got = M.unposed_sample(s, W, lambda shape: None)
    np.testing.assert_allclose(got, unpose_arm(V, W, J_FIT, pose) - np.array([0.2, 1.3, 0.1]), atol=1e-15)
    assert got.dtype == np.float64


def test_a_captured_sequence_is_one_shape_row_the_frames_mean_minus_the_prior_pose_term(monkeypatch):
    """No frame in the base pose, a prior: the subject's base rows are ONE row, the mean over frames of
    (unposed frame - the prior's pose term of its angles); the pose rows are the unposed frames minus it."""
    V, W = _arm()
    poses = [_pose(10 + k) for k in range(3)]
    samples = [M.ArmSample("cap", SHAPE, V + 0.01 * k, p, J_FIT) for k, p in enumerate(poses)]
    term = {}

    def pose_term(prior, a):
        assert prior == "PRIOR"
        term[tuple(np.round(a, 12))] = d = np.outer(np.arange(len(V)), a[:3]) * 1e-3
        return d

    monkeypatch.setattr(M, "pose_displacements", pose_term)
    rows, base, angles, pose_rows = M._subject_rows(samples, W, lambda shape: None, "PRIOR")
    unposed = np.stack([M.unposed_sample(s, W, None) for s in samples])
    want = np.mean([u - term[tuple(np.round(p.angles.reshape(9), 12))] for u, p in zip(unposed, poses, strict=True)],
                   axis=0)
    assert rows.shape == (1, len(V), 3)
    np.testing.assert_allclose(rows[0], want, atol=1e-15)
    np.testing.assert_allclose(base, want, atol=1e-15)
    np.testing.assert_array_equal(angles, np.stack([p.angles.reshape(9) for p in poses]))
    np.testing.assert_allclose(pose_rows, unposed - want, atol=1e-15)


def test_base_pose_frames_are_the_rows_and_without_them_or_a_prior_the_subject_is_refused():
    V, W = _arm()
    near = ArmPose(np.eye(4), np.full((3, 3), np.deg2rad(7.9)))
    far = _pose(4)
    samples = [M.ArmSample("s", SHAPE, V, near, J_FIT), M.ArmSample("s", SHAPE, V + 0.01, far, J_FIT),
               M.ArmSample("s", SHAPE, V + 0.02, ArmPose.rest(), J_FIT)]
    rows, base, _, _ = M._subject_rows(samples, W, None, "PRIOR")
    assert rows.shape == (2, len(V), 3)
    np.testing.assert_allclose(base, 0.5 * (M.unposed_sample(samples[0], W, None)
                                            + M.unposed_sample(samples[2], W, None)), atol=1e-15)
    with pytest.raises(InputError, match=r"^subject 's' has no mesh in the base pose \(all joint angles < 8 deg\); "
                                         r"add one or extend an existing model$"):
        M._subject_rows(samples[1:2], W, None, None)


def _capture(shape=SHAPE, joints=J_FIT, n=2):
    V, _ = _arm()
    return SimpleNamespace(vertices=[V + 0.01 * k for k in range(n)], poses=[_pose(20 + k) for k in range(n)],
                           shape=shape, similarity=(1.0, np.eye(3), np.zeros(3)), joints=joints)


def test_capture_samples_centre_fitted_regressed_and_by_sex(monkeypatch):
    asked = []
    monkeypatch.setattr(M, "model_joints", lambda model, shape: asked.append((model, shape)) or J_FIT + 0.5)
    cap = _capture()
    fitted = M.capture_samples(cap, "c")
    assert all(s.rest_origin is None for s in fitted) and asked == []
    assert all(s.rest_origin is None for s in M.capture_samples(cap, "c", centre="fitted", model="MODEL"))
    regressed = M.capture_samples(cap, "c", model="MODEL", centre="regressed")
    assert asked == [("MODEL", SHAPE)] and len(regressed) == 2
    for s in regressed:
        np.testing.assert_array_equal(s.rest_origin, J_FIT[0] + 0.5)
        np.testing.assert_array_equal(s.joints, J_FIT)
    # the regression of the capture's own shape, not the shape the samples are given
    M.capture_samples(cap, "c", shape=WOMAN, model="MODEL", centre="regressed")
    assert asked[-1] == ("MODEL", SHAPE)
    # a capture whose shape is a plain vector: the given shape's regression
    M.capture_samples(_capture(shape={"vector": [1.0]}), "c", shape=WOMAN, model="MODEL", centre="regressed")
    assert asked[-1] == ("MODEL", WOMAN)
    # by sex: a man's regressed shoulder, a woman's fitted one (of the samples' shape)
    asked.clear()
    man = M.capture_samples(cap, "c", model="MODEL", centre="sex")
    np.testing.assert_array_equal(man[0].rest_origin, J_FIT[0] + 0.5)
    woman = M.capture_samples(_capture(shape=WOMAN), "w", model="MODEL", centre="sex")
    assert all(s.rest_origin is None for s in woman) and asked == [("MODEL", SHAPE)]
    half = M.ArmShapeParams(24.0, 0.5, 1.78, 0.52, sex=0.5)
    assert M.capture_samples(cap, "c", shape=half, model="MODEL", centre="sex")[0].rest_origin is not None
    assert M.capture_samples(cap, "c", shape=WOMAN, model="MODEL", centre="sex")[0].rest_origin is None


def test_capture_samples_refuse_an_unknown_centre_or_a_missing_model():
    cap = _capture()
    with pytest.raises(InputError, match=r"^centre='elbow' must be 'fitted', 'regressed' or 'sex'$"):
        M.capture_samples(cap, "c", centre="elbow")
    with pytest.raises(InputError, match=r"^capture 'c': centre='regressed' needs the model the capture was made with "
                                         r"\(model=\.\.\.\) for its regressed shoulder$"):
        M.capture_samples(cap, "c", centre="regressed")
    with pytest.raises(InputError, match=r"^capture 'c': centre='sex' needs the model the capture"):
        M.capture_samples(cap, "c", centre="sex")
    M.capture_samples(_capture(shape=WOMAN), "c", centre="sex")  # a woman: her fitted shoulder, no model needed


def test_a_frame_exactly_at_the_base_pose_tolerance_is_a_base_row_and_the_regression_unposes_without_joints():
    V, W = _arm()
    edge = ArmPose(np.eye(4), np.full((3, 3), M.BASE_POSE_TOL_RAD))
    J_reg = J_FIT + 0.01
    s = M.ArmSample("s", SHAPE, V, edge)
    rows, base, _, _ = M._subject_rows([s], W, lambda shape: J_reg, None)
    np.testing.assert_allclose(base, unpose_arm(V, W, J_reg, edge) - J_reg[0], atol=1e-15)
    assert rows.shape == (1, len(V), 3)


def test_capture_samples_map_every_stride_th_posed_frame_back_to_the_template(monkeypatch):
    """Each ``stride``-th frame with a pose, world -> template by the inverse similarity ((V - t) R / s), with
    the capture's name, the shape, its pose and joints; a capture object without ``joints``: None."""
    c, s_ = np.cos(0.7), np.sin(0.7)
    R = np.array([[c, -s_, 0.0], [s_, c, 0.0], [0.0, 0.0, 1.0]])
    t = np.array([0.3, -0.2, 1.1])
    V, _ = _arm()
    local = [V + 0.01 * k for k in range(5)]
    poses = [_pose(30), None, _pose(32), _pose(33), _pose(34)]
    cap = SimpleNamespace(vertices=[2.0 * X @ R.T + t for X in local], poses=poses, shape=SHAPE,
                          similarity=(2, R.tolist(), t.tolist()))
    out = M.capture_samples(cap, "cap", shape=WOMAN)
    assert [o.subject for o in out] == ["cap"] * 4 and all(o.shape == WOMAN for o in out)
    assert [o.pose for o in out] == [poses[0], poses[2], poses[3], poses[4]]
    for o, k in zip(out, (0, 2, 3, 4), strict=True):
        np.testing.assert_allclose(o.vertices, local[k], atol=1e-12)
        assert o.joints is None and o.rest_origin is None
    out = M.capture_samples(cap, "cap", stride=2)
    assert [o.pose for o in out] == [poses[0], poses[2], poses[4]] and out[0].shape == SHAPE
    assert [o.pose for o in M.capture_samples(cap, "cap", stride=3)] == [poses[0], poses[3]]


def test_capture_samples_messages():
    cap = _capture()
    with pytest.raises(InputError, match=r"^stride=0 must be >= 1$"):
        M.capture_samples(cap, "c", stride=0)
    with pytest.raises(InputError, match=r"^capture 'c' has no shape parameters \(a no-model capture\); give them "
                                         r"with --shape bmi=\.\.,muscularity=\.\.,height_m=\.\.,arm_length_m=\.\.$"):
        M.capture_samples(_capture(shape=None), "c")
    cap.poses = [None, None]
    with pytest.raises(InputError, match=r"^capture 'c' has no frames with joint angles \(a no-model capture\); "
                                         r"capture it with the model to extend the dataset$"):
        M.capture_samples(cap, "c")
