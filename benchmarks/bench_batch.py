"""Batch jobs on dask.distributed (issue 14): frames/s at 1 and 2 workers, parallel efficiency, scheduler
overhead per task, I/O per unit, scans per hour, the accuracy cost of the chunk border, and arm-capture frames/s at
1 and 2 workers (one sequence per unit).

Everything runs in this one process, side by side: a LocalCluster of 1 worker, then one of 2 workers, each
warmed up (numba caches loaded, body models built) before the timed run of the same chunks with ``force``.
The chunk border: Rapid Skin with ``warm_start`` on, one sequential run over the session against chunks
of ``CHUNK`` frames (each chunk restarts from the generic template at its first frame).
"""

from __future__ import annotations

import os
import shutil
import tempfile
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np

from benchmarks.timing import markdown_table

CHUNK = 4


def _session(root: Path, quick: bool) -> Path:
    from bodystudio.capture.synth import synth_session

    path = root / "session"
    if quick:
        synth_session(path, n_cameras=2, n_frames=8, motion="walk", subject_seed=11, kinect="v2",
                      resolution=(160, 120), template="2k", n_background=1)
    else:
        synth_session(path, n_cameras=4, n_frames=16, motion="walk", subject_seed=11, kinect="v2",
                      resolution=(320, 240), template="6k", n_background=1)
    return path


def _frames_per_second(session: Path, workers: int, options, chunk: int) -> tuple[float, float, dict]:
    """(frames/s of the timed batch, worker seconds per frame, report) on a fresh LocalCluster of ``workers``."""
    from bodystudio.batch import batch_client, reconstruct_batch

    with batch_client(workers=workers) as client:
        reconstruct_batch(session, client, options, chunk=chunk, force=True)  # warm-up: caches, body models
        t0 = time.perf_counter()
        summary, report = reconstruct_batch(session, client, options, chunk=chunk, force=True)
        wall = time.perf_counter() - t0
        overhead = _scheduler_overhead_s(client)
    n = summary["frames"]
    unit_s = sum(report.seconds.values()) / n
    return n / wall, unit_s, {"overhead_s": overhead, "wall_s": wall}


def _noop(x):
    return x


def _scheduler_overhead_s(client, n: int = 200) -> float:
    """Seconds per task of ``n`` no-op tasks submitted together (scheduling, transfer, result)."""
    t0 = time.perf_counter()
    futures = client.map(_noop, range(n), pure=False)
    client.gather(futures)
    return (time.perf_counter() - t0) / n


def _chunk_border(root: Path, session: Path, template: str) -> list[list[object]]:
    from bodystudio.batch import ReconstructOptions, batch_client, reconstruct_batch
    from bodystudio.reconstruct.rapid_skin import RapidSkinParams
    from bodystudio.reconstruct.sequence import reconstruct_session

    rows = []
    seq, bat = root / "seq", root / "bat"
    for p in (seq, bat):
        shutil.copytree(session, p)
        shutil.rmtree(p / "reconstruct", ignore_errors=True)
    params = RapidSkinParams()
    s = reconstruct_session(seq, template=template, warm_start=True, params=params)
    with batch_client(workers=2) as client:
        b, _ = reconstruct_batch(bat, client, ReconstructOptions(template=template, warm_start=True,
                                                                 params=asdict(params)), chunk=CHUNK)
    cold = reconstruct_session(seq, template=template, warm_start=False, params=params)
    for name, r in (("sequential, warm start over the session", s), (f"chunks of {CHUNK}, warm start inside each", b),
                    ("no warm start (default; chunked = sequential exactly)", cold)):
        rows.append([name, f"{r['median_mm']:.2f}", f"{r['p90_mm']:.2f}", f"{r['hausdorff_mm']:.1f}"])
    return rows


def _scans_per_hour(root: Path, quick: bool) -> tuple[float, int, float]:
    from bodystudio.batch import batch_client, rig_batch
    from bodystudio.register.synthetic import save_synthetic_scan, synthetic_scan

    scans = root / "scans"
    scans.mkdir()
    n = 2 if quick else 4
    for k in range(n):
        scan, gt = synthetic_scan(101 + k, "a", 20_000 if quick else 50_000, 1.0, True)
        save_synthetic_scan(scans / f"scan{k}.ply", scan, gt)
        shutil.rmtree(scans / f"scan{k}.ply.gt", ignore_errors=True)
    for p in scans.iterdir():  # only the scans themselves
        if p.is_dir():
            shutil.rmtree(p)
    with batch_client(workers=2) as client:
        t0 = time.perf_counter()
        report = rig_batch(scans, root / "avatars", client, template="6k")
        wall = time.perf_counter() - t0
    assert not report.errors, report.errors
    return 3600.0 * n / wall, n, float(np.mean(list(report.seconds.values())))


