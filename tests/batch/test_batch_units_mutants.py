"""The batch's chunking, client set-up, work units and assembly, pinned without a cluster (mutation round mutFF,
issue 17).

A batch result must be the single-process run's: every selected frame in exactly one chunk, each chunk handed the
run's options (bone lengths, subject, constraints), the chunks' meshes and records published as one run, a failed
chunk refusing the assembly, and a re-run skipping only the whole units. tests/batch checks this end to end on a
real LocalCluster (seconds per case); here a stand-in client runs each submission at once in this process and the
worker-side steps (``reconstruct_frames``, the arm capture, the rig) are stand-ins that write known files, so the
batch's own code is checked against hand-written expectations. The whole file takes about a second.
"""

from __future__ import annotations

import json
import os
import re
from pathlib import Path
from types import SimpleNamespace

import pytest

import bodystudio.batch as batch
from bodystudio.batch import (
    BatchError,
    BatchReport,
    MuscleOptions,
    ReconstructOptions,
    check_capture_sessions,
    check_worker_versions,
    chunk_frames,
    chunk_inputs_sha256,
    chunk_name,
    list_scans,
    max_local_workers,
    resolve_scheduler,
    sequence_inputs_sha256,
    unit_is_complete,
    unit_layout,
)
from bodystudio.errors import InputError
from bodystudio.runfolder import OutputLockedError, RunWriter

# ---------------------------------------------------------------------------------------------- small pieces


def test_chunk_frames_covers_every_frame_once_in_order():
    frames = [3, 4, 5, 8, 9, 11, 12]
    assert chunk_frames(frames, 3) == [[3, 4, 5], [8, 9, 11], [12]]
    assert chunk_frames(frames, 1) == [[f] for f in frames]
    assert chunk_frames(frames, 7) == [frames] and chunk_frames(frames, 100) == [frames]
    assert chunk_frames([], 2) == []
    for chunk in range(1, 9):  # brute force: concatenated, the chunks are the frames; all but the last full
        got = chunk_frames(frames, chunk)
        assert [f for c in got for f in c] == frames
        assert all(len(c) == chunk for c in got[:-1]) and 1 <= len(got[-1]) <= chunk
    for bad in (0, -2):
        with pytest.raises(InputError) as err:
            chunk_frames(frames, bad)
        assert str(err.value) == f"--chunk {bad}: give at least 1 frame per work unit"


def test_chunk_name_is_its_first_and_last_frame():
    assert chunk_name([7, 8, 123]) == "00007-00123"
    assert chunk_name([42]) == "00042-00042"


def test_batch_report_counts_and_names_the_first_failure(tmp_path):
    report = BatchReport(status={"a": "done", "b": "failed", "c": "skipped", "d": "failed", "e": "done"},
                         errors={"b": "bad scan", "d": "other"}, record=tmp_path / "batch.json")
    assert [report.count(s) for s in ("done", "failed", "skipped", "computed")] == [2, 2, 1, 0]
    assert report.failure_message("scans") == (f"2 of 5 scans failed (errors in {tmp_path / 'batch.json'}); "
                                               "first: b: bad scan")
    assert BatchReport().wall_s == 0.0 and BatchReport().record is None and BatchReport().dashboard is None


def test_worker_versions_other_than_the_clients_are_refused_in_one_line():
    check_worker_versions({"tcp://a:1": "1.0", "tcp://b:2": "1.0"}, local="1.0")
    check_worker_versions({})
    with pytest.raises(InputError) as err:
        check_worker_versions({"tcp://a:1": "1.0", "tcp://b:2": "0.9", "tcp://c:3": "0.8"}, local="1.0")
    assert str(err.value) == ("--scheduler: 2 of 3 workers run bodystudio 0.9 (e.g. tcp://b:2) but this client "
                              "runs 1.0; install the same version on every worker")
    assert batch._worker_version() == batch.__version__


def test_local_worker_cap_is_four_per_core(monkeypatch):
    monkeypatch.setattr(os, "cpu_count", lambda: 3)
    assert max_local_workers() == 12
    monkeypatch.setattr(os, "cpu_count", lambda: None)  # unknown: one core
    assert max_local_workers() == 4
    with pytest.raises(InputError, match=r"^--workers 5: at most 4 on this machine \(1 cores; "):
        resolve_scheduler(None, 5)


