"""``capture import --joints`` when the tracker wrote nothing for a frame (adversarial pass 5).

Before: joints went to the recording's frames in order, so a CSV with rows for frames 0 and 2 (the body lost at
frame 1) put frame 2's joints on session frame 1 with exit 0, and a per-frame JSON folder missing ``00001.json`` did
the same; with one joint frame fewer than recorded frames the refusal suggested the ``--frames`` that did it. A CSV
frame of ``1.5`` raised a ValueError traceback. Now the frame numbers must run without a gap, each problem one line."""

from __future__ import annotations

import json

import pytest

from tests.reliability.conftest import assert_clean_error, run_inprocess

NAMES = ["SpineBase", "Neck", "Head"]


def _csv(path, frames, bad_row: str | None = None):
    lines = ["frame,joint,x,y,z,tracked"]
    for f in frames:
        lines += [f"{f},{n},{0.1 * f},{0.9 + 0.3 * j},0.0,1" for j, n in enumerate(NAMES)]
    if bad_row is not None:
        lines.append(bad_row)
    path.write_text("\n".join(lines) + "\n")
    return path


def _folder(path, frames):
    path.mkdir()
    for f in frames:
        (path / f"{f:05d}.json").write_text(json.dumps(
            {"names": NAMES, "positions": [[0.1 * f, 0.9 + 0.3 * j, 0.0] for j in range(3)]}))
    return path


def _import(studio, tmp_path, capfd, joints):
    return run_inprocess(["capture", "import", tmp_path / "S", "--cameras", studio.cameras_json, "--images",
                          studio.images, "--joints", joints], capfd)


@pytest.mark.parametrize("kind", ["csv", "folder"])
def test_joint_frames_with_a_gap_are_refused(studio, tmp_path, capfd, kind):
    joints = _csv(tmp_path / "j.csv", [0, 2]) if kind == "csv" else _folder(tmp_path / "j", [0, 2])
    result = _import(studio, tmp_path, capfd, joints)
    what = "frame 0 to frame 2" if kind == "csv" else "00000.json to 00002.json"
    assert_clean_error(result, 2, f"{joints}: the joint frames jump from {what}")
    assert not (tmp_path / "S").exists()


@pytest.mark.parametrize("kind", ["csv", "folder"])
def test_joint_frames_numbered_from_one_import(studio, tmp_path, capfd, kind):
    from bodystudio.capture.session import open_session

    joints = _csv(tmp_path / "j.csv", [1, 2]) if kind == "csv" else _folder(tmp_path / "j", [1, 2])
    assert_clean_error(_import(studio, tmp_path, capfd, joints), 0, "")
    session = open_session(tmp_path / "S")
    assert session.frame(session.frame_ids[1]).kinect_joints["positions"][0][0] == pytest.approx(0.2)


def test_a_frame_number_that_is_not_whole_is_one_line(studio, tmp_path, capfd):
    joints = _csv(tmp_path / "j.csv", [0, 1], bad_row="1.5,Head,0,1,0,1")
    assert_clean_error(_import(studio, tmp_path, capfd, joints), 2, f"{joints}:8: frame '1.5' is not a whole frame")
