"""Names, numbers and addresses from users and recorders: refused in one line or read right (rel6b).

mutCC found ``capture.session``'s camera-name check matching before a trailing newline (``^...$``, fixed with
``\\Z``); the importer's ``_safe_name`` had the same pattern, so ``'cam1\\n'`` was kept as a camera name which the
session writer then refused. The audit of the other validators on user input found: ``str.isdigit`` taking '²'
(``int`` then raises a traceback) and other scripts' digits ('٠٠٠٠١' read as frame 1 beside ``00001.png``: the
wrong image, silently) in the frame-file scans (calibration captures, live mirror folders, session manifests,
recorder file order); the scheduler address letting the host swallow a port in other digits and a NUL; a name given
twice in ``--shape`` / ``--reshape`` / ``--local`` (the last one silently won); two EasyMocap cameras whose names
became one folder name (one calibration silently dropped). Held (checked here, not changed): ``int`` / ``float``
parsing of ``--frames A:B``, ``--player``, edit values (a trailing newline, '+', '-0' read right; NUL, '²', 'nan',
'inf' refused by the range checks).
"""

from __future__ import annotations

import numpy as np
import pytest

from bodystudio.errors import BodyStudioError, FileFormatError, InputError


def test_safe_name_matches_the_whole_name():
    from bodystudio.capture.importer import _safe_name

    assert _safe_name("cam_01") == "cam_01" and _safe_name("cam 1") == "cam_1"
    assert _safe_name("cam1\n") == "cam1_"  # before: 'cam1\n' kept ('$' matches before a final newline)
    assert _safe_name("cam1\x00") == "cam1_"


def _rig(names):
    from bodystudio.geometry.camera import Camera, CameraRig

    K = [[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]]
    return CameraRig({n: Camera(n, K, None, np.eye(3), np.array([0.1 * k, 0, 2.0]), 640, 480)
                      for k, n in enumerate(names)})


def test_two_easymocap_cameras_that_become_one_folder_name_are_refused(tmp_path):
    """'cam 1' and 'cam_1' both became 'cam_1': the rig kept one camera, the other's calibration silently gone."""
    from bodystudio.capture.importer import load_easymocap_cameras, save_easymocap_cameras

    save_easymocap_cameras(tmp_path / "ok", _rig(["cam 1", "cam_2"]))
    rig = load_easymocap_cameras(tmp_path / "ok" / "intri.yml", tmp_path / "ok" / "extri.yml")
    assert sorted(rig.cameras) == ["cam_1", "cam_2"]
    save_easymocap_cameras(tmp_path / "bad", _rig(["cam 1", "cam_1"]))
    with pytest.raises(FileFormatError, match="^.*intri.yml: cameras 'cam 1' and 'cam_1' both become 'cam_1' as "
                       "folder names; rename one"):
        load_easymocap_cameras(tmp_path / "bad" / "intri.yml", tmp_path / "bad" / "extri.yml")


@pytest.mark.parametrize("stem, ok", [("00001", True), ("7", True), ("²³", False), ("٠٠٠٠١", False), ("1\n", False),
                                      ("", False), ("-1", False), ("+1", False)])
def test_a_frame_number_is_ascii_digits(stem, ok):
    from bodystudio.fileio import is_frame_number

    assert is_frame_number(stem) is ok


def test_recorder_file_order_with_superscript_digits():
    """'frame_1²0.png' crashed the import's file order (its part '²' is ``isdigit`` but not ``int``); now the '²'
    is ordered as text."""
    from pathlib import Path

    from bodystudio.capture.importer import frame_order

    names = ["frame_10.png", "frame_9.png", "frame_1²0.png"]
    assert sorted(names, key=lambda n: frame_order(Path(n))) == ["frame_1²0.png", "frame_9.png", "frame_10.png"]


