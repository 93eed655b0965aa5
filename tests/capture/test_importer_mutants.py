"""The import of real recordings, its functions called directly on tiny inputs (issue 17, mutation testing of
``capture/importer.py``; adv4's validation functions are in tests/reliability/test_adv4_validation_mutants.py):
the timestamp synchronisation and TUM's association (hand-worked cases, both tolerance boundaries), the depth
units, the Kinect SDK's axes (against the camera equations written out), the joints readers (per-frame JSON,
one JSON, CSV) and the joints-frame check, EasyMocap's YAML (written with OpenCV's own FileStorage), the sizes,
and ``import_recording`` end to end on an 8 x 6 two-camera recording with TUM depth and joints. Every refusal's
whole line; < 3 s."""

from __future__ import annotations

import json
import re
from pathlib import Path

import cv2
import numpy as np
import pytest

from bodystudio.capture import importer as imp
from bodystudio.errors import FileFormatError, InputError
from bodystudio.geometry.camera import Camera, CameraRig, RGBDSensor

W, H = 8, 6


def _raises(exc, message):
    return pytest.raises(exc, match="^" + re.escape(message) + "$")


# --- synchronisation ---------------------------------------------------------------------------------------------

def test_timestamp_synchronisation_keeps_frames_every_camera_saw_within_half_a_period():
    ref = np.array([0.0, 0.25, 0.5, 0.75, 1.0])  # median period 0.25: tolerance 0.125 (exact in binary)
    b = np.array([0.125, 0.5, 0.875, 1.0])
    c = np.array([0.0, 0.25, 0.5, 0.75])
    got = imp.synchronise_by_timestamps({"a": ref, "b": b, "c": c})
    # frame 0: b at 0.125 is exactly the tolerance away (kept); 0.25: nearest 0.125 (kept, first of the two
    # equally near); 0.75: 0.875 (kept); 1.0: c's nearest 0.75 is 0.25 away (dropped)
    assert got == [{"a": 0, "b": 0, "c": 0}, {"a": 1, "b": 0, "c": 1}, {"a": 2, "b": 1, "c": 2},
                   {"a": 3, "b": 2, "c": 3}]
    assert imp.synchronise_by_timestamps({"a": ref, "b": b}, tolerance_s=0.1) == [
        {"a": 2, "b": 1}, {"a": 4, "b": 3}]
    # the median, not the mean, period: one long gap leaves the tolerance at half the usual period
    assert imp.synchronise_by_timestamps({"a": np.array([0.0, 1.0, 2.0, 10.0]), "b": np.array([0.4, 2.6, 10.5])}) \
        == [{"a": 0, "b": 0}, {"a": 3, "b": 2}]
    # a single reference frame: any distance
    assert imp.synchronise_by_timestamps({"a": np.array([5.0]), "b": np.array([0.0, 1.0])}) == [{"a": 0, "b": 1}]
    assert imp.synchronise_by_timestamps({"a": ref}) == [{"a": k} for k in range(5)]


def test_tum_association_is_greedy_on_the_closest_pairs_strictly_within_the_limit():
    depth = [(1.0, "d1"), (1.03, "d2"), (1.1, "d3"), (2.0, "d4")]
    rgb = [(1.01, "r1"), (1.025, "r2"), (1.13, "r3"), (2.0 + 0.015625, "r4")]
    assert imp.associate_tum(depth, rgb) == [(1.0, "d1", "r1"), (1.03, "d2", "r2"), (2.0, "d4", "r4")]
    # d1-r1 0.01 and d2-r2 0.005: d2 takes r2 first, d1 then r1; with 0.0078125 only d2-r2 is close enough
    assert imp.associate_tum(depth, rgb, max_difference_s=0.0078125) == [(1.03, "d2", "r2")]
    assert imp.associate_tum(depth, rgb, max_difference_s=0.015625) == [(1.0, "d1", "r1"), (1.03, "d2", "r2")]
    assert imp.associate_tum([(3.0, "a"), (1.0, "b")], [(1.0, "x"), (3.0, "y")]) == [(1.0, "b", "x"), (3.0, "a", "y")]
    # one colour frame between two depth frames goes to the nearer one only
    assert imp.associate_tum([(1.0, "a"), (1.012, "b")], [(1.01, "x")]) == [(1.012, "b", "x")]
    assert imp.associate_tum([], rgb) == []


# --- depth units -------------------------------------------------------------------------------------------------

def test_depth_units_are_told_apart_by_where_a_kinect_sees_a_body():
    tum = np.array([[0, 10000, 10000, 12500]], np.uint16)  # median 10000: 2 m in TUM units only
    assert imp.depth_scale_of(tum, "d.png", None) == 5000.0
    assert imp.depth_scale_of(tum, "d.png", 1000.0) == 1000.0
    assert imp.depth_scale_of(np.zeros((2, 2), np.uint16), "d.png", None) == 5000.0
    assert imp.depth_scale_of(np.zeros((2, 2), np.uint16), "d.png", None, default=1000.0) == 1000.0
    assert imp.depth_scale_of(np.full((2, 2), 2.0, np.float32), "d.tiff", 1.0) == 1.0
    assert imp.depth_scale_of(np.array([[2500, 22500]], np.uint16), "d.png", None) == 5000.0  # 0.5 / 4.5 m bounds
    with _raises(FileFormatError, "d.tiff: depth is stored as floating point (metres?); pass --depth-scale 1 for "
                                  "metres, or store 16-bit PNG in TUM units (5000 per metre)"):
        imp.depth_scale_of(np.full((2, 2), 2.0), "d.tiff", None)
    for raw, dtype in ((np.full((2, 2), 200, np.uint8), "uint8"), (np.full((2, 2), 2000, np.int32), "int32")):
        with _raises(FileFormatError, f"d.png: depth must be a 16-bit PNG, got {dtype} (8-bit images lose the "
                                      "depth); export 16-bit depth"):
            imp.depth_scale_of(raw, "d.png", 1000.0)
    with _raises(FileFormatError, "d.png: depth looks like millimetres (median 1.80 m at 1000 per metre, 0.36 m at "
                                  "TUM's 5000); pass --depth-scale 1000"):
        imp.depth_scale_of(np.array([[0, 1700, 1800, 1900]], np.uint16), "d.png", None)
    with _raises(FileFormatError, "d.png: depth looks like metres (median 2.00 m at 1 per metre, 0.00 m at TUM's "
                                  "5000); pass --depth-scale 1"):
        imp.depth_scale_of(np.array([[2, 2, 3, 1]], np.uint16), "d.png", None)
    with _raises(FileFormatError, "d.png: depth units are ambiguous (median 0.90 m as TUM units or 4.50 m as "
                                  "millimetres); pass --depth-scale 5000 or --depth-scale 1000"):
        imp.depth_scale_of(np.array([[4500]], np.uint16), "d.png", None)
    with _raises(FileFormatError, "d.png: depth values (median 60000) are not in a known unit; pass --depth-scale "
                                  "(units per metre)"):
        imp.depth_scale_of(np.array([[60000, 0]], np.uint16), "d.png", None)


# --- the Kinect SDK's axes --------------------------------------------------------------------------------------

def _sensor(size=(W, H)):
    depth = Camera.look_at("k_depth", (0.2, 1.0, 2.5), (0.0, 0.9, 0.0), fx=6.0, width=size[0], height=size[1])
    color = Camera.look_at("k_color", (0.25, 1.0, 2.5), (0.0, 0.9, 0.0), fx=7.0, width=size[0], height=size[1])
    T = np.eye(4)
    T[:3, :3] = color.R @ depth.R.T
    T[:3, 3] = color.t - T[:3, :3] @ depth.t
    return RGBDSensor("k", "v1", depth, color, T)


