"""Analytic tests of the statistical arm model (Eq. 6-12 of Arm-Muscle Capture, muscle/model.py).

Each test checks a property the maths fixes exactly: the terms of Eq. 12 on a hand-made model, the PCA of
the length term (Eq. 8-9), the Tikhonov solutions against their stored normal equations, the prior's pose
term removed from a sequence without a base-pose mesh, dataset extension equal to learning from the union,
and the loader's refusals (issue 17: planted bugs must fail a fast test).
"""

import json

import numpy as np
import pytest

from bodystudio.errors import FileFormatError, InputError
from bodystudio.muscle import model as M
from bodystudio.muscle.arm import ArmPose, pose_arm
from bodystudio.muscle.model import (
    SHAPE_NAMES,
    ArmModel,
    ArmSample,
    ArmShapeParams,
    extend_arm_model,
    learn_arm_model,
    limit_displacement_norms,
    load_arm_model,
    model_error_mm,
    model_joints,
    model_mesh,
    model_rest_vertices,
    save_arm_model,
    tikhonov_from_normal_equations,
)

SHAPE = ArmShapeParams(24.0, 0.6, 1.78, 0.56)


def _toy_model(n: int = 6, k: int = 3, seed: int = 0) -> ArmModel:
    """A hand-made model on ``n`` vertices with random terms (every coefficient non-zero)."""
    rng = np.random.default_rng(seed)
    w = rng.uniform(0.1, 1.0, (n, 4))
    return ArmModel(
        "toy", np.array([[0, 1, 2]]), w / w.sum(1, keepdims=True), np.ones(n, bool), rng.normal(0, 0.1, (n, 3)),
        np.linalg.qr(rng.normal(size=(3 * n, k)))[0].T, rng.normal(0, 0.01, (2, k)), rng.normal(0, 0.1, (5, 9)),
        rng.normal(0, 0.01, (6, 3 * n)), rng.normal(0, 0.01, (10, 3 * n)), np.array([22.0, 0.5, 1.7, 0.55]),
        np.array([3.0, 0.2, 0.08, 0.03]), 1.0, np.zeros((0, 5)), np.zeros((0, 3 * n)), np.zeros((10, 10)),
        np.zeros((10, 3 * n)), np.eye(5), np.zeros((5, 9)),
        subjects=[{"name": "a", "shape": ArmShapeParams(20, 0.2, 1.6, 0.5).to_dict()},
                  {"name": "b", "shape": ArmShapeParams(27, 0.9, 1.9, 0.6).to_dict()}])


# --- shape parameters ------------------------------------------------------------------------------------

def test_shape_params_vector_and_dict_round_trip_in_the_documented_order():
    v = SHAPE.as_vector()
    assert v.dtype == np.float64 and v.tolist() == [24.0, 0.6, 1.78, 0.56]
    assert ArmShapeParams.from_vector(v) == SHAPE
    assert ArmShapeParams.from_vector(v.reshape(2, 2)) == SHAPE
    assert ArmShapeParams.from_dict(SHAPE.to_dict()) == SHAPE
    assert list(SHAPE.to_dict()) == [*SHAPE_NAMES, "sex"] and SHAPE.sex == 1.0  # male unless said
    assert SHAPE.as_row().tolist() == [24.0, 0.6, 1.78, 0.56, 1.0]
    with pytest.raises(InputError, match=r"^my.json: needs bmi, muscularity, height_m, arm_length_m"):
        ArmShapeParams.from_dict({"bmi": 20}, "my.json")
    with pytest.raises(InputError, match=r"^shape parameters: needs bmi"):
        ArmShapeParams.from_dict({**SHAPE.to_dict(), "bmi": "fat"})


def test_measure_arm_shape_is_bmi_muscle_stature_and_the_arm_chain_length():
    from bodystudio.body import Phenotype, build_body
    from bodystudio.body.measure import measure_body

    phenotype = Phenotype(gender=1.0, muscle=0.7, weight=0.6)
    # The left forearm lengthened only: the two sides differ, so the side's bones are tested.
    local = {"l-lowerarm-scale-vert-decr-incr": 1.0}
    left, right = M.measure_arm_shape(phenotype, local), M.measure_arm_shape(phenotype, local, side="right")
    body = build_body(phenotype, local, resolution="6k")
    m = measure_body(body)
    names = body.skeleton.bone_names
    for side, params in (("l", left), ("r", right)):
        h = body.skeleton.heads[[names.index(f"{b}_{side}") for b in ("upperarm", "lowerarm", "hand")]]
        arm = np.linalg.norm(h[1] - h[0]) + np.linalg.norm(h[2] - h[1])
        assert params.arm_length_m == pytest.approx(arm, rel=1e-12)
        assert params.bmi == pytest.approx(m["mass_kg"] / m["stature_m"] ** 2, rel=1e-12)
        assert params.muscularity == 0.7 and params.height_m == pytest.approx(m["stature_m"], rel=1e-12)
    assert left.arm_length_m > right.arm_length_m + 3e-5  # 0.06 mm
    assert 15 < left.bmi < 40 and 0.4 < right.arm_length_m < 0.75