def _arm_sessions(root: Path, quick: bool) -> tuple[list[Path], Path, int]:
    """Synthetic Kinect v2 arm sequences (elbow flexion, one subject each) and a small arm model on their
    template (2 training subjects: the capture's cost per frame, not its accuracy, is measured here)."""
    from bodystudio.body import build_body
    from bodystudio.muscle.arm import arm_template
    from bodystudio.muscle.model import learn_arm_model, save_arm_model
    from bodystudio.muscle.synthetic import sample_arm_subject, subject_arm_samples, synth_arm_session

    n, frames, res = (4, 8, "2k") if quick else (4, 24, "6k")
    sessions = []
    for k in range(n):
        path = root / "arms" / f"arm{k}"
        synth_arm_session(path, subject_seed=2 + k, motion="elbow_flex", n_frames=frames, kinect="v2",
                          distance_m=1.0, seed=k, resolution=res)
        sessions.append(path)
    samples = subject_arm_samples(sample_arm_subject(1000), res, n_shapes=1, n_poses=2)
    samples += subject_arm_samples(sample_arm_subject(1001), res, n_shapes=1, n_poses=2)
    model = learn_arm_model(samples, arm_template(build_body(resolution=res), "left"), population_size=3)
    model_path = root / "arms" / "model.npz"
    save_arm_model(model_path, model)
    return sessions, model_path, n * frames


def _muscle_frames_per_second(root: Path, quick: bool) -> tuple[list[list[object]], str]:
    """Arm capture (full mode) of several sequences, one per work unit: frames/s in process, then on fresh
    LocalClusters of 1 and 2 workers (each warmed up by a first run, the timed run with ``force``)."""
    from bodystudio.batch import MuscleOptions, batch_client, muscle_batch
    from bodystudio.muscle.capture import capture_session_arm

    sessions, model_path, n_frames = _arm_sessions(root, quick)
    options = MuscleOptions(mode="full", model=str(model_path))
    t0 = time.perf_counter()
    for s in sessions:
        capture_session_arm(s, model_path, "full")
    seq_fps = n_frames / (time.perf_counter() - t0)
    fps, unit = {}, {}
    for workers in (1, 2):
        out = root / f"arm_captures_{workers}"
        with batch_client(workers=workers) as client:
            muscle_batch(sessions, out, client, options)  # warm-up: imports, numba caches, body models
            t0 = time.perf_counter()
            report = muscle_batch(sessions, out, client, options, force=True)
            wall = time.perf_counter() - t0
        assert not report.errors, report.errors
        fps[workers] = n_frames / wall
        unit[workers] = sum(report.seconds.values()) / n_frames
    eff = fps[2] / (2 * fps[1])
    rows = [["sequential (no cluster, in process)", f"{seq_fps:.2f}", "-", "-"],
            ["LocalCluster, 1 worker", f"{fps[1]:.2f}", f"{unit[1]:.2f}", "1.00"],
            ["LocalCluster, 2 workers", f"{fps[2]:.2f}", f"{unit[2]:.2f}", f"{eff:.2f}"]]
    res = "2k" if quick else "6k"
    what = (f"{len(sessions)} synthetic Kinect v2 arm sequences of {n_frames // len(sessions)} frames (template "
            f"{res}, full mode: NICP, model-based filtering, refinement), one sequence per work unit "
            "(`bodystudio muscle capture S1 S2 S3 S4 --out DIR --model M --workers N`)")
    return rows, what


def run_muscle(quick: bool = False) -> str:
    """Only the muscle capture section (``python -m benchmarks.bench_batch --muscle [--quick]``)."""
    with tempfile.TemporaryDirectory(prefix="bench_batch_") as tmp:
        rows, what = _muscle_frames_per_second(Path(tmp), quick)
    load = os.getloadavg()
    return "\n".join([
        f"Arm capture batch: {what}; frames/s of the timed run after a warm-up on the same cluster. Load average "
        f"at the end: {load[0]:.1f} / {load[1]:.1f} / {load[2]:.1f} on {os.cpu_count()} cores.",
        "",
        markdown_table(["run", "frames/s", "worker s/frame", "parallel efficiency"], rows),
    ])


