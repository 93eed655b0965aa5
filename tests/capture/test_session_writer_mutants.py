"""The session writer called directly (issue 17, mutation testing of ``capture/session.py``): the manifest a
commit writes (fields, sorted frames and files, each file's sha256 by hashlib over the bytes on disk), each
``write_*``'s path, stream and content read back by independent readers (json, Pillow, trimesh, numpy's npz
reader), its refusals word for word, the lock and the new folder cleaned up after a refusal or an abort, updates
that keep the previous files. Each test writes its own session (mutmut's forked mutants inherit anything cached);
< 2 s."""

from __future__ import annotations

import hashlib
import json
import re
import socket

import numpy as np
import pytest

from bodystudio.capture import session as sess
from bodystudio.capture.session import SessionWriter, open_session
from bodystudio.errors import SessionError
from bodystudio.geometry.camera import Camera, CameraRig, kinect_v1

W, H = 8, 6


def _raises(exc, message):
    return pytest.raises(exc, match="^" + re.escape(message) + "$")


def _rig(names=("cam_00", "cam_01")):
    return CameraRig({n: Camera.look_at(n, (np.sin(i), 1.0, 3 * np.cos(i)), (0, 1, 0), fx=10.0, width=W, height=H)
                      for i, n in enumerate(names)})


def _rgb(seed):
    return np.random.default_rng(seed).integers(0, 256, (H, W, 3), dtype=np.uint8)


def _pil(path):
    from PIL import Image

    return np.asarray(Image.open(path))


def _json(path):
    return json.loads(path.read_text())


def _manifest(path):
    return _json(path / "session.json")


def test_a_new_sessions_manifest_lists_every_file_with_its_sha256(tmp_path):
    s = tmp_path / "s"
    rig = _rig()
    with SessionWriter(s, rig, source="synthetic", metadata={"seed": 3}, command="test write") as w:
        assert w.camera_names == ["cam_00", "cam_01"]
        assert _json(s / ".lock")["command"] == "test write" and _json(s / ".lock")["pid"] > 0
        w.write_image("cam_01", np.int64(2), _rgb(2))
        w.write_mask("cam_00", 2, np.eye(H, W))
        w.write_image("cam_00", 0, _rgb(0))
        w.write_image("cam_00", 2, _rgb(1))
        assert not (s / "session.json").exists() and (s / ".staging" / "cam_00/rgb/00000.png").is_file()
    m = _manifest(s)
    files = sorted(p.relative_to(s).as_posix() for p in s.rglob("*") if p.is_file() and p.name != "session.json")
    assert files == ["calibration/cameras.json", "cam_00/mask/00002.png", "cam_00/rgb/00000.png",
                     "cam_00/rgb/00002.png", "cam_01/rgb/00002.png"]
    assert m == {"format": "bodystudio-session", "version": 1, "source": "synthetic", "cameras": ["cam_00", "cam_01"],
                 "frames": [0, 2], "streams": ["rgb", "mask"], "metadata": {"seed": 3},
                 "files": {f: hashlib.sha256((s / f).read_bytes()).hexdigest() for f in files}}
    assert list(m["files"]) == files and type(m["frames"][1]) is int
    assert CameraRig.from_dict(_json(s / "calibration/cameras.json")).to_dict() == rig.to_dict()
    assert np.array_equal(_pil(s / "cam_00/rgb/00002.png"), _rgb(1))
    assert not (s / ".staging").exists() and not (s / ".lock").exists()


