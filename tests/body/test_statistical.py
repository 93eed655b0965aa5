"""Statistical body model: held-out PCA reconstruction, joints in the PCA space, semantic edits, caching."""

import numpy as np
import pytest

from bodystudio.body import Phenotype, Pose, build_body
from bodystudio.body.population import sample_population
from bodystudio.body.statistical import (
    StatisticalBodyModel,
    load_statistical_model,
    population_shapes,
    read_statistical_model,
    save_statistical_model,
)
from bodystudio.errors import FileFormatError, InputError

HELD_OUT_SEED = 20261121  # training uses seed 0


@pytest.fixture(scope="module")
def sm() -> StatisticalBodyModel:
    """The cached default model (300 bodies, 20 components) at the 2k template; built on first use (~20 s)."""
    return load_statistical_model(resolution="2k", progress=False)


@pytest.fixture(scope="module")
def held_out(sm):
    subjects = sample_population(12, seed=HELD_OUT_SEED)
    return subjects, list(population_shapes(subjects, sm.vertex_ids, sm.rig))


def test_model_is_learned_from_300_bodies_with_20_components(sm):
    assert sm.training_coeffs.shape == (300, 20) and sm.n_components == 20
    assert sm.basis.shape == (20,) + sm.mean.shape and sm.faces.shape[1] == 3
    assert np.all(np.diff(sm.stddev) <= 0) and sm.stddev[-1] > 0
    assert sm.attribute_names == ("stature_m", "mass_kg", "chest_m", "waist_m", "hip_m", "arm_length_m",
                                  "leg_length_m", "muscularity")


def test_population_shapes_equal_build_body():
    subjects = sample_population(3, seed=7)
    shapes = list(population_shapes(subjects, build_body(resolution="2k").vertex_ids))
    for (phenotype, local), (V, heads, tails) in zip(subjects, shapes, strict=True):
        body = build_body(phenotype, local, resolution="2k")
        np.testing.assert_allclose(V, body.vertices, atol=1e-12)
        np.testing.assert_allclose(heads, body.skeleton.heads, atol=1e-12)
        np.testing.assert_allclose(tails, body.skeleton.tails, atol=1e-12)


def test_pca_reconstructs_held_out_bodies(sm, held_out):
    _, shapes = held_out
    errors = [np.linalg.norm(sm.vertices(sm.project(V)) - V, axis=1).mean() for V, _, _ in shapes]
    assert np.mean(errors) < 5e-3
    # and a plain mean body would not do: the bound is meaningful
    assert np.mean([np.linalg.norm(sm.mean - V, axis=1).mean() for V, _, _ in shapes]) > 10e-3


def test_joints_follow_the_shape_in_pca_space(sm, held_out):
    _, shapes = held_out
    for V, heads, tails in shapes[:6]:
        skel = sm.skeleton(sm.project(V))
        assert np.linalg.norm(skel.heads - heads, axis=1).mean() < 5e-3
        assert np.linalg.norm(skel.tails - tails, axis=1).max() < 0.02


def test_model_body_poses_with_the_rig(sm):
    body = sm.body(0.5 * sm.stddev)
    assert body.skeleton.bone_names == sm.bone_names and body.weights.shape == (len(body.vertices), len(sm.bone_names))
    rest, _ = body.pose(Pose.rest(len(sm.bone_names)))
    np.testing.assert_allclose(rest, body.vertices, atol=1e-10)
    rotations = np.zeros((len(sm.bone_names), 3))
    rotations[body.skeleton.index("lowerarm_l")] = [np.pi / 2, 0, 0]
    bent, _ = body.pose(Pose(rotations=rotations, translation=np.zeros(3)))
    assert np.linalg.norm(bent - rest, axis=1).max() > 0.1


@pytest.mark.parametrize("start", ["mean", "held_out"])
def test_semantic_edit_hits_stature_and_mass(sm, held_out, start):
    c0 = np.zeros(sm.n_components) if start == "mean" else sm.project(held_out[1][0][0])
    before = sm.measure(c0)
    taller = sm.measure(sm.edit(c0, {"stature_m": 0.05}))
    assert taller["stature_m"] - before["stature_m"] == pytest.approx(0.05, abs=0.005)
    assert abs(taller["mass_kg"] - before["mass_kg"]) < 1.0
    assert abs(taller["waist_m"] - before["waist_m"]) < 0.01
    heavier = sm.measure(sm.edit(c0, {"mass_kg": 5.0}))
    assert heavier["mass_kg"] - before["mass_kg"] == pytest.approx(5.0, abs=1.0)
    assert abs(heavier["stature_m"] - before["stature_m"]) < 0.005


