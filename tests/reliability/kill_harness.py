"""Run a bodystudio command in a child process and SIGKILL it at a chosen file event or time.

File events are the child's ``os.replace`` calls: every atomic write (a staged file, the commit record,
the manifest) and every move of the commit ends in one, so "kill at event k" stops the run between any
two steps of its write protocol. The child kills itself with a real SIGKILL (no clean-up runs).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]

CHILD = r"""
import json, os, signal, sys
kill_at = int(os.environ.get("KILL_AT", "0"))
match = os.environ.get("KILL_AFTER_MATCH")
offset = int(os.environ.get("KILL_OFFSET", "0"))
log_path = os.environ.get("EVENT_LOG")
events = []
state = {"matched_at": None}
real_replace = os.replace

scope = os.environ.get("KILL_SCOPE")

def replace(src, dst):
    if scope and not os.path.realpath(str(dst)).startswith(scope):
        return real_replace(src, dst)  # e.g. numba's cache: not an event of the output's write
    events.append(str(dst))
    n = len(events)
    if match and state["matched_at"] is None and str(dst).endswith(match):
        state["matched_at"] = n
    if n == kill_at or (state["matched_at"] is not None and n == state["matched_at"] + offset):
        os.kill(os.getpid(), signal.SIGKILL)
    return real_replace(src, dst)

os.replace = replace
if log_path:
    import atexit
    atexit.register(lambda: open(log_path, "w").write(json.dumps(events)))
setup = os.environ.get("CHILD_SETUP")
if setup:
    exec(compile(open(setup).read(), setup, "exec"))
from bodystudio.cli.main import main
sys.exit(main(sys.argv[1:]))
"""


def run_child(args: list[str], cwd: Path, kill_at: int = 0, after_match: str | None = None, offset: int = 0,
              event_log: Path | None = None, setup: Path | None = None, kill_after_s: float | None = None,
              timeout: float = 300, scope: Path | None = None) -> subprocess.CompletedProcess:
    """Run ``bodystudio ARGS`` in a child (returncode -9 when SIGKILLed).

    Only writes under ``scope`` (default ``cwd``) count as events, so that caches written elsewhere on a
    first run do not shift the event numbers between runs.
    """
    env = dict(os.environ, PYTHONPATH=f"{REPO}{os.pathsep}{os.environ.get('PYTHONPATH', '')}",
               KILL_AT=str(kill_at), KILL_OFFSET=str(offset))
    env["KILL_SCOPE"] = os.path.realpath(scope or cwd)
    if after_match:
        env["KILL_AFTER_MATCH"] = after_match
    if event_log:
        env["EVENT_LOG"] = str(event_log)
    if setup:
        env["CHILD_SETUP"] = str(setup)
    proc = subprocess.Popen([sys.executable, "-c", CHILD, *args], cwd=cwd, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    if kill_after_s is not None:
        deadline = time.monotonic() + kill_after_s
        while time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.02)
        if proc.poll() is None:
            proc.send_signal(signal.SIGKILL)
    try:
        out, err = proc.communicate(timeout=timeout)  # reaps the child: a zombie would look alive
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.communicate()
        raise
    return subprocess.CompletedProcess(args, proc.returncode, out.decode(), err.decode())


def read_events(path: Path) -> list[str]:
    return json.loads(path.read_text())


def kill_points(events: list[str], seed: int, n: int) -> list[int]:
    """A seeded set of event numbers (1-based): the commit record, the first move after it, the manifest,
    and ``n`` others drawn at random. Read-lock files (``...readers/``, written when the command opens its
    finished output to report on it) come after the run is complete and are not kill points."""
    import random

    points = [k + 1 for k, e in enumerate(events) if "readers/" not in e]
    total = points[-1]
    commit = next((k + 1 for k, e in enumerate(events) if e.endswith("commit.json")), None)
    fixed = {p for p in (commit, commit + 1 if commit else None, total) if p}
    rng = random.Random(seed)
    others = rng.sample(points, min(n, len(points)))
    return sorted(fixed | set(others))


def snapshot(root: Path, skip_hidden: bool = True) -> dict[str, bytes]:
    """Relative path -> content of every visible file under ``root``."""
    out = {}
    for p in sorted(root.rglob("*")):
        rel = p.relative_to(root)
        if p.is_file() and not (skip_hidden and any(part.startswith(".") for part in rel.parts)):
            out[rel.as_posix()] = p.read_bytes()
    return out
