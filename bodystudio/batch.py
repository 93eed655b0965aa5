"""Batch jobs on a dask.distributed cluster: reconstruction chunks and scan rigs, resumable and kill-safe (issue 14).

A batch is a list of **work units** (a chunk of consecutive frames of a session; one scan), each run by a
worker process and written by that worker through :mod:`bodystudio.runfolder` (lock, staging, commit,
manifest last) into its own folder, so a unit's outputs appear whole or not at all. A unit's manifest
records the sha256 of its inputs (the session files of its frames, or the scan, and the options), so a
re-run of the same command skips the units whose inputs did not change, redoes the partial ones (a killed
worker's or client's leftover staging is discarded first) and ``force`` redoes everything. A failing unit is
recorded with its one-line error and the others finish; the client reports the failures at the end.

Without a scheduler address the client starts a :class:`distributed.LocalCluster` with one single-threaded
worker process per core (numba/BLAS thread pools pinned to 1 inside the workers, so N workers use N cores).
Data reaches the workers by path: a multi-machine cluster needs the session/scan folders on shared storage
at the same path, and the same bodystudio version on every worker (checked, mismatches refused).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import os
import re
import shutil
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

from bodystudio import __version__
from bodystudio.errors import BodyStudioError, InputError
from bodystudio.fileio import read_json, sha256_file, write_json
from bodystudio.runfolder import (
    OutputLockedError,
    RunLayout,
    RunWriter,
    acquire_lock,
    check_readable,
    recover_layout,
    release_lock,
    verify_run_files,
)

log = logging.getLogger(__name__)

ENV_SCHEDULER = "BODYSTUDIO_SCHEDULER"
#: Thread pools pinned to one thread inside each worker: one worker process per core is the parallelism.
WORKER_ENV = {"NUMBA_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
              "OPENBLAS_NUM_THREADS": "1", "VECLIB_MAXIMUM_THREADS": "1"}
CONNECT_TIMEOUT_S = 5.0
UNIT_MANIFEST = "unit.json"
CHUNKS_DIR = "chunks"
RECORD = "record.json"
SCAN_SUFFIXES = (".ply", ".obj", ".glb", ".gltf", ".stl")


class BatchError(BodyStudioError):
    """Some units of a batch failed (each error is in the batch record); the others completed."""


@dataclass
class BatchReport:
    """What one batch run did: unit name -> ``done`` | ``skipped`` | ``failed`` and the failures' errors."""

    status: dict[str, str] = field(default_factory=dict)
    errors: dict[str, str] = field(default_factory=dict)
    seconds: dict[str, float] = field(default_factory=dict)
    record: Path | None = None
    dashboard: str | None = None
    wall_s: float = 0.0

    def count(self, status: str) -> int:
        return sum(1 for s in self.status.values() if s == status)

    def failure_message(self, what: str) -> str:
        first = next(iter(self.errors.items()))
        return (f"{len(self.errors)} of {len(self.status)} {what} failed (errors in {self.record}); "
                f"first: {first[0]}: {first[1]}")


# ------------------------------------------------------------------------------------------ cluster

def _worker_version() -> str:
    import bodystudio

    return bodystudio.__version__


def check_worker_versions(versions: dict[str, str], local: str = __version__) -> None:
    """Refuse (one line) a cluster whose workers run another bodystudio version than the client."""
    bad = {w: v for w, v in versions.items() if v != local}
    if bad:
        worker, version = next(iter(bad.items()))
        raise InputError(f"--scheduler: {len(bad)} of {len(versions)} workers run bodystudio {version} "
                         f"(e.g. {worker}) but this client runs {local}; install the same version on every worker")


def _exit_with_client_plugin():
    """Worker plugin: a worker of a local cluster exits when its parent (the client) dies.

    A SIGKILLed client cannot stop its LocalCluster; its workers would go on holding unit locks.
    """
    from distributed import WorkerPlugin

    class ExitWithClient(WorkerPlugin):
        name = "bodystudio-exit-with-client"

        def setup(self, worker) -> None:
            # a failing unit is recorded (and reported) by the client; its traceback on the worker's stderr
            # would only bury the report
            logging.getLogger("distributed.worker").setLevel(logging.CRITICAL)
            parent = os.getppid()

            def watch() -> None:
                while True:
                    time.sleep(0.5)
                    if os.getppid() != parent:
                        os._exit(1)

            threading.Thread(target=watch, daemon=True, name="exit-with-client").start()

    return ExitWithClient()


#: Libraries whose first import must come from a worker's main thread (bodystudio.geometry.meshlab: pymeshlab's Qt
#: plugins, imported by a task thread that ends at the worker's close, corrupted the heap at its exit).
MAIN_THREAD_IMPORTS = ("pymeshlab",)


