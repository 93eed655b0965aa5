"""``capture import --images`` with a machine-vision camera's 16-bit frames (adversarial pass 5).

Before: a 16-bit colour frame was read by its top byte, so a 12-bit camera's right-aligned data (0..4095) became a
frame peaking at 15 of 255, nearly black, exit 0. Now such a frame is refused naming it and the fix; full-range
16-bit frames read as before (the top byte)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from tests.reliability.conftest import assert_clean_error, run_inprocess

W, H = 32, 24


def _recording(root, frames: list[np.ndarray]):
    from bodystudio.geometry.camera import Camera, CameraRig, save_cameras_json

    K = np.array([[30.0, 0, W / 2], [0, 30.0, H / 2], [0, 0, 1]])
    save_cameras_json(root / "cameras.json", CameraRig({"cam_a": Camera("cam_a", K, np.zeros(5), np.eye(3),
                                                                        np.array([0, 0, 3.0]), W, H)}))
    (root / "images" / "cam_a").mkdir(parents=True)
    for k, frame in enumerate(frames):
        assert cv2.imwrite(str(root / "images" / "cam_a" / f"{k:05d}.png"), frame)
    return root


def _run(root, capfd):
    return run_inprocess(["capture", "import", root / "S", "--cameras", root / "cameras.json", "--images",
                          root / "images"], capfd)


@pytest.mark.parametrize("channels", [1, 3], ids=["mono12", "rgb12"])
def test_12_bit_data_in_16_bit_frames_is_refused(tmp_path, capfd, channels):
    rng = np.random.default_rng(0)
    shape = (H, W) if channels == 1 else (H, W, 3)
    root = _recording(tmp_path, [rng.integers(0, 4096, shape, dtype=np.uint16) for _ in range(2)])
    result = _run(root, capfd)
    assert_clean_error(result, 2, f"{root / 'images' / 'cam_a' / '00000.png'}: 16-bit image whose brightest value")
    assert not (root / "S").exists()


def test_full_range_16_bit_frames_keep_their_top_byte(tmp_path, capfd):
    from bodystudio.capture.session import open_session

    rng = np.random.default_rng(1)
    frames = [rng.integers(0, 65536, (H, W, 3), dtype=np.uint16) for _ in range(2)]
    root = _recording(tmp_path, frames)
    assert_clean_error(_run(root, capfd), 0, "")
    session = open_session(root / "S")
    for frame, raw in zip(session, frames, strict=True):
        assert np.array_equal(frame.images["cam_a"], (raw >> 8).astype(np.uint8)[..., ::-1])