def test_kinect_sdk_points_are_x_left_y_up_z_forward_of_the_depth_camera():
    s = _sensor()
    sdk = np.array([[0.1, 0.2, 2.0], [-0.3, 0.0, 1.0]])
    opencv = sdk * [-1.0, -1.0, 1.0]  # OpenCV's camera: x right, y down, z forward
    want = (opencv - s.depth.t) @ s.depth.R  # R^T (X_cam - t), row by row
    got = imp.kinect_sdk_to_studio(sdk, s)
    assert np.allclose(got, want, atol=1e-12)
    assert np.allclose(imp.studio_to_kinect_sdk(want, s), sdk, atol=1e-12)
    assert np.allclose(imp.kinect_sdk_to_studio([[0.0, 0.0, 0.0]], s)[0], s.depth.center, atol=1e-12)


def _track(P):
    P = np.asarray(P, np.float64).reshape(1, -1, 3)
    return imp.JointTrack(["a"] * P.shape[1], P, np.ones(P.shape[:2], bool))


def test_joints_frame_check_refuses_joints_given_in_the_other_frame():
    s = _sensor(size=(64, 48))
    person = np.array([[0.0, 1.0, 0.0], [0.0, 1.4, 0.1], [0.1, 0.6, 0.0]])
    imp.check_joints_frame(_track(person), s, "studio", Path("j.csv"))
    sdk = imp.studio_to_kinect_sdk(person, s)
    imp.check_joints_frame(_track(sdk), s, "kinect-sdk", Path("j.csv"))

    def where(P):  # the median depth and pixel, written out from the pinhole equations
        C = P @ s.depth.R.T + s.depth.t
        z, zc = np.median(C[:, 2]), np.maximum(C[:, 2], 1e-6)  # behind the camera: far off the image
        u = np.median(C[:, 0] / zc) * s.depth.K[0, 0] + s.depth.K[0, 2]
        v = np.median(C[:, 1] / zc) * s.depth.K[1, 1] + s.depth.K[1, 2]
        return z, u, v

    for P, frame, other, seen in ((sdk, "studio", "kinect-sdk", sdk), (person, "kinect-sdk", "studio",
                                                                       imp.kinect_sdk_to_studio(person, s))):
        z, u, v = where(seen)
        with _raises(FileFormatError, f"j.csv: read as --joints-frame {frame}, the joints lie {z:.2f} m in front of "
                                      f"the Kinect depth camera at pixel ({u:.0f}, {v:.0f}) of its 64x48 image, not "
                                      f"where it sees a person; if they are in the {other} frame pass --joints-frame "
                                      f"{other}, else check the --kinect-calibration"):
            imp.check_joints_frame(_track(P), s, frame, Path("j.csv"))
    # the bounds: 0.3..8 m in front, the pixel within half an image around it (a hair inside and outside: the
    # round trip through the camera is not exact to the last bit)
    cam = s.depth
    for z, ok in ((0.301, True), (0.299, False), (7.999, True), (8.001, False)):
        P = cam.camera_to_world(np.array([[0.0, 0.0, z]]) + [[(32 - cam.K[0, 2]) / cam.K[0, 0] * z,
                                                             (24 - cam.K[1, 2]) / cam.K[1, 1] * z, 0.0]])
        if ok:
            imp.check_joints_frame(_track(P), s, "studio", Path("j.csv"))
        else:
            with pytest.raises(FileFormatError):
                imp.check_joints_frame(_track(P), s, "studio", Path("j.csv"))
    for u, v, ok in ((-31.99, 24, True), (-32.01, 24, False), (95.99, 24, True), (96.01, 24, False),
                     (32, -23.99, True), (32, -24.01, False), (32, 71.99, True), (32, 72.01, False)):
        xn, yn = (u - cam.K[0, 2]) / cam.K[0, 0], (v - cam.K[1, 2]) / cam.K[1, 1]
        P = cam.camera_to_world(np.array([[xn * 2.0, yn * 2.0, 2.0]]))
        if ok:
            imp.check_joints_frame(_track(P), s, "studio", Path("j.csv"))
        else:
            with pytest.raises(FileFormatError, match=r"at pixel \("):
                imp.check_joints_frame(_track(P), s, "studio", Path("j.csv"))


# --- joints files ------------------------------------------------------------------------------------------------

def test_joints_from_a_folder_of_frames_in_natural_order(tmp_path):
    d = tmp_path / "joints"
    d.mkdir()
    for k, name in ((10, "f10.json"), (9, "f9.json"), (8, "f8.json")):  # numbers without a gap (adv5)
        (d / name).write_text(json.dumps({"names": ["a", "b"], "positions": [[k, 0, 0], [0, k, 0]],
                                          "tracked": [True, k != 9]}))
    (d / "notes.txt").write_text("x")
    track = imp.load_joints(d)
    assert track.names == ["a", "b"] and track.positions.shape == (3, 2, 3)
    assert track.positions[:, 0, 0].tolist() == [8, 9, 10] and track.tracked.tolist() == [[1, 1], [1, 0], [1, 1]]
    (d / "f11.json").write_text(json.dumps({"joints": {"a": [1, 2, 3], "c": [0, 0, 1]}}))
    with _raises(FileFormatError, f"{d / 'f11.json'}: joint names differ from f8.json; every frame needs the same "
                                  "joints"):
        imp.load_joints(d)
    (d / "f11.json").write_text(json.dumps({"joints": {"a": [11, 2, 3], "b": [0, 0, 1]}}))
    track = imp.load_joints(d)
    assert track.positions[3].tolist() == [[11, 2, 3], [0, 0, 1]] and track.tracked[3].tolist() == [True, True]
    empty = tmp_path / "empty"
    empty.mkdir()
    with _raises(FileFormatError, f"{empty}: no per-frame joint JSON files"):
        imp.load_joints(empty)
    for data, why in (({"names": ["a"]}, "'positions'"), ({"positions": [[1, 2, 3]]}, "'names'"),
                      ({"names": ["a", "b"], "positions": [[1, 2, 3]]},
                       "cannot reshape array of size 3 into shape (2,3)"),
                      ({"joints": {"a": [1, 2]}}, "cannot reshape array of size 2 into shape (3)"),
                      ([1, 2], "list indices must be integers or slices, not str")):
        with _raises(FileFormatError, f"f.json: joints need 'names' + 'positions' or a 'joints' object ({why})"):
            imp._joint_frame(data, Path("f.json"))


def test_joints_from_one_json_and_the_plausibility_checks(tmp_path):
    p = tmp_path / "j.json"
    p.write_text(json.dumps({"names": ["a", "b"], "frames": [[[1, 2, 3], [4, 5, 6]], [[0, 0, 20], [0, -20, 0]]]}))
    track = imp.load_joints(p)
    assert track.names == ["a", "b"] and track.positions.dtype == np.float64
    assert track.positions.tolist() == [[[1, 2, 3], [4, 5, 6]], [[0, 0, 20], [0, -20, 0]]]
    assert track.tracked.dtype == bool and track.tracked.all() and track.tracked.shape == (2, 2)
    p.write_text(json.dumps({"names": ["a"], "frames": [[[1, 2, 3]], [[1, 2, 3]]], "tracked": [[0], [1]]}))
    assert imp.load_joints(p).tracked.tolist() == [[False], [True]]
    for data, why in (({"frames": []}, "'names'"), ({"names": ["a"], "frames": [[1, 2]]},
                                                    "cannot reshape array of size 2 into shape (1,3)"),
                      ({"names": ["a"], "frames": [[1, 2, 3]], "tracked": [1, 1]},
                       "cannot reshape array of size 2 into shape (1,1)")):
        p.write_text(json.dumps(data))
        with _raises(FileFormatError, f"{p}: joints JSON needs 'names' and 'frames' (T x J x 3 metres): {why}"):
            imp.load_joints(p)
    p.write_text(json.dumps({"names": ["a"], "frames": [[[1, 2, 25.4]]]}))
    with _raises(FileFormatError, f"{p}: joint coordinates up to 25 look like millimetres; give metres"):
        imp.load_joints(p)
    p.write_text(json.dumps({"names": ["a"], "frames": [[[1, -21, 0]]]}))
    with pytest.raises(FileFormatError, match="up to 21 look like millimetres"):
        imp.load_joints(p)
    p.write_text('{"names": ["a"], "frames": [[[1, NaN, 0]]]}')
    with _raises(FileFormatError, f"{p}: joint positions contain NaN or infinity"):
        imp.load_joints(p)
    p.write_text('{"names": ["a"], "frames": [[[1, Infinity, 0]]]}')
    with _raises(FileFormatError, f"{p}: joint positions contain NaN or infinity"):
        imp.load_joints(p)
    other = tmp_path / "j.txt"
    other.write_text("x")
    with _raises(FileFormatError, f"{other}: joints must be a folder of JSON, a .json or a .csv file"):
        imp.load_joints(other)
    upper = tmp_path / "J.JSON"
    upper.write_text(json.dumps({"names": ["a"], "frames": [[[1, 2, 3]]]}))
    assert imp.load_joints(upper).positions.shape == (1, 1, 3)