# --- the terms of Eq. 12 on a hand-made model --------------------------------------------------------------

def test_standardised_parameters_and_each_displacement_term():
    model = _toy_model()
    z = (SHAPE.as_vector() - model.param_center) / model.param_scale
    np.testing.assert_allclose(M._z(model, model.param_center), 0.0, atol=1e-15)
    np.testing.assert_allclose(M._z(model, SHAPE.as_vector()), z, rtol=1e-14)
    # Eq. 8: PCA weights [1, z(arm length)] @ length_coeffs, then the eigenvectors.
    d_l = (np.array([1.0, z[3]]) @ model.length_coeffs @ model.length_basis).reshape(-1, 3)
    np.testing.assert_allclose(M.length_displacements(model, SHAPE), d_l, rtol=1e-12)
    # Eq. 6: [1, z(BMI), z(muscularity), z(height), z(arm length), 1 - sex] @ shape_coeffs.
    np.testing.assert_allclose(M.shape_displacements(model, SHAPE),
                               (np.r_[1.0, z, 0.0] @ model.shape_coeffs).reshape(-1, 3), rtol=1e-12)
    woman = ArmShapeParams(*SHAPE.as_vector(), sex=0.0)
    np.testing.assert_allclose(M.shape_displacements(model, woman),
                               (np.r_[1.0, z, 1.0] @ model.shape_coeffs).reshape(-1, 3), rtol=1e-12)
    # Eq. 10: an intercept plus a linear term in the 9 angle coordinates.
    a = np.arange(9.0).reshape(3, 3) / 10
    np.testing.assert_allclose(M.pose_displacements(model, np.zeros((3, 3))), model.pose_coeffs[0].reshape(-1, 3))
    want = (np.r_[1.0, a.ravel()] @ model.pose_coeffs).reshape(-1, 3)
    np.testing.assert_allclose(M.pose_displacements(model, a), want, rtol=1e-12)
    want = (np.r_[1.0, z] @ model.joint_coeffs).reshape(3, 3)
    np.testing.assert_allclose(model_joints(model, SHAPE), want, rtol=1e-12)


def test_rest_vertices_sum_the_terms_at_the_shoulder():
    model = _toy_model()
    terms = model.base_vertices + M.length_displacements(model, SHAPE) + M.shape_displacements(model, SHAPE)
    J = model_joints(model, SHAPE)
    np.testing.assert_allclose(model_rest_vertices(model, SHAPE), terms + J[0], rtol=1e-12)
    given = np.arange(9).reshape(3, 3)  # integers: converted, only the shoulder places the arm
    np.testing.assert_allclose(model_rest_vertices(model, SHAPE, given), terms + [0, 1, 2], rtol=1e-12)


def test_model_mesh_is_skinning_of_the_sum_with_the_limited_pose_term():
    """Eq. 12: ``skinning(v_base + d_l + d_theta + limit(d_rho))`` with the regressed or the given joints."""
    model = _toy_model()
    rng = np.random.default_rng(3)
    pose = ArmPose(np.eye(4), rng.normal(0, 0.4, (3, 3)))
    J = model_joints(model, SHAPE)
    for limit in (0.0, 0.5, 1.0):
        d_rho = limit_displacement_norms(M.pose_displacements(model, pose.angles), limit)
        want = pose_arm(model_rest_vertices(model, SHAPE) + d_rho, model.part_weights, J, pose)
        np.testing.assert_allclose(model_mesh(model, SHAPE, pose, limit), want, rtol=1e-12, atol=1e-15)
    Jg = J + 0.01
    want = pose_arm(model_rest_vertices(model, SHAPE, Jg) + limit_displacement_norms(
        M.pose_displacements(model, pose.angles), 0.9), model.part_weights, Jg, pose)
    np.testing.assert_allclose(model_mesh(model, SHAPE, pose, joints=Jg.tolist()), want, rtol=1e-12, atol=1e-15)


