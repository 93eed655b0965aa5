"""A batch unit's skip / redo decision and its record, pinned without a cluster (mutation round mutV, issue 17).

A re-run of a batch skips a unit only when its committed result is whole and made from the same inputs, and
redoes it otherwise (an interrupted write, other inputs, an edited file). The inputs' checksums decide it:
``options_sha256``, ``chunk_inputs_sha256`` / ``_frame_files`` (a file of another frame does not change a
chunk), ``sequence_inputs_sha256`` and the scan's in ``rig_batch``; ``_run_units`` keeps the record current
and ``task_key`` makes every submission a new dask task. The tests/batch files check all this end to end on a
real LocalCluster (seconds per case); here a stand-in client runs the units in this process, so the whole
file takes under a second.
"""

from __future__ import annotations

import hashlib
import json
import re
import sys
from dataclasses import asdict
from pathlib import Path
from types import SimpleNamespace

import pytest

import bodystudio.batch as batch
from bodystudio import __version__
from bodystudio.batch import (
    MuscleOptions,
    ReconstructOptions,
    _frame_files,
    _run_units,
    _UnitWriter,
    chunk_inputs_sha256,
    options_sha256,
    rig_is_complete,
    sequence_inputs_sha256,
    task_key,
    unit_is_complete,
    unit_layout,
)
from bodystudio.errors import InputError
from bodystudio.fileio import sha256_file
from bodystudio.runfolder import OutputLockedError, RunLayout, RunWriter, acquire_lock


def _sha(text: str | bytes) -> str:
    return hashlib.sha256(text.encode() if isinstance(text, str) else text).hexdigest()


# ---------------------------------------------------------------------------------------------- checksums

def test_options_sha256_is_of_the_sorted_json_with_strings_for_the_rest():
    opts = {"template": "6k", "b": Path("/x/y"), "a": [1, 2]}
    assert options_sha256(opts) == _sha('{"a": [1, 2], "b": "/x/y", "template": "6k"}')
    assert options_sha256(dict(reversed(list(opts.items())))) == options_sha256(opts)


SESSION_FILES = {
    "calibration/cameras.json": "c0",
    "cam0/00000.png": "f0", "cam0/00001.png": "f1", "cam1/00002.png": "f2", "kinect/depth_00003.png": "f3",
    "cam0/background_00001.png": "bg",  # a background image named like a frame belongs to every chunk
    "cam1/background_00000.png": "bg0",
    "frames/00002/meta.json": "dir",  # only the file name is read: this file is of no frame
    "cam0/123456.png": "six",  # six digits: no frame number
    "cam0/00009.png": "f9",  # a number that is no frame of the session: kept
}


def test_frame_files_keeps_a_chunks_frames_and_the_files_of_no_frame():
    keep = _frame_files(SESSION_FILES, [0, 1, 2, 3], [1, 2])
    assert keep == {"calibration/cameras.json": "c0", "cam0/00001.png": "f1", "cam1/00002.png": "f2",
                    "cam0/background_00001.png": "bg", "cam1/background_00000.png": "bg0",
                    "frames/00002/meta.json": "dir", "cam0/123456.png": "six",
                    "cam0/00009.png": "f9"}
    assert "cam0/00000.png" in _frame_files(SESSION_FILES, [0, 1, 2, 3], [0])
    assert _frame_files({"a/00001_00003.png": "x"}, [1, 3], [3]) == {"a/00001_00003.png": "x"}  # one of its frames


