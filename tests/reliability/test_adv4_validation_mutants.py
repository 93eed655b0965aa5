"""adv4's validation functions called directly (issue 17, mutation testing): the camera times file
(``importer.read_timestamps``), TUM's lists (``read_tum_list``), the recording's frame rate (``recording_fps``), the
frame files' natural order (``frame_order`` and its two callers), the session manifest's frame-order check
(``session._check_manifest``) and the frame's first body's player (the arm capture's tracked person, mutated here
in ``muscle.capture.arm_subject_player`` / ``subject_joints`` before rel5a moved it to ``capture/subject.py``).
The adv4 files run them through ``capture import`` / ``muscle capture`` on the studio
session (seconds per case, capfd); here each refusal's whole message, each boundary and each return value, on files
of a few lines and stand-in frames; < 1 s."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from bodystudio.capture.importer import (
    frame_order,
    image_files,
    load_joints,
    read_timestamps,
    read_tum_list,
    recording_fps,
)
from bodystudio.capture.session import CAMERAS_JSON, SESSION_FORMAT, SESSION_VERSION, _check_manifest
from bodystudio.errors import FileFormatError, SessionError

_NOT_AFTER = ("(a duplicated or out-of-order frame); one time per frame, increasing, in the order of the camera's "
              "frames: remove the duplicate or sort the frames")


def _file(tmp_path, text, name="cam_00.txt"):
    p = tmp_path / name
    p.write_text(text)
    return p


def _raises(exc, message):
    import re

    return pytest.raises(exc, match="^" + re.escape(message) + "$")


# --- read_timestamps -------------------------------------------------------------------------------------------

def test_timestamps_first_column_comments_and_blank_lines(tmp_path):
    p = _file(tmp_path, "# t frame\n\n  0.5, f0.png\n1.0 f1\n   # indented comment\n  1.25\n")
    t = read_timestamps(p)
    assert t.dtype == np.float64
    assert t.tolist() == [0.5, 1.0, 1.25]
    # strictly increasing by a hair is a frame
    assert read_timestamps(_file(tmp_path, "0.1\n0.1000001\n", "b.txt")).tolist() == [0.1, 0.1000001]


def test_timestamps_refusals_name_the_file_line_and_fix(tmp_path):
    missing = tmp_path / "cam_09.txt"
    with _raises(FileFormatError, f"{missing}: timestamps file not found; give one <camera>.txt per camera"):
        read_timestamps(missing)
    for text, n, shown in (("# c\nabc\n", 2, "'abc'"), ("0.0\nnan\n", 2, "'nan'"), ("# c\n\n-inf x\n", 3, "'-inf x'"),
                           ("inf\n", 1, "'inf'")):
        p = _file(tmp_path, text)
        with _raises(FileFormatError, f"{p}:{n}: {shown} is not a time in seconds"):
            read_timestamps(p)
    for text, message in (("0.5\n0.5\n", "2: time 0.5 s is not after line 1's 0.5 s "),
                          ("1.0\n# c\n0.25\n", "3: time 0.25 s is not after line 1's 1 s "),
                          ("0\n2\n1\n", "3: time 1 s is not after line 2's 2 s "),
                          ("0\n1\n2\n2\n", "4: time 2 s is not after line 3's 2 s ")):
        p = _file(tmp_path, text)
        with _raises(FileFormatError, f"{p}:{message}{_NOT_AFTER}"):
            read_timestamps(p)
    p = _file(tmp_path, "# only\n\n")
    with _raises(FileFormatError, f"{p}: no timestamps"):
        read_timestamps(p)


# --- read_tum_list -----------------------------------------------------------------------------------------------

def test_tum_list_lines_and_order_kept(tmp_path):
    p = _file(tmp_path, "# depth maps\n  # t f\n\n100.033 depth/b.png extra\n100.000 depth/a.png\n", "depth.txt")
    assert read_tum_list(p) == [(100.033, "depth/b.png"), (100.0, "depth/a.png")]


def test_tum_list_refusals(tmp_path):
    missing = tmp_path / "rgb.txt"
    with _raises(FileFormatError, f"{missing}: not found; a TUM RGB-D folder has depth.txt and rgb.txt"):
        read_tum_list(missing)
    for text, n, shown in (("# c\n100.0\n", 2, "'100.0'"), ("x a.png\n", 1, "'x a.png'")):
        p = _file(tmp_path, text, "depth.txt")
        with _raises(FileFormatError, f"{p}:{n}: expected 'timestamp filename', got {shown}"):
            read_tum_list(p)
    for text, message in (("# c\n100.0 a.png\n100.00 b.png\n", "3: time 100.00 repeats line 2's (a duplicated "
                                                                "frame); remove the duplicate"),
                          ("1 a\n2 b\n1.0 c\n", "3: time 1.0 repeats line 1's (a duplicated frame); remove the "
                                                "duplicate"),
                          ("# c\nnan a.png\n", "2: time nan is not a time in seconds"),
                          ("1 a\ninf b\n", "2: time inf is not a time in seconds")):
        p = _file(tmp_path, text, "depth.txt")
        with _raises(FileFormatError, f"{p}:{message}"):
            read_tum_list(p)


# --- recording_fps -------------------------------------------------------------------------------------------------

def test_frame_rate_is_one_over_the_median_period():
    assert recording_fps(None) is None
    assert recording_fps([]) is None
    assert recording_fps([3.0]) is None
    assert recording_fps([0.0, 1 / 15, 2 / 15]) == 15.0
    assert recording_fps([2 / 15, 0.0, 1 / 15]) == 15.0  # sorted first
    assert recording_fps([0.0, 0.1, 0.2, 0.25, 0.3]) == 13.333  # median of 0.1, 0.1, 0.05, 0.05: 0.075
    assert recording_fps(np.array([0, 1, 2])) == 1.0  # integers: the lower bound is a camera's
    assert recording_fps([0.0, 0.25 / 60]) == 240.0  # the upper bound too
    assert type(recording_fps([0.0, 0.5])) is float


@pytest.mark.parametrize(("times", "period"), [([0.0, 2.0, 4.0], "2"), ([0.0, 0.004], "0.004"),
                                               ([5.0, 5.0, 5.0], "0"), ([0, 66.7, 133.4], "66.7"),
                                               ([0.0, 1 / 240.5], "0.004158")])
def test_frame_rates_outside_a_camera_are_refused(times, period):
    src = Path("ts/cam_00.txt")
    with _raises(FileFormatError, f"{src}: the median frame period {period} s is not a camera's (1..240 fps); give "
                                  "the times in seconds"):
        recording_fps(times, src)


# --- frame_order ----------------------------------------------------------------------------------------------------

def test_frame_order_key_and_sort():
    assert frame_order(Path("cam/f10_b.png")) == [(1, 0, "f"), (0, 10, "10"), (1, 0, "_b.png")]
    assert frame_order(Path("9.json")) == [(1, 0, ""), (0, 9, "9"), (1, 0, ".json")]
    names = ["f2.png", "f10.png", "f9.png", "f1.png", "g.png", "f01.png", "a10b10.png", "a10b2.png", "a9b99.png"]
    assert sorted(names, key=lambda n: frame_order(Path(n))) == [
        "a9b99.png", "a10b2.png", "a10b10.png", "f01.png", "f1.png", "f2.png", "f9.png", "f10.png", "g.png"]


def test_image_files_and_joint_folders_in_frame_order(tmp_path):
    images = tmp_path / "cam_00"
    images.mkdir()
    for n in ("f10.png", "f9.PNG", "f100.jpg", ".f1.png", "notes.txt"):
        (images / n).write_bytes(b"")
    assert [p.name for p in image_files(images)] == ["f9.PNG", "f10.png", "f100.jpg"]
    (images / "f50.png").mkdir()  # a folder with an image's name: refused, not skipped
    with _raises(FileFormatError, f"{images / 'f50.png'}: not a regular file (a folder, pipe or device); remove it "
                                  "from the image folder"):
        image_files(images)
    joints = tmp_path / "joints"
    joints.mkdir()
    for k in (10, 9, 11):  # numbers without a gap (adv5 refuses one); 10 sorts before 9 by plain name
        (joints / f"{k}.json").write_text(json.dumps({"names": ["Head"], "positions": [[k / 100, 1.0, 0.0]]}))
    assert load_joints(joints).positions[:, 0, 0].tolist() == [0.09, 0.1, 0.11]


# --- the session manifest's frame order -----------------------------------------------------------------------------

def _manifest(frames):
    return {"format": SESSION_FORMAT, "version": SESSION_VERSION, "cameras": ["cam_00"], "frames": frames,
            "streams": [], "files": {CAMERAS_JSON: "0" * 64}}


@pytest.mark.parametrize(("frames", "shown"), [([1, 0], "0 after 1"), ([0, 0, 1], "0 after 0"),
                                               ([0, 5, 5, 2], "5 after 5"), ([0, 1, 2, 7, 3], "3 after 7")])
def test_manifest_frames_out_of_order_are_refused(frames, shown):
    src = Path("S/session.json")
    with _raises(SessionError, f"{src}: manifest field 'frames' lists frame {shown}; each frame id once, increasing: "
                               "fix session.json or re-import"):
        _check_manifest(_manifest(frames), src)


def test_manifest_frames_increasing_are_taken():
    for frames in ([], [4], [0, 1], [0, 2, 9, 10]):
        _check_manifest(_manifest(frames), Path("S/session.json"))


# --- the frame's first body (the arm capture's and reconstruct's subject: bodystudio/capture/subject.py,
# mutated with tests/capture/test_subject_mutants.py) -------------------------------------------------------------

def test_the_frames_first_body_records_its_player():
    """``Frame.kinect_joints`` (the lowest player id's body) carries ``player``."""
    from bodystudio.capture.session import Frame

    bodies = [{"player": p, "names": [f"n{p}"], "positions": np.full((1, 3), p), "tracked": np.ones(1, bool),
               "joint_set": "v2"} for p in (3, 2, 5)]
    frame = Frame(None, 0)
    frame.__dict__["kinect_bodies"] = bodies  # the parsed joints file (cached_property's slot)
    assert frame.kinect_joints == {k: bodies[1][k] for k in ("names", "positions", "tracked", "joint_set", "player")}
