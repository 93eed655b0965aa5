"""Fast analytic tests of mus11h's body form of the arm model's shape term (``model.fit_body_form``,
``body_form_design``, ``body_form_columns``, ``shape_row_parameters``, ``regressed_body_parameters``,
``body_form_rest_vertices``, ``shape_displacements``' body branch, ``with_shape_form``,
``extend_arm_model(shape_form=)`` through ``_add_subjects``, and the version 3 file; issue 17, mutation testing;
branch mutP). The 12-vertex stand-in shape space and hand-built arm model of
tests/muscle/test_body_rest_extension_mutants.py: no body assets. Each piece is compared with its docstring written
out here (the per-parameter ridge on its own columns, Eq. 7 on what the body model's arm at the regressed parameters
leaves of each row)."""

import json
from dataclasses import replace

import numpy as np
import pytest

from bodystudio.errors import FileFormatError, InputError
from bodystudio.muscle import model as mm
from bodystudio.muscle.model import (
    BODY_MACRO_NAMES,
    SHAPE_ROW_PRIOR_WEIGHT,
    ArmShapeParams,
    body_form_columns,
    body_form_design,
    body_form_rest_vertices,
    body_space_rest_mesh,
    extend_arm_model,
    fit_body_form,
    fit_shape_coefficients,
    length_displacements,
    load_arm_model,
    regressed_body_parameters,
    save_arm_model,
    shape_displacements,
    shape_row_parameters,
    with_shape_form,
)
from tests.muscle.test_body_rest_extension_mutants import N_V, SHAPE, _frames, _planted, _stand_in, _tiny_model


@pytest.fixture(autouse=True)
def _regressed_weight(monkeypatch):
    """These tests pin mus11h's body form with the weight macro regressed like the other parameters; the weight
    solved from the BMI (the ninth pass's default, ``BODY_FORM_WEIGHT = "bmi"``) needs the real body model's
    measurement, which the stand-in space has not: tests/muscle/test_body_weight_from_bmi.py covers it."""
    monkeypatch.setattr(mm, "BODY_FORM_WEIGHT", "regressed")

# the body-space parameters each is regressed on, by column of the design [1, z(bmi), z(mu), z(h), z(L), 1-sex,
# z(bmi) z(mu)] (BODY_FORM_INPUTS written out); the ethnic mix, the age and the local targets: the intercept
COLUMNS = {"gender": [0, 5], "age": [0], "muscle": [0, 2], "weight": [0, 1, 2, 3, 6], "height": [0, 3, 5],
           "proportions": [0, 3, 4, 5], "african": [0], "asian": [0], "caucasian": [0]}


def _rows(n=8, seed=2):
    rng = np.random.default_rng(seed)
    return np.c_[rng.uniform(18, 32, n), rng.uniform(0.1, 0.9, n), rng.uniform(1.55, 1.95, n),
                 rng.uniform(0.5, 0.7, n), rng.integers(0, 2, n).astype(float)]


def _design(model, rows):
    z = (rows[:, :4] - model.param_center) / model.param_scale
    return np.c_[np.ones(len(rows)), z, 1.0 - rows[:, 4], z[:, 0] * z[:, 1]]


def _shape(row):
    return ArmShapeParams.from_vector(row[:4], sex=row[4])


def _model(monkeypatch, rows=None, seed=4, regularization=0.7, sex_regularization=0.2):
    """The tiny model with ``rows`` (default: 8 random subjects) and residuals that are arms of the stand-in space
    plus noise; its regularization weights apart (so the continuous and the sex weights are told apart)."""
    space, calls = _stand_in(monkeypatch)
    model = _tiny_model()
    rows = _rows() if rows is None else rows
    rng = np.random.default_rng(seed)
    mean, sigma = space.prior()
    res = []
    for row in rows:
        x = np.clip(mean + sigma * rng.normal(size=len(mean)) * 0.5, 0.0, None)
        x[9:] = 0.3 * rng.normal(size=len(x) - 9)
        arm = space.rest_and_joints(x)[0] + 0.001 * rng.normal(size=(N_V, 3))
        res.append((arm - model.base_vertices - length_displacements(model, _shape(row))).ravel())
    model = replace(model, shape_rows=rows, shape_residuals=np.array(res), regularization=regularization,
                    sex_regularization=sex_regularization,
                    subjects=[{"name": f"m{k}", "shape": {}, "n_meshes": 1, "source": "training"}
                              for k in range(len(rows))])
    return model, space, calls


