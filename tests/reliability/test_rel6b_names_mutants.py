"""rel6b's name and number checks, each refusal's whole line and both sides of each rule (mutLL).

``fileio.is_frame_number``, ``importer._safe_name`` / ``_CAMERA_NAME`` and the two-cameras-one-folder refusal (the
EasyMocap files written with OpenCV's own ``FileStorage``), ``batch._SCHEDULER_ADDRESS``, and the "given twice" rule
of ``--local`` (``cli.body.parse_assignments``), ``--reshape`` (``rig.reshape.parse_reshape``) and ``--shape``
(``cli.muscle._parse_shape``). Milliseconds.
"""

from __future__ import annotations

import re
from pathlib import Path

import cv2
import numpy as np
import pytest

from bodystudio.errors import FileFormatError, InputError


@pytest.mark.parametrize("stem, ok", [("0", True), ("0123456789", True), ("00001", True), ("a1", False),
                                      ("1a", False), ("1 ", False), ("١", False), ("¹", False), ("1.5", False)])
def test_is_frame_number_is_ascii_digits_only(stem, ok):
    from bodystudio.fileio import is_frame_number

    # the reference: every character one of the ten ASCII digits, and at least one
    assert (bool(stem) and all(ch in "0123456789" for ch in stem)) is ok
    assert is_frame_number(stem) is ok


@pytest.mark.parametrize("name, safe", [("cam_01", "cam_01"), ("Cam.2-b", "Cam.2-b"), ("9", "9"),
                                        ("_cam", "_cam"), (".cam", ".cam"), ("-cam", "-cam"), ("cam 1", "cam_1"),
                                        ("cam1\n", "cam1_"), ("\ncam1", "_cam1"), ("kamera/1", "kamera_1"),
                                        ("cämera", "c_mera"), ("a\x00b", "a_b")])
def test_safe_name_keeps_a_folder_name_and_replaces_each_other_character(name, safe):
    from bodystudio.capture.importer import _safe_name

    assert _safe_name(name) == safe


def test_safe_name_keeps_a_name_that_starts_with_an_allowed_but_not_leading_character():
    """'_cam' is not a full match of the folder-name pattern (it must start with a letter or digit), so it goes
    through the substitution, which keeps it as it is: '_', '.', '-' are allowed characters."""
    from bodystudio.capture.importer import _CAMERA_NAME, _safe_name

    assert _CAMERA_NAME.fullmatch("_cam") is None and _CAMERA_NAME.fullmatch("c_a.m-1") is not None
    assert _CAMERA_NAME.fullmatch("cam1\n") is None and _CAMERA_NAME.fullmatch("cam 1") is None
    assert _safe_name("_cam") == "_cam"


def _write_easymocap(folder: Path, names: list[str], width: int = 640) -> tuple[Path, Path]:
    """intri.yml / extri.yml with OpenCV's writer, one entry set per distinct name, ``names`` listed as given."""
    folder.mkdir(parents=True, exist_ok=True)
    K = np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])
    paths = folder / "intri.yml", folder / "extri.yml"
    for path, intri in zip(paths, (True, False), strict=True):
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
        fs.startWriteStruct("names", cv2.FileNode_SEQ)
        for n in names:
            fs.write("", n)
        fs.endWriteStruct()
        for k, n in enumerate(dict.fromkeys(names)):
            if intri:
                fs.write(f"K_{n}", K)
                fs.write(f"dist_{n}", np.zeros((1, 5)))
                fs.write(f"H_{n}", 480)
                fs.write(f"W_{n}", width)
            else:
                fs.write(f"R_{n}", np.zeros((3, 1)))
                fs.write(f"T_{n}", np.array([[0.1 * k], [0.0], [2.0]]))
        fs.release()
    return paths


