"""Property (fuzz) tests for every file loader: any mutation of a valid file either loads or raises a
``BodyStudioError`` subclass (one line for the CLI), never another exception.

Each test starts from a valid file written by our own writer and applies 1-3 random mutations: JSON
loaders get structural ones (a value replaced by any JSON value, a key or item deleted); text formats
(PLY, OBJ, OpenCV YAML, COLMAP text) get token, line and byte edits. CI runs a bounded, derandomised
number of examples per loader; a long run sets ``BODYSTUDIO_FUZZ_EXAMPLES`` (e.g. 20000), which also
draws fresh random examples; ``BODYSTUDIO_FUZZ_SECONDS`` instead runs each loader for a wall-clock time
(batches of 500 fresh examples until the time is up):

    BODYSTUDIO_FUZZ_EXAMPLES=20000 python -m pytest -q -s tests/reliability/test_fuzz_loaders.py
    BODYSTUDIO_FUZZ_SECONDS=600 python -m pytest -q -s tests/reliability/test_fuzz_loaders.py
"""

from __future__ import annotations

import copy
import json
import os
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bodystudio.errors import BodyStudioError

EXAMPLES = int(os.environ.get("BODYSTUDIO_FUZZ_EXAMPLES", "0") or 0)
SECONDS = float(os.environ.get("BODYSTUDIO_FUZZ_SECONDS", "0") or 0)
LONG_RUN = EXAMPLES > 0 or SECONDS > 0
FUZZ = settings(max_examples=(EXAMPLES or 500) if LONG_RUN else 80, deadline=None, database=None,
                derandomize=not LONG_RUN, suppress_health_check=list(HealthCheck), print_blob=True)

# --- strategies ---------------------------------------------------------------------------------------

_leaf = st.one_of(st.none(), st.booleans(), st.integers(-(2**70), 2**70), st.integers(-3, 3),
                  st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=8),
                  st.sampled_from(["", "cam_00", "../x", "a/b", "nan", "1e400", "\x00", "-1"]))
_json_value = st.recursive(_leaf, lambda c: st.lists(c, max_size=4) | st.dictionaries(st.text(max_size=6), c,
                                                                                       max_size=4), max_leaves=8)


def _mutate_json(draw, node):
    """One structural edit somewhere in ``node``: replace a subtree, delete a key/item, or add a key."""
    if not isinstance(node, (dict, list)) or not node or draw(st.integers(0, 4)) == 0:
        return draw(_json_value)
    keys = list(node.keys()) if isinstance(node, dict) else list(range(len(node)))
    key = draw(st.sampled_from(keys))
    op = draw(st.sampled_from(["descend", "descend", "replace", "delete", "add"]))
    if op == "descend":
        node[key] = _mutate_json(draw, node[key])
    elif op == "replace":
        node[key] = draw(_json_value)
    elif op == "delete":
        del node[key]
    elif isinstance(node, dict):
        node[draw(st.text(max_size=6))] = draw(_json_value)
    else:
        node.append(draw(_json_value))
    return node


@st.composite
def mutated_json(draw, doc):
    doc = copy.deepcopy(doc)
    for _ in range(draw(st.integers(1, 3))):
        doc = _mutate_json(draw, doc)
    return json.dumps(doc).encode()


_token = st.one_of(st.sampled_from(["nan", "inf", "-inf", "-1", "0", "1e400", "-1e308", "999999999999", "3.5",
                                    "x", "", "[", "]", "{", "}", ":", "-", "'", '"', "#", "%YAML:1.0",
                                    "!!opencv-matrix",
                                    "end_header", "element vertex 3", "element face -1", "property float x",
                                    "format binary_little_endian 1.0", "f 1 2 99", "v 1 2", "vt", "mtllib x.mtl"]),
                   st.integers(-(2**40), 2**40).map(str), st.floats().map(repr), st.text(max_size=6))