def _ref_fit(model, space, rows, residuals, params):
    """``fit_body_form`` written from its docstring."""
    mean, sigma = space.prior()
    X = _design(model, rows)
    q = 3.0 * model.regularization
    w = np.r_[0.0, q, q, q, q, model.sex_regularization, q] ** 2
    U = (params - mean) / sigma
    A = np.zeros((7, U.shape[1]))
    for p in range(U.shape[1]):
        cols = COLUMNS[BODY_MACRO_NAMES[p]] if p < len(BODY_MACRO_NAMES) else [0]
        Xc = X[:, cols]
        A[cols, p] = np.linalg.lstsq(np.r_[Xc, np.diag(np.sqrt(w[cols]))], np.r_[U[:, p], np.zeros(len(cols))],
                                     rcond=None)[0]
    left = np.stack([(model.base_vertices + length_displacements(model, _shape(row)) + r.reshape(-1, 3)
                      - space.rest_and_joints(mean + sigma * (X[i] @ A))[0]).ravel()
                     for i, (row, r) in enumerate(zip(rows, residuals, strict=True))])
    return A, fit_shape_coefficients(model, rows, left)


def _ref_params(model, space, rows, residuals, prior_weight=SHAPE_ROW_PRIOR_WEIGHT):
    return np.stack([body_space_rest_mesh(space, model.base_vertices + length_displacements(model, _shape(row))
                                          + r.reshape(-1, 3), _shape(row), prior_weight)[1]
                     for row, r in zip(rows, residuals, strict=True)])


# --- the design and the columns ----------------------------------------------------------------------------------


def test_the_design_is_eq6s_with_the_bmi_muscularity_product_and_each_parameter_has_its_columns(monkeypatch):
    model, space, _ = _model(monkeypatch)
    rows = _rows(5, seed=9)
    np.testing.assert_allclose(body_form_design(model, rows), _design(model, rows), rtol=0, atol=1e-14)
    assert body_form_design(model, rows[0]).shape == (1, 7)
    for p, name in enumerate(BODY_MACRO_NAMES):
        assert body_form_columns(p) == COLUMNS[name], name
    for p in range(len(BODY_MACRO_NAMES), space.n_parameters + 2):
        assert body_form_columns(p) == [0]


# --- fit_body_form ------------------------------------------------------------------------------------------------


def test_fit_body_form_is_the_per_parameter_ridge_then_eq7_on_what_the_regressed_arm_leaves(monkeypatch):
    model, space, _ = _model(monkeypatch)
    rng = np.random.default_rng(7)
    mean, sigma = space.prior()
    params = mean + sigma * rng.normal(size=(len(model.shape_rows), space.n_parameters))
    A, S = fit_body_form(model, model.shape_rows, model.shape_residuals, params)
    A_ref, S_ref = _ref_fit(model, space, model.shape_rows, model.shape_residuals, params)
    assert A.shape == (7, space.n_parameters) and S.shape == model.shape_coeffs.shape
    np.testing.assert_allclose(A, A_ref, rtol=0, atol=1e-10)
    np.testing.assert_allclose(S, S_ref, rtol=0, atol=1e-10)
    # each weight acts: the continuous inputs' (times 3) and the sex column's
    for kw in (dict(regularization=0.3), dict(sex_regularization=2.0)):
        other = replace(model, **kw)
        A2, _ = fit_body_form(other, model.shape_rows, model.shape_residuals, params)
        np.testing.assert_allclose(A2, _ref_fit(other, space, model.shape_rows, model.shape_residuals, params)[0],
                                   rtol=0, atol=1e-10)
        assert np.abs(A2 - A).max() > 1e-4
    # parameters given as a list are taken
    A3, _ = fit_body_form(model, model.shape_rows, model.shape_residuals, params.tolist())
    np.testing.assert_allclose(A3, A, rtol=0, atol=1e-12)


