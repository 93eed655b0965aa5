"""Whole-run atomicity for multi-file outputs: a writer lock, staging, a commit record, the manifest last.

The capture session's scheme (``docs/session-format.md``), shared by every command that writes more
than one file (reconstruction runs, rigs with their sidecars, calibrations with their exports, imports):

1. **Lock** ``ROOT/<prefix>lock``, created with ``O_EXCL`` and holding the writer's pid, host, process
   start time and command. A second writer (or a reader) is refused with one line naming the holder;
   a lock whose process is dead (or whose pid was reused) is stale and is taken over.
2. **Staging**: every file is written (atomically) into ``ROOT/<prefix>staging/`` first; nothing the
   readers look at changes.
3. **Commit point**: ``<prefix>staging/commit.json`` lists the moves, the deletes and the new manifest.
4. The staged files are moved into place (``os.replace``), stale files deleted, and the **manifest is
   written last**; it records every file's sha256, a run id and what produced the run.

A write killed before the commit point leaves the previous complete result and an uncommitted
staging folder, which :func:`recover` discards; one killed after it leaves a commit record that
:func:`recover` completes. Readers call :func:`check_readable` (refuses a live writer or a committed but
unfinished write) and :func:`verify_run_files` (refuses parts whose checksums disagree with the manifest).
"""

from __future__ import annotations

import atexit
import contextlib
import errno
import glob
import json
import logging
import os
import re
import shutil
import socket
import sys
import time
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bodystudio.errors import BodyStudioError, FileFormatError, OutputSpaceError, disk_full
from bodystudio.fileio import _json_default, atomic_write, sha256_file

log = logging.getLogger(__name__)

COMMIT = "commit.json"
#: Seconds an unreadable (empty, half-written) lock file is taken as being created right now.
LOCK_GRACE_S = 10.0
#: A staging folder's leftover of a killed :func:`remove_staging` (``<staging>.stale.<pid>``)
_TOMB = re.compile(r"(.+)\.stale\.\d+")


class OutputLockedError(BodyStudioError):
    """An output is being written by another process, or a previous write was interrupted."""


@dataclass(frozen=True)
class RunLayout:
    """Where one multi-file output keeps its lock, staging folder and manifest.

    ``root`` is the folder of the manifest; ``prefix`` names the lock and staging (``"."`` for a
    session's ``.lock`` / ``.staging``, ``".a.glb."`` for a rig's ``.a.glb.lock`` / ``.a.glb.staging``);
    ``what`` is the path named in messages and given to ``bodystudio recover``.
    """

    root: Path
    manifest: str
    prefix: str = "."
    what: str = ""

    @property
    def lock(self) -> Path:
        return self.root / f"{self.prefix}lock"

    @property
    def staging(self) -> Path:
        return self.root / f"{self.prefix}staging"

    @property
    def readers(self) -> Path:
        """Folder of the shared read locks, one file per reading process."""
        return self.root / f"{self.prefix}readers"

    @property
    def commit_record(self) -> Path:
        return self.staging / COMMIT

    @property
    def manifest_path(self) -> Path:
        return self.root / self.manifest

    @property
    def name(self) -> str:
        return self.what or str(self.root)


# ---------------------------------------------------------------------------------------------- lock

def _process_start(pid: int) -> str | None:
    """Start time of a process (clock ticks since boot, Linux), to tell a reused pid from the writer."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = stat[stat.rfind(")") + 2:].split()
    return fields[19] if len(fields) > 19 else None


def _process_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    with contextlib.suppress(OSError):
        stat = Path(f"/proc/{pid}/stat").read_text()
        if stat[stat.rfind(")") + 2:].startswith("Z"):  # killed, not yet reaped by its parent
            return False
    return True


def process_alive(pid: int) -> bool:
    """Whether process ``pid`` runs on this machine (a zombie, killed and not yet reaped, does not)."""
    return _process_alive(int(pid))


def read_lock(path: Path) -> dict | None:
    """The lock's holder ``{pid, host, start, command, since}``, or None for a missing or unreadable lock."""
    try:
        data = json.loads(path.read_bytes())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) and isinstance(data.get("pid"), int) else None


