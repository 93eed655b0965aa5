"""The session format's readers and validators called directly (issue 17, mutation testing of
``capture/session.py``): the manifest check, the folder's opening and its read lock, checksummed reads and who
rewrote a file, ``verify`` and the manifest's unbacked entries, the frame list, the joints file's bodies, the
ground-truth PLY / npz / PNG / albedo readers and the Kinect calibration. Every refusal's whole line, every
boundary; the references are independent of the module: hashlib over the manifest's lines, trimesh's PLY reader,
numpy's npz reader, Pillow's PNG decoder, the depth->colour transform applied to a world point. Each test writes
what it reads (mutmut's forked mutants inherit anything cached); < 2 s."""

from __future__ import annotations

import gc
import hashlib
import io
import json
import logging
import re
import socket
from pathlib import Path

import numpy as np
import pytest

from bodystudio.capture import session as sess
from bodystudio.capture.session import (
    CAMERAS_JSON,
    SESSION_FORMAT,
    SESSION_VERSION,
    Session,
    SessionWriter,
    open_session,
)
from bodystudio.errors import FileFormatError, SessionError
from bodystudio.geometry.camera import Camera, CameraRig, kinect_v1
from bodystudio.runfolder import command_read_locks

W, H = 8, 6
SRC = Path("S/session.json")


def _raises(exc, message):
    return pytest.raises(exc, match="^" + re.escape(message) + "$")


def _rig(names=("cam_00", "cam_01")):
    return CameraRig({n: Camera.look_at(n, (np.sin(i), 1.0, 3 * np.cos(i)), (0, 1, 0), fx=10.0, width=W, height=H)
                      for i, n in enumerate(names)})


def _rgb(seed):
    return np.random.default_rng(seed).integers(0, 256, (H, W, 3), dtype=np.uint8)


def _write(path, frames=(0, 1), cameras=("cam_00", "cam_01")):
    with SessionWriter(path, _rig(cameras), source="synthetic") as w:
        for f in frames:
            for i, c in enumerate(cameras):
                w.write_image(c, f, _rgb(10 * f + i))
    return path


def _rewrite(path, rel, data: bytes):
    """Replace one file of a session and its manifest checksum (a consistent hand edit)."""
    (path / rel).parent.mkdir(parents=True, exist_ok=True)
    (path / rel).write_bytes(data)
    manifest = json.loads((path / "session.json").read_text())
    manifest["files"][rel] = hashlib.sha256(data).hexdigest()
    (path / "session.json").write_text(json.dumps(manifest))


def _other_host_lock(path):
    """A writer's lock of another machine: never stale (this one cannot see that machine's processes)."""
    (path / ".lock").write_text(json.dumps({"pid": 4242, "host": "elsewhere-" + socket.gethostname(),
                                            "command": "bodystudio synth", "since": "2026-01-02T03:04:05Z"}))


# --- the manifest check ---------------------------------------------------------------------------------------

def _manifest(**over):
    m = {"format": SESSION_FORMAT, "version": SESSION_VERSION, "cameras": ["cam_00"], "frames": [0, 1],
         "streams": ["rgb"], "files": {CAMERAS_JSON: "ab"}}
    m.update(over)
    return m


def test_manifest_check_accepts_a_valid_manifest_and_every_name_the_rule_allows():
    assert sess._check_manifest(_manifest(), SRC) is None
    sess._check_manifest(_manifest(cameras=["a", "0", "A.b-c_9", "cam..1"], frames=[], streams=[],
                                   files={CAMERAS_JSON: "x", "..a/b..": "y", "a/./b": "z"}), SRC)
    sess._check_manifest(_manifest(frames=[0]), SRC)


def test_manifest_check_refuses_other_formats_and_versions():
    not_ours = f"{SRC}: not a bodystudio session manifest (format != 'bodystudio-session')"
    for m in ([], None, {"format": "bodystudio-sessions", "version": 1}, {k: v for k, v in _manifest().items()
                                                                          if k != "format"}):
        with _raises(SessionError, not_ours):
            sess._check_manifest(m, SRC)
    for version, shown in ((2, "2"), (None, "None"), ("1", "'1'")):
        with _raises(SessionError, f"{SRC}: session format version {shown} is not supported (this bodystudio reads "
                                   "version 1); upgrade bodystudio or re-import"):
            sess._check_manifest(_manifest(version=version), SRC)
    with _raises(SessionError, f"{SRC}: session format version None is not supported (this bodystudio reads "
                               "version 1); upgrade bodystudio or re-import"):
        sess._check_manifest({k: v for k, v in _manifest().items() if k != "version"}, SRC)


@pytest.mark.parametrize("key, kind, wrong", [("cameras", "list", {"cam_00": 1}), ("frames", "list", "0"),
                                              ("streams", "list", None), ("files", "dict", [CAMERAS_JSON])])
def test_manifest_check_names_each_missing_or_mistyped_field(key, kind, wrong):
    message = f"{SRC}: manifest field {key!r} is missing or not a {kind}"
    with _raises(SessionError, message):
        sess._check_manifest(_manifest(**{key: wrong}), SRC)
    with _raises(SessionError, message):
        sess._check_manifest({k: v for k, v in _manifest().items() if k != key}, SRC)


def test_manifest_check_refuses_camera_names_frames_streams_and_entries():
    cams = f"{SRC}: manifest field 'cameras' must list camera names (letters, digits, _ . -)"
    for name in ("", "_a", "-a", ".a", "a b", "a/b", "a\n", 3, None):
        with _raises(SessionError, cams):
            sess._check_manifest(_manifest(cameras=["cam_00", name]), SRC)
    frames = f"{SRC}: manifest field 'frames' must list non-negative integer frame ids"
    for bad in (-1, 1.0, "1", True, None):
        with _raises(SessionError, frames):
            sess._check_manifest(_manifest(frames=[0, bad]), SRC)
    with _raises(SessionError, f"{SRC}: manifest field 'streams' must list stream names"):
        sess._check_manifest(_manifest(streams=["rgb", 1]), SRC)
    for rel, digest in (("", "ab"), ("/abs/x.png", "ab"), ("a/../b", "ab"), ("..", "ab"), ("a/b", None),
                        ("a/b", 1)):
        with _raises(SessionError, f"{SRC}: manifest entry {rel!r} is not a relative path inside the session with a "
                                   "sha256; the manifest is corrupt, regenerate or re-import the session"):
            sess._check_manifest(_manifest(files={CAMERAS_JSON: "ab", rel: digest}), SRC)
    with _raises(SessionError, f"{SRC}: lists no calibration/cameras.json; every session needs the studio "
                               "calibration"):
        sess._check_manifest(_manifest(files={"cam_00/rgb/00000.png": "ab"}), SRC)


# --- opening a folder -------------------------------------------------------------------------------------------

def test_open_refuses_a_missing_folder_and_a_file(tmp_path):
    for p in (tmp_path / "nope", tmp_path / "file"):
        if p.name == "file":
            p.write_text("x")
        with _raises(SessionError, f"{p}: no such session folder"):
            open_session(p)