def test_calibration_capture_takes_only_ascii_numbered_images(tmp_path):
    """A capture folder with '²³.png' (a traceback before) and '٠٠٠٠١.png' (read as frame 1, and after
    ``00001.png`` in name order it replaced that frame's image): both are not frames."""
    from bodystudio.calib.observations import capture_images

    cam = tmp_path / "cam_00"
    cam.mkdir()
    for name in ("00001.png", "00002.png", "²³.png", "٠٠٠٠١.png"):
        (cam / name).write_bytes(b"")
    images = capture_images(tmp_path)
    assert images == {"cam_00": {1: cam / "00001.png", 2: cam / "00002.png"}}


def test_live_mirror_folder_ignores_other_digits(tmp_path):
    """A live recording folder's ``kinect/rgb/²³.png`` stopped the live run with a traceback."""
    from bodystudio.mirror.run import _ArrivedFrames

    rgb = tmp_path / "kinect" / "rgb"
    rgb.mkdir(parents=True)
    for name in ("00000.png", "00001.png", "²³.png", "٠٠٠٠٢.png"):
        (rgb / name).write_bytes(b"")
    assert list(_ArrivedFrames(tmp_path)) == [0, 1]


@pytest.mark.parametrize("address", ["tcp://10.0.0.5:٨٧٨٦", "tcp://10.0.0.5\x00:8786", "tcp://10.0.0.5:", "tcp://h:1:2"])
def test_scheduler_address_in_other_digits_or_with_nul_is_refused(address):
    from bodystudio.batch import resolve_scheduler

    with pytest.raises(InputError, match="not a scheduler address; give tcp://HOST:PORT"):
        resolve_scheduler(address, None)
    assert resolve_scheduler("tcp://[::1]:8786", None) == "tcp://[::1]:8786"


def test_a_name_given_twice_is_refused():
    from bodystudio.cli.body import parse_assignments
    from bodystudio.cli.muscle import _parse_shape
    from bodystudio.rig.reshape import parse_reshape

    with pytest.raises(InputError, match=r"^--shape .*: bmi is given twice; give each once$"):
        _parse_shape("bmi=20,muscularity=0.3,height_m=1.7,arm_length_m=0.6,bmi=31")
    assert _parse_shape("bmi=20,muscularity=0.3,height_m=1.7,arm_length_m=0.6").bmi == 20
    with pytest.raises(InputError, match="stature_m is given twice"):
        parse_reshape("stature=0.05,stature_m=-0.05")
    assert parse_reshape("stature=+0.05,mass=-5") == {"stature_m": 0.05, "mass_kg": -5.0}
    with pytest.raises(InputError, match="^--local upperarm-fat-decr-incr: given twice; give each once$"):
        parse_assignments(["upperarm-fat-decr-incr=0.1", "upperarm-fat-decr-incr =0.5"], "--local")


@pytest.mark.parametrize("text, frames", [("10:12\n", [10, 11]), ("+10:12", [10, 11]), ("-0:2", [0, 1]),
                                          ("10", [10])])
def test_held_frame_ranges_read_right(text, frames):
    from bodystudio.reconstruct.sequence import parse_frames

    assert parse_frames(text, list(range(20))) == frames


@pytest.mark.parametrize("text", ["1\x00:5", "²:5", "nan:5", "inf:5", "0:5:7"])
def test_held_frame_ranges_refused(text):
    from bodystudio.garment.person import parse_frame_range
    from bodystudio.reconstruct.sequence import parse_frames

    with pytest.raises(InputError, match="--frames"):
        parse_frames(text, list(range(20)))
    with pytest.raises(InputError, match="--frames"):
        parse_frame_range(text, 20, "video.mp4")


@pytest.mark.parametrize("value", ["nan", "inf", "-inf", "²", "0.3\x00"])
def test_held_shape_values_refused(value):
    from bodystudio.cli.muscle import _parse_shape

    with pytest.raises(BodyStudioError):
        _parse_shape(f"bmi=25,muscularity={value},height_m=1.7,arm_length_m=0.6")