def test_fit_body_form_on_exact_rows_regresses_the_parameters_and_leaves_no_residual_term(monkeypatch):
    """Rows that are the space's arms at parameters linear in their own inputs (no noise, tiny weights): the
    regression returns those parameters for a new shape and the linear term of what is left is ~0."""
    model, space, _ = _model(monkeypatch, regularization=1e-6, sex_regularization=1e-6)
    mean, sigma = space.prior()
    rows = model.shape_rows
    X = _design(model, rows)
    A_true = np.zeros((7, space.n_parameters))
    for p in range(space.n_parameters):
        cols = COLUMNS[BODY_MACRO_NAMES[p]] if p < len(BODY_MACRO_NAMES) else [0]
        A_true[cols, p] = 0.2 * np.cos(np.arange(len(cols)) + p)
    params = mean + sigma * (X @ A_true)
    res = np.stack([(space.rest_and_joints(x)[0] - model.base_vertices - length_displacements(model, _shape(r))).ravel()
                    for x, r in zip(params, rows, strict=True)])
    A, S = fit_body_form(model, rows, res, params)
    np.testing.assert_allclose(A, A_true, atol=1e-5)
    assert np.abs(S).max() < 1e-6


# --- shape_row_parameters ------------------------------------------------------------------------------------------


def test_each_rows_parameters_are_its_rest_mesh_projected_and_repeats_are_projected_once(monkeypatch):
    model, space, _ = _model(monkeypatch)
    rows = np.r_[model.shape_rows[:3], model.shape_rows[1:2], model.shape_rows[1:2]]
    res = np.r_[model.shape_residuals[:3], model.shape_residuals[1:2], model.shape_residuals[2:3]]
    seen = []
    real = mm.body_space_rest_mesh

    def spy(space_, rest, shape, prior_weight):
        seen.append(prior_weight)
        return real(space_, rest, shape, prior_weight)

    monkeypatch.setattr(mm, "body_space_rest_mesh", spy)
    got = shape_row_parameters(model, rows, res)
    assert len(seen) == 4 and set(seen) == {SHAPE_ROW_PRIOR_WEIGHT}  # row 3 repeats row 1 (same row, same mesh)
    np.testing.assert_allclose(got, _ref_params(model, space, rows, res), rtol=0, atol=1e-12)
    np.testing.assert_array_equal(got[3], got[1])
    assert got.shape == (5, space.n_parameters)
    seen.clear()
    w = shape_row_parameters(model, rows[:3], res[:3], prior_weight=30.0)
    assert set(seen) == {30.0}
    np.testing.assert_allclose(w, _ref_params(model, space, rows[:3], res[:3], 30.0), rtol=0, atol=1e-12)
    assert np.abs(w - got[:3]).max() > 1e-4


# --- the body form's rest arm ----------------------------------------------------------------------------------------


def _body_model(monkeypatch, seed=5):
    model, space, calls = _model(monkeypatch)
    rng = np.random.default_rng(seed)
    coeffs = 0.3 * rng.normal(size=(7, space.n_parameters))
    params = rng.normal(size=(len(model.shape_rows), space.n_parameters))
    return replace(model, shape_form="body", body_coeffs=coeffs, shape_params=params), space, calls


