"""Dataset extension from captures (issue 11 §4, fifth pass): where a captured rest mesh is centred.
Planted captured subjects on the 2k model: the extension must recover the planted rest-shape residual
exactly, where the old construction does not."""

from types import SimpleNamespace

import numpy as np
import pytest

from bodystudio.errors import InputError
from bodystudio.muscle import model as M
from bodystudio.muscle.arm import ArmPose, pose_arm
from bodystudio.muscle.model import (
    capture_samples,
    extend_arm_model,
    model_joints,
    model_rest_vertices,
    pose_displacements,
    shape_displacements,
)

SHOULDER_ERROR = np.array([0.012, -0.008, 0.010])  # a fitted shoulder 17.6 mm off the regressed one


def _planted_capture(model, shape, residual, joints, n_frames=4, seed=5):
    """A capture made the way ``refine.skeleton_model_mesh`` makes one: the model's rest mesh (at the regressed
    shoulder) plus a planted rest-shape ``residual``, posed about ``joints``; similarity (s, R, t) applied."""
    rng = np.random.default_rng(seed)
    rest = model_rest_vertices(model, shape) + residual
    poses = [ArmPose(np.eye(4), rng.normal(0, 0.4, (3, 3))) for _ in range(n_frames)]
    frames = [pose_arm(rest + pose_displacements(model, p.angles), model.part_weights, joints, p) for p in poses]
    s, R, t = 1.0, np.eye(3), np.array([0.05, 1.2, 1.0])
    return SimpleNamespace(vertices=np.stack([s * V @ R.T + t for V in frames]), poses=poses, shape=shape,
                           similarity=(s, R, t), joints=joints, faces=None)


@pytest.fixture(scope="module")
def planted(arm_model_2k, arm_training_2k):
    model = arm_model_2k
    shape = M.ArmShapeParams(17.0, 0.3, 1.60, 0.47, sex=0.0)  # a thin, short woman: outside the men's range
    n = model.n_vertices
    # A smooth planted residual: 6 mm along x growing with the distance from the shoulder, 3 mm in z.
    rest = model_rest_vertices(model, shape)
    r = np.linalg.norm(rest - rest[model.arm_mask].mean(axis=0), axis=1)
    residual = np.c_[0.006 * r / r.max(), np.zeros(n), np.full(n, 0.003)]
    fitted = model_joints(model, shape) + SHOULDER_ERROR  # a whole skeleton moved: the men's placement error
    return model, shape, residual, fitted


def _new_rows(model, ext):
    return ext.shape_residuals[len(model.shape_residuals):].reshape(-1, model.n_vertices, 3)


def test_regressed_centring_recovers_the_planted_residual_where_the_fitted_shoulder_shifts_it(planted):
    model, shape, residual, fitted = planted
    cap = _planted_capture(model, shape, residual, fitted)
    want = shape_displacements(model, shape) + residual  # the row: the subject's rest mesh minus v_base + d_l
    ext = extend_arm_model(model, capture_samples(cap, "c", shape, model=model, centre="regressed"))
    rows = _new_rows(model, ext)
    assert len(rows) == 1  # one shape row per captured subject: its frames' mean (sixth pass)
    np.testing.assert_allclose(rows, np.broadcast_to(want, rows.shape), atol=1e-9)
    # The old centring (on the fitted shoulder) copies the shoulder's error into every row as a translation.
    old = _new_rows(model, extend_arm_model(model, capture_samples(cap, "c", shape, model=model)))
    np.testing.assert_allclose(old - want, np.broadcast_to(-SHOULDER_ERROR, old.shape), atol=1e-9)
    # With the regressed skeleton (no skeleton fit) both centrings are the same rows.
    cap0 = _planted_capture(model, shape, residual, model_joints(model, shape))
    a = _new_rows(model, extend_arm_model(model, capture_samples(cap0, "c", shape, model=model, centre="regressed")))
    b = _new_rows(model, extend_arm_model(model, capture_samples(cap0, "c", shape, model=model)))
    np.testing.assert_allclose(a, b, atol=1e-12)


def test_centring_by_sex_takes_a_womans_fitted_shoulder_and_a_mans_regressed_one(planted):
    """The joint regression has no sex input: a woman's regressed shoulder is sex-averaged and her fitted one
    places her residual; a man's regression is trusted and his fitted shoulder's error is kept out."""
    model, shape, residual, fitted = planted
    assert shape.sex == 0.0
    woman = _planted_capture(model, shape, residual, fitted)
    rows = {c: _new_rows(model, extend_arm_model(model, capture_samples(woman, "c", shape, model=model, centre=c)))
            for c in ("sex", "fitted", "regressed")}
    np.testing.assert_allclose(rows["sex"], rows["fitted"], atol=1e-12)
    assert np.abs(rows["sex"] - rows["regressed"]).max() > 0.01
    man = M.ArmShapeParams(31.5, 0.5, 1.75, 0.52, sex=1.0)
    fitted_m = model_joints(model, man) + SHOULDER_ERROR
    cap = _planted_capture(model, man, residual, fitted_m)
    got = _new_rows(model, extend_arm_model(model, capture_samples(cap, "m", man, model=model, centre="sex")))
    want = shape_displacements(model, man) + residual
    np.testing.assert_allclose(got, np.broadcast_to(want, got.shape), atol=1e-9)


def test_capture_samples_refuse_a_bad_centre(planted):
    model, shape, residual, fitted = planted
    cap = _planted_capture(model, shape, residual, fitted, n_frames=1)
    with pytest.raises(InputError, match="centre"):
        capture_samples(cap, "c", shape, centre="elbow")
    with pytest.raises(InputError, match="model"):
        capture_samples(cap, "c", shape, centre="regressed")
    capture_samples(cap, "c", shape, centre="sex")  # a woman: her fitted shoulder, no model needed
    man = M.ArmShapeParams(31.5, 0.5, 1.75, 0.52, sex=1.0)
    with pytest.raises(InputError, match="centre='sex' needs the model"):
        capture_samples(cap, "c", man, centre="sex")


def test_an_added_subject_weighs_as_much_as_a_training_subject(planted):
    """Tenth pass's option (``subject_rows="training"``, off by default): a captured subject's one shape row is repeated
    to the rows of a training subject (2 base-pose meshes each in the 2k model), so Eq. 7 shrinks a planted out-of-range
    man's residual less: his rest shape comes back closer than with his one row, and the repeated rows are exactly the
    one row's."""
    model, _, residual, _ = planted
    man = M.ArmShapeParams(31.5, 0.5, 1.75, 0.52, sex=1.0)  # heavier than the training men
    cap = _planted_capture(model, man, 3 * residual, model_joints(model, man))
    want = shape_displacements(model, man) + 3 * residual
    samples = capture_samples(cap, "m", man, model=model, centre="regressed")
    err = {}
    for rows in ("own", "training"):
        ext = extend_arm_model(model, samples, subject_rows=rows)
        err[rows] = 1000 * np.median(np.linalg.norm((shape_displacements(ext, man) - want)[model.arm_mask], axis=1))
    one = _new_rows(model, extend_arm_model(model, samples, subject_rows="own"))
    both = _new_rows(model, extend_arm_model(model, samples, subject_rows="training"))
    assert len(one) == 1 and len(both) == M.training_rows_per_subject(model) == 2
    np.testing.assert_allclose(both, np.broadcast_to(one, both.shape), atol=1e-12)
    assert err["training"] < 2.2 and err["training"] < 0.7 * err["own"], err  # measured 1.76 / 3.01 mm
