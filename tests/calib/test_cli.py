"""Calibration CLI and capture-folder errors; the rendered end-to-end run is marked slow."""

import json

import numpy as np
import pytest

from bodystudio.calib.board import CharucoBoardSpec, save_board_json
from bodystudio.calib.observations import detect_capture
from bodystudio.calib.synthetic import write_png
from bodystudio.cli.main import main
from bodystudio.errors import SessionError
from bodystudio.geometry.camera import ring_rig, save_cameras_json


def _blank_capture(tmp_path, sizes):
    save_board_json(tmp_path / "board.json", CharucoBoardSpec())
    for cam, frames in sizes.items():
        for f, (w, h) in enumerate(frames):
            write_png(tmp_path / cam / f"{f:05d}.png", np.full((h, w), 128, np.uint8))
    return tmp_path


def test_images_without_board_name_the_camera(tmp_path, capsys):
    folder = _blank_capture(tmp_path, {"cam_00": [(64, 48)] * 2, "cam_01": [(64, 48)] * 2})
    with pytest.raises(SessionError, match="camera cam_00: no ChArUco board found"):
        detect_capture(folder, CharucoBoardSpec())
    assert main(["calibrate", str(folder), "--out", str(tmp_path / "out.json")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: camera cam_00") and "\n" not in err
    assert not (tmp_path / "out.json").exists()


def test_inconsistent_image_sizes_name_the_camera(tmp_path):
    folder = _blank_capture(tmp_path, {"cam_00": [(64, 48), (80, 48)]})
    with pytest.raises(SessionError, match="camera cam_00: 00001.png is 80x48"):
        detect_capture(folder, CharucoBoardSpec())


def test_board_and_eval_commands(tmp_path, capsys):
    assert main(["calib", "board", str(tmp_path / "b" / "board.png"), "--squares-x", "5", "--squares-y", "4",
                 "--square-mm", "40", "--marker-mm", "30", "--dpi", "100"]) == 0
    assert (tmp_path / "b" / "board.json").is_file()
    gt = ring_rig(3)
    save_cameras_json(tmp_path / "gt.json", gt)
    save_cameras_json(tmp_path / "est.json", gt)
    capsys.readouterr()
    assert main(["eval", "calib", str(tmp_path / "est.json"), str(tmp_path / "gt.json")]) == 0
    scores = json.loads(capsys.readouterr().out)
    for key in ("center_err_mm", "rot_err_deg", "focal_err_pct", "volume_reproj_rms_px"):
        assert scores["overall"][key] == pytest.approx(0.0, abs=1e-6)
    assert set(scores["cameras"]) == {"cam_00", "cam_01", "cam_02"}
    assert main(["calib", "export", str(tmp_path / "est.json"), "--colmap", str(tmp_path / "colmap")]) == 0
    assert main(["calib", "import", str(tmp_path / "colmap"), "--out", str(tmp_path / "back.json")]) == 0


@pytest.mark.slow
def test_rendered_capture_end_to_end(tmp_path, capsys):
    """Render a 4-camera capture, detect, calibrate through the CLI and score against ground truth."""
    cap = tmp_path / "cap"
    assert main(["synth", "calibration", str(cap), "--cameras", "4", "--poses", "12", "--seed", "3",
                 "--kinect", "v2"]) == 0
    est = tmp_path / "est"
    assert main(["calibrate", str(cap), "--out", str(est / "cameras.json"), "--easymocap", str(tmp_path / "em"),
                 "--accept-uncertain"]) == 0
    assert (tmp_path / "em" / "extri.yml").is_file()
    assert main(["calib", "kinect", str(cap), "--report", str(est / "cameras.report.json"),
                 "--out", str(est / "kinect.json")]) == 0
    capsys.readouterr()
    assert main(["eval", "calib", str(est / "cameras.json"), str(cap / "gt" / "cameras.json"),
                 "--kinect", str(est / "kinect.json"), "--kinect", str(cap / "gt" / "kinect.json")]) == 0
    scores = json.loads(capsys.readouterr().out)
    assert scores["kinect"]["depth_to_color_t_err_mm"] < 3.0
    assert scores["kinect"]["depth_to_color_rot_err_deg"] < 0.3
    assert scores["kinect"]["color_center_err_mm"] < 20.0
    assert scores["overall"]["reproj_rms_px"] < 0.6
    assert scores["max"]["center_err_mm"] < 40
    assert scores["max"]["rot_err_deg"] < 1.0
    assert scores["max"]["focal_err_pct"] < 1.5
