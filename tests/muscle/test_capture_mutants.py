"""Fast tests of the arm capture code added since its mutation row (issue 17, docs/mutation/muscle-capture.md):
the visible-only refinement (Sec. 7 pairs of vertices the model mesh hides dropped), the placement prior and chest
weight reaching the sequence fit, the capture for extension, the recording's fingerprint and the checks of a
capture folder's shape, similarity and joints. Stand-ins and tiny meshes; the tiny model's three frames
(``scene``, as in test_capture_analytic.py) only where the real pipeline must run.
"""

import json
from functools import lru_cache
from types import SimpleNamespace

import numpy as np
import pytest

from bodystudio.errors import FileFormatError, InputError
from bodystudio.muscle import capture as cap_mod
from bodystudio.muscle.arm import ArmPose
from bodystudio.muscle.capture import ArmCapture, CaptureOptions, capture_arm_frames
from bodystudio.muscle.nicp import NicpOptions, apply_similarity
from tests.muscle.test_capture import _two_plates
from tests.muscle.test_capture_analytic import (
    Spies,  # records each wrapped call  # the scene of test_capture.py's visibility tests
    stub_capture_checks,  # trust4's self-checks stood in
)

FAST = dict(shape_frames=2, shape_rounds=1, first_frame_nicp_iterations=3, sequence_rounds=1, sequence_max_nfev=3,
            nicp=NicpOptions(iterations=2))


@lru_cache(maxsize=1)
def _tiny_model_path():
    """The conftest's tiny arm model (two synthetic subjects, a 3-body population), saved once per process in a
    temporary folder (a plain function, so docs/mutation/recheck_direct.py can build it before forking)."""
    import tempfile
    from pathlib import Path

    from bodystudio.body import build_body
    from bodystudio.muscle.arm import arm_template
    from bodystudio.muscle.model import learn_arm_model, save_arm_model
    from bodystudio.muscle.synthetic import sample_arm_subject, subject_arm_samples

    samples = subject_arm_samples(sample_arm_subject(1000), "2k", n_shapes=1, n_poses=2)
    samples += subject_arm_samples(sample_arm_subject(1001), "2k", n_shapes=1, n_poses=2)
    model = learn_arm_model(samples, arm_template(build_body(resolution="2k"), "left"), population_size=3)
    path = Path(tempfile.mkdtemp(prefix="tiny-arm-model-")) / "tiny.npz"
    save_arm_model(path, model)
    return path


@pytest.fixture(scope="module")
def scene():
    return _scene()


@lru_cache(maxsize=1)
def _scene():
    """The tiny model, its template and mean shape, a Kinect v2 at 1 m and 2 noise-free frames of its own mesh
    (elbow 0 and 15 deg) with the tracker's joints."""
    from bodystudio.body import build_body
    from bodystudio.capture.kinect import simulate_kinect_depth
    from bodystudio.geometry.camera import kinect_v2
    from bodystudio.muscle.arm import arm_template
    from bodystudio.muscle.model import ArmShapeParams, load_arm_model, model_joints, model_mesh
    from bodystudio.muscle.refine import _shape_bounds, posed_joints

    template = arm_template(build_body(resolution="2k"), "left")
    model = load_arm_model(_tiny_model_path(), template)
    shape = ArmShapeParams.from_vector(_shape_bounds(model, None)[2])
    J = model_joints(model, shape)
    s, e, _ = J
    target = 0.5 * (s + e) + np.array([0.0, 0.0, 0.05])
    sensor = kinect_v2(eye=tuple(target + np.array([np.sin(0.4), 0.1, np.cos(0.4)])), target=tuple(target))
    axis = np.cross(e - s, [0.0, 0.0, 1.0])
    axis /= np.linalg.norm(axis)
    depths, joints = [], []
    for k, deg in enumerate((0.0, 15.0)):
        pose = ArmPose(np.eye(4), np.stack([np.zeros(3), np.radians(deg) * axis, np.zeros(3)]))
        V = model_mesh(model, shape, pose)
        # the tracker's joints with a few mm of scatter, so the placement prior's weight is finite
        joints.append(posed_joints(J, pose) + np.random.default_rng(k).normal(0.0, 0.003, (3, 3)))
        depths.append(simulate_kinect_depth(V, template.faces, sensor, np.random.default_rng(k), noise=False))
    return SimpleNamespace(model=model, template=template, shape=shape, camera=sensor.depth, depths=depths,
                           tracker=np.stack(joints))


