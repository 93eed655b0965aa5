"""``bodystudio muscle capture S1 S2 ... --out DIR`` on a real 2-worker LocalCluster (issue 14).

One sequence per work unit: each unit folder is the single capture's folder exactly (same meshes as the
in-process capture); a corrupt sequence fails alone with its error recorded; a re-run redoes nothing (record
and mtimes) and ``--force`` redoes all; the CLI reaches an existing cluster through $BODYSTUDIO_SCHEDULER.
"""

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from bodystudio.batch import MuscleOptions, muscle_batch, unit_is_complete, unit_layout
from bodystudio.cli.main import main
from bodystudio.muscle.capture import capture_session_arm, load_arm_capture


@pytest.fixture(scope="module")
def arm_sessions(tmp_path_factory):
    """Three short synthetic Kinect v2 arm sequences on the 2k template (read-only: copy to modify)."""
    root = tmp_path_factory.mktemp("arms")
    for k, seed in enumerate((3, 4, 5)):
        assert main(["synth", "arm", str(root / f"s{k}"), "--subject-seed", str(seed), "--frames", "4",
                     "--resolution", "2k"]) == 0
    return root


def _copies(arm_sessions, tmp_path, names=("s0", "s1", "s2")):
    out = []
    for name in names:
        shutil.copytree(arm_sessions / name, tmp_path / name)
        out.append(tmp_path / name)
    return out


def _mtimes(root: Path) -> dict[str, int]:
    return {p.relative_to(root).as_posix(): p.stat().st_mtime_ns for p in root.rglob("*") if p.is_file()
            and p.name != "batch.json"}


def test_batch_matches_sequential_and_rerun_redoes_nothing(arm_sessions, tiny_arm_model_path, cluster, tmp_path):
    sessions = _copies(arm_sessions, tmp_path, ("s0", "s1"))
    options = MuscleOptions(mode="full", model=str(tiny_arm_model_path))
    out = tmp_path / "out"
    report = muscle_batch(sessions, out, cluster, options)
    assert report.status == {"s0": "done", "s1": "done"}, report.errors
    for s in sessions:
        # the workers run single-threaded (batch.WORKER_ENV), this process with every BLAS thread: the capture does
        # not depend on the thread count (muscle.normal_equations; tests/muscle/test_thread_independence.py)
        expected = capture_session_arm(s, tiny_arm_model_path, "full")
        got = load_arm_capture(out / s.name)  # the single capture's folder format, read by eval and extend
        assert got.mode == "full" and got.frame_ids == [0, 1, 2, 3]
        np.testing.assert_allclose(got.vertices, expected.vertices, atol=1e-6)
    # two subjects: each unit captured its own sequence
    assert np.abs(load_arm_capture(out / "s0").vertices - load_arm_capture(out / "s1").vertices).max() > 5e-3
    from bodystudio.cli.muscle import evaluate_capture_folder

    assert evaluate_capture_folder(out / "s0")["median_mm"] < 25.0  # an arm captured, not the template

    # the re-run skips both sequences (no file rewritten); --force redoes them
    before = _mtimes(out)
    again = muscle_batch(sessions, out, cluster, options)
    assert set(again.status.values()) == {"skipped"}
    assert _mtimes(out) == before
    record = json.loads((out / "batch.json").read_text())["units"]
    assert {u["action"] for u in record.values()} == {"skipped"} and {u["status"] for u in record.values()} == {"done"}
    assert record["s0"]["session"] == str(sessions[0].resolve())
    forced = muscle_batch(sessions, out, cluster, options, force=True)
    assert set(forced.status.values()) == {"done"}
    after = _mtimes(out)
    assert all(after[k] > before[k] for k in before if k.endswith("unit.json"))


