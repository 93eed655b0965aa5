"""The muscle commands through the real CLI entry point: synth arm -> muscle capture -> eval muscle."""

import json

import numpy as np
import pytest

from bodystudio.cli.main import main


@pytest.fixture(scope="module")
def arm_session(tmp_path_factory):
    """A short synthetic Kinect v2 arm sequence on the 2k template (subject 3, elbow flexion)."""
    out = tmp_path_factory.mktemp("arm") / "session"
    assert main(["synth", "arm", str(out), "--subject-seed", "3", "--frames", "4", "--resolution", "2k"]) == 0
    return out


def test_synth_arm_writes_ground_truth_per_frame(arm_session):
    from bodystudio.capture.session import open_session

    s = open_session(arm_session)
    assert s.frame_ids == [0, 1, 2, 3] and s.kinect is not None
    assert {"kinect_depth", "gt_arm_mesh", "gt_arm_pose"} <= set(s.streams)
    gt = s.frame(2).gt_arm_mesh
    assert gt is not None and 300 < gt.n_vertices < 600
    depth = s.frame(0).kinect_depth_m
    assert np.count_nonzero((depth > 0.5) & (depth < 1.5)) > 1000  # the subject at about 1 m


def test_capture_without_model_writes_one_folder(arm_session, tmp_path, capsys):
    from bodystudio.geometry.mesh import load_mesh

    out = tmp_path / "cap"
    assert main(["muscle", "capture", str(arm_session), "--out", str(out), "--no-model"]) == 0
    assert "4 frames (nicp)" in capsys.readouterr().out
    meshes = sorted((out / "meshes").glob("*.ply"))
    assert len(meshes) == 4
    params = json.loads((out / "params.json").read_text())
    assert params["mode"] == "nicp" and params["frame_ids"] == [0, 1, 2, 3]
    assert [p.name for p in tmp_path.iterdir()] == ["cap"]  # no staging leftovers
    assert load_mesh(meshes[0]).n_vertices == load_mesh(arm_session / "gt" / "arm" / "00000.ply").n_vertices


@pytest.fixture(scope="module")
def nicp_capture(arm_session, tmp_path_factory):
    out = tmp_path_factory.mktemp("cap") / "nicp"
    assert main(["muscle", "capture", str(arm_session), "--out", str(out), "--no-model"]) == 0
    return out


def test_eval_muscle_prints_the_issue_figures(nicp_capture, capsys):
    capsys.readouterr()
    assert main(["eval", "muscle", str(nicp_capture)]) == 0
    scores = json.loads(capsys.readouterr().out)
    keys = ["median_mm", "p90_mm", "surface_median_mm", "surface_p90_mm", "front_median_mm", "back_median_mm",
            "bulge_err_mm", "jitter_mm", "ms_per_frame"]
    assert list(scores)[:9] == keys
    assert scores["surface_median_mm"] <= scores["median_mm"]  # the skin is nearer than the vertex it should be
    assert all(np.isfinite(scores[k]) for k in keys)
    assert 0 < scores["median_mm"] <= scores["p90_mm"] < 100  # an arm, not garbage
    assert scores["mode"] == "nicp" and scores["n_frames"] == 4


def test_capture_glb_plays_the_captured_meshes(nicp_capture):
    from bodystudio.geometry.mesh import load_mesh
    from bodystudio.muscle.export import read_morph_glb

    seq = read_morph_glb(nicp_capture / "arm.glb")
    assert len(seq.targets) == 4
    for k in range(4):
        V = load_mesh(nicp_capture / "meshes" / f"{k:05d}.ply").vertices
        assert np.abs(seq.frame_vertices(k) - V).max() < 1e-5


@pytest.mark.slow
def test_model_build_capture_extend_info(arm_session, tmp_path, capsys):
    """The whole chain on a small model (2 training men, 1 woman): each command's output feeds the next."""
    model, cap, ext = tmp_path / "m.npz", tmp_path / "cap", tmp_path / "m2.npz"
    assert main(["muscle", "model", "build", "--out", str(model), "--resolution", "2k", "--subjects", "2",
                 "--women", "1", "--shapes", "1", "--poses", "3"]) == 0
    from bodystudio.capture.session import open_session

    truth = open_session(arm_session).gt_subject["arm"]["subject"]
    capsys.readouterr()
    assert main(["muscle", "model", "info", str(model)]) == 0
    span = json.loads(capsys.readouterr().out)["shape_range"]
    # a measured shape inside the 2-subject model's range (the capture keeps shapes near the training range)
    given = {k: round(sum(span[k]) / 2, 4) for k in ("bmi", "muscularity", "height_m", "arm_length_m")}
    assert main(["muscle", "capture", str(arm_session), "--out", str(cap), "--model", str(model),
                 "--shape", ",".join(f"{k}={v}" for k, v in given.items())]) == 0
    params = json.loads((cap / "params.json").read_text())
    assert params["mode"] == "full" and params["poses"][0] is not None
    assert params["shape"] == pytest.approx({**given, "sex": 1.0})  # the measured shape, not a fit; male by default
    assert main(["muscle", "model", "extend", str(model), str(cap), "--out", str(ext), "--stride", "2"]) == 0
    assert f"{cap}: shape from the measured subject of" in capsys.readouterr().err  # says where the shape came from
    assert main(["muscle", "model", "info", str(ext)]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["n_subjects"] == 4 and info["subjects"][-1]["name"] == "capture_cap"
    assert info["subjects"][-1]["n_meshes"] == 2 and info["subjects"][-1]["source"] == "capture"
    # the captured subject's shape is the session's measured one, not the fit
    assert info["subjects"][-1]["shape"]["bmi"] == pytest.approx(truth["bmi"])
