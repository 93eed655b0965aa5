"""Bad inputs of the mirror's source body and tracking (issue 12): no person, no joints, no depth, a wrong
model, unknown or out-of-range edits, broken source-body files, and `bodystudio mirror init` on sessions
that cannot be initialised. Each gives a one-line error naming the fix, never a traceback or a wrong body."""

from pathlib import Path

import numpy as np
import pytest

from bodystudio.body import build_body
from bodystudio.body.kinect import kinect_joint_names
from bodystudio.errors import FileFormatError, InputError
from bodystudio.mirror.init import (
    InitObservation,
    SourceBody,
    initialise_from_observations,
    load_source_body,
    refit_skeleton,
    save_source_body,
    transform_to_default_pose,
)
from bodystudio.mirror.reshape import check_edits, ramp_edits, target_coeffs
from bodystudio.mirror.track import ik_pose

from .conftest import assert_clean_error, run_inprocess

J = len(kinect_joint_names("v2"))


@pytest.fixture(scope="module")
def model():
    from bodystudio.body.statistical import load_statistical_model

    return load_statistical_model("2k", progress=False)


@pytest.fixture(scope="module")
def standing(model):
    """A noise-free standing body: its Kinect joints and a slab of points in front of it."""
    from bodystudio.body.kinect import kinect_joints

    sk = model.skeleton(np.zeros(model.n_components))
    K = kinect_joints(sk, sk.heads, sk.tails, "v2")
    V = model.mean
    return K, V[V[:, 2] > np.median(V[:, 2])]


def test_no_person_points(model, standing):
    K, _ = standing
    obs = [InitObservation(0, np.zeros((5, 3)), K, np.ones(J, bool), "v2")]
    with pytest.raises(InputError, match="depth points on the person"):
        initialise_from_observations(obs, model)


def test_no_depth_at_all(model, standing):
    K, _ = standing
    obs = [InitObservation(i, np.zeros((0, 3)), K, np.ones(J, bool), "v2") for i in range(3)]
    with pytest.raises(InputError, match="stand fully in view"):
        initialise_from_observations(obs, model)


def test_no_joints(model, standing):
    _, P = standing
    K = np.full((J, 3), np.nan)
    obs = [InitObservation(0, P, K, np.zeros(J, bool), "v2")]
    with pytest.raises(InputError, match="cannot be tracked|pelvis"):
        initialise_from_observations(obs, model)


def test_joints_of_the_wrong_shape(model, standing):
    _, P = standing
    with pytest.raises(InputError, match="25 Kinect v2 joints"):
        transform_to_default_pose(P, np.zeros((20, 3)), model.body(np.zeros(model.n_components)))
    with pytest.raises(InputError, match="one per Kinect"):
        ik_pose(model.skeleton(np.zeros(model.n_components)), np.zeros((J, 3)), np.ones(3, bool), "v2")


def test_points_far_from_the_joints_are_refused(model, standing):
    K, P = standing
    obs = [InitObservation(0, P + np.array([3.0, 0.0, 0.0]), K, np.ones(J, bool), "v2")]
    with pytest.raises(InputError, match="same sensor calibration"):
        initialise_from_observations(obs, model)


@pytest.mark.parametrize("weight", [-1.0, float("nan"), float("inf")])
def test_bad_bone_length_weight(model, standing, weight):
    """MIR12o's joint-distance option: a weight that is not a finite number >= 0 is refused before any work."""
    K, P = standing
    obs = [InitObservation(0, P, K, np.ones(J, bool), "v2")]
    with pytest.raises(InputError, match="bone_length_weight must be a finite number >= 0"):
        initialise_from_observations(obs, model, bone_length_weight=weight)


@pytest.mark.parametrize("choice", ["most", "", 3])
def test_bad_frame_choice(model, standing, choice):
    """mir12w's frame choice of the init: anything but 'first' / 'spread' is refused before any work."""
    K, P = standing
    obs = [InitObservation(0, P, K, np.ones(J, bool), "v2")]
    with pytest.raises(InputError, match="frame_choice must be 'first' or 'spread'"):
        initialise_from_observations(obs, model, frame_choice=choice)