# --- the options' checks ------------------------------------------------------------------------------------

@pytest.mark.parametrize("name", ["sequence_placement_prior_m", "sequence_torso_pair_weight"])
def test_the_placement_prior_and_chest_weight_must_be_non_negative_numbers(name):
    for bad in (-0.001, float("nan")):
        with pytest.raises(InputError, match=rf"^{name} must be >= 0, got {bad}$"):
            CaptureOptions(**{name: bad})
    assert getattr(CaptureOptions(**{name: 0.0}), name) == 0.0
    assert getattr(CaptureOptions(**{name: 2.5}), name) == 2.5


def test_the_extension_setting_and_the_new_defaults():
    # the extension keeps the setting it was measured with, pinned (docs/muscle.md, "Dataset extension, eleventh
    # pass": the skeleton fit on the capture's defaults of that pass)
    assert cap_mod.EXTENSION_CAPTURE == {"sequence_fit_skeleton": True, "sequence_fit_root": True,
                                         "sequence_depth_huber_only": True, "body_rest_shape": True,
                                         "body_rest_tracker_weight": 10.0, "norm_limit": 0.2, "pose_refit": True,
                                         "refine_unseen_hold": 1.0, "refine_min_facing_cos": 0.35,
                                         "refine_depth_median_px": 1, "refine_depth_gaussian_sigma_px": 0.5,
                                         "sequence_min_facing_cos": 0.3,
                                         "pose_sigma_frames": 2.5, "pose_smoothing_degree": 0,
                                         "body_rest_population_locals": 0.0, "body_rest_local_sigma": 0.25,
                                         "body_rest_outline_weight": 0.0}
    o = CaptureOptions()
    # docs/muscle.md sixteenth pass: the outline pairs in the rest fit, the population's spread doubled
    assert (o.body_rest_outline_weight, o.body_rest_outline_offset_m, o.body_rest_population_locals) == (1.0, 0.0004,
                                                                                                         2.0)
    # docs/muscle.md fifteenth pass: the pose smoothing's local quadratic at sigma 5
    assert (o.pose_sigma_frames, o.pose_smoothing_degree) == (5.0, 2)
    # docs/muscle.md fourteenth pass (the rest arm): the pose fits without the grazing pairs, the rest fit's tracker 10
    assert o.sequence_min_facing_cos == 0.3 and o.body_rest_min_facing_cos == 0.0 and o.body_rest_tracker_weight == 10.0
    assert o.refine_visible_only is True and o.norm_limit == 0.2 and o.pose_refit is True
    assert o.refine_unseen_hold == 1.0 and o.refine_unseen_band_m == 0.02  # docs/muscle.md twelfth pass
    assert o.refine_min_facing_cos == 0.35  # docs/muscle.md fourteenth pass
    assert o.refine_depth_median_px == 1 and o.refine_depth_gaussian_sigma_px == 0.5
    assert o.sequence_placement_prior_m == 0.0 and o.sequence_torso_pair_weight == 1.0


# --- the recording's fingerprint ------------------------------------------------------------------------------

def test_is_from_compares_the_captured_frames_fingerprint(monkeypatch):
    import bodystudio.capture.session as session_mod

    asked = []
    monkeypatch.setattr(session_mod, "stream_fingerprint",
                        lambda session, stream, ids: asked.append((session, stream, list(ids))) or "F-" + session)
    c = ArmCapture(np.zeros((2, 1, 3)), np.zeros((0, 3)), [None, None], None, (1.0, np.eye(3), np.zeros(3)), "nicp",
                   "k", frame_ids=[4, 6])
    assert c.is_from("A") is None and asked == []  # written before the fingerprint existed: unknown
    c.source_fingerprint = "F-A"
    assert c.is_from("A") is True and c.is_from("B") is False
    assert asked == [("A", "kinect_depth", [4, 6]), ("B", "kinect_depth", [4, 6])]