def test_changed_input_redoes_only_that_sequence(arm_sessions, cluster, tmp_path):
    """Inputs are the session's files and the options: a changed depth frame redoes its sequence only; a
    unit whose file was edited after its commit is not complete (checksums) and is redone."""
    from bodystudio.capture.session import SessionWriter, open_session

    sessions = _copies(arm_sessions, tmp_path, ("s0", "s1"))
    options = MuscleOptions(mode="nicp")
    out = tmp_path / "out"
    muscle_batch(sessions, out, cluster, options)
    depth = open_session(sessions[1]).frame(2).kinect_depth_m
    with SessionWriter(sessions[1], update=True) as w:
        w.write_kinect_depth(2, np.where(depth > 0, depth + 0.01, 0.0))
    report = muscle_batch(sessions, out, cluster, options)
    assert report.status == {"s0": "skipped", "s1": "done"}
    (out / "s0" / "meshes" / "00001.ply").write_bytes(b"edited")
    assert not unit_is_complete(unit_layout(out / "s0"), json.loads((out / "batch.json").read_text())
                                ["units"]["s0"]["inputs_sha256"])
    report = muscle_batch(sessions, out, cluster, options)
    assert report.status == {"s0": "done", "s1": "skipped"}
    load_arm_capture(out / "s0")
    # other frames are other inputs
    report = muscle_batch(sessions, out, cluster, MuscleOptions(mode="nicp", frames=3))
    assert set(report.status.values()) == {"done"} and load_arm_capture(out / "s1").frame_ids == [0, 1, 2]


