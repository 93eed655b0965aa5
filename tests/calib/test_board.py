"""ChArUco boards: specification, printable files, rendering and detection accuracy."""

import numpy as np
import pytest

from bodystudio.calib.board import (
    CharucoBoardSpec,
    board_corners,
    detect_charuco,
    load_board_json,
    save_board_json,
    write_board_pdf,
    write_board_png,
)
from bodystudio.calib.synthetic import board_pose_facing, render_board_view, visible_corners
from bodystudio.errors import InputError
from bodystudio.geometry.camera import Camera


def test_spec_validation_and_json(tmp_path):
    spec = CharucoBoardSpec(6, 5, 0.05, 0.035, "DICT_5X5_100")
    assert board_corners(spec).shape == (spec.n_corners, 3) == (20, 3)
    np.testing.assert_allclose(board_corners(spec)[0], [0.05, 0.05, 0.0])
    save_board_json(tmp_path / "board.json", spec)
    assert load_board_json(tmp_path / "board.json") == spec
    with pytest.raises(InputError, match="marker size"):
        CharucoBoardSpec(6, 5, 0.05, 0.06)
    with pytest.raises(InputError, match="unknown ArUco dictionary"):
        CharucoBoardSpec(dictionary="DICT_7X7_1")
    with pytest.raises(InputError, match="too few markers"):
        CharucoBoardSpec(12, 10, 0.05, 0.04, "DICT_4X4_50")


def test_printable_board_files(tmp_path):
    spec = CharucoBoardSpec(5, 4, 0.04, 0.03)
    write_board_pdf(tmp_path / "b.pdf", spec, margin_m=0.01)
    head = (tmp_path / "b.pdf").read_bytes()
    assert head.startswith(b"%PDF")
    # True size: the page is (board + 2 margins) in PostScript points.
    w_pt = (0.2 + 0.02) / 0.0254 * 72
    h_pt = (0.16 + 0.02) / 0.0254 * 72
    import re

    box = [float(v) for v in re.search(rb"/MediaBox \[ *([\d. ]+)\]", head).group(1).split()]
    assert abs(box[2] - w_pt) < 1 and abs(box[3] - h_pt) < 1
    write_board_png(tmp_path / "b.png", spec, dpi=200)
    import cv2

    img = cv2.imread(str(tmp_path / "b.png"), cv2.IMREAD_GRAYSCALE)
    assert abs(img.shape[1] - 0.22 / 0.0254 * 200) < 3
    det = detect_charuco(img, spec)
    assert det.n_corners == spec.n_corners


def test_rendered_board_detection_is_subpixel():
    """A rendered board (with lens distortion, blur, light, noise) is detected within a fraction of a pixel."""
    spec = CharucoBoardSpec(7, 5, 0.06, 0.045)
    cam = Camera.look_at("cam", [0.3, 1.2, 1.6], [0, 1.0, 0], fx=700, width=640, height=480,
                         dist=(-0.08, 0.02, 0.0004, -0.0003, 0.0))
    rng = np.random.default_rng(0)
    errs = []
    for k, tilt in enumerate((-0.4, 0.0, 0.5)):
        facing = np.array([0.3 + tilt, 0.2, 1.6])
        pose = board_pose_facing([0, 1.0, 0], facing, 0.2 * k, spec)
        assert visible_corners(cam, spec, pose).sum() == spec.n_corners
        det = detect_charuco(render_board_view(cam, spec, pose, rng), spec)
        assert det.n_corners >= 0.9 * spec.n_corners
        truth = cam.project(board_corners(spec)[det.corner_ids] @ pose[:3, :3].T + pose[:3, 3])
        errs.append(det.corners_px - truth)
        assert 0 < det.coverage < 1
    e = np.linalg.norm(np.concatenate(errs), axis=1)
    assert np.sqrt((e ** 2).mean()) < 0.3
    assert e.max() < 1.0


def test_back_of_board_is_not_detected():
    spec = CharucoBoardSpec(7, 5, 0.06, 0.045)
    cam = Camera.look_at("cam", [0, 1.0, 1.6], [0, 1.0, 0], fx=700, width=640, height=480)
    pose = board_pose_facing([0, 1.0, 0], [0, 0, -1.0], 0.0, spec)  # printed face away from the camera
    assert visible_corners(cam, spec, pose).sum() == 0
    assert detect_charuco(render_board_view(cam, spec, pose, np.random.default_rng(0)), spec).n_corners == 0


def test_floor_board_is_detected_by_upper_cameras_at_vga():
    """The world frame needs the floor board: the board chosen for 640x480 rigs must decode there."""
    from bodystudio.calib.synthetic import board_for_resolution
    from bodystudio.calib.world import floor_board_to_world
    from bodystudio.geometry.camera import ring_rig

    rig = ring_rig(4, width=640, height=480)
    spec = board_for_resolution(640)
    upper = rig["cam_01"]  # odd cameras stand on the upper ring
    pose = floor_board_to_world(spec)
    det = detect_charuco(render_board_view(upper, spec, pose, np.random.default_rng(0)), spec)
    assert det.n_corners >= 6
    truth = upper.project(board_corners(spec)[det.corner_ids] @ pose[:3, :3].T + pose[:3, 3])
    assert np.sqrt(((det.corners_px - truth) ** 2).sum(1).mean()) < 0.6