def test_open_names_the_interrupted_commit_the_missing_and_the_corrupt_manifest(tmp_path, caplog):
    s = _write(tmp_path / "s")
    staging = s / ".staging"
    (staging / "cam_00" / "rgb").mkdir(parents=True)
    (staging / "cam_00" / "rgb" / "00002.png").write_bytes(b"x")
    (staging / "notes").write_bytes(b"y")
    interrupted = f"{staging}: an interrupted write left 2 uncommitted files"
    with caplog.at_level(logging.WARNING, logger="bodystudio.capture.session"):
        opened = open_session(s)
    assert opened.interrupted_write == interrupted and opened.frame_ids == [0, 1] and opened.path == s
    assert [r.getMessage() for r in caplog.records if r.name == "bodystudio.capture.session"] == [
        f"{interrupted}; showing the last committed state (run `bodystudio capture recover {s}` to discard it)"]
    manifest = (s / "session.json").read_bytes()
    (s / "session.json").unlink()
    with _raises(SessionError, f"{s / 'session.json'}: missing, the session was never completed ({interrupted}); "
                               "regenerate or re-import it"):
        open_session(s)
    (staging / "commit.json").write_text("{}")
    with _raises(SessionError, f"{staging / 'commit.json'}: a write was interrupted while committing; run "
                               f"`bodystudio capture recover {s}` to finish it"):
        open_session(s)
    import shutil

    shutil.rmtree(staging)
    with _raises(SessionError, f"{s / 'session.json'}: missing, the session was never completed; regenerate or "
                               "re-import it"):
        open_session(s)
    for garbage in (b"{ not json", b'"\xff"'):
        (s / "session.json").write_bytes(garbage)
        try:
            json.loads(garbage)
        except ValueError as exc:
            why = str(exc)
        with _raises(SessionError, f"{s / 'session.json'}: corrupted manifest ({why}); regenerate or re-import the "
                                   "session"):
            open_session(s)
    (s / "session.json").write_bytes(manifest)
    clean = open_session(s)
    assert clean.interrupted_write is None and clean.manifest == json.loads(manifest)
    (s / "cam_01" / "rgb" / "00001.png").unlink()
    with _raises(SessionError, f"{s / 'cam_01/rgb/00001.png'}: missing (listed in session.json); the session is "
                               "incomplete, re-import or regenerate it"):
        open_session(s)
    bad = json.loads(manifest)
    bad["frames"] = [1, 0]
    (s / "session.json").write_text(json.dumps(bad))
    with pytest.raises(SessionError, match="lists frame 0 after 1"):
        open_session(s)


def test_open_refuses_a_session_being_written_and_releases_its_read_lock(tmp_path):
    s = _write(tmp_path / "s")
    _other_host_lock(s)
    busy = (f"{s}: session is being written by pid 4242 on elsewhere-{socket.gethostname()} (bodystudio synth, "
            f"since 2026-01-02T03:04:05Z); wait for it to finish (if that process is gone, delete {s / '.lock'})")
    with _raises(SessionError, busy):
        open_session(s)
    with command_read_locks(), _raises(SessionError, busy):
        open_session(s)
    (s / ".lock").unlink()
    with command_read_locks():
        opened = open_session(s)
        assert [p.name.rsplit(".", 2)[0] for p in (s / ".readers").iterdir()] == [socket.gethostname()]
        del opened
        gc.collect()
        assert not (s / ".readers").exists()  # released with the session
        (s / "session.json").rename(s / "moved.json")
        with pytest.raises(SessionError, match="missing, the session was never completed"):
            open_session(s)
        assert not (s / ".readers").exists()  # released by the refusal
        (s / "moved.json").rename(s / "session.json")
    assert open_session(s).frame_ids == [0, 1]


# --- checksummed reads ------------------------------------------------------------------------------------------

def test_reads_check_the_manifests_sha256_and_say_who_rewrote_a_file(tmp_path):
    s = _write(tmp_path / "s")
    opened = open_session(s)
    rel = "cam_00/rgb/00001.png"
    assert opened.read_bytes(rel) == (s / rel).read_bytes()
    assert hashlib.sha256(opened.read_bytes(rel)).hexdigest() == opened.files[rel]
    (s / "notes.txt").write_bytes(b"not listed")
    assert opened.read_bytes("notes.txt") == b"not listed"  # not in the manifest: nothing to check against
    (s / rel).write_bytes((s / rel).read_bytes() + b"\0")
    corrupted = f"{s / rel}: corrupted (sha256 differs from session.json); re-import or regenerate it"
    with _raises(SessionError, corrupted):
        opened.read_bytes(rel)
    with _raises(SessionError, corrupted):
        opened.frame(1).images["cam_00"]
    _other_host_lock(s)
    with _raises(SessionError, f"{s / rel}: changed while being read; the session is being written by pid 4242 "
                               "(bodystudio synth, since 2026-01-02T03:04:05Z); wait for it to finish and re-run"):
        opened.read_bytes(rel)
    (s / ".lock").unlink()
    rewritten = f"{s / rel}: changed while being read (the session was rewritten by another command since it was " \
                "opened); re-run"
    manifest = (s / "session.json").read_bytes()
    for changed in (manifest.replace(b'"synthetic"', b'"import"'), b"{ garbage", None):
        if changed is None:
            (s / "session.json").unlink()
        else:
            (s / "session.json").write_bytes(changed)
        with _raises(SessionError, rewritten):
            opened.read_bytes(rel)
    (s / "session.json").write_bytes(manifest)
    with _raises(SessionError, corrupted):
        opened.read_bytes(rel)
    (s / ".staging").mkdir()
    (s / ".staging" / "commit.json").write_text("{}")
    with _raises(SessionError, rewritten):
        opened.read_bytes(rel)
    (s / ".staging" / "commit.json").unlink()
    (s / rel).unlink()
    with _raises(SessionError, f"{s / rel}: missing (listed in session.json); the session is incomplete, re-import "
                               "or regenerate it"):
        opened.read_bytes(rel)


def test_read_json_names_the_file_and_the_decoder_error(tmp_path):
    s = _write(tmp_path / "s")
    for rel, data in (("gt/a.json", b'{"a": [1, 2]}'), ("gt/b.json", b"{ nope"), ("gt/c.json", b'"\xff"')):
        _rewrite(s, rel, data)
    opened = open_session(s)
    assert opened.read_json("gt/a.json") == {"a": [1, 2]}
    for rel, data in (("gt/b.json", b"{ nope"), ("gt/c.json", b'"\xff"')):
        try:
            json.loads(data)
        except ValueError as exc:
            why = str(exc)
        with _raises(SessionError, f"{s / rel}: not valid JSON ({why}); regenerate the session"):
            opened.read_json(rel)


