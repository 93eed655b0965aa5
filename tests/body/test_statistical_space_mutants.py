"""bodystudio.body.statistical's shape space, attribute map, measure / project and model files against references
independent of the module (issue 17, mutation testing): a toy model whose vertices, joints and least-squares
projection are summed / solved by hand (normal equations), the Gaussian conditioning of Eq. 4's attribute map
checked against a regression on the training attributes, the PCA against numpy's SVD of the centred data, the
population's bodies against build_body and measure_attributes, and the model file read back field by field."""

import logging
import re
from functools import cache

import numpy as np
import pytest

from bodystudio.body import statistical as st
from bodystudio.body.measure import ATTRIBUTE_NAMES, measure_attributes
from bodystudio.body.model import build_body, rig_definition
from bodystudio.body.population import sample_population
from bodystudio.errors import FileFormatError, InputError


def _toy(vertex_ids=None, resolution="2k"):
    """5 vertices, 3 components (not orthonormal), 2 bones, the 8 attributes correlated in 40 training bodies."""
    rng = np.random.default_rng(3)
    n, k, B, N = 5, 3, 2, 40
    A = rng.normal(size=(N, 8)) @ rng.normal(size=(8, 8)) + np.arange(8)
    return st.StatisticalBodyModel(
        resolution=resolution, rig="cmu_mb", mean=rng.normal(size=(n, 3)), basis=rng.normal(size=(k, n, 3)),
        stddev=np.array([3.0, 2.0, 1.0]), faces=np.array([[0, 1, 2], [2, 3, 4]]), weights=rng.random((n, B)),
        vertex_ids=vertex_ids, bone_names=("root", "child"), parents=np.array([-1, 0]), rolls=np.array([0.1, 0.2]),
        joint_mean_heads=rng.normal(size=(B, 3)), joint_mean_tails=rng.normal(size=(B, 3)),
        joint_basis_heads=rng.normal(size=(k, B, 3)), joint_basis_tails=rng.normal(size=(k, B, 3)),
        attribute_names=ATTRIBUTE_NAMES, attribute_map=rng.normal(size=(9, k)),
        coeffs_to_attribute_map=rng.normal(size=(k + 1, 8)), training_attributes=A,
        training_coeffs=rng.normal(size=(N, k)))


def test_vertices_and_joints_are_the_mean_plus_the_weighted_components():
    sm = _toy()
    c = [2, -1, 3]  # integers: taken as float64
    V, heads, tails = sm.mean.copy(), sm.joint_mean_heads.copy(), sm.joint_mean_tails.copy()
    for i, ci in enumerate(c):
        V += ci * sm.basis[i]
        heads += ci * sm.joint_basis_heads[i]
        tails += ci * sm.joint_basis_tails[i]
    np.testing.assert_allclose(sm.vertices(c), V, atol=1e-12)
    sk = sm.skeleton(c)
    np.testing.assert_allclose(sk.heads, heads, atol=1e-12)
    np.testing.assert_allclose(sk.tails, tails, atol=1e-12)
    assert sk.bone_names == ("root", "child")
    np.testing.assert_array_equal(sk.parents, [-1, 0])
    np.testing.assert_array_equal(sk.rolls, [0.1, 0.2])
    body = sm.body(c)
    np.testing.assert_allclose(body.vertices, V, atol=1e-12)
    np.testing.assert_allclose(body.skeleton.heads, heads, atol=1e-12)
    np.testing.assert_array_equal(body.faces, sm.faces)
    assert body.weights is sm.weights and body.resolution == "2k" and body.rig == "cmu_mb"  # not the default rig
    assert body.vertex_ids is None
    ids = np.array([4, 8, 15, 16, 23])
    assert _toy(ids).body(c).vertex_ids is ids


@pytest.mark.parametrize("bad", [[1.0, 2.0], [[1.0], [2.0], [3.0]], np.zeros(4)])
def test_a_wrong_number_of_coefficients_is_refused(bad):
    sm = _toy()
    shape = np.asarray(bad).shape
    for call in (sm.vertices, sm.skeleton, sm.measure):
        with pytest.raises(InputError) as err:
            call(bad)
        assert str(err.value) == f"expected 3 shape coefficients, got array of shape {shape}"