def test_resolve_scheduler(monkeypatch):
    monkeypatch.setattr(os, "cpu_count", lambda: 2)
    monkeypatch.delenv(batch.ENV_SCHEDULER, raising=False)
    assert resolve_scheduler(None, None) is None
    assert resolve_scheduler(None, 1) is None and resolve_scheduler(None, 8) is None  # 1 .. the cap
    with pytest.raises(InputError) as err:
        resolve_scheduler(None, 9)
    assert str(err.value) == ("--workers 9: at most 8 on this machine (2 cores; single-threaded workers beyond 4 per "
                              "core only share them and each holds its own memory); give fewer, or --scheduler for "
                              "a cluster of several machines")
    with pytest.raises(InputError) as err:
        resolve_scheduler(None, 0)
    assert str(err.value) == "--workers 0: give at least 1 worker process (default: one per core)"
    for good in ("tcp://10.0.0.5:8786", "tls://host", "inproc://x/", "ucx://h:1", "ws://h:2", "wss://h"):
        assert resolve_scheduler(good, None) == good
    for bad in ("10.0.0.5:8786", "tcp://a b:1", "http://h:1", "tcp://h:1/x", "xtcp://h:1"):
        with pytest.raises(InputError) as err:
            resolve_scheduler(bad, None)
        assert str(err.value) == (f"--scheduler {bad!r}: not a scheduler address; give tcp://HOST:PORT "
                                  "(e.g. tcp://10.0.0.5:8786)")
    with pytest.raises(InputError) as err:
        resolve_scheduler("tcp://h:1", 2)
    assert str(err.value) == "--scheduler and --workers: give one (--workers starts a local cluster)"
    monkeypatch.setenv(batch.ENV_SCHEDULER, "tcp://env:1")
    assert resolve_scheduler(None, None) == "tcp://env:1"
    assert resolve_scheduler(None, 2) is None  # --workers asks for a local cluster over the variable
    assert resolve_scheduler("tcp://cli:2", None) == "tcp://cli:2"  # the option over the variable
    monkeypatch.setenv(batch.ENV_SCHEDULER, "env:1")
    with pytest.raises(InputError) as err:
        resolve_scheduler(None, None)
    assert str(err.value).startswith(f"${batch.ENV_SCHEDULER} 'env:1': not a scheduler address")
    monkeypatch.setenv(batch.ENV_SCHEDULER, "")
    assert resolve_scheduler(None, None) is None  # an empty variable is no address


def test_dashboard_link_or_none():
    assert batch.dashboard_link(SimpleNamespace(dashboard_link="http://h:8787/status")) == "http://h:8787/status"

    class NoDashboard:
        @property
        def dashboard_link(self):
            raise KeyError("bokeh")

    assert batch.dashboard_link(NoDashboard()) is None


def test_unit_layout_and_rig_unit_record(tmp_path):
    layout = unit_layout(tmp_path / "u")
    assert (layout.root, layout.manifest_path, layout.name) == (tmp_path / "u", tmp_path / "u" / "unit.json",
                                                                str(tmp_path / "u"))
    assert layout.staging.parent == tmp_path / "u"
    assert batch._rig_unit_record(tmp_path / "o" / "bob.glb") == tmp_path / "o" / ".batch" / "bob.json"


def test_list_scans(tmp_path):
    scans = tmp_path / "scans"
    scans.mkdir()
    for name in ("b.PLY", "a.obj", "c.glb", "d.gltf", "e.stl", "notes.txt", "f.ply.bak"):
        (scans / name).write_bytes(b"x")
    (scans / "sub.ply").mkdir()  # a folder named like a scan is no scan
    assert list_scans(str(scans)) == [scans / n for n in ("a.obj", "b.PLY", "c.glb", "d.gltf", "e.stl")]
    with pytest.raises(InputError) as err:
        list_scans(tmp_path / "nope")
    assert str(err.value) == f"{tmp_path / 'nope'}: no such folder of scans"
    (tmp_path / "file").write_bytes(b"")
    with pytest.raises(InputError, match="no such folder of scans"):
        list_scans(tmp_path / "file")
    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / "x.txt").write_bytes(b"")
    with pytest.raises(InputError) as err:
        list_scans(empty)
    assert str(err.value) == f"{empty}: no scan files (.ply, .obj, .glb, .gltf, .stl) in this folder"
    (scans / "a.stl").write_bytes(b"x")
    with pytest.raises(InputError) as err:
        list_scans(scans)
    assert str(err.value) == f"{scans}: a.obj and a.stl would both write a.glb; rename one"


def test_check_capture_sessions(tmp_path):
    for n in ("x/s1", "y/s2", "z/s1"):
        (tmp_path / n).mkdir(parents=True)
    got = check_capture_sessions([str(tmp_path / "x/s1"), tmp_path / "y/s2"])
    assert got == [tmp_path / "x/s1", tmp_path / "y/s2"] and all(isinstance(p, Path) for p in got)
    with pytest.raises(InputError) as err:
        check_capture_sessions([tmp_path / "x/s1", tmp_path / "z/s1"])
    assert str(err.value) == f"{tmp_path / 'x/s1'} and {tmp_path / 'z/s1'} would both write s1/ in --out; rename one"
    with pytest.raises(InputError) as err:
        check_capture_sessions([tmp_path / "x/s1", tmp_path / "nope"])
    assert str(err.value) == (f"{tmp_path / 'nope'}: no such session folder; give Kinect session folders "
                              "(bodystudio synth arm)")


# ---------------------------------------------------------------------------------------------- stand-in client

class _Future:
    def __init__(self, outcome):
        self.outcome = outcome

    def result(self):
        if isinstance(self.outcome, BaseException):
            raise self.outcome
        return self.outcome


class _Bar:
    def __init__(self, log, enabled):
        self.log = log
        log.append(("enabled", enabled))

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    def add_task(self, describe, **k):
        self.log.append(("describe", describe))
        return 0

    def advance(self, task):
        pass


@pytest.fixture
def client(monkeypatch):
    """A client whose submissions run at once in this process (the worker's function called with the arguments
    the batch hands dask); ``calls`` keeps (function name, args, key, pure)."""
    import distributed

    import bodystudio.capture.session as cs

    monkeypatch.setattr(distributed, "as_completed", lambda futures, loop=None: iter(futures))
    bars = []
    monkeypatch.setattr(cs, "progress_bar", lambda enabled: _Bar(bars, enabled))
    calls = []

    def submit(fn, *args, key, pure):
        calls.append((fn.__name__, args, key, pure))
        try:
            return _Future(fn(*args))
        except Exception as exc:  # noqa: BLE001 - a failing unit, as dask hands it back
            return _Future(exc)

    return SimpleNamespace(loop=None, dashboard_link=None, submit=submit, calls=calls, bars=bars)