def test_the_body_forms_rest_arm_is_the_spaces_arm_at_the_regressed_parameters_plus_the_linear_term(monkeypatch):
    model, space, _ = _body_model(monkeypatch)
    mean, sigma = space.prior()
    for row in _rows(3, seed=11):
        shape = _shape(row)
        x = mean + sigma * (_design(model, row[None])[0] @ model.body_coeffs)
        np.testing.assert_allclose(regressed_body_parameters(model, shape), x, rtol=0, atol=1e-13)
        arm = space.rest_and_joints(x)[0]
        np.testing.assert_allclose(body_form_rest_vertices(model, shape), arm, rtol=0, atol=1e-13)
        linear = (np.r_[1.0, (row[:4] - model.param_center) / model.param_scale, 1.0 - row[4]]
                  @ model.shape_coeffs).reshape(-1, 3)
        want = linear + arm - model.base_vertices - length_displacements(model, shape)
        np.testing.assert_allclose(shape_displacements(model, shape), want, rtol=0, atol=1e-13)
        np.testing.assert_allclose(shape_displacements(replace(model, shape_form="linear"), shape), linear, rtol=0,
                                   atol=1e-13)


# --- with_shape_form -------------------------------------------------------------------------------------------------


def test_with_shape_form_learns_the_body_form_from_the_stored_rows_and_back(monkeypatch):
    model, space, _ = _model(monkeypatch)
    assert with_shape_form(model, "linear") is model
    body = with_shape_form(model, "body")
    P = _ref_params(model, space, model.shape_rows, model.shape_residuals)
    A, S = _ref_fit(model, space, model.shape_rows, model.shape_residuals, P)
    assert body.shape_form == "body"
    np.testing.assert_allclose(body.shape_params, P, rtol=0, atol=1e-12)
    np.testing.assert_allclose(body.body_coeffs, A, rtol=0, atol=1e-10)
    np.testing.assert_allclose(body.shape_coeffs, S, rtol=0, atol=1e-10)
    for k in ("pose_coeffs", "joint_coeffs", "shape_rows", "shape_residuals", "length_coeffs"):
        np.testing.assert_array_equal(getattr(body, k), getattr(model, k))
    assert with_shape_form(body, "body") is body
    back = with_shape_form(body, "linear")
    assert back.shape_form == "linear" and back.shape_params is None and back.body_coeffs is None
    np.testing.assert_allclose(back.shape_coeffs, fit_shape_coefficients(model, model.shape_rows,
                                                                         model.shape_residuals), rtol=0, atol=1e-12)
    for bad in ("Body", "", None):
        with pytest.raises(InputError, match=r"^shape_form=.* must be one of linear, body$"):
            with_shape_form(model, bad)


# --- the extension ------------------------------------------------------------------------------------------------


def test_extending_a_body_form_model_keeps_its_rows_parameters_and_projects_the_new_row(monkeypatch):
    model, space, calls = _model(monkeypatch)
    body = with_shape_form(model, "body")
    rest = _planted(space, np.r_[space.prior()[0][:9], 0.2, -0.1, 0.1], np.array([0.001, -0.002, 0.0]), noise=0.001)
    frames = _frames(body, rest, name="new")
    ext = extend_arm_model(body, frames)
    assert ext.shape_form == "body" and len(ext.shape_params) == len(model.shape_rows) + 1
    np.testing.assert_array_equal(ext.shape_params[:-1], body.shape_params)
    new = _ref_params(ext, space, ext.shape_rows[-1:], ext.shape_residuals[-1:])
    np.testing.assert_allclose(ext.shape_params[-1:], new, rtol=0, atol=1e-12)
    A, S = _ref_fit(ext, space, ext.shape_rows, ext.shape_residuals, ext.shape_params)
    np.testing.assert_allclose(ext.body_coeffs, A, rtol=0, atol=1e-10)
    np.testing.assert_allclose(ext.shape_coeffs, S, rtol=0, atol=1e-10)
    # stored parameters that do not match the rows (a linear model's, or none) are projected afresh, all of them
    for stale in (None, body.shape_params[:-1]):
        ext2 = extend_arm_model(replace(body, shape_params=stale), frames)
        np.testing.assert_allclose(ext2.shape_params, _ref_params(ext2, space, ext2.shape_rows, ext2.shape_residuals),
                                   rtol=0, atol=1e-12)
    # a linear model extended into the body form: its rows projected first, then the new one
    lin_to_body = extend_arm_model(model, frames, shape_form="body")
    assert lin_to_body.shape_form == "body"
    np.testing.assert_allclose(lin_to_body.shape_params, ext.shape_params, rtol=0, atol=1e-12)
    np.testing.assert_allclose(lin_to_body.body_coeffs, ext.body_coeffs, rtol=0, atol=1e-12)
    # and back: the linear form, Eq. 7 on every row
    to_lin = extend_arm_model(body, frames, shape_form="linear")
    assert to_lin.shape_form == "linear" and to_lin.shape_params is None and to_lin.body_coeffs is None
    np.testing.assert_allclose(to_lin.shape_coeffs, fit_shape_coefficients(ext, ext.shape_rows, ext.shape_residuals),
                               rtol=0, atol=1e-12)
    lin = extend_arm_model(model, frames)
    assert lin.shape_form == "linear" and lin.shape_params is None and lin.body_coeffs is None