def test_project_is_the_least_squares_solution_of_the_normal_equations():
    sm = _toy()
    rng = np.random.default_rng(5)
    V = sm.mean + rng.normal(size=sm.mean.shape)  # not in the span
    Bf = sm.basis.reshape(3, -1).T
    expected = np.linalg.solve(Bf.T @ Bf, Bf.T @ (V - sm.mean).ravel())
    np.testing.assert_allclose(sm.project(V), expected, atol=1e-10)
    np.testing.assert_allclose(sm.project(sm.vertices([0.5, -2.0, 1.0]).tolist()), [0.5, -2.0, 1.0], atol=1e-10)
    with pytest.raises(InputError) as err:
        sm.project(np.zeros((4, 3)))
    assert str(err.value) == "expected (5, 3) vertices in the 2k template, got (4, 3)"


def test_unknown_attributes_are_listed_with_the_valid_ones():
    with pytest.raises(InputError) as err:
        _toy().attributes_to_coeffs({"zz": 1.0, "stature_m": 1.8, "bogus": 2.0})
    assert str(err.value) == f"unknown attribute(s) bogus, zz; valid: {', '.join(ATTRIBUTE_NAMES)}"


def _regressed(A, given):
    """Population mean, with the given attributes' offsets and the others' least-squares regression on them."""
    mu = A.mean(0)
    cols = [ATTRIBUTE_NAMES.index(n) for n in given]
    rest = [i for i in range(8) if i not in cols]
    Ac = A - mu
    slope = np.linalg.lstsq(Ac[:, cols], Ac[:, rest], rcond=None)[0]
    offsets = np.array([given[n] - mu[i] for n, i in zip(given, cols, strict=True)])
    a = mu.copy()
    a[cols] = list(given.values())
    a[rest] += offsets @ slope
    return a


@pytest.mark.parametrize("given", [
    {"stature_m": 1.7, "mass_kg": 4.0},
    {"hip_m": -2.0},
    {"muscularity": 9.0, "waist_m": 1.0, "chest_m": 0.5},
])
def test_attributes_to_coeffs_conditions_the_others_on_the_population(given):
    sm = _toy()
    a = _regressed(sm.training_attributes, given)
    np.testing.assert_allclose(sm.attributes_to_coeffs(given, refine=False), np.append(a, 1.0) @ sm.attribute_map,
                               atol=1e-9)


def test_attributes_to_coeffs_with_all_or_none_given():
    sm = _toy()
    every = {n: float(i) - 0.5 for i, n in enumerate(ATTRIBUTE_NAMES)}
    np.testing.assert_allclose(sm.attributes_to_coeffs(every, refine=False),
                               np.append(list(every.values()), 1.0) @ sm.attribute_map, atol=1e-12)
    mu = sm.training_attributes.mean(0)
    np.testing.assert_allclose(sm.attributes_to_coeffs({}), np.append(mu, 1.0) @ sm.attribute_map, atol=1e-12)


def test_attributes_to_coeffs_refines_only_the_given_mesh_attributes(monkeypatch):
    calls = []

    def spy(self, c, targets, iterations=5, with_residual=False):
        calls.append((np.array(c), dict(targets)))
        return c + 100.0

    monkeypatch.setattr(st.StatisticalBodyModel, "_match_measured", spy)
    sm = _toy()
    given = {"muscularity": 0.7, "mass_kg": 80, "stature_m": 1.9}
    linear = sm.attributes_to_coeffs(given, refine=False)
    assert not calls
    refined = sm.attributes_to_coeffs(given)
    np.testing.assert_allclose(refined, linear + 100.0)
    assert len(calls) == 1
    np.testing.assert_allclose(calls[0][0], linear, atol=1e-12)
    assert calls[0][1] == {"stature_m": 1.9, "mass_kg": 80.0}
    assert list(calls[0][1]) == ["stature_m", "mass_kg"]  # in the attribute order
    assert type(calls[0][1]["mass_kg"]) is float
    np.testing.assert_allclose(sm.attributes_to_coeffs({"muscularity": 0.7}), sm.attributes_to_coeffs(
        {"muscularity": 0.7}, refine=False))  # nothing measurable to refine
    assert len(calls) == 1


@cache
def _model_2k():
    """The cached 2k model as data (its loader is tested on the toy below); measure() runs in each test."""
    return st.load_statistical_model(resolution="2k", progress=False)