def test_json_or_error_names_the_file(tmp_path):
    with _raises(FileFormatError, f"{tmp_path}: not a regular file"):
        imp.json_or_error(tmp_path)
    p = tmp_path / "x.json"
    for data in (b"{ nope", b'"\xff"'):
        p.write_bytes(data)
        try:
            json.loads(p.read_text()) if data[:1] == b"{" else data.decode()
        except ValueError as exc:
            why = str(exc)
        with _raises(FileFormatError, f"{p}: not valid JSON ({why})"):
            imp.json_or_error(p)
    p.write_text('{"a": 1}')
    assert imp.json_or_error(p) == {"a": 1}


def test_joints_csv_rows_tracked_words_and_refusals(tmp_path):
    p = tmp_path / "J.CSV"
    p.write_text("frame,joint,x,y,z,tracked\n"
                 "4,head,0,1.5,0.1,1\n4,neck,0,1.4,0,FALSE\n3,neck,1,2,3, no \n3,head,4,5,6,yes\n"
                 "5,head,0,0,0,0\n5,neck,1,1,1,true\n")
    track = imp.load_joints(p)
    assert track.names == ["head", "neck"]
    assert track.positions.tolist() == [[[4, 5, 6], [1, 2, 3]], [[0, 1.5, 0.1], [0, 1.4, 0]], [[0, 0, 0], [1, 1, 1]]]
    assert track.tracked.tolist() == [[True, False], [True, False], [False, True]]
    p.write_text("frame,joint,x,y,z\n0,a,1,2,3\n")
    assert imp.load_joints(p).tracked.tolist() == [[True]]
    for text in ("frame,joint,x,y\n0,a,1,2\n", "frame,joint,x,y,z\n", ""):
        p.write_text(text)
        with _raises(FileFormatError, f"{p}: CSV needs a header with columns frame,joint,x,y,z[,tracked]"):
            imp.load_joints(p)
    p.write_text("frame,joint,x,y,z\n0,a,1,2,3\n0,b,1,two,3\n")
    with _raises(FileFormatError, f"{p}:3: frame, x, y, z must be numbers"):
        imp.load_joints(p)
    p.write_text("frame,joint,x,y,z\n0,a,1,2,3\n1,a,1,2,3\n1,b,1,2,3\n")
    with _raises(FileFormatError, f"{p}: frame 0 has no row for joint b"):
        imp.load_joints(p)
    # a frame the tracker wrote nothing for (adv5): the later joints would go to the frame before theirs
    p.write_text("frame,joint,x,y,z\n0,a,1,2,3\n2,a,1,2,3\n")
    with _raises(FileFormatError, f"{p}: the joint frames jump from frame 0 to frame 2; joints go to the recording's "
                                  "frames in order, so each later frame's would go to an earlier frame: give one entry "
                                  "per recorded frame (tracked 0 where the body was lost)"):
        imp.load_joints(p)


# --- EasyMocap cameras, written with OpenCV's own FileStorage ---------------------------------------------------

def _cam(name, eye, f, dist=(0.0,) * 5):
    return Camera.look_at(name, eye, (0, 1, 0), fx=f, width=64, height=48, dist=dist)


def _yml(path, names, entries):
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.startWriteStruct("names", cv2.FileNode_SEQ)
    for n in names:
        fs.write("", n)
    fs.endWriteStruct()
    for k, v in entries.items():
        fs.write(k, v)
    fs.release()


def _easymocap(folder, cams, sizes=True, rodrigues=True, rot=True, names=None):
    folder.mkdir(exist_ok=True)
    intri, extri = {}, {}
    for c in cams:
        intri[f"K_{c.name}"] = c.K
        intri[f"dist_{c.name}"] = c.dist[None, :4]  # four coefficients: k3 padded with 0
        if sizes:
            intri[f"W_{c.name}"], intri[f"H_{c.name}"] = c.width, c.height
        if rodrigues:
            extri[f"R_{c.name}"] = cv2.Rodrigues(c.R)[0]
        if rot:
            extri[f"Rot_{c.name}"] = np.round(c.R, 6) if not rodrigues else np.eye(3)
        extri[f"T_{c.name}"] = c.t[:, None]
    names = [c.name for c in cams] if names is None else names
    _yml(folder / "intri.yml", names, intri)
    _yml(folder / "extri.yml", names, extri)
    return folder


def test_easymocap_cameras_read_back_with_the_rodrigues_vector_first(tmp_path):
    a = _cam("a", (0.5, 1.2, 3.0), 50.0, dist=(0.1, -0.05, 0.001, 0.002, 0.0))
    b = _cam("b", (-1.0, 1.0, 2.0), 60.0)
    rig = imp.load_studio_cameras(_easymocap(tmp_path / "c", [a, b]))
    assert list(rig.cameras) == ["a", "b"]
    for got, want in ((rig["a"], a), (rig["b"], b)):
        assert np.allclose(got.K, want.K) and np.allclose(got.R, want.R, atol=1e-12)
        assert np.allclose(got.t, want.t) and np.allclose(got.dist, want.dist) and got.dist.shape == (5,)
        assert (got.width, got.height) == (64, 48)
    # the rotation matrix alone, rounded to 6 decimals: the nearest rotation (orthonormal, det +1)
    rig = imp.load_studio_cameras(_easymocap(tmp_path / "d", [a], rodrigues=False) / "extri.yml")
    R = rig["a"].R
    assert np.allclose(R, a.R, atol=2e-6) and np.allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert np.isclose(np.linalg.det(R), 1.0)
    # sizes from the frames, else the default
    folder = _easymocap(tmp_path / "e", [a, b], sizes=False)
    rig = imp.load_studio_cameras(folder, {"a": (64, 48), "b": (66, 50)})
    assert (rig["b"].width, rig["b"].height) == (66, 50)
    # frames of another size than K's (its principal point far off their centre) are refused (adv5)
    with _raises(FileFormatError, f"{folder / 'intri.yml'}: camera b has no W_b/H_b and its frames are 32x24, but K's "
                                  "principal point (31.5, 23.5) is 48 % of the image off their centre (a lens's lies "
                                  "within a few %): it is for about 63x47 images; calibrate at the frames' size and "
                                  "orientation, or add W_b/H_b to intri.yml"):
        imp.load_studio_cameras(folder, {"a": (64, 48), "b": (32, 24)})
    rig = imp.load_easymocap_cameras(folder / "intri.yml", folder / "extri.yml", {"a": (64, 48)}, (63, 47))
    assert (rig["a"].width, rig["b"].width, rig["b"].height) == (64, 63, 47)
    with _raises(FileFormatError, f"{folder / 'intri.yml'}: no image size for camera a (W_a/H_a) and no frames to "
                                  "take it from; add them or import with --images/--videos"):
        imp.load_studio_cameras(folder / "intri.yml")