def test_verify_counts_the_files_and_names_the_first_problem(tmp_path):
    s = _write(tmp_path / "s")
    opened = open_session(s)
    assert opened.verify() == 5 == len(opened.files)
    (s / "cam_01/rgb/00000.png").write_bytes(b"x")
    with _raises(SessionError, f"{s / 'cam_01/rgb/00000.png'}: corrupted (sha256 mismatch); re-import or "
                               "regenerate the session"):
        opened.verify()
    (s / "cam_00/rgb/00000.png").unlink()
    with _raises(SessionError, f"{s / 'cam_00/rgb/00000.png'}: missing (and 1 more problems); re-import or "
                               "regenerate the session"):
        opened.verify()
    (s / "cam_00/rgb/00001.png").unlink()
    (s / "cam_00/rgb/00001.png").mkdir()  # a folder where the file was: missing too
    with _raises(SessionError, f"{s / 'cam_00/rgb/00000.png'}: missing (and 2 more problems); re-import or "
                               "regenerate the session"):
        opened.verify()


def _in_memory_session(files, cameras=("cam_00", "cam_01"), frames=(0, 1), streams=("rgb",)):
    return Session(Path("S"), {"cameras": list(cameras), "frames": list(frames), "streams": list(streams),
                               "files": {f: "ab" for f in files}})


def test_unbacked_entries_name_cameras_frames_and_streams_without_files():
    full = [f"{c}/rgb/{f:05d}.png" for c in ("cam_00", "cam_01") for f in (0, 1)]
    assert _in_memory_session(full)._unbacked_entries() == []
    # a camera backed only by its ground-truth masks; the frames backed by the Kinect's files
    assert _in_memory_session(["cam_00/rgb/00000.png", "gt/masks/cam_01/00000.png", "kinect/joints/00001.json"],
                    streams=())._unbacked_entries() == []
    problems = _in_memory_session(["cam_0/rgb/00000.png", "cam_01/background/00001.png", "cam_01/rgb/00000.extra.png",
                         "gt/mirror/actors.npz"], cameras=("cam_00", "cam_01", "cam_0"), frames=(0, 1, 2),
                        streams=("rgb", "kinect_depth", "background", "made_up"))._unbacked_entries()
    assert problems == [
        "S/session.json: camera cam_00 is listed but has no files",
        "S/session.json: frame 1 is listed but has no files",
        "S/session.json: frame 2 is listed but has no files",
        "S/session.json: cam_00/rgb/00000.png (rgb of a listed camera and frame) is not in the manifest (8 such)",
        "S/session.json: stream kinect_depth is listed but has no files"]
    # holes in another camera stream are not the rgb stream's rule; a stream with some files is backed
    assert _in_memory_session(full + ["cam_00/mask/00001.png", "kinect/depth/00000.png"],
                    streams=("rgb", "mask", "kinect_depth"))._unbacked_entries() == []
    holes = _in_memory_session(full[:3], streams=("rgb",))._unbacked_entries()
    assert holes == ["S/session.json: cam_01/rgb/00001.png (rgb of a listed camera and frame) is not in the "
                     "manifest (1 such)"]
    assert _in_memory_session(["cam_00/rgb/00000.png"], cameras=("cam_00",), frames=(0,),
                    streams=("mask", "rgb"))._unbacked_entries() == [
        "S/session.json: stream mask is listed but has no files"]


def test_verify_reports_the_unbacked_entries_after_the_files(tmp_path):
    s = _write(tmp_path / "s")
    manifest = json.loads((s / "session.json").read_text())
    manifest["frames"] = [0, 1, 5]
    (s / "session.json").write_text(json.dumps(manifest))
    with _raises(SessionError, f"{s / 'session.json'}: frame 5 is listed but has no files (and 1 more problems); "
                               "re-import or regenerate the session"):
        open_session(s).verify()


# --- frames, streams, fingerprints ------------------------------------------------------------------------------

def test_frame_lookup_iteration_and_the_frame_list_in_messages(tmp_path):
    assert sess._ranges([]) == "none"
    assert sess._ranges([3]) == "3..3 (1 frames)"
    assert sess._ranges([0, 1, 2]) == "0..2 (3 frames)"
    assert sess._ranges([4, 5]) == "4..5 (2 frames)"
    assert sess._ranges([0, 2]) == "[0, 2]"
    assert sess._ranges([2, 3, 5]) == "[2, 3, 5]"
    s = open_session(_write(tmp_path / "s", frames=(3, 4, 5)))
    f = s.frame(np.int64(4))
    assert type(f.frame_id) is int and f.frame_id == 4 and f.session is s
    assert [x.frame_id for x in s] == [3, 4, 5] and len(s) == 3
    with _raises(SessionError, f"{s.path / 'session.json'}: no frame 7; frames are 3..5 (3 frames)"):
        s.frame(7)
    with _raises(SessionError, "S/session.json: no frame 1; frames are [0, 2]"):
        _in_memory_session([], frames=(0, 2)).frame(1)
    with _raises(SessionError, "S/session.json: no frame 0; frames are none"):
        _in_memory_session([], frames=()).frame(0)


def test_stream_paths_and_the_fingerprint_over_the_manifests_lines():
    assert sess.stream_path("rgb", 7, "c") == "c/rgb/00007.png"
    assert sess.stream_path("gt_mask", 123456, "c") == "gt/masks/c/123456.png"
    assert sess.stream_path("kinect_depth", 12) == "kinect/depth/00012.png"
    assert sess.stream_path("gt_mirror", 0, "ignored") == "gt/mirror/00000.npz"
    with pytest.raises(KeyError):
        sess.stream_path("made_up", 0)
    files = {"kinect/depth/00000.png": "d0", "kinect/depth/00001.png": "d1", "c/rgb/00001.png": "r1"}
    s = Session(Path("S"), {"files": files})
    want = hashlib.sha256(b"kinect/depth/00001.png d1\nkinect/depth/00000.png d0\n").hexdigest()
    assert sess.stream_fingerprint(s, "kinect_depth", ["1", 0.0]) == want
    assert sess.stream_fingerprint(s, "rgb", [1], "c") == hashlib.sha256(b"c/rgb/00001.png r1\n").hexdigest()
    assert sess.stream_fingerprint(s, "kinect_depth", []) == hashlib.sha256(b"").hexdigest()
    assert sess.stream_fingerprint(s, "kinect_depth", [0, 2]) is None
    assert sess.stream_fingerprint(s, "rgb", [1], "d") is None


def test_lazy_camera_files_list_only_cameras_with_a_file_and_decode_once(tmp_path):
    s = tmp_path / "s"
    with SessionWriter(s, _rig(("a", "b", "c")), source="synthetic") as w:
        w.write_image("c", 0, _rgb(1))
        w.write_image("a", 0, _rgb(2))
        w.write_image("b", 1, _rgb(3))
    images = open_session(s).frame(0).images
    assert list(images) == ["a", "c"] and len(images) == 2 and "b" not in images
    first = images["c"]
    assert np.array_equal(first, _rgb(1)) and images["c"] is first
    with pytest.raises(KeyError) as info:
        images["b"]
    assert info.value.args == (f"b: no rgb for frame 0 in {s}",)