def test_bone_lengths_without_any_tracked_pair(model, standing):
    """The option on frames whose joints track no pair in three frames adds no rows: the fit is the one without."""
    K, P = standing
    tracked = np.ones(J, bool)
    tracked[[kinect_joint_names("v2").index(n) for n in ("ShoulderLeft", "ShoulderRight", "HipLeft", "HipRight",
                                                          "SpineShoulder", "Neck")]] = False
    obs = [InitObservation(i, P, K, tracked, "v2") for i in range(2)]
    with_option = initialise_from_observations(obs, model, passes=1, bone_length_weight=1.0)
    without = initialise_from_observations(obs, model, passes=1)
    np.testing.assert_array_equal(with_option.coeffs, without.coeffs)


def test_wrong_model(standing):
    K, P = standing
    obs = [InitObservation(0, P, K, np.ones(J, bool), "v2")]
    with pytest.raises(InputError, match="StatisticalBodyModel"):
        initialise_from_observations(obs, build_body(resolution="2k"))


def test_source_body_of_another_model(model, tmp_path):
    from bodystudio.body.statistical import load_statistical_model

    c = np.zeros(model.n_components)
    src = SourceBody(c, model.vertices(c), refit_skeleton(model, c), (0,), 1.0)
    save_source_body(tmp_path / "s.npz", src)
    with pytest.raises(InputError, match="another statistical model"):
        load_source_body(tmp_path / "s.npz", load_statistical_model("6k", progress=False))


@pytest.mark.parametrize("content", [b"", b"not a zip", b"PK\x03\x04garbage"])
def test_broken_source_body_file(tmp_path, content):
    path = tmp_path / "source_body.npz"
    path.write_bytes(content)
    with pytest.raises(FileFormatError, match="rerun 'bodystudio mirror init'"):
        load_source_body(path)


def test_missing_source_body_file(tmp_path):
    with pytest.raises(FileFormatError, match="run 'bodystudio mirror init"):
        load_source_body(tmp_path / "nope.npz")


@pytest.mark.parametrize("edits, phrase", [
    ({"tallness": 0.1}, "unknown edit 'tallness'"),
    ({"taller": 0.5}, "taller=0.5 is out of range"),
    ({"heavier": -60}, "heavier=-60 is out of range"),
    ({"muscular": float("nan")}, "out of range"),
    ({"waist": "wide"}, "must be a number"),
])
def test_bad_edits(model, edits, phrase):
    with pytest.raises(InputError, match=phrase):
        target_coeffs(model, np.zeros(model.n_components), edits)
    with pytest.raises(InputError, match=phrase):
        ramp_edits({}, edits)


def test_edit_range_limits_are_accepted():
    assert check_edits({"taller": -0.3, "heavier": 40.0}) == {"taller": -0.3, "heavier": 40.0}


def test_ramp_step_must_be_positive():
    with pytest.raises(InputError, match="positive"):
        ramp_edits({}, {"taller": 0.1}, max_step=0.0)


# --- the CLI ------------------------------------------------------------------------------------------

def test_cli_init_refuses_a_session_without_kinect(studio, capfd):
    result = run_inprocess(["mirror", "init", studio.session], capfd)
    assert_clean_error(result, 2, "no Kinect calibration")
    assert not (Path(studio.session) / "mirror").exists()


@pytest.mark.parametrize("args, phrase", [
    (["--frames", "0"], "--frames 0"),
    (["--player", "7"], "--player 7"),
    (["--resolution", "full"], "--resolution"),
])
def test_cli_init_bad_options(studio, capfd, args, phrase):
    result = run_inprocess(["mirror", "init", studio.session, *args], capfd)
    assert_clean_error(result, 2, phrase)


def test_cli_init_missing_session(tmp_path, capfd):
    result = run_inprocess(["mirror", "init", tmp_path / "nothing"], capfd)
    assert_clean_error(result, 2, "no such session")


# --- `mirror init --silhouette-shape` (MIR12c) ------------------------------------------------------------------

def test_cli_init_silhouette_shape_refuses_a_session_without_kinect(studio, capfd):
    result = run_inprocess(["mirror", "init", studio.session, "--silhouette-shape"], capfd)
    assert_clean_error(result, 2, "no Kinect calibration")
    assert not (Path(studio.session) / "mirror").exists()


@pytest.mark.parametrize("args, phrase", [
    (["--silhouette-shape", "--player", "7"], "--player 7"),
    (["--silhouette-shape", "--frames", "0"], "--frames 0"),
])
def test_cli_init_silhouette_shape_bad_options(studio, capfd, args, phrase):
    result = run_inprocess(["mirror", "init", studio.session, *args], capfd)
    assert_clean_error(result, 2, phrase)