def test_commit_returns_the_opened_session_and_an_update_keeps_the_rest(tmp_path):
    s = tmp_path / "s"
    w = SessionWriter(s, _rig(), source="import", metadata={"a": 1, "b": 2})
    w.write_image("cam_00", 1, _rgb(1))
    opened = w.commit()
    assert opened.path == s and opened.frame_ids == [1] and opened.source == "import" and not (s / ".lock").exists()
    before = _manifest(s)
    with SessionWriter(s, update=True, metadata={"b": 3, "c": 4}) as w:
        assert w.camera_names == ["cam_00", "cam_01"]
        w.write_image("cam_01", 0, _rgb(0))
        w.write_image("cam_00", 1, _rgb(5))  # replaced
    m = _manifest(s)
    assert m["metadata"] == {"a": 1, "b": 3, "c": 4} and m["frames"] == [0, 1] and m["streams"] == ["rgb"]
    assert m["source"] == "import" and m["cameras"] == before["cameras"]
    assert list(m["files"]) == ["calibration/cameras.json", "cam_00/rgb/00001.png", "cam_01/rgb/00000.png"]
    assert m["files"]["calibration/cameras.json"] == before["files"]["calibration/cameras.json"]
    assert m["files"]["cam_00/rgb/00001.png"] == hashlib.sha256((s / "cam_00/rgb/00001.png").read_bytes()).hexdigest()
    assert np.array_equal(_pil(s / "cam_00/rgb/00001.png"), _rgb(5))
    # an update with nothing new leaves metadata alone when none is given
    with SessionWriter(s, update=True):
        pass
    assert _manifest(s) == m


def test_the_writers_refusals_release_the_lock_and_remove_a_new_empty_folder(tmp_path):
    s = tmp_path / "new"
    with _raises(ValueError, "a new session needs its cameras (CameraRig)"):
        SessionWriter(s)
    assert not s.exists()
    for bad in ("cam 0", "cam_00\n", "_cam", ""):
        rig = CameraRig({"ok": _rig(("ok",))["ok"], bad: _rig(("x",))["x"]})
        with _raises(SessionError, f"camera name {bad!r} cannot be a folder name; use letters, digits, _ . -"):
            SessionWriter(s, rig)
        assert not s.exists()
    kept = tmp_path / "kept"
    kept.mkdir()
    (kept / "other.txt").write_text("x")
    with _raises(SessionError, f"{kept / '.staging'}: another write is in progress or was interrupted; run "
                               f"`bodystudio capture recover {kept}` first"):
        (kept / ".staging").mkdir()
        SessionWriter(kept, _rig())
    assert sorted(p.name for p in kept.iterdir()) == [".staging", "other.txt"]
    (kept / ".staging").rmdir()
    SessionWriter(kept, _rig()).commit()
    with _raises(SessionError, f"{kept}: already holds a session; choose a new folder or delete it"):
        SessionWriter(kept, _rig())
    assert not (kept / ".lock").exists() and (kept / "session.json").is_file()
    with _raises(SessionError, f"{tmp_path / 'missing' / 'session.json'}: missing, the session was never "
                               "completed; regenerate or re-import it"):
        SessionWriter(tmp_path / "missing", update=True)
    assert not (tmp_path / "missing").exists()
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(SessionError, match="missing, the session was never completed"):
        SessionWriter(empty, update=True)
    assert empty.is_dir() and not any(empty.iterdir())  # it existed before: stays


def test_a_second_writer_is_refused_while_one_is_open(tmp_path):
    s = tmp_path / "s"
    first = SessionWriter(s, _rig())
    with _raises(SessionError, f"{s / '.staging'}: another write is in progress or was interrupted; run "
                               f"`bodystudio capture recover {s}` first"):
        SessionWriter(s, _rig())
    assert (s / ".lock").exists()  # the first writer's lock stays
    first.abort()
    assert not s.exists()
    (s).mkdir()
    (s / ".lock").write_text(json.dumps({"pid": 4242, "host": "elsewhere-" + socket.gethostname(),
                                         "command": "bodystudio synth", "since": "t0"}))
    with _raises(SessionError, f"{s}: session is being written by pid 4242 on elsewhere-{socket.gethostname()} "
                               f"(bodystudio synth, since t0); wait for it to finish (if that process is gone, "
                               f"delete {s / '.lock'})"):
        SessionWriter(s, _rig())
    assert (s / ".lock").exists()


