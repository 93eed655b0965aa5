"""Session format: write/read round trip with checksums, lazy frames, corruption and interrupted writes."""

import json
import os
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bodystudio.capture import session as sess
from bodystudio.capture.session import SessionWriter, open_session, recover_session
from bodystudio.errors import SessionError
from bodystudio.geometry.camera import Camera, CameraRig, kinect_v1

W, H = 40, 30


def small_rig(n=2):
    return CameraRig({f"cam_{i:02d}": Camera.look_at(f"cam_{i:02d}", (np.sin(i), 1.0, 3 * np.cos(i)), (0, 1, 0),
                                                     fx=50.0, width=W, height=H) for i in range(n)})


def frame_data(rng, i):
    rgb = {c: rng.integers(0, 256, (H, W, 3), dtype=np.uint8) for c in ("cam_00", "cam_01")}
    mask = {c: rng.random((H, W)) > 0.5 for c in rgb}
    depth = np.round(rng.uniform(0.5, 4.5, (24, 32)), 3)
    depth[0, :5] = 0.0
    return rgb, mask, depth


def write_small(path, n_frames=2, seed=0):
    rng = np.random.default_rng(seed)
    data = []
    V = rng.normal(size=(10, 3))
    F = rng.integers(0, 10, (8, 3))
    from bodystudio.body import Pose

    with SessionWriter(path, small_rig(), source="synthetic", metadata={"test": True}) as w:
        w.write_kinect_calibration(kinect_v1("320x240"))
        w.write_gt_subject({"gender": 0.5}, {"upperarm-fat-decr-incr": 0.1})
        for c in w.camera_names:
            w.write_background(c, 0, rng.integers(0, 256, (H, W, 3), dtype=np.uint8))
        for i in range(n_frames):
            rgb, mask, depth = frame_data(rng, i)
            for c in rgb:
                w.write_image(c, i, rgb[c])
                w.write_mask(c, i, mask[c])
                w.write_mask(c, i, ~mask[c], ground_truth=True)
            w.write_kinect_depth(i, depth)
            w.write_kinect_rgb(i, rgb["cam_00"])
            w.write_kinect_joints(i, ["Head", "Neck"], [[0, 1.7, 0], [0, 1.5, 0.01]], [True, False], joint_set="v2")
            w.write_gt_mesh(i, V + i, F)
            w.write_gt_joints(i, ["root", "spine"], V[:2], V[2:4])
            rot = np.zeros((2, 3))
            rot[1] = [0.1 * i, 0.2, 0.0]
            w.write_gt_pose(i, Pose(rot, np.array([0.0, 0.0, 0.1 * i])), ["root", "spine"])
            data.append((rgb, mask, depth, V + i, F, rot))
    return data


def test_round_trip_with_checksums(tmp_path):
    data = write_small(tmp_path / "s")
    s = open_session(tmp_path / "s")
    assert s.frame_ids == [0, 1] and s.camera_names == ["cam_00", "cam_01"] and s.source == "synthetic"
    assert set(s.streams) >= {"rgb", "mask", "gt_mask", "kinect_depth", "kinect_rgb", "kinect_joints",
                              "gt_mesh", "gt_joints", "gt_pose", "background"}
    assert s.verify() == len(s.files) and all(len(h) == 64 for h in s.files.values())
    assert np.allclose(s.cameras["cam_01"].K, small_rig()["cam_01"].K)
    assert s.kinect.depth.width == 320 and s.kinect.version == "v1"
    assert np.allclose(s.kinect.depth_to_color, kinect_v1("320x240").depth_to_color)
    for i, (rgb, mask, depth, V, F, rot) in enumerate(data):
        f = s.frame(i)
        assert list(f.images) == ["cam_00", "cam_01"]
        for c in rgb:
            assert np.array_equal(f.images[c], rgb[c])
            assert np.array_equal(f.masks[c], mask[c]) and np.array_equal(f.gt_masks[c], ~mask[c])
        assert np.abs(f.kinect_depth_m - depth).max() < 5e-4 and f.kinect_depth_m[0, 0] == 0.0
        assert np.array_equal(f.kinect_rgb, rgb["cam_00"])
        assert f.kinect_joints["names"] == ["Head", "Neck"] and f.kinect_joints["tracked"].tolist() == [True, False]
        assert np.array_equal(f.gt_mesh.vertices, V) and np.array_equal(f.gt_mesh.faces, F)
        assert np.allclose(f.gt_pose.rotations, rot) and np.isclose(f.gt_pose.translation[2], 0.1 * i)
        assert f.gt_joints["bone_names"] == ["root", "spine"]
    assert s.gt_subject["local"] == {"upperarm-fat-decr-incr": 0.1}
    assert len(s.background_frames("cam_01")) == 1
    with pytest.raises(SessionError, match="no frame 7"):
        s.frame(7)