def test_norm_limit_on_displacements_shorter_than_a_metre_and_on_no_displacement():
    d = np.array([[0.01, 0.0, 0.0], [0.0, 0.002, 0.0], [0.0, 0.0, 0.006]])
    out = limit_displacement_norms(d, 0.5)  # cap = 5 mm
    np.testing.assert_allclose(np.linalg.norm(out, axis=1), [0.005, 0.002, 0.005], rtol=1e-12)
    np.testing.assert_allclose(out[0] / np.linalg.norm(out[0]), [1, 0, 0])
    assert limit_displacement_norms(np.zeros((0, 3)), 0.9).shape == (0, 3)
    np.testing.assert_array_equal(limit_displacement_norms(np.zeros((4, 3)), 0.9), 0.0)


def test_shape_range_spans_the_training_subjects():
    r = _toy_model().shape_range()
    assert list(r) == list(SHAPE_NAMES)
    assert r["bmi"] == (20.0, 27.0) and r["muscularity"] == (0.2, 0.9) and r["arm_length_m"] == (0.5, 0.6)


def test_model_error_of_the_models_own_meshes_is_zero_and_of_an_offset_is_the_offset():
    model = _toy_model()
    rng = np.random.default_rng(4)
    poses = [ArmPose(np.eye(4), rng.normal(0, 0.3, (3, 3))) for _ in range(3)]
    exact = [ArmSample("a", SHAPE, model_mesh(model, SHAPE, p, 0.0), p) for p in poses]
    e = model_error_mm(model, exact)  # the default is the unlimited model (norm limit 0)
    assert e == {"mean_mm": pytest.approx(0, abs=1e-9), "median_mm": pytest.approx(0, abs=1e-9),
                 "p90_mm": pytest.approx(0, abs=1e-9), "n_meshes": 3}
    shift = np.array([0.003, 0.0, 0.004])  # 5 mm everywhere
    moved = [ArmSample("a", SHAPE, s.vertices + shift, s.pose) for s in exact]
    e = model_error_mm(model, moved)
    assert e["mean_mm"] == pytest.approx(5.0, rel=1e-9) and e["median_mm"] == pytest.approx(5.0, rel=1e-9)
    assert model_error_mm(model, moved, fit_translation=True)["mean_mm"] < 1e-9
    # Distances growing along the arm: median and 90th percentile of them.
    ramp = [ArmSample("a", SHAPE, s.vertices + np.c_[np.arange(6) * 0.001, np.zeros((6, 2))], s.pose)
            for s in exact[:1]]
    e = model_error_mm(model, ramp)
    assert (e["mean_mm"], e["median_mm"], e["p90_mm"]) == pytest.approx((2.5, 2.5, 4.5), rel=1e-9)
    with_joints = [ArmSample("a", SHAPE, model_mesh(model, SHAPE, p, 0.0, joints=model_joints(model, SHAPE) + 0.01), p,
                             model_joints(model, SHAPE) + 0.01) for p in poses]
    assert model_error_mm(model, with_joints, use_sample_joints=True)["mean_mm"] < 1e-9
    assert model_error_mm(model, with_joints)["mean_mm"] > 5.0


# --- learning (Eq. 6-10) ---------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def population_12(arm_template_2k):
    return M.population_arms(arm_template_2k.resolution, arm_template_2k.side, 12, 114)


def _subject(samples, name):
    return [s for s in samples if s.subject == name]


@pytest.fixture(scope="module")
def unregularised_model(arm_template_2k, arm_training_2k):
    samples, _ = arm_training_2k
    return learn_arm_model(samples, arm_template_2k, regularization=0.0, population_size=12)