def test_a_camera_listed_twice_and_two_names_for_one_folder_are_refused_in_one_line(tmp_path):
    from bodystudio.capture.importer import load_easymocap_cameras

    intri, extri = _write_easymocap(tmp_path / "twice", ["cam1", "cam2", "cam1"])
    with pytest.raises(FileFormatError) as err:
        load_easymocap_cameras(intri, extri)
    assert str(err.value) == f"{intri}: camera 'cam1' is listed twice in 'names'; list each camera once"
    # OpenCV's keys take letters, digits, '-', '_' and ' ': 'cam 1' and 'cam_1' are the two names of one folder
    intri, extri = _write_easymocap(tmp_path / "clash", ["cam_1", "cam-a", "cam 1"])
    with pytest.raises(FileFormatError) as err:
        load_easymocap_cameras(intri, extri)
    assert str(err.value) == (f"{intri}: cameras 'cam_1' and 'cam 1' both become 'cam_1' as folder names; rename one "
                              "(letters, digits, _ . -)")
    # distinct folder names: every camera kept under its folder name, with its own calibration
    intri, extri = _write_easymocap(tmp_path / "ok", ["cam 1", "cam-1", "cam2"])
    rig = load_easymocap_cameras(intri, extri)
    assert sorted(rig.cameras) == ["cam-1", "cam2", "cam_1"]
    assert [rig.cameras[n].t[0] for n in ("cam_1", "cam-1", "cam2")] == pytest.approx([0.0, 0.1, 0.2])
    assert all(rig.cameras[n].name == n for n in rig.cameras)


#: The address grammar, written out: PROTOCOL "://" HOST [":" PORT] ["/"], HOST a bracketed IPv6 literal or a run
#: of characters other than whitespace, '/', ':' and ASCII controls, PORT ASCII digits.
_REFERENCE = re.compile(r"(tcp|tls|inproc|ucx|ws|wss)://(\[[0-9A-Fa-f:.]+\]|[^\s/:\x00-\x1f\x7f]+)(:[0-9]+)?/?")


@pytest.mark.parametrize("address, ok", [
    ("tcp://10.0.0.5:8786", True), ("tcp://10.0.0.5", True), ("tcp://host:8786/", True), ("tls://h/", True),
    ("inproc://h", True), ("ucx://h:1", True), ("ws://h:1", True), ("wss://h:1", True), ("tcp://[::1]:8786", True),
    ("tcp://[fe80::1%eth0]:1", False), ("tcp://[::1]", True), ("TCP://h:1", False), ("http://h:1", False),
    ("tcp://h:1//", False), ("tcp://h:١", False), ("tcp://h:", False), ("tcp://:1", False), ("tcp://h\x7f:1", False),
    ("tcp://h\x1f", False), ("tcp://h\t:1", False), ("tcp://a/b:1", False), ("tcp://h:1:2", False),
    (" tcp://h:1", False), ("tcp://h:1\n", False), ("tcp://[::1]x:1", False)])
def test_scheduler_address_grammar(address, ok):
    from bodystudio.batch import _SCHEDULER_ADDRESS, resolve_scheduler

    assert (_REFERENCE.fullmatch(address) is not None) is ok
    assert (_SCHEDULER_ADDRESS.fullmatch(address) is not None) is ok
    if ok:
        assert resolve_scheduler(address, None) == address
    else:
        with pytest.raises(InputError) as err:
            resolve_scheduler(address, None)
        assert str(err.value) == (f"--scheduler {address!r}: not a scheduler address; give tcp://HOST:PORT "
                                  "(e.g. tcp://10.0.0.5:8786)")


def test_local_given_twice_is_refused_after_each_value_is_read():
    from bodystudio.cli.body import parse_assignments

    assert parse_assignments([" a =0.5", "b=-1"], "--local") == {"a": 0.5, "b": -1.0}
    for items in (["a=0.5", "a=0.5"], ["a=1", " a=2"], ["a =1", "b=0", "a=3"]):
        with pytest.raises(InputError) as err:
            parse_assignments(items, "--local")
        assert str(err.value) == "--local a: given twice; give each once"
    # a bad value is refused as not NAME=VALUE before the repeat is noticed; a blank name too
    for item in ("a=x", " =1", "=1", "a"):
        with pytest.raises(InputError) as err:
            parse_assignments(["a=1", item], "--macro")
        assert str(err.value) == (f"--macro {item!r} is not NAME=VALUE with a number, "
                                  "e.g. upperarm-fat-decr-incr=0.5")
    assert parse_assignments(None, "--local") == {} and parse_assignments([], "--local") == {}