def test_measure_is_the_mesh_measurement_and_the_linear_muscularity():
    sm = _model_2k()
    c = sm.stddev * np.linspace(-1.0, 1.0, sm.n_components)
    V = sm.mean + np.einsum("i,inj->nj", c, sm.basis)
    got = sm.measure(c)
    ref = measure_attributes(V, sm.faces, vertex_ids=sm.vertex_ids)
    for n in ATTRIBUTE_NAMES[:-1]:
        assert got[n] == pytest.approx(ref[n], abs=1e-12)
    assert got["muscularity"] == pytest.approx(float(np.append(c, 1.0) @ sm.coeffs_to_attribute_map[:, 7]),
                                               abs=1e-12)
    np.testing.assert_allclose(sm._mesh_attributes(c, ["hip_m", "stature_m"]), [ref["hip_m"], ref["stature_m"]],
                               atol=1e-12)


def test_measure_of_a_full_body_model_names_its_template():
    body = build_body()
    toy = _toy()
    k = toy.n_components
    full = st.StatisticalBodyModel(**{**toy.__dict__, "mean": body.vertices, "faces": body.faces,
                                      "basis": np.zeros((k,) + body.vertices.shape), "vertex_ids": None,
                                      "resolution": "full"})
    got = full.measure(np.zeros(k))
    ref = measure_attributes(body.vertices, body.faces, resolution="full")
    for n in ATTRIBUTE_NAMES[:-1]:
        assert got[n] == pytest.approx(ref[n], abs=1e-12)


def _synthetic_training(n_samples, resolution="2k", rig="game_engine"):
    template = build_body(resolution=resolution, rig=rig)
    n, B = template.n_vertices, template.skeleton.n_bones
    rng = np.random.default_rng(11)
    X = (rng.normal(size=(n_samples, 4)) * [3.0, 2.0, 1.0, 0.5]) @ rng.normal(size=(4, 3 * n + 6 * B))
    X += 0.01 * rng.normal(size=X.shape) + np.linspace(0, 1, X.shape[1])
    A = rng.normal(size=(n_samples, 8)) + np.arange(8)
    return template, X, A


@pytest.mark.parametrize("rig, scale", [("game_engine", 1.0), ("cmu_mb", 1.0), ("game_engine", 1e-4)])
def test_the_pca_and_attribute_maps_against_an_svd_and_normal_equations(monkeypatch, caplog, rig, scale):
    N, k = 12, 3
    template, X, A = _synthetic_training(N, rig=rig)
    X = X * scale  # 1e-4: singular values below 1 (the real model's are a few tenths)
    calls = []

    def fake(n_samples, seed, resolution, rig, progress):
        calls.append((n_samples, seed, resolution, rig, progress))
        return X, A, template.faces

    monkeypatch.setattr(st, "population_training_set", fake)
    with caplog.at_level(logging.INFO, logger="bodystudio.body.statistical"):
        sm = st.build_statistical_model("2k", n_components=k, n_samples=N, seed=5, rig=rig, progress=False)
    assert calls == [(N, 5, "2k", rig, False)]
    n, B = template.n_vertices, template.skeleton.n_bones
    mean = X.mean(0)
    Xc = X - mean
    _, S, Vt = np.linalg.svd(Xc, full_matrices=False)
    basis = np.concatenate([sm.basis.reshape(k, -1), sm.joint_basis_heads.reshape(k, -1),
                            sm.joint_basis_tails.reshape(k, -1)], 1)
    np.testing.assert_allclose(np.abs(np.einsum("ij,ij->i", basis, Vt[:k])), 1.0, atol=1e-9)  # same axes
    np.testing.assert_allclose(sm.stddev, S[:k] / np.sqrt(N - 1), rtol=1e-9)
    explained = (S[:k] ** 2).sum() / (S ** 2).sum()
    assert caplog.records[-1].getMessage() == (f"statistical model 2k: {N} bodies, {k} components explain "
                                               f"{explained:.4f} of the variance")
    np.testing.assert_allclose(sm.training_coeffs, Xc @ basis.T, atol=1e-8 * scale)
    np.testing.assert_allclose(sm.mean, mean[: 3 * n].reshape(n, 3), atol=1e-12 * scale)
    np.testing.assert_allclose(sm.joint_mean_heads, mean[3 * n: 3 * n + 3 * B].reshape(B, 3), atol=1e-12)
    np.testing.assert_allclose(sm.joint_mean_tails, mean[3 * n + 3 * B:].reshape(B, 3), atol=1e-12)
    Z = np.hstack([A, np.ones((N, 1))])
    np.testing.assert_allclose(sm.attribute_map, np.linalg.solve(Z.T @ Z, Z.T @ sm.training_coeffs),
                               atol=1e-8 * scale)
    Zc = np.hstack([sm.training_coeffs, np.ones((N, 1))])
    np.testing.assert_allclose(sm.coeffs_to_attribute_map, np.linalg.solve(Zc.T @ Zc, Zc.T @ A), rtol=1e-6,
                               atol=1e-8 / scale)
    np.testing.assert_array_equal(sm.training_attributes, A)
    assert sm.resolution == "2k" and sm.rig == rig and sm.attribute_names == ATTRIBUTE_NAMES
    np.testing.assert_array_equal(sm.vertex_ids, template.vertex_ids)
    np.testing.assert_array_equal(sm.faces, template.faces)
    np.testing.assert_array_equal(sm.weights, template.weights)
    assert sm.bone_names == template.skeleton.bone_names
    np.testing.assert_array_equal(sm.parents, template.skeleton.parents)
    np.testing.assert_array_equal(sm.rolls, template.skeleton.rolls)