def lock_is_stale(holder: dict | None, path: Path) -> bool:
    """True when the lock's process is gone (same host: dead pid or a reused one; unreadable: old file)."""
    if holder is None:
        try:
            return time.time() - path.stat().st_mtime > LOCK_GRACE_S
        except FileNotFoundError:
            return True
    if holder.get("host") != socket.gethostname():
        return False  # cannot see another machine's processes; the message tells the user what to do
    pid = holder["pid"]
    if not _process_alive(pid):
        return True
    start = holder.get("start")
    return start is not None and _process_start(pid) not in (None, start)


def remove_stale_lock(path: Path, own_is_stale: bool = False) -> bool:
    """Remove the lock at ``path`` if it is stale, compare-and-remove: the lock is renamed to
    ``<lock>.stale.<pid>`` first (of two processes removing it, only one gets it), then what was renamed is read
    again, and removed only when it is still stale (:func:`lock_is_stale`; ``own_is_stale``: a lock of this very
    process too, as :func:`lock_holder` counts it). A live lock renamed here (another writer took the stale one
    over between the caller's check and the rename) goes back to ``path`` without replacing a lock created
    meanwhile. True when a stale lock was removed, False when there was none or it was live."""
    stale = path.with_name(f"{path.name}.stale.{os.getpid()}")
    try:
        os.replace(path, stale)
    except FileNotFoundError:
        return False
    holder = read_lock(stale)
    own = (own_is_stale and holder is not None and holder["pid"] == os.getpid()
           and holder.get("host") == socket.gethostname())
    if own or lock_is_stale(holder, stale):
        stale.unlink(missing_ok=True)
        return True
    try:
        os.link(stale, path)  # back, unless a third writer created the lock in between (then that one holds it)
    except FileExistsError:
        log.warning("%s: a lock renamed as stale was live (pid %s) and another lock was taken meanwhile",
                    path, holder.get("pid") if holder else "?")
    except OSError:  # a file system without hard links
        if not path.exists():
            os.replace(stale, path)
    stale.unlink(missing_ok=True)
    return False


def lock_holder(layout: RunLayout) -> dict | None:
    """The live holder of the layout's lock other than this process, or None."""
    path = layout.lock
    if not path.exists():
        return None
    holder = read_lock(path)
    if lock_is_stale(holder, path):
        return None
    if holder is not None and holder["pid"] == os.getpid() and holder.get("host") == socket.gethostname():
        return None
    return holder or {"pid": "?", "host": "?", "command": "unknown command", "since": "just now"}


def _busy_message(layout: RunLayout, holder: dict) -> str:
    """One line naming the writer; the way out: wait, or `recover` (a lock of this host whose process died is
    stale anyway), or delete the lock of another host's process, which this one cannot see."""
    if holder.get("host") == socket.gethostname():
        fix = f"wait for it to finish or run `bodystudio recover {layout.name}`"
    else:
        fix = f"wait for it to finish (if that process is gone, delete {layout.lock})"
    return (f"{layout.name}: being written by pid {holder.get('pid')} on {holder.get('host')} "
            f"({holder.get('command')}, since {holder.get('since')}); {fix}")