def run(quick: bool = False) -> str:
    from bodystudio.batch import ReconstructOptions
    from bodystudio.reconstruct.rapid_skin import RapidSkinParams
    from bodystudio.reconstruct.sequence import reconstruct_session

    template = "2k" if quick else "6k"
    with tempfile.TemporaryDirectory(prefix="bench_batch_") as tmp:
        root = Path(tmp)
        session = _session(root, quick)
        options = ReconstructOptions(template=template, score=False, params=asdict(RapidSkinParams()))
        t0 = time.perf_counter()
        seq = reconstruct_session(session, template=template, score=False)
        seq_fps = seq["frames"] / (time.perf_counter() - t0)
        fps1, unit1, info1 = _frames_per_second(session, 1, options, CHUNK)
        fps2, unit2, info2 = _frames_per_second(session, 2, options, CHUNK)
        load = os.getloadavg()
        mesh_bytes = np.mean([p.stat().st_size for p in (session / "reconstruct" / "meshes").glob("*.ply")])
        frame_bytes = sum(p.stat().st_size for p in session.rglob("*") if p.is_file() and "/mask/" in p.as_posix())
        frame_bytes /= seq["frames"]
        border = _chunk_border(root, session, template)
        sph, n_scans, rig_s = _scans_per_hour(root, quick)
    eff = fps2 / (2 * fps1)
    rows = [["sequential (no cluster, in process)", f"{seq_fps:.2f}", "-", "-"],
            ["LocalCluster, 1 worker", f"{fps1:.2f}", f"{unit1:.2f}", "1.00"],
            ["LocalCluster, 2 workers", f"{fps2:.2f}", f"{unit2:.2f}", f"{eff:.2f}"]]
    return "\n".join([
        "## Batch on dask.distributed (issue 14)",
        "",
        f"Rapid Skin, template {template}, {seq['frames']} frames in chunks of {CHUNK} (`bodystudio reconstruct "
        "--workers N --chunk 4`), each worker a single-threaded process; frames/s of the timed run after a warm-up "
        f"on the same cluster. Parallel efficiency = fps(2) / (2 fps(1)). Load average during the run: "
        f"{load[0]:.1f} / {load[1]:.1f} / {load[2]:.1f} on {os.cpu_count()} cores (other work on the machine "
        "takes cores from the workers, so the efficiency measured here is a lower bound).",
        "",
        markdown_table(["run", "frames/s", "worker s/frame", "parallel efficiency"], rows),
        "",
        f"Scheduler overhead per task (200 no-op tasks): {1000 * info1['overhead_s']:.1f} ms (1 worker), "
        f"{1000 * info2['overhead_s']:.1f} ms (2 workers). I/O per frame: {frame_bytes / 1e3:.0f} kB of masks read, "
        f"{mesh_bytes / 1e3:.0f} kB of mesh written.",
        "",
        f"Scans: {n_scans} synthetic scans ({'20K' if quick else '50K'} vertices) rigged (template 6k) on 2 "
        f"workers: **{sph:.0f} scans/hour** ({rig_s:.1f} s per scan on a worker).",
        "",
        f"Chunk border (warm start on, chunks of {CHUNK}, visible-surface error vs ground truth, mean over frames):",
        "",
        markdown_table(["run", "median mm", "p90 mm", "Hausdorff mm"], border),
        "",
        run_muscle(quick),
    ])


if __name__ == "__main__":
    import sys

    quick = "--quick" in sys.argv
    if "--scans" in sys.argv:
        # the scans stage alone, N times, each on a fresh 2-worker cluster closed at its end: the loop that
        # reproduced the heap abort at worker exit (docs/batch.md); run it under glibc's malloc checks:
        # LD_PRELOAD=libc_malloc_debug.so.0 GLIBC_TUNABLES=glibc.malloc.check=3 (and ulimit -c unlimited)
        for k in range(int(sys.argv[sys.argv.index("--scans") + 1])):
            with tempfile.TemporaryDirectory(prefix="bench_batch_") as tmp:
                sph, n, rig_s = _scans_per_hour(Path(tmp), True)
            print(f"run {k}: {sph:.0f} scans/hour ({rig_s:.1f} s per scan)", flush=True)
    else:
        print(run_muscle(quick) if "--muscle" in sys.argv else run(quick))