def test_background_frames_are_one_cameras_in_index_order(tmp_path):
    s = tmp_path / "s"
    with SessionWriter(s, _rig(("cam_0", "cam_00")), source="synthetic") as w:
        w.write_image("cam_0", 0, _rgb(0))
        w.write_background("cam_00", 1, _rgb(11))
        w.write_background("cam_00", 0, _rgb(10))
        w.write_background("cam_0", 0, _rgb(20))
    opened = open_session(s)
    got = opened.background_frames("cam_00")
    assert len(got) == 2 and np.array_equal(got[0], _rgb(10)) and np.array_equal(got[1], _rgb(11))
    assert [g.shape for g in opened.background_frames("cam_0")] == [(H, W, 3)]
    assert opened.background_frames("cam") == []


# --- the joints file's bodies -----------------------------------------------------------------------------------

def test_a_body_parses_names_positions_tracked_player_and_joint_set():
    src = Path("S/kinect/joints/00000.json")
    body = sess._parse_body({"names": [1, "b"], "positions": [[0, 1, 2], [None, 3, None]]}, src, "v2")
    assert body["names"] == ["1", "b"] and body["player"] == 1 and body["joint_set"] == "v2"
    assert body["positions"].dtype == np.float64 and body["positions"].shape == (2, 3)
    np.testing.assert_array_equal(body["positions"], [[0, 1, 2], [np.nan, 3, np.nan]])
    assert body["tracked"].dtype == bool and body["tracked"].tolist() == [True, True]
    body = sess._parse_body({"names": ["a"], "positions": [[1, 2, 3]], "tracked": [0], "player": 6,
                             "joint_set": "v1"}, src, "v2")
    assert body["tracked"].tolist() == [False] and body["player"] == 6 and body["joint_set"] == "v1"
    assert sorted(body) == ["joint_set", "names", "player", "positions", "tracked"]
    assert sess._parse_body({"names": [], "positions": []}, src, None)["positions"].shape == (0, 3)
    for player in (0, 7, True, 1.0, "1", None):
        with _raises(SessionError, f"{src}: malformed joints (player must be an integer 1..6, got {player!r}); "
                                   "needs names and positions"):
            sess._parse_body({"names": ["a"], "positions": [[1, 2, 3]], "player": player}, src, None)
    for data, why in (({"positions": [[1, 2, 3]]}, "'names'"), ({"names": ["a"]}, "'positions'"),
                      ({"names": ["a"], "positions": [[1, 2]]}, "cannot reshape array of size 2 into shape (1,3)"),
                      ({"names": ["a"], "positions": [[1, 2, 3]], "tracked": [1, 1]},
                       "cannot reshape array of size 2 into shape (1,)")):
        with _raises(SessionError, f"{src}: malformed joints ({why}); needs names and positions"):
            sess._parse_body(data, src, None)


# --- optional frame streams: labels, meshes ---------------------------------------------------------------------