def test_corrupted_file_is_named(tmp_path):
    write_small(tmp_path / "s")
    target = tmp_path / "s" / "cam_01" / "rgb" / "00001.png"
    raw = bytearray(target.read_bytes())
    raw[100] ^= 0xFF
    target.write_bytes(bytes(raw))
    s = open_session(tmp_path / "s")  # existence checks pass; checksums are checked on read
    with pytest.raises(SessionError, match=r"cam_01/rgb/00001\.png: corrupted"):
        s.verify()
    with pytest.raises(SessionError, match=r"cam_01/rgb/00001\.png: corrupted"):
        s.frame(1).images["cam_01"]
    assert s.frame(1).images["cam_00"].shape == (H, W, 3)  # the rest stays readable


@pytest.mark.parametrize("damage, message", [
    ("delete_image", r"kinect/depth/00000\.png: missing"),
    ("delete_manifest", r"session\.json: missing, the session was never completed"),
    ("garble_manifest", r"session\.json: corrupted manifest"),
    ("future_version", r"session\.json: session format version 99 is not supported"),
])
def test_incomplete_session_says_what_is_missing(tmp_path, damage, message):
    write_small(tmp_path / "s", n_frames=1)
    root = tmp_path / "s"
    if damage == "delete_image":
        (root / "kinect" / "depth" / "00000.png").unlink()
    elif damage == "delete_manifest":
        (root / "session.json").unlink()
    elif damage == "garble_manifest":
        (root / "session.json").write_text("{ not json")
    else:
        m = json.loads((root / "session.json").read_text())
        m["version"] = 99
        (root / "session.json").write_text(json.dumps(m))
    with pytest.raises(SessionError, match=message) as err:
        open_session(root)
    assert "\n" not in str(err.value)


def test_update_interrupted_before_commit_keeps_previous_state(tmp_path):
    data = write_small(tmp_path / "s")
    root = tmp_path / "s"
    w = SessionWriter(root, update=True)
    w.write_mask("cam_00", 0, np.ones((H, W), bool))
    del w  # the process dies here: no commit, no abort
    s = open_session(root)
    assert s.interrupted_write is not None and "1 uncommitted files" in s.interrupted_write
    assert np.array_equal(s.frame(0).masks["cam_00"], data[0][1]["cam_00"])
    s.verify()
    with pytest.raises(SessionError, match="interrupted"):
        SessionWriter(root, update=True)
    assert "discarded" in recover_session(root)
    assert open_session(root).interrupted_write is None


def test_update_interrupted_after_commit_point_is_recovered(tmp_path, monkeypatch):
    write_small(tmp_path / "s")
    root = tmp_path / "s"
    calls = {"n": 0}
    real_replace = os.replace

    def dying_replace(src, dst):
        if ".staging" in str(src) and "commit.json" not in str(dst) and not str(src).endswith(".tmp"):
            calls["n"] += 1
            if calls["n"] == 2:
                raise KeyboardInterrupt("killed while moving files")
        return real_replace(src, dst)

    monkeypatch.setattr(sess.os, "replace", dying_replace)
    with pytest.raises(KeyboardInterrupt):
        with SessionWriter(root, update=True) as w:
            w.write_mask("cam_00", 0, np.ones((H, W), bool))
            w.write_mask("cam_01", 0, np.ones((H, W), bool))
    monkeypatch.setattr(sess.os, "replace", real_replace)
    with pytest.raises(SessionError, match=r"commit\.json: a write was interrupted while committing"):
        open_session(root)
    assert "completed" in recover_session(root)
    s = open_session(root)
    assert s.verify() and s.frame(0).masks["cam_01"].all() and s.frame(0).masks["cam_00"].all()


