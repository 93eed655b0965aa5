"""``bodystudio reconstruct --workers/--chunk`` on a real 2-worker LocalCluster (issue 14).

Same meshes as the sequential path; a re-run skips the unchanged chunks (record and mtimes), ``--force``
redoes them; a SIGKILLed client leaves only complete chunks, and the re-run redoes none of them.
"""

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np
import pytest

from bodystudio.batch import CHUNKS_DIR, RECORD, ReconstructOptions, reconstruct_batch
from bodystudio.geometry.mesh import load_mesh
from bodystudio.reconstruct.rapid_skin import RapidSkinParams
from bodystudio.reconstruct.sequence import read_reconstruction, reconstruct_session

PARAMS = RapidSkinParams(outer_iterations=2, inner_iterations=4)
OPTIONS = ReconstructOptions(template="2k", refine_pose=False, score=True, params=asdict(PARAMS))
CLI_RUN = ["--template", "2k", "--outer", "2", "--inner", "4", "--no-refine-pose", "--no-score"]


def _copy(src, tmp_path, name="s"):
    dst = tmp_path / name
    shutil.copytree(src, dst)
    return dst


def _mtimes(root: Path) -> dict[str, int]:
    return {p.relative_to(root).as_posix(): p.stat().st_mtime_ns for p in root.rglob("*") if p.is_file()
            and p.name != RECORD}


def test_batch_matches_sequential(batch_session, cluster, tmp_path):
    seq = _copy(batch_session, tmp_path, "seq")
    bat = _copy(batch_session, tmp_path, "bat")
    expected = reconstruct_session(seq, template="2k", refine_pose=False, params=PARAMS)
    summary, report = reconstruct_batch(bat, cluster, OPTIONS, chunk=3)
    assert report.status == {"00000-00002": "done", "00003-00003": "done"}
    run, meshes = read_reconstruction(bat)  # one complete run, checksummed like a sequential one
    assert run["frames"] == [0, 1, 2, 3] and run["batch"]["chunk"] == 3
    for fid, path in read_reconstruction(seq)[1].items():
        np.testing.assert_allclose(load_mesh(meshes[fid]).vertices, load_mesh(path).vertices, atol=1e-9)
    assert summary["p90_mm"] == pytest.approx(expected["p90_mm"], abs=1e-6)
    assert expected["p90_mm"] < 40.0  # a real reconstruction, not the posed template

    # the re-run skips every chunk (no file rewritten); --force redoes them
    before = _mtimes(bat / "reconstruct" / CHUNKS_DIR)
    _, again = reconstruct_batch(bat, cluster, OPTIONS, chunk=3)
    assert set(again.status.values()) == {"skipped"}
    assert _mtimes(bat / "reconstruct" / CHUNKS_DIR) == before
    record = json.loads((bat / "reconstruct" / CHUNKS_DIR / RECORD).read_text())["units"]
    assert {u["action"] for u in record.values()} == {"skipped"}
    _, forced = reconstruct_batch(bat, cluster, OPTIONS, chunk=3, force=True)
    assert set(forced.status.values()) == {"done"}
    after = _mtimes(bat / "reconstruct" / CHUNKS_DIR)
    assert all(after[k] > before[k] for k in before if k.endswith("unit.json"))


def test_changed_options_redo_partial_chunk_redone(batch_session, cluster, tmp_path):
    """A chunk's inputs include the options: other options redo it; a leftover staging and stale locks (a
    killed worker and client) are discarded, the partial chunk redone and the complete one kept."""
    s = _copy(batch_session, tmp_path)
    reconstruct_batch(s, cluster, OPTIONS, chunk=2)
    other = ReconstructOptions(**{**asdict(OPTIONS), "params": asdict(RapidSkinParams(outer_iterations=1,
                                                                                       inner_iterations=4))})
    _, report = reconstruct_batch(s, cluster, other, chunk=2)
    assert set(report.status.values()) == {"done"}
    unit = s / "reconstruct" / CHUNKS_DIR / "00002-00003"
    (unit / ".staging" / "meshes").mkdir(parents=True)
    (unit / ".staging" / "meshes" / "00002.ply").write_bytes(b"half a mesh")
    # what a SIGKILLed client and worker leave: their locks, held by processes that are gone
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    for lock in (s / "reconstruct" / ".lock", unit / ".lock"):
        lock.write_text(json.dumps({"pid": dead.pid, "host": socket.gethostname(), "command": "killed"}))
    _, report = reconstruct_batch(s, cluster, other, chunk=2)
    assert report.status == {"00000-00001": "skipped", "00002-00003": "done"}
    assert not (unit / ".staging").exists() and not (unit / ".lock").exists()
    assert not (s / "reconstruct" / ".lock").exists()
    read_reconstruction(s)