def _main_thread_imports_plugin():
    """Worker plugin: import :data:`MAIN_THREAD_IMPORTS` in the worker's main thread, before any task runs.

    ``setup`` runs on the worker's event loop, the main thread of the worker process (checked: a plugin run
    anywhere else raises, and the worker does not start). Every worker gets it, a restarted one too.
    """
    from distributed import WorkerPlugin

    class MainThreadImports(WorkerPlugin):
        name = "bodystudio-main-thread-imports"

        def setup(self, worker) -> None:
            import importlib

            if threading.current_thread() is not threading.main_thread():
                raise RuntimeError("bodystudio worker plugin: setup outside the worker's main thread")
            for module in MAIN_THREAD_IMPORTS:
                with contextlib.suppress(ImportError):
                    importlib.import_module(module)

    return MainThreadImports()


def worker_main_thread_imports() -> dict[str, bool]:
    """(On a worker) which of :data:`MAIN_THREAD_IMPORTS` are imported: True for each once the plugin ran."""
    import sys

    return {m: m in sys.modules for m in MAIN_THREAD_IMPORTS}


#: A local cluster's upper bound is this many single-threaded workers per core.
WORKERS_PER_CORE = 4


def max_local_workers() -> int:
    """The most ``--workers`` a local cluster starts: :data:`WORKERS_PER_CORE` per core of this machine."""
    return WORKERS_PER_CORE * (os.cpu_count() or 1)


def resolve_scheduler(scheduler: str | None, workers: int | None) -> str | None:
    """The scheduler address from ``--scheduler`` or ``$BODYSTUDIO_SCHEDULER`` (None: a local cluster)."""
    if workers is not None and workers < 1:
        raise InputError(f"--workers {workers}: give at least 1 worker process (default: one per core)")
    cap = max_local_workers()
    if workers is not None and workers > cap:
        raise InputError(f"--workers {workers}: at most {cap} on this machine ({os.cpu_count() or 1} cores; "
                         f"single-threaded workers beyond {WORKERS_PER_CORE} per core only share them and each "
                         "holds its own memory); give fewer, or --scheduler for a cluster of several machines")
    address = scheduler or os.environ.get(ENV_SCHEDULER) or None
    if address is not None and scheduler and workers is not None:
        raise InputError("--scheduler and --workers: give one (--workers starts a local cluster)")
    if address is not None and workers is not None:
        return None  # --workers asks for a local cluster over the environment's address
    if address is not None and not _SCHEDULER_ADDRESS.fullmatch(address):
        src = "--scheduler" if scheduler else f"${ENV_SCHEDULER}"
        raise InputError(f"{src} {address!r}: not a scheduler address; give tcp://HOST:PORT (e.g. tcp://10.0.0.5:8786)")
    return address


@contextlib.contextmanager
def batch_client(scheduler: str | None = None, workers: int | None = None, units: int | None = None) -> Iterator:
    """A dask client: to ``scheduler`` (or ``$BODYSTUDIO_SCHEDULER``), else to a new LocalCluster of
    ``workers`` single-threaded worker processes (default one per core), never more than the batch's ``units``
    of work (when known): a worker without a unit would only cost its start-up and memory. Worker versions
    are checked."""
    from distributed import Client, LocalCluster

    address = resolve_scheduler(scheduler, workers)
    # the scheduler's and nannies' INFO lines (start, connections, plugins) are noise in a command's output
    for name in ("distributed", "distributed.http.proxy"):
        logging.getLogger(name).setLevel(logging.WARNING)
    cluster = None
    if address is not None:
        try:
            client = Client(address, timeout=f"{CONNECT_TIMEOUT_S}s", set_as_default=False)
        except (OSError, TimeoutError) as exc:
            src = "--scheduler" if scheduler else f"${ENV_SCHEDULER}"
            reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            raise InputError(f"{src} {address}: cannot reach the scheduler ({reason[:120]}); start one with "
                             "`dask scheduler` or leave the option out for a local cluster") from None
    else:
        n = workers or os.cpu_count() or 1
        if units is not None:
            n = max(1, min(n, int(units)))
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, env=dict(WORKER_ENV),
                               dashboard_address=":0", silence_logs=logging.ERROR)
        client = Client(cluster, set_as_default=False)
        client.register_plugin(_exit_with_client_plugin())
    try:
        check_worker_versions(client.run(_worker_version))
        client.register_plugin(_main_thread_imports_plugin())
        yield client
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def dashboard_link(client) -> str | None:
    """The cluster's dashboard URL (None when the scheduler serves no dashboard: ``bokeh`` not installed)."""
    try:
        return client.dashboard_link
    except Exception:  # noqa: BLE001 - a scheduler without a dashboard has no link to show
        return None


