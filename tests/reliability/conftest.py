"""Shared helpers of the reliability tests: run the CLI (in-process or as the installed console script) and
small synthetic inputs built once per session (a 2-camera x 2-frame 160x120 session, a 5000-vertex scan).

The code under test is whichever ``bodystudio`` this interpreter imports (``PYTHONPATH``); the console-script
subprocesses get the same path, so the catalogue can be run against another checkout for a before/after count.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import traceback
from dataclasses import dataclass
from pathlib import Path

import pytest

import bodystudio

#: The checkout whose code the tests run (the folder holding the ``bodystudio`` package).
CODE_ROOT = Path(bodystudio.__file__).resolve().parents[1]


@dataclass
class CliResult:
    """Exit code, stdout and stderr of one CLI run; ``crashed`` holds a traceback that escaped ``main``."""

    rc: int | None
    stdout: str
    stderr: str
    crashed: str | None = None
    hung: bool = False

    @property
    def text(self) -> str:
        return self.stdout + self.stderr + (self.crashed or "")


def console_script() -> list[str]:
    """The installed ``bodystudio`` entry point beside this interpreter (else ``python -m``)."""
    script = Path(sys.executable).with_name("bodystudio")
    return [str(script)] if script.is_file() else [sys.executable, "-m", "bodystudio.cli.main"]


def cli_env(extra: dict[str, str] | None = None) -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(CODE_ROOT)] + [p for p in env.get("PYTHONPATH", "").split(os.pathsep)
                                                             if p and Path(p).resolve() != CODE_ROOT])
    env.pop("FORCE_COLOR", None)
    env["COLUMNS"] = "200"
    env.update(extra or {})
    return env


def run_subprocess(args: list[str], cwd: Path | None = None, env: dict[str, str] | None = None,
                   timeout: float = 120) -> CliResult:
    """Run the real console script (stdin closed, stdout/stderr pipes, i.e. not a terminal)."""
    try:
        proc = subprocess.run(console_script() + [str(a) for a in args], cwd=cwd, env=cli_env(env),
                              stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired as exc:
        out = exc.stdout.decode() if isinstance(exc.stdout, bytes) else exc.stdout or ""
        err = exc.stderr.decode() if isinstance(exc.stderr, bytes) else exc.stderr or ""
        return CliResult(None, out, err, hung=True)
    crashed = proc.stderr if "Traceback (most recent call last)" in proc.stderr else None
    return CliResult(proc.returncode, proc.stdout, proc.stderr, crashed)


def run_inprocess(args: list[str], capfd) -> CliResult:
    """Call ``bodystudio.cli.main.main`` in this process (fast: no interpreter start, imports shared)."""
    from bodystudio.cli.main import main

    capfd.readouterr()
    crashed, rc = None, None
    try:
        rc = main([str(a) for a in args])
    except SystemExit as exc:  # a code path calling sys.exit
        rc = exc.code if isinstance(exc.code, int) else 1
    except BaseException:  # noqa: BLE001 - the traceback is the finding
        crashed = traceback.format_exc()
    out, err = capfd.readouterr()
    return CliResult(rc, out, err, crashed)


_LOG_LINE = re.compile(r"^(WARNING|INFO|DEBUG) [\w.]+: ")


def assert_clean_error(result: CliResult, rc: int, phrase: str, usage: bool = False) -> None:
    """The promise of the README: the expected exit code, a message with ``phrase``, no traceback, no hang;
    a user error is ONE stderr line (log lines of our own loggers aside), with no progress-bar or C-library
    chatter around it; a usage error is click's short usage message."""
    assert not result.hung, f"hung; stderr: {result.stderr[-500:]}"
    assert result.crashed is None, f"traceback:\n{result.crashed[-2000:]}"
    assert "Traceback (most recent call last)" not in result.text, result.text[-2000:]
    assert result.rc == rc, f"exit {result.rc}, expected {rc}; stderr: {result.stderr[-800:]}"
    if rc == 0:
        return
    assert phrase.lower() in result.stderr.lower(), f"{phrase!r} not in stderr: {result.stderr[-800:]}"
    if usage:
        assert "Usage:" in result.stderr and result.stderr.count("\n") < 12, result.stderr
        return
    lines = [ln for ln in result.stderr.splitlines() if ln.strip() and not _LOG_LINE.match(ln)]
    assert len(lines) == 1 and lines[0].startswith("error: "), f"not one error line: {result.stderr!r}"