def test_killed_process_leaves_a_reported_incomplete_session(tmp_path):
    """A real SIGKILL in the middle of writing a new session: no manifest, and open says so."""
    root = tmp_path / "killed"
    script = textwrap.dedent(f"""
        import time, numpy as np, sys
        sys.path.insert(0, {str(os.getcwd())!r})
        from tests.capture.test_session import small_rig
        from bodystudio.capture.session import SessionWriter
        with SessionWriter({str(root)!r}, small_rig()) as w:
            for i in range(10000):
                w.write_image("cam_00", i, np.zeros((30, 40, 3), np.uint8))
                time.sleep(0.01)
    """)
    proc = subprocess.Popen([sys.executable, "-c", script])
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and not (root / ".staging" / "cam_00" / "rgb" / "00003.png").exists():
            time.sleep(0.05)
        assert proc.poll() is None, "writer exited before it could be killed"
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    with pytest.raises(SessionError, match=r"session\.json: missing, the session was never completed .*uncommitted"):
        open_session(root)


def test_exception_inside_writer_discards_the_new_session(tmp_path):
    with pytest.raises(RuntimeError):
        with SessionWriter(tmp_path / "new", small_rig()) as w:
            w.write_image("cam_00", 0, np.zeros((H, W, 3), np.uint8))
            raise RuntimeError("bad input found halfway")
    assert not (tmp_path / "new").exists()


def test_writer_refuses_existing_session_and_unknown_camera(tmp_path):
    write_small(tmp_path / "s", n_frames=1)
    with pytest.raises(SessionError, match="already holds a session"):
        SessionWriter(tmp_path / "s", small_rig())
    w = SessionWriter(tmp_path / "t", small_rig())
    with pytest.raises(SessionError, match="'cam_09' is not in this session's calibration"):
        w.write_image("cam_09", 0, np.zeros((H, W, 3), np.uint8))


@settings(max_examples=40, deadline=None)
@given(st.lists(st.floats(0.0, 60.0, allow_nan=False), min_size=1, max_size=50))
def test_depth_millimetre_encoding_round_trip(values):
    depth = np.asarray(values)
    png = sess.decode_png(sess.encode_png(sess.depth_to_png_mm(depth[None, :])), "t", color=False)
    assert png.dtype == np.uint16
    assert np.abs(png[0] / 1000.0 - depth).max() <= 0.0005 + 1e-12


def test_stream_fingerprint_names_the_recording_not_the_folder(tmp_path):
    """Same frames (a moved copy, a file added later) -> same fingerprint; other frames, another order, another
    camera or a missing frame -> different or None."""
    import shutil

    write_small(tmp_path / "a", n_frames=3, seed=0)
    write_small(tmp_path / "b", n_frames=3, seed=1)
    shutil.copytree(tmp_path / "a", tmp_path / "moved")
    a, b, moved = (open_session(tmp_path / n) for n in ("a", "b", "moved"))
    fp = sess.stream_fingerprint(a, "kinect_depth", [0, 1, 2])
    assert len(fp) == 64 and fp == sess.stream_fingerprint(moved, "kinect_depth", [0, 1, 2])
    assert fp != sess.stream_fingerprint(b, "kinect_depth", [0, 1, 2])
    assert fp != sess.stream_fingerprint(a, "kinect_depth", [0, 2, 1])
    assert fp != sess.stream_fingerprint(a, "kinect_depth", [0, 1])
    assert sess.stream_fingerprint(a, "kinect_depth", [0, 1, 7]) is None
    rgb = sess.stream_fingerprint(a, "rgb", [0, 1], "cam_00")
    assert rgb is not None and rgb != sess.stream_fingerprint(a, "rgb", [0, 1], "cam_01")
    with SessionWriter(tmp_path / "moved", update=True) as w:
        w.write_gt_subject({"gender": 0.2}, {})
    assert sess.stream_fingerprint(open_session(tmp_path / "moved"), "kinect_depth", [0, 1, 2]) == fp