def test_length_term_is_the_population_pca(unregularised_model, population_12, arm_template_2k):
    """Eq. 8-9: v_base the shoulder-centred population mean, e_j its k = min(8, N - 1) principal axes."""
    model = unregularised_model
    popV, popJ, popP = population_12
    X = (popV - popJ[:, :1]).reshape(12, -1)
    mean = X.mean(axis=0)
    np.testing.assert_allclose(model.base_vertices, mean.reshape(-1, 3), atol=1e-12)
    E = model.length_basis
    assert E.shape == (8, X.shape[1])
    np.testing.assert_allclose(E @ E.T, np.eye(8), atol=1e-10)
    # Eckart-Young: the residual of the centred population off the basis is the discarded singular values.
    sv = np.linalg.svd(X - mean, compute_uv=False)
    resid = (X - mean) - (X - mean) @ E.T @ E
    assert np.linalg.norm(resid) == pytest.approx(np.sqrt((sv[8:] ** 2).sum()), rel=1e-6)
    np.testing.assert_allclose(model.param_center, popP.mean(axis=0), rtol=1e-12)
    np.testing.assert_allclose(model.param_scale, popP.std(axis=0), rtol=1e-9)
    # Eq. 9 with q = 0: the least-squares line of the PCA weights on the standardised arm length.
    z = (popP[:, 3] - model.param_center[3]) / model.param_scale[3]
    want = np.linalg.lstsq(np.c_[np.ones(12), z], (X - mean) @ E.T, rcond=None)[0]
    np.testing.assert_allclose(model.length_coeffs, want, atol=1e-9 * np.abs(want).max())
    assert model.template_key == arm_template_2k.key
    np.testing.assert_array_equal(model.faces, arm_template_2k.faces)
    np.testing.assert_array_equal(model.part_weights, arm_template_2k.part_weights)


def test_a_small_population_keeps_n_minus_one_axes(arm_template_2k, arm_training_2k):
    samples, _ = arm_training_2k
    model = learn_arm_model(samples[:10], arm_template_2k, population_size=6)
    assert model.length_basis.shape[0] == 5  # 6 centred arms span 5 directions


def test_a_non_default_population_seed_is_used(arm_template_2k, arm_training_2k):
    samples, _ = arm_training_2k
    model = learn_arm_model(samples[:10], arm_template_2k, population_size=6, population_seed=7)
    popV, popJ, _ = M.population_arms(arm_template_2k.resolution, arm_template_2k.side, 6, 7)
    np.testing.assert_allclose(model.base_vertices, (popV - popJ[:, :1]).mean(axis=0), atol=1e-12)


def test_coefficients_solve_their_stored_normal_equations(arm_model_2k, arm_training_2k, population_12):
    """Eq. 7 and 10: shape, pose and joint coefficients are the Tikhonov solutions of the kept statistics."""
    model = arm_model_2k
    samples, subjects = arm_training_2k
    q = model.regularization
    n3 = 3 * model.n_vertices
    assert model.shape_coeffs.shape == (6, n3) and model.pose_coeffs.shape == (10, n3)
    X = np.c_[np.ones(len(model.shape_rows)), M._z(model, model.shape_rows[:, :4]), 1.0 - model.shape_rows[:, 4]]
    weights = np.r_[0.0, np.full(4, q), model.sex_regularization] ** 2
    want = np.linalg.solve(X.T @ X + np.diag(weights), X.T @ model.shape_residuals)
    np.testing.assert_allclose(model.shape_coeffs, want, atol=1e-12)
    np.testing.assert_allclose(model.shape_coeffs[-1], 0.0, atol=1e-15)  # all-male training: no female term
    np.testing.assert_allclose(model.pose_coeffs, tikhonov_from_normal_equations(model.pose_xtx, model.pose_xtd, q),
                               atol=1e-12)
    np.testing.assert_allclose(model.joint_coeffs, tikhonov_from_normal_equations(model.joint_xtx, model.joint_xty, q),
                               atol=1e-12)
    # The pose statistics: one row [1, angles] per training mesh.
    A = np.array([np.r_[1.0, s.pose.angles.ravel()] for s in samples])
    np.testing.assert_allclose(model.pose_xtx, A.T @ A, rtol=1e-12)
    # Every subject with measured joints adds one row [1, z(shape)] to the population's joint regression.
    rows = np.array([np.r_[1.0, M._z(model, _subject(samples, f"subject_{s.seed}")[0].shape.as_vector())]
                     for s in subjects])
    assert len(model.shape_rows) == 2 * len(subjects)  # two base-pose meshes each
    assert model.subjects == [{"name": f"subject_{s.seed}",
                               "shape": _subject(samples, f"subject_{s.seed}")[0].shape.to_dict(),
                               "n_meshes": 10, "source": "training"} for s in subjects]
    popP = population_12[2]
    P = np.c_[np.ones(12), M._z(model, popP)]
    np.testing.assert_allclose(model.joint_xtx, P.T @ P + rows.T @ rows, atol=1e-9)