def test_chunk_inputs_sha256_is_of_its_files_frames_and_options():
    options = ReconstructOptions(template="2k", params={"outer_iterations": 2}, lengths=(0.5, 0.25))
    keep = _frame_files(SESSION_FILES, [0, 1, 2, 3], [1, 2])
    h = hashlib.sha256(json.dumps(keep, sort_keys=True).encode())
    h.update(json.dumps({"frames": [1, 2], "options": asdict(options)}, sort_keys=True, default=str).encode())
    got = chunk_inputs_sha256(SESSION_FILES, [0, 1, 2, 3], [1, 2], options)
    assert got == h.hexdigest()
    other_frame = {**SESSION_FILES, "cam0/00000.png": "edited"}
    assert chunk_inputs_sha256(other_frame, [0, 1, 2, 3], [1, 2], options) == got  # not this chunk's frame
    for changed in ({**SESSION_FILES, "cam0/00001.png": "edited"}, {**SESSION_FILES, "calibration/cameras.json": "e"}):
        assert chunk_inputs_sha256(changed, [0, 1, 2, 3], [1, 2], options) != got
    assert chunk_inputs_sha256(SESSION_FILES, [0, 1, 2, 3], [1, 2], ReconstructOptions(template="2k")) != got
    # a library caller's Path hashes as its text (the CLI hands strings)
    as_path = ReconstructOptions(joints="file", joints_path=Path("/j"))
    assert chunk_inputs_sha256(SESSION_FILES, [0, 1, 2, 3], [1], as_path) == chunk_inputs_sha256(
        SESSION_FILES, [0, 1, 2, 3], [1], ReconstructOptions(joints="file", joints_path="/j"))


def _session(frame_ids, files):
    return SimpleNamespace(frame_ids=frame_ids, files=files)


def test_sequence_inputs_sha256_of_a_session(monkeypatch, tmp_path):
    import bodystudio.capture.session as cs

    files = {"calibration.json": "c", "kinect/00000.png": "a", "kinect/00001.png": "b", "kinect/00002.png": "z"}
    monkeypatch.setattr(cs, "open_session", lambda p: _session([0, 1, 2], files))
    opts = MuscleOptions(mode="nicp", frames=2)
    fields = asdict(opts)
    del fields["for_extension"]  # units captured before the option keep their hash
    h = hashlib.sha256(json.dumps({"options": fields, "model": "m1", "version": __version__}, sort_keys=True,
                                  default=str).encode())
    h.update(json.dumps({"calibration.json": "c", "kinect/00000.png": "a", "kinect/00001.png": "b"},
                        sort_keys=True).encode())
    got = sequence_inputs_sha256(tmp_path, opts, "m1")
    assert got == h.hexdigest()
    assert sequence_inputs_sha256(tmp_path, opts, "m2") != got
    everything = sequence_inputs_sha256(tmp_path, MuscleOptions(mode="nicp"), "m1")  # frames None: all of them
    fields = asdict(MuscleOptions(mode="nicp"))
    del fields["for_extension"]
    h = hashlib.sha256(json.dumps({"options": fields, "model": "m1", "version": __version__}, sort_keys=True,
                                  default=str).encode())
    h.update(json.dumps(files, sort_keys=True).encode())
    assert everything == h.hexdigest()
    ext = MuscleOptions(mode="nicp", frames=2, for_extension=True)
    h = hashlib.sha256(json.dumps({"options": asdict(ext), "model": "m1", "version": __version__}, sort_keys=True,
                                  default=str).encode())
    h.update(json.dumps({"calibration.json": "c", "kinect/00000.png": "a", "kinect/00001.png": "b"},
                        sort_keys=True).encode())
    assert sequence_inputs_sha256(tmp_path, ext, "m1") == h.hexdigest()
    # the session manifest's file order does not matter; a Path hashes as its text
    monkeypatch.setattr(cs, "open_session", lambda p: _session([0, 1, 2], dict(reversed(list(files.items())))))
    assert sequence_inputs_sha256(tmp_path, opts, "m1") == got
    assert sequence_inputs_sha256(tmp_path, MuscleOptions(model=Path("/m.npz")), None) == sequence_inputs_sha256(
        tmp_path, MuscleOptions(model="/m.npz"), None)


