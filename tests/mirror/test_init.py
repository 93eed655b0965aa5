"""Source-body initialisation (§4 of Real-time Reshaping): transform to the default pose, Eq. 2, Eq. 3, save/load."""

import numpy as np
import pytest
from scipy.spatial import cKDTree

from bodystudio.mirror.init import (
    fit_shape,
    initialise_from_observations,
    load_source_body,
    refit_skeleton,
    save_source_body,
    transform_to_default_pose,
)
from tests.mirror.scene import synthetic_scene


@pytest.fixture(scope="module")
def source(walk_scene, model_6k):
    return initialise_from_observations(walk_scene.observations, model_6k, view_point=walk_scene.sensor.depth.center)


def test_initialisation_recovers_stature_and_mass(source, walk_scene, model_6k):
    m = model_6k.measure(source.coeffs)
    stature_err = abs(m["stature_m"] - walk_scene.truth["stature_m"])
    mass_err = abs(m["mass_kg"] - walk_scene.truth["mass_kg"])
    # measured: 6.4 mm and 1.1 kg on this 6-frame case (the scene's player mask leaves out the flying pixels
    # behind the silhouette; vertices seen at more than 75 degrees take no points). Before the grazing-angle
    # candidate limit and the looser outlier rejections: 9.7 mm, 3.7 kg with the same mask. Held-out
    # synthetic mirror sessions 201-206 (benchmarks/mirror_init_accuracy.py): max 8.3 mm, 2.7 kg.
    assert stature_err < 0.0095 and mass_err < 2.0
    # the mean shape (what a skipped fit returns) is far off for this subject, so the bounds mean something
    mean = model_6k.measure(np.zeros(model_6k.n_components))
    assert abs(mean["stature_m"] - walk_scene.truth["stature_m"]) > 0.1
    assert abs(mean["mass_kg"] - walk_scene.truth["mass_kg"]) > 15.0
    assert source.frames_used == tuple(range(6)) and 5.0 < source.residual_mm < 20.0


def test_initialised_surface_matches_the_true_body(source, walk_scene, model_6k):
    truth = walk_scene.body.vertices
    err = np.linalg.norm(source.vertices - truth, axis=1)
    # the source is in the template topology: compare vertex by vertex (measured median 9.0 mm; mean shape 118 mm)
    assert np.median(err) < 0.0135
    assert np.median(np.linalg.norm(model_6k.mean - truth, axis=1)) > 0.05


def test_transform_to_default_pose_unposes_the_cloud(model_6k):
    """Noise-free depth and joints of a walking subject: P_0 lies on the true rest body, P_in does not."""
    sc = synthetic_scene(8, n_frames=1, motion="arms_raise", frame_stride=1, noise=False, joint_noise_m=0.0)
    o = sc.observations[0]
    P0 = transform_to_default_pose(o.points, o.joints, sc.body, o.tracked, "v2", view_point=sc.sensor.depth.center)
    ok = np.all(np.isfinite(P0), axis=1)
    assert ok.mean() > 0.97
    tree = cKDTree(sc.body.vertices)
    d0 = tree.query(P0[ok])[0]
    d_in = tree.query(o.points)[0]
    # measured: median 7.6 mm (point to nearest vertex of a ~1.5 cm mesh), p90 13.5 mm; P_in: 193 mm
    assert np.median(d0) < 0.011 and np.percentile(d0, 90) < 0.020
    assert np.median(d_in) > 0.1


def test_fit_shape_recovers_coefficients_from_the_model_surface(model_6k):
    rng = np.random.default_rng(1)
    c_true = rng.normal(0.0, 1.0, model_6k.n_components) * model_6k.stddev * 0.8
    V = model_6k.vertices(c_true) + np.array([0.02, -0.01, 0.03])
    c = fit_shape(V, model_6k, correspondence=np.arange(len(V)), iterations=1)
    np.testing.assert_allclose(model_6k.vertices(c), model_6k.vertices(c_true), atol=1e-3)


def test_refit_skeleton_eq3_follows_the_shape(model_6k):
    rng = np.random.default_rng(2)
    errs, moved = [], []
    for _ in range(5):
        c = rng.normal(0.0, 1.0, model_6k.n_components) * model_6k.stddev
        exact = model_6k.skeleton(c)  # the rig's own joint definition on that shape
        sk = refit_skeleton(model_6k, c)
        errs.append(np.linalg.norm(sk.heads - exact.heads, axis=1).mean())
        moved.append(np.linalg.norm(model_6k.joint_mean_heads - exact.heads, axis=1).mean())
    # measured: 2.9 mm mean joint error; the default body's joints are 36 mm away
    assert np.mean(errs) < 0.005 and np.mean(moved) > 0.02


def test_source_body_round_trips(source, model_6k, tmp_path):
    path = tmp_path / "source_body.npz"
    save_source_body(path, source)
    back = load_source_body(path, model_6k)
    np.testing.assert_array_equal(back.coeffs, source.coeffs)
    np.testing.assert_array_equal(back.vertices, source.vertices)
    np.testing.assert_array_equal(back.skeleton.heads, source.skeleton.heads)
    assert back.frames_used == source.frames_used and back.weights is model_6k.weights


@pytest.mark.slow
def test_cli_init_on_a_synthetic_mirror_session(tmp_path, model_6k):
    """`bodystudio mirror init` end to end on a synthetic mirror session."""
    import json

    from bodystudio.cli.main import main
    from bodystudio.mirror import synthetic

    session = synthetic.synth_mirror_session(tmp_path / "s", 201, n_frames=40, model=model_6k)
    assert main(["mirror", "init", str(session.path), "--frames", "30"]) == 0
    summary = json.loads((session.path / "mirror" / "source_body.json").read_text())
    truth = session.read_json("gt/phenotype.json")["actors"][0]["measured"]
    back = load_source_body(session.path / "mirror" / "source_body.npz", model_6k)
    assert back.frames_used == tuple(summary["frames_used"]) and len(back.frames_used) <= 15
    # measured on this session: -2.1 mm, -1.8 kg (8 frames); the mean shape is 13 cm / 12.7 kg off for subject 201
    assert abs(summary["stature_m"] - truth["stature_m"]) < 0.006
    assert abs(summary["mass_kg"] - truth["mass_kg"]) < 3.0


def test_scene_player_mask_drops_flying_pixels_and_keeps_both_surfaces():
    from bodystudio.mirror.init_case import drop_flying_pixels

    depth = np.full((20, 30), 4.3)  # the wall
    depth[:, :12] = 2.6  # the person, its silhouette at column 11/12
    depth[5:15, 12] = np.linspace(2.8, 4.0, 10)  # flying pixels: mixtures of person and wall depth
    depth[0, 0] = 0.0  # no measurement
    out = drop_flying_pixels(depth)
    assert (out[5:15, 12] == 0).all()
    assert (out[:, :12][depth[:, :12] > 0] == 2.6).all()  # the person's edge pixels stay
    assert (out[:, 13:] == 4.3).all() and out[0, 0] == 0.0
    # beside empty pixels (counted as far) a pixel on the near side stays, one behind a nearer one goes
    d = np.zeros((5, 5))
    d[2, 1], d[2, 2] = 2.6, 2.75
    assert drop_flying_pixels(d)[2, 1] == 2.6 and drop_flying_pixels(d)[2, 2] == 0.0