def test_extension_equals_learning_from_the_union(arm_template_2k, arm_training_2k):
    """Dataset extension keeps the normal equations: learn(A) + extend(B) == learn(A + B) (issue §4)."""
    samples, _ = arm_training_2k
    names = sorted({s.subject for s in samples})
    A = [s for s in samples if s.subject in names[:3]]
    B = [s for s in samples if s.subject in names[3:]]
    union = learn_arm_model(A + B, arm_template_2k, population_size=12)
    extended = extend_arm_model(learn_arm_model(A, arm_template_2k, population_size=12), B)
    for k in ("shape_coeffs", "pose_coeffs", "joint_coeffs", "pose_xtx", "pose_xtd", "joint_xtx", "joint_xty",
              "shape_rows", "shape_residuals"):
        np.testing.assert_allclose(getattr(extended, k), getattr(union, k), rtol=1e-9,
                                   atol=1e-12 * np.abs(getattr(union, k)).max(), err_msg=k)
    assert [s["source"] for s in extended.subjects] == ["training"] * 3 + ["capture"] * 2
    assert [s["name"] for s in extended.subjects] == names
    last = _subject(B, names[-1])
    assert extended.subjects[-1] == {"name": names[-1], "shape": last[0].shape.to_dict(), "n_meshes": len(last),
                                     "source": "capture"}
    # The joint regression is re-solved from its (population + measured joints) normal equations.
    for m in (union, extended):
        np.testing.assert_allclose(m.joint_coeffs, tikhonov_from_normal_equations(m.joint_xtx, m.joint_xty, 1.0),
                                   atol=1e-12)
    custom = extend_arm_model(learn_arm_model(A, arm_template_2k, population_size=12), B, source="studio 2")
    assert custom.subjects[-1]["source"] == "studio 2"


def test_a_subject_with_one_mesh_and_unknown_joints(arm_model_2k, arm_training_2k):
    """One base-pose mesh, no joints: the model's joint regression unposes it and its shape row is that mesh."""
    model = arm_model_2k
    shape = arm_training_2k[0][0].shape
    V = model_mesh(model, shape, ArmPose.rest(), 0.0)
    ext = extend_arm_model(model, [ArmSample("one", shape, V, ArmPose.rest())], subject_rows="own")
    assert ext.subjects[-1]["n_meshes"] == 1 and len(ext.shape_rows) == len(model.shape_rows) + 1
    J = model_joints(model, shape)
    row = V - J[0] - model.base_vertices - M.length_displacements(model, shape)
    np.testing.assert_allclose(ext.shape_residuals[-1], row.ravel(), atol=1e-12)
    np.testing.assert_array_equal(ext.joint_xtx, model.joint_xtx)  # no measured joints: regression unchanged


def test_a_sequence_without_a_base_pose_mesh_loses_the_priors_pose_term(arm_model_2k, arm_training_2k):
    """Extension from a capture: every frame minus the prior's d_rho is the subject's base mesh (exact for
    frames the model itself made), the frames' mean its one shape row, and the pose rows are the prior's d_rho."""
    model = arm_model_2k
    shape = arm_training_2k[0][0].shape
    rng = np.random.default_rng(9)
    poses = [ArmPose(np.eye(4), rng.normal(0, 0.5, (3, 3))) for _ in range(4)]
    frames = [ArmSample("seq", shape, model_mesh(model, shape, p, 0.0), p) for p in poses]
    base_rows, base, angles, d = M._subject_rows(frames, model.part_weights, lambda s: model_joints(model, s), model)
    rest = model_rest_vertices(model, shape) - model_joints(model, shape)[0]
    assert base_rows.shape == (1, *rest.shape)
    np.testing.assert_allclose(base_rows[0], rest, atol=1e-9)
    np.testing.assert_allclose(base, rest, atol=1e-9)
    for a, di in zip(angles, d, strict=True):
        np.testing.assert_allclose(di, M.pose_displacements(model, a), atol=1e-9)
    ext = extend_arm_model(model, frames, subject_rows="own")
    assert len(ext.shape_rows) == len(model.shape_rows) + 1
    np.testing.assert_allclose(ext.pose_xtd - model.pose_xtd,
                               sum(np.outer(np.r_[1.0, a], di.ravel()) for a, di in zip(angles, d, strict=True)),
                               atol=1e-9)


def test_measured_joints_refine_the_joint_regression(arm_model_2k, arm_training_2k):
    model = arm_model_2k
    s0 = arm_training_2k[0][0]
    J = s0.joints + 0.01
    meshes = [ArmSample("j", s0.shape, s0.vertices, s0.pose, J),
              ArmSample("j", s0.shape, s0.vertices, s0.pose, J + 0.02)]
    ext = extend_arm_model(model, meshes)
    xj = np.r_[1.0, M._z(model, s0.shape.as_vector())]
    np.testing.assert_allclose(ext.joint_xtx - model.joint_xtx, np.outer(xj, xj), atol=1e-9)
    np.testing.assert_allclose(ext.joint_xty - model.joint_xty, np.outer(xj, (J + 0.01).ravel()), atol=1e-9)