@st.composite
def mutated_text(draw, data: bytes):
    """1-3 edits of a text file: a token replaced, a line deleted/duplicated/swapped, truncation, bytes."""
    lines = data.split(b"\n")
    for _ in range(draw(st.integers(1, 3))):
        op = draw(st.sampled_from(["token", "token", "token", "delete", "duplicate", "swap", "truncate", "bytes"]))
        i = draw(st.integers(0, len(lines) - 1)) if lines else 0
        if op == "token" and lines:
            words = lines[i].split(b" ")
            j = draw(st.integers(0, len(words) - 1))
            words[j] = draw(_token).encode("utf-8", "surrogatepass")
            lines[i] = b" ".join(words)
        elif op == "delete" and lines:
            del lines[i]
        elif op == "duplicate" and lines:
            lines.insert(i, lines[i])
        elif op == "swap" and len(lines) > 1:
            k = draw(st.integers(0, len(lines) - 1))
            lines[i], lines[k] = lines[k], lines[i]
        elif op == "truncate":
            text = b"\n".join(lines)
            lines = text[:draw(st.integers(0, len(text)))].split(b"\n")
        else:
            text = b"\n".join(lines)
            at = draw(st.integers(0, len(text)))
            lines = (text[:at] + draw(st.binary(min_size=1, max_size=8)) + text[at:]).split(b"\n")
    return b"\n".join(lines)


_STATS = {"examples": 0, "loaded": 0, "refused": 0}


def _drive(run) -> None:
    """Run a ``@given`` test once, or, with ``BODYSTUDIO_FUZZ_SECONDS``, in fresh batches until the time is up."""
    start = time.monotonic()
    run()
    while time.monotonic() - start < SECONDS:
        run()
    _STATS["seconds"] = time.monotonic() - start


@pytest.fixture(autouse=True)
def _count_examples(request):
    """Counts per test; the long run (``-s``) prints them: examples, loads that succeeded, one-line refusals."""
    _STATS.update(examples=0, loaded=0, refused=0, seconds=0.0)
    yield
    if LONG_RUN:
        print(f"\nFUZZ {request.node.name}: {_STATS.get('seconds', 0):.0f} s, {_STATS['examples']} examples, "
              f"{_STATS['loaded']} loader calls loaded, "
              f"{_STATS['refused']} refused with a one-line error")


def _only_user_errors(load, *args):
    """Run a loader: success or a BodyStudioError are fine; any other exception fails the test."""
    try:
        result = load(*args)
    except BodyStudioError as exc:
        assert "\n" not in str(exc).strip(), f"multi-line error: {exc}"
        _STATS["refused"] += 1
        return None
    _STATS["loaded"] += 1
    return result


# --- the loaders --------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def folder(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("fuzz")


def _rig():
    from bodystudio.geometry.camera import ring_rig

    return ring_rig(2, width=32, height=24)


def test_cameras_json(folder):
    from bodystudio.geometry.camera import load_cameras_json, save_cameras_json

    save_cameras_json(folder / "cameras.json", _rig())
    doc = json.loads((folder / "cameras.json").read_text())
    assert len(load_cameras_json(folder / "cameras.json")) == 2

    @FUZZ
    @given(mutated_json(doc))
    def run(data):
        _STATS["examples"] += 1
        (folder / "cameras.json").write_bytes(data)
        rig = _only_user_errors(load_cameras_json, folder / "cameras.json")
        if rig is not None:
            for cam in rig:  # what every caller does next: project a point
                cam.project(np.array([[0.0, 1.0, 0.0]]))

    _drive(run)


def test_board_json(folder):
    from bodystudio.calib.board import CharucoBoardSpec, load_board_json, save_board_json

    save_board_json(folder / "board.json", CharucoBoardSpec())
    doc = json.loads((folder / "board.json").read_text())

    @FUZZ
    @given(mutated_json(doc))
    def run(data):
        _STATS["examples"] += 1
        (folder / "board.json").write_bytes(data)
        spec = _only_user_errors(load_board_json, folder / "board.json")
        if spec is not None:
            assert spec.n_corners > 0 and np.all(np.isfinite(spec.size_m))

    _drive(run)


