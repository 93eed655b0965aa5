"""The calibration commands' refusals, word for word (issue 17, mutation of bodystudio/cli/calib.py).

Each refused input: exit code 2, one line on stderr (the whole line compared), nothing on stdout, no output
written. Run in-process through ``bodystudio.cli.main.main`` with typer's CliRunner isolating the streams. The
refusals that come before any detection are checked on a capture of blank images (nothing is calibrated); an
accepted value is shown by the next refusal it reaches.
"""

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from bodystudio.calib.board import CharucoBoardSpec, board_image, save_board_json
from bodystudio.cli.main import main
from bodystudio.geometry.camera import ring_rig, save_cameras_json

SPEC = CharucoBoardSpec(5, 4, 0.04, 0.03)


def _run(*args) -> tuple[int, str, str]:
    with CliRunner().isolation() as (out, err, _):
        code = main([str(a) for a in args])
        return code, out.getvalue().decode(), err.getvalue().decode()


def _refused(*args) -> str:
    """The one error line of a refused command (exit 2, nothing on stdout)."""
    code, out, err = _run(*args)
    assert code == 2 and out == "", (code, out, err)
    lines = err.splitlines()
    assert len(lines) == 1 and err.endswith("\n"), err
    return lines[0]


def _files(folder: Path) -> list[str]:
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*"))


def _capture(root: Path, board: bool = True) -> Path:
    """cam_00 (frame 0) and cam_01 (frames 0, 1): blank 32 x 24 images, and board.json."""
    for cam, frames in (("cam_00", [0]), ("cam_01", [0, 1])):
        (root / cam).mkdir(parents=True)
        for f in frames:
            cv2.imwrite(str(root / cam / f"{f:05d}.png"), np.full((24, 32), 128, np.uint8))
    if board:
        save_board_json(root / "board.json", SPEC)
    return root


# --- bodystudio calibrate ------------------------------------------------------------------------------------

def test_calibrate_option_refusals(tmp_path):
    cap = _capture(tmp_path / "cap")
    before = _files(tmp_path)
    out = tmp_path / "est" / "cameras.json"
    assert _refused("calibrate", cap, "--out", out, "--distortion-terms", 6) == (
        "error: --distortion-terms must be 4 (k1 k2 p1 p2) or 5 (also k3), got 6")
    assert _refused("calibrate", cap, "--out", out, "--distortion-terms", 3) == (
        "error: --distortion-terms must be 4 (k1 k2 p1 p2) or 5 (also k3), got 3")
    floor = (f"error: --floor-frame 99: no camera has this frame in {cap}; give the frame whose board lies on the "
             "floor, or --reference-camera")
    for terms in (4, 5):  # both accepted: the next check refuses
        assert _refused("calibrate", cap, "--out", out, "--distortion-terms", terms, "--floor-frame", 99) == floor
    assert _refused("calibrate", cap, "--out", out, "--floor-frame", 99) == floor
    assert _refused("calibrate", cap, "--out", out, "--reference-camera", "cam_77") == (
        f"error: --reference-camera cam_77: no such camera in {cap} (cam_00, cam_01)")
    # frame 1 is in cam_01 only: enough; a reference camera makes the floor frame irrelevant. Both reach the
    # detection, which finds no board in the blank images.
    no_board = _refused("calibrate", cap, "--out", out, "--floor-frame", 1)
    assert no_board.startswith("error: camera cam_00: no ChArUco board found")
    assert _refused("calibrate", cap, "--out", out, "--reference-camera", "cam_01", "--floor-frame", 99) == no_board
    assert _files(tmp_path) == before


