"""The monocular fit of §4-5 (garment/fit.py) against a small synthetic garment session.

One 6-frame 240x320 walk (2k body) is fitted once per module with the user stature from the ground truth.
Bounds are set from the measured figures (docs/garment.md) with a margin. A planted bug that fails them:
the pose not optimised (7.5 px, IoU 0.77), the lights not estimated, §5's chromaticity materials and
light sparsity dropped (21 deg against the 10 deg bound). NOT caught: the Nelder-Mead shape
stages skipped (they barely improve on the stature-matched start; an open item of issue 13).
"""

import numpy as np
import pytest

from bodystudio.errors import InputError

SEED = 4  # hidden subjects for the documented figures are 3, 11, 21


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    from bodystudio.garment.synthetic import synth_garment_session

    return synth_garment_session(tmp_path_factory.mktemp("gfit") / "s", subject_seed=SEED, n_frames=6,
                                 resolution=(240, 320), template="2k", texture_size=128)


@pytest.fixture(scope="module")
def fitted(session, tmp_path_factory):
    from bodystudio.garment.fit import fit_garment_video

    out = tmp_path_factory.mktemp("gfit_out") / "fit"
    fit = fit_garment_video(session.path, session.gt_subject["stature_m"], out)
    return fit, out


@pytest.fixture(scope="module")
def scores(fitted, session):
    from bodystudio.garment.evaluate import fit_errors

    scores = fit_errors(fitted[0], session)
    print("garment fit scores:", scores)  # visible with -s: the figures the bounds below were set from
    return scores


def test_fit_recovers_stature_and_shape(scores):
    assert scores["stature_err_mm"] <= 10.0, scores
    # the start (the default body at the given stature) is 15.5 mm off for this subject; measured 15.8 with the
    # shape refinement and its 4 mm clothing allowance (gar13c; 14.8 without it, 14.9 before the shape prior of
    # the local modifiers; on the 480x640 hidden subjects the refinement gains 0.8-5 mm).
    # The Nelder-Mead stages barely improve on the stature match (docs/garment.md), so this bound does not
    # catch them being skipped; it catches a shape that drifts away from the silhouettes.
    assert scores["shape_err_mm"] <= 17.0, scores


def test_fit_recovers_pose(scores):
    assert scores["joint_err_px"] <= 4.0, scores
    # measured 2.29 px / 58 mm / IoU 0.901 with the pose refinement on the refined shape (gar13d, step 4c; its own
    # test is test_garment_pose_refine.py); 2.47 px / 61 mm / IoU 0.904 with the shape refinement alone
    # (2.55 / 61 / 0.936 before the shape refinement: its 4 mm clothing
    # allowance leaves the body deliberately inside the clothed matte; 2.6 / 63 / 0.932 before the shape prior);
    # the pose not optimised gives IoU 0.77
    assert scores["joint_err_mm"] <= 80.0, scores
    assert scores["silhouette_iou"] >= 0.88, scores


def test_fit_recovers_light_and_albedo(scores):
    # the goal: 10 deg. Measured 4.5 deg / albedo 0.110 with the pose refinement (gar13d), 3.3 deg /
    # albedo 0.109 with the shape refinement alone (gar13c), 6.0 deg
    # with the shape prior (3.97 before it; 3.1-9.1 on hidden subjects); the first version of §5 (per-vertex
    # albedo, no sparsity: estimate_appearance(grouped=False, sparsity=0)) gave 21 deg
    assert scores["light_dir_err_deg"] <= 10.0, scores
    assert scores["albedo_err"] <= 0.14, scores  # measured 0.114 here (first version 0.146), 0.075-0.107 hidden


def test_fit_folder_round_trip(fitted):
    from bodystudio.garment.fitfile import load_garment_fit

    fit, out = fitted
    back = load_garment_fit(out)
    np.testing.assert_allclose(back.rotations, fit.rotations)
    assert back.lighting is not None and back.albedo is not None
    assert set(back.timings_ms) >= {"masks", "shape", "pose", "appearance"}


def test_pose_space_matches_body_skinning():
    """The fit's own forward kinematics and four-weight skinning agree with the body package."""
    from bodystudio.body import build_body
    from bodystudio.body.skinning import skinning_transforms
    from bodystudio.garment.fit import pose_space

    body = build_body(resolution="2k")
    space = pose_space(body)
    x = np.random.default_rng(1).normal(0, 0.3, space.n_params)
    np.testing.assert_allclose(space.transforms(x), skinning_transforms(body.skeleton, space.pose(x)), atol=1e-12)
    V_full, _ = body.pose(space.pose(x))
    assert np.percentile(np.linalg.norm(space.vertices(x) - V_full, axis=1), 99) < 0.01