# ---------------------------------------------------------------------------------------------- reconstruction

FRAMES = [0, 1, 2, 3, 4, 5, 6]
PLAYERS = {0: 7, 1: 7, 2: 7, 3: 9, 4: 9, 5: 9, 6: 9}  # the tracker renamed the subject at frame 3


def _files(frames=FRAMES):
    return {"calibration/cameras.json": "c", **{f"cam0/{f:05d}.png": f"img{f}" for f in frames}}


@pytest.fixture
def studio(monkeypatch, tmp_path):
    """A stand-in session and Rapid Skin (``reconstruct_frames`` writes ``mesh F`` per frame and a record)."""
    import bodystudio.capture.session as cs
    import bodystudio.reconstruct.sequence as seq

    path = tmp_path / "s"
    path.mkdir()
    state = SimpleNamespace(path=path, files=_files(), kinect="kinect-calibration", chunks=[], judged=[],
                            fail_frame=None, subject_calls=[], length_calls=[], frame_ids=list(FRAMES),
                            locks=[])

    def open_session(p):
        assert Path(p) == path
        return SimpleNamespace(path=Path(p), frame_ids=list(state.frame_ids), files=dict(state.files),
                               cameras=("C0", "C1"), kinect=state.kinect)

    def run_subject(session, selected, joints, player=None):
        assert session.path == path  # the opened session
        state.subject_calls.append((list(selected), joints, player))
        return {f: PLAYERS.get(f, 9) for f in selected} if joints == "tracker" else None

    def run_bone_lengths(session, selected, joints, joints_path, subject=None):
        assert session.path == path
        state.length_calls.append((list(selected), joints, joints_path, subject))
        return [0.5, 0.25]

    def reconstruct_frames(session, writer, selected, cameras, sensor, params, solver, template, joints,
                           joints_path, warm_start, refine_pose, score, accept_implausible, bone_lengths, subject):
        from bodystudio.reconstruct.sequence import reconstruction_layout

        assert session.path == path
        lock = reconstruction_layout(path).lock  # the client holds the run's lock while the chunks run
        state.locks.append(json.loads(lock.read_text())["command"] if lock.is_file() else None)
        state.chunks.append({"frames": selected, "cameras": cameras, "sensor": sensor, "params": params,
                             "solver": solver, "template": template, "joints": joints, "joints_path": joints_path,
                             "warm_start": warm_start, "refine_pose": refine_pose, "score": score,
                             "accept": accept_implausible, "bone_lengths": bone_lengths, "subject": subject})
        if state.fail_frame in selected:
            raise InputError(f"frame {state.fail_frame}: no silhouette")
        for f in selected:
            writer.write_bytes(f"meshes/{f:05d}.ply", f"mesh {f}".encode())
        writer.write_json("frames.json", {"frames": [{"frame": f, "plausibility": {"f": f}} for f in selected]})
        writer.commit({"constraints": list(params.constraints), "params": {"first": selected[0]},
                       "n_vertices": 1000 + selected[0]})

    def judge_run(records, session_path, accept_implausible):
        state.judged.append(([r["frame"] for r in records], Path(session_path), accept_implausible))
        return {"ok": True, "judged": len(records)}

    monkeypatch.setattr(cs, "open_session", open_session)
    monkeypatch.setattr(seq, "run_subject", run_subject)
    monkeypatch.setattr(seq, "run_bone_lengths", run_bone_lengths)
    monkeypatch.setattr(seq, "reconstruct_frames", reconstruct_frames)
    monkeypatch.setattr(seq, "judge_run", judge_run)
    monkeypatch.setattr(seq, "summarize", lambda records: {"frames": [r["frame"] for r in records]})
    return state


def _options(**kw):
    return ReconstructOptions(template="2k", params={"outer_iterations": 3, "constraints": ["silhouette", "depth"]},
                              **kw)