def test_pose_json(folder):
    from bodystudio.body.pose import load_pose

    bones = ("root", "spine", "head")
    doc = {"rotations": {"spine": [0.1, 0.0, -0.2], "head": [0.0, 0.3, 0.0]}, "translation": [0.0, 0.9, 0.1]}
    euler = {"bone_rotations": {"spine": [10.0, 0.0, 5.0]}, "translation": [0.0, 0.0, 0.0]}

    @FUZZ
    @given(st.one_of(mutated_json(doc), mutated_json(euler)))
    def run(data):
        _STATS["examples"] += 1
        (folder / "pose.json").write_bytes(data)
        pose = _only_user_errors(load_pose, folder / "pose.json", bones)
        if pose is not None:
            assert pose.rotations.shape == (3, 3) and np.all(np.isfinite(pose.rotations))

    _drive(run)


def _session(folder: Path) -> Path:
    from bodystudio.capture.session import SessionWriter

    path = folder / "session"
    if not (path / "session.json").is_file():
        with SessionWriter(path, _rig(), source="synthetic") as w:
            for frame in (0, 1):
                for cam in ("cam_00", "cam_01"):
                    w.write_image(cam, frame, np.full((24, 32, 3), 90, np.uint8))
                    w.write_mask(cam, frame, np.eye(24, 32, dtype=bool))
    return path


def _read_session(path: Path):
    from bodystudio.capture.session import open_session

    s = open_session(path)
    _ = (s.camera_names, s.frame_ids, s.streams, s.source, s.metadata, len(s), s.cameras)
    for fid in s.frame_ids[:3]:
        frame = s.frame(fid)
        for cam in frame.masks:
            assert frame.masks[cam].ndim == 2
    s.verify()
    return s


def test_session_json(folder):
    path = _session(folder)
    valid = (path / "session.json").read_bytes()
    assert len(_read_session(path)) == 2

    @FUZZ
    @given(mutated_json(json.loads(valid)))
    def run(data):
        _STATS["examples"] += 1
        (path / "session.json").write_bytes(data)
        _only_user_errors(_read_session, path)

    try:
        _drive(run)
    finally:
        (path / "session.json").write_bytes(valid)


def _mesh_files() -> dict[str, bytes]:
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=0)
    out = {".ply": m.export(file_type="ply", encoding="ascii"), ".obj": m.export(file_type="obj"),
           ".binply": m.export(file_type="ply")}  # binary body behind a text header
    return {k: v.encode() if isinstance(v, str) else v for k, v in out.items()}


@pytest.mark.parametrize("kind", [".ply", ".obj", ".binply"])
def test_scan_and_mesh_files(folder, kind):
    from bodystudio.geometry.mesh import load_mesh
    from bodystudio.register.scan import read_scan_file

    valid = _mesh_files()[kind]
    path = folder / ("mesh" + (".ply" if kind == ".binply" else kind))
    path.write_bytes(valid)
    assert read_scan_file(path).n_faces == 20

    @FUZZ
    @given(mutated_text(valid))
    def run(data):
        _STATS["examples"] += 1
        path.write_bytes(data)
        for load in (read_scan_file, load_mesh):
            mesh = _only_user_errors(load, path)
            if mesh is not None:
                assert mesh.faces.min(initial=0) >= 0 and mesh.faces.max(initial=0) < mesh.n_vertices

    _drive(run)


def test_session_ground_truth_ply(folder):
    from bodystudio.capture.session import mesh_ply_bytes, parse_ply_bytes

    valid = mesh_ply_bytes(np.random.default_rng(0).normal(size=(5, 3)), np.array([[0, 1, 2], [2, 3, 4]]))
    assert parse_ply_bytes(valid, "gt.ply")[1].shape == (2, 3)

    @FUZZ
    @given(mutated_text(valid))
    def run(data):
        _STATS["examples"] += 1
        _only_user_errors(parse_ply_bytes, data, "gt.ply")

    _drive(run)


