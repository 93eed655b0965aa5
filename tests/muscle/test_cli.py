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