def test_reconstruct_batch_publishes_the_chunks_as_the_single_run(studio, client):
    run_dir = studio.path / "reconstruct"
    (run_dir / "meshes").mkdir(parents=True)
    (run_dir / "meshes" / "00099.ply").write_bytes(b"an earlier run's frame")  # not in this run: deleted
    summary, report = batch.reconstruct_batch(studio.path, client, _options(warm_start=True), frames="1:7", chunk=4,
                                              accept_implausible=True, player=9)
    selected = [1, 2, 3, 4, 5, 6]
    assert summary == {"frames": selected}
    assert report.status == {"00001-00004": "done", "00005-00006": "done"} and not report.errors
    assert studio.subject_calls == [(selected, "tracker", 9)]
    assert studio.length_calls == [(selected, "tracker", None, {f: PLAYERS[f] for f in selected})]
    lengths = (0.5, 0.25)
    # every chunk got the run's options: its frames, both cameras, the Kinect, the lengths of the whole run
    from bodystudio.reconstruct.rapid_skin import RapidSkinParams

    params = RapidSkinParams(outer_iterations=3, constraints=("silhouette", "depth"))
    for c, frames in zip(studio.chunks, ([1, 2, 3, 4], [5, 6]), strict=True):
        assert c == {"frames": frames, "cameras": ["C0", "C1"], "sensor": "kinect-calibration", "params": params,
                     "solver": "gs", "template": "2k", "joints": "tracker", "joints_path": None,
                     "warm_start": True, "refine_pose": True, "score": True, "accept": False,
                     "bone_lengths": lengths, "subject": {f: PLAYERS[f] for f in frames}}
    opts = _options(warm_start=True, lengths=lengths)
    for (name, args, key, pure), frames in zip(client.calls, ([1, 2, 3, 4], [5, 6]), strict=True):
        sha = chunk_inputs_sha256(_files(), FRAMES, frames, opts, [[f, PLAYERS[f]] for f in frames])
        root = run_dir / "chunks" / chunk_name(frames)
        assert (name, pure) == ("reconstruct_chunk", False)
        assert args == (str(studio.path), frames, opts, str(root), sha, [[f, PLAYERS[f]] for f in frames])
        assert re.fullmatch(rf"reconstruct-{chunk_name(frames)}-{sha[:12]}-[0-9a-f]{{8}}", key)
        unit = json.loads((root / "unit.json").read_text())["unit"]
        assert unit == {"inputs_sha256": sha, "frames": frames, "pid": os.getpid()}
        assert unit_is_complete(unit_layout(root), sha)
    # the published run: every frame's mesh once, the records in frame order, run.json as the sequential run's
    assert sorted(p.name for p in (run_dir / "meshes").iterdir()) == [f"{f:05d}.ply" for f in selected]
    assert all((run_dir / f"meshes/{f:05d}.ply").read_bytes() == f"mesh {f}".encode() for f in selected)
    records = json.loads((run_dir / "frames.json").read_text())["frames"]
    assert [r["frame"] for r in records] == selected
    assert studio.judged == [(selected, studio.path, True)]
    run = json.loads((run_dir / "run.json").read_text())
    assert {k: v for k, v in run.items() if k not in ("run", "plausibility")} == {
        "solver": "gs", "template": "2k", "joints": "tracker", "constraints": ["silhouette", "depth"],
        "frames": selected, "warm_start": True, "refine_pose": True, "bone_lengths": "sequence",
        "params": {"first": 1}, "n_vertices": 1001, "subject_player": 7,
        "subject_players": {str(f): PLAYERS[f] for f in selected},
        "batch": {"chunk": 4, "units": ["00001-00004", "00005-00006"]}}
    assert run["plausibility"] == {"ok": True, "judged": 6}
    assert run["run"]["command"] == "bodystudio reconstruct (batch)" and run["run"]["producer"] == {"template": "2k"}
    assert sorted(run["run"]["files"]) == ["frames.json"] + [f"meshes/{f:05d}.ply" for f in selected]
    assert not (run_dir / ".lock").exists() and not list(run_dir.glob(".*staging*"))
    assert studio.locks == ["bodystudio reconstruct (batch)"] * 2
    assert client.bars == [("enabled", False), ("describe", "rapid skin gs 2k (chunks of 4)")]
    rec = json.loads((run_dir / "chunks" / "record.json").read_text())["units"]
    assert {n: (e["output"], e["frames"]) for n, e in rec.items()} == {
        "00001-00004": (str(run_dir / "chunks" / "00001-00004"), [1, 2, 3, 4]),
        "00005-00006": (str(run_dir / "chunks" / "00005-00006"), [5, 6])}

    # a re-run of the same command skips both chunks; a changed frame redoes its chunk only
    client.calls.clear()
    _, report = batch.reconstruct_batch(studio.path, client, _options(warm_start=True), frames="1:7", chunk=4,
                                        player=9)
    assert report.status == {"00001-00004": "skipped", "00005-00006": "skipped"} and client.calls == []
    studio.files["cam0/00005.png"] = "edited"
    _, report = batch.reconstruct_batch(studio.path, client, _options(warm_start=True), frames="1:7", chunk=4,
                                        player=9)
    assert report.status == {"00001-00004": "skipped", "00005-00006": "done"}
    assert [c[1][1] for c in client.calls] == [[5, 6]]
    client.calls.clear()
    batch.reconstruct_batch(studio.path, client, _options(warm_start=True), frames="1:7", chunk=4, force=True,
                            player=9)
    assert [c[1][1] for c in client.calls] == [[1, 2, 3, 4], [5, 6]]


def test_reconstruct_batch_without_the_tracker_or_the_sequence_lengths(studio, client):
    studio.kinect = None
    opts = ReconstructOptions(template="2k", joints="file", joints_path="/j", bone_lengths="frame",
                              refine_pose=False, score=False, solver="jacobi")
    summary, _ = batch.reconstruct_batch(studio.path, client, opts, chunk=3, progress=True)
    assert summary == {"frames": FRAMES} and studio.length_calls == []
    assert studio.judged[0][2] is False and client.bars[0] == ("enabled", True)
    assert [c["frames"] for c in studio.chunks] == [[0, 1, 2], [3, 4, 5], [6]]
    assert {(c["subject"], c["bone_lengths"], c["joints_path"], c["sensor"], c["refine_pose"], c["score"],
             c["solver"], c["params"].constraints) for c in studio.chunks} == {
        (None, "frame", "/j", None, False, False, "jacobi", ("silhouette",))}
    assert [c[1][5] for c in client.calls] == [None, None, None]  # no players
    run = json.loads((studio.path / "reconstruct" / "run.json").read_text())
    assert "subject_player" not in run and run["batch"] == {"chunk": 3, "units": ["00000-00002", "00003-00005",
                                                                                "00006-00006"]}
    assert (run["solver"], run["refine_pose"], run["warm_start"], run["bone_lengths"], run["n_vertices"]) == (
        "jacobi", False, False, "frame", 1000)
    # hull joints never take the run's lengths; given lengths are kept
    batch.reconstruct_batch(studio.path, client, ReconstructOptions(template="2k", joints="hull"), chunk=7)
    batch.reconstruct_batch(studio.path, client, ReconstructOptions(template="2k", lengths=(1.0,)), chunk=7)
    assert studio.length_calls == [] and [c["bone_lengths"] for c in studio.chunks[-2:]] == ["sequence", (1.0,)]
    batch.reconstruct_batch(studio.path, client, ReconstructOptions(template="2k", joints="file", joints_path="/j"),
                            chunk=7)
    assert studio.length_calls == [(FRAMES, "file", "/j", None)]


