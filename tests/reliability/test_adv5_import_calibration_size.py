"""``capture import`` with EasyMocap cameras that do not state their image size (adversarial pass 5).

Before: without ``W_``/``H_`` the size was taken from the frames, whatever size K was calibrated at: K of a 320x240
calibration on 160x120 frames (principal point (160, 120), on the image's corner) or of portrait frames on landscape
ones imported with exit 0, every pixel's ray wrong. Now a principal point more than 15 % of the image off the frames'
centre is refused, naming the size K is for, or the 90-degree turn."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from tests.reliability.conftest import assert_clean_error, run_inprocess


def _easymocap_without_size(folder, rig, cx: float, cy: float):
    folder.mkdir(parents=True)
    intri = cv2.FileStorage(str(folder / "intri.yml"), cv2.FILE_STORAGE_WRITE)
    extri = cv2.FileStorage(str(folder / "extri.yml"), cv2.FILE_STORAGE_WRITE)
    intri.startWriteStruct("names", cv2.FileNode_SEQ)
    for cam in rig:
        intri.write("", cam.name)
    intri.endWriteStruct()
    for cam in rig:
        K = np.array(cam.K, np.float64)
        K[0, 2], K[1, 2] = cx, cy
        intri.write(f"K_{cam.name}", K)
        intri.write(f"dist_{cam.name}", np.zeros((1, 5)))
        extri.write(f"R_{cam.name}", cv2.Rodrigues(np.asarray(cam.R))[0])
        extri.write(f"T_{cam.name}", np.asarray(cam.t, np.float64).reshape(3, 1))
    intri.release()
    extri.release()
    return folder


@pytest.mark.parametrize(("cx", "cy", "phrase"), [(160.0, 120.0, "it is for about 320x240 images"),
                                                  (60.0, 80.0, "the frames are turned 90 degrees against it"),
                                                  (80.0, 60.0, None), (90.0, 55.0, None)],
                         ids=["calibrated_at_320x240", "portrait", "centred", "a_few_percent_off"])
def test_k_of_another_size_is_refused(studio, tmp_path, capfd, cx, cy, phrase):
    from bodystudio.geometry.camera import load_cameras_json

    folder = _easymocap_without_size(tmp_path / "calib", load_cameras_json(studio.cameras_json), cx, cy)
    out = tmp_path / "S"
    result = run_inprocess(["capture", "import", out, "--cameras", folder, "--images", studio.images], capfd)
    if phrase is None:
        assert_clean_error(result, 0, "")
        return
    assert_clean_error(result, 2, f"{folder / 'intri.yml'}: camera cam_00 has no W_cam_00/H_cam_00 and its frames "
                                  "are 160x120")
    assert phrase in result.stderr and not out.exists()