def test_edit_with_correlated_attributes_following(sm):
    """others="follow": the unasked attributes change as the population predicts, the asked ones exactly."""
    c0 = np.zeros(sm.n_components)
    before = sm.measure(c0)
    c = sm.edit(c0, {"mass_kg": 10.0, "stature_m": 0.0}, others="follow")
    after = sm.measure(c)
    assert after["mass_kg"] - before["mass_kg"] == pytest.approx(10.0, abs=1.0)
    assert after["stature_m"] == pytest.approx(before["stature_m"], abs=0.005)
    assert after["waist_m"] - before["waist_m"] > 0.02  # a heavier body of the same height is wider
    # and it stays a plausible member of the population, unlike holding every girth fixed
    assert np.abs(c / sm.stddev).max() < np.abs(sm.edit(c0, {"mass_kg": 10.0}) / sm.stddev).max()
    with pytest.raises(InputError, match="valid: held, follow"):
        sm.edit(c0, {"mass_kg": 1.0}, others="free")


def test_linear_step_alone_is_eq4(sm):
    """Without Newton steps the edit is exactly c + lambda w_i, and moves stature the right way."""
    c0 = np.zeros(sm.n_components)
    c = sm.edit(c0, {"stature_m": 0.05}, iterations=0)
    np.testing.assert_allclose(c, 0.05 * sm.semantic_directions[0])
    assert sm.measure(c)["stature_m"] - sm.measure(c0)["stature_m"] == pytest.approx(0.05, abs=0.01)


def test_attributes_to_coeffs_gives_the_asked_measurements(sm):
    c = sm.attributes_to_coeffs({"stature_m": 1.62, "mass_kg": 68.0})
    m = sm.measure(c)
    assert m["stature_m"] == pytest.approx(1.62, abs=0.005)
    assert m["mass_kg"] == pytest.approx(68.0, abs=1.0)
    assert np.all(np.abs(c / sm.stddev) < 4)  # a plausible member of the population


def test_default_bodies_project_to_plausible_coefficients(sm):
    female = build_body(Phenotype(gender=0.0), resolution="2k")
    male = build_body(Phenotype(gender=1.0), resolution="2k")
    cf, cm = sm.project(female.vertices), sm.project(male.vertices)
    assert sm.measure(cm)["stature_m"] > sm.measure(cf)["stature_m"] + 0.05
    assert np.linalg.norm(sm.vertices(cf) - female.vertices, axis=1).mean() < 5e-3


def test_bad_input(sm):
    with pytest.raises(InputError, match="valid: stature_m"):
        sm.edit(np.zeros(sm.n_components), {"height_cm": 5})
    with pytest.raises(InputError, match="20 shape coefficients"):
        sm.vertices(np.zeros(3))
    with pytest.raises(InputError, match="2k template"):
        sm.project(np.zeros((10, 3)))
    with pytest.raises(InputError, match="resolution"):
        load_statistical_model(resolution="99k")


def test_save_read_roundtrip_and_corrupt_file(sm, tmp_path):
    path = tmp_path / "model.npz"
    save_statistical_model(path, sm)
    again = read_statistical_model(path)
    np.testing.assert_array_equal(again.basis, sm.basis)
    assert again.bone_names == sm.bone_names and again.vertex_ids is not None
    np.testing.assert_allclose(again.vertices(sm.stddev), sm.vertices(sm.stddev))
    path.write_bytes(path.read_bytes()[:1000])
    with pytest.raises(FileFormatError, match="model.npz"):
        read_statistical_model(path)


def test_corrupt_cache_is_rebuilt_not_used(tmp_path, monkeypatch):
    import bodystudio.body.statistical as statistical

    path = tmp_path / "cached.npz"
    path.write_bytes(b"not a model")
    monkeypatch.setattr(statistical, "statistical_model_path", lambda *args: path)
    model = load_statistical_model(resolution="2k", n_components=4, n_samples=30, seed=3, progress=False)
    assert model.n_components == 4 and model.training_coeffs.shape == (30, 4)
    assert read_statistical_model(path).n_components == 4