def test_the_extensions_shape_form_is_checked_and_builds_the_space_only_when_needed(monkeypatch):
    model, space, calls = _model(monkeypatch)
    frames = _frames(model, space.rest_and_joints(space.prior()[0])[0], name="new")
    with pytest.raises(InputError, match=r"^shape_form='bent' must be one of linear, body$"):
        extend_arm_model(model, frames, shape_form="bent")
    assert calls == []
    extend_arm_model(model, frames)
    extend_arm_model(model, frames, shape_form="linear")
    assert calls == []  # the mesh rows of a linear model need no body space
    extend_arm_model(model, frames, shape_form="body")
    assert calls and calls[0] == ("tiny", "left")
    # a body-form extension with mesh rows keeps the captured mesh as the row (no body-space record)
    ext = extend_arm_model(model, frames, shape_form="body", captured_rest="mesh")
    assert "rest" not in ext.subjects[-1]
    ext_b = extend_arm_model(model, frames, shape_form="body", captured_rest="body")
    assert ext_b.subjects[-1]["rest"].startswith("body space")


# --- the version 3 file ---------------------------------------------------------------------------------------------


def test_a_body_form_model_saves_and_reads_back_exactly(monkeypatch, tmp_path):
    model, space, _ = _model(monkeypatch)
    body = with_shape_form(model, "body")
    save_arm_model(tmp_path / "b.npz", body)
    with np.load(tmp_path / "b.npz") as z:
        header = json.loads(str(z["header"]))
        assert {"shape_params", "body_coeffs"} <= set(z.files)
    assert header["version"] == 3 and header["shape_form"] == "body"
    assert header["body_space"] == {"local_targets": list(space.local_names)}
    back = load_arm_model(tmp_path / "b.npz")
    assert back.shape_form == "body" and back.version == 3
    np.testing.assert_array_equal(back.shape_params, body.shape_params)
    np.testing.assert_array_equal(back.body_coeffs, body.body_coeffs)
    np.testing.assert_array_equal(back.shape_coeffs, body.shape_coeffs)
    shape = _shape(model.shape_rows[0])
    np.testing.assert_array_equal(shape_displacements(back, shape), shape_displacements(body, shape))
    # the linear form: no body arrays, read back as linear
    save_arm_model(tmp_path / "l.npz", model)
    with np.load(tmp_path / "l.npz") as z:
        assert "shape_params" not in z.files and "body_coeffs" not in z.files
        assert json.loads(str(z["header"]))["shape_form"] == "linear"
        assert "body_space" not in json.loads(str(z["header"]))
    lin = load_arm_model(tmp_path / "l.npz")
    assert lin.shape_form == "linear" and lin.shape_params is None and lin.body_coeffs is None