# ------------------------------------------------------------------------------------------ units

def options_sha256(options: dict) -> str:
    return hashlib.sha256(json.dumps(options, sort_keys=True, default=str).encode()).hexdigest()


def unit_layout(root: Path) -> RunLayout:
    """Lock, staging and manifest (``unit.json``) of one unit's folder."""
    return RunLayout(Path(root), UNIT_MANIFEST, ".", str(root))


class _UnitWriter(RunWriter):
    """A RunWriter whose manifest also records the unit's input checksum (so skip/redo is decided by it)."""

    def __init__(self, layout: RunLayout, command: str, producer: dict, unit: dict):
        super().__init__(layout, command, producer)
        self.unit = unit

    def commit(self, manifest: dict, deletes=(), indent: int = 2) -> dict:
        return super().commit({**manifest, "unit": self.unit}, deletes, indent)


def unit_is_complete(layout: RunLayout, inputs_sha256: str) -> bool:
    """True when the unit's committed manifest has these inputs and every file it lists is intact.

    A killed worker's write that passed its commit point (a commit record in the staging folder) is finished
    here first (:func:`recover_layout`, idempotent): its unit is complete, not to be redone. An uncommitted
    leftover makes the unit partial (redone; the worker discards the leftover first).
    """
    try:
        if layout.commit_record.is_file():
            recover_layout(layout)  # refuses (False below) while a live worker still holds the unit
        if check_readable(layout) is not None or not layout.manifest_path.is_file():
            return False
        manifest = read_json(layout.manifest_path, "batch unit record")
        unit = manifest.get("unit") if isinstance(manifest, dict) else None
        # valid JSON of another shape (edited by hand) is redone, not an AttributeError that stops the client
        if not isinstance(unit, dict) or unit.get("inputs_sha256") != inputs_sha256:
            return False
        verify_run_files(layout, manifest.get("run"))
    except BodyStudioError:
        return False
    return True


def task_key(kind: str, unit: dict) -> str:
    """A new dask key for one submission of a unit: readable (kind, unit, inputs) and unique per run.

    A key made of the unit's name and inputs only collided with the task of an earlier run still known to
    the scheduler: the same scan or sequence content under another folder, or a re-run after a failure, got
    the earlier task's result (its error) back without running (tests/batch/test_batch_muscle.py)."""
    import uuid

    return f"{kind}-{unit['name']}-{unit['inputs_sha256'][:12]}-{uuid.uuid4().hex[:8]}"


def _run_units(client, units: list[dict], submit: Callable, record_path: Path, force: bool, progress: bool,
               describe: str, previous: dict) -> BatchReport:
    """Skip the complete units, submit the others, follow them with a progress bar, keep the record current."""
    from distributed import as_completed

    from bodystudio.capture.session import progress_bar

    report = BatchReport(record=record_path, dashboard=dashboard_link(client))
    record = {"version": __version__, "units": dict(previous)}
    t0 = time.perf_counter()

    def save(name: str, action: str, unit: dict, error: str | None = None, seconds: float | None = None,
             flush: bool = True) -> None:
        """Record a unit: ``status`` done | failed; ``action`` what this run did (computed, skipped, failed)."""
        entry = {**(record["units"].get(name, {}) if action == "skipped" else {}),
                 **{k: v for k, v in unit.items() if k in ("frames", "scan", "session", "output")},
                 "inputs_sha256": unit["inputs_sha256"], "status": "failed" if error is not None else "done",
                 "action": action, "time": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}
        entry.pop("error", None)
        if error is not None:
            entry["error"] = error
        if seconds is not None:
            entry["seconds"] = seconds
        record["units"][name] = entry
        if flush:
            write_json(record_path, record)

    pending = {}
    for unit in units:
        if not force and unit["complete"]():
            report.status[unit["name"]] = "skipped"
            save(unit["name"], "skipped", unit, flush=False)
        else:
            pending[submit(unit)] = unit
    write_json(record_path, record)
    with progress_bar(progress) as bar:
        task = bar.add_task(describe, total=len(units), completed=len(units) - len(pending))
        for future in as_completed(list(pending), loop=client.loop):
            unit = pending[future]
            name = unit["name"]
            try:
                result = future.result()
            except Exception as exc:  # noqa: BLE001 - a failed unit is recorded; the others finish
                message = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
                if not isinstance(exc, BodyStudioError):
                    message = f"{type(exc).__name__}: {message}"
                report.status[name], report.errors[name] = "failed", message
                save(name, "failed", unit, error=message)
                log.warning("%s failed: %s", name, message)
            else:
                report.status[name] = "done"
                report.seconds[name] = result["seconds"]
                save(name, "computed", unit, seconds=result["seconds"])
            bar.advance(task)
    report.wall_s = time.perf_counter() - t0
    return report