def test_calibrate_input_refusals(tmp_path):
    assert _refused("calibrate", tmp_path / "nothing") == (
        f"error: {tmp_path / 'nothing'}: no such capture folder (cam_NN/FFFFF.png board images)")
    cap = _capture(tmp_path / "cap", board=False)
    assert _refused("calibrate", cap) == (
        f"error: {cap / 'board.json'}: board description not found; pass --board or write one with "
        "`bodystudio calib board`")
    assert _refused("calibrate", cap, "--board", tmp_path / "b.json") == (
        f"error: {tmp_path / 'b.json'}: board description not found; pass --board or write one with "
        "`bodystudio calib board`")
    (tmp_path / "b.json").write_text(json.dumps({"squares_x": 5}))
    assert _refused("calibrate", cap, "--board", tmp_path / "b.json") == (
        f"error: {tmp_path / 'b.json'}: board description lacks squares_y, square_m, marker_m; write one with "
        "`bodystudio calib board`")
    assert not (cap / "cameras.json").exists() and not (cap / "cameras.report.json").exists()


def test_calibrate_output_refusals(tmp_path):
    cap = _capture(tmp_path / "cap")
    assert _refused("calibrate", cap, "--out", tmp_path / "c.txt") == (
        f"error: --out {tmp_path / 'c.txt'}: unsupported output format; use .json")
    (cap / "cameras.json").mkdir()  # the default output of a plain capture folder: FOLDER/cameras.json
    assert _refused("calibrate", cap) == f"error: --out {cap / 'cameras.json'}: is a folder; give a file path"
    (tmp_path / "o" / "c.report.json").mkdir(parents=True)  # the report beside it
    assert _refused("calibrate", cap, "--out", tmp_path / "o" / "c.json") == (
        f"error: --out {tmp_path / 'o' / 'c.report.json'}: is a folder; give a file path")
    (tmp_path / "file").write_text("x")
    out = tmp_path / "est" / "cameras.json"
    assert _refused("calibrate", cap, "--out", out, "--easymocap", tmp_path / "file") == (
        f"error: --easymocap {tmp_path / 'file'}: exists and is a file, not a folder; choose a folder path")
    assert _refused("calibrate", cap, "--out", out, "--colmap", tmp_path / "file") == (
        f"error: --colmap {tmp_path / 'file'}: exists and is a file, not a folder; choose a folder path")
    (tmp_path / "model" / "notes.txt").parent.mkdir()
    (tmp_path / "model" / "notes.txt").write_text("keep")
    assert _refused("calibrate", cap, "--out", out, "--colmap", tmp_path / "model") == (
        f"error: --colmap {tmp_path / 'model'}: the folder holds other files (notes.txt); the model replaces the "
        "whole folder, so give an empty or a COLMAP model folder")
    assert not out.parent.exists()


def test_calibrate_session_layout(tmp_path):
    """A session: the images in SESSION/calibration_images, the rig written to SESSION/calibration/cameras.json."""
    session = tmp_path / "S"
    _capture(session / "calibration_images")
    (session / "calibration" / "cameras.json").mkdir(parents=True)
    assert _refused("calibrate", session) == (
        f"error: --out {session / 'calibration' / 'cameras.json'}: is a folder; give a file path")
    assert _refused("calibrate", session, "--out", tmp_path / "c.json", "--floor-frame", 7) == (
        f"error: --floor-frame 7: no camera has this frame in {session / 'calibration_images'}; give the frame "
        "whose board lies on the floor, or --reference-camera")


# --- bodystudio calib board ----------------------------------------------------------------------------------

@pytest.mark.parametrize("args, line", [
    (["--squares-x", "2"], "board needs at least 3x3 and at most 100x100 squares, got 2x9"),
    (["--squares-y", "101"], "board needs at least 3x3 and at most 100x100 squares, got 12x101"),
    (["--marker-mm", "100"], "marker size 0.1 m must be positive and smaller than the square size 0.1 m"),
    (["--square-mm", "2500"],
     "board square size 2.5 m is outside 0.001-2.0 m; give the printed square's side in metres"),
    (["--dictionary", "DICT_4X4_50"],
     "DICT_4X4_50 has too few markers for a 12x9 board (54 needed); pick a larger dictionary"),
    (["--dpi", "20"], "--dpi 20: choose between 50 and 1200 (300 is a good print resolution)"),
    # the defaults: 300 dpi, and markers of the given size
    (["--square-mm", "2", "--marker-mm", "1"],
     "--dpi 300: the 1 mm markers would be 12 px wide; raise --dpi or the marker size so that they are at least 20 px"),
])
def test_board_refusals(tmp_path, args, line):
    assert _refused("calib", "board", tmp_path / "b.png", *args) == f"error: {line}"
    assert _files(tmp_path) == []