def test_easymocap_refusals_name_the_file_and_the_camera(tmp_path):
    a = _cam("a", (0.5, 1.2, 3.0), 50.0)
    missing = tmp_path / "none"
    missing.mkdir()
    with _raises(FileFormatError, f"{missing / 'intri.yml'}: not found; give cameras.json or a folder with EasyMocap "
                                  "intri.yml and extri.yml"):
        imp.load_studio_cameras(missing)
    (missing / "intri.yml").write_text("%YAML:1.0\n---\n")
    with _raises(FileFormatError, f"{missing / 'extri.yml'}: not found; give cameras.json or a folder with EasyMocap "
                                  "intri.yml and extri.yml"):
        imp.load_studio_cameras(missing / "intri.yml")
    folder = _easymocap(tmp_path / "c", [a], rodrigues=False)
    skew = np.round(a.R, 6)
    skew[0, 0] += 0.01
    _yml(folder / "extri.yml", ["a"], {"Rot_a": skew, "T_a": a.t[:, None]})
    with _raises(FileFormatError, f"{folder / 'extri.yml'}: Rot_a is not a rotation matrix; fix the calibration"):
        imp.load_studio_cameras(folder)
    _yml(folder / "extri.yml", ["a"], {"Rot_a": -np.round(a.R, 6), "T_a": a.t[:, None]})  # a reflection
    with pytest.raises(FileFormatError, match="Rot_a is not a rotation matrix"):
        imp.load_studio_cameras(folder)
    _yml(folder / "extri.yml", ["a"], {"R_a": cv2.Rodrigues(a.R)[0]})
    with _raises(FileFormatError, f"{folder / 'extri.yml'}: missing matrix 'T_a'; EasyMocap files need K_, dist_, "
                                  "Rot_/R_ and T_ per camera"):
        imp.load_studio_cameras(folder)
    _yml(folder / "extri.yml", ["a"], {"R_a": cv2.Rodrigues(a.R)[0], "T_a": a.t[:, None]})
    _yml(folder / "intri.yml", ["a"], {"K_a": a.K, "W_a": 64, "H_a": 0})
    with _raises(FileFormatError, f"{folder / 'intri.yml'}: camera a has image size W_a=64 H_a=0; use whole pixel "
                                  "counts 1-65536"):
        imp.load_studio_cameras(folder)
    for w, h, ok in ((1, 1, True), (65536, 2, True), (65537, 2, False), (2.5, 2, False), (64, 0.5, False)):
        if ok:
            assert imp._image_size(w, h, Path("i.yml"), "a") == (int(w), int(h))
        else:
            with pytest.raises(FileFormatError, match=r"^i\.yml: camera a has image size W_a="):
                imp._image_size(w, h, Path("i.yml"), "a")
    _yml(folder / "intri.yml", ["a"], {"W_a": 64, "H_a": 48})
    with _raises(FileFormatError, f"{folder / 'intri.yml'}: missing matrix 'K_a'; EasyMocap files need K_, dist_, "
                                  "Rot_/R_ and T_ per camera"):
        imp.load_studio_cameras(folder)
    K = a.K.copy()
    K[0, 0] = -5.0
    _yml(folder / "intri.yml", ["a"], {"K_a": K, "W_a": 64, "H_a": 48})
    with pytest.raises(FileFormatError, match=rf"^{re.escape(str(folder / 'intri.yml'))}: camera a: "):
        imp.load_studio_cameras(folder)
    _yml(folder / "intri.yml", [], {})
    _yml(folder / "extri.yml", [], {})
    with _raises(FileFormatError, f"{folder / 'intri.yml'}: the 'names' list is empty; list the cameras"):
        imp.load_studio_cameras(folder)
    fs = cv2.FileStorage(str(folder / "intri.yml"), cv2.FILE_STORAGE_WRITE)
    fs.write("K_a", a.K)
    fs.release()
    with _raises(FileFormatError, f"{folder / 'intri.yml'}: no 'names' list of cameras (EasyMocap layout)"):
        imp.load_studio_cameras(folder)


def test_camera_names_numbers_and_unsafe_characters(tmp_path):
    assert imp._safe_name("cam_01.a-b") == "cam_01.a-b"
    assert imp._safe_name("cam 01/x") == "cam_01_x" and imp._safe_name("_a") == "_a"
    assert imp._safe_name("é1") == "_1"
    a = _cam("x", (0.5, 1.2, 3.0), 50.0)
    folder = tmp_path / "c"
    folder.mkdir()
    _yml(folder / "intri.yml", ["cam 1"], {"K_cam 1": a.K, "W_cam 1": 64, "H_cam 1": 48})
    _yml(folder / "extri.yml", ["cam 1"], {"R_cam 1": cv2.Rodrigues(a.R)[0], "T_cam 1": a.t[:, None]})
    fs = cv2.FileStorage(str(folder / "intri.yml"), cv2.FILE_STORAGE_READ)
    assert imp._storage_names(fs, folder / "intri.yml") == ["cam 1"]
    fs.release()
    (folder / "names.yml").write_text("%YAML:1.0\n---\nnames:\n  - 3\n  - \"01\"\n")
    fs = cv2.FileStorage(str(folder / "names.yml"), cv2.FILE_STORAGE_READ)
    assert imp._storage_names(fs, folder / "names.yml") == ["3", "01"]
    assert imp._storage_mat(fs, "K_3", folder / "names.yml", required=False) is None
    fs.release()


# --- images and the whole import ---------------------------------------------------------------------------------

def _rgb(seed, size=(W, H)):
    return np.random.default_rng(seed).integers(0, 256, (size[1], size[0], 3), dtype=np.uint8)


def _png(path, rgb):
    from PIL import Image

    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(rgb).save(path)


def test_images_are_read_as_rgb_and_sizes_are_checked(tmp_path):
    _png(tmp_path / "a.png", _rgb(1))
    assert np.array_equal(imp.read_image_file(tmp_path / "a.png"), _rgb(1))
    grey = imp.read_image_file(tmp_path / "a.png", cv2.IMREAD_GRAYSCALE)
    assert grey.shape == (H, W)
    cam = _cam("c", (0, 1, 3), 10.0)
    imp._check_size(np.zeros((48, 64)), cam, "x.png")
    with _raises(FileFormatError, "x.png: image is 64x64 but the calibration of c says 64x48; use the matching "
                                  "calibration or frames"):
        imp._check_size(np.zeros((64, 64, 3)), cam, "x.png")
    # the transposed size is a rotation flag the reader applied (adv5)
    with _raises(FileFormatError, "x.png: image is 48x64, turned 90 degrees against the calibration of c (64x48; a "
                                  "phone video's rotation flag or a photo's EXIF orientation, which the reader "
                                  "applies); calibrate on frames read the same way, or drop the flag (ffmpeg "
                                  "-display_rotation 0 -i IN -c copy OUT)"):
        imp._check_size(np.zeros((64, 48, 3)), cam, "x.png")


def _recording(tmp_path, n=3):
    rig = CameraRig({c: Camera.look_at(c, (np.sin(i), 1.0, 3 * np.cos(i)), (0, 1, 0), fx=10.0, width=W, height=H)
                     for i, c in enumerate(("cam_00", "cam_01"))})
    (tmp_path / "cameras.json").write_text(json.dumps(rig.to_dict()))
    for c in rig.cameras:
        for k in range(n):
            _png(tmp_path / "images" / c / f"{k}.png", _rgb(10 * k + int(c[-1])))
    sensor = _sensor()
    from bodystudio.capture.session import kinect_calibration_to_dict

    (tmp_path / "kinect.json").write_text(json.dumps(kinect_calibration_to_dict(sensor)))
    tum = tmp_path / "tum"
    depth_lines, rgb_lines = [], []
    for k in range(n):
        t = 100.0 + k / 16
        raw = np.full((H, W), 10000 + 500 * k, np.uint16)
        raw[0, 0] = 0
        (tum / "depth").mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(tum / "depth" / f"{k}.png"), raw)
        _png(tum / "rgb" / f"{k}.png", _rgb(100 + k))
        depth_lines.append(f"{t} depth/{k}.png")
        rgb_lines.append(f"{t + 0.005} rgb/{k}.png")
    (tum / "depth.txt").write_text("\n".join(depth_lines) + "\n")
    (tum / "rgb.txt").write_text("\n".join(rgb_lines) + "\n")
    person = np.array([[0.0, 1.0, 0.0], [0.0, 1.4, 0.1]])
    frames = [person + [0.01 * k, 0, 0] for k in range(n)]
    (tmp_path / "joints.json").write_text(json.dumps({"names": ["a", "b"], "frames": [f.tolist() for f in frames]}))
    return rig, sensor, frames