def _load_record(path: Path) -> dict:
    try:
        data = read_json(path, "batch record")
    except BodyStudioError:
        return {}
    units = data.get("units") if isinstance(data, dict) else None
    return units if isinstance(units, dict) else {}


# ------------------------------------------------------------------------------------------ reconstruction

@dataclass(frozen=True)
class ReconstructOptions:
    """The options of ``bodystudio reconstruct`` that change a chunk's result (hashed into its inputs)."""

    solver: str = "gs"
    template: str = "13k"
    joints: str = "tracker"
    joints_path: str | None = None
    warm_start: bool = False
    refine_pose: bool = True
    score: bool = True
    params: dict = field(default_factory=dict)  # RapidSkinParams as a dict
    bone_lengths: str = "sequence"
    #: the run's bone lengths (``sequence``: the median over all its frames, computed by the client, so every
    #: chunk poses with the same lengths as the sequential run)
    lengths: tuple[float, ...] | None = None


def chunk_frames(frames: list[int], chunk: int) -> list[list[int]]:
    """Consecutive frames in chunks of ``chunk`` (the last one shorter)."""
    if chunk < 1:
        raise InputError(f"--chunk {chunk}: give at least 1 frame per work unit")
    return [frames[i:i + chunk] for i in range(0, len(frames), chunk)]


#: A Dask scheduler address: PROTOCOL://HOST[:PORT][/]. The host has no ':' outside IPv6 brackets and no control
#: character, the port ASCII digits: before (rel6b) ``[^\s/]+(:\d+)?`` let the host take ``host:٨٧٨٦`` (a port
#: in other digits) and a NUL, which reached dask.
_SCHEDULER_ADDRESS = re.compile(r"(tcp|tls|inproc|ucx|ws|wss)://(\[[0-9A-Fa-f:.]+\]|[^\s/:\x00-\x1f\x7f]+)(:[0-9]+)?/?")


def chunk_name(frames: list[int]) -> str:
    return f"{frames[0]:05d}-{frames[-1]:05d}"


_FRAME_NUMBER = re.compile(r"(?<![0-9])([0-9]{5})(?![0-9])")


def chunk_inputs_sha256(session_files: dict[str, str], all_frames: list[int], frames: list[int],
                        options: ReconstructOptions, players: list | None = None) -> str:
    """sha256 over the chunk's inputs: the session files of its frames, the files of no frame (calibration,
    background), the options and the run's subject in its frames (``players``, ``[[frame, player id], ...]``;
    None: the joints are not the tracker's). A file of another frame does not change the chunk."""
    keep = _frame_files(session_files, all_frames, frames)
    h = hashlib.sha256(json.dumps(keep, sort_keys=True).encode())
    h.update(json.dumps({"frames": frames, "options": asdict(options)}, sort_keys=True, default=str).encode())
    if players is not None:
        h.update(json.dumps({"players": players}).encode())
    return h.hexdigest()


def reconstruct_chunk(session_path: str, frames: list[int], options: ReconstructOptions, unit_root: str,
                      inputs_sha256: str, players: list | None = None) -> dict:
    """One work unit, on a worker: Rapid Skin over consecutive ``frames`` into ``unit_root`` (atomic).

    The chunk starts from its first frame's tracker (and refined) pose; with ``warm_start`` the shape is
    carried over inside the chunk only. ``players`` (``[[frame, player id], ...]``): the run's subject in these
    frames, chosen by the client over the whole run (a chunk that starts after a second person came into view
    with a lower id must not choose them). A leftover of a killed attempt is discarded first.
    """
    from bodystudio.capture.session import open_session
    from bodystudio.reconstruct.rapid_skin import RapidSkinParams
    from bodystudio.reconstruct.sequence import reconstruct_frames

    t0 = time.perf_counter()
    layout = unit_layout(Path(unit_root))
    recover_layout(layout)
    session = open_session(session_path)
    params = RapidSkinParams(**{**options.params, "constraints": tuple(options.params.get("constraints",
                                                                                           ("silhouette",)))})
    unit = {"inputs_sha256": inputs_sha256, "frames": list(frames), "pid": os.getpid()}
    with _UnitWriter(layout, "bodystudio reconstruct (batch unit)", {"session": str(session_path)}, unit) as writer:
        reconstruct_frames(session, writer, list(frames), list(session.cameras), session.kinect, params,
                            options.solver, options.template, options.joints, options.joints_path,
                            options.warm_start, options.refine_pose, options.score, False,
                            bone_lengths=options.bone_lengths if options.lengths is None else options.lengths,
                            subject=None if players is None else {int(f): p for f, p in players})
    return {"frames": list(frames), "seconds": time.perf_counter() - t0, "pid": os.getpid()}


