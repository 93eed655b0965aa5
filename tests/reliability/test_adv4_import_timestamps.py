"""``capture import --timestamps`` on a recording with a duplicated or reordered frame, and with tracker joints when
the synchronisation drops a frame (adversarial pass 4).

Before: a camera's times file with a repeated time, an earlier time or ``nan`` imported with exit 0 (matched by
nearest time, a repeated time became the same image in two session frames, and the first camera's reordered times
became frames out of time order); and ``--joints`` went to session frames by session index, so once the
synchronisation dropped a frame another camera missed, every later frame got the joints of the frame before it. Now a
time that is not after the previous line's is refused naming the file and line, and the joints follow the first
camera's frame, as the images do."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from tests.reliability.conftest import assert_clean_error, run_inprocess

NAMES = ["SpineBase", "Neck", "Head"]


def _times(folder, **per_camera):
    folder.mkdir()
    for cam, lines in per_camera.items():
        (folder / f"{cam}.txt").write_text("".join(f"{t}\n" for t in lines))
    return folder


@pytest.mark.parametrize("cam_01", [["0.0", "0.0"], ["0.033", "0.0"], ["0.0", "nan"]],
                         ids=["duplicated", "out_of_order", "nan"])
def test_a_time_not_after_the_previous_is_refused(studio, tmp_path, capfd, cam_01):
    stamps = _times(tmp_path / "ts", cam_00=["0.0", "0.033"], cam_01=cam_01)
    out = tmp_path / "S"
    result = run_inprocess(["capture", "import", out, "--cameras", studio.cameras_json, "--images", studio.images,
                            "--timestamps", stamps], capfd)
    assert_clean_error(result, 2, f"{stamps / 'cam_01.txt'}:2:")
    assert not out.exists()


def test_joints_follow_the_first_cameras_frame_when_a_frame_is_dropped(studio, tmp_path, capfd):
    from bodystudio.capture.session import open_session

    # cam_01 has no frame within half a period of cam_00's first: the session is cam_00's second frame only
    stamps = _times(tmp_path / "ts", cam_00=["0.0", "0.033"], cam_01=["0.033", "0.5"])
    frames = np.array([[[0.0, 0.9, 0.0], [0.0, 1.4, 0.0], [0.0, 1.6, 0.0]],
                       [[0.5, 0.9, 0.0], [0.5, 1.4, 0.0], [0.5, 1.6, 0.0]]])
    joints = tmp_path / "joints.json"
    joints.write_text(json.dumps({"names": NAMES, "frames": frames.tolist()}))
    out = tmp_path / "S"
    result = run_inprocess(["capture", "import", out, "--cameras", studio.cameras_json, "--images", studio.images,
                            "--timestamps", stamps, "--joints", joints], capfd)
    assert_clean_error(result, 0, "")
    session = open_session(out)
    assert len(session) == 1
    np.testing.assert_allclose(session.frame(session.frame_ids[0]).kinect_joints["positions"], frames[1])
    # a joints file one frame short of the first camera's frames is refused with the --frames that fits
    short = tmp_path / "short.json"
    short.write_text(json.dumps({"names": NAMES, "frames": frames[:1].tolist()}))
    result = run_inprocess(["capture", "import", tmp_path / "S2", "--cameras", studio.cameras_json, "--images",
                            studio.images, "--timestamps", stamps, "--joints", short], capfd)
    assert_clean_error(result, 2, "1 joint frames but the recording has 2 frames; give one per recorded frame")


def test_the_recordings_frame_rate_is_recorded_and_milliseconds_refused(studio, tmp_path, capfd):
    """A 15 fps recording: session metadata fps 15 (readers assumed 30 without it: ``mirror run``'s video played
    twice as fast); times written in milliseconds are refused (a frame every 66.7 s)."""
    from bodystudio.capture.session import open_session

    stamps = _times(tmp_path / "ts", cam_00=["10.0", "10.0667"], cam_01=["10.001", "10.0677"])
    out = tmp_path / "S"
    result = run_inprocess(["capture", "import", out, "--cameras", studio.cameras_json, "--images", studio.images,
                            "--timestamps", stamps], capfd)
    assert_clean_error(result, 0, "")
    assert open_session(out).metadata["fps"] == pytest.approx(15.0, abs=0.01)
    ms = _times(tmp_path / "ms", cam_00=["0", "66.7"], cam_01=["0.5", "67.2"])
    result = run_inprocess(["capture", "import", tmp_path / "S2", "--cameras", studio.cameras_json, "--images",
                            studio.images, "--timestamps", ms], capfd)
    assert_clean_error(result, 2, f"{ms / 'cam_00.txt'}: the median frame period 66.7 s is not a camera's")
    assert not (tmp_path / "S2").exists()


def test_a_tum_list_with_a_repeated_time_is_refused(tmp_path):
    """TUM's depth.txt with a line repeated and a 60 fps colour list: both copies were paired with a colour frame, so
    one depth image became two session frames (exit 0); now refused naming the line. Lines out of order still read
    (the pairs are sorted by time)."""
    from bodystudio.capture.importer import associate_tum, read_tum_list
    from bodystudio.errors import FileFormatError

    depth = [(100 + k / 30, f"depth/{k}.png") for k in range(4)]
    colour = [(100.003 + k / 60, f"rgb/{k}.png") for k in range(8)]
    twice = associate_tum([*depth[:3], depth[2], depth[3]], colour)
    assert [p[1] for p in twice].count("depth/2.png") == 2  # what the refusal prevents
    ok = tmp_path / "ok.txt"
    ok.write_text("# depth maps\n100.033 depth/b.png\n100.000 depth/a.png\n")
    assert read_tum_list(ok) == [(100.033, "depth/b.png"), (100.0, "depth/a.png")]
    for lines, phrase in ((["100.0 depth/a.png", "100.0 depth/a.png"], "3: time 100.0 repeats line 2's"),
                          (["nan depth/a.png"], "2: time nan is not a time in seconds")):
        bad = tmp_path / "depth.txt"
        bad.write_text("# depth maps\n" + "\n".join(lines) + "\n")
        with pytest.raises(FileFormatError, match=rf"^{bad}:{phrase}"):
            read_tum_list(bad)


def test_unpadded_frame_numbers_keep_their_order(studio, tmp_path, capfd):
    """A recorder's unpadded names (``f9.png``, ``f10.png``; per-frame joints ``9.json``, ``10.json``): sorted by
    plain name ``f10`` came first, the session's frames out of time order with exit 0. Digit runs now sort as
    numbers."""
    import shutil

    import cv2

    from bodystudio.capture.importer import frame_order
    from bodystudio.capture.session import open_session

    names = ["f2.png", "f10.png", "f9.png", "f1.png", "g.png", "f01.png"]
    assert sorted(names, key=lambda n: frame_order(Path(n))) == ["f01.png", "f1.png", "f2.png", "f9.png", "f10.png",
                                                                 "g.png"]
    images = tmp_path / "images"
    for cam in ("cam_00", "cam_01"):
        (images / cam).mkdir(parents=True)
        first, second = sorted((studio.images / cam).iterdir())
        shutil.copy(first, images / cam / "f9.png")
        shutil.copy(second, images / cam / "f10.png")
    joints = tmp_path / "joints"
    joints.mkdir()
    for k, frame in ((9, 0), (10, 1)):
        (joints / f"{k}.json").write_text(json.dumps({"names": NAMES, "positions": [[frame, 1.0, 0.0]] * 3}))
    out = tmp_path / "S"
    result = run_inprocess(["capture", "import", out, "--cameras", studio.cameras_json, "--images", images,
                            "--joints", joints], capfd)
    assert_clean_error(result, 0, "")
    session = open_session(out)
    want = cv2.imread(str(sorted((studio.images / "cam_00").iterdir())[0]))[..., ::-1]
    assert np.array_equal(session.frame(0).images["cam_00"], want)
    assert session.frame(1).kinect_joints["positions"][0, 0] == 1.0