def test_reconstruct_batch_default_and_smallest_chunks(studio, client):
    studio.frame_ids = list(range(12))
    studio.files = _files(studio.frame_ids)
    batch.reconstruct_batch(studio.path, client, ReconstructOptions(template="2k"))  # chunks of 10 by default
    assert [c["frames"] for c in studio.chunks] == [list(range(10)), [10, 11]]
    studio.chunks.clear()
    _, report = batch.reconstruct_batch(studio.path, client, ReconstructOptions(template="2k"), frames="3:5", chunk=1)
    assert [c["frames"] for c in studio.chunks] == [[3], [4]] and list(report.status) == ["00003-00003",
                                                                                         "00004-00004"]


def test_assembly_copies_where_it_cannot_link_and_names_a_broken_unit(studio, client, monkeypatch):
    batch.reconstruct_batch(studio.path, client, _options(), chunk=4)
    from bodystudio.reconstruct.sequence import reconstruction_layout

    layout = reconstruction_layout(studio.path)
    units = [{"name": n, "root": layout.root / "chunks" / n, "frames": fr} for n, fr in (("00000-00003", [0, 1, 2, 3]),
                                                                             ("00004-00006", [4, 5, 6]))]

    def no_link(src, dst):
        raise OSError(18, "Invalid cross-device link")

    monkeypatch.setattr(os, "link", no_link)
    studio.judged.clear()
    records = batch._assemble_reconstruction(layout, units, _options(), FRAMES, 4)  # defaults: no session, strict
    assert [r["frame"] for r in records] == FRAMES
    assert studio.judged == [(FRAMES, studio.path, False)]  # the session is the run folder's parent
    for f in FRAMES:
        mesh = layout.root / f"meshes/{f:05d}.ply"
        assert mesh.read_bytes() == f"mesh {f}".encode() and os.stat(mesh).st_nlink == 1  # a copy
    unit_json = units[1]["root"] / "unit.json"
    unit_json.write_text("{")
    with pytest.raises(Exception) as err:  # noqa: PT011 - FileFormatError, its one line checked
        batch._assemble_reconstruction(layout, units, _options(), FRAMES, 4)
    assert str(err.value).startswith(f"{unit_json}: not a valid batch unit record (")


def test_a_failed_chunk_is_named_and_nothing_is_assembled(studio, client):
    studio.fail_frame = 4
    with pytest.raises(BatchError) as err:
        batch.reconstruct_batch(studio.path, client, _options(), chunk=3)
    record = studio.path / "reconstruct" / "chunks" / "record.json"
    assert str(err.value) == (f"1 of 3 chunks failed (errors in {record}); first: 00003-00005: frame 4: "
                              "no silhouette")
    assert not (studio.path / "reconstruct" / "run.json").exists()
    assert not (studio.path / "reconstruct" / "meshes").exists()
    assert not (studio.path / "reconstruct" / ".lock").exists()  # the lock is released: a re-run may go on
    studio.fail_frame = None
    client.calls.clear()
    _, report = batch.reconstruct_batch(studio.path, client, _options(), chunk=3)
    assert report.status == {"00000-00002": "skipped", "00003-00005": "done", "00006-00006": "skipped"}
    assert json.loads((studio.path / "reconstruct" / "run.json").read_text())["frames"] == FRAMES


@pytest.mark.parametrize("kw, message", [
    ({"template": "4k"}, "unknown template '4k'; valid: 13k, 6k, 2k"),
    ({"joints": "mocap"}, "unknown joint source 'mocap'; valid: tracker, file, hull"),
    ({"joints": "file"}, "--joints file needs --joints-path DIR with NNNNN.json files ({names, positions})"),
    ({"bone_lengths": "median"}, "unknown bone lengths 'median'; valid: frame, sequence"),
])
def test_reconstruct_batch_refuses_bad_options_before_any_output(studio, client, kw, message):
    with pytest.raises(InputError) as err:
        batch.reconstruct_batch(studio.path, client, ReconstructOptions(**{"template": "2k", **kw}))
    assert str(err.value) == message
    assert not (studio.path / "reconstruct").exists() and client.calls == []


def test_reconstruct_batch_refuses_chunk_depth_and_an_interrupted_write(studio, client):
    for chunk in (0, -1):
        with pytest.raises(InputError) as err:
            batch.reconstruct_batch(studio.path, client, _options(), chunk=chunk)
        assert str(err.value) == f"--chunk {chunk}: give at least 1 frame per work unit"
    studio.kinect = None
    with pytest.raises(InputError) as err:
        batch.reconstruct_batch(studio.path, client, _options())
    assert str(err.value) == (f"{studio.path}: no Kinect calibration, so no depth constraints; use --constraints "
                              "silhouette")
    assert not (studio.path / "reconstruct").exists()
    studio.kinect = "k"
    from bodystudio.reconstruct.sequence import reconstruction_layout

    staging = reconstruction_layout(studio.path).staging
    staging.mkdir(parents=True)
    with pytest.raises(OutputLockedError) as err:
        batch.reconstruct_batch(studio.path, client, _options())
    name = reconstruction_layout(studio.path).name
    assert str(err.value) == (f"{name}: a previous write was interrupted; run `bodystudio recover {name}` first "
                              "(the previous result stays)")
    assert client.calls == [] and not (studio.path / "reconstruct" / ".lock").exists()