def test_cli_init_silhouette_shape_on_a_small_mirror_session(tmp_path, capfd):
    """The option on a 14-frame synthetic mirror session (4 actor frames, the actor standing): exit 0, the summary
    says so, the body loads, and stature and mass are the depth fit's (held) while the shape moved."""
    import json

    from bodystudio.mirror import synthetic

    session = synthetic.synth_mirror_session(tmp_path / "s", 3, n_frames=14, walk_in=False)
    summaries = {}
    for flag in ("--no-silhouette-shape", "--silhouette-shape"):
        result = run_inprocess(["mirror", "init", session.path, "--resolution", "2k", flag, "--force"], capfd)
        assert_clean_error(result, 0, "")
        summaries[flag] = json.loads((session.path / "mirror" / "source_body.json").read_text())
        bodies = np.load(session.path / "mirror" / "source_body.npz")
        summaries[flag]["coeffs"] = bodies["coeffs"]
    off, on = summaries["--no-silhouette-shape"], summaries["--silhouette-shape"]
    assert on["silhouette_shape"] is True and off["silhouette_shape"] is False
    assert abs(on["stature_m"] - off["stature_m"]) < 0.003 and abs(on["mass_kg"] - off["mass_kg"]) < 0.5
    assert np.abs(on["coeffs"] - off["coeffs"]).max() > 1e-4


def test_an_edit_the_body_cannot_take_is_refused(model):
    """A target the shape space cannot make with the other measurements held: one line, never a half-made body."""
    with pytest.raises(InputError, match=r"edit \(stature_m -0.3\) is not reachable .* use a smaller edit"):
        target_coeffs(model, np.zeros(model.n_components), {"taller": -0.3})


# --- `mirror init --trunk-refit` (MIR12r) ---------------------------------------------------------------------

def test_trunk_refit_of_an_unknown_joint_is_refused(model):
    from bodystudio.mirror.init import refit_trunk_joints

    with pytest.raises(InputError, match=r"unknown trunk joint 'Spine'; valid: SpineMid, SpineShoulder, Neck"):
        refit_trunk_joints(model.body(np.zeros(model.n_components)), [], None, joints=("Spine",))


def test_cli_init_trunk_refit_refuses_a_session_without_kinect(studio, capfd):
    result = run_inprocess(["mirror", "init", studio.session, "--trunk-refit"], capfd)
    assert_clean_error(result, 2, "no Kinect calibration")
    assert not (Path(studio.session) / "mirror").exists()


@pytest.mark.parametrize("args, phrase", [
    (["--trunk-refit", "--player", "7"], "--player 7"),
    (["--trunk-refit", "--frames", "0"], "--frames 0"),
])
def test_cli_init_trunk_refit_bad_options(studio, capfd, args, phrase):
    result = run_inprocess(["mirror", "init", studio.session, *args], capfd)
    assert_clean_error(result, 2, phrase)


# --- `mirror init --unpose-posture` (mir12v) ------------------------------------------------------------------

def test_unpose_posture_of_an_unknown_bone_is_refused(model):
    """A bone the model's rig lacks is one line naming it, before any frame is read."""
    with pytest.raises(InputError, match=r"unpose_posture_bones: unknown bone\(s\) \['Spine', 'neck'\]"):
        initialise_from_observations([], model, unpose_posture_bones=("spine_02", "neck", "Spine"))


def test_cli_init_unpose_posture_refuses_a_session_without_kinect(studio, capfd):
    result = run_inprocess(["mirror", "init", studio.session, "--unpose-posture"], capfd)
    assert_clean_error(result, 2, "no Kinect calibration")
    assert not (Path(studio.session) / "mirror").exists()


@pytest.mark.parametrize("args, phrase", [
    (["--unpose-posture", "--player", "0"], "--player 0"),
    (["--unpose-posture", "--frames", "901"], "--frames 901"),
    (["--unpose-posture", "--resolution", "13k"], "--resolution '13k'"),
])
def test_cli_init_unpose_posture_bad_options(studio, capfd, args, phrase):
    result = run_inprocess(["mirror", "init", studio.session, *args], capfd)
    assert_clean_error(result, 2, phrase)
    assert not (Path(studio.session) / "mirror").exists()