def test_board_output_refusals(tmp_path):
    assert _refused("calib", "board", tmp_path / "b.svg") == (
        f"error: calib board {tmp_path / 'b.svg'}: unsupported output format; use .png or .pdf")
    (tmp_path / "board.json").mkdir()
    assert _refused("calib", "board", tmp_path / "b.png") == (
        f"error: calib board {tmp_path / 'board.json'}: is a folder; give a file path")
    assert _files(tmp_path) == ["board.json"]


def test_board_files_and_defaults(tmp_path, monkeypatch):
    code, out, err = _run("calib", "board", tmp_path / "a" / "B.PDF", "--squares-x", 5, "--squares-y", 4,
                          "--square-mm", 40, "--marker-mm", 30)
    assert (code, err) == (0, "")
    assert out == f"wrote {tmp_path / 'a' / 'B.PDF'} (200 x 160 mm) and {tmp_path / 'a' / 'board.json'}\n"
    assert (tmp_path / "a" / "B.PDF").read_bytes()[:4] == b"%PDF"
    assert json.loads((tmp_path / "a" / "board.json").read_text()) == {
        "type": "charuco", "squares_x": 5, "squares_y": 4, "square_m": 0.04, "marker_m": 0.03,
        "dictionary": "DICT_4X4_100", "legacy_pattern": False}
    code, out, err = _run("calib", "board", tmp_path / "b" / "b.png", "--squares-x", 3, "--squares-y", 3,
                          "--square-mm", 20, "--marker-mm", 16, "--dpi", 127)
    assert (code, err) == (0, "") and out.startswith(f"wrote {tmp_path / 'b' / 'b.png'} (60 x 60 mm)")
    img = cv2.imread(str(tmp_path / "b" / "b.png"), cv2.IMREAD_GRAYSCALE)
    spec = CharucoBoardSpec(3, 3, 0.02, 0.016, "DICT_4X4_100")
    assert np.array_equal(img, board_image(spec, px_per_m=5000.0, margin_m=0.01))  # 127 dpi = 5000 px/m
    # the defaults: the studio protocol's 12 x 9 board (its page drawn by a stand-in: 11 s for the real one)
    import bodystudio.calib.board as board_module

    pages = []
    monkeypatch.setattr(board_module, "write_board_pdf", lambda path, spec: pages.append((path, spec)))
    code, out, err = _run("calib", "board", tmp_path / "c" / "b.pdf")
    assert code == 0 and pages == [(tmp_path / "c" / "b.pdf", CharucoBoardSpec(12, 9, 0.1, 0.075, "DICT_4X4_100"))]
    assert json.loads((tmp_path / "c" / "board.json").read_text()) == {
        "type": "charuco", "squares_x": 12, "squares_y": 9, "square_m": 0.1, "marker_m": 0.075,
        "dictionary": "DICT_4X4_100", "legacy_pattern": False}
    assert out == f"wrote {tmp_path / 'c' / 'b.pdf'} (1200 x 900 mm) and {tmp_path / 'c' / 'board.json'}\n"


# --- bodystudio calib kinect ---------------------------------------------------------------------------------

def _kinect_folder(root: Path) -> Path:
    from bodystudio.capture.kinect import write_depth_png

    (root / "kinect" / "rgb").mkdir(parents=True)
    (root / "kinect" / "depth").mkdir(parents=True)
    cv2.imwrite(str(root / "kinect" / "rgb" / "00003.png"), board_image(SPEC, px_per_m=1000.0, margin_m=0.02))
    write_depth_png(root / "kinect" / "depth" / "00003.png", np.full((4, 4), 1.5))
    save_board_json(root / "board.json", SPEC)
    return root