def test_abort_discards_the_staged_files_and_keeps_an_updated_session(tmp_path):
    s = tmp_path / "s"
    with pytest.raises(RuntimeError):
        with SessionWriter(s, _rig()) as w:
            w.write_image("cam_00", 0, _rgb(0))
            raise RuntimeError("stop")
    assert not s.exists()
    with SessionWriter(s, _rig()) as w:
        w.write_image("cam_00", 0, _rgb(0))
    before = _manifest(s)
    w = SessionWriter(s, update=True)
    w.write_image("cam_01", 0, _rgb(1))
    w.abort()
    assert w._staged == {} and _manifest(s) == before and not (s / ".staging").exists()
    assert not (s / ".lock").exists() and s.is_dir()
    # nothing staged, but a new session's folder holding something else stays on abort
    t = tmp_path / "t"
    w = SessionWriter(t, _rig())
    (t / "keep.txt").write_text("x")
    w.abort()
    assert sorted(p.name for p in t.iterdir()) == ["keep.txt"]


def test_images_masks_layers_targets_and_backgrounds_go_to_their_paths(tmp_path):
    s = tmp_path / "s"
    mask = np.array([[0, 1, 2, -1, 255, 0, 0, 3]] * H)
    labels = np.tile(np.array([0, 1, 2, 1, 0, 2, 2, 0], np.int64), (H, 1))
    with SessionWriter(s, _rig()) as w:
        w.write_mask("cam_01", 4, mask)
        w.write_mask("cam_01", 4, mask == 0, ground_truth=True)
        w.write_layers("cam_00", 4, labels)
        w.write_layers("cam_00", 4, labels[:, ::-1], target=True)
        w.write_target("cam_01", 5, _rgb(7))
        w.write_background("cam_00", 12, _rgb(8))
        for call in (lambda: w.write_image("cam_09", 0, _rgb(0)), lambda: w.write_mask("cam_09", 0, mask),
                     lambda: w.write_layers("cam_09", 0, labels), lambda: w.write_target("cam_09", 0, _rgb(0)),
                     lambda: w.write_background("cam_09", 0, _rgb(0))):
            with _raises(SessionError, "camera 'cam_09' is not in this session's calibration (cam_00, cam_01)"):
                call()
    m = _manifest(s)
    assert m["frames"] == [4, 5]
    assert m["streams"] == ["mask", "gt_mask", "gt_layers", "gt_target_layers", "gt_target", "background"]
    want = (mask > 0).astype(np.uint8) * 255
    assert np.array_equal(_pil(s / "cam_01/mask/00004.png"), want)
    assert np.array_equal(_pil(s / "gt/masks/cam_01/00004.png"), (mask == 0).astype(np.uint8) * 255)
    assert np.array_equal(_pil(s / "gt/layers/cam_00/00004.png"), labels)
    assert np.array_equal(_pil(s / "gt/garment_target_layers/cam_00/00004.png"), labels[:, ::-1])
    assert np.array_equal(_pil(s / "gt/garment_target/cam_01/00005.png"), _rgb(7))
    assert np.array_equal(_pil(s / "cam_00/background/00012.png"), _rgb(8))
    f = open_session(s).frame(4)
    assert np.array_equal(f.masks["cam_01"], mask > 0) and np.array_equal(f.gt_layers["cam_00"], labels)
    assert np.array_equal(f.gt_target_layers["cam_00"], labels[:, ::-1])
    with pytest.raises(ValueError, match=r"^cam_00 frame 3: PNG needs"):
        with SessionWriter(tmp_path / "t", _rig()) as w:
            w.write_image("cam_00", 3, np.zeros((H, W, 3)))
    with pytest.raises(ValueError, match=r"^cam_01 target 6: PNG needs"):
        with SessionWriter(tmp_path / "t", _rig()) as w:
            w.write_target("cam_01", 6, np.zeros((H, W, 3)))