@dataclass
class Studio:
    """The shared small inputs (read-only: a case that alters one copies it first)."""

    root: Path
    session: Path  # synthetic session, 2 cameras x 2 frames, 160x120, 2k template, no Kinect
    cameras_json: Path  # its calibration
    images: Path  # images/<cam>/00000.png..., the session's frames as an import source
    scan: Path  # synthetic scan PLY (5000 vertices) with scan.gt/
    board_folder: Path  # a capture folder holding only board.json
    calibration: Path  # a small synthetic ChArUco capture (4 cameras x 6 poses, 640x480)

    def copy_session(self, dest: Path) -> Path:
        shutil.copytree(self.session, dest)
        return dest

    def copy_images(self, dest: Path) -> Path:
        shutil.copytree(self.images, dest)
        return dest


def _build(args: list[str]) -> None:
    from bodystudio.cli.main import main

    assert main([str(a) for a in args]) == 0, f"fixture command {args} failed"


@pytest.fixture(scope="session")
def studio(tmp_path_factory) -> Studio:
    root = tmp_path_factory.mktemp("studio")
    session, scan, board = root / "session", root / "scan.ply", root / "boardcap"
    _build(["synth", "session", session, "--cameras", "2", "--frames", "2", "--resolution", "160x120",
            "--template", "2k", "--kinect", "none", "--seed", "1"])
    _build(["synth", "scan", scan, "--vertices", "5000", "--no-holes"])
    board.mkdir()
    _build(["calib", "board", board / "board.png", "--squares-x", "5", "--squares-y", "4", "--dpi", "72",
            "--square-mm", "40", "--marker-mm", "30"])
    _build(["synth", "calibration", root / "cal", "--cameras", "4", "--poses", "6", "--width", "640", "--height",
            "480"])
    images = root / "images"
    for cam_dir in sorted(session.glob("cam_*")):
        (images / cam_dir.name).mkdir(parents=True)
        for f in sorted((cam_dir / "rgb").glob("*.png")):
            shutil.copy(f, images / cam_dir.name / f.name)
    return Studio(root, session, session / "calibration" / "cameras.json", images, scan, board, root / "cal")


def run_bad(args, capsys, phrase):
    """Run the CLI in process on ``args``; assert exit 2 and one stderr line (no traceback) holding
    ``phrase``; returns that line."""
    from bodystudio.cli.main import main

    code = main([str(a) for a in args])
    err = capsys.readouterr().err.strip()
    assert code == 2, err
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert phrase in err, err
    return err


@dataclass
class Rel7aArm:
    """rel7a's 8-frame 2k arm session ``clean``, a copy ``planted`` with two bad frames (frame 2's depth PNG truncated;
    frame 5: the subject lost and a bystander, not tracked before, given its id 0.85 m aside; the subject back under
    id 2 from frame 6 with the bystander beside it), and both captured without the model (``cap_clean``,
    ``cap_planted``; ``planted_stderr``: what the planted capture printed there)."""

    clean: Path
    planted: Path
    cap_clean: Path
    cap_planted: Path
    planted_stderr: str


REL7A_BYSTANDER_DX = 0.85


@pytest.fixture(scope="session")
def rel7a_arm(tmp_path_factory) -> Rel7aArm:
    import contextlib
    import io
    import json

    from bodystudio.capture.faults import restamp
    from bodystudio.muscle.synthetic import synth_arm_session

    root = tmp_path_factory.mktemp("rel7a_arm")
    clean, planted = root / "S", root / "P"
    synth_arm_session(clean, subject_seed=501, n_frames=8, resolution="2k")
    shutil.copytree(clean, planted)
    rel = "kinect/depth/00002.png"
    data = (planted / rel).read_bytes()
    (planted / rel).write_bytes(data[: len(data) // 2])
    restamp(planted, rel)
    for f in range(5, 8):
        rel = f"kinect/joints/{f:05d}.json"
        joints = json.loads((planted / rel).read_text())
        me = {k: joints[k] for k in ("names", "positions", "tracked")}
        other = {"player": 1, "names": joints["names"], "tracked": joints["tracked"],
                 "positions": [[x + REL7A_BYSTANDER_DX, y, z] for x, y, z in joints["positions"]]}
        joints.update({k: other[k] for k in ("names", "positions", "tracked")})
        joints["bodies"] = [other] if f == 5 else [other, {"player": 2, **me}]
        (planted / rel).write_text(json.dumps(joints))
        restamp(planted, rel)
    _build(["muscle", "capture", clean, "--out", root / "cap_S", "--no-model"])
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        _build(["muscle", "capture", planted, "--out", root / "cap_P", "--no-model"])
    return Rel7aArm(clean, planted, root / "cap_S", root / "cap_P", err.getvalue())