def reconstruct_batch(path: str | Path, client, options: ReconstructOptions, frames: str | None = None,
                      chunk: int = 10, force: bool = False, progress: bool = False,
                      accept_implausible: bool = False, player: int | None = None) -> tuple[dict, BatchReport]:
    """``bodystudio reconstruct SESSION --workers N``: chunks on the cluster, then one committed run.

    Chunks are written to ``SESSION/reconstruct/chunks/AAAAA-BBBBB/`` (each its own atomic run with its
    inputs' sha256, the record of completed units), then assembled into ``SESSION/reconstruct/`` as one
    run exactly like the sequential path's (same ``run.json`` keys plus ``batch``). Failed chunks: nothing
    is assembled and :class:`BatchError` names them; a re-run redoes only those. ``player``: the Kinect id of the
    person to reconstruct (default: the first tracked frame's lowest), chosen here for every chunk.
    """
    from bodystudio.capture.session import open_session
    from bodystudio.reconstruct.sequence import (
        BONE_LENGTHS,
        JOINT_SOURCES,
        TEMPLATES,
        parse_frames,
        reconstruction_layout,
        run_bone_lengths,
        run_subject,
        summarize,
    )

    if options.template not in TEMPLATES:
        raise InputError(f"unknown template {options.template!r}; valid: 13k, 6k, 2k")
    if options.joints not in JOINT_SOURCES:
        raise InputError(f"unknown joint source {options.joints!r}; valid: {', '.join(JOINT_SOURCES)}")
    if options.joints == "file" and options.joints_path is None:
        raise InputError("--joints file needs --joints-path DIR with NNNNN.json files ({names, positions})")
    if chunk < 1:
        raise InputError(f"--chunk {chunk}: give at least 1 frame per work unit")
    session = open_session(path)
    if "depth" in options.params.get("constraints", ()) and session.kinect is None:
        raise InputError(f"{session.path}: no Kinect calibration, so no depth constraints; "
                         "use --constraints silhouette")
    selected = parse_frames(frames, session.frame_ids)
    if options.bone_lengths not in BONE_LENGTHS:
        raise InputError(f"unknown bone lengths {options.bone_lengths!r}; valid: {', '.join(BONE_LENGTHS)}")
    # the run's subject, chosen once over all its frames (each chunk gets its frames' share)
    subject = run_subject(session, selected, options.joints, player)
    if options.bone_lengths == "sequence" and options.joints != "hull" and options.lengths is None:
        lengths = run_bone_lengths(session, selected, options.joints, options.joints_path, subject)
        options = replace(options, lengths=tuple(float(x) for x in lengths))
    layout = reconstruction_layout(session.path)
    chunks_root = layout.root / CHUNKS_DIR
    # The client holds the reconstruction's lock for the whole batch: a second reconstruct is refused at once.
    acquire_lock(layout, "bodystudio reconstruct (batch)")
    try:
        if layout.staging.exists():
            raise OutputLockedError(f"{layout.name}: a previous write was interrupted; run "
                                    f"`bodystudio recover {layout.name}` first (the previous result stays)")
        chunks_root.mkdir(parents=True, exist_ok=True)
        units = []
        for fr in chunk_frames(selected, chunk):
            name = chunk_name(fr)
            players = None if subject is None else [[f, subject[f]] for f in fr]
            sha = chunk_inputs_sha256(session.files, session.frame_ids, fr, options, players)
            root = chunks_root / name
            units.append({"name": name, "frames": fr, "inputs_sha256": sha, "root": root, "output": str(root),
                          "players": players,
                          "complete": (lambda r=root, s=sha: unit_is_complete(unit_layout(r), s))})
        record_path = chunks_root / RECORD

        def submit(unit):
            return client.submit(reconstruct_chunk, str(session.path), unit["frames"], options, str(unit["root"]),
                                 unit["inputs_sha256"], unit["players"], key=task_key("reconstruct", unit),
                                 pure=False)

        report = _run_units(client, units, submit, record_path, force, progress,
                            f"rapid skin {options.solver} {options.template} (chunks of {chunk})",
                            _load_record(record_path))
        if report.errors:
            raise BatchError(report.failure_message("chunks"))
    finally:
        release_lock(layout)
    records = _assemble_reconstruction(layout, units, options, selected, chunk, session.path, accept_implausible,
                                       subject)
    return summarize(records), report