def test_learning_accepts_any_non_negative_regularisation_and_refuses_bad_input(arm_template_2k, arm_training_2k):
    samples, _ = arm_training_2k
    # q = 0 is learned by the unregularised_model fixture (one subject alone is singular without q).
    assert learn_arm_model(samples[:10], arm_template_2k, regularization=0.5, population_size=12).regularization == 0.5
    with pytest.raises(InputError, match=r"regularization=-1 must be >= 0"):
        learn_arm_model(samples[:10], arm_template_2k, regularization=-1, population_size=12)
    with pytest.raises(InputError, match="^no training meshes given; the arm model needs at least one subject$"):
        learn_arm_model([], arm_template_2k, population_size=12)
    s = samples[0]
    with pytest.raises(InputError, match=r"subject 'x': mesh has shape \(\d+, 3\), the arm template needs"):
        learn_arm_model([ArmSample("x", s.shape, np.full_like(s.vertices, np.nan), s.pose)], arm_template_2k)
    with pytest.raises(InputError, match=r"mesh has shape \(3, 3\)"):
        learn_arm_model([ArmSample("x", s.shape, s.vertices[:3], s.pose)], arm_template_2k)
    posed = [ArmSample("p", s.shape, x.vertices, x.pose) for x in samples[2:5]]
    with pytest.raises(InputError, match=r"subject 'p' has no mesh in the base pose"):
        learn_arm_model(posed, arm_template_2k, population_size=12)
    with pytest.raises(InputError, match=r"subject 'p' has no mesh in the base pose"):  # one mesh only
        learn_arm_model(posed[:1], arm_template_2k, population_size=12)
    names = sorted({x.subject for x in samples})
    with pytest.raises(InputError, match=rf"subject\(s\) {', '.join(names)} are already in the model; give"):
        extend_arm_model(learn_arm_model(samples, arm_template_2k, population_size=12), samples)


# --- files -----------------------------------------------------------------------------------------------

def _write(path, arrays, header):
    np.savez(path, **{**arrays, "header": np.array(json.dumps(header))})
    return path


@pytest.fixture(scope="module")
def saved(arm_model_2k, tmp_path_factory):
    path = tmp_path_factory.mktemp("model") / "arm.npz"
    save_arm_model(path, arm_model_2k)
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files if k != "header"}
        header = json.loads(str(z["header"]))
    return path, arrays, header


def test_loaded_model_keeps_every_field(saved, arm_model_2k):
    path, _, _ = saved
    loaded = load_arm_model(path)
    for k in M._ARRAYS:
        np.testing.assert_array_equal(getattr(loaded, k), getattr(arm_model_2k, k), err_msg=k)
    assert loaded.arm_mask.dtype == bool and loaded.regularization == arm_model_2k.regularization == 1.0
    assert loaded.version == M.MODEL_VERSION and loaded.subjects == arm_model_2k.subjects


def test_header_without_subjects_loads_with_none(saved, tmp_path):
    path, arrays, header = saved
    header = {k: v for k, v in header.items() if k != "subjects"}
    assert load_arm_model(_write(tmp_path / "m.npz", arrays, header)).subjects == []


@pytest.mark.parametrize("change, phrase", [
    ({"format": "other"}, r"not a bodystudio arm model \(format 'other'\)"),
    ({"version": 99}, r"arm model version 99 is not supported \(this bodystudio reads versions 1-3\); rebuild it with "
                      r"`bodystudio muscle model build`"),
    ({"template_key": None}, "arm model header lacks template_key / regularization / subjects; rebuild it with "
                             "`bodystudio muscle model build`"),
    ({"regularization": "high"}, "arm model header lacks template_key"),
    ({"subjects": {"a": 1}}, "arm model header lacks template_key"),
])
def test_bad_headers_are_refused_naming_the_file(saved, tmp_path, change, phrase):
    path, arrays, header = saved
    bad = _write(tmp_path / "bad.npz", arrays, {**header, **change})
    with pytest.raises(FileFormatError, match=rf"^{bad}: {phrase}"):
        load_arm_model(bad)