def test_sequence_inputs_sha256_of_an_unreadable_session_hashes_its_error(tmp_path):
    from bodystudio.capture.session import open_session
    from bodystudio.errors import BodyStudioError

    missing = tmp_path / "nope"
    with pytest.raises(BodyStudioError) as err:
        open_session(missing)
    fields = asdict(MuscleOptions())
    del fields["for_extension"]
    h = hashlib.sha256(json.dumps({"options": fields, "model": None, "version": __version__}, sort_keys=True,
                                  default=str).encode())
    h.update(f"unreadable: {err.value}".encode())
    assert sequence_inputs_sha256(missing, MuscleOptions(), None) == h.hexdigest()


def test_task_key_is_readable_and_new_per_submission():
    unit = {"name": "00000-00009", "inputs_sha256": "0123456789abcdef" * 4}
    a, b = task_key("reconstruct", unit), task_key("reconstruct", unit)
    assert re.fullmatch(r"reconstruct-00000-00009-0123456789ab-[0-9a-f]{8}", a) and a != b


# ---------------------------------------------------------------------------------------------- unit_is_complete

def _committed_unit(root: Path, sha: str = "abc", files: dict | None = None) -> RunLayout:
    layout = unit_layout(root)
    with _UnitWriter(layout, "bodystudio reconstruct (batch unit)", {"session": "s"}, {"inputs_sha256": sha}) as w:
        for rel, data in (files or {"meshes/00000.ply": b"ply0", "frames.json": b"{}"}).items():
            w.write_bytes(rel, data)
        w.commit({"frames": [0]})
    return layout


def test_a_whole_unit_with_the_same_inputs_is_skipped_and_any_other_is_redone(tmp_path):
    layout = _committed_unit(tmp_path / "u")
    assert layout == RunLayout(tmp_path / "u", "unit.json", ".", str(tmp_path / "u"))
    manifest = json.loads(layout.manifest_path.read_text())
    assert manifest["unit"] == {"inputs_sha256": "abc"} and manifest["frames"] == [0]
    assert unit_is_complete(layout, "abc")
    assert not unit_is_complete(layout, "other inputs")
    (layout.root / "meshes/00000.ply").write_bytes(b"edited")
    assert not unit_is_complete(layout, "abc")


@pytest.mark.parametrize("damage", ["staging", "record", "no manifest", "list manifest", "no unit", "no run",
                                    "bad json", "writer", "unit not a record"])
def test_an_interrupted_or_foreign_unit_is_redone(tmp_path, damage):
    layout = _committed_unit(tmp_path / "u")
    m = json.loads(layout.manifest_path.read_text())
    if damage == "staging":  # killed before its commit: the previous result is whole, but not of this run
        (layout.staging / "x").parent.mkdir()
        (layout.staging / "x").write_text("x")
    elif damage == "record":  # an unreadable commit record: nothing to finish (a readable one is finished:
        layout.staging.mkdir()  # tests/reliability/test_commit_cleanup_kill.py)
        layout.commit_record.write_text('{"moves": ')
    elif damage == "no manifest":
        layout.manifest_path.unlink()
    elif damage == "list manifest":
        layout.manifest_path.write_text("[]")
    elif damage == "no unit":
        del m["unit"]
        layout.manifest_path.write_text(json.dumps(m))
    elif damage == "unit not a record":  # valid JSON of the wrong shape: redone, not a traceback in the client
        m["unit"] = "abc"
        layout.manifest_path.write_text(json.dumps(m))
    elif damage == "no run":
        del m["run"]
        layout.manifest_path.write_text(json.dumps(m))
    elif damage == "bad json":
        layout.manifest_path.write_text("{")
    elif damage == "writer":
        import os
        import socket

        from bodystudio.runfolder import _process_start

        layout.lock.write_text(json.dumps({"pid": os.getppid(), "host": socket.gethostname(),
                                           "start": _process_start(os.getppid()), "command": "w", "since": "now"}))
    assert not unit_is_complete(layout, "abc")


