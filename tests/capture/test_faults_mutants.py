"""The planted studio faults of capture/faults.py, each on a tiny hand-made session folder (issue 17's mutation tests).

The plausibility tests (tests/reliability/test_*_plausibility.py) plant these faults into synthetic sessions and
reconstruct them (minutes); here each fault is checked exactly: which file changes, by how much, that every other
file and entry is left alone, and that the manifest records the new checksum (the fault is in the data, not in
the file, so every reader accepts it). Each test runs in milliseconds.
"""

import hashlib
import json

import cv2
import numpy as np
import pytest

from bodystudio.capture import faults

JOINTS = ("SpineBase", "KneeLeft", "KneeRight", "AnkleLeft", "AnkleRight", "FootLeft", "FootRight", "HandLeft")


def _sha(path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _cam(i: int) -> dict:
    a = 0.3 * i
    R = [[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0], [-np.sin(a), 0.0, np.cos(a)]]
    return {"R": R, "t": [0.1 * i, -0.2, 3.0 + i], "K": [[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]]}


def _make_session(tmp_path):
    """(A function, not a fixture: docs/mutation/recheck_direct.py builds fixtures once, and every test changes the
    folder.) Three cameras' masks (2 frames), the calibration, a Kinect's depth, colour calibration and joints."""
    S = tmp_path / "s"
    files = {}

    def put(rel, data: bytes):
        p = S / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_bytes(data)
        files[rel] = hashlib.sha256(data).hexdigest()

    put("calibration/cameras.json", json.dumps({"cameras": {f"cam_0{i}": _cam(i) for i in (1, 2, 3)},
                                                 "board": {"squares": 7}}).encode())
    rng = np.random.default_rng(0)
    for cam in ("cam_01", "cam_02", "cam_03"):
        for f in ("000000.png", "000001.png"):
            m = (rng.random((6, 8)) > 0.5).astype(np.uint8) * 255
            put(f"{cam}/mask/{f}", cv2.imencode(".png", m)[1].tobytes())
    depth = np.array([[0, 500, 1000, 6000], [6553, 6554, 7000, 65535]], np.uint16)
    for f in ("000000.png", "000001.png"):
        put(f"kinect/depth/{f}", cv2.imencode(".png", depth)[1].tobytes())
        depth = depth // 2
    put("kinect/calibration.json", json.dumps({"color": {"K": [[520.0, 0.0, 310.5], [0.0, 521.0, 250.5],
                                                                [0.0, 0.0, 1.0]], "size": [640, 480]},
                                                "depth": {"K": [[365.0, 0.0, 256.0], [0.0, 365.0, 212.0],
                                                                [0.0, 0.0, 1.0]]}}).encode())
    tracked = [True, True, True, False, True, True, True, True]
    put("kinect/joints/000000.json", json.dumps({"names": list(JOINTS), "tracked": tracked,
                                                 "bodies": [{"tracked": [True] * 8},
                                                            {"tracked": [1, 1, 1, 1, 1, 1, 0, 1],
                                                             "names": list(JOINTS[1:] + JOINTS[:1])},
                                                            {"id": 7}]}).encode())
    put("kinect/joints/000001.json", json.dumps({"names": list(JOINTS), "tracked": [True] * 8}).encode())
    put("kinect/joints/000002.json", json.dumps({"names": list(JOINTS), "bodies": None}).encode())
    (S / "session.json").write_text(json.dumps({"version": 1, "files": files, "subject": "x"}))
    return S


def _snapshot(S) -> dict:
    return {str(p.relative_to(S)): p.read_bytes() for p in sorted(S.rglob("*")) if p.is_file()}


def _changed(before: dict, S) -> set:
    after = _snapshot(S)
    assert set(after) == set(before)
    return {k for k in after if after[k] != before[k]}


def _manifest_matches(S) -> None:
    """Every file the manifest lists has the recorded checksum; the other manifest keys are kept."""
    manifest = json.loads((S / "session.json").read_text())
    assert manifest["version"] == 1 and manifest["subject"] == "x"
    for rel, sha in manifest["files"].items():
        assert _sha(S / rel) == sha, rel


def test_restamp_records_the_files_new_checksum_only(tmp_path):
    session = _make_session(tmp_path)
    (session / "kinect/calibration.json").write_text("{}")
    before = json.loads((session / "session.json").read_text())
    faults.restamp(str(session), "kinect/calibration.json")
    after = json.loads((session / "session.json").read_text())
    assert after["files"].pop("kinect/calibration.json") == _sha(session / "kinect/calibration.json")
    before["files"].pop("kinect/calibration.json")
    assert after == before


def test_bump_camera_rotates_about_y_and_shifts_along_x(tmp_path):
    session = _make_session(tmp_path)
    before = _snapshot(session)
    old = json.loads((session / "calibration/cameras.json").read_text())
    faults.bump_camera(session)  # cam_02, 3 degrees, 5 cm
    assert _changed(before, session) == {"calibration/cameras.json", "session.json"}
    new = json.loads((session / "calibration/cameras.json").read_text())
    a = np.deg2rad(3.0)
    dR = np.array([[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0], [-np.sin(a), 0.0, np.cos(a)]])
    R0, t0 = np.array(old["cameras"]["cam_02"]["R"]), np.array(old["cameras"]["cam_02"]["t"])
    np.testing.assert_allclose(new["cameras"]["cam_02"]["R"], dR @ R0, atol=1e-12)
    np.testing.assert_allclose(new["cameras"]["cam_02"]["t"], dR @ t0 + [0.05, 0.0, 0.0], atol=1e-12)
    assert new["cameras"]["cam_02"]["K"] == old["cameras"]["cam_02"]["K"]
    for k in ("cam_01", "cam_03"):
        assert new["cameras"][k] == old["cameras"][k]
    assert new["board"] == old["board"]
    _manifest_matches(session)


def test_bump_camera_takes_its_camera_angle_and_shift(tmp_path):
    session = _make_session(tmp_path)
    old = json.loads((session / "calibration/cameras.json").read_text())
    faults.bump_camera(str(session), camera="cam_03", deg=-10.0, shift_m=0.2)
    new = json.loads((session / "calibration/cameras.json").read_text())
    a = np.deg2rad(-10.0)
    dR = np.array([[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0], [-np.sin(a), 0.0, np.cos(a)]])
    R0, t0 = np.array(old["cameras"]["cam_03"]["R"]), np.array(old["cameras"]["cam_03"]["t"])
    np.testing.assert_allclose(new["cameras"]["cam_03"]["R"], dR @ R0, atol=1e-12)
    np.testing.assert_allclose(new["cameras"]["cam_03"]["t"], dR @ t0 + [0.2, 0, 0], atol=1e-12)
    assert new["cameras"]["cam_02"] == old["cameras"]["cam_02"]
    _manifest_matches(session)


def test_swap_masks_exchanges_two_cameras_masks(tmp_path):
    session = _make_session(tmp_path)
    before = _snapshot(session)
    faults.swap_masks(session)  # cam_01 <-> cam_03
    after = _snapshot(session)
    changed = _changed(before, session)
    assert changed == {"session.json"} | {f"{c}/mask/00000{i}.png" for c in ("cam_01", "cam_03") for i in (0, 1)}
    for i in (0, 1):
        f = f"00000{i}.png"
        assert after[f"cam_01/mask/{f}"] == before[f"cam_03/mask/{f}"]
        assert after[f"cam_03/mask/{f}"] == before[f"cam_01/mask/{f}"]
    _manifest_matches(session)


def test_swap_masks_takes_the_two_cameras(tmp_path):
    session = _make_session(tmp_path)
    before = _snapshot(session)
    faults.swap_masks(str(session), a="cam_02", b="cam_01")
    after = _snapshot(session)
    assert after["cam_02/mask/000001.png"] == before["cam_01/mask/000001.png"]
    assert after["cam_01/mask/000000.png"] == before["cam_02/mask/000000.png"]
    assert after["cam_03/mask/000000.png"] == before["cam_03/mask/000000.png"]
    _manifest_matches(session)


@pytest.mark.parametrize("factor", [None, 0.5, 3.0])
def test_scale_depth_multiplies_every_reading_and_clips_at_16_bits(tmp_path, factor):
    session = _make_session(tmp_path)
    before = _snapshot(session)
    old = [cv2.imread(str(session / f"kinect/depth/00000{i}.png"), cv2.IMREAD_UNCHANGED) for i in (0, 1)]
    if factor is None:
        faults.scale_depth(session)
        factor = 10.0
    else:
        faults.scale_depth(str(session), factor=factor)
    assert _changed(before, session) == {"session.json", "kinect/depth/000000.png", "kinect/depth/000001.png"}
    for i, D0 in enumerate(old):
        D = cv2.imread(str(session / f"kinect/depth/00000{i}.png"), cv2.IMREAD_UNCHANGED)
        assert D.dtype == np.uint16
        np.testing.assert_array_equal(D, np.clip(D0.astype(np.float64) * factor, 0, 65535).astype(np.uint16))
    _manifest_matches(session)


def test_scale_depth_by_ten_saturates_far_readings(tmp_path):
    session = _make_session(tmp_path)
    faults.scale_depth(session)
    D = cv2.imread(str(session / "kinect/depth/000000.png"), cv2.IMREAD_UNCHANGED)
    np.testing.assert_array_equal(D, [[0, 5000, 10000, 60000], [65530, 65535, 65535, 65535]])


def test_shift_colour_camera_moves_the_principal_point(tmp_path):
    session = _make_session(tmp_path)
    before = _snapshot(session)
    old = json.loads((session / "kinect/calibration.json").read_text())
    faults.shift_colour_camera(session)
    assert _changed(before, session) == {"session.json", "kinect/calibration.json"}
    new = json.loads((session / "kinect/calibration.json").read_text())
    assert new["color"]["K"][0][2] == 320.5
    new["color"]["K"][0][2] = old["color"]["K"][0][2]
    assert new == old
    faults.shift_colour_camera(str(session), px=-4.5)
    assert json.loads((session / "kinect/calibration.json").read_text())["color"]["K"][0][2] == 316.0
    _manifest_matches(session)


def test_legs_untracked_marks_knees_ankles_and_feet_inferred(tmp_path):
    session = _make_session(tmp_path)
    before = _snapshot(session)
    faults.legs_untracked(session)
    assert _changed(before, session) == {"session.json"} | {f"kinect/joints/00000{i}.json" for i in (0, 1)}
    legs = [n in faults.LEG_JOINTS for n in JOINTS]
    doc = json.loads((session / "kinect/joints/000000.json").read_text())
    assert doc["tracked"] == [True, False, False, False, False, False, False, True]
    assert doc["bodies"][0]["tracked"] == [not g for g in legs]
    # the second body lists its joints in another order (its own names count); its untracked one stays untracked
    assert doc["bodies"][1]["tracked"] == [False, False, False, False, False, False, False, True]
    assert doc["bodies"][2] == {"id": 7}
    assert doc["names"] == list(JOINTS)
    doc1 = json.loads((session / "kinect/joints/000001.json").read_text())
    assert doc1 == {"names": list(JOINTS), "tracked": [not g for g in legs]}
    assert json.loads((session / "kinect/joints/000002.json").read_text()) == {"names": list(JOINTS), "bodies": None}
    assert all(type(t) is bool for t in doc["bodies"][1]["tracked"])
    _manifest_matches(session)


def test_leg_joints_are_the_kinects_knees_ankles_and_feet():
    assert set(faults.LEG_JOINTS) == {"KneeLeft", "KneeRight", "AnkleLeft", "AnkleRight", "FootLeft", "FootRight"}


def test_legs_untracked_refuses_a_tracked_list_that_does_not_match_the_names(tmp_path):
    session = _make_session(tmp_path)
    doc = json.loads((session / "kinect/joints/000001.json").read_text())
    doc["tracked"] = doc["tracked"][:-1]
    (session / "kinect/joints/000001.json").write_text(json.dumps(doc))
    with pytest.raises(ValueError):
        faults.legs_untracked(session)