def test_kinect_refusals(tmp_path):
    t = tmp_path / "t"
    t.mkdir()
    assert _refused("calib", "kinect", t, "--out", t / "k.txt") == (
        f"error: --out {t / 'k.txt'}: unsupported output format; use .json")
    assert _refused("calib", "kinect", t, "--out", t / "k.json") == (
        f"error: {t / 'board.json'}: board description not found")
    save_board_json(t / "board.json", SPEC)
    assert _refused("calib", "kinect", t, "--out", t / "k.json", "--model", "v3") == (
        "error: --model must be v1 or v2, got 'v3'")
    for model in ("v1", "v2"):  # accepted: the capture folder is what is refused
        assert _refused("calib", "kinect", t, "--out", t / "k.json", "--model", model) == (
            f"error: {t}: no kinect/rgb and kinect/depth folders; record the boards with the Kinect too")
    assert _refused("calib", "kinect", t, "--out", t / "k.json", "--sensor", t / "s.json", "--model", "v3") == (
        f"error: {t / 's.json'}: Kinect calibration not found")
    k = _kinect_folder(tmp_path / "k")
    (k / "report.json").write_text(json.dumps({"board_to_world": {"4": np.eye(4).tolist()}}))
    assert _refused("calib", "kinect", k, "--out", k / "k.json", "--report", k / "report.json") == (
        f"error: {k / 'report.json'}: none of the Kinect's board frames ([3]...) was seen by the studio cameras; "
        "capture boards seen by both")
    assert not (t / "k.json").exists() and not (k / "k.json").exists()


# --- export, import, eval, synth -----------------------------------------------------------------------------

def test_export_import_eval_refusals(tmp_path):
    cams = tmp_path / "cameras.json"
    save_cameras_json(cams, ring_rig(2))
    (tmp_path / "file").write_text("x")
    assert _refused("calib", "export", cams) == "error: nothing to export: give --easymocap DIR and/or --colmap DIR"
    assert _refused("calib", "export", cams, "--easymocap", tmp_path / "file") == (
        f"error: --easymocap {tmp_path / 'file'}: exists and is a file, not a folder; choose a folder path")
    assert _refused("calib", "export", cams, "--colmap", tmp_path / "file") == (
        f"error: --colmap {tmp_path / 'file'}: exists and is a file, not a folder; choose a folder path")
    (tmp_path / "model").mkdir()
    (tmp_path / "model" / "notes.txt").write_text("keep")
    assert _refused("calib", "export", cams, "--colmap", tmp_path / "model") == (
        f"error: --colmap {tmp_path / 'model'}: the folder holds other files (notes.txt); the model replaces the "
        "whole folder, so give an empty or a COLMAP model folder")
    assert _files(tmp_path / "model") == ["notes.txt"]
    # with both exports the COLMAP folder is refused before the EasyMocap files are written
    assert _refused("calib", "export", cams, "--easymocap", tmp_path / "both", "--colmap", tmp_path / "model") == (
        f"error: --colmap {tmp_path / 'model'}: the folder holds other files (notes.txt); the model replaces the "
        "whole folder, so give an empty or a COLMAP model folder")
    assert not (tmp_path / "both").exists() or _files(tmp_path / "both") == []
    assert _refused("calib", "export", tmp_path / "none.json", "--easymocap", tmp_path / "emc") == (
        f"error: {tmp_path / 'none.json'}: cameras.json not found")
    assert not (tmp_path / "emc").exists() or _files(tmp_path / "emc") == []
    assert _refused("calib", "import", tmp_path / "none", "--out", tmp_path / "c.json") == (
        f"error: {tmp_path / 'none'}: no such folder; give a COLMAP model folder or an EasyMocap folder (intri.yml)")
    assert _refused("calib", "import", tmp_path, "--out", tmp_path / "c.txt") == (
        f"error: --out {tmp_path / 'c.txt'}: unsupported output format; use .json")
    assert _refused("eval", "calib", cams, cams, "--kinect", tmp_path / "k.json") == (
        "error: --kinect needs the estimated and the ground-truth calibration.json: give it twice")
    assert _refused("synth", "calibration", tmp_path / "file") == (
        f"error: synth calibration {tmp_path / 'file'}: exists and is a file, not a folder; choose a folder path")
    assert not (tmp_path / "c.json").exists()