def test_a_header_that_is_not_an_object_is_refused(saved, tmp_path):
    path, arrays, _ = saved
    bad = tmp_path / "list.npz"
    np.savez(bad, **{**arrays, "header": np.array("[1, 2]")})
    with pytest.raises(FileFormatError, match=rf"^{bad}: not a bodystudio arm model$"):
        load_arm_model(bad)


def test_junk_is_refused_naming_the_error(tmp_path):
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"not a zip file")
    with pytest.raises(FileFormatError, match=r"junk.npz: not a bodystudio arm model \(ValueError: .*pickled.*\); "
                                              r"rebuild it with `bodystudio muscle model build`"):
        load_arm_model(junk)


@pytest.mark.parametrize("damage", ["pose_shape", "shape_shape", "nan_base", "nan_pose", "nan_shape"])
def test_inconsistent_or_non_finite_arrays_are_refused(saved, tmp_path, damage):
    path, arrays, header = saved
    arrays = dict(arrays)
    if damage == "pose_shape":
        arrays["pose_coeffs"] = arrays["pose_coeffs"][:9]
    elif damage == "shape_shape":
        arrays["shape_coeffs"] = arrays["shape_coeffs"][:, :-3]
    else:
        key = {"nan_base": "base_vertices", "nan_pose": "pose_coeffs", "nan_shape": "shape_coeffs"}[damage]
        arrays[key] = arrays[key].copy()
        arrays[key].flat[5] = np.nan
    bad = _write(tmp_path / "bad.npz", arrays, header)
    with pytest.raises(FileFormatError, match=rf"^{bad}: arm model arrays are inconsistent or not finite; rebuild"):
        load_arm_model(bad)


def test_another_template_is_refused_with_the_fix(saved, arm_template_2k, muscular_body_2k):
    from bodystudio.muscle.arm import arm_template

    path, _, _ = saved
    assert load_arm_model(path, arm_template_2k).template_key == arm_template_2k.key
    with pytest.raises(InputError, match="use the same --resolution and --side as the model or rebuild it "
                                         "for this template$"):
        load_arm_model(path, arm_template(muscular_body_2k, "right"))


# --- captured frames as training meshes ------------------------------------------------------------------

def test_capture_samples_keep_every_posed_frame_and_the_given_shape(arm_training_2k):
    from types import SimpleNamespace

    samples, _ = arm_training_2k
    poses = [samples[0].pose, None, samples[2].pose, samples[3].pose]
    s, R, t = 2, np.array([[0, 0, 1], [0, 1, 0], [-1, 0, 0]]), np.array([1, 2, 3])  # integers: converted
    capture = SimpleNamespace(vertices=[s * x.vertices @ R.T + t for x in samples[:4]], poses=poses,
                              shape=samples[0].shape, similarity=(s, R, t))
    out = M.capture_samples(capture, "cap", shape=SHAPE)
    assert len(out) == 3 and all(o.shape == SHAPE for o in out)
    assert [o.pose for o in out] == [poses[0], poses[2], poses[3]]
    np.testing.assert_allclose(out[2].vertices, samples[3].vertices, atol=1e-12)
    with pytest.raises(InputError, match="stride=0 must be >= 1"):
        M.capture_samples(capture, "cap", stride=0)
    with pytest.raises(InputError, match=r"--shape bmi=\.\.,muscularity=\.\.,height_m=\.\.,arm_length_m=\.\.$"):
        M.capture_samples(SimpleNamespace(**{**capture.__dict__, "shape": None}), "cap")
    with pytest.raises(InputError, match="capture it with the model to extend the dataset$"):
        M.capture_samples(SimpleNamespace(**{**capture.__dict__, "poses": [None] * 4}), "cap")


def test_capture_samples_carry_the_captures_fitted_skeleton():
    """``capture.joints`` (the rest skeleton a capture's poses turn about, ``refine.fit_arm_sequence_skeleton``) goes
    with every sample, so the extension unposes about it; a capture without one (``joints`` None, or a capture
    object from before the field) leaves the joints to the model's regression (None). Issue 17: the pass-through
    survived the model's tests (only tests/muscle/test_sequence_fit.py reached it)."""
    from types import SimpleNamespace

    J = np.array([[0.1, 1.4, 0.0], [0.4, 1.38, 0.01], [0.65, 1.37, 0.02]])
    V = np.arange(12.0).reshape(4, 3)
    pose = ArmPose(np.eye(4), np.zeros((3, 3)))
    cap = SimpleNamespace(vertices=[V, V + 1.0], poses=[pose, pose], shape=SHAPE,
                          similarity=(1.0, np.eye(3), np.zeros(3)), joints=J)
    out = M.capture_samples(cap, "c")
    assert len(out) == 2
    for o in out:
        np.testing.assert_array_equal(o.joints, J)
    assert all(o.joints is None for o in M.capture_samples(SimpleNamespace(**{**vars(cap), "joints": None}), "c"))
    older = SimpleNamespace(**{k: v for k, v in vars(cap).items() if k != "joints"})
    assert all(o.joints is None for o in M.capture_samples(older, "c"))


