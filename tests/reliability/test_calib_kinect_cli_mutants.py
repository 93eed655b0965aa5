"""``bodystudio calib kinect --report``: the studio report's board poses, with the detection, the plane calibration
and the PnP replaced by stand-ins (mutNN; mutII's test_kinect_wiring covers the rest of the command).

A report it cannot read or without board poses is refused naming it (not a crash), the board reaches the PnP, and
the placed sensor's file is read back with the session reader.
"""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from bodystudio.calib.board import CharucoBoardSpec, save_board_json

from .test_calib_cli_rest_mutants import _run

SPEC = CharucoBoardSpec(5, 4, 0.04, 0.03)
FRAMES = [3, 5, 8, 9, 10, 11]


@pytest.fixture
def stand_ins(tmp_path, monkeypatch):
    import bodystudio.calib.depth as depth_module
    from bodystudio.calib.world import rigid

    calls = {}
    W = rigid(cv2.Rodrigues(np.array([0.2, 2.9, -0.1]))[0], [0.3, -0.9, 2.4])

    def calibrate(rgbd, spec, views, board_to_world):
        return rgbd, {"n_views": len(views)}

    def pnp(color, spec, views, board_to_world):
        calls["pnp_spec"] = spec
        return W

    monkeypatch.setattr(depth_module, "detect_rgbd_capture", lambda folder, spec: (FRAMES, [f"v{f}" for f in FRAMES]))
    monkeypatch.setattr(depth_module, "calibrate_rgbd_sensor", calibrate)
    monkeypatch.setattr(depth_module, "sensor_to_studio", pnp)
    save_board_json(tmp_path / "board.json", SPEC)
    return calls


def test_report_without_board_poses_is_refused_naming_the_frames(tmp_path, stand_ins):
    (tmp_path / "report.json").write_text(json.dumps({"rms_px": 0.3}))
    code, out, err = _run("calib", "kinect", tmp_path, "--out", tmp_path / "k.json", "--report",
                          tmp_path / "report.json")
    assert (code, out) == (2, "")
    assert err == (f"error: {tmp_path / 'report.json'}: none of the Kinect's board frames ([3, 5, 8, 9, 10]...) was "
                   "seen by the studio cameras; capture boards seen by both\n")
    assert not (tmp_path / "k.json").exists()


def test_unreadable_report_is_named(tmp_path, stand_ins):
    (tmp_path / "report.json").write_text("{not json")
    code, out, err = _run("calib", "kinect", tmp_path, "--out", tmp_path / "k.json", "--report",
                          tmp_path / "report.json")
    assert (code, out) == (2, "")
    assert err.startswith(f"error: {tmp_path / 'report.json'}: not a valid calibration report (")
    assert err.endswith("); fix or regenerate the file\n")


def test_the_board_reaches_the_pnp(tmp_path, stand_ins):
    from bodystudio.capture.session import load_kinect_calibration

    poses = {"5": np.eye(4).tolist()}
    (tmp_path / "report.json").write_text(json.dumps({"board_to_world": poses}))
    code, out, err = _run("calib", "kinect", tmp_path, "--out", tmp_path / "k.json", "--report",
                          tmp_path / "report.json")
    assert (code, err) == (0, "")
    assert stand_ins["pnp_spec"] == SPEC
    assert load_kinect_calibration(tmp_path / "k.json").version == "v2"