@pytest.fixture
def clock(monkeypatch):
    """A stand-in for the batch module's ``time.perf_counter``: 100.0, then 1.25 s more at each call; returns the
    readings, so a unit's ``seconds`` is checked as its clock's last reading minus its first (no wall clock)."""
    import time as real_time

    readings = []

    def perf_counter():
        readings.append(100.0 + 1.25 * len(readings))
        return readings[-1]

    monkeypatch.setattr(batch, "time", SimpleNamespace(perf_counter=perf_counter, sleep=real_time.sleep,
                                                       gmtime=real_time.gmtime, strftime=real_time.strftime))
    return readings


def test_reconstruct_chunk_discards_a_killed_attempts_leftover(studio, tmp_path, clock):
    root = tmp_path / "chunk"
    layout = unit_layout(root)
    layout.staging.mkdir(parents=True)
    (layout.staging / "meshes").mkdir()
    (layout.staging / "meshes" / "00009.ply").write_bytes(b"half written")
    out = batch.reconstruct_chunk(str(studio.path), (2, 3), _options(), str(root), "abc")
    assert out["frames"] == [2, 3] and out["pid"] == os.getpid() and out["seconds"] == clock[-1] - clock[0] > 0
    assert sorted(p.name for p in (root / "meshes").iterdir()) == ["00002.ply", "00003.ply"]
    assert studio.chunks[0]["subject"] is None and studio.chunks[0]["frames"] == [2, 3]
    run = json.loads((root / "unit.json").read_text())["run"]
    assert run["command"] == "bodystudio reconstruct (batch unit)" and run["producer"] == {"session": str(studio.path)}
    batch.reconstruct_chunk(str(studio.path), [4], _options(), str(tmp_path / "c2"), "d", [["4", 9]])
    assert studio.chunks[1]["subject"] == {4: 9}


# ---------------------------------------------------------------------------------------------- muscle capture

@pytest.fixture
def arm(monkeypatch):
    import bodystudio.muscle.capture as mc

    state = SimpleNamespace(captures=[], fail=set(), out=None, locks=[])

    def capture_session_arm(session_path, model, mode, resolution, side, frames, shape, sequence_fit,
                            for_extension):
        lock = None if state.out is None else state.out / ".batch.lock"
        state.locks.append(json.loads(lock.read_text())["command"] if lock and lock.is_file() else None)
        state.captures.append((Path(session_path).name, model, mode, resolution, side, frames, shape, sequence_fit,
                               for_extension))
        if Path(session_path).name in state.fail:
            raise ValueError("no arm\nsecond line")
        return SimpleNamespace(mode=mode, n_frames=3, template_key="tk", session=Path(session_path).name)

    def write_arm_capture_files(path_for, capture, fps):
        path_for("arm.glb").write_bytes(f"{capture.session} {fps}".encode())

    monkeypatch.setattr(mc, "capture_session_arm", capture_session_arm)
    monkeypatch.setattr(mc, "write_arm_capture_files", write_arm_capture_files)
    monkeypatch.setattr(mc, "session_fps", lambda p: 25.0 if Path(p).name != "seq60" else 60.0)
    return state