def _rewrite(src, dst, header=None, drop=(), arrays=None):
    with np.load(src) as z:
        files = {k: np.array(z[k]) for k in z.files if k not in drop}
    h = json.loads(str(files.pop("header")))
    if header is not None:
        h = header(h)
    files.update(arrays or {})
    np.savez(dst, header=np.array(json.dumps(h)), **files)
    return dst


def test_version_2_files_read_as_linear_and_bad_body_form_files_are_refused(monkeypatch, tmp_path):
    model, space, _ = _model(monkeypatch)
    body = with_shape_form(model, "body")
    save_arm_model(tmp_path / "b.npz", body)
    save_arm_model(tmp_path / "l.npz", model)

    def v2(h):
        h = {k: v for k, v in h.items() if k not in ("shape_form", "body_space")}
        return {**h, "version": 2}

    old = load_arm_model(_rewrite(tmp_path / "l.npz", tmp_path / "v2.npz", v2))
    assert old.shape_form == "linear" and old.version == 3
    old_b = load_arm_model(_rewrite(tmp_path / "b.npz", tmp_path / "v2b.npz", v2))
    assert old_b.shape_form == "linear" and old_b.shape_params is None  # no form in a version 2 header
    P, A = body.shape_params, body.body_coeffs
    bad = {
        "form": dict(header=lambda h: {**h, "shape_form": "Body"}),
        "no params": dict(drop=("shape_params",)),
        "no coeffs": dict(drop=("body_coeffs",)),
        "params 1-D": dict(arrays={"shape_params": P[:, 0]}),
        "params rows": dict(arrays={"shape_params": P[:-1]}),
        "coeffs rows": dict(arrays={"body_coeffs": A[:-1]}),
        "coeffs cols": dict(arrays={"body_coeffs": A[:, :-1]}),
        "coeffs nan": dict(arrays={"body_coeffs": np.where(np.arange(A.size).reshape(A.shape) == 3, np.nan, A)}),
        "targets": dict(header=lambda h: {**h, "body_space": {"local_targets": ["local/other"]}}),
        "no targets": dict(header=lambda h: {k: v for k, v in h.items() if k != "body_space"}),
        "empty space": dict(header=lambda h: {**h, "body_space": None}),
    }
    msgs = {"form": r"shape_form 'Body' is not one of linear, body; rebuild the model$",
            "targets": r"was learned on another body shape space \(1 local targets, this body model's 3\); "
                       r"re-extend it with `bodystudio muscle model extend --shape-form body`$",
            "no targets": r"\(0 local targets, this body model's 3\)",
            "empty space": r"\(0 local targets, this body model's 3\)"}
    for name, kw in bad.items():
        path = _rewrite(tmp_path / "b.npz", tmp_path / f"bad-{name.replace(' ', '_')}.npz", **kw)
        want = msgs.get(name, r"lacks consistent shape_params / body_coeffs; rebuild the model$")
        with pytest.raises(FileFormatError, match=want):
            load_arm_model(path)
    # coefficients of another space's size with the saved targets matching: refused too
    bigger = np.c_[A, A[:, :1]]
    path = _rewrite(tmp_path / "b.npz", tmp_path / "wide.npz", arrays={"body_coeffs": bigger,
                                                                       "shape_params": np.c_[P, P[:, :1]]})
    with pytest.raises(FileFormatError, match="another body shape space"):
        load_arm_model(path)
    # the stand-in's local targets are what the file records
    assert space.n_parameters == len(BODY_MACRO_NAMES) + 3 and N_V == 12
    assert SHAPE.sex == 0.0


def test_rows_and_residuals_of_different_lengths_are_refused(monkeypatch):
    model, space, _ = _model(monkeypatch)
    rows, res = model.shape_rows, model.shape_residuals
    for r, d in ((rows, res[:-1]), (rows[:-1], res)):
        with pytest.raises(ValueError):
            shape_row_parameters(model, r, d)