def test_capture_arm_sequence_keeps_the_fingerprint_of_the_frames_it_read(monkeypatch):
    import bodystudio.capture.session as session_mod

    asked = []
    monkeypatch.setattr(session_mod, "stream_fingerprint",
                        lambda session, stream, ids: asked.append((session.path, stream, list(ids)))
                        or f"{stream}:{list(ids)}")
    monkeypatch.setattr(cap_mod, "capture_arm_frames", lambda depths, *a, **kw: ArmCapture(
        np.zeros((len(depths), 1, 3)), np.zeros((0, 3)), [], None, (1.0, np.eye(3), np.zeros(3)), "nicp", "k"))
    session = SimpleNamespace(path="/tmp/fake-session", kinect=SimpleNamespace(depth="CAM"), frame_ids=[0, 1, 2, 3],
                              frame=lambda f: SimpleNamespace(kinect_depth_m=np.zeros((2, 2)), kinect_joints=None))
    # the stand-in session has no depth camera to check the frames against: the path that reads every frame as it is
    c = cap_mod.capture_arm_sequence(session, None, SimpleNamespace(side="left"), frames=slice(1, 3),
                                     skip_bad_frames=False)
    assert c.source_fingerprint == "kinect_depth:[1, 2]" and asked == [("/tmp/fake-session", "kinect_depth", [1, 2])]


# --- the capture for extension ------------------------------------------------------------------------------

def test_the_capture_for_extension_sets_the_extension_options_and_needs_the_sequence_fit(monkeypatch):
    import bodystudio.capture.session as session_mod

    tiny_arm_model_path = _tiny_model_path()
    session = SimpleNamespace(path="S", frame_ids=[0, 1], gt_subject={"arm": {"resolution": "2k", "side": "left"}})
    monkeypatch.setattr(session_mod, "open_session", lambda p: session)
    seen = {}
    monkeypatch.setattr(cap_mod, "capture_arm_sequence",
                        lambda s, model, template, options, frames=None, known_shape=None, skip_bad_frames=True:
                        seen.update(o=options)
                        or SimpleNamespace())
    stub_capture_checks(monkeypatch)
    cap_mod.capture_session_arm("S", tiny_arm_model_path, mode="model", for_extension=True)
    assert seen["o"] == CaptureOptions(mode="model", sequence_fit_skeleton=True, sequence_fit_root=True,
                                       sequence_depth_huber_only=True, body_rest_shape=True,
                                       body_rest_tracker_weight=10.0, norm_limit=0.2, pose_refit=True,
                                       refine_unseen_hold=1.0, refine_min_facing_cos=0.35, refine_depth_median_px=1,
                                       refine_depth_gaussian_sigma_px=0.5, sequence_min_facing_cos=0.3,
                                       pose_sigma_frames=2.5, pose_smoothing_degree=0,
                                       body_rest_population_locals=0.0, body_rest_local_sigma=0.25,
                                       body_rest_outline_weight=0.0)
    cap_mod.capture_session_arm("S", tiny_arm_model_path, for_extension=True)
    assert seen["o"] == CaptureOptions(mode="full", **cap_mod.EXTENSION_CAPTURE)
    cap_mod.capture_session_arm("S", tiny_arm_model_path, mode="model", for_extension=False)
    assert seen["o"] == CaptureOptions(mode="model")
    cap_mod.capture_session_arm("S", tiny_arm_model_path, mode="model", sequence_fit=False)
    assert seen["o"] == CaptureOptions(mode="model", sequence_rounds=0)
    seen.clear()
    msg = (r"^the capture for extension fits the skeleton in the sequence fit: it needs the model and the sequence "
           r"fit$")
    for kwargs in ({"mode": "model", "sequence_fit": False}, {"mode": "nicp"}, {"mode": "nicp", "sequence_fit": False}):
        with pytest.raises(InputError, match=msg):
            cap_mod.capture_session_arm("S", tiny_arm_model_path, for_extension=True, **kwargs)
    assert seen == {}


# --- the sequence fit gets the placement prior and the chest weight ---------------------------------------------