def test_an_image_folder_recording_with_tum_depth_and_joints_is_imported_frame_for_frame(tmp_path):
    rig, sensor, frames = _recording(tmp_path)
    s = imp.import_recording(tmp_path / "out", cameras=tmp_path / "cameras.json", images=tmp_path / "images",
                             tum=tmp_path / "tum", kinect_calibration=tmp_path / "kinect.json",
                             joints=tmp_path / "joints.json")
    assert s.frame_ids == [0, 1, 2] and s.camera_names == ["cam_00", "cam_01"] and s.source == "import"
    assert s.metadata["generator"] == "bodystudio capture import" and "fps" not in s.metadata
    assert s.metadata["inputs"] == {"cameras": str(tmp_path / "cameras.json"), "images": str(tmp_path / "images"),
                                    "tum": str(tmp_path / "tum"), "kinect_calibration": str(tmp_path / "kinect.json"),
                                    "joints": str(tmp_path / "joints.json")}
    assert s.kinect.version == "v1" and np.allclose(s.kinect.depth.K, sensor.depth.K)
    for k, f in enumerate(s):
        assert np.array_equal(f.images["cam_00"], _rgb(10 * k)) and np.array_equal(f.images["cam_01"], _rgb(10 * k + 1))
        want = np.full((H, W), (10000 + 500 * k) / 5000)
        want[0, 0] = 0
        assert np.allclose(f.kinect_depth_m, want, atol=1e-12)
        assert np.array_equal(f.kinect_rgb, _rgb(100 + k))
        assert np.allclose(f.kinect_joints["positions"], frames[k]) and f.kinect_joints["joint_set"] == "v1"
    # the first two frames only; joints given in the Kinect SDK's axes are converted back
    sdk = [imp.studio_to_kinect_sdk(f, sensor) for f in frames]
    (tmp_path / "sdk.json").write_text(json.dumps({"names": ["a", "b"], "frames": [f.tolist() for f in sdk]}))
    s = imp.import_recording(tmp_path / "out2", cameras=tmp_path / "cameras.json", images=tmp_path / "images",
                             kinect_calibration=tmp_path / "kinect.json", joints=tmp_path / "sdk.json",
                             joints_frame="kinect-sdk", n_frames=2)
    assert s.frame_ids == [0, 1] and "fps" not in s.metadata
    assert all(np.allclose(f.kinect_joints["positions"], frames[k], atol=1e-12) for k, f in enumerate(s))
    # a Kinect-only recording: its colour camera is the one studio camera, the rate from TUM's depth times
    s = imp.import_recording(tmp_path / "out3", tum=tmp_path / "tum", kinect_calibration=tmp_path / "kinect.json",
                             depth_scale=1000.0)
    assert s.camera_names == ["kinect_color"] and s.metadata["fps"] == 16.0 and s.frame_ids == [0, 1, 2]
    assert np.array_equal(s.cameras["kinect_color"].K, sensor.color.K) and "rgb" not in s.streams
    assert np.allclose(s.frame(2).kinect_depth_m[1:, 1:], 11.0, atol=1e-12)


def test_the_imports_refusals_come_before_anything_is_written(tmp_path):
    _recording(tmp_path)
    cams, images, tum, kin = (tmp_path / n for n in ("cameras.json", "images", "tum", "kinect.json"))
    out = tmp_path / "out"
    for kwargs, exc, message in (
            (dict(images=images, videos=images, cameras=cams), InputError, "give --images or --videos, not both"),
            (dict(images=tmp_path / "nope", cameras=cams), FileFormatError, f"{tmp_path / 'nope'}: no such folder"),
            (dict(images=images), InputError, "give --cameras (cameras.json or EasyMocap intri.yml/extri.yml)"),
            (dict(tum=tum), InputError, f"{tum}: Kinect depth needs --kinect-calibration (JSON with 'depth' and "
                                        "'color' cameras, see docs/session-format.md)"),
            (dict(images=images, cameras=cams, n_frames=0), InputError, "--frames 0: import at least one frame"),
            (dict(tum=tum, kinect_calibration=kin, depth_scale=0.0), InputError,
             "--depth-scale 0.0: give the depth units per metre (> 0; TUM: 5000)"),
            (dict(tum=tum, kinect_calibration=kin, depth_scale=float("nan")), InputError,
             "--depth-scale nan: give the depth units per metre (> 0; TUM: 5000)"),
            (dict(images=images, cameras=cams, joints_frame="sdk"), InputError,
             "--joints-frame 'sdk' is not one of studio, kinect-sdk"),
            (dict(images=images, cameras=cams, joints_frame="kinect-sdk"), InputError,
             "--joints-frame kinect-sdk needs --kinect-calibration to place the Kinect in the studio"),
            (dict(cameras=cams), InputError, "nothing to import: give --images, --videos or --tum")):
        with _raises(exc, message):
            imp.import_recording(out, **kwargs)
        assert not out.exists()
    out.mkdir()
    (out / "x").write_text("x")
    with _raises(InputError, f"{out}: output folder exists and is not empty; choose a new folder"):
        imp.import_recording(out, cameras=cams, images=images)
    (tmp_path / "short.json").write_text(json.dumps({"names": ["a"], "frames": [[[0, 1, 0]], [[0, 1, 0]]]}))
    with _raises(FileFormatError, f"{tmp_path / 'short.json'}: 2 joint frames but the recording has 3 frames; pass "
                                  "--frames 2"):
        imp.import_recording(tmp_path / "o2", cameras=cams, images=images, joints=tmp_path / "short.json")
    (tum / "depth.txt").write_text("100.0 depth/0.png\n")
    with _raises(FileFormatError, f"{tum / 'depth.txt'}: 1 TUM depth/colour pairs but the recording has 3 frames; "
                                  "pass --frames 1"):
        imp.import_recording(tmp_path / "o3", cameras=cams, images=images, tum=tum, kinect_calibration=kin)
    (tum / "depth.txt").write_text("50.0 depth/0.png\n")
    with _raises(FileFormatError, f"{tum / 'depth.txt'}: no depth frame has a colour frame within 0.02 s in rgb.txt"):
        imp.import_recording(tmp_path / "o4", cameras=cams, images=images, tum=tum, kinect_calibration=kin)
    (images / "cam_01" / "2.png").unlink()
    with _raises(FileFormatError, f"{images / 'cam_01'}: 2 frames but {images / 'cam_00'} has 3; give a timestamps "
                                  "folder to synchronise, or --frames 2 to use the first frames"):
        imp.import_recording(tmp_path / "o5", cameras=cams, images=images)
    assert imp.import_recording(tmp_path / "o6", cameras=cams, images=images, n_frames=5).frame_ids == [0, 1]
    for o in ("o2", "o3", "o4", "o5"):
        assert not (tmp_path / o).exists()


# --- EasyMocap writer, frame sources, backgrounds ---------------------------------------------------------------