def acquire_lock(layout: RunLayout, command: str) -> None:
    """Create the layout's lock (``O_EXCL``); a live holder is refused, a stale lock taken over."""
    if layout.root.exists() and not layout.root.is_dir():
        raise FileFormatError(f"{layout.root}: is a file, not a folder; choose another output path")
    created = not layout.root.exists()
    try:
        layout.root.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise FileFormatError(f"{layout.root}: cannot create the output folder ({exc.strerror}); "
                              "choose another output path") from None
    info = {"pid": os.getpid(), "host": socket.gethostname(), "start": _process_start(os.getpid()),
            "command": command, "since": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}
    for _ in range(3):
        try:
            fd = os.open(layout.lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except PermissionError:
            raise FileFormatError(f"{layout.root}: not writable, cannot write {layout.name} there; "
                                  "choose another output path") from None
        except FileExistsError:
            holder = read_lock(layout.lock)
            if not lock_is_stale(holder, layout.lock):
                raise OutputLockedError(_busy_message(layout, holder or {"pid": "?", "host": "?",
                                                                         "command": "unknown command",
                                                                         "since": "just now"})) from None
            log.warning("%s: taking over the stale lock of pid %s (%s)", layout.name,
                        holder.get("pid") if holder else "?", holder.get("command") if holder else "unreadable")
            remove_stale_lock(layout.lock)  # a lock that turned live meanwhile stays: the next O_EXCL is refused
            continue
        except OSError as exc:
            if disk_full(exc):
                _undo_root(layout, created)
                raise OutputSpaceError(layout.lock, exc.strerror or "no space left on device") from None
            raise
        try:
            with os.fdopen(fd, "w") as f:
                f.write(json.dumps(info) + "\n")
                f.flush()
                os.fsync(f.fileno())
        except OSError as exc:  # a full disk: no half-written lock (read as a live writer's) is left behind
            layout.lock.unlink(missing_ok=True)
            _undo_root(layout, created)
            if disk_full(exc):
                raise OutputSpaceError(layout.lock, exc.strerror or "no space left on device") from None
            raise
        # Lock first, then look for readers (a reader registers first, then looks for the lock): of a
        # writer and a reader starting together at least one sees the other, so they never overlap.
        readers = live_readers(layout)
        if readers:
            layout.lock.unlink(missing_ok=True)
            r = readers[0]
            more = f" and {len(readers) - 1} more" if len(readers) > 1 else ""
            raise OutputLockedError(f"{layout.name}: being read by pid {r.get('pid')}{more} ({r.get('command')}, "
                                    f"since {r.get('since')}); wait for it to finish")
        return
    raise OutputLockedError(f"{layout.name}: could not take the lock {layout.lock}; another writer keeps "
                            "taking it, retry when it is done")


def _undo_root(layout: RunLayout, created: bool) -> None:
    """Remove the output folder the lock's writer created, while it is still empty."""
    if created:
        with contextlib.suppress(OSError):
            layout.root.rmdir()


def release_lock(layout: RunLayout) -> None:
    holder = read_lock(layout.lock)
    if holder is not None and holder["pid"] == os.getpid():
        layout.lock.unlink(missing_ok=True)


# ---------------------------------------------------------------------------------------------- read locks

def _holder_info(command: str) -> dict:
    return {"pid": os.getpid(), "host": socket.gethostname(), "start": _process_start(os.getpid()),
            "command": command, "since": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}


def live_readers(layout: RunLayout) -> list[dict]:
    """Holders of the layout's shared read locks that are alive and not this process (stale ones removed)."""
    try:
        entries = list(layout.readers.iterdir())
    except OSError:
        return []
    out = []
    for path in entries:
        if path.name.startswith("."):  # a registration being written (atomic_write's temporary file)
            continue
        holder = read_lock(path)
        if lock_is_stale(holder, path):
            path.unlink(missing_ok=True)
            continue
        if holder is None:  # being written right now: a reader is starting
            out.append({"pid": "?", "command": "a reader starting", "since": "just now"})
        elif not (holder["pid"] == os.getpid() and holder.get("host") == socket.gethostname()):
            out.append(holder)
    return out


class ReadLock:
    """A shared read lock on a run folder (``ROOT/<prefix>readers/<host>.<pid>.<n>``): any number of readers,
    no writer while one is held. Taken at the start of a read, so a reader meets a live writer at its start
    (refused with one line) and a writer starting later is refused while the read lasts.

    Registration comes first and the writer's lock is checked second (a writer does the reverse), so a reader
    and a writer that start at the same moment cannot both go on. A killed reader leaves a file naming a dead
    pid, which every later writer ignores and removes.
    """

    _count = 0

    def __init__(self, layout: RunLayout, command: str):
        self.layout = layout
        self.path: Path | None = None
        if not layout.root.is_dir():
            return  # nothing to read yet; the reader's own check reports it
        ReadLock._count += 1
        name = f"{socket.gethostname()}.{os.getpid()}.{ReadLock._count}"
        try:
            layout.readers.mkdir(exist_ok=True)
            with atomic_write(layout.readers / name, "wb") as f:
                f.write((json.dumps(_holder_info(command)) + "\n").encode())
            self.path = layout.readers / name
        except OSError:  # a read-only folder (an archive, a CD): nobody can write it either
            self.path = None
        try:
            holder = lock_holder(layout)
            if holder is not None:
                raise OutputLockedError(_busy_message(layout, holder))
        except BaseException:
            self.release()
            raise

    def release(self) -> None:
        if self.path is not None:
            self.path.unlink(missing_ok=True)
            self.path = None
            with contextlib.suppress(OSError):
                self.layout.readers.rmdir()  # only when empty

    def __enter__(self) -> ReadLock:
        return self

    def __exit__(self, *exc) -> None:
        self.release()


_HELD: list[ReadLock] = []
_HOLDING = [False]  # inside command_read_locks(): readers register shared locks


@contextlib.contextmanager
def command_read_locks():
    """Scope of one command: every read inside takes a shared read lock, all released at the end.

    The CLI runs each command inside it. Outside it (library use: a notebook, a test reading a folder)
    readers only check for a live writer at their start, so a long-lived process never blocks writers."""
    previous = _HOLDING[0]
    _HOLDING[0] = True
    try:
        yield
    finally:
        _HOLDING[0] = previous
        if not previous:
            release_read_locks()


def reader_command() -> str:
    """How this process is named in a read lock: the command line's first words."""
    return " ".join([Path(sys.argv[0]).name] + sys.argv[1:3]) if sys.argv and sys.argv[0] else "python"


def hold_read_lock(layout: RunLayout, command: str | None = None) -> ReadLock | None:
    """Inside :func:`command_read_locks`: take a read lock held until the command ends (refuses a live writer
    now, and writers until then). Outside it: only refuse a live writer now (None)."""
    if not _HOLDING[0]:
        holder = lock_holder(layout)
        if holder is not None:
            raise OutputLockedError(_busy_message(layout, holder))
        return None
    lock = ReadLock(layout, command or reader_command())
    _HELD.append(lock)
    return lock


def release_read_locks() -> None:
    """Release every read lock this process holds (end of a command)."""
    while _HELD:
        _HELD.pop().release()


atexit.register(release_read_locks)


# ---------------------------------------------------------------------------------------------- readers

def interrupted_message(layout: RunLayout) -> str:
    return (f"{layout.name}: a write was interrupted while committing; run `bodystudio recover {layout.name}` "
            "to finish it")


def check_readable(layout: RunLayout) -> str | None:
    """Take a read lock (:func:`hold_read_lock`: refuses a live writer now, and, in a command, writers until it
    ends), refuse a committed-but-unfinished write; return a note for an uncommitted leftover.

    With an uncommitted leftover the previous complete result is still in place and readable.
    """
    hold_read_lock(layout)
    if layout.commit_record.is_file():
        raise OutputLockedError(interrupted_message(layout))
    if layout.staging.is_dir():
        n = sum(1 for p in layout.staging.rglob("*") if p.is_file())
        note = f"{layout.staging}: an interrupted write left {n} uncommitted files"
        log.warning("%s; showing the last complete result (run `bodystudio recover %s` to discard it)",
                    note, layout.name)
        return note
    return None


def resolve(layout: RunLayout, key: str) -> Path:
    """A manifest's file key (relative to the root, or absolute for files written elsewhere) as a path."""
    p = Path(key)
    return p if p.is_absolute() else layout.root / p


def verify_run_files(layout: RunLayout, run: Any, only: tuple[str, ...] | None = None) -> dict:
    """Check the files a manifest's ``run`` block lists against their sha256; returns the block.

    A missing block, a missing file or a checksum that differs is a one-line FileFormatError: the
    folder mixes parts of different runs (or was edited), and must not be read as one result.
    """
    source = layout.manifest_path
    if not isinstance(run, dict) or not isinstance(run.get("files"), dict) or not run.get("run_id"):
        raise FileFormatError(f"{source}: records no run id and checksums (written by an older bodystudio or by "
                              "hand); re-run the command that produced it")
    for key, expected in run["files"].items():
        if only is not None and key not in only:
            continue
        path = resolve(layout, key)
        if not path.is_file():
            raise FileFormatError(f"{path}: missing, but {source} lists it (run {run['run_id']}); the output is "
                                  "incomplete, re-run the command that produced it")
        if sha256_file(path) != expected:
            raise FileFormatError(f"{path}: does not belong to run {run['run_id']} of {source} (sha256 differs); "
                                  "the output mixes two runs or was edited, re-run the command that produced it")
    return run


# ---------------------------------------------------------------------------------------------- commit

def apply_commit(layout: RunLayout, plan: dict) -> None:
    """Carry out a commit record: moves (staged -> destination), deletes, the manifest last, staging gone.

    Idempotent: a move whose staged file is gone already happened in an earlier, interrupted attempt.
    A move is ``"rel"`` (same path under the staging and the root) or ``["staged rel", "destination"]``.
    """
    if plan.get("manifest") is not None and not plan.get("manifest_name", layout.manifest):
        raise FileFormatError(f"{layout.commit_record}: names no manifest to write; delete {layout.staging} "
                              "to keep the previous result")
    for move in plan["moves"]:
        staged_rel, dest_key = (move, move) if isinstance(move, str) else move
        src, dst = layout.staging / staged_rel, resolve(layout, dest_key)
        if src.is_file():
            dst.parent.mkdir(parents=True, exist_ok=True)
            try:
                os.replace(src, dst)
            except OSError as exc:
                if exc.errno != errno.EXDEV:
                    raise
                # another file system: copy beside the destination, then rename
                with atomic_write(dst, "wb") as f, open(src, "rb") as g:
                    shutil.copyfileobj(g, f)
                src.unlink()
    for key in plan.get("deletes", []):
        resolve(layout, key).unlink(missing_ok=True)
    if plan.get("manifest") is not None:
        data = plan["manifest"]
        raw = data.encode() if isinstance(data, str) else (json.dumps(data, indent=plan.get("indent", 1),
                                                                        default=_json_default) + "\n").encode()
        with atomic_write(layout.root / plan.get("manifest_name", layout.manifest), "wb") as f:
            f.write(raw)
    remove_staging(layout)


def remove_staging(layout: RunLayout) -> None:
    """Delete the staging folder in one step as a reader sees it: renamed to ``<staging>.stale.<pid>``, then deleted.

    A plain recursive delete killed halfway through left the staging folder, empty, beside the complete result
    it had just committed, which reads as an interrupted write (a batch re-run redid such a unit). A killed
    delete now leaves only the ``.stale.`` folder, which the next writer of the layout removes.
    """
    tomb = layout.staging.with_name(f"{layout.staging.name}.stale.{os.getpid()}")
    shutil.rmtree(tomb, ignore_errors=True)
    try:
        os.replace(layout.staging, tomb)
    except FileNotFoundError:
        return
    shutil.rmtree(tomb, ignore_errors=True)


def remove_stale_staging(layout: RunLayout) -> int:
    """Delete the ``.stale.`` folders a killed :func:`remove_staging` left; returns how many.

    Nothing reads them, so deleting one that its own process is still deleting is harmless.
    """
    stale = list(layout.root.glob(f"{glob.escape(layout.staging.name)}.stale.*"))
    for p in stale:
        shutil.rmtree(p, ignore_errors=True)
    return len(stale)


def recover_layout(layout: RunLayout) -> str | None:
    """Finish a committed-but-unfinished write or discard an uncommitted one (None: nothing to do)."""
    holder = lock_holder(layout)
    if holder is not None:
        raise OutputLockedError(_busy_message(layout, holder) + "; nothing to recover while it runs")
    readers = live_readers(layout)
    if readers and (layout.commit_record.is_file() or layout.staging.is_dir()):
        raise OutputLockedError(f"{layout.name}: being read by pid {readers[0].get('pid')} "
                                f"({readers[0].get('command')}); recover it when that has finished")
    message = None
    if layout.commit_record.is_file():
        try:
            plan = json.loads(layout.commit_record.read_bytes())
            if not isinstance(plan, dict) or not isinstance(plan.get("moves"), list):
                raise ValueError("no moves")
            for move in plan["moves"]:
                if not (isinstance(move, str) or (isinstance(move, list) and len(move) == 2
                                                  and all(isinstance(m, str) for m in move))):
                    raise ValueError(f"bad move {move!r}")
        except (OSError, ValueError) as exc:
            raise FileFormatError(f"{layout.commit_record}: unreadable commit record ({exc}); delete "
                                  f"{layout.staging} to keep the previous result") from None
        apply_commit(layout, plan)
        message = f"completed the interrupted write ({len(plan['moves'])} files)"
    elif layout.staging.is_dir():
        n = sum(1 for p in layout.staging.rglob("*") if p.is_file())
        shutil.rmtree(layout.staging)
        message = f"discarded an uncommitted write ({n} files); the previous result stays"
    if remove_stale_staging(layout):
        message = message or "removed the leftover of a finished write"
    # lock_holder found no live process at the start, but a writer may have taken the stale lock over since: the
    # lock is compared and removed (a live one stays), never unlinked unread
    if layout.lock.exists() and remove_stale_lock(layout.lock, own_is_stale=True):
        message = message or "removed a stale lock"
    return message


def layouts_under(path: Path) -> list[RunLayout]:
    """Every lock or staging folder (or a staging folder's ``.stale.`` leftover) in ``path`` (a folder) and its
    direct sub-folders."""
    folders = [path] + sorted(p for p in path.iterdir() if p.is_dir() and not p.name.endswith("staging")
                              and not _TOMB.fullmatch(p.name))
    found = {}
    for folder in folders:
        for p in folder.iterdir():
            # a lock's .stale. copy (a file, ending in the pid) is no layout; ".stale." elsewhere in a name is the
            # user's (an avatar a.stale.glb has the lock .a.stale.glb.lock)
            tomb = _TOMB.fullmatch(p.name) if p.is_dir() else None
            name = tomb.group(1) if tomb else p.name
            for suffix in ("staging", "lock"):
                if name.startswith(".") and name.endswith(suffix):
                    prefix = name[: -len(suffix)]
                    target = folder if prefix == "." else folder / prefix[1:-1]
                    # a session's commit records predate manifest_name: its manifest is session.json
                    found[(folder, prefix)] = RunLayout(folder, "session.json" if prefix == "." else "", prefix,
                                                        str(target))
    return list(found.values())


def recover(path: str | os.PathLike) -> list[str]:
    """``bodystudio recover PATH``: finish or discard every interrupted write at PATH; one line each."""
    path = Path(path)
    if path.is_dir():
        layouts = layouts_under(path)
    elif path.parent.is_dir():
        layouts = [RunLayout(path.parent, "", f".{path.name}.", str(path))]
    else:
        raise FileFormatError(f"{path}: no such file or folder")
    out = []
    for layout in layouts:
        message = recover_layout(layout)
        if message:
            out.append(f"{layout.name}: {message}")
    return out or [f"{path}: nothing to recover"]


# ---------------------------------------------------------------------------------------------- writer

def check_output_destination(path: str | os.PathLike, what: str = "output") -> None:
    """Refuse, before any work, a destination that cannot be written (see :func:`fileio.check_output_file`:
    a folder in the file's place, a file where one of its folders should be, an unwritable place)."""
    from bodystudio.fileio import check_output_file

    check_output_file(path, what)


def new_run_id() -> str:
    return uuid.uuid4().hex[:16]


class RunWriter:
    """Stage a multi-file output and commit it as a whole (see the module docstring).

    >>> with RunWriter(RunLayout(folder, "run.json", ".", str(folder)), "bodystudio reconstruct") as w:
    ...     save_mesh(w.path_for("meshes/00000.ply"), mesh)
    ...     w.commit({"template": "2k"})

    Leaving the block without :meth:`commit` (an exception) discards the staging and keeps the previous
    result. The lock is taken here, before any work, so a second writer is refused at once.
    """

    def __init__(self, layout: RunLayout, command: str, producer: dict | None = None):
        self.layout = layout
        self.command = command
        self.producer = dict(producer or {})
        self.run_id = new_run_id()
        self._external: dict[str, str] = {}  # staged prefix -> destination outside the root
        self.committed = False
        self._created_root = not layout.root.exists()
        acquire_lock(layout, command)
        try:
            if layout.commit_record.is_file():
                raise OutputLockedError(interrupted_message(layout))
            if layout.staging.exists():
                raise OutputLockedError(f"{layout.name}: a previous write was interrupted before its commit; run "
                                        f"`bodystudio recover {layout.name}` first (the previous result stays)")
            remove_stale_staging(layout)
            layout.staging.mkdir(parents=True)
        except BaseException:
            self._release()
            raise

    def __enter__(self) -> RunWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if not self.committed:
            self.abort()

    def _key(self, dest: str | os.PathLike) -> str:
        """Manifest key of a destination: relative to the root (``../`` for a file beside it, so that the
        whole tree can move), absolute only on another drive."""
        dest = Path(dest)
        if not dest.is_absolute():
            return dest.as_posix()
        try:
            return Path(os.path.relpath(dest.resolve(), self.layout.root.resolve())).as_posix()
        except ValueError:
            return str(dest.resolve())

    def path_for(self, dest: str | os.PathLike) -> Path:
        """Staged path of a file (or a folder, for exporters that write several files into one) to publish."""
        key = self._key(dest)
        if Path(key).is_absolute() or key.split("/")[0] == "..":
            staged = f"_external/{len(self._external)}"
            self._external[staged] = key
        else:
            staged = key
        path = self.layout.staging / staged
        path.parent.mkdir(parents=True, exist_ok=True)
        return path

    def write_bytes(self, dest: str | os.PathLike, data: bytes) -> None:
        with atomic_write(self.path_for(dest), "wb") as f:
            f.write(data)

    def write_json(self, dest: str | os.PathLike, data: Any) -> None:
        self.write_bytes(dest, (json.dumps(data, indent=2, default=_json_default) + "\n").encode())

    def staged_files(self) -> dict[str, str]:
        """Staged relative path -> manifest key of every staged file."""
        out = {}
        for p in sorted(self.layout.staging.rglob("*")):
            if not p.is_file() or p.name.startswith("."):
                continue
            rel = p.relative_to(self.layout.staging).as_posix()
            for prefix, dest in self._external.items():
                if rel == prefix or rel.startswith(prefix + "/"):
                    rel_dest = dest + rel[len(prefix):]
                    break
            else:
                rel_dest = rel
            out[rel] = rel_dest
        return out

    def run_block(self) -> dict:
        """``{"run_id", "command", "producer", "files": {key: sha256}}`` of what is staged now."""
        files = {dest: sha256_file(self.layout.staging / rel) for rel, dest in self.staged_files().items()}
        return {"run_id": self.run_id, "command": self.command, "producer": self.producer, "files": files,
                "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}

    def commit(self, manifest: dict, deletes: list[str] | tuple[str, ...] = (), indent: int = 2) -> dict:
        """Publish: commit record, moves, deletes, ``manifest`` (plus a ``run`` block) last; releases the lock.

        ``deletes``: keys of files of the previous result that this one no longer has.
        """
        run = self.run_block()
        manifest = {**manifest, "run": run}
        moves = [[rel, dest] for rel, dest in self.staged_files().items()]
        for _, dest in moves:  # before the commit point: a failed move after it would need a recovery
            check_output_destination(resolve(self.layout, dest))
        deletes = sorted(set(deletes) - set(run["files"]) - {self.layout.manifest})
        plan = {"moves": moves, "deletes": deletes, "manifest": manifest, "manifest_name": self.layout.manifest,
                "indent": indent}
        with atomic_write(self.layout.commit_record, "wb") as f:
            f.write((json.dumps(plan, default=_json_default) + "\n").encode())
        apply_commit(self.layout, plan)
        self.committed = True
        release_lock(self.layout)
        return manifest

    def abort(self) -> None:
        """Discard the staged files; the previous result stays. Releases the lock."""
        remove_staging(self.layout)
        self.committed = True
        self._release()

    def _release(self) -> None:
        release_lock(self.layout)
        if self._created_root:  # a failed first run leaves no empty output folder behind
            with contextlib.suppress(OSError):
                self.layout.root.rmdir()