def test_the_placement_prior_weight_and_chest_weight_reach_the_sequence_fit(scene, monkeypatch):
    """``sequence_placement_prior_m`` > 0 with a tracker: the weight ``refine.tracker_placement_prior_weight``
    gives for the tracker in the template's frame; 0 or no tracker: None. ``sequence_torso_pair_weight`` as given."""
    from bodystudio.muscle.refine import tracker_placement_prior_weight

    spies = Spies(monkeypatch, ("fit_arm_sequence_skeleton", "tracker_placement_prior_weight"))
    o = CaptureOptions(mode="model", **FAST, sequence_placement_prior_m=0.02, sequence_torso_pair_weight=0.25)
    c = capture_arm_frames(scene.depths, scene.camera, scene.template, scene.model, o, tracker_joints=scene.tracker,
                           known_shape=scene.shape)
    fits = spies["fit_arm_sequence_skeleton"]  # one per rest-shape round (the body rest shape is on by default)
    weights = spies["tracker_placement_prior_weight"]
    assert len(fits) >= 1 and len(weights) == len(fits)
    tracker_t = fits[0].args[6]
    for fit, w in zip(fits, weights, strict=True):
        assert fit.args[6] is tracker_t and w.args == (tracker_t, 0.02)
        assert fit.kwargs["tracker_placement_weight"] == tracker_placement_prior_weight(tracker_t, 0.02) > 0
        assert fit.kwargs["torso_pair_weight"] == 0.25
    n_weights = len(weights)
    np.testing.assert_allclose(apply_similarity(c.similarity, tracker_t.reshape(-1, 3)),
                               scene.tracker.reshape(-1, 3), atol=1e-9)  # the tracker in the template's frame
    for placement, tracker in ((0.0, scene.tracker), (0.02, None)):
        o = CaptureOptions(mode="model", **FAST, sequence_placement_prior_m=placement)
        capture_arm_frames(scene.depths, scene.camera, scene.template, scene.model, o, tracker_joints=tracker,
                           known_shape=scene.shape)
        assert spies["fit_arm_sequence_skeleton"][-1].kwargs["tracker_placement_weight"] is None
        assert spies["fit_arm_sequence_skeleton"][-1].kwargs["torso_pair_weight"] == 1.0
    assert len(spies["tracker_placement_prior_weight"]) == n_weights


# --- the visible-only refinement ---------------------------------------------------------------------------------

def test_model_visible_vertices_is_the_z_buffer_of_the_mesh_with_its_tolerance(monkeypatch):
    import bodystudio.muscle.evaluate as evaluate

    V, F, _, hidden, sensor = _two_plates()
    seen = cap_mod.model_visible_vertices(V, F, sensor)
    assert not seen[hidden].any() and seen[~hidden].sum() > 0.9 * (~hidden).sum()
    # 20 mm of tolerance: the back plate 12 mm behind the front one counts as seen
    assert cap_mod.model_visible_vertices(V, F, sensor, 0.02)[hidden].all()
    asked = []
    monkeypatch.setattr(evaluate, "visible_vertices", lambda *a: asked.append(a) or "SEEN")
    assert cap_mod.model_visible_vertices(V, F, sensor) == "SEEN"
    assert cap_mod.model_visible_vertices(V, F, sensor, tolerance_m=0.003) == "SEEN"
    assert asked[0][:3] == (V, F, sensor) and asked[0][3] == 0.01 and asked[1][3] == 0.003