def test_easymocap_files_written_are_what_opencvs_filestorage_reads(tmp_path):
    a = _cam("a", (0.5, 1.2, 3.0), 50.0, dist=(0.1, -0.05, 0.001, 0.002, 0.01))
    b = _cam("b 2", (-1.0, 1.0, 2.0), 60.0)
    imp.save_easymocap_cameras(tmp_path / "out", CameraRig({"a": a, "b 2": b}))
    fi = cv2.FileStorage(str(tmp_path / "out" / "intri.yml"), cv2.FILE_STORAGE_READ)
    fe = cv2.FileStorage(str(tmp_path / "out" / "extri.yml"), cv2.FILE_STORAGE_READ)
    names = fi.getNode("names")
    assert [names.at(i).string() for i in range(names.size())] == ["a", "b 2"]
    for c in (a, b):
        assert np.array_equal(fi.getNode(f"K_{c.name}").mat(), c.K)
        assert np.array_equal(fi.getNode(f"dist_{c.name}").mat(), c.dist[None])
        assert (fi.getNode(f"W_{c.name}").real(), fi.getNode(f"H_{c.name}").real()) == (64, 48)
        assert np.allclose(cv2.Rodrigues(fe.getNode(f"R_{c.name}").mat())[0], c.R, atol=1e-12)
        assert np.array_equal(fe.getNode(f"Rot_{c.name}").mat(), c.R)
        assert np.array_equal(fe.getNode(f"T_{c.name}").mat(), c.t[:, None])
    fi.release()
    fe.release()
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["extri.yml", "intri.yml"]


def test_frame_sources_and_their_refusals(tmp_path):
    root = tmp_path / "images"
    for k in (10, 9, 2):
        _png(root / "a" / f"f{k}.png", _rgb(k))
    (root / "b").mkdir()
    (root / "c").mkdir()
    sources = imp.camera_sources(root, ["a"], videos=False)
    src = sources["a"]
    assert len(src) == 3 and src.where == root / "a"
    image, where = src.read(1)
    assert np.array_equal(image, _rgb(9)) and where == str(root / "a" / "f9.png")
    src.close()
    with _raises(FileFormatError, f"{root / 'b'}: no images (.png, .jpg, .jpeg, .bmp, .tif, .tiff) in this camera "
                                  "folder"):
        imp.camera_sources(root, ["a", "b"], videos=False)
    with _raises(FileFormatError, f"{root / 'd'}: missing image folder for camera d (the calibration lists it); found "
                                  "a, b, c"):
        imp.camera_sources(root, ["d"], videos=False)
    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / "x.avi").mkdir()
    with _raises(FileFormatError, f"{empty / 'd'}: missing image folder for camera d (the calibration lists it); "
                                  "found x.avi"):
        imp.camera_sources(empty, ["d"], videos=False)
    (empty / "x.avi").rmdir()
    with _raises(FileFormatError, f"{empty / 'd'}: missing image folder for camera d (the calibration lists it); "
                                  "found no folders"):
        imp.camera_sources(empty, ["d"], videos=False)
    with _raises(FileFormatError, f"{empty / 'd'}.*: no video for camera d (the calibration lists it); found no "
                                  "videos; name each video after its camera"):
        imp.camera_sources(empty, ["d"], videos=True)
    (empty / "e.MP4").write_bytes(b"")
    (empty / "f.txt").write_bytes(b"")
    with _raises(FileFormatError, f"{empty / 'd'}.*: no video for camera d (the calibration lists it); found e.MP4; "
                                  "name each video after its camera"):
        imp.camera_sources(empty, ["d"], videos=True)
    (empty / "d.avi").write_bytes(b"not a video")
    with _raises(FileFormatError, f"{empty / 'd.avi'}: cannot open the video (unsupported codec or not a video); "
                                  "convert it (e.g. ffmpeg -c:v mjpeg) or export an image folder"):
        imp.camera_sources(empty, ["d"], videos=True)


def _video(path, frames):
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 15.0, (W, H))
    assert writer.isOpened()
    for f in frames:
        writer.write(cv2.cvtColor(f, cv2.COLOR_RGB2BGR))
    writer.release()


def test_a_video_is_read_in_order_and_a_missing_frame_is_named(tmp_path):
    flat = [np.full((H, W, 3), v, np.uint8) for v in ((200, 30, 30), (30, 200, 30), (30, 30, 200))]
    _video(tmp_path / "a.avi", flat)
    src = imp.camera_sources(tmp_path, ["a"], videos=True)["a"]
    assert len(src) == 3 and src.where == tmp_path / "a.avi"
    image, where = src.read(1)  # frame 0 skipped
    assert where == f"{tmp_path / 'a.avi'} frame 1" and np.abs(image.astype(int) - flat[1]).max() < 12
    image, _ = src.read(2)
    assert np.abs(image.astype(int) - flat[2]).max() < 12
    with _raises(ValueError, "video frames must be read in increasing order"):
        src.read(2)
    src.close()
    src = imp.VideoSource(tmp_path / "a.avi")
    with _raises(FileFormatError, f"{tmp_path / 'a.avi'}: frame 5 cannot be decoded (the video had 3 frames when "
                                  "it was opened); the file changed or is damaged"):
        src.read(5)
    src.close()
    assert imp._frame_sizes(tmp_path, videos=True) == {"a": (W, H)}


def test_frame_sizes_from_the_first_image_and_backgrounds_of_each_kind(tmp_path):
    _png(tmp_path / "images" / "a" / "0.png", _rgb(0))
    _png(tmp_path / "images" / "b" / "0.png", _rgb(1, size=(4, 2)))
    (tmp_path / "images" / "c").mkdir()
    (tmp_path / "images" / "x.png").write_bytes(b"")
    assert imp._frame_sizes(tmp_path / "images", videos=False) == {"a": (W, H), "b": (4, 2)}
    rig = CameraRig({n: Camera.look_at(n, (0.0, 1.0, 3.0 + i), (0, 1, 0), fx=10.0, width=W, height=H)
                     for i, n in enumerate(("a", "b", "c"))})
    bg = tmp_path / "bg"
    _png(bg / "a" / "1.png", _rgb(5))
    _png(bg / "a" / "0.png", _rgb(4))
    _png(bg / "b.png", _rgb(6))
    _video(bg / "c.avi", [_rgb(7), _rgb(8)])
    from bodystudio.capture.session import SessionWriter

    with SessionWriter(tmp_path / "s", rig) as w:
        imp._import_backgrounds(w, bg, rig)
    from bodystudio.capture.session import open_session

    s = open_session(tmp_path / "s")
    a = s.background_frames("a")
    assert len(a) == 2 and np.array_equal(a[0], _rgb(4)) and np.array_equal(a[1], _rgb(5))
    assert len(s.background_frames("b")) == 1 and np.array_equal(s.background_frames("b")[0], _rgb(6))
    assert len(s.background_frames("c")) == 2
    (bg / "b.png").unlink()
    with SessionWriter(tmp_path / "t", rig) as w, \
            _raises(FileFormatError, f"{bg / 'b'}: no empty-studio frames for camera b (a folder, an image or a video "
                                     "named after the camera)"):
        imp._import_backgrounds(w, bg, rig)
    _png(bg / "b.png", _rgb(6, size=(4, 2)))
    with SessionWriter(tmp_path / "u", rig) as w, \
            _raises(FileFormatError, f"{bg / 'b.png'}: image is 4x2 but the calibration of b says 8x6; use the "
                                     "matching calibration or frames"):
        imp._import_backgrounds(w, bg, rig)
    with SessionWriter(tmp_path / "v", rig) as w, \
            _raises(FileFormatError, f"{tmp_path / 'none'}: no such backgrounds folder"):
        imp._import_backgrounds(w, tmp_path / "none", rig)