def test_ground_truth_json_files_of_the_whole_session(tmp_path):
    s = tmp_path / "s"
    with SessionWriter(s, _rig()) as w:
        w.write_image("cam_00", 0, _rgb(0))
        for rel in ("gt/lighting.json", "gt/garment.json", "gt/albedo.json"):
            w.write_gt_json(rel, {"rel": rel, "x": np.arange(2)})
        with _raises(ValueError, "unknown ground-truth file 'gt/other.json'"):
            w.write_gt_json("gt/other.json", {})
        w.write_gt_subject({"gender": 0.5}, {"belly": 0.1}, resolution="6k", rig="game_engine")
        w.write_gt_arm_pose(0, {"shoulder": [0.1, 0.2, 0.3]})
    m = _manifest(s)
    assert m["streams"] == ["rgb", "gt_arm_pose"] and m["frames"] == [0]
    for rel in ("gt/lighting.json", "gt/garment.json", "gt/albedo.json"):
        assert _json(s / rel) == {"rel": rel, "x": [0, 1]}
        assert (s / rel).read_text().endswith("}\n")
    assert _json(s / "gt/phenotype.json") == {"phenotype": {"gender": 0.5}, "local": {"belly": 0.1},
                                              "resolution": "6k", "rig": "game_engine"}
    assert _json(s / "gt/arm_pose/00000.json") == {"shoulder": [0.1, 0.2, 0.3]}
    opened = open_session(s)
    assert opened.gt_lighting["rel"] == "gt/lighting.json" and opened.gt_garment["rel"] == "gt/garment.json"
    assert opened.frame(0).gt_arm_pose == {"shoulder": [0.1, 0.2, 0.3]}


def test_kinect_streams_and_calibration(tmp_path):
    s = tmp_path / "s"
    sensor = kinect_v1("320x240")
    depth = np.array([[0.0, 1.0005, 2.5], [np.nan, 4.0, 0.25]])
    with SessionWriter(s, _rig()) as w:
        w.write_kinect_calibration(sensor)
        w.write_kinect_depth(3, depth)
        w.write_kinect_rgb(3, _rgb(3))
        w.write_kinect_joints(np.int64(3), ("Head", "Neck", "Hip"), [0, 1.7, 0, np.nan, 1.5, 0, 0, 1, np.inf])
        w.write_kinect_joints(4, ["Head"], [[0, 1, 2]], tracked=[0], joint_set="v1")
    m = _manifest(s)
    assert m["streams"] == ["kinect_depth", "kinect_rgb", "kinect_joints"] and m["frames"] == [3, 4]
    assert _json(s / "kinect/calibration.json") == {"format_version": 1, "depth_unit": "mm", **json.loads(
        json.dumps(sensor.to_dict()))}
    assert _pil(s / "kinect/depth/00003.png").astype(np.int64).tolist() == [[0, 1000, 2500], [0, 4000, 250]]
    assert np.array_equal(_pil(s / "kinect/rgb/00003.png"), _rgb(3))
    assert _json(s / "kinect/joints/00003.json") == {
        "joint_set": None, "frame": "studio", "unit": "m", "names": ["Head", "Neck", "Hip"],
        "positions": [[0.0, 1.7, 0.0], [None, None, None], [None, None, None]], "tracked": [True, True, True]}
    assert _json(s / "kinect/joints/00004.json") == {
        "joint_set": "v1", "frame": "studio", "unit": "m", "names": ["Head"], "positions": [[0.0, 1.0, 2.0]],
        "tracked": [False]}
    assert open_session(s).kinect.version == "v1"
    with pytest.raises(ValueError, match="cannot reshape"):
        with SessionWriter(tmp_path / "t", _rig()) as w:
            w.write_kinect_joints(0, ["a", "b"], [[0, 1, 2]])


def test_several_bodies_the_lowest_player_at_the_top_and_the_refusals(tmp_path):
    s = tmp_path / "s"
    a = {"player": 3, "names": ["Head", "Neck"], "positions": [[0, 1.7, 0], [np.nan, 0, 0]], "tracked": [1, 0]}
    b = {"player": np.int64(2), "names": ("Head",), "positions": [0, 1.6, 1]}
    with SessionWriter(s, _rig()) as w:
        w.write_kinect_bodies(0, [a, b], joint_set="v2")
        w.write_kinect_bodies(1, [])
        w.write_kinect_bodies(2, [{**a, "player": 6}, {**b, "player": 1}])
        for bodies, message in (([{**a, "player": 0}], "player ids are 1..6, got 0"),
                                ([{**a, "player": 7}], "player ids are 1..6, got 7"),
                                ([a, {**b, "player": 3}], "player ids must differ between bodies, got [3, 3]")):
            with _raises(ValueError, message):
                w.write_kinect_bodies(5, bodies)
        with pytest.raises(ValueError, match="cannot reshape"):
            w.write_kinect_bodies(5, [{**a, "tracked": [1, 0, 1]}])
    assert _manifest(s)["frames"] == [0, 1, 2] and _manifest(s)["streams"] == ["kinect_joints"]
    low = {"player": 2, "names": ["Head"], "positions": [[0.0, 1.6, 1.0]], "tracked": [True]}
    high = {"player": 3, "names": ["Head", "Neck"], "positions": [[0.0, 1.7, 0.0], [None, None, None]],
            "tracked": [True, False]}
    assert _json(s / "kinect/joints/00000.json") == {
        "joint_set": "v2", "frame": "studio", "unit": "m", "names": ["Head"], "positions": [[0.0, 1.6, 1.0]],
        "tracked": [True], "bodies": [low, high]}
    assert _json(s / "kinect/joints/00001.json") == {"joint_set": None, "frame": "studio", "unit": "m", "bodies": []}
    two = _json(s / "kinect/joints/00002.json")
    assert [x["player"] for x in two["bodies"]] == [1, 6] and two["names"] == ["Head"]
    f = open_session(s).frame(0)
    assert [x["player"] for x in f.kinect_bodies] == [2, 3] and f.kinect_joints["player"] == 2