def _lift_mm(o, similarity=(1.0, np.eye(3), np.zeros(3)), with_camera=True):
    """Sec. 7 on the two plates, the model mesh already right and given in the template's frame (the world mapped
    by ``similarity``^-1): the largest move of the hidden back-plate vertices towards the sensor, mm."""
    from scipy.spatial import cKDTree

    from bodystudio.muscle import nicp

    V, F, points, hidden, sensor = _two_plates()
    S_inv = cap_mod._inverse_similarity(similarity)
    Vt, Pt = apply_similarity(S_inv, V), apply_similarity(S_inv, points)
    normals = np.tile(similarity[1].T @ [0.0, 0.0, 1.0], (len(points), 1))
    adjacency = nicp.vertex_neighbourhoods(F, len(V))
    joints = np.array([[5.0, 5.0, 5.0], [6.0, 5.0, 5.0], [7.0, 5.0, 5.0]])  # far: no Sec. 7.2 joint factor
    joints = apply_similarity(S_inv, joints)
    poses = [ArmPose(np.eye(4), np.zeros((3, 3)))] * 3
    center = apply_similarity(S_inv, sensor.center[None])[0]
    out = cap_mod._refinement([Vt] * 3, poses, [(Pt, normals)] * 3, [cKDTree(Pt)] * 3, F, center,
                              np.ones(len(V), bool), adjacency, joints, o, cap_mod._Timer(),
                              camera=sensor if with_camera else None, similarity=similarity)
    lift = (apply_similarity(similarity, out[1]) - V) @ [0.0, 0.0, 1.0]
    return 1000 * lift[hidden].max()


def test_the_visible_only_refinement_drops_the_pairs_of_hidden_vertices():
    """Without the filter the hidden part of the back plate is lifted onto the front plate's points (measured
    ~8 mm); with it (the default) it stays; without a camera the filter cannot run."""
    o = CaptureOptions(detail_sigma_frames=0.0)
    assert o.refine_visible_only
    assert _lift_mm(o) < 0.5
    assert _lift_mm(CaptureOptions(detail_sigma_frames=0.0, refine_visible_only=False)) > 3.0
    assert _lift_mm(o, with_camera=False) > 3.0


def test_the_visible_only_filter_sees_the_mesh_in_the_world_through_the_similarity():
    """The model meshes are in the template's frame: the z-buffer must see them mapped to the world by the
    Sec. 5.1 similarity (here a rotation about y and a shift; read as world, the plates would face away)."""
    c, s = np.cos(2.5), np.sin(2.5)
    R = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    o = CaptureOptions(detail_sigma_frames=0.0)
    assert _lift_mm(o, similarity=(1.0, R, np.array([0.3, -0.2, 0.4]))) < 0.5
    assert _lift_mm(CaptureOptions(detail_sigma_frames=0.0, refine_visible_only=False),
                    similarity=(1.0, R, np.array([0.3, -0.2, 0.4]))) > 3.0


def test_the_full_capture_hands_the_refinement_the_camera_and_similarity(scene, monkeypatch):
    spies = Spies(monkeypatch, ("model_visible_vertices",))
    o = CaptureOptions(**FAST)
    c = capture_arm_frames(scene.depths, scene.camera, scene.template, scene.model, o, known_shape=scene.shape)
    calls = spies["model_visible_vertices"]
    assert len(calls) == 2
    for call, M in zip(calls, c.stages["model"], strict=True):
        np.testing.assert_allclose(call.args[0], M, atol=1e-12)  # the model mesh in the world
        assert call.args[1] is c.faces or np.array_equal(call.args[1], c.faces)
        assert call.args[2] is scene.camera
    spies["model_visible_vertices"].clear()
    capture_arm_frames(scene.depths, scene.camera, scene.template, scene.model,
                       CaptureOptions(**FAST, refine_visible_only=False), known_shape=scene.shape)
    assert spies["model_visible_vertices"] == []


# --- the folder's new fields and checks -------------------------------------------------------------------------

def _tiny_capture(shape=None, joints=None, fingerprint=None):
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    return ArmCapture(np.stack([V, V + 0.25]), F, [None, None], shape, (1.1, np.eye(3), np.array([0.1, 0.2, 0.3])),
                      "model", "k", {}, [10, 11], session_path="/s", joints=joints, source_fingerprint=fingerprint)