def test_kinect_wiring(tmp_path, monkeypatch):
    """The command's own lines, with the detection, the plane calibration and the PnP replaced by stand-ins: the
    nominal sensor of --model, the views the studio saw (in order) handed to the PnP, both cameras placed from its
    answer, the file and the JSON line written."""
    import bodystudio.calib.depth as depth_module
    from bodystudio.calib.world import rigid, rigid_inverse
    from bodystudio.capture.session import load_kinect_calibration

    calls = {}
    views = ["view3", "view5", "view8"]
    D = rigid(cv2.Rodrigues(np.array([0.01, -0.02, 0.03]))[0], [0.05, 0.001, -0.002])
    W = rigid(cv2.Rodrigues(np.array([0.2, 2.9, -0.1]))[0], [0.3, -0.9, 2.4])
    report = {"n_views": 3, "plane_rms_mm": [1.0, 2.0, 3.0], "corner_to_plane_rms_mm": 0.25}

    def detect(folder, spec):
        calls["detect"] = (folder, spec)
        return [3, 5, 8], views

    def calibrate(rgbd, spec, views_, board_to_world):
        from dataclasses import replace

        calls["calibrate"] = (rgbd, spec, views_, board_to_world)
        return replace(rgbd, depth_to_color=D), report

    def pnp(color, spec, views_, board_to_world):
        calls["pnp"] = (color, views_, [np.asarray(T) for T in board_to_world])
        return W

    monkeypatch.setattr(depth_module, "detect_rgbd_capture", detect)
    monkeypatch.setattr(depth_module, "calibrate_rgbd_sensor", calibrate)
    monkeypatch.setattr(depth_module, "sensor_to_studio", pnp)
    save_board_json(tmp_path / "board.json", SPEC)
    code, out, err = _run("calib", "kinect", tmp_path, "--out", tmp_path / "k1.json", "--model", "v1")
    assert (code, err) == (0, "")
    assert json.loads(out) == {"frames": [3, 5, 8], **report, "in_studio_frame": False}
    rgbd, spec, views_, none = calls["calibrate"]
    assert (rgbd.version, rgbd.color.width, spec, views_, none) == ("v1", 640, SPEC, views, None)
    assert calls["detect"] == (tmp_path, SPEC) and "pnp" not in calls
    k1 = load_kinect_calibration(tmp_path / "k1.json")
    np.testing.assert_allclose(k1.depth_to_color, D, atol=1e-9)
    np.testing.assert_allclose(k1.color.extrinsic, rgbd.color.extrinsic, atol=1e-9)  # not moved

    poses = {"5": rigid(np.eye(3), [1.0, 2.0, 3.0]).tolist(), "8": rigid(np.eye(3), [4.0, 5.0, 6.0]).tolist(),
             "9": np.eye(4).tolist()}
    (tmp_path / "report.json").write_text(json.dumps({"board_to_world": poses}))
    code, out, err = _run("calib", "kinect", tmp_path, "--out", tmp_path / "k2.json", "--report",
                          tmp_path / "report.json")  # the default model: v2
    assert (code, err) == (0, "")
    assert json.loads(out) == {"frames": [3, 5, 8], **report, "in_studio_frame": True}
    rgbd = calls["calibrate"][0]
    assert rgbd.version == "v2" and rgbd.color.width == 1920 and calls["calibrate"][3] is None
    color, views_w, board_to_world = calls["pnp"]
    assert views_w == ["view5", "view8"]
    np.testing.assert_array_equal(board_to_world, [poses["5"], poses["8"]])
    np.testing.assert_array_equal(color.K, rgbd.color.K)
    k2 = load_kinect_calibration(tmp_path / "k2.json")
    assert (k2.name, k2.version, k2.baseline_m, tuple(k2.depth_range_m)) == (
        rgbd.name, rgbd.version, rgbd.baseline_m, tuple(rgbd.depth_range_m))
    np.testing.assert_allclose(k2.color.extrinsic, W, atol=1e-9)
    np.testing.assert_allclose(k2.depth.extrinsic, rigid_inverse(D) @ W, atol=1e-9)
    np.testing.assert_allclose(k2.depth_to_color, D, atol=1e-9)
    for got, cam in ((k2.color, rgbd.color), (k2.depth, rgbd.depth)):
        np.testing.assert_allclose(got.K, cam.K)
        np.testing.assert_allclose(got.dist, cam.dist)
        assert (got.width, got.height) == (cam.width, cam.height)
    # --sensor: that file's intrinsics, name, baseline and range kept (the model is not looked at)
    from dataclasses import replace

    from bodystudio.capture.session import kinect_calibration_to_dict
    from bodystudio.fileio import write_json
    from bodystudio.geometry.camera import kinect_v1

    own = replace(kinect_v1(name="studio_kinect"), baseline_m=0.08, depth_range_m=(0.6, 4.0))
    write_json(tmp_path / "sensor.json", kinect_calibration_to_dict(own))
    code, out, err = _run("calib", "kinect", tmp_path, "--out", tmp_path / "k3.json", "--report",
                          tmp_path / "report.json", "--sensor", tmp_path / "sensor.json", "--model", "v3")
    assert (code, err) == (0, "")
    k3 = load_kinect_calibration(tmp_path / "k3.json")
    assert (k3.name, k3.version, k3.baseline_m, tuple(k3.depth_range_m)) == ("studio_kinect", "v1", 0.08, (0.6, 4.0))
    np.testing.assert_allclose(k3.color.K, own.color.K)
    np.testing.assert_allclose(k3.color.extrinsic, W, atol=1e-9)


