"""Session format: the player-mask stream and joints files holding several bodies (mirror sessions, issue 12)."""

import json

import numpy as np
import pytest

from bodystudio.capture.session import SessionWriter, open_session
from bodystudio.errors import SessionError
from bodystudio.geometry.camera import CameraRig, kinect_v1

NAMES = ["Head", "Neck"]


def _write(path, bodies=None, single=None, player=None):
    with SessionWriter(path, CameraRig([]), source="synthetic") as w:
        w.write_kinect_calibration(kinect_v1("320x240"))
        w.write_kinect_depth(0, np.full((240, 320), 2.0))
        if bodies is not None:
            w.write_kinect_bodies(0, bodies, joint_set="v1")
        if single is not None:
            w.write_kinect_joints(0, NAMES, single, [True, False], joint_set="v1")
        if player is not None:
            w.write_kinect_player(0, player)
    return open_session(path)


def test_two_bodies_round_trip_and_single_body_readers_see_the_lowest_player(tmp_path):
    a = {"player": 2, "names": NAMES, "positions": [[0, 1.7, 0], [np.nan, np.nan, np.nan]], "tracked": [True, False]}
    b = {"player": 1, "names": NAMES, "positions": [[1, 1.6, 0], [1, 1.4, 0]]}
    frame = _write(tmp_path / "s", bodies=[a, b]).frame(0)
    bodies = frame.kinect_bodies
    assert [x["player"] for x in bodies] == [1, 2]
    np.testing.assert_array_equal(bodies[1]["positions"][0], [0, 1.7, 0])
    assert np.all(np.isnan(bodies[1]["positions"][1])) and list(bodies[1]["tracked"]) == [True, False]
    assert list(bodies[0]["tracked"]) == [True, True]
    np.testing.assert_array_equal(frame.kinect_joints["positions"], [[1, 1.6, 0], [1, 1.4, 0]])
    # the file keeps the single-body layout at the top level for older readers
    raw = json.loads((tmp_path / "s/kinect/joints/00000.json").read_text())
    assert raw["names"] == NAMES and raw["positions"][0] == [1.0, 1.6, 0.0]


def test_old_single_body_layout_reads_as_player_one(tmp_path):
    frame = _write(tmp_path / "s", single=[[0, 1.7, 0], [0, 1.5, 0]]).frame(0)
    (body,) = frame.kinect_bodies
    assert body["player"] == 1 and body["names"] == NAMES and list(body["tracked"]) == [True, False]


def test_empty_body_list_means_nobody_tracked(tmp_path):
    frame = _write(tmp_path / "s", bodies=[]).frame(0)
    assert frame.kinect_bodies == [] and frame.kinect_joints is None


def test_player_mask_round_trip_and_range(tmp_path):
    mask = np.zeros((240, 320), np.uint8)
    mask[10:20, 30:40] = 1
    mask[50:60, 30:40] = 6
    s = _write(tmp_path / "s", player=mask)
    assert "kinect_player" in s.streams
    np.testing.assert_array_equal(s.frame(0).kinect_player, mask)
    with pytest.raises(ValueError, match="0..6"):
        _write(tmp_path / "t", player=np.full((240, 320), 7, np.uint8))
    assert s.frame(0).kinect_player.dtype == np.uint8


def test_bad_bodies_are_refused(tmp_path):
    body = {"player": 1, "names": NAMES, "positions": [[0, 1, 0], [0, 2, 0]]}
    with pytest.raises(ValueError, match="differ"):
        _write(tmp_path / "a", bodies=[body, dict(body)])
    with pytest.raises(ValueError, match="1..6"):
        _write(tmp_path / "b", bodies=[{**body, "player": 0}])


def test_malformed_bodies_file_is_a_one_line_session_error(tmp_path):
    from bodystudio.capture.session import sha256_bytes

    s = _write(tmp_path / "s", bodies=[{"player": 1, "names": NAMES, "positions": [[0, 1, 0], [0, 2, 0]]}])
    rel = "kinect/joints/00000.json"
    for bad in ({"bodies": {"player": 1}}, {"bodies": [{"player": 9, "names": NAMES, "positions": [[0] * 3] * 2}]},
                {"bodies": [{"player": 1, "names": NAMES, "positions": [[0] * 3]}]}, [1, 2]):
        data = json.dumps(bad).encode()
        (s.path / rel).write_bytes(data)
        manifest = json.loads((s.path / "session.json").read_text())
        manifest["files"][rel] = sha256_bytes(data)
        (s.path / "session.json").write_text(json.dumps(manifest))
        with pytest.raises(SessionError, match="malformed joints") as info:
            _ = open_session(s.path).frame(0).kinect_bodies
        assert "\n" not in str(info.value)