def test_the_number_of_components_is_checked(monkeypatch):
    template, X, A = _synthetic_training(4)
    monkeypatch.setattr(st, "population_training_set", lambda *a: (X, A, template.faces))
    for k in (0, 4):
        with pytest.raises(InputError) as err:
            st.build_statistical_model("2k", n_components=k, n_samples=4, progress=False)
        assert str(err.value) == f"n_components={k} must be between 1 and n_samples-1=3"
    assert st.build_statistical_model("2k", n_components=3, n_samples=4, progress=False).n_components == 3
    assert st.build_statistical_model("2k", n_components=1, n_samples=4, progress=False).n_components == 1


class _Stop(Exception):
    pass


def test_build_defaults(monkeypatch):
    calls = []

    def stub(*args):
        calls.append(args)
        raise _Stop

    monkeypatch.setattr(st, "population_training_set", stub)
    with pytest.raises(_Stop):
        st.build_statistical_model(n_samples=21)  # the default 20 components fit 21 bodies
    assert calls == [(21, 0, "6k", "game_engine", True)]
    with pytest.raises(_Stop):
        st.build_statistical_model()
    assert calls[-1] == (300, 0, "6k", "game_engine", True)
    with pytest.raises(InputError, match=r"^n_components=20 must be between 1 and n_samples-1=19$"):
        st.build_statistical_model(n_samples=20)


def test_population_training_set_shows_one_bar_step_per_body(monkeypatch):
    import rich.progress

    seen = []

    class Bar:
        def __init__(self, **kw):
            seen.append(("bar", kw))

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            return False

        def add_task(self, *args, **kw):
            seen.append(("task", args, kw))
            return 7

        def advance(self, task):
            seen.append(("advance", task))

    monkeypatch.setattr(rich.progress, "Progress", Bar)
    st.population_training_set(2, 4, "2k")
    assert seen == [("bar", {"disable": False, "transient": True}), ("task", ("population (2k)",), {"total": 2}),
                    ("advance", 7), ("advance", 7)]
    seen.clear()
    st.population_training_set(1, 4, "2k", progress=False)
    assert seen[0] == ("bar", {"disable": True, "transient": True})


def test_population_training_set_on_the_full_template():
    X, A, faces = st.population_training_set(1, 4, "full", progress=False)
    phenotype, local = sample_population(1, 4)[0]
    body = build_body(phenotype, local)
    np.testing.assert_allclose(X[0, : 3 * body.n_vertices], body.vertices.ravel(), atol=1e-12)
    m = measure_attributes(body.vertices, body.faces, resolution="full", muscularity=phenotype.muscle)
    np.testing.assert_allclose(A[0], [m[n] for n in ATTRIBUTE_NAMES], atol=1e-12)


def test_population_shapes_in_chunks_and_on_the_full_template():
    subjects = sample_population(3, seed=21)
    rig = rig_definition()
    for ids, chunk in ((build_body(resolution="2k").vertex_ids, 2), (None, 1)):
        shapes = list(st.population_shapes(subjects, ids, "game_engine", chunk=chunk))
        assert len(shapes) == 3
        for (phenotype, local), (V, heads, tails) in zip(subjects, shapes, strict=True):
            body = build_body(phenotype, local, resolution="2k" if ids is not None else "full")
            np.testing.assert_allclose(V, body.vertices, atol=1e-12)
            np.testing.assert_allclose(heads, body.skeleton.heads, atol=1e-12)
            np.testing.assert_allclose(tails, body.skeleton.tails, atol=1e-12)
            assert heads.shape == (len(rig.bone_names), 3)