def test_calibrate_hands_its_options_on(tmp_path, monkeypatch):
    """The options reach the calibration (stand-ins for the detection and the solve: the second refuses, so
    nothing is written); an existing export folder is accepted."""
    import bodystudio.calib.calibrate as calibrate_module
    import bodystudio.calib.observations as observations_module
    from bodystudio.errors import SessionError

    seen = []

    def detect(folder, spec, progress=None):
        seen.append(("detect", folder, spec))
        return "observations", {}

    def solve(obs, spec, options):
        seen.append(("solve", obs, options))
        raise SessionError("stand-in solve")

    monkeypatch.setattr(observations_module, "detect_capture", detect)
    monkeypatch.setattr(calibrate_module, "calibrate_cameras", solve)
    cap = _capture(tmp_path / "cap")
    (tmp_path / "emc").mkdir()
    out = tmp_path / "est" / "cameras.json"
    assert _refused("calibrate", cap, "--out", out, "--distortion-terms", 5, "--floor-frame", 1, "--easymocap",
                    tmp_path / "emc") == "error: stand-in solve"
    [(step1, folder, spec), (step2, obs, options)] = seen
    assert (step1, folder, spec, step2, obs) == ("detect", cap, SPEC, "solve", "observations")
    assert (options.distortion_terms, options.floor_frame, options.reference_camera) == (5, 1, None)
    seen.clear()
    assert _refused("calibrate", cap, "--out", out, "--reference-camera", "cam_01", "--floor-frame", 1) == (
        "error: stand-in solve")
    options = seen[1][2]
    assert (options.distortion_terms, options.floor_frame, options.reference_camera) == (4, None, "cam_01")
    assert not out.exists() and _files(tmp_path / "emc") == []