def test_joints_json(folder):
    from bodystudio.capture.importer import load_joints

    doc = {"names": ["HipCenter", "Head", "HandLeft"], "frames": [[[0, 1, 0], [0, 1.7, 0], [0.4, 1, 0.1]]] * 2,
           "tracked": [[True, True, False]] * 2}

    @FUZZ
    @given(mutated_json(doc))
    def run(data):
        _STATS["examples"] += 1
        (folder / "joints.json").write_bytes(data)
        track = _only_user_errors(load_joints, folder / "joints.json")
        if track is not None:
            assert track.positions.shape[1:] == (len(track.names), 3)

    _drive(run)


def test_kinect_calibration_json(folder):
    from bodystudio.capture.session import kinect_calibration_to_dict, load_kinect_calibration
    from bodystudio.fileio import write_json
    from bodystudio.geometry.camera import kinect_v2

    doc = json.loads(json.dumps(kinect_calibration_to_dict(kinect_v2()), default=lambda a: np.asarray(a).tolist()))
    write_json(folder / "kinect.json", doc)
    assert load_kinect_calibration(folder / "kinect.json").version == "v2"

    @FUZZ
    @given(mutated_json(doc))
    def run(data):
        _STATS["examples"] += 1
        (folder / "kinect.json").write_bytes(data)
        _only_user_errors(load_kinect_calibration, folder / "kinect.json")

    _drive(run)


@pytest.mark.parametrize("which", ["intri.yml", "extri.yml"])
def test_easymocap_yaml(folder, which):
    from bodystudio.calib.io import load_easymocap_yaml, save_easymocap_yaml
    from bodystudio.capture.importer import load_studio_cameras

    sub = folder / "easymocap"
    sub.mkdir(exist_ok=True)
    save_easymocap_yaml(sub, _rig())
    valid = {n: (sub / n).read_bytes() for n in ("intri.yml", "extri.yml")}
    assert len(load_easymocap_yaml(sub)) == 2

    @FUZZ
    @given(mutated_text(valid[which]))
    def run(data):
        _STATS["examples"] += 1
        (sub / which).write_bytes(data)
        _only_user_errors(load_easymocap_yaml, sub)  # the calibration stage's reader
        _only_user_errors(load_studio_cameras, sub)  # the importer's

    try:
        _drive(run)
    finally:
        for n, b in valid.items():
            (sub / n).write_bytes(b)


@pytest.mark.parametrize("which", ["cameras.txt", "images.txt"])
def test_colmap_text(folder, which):
    from bodystudio.calib.io import load_colmap_model, save_colmap_model

    sub = folder / "colmap"
    save_colmap_model(sub, _rig())
    valid = {n: (sub / n).read_bytes() for n in ("cameras.txt", "images.txt", "points3D.txt")}
    assert len(load_colmap_model(sub)) == 2

    @FUZZ
    @given(mutated_text(valid[which]))
    def run(data):
        _STATS["examples"] += 1
        (sub / which).write_bytes(data)
        _only_user_errors(load_colmap_model, sub)

    try:
        _drive(run)
    finally:
        for n, b in valid.items():
            (sub / n).write_bytes(b)


def test_opencv_matrix_without_cols_is_a_one_line_error(folder):
    """OpenCV 5.0's FileNode.mat() corrupts the heap on this node (found by the fuzz test above: the process
    died with ``malloc(): invalid size``); both EasyMocap readers parse matrices themselves."""
    from bodystudio.calib.io import load_easymocap_yaml, save_easymocap_yaml
    from bodystudio.capture.importer import load_studio_cameras
    from bodystudio.errors import FileFormatError

    sub = folder / "nocols"
    sub.mkdir(exist_ok=True)
    save_easymocap_yaml(sub, _rig())
    text = (sub / "intri.yml").read_text()
    at = text.index("K_cam_01")
    (sub / "intri.yml").write_text(text[:at] + text[at:].replace("   cols: 3\n", "", 1))
    for load in (load_easymocap_yaml, load_studio_cameras):
        with pytest.raises(FileFormatError, match="K_cam_01"):
            load(sub)


