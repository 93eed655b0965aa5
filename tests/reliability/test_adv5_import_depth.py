"""``capture import --tum`` when the depth's unit is not the first frame's business (adversarial pass 5).

Before: the depth unit was decided on the first depth frame alone; a blank first frame (a Kinect's first frames
often are) returned TUM's 5000 per metre and every later frame in millimetres was stored 5x short (2 m read 0.40 m,
exit 0); a recording whose frames switch unit, or switch from 16-bit to floating point, was divided by the first
frame's scale with exit 0. Now the unit is taken from the first frame with depth, and a later frame in another format,
or that only another unit makes plausible, is refused naming it."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from tests.reliability.conftest import assert_clean_error, run_inprocess

W, H = 32, 24


def _camera(t_x: float) -> dict:
    return {"K": [[30.0, 0, W / 2], [0, 30.0, H / 2], [0, 0, 1]], "dist": [0] * 5, "R": np.eye(3).tolist(),
            "t": [t_x, 0, 0], "width": W, "height": H}


def _tum(root, frames, suffixes=None):
    (root / "depth").mkdir(parents=True)
    (root / "rgb").mkdir()
    depth_lines, rgb_lines = [], []
    for k, depth in enumerate(frames):
        t = 100.0 + k / 30.0
        name = f"depth/{k}{(suffixes or {}).get(k, '.png')}"
        assert cv2.imwrite(str(root / name), depth)
        cv2.imwrite(str(root / "rgb" / f"{k}.png"), np.full((H, W, 3), 90, np.uint8))
        depth_lines.append(f"{t:.6f} {name}")
        rgb_lines.append(f"{t + 0.005:.6f} rgb/{k}.png")
    (root / "depth.txt").write_text("\n".join(depth_lines) + "\n")
    (root / "rgb.txt").write_text("\n".join(rgb_lines) + "\n")
    return root


def _import(tmp_path, capfd, frames, *extra, suffixes=None):
    tmp_path.mkdir(parents=True, exist_ok=True)
    calibration = tmp_path / "kinect.json"
    calibration.write_text(json.dumps({"depth": _camera(0.0), "color": _camera(-0.05)}))
    tum = _tum(tmp_path / "tum", frames, suffixes)
    out = tmp_path / "S"
    result = run_inprocess(["capture", "import", out, "--tum", tum, "--kinect-calibration", calibration, *extra],
                           capfd)
    return result, out, tum


MM_2M = np.full((H, W), 2000, np.uint16)  # 2 m in millimetres (0.40 m in TUM units)
TUM_2M = np.full((H, W), 10000, np.uint16)  # 2 m in TUM units
BLANK = np.zeros((H, W), np.uint16)


def test_a_blank_first_frame_does_not_decide_the_unit(tmp_path, capfd):
    from bodystudio.capture.session import open_session

    result, out, tum = _import(tmp_path / "auto", capfd, [BLANK, MM_2M, MM_2M])
    assert_clean_error(result, 2, f"{tum / 'depth' / '1.png'}: depth looks like millimetres")
    assert "--depth-scale 1000" in result.stderr and not out.exists()
    result, out, _ = _import(tmp_path / "mm", capfd, [BLANK, MM_2M, MM_2M], "--depth-scale", "1000")
    assert_clean_error(result, 0, "")
    depth = [f.kinect_depth_m for f in open_session(out)]
    assert np.all(depth[0] == 0) and all(np.allclose(d, 2.0) for d in depth[1:])
    result, out, _ = _import(tmp_path / "tum_units", capfd, [BLANK, TUM_2M])
    assert_clean_error(result, 0, "")
    assert np.allclose(open_session(out).frame(1).kinect_depth_m, 2.0)


def test_a_frame_in_another_unit_or_format_is_refused(tmp_path, capfd):
    result, out, tum = _import(tmp_path / "unit", capfd, [TUM_2M, MM_2M])
    assert_clean_error(result, 2, f"{tum / 'depth' / '1.png'}: depth looks like millimetres (median 2.00 m; 0.40 m "
                                  f"at 5000 per metre) but {tum / 'depth' / '0.png'} was read at 5000 per metre")
    assert not out.exists()
    metres = np.full((H, W), 2.0, np.float32)
    result, out, tum = _import(tmp_path / "format", capfd, [TUM_2M, metres], suffixes={1: ".tiff"})
    assert_clean_error(result, 2, f"{tum / 'depth' / '1.tiff'}: depth stored as float32 but")
    assert not out.exists()
    # a frame of a far wall (4.8 m in TUM units: no other unit makes it plausible) is depth, not a unit change
    far = np.full((H, W), 24000, np.uint16)
    result, out, _ = _import(tmp_path / "far", capfd, [TUM_2M, far])
    assert_clean_error(result, 0, "")


@pytest.mark.parametrize("explicit", [False, True])
def test_an_8_bit_frame_after_16_bit_ones_is_refused(tmp_path, capfd, explicit):
    extra = ("--depth-scale", "5000") if explicit else ()
    result, out, tum = _import(tmp_path, capfd, [TUM_2M, np.full((H, W), 40, np.uint8)], *extra)
    assert_clean_error(result, 2, f"{tum / 'depth' / '1.png'}: depth ")
    assert not out.exists()


@pytest.mark.parametrize(("depth", "scale", "median"), [(2000.0, "1", "2000 m"), (2.0, "1000", "0.002 m")],
                         ids=["millimetres_as_metres", "metres_as_millimetres"])
def test_a_stated_scale_no_depth_camera_could_have_is_refused(tmp_path, capfd, depth, scale, median):
    """Before: float millimetres at ``--depth-scale 1`` raised a ValueError traceback when stored (2000 m does not fit
    16-bit millimetres); float metres at 1000 per metre (2 mm) were stored as no depth, exit 0."""
    frames = [np.full((H, W), depth, np.float32)] * 2
    result, out, tum = _import(tmp_path, capfd, frames, "--depth-scale", scale, suffixes={0: ".tiff", 1: ".tiff"})
    assert_clean_error(result, 2, f"{tum / 'depth' / '0.tiff'}: at --depth-scale {scale} the median depth is {median}")
    assert not out.exists()