def test_tikhonov_column_weights_are_squared_per_column_and_the_intercept_is_free():
    """``tikhonov_from_normal_equations``: ``(X^T X + diag(0, w_1^2, ...)) c = X^T y``, with one weight per column
    (the sex column's own, Eq. 7) or ``q`` for all; the intercept (column 0) is never shrunk."""
    xtx, xty = 2.0 * np.eye(3), np.array([2.0, 2.0, 2.0])
    np.testing.assert_allclose(M.tikhonov_from_normal_equations(xtx, xty, 0.0, column_weights=[5.0, 1.0, 2.0]),
                               [1.0, 2.0 / 3.0, 2.0 / 6.0], atol=1e-15)
    np.testing.assert_allclose(M.tikhonov_from_normal_equations(xtx, xty, 2.0), [1.0, 2.0 / 6.0, 2.0 / 6.0],
                               atol=1e-15)


@pytest.mark.parametrize("value", [0, 0.0, -0.1, float("inf"), "0.1", True])
def test_a_bad_sex_regularization_in_the_header_is_refused(saved, tmp_path, value):
    import re

    path, arrays, header = saved
    bad = _write(tmp_path / "bad.npz", arrays, {**header, "sex_regularization": value})
    want = rf"^{re.escape(str(bad))}: arm model sex_regularization {re.escape(repr(value))} is not a positive number; "
    with pytest.raises(FileFormatError, match=want + "rebuild the model$"):
        load_arm_model(bad)


def test_the_sex_regularization_of_the_header_is_the_loaded_one(saved, tmp_path):
    path, arrays, header = saved
    assert header["sex_regularization"] == M.SEX_REGULARIZATION
    assert load_arm_model(_write(tmp_path / "q.npz", arrays, {**header, "sex_regularization": 0.37})) \
        .sex_regularization == 0.37
    assert load_arm_model(_write(tmp_path / "i.npz", arrays, {**header, "sex_regularization": 3})) \
        .sex_regularization == 3.0


def test_a_captured_subject_is_one_shape_row_the_mean_of_its_frames(arm_model_2k, arm_training_2k):
    """Sixth pass: a capture's frames give one shape row, their mean rest shape (minus the prior's d_rho), so a
    subject counts once in Eq. 7 whatever its frame count (a row per frame weighed it by its 8 frames): 2 frames
    of one planted rest offset and 6 of another give one row, at the frames' mean offset."""
    model = arm_model_2k
    shape = arm_training_2k[0][0].shape
    rng = np.random.default_rng(4)
    poses = [ArmPose(np.eye(4), rng.normal(0, 0.4, (3, 3))) for _ in range(8)]
    rest = model_rest_vertices(model, shape)
    J = model_joints(model, shape)
    a, b = np.array([0.004, 0.0, 0.0]), np.array([0.0, 0.0, -0.008])
    frames = []
    for k, p in enumerate(poses):
        offset = a if k < 2 else b
        V = pose_arm(rest + offset + M.pose_displacements(model, p.angles), model.part_weights, J, p)
        frames.append(ArmSample("seq", shape, V, p))
    ext = extend_arm_model(model, frames, subject_rows="own")
    assert len(ext.shape_rows) == len(model.shape_rows) + 1
    expected = (rest - J[0] - model.base_vertices - M.length_displacements(model, shape)) + (2 * a + 6 * b) / 8
    np.testing.assert_allclose(ext.shape_residuals[-1], expected.ravel(), atol=1e-9)
    # The tenth pass's option: that row repeated to as many rows as a training subject of the model has (2 here).
    ext = extend_arm_model(model, frames, subject_rows="training")
    assert M.training_rows_per_subject(model) == 2 and len(ext.shape_rows) == len(model.shape_rows) + 2
    np.testing.assert_allclose(ext.shape_residuals[-2:], np.tile(expected.ravel(), (2, 1)), atol=1e-9)
    np.testing.assert_array_equal(ext.shape_rows[-2:], np.tile(shape.as_row(), (2, 1)))