def test_player_masks_and_person_labels_are_checked_before_writing(tmp_path):
    s = tmp_path / "s"
    player = np.zeros((H, W), np.int64)
    player[1, 2], player[3, 4] = 6, 1
    labels = np.zeros((H, W), np.int32)
    labels[2, 2:5] = 6
    with SessionWriter(s, _rig()) as w:
        w.write_kinect_player(0, player)
        w.write_kinect_player(1, player > 0)
        w.write_gt_person(0, labels)
        w.write_gt_person(1, labels // 2, target=True)
        for bad, message in ((np.zeros((H, W, 1), np.uint8), "player mask must be an (H, W) integer image, got uint8 "
                                                            "(6, 8, 1)"),
                             (np.zeros((H, W)), "player mask must be an (H, W) integer image, got float64 (6, 8)"),
                             (np.full((H, W), 7), "player mask values must be 0..6, got 7..7"),
                             (player - 1, "player mask values must be 0..6, got -1..5")):
            with _raises(ValueError, message):
                w.write_kinect_player(2, bad)
        for bad in (labels + 1, labels - 1, labels[None]):
            with _raises(ValueError, "person labels must be an (H, W) image with values 0..6"):
                w.write_gt_person(2, bad)
    assert _manifest(s)["frames"] == [0, 1]
    assert _manifest(s)["streams"] == ["kinect_player", "gt_person", "gt_target_person"]
    assert np.array_equal(_pil(s / "kinect/player/00000.png"), player)
    assert np.array_equal(_pil(s / "kinect/player/00001.png"), (player > 0).astype(np.uint8))
    assert np.array_equal(_pil(s / "gt/person/00000.png"), labels)
    assert np.array_equal(_pil(s / "gt/target/person/00001.png"), labels // 2)


def test_meshes_joints_poses_and_mirror_arrays_read_back_by_other_readers(tmp_path):
    import trimesh

    from bodystudio.body import Pose

    rng = np.random.default_rng(2)
    V, F = rng.normal(size=(5, 3)), np.array([[0, 1, 2], [2, 3, 4]])
    heads, tails = rng.normal(size=(2, 3)), rng.normal(size=(2, 3))
    rot = rng.normal(size=(2, 3)) * 0.3
    s = tmp_path / "s"
    with SessionWriter(s, _rig()) as w:
        w.write_gt_mesh(0, V, F)
        w.write_gt_arm_mesh(1, V * 2, F[::-1])
        w.write_gt_joints(0, ("root", "spine"), heads, tails)
        w.write_gt_pose(0, Pose(rot, np.array([0.0, 0.1, 0.2])), ("root", "spine"))
        w.write_gt_target_rgb(2, _rgb(4))
        w.write_gt_mirror(2, {"posed": V, "ids": np.arange(3)})
        w.write_gt_mirror_actors({"rest": V[:2]})
    m = _manifest(s)
    assert m["frames"] == [0, 1, 2]
    assert m["streams"] == ["gt_mesh", "gt_arm_mesh", "gt_joints", "gt_pose", "gt_target_rgb", "gt_mirror"]
    for rel, Vw, Fw in (("gt/meshes/00000.ply", V, F), ("gt/arm/00001.ply", V * 2, F[::-1])):
        t = trimesh.load(s / rel, process=False)
        assert np.array_equal(np.asarray(t.vertices), Vw) and np.array_equal(np.asarray(t.faces), Fw)
    j = _json(s / "gt/joints/00000.json")
    assert j == {"bone_names": ["root", "spine"], "heads": heads.tolist(), "tails": tails.tolist()}
    p = _json(s / "gt/pose/00000.json")
    assert p["bone_names"] == ["root", "spine"]
    f = open_session(s).frame(0)
    assert np.allclose(f.gt_pose.rotations, rot, atol=1e-12) and np.allclose(f.gt_pose.translation, [0, 0.1, 0.2])
    assert np.array_equal(f.gt_joints["heads"], heads) and f.gt_joints["bone_names"] == ["root", "spine"]
    assert np.array_equal(_pil(s / "gt/target/rgb/00002.png"), _rgb(4))
    with np.load(s / "gt/mirror/00002.npz") as z:
        assert sorted(z.files) == ["ids", "posed"] and np.array_equal(z["posed"], V)
    with np.load(s / "gt/mirror/actors.npz") as z:
        assert np.array_equal(z["rest"], V[:2])


def test_staging_is_atomic_per_file_and_its_hash_is_of_the_bytes(tmp_path):
    s = tmp_path / "s"
    w = SessionWriter(s, _rig())
    data = sess.encode_png(_rgb(9))
    w._stage("cam_00/rgb/00007.png", data, "rgb", np.int64(7))
    w._stage("cam_00/rgb/00007.png", data, "rgb", 7)
    w._stage("notes/x.bin", b"abc")
    assert w._staged == {"calibration/cameras.json": w._staged["calibration/cameras.json"],
                         "cam_00/rgb/00007.png": hashlib.sha256(data).hexdigest(),
                         "notes/x.bin": hashlib.sha256(b"abc").hexdigest()}
    assert w._manifest["frames"] == [7] and type(w._manifest["frames"][0]) is int and w._manifest["streams"] == ["rgb"]
    assert (s / ".staging/notes/x.bin").read_bytes() == b"abc"
    assert sorted(p.name for p in (s / ".staging").rglob("*") if p.is_file()) == ["00007.png", "cameras.json", "x.bin"]
    w.abort()


def _each_frame_writer(w, frame):
    """Every writer of a per-frame file, each called alone for ``frame``."""
    rng = np.random.default_rng(frame)
    V, F = rng.normal(size=(3, 3)), np.array([[0, 1, 2]])
    from bodystudio.body import Pose

    return {
        "rgb": lambda: w.write_image("cam_00", frame, _rgb(frame)),
        "mask": lambda: w.write_mask("cam_00", frame, np.eye(H, W)),
        "gt_layers": lambda: w.write_layers("cam_00", frame, np.zeros((H, W), np.uint8)),
        "gt_target": lambda: w.write_target("cam_00", frame, _rgb(frame)),
        "kinect_depth": lambda: w.write_kinect_depth(frame, np.ones((H, W))),
        "kinect_rgb": lambda: w.write_kinect_rgb(frame, _rgb(frame)),
        "kinect_joints": lambda: w.write_kinect_joints(frame, ["a"], [[0, 1, 2]]),
        "kinect_player": lambda: w.write_kinect_player(frame, np.zeros((H, W), np.uint8)),
        "gt_mesh": lambda: w.write_gt_mesh(frame, V, F),
        "gt_joints": lambda: w.write_gt_joints(frame, ["root"], V[:1], V[1:2]),
        "gt_pose": lambda: w.write_gt_pose(frame, Pose(np.zeros((1, 3)), np.zeros(3)), ["root"]),
        "gt_arm_mesh": lambda: w.write_gt_arm_mesh(frame, V, F),
        "gt_arm_pose": lambda: w.write_gt_arm_pose(frame, {"elbow": [0, 0, 1]}),
        "gt_person": lambda: w.write_gt_person(frame, np.zeros((H, W), np.uint8)),
        "gt_target_rgb": lambda: w.write_gt_target_rgb(frame, _rgb(frame)),
        "gt_mirror": lambda: w.write_gt_mirror(frame, {"a": np.zeros(2)}),
    }


def test_each_per_frame_writer_alone_lists_its_frame_and_stream(tmp_path):
    s = tmp_path / "s"
    with SessionWriter(s, _rig()) as w:
        calls = _each_frame_writer(w, 0)
        for k, stream in enumerate(calls):
            _each_frame_writer(w, k + 3)[stream]()
    m = _manifest(s)
    assert m["frames"] == list(range(3, 3 + len(calls)))
    assert m["streams"] == list(calls)
    for k, stream in enumerate(calls):
        rel = sess.stream_path(stream, k + 3, "cam_00")
        assert rel in m["files"] and (s / rel).is_file()


def test_tracked_flags_are_json_booleans(tmp_path):
    s = tmp_path / "s"
    with SessionWriter(s, _rig()) as w:
        w.write_kinect_joints(0, ["a", "b"], [[0, 1, 2], [1, 2, 3]])
        w.write_kinect_joints(1, ["a", "b"], [[0, 1, 2], [1, 2, 3]], tracked=[1, 0])
        w.write_kinect_bodies(2, [{"player": 1, "names": ["a"], "positions": [[0, 1, 2]]},
                                  {"player": 2, "names": ["a"], "positions": [[0, 1, 2]], "tracked": [0]}])
    for frame, want in ((0, [True, True]), (1, [True, False])):
        got = _json(s / f"kinect/joints/{frame:05d}.json")["tracked"]
        assert got == want and all(type(x) is bool for x in got)
    bodies = _json(s / "kinect/joints/00002.json")["bodies"]
    assert [b["tracked"] for b in bodies] == [[True], [False]]
    assert all(type(x) is bool for b in bodies for x in b["tracked"])
    assert all(type(x) is float for b in bodies for p in b["positions"] for x in p)


def test_an_update_of_a_manifest_without_metadata_adds_it(tmp_path):
    s = tmp_path / "s"
    with SessionWriter(s, _rig()) as w:
        w.write_image("cam_00", 0, _rgb(0))
    m = _manifest(s)
    del m["metadata"]
    (s / "session.json").write_text(json.dumps(m))
    with SessionWriter(s, update=True, metadata={"k": 1}):
        pass
    assert _manifest(s)["metadata"] == {"k": 1}


def test_the_progress_bar_goes_to_stderr_and_only_on_a_terminal(monkeypatch):
    import rich.console

    bar = sess.progress_bar(True)
    assert bar.console.stderr is True and bar.disable is (not bar.console.is_terminal)
    assert [type(c).__name__ for c in bar.columns] == ["TextColumn", "BarColumn", "MofNCompleteColumn",
                                                      "TimeRemainingColumn"]
    assert bar.columns[0].text_format == "{task.description}"
    monkeypatch.setattr(rich.console.Console, "is_terminal", property(lambda self: True))
    assert sess.progress_bar(True).disable is False and sess.progress_bar(False).disable is True
    monkeypatch.setattr(rich.console.Console, "is_terminal", property(lambda self: False))
    assert sess.progress_bar(True).disable is True


def test_recover_says_what_it_did_and_refuses_a_live_writer(tmp_path):
    s = tmp_path / "s"
    with SessionWriter(s, _rig()) as w:
        w.write_image("cam_00", 0, _rgb(0))
    assert sess.recover_session(s) == "nothing to recover"
    assert sess.recover_session(str(s)) == "nothing to recover"
    layout = sess.session_layout(f"{s}/")
    assert layout.root == s and layout.manifest == "session.json" and layout.prefix == "." and layout.what == f"{s}/"
    (s / ".lock").write_text(json.dumps({"pid": 4242, "host": "elsewhere-" + socket.gethostname(),
                                         "command": "bodystudio synth", "since": "t0"}))
    with _raises(SessionError, f"{s}: being written by pid 4242 on elsewhere-{socket.gethostname()} (bodystudio "
                               f"synth, since t0); wait for it to finish (if that process is gone, delete "
                               f"{s / '.lock'}); nothing to recover while it runs"):
        sess.recover_session(s)