def test_population_shapes_keep_targets_of_weight_exactly_one_and_take_the_rig():
    from bodystudio.body.phenotype import Phenotype

    subjects = [(Phenotype(gender=1.0), {}), (Phenotype(), {"upperarm-fat-decr-incr": 1.0})]
    ids = build_body(resolution="2k").vertex_ids
    for (phenotype, local), (V, heads, tails) in zip(subjects, st.population_shapes(subjects, ids, "cmu_mb"),
                                                     strict=True):
        body = build_body(phenotype, local, resolution="2k", rig="cmu_mb")
        np.testing.assert_allclose(V, body.vertices, atol=1e-12)
        np.testing.assert_allclose(heads, body.skeleton.heads, atol=1e-12)
        np.testing.assert_allclose(tails, body.skeleton.tails, atol=1e-12)


def test_population_training_set_on_another_rig():
    X, _, _ = st.population_training_set(1, 4, "2k", rig="cmu_mb", progress=False)
    phenotype, local = sample_population(1, 4)[0]
    body = build_body(phenotype, local, resolution="2k", rig="cmu_mb")
    np.testing.assert_allclose(X[0], np.concatenate([body.vertices.ravel(), body.skeleton.heads.ravel(),
                                                     body.skeleton.tails.ravel()]), atol=1e-12)


def test_population_training_set_stacks_the_bodies_and_their_measurements():
    X, A, faces = st.population_training_set(3, 4, "2k", progress=False)
    template = build_body(resolution="2k")
    np.testing.assert_array_equal(faces, template.faces)
    assert X.shape == (3, 3 * template.n_vertices + 6 * template.skeleton.n_bones)
    for i, (phenotype, local) in enumerate(sample_population(3, 4)):
        body = build_body(phenotype, local, resolution="2k")
        row = np.concatenate([body.vertices.ravel(), body.skeleton.heads.ravel(), body.skeleton.tails.ravel()])
        np.testing.assert_allclose(X[i], row, atol=1e-12)
        m = measure_attributes(body.vertices, body.faces, vertex_ids=body.vertex_ids, muscularity=phenotype.muscle)
        np.testing.assert_allclose(A[i], [m[n] for n in ATTRIBUTE_NAMES], atol=1e-12)


@pytest.mark.parametrize("ids", [None, np.array([3, 1, 4, 1, 5])])
def test_a_model_file_reads_back_field_by_field(tmp_path, ids):
    sm = _toy(ids)
    path = tmp_path / "m.npz"
    st.save_statistical_model(path, sm)
    with np.load(path) as z:  # numpy's own reader
        assert int(z["version"]) == st.STATISTICAL_MODEL_VERSION and str(z["resolution"]) == "2k"
        assert z["vertex_ids"].dtype == np.int64
        assert len(z["vertex_ids"]) == (0 if ids is None else 5)
    back = st.read_statistical_model(str(path))
    for f in st._ARRAY_FIELDS:
        np.testing.assert_array_equal(getattr(back, f), getattr(sm, f))
    assert back.resolution == "2k" and back.rig == "cmu_mb" and back.bone_names == ("root", "child")
    assert back.attribute_names == ATTRIBUTE_NAMES and type(back.resolution) is str
    assert all(type(b) is str for b in back.bone_names + back.attribute_names)
    if ids is None:
        assert back.vertex_ids is None
    else:
        np.testing.assert_array_equal(back.vertex_ids, ids)


def test_a_model_file_without_the_npz_suffix_is_written_whole(tmp_path):
    path = tmp_path / "model.cache"
    st.save_statistical_model(path, _toy())
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model.cache"]  # numpy appended nothing
    np.testing.assert_array_equal(st.read_statistical_model(path).basis, _toy().basis)