def test_muscle_batch_captures_each_sequence_with_its_options(arm, client, tmp_path):
    from bodystudio.fileio import sha256_file
    from bodystudio.muscle.model import ArmShapeParams

    sessions = [tmp_path / "in" / n for n in ("s1", "s2")]
    for s in sessions:
        s.mkdir(parents=True)
    model = tmp_path / "arm.npz"
    model.write_bytes(b"model")
    out = arm.out = tmp_path / "out"
    options = MuscleOptions(mode="full", resolution="low", side="left", frames=5, model=str(model),
                            sequence_fit=False, for_extension=True)
    shape = {"bmi": 22.0, "muscularity": 0.5, "height_m": 1.8, "arm_length_m": 0.6}
    report = batch.muscle_batch([str(s) for s in sessions], out, client, options, shapes=[shape, None], setup=print)
    assert report.status == {"s1": "done", "s2": "done"}
    assert arm.locks == ["bodystudio muscle capture (batch)"] * 2  # the batch's lock held while units run
    assert client.bars == [("enabled", False), ("describe", "arm capture (full) of 2 sequences")]
    assert arm.captures == [
        ("s1", str(model), "full", "low", "left", 5, ArmShapeParams(**shape), False, True),
        ("s2", str(model), "full", "low", "left", 5, None, False, True)]
    from dataclasses import replace

    for (name, args, key, pure), s, sh in zip(client.calls, sessions, (shape, None), strict=True):
        opts = replace(options, shape=sh)
        sha = sequence_inputs_sha256(s, opts, sha256_file(model))
        assert (name, pure) == ("capture_unit", False)
        assert args == (str(s.resolve()), str(out / s.name), opts, sha, print)
        assert re.fullmatch(rf"capture-{s.name}-{sha[:12]}-[0-9a-f]{{8}}", key)
        manifest = json.loads((out / s.name / "unit.json").read_text())
        assert manifest["unit"] == {"inputs_sha256": sha, "session": str(s.resolve()), "pid": os.getpid()}
        assert {k: manifest[k] for k in ("mode", "n_frames", "template_key")} == {"mode": "full", "n_frames": 3,
                                                                                "template_key": "tk"}
        assert manifest["run"]["command"] == "bodystudio muscle capture (batch unit)"
        assert manifest["run"]["producer"] == {"session": str(s.resolve())}
        assert (out / s.name / "arm.glb").read_bytes() == f"{s.name} 25.0".encode()
    rec = json.loads((out / "batch.json").read_text())["units"]
    assert {n: (e["session"], e["output"]) for n, e in rec.items()} == {
        s.name: (str(s.resolve()), str(out / s.name)) for s in sessions}
    assert not (out / ".batch.lock").exists()
    with pytest.raises(InputError) as err:
        batch.muscle_batch(sessions, model, client, options)
    assert str(err.value).startswith(f"--out {model}: exists and is a file")
    # the same command again skips both; another model redoes both
    client.calls.clear()
    report = batch.muscle_batch(sessions, out, client, options, shapes=[shape, None])
    assert report.status == {"s1": "skipped", "s2": "skipped"} and client.calls == []
    model.write_bytes(b"model 2")
    report = batch.muscle_batch(sessions, out, client, options, shapes=[shape, None])
    assert report.status == {"s1": "done", "s2": "done"}
    # without shapes every sequence takes the options' own; a failing sequence is recorded, the other finishes
    arm.captures.clear()
    arm.fail = {"s1"}
    report = batch.muscle_batch(sessions, tmp_path / "o2", client, MuscleOptions(mode="nicp"))
    assert report.status == {"s1": "failed", "s2": "done"} and report.errors == {"s1": "ValueError: no arm"}
    assert [c[2] for c in arm.captures] == ["nicp", "nicp"] and [c[6] for c in arm.captures] == [None, None]
    assert [c[1][2].shape for c in client.calls[-2:]] == [None, None]


def test_capture_unit_runs_setup_first_and_discards_a_leftover(arm, tmp_path, clock):
    root = tmp_path / "u"
    unit_layout(root).staging.mkdir(parents=True)
    (unit_layout(root).staging / "arm.glb").write_bytes(b"half")
    order = []
    arm_before = len(arm.captures)
    out = batch.capture_unit(str(tmp_path / "seq60"), str(root), MuscleOptions(mode="nicp"), "sha",
                             lambda: order.append(len(arm.captures)))
    assert order == [arm_before] and out["frames"] == 3 and out["pid"] == os.getpid()
    assert out["seconds"] == clock[-1] - clock[0] > 0
    assert (root / "arm.glb").read_bytes() == b"seq60 60.0" and unit_is_complete(unit_layout(root), "sha")


def test_muscle_batch_refuses_bad_options(arm, client, tmp_path):
    s = tmp_path / "s1"
    s.mkdir()
    cases = [
        (MuscleOptions(mode="fast"), {}, "capture mode 'fast': valid: full, nicp, model"),
        (MuscleOptions(mode="nicp", model="m.npz"), {},
         "a capture batch needs an arm model for modes full/model and none for nicp"),
        (MuscleOptions(mode="full"), {}, "a capture batch needs an arm model for modes full/model and none for nicp"),
        (MuscleOptions(mode="model"), {}, "a capture batch needs an arm model for modes full/model and none for nicp"),
        (MuscleOptions(mode="nicp"), {"shapes": [None, None]},
         "2 measured shapes for 1 sessions: give one per session"),
    ]
    for options, kw, message in cases:
        with pytest.raises(InputError) as err:
            batch.muscle_batch([s], tmp_path / "out", client, options, **kw)
        assert str(err.value) == message
    assert not (tmp_path / "out").exists() and client.calls == []


# ---------------------------------------------------------------------------------------------- rig unit

def test_rig_unit_commits_the_rig_then_its_unit_record(monkeypatch, tmp_path, clock):
    import bodystudio.cli.rig as cli_rig
    from bodystudio.rig.export import rig_layout

    glb = tmp_path / "out" / "bob.glb"
    (glb.parent / ".batch").mkdir(parents=True)
    rig_layout(glb).staging.mkdir()  # a killed attempt's leftover: discarded first
    calls = []

    def rig_to_files(scan, out, template):
        calls.append((scan, out, template))
        with RunWriter(rig_layout(out), "bodystudio rig") as w:
            w.write_bytes(out, b"glTF")
            w.commit({"kind": "rig"})
        return {"fit_err_mm_median": 1.5}

    monkeypatch.setattr(cli_rig, "rig_to_files", rig_to_files)
    order = []
    out = batch.rig_unit(str(tmp_path / "bob.ply"), str(glb), "2k", "sha1", lambda: order.append(len(calls)))
    assert order == [0] and calls == [(tmp_path / "bob.ply", glb, "2k")]
    assert out["fit_err_mm_median"] == 1.5 and out["seconds"] == clock[-1] - clock[0] > 0
    run_id = json.loads(rig_layout(glb).manifest_path.read_text())["run"]["run_id"]
    assert json.loads((glb.parent / ".batch" / "bob.json").read_text()) == {
        "inputs_sha256": "sha1", "scan": str(tmp_path / "bob.ply"), "run_id": run_id, "pid": os.getpid()}
    assert batch.rig_is_complete(glb, "sha1")


# ---------------------------------------------------------------------------------------------- batch_client