def test_integer_joints_read_as_float64_positions_and_bool_flags(tmp_path):
    d = tmp_path / "joints"
    d.mkdir()
    (d / "0.json").write_text(json.dumps({"names": ["a"], "positions": [[1, 2, 3]], "tracked": [0]}))
    (d / "1.json").write_text(json.dumps({"joints": {"a": [4, 5, 6]}}))
    track = imp.load_joints(d)
    assert track.positions.dtype == np.float64 and track.tracked.dtype == bool
    assert track.tracked.tolist() == [[False], [True]]
    for data in ({"names": ["a"], "positions": [[1, 2, 3]], "tracked": [1]}, {"joints": {"a": [1, 2, 3]}}):
        names, pos, tracked = imp._joint_frame(data, Path("f.json"))
        assert pos.dtype == np.float64 and tracked.dtype == bool
    p = tmp_path / "j.csv"
    p.write_text("frame,joint,x,y,z,tracked\n0,a,1,2,3,0\n")
    assert imp.load_joints(p).tracked.dtype == bool
    p.write_text("frame,joint,x,y,z\n0,a,1,nan,3\n")
    with _raises(FileFormatError, f"{p}: joint positions contain NaN or infinity"):
        imp.load_joints(p)


def test_two_reference_frames_already_set_the_tolerance_and_the_writer_makes_or_reuses_its_folder(tmp_path):
    got = imp.synchronise_by_timestamps({"a": np.array([0.0, 1.0]), "b": np.array([0.0, 1.75])})
    assert got == [{"a": 0, "b": 0}]  # half of the 1 s period: 1.75 is too far from 1.0
    rig = CameraRig({"a": _cam("a", (0.5, 1.2, 3.0), 50.0)})
    nested = tmp_path / "x" / "y"
    imp.save_easymocap_cameras(nested, rig)
    imp.save_easymocap_cameras(nested, rig)  # again, into the existing folder
    assert np.allclose(imp.load_studio_cameras(nested)["a"].K, rig["a"].K)


def _timed_recording(tmp_path):
    """cam_00 records 4 frames 1/16 s apart, cam_01 misses the third; masks per source frame; TUM depth for the
    first, second and fourth time only (the third's pair is 0.05 s late); joints per cam_00 frame."""
    rig, sensor, _ = _recording(tmp_path, n=1)
    import shutil

    shutil.rmtree(tmp_path / "images")
    shutil.rmtree(tmp_path / "tum")
    times = {"cam_00": [0.0, 0.0625, 0.125, 0.1875], "cam_01": [0.002, 0.0645, 0.1895]}
    (tmp_path / "ts").mkdir()
    for c, ts in times.items():
        (tmp_path / "ts" / f"{c}.txt").write_text("\n".join(str(t) for t in ts) + "\n")
        for k in range(len(ts)):
            _png(tmp_path / "images" / c / f"{k}.png", _rgb(20 * k + int(c[-1])))
            m = np.zeros((H, W), np.uint8)
            m[k % H, :] = 255 if k % 2 else 1  # any non-zero value is the subject
            _png(tmp_path / "masks" / c / f"{k}.png", m)
    tum = tmp_path / "tum"
    lines = []
    for k, t in enumerate([0.0, 0.0625, 0.175, 0.1875]):
        (tum / "depth").mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(tum / "depth" / f"{k}.png"), np.full((H, W), 10000 + 1000 * k, np.uint16))
        _png(tum / "rgb" / f"{k}.png", _rgb(200 + k))
        lines.append((t, f"depth/{k}.png", f"rgb/{k}.png"))
    (tum / "depth.txt").write_text("".join(f"{t} {d}\n" for t, d, _ in lines))
    (tum / "rgb.txt").write_text("".join(f"{t + 0.001} {r}\n" for t, _, r in lines))
    person = np.array([[0.0, 1.0, 0.0], [0.0, 1.4, 0.1]])
    frames = [person + [0.01 * k, 0, 0] for k in range(4)]
    (tmp_path / "joints.json").write_text(json.dumps({"names": ["a", "b"], "frames": [f.tolist() for f in frames],
                                                      "tracked": [[True, k != 3] for k in range(4)]}))
    _png(tmp_path / "bg" / "cam_00.png", _rgb(300))
    _png(tmp_path / "bg" / "cam_01.png", _rgb(301))
    return rig, sensor, frames


def test_a_timestamped_recording_with_masks_backgrounds_and_a_late_depth_frame(tmp_path, caplog):
    import logging

    _, _, frames = _timed_recording(tmp_path)
    args = dict(cameras=tmp_path / "cameras.json", images=tmp_path / "images", timestamps=tmp_path / "ts",
                backgrounds=tmp_path / "bg", tum=tmp_path / "tum", kinect_calibration=tmp_path / "kinect.json",
                joints=tmp_path / "joints.json", masks=tmp_path / "masks")
    with caplog.at_level(logging.INFO, logger="bodystudio.capture.importer"):
        s = imp.import_recording(tmp_path / "out", **args)
    assert [r.getMessage() for r in caplog.records if r.name == "bodystudio.capture.importer"] == [
        f"imported 3 frames of 2 cameras into {tmp_path / 'out'}"]
    assert s.frame_ids == [0, 1, 2] and s.metadata["fps"] == round(1 / 0.09375, 3)  # median of 1/16 s and 1/8 s
    assert s.metadata["inputs"] == {k: str(v) for k, v in args.items() if k != "masks"}
    assert _json_lock_free(tmp_path / "out")
    source = {"cam_00": [0, 1, 3], "cam_01": [0, 1, 2]}  # cam_00's third frame has no cam_01 frame near it
    for i, f in enumerate(s):
        for c, ks in source.items():
            assert np.array_equal(f.images[c], _rgb(20 * ks[i] + int(c[-1])))
            want = np.zeros((H, W), bool)
            want[ks[i] % H, :] = True
            assert np.array_equal(f.masks[c], want)
        assert np.allclose(f.kinect_joints["positions"], frames[source["cam_00"][i]])
        assert f.kinect_joints["tracked"].tolist() == [True, source["cam_00"][i] != 3]
    depth = [s.frame(i).kinect_depth_m for i in range(3)]
    assert np.allclose(depth[0], 2.0) and np.allclose(depth[1], 2.2) and depth[2] is not None
    assert np.allclose(depth[2], 2.6)  # the fourth pair (t = 0.1875), not the late third
    assert np.array_equal(s.background_frames("cam_01")[0], _rgb(301))
    (tmp_path / "tum" / "depth.txt").write_text("0.0 depth/0.png\n0.0625 depth/1.png\n0.2875 depth/3.png\n")
    (tmp_path / "tum" / "rgb.txt").write_text("0.001 rgb/0.png\n0.0635 rgb/1.png\n0.2885 rgb/3.png\n")
    s = imp.import_recording(tmp_path / "out2", **{**args, "n_frames": 3})
    assert s.frame(2).kinect_depth_m is None and s.frame(2).kinect_rgb is None  # no pair within 0.02 s
    assert s.frame(1).kinect_rgb is not None


def _json_lock_free(out):
    return not (out / ".lock").exists() and not (out / ".staging").exists()