def _assemble_reconstruction(layout: RunLayout, units: list[dict], options: ReconstructOptions,
                             selected: list[int], chunk: int, session_path=None,
                             accept_implausible: bool = False, subject: dict | None = None) -> list[dict]:
    """Publish the chunks as one reconstruction run (meshes, frames.json, run.json last), judged as one run by
    the reconstruction's self-check (:func:`bodystudio.reconstruct.sequence.judge_run`); ``subject``: the run's
    player per frame (:func:`bodystudio.reconstruct.sequence.run_subject`), recorded as the sequential run does."""
    from bodystudio.reconstruct.sequence import judge_run, subject_record

    records = []
    with RunWriter(layout, "bodystudio reconstruct (batch)", {"template": options.template}) as writer:
        for unit in units:
            ul = unit_layout(unit["root"])
            manifest = read_json(ul.manifest_path, "batch unit record")
            verify_run_files(ul, manifest.get("run"))
            records.extend(read_json(ul.root / "frames.json", "batch unit frames")["frames"])
            for fid in unit["frames"]:
                src, dst = ul.root / f"meshes/{fid:05d}.ply", writer.path_for(f"meshes/{fid:05d}.ply")
                try:
                    os.link(src, dst)
                except OSError:
                    shutil.copyfile(src, dst)
        verdict = judge_run(records, session_path or layout.root.parent, accept_implausible)
        writer.write_json("frames.json", {"frames": records})
        previous = [f"meshes/{p.name}" for p in (layout.root / "meshes").glob("*.ply")]
        first = read_json(unit_layout(units[0]["root"]).manifest_path, "batch unit record")
        writer.commit({"solver": options.solver, "template": options.template, "joints": options.joints,
                       "constraints": list(first["constraints"]), "frames": selected,
                       "warm_start": options.warm_start, "refine_pose": options.refine_pose,
                       "bone_lengths": options.bone_lengths, "params": first["params"],
                       "n_vertices": first["n_vertices"], **subject_record(subject),
                       "plausibility": verdict,
                       "batch": {"chunk": chunk, "units": [u["name"] for u in units]}}, deletes=previous)
    return records


# ------------------------------------------------------------------------------------------ rig

def list_scans(scans_dir: Path) -> list[Path]:
    """The scan files (PLY, OBJ, GLB/GLTF, STL) directly in ``scans_dir``, sorted."""
    scans_dir = Path(scans_dir)
    if not scans_dir.is_dir():
        raise InputError(f"{scans_dir}: no such folder of scans")
    scans = sorted(p for p in scans_dir.iterdir() if p.is_file() and p.suffix.lower() in SCAN_SUFFIXES)
    if not scans:
        raise InputError(f"{scans_dir}: no scan files ({', '.join(SCAN_SUFFIXES)}) in this folder")
    stems = {}
    for p in scans:
        if p.stem in stems:
            raise InputError(f"{scans_dir}: {stems[p.stem].name} and {p.name} would both write {p.stem}.glb; "
                             "rename one")
        stems[p.stem] = p
    return scans


def rig_unit(scan: str, glb: str, template: str, inputs_sha256: str, setup: Callable | None = None) -> dict:
    """One work unit, on a worker: rig ``scan`` into ``glb`` (+ .rig.json) atomically, then its unit record.

    The unit record (``.batch/STEM.json``, written after the rig's commit) holds the input checksum and the
    rig's run id; a crash between the two only redoes this scan.
    """
    from bodystudio.cli.rig import rig_to_files
    from bodystudio.rig.export import rig_layout

    t0 = time.perf_counter()
    if setup is not None:
        setup()
    recover_layout(rig_layout(glb))
    desc = rig_to_files(Path(scan), Path(glb), template=template)
    manifest = read_json(rig_layout(glb).manifest_path, "rig record")
    write_json(_rig_unit_record(Path(glb)), {"inputs_sha256": inputs_sha256, "scan": str(scan),
                                             "run_id": manifest["run"]["run_id"], "pid": os.getpid()})
    return {"seconds": time.perf_counter() - t0, "fit_err_mm_median": desc.get("fit_err_mm_median")}


def _rig_unit_record(glb: Path) -> Path:
    return glb.parent / ".batch" / f"{glb.stem}.json"


def rig_is_complete(glb: Path, inputs_sha256: str) -> bool:
    """The avatar's unit record has these inputs and names the committed rig run, whose files are intact."""
    from bodystudio.rig.export import rig_layout

    layout = rig_layout(glb)
    try:
        unit = read_json(_rig_unit_record(glb), "batch unit record")
        if check_readable(layout) is not None or not layout.manifest_path.is_file():
            return False
        manifest = read_json(layout.manifest_path, "rig record")
        if unit.get("inputs_sha256") != inputs_sha256 or manifest["run"]["run_id"] != unit.get("run_id"):
            return False
        verify_run_files(layout, manifest.get("run"))
    except (BodyStudioError, KeyError, TypeError, AttributeError):
        return False
    return True