class _Cluster:
    def __init__(self, log, **kw):
        self.log, self.kw = log, kw
        log.append(("cluster", kw))

    def close(self):
        self.log.append(("cluster closed",))


class _Client:
    def __init__(self, log, versions, target, **kw):
        self.log, self.versions = log, versions
        if isinstance(target, str) and "unreachable" in target:
            raise OSError("Timed out trying to connect to tcp://unreachable:1 after 5 s\nmore")
        if isinstance(target, str) and "silent" in target:
            raise TimeoutError()
        log.append(("client", target if isinstance(target, str) else "cluster", kw))

    def run(self, fn):
        self.log.append(("run", fn.__name__))
        return dict(self.versions)

    def register_plugin(self, plugin):
        self.log.append(("plugin", plugin.name))

    def close(self):
        self.log.append(("client closed",))


@pytest.fixture
def dask_stand_in(monkeypatch):
    import distributed

    state = SimpleNamespace(log=[], versions={"w1": batch.__version__})
    monkeypatch.setattr(distributed, "LocalCluster", lambda **kw: _Cluster(state.log, **kw))
    monkeypatch.setattr(distributed, "Client", lambda target, **kw: _Client(state.log, state.versions, target, **kw))
    monkeypatch.setattr(os, "cpu_count", lambda: 3)
    monkeypatch.delenv(batch.ENV_SCHEDULER, raising=False)
    return state


def _local(n):
    return ("cluster", {"n_workers": n, "threads_per_worker": 1, "processes": True, "env": batch.WORKER_ENV,
                        "dashboard_address": ":0", "silence_logs": 40})


def test_batch_client_starts_a_local_cluster_no_larger_than_the_batch(dask_stand_in):
    import logging

    steps = [("client", "cluster", {"set_as_default": False}), ("plugin", "bodystudio-exit-with-client"),
             ("run", "_worker_version"), ("plugin", "bodystudio-main-thread-imports")]
    for kw, n in (({}, 3), ({"workers": 2}, 2), ({"units": 2}, 2), ({"workers": 5, "units": 4}, 4),
                  ({"units": 0}, 1), ({"workers": 1, "units": 9}, 1)):
        dask_stand_in.log.clear()
        with batch.batch_client(**kw) as client:
            assert isinstance(client, _Client)
            assert dask_stand_in.log == [_local(n)] + steps, kw
        assert dask_stand_in.log[-2:] == [("client closed",), ("cluster closed",)]
    assert logging.getLogger("distributed").level == logging.WARNING
    assert logging.getLogger("distributed.http.proxy").level == logging.WARNING
    assert batch.WORKER_ENV == {"NUMBA_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
                                "OPENBLAS_NUM_THREADS": "1", "VECLIB_MAXIMUM_THREADS": "1"}
    dask_stand_in.log.clear()
    with pytest.raises(RuntimeError, match="unit failed"), batch.batch_client(workers=2):
        raise RuntimeError("unit failed")
    assert dask_stand_in.log[-2:] == [("client closed",), ("cluster closed",)]  # closed also on an error


def test_batch_client_connects_to_a_scheduler_and_checks_versions(dask_stand_in, monkeypatch):
    with batch.batch_client("tcp://h:1") as client:
        assert isinstance(client, _Client)
    assert dask_stand_in.log == [("client", "tcp://h:1", {"timeout": "5.0s", "set_as_default": False}),
                                 ("run", "_worker_version"), ("plugin", "bodystudio-main-thread-imports"),
                                 ("client closed",)]
    with pytest.raises(InputError) as err, batch.batch_client("tcp://unreachable:1"):
        pass
    assert str(err.value) == ("--scheduler tcp://unreachable:1: cannot reach the scheduler (Timed out trying to "
                              "connect to tcp://unreachable:1 after 5 s); start one with `dask scheduler` or leave "
                              "the option out for a local cluster")
    monkeypatch.setenv(batch.ENV_SCHEDULER, "tcp://silent:2")
    with pytest.raises(InputError) as err, batch.batch_client():
        pass
    assert str(err.value).startswith(f"${batch.ENV_SCHEDULER} tcp://silent:2: cannot reach the scheduler "
                                     "(TimeoutError); start one")
    monkeypatch.delenv(batch.ENV_SCHEDULER)
    dask_stand_in.versions = {"w1": batch.__version__, "w2": "0.0.1"}
    dask_stand_in.log.clear()
    with pytest.raises(InputError, match="1 of 2 workers run bodystudio 0.0.1"), batch.batch_client(workers=2):
        pass
    assert dask_stand_in.log[-2:] == [("client closed",), ("cluster closed",)]


def test_a_second_capture_batch_on_the_same_folder_is_refused_naming_it(arm, client, tmp_path):
    """Another live process (a child of this test: never the test's parent, which under mutmut is mutmut) holds
    the output folder's batch lock."""
    import socket
    import subprocess
    import sys

    from bodystudio.runfolder import _process_start

    s = tmp_path / "s1"
    s.mkdir()
    out = tmp_path / "out"
    out.mkdir()
    child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        (out / ".batch.lock").write_text(json.dumps({"pid": child.pid, "host": socket.gethostname(), "command": "w",
                                                     "start": _process_start(child.pid), "since": "now"}))
        with pytest.raises(OutputLockedError) as err:
            batch.muscle_batch([s], out, client, MuscleOptions(mode="nicp"))
        assert str(err.value).startswith(f"{out}: being written by pid {child.pid} ")
    finally:
        child.kill()
        child.wait()
    assert client.calls == []