def test_batch_chunks_share_the_runs_bone_lengths(batch_session, cluster, tmp_path):
    """``--bone-lengths sequence``: every chunk poses with the median over the whole run, as the sequential path
    does (a chunk's own median would differ), and the lengths are part of the chunks' inputs."""
    from bodystudio.body.kinect import kinect_joint_names
    from bodystudio.capture.session import open_session
    from bodystudio.reconstruct.sequence import frame_joints

    names = kinect_joint_names("v2")
    knee, ankle = names.index("KneeLeft"), names.index("AnkleLeft")
    session = open_session(batch_session)
    jdir = tmp_path / "joints"
    jdir.mkdir()
    for fid, stretch in zip(session.frame_ids, (0.0, 0.2, -0.1, 0.15), strict=True):  # jittered shins
        J = frame_joints(session, session.frame(fid), "tracker", None)
        J[[ankle, names.index("FootLeft")]] += stretch * (J[ankle] - J[knee])
        (jdir / f"{fid:05d}.json").write_text(json.dumps({"names": names, "positions": J.tolist()}))
    seq, bat = _copy(batch_session, tmp_path, "seq"), _copy(batch_session, tmp_path, "bat")
    reconstruct_session(seq, template="2k", refine_pose=False, params=PARAMS, joints="file", joints_path=jdir,
                        score=False)
    opts = ReconstructOptions(**{**asdict(OPTIONS), "joints": "file", "joints_path": str(jdir), "score": False})
    reconstruct_batch(bat, cluster, opts, chunk=3)
    for fid, path in read_reconstruction(seq)[1].items():
        np.testing.assert_allclose(load_mesh(read_reconstruction(bat)[1][fid]).vertices, load_mesh(path).vertices,
                                   atol=1e-9)
    assert json.loads((bat / "reconstruct" / "run.json").read_text())["bone_lengths"] == "sequence"


@pytest.mark.slow  # ~30 s on the loaded 2-core machine (a second cluster); the fast stand-in is the test above
def test_killed_client_rerun_redoes_nothing_done(batch_session, cluster, tmp_path):
    """SIGKILL the CLI client as soon as a chunk is complete; the re-run keeps every complete chunk as is."""
    s = _copy(batch_session, tmp_path)
    chunks = s / "reconstruct" / CHUNKS_DIR
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).parents[2])}
    proc = subprocess.Popen([sys.executable, "-m", "bodystudio.cli.main", "reconstruct", str(s), *CLI_RUN,
                             "--workers", "2", "--chunk", "1"], env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, start_new_session=True)
    try:
        deadline = time.monotonic() + 120
        while not list(chunks.glob("*/unit.json")) and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.01)
        proc.kill()
        proc.wait()
    finally:
        time.sleep(1.5)  # the workers notice their client is gone (bodystudio.batch exits them)
        os.killpg(proc.pid, signal.SIGKILL) if _group_alive(proc.pid) else None
    # done: a unit past its commit point (its manifest written, or a commit record its worker was killed
    # carrying out: the re-run finishes that one, it does not redo it)
    done = sorted({p.parent.name for p in chunks.glob("*/unit.json")}
                  | {p.parents[1].name for p in chunks.glob("*/.staging/commit.json")})
    assert done, proc.stderr.read().decode()
    settled = [name for name in done if not (chunks / name / ".staging").exists()]
    before = {name: _mtimes(chunks / name) for name in settled}
    _, report = reconstruct_batch(s, cluster, ReconstructOptions(template="2k", refine_pose=False, score=False,
                                                                 params=asdict(PARAMS)), chunk=1)
    assert {n for n, st in report.status.items() if st == "skipped"} == set(done)
    assert {name: _mtimes(chunks / name) for name in settled} == before
    record = json.loads((chunks / RECORD).read_text())["units"]
    assert all(record[n]["action"] == "skipped" for n in done)
    assert read_reconstruction(s)[0]["frames"] == [0, 1, 2, 3]


def _group_alive(pgid: int) -> bool:
    try:
        os.killpg(pgid, 0)
    except ProcessLookupError:
        return False
    return True