def test_stored_parameters_are_kept_as_given_and_stale_ones_all_replaced(monkeypatch):
    """The rows' stored parameters (given, not a projection: as the planted 2k test gives them) are kept for the
    old rows; stored parameters whose count does not match the rows are replaced by projections, all of them (a
    one-row model included)."""
    model, space, _ = _model(monkeypatch)
    rng = np.random.default_rng(13)
    frames = _frames(model, space.rest_and_joints(space.prior()[0])[0], name="new", shape=SHAPE)
    given = space.prior()[0] + 0.1 * rng.normal(size=(len(model.shape_rows), space.n_parameters))
    body = replace(with_shape_form(model, "body"), shape_params=given)
    ext = extend_arm_model(body, frames)
    np.testing.assert_array_equal(ext.shape_params[:-1], given)
    np.testing.assert_allclose(ext.shape_params[-1:], _ref_params(ext, space, ext.shape_rows[-1:],
                                                                  ext.shape_residuals[-1:]), rtol=0, atol=1e-12)
    for stale in (given[:-1], given[:1]):
        ext2 = extend_arm_model(replace(body, shape_params=stale), frames)
        np.testing.assert_allclose(ext2.shape_params, _ref_params(ext2, space, ext2.shape_rows, ext2.shape_residuals),
                                   rtol=0, atol=1e-12)
    one = replace(body, shape_rows=model.shape_rows[:1], shape_residuals=model.shape_residuals[:1], shape_params=None)
    ext1 = extend_arm_model(one, frames)
    np.testing.assert_allclose(ext1.shape_params, _ref_params(ext1, space, ext1.shape_rows, ext1.shape_residuals),
                               rtol=0, atol=1e-12)


def test_body_rows_with_either_form_and_the_source_reach_the_record(monkeypatch):
    model, space, calls = _model(monkeypatch)
    frames = _frames(model, space.rest_and_joints(space.prior()[0])[0], name="new")
    for form in (None, "linear", "body"):
        ext = extend_arm_model(model, frames, captured_rest="body", shape_form=form)
        assert ext.subjects[-1]["rest"].startswith("body space"), form
        assert ext.subjects[-1]["source"] == "capture"
    assert extend_arm_model(model, frames, source="ground truth").subjects[-1]["source"] == "ground truth"
    ext = extend_arm_model(model, frames, captured_rest="body", shape_form="body", prior_weight=0.5)
    assert ext.subjects[-1]["rest"] == "body space (prior weight 0.5, weight macro 3)"
    ext = extend_arm_model(model, frames, captured_rest="body", prior_weight=0.5, weight_prior_weight=None)
    assert ext.subjects[-1]["rest"] == "body space (prior weight 0.5)"


def test_the_file_keeps_the_subjects_and_the_sex_weight_and_reads_versions_1_to_3_only(monkeypatch, tmp_path):
    model, space, _ = _model(monkeypatch)
    body = with_shape_form(model, "body")
    save_arm_model(tmp_path / "b.npz", body)
    back = load_arm_model(tmp_path / "b.npz")
    assert back.subjects == body.subjects and back.sex_regularization == 0.2 and back.regularization == 0.7
    save_arm_model(tmp_path / "l.npz", model)
    v1 = load_arm_model(_rewrite(tmp_path / "l.npz", tmp_path / "v1.npz",  # no sex column, no form: linear
                                 lambda h: {k: v for k, v in h.items() if k not in ("shape_form", "sex_regularization")}
                                 | {"version": 1}, arrays={"shape_rows": model.shape_rows[:, :4],
                                                           "shape_coeffs": model.shape_coeffs[:5]}))
    assert v1.shape_form == "linear" and v1.shape_params is None
    for bad in (4, 0, True, "3"):
        path = _rewrite(tmp_path / "b.npz", tmp_path / f"v{bad}.npz", lambda h, bad=bad: {**h, "version": bad})
        with pytest.raises(FileFormatError, match="is not supported"):
            load_arm_model(path)