def rig_batch(scans_dir: str | Path, out: str | Path, client, template: str = "6k", force: bool = False,
              progress: bool = False, setup: Callable | None = None) -> BatchReport:
    """``bodystudio batch rig SCANS_DIR --out DIR``: every scan rigged into ``DIR/STEM.glb`` on the cluster.

    ``DIR/batch.json`` records every unit (input sha256, status, error). Failures do not stop the others;
    they are in the returned report (the CLI raises :class:`BatchError` for them at the end). ``setup``
    (tests) runs in the worker before each unit.
    """
    from bodystudio.fileio import check_output_folder

    if template not in ("6k", "13k", "2k"):
        raise InputError(f"--template {template!r}: use 6k, 13k or 2k")
    scans = list_scans(Path(scans_dir))
    out = Path(out)
    check_output_folder(out, "--out")
    layout = RunLayout(out, "batch.json", ".batch.", str(out))
    acquire_lock(layout, "bodystudio batch rig")
    try:
        (out / ".batch").mkdir(exist_ok=True)
        opts = options_sha256({"template": template, "version": __version__})
        units = []
        for scan in scans:
            sha = hashlib.sha256((sha256_file(scan) + opts).encode()).hexdigest()
            glb = out / f"{scan.stem}.glb"
            units.append({"name": scan.name, "scan": str(scan), "output": str(glb), "inputs_sha256": sha,
                          "complete": (lambda g=glb, s=sha: rig_is_complete(g, s))})

        def submit(unit):
            return client.submit(rig_unit, unit["scan"], unit["output"], template, unit["inputs_sha256"], setup,
                                 key=task_key("rig", unit), pure=False)

        record_path = out / "batch.json"
        report = _run_units(client, units, submit, record_path, force, progress, f"rig {len(scans)} scans",
                            _load_record(record_path))
    finally:
        release_lock(layout)
    return report


# ------------------------------------------------------------------------------------------ muscle capture

@dataclass(frozen=True)
class MuscleOptions:
    """The options of ``bodystudio muscle capture`` that change a sequence's result (hashed into its inputs;
    the model by its sha256, not its path)."""

    mode: str = "full"  # full | nicp | model
    resolution: str | None = None  # None: the session's
    side: str | None = None
    frames: int | None = None  # the first N frames (None: all)
    shape: dict | None = None  # ArmShapeParams as a dict (None: fitted)
    model: str | None = None  # path of the arm model .npz (None: --no-model)
    sequence_fit: bool = True  # the whole-sequence pose fit (False: --no-sequence-fit)
    for_extension: bool = False  # the capture setting for extending a model (--for-extension)


def check_capture_sessions(paths: list[Path]) -> list[Path]:
    """The sessions of a capture batch: folders, each named once (its name is its output folder)."""
    names: dict[str, Path] = {}
    for p in map(Path, paths):
        if not p.is_dir():
            raise InputError(f"{p}: no such session folder; give Kinect session folders (bodystudio synth arm)")
        if p.name in names:
            raise InputError(f"{names[p.name]} and {p} would both write {p.name}/ in --out; rename one")
        names[p.name] = p
    return [Path(p) for p in paths]


def sequence_inputs_sha256(session_path: Path, options: MuscleOptions, model_sha256: str | None) -> str:
    """sha256 over a sequence's inputs: the session manifest's sha256 of every file of the captured frames
    and of no frame (calibration), the options and the model file's sha256. A session that cannot be
    opened hashes its error (its unit is then run, and fails on the worker with that error)."""
    from bodystudio.capture.session import open_session

    fields = asdict(options)
    if not fields["for_extension"]:  # added later: units captured before it keep their hash (a batch resumes)
        del fields["for_extension"]
    h = hashlib.sha256(json.dumps({"options": fields, "model": model_sha256, "version": __version__},
                                  sort_keys=True, default=str).encode())
    try:
        session = open_session(session_path)
    except BodyStudioError as exc:
        h.update(f"unreadable: {exc}".encode())
        return h.hexdigest()
    frames = session.frame_ids if options.frames is None else session.frame_ids[:options.frames]
    h.update(json.dumps(_frame_files(session.files, session.frame_ids, frames), sort_keys=True).encode())
    return h.hexdigest()