def test_a_model_file_of_another_version_or_broken_is_refused(tmp_path, monkeypatch):
    path = tmp_path / "m.npz"
    monkeypatch.setattr(st, "STATISTICAL_MODEL_VERSION", 7)
    st.save_statistical_model(path, _toy())
    monkeypatch.undo()
    with pytest.raises(FileFormatError) as err:
        st.read_statistical_model(path)
    assert str(err.value) == f"{path}: statistical model version 7, expected 1; delete it to rebuild"
    arrays = dict(np.load(path))
    arrays["version"] = np.array(1)
    del arrays["rolls"]
    np.savez(path, **arrays)
    with pytest.raises(FileFormatError) as err:
        st.read_statistical_model(path)
    assert str(err.value).startswith(f"{path}: not a readable statistical body model (")
    assert str(err.value).endswith("); delete it to rebuild")
    path.write_bytes(b"PK\x03\x04 broken")
    with pytest.raises(FileFormatError, match="not a readable statistical body model"):
        st.read_statistical_model(path)


def test_the_cache_path_names_its_inputs(monkeypatch, tmp_path):
    monkeypatch.setenv("BODYSTUDIO_HOME", str(tmp_path))
    p = st.statistical_model_path("2k", 20, 300, 0, "game_engine")
    assert p.parent == tmp_path / "compiled"
    assert re.fullmatch(r"statistical-2k-game_engine-k20-n300-s0-v1-[0-9a-f]{10}\.npz", p.name)
    assert st.statistical_model_path("2k", 20, 300, 0, "game_engine") == p
    assert st.statistical_model_path("2k", 20, 300, 1, "game_engine").name[-15:] != p.name[-15:]  # the seed
    assert st.statistical_model_path("6k", 20, 300, 0, "game_engine").name[-15:] != p.name[-15:]  # the template
    assert st.statistical_model_path("2k", 20, 300, 0, "cmu_mb").name.startswith("statistical-2k-cmu_mb-k20-")
    full = st.statistical_model_path("full", 5, 30, 0, "game_engine").name
    assert full.startswith("statistical-full-game_engine-k5-n30-s0-v1-") and full[-15:] != p.name[-15:]


@pytest.mark.parametrize("resolution", ["2k", "full"])
def test_the_cache_fingerprint_is_the_population_the_shape_and_the_template(monkeypatch, tmp_path, resolution):
    import hashlib

    from bodystudio.body.model import shaped_vertices, template_topology

    monkeypatch.setenv("BODYSTUDIO_HOME", str(tmp_path))
    ids, faces = template_topology(resolution)
    h = hashlib.sha1(repr(sample_population(4, 3)).encode())
    h.update(np.ascontiguousarray(shaped_vertices().round(7)).tobytes())
    h.update(np.ascontiguousarray(faces).tobytes())
    h.update(b"" if ids is None else np.ascontiguousarray(ids).tobytes())
    name = st.statistical_model_path(resolution, 20, 300, 3, "game_engine").name
    assert name == f"statistical-{resolution}-game_engine-k20-n300-s3-v1-{h.hexdigest()[:10]}.npz"


def test_load_builds_once_then_reads_and_rebuilds_a_broken_file(monkeypatch, tmp_path, caplog):
    path = tmp_path / "model.npz"
    built = []

    def build(*args):
        built.append(args)
        return _toy()

    monkeypatch.setattr(st, "statistical_model_path", lambda *args: built.append(("path",) + args) or path)
    monkeypatch.setattr(st, "build_statistical_model", build)
    first = st.load_statistical_model("2k", 3, 40, 9, "cmu_mb", progress=False)
    assert built == [("path", "2k", 3, 40, 9, "cmu_mb"), ("2k", 3, 40, 9, "cmu_mb", False)]
    np.testing.assert_array_equal(first.basis, _toy().basis)
    again = st.load_statistical_model("2k", 3, 40, 9, "cmu_mb", progress=False)
    assert len(built) == 3  # read, not built
    np.testing.assert_array_equal(again.basis, first.basis)
    path.write_bytes(b"not a model")
    with caplog.at_level(logging.WARNING, logger="bodystudio.body.statistical"):
        st.load_statistical_model("2k", 3, 40, 9, "cmu_mb", progress=False)
    assert len(built) == 5
    assert caplog.records[-1].getMessage().startswith(f"rebuilding: {path}: not a readable statistical body model (")
    st.read_statistical_model(path)  # the rebuilt model was written
    built.clear()
    st.load_statistical_model()
    assert built == [("path", "6k", 20, 300, 0, "game_engine")]  # the defaults; the file there is read
    path.unlink()
    st.load_statistical_model()
    assert built[-1] == ("6k", 20, 300, 0, "game_engine", True)  # built with the progress bar by default