def test_corrupt_sequence_fails_alone(arm_sessions, cluster, tmp_path):
    """Two of s1's four depth frames truncated: more than the capture skips (rel7a: 25 %), so s1 fails, alone."""
    sessions = _copies(arm_sessions, tmp_path)
    depth, depth2 = (sessions[1] / "kinect" / "depth" / f"{i:05d}.png" for i in (1, 2))
    good, good2 = depth.read_bytes(), depth2.read_bytes()
    depth.write_bytes(good[: len(good) // 2])  # truncated depth frames
    depth2.write_bytes(good2[: len(good2) // 2])
    out = tmp_path / "out"
    report = muscle_batch(sessions, out, cluster, MuscleOptions(mode="nicp"))
    assert report.status == {"s0": "done", "s1": "failed", "s2": "done"}
    assert "corrupted" in report.errors["s1"] and "\n" not in report.errors["s1"], report.errors
    assert not (out / "s1").exists() or not list((out / "s1").iterdir())
    for name in ("s0", "s2"):
        assert load_arm_capture(out / name).n_frames == 4
    record = json.loads((out / "batch.json").read_text())["units"]
    assert record["s1"]["status"] == "failed" and "corrupted" in record["s1"]["error"]
    assert record["s0"]["status"] == "done" and record["s0"]["action"] == "computed"

    # the re-run redoes only the failed sequence
    before = _mtimes(out)
    report = muscle_batch(sessions, out, cluster, MuscleOptions(mode="nicp"))
    assert report.status == {"s0": "skipped", "s1": "failed", "s2": "skipped"}
    assert _mtimes(out) == before

    # the frames repaired (same manifest, so the same inputs sha256): the failed sequence is run again, not
    # answered with the earlier task's error (each submission has its own dask key)
    depth.write_bytes(good)
    depth2.write_bytes(good2)
    report = muscle_batch(sessions, out, cluster, MuscleOptions(mode="nicp"))
    assert report.status == {"s0": "skipped", "s1": "done", "s2": "skipped"}, report.errors
    assert load_arm_capture(out / "s1").n_frames == 4


def test_cli_batch_on_the_scheduler_of_the_environment(arm_sessions, cluster, tmp_path, capsys, monkeypatch):
    """Several SESSIONs make a batch; $BODYSTUDIO_SCHEDULER names the cluster (here the tests' own)."""
    sessions = _copies(arm_sessions, tmp_path, ("s0", "s2"))
    monkeypatch.setenv("BODYSTUDIO_SCHEDULER", cluster.scheduler.address)
    out = tmp_path / "out"
    assert main(["muscle", "capture", *map(str, sessions), "--out", str(out), "--no-model"]) == 0
    assert "2 workers" in capsys.readouterr().err
    assert sorted(p.name for p in out.iterdir()) == [".batch", "batch.json", "s0", "s2"] or \
        sorted(p.name for p in out.iterdir()) == ["batch.json", "s0", "s2"]
    assert load_arm_capture(out / "s2").mode == "nicp"
    sessions[1].joinpath("session.json").write_text("{")  # a sequence that cannot be opened: the batch fails
    code = main(["muscle", "capture", *map(str, sessions), "--out", str(out), "--no-model"])
    err = capsys.readouterr().err
    assert code == 2 and "1 of 2 sequences failed" in err.strip().splitlines()[-1] and "s2" in err


def test_killed_worker_mid_sequence_completes(arm_sessions, cluster, tmp_path):
    """A worker SIGKILLed while it holds a sequence (lock taken, files staged): Dask reschedules the unit, the
    new attempt takes over the stale lock and discards the staging; both sequences complete."""
    import os
    import signal
    import threading
    import time

    import quickrig

    from bodystudio.batch import worker_main_thread_imports

    sessions = _copies(arm_sessions, tmp_path, ("s0", "s1"))
    out, pids = tmp_path / "out", tmp_path / "pids"
    pids.mkdir()
    killed = []

    def kill_first_unit():
        deadline = time.monotonic() + 120
        while not list(pids.iterdir()) and time.monotonic() < deadline:
            time.sleep(0.02)
        for p in pids.iterdir():
            pid = int(p.name)
            held = [lk for lk in out.glob("*/.lock") if json.loads(lk.read_text())["pid"] == pid]
            staged = [st for st in out.glob("*/.staging") if any(st.rglob("*.ply"))]
            killed.append((pid, held, staged))
            os.kill(pid, signal.SIGKILL)
            return

    killer = threading.Thread(target=kill_first_unit)
    killer.start()
    report = muscle_batch(sessions, out, cluster, MuscleOptions(mode="nicp"),
                          setup=quickrig.SlowCaptureWrite(str(pids), 3.0))
    killer.join()
    assert killed and killed[0][1] and killed[0][2], f"no unit killed while holding its lock and staging: {killed}"
    assert report.status == {"s0": "done", "s1": "done"}, report.errors
    for s in sessions:
        assert load_arm_capture(out / s.name).n_frames == 4
        assert not (out / s.name / ".staging").exists() and not (out / s.name / ".lock").exists()
        assert unit_is_complete(unit_layout(out / s.name), json.loads((out / "batch.json").read_text())
                                ["units"][s.name]["inputs_sha256"])
    cluster.wait_for_workers(2, timeout=60)  # the nanny restarts the killed worker for the next tests
    assert all(all(flags.values()) for flags in cluster.run(worker_main_thread_imports).values())


def test_each_sequence_gets_its_own_measured_shape(arm_sessions, tiny_arm_model_path, cluster, tmp_path):
    """``muscle capture S1 S2 --shape A --shape B``: each unit captures with its own subject's shape."""
    from dataclasses import asdict

    from bodystudio.muscle.model import ArmShapeParams

    sessions = _copies(arm_sessions, tmp_path, ("s0", "s1"))
    shapes = [ArmShapeParams(bmi=22.0, muscularity=0.3, height_m=1.70, arm_length_m=0.50),
              ArmShapeParams(bmi=27.0, muscularity=0.6, height_m=1.85, arm_length_m=0.56, sex=0.0)]
    out = tmp_path / "out"
    options = MuscleOptions(mode="model", model=str(tiny_arm_model_path), frames=2)
    report = muscle_batch(sessions, out, cluster, options, shapes=[asdict(s) for s in shapes])
    assert report.status == {"s0": "done", "s1": "done"}, report.errors
    for name, shape in zip(("s0", "s1"), shapes, strict=True):
        assert load_arm_capture(out / name).shape == shape
    with pytest.raises(Exception, match="2 measured shapes for 1 sessions"):
        muscle_batch(sessions[:1], tmp_path / "out2", cluster, options, shapes=[None, None])


def test_one_bad_frame_is_skipped_in_a_batch_not_the_sequence(arm_sessions, cluster, tmp_path):
    """rel7a in a batch: one truncated depth frame of s1 (1 of 4) is skipped and recorded, s1 still done."""
    sessions = _copies(arm_sessions, tmp_path, ("s1",))
    depth = sessions[0] / "kinect" / "depth" / "00001.png"
    depth.write_bytes(depth.read_bytes()[:100])
    out = tmp_path / "out"
    report = muscle_batch(sessions, out, cluster, MuscleOptions(mode="nicp"))
    assert report.status == {"s1": "done"}, report.errors
    params = json.loads((out / "s1" / "params.json").read_text())
    assert [s["frame"] for s in params["skipped_frames"]] == [1]
    assert not (out / "s1" / "meshes" / "00001.ply").exists() and (out / "s1" / "meshes" / "00002.ply").exists()