# --- crashes the long fuzz run found (kept as fixed cases) ---------------------------------------------

def test_board_json_with_a_huge_integer_square_is_one_line(folder):
    from bodystudio.calib.board import load_board_json

    doc = {"type": "charuco", "squares_x": 10, "squares_y": 7, "square_m": 1844674407370955162, "marker_m": 0.075,
           "dictionary": "DICT_4X4_50", "legacy_pattern": False}
    (folder / "board.json").write_text(json.dumps(doc))
    with pytest.raises(BodyStudioError, match="square size"):
        load_board_json(folder / "board.json")
    doc["square_m"] = 1  # an integer size in range still loads, as a float
    (folder / "board.json").write_text(json.dumps({**doc, "marker_m": 0.75}))
    spec = load_board_json(folder / "board.json")
    assert isinstance(spec.square_m, float) and np.all(np.isfinite(spec.size_m))


def test_easymocap_image_size_of_1e400_is_one_line(folder):
    from bodystudio.calib.io import load_easymocap_yaml, save_easymocap_yaml
    from bodystudio.geometry.camera import ring_rig

    save_easymocap_yaml(folder / "emc", ring_rig(2, width=32, height=24))
    intri = folder / "emc" / "intri.yml"
    intri.write_text(intri.read_text().replace("H_cam_01: 24", "H_cam_01: 1e400"))
    with pytest.raises(BodyStudioError, match="image size"):
        load_easymocap_yaml(folder / "emc")


@pytest.mark.parametrize("field, value", [("squares_x", float("nan")), ("squares_y", 7.5), ("squares_x", True),
                                          ("squares_x", 10**30), ("dictionary", "DICT_ARUCO_ORIGINAL"),
                                          ("dictionary", ["DICT_4X4_50"]), ("legacy_pattern", "no")])
def test_board_json_squares_and_dictionary_are_checked_by_type(folder, field, value):
    """The re-run found NaN squares passing ``< 3`` and a dictionary whose name has no marker count; a
    real dictionary without a count (ARUCO_ORIGINAL, 1024 markers) loads."""
    from bodystudio.calib.board import load_board_json

    doc = {"type": "charuco", "squares_x": 10, "squares_y": 7, "square_m": 0.1, "marker_m": 0.075,
           "dictionary": "DICT_4X4_50", "legacy_pattern": False, field: value}
    (folder / "board.json").write_text(json.dumps(doc))
    if value == "DICT_ARUCO_ORIGINAL":
        assert load_board_json(folder / "board.json").dictionary == value
        return
    with pytest.raises(BodyStudioError) as exc:
        load_board_json(folder / "board.json")
    assert field in str(exc.value) or "squares" in str(exc.value) or "dictionary" in str(exc.value)


@pytest.mark.parametrize("size", ["1e400", ".nan", "0.5", "-3", "70000"])
def test_both_easymocap_readers_refuse_an_impossible_image_size(folder, size):
    """The importer's EasyMocap reader cast W_ to int itself (OverflowError on 1e400) after the calibration
    reader was fixed; there is now one reader for both, and both entry points refuse in one line."""
    from bodystudio.calib.io import load_easymocap_yaml, save_easymocap_yaml
    from bodystudio.capture.importer import load_studio_cameras

    save_easymocap_yaml(folder / "emc2", _rig())
    intri = folder / "emc2" / "intri.yml"
    intri.write_text(intri.read_text().replace("W_cam_00: 32", f"W_cam_00: {size}"))
    for load in (load_easymocap_yaml, load_studio_cameras):
        with pytest.raises(BodyStudioError, match="image size"):
            load(folder / "emc2")
