"""``capture import --images`` when each camera dropped a different frame (adversarial pass 5).

Before: image folders were paired by order alone; ``cam_a`` without its frame 3 and ``cam_b`` without its frame 4
have five files each, so from the fourth session frame on cam_a's frame 4 was paired with cam_b's frame 3, exit 0.
Now numbered files whose numbers drift apart between cameras are refused naming the first such file; a constant
offset (one camera's counter started elsewhere) and unnumbered names still import."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from tests.reliability.conftest import assert_clean_error, run_inprocess

W, H = 32, 24


def _recording(root, numbers: dict[str, list[int]], pattern="{:05d}.png"):
    from bodystudio.geometry.camera import Camera, CameraRig, save_cameras_json

    K = np.array([[30.0, 0, W / 2], [0, 30.0, H / 2], [0, 0, 1]])
    rig = CameraRig({cam: Camera(cam, K, np.zeros(5), np.eye(3), np.array([0, 0, 3.0 + i]), W, H)
                     for i, cam in enumerate(numbers)})
    save_cameras_json(root / "cameras.json", rig)
    for cam, frames in numbers.items():
        (root / "images" / cam).mkdir(parents=True)
        for n in frames:
            cv2.imwrite(str(root / "images" / cam / pattern.format(n)), np.full((H, W, 3), 10 * n % 256, np.uint8))
    return root


def _run(root, capfd, *extra):
    return run_inprocess(["capture", "import", root / "S", "--cameras", root / "cameras.json", "--images",
                          root / "images", *extra], capfd)


def test_frames_dropped_by_different_cameras_are_not_paired(tmp_path, capfd):
    root = _recording(tmp_path, {"cam_a": [0, 1, 2, 4, 5], "cam_b": [0, 1, 2, 3, 5]})
    result = _run(root, capfd)
    assert_clean_error(result, 2, f"{root / 'images' / 'cam_b' / '00003.png'}: paired by order with 00004.png of "
                                  "cam_a, but their frame numbers drift apart from there (3 and 4, 0 apart before)")
    assert not (root / "S").exists()


def test_the_frames_option_does_not_pair_past_a_drop(tmp_path, capfd):
    """One camera dropped frame 3: the count error suggests ``--frames 5``, which must not pair 4 with 3 either."""
    root = _recording(tmp_path, {"cam_a": [0, 1, 2, 3, 4, 5], "cam_b": [0, 1, 2, 4, 5]})
    assert_clean_error(_run(root, capfd), 2, "--frames 5")
    result = _run(root, capfd, "--frames", "5")
    assert_clean_error(result, 2, f"{root / 'images' / 'cam_b' / '00004.png'}: paired by order with 00003.png")
    assert_clean_error(_run(root, capfd, "--frames", "3"), 0, "")  # the frames before the drop pair


@pytest.mark.parametrize(("numbers", "pattern"), [({"cam_a": [100, 101, 102], "cam_b": [0, 1, 2]}, "{:05d}.png"),
                                                  ({"cam_a": [0, 1, 2], "cam_b": [0, 1, 2]}, "frame_{}.png")],
                         ids=["offset_counters", "unpadded"])
def test_consistent_numbering_imports(tmp_path, capfd, numbers, pattern):
    root = _recording(tmp_path, numbers, pattern)
    assert_clean_error(_run(root, capfd), 0, "")


def test_names_that_are_not_frame_counters_are_not_compared(tmp_path, capfd):
    """Phone stills named by the time they were taken (IMG_..._120003.jpg) step by seconds, not frames."""
    root = _recording(tmp_path, {"cam_a": [120000, 120003, 120007], "cam_b": [120001, 120003, 120009]},
                      "IMG_20240101_{}.png")
    assert_clean_error(_run(root, capfd), 0, "")


def test_a_mask_folder_missing_a_frames_mask_is_not_paired_past_it(tmp_path, capfd):
    root = _recording(tmp_path, {"cam_a": [0, 1, 2, 3]})
    (root / "masks" / "cam_a").mkdir(parents=True)
    for n in (0, 1, 3, 4):  # no mask for frame 2, one for a frame 4 that was not imported
        cv2.imwrite(str(root / "masks" / "cam_a" / f"{n:05d}.png"), np.full((H, W), 255, np.uint8))
    result = _run(root, capfd, "--masks", root / "masks")
    assert_clean_error(result, 2, f"{root / 'masks' / 'cam_a' / '00003.png'}: paired by order with 00002.png of cam_a")