def test_reshape_given_twice_by_alias_or_name_is_refused():
    from bodystudio.rig.reshape import parse_reshape

    for text, key in (("mass=1,mass=2", "mass_kg"), ("stature_m=0.1,stature=0.2", "stature_m"),
                      ("mass_kg=1, mass=2", "mass_kg")):
        with pytest.raises(InputError) as err:
            parse_reshape(text)
        assert str(err.value) == f"--reshape {text!r}: {key} is given twice; give each attribute once"
    assert parse_reshape("stature=0.1,mass_kg=-2") == {"stature_m": 0.1, "mass_kg": -2.0}


def test_shape_given_twice_is_refused_sex_too():
    from bodystudio.cli.muscle import _parse_shape

    base = "bmi=20,muscularity=0.3,height_m=1.7,arm_length_m=0.6"
    for text, name in ((base + ",muscularity=0.4", "muscularity"), ("sex=male," + base + ",sex=female", "sex"),
                       (base + ", bmi =21", "bmi")):
        with pytest.raises(InputError) as err:
            _parse_shape(text)
        assert str(err.value) == f"--shape {text!r}: {name} is given twice; give each once"
    shape = _parse_shape("sex=female," + base)
    assert (shape.bmi, shape.muscularity, shape.height_m, shape.arm_length_m) == (20, 0.3, 1.7, 0.6)


def test_resolve_scheduler_workers_bounds_and_both_given(monkeypatch):
    from bodystudio import batch

    monkeypatch.delenv(batch.ENV_SCHEDULER, raising=False)
    assert batch.resolve_scheduler(None, 1) is None and batch.resolve_scheduler(None, None) is None
    monkeypatch.setattr(batch, "max_local_workers", lambda: 2)
    for cores, shown in ((4, 4), (None, 1)):
        monkeypatch.setattr(batch.os, "cpu_count", lambda c=cores: c)
        with pytest.raises(InputError) as err:
            batch.resolve_scheduler(None, 3)
        assert str(err.value) == (f"--workers 3: at most 2 on this machine ({shown} cores; single-threaded workers "
                                  f"beyond {batch.WORKERS_PER_CORE} per core only share them and each holds its own "
                                  "memory); give fewer, or --scheduler for a cluster of several machines")
    assert batch.resolve_scheduler(None, 2) is None
    with pytest.raises(InputError) as err:
        batch.resolve_scheduler("tcp://h:1", 2)
    assert str(err.value) == "--scheduler and --workers: give one (--workers starts a local cluster)"
    # the environment's address with --workers: a local cluster; alone: the address, checked as $BODYSTUDIO_SCHEDULER
    monkeypatch.setenv(batch.ENV_SCHEDULER, "tcp://h:1")
    assert batch.resolve_scheduler(None, 2) is None and batch.resolve_scheduler(None, None) == "tcp://h:1"
    monkeypatch.setenv(batch.ENV_SCHEDULER, "tcp://h:")
    with pytest.raises(InputError) as err:
        batch.resolve_scheduler(None, None)
    assert str(err.value) == (f"${batch.ENV_SCHEDULER} 'tcp://h:': not a scheduler address; give tcp://HOST:PORT "
                              "(e.g. tcp://10.0.0.5:8786)")


def test_local_splits_at_the_first_equals_sign():
    from bodystudio.cli.body import parse_assignments

    with pytest.raises(InputError) as err:
        parse_assignments(["a=b=1"], "--local")
    assert str(err.value) == "--local 'a=b=1' is not NAME=VALUE with a number, e.g. upperarm-fat-decr-incr=0.5"


def test_reshape_refusals_word_for_word():
    from bodystudio.rig.reshape import parse_reshape

    for text, line in (("stature", "--reshape 'stature': expected NAME=DELTA, e.g. stature=+0.05,mass=-5"),
                       ("mass=1=2", "--reshape 'mass=1=2': '1=2' is not a number"),
                       ("mass=x", "--reshape 'mass=x': 'x' is not a number"),
                       (" , ,", "--reshape is empty; e.g. stature=+0.05,mass=-5"),
                       ("", "--reshape is empty; e.g. stature=+0.05,mass=-5")):
        with pytest.raises(InputError) as err:
            parse_reshape(text)
        assert str(err.value) == line