def test_temporal_term_grows_exponentially():
    """Eq. 5 in its smooth form: zero at no change, symmetric, faster than quadratic for big jumps."""
    from bodystudio.garment.fit import temporal_residuals

    x = np.zeros(12)
    assert np.allclose(temporal_residuals(x, x), 0)
    small, big = np.zeros(12), np.zeros(12)
    small[7], big[7] = 0.1, 1.0
    e_small, e_big = (float(np.sum(temporal_residuals(v, x) ** 2)) for v in (small, big))
    assert e_big > 100 * e_small * 1.5
    assert np.isclose(e_small, float(np.sum(temporal_residuals(-small, x) ** 2)))


def test_interpenetration_term_sees_an_arm_in_the_chest():
    from bodystudio.body import build_body
    from bodystudio.garment.fit import interpenetration_residuals, penetration_spheres, pose_space

    body = build_body(resolution="2k")
    space = pose_space(body)
    spheres = penetration_spheres(body)
    x = np.zeros(space.n_params)
    x[6:] = space.base[space.bone_ids].ravel()
    T = space.transforms(x)
    assert interpenetration_residuals(space.vertices(x), T, spheres).max() < 1e-3
    # forearm swung into the torso: the left upper arm rotated forward and inward
    names = list(body.skeleton.bone_names)
    idx = 6 + 3 * list(space.bone_ids).index(names.index("lowerarm_l"))
    hits = []
    for angle in np.linspace(-2.5, 2.5, 11):
        for axis in range(3):
            y = x.copy()
            y[idx + axis] += angle
            hits.append(interpenetration_residuals(space.vertices(y), space.transforms(y), spheres).max())
    assert max(hits) > 0.02


def test_keyframe_constraints_pull_a_joint(tmp_path):
    import json

    from bodystudio.body import build_body
    from bodystudio.garment.fit import KeyframeConstraints, keyframe_residuals

    body = build_body(resolution="2k")
    path = tmp_path / "keys.json"
    path.write_text(json.dumps({"frames": {"3": {"hand_l": [100.0, 120.0]}}}))
    c = KeyframeConstraints.load(path, body.skeleton.bone_names).points
    assert set(c) == {3}
    from bodystudio.garment.fit import camera_hypothesis

    cam = camera_hypothesis(240, 320)
    J = body.skeleton.heads.copy()
    J[:, 2] -= 3.0
    r = keyframe_residuals(J, cam, c[3], list(body.skeleton.bone_names))
    assert r.shape == (2,) and np.allclose(r, cam.project(J[[body.skeleton.index("hand_l")]])[0] - [100, 120])
    path.write_text(json.dumps({"frames": {"3": {"wing_l": [1, 2]}}}))
    with pytest.raises(Exception, match="unknown joint 'wing_l'"):
        KeyframeConstraints.load(path, body.skeleton.bone_names)


def test_stature_out_of_range_is_refused(tmp_path):
    from bodystudio.garment.fit import fit_garment_video

    with pytest.raises(InputError, match="between 0.5 and 2.5"):
        fit_garment_video(tmp_path, 3.0, tmp_path / "out")


def test_pose_residuals_stay_finite_when_the_body_passes_behind_the_camera():
    """A trial step that carries the body through the camera gives large, finite residuals (it used to give
    NaN pixels, and the KD-tree of the silhouette term raised on a video of noise)."""
    from bodystudio.body import build_body
    from bodystudio.garment.fit import (
        PoseProblem,
        camera_hypothesis,
        finite_projection,
        penetration_spheres,
        pose_residuals,
        pose_space,
        silhouette_target,
    )

    body = build_body(resolution="2k")
    space = pose_space(body)
    cam = camera_hypothesis(160, 120)  # 1 m high, looking along -z
    mask = np.zeros((120, 160), bool)
    mask[20:100, 60:100] = True
    problem = PoseProblem(space, cam, silhouette_target(mask), penetration_spheres(body))
    x = np.zeros(space.n_params)
    x[6:] = space.base[space.bone_ids].ravel()
    x[3:6] = (0.0, 0.0, -3.0)  # in front of the camera
    in_front = pose_residuals(x, problem)
    x[5] = 3.0  # behind it
    behind = pose_residuals(x, problem)
    assert np.isfinite(in_front).all() and np.isfinite(behind).all()
    assert np.linalg.norm(behind) > 5 * np.linalg.norm(in_front)
    uv = finite_projection(cam, np.array([[0.0, 1.0, -2.0], [0.0, 1.0, 1.0], [0.0, 1.0, -0.01]]), (120, 160))
    assert np.allclose(uv[0], cam.project(np.array([[0.0, 1.0, -2.0]]))[0])
    assert np.allclose(uv[1:], [(-480.0, -360.0)] * 2)