def test_more_import_refusals_and_bounds(tmp_path):
    _timed_recording(tmp_path)
    base = dict(cameras=tmp_path / "cameras.json", images=tmp_path / "images", timestamps=tmp_path / "ts")
    (tmp_path / "ts" / "cam_01.txt").write_text("0.0\n0.1\n")
    with _raises(FileFormatError, f"{tmp_path / 'ts' / 'cam_01.txt'}: 2 timestamps but {tmp_path / 'images' / 'cam_01'}"
                                  " has 3 frames"):
        imp.import_recording(tmp_path / "o1", **base)
    (tmp_path / "ts" / "cam_01.txt").write_text("0.002\n0.0645\n0.1895\n")
    (tmp_path / "masks" / "cam_01" / "2.png").unlink()
    with _raises(FileFormatError, f"{tmp_path / 'masks' / 'cam_01'}: 2 masks but frame 2 is needed; give one mask per "
                                  "frame"):
        imp.import_recording(tmp_path / "o2", masks=tmp_path / "masks", **base)
    _png(tmp_path / "masks" / "cam_01" / "2.png", np.zeros((2, 4), np.uint8))
    with _raises(FileFormatError, f"{tmp_path / 'masks' / 'cam_01' / '2.png'}: image is 4x2 but the calibration of "
                                  "cam_01 says 8x6; use the matching calibration or frames"):
        imp.import_recording(tmp_path / "o3", masks=tmp_path / "masks", **base)
    (tmp_path / "none.json").write_text(json.dumps({"names": ["a"], "frames": []}))
    with _raises(FileFormatError, f"{tmp_path / 'none.json'}: 0 joint frames but the recording has 3 frames; give one "
                                  "per recorded frame"):
        imp.import_recording(tmp_path / "o4", cameras=tmp_path / "cameras.json", images=tmp_path / "images",
                             joints=tmp_path / "none.json", n_frames=4)
    assert imp.import_recording(tmp_path / "o5", cameras=tmp_path / "cameras.json", images=tmp_path / "masks",
                                n_frames=1).frame_ids == [0]
    tum, kin = tmp_path / "tum", tmp_path / "kinect.json"
    one = tmp_path / "tum1"
    (one / "depth").mkdir(parents=True)
    cv2.imwrite(str(one / "depth" / "0.png"), np.full((H, W), 3, np.uint16))
    _png(one / "rgb" / "0.png", _rgb(0))
    (one / "depth.txt").write_text("1.0 depth/0.png\n")
    (one / "rgb.txt").write_text("1.0 rgb/0.png\n")
    for scale, metres in ((1.0, 3.0), (0.5, 6.0)):  # any positive number of units per metre
        s = imp.import_recording(tmp_path / f"o6_{scale}", tum=one, kinect_calibration=kin, depth_scale=scale)
        assert np.allclose(s.frame(0).kinect_depth_m, metres)
    cv2.imwrite(str(tum / "depth" / "1.png"), np.full((H, W), 200, np.uint8))
    with _raises(FileFormatError, f"{tum / 'depth/1.png'}: depth must be a 16-bit PNG, got uint8 (8-bit images lose "
                                  "the depth); export 16-bit depth"):
        imp.import_recording(tmp_path / "o7", tum=tum, kinect_calibration=kin)
    cv2.imwrite(str(tum / "depth" / "1.png"), np.full((2, 4), 10000, np.uint16))
    with _raises(FileFormatError, f"{tum / 'depth/1.png'}: image is 4x2 but the calibration of k_depth says 8x6; use "
                                  "the matching calibration or frames"):
        imp.import_recording(tmp_path / "o8", tum=tum, kinect_calibration=kin)
    _png(tum / "rgb" / "0.png", _rgb(0, size=(4, 2)))
    with _raises(FileFormatError, f"{tum / 'rgb/0.png'}: image is 4x2 but the calibration of k_color says 8x6; use "
                                  "the matching calibration or frames"):
        imp.import_recording(tmp_path / "o9", tum=tum, kinect_calibration=kin)
    _png(tmp_path / "images" / "cam_01" / "1.png", _rgb(0, size=(4, 2)))
    with _raises(FileFormatError, f"{tmp_path / 'images' / 'cam_01' / '1.png'}: image is 4x2 but the calibration of "
                                  "cam_01 says 8x6; use the matching calibration or frames"):
        imp.import_recording(tmp_path / "o10", **base)


def test_easymocap_cameras_without_sizes_take_them_from_the_first_frames(tmp_path):
    a, b = _cam("cam_00", (0.5, 1.2, 3.0), 3.0), _cam("cam_01", (-1.0, 1.0, 2.0), 3.0)
    a = Camera(a.name, np.array([[3.0, 0, 3.5], [0, 3.0, 2.5], [0, 0, 1]]), a.dist, a.R, a.t, W, H)
    b = Camera(b.name, a.K, b.dist, b.R, b.t, W, H)
    _easymocap(tmp_path / "calib", [a, b], sizes=False)
    for c in ("cam_00", "cam_01"):
        _png(tmp_path / "images" / c / "0.png", _rgb(int(c[-1])))
    s = imp.import_recording(tmp_path / "out", cameras=tmp_path / "calib", images=tmp_path / "images")
    assert [(s.cameras[c].width, s.cameras[c].height) for c in ("cam_00", "cam_01")] == [(W, H), (W, H)]


def test_a_depth_frame_pairs_once_bounds_of_the_units_and_names_listed(tmp_path):
    assert imp.associate_tum([(1.0, "a")], [(1.0, "x"), (1.005, "y")]) == [(1.0, "a", "x")]
    with _raises(FileFormatError, "d.png: depth units are ambiguous (median 0.50 m as TUM units or 2.50 m as "
                                  "millimetres); pass --depth-scale 5000 or --depth-scale 1000"):
        imp.depth_scale_of(np.array([[2500]], np.uint16), "d.png", None)  # 0.5 m is inside the range
    with _raises(FileFormatError, "d.png: depth looks like metres (median 1.00 m at 1 per metre, 0.00 m at TUM's "
                                  "5000); pass --depth-scale 1"):
        imp.depth_scale_of(np.array([[1, 1, 1, 10000]], np.uint16), "d.png", None)  # 1 is a measurement
    assert imp._safe_name("CAM 01") == "CAM_01" and imp._safe_name("Cam.A-1") == "Cam.A-1"
    (tmp_path / "e.MP4").write_bytes(b"")
    (tmp_path / "g.avi").write_bytes(b"")
    with _raises(FileFormatError, f"{tmp_path / 'd'}.*: no video for camera d (the calibration lists it); found e.MP4, "
                                  "g.avi; name each video after its camera"):
        imp.camera_sources(tmp_path, ["d"], videos=True)


def test_easymocap_details_and_imports_without_a_kinect_or_without_frames(tmp_path):
    a = _cam("a", (0.5, 1.2, 3.0), 50.0)
    folder = tmp_path / "c"
    folder.mkdir()
    _yml(folder / "intri.yml", ["a"], {"K_a": a.K, "W_a": 64})  # no dist_; W_ without H_
    _yml(folder / "extri.yml", ["a"], {"R_a": cv2.Rodrigues(a.R)[0], "T_a": a.t[:, None]})
    rig = imp.load_studio_cameras(folder, {"a": (64, 48)})
    assert rig["a"].dist.shape == (5,) and not rig["a"].dist.any() and rig["a"].height == 48
    (folder / "names.yml").write_text("%YAML:1.0\n---\nnames:\n  - 3\n  - 4\n")
    fs = cv2.FileStorage(str(folder / "names.yml"), cv2.FILE_STORAGE_READ)
    assert imp._storage_names(fs, folder / "names.yml") == ["3", "4"]
    fs.release()
    # joints without a Kinect calibration; a mask file in colour (red only) is the subject where its grey is not 0
    (tmp_path / "r").mkdir()
    _, _, frames = _recording(tmp_path / "r", n=2)
    r = tmp_path / "r"
    for c in ("cam_00", "cam_01"):
        for k in range(2):
            m = np.zeros((H, W, 3), np.uint8)
            m[k, :, 0] = 200
            _png(r / "masks" / c / f"{k}.png", m)
    s = imp.import_recording(tmp_path / "o1", cameras=r / "cameras.json", images=r / "images", joints=r / "joints.json",
                             masks=r / "masks")
    assert s.frame(1).kinect_joints["joint_set"] is None and np.allclose(s.frame(1).kinect_joints["positions"],
                                                                         frames[1])
    assert s.frame(1).masks["cam_01"][1].all() and s.frame(1).masks["cam_01"].sum() == W
    # EasyMocap cameras and TUM depth only: no frames to take sizes from, none needed
    _easymocap(tmp_path / "em", [_cam("cam_00", (0.5, 1.2, 3.0), 50.0)])
    s = imp.import_recording(tmp_path / "o2", cameras=tmp_path / "em", tum=r / "tum",
                             kinect_calibration=r / "kinect.json")
    assert s.camera_names == ["cam_00"] and s.frame_ids == [0, 1] and s.frame(0).kinect_depth_m is not None