def _frame_files(session_files: dict[str, str], all_frames: list[int], frames: list[int]) -> dict[str, str]:
    """The session files (relative path -> sha256) of ``frames`` and of no frame."""
    every, mine = set(all_frames), set(frames)
    keep = {}
    for rel, digest in session_files.items():
        numbers = set() if "background" in rel else {int(m) for m in _FRAME_NUMBER.findall(Path(rel).name)} & every
        if not numbers or numbers & mine:
            keep[rel] = digest
    return keep


def capture_unit(session_path: str, unit_root: str, options: MuscleOptions, inputs_sha256: str,
                 setup: Callable | None = None) -> dict:
    """One work unit, on a worker: the arm capture of one sequence into ``unit_root`` (atomic).

    The folder is the one ``muscle capture SESSION --out`` writes (meshes/, arm.glb, params.json,
    manifest.json) plus ``unit.json`` last (checksums and the inputs' sha256). A leftover of a killed
    attempt is discarded first. ``setup`` (tests) runs first.
    """
    t0 = time.perf_counter()
    if setup is not None:
        setup()
    from bodystudio.muscle.capture import capture_session_arm, session_fps, write_arm_capture_files
    from bodystudio.muscle.model import ArmShapeParams

    layout = unit_layout(Path(unit_root))
    recover_layout(layout)
    shape = None if options.shape is None else ArmShapeParams(**options.shape)
    capture = capture_session_arm(session_path, options.model, options.mode, options.resolution, options.side,
                                  options.frames, shape, options.sequence_fit, options.for_extension)
    unit = {"inputs_sha256": inputs_sha256, "session": str(session_path), "pid": os.getpid()}
    with _UnitWriter(layout, "bodystudio muscle capture (batch unit)", {"session": str(session_path)},
                     unit) as writer:
        write_arm_capture_files(writer.path_for, capture, session_fps(session_path))
        writer.commit({"mode": capture.mode, "n_frames": capture.n_frames, "template_key": capture.template_key})
    return {"seconds": time.perf_counter() - t0, "frames": capture.n_frames, "pid": os.getpid()}


def muscle_batch(session_paths: list[str | Path], out: str | Path, client, options: MuscleOptions,
                 force: bool = False, progress: bool = False, setup: Callable | None = None,
                 shapes: list[dict | None] | None = None) -> BatchReport:
    """``bodystudio muscle capture S1 S2 ... --out DIR``: every sequence a work unit on the cluster.

    ``DIR/NAME/`` is the capture of session ``NAME`` (readable by ``eval muscle`` and ``muscle model
    extend``), committed by its worker with ``unit.json`` last; ``DIR/batch.json`` records every unit
    (inputs sha256, status, error). A sequence is one unit: the shape fit (Sec. 6.2 of Arm-Muscle Capture)
    uses its first frames and the refinement (Sec. 7) neighbouring frames, so a chunk border would change the
    result. Failures do not stop the others; they are in the report (the CLI raises :class:`BatchError`).
    ``shapes`` (one per session, or None) replaces ``options.shape`` per sequence: each subject's measured shape.
    """
    from dataclasses import replace

    from bodystudio.fileio import check_output_folder

    if options.mode not in ("full", "nicp", "model"):
        raise InputError(f"capture mode {options.mode!r}: valid: full, nicp, model")
    if (options.mode == "nicp") != (options.model is None):
        raise InputError("a capture batch needs an arm model for modes full/model and none for nicp")
    sessions = check_capture_sessions([Path(p) for p in session_paths])
    if shapes is not None and len(shapes) != len(sessions):
        raise InputError(f"{len(shapes)} measured shapes for {len(sessions)} sessions: give one per session")
    out = Path(out)
    check_output_folder(out, "--out")
    model_sha = None if options.model is None else sha256_file(Path(options.model))
    layout = RunLayout(out, "batch.json", ".batch.", str(out))
    acquire_lock(layout, "bodystudio muscle capture (batch)")
    try:
        units = []
        for k, session in enumerate(sessions):
            opts = options if shapes is None else replace(options, shape=shapes[k])
            sha = sequence_inputs_sha256(session, opts, model_sha)
            root = out / session.name
            units.append({"name": session.name, "session": str(session.resolve()), "output": str(root),
                          "inputs_sha256": sha, "root": root, "options": opts,
                          "complete": (lambda r=root, s=sha: unit_is_complete(unit_layout(r), s))})

        def submit(unit):
            return client.submit(capture_unit, unit["session"], str(unit["root"]), unit["options"],
                                 unit["inputs_sha256"],
                                 setup, key=task_key("capture", unit), pure=False)

        record_path = out / "batch.json"
        report = _run_units(client, units, submit, record_path, force, progress,
                            f"arm capture ({options.mode}) of {len(units)} sequences", _load_record(record_path))
    finally:
        release_lock(layout)
    return report