# ---------------------------------------------------------------------------------------------- rig_is_complete

def _rig(out: Path, sha: str = "s1", run_id: str | None = None) -> Path:
    from bodystudio.rig.export import rig_layout

    glb = out / "a.glb"
    with RunWriter(rig_layout(glb), "bodystudio rig") as w:
        w.write_bytes(glb, b"glTF")
        manifest = w.commit({"kind": "rig"})
    (out / ".batch").mkdir(exist_ok=True)
    (out / ".batch" / "a.json").write_text(json.dumps({"inputs_sha256": sha, "run_id": run_id or
                                                       manifest["run"]["run_id"]}))
    return glb


def test_rig_is_complete(tmp_path):
    from bodystudio.rig.export import rig_layout

    glb = _rig(tmp_path)
    assert rig_is_complete(glb, "s1")
    assert not rig_is_complete(glb, "s2")
    glb.write_bytes(b"edited")
    assert not rig_is_complete(glb, "s1")
    glb = _rig(tmp_path / "b", run_id="another run")  # the unit record of an earlier rig
    assert not rig_is_complete(glb, "s1")
    glb = _rig(tmp_path / "c")
    rig_layout(glb).staging.mkdir()
    assert not rig_is_complete(glb, "s1")
    glb = _rig(tmp_path / "d")
    (tmp_path / "d" / ".batch" / "a.json").unlink()
    assert not rig_is_complete(glb, "s1")
    glb = _rig(tmp_path / "e")
    rig_layout(glb).manifest_path.unlink()
    assert not rig_is_complete(glb, "s1")
    for bad in ("[]", '{"run": []}', '{"kind": 1}'):
        glb = _rig(tmp_path / "f")
        rig_layout(glb).manifest_path.write_text(bad)
        assert not rig_is_complete(glb, "s1")


# ---------------------------------------------------------------------------------------------- _run_units

class _Future:
    def __init__(self, unit, outcome):
        self.unit, self.outcome = unit, outcome

    def result(self):
        if isinstance(self.outcome, BaseException):
            raise self.outcome
        return self.outcome


class _Bar:
    def __init__(self, log):
        self.log = log

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    def add_task(self, describe, total, completed):
        self.log.append(("add", describe, total, completed))
        return 7

    def advance(self, task):
        self.log.append(("advance", task))


@pytest.fixture
def stand_in(monkeypatch):
    """A client whose submissions finish in this process; the record read back after every unit."""
    import distributed

    import bodystudio.capture.session as cs

    state = SimpleNamespace(submitted=[], snapshots=[], bar=[], record=None)
    client = SimpleNamespace(loop=object(), dashboard_link="http://dash")

    def as_completed(futures, loop=None):
        assert loop is client.loop
        state.snapshots.append(json.loads(state.record.read_text()))  # written before the first result
        for f in futures:
            yield f
            state.snapshots.append(json.loads(state.record.read_text()))  # ... and after each

    monkeypatch.setattr(distributed, "as_completed", as_completed)
    monkeypatch.setattr(cs, "progress_bar",
                        lambda enabled: (state.bar.append(("enabled", enabled)), _Bar(state.bar))[1])
    state.client = client
    return state


def _units(outcomes: dict, complete: set):
    return [{"name": name, "inputs_sha256": f"sha-{name}", "frames": [1, 2], "output": f"/o/{name}",
             "root": Path("/o") / name, "options": "not recorded", "complete": (lambda n=name: n in complete),
             "outcome": outcome} for name, outcome in outcomes.items()]


def _go(stand_in, tmp_path, units, force=False, previous=None, progress=False):
    stand_in.record = tmp_path / "record.json"

    def submit(unit):
        f = _Future(unit, unit["outcome"])
        stand_in.submitted.append(unit["name"])
        return f

    return _run_units(stand_in.client, units, submit, stand_in.record, force, progress, "doing", previous or {})