def test_optional_streams_are_none_when_absent_and_labels_are_checked(tmp_path):
    s = tmp_path / "s"
    labels = np.zeros((H, W), np.uint8)
    labels[1:3, 2:5] = 6
    with SessionWriter(s, _rig(), source="synthetic") as w:
        w.write_image("cam_00", 0, _rgb(0))
        w.write_gt_person(0, labels)
        w.write_gt_person(0, labels // 3, target=True)
        w.write_image("cam_00", 1, _rgb(1))
    opened = open_session(s)
    f0, f1 = opened.frame(0), opened.frame(1)
    assert f0._optional("gt_person") == "gt/person/00000.png" and f1._optional("gt_person") is None
    assert np.array_equal(f0.gt_person, labels) and np.array_equal(f0.gt_target_person, labels // 3)
    assert f0.gt_person.dtype == np.uint8 and f1.gt_person is None and f1.gt_mesh is None
    assert f0._optional_mesh("gt_mesh") is None and f0._optional_labels("gt_mirror") is None
    for stream, rel, image in (("gt_person", "gt/person/00000.png", np.full((H, W), 7, np.uint8)),
                               ("gt_target_person", "gt/target/person/00000.png", np.ones((H, W), np.uint16))):
        _rewrite(s, rel, sess.encode_png(image))
        with _raises(SessionError, f"{s / rel}: a person label image must be an 8-bit PNG with values 0..6; "
                                   "regenerate the session"):
            open_session(s).frame(0)._optional_labels(stream)


def test_ground_truth_mesh_reads_back_exactly(tmp_path):
    rng = np.random.default_rng(4)
    V = rng.normal(size=(7, 3))
    F = np.array([[0, 1, 2], [2, 3, 6], [4, 5, 0]])
    s = tmp_path / "s"
    with SessionWriter(s, _rig(), source="synthetic") as w:
        w.write_image("cam_00", 0, _rgb(0))
        w.write_gt_mesh(0, V, F)
        w.write_gt_arm_mesh(0, V[::-1].copy(), F[:1])
    f = open_session(s).frame(0)
    assert np.array_equal(f.gt_mesh.vertices, V) and np.array_equal(f.gt_mesh.faces, F)
    mesh = f._optional_mesh("gt_arm_mesh")
    assert np.array_equal(mesh.vertices, V[::-1]) and np.array_equal(mesh.faces, F[:1])


# --- the ground-truth PLY, against trimesh's reader -------------------------------------------------------------

def _ply(nv, nf, body=b"", header_extra=""):
    return (f"ply\nformat binary_little_endian 1.0\nelement vertex {nv}\nproperty double x\nproperty double y\n"
            f"property double z\n{header_extra}element face {nf}\nproperty list uchar int vertex_indices\n"
            "end_header\n").encode() + body


def _faces(F, n=3):
    f = np.empty(len(F), dtype=[("n", "u1"), ("i", "<i4", (3,))])
    f["n"] = n
    f["i"] = F
    return f.tobytes()


def test_ground_truth_ply_is_what_trimesh_reads_and_reads_back_exactly():
    import trimesh

    rng = np.random.default_rng(1)
    V = rng.normal(size=(9, 3)) * 1e3
    F = rng.integers(0, 9, (5, 3))
    data = sess.mesh_ply_bytes(V.astype(np.float32).astype(np.float64) + 1e-9, F)
    t = trimesh.load(io.BytesIO(data), file_type="ply", process=False)
    assert np.array_equal(np.asarray(t.vertices), V.astype(np.float32).astype(np.float64) + 1e-9)
    assert np.array_equal(np.asarray(t.faces), F)
    V2, F2 = sess.parse_ply_bytes(data, "m.ply")
    assert V2.dtype == np.float64 and F2.dtype == np.int64
    assert np.array_equal(V2, V.astype(np.float32).astype(np.float64) + 1e-9) and np.array_equal(F2, F)
    V0, F0 = sess.parse_ply_bytes(sess.mesh_ply_bytes(V[:0], F[:0]), "e.ply")
    assert V0.shape == (0, 3) and F0.shape == (0, 3)
    V1, F1 = sess.parse_ply_bytes(_ply(3, 0, V[:3].astype("<f8").tobytes()), "p.ply")
    assert np.array_equal(V1, V[:3]) and F1.shape == (0, 3)
    # the last vertex may be used; a header with other lines between is still ours
    V3, F3 = sess.parse_ply_bytes(_ply(3, 1, V[:3].tobytes() + _faces([[0, 1, 2]]), "comment x\n"), "q.ply")
    assert F3.tolist() == [[0, 1, 2]]


def test_ground_truth_ply_refusals_name_the_file():
    V = np.arange(9, dtype="<f8").reshape(3, 3)
    ours = "m.ply: not a bodystudio ground-truth PLY; regenerate the session"
    good = _ply(3, 1, V.tobytes() + _faces([[0, 1, 2]]))
    for bad in (b"", b"end_header\n" + good, good.replace(b"end_header\n", b"end_headr\n"),
                good.replace(b"ply\n", b"plx\n", 1), good.replace(b"property double x", b"property float x"),
                good.replace(b"element vertex 3", b"element vertex"),
                good.replace(b"element vertex 3", b"element vertex three"),
                good.replace(b"element face 1\n", b""), good.replace(b"element vertex 3\n", b""),
                _ply(-1, 1, V.tobytes()), _ply(3, -1, V.tobytes()), b" " + good):
        with _raises(SessionError, ours):
            sess.parse_ply_bytes(bad, "m.ply")
    for body, n in ((V.tobytes() + _faces([[0, 1, 2]])[:-1], 84), (V.tobytes() + _faces([[0, 1, 2]]) + b"\0", 86),
                    (V.tobytes(), 72)):
        with _raises(SessionError, f"m.ply: truncated PLY ({n} of 85 bytes); regenerate the session"):
            sess.parse_ply_bytes(_ply(3, 1, body), "m.ply")
    corrupt = ("m.ply: corrupt PLY (faces that are not triangles of its 3 vertices, or non-finite vertices); "
               "regenerate the session")
    for Vb, Fb, n in ((V, [[0, 1, 3]], 3), (V, [[-1, 1, 2]], 3), (V, [[0, 1, 2]], 4),
                      (np.where(np.arange(9).reshape(3, 3) == 4, np.nan, V), [[0, 1, 2]], 3),
                      (np.where(np.arange(9).reshape(3, 3) == 8, -np.inf, V), [[0, 1, 2]], 3)):
        with _raises(SessionError, corrupt):
            sess.parse_ply_bytes(_ply(3, 1, np.asarray(Vb, "<f8").tobytes() + _faces(Fb, n)), "m.ply")
    with _raises(SessionError, corrupt.replace("its 3 vertices", "its 0 vertices")):
        sess.parse_ply_bytes(_ply(0, 1, _faces([[0, 0, 0]])), "m.ply")


# --- npz, PNG, depth, albedo --------------------------------------------------------------------------------------

def test_npz_is_numpys_own_format_deterministic_and_refused_when_damaged():
    import zipfile

    arrays = {"b": np.arange(6.0).reshape(2, 3), "a": np.array([1, 2], np.int16), "c": np.zeros((0, 3))}
    data = sess.npz_bytes(arrays)
    with np.load(io.BytesIO(data), allow_pickle=False) as z:
        assert sorted(z.files) == ["a", "b", "c"]
        for k, v in arrays.items():
            assert z[k].dtype == v.dtype and np.array_equal(z[k], v)
    with zipfile.ZipFile(io.BytesIO(data)) as z:
        assert [i.filename for i in z.infolist()] == ["a.npy", "b.npy", "c.npy"]
        assert {i.date_time for i in z.infolist()} == {(1980, 1, 1, 0, 0, 0)}
        assert {i.compress_type for i in z.infolist()} == {zipfile.ZIP_STORED}
    assert sess.npz_bytes(dict(reversed(list(arrays.items())))) == data
    parsed = sess.parse_npz_bytes(data, "g.npz")
    assert sorted(parsed) == ["a", "b", "c"] and all(np.array_equal(parsed[k], arrays[k]) for k in arrays)
    with pytest.raises(ValueError):
        sess.npz_bytes({"o": np.array([{"x": 1}], dtype=object)})
    pickled = io.BytesIO()
    np.savez(pickled, o=np.array([{"x": 1}], dtype=object))
    for bad in (b"", b"PK\x03\x04 broken", data[:40], pickled.getvalue()):
        with pytest.raises(SessionError, match=r"^g\.npz: not a readable \.npz \(.+\); regenerate the session$"):
            sess.parse_npz_bytes(bad, "g.npz")


def test_png_encoding_is_what_pillow_decodes():
    from PIL import Image

    rgb = _rgb(5)
    png = sess.encode_png(rgb)
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    assert np.array_equal(np.asarray(Image.open(io.BytesIO(png)).convert("RGB")), rgb)
    grey = np.arange(H * W, dtype=np.uint8).reshape(H, W) * 5
    assert np.array_equal(np.asarray(Image.open(io.BytesIO(sess.encode_png(grey)))), grey)
    deep = (np.arange(H * W, dtype=np.uint16).reshape(H, W) * 1234).astype(np.uint16)
    assert np.array_equal(np.asarray(Image.open(io.BytesIO(sess.encode_png(deep)))).astype(np.uint16), deep)
    mask = np.eye(H, W, dtype=bool)
    assert np.array_equal(np.asarray(Image.open(io.BytesIO(sess.encode_png(mask)))), mask.astype(np.uint8) * 255)
    for bad, shown in ((np.zeros((2, 2)), "float64 (2, 2)"), (np.zeros(4, np.uint8), "uint8 (4,)"),
                       (np.zeros((2, 2, 3, 1), np.uint8), "uint8 (2, 2, 3, 1)"), (np.zeros((2, 2), np.int32),
                                                                                  "int32 (2, 2)")):
        with _raises(ValueError, f"cam x: PNG needs (H, W[, 3]) uint8 or uint16, got {shown}"):
            sess.encode_png(bad, "cam x")
    with _raises(ValueError, "image: PNG needs (H, W[, 3]) uint8 or uint16, got int8 (2, 2)"):
        sess.encode_png(np.zeros((2, 2), np.int8))


def test_png_decoding_of_pillows_files():
    from PIL import Image

    def pil(array, mode=None):
        buf = io.BytesIO()
        Image.fromarray(array, mode).save(buf, format="PNG")
        return buf.getvalue()

    rgb = _rgb(6)
    assert np.array_equal(sess.decode_png(pil(rgb), "x", True), rgb)
    grey = (np.arange(H * W).reshape(H, W) * 7 % 256).astype(np.uint8)
    out = sess.decode_png(pil(grey), "x", False)
    assert out.dtype == np.uint8 and np.array_equal(out, grey)
    assert np.array_equal(sess.decode_png(pil(grey), "x", True), np.repeat(grey[..., None], 3, axis=2))
    deep = (np.arange(H * W).reshape(H, W) * 1111).astype(np.uint16)
    out = sess.decode_png(sess.encode_png(deep), "x", False)
    assert out.dtype == np.uint16 and np.array_equal(out, deep)
    # a colour file read as one channel: the first channel OpenCV stores (blue), 2-D
    out = sess.decode_png(pil(rgb), "x", False)
    assert out.shape == (H, W) and np.array_equal(out, rgb[..., 2])
    with pytest.raises(SessionError, match=r"^S/cam_00/mask/00000\.png: unreadable image \(.*\); replace or remove "
                                           r"it; re-import or regenerate the session$"):
        sess.decode_png(b"\x89PNG\r\n\x1a\n broken", "S/cam_00/mask/00000.png", False)


def test_depth_is_stored_as_rounded_millimetres_and_missing_is_zero(tmp_path):
    d = np.array([[0.0, -1.0, np.nan, np.inf, 0.0004, 0.0016, 1.2346, 65.535]])
    mm = sess.depth_to_png_mm(d)
    assert mm.dtype == np.uint16 and mm.tolist() == [[0, 0, 0, 0, 0, 2, 1235, 65535]]
    assert sess.depth_to_png_mm(np.zeros((0, 4))).shape == (0, 4)
    assert sess.depth_to_png_mm([[1, 2]]).tolist() == [[1000, 2000]]
    with _raises(ValueError, "depth up to 65.5 m does not fit 16-bit millimetres (max 65.535 m)"):
        sess.depth_to_png_mm([[65.5355]])
    with _raises(ValueError, "depth up to 70.0 m does not fit 16-bit millimetres (max 65.535 m)"):
        sess.depth_to_png_mm([[1.0, 70.0, np.nan]])
    s = tmp_path / "s"
    with SessionWriter(s, _rig(), source="synthetic") as w:
        w.write_image("cam_00", 0, _rgb(0))
        w.write_kinect_depth(0, np.array([[0.0, 1.5], [2.2504, np.nan]]))
    f = open_session(s).frame(0)
    assert f.kinect_depth_m.dtype == np.float64 and f.kinect_depth_m.tolist() == [[0.0, 1.5], [2.25, 0.0]]


def test_albedo_reads_n_by_3_and_names_a_malformed_file(tmp_path):
    s = _write(tmp_path / "s", frames=(0,))
    assert open_session(s).gt_albedo is None and open_session(s)._gt_albedo("appearance") is None
    _rewrite(s, "gt/albedo.json", json.dumps({"albedo": [0.1, 0.2, 0.3, 0.4, 0.5, 0.6],
                                              "appearance": [[1, 0, 0]]}).encode())
    opened = open_session(s)
    assert opened._gt_albedo("albedo").dtype == np.float64
    assert opened._gt_albedo("albedo").tolist() == [[0.1, 0.2, 0.3], [0.4, 0.5, 0.6]]
    assert opened._gt_albedo("appearance").tolist() == [[1.0, 0.0, 0.0]]
    src = s / "gt/albedo.json"
    for data, why in (({"albedo": [1, 2]}, "cannot reshape array of size 2 into shape (3)"),
                      ({"albedo": [[1, "x", 2]]}, "could not convert string to float: 'x'"),
                      ({"other": []}, "'albedo'"), ([1], "list indices must be integers or slices, not str")):
        _rewrite(s, "gt/albedo.json", json.dumps(data).encode())
        with _raises(SessionError, f"{src}: malformed albedo ({why}); regenerate the session"):
            open_session(s)._gt_albedo("albedo")


# --- the Kinect calibration -------------------------------------------------------------------------------------

def _camera_dict(eye, f):
    return Camera.look_at("x", eye, (0, 1, 0), fx=f, width=64, height=48).to_dict()


def test_kinect_calibration_defaults_and_the_derived_depth_to_color_transform(tmp_path):
    depth, color = _camera_dict((0.1, 1.2, 2.5), 50.0), _camera_dict((0.3, 1.1, 2.4), 70.0)
    sensor = sess.kinect_calibration_from_dict({"depth": depth, "color": color}, "k.json")
    assert sensor.name == "kinect" and sensor.version == "v2" and sensor.depth.name == "kinect_depth"
    assert sensor.color.name == "kinect_color" and sensor.depth.K[0, 0] == 50.0 and sensor.color.K[0, 0] == 70.0
    assert sensor.baseline_m == 0.075 and sensor.depth_range_m == (0.5, 4.5)
    assert type(sensor.baseline_m) is float and all(type(x) is float for x in sensor.depth_range_m)
    # a world point in the depth camera's frame, moved by the transform, is the point in the colour camera's frame
    X = np.array([0.2, 0.9, -0.4])
    Xd, Xc = sensor.depth.R @ X + sensor.depth.t, sensor.color.R @ X + sensor.color.t
    T = sensor.depth_to_color
    assert T.shape == (4, 4) and np.allclose(T[:3, :3] @ Xd + T[:3, 3], Xc, atol=1e-12)
    assert np.array_equal(T[3], [0, 0, 0, 1])
    given = np.arange(16.0)
    sensor = sess.kinect_calibration_from_dict(
        {"name": "k2", "version": "v1", "depth": depth, "color": color, "depth_to_color": given.tolist(),
         "baseline_m": "0.1", "depth_range_m": ["0.8", 3]}, "k.json")
    assert sensor.name == "k2" and sensor.version == "v1" and sensor.depth.name == "k2_depth"
    assert sensor.color.name == "k2_color" and np.array_equal(sensor.depth_to_color, given.reshape(4, 4))
    assert sensor.baseline_m == 0.1 and sensor.depth_range_m == (0.8, 3.0)
    real = kinect_v1("320x240")
    d = sess.kinect_calibration_to_dict(real)
    assert d["format_version"] == 1 and d["depth_unit"] == "mm"
    assert {k: v for k, v in d.items() if k not in ("format_version", "depth_unit")} == real.to_dict()
    (tmp_path / "k.json").write_text(json.dumps(d))
    back = sess.load_kinect_calibration(tmp_path / "k.json")
    assert back.version == "v1" and np.array_equal(back.depth_to_color, real.depth_to_color)
    assert np.array_equal(back.depth.K, real.depth.K) and back.baseline_m == real.baseline_m


def test_kinect_calibration_refusals_name_the_file_and_what_it_needs(tmp_path):
    depth = _camera_dict((0.1, 1.2, 2.5), 50.0)
    tail = "; it needs 'depth' and 'color' cameras as in calibration/cameras.json"
    for data, why in (([1], "TypeError: top level must be an object"),
                      ({"depth": depth}, "KeyError: 'color'"),
                      ({"color": depth, "depth": depth, "version": "v3"}, "ValueError: version must be v1 or v2, got "
                                                                          "'v3'"),
                      ({"color": depth, "depth": {}}, "InputError: camera kinect_depth: missing key 'K' (need K, "
                                                      "dist, R, t, width, height)"),
                      ({"color": depth, "depth": depth, "depth_to_color": [1, 2]},
                       "ValueError: cannot reshape array of size 2 into shape (4,4)"),
                      ({"color": depth, "depth": depth, "baseline_m": "far"},
                       "ValueError: could not convert string to float: 'far'")):
        with _raises(FileFormatError, f"k.json: not a Kinect calibration ({why}){tail}"):
            sess.kinect_calibration_from_dict(data, "k.json")
    (tmp_path / "k.json").write_text(json.dumps({"depth": depth}))
    with _raises(FileFormatError, f"{tmp_path / 'k.json'}: not a Kinect calibration (KeyError: 'color'){tail}"):
        sess.load_kinect_calibration(tmp_path / "k.json")


# --- the survivors of the first recheck ---------------------------------------------------------------------------

def test_repeated_frame_ids_a_top_level_entry_and_the_manifests_path_in_open_refusals(tmp_path):
    with _raises(SessionError, f"{SRC}: manifest field 'frames' lists frame 0 after 0; each frame id once, "
                               "increasing: fix session.json or re-import"):
        sess._check_manifest(_manifest(frames=[0, 0]), SRC)
    assert _in_memory_session(["cam_00/rgb/00000.png", "readme.txt"], cameras=("cam_00",), frames=(0,),
                              streams=("rgb",))._unbacked_entries() == []
    s = _write(tmp_path / "s")
    m = json.loads((s / "session.json").read_text())
    m["cameras"] = ["cam 00"]
    (s / "session.json").write_text(json.dumps(m))
    with _raises(SessionError, f"{s / 'session.json'}: manifest field 'cameras' must list camera names (letters, "
                               "digits, _ . -)"):
        open_session(s)


def test_iterated_frames_read_their_session(tmp_path):
    s = open_session(_write(tmp_path / "s", frames=(0, 1)))
    assert [np.array_equal(f.images["cam_01"], _rgb(10 * f.frame_id + 1)) for f in s] == [True, True]


def test_a_body_with_integer_positions_and_tracked_flags_reads_as_float64_and_bool():
    body = sess._parse_body({"names": ["a", "b"], "positions": [[0, 1, 2], [3, 4, 5]], "tracked": [1, 0]},
                            Path("j.json"), None)
    assert body["positions"].dtype == np.float64 and body["tracked"].dtype == bool
    assert body["tracked"].tolist() == [True, False]
    assert sess._parse_body({"names": ["a"], "positions": [[0, 1, 2]]}, Path("j.json"), None)["tracked"].dtype == bool


def test_an_rgba_png_decodes_to_rgb_and_a_16_bit_one_to_8_bit_colour():
    from PIL import Image

    rgba = np.dstack([_rgb(7), np.full((H, W), 128, np.uint8)])
    buf = io.BytesIO()
    Image.fromarray(rgba, "RGBA").save(buf, format="PNG")
    out = sess.decode_png(buf.getvalue(), "x", True)
    assert out.shape == (H, W, 3) and np.array_equal(out, _rgb(7))
    deep = np.full((H, W), 0x1234, np.uint16)
    out = sess.decode_png(sess.encode_png(deep), "x", True)
    assert out.dtype == np.uint8 and out.shape == (H, W, 3)


def test_an_integer_depth_to_color_matrix_reads_as_float64(tmp_path):
    depth = _camera_dict((0.1, 1.2, 2.5), 50.0)
    sensor = sess.kinect_calibration_from_dict({"depth": depth, "color": depth, "depth_to_color": np.eye(4, dtype=int)
                                                .tolist()}, "k.json")
    assert sensor.depth_to_color.dtype == np.float64 and np.array_equal(sensor.depth_to_color, np.eye(4))
    (tmp_path / "k.json").write_text("{ nope")
    try:
        json.loads("{ nope")
    except ValueError as exc:
        why = str(exc)
    with _raises(FileFormatError, f"{tmp_path / 'k.json'}: not a valid Kinect calibration ({why}); fix or regenerate "
                                  "the file"):
        sess.load_kinect_calibration(tmp_path / "k.json")


def test_float32_and_integer_vertices_are_stored_as_float64():
    for V in (np.arange(9, dtype=np.float32).reshape(3, 3) / 7, np.arange(9).reshape(3, 3)):
        got, F = sess.parse_ply_bytes(sess.mesh_ply_bytes(V, [[0, 1, 2]]), "m.ply")
        assert got.dtype == np.float64 and np.array_equal(got, V.astype(np.float64)) and F.tolist() == [[0, 1, 2]]


def test_the_header_ends_at_the_first_end_header_and_non_ascii_header_bytes_are_ours_to_refuse():
    # vertex bytes that spell the header's last line: the body starts after the first one
    V = np.frombuffer(b"end_header\n" + b"\x00" * 61, dtype="<f8").reshape(3, 3)
    assert np.all(np.isfinite(V))
    got, _ = sess.parse_ply_bytes(sess.mesh_ply_bytes(V, [[0, 0, 0]]), "m.ply")
    assert np.array_equal(got, V)
    data = _ply(3, 1, np.zeros(9).tobytes() + _faces([[0, 1, 2]]), "comment caf\xe9\n".replace("\xe9", "?"))
    assert sess.parse_ply_bytes(data.replace(b"caf?", b"caf\xe9"), "m.ply")[1].tolist() == [[0, 1, 2]]
    with _raises(SessionError, "m.ply: not a bodystudio ground-truth PLY; regenerate the session"):
        sess.parse_ply_bytes(b"pl\xff\nend_header\n", "m.ply")


def test_damaged_ground_truth_files_in_a_session_name_the_file(tmp_path):
    s = tmp_path / "s"
    with SessionWriter(s, _rig(), source="synthetic") as w:
        w.write_image("cam_00", 0, _rgb(0))
        w.write_gt_mesh(0, np.zeros((3, 3)), [[0, 1, 2]])
    _rewrite(s, "gt/meshes/00000.ply", b"ply\nend_header\n")
    with _raises(SessionError, f"{s / 'gt/meshes/00000.ply'}: not a bodystudio ground-truth PLY; regenerate the "
                               "session"):
        open_session(s).frame(0)._optional_mesh("gt_mesh")
    _rewrite(s, "cam_00/rgb/00000.png", b"\x89PNG\r\n\x1a\n broken")
    with pytest.raises(SessionError, match="^" + re.escape(f"{s / 'cam_00/rgb/00000.png'}: unreadable image")):
        open_session(s).read_image("cam_00/rgb/00000.png", True)


def test_float32_depth_is_rounded_to_the_nearest_millimetre_of_its_exact_value():
    # 0.5035 as float32 is 0.50349998...: 503 mm; in float32 arithmetic 0.5035 * 1000 rounds up to 503.5 -> 504
    d = np.array([[0.5035, 0.5065, 2.0005]], np.float32)
    want = np.rint(d.astype(np.float64) * 1000.0)
    assert want.tolist() == [[503, 507, 2000]]
    assert sess.depth_to_png_mm(d).tolist() == want.tolist()


# --- the decorated readers (cached properties: mutmut makes no mutant; docs/mutation/capture-session-plant.py) ---

def test_property_readers_check_what_they_read(tmp_path):
    s = tmp_path / "s"
    with SessionWriter(s, _rig(), source="synthetic") as w:
        w.write_image("cam_00", 0, _rgb(0))
        w.write_mask("cam_00", 0, np.ones((H, W), bool))
        w.write_kinect_depth(0, np.ones((H, W)))
        w.write_kinect_player(0, np.zeros((H, W), np.uint8))
        w.write_kinect_joints(0, ["a"], [[0, 1, 2]])
    mask = np.zeros((H, W), np.uint8)
    mask[0, :3] = (127, 128, 255)
    _rewrite(s, "cam_00/mask/00000.png", sess.encode_png(mask))
    assert open_session(s).frame(0).masks["cam_00"][0, :4].tolist() == [False, True, True, False]
    _rewrite(s, "kinect/depth/00000.png", sess.encode_png(np.full((H, W), 200, np.uint8)))
    with _raises(SessionError, f"{s / 'kinect/depth/00000.png'}: depth must be a 16-bit PNG in millimetres, got uint8; "
                               "re-import with the right --depth-scale"):
        _ = open_session(s).frame(0).kinect_depth_m
    for image, shown in ((np.full((H, W), 7, np.uint8), "uint8 up to 7"), (np.full((H, W), 1, np.uint16),
                                                                          "uint16 up to 1")):
        _rewrite(s, "kinect/player/00000.png", sess.encode_png(image))
        with _raises(SessionError, f"{s / 'kinect/player/00000.png'}: a player mask must be an 8-bit PNG with values "
                                   f"0...6, got {shown}; regenerate the session"):
            _ = open_session(s).frame(0).kinect_player
    _rewrite(s, "kinect/player/00000.png", sess.encode_png(np.full((H, W), 6, np.uint8)))
    assert open_session(s).frame(0).kinect_player.max() == 6
    src = s / "kinect/joints/00000.json"
    body = {"names": ["a"], "positions": [[0, 1, 2]]}
    for data, why in (([body], "top level must be an object"), ({"bodies": {"0": body}}, "'bodies' must be a list"),
                      ({"bodies": [{**body, "player": 2}, {**body, "player": 2}]}, "player ids [2, 2] repeat")):
        _rewrite(s, "kinect/joints/00000.json", json.dumps(data).encode())
        with _raises(SessionError, f"{src}: malformed joints ({why}); regenerate the session"):
            _ = open_session(s).frame(0).kinect_bodies


def test_bodies_take_the_files_joint_set_and_the_old_layout_is_player_one(tmp_path):
    s = tmp_path / "s"
    with SessionWriter(s, _rig(), source="synthetic") as w:
        w.write_image("cam_00", 0, _rgb(0))
        w.write_kinect_bodies(0, [{"player": 4, "names": ["a"], "positions": [[0, 1, 2]]}], joint_set="v1")
    (body,) = open_session(s).frame(0).kinect_bodies
    assert body["player"] == 4 and body["joint_set"] == "v1"
    old = {"joint_set": "v2", "player": 3, "names": ["a"], "positions": [[0, 1, 2]]}
    _rewrite(s, "kinect/joints/00000.json", json.dumps(old).encode())
    f = open_session(s).frame(0)
    assert [(b["player"], b["joint_set"]) for b in f.kinect_bodies] == [(1, "v2")] and f.kinect_joints["player"] == 1


def test_ground_truth_properties_and_the_manifests_optional_fields(tmp_path):
    from bodystudio.body import Pose

    rng = np.random.default_rng(8)
    V, F = rng.normal(size=(4, 3)), np.array([[0, 1, 2], [1, 2, 3]])
    heads, tails = rng.normal(size=(2, 3)), rng.normal(size=(2, 3))
    rot = rng.normal(size=(2, 3)) * 0.2
    s = tmp_path / "s"
    with SessionWriter(s, _rig(), source="synthetic", metadata={"seed": 3}) as w:
        w.write_gt_target_rgb(0, _rgb(5))
        w.write_gt_arm_mesh(0, V, F)
        w.write_gt_mesh(0, V * 2, F[:1])
        w.write_gt_joints(0, ["root", "spine"], heads, tails)
        w.write_gt_pose(1, Pose(rot, np.zeros(3)), ["root", "spine"])  # a frame with a pose and no joints
    opened = open_session(s)
    f = opened.frame(0)
    assert np.array_equal(f.gt_target_rgb, _rgb(5))
    assert np.array_equal(f.gt_arm_mesh.vertices, V) and np.array_equal(f.gt_arm_mesh.faces, F)
    assert np.array_equal(f.gt_joints["heads"], heads) and np.array_equal(f.gt_joints["tails"], tails)
    assert opened.frame(1).gt_joints is None and np.allclose(opened.frame(1).gt_pose.rotations, rot, atol=1e-12)
    assert opened.metadata == {"seed": 3} and opened.source == "synthetic"
    bare = Session(Path("S"), {})
    assert bare.source == "unknown" and bare.metadata == {}


def test_the_cameras_are_checksum_checked_and_the_albedo_properties_read_their_keys(tmp_path):
    s = _write(tmp_path / "s", frames=(0,))
    _rewrite(s, "gt/albedo.json", json.dumps({"albedo": [[0.1, 0.2, 0.3]], "appearance": [[0.9, 0.8, 0.7]]}).encode())
    opened = open_session(s)
    assert opened.gt_albedo.tolist() == [[0.1, 0.2, 0.3]] and opened.gt_appearance_albedo.tolist() == [[0.9, 0.8, 0.7]]
    rig = json.loads((s / "calibration/cameras.json").read_text())
    rig["cameras"]["cam_00"]["t"] = [0.0, 0.0, 9.0]
    (s / "calibration/cameras.json").write_text(json.dumps(rig))  # a hand edit the manifest does not know
    with _raises(SessionError, f"{s / 'calibration/cameras.json'}: corrupted (sha256 differs from session.json); "
                               "re-import or regenerate it"):
        _ = open_session(s).cameras


def test_the_mirror_actors_file_reads_back(tmp_path):
    s = _write(tmp_path / "s", frames=(0,))
    assert open_session(s).gt_mirror_actors is None
    with SessionWriter(s, update=True) as w:
        w.write_gt_mirror_actors({"rest": np.arange(6.0).reshape(2, 3), "ids": np.array([3, 4])})
    actors = open_session(s).gt_mirror_actors
    assert sorted(actors) == ["ids", "rest"] and actors["ids"].tolist() == [3, 4] and actors["rest"][1, 2] == 5.0