def test_the_fingerprint_and_joints_round_trip(tmp_path):
    J = np.arange(9.0).reshape(3, 3) / 7
    cap_mod.write_arm_capture(tmp_path / "a", _tiny_capture(joints=J, fingerprint="abc123"))
    params = json.loads((tmp_path / "a" / "params.json").read_text())
    assert params["session_fingerprint"] == "abc123" and params["joints"] == J.tolist()
    back = cap_mod.load_arm_capture(tmp_path / "a")
    assert back.source_fingerprint == "abc123" and back.session_path == "/s" and params["session"] == "/s"
    np.testing.assert_array_equal(back.joints, J)
    assert back.joints.shape == (3, 3) and back.joints.dtype == np.float64
    cap_mod.write_arm_capture(tmp_path / "b", _tiny_capture())
    params = json.loads((tmp_path / "b" / "params.json").read_text())
    assert params["session_fingerprint"] is None and params["joints"] is None
    back = cap_mod.load_arm_capture(tmp_path / "b")
    assert back.source_fingerprint is None and back.joints is None
    # a flat list of 9 is read as the (3, 3) joints
    params["joints"] = J.ravel().tolist()
    (tmp_path / "b" / "params.json").write_text(json.dumps(params))
    np.testing.assert_array_equal(cap_mod.load_arm_capture(tmp_path / "b").joints, J)


def _damaged(tmp_path, edit):
    out = tmp_path / "out"
    cap_mod.write_arm_capture(out, _tiny_capture(joints=np.eye(3)))
    params = json.loads((out / "params.json").read_text())
    edit(params)
    (out / "params.json").write_text(json.dumps(params))
    return out


@pytest.mark.parametrize("where", ["scale", "R", "t", "joints"])
def test_nan_or_infinite_similarity_or_joints_are_refused(tmp_path, where):
    def edit(params):
        if where == "joints":
            params["joints"][1][2] = float("nan")
        elif where == "scale":
            params["similarity"]["scale"] = float("inf")
        else:
            params["similarity"][where][2] = [float("nan")] * 3 if where == "R" else float("nan")

    out = _damaged(tmp_path, edit)
    name = "joints" if where == "joints" else "similarity"
    with pytest.raises(FileFormatError, match=rf"^.*out/params.json: {name} is NaN or infinite; re-run bodystudio "
                                              r"muscle capture$"):
        cap_mod.load_arm_capture(out)


NAN_SHAPE = r"ValueError: shape is NaN or infinite"


@pytest.mark.parametrize("shape, cause", [
    ({"vector": [1.0, float("nan")]}, r"ValueError: shape vector is NaN or infinite"),
    ({"vector": [1.0, float("inf")]}, r"ValueError: shape vector is NaN or infinite"),
    ({"bmi": 22.0, "muscularity": 0.5, "height_m": 1.8, "arm_length_m": 0.6, "colour": 1},
     r"ValueError: shape has unknown names \['colour'\]"),
    ({"bmi": 22.0, "muscularity": 0.5, "height_m": 1.8}, r"InputError: .*params.json shape: needs bmi"),
    ({"bmi": float("nan"), "muscularity": 0.5, "height_m": 1.8, "arm_length_m": 0.6}, NAN_SHAPE),
    ({"bmi": 22.0, "muscularity": 0.5, "height_m": float("inf"), "arm_length_m": 0.6}, NAN_SHAPE),
])
def test_a_bad_shape_in_params_is_refused(tmp_path, shape, cause):
    out = _damaged(tmp_path, lambda params: params.update(shape=shape))
    with pytest.raises(FileFormatError, match=rf"^.*out: not a readable arm capture folder \({cause}.*\); re-run "):
        cap_mod.load_arm_capture(out)


def test_the_shape_of_params_is_read_by_name_with_its_sex_or_as_a_vector():
    from bodystudio.muscle.model import ArmShapeParams

    assert cap_mod._capture_shape(None, "p") is None
    vec = {"vector": [1.0, 2.0, 3.0]}
    assert cap_mod._capture_shape(vec, "p") is vec
    named = {"bmi": 22.0, "muscularity": 0.5, "height_m": 1.8, "arm_length_m": 0.6, "sex": 0.0}
    parsed = cap_mod._capture_shape(named, "p")
    assert parsed == ArmShapeParams(22.0, 0.5, 1.8, 0.6, sex="female")
    male = cap_mod._capture_shape({k: v for k, v in named.items() if k != "sex"}, "p")
    assert male == ArmShapeParams(22.0, 0.5, 1.8, 0.6)
    with pytest.raises(InputError, match=r"^src shape: needs bmi"):
        cap_mod._capture_shape({"bmi": 1.0}, "src")