TIME = re.compile(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\dZ")


def _no_time(entry: dict) -> dict:
    assert TIME.fullmatch(entry["time"]), entry
    return {k: v for k, v in entry.items() if k != "time"}


def test_run_units_skips_complete_units_and_records_every_outcome(stand_in, tmp_path, caplog, monkeypatch):
    import time

    previous = {"a": {"status": "failed", "error": "old error", "seconds": 3.5, "note": "kept"},
                "c": {"status": "done", "seconds": 9.0, "note": "of an earlier run"},
                "gone": {"status": "done", "inputs_sha256": "x"}}
    units = _units({"a": {"seconds": 1.0}, "b": {"seconds": 2.25}, "c": InputError("bad scan\nsecond line"),
                    "d": ValueError("boom\nmore"), "e": RuntimeError()}, complete={"a"})
    units[1].update(scan="/s/b.ply", session="/s/b")
    monkeypatch.setenv("TZ", "Asia/Kolkata")  # the record's times are UTC whatever the time zone
    time.tzset()
    try:
        t0 = time.perf_counter()
        with caplog.at_level("WARNING", logger="bodystudio.batch"):
            report = _go(stand_in, tmp_path, units, previous=previous, progress=True)
        took = time.perf_counter() - t0
    finally:
        monkeypatch.delenv("TZ")
        time.tzset()
    assert caplog.messages == ["c failed: bad scan\\nsecond line", "d failed: ValueError: boom",
                               "e failed: RuntimeError: RuntimeError"]
    now = time.gmtime()
    for entry in json.loads(stand_in.record.read_text())["units"].values():
        if "time" in entry:
            t = time.strptime(entry["time"], "%Y-%m-%dT%H:%M:%SZ")
            assert abs((t.tm_hour * 60 + t.tm_min) - (now.tm_hour * 60 + now.tm_min)) % (24 * 60) <= 2
    assert stand_in.submitted == ["b", "c", "d", "e"]
    assert report.status == {"a": "skipped", "b": "done", "c": "failed", "d": "failed", "e": "failed"}
    # a BodyStudioError is one line by construction (its line breaks shown as \\n), without its type's name
    assert report.errors == {"c": "bad scan\\nsecond line", "d": "ValueError: boom", "e": "RuntimeError: RuntimeError"}
    assert report.seconds == {"b": 2.25} and report.record == stand_in.record and report.dashboard == "http://dash"
    assert 0 < report.wall_s <= took
    record = json.loads(stand_in.record.read_text())
    assert record["version"] == __version__ and list(record["units"]) == ["a", "c", "gone", "b", "d", "e"]
    units_rec = {k: _no_time(v) if k != "gone" else v for k, v in record["units"].items()}
    base = {"frames": [1, 2], "output": "/o/{}", "inputs_sha256": "sha-{}"}

    def entry(name, **kw):
        return {**{k: (v.format(name) if isinstance(v, str) else v) for k, v in base.items()}, **kw}

    assert units_rec == {
        # a skipped unit keeps what the record said of it (its time), never an old error
        "a": {"seconds": 3.5, "note": "kept", **entry("a"), "status": "done", "action": "skipped"},
        "gone": {"status": "done", "inputs_sha256": "x"},
        "b": entry("b", status="done", action="computed", seconds=2.25, scan="/s/b.ply", session="/s/b"),
        "c": entry("c", status="failed", action="failed", error="bad scan\\nsecond line"),
        "d": entry("d", status="failed", action="failed", error="ValueError: boom"),
        "e": entry("e", status="failed", action="failed", error="RuntimeError: RuntimeError"),
    }
    # the record is on disk before the first result (the skipped units, the previous ones) and after each
    assert [list(s["units"]) for s in stand_in.snapshots] == [
        ["a", "c", "gone"], ["a", "c", "gone", "b"], ["a", "c", "gone", "b"], ["a", "c", "gone", "b", "d"],
        ["a", "c", "gone", "b", "d", "e"]]
    assert stand_in.snapshots[2]["units"]["c"]["status"] == "failed"  # written as it failed
    assert stand_in.bar == [("enabled", True), ("add", "doing", 5, 1)] + [("advance", 7)] * 4


def test_run_units_force_redoes_complete_units(stand_in, tmp_path):
    units = _units({"a": {"seconds": 1.0}, "b": {"seconds": 1.5}}, complete={"a", "b"})
    report = _go(stand_in, tmp_path, units, force=True)
    assert stand_in.submitted == ["a", "b"] and report.status == {"a": "done", "b": "done"}
    assert stand_in.bar == [("enabled", False), ("add", "doing", 2, 0), ("advance", 7), ("advance", 7)]
    rec = json.loads(stand_in.record.read_text())["units"]
    assert [rec[n]["action"] for n in "ab"] == ["computed", "computed"]


def test_a_unit_that_now_completes_forgets_its_earlier_error(stand_in, tmp_path):
    previous = {"a": {"status": "failed", "action": "failed", "error": "was bad", "inputs_sha256": "sha-a"}}
    report = _go(stand_in, tmp_path, _units({"a": {"seconds": 4.0}}, complete=set()), previous=previous)
    rec = _no_time(json.loads(stand_in.record.read_text())["units"]["a"])
    assert rec == {"frames": [1, 2], "output": "/o/a", "inputs_sha256": "sha-a", "status": "done",
                   "action": "computed", "seconds": 4.0}
    assert report.status == {"a": "done"} and not report.errors


def test_all_skipped_writes_the_record_once_and_submits_nothing(stand_in, tmp_path):
    units = _units({"a": None, "b": None}, complete={"a", "b"})
    report = _go(stand_in, tmp_path, units)
    assert stand_in.submitted == [] and report.status == {"a": "skipped", "b": "skipped"}
    rec = json.loads(stand_in.record.read_text())["units"]
    assert [_no_time(rec[n])["action"] for n in "ab"] == ["skipped", "skipped"]
    assert "seconds" not in rec["a"] and "error" not in rec["a"]


def test_rig_batch_hashes_each_scan_with_its_options_and_skips_a_complete_rig(stand_in, tmp_path, monkeypatch):
    scans = tmp_path / "scans"
    scans.mkdir()
    (scans / "a.ply").write_bytes(b"ply a")
    (scans / "b.obj").write_bytes(b"obj b")
    out = tmp_path / "out"
    stand_in.record = out / "batch.json"
    calls = []

    def submit(fn, *args, key, pure):
        calls.append((fn.__name__, args, key, pure))
        holder = json.loads((out / ".batch.lock").read_text())  # the client holds the output's lock meanwhile
        assert holder["command"] == "bodystudio batch rig"
        with pytest.raises(OutputLockedError) as err:  # ... so a second batch is refused, naming the folder
            acquire_lock(RunLayout(out, "batch.json", ".batch.", str(out)), "second")
        assert str(err.value).startswith(f"{out}: being written by pid ")
        return _Future(None, {"seconds": 0.5})

    stand_in.client.submit = submit
    opts = options_sha256({"template": "2k", "version": __version__})
    sha = {s: _sha(sha256_file(scans / s) + opts) for s in ("a.ply", "b.obj")}
    _rig(out, sha=sha["a.ply"])  # a.glb of an earlier run of the same inputs
    report = batch.rig_batch(scans, out, stand_in.client, template="2k", setup=print)
    assert report.status == {"a.ply": "skipped", "b.obj": "done"}
    assert [(c[0], c[1], c[3]) for c in calls] == [("rig_unit", (str(scans / "b.obj"), str(out / "b.glb"), "2k",
                                                                 sha["b.obj"], print), False)]
    assert re.fullmatch(rf"rig-b\.obj-{sha['b.obj'][:12]}-[0-9a-f]{{8}}", calls[0][2])
    rec = json.loads((out / "batch.json").read_text())["units"]
    assert {n: (e["inputs_sha256"], e["scan"], e["output"]) for n, e in rec.items()} == {
        "a.ply": (sha["a.ply"], str(scans / "a.ply"), str(out / "a.glb")),
        "b.obj": (sha["b.obj"], str(scans / "b.obj"), str(out / "b.glb"))}
    assert sorted(p.name for p in out.iterdir()) == [".batch", "a.glb", "a.rig.json", "batch.json"]
    assert stand_in.bar == [("enabled", False), ("add", "rig 2 scans", 2, 1), ("advance", 7)]
    with pytest.raises(InputError, match="--template '4k': use 6k, 13k or 2k"):
        batch.rig_batch(scans, out, stand_in.client, template="4k")
    import os
    import socket

    from bodystudio.runfolder import _process_start

    (out / ".batch.lock").write_text(json.dumps({"pid": os.getppid(), "host": socket.gethostname(), "command": "w",
                                                 "start": _process_start(os.getppid()), "since": "now"}))
    with pytest.raises(OutputLockedError, match=f"^{out}: being written by pid {os.getppid()} "):
        batch.rig_batch(scans, out, stand_in.client, template="2k")  # another batch writes this folder
    (out / ".batch.lock").unlink()
    with pytest.raises(InputError, match=f"^--out {scans / 'a.ply'}: exists and is a file"):
        batch.rig_batch(scans, scans / "a.ply", stand_in.client)
    for template in ("6k", "13k", None):  # the valid ones, and the default 6k
        calls.clear()
        kw = {} if template is None else {"template": template}
        stand_in.record = tmp_path / f"o{template}" / "batch.json"
        out = tmp_path / f"o{template}"
        batch.rig_batch(scans, out, stand_in.client, **kw)
        opts = options_sha256({"template": template or "6k", "version": __version__})
        assert [c[1][2:4] for c in calls] == [(template or "6k", _sha(sha256_file(scans / s) + opts))
                                              for s in ("a.ply", "b.obj")]


def test_load_record_reads_the_units_of_a_record_and_nothing_else(tmp_path):
    p = tmp_path / "batch.json"
    assert batch._load_record(p) == {}  # no record yet
    for bad in ("{", "[]", '{"units": []}', '{"version": "0"}', '"x"'):
        p.write_text(bad)
        assert batch._load_record(p) == {}, bad
    p.write_text('{"version": "0", "units": {"a": {"status": "done"}}}')
    assert batch._load_record(p) == {"a": {"status": "done"}}


def test_unit_writer_records_the_unit_in_its_manifest(tmp_path):
    layout = unit_layout(tmp_path / "u")
    w = _UnitWriter(layout, "cmd", {"session": "s"}, {"inputs_sha256": "abc", "frames": [3]})
    assert w.unit == {"inputs_sha256": "abc", "frames": [3]} and w.producer == {"session": "s"}
    w.write_bytes("old.txt", b"x")
    first = w.commit({"k": 1})
    assert first["run"]["command"] == "cmd"
    assert layout.manifest_path.read_bytes() == (json.dumps(first, indent=2) + "\n").encode()
    w = _UnitWriter(layout, "cmd", {}, {"inputs_sha256": "def"})
    w.write_bytes("new.txt", b"y")
    manifest = w.commit({"k": 2}, deletes=["old.txt"], indent=4)
    assert manifest["unit"] == {"inputs_sha256": "def"} and manifest["k"] == 2
    assert layout.manifest_path.read_bytes() == (json.dumps(manifest, indent=4) + "\n").encode()
    assert not (layout.root / "old.txt").exists() and unit_is_complete(layout, "def")


if __name__ == "__main__":
    sys.exit(pytest.main([__file__, "-q"]))
