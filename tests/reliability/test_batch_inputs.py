"""Bad input to the batch commands (``batch rig``, ``reconstruct --workers/--scheduler/--chunk``): one line on
stderr, exit 2, refused before any cluster starts or any output is written (issue 14); also `muscle capture`
with several sessions or --workers/--scheduler."""

import os
import subprocess
import sys

import pytest

from bodystudio.batch import check_worker_versions, max_local_workers, resolve_scheduler
from bodystudio.errors import InputError

from .conftest import run_bad


@pytest.fixture()
def scans(tmp_path):
    folder = tmp_path / "scans"
    folder.mkdir()
    (folder / "a.ply").write_bytes(b"ply\n")
    return folder


@pytest.mark.parametrize("extra, phrase", [
    (["--workers", "0"], "--workers 0"),
    (["--workers", "-3"], "--workers -3"),
    (["--scheduler", "localhost:8786"], "not a scheduler address"),
    (["--scheduler", "tcp://bad host:1"], "not a scheduler address"),
    (["--scheduler", "tcp://127.0.0.1:1", "--workers", "2"], "--scheduler and --workers"),
    (["--template", "99k"], "--template"),
])
def test_batch_rig_bad_options(scans, tmp_path, capsys, extra, phrase):
    run_bad(["batch", "rig", scans, "--out", tmp_path / "out", *extra], capsys, phrase)
    assert not (tmp_path / "out").exists()


def test_batch_rig_bad_folders(scans, tmp_path, capsys):
    run_bad(["batch", "rig", tmp_path / "nope", "--out", tmp_path / "out"], capsys, "no such folder")
    empty = tmp_path / "empty"
    empty.mkdir()
    run_bad(["batch", "rig", empty, "--out", tmp_path / "out"], capsys, "no scan files")
    (scans / "a.obj").write_text("v 0 0 0\n")
    run_bad(["batch", "rig", scans, "--out", tmp_path / "out"], capsys, "rename one")
    (scans / "a.obj").unlink()
    (tmp_path / "file").write_text("")
    run_bad(["batch", "rig", scans, "--out", tmp_path / "file"], capsys, "not a folder")
    assert not (tmp_path / "out").exists()


def test_workers_beyond_the_machine_are_refused(scans, two_sessions, tmp_path, capsys):
    """``--workers 100000`` had no upper bound (adversarial pass 3): a local cluster as large as the batch's
    units started (a 10000-scan folder, 10000 processes). Now more than 4 per core is one line, before any
    cluster, naming the machine's cap and --scheduler; the cap itself is accepted by the check."""
    cap = max_local_workers()
    assert resolve_scheduler(None, cap) is None
    too_many = str(cap + 1)
    run_bad(["batch", "rig", scans, "--out", tmp_path / "out", "--workers", too_many], capsys,
            f"--workers {too_many}: at most {cap} on this machine")
    session = tmp_path / "s"
    session.mkdir()
    run_bad(["reconstruct", session, "--workers", "100000"], capsys, "--workers 100000: at most")
    run_bad(["muscle", "capture", *two_sessions, "--out", tmp_path / "m", "--no-model", "--workers", "100000"], capsys,
            "--scheduler for a cluster")
    assert not (tmp_path / "out").exists() and not (tmp_path / "m").exists()
    assert not (session / "reconstruct").exists()


def test_unreachable_scheduler_is_one_line(scans, tmp_path):
    """A scheduler nobody listens on: one line within the connect timeout (the subprocess limit is a hang guard)."""
    env = {**os.environ, "BODYSTUDIO_SCHEDULER": "tcp://127.0.0.1:1"}
    proc = subprocess.run([sys.executable, "-m", "bodystudio.cli.main", "batch", "rig", str(scans), "--out",
                           str(tmp_path / "out")], env=env, capture_output=True, text=True, timeout=90)
    err = proc.stderr.strip()
    assert proc.returncode == 2 and len(err.splitlines()) == 1, err
    assert "$BODYSTUDIO_SCHEDULER tcp://127.0.0.1:1: cannot reach the scheduler" in err, err


def test_bad_scheduler_variable_is_named():
    os.environ["BODYSTUDIO_SCHEDULER"] = "8786"
    try:
        with pytest.raises(InputError, match=r"\$BODYSTUDIO_SCHEDULER '8786': not a scheduler address"):
            resolve_scheduler(None, None)
        assert resolve_scheduler(None, 2) is None  # --workers asks for a local cluster over the variable
    finally:
        del os.environ["BODYSTUDIO_SCHEDULER"]


def test_worker_version_mismatch_refused():
    check_worker_versions({"tcp://a:1": "0.1.0"}, "0.1.0")
    with pytest.raises(InputError, match=r"1 of 2 workers run bodystudio 0\.0\.9 .*install the same version"):
        check_worker_versions({"tcp://a:1": "0.1.0", "tcp://b:1": "0.0.9"}, "0.1.0")


@pytest.mark.parametrize("extra, phrase", [
    (["--chunk", "0"], "--chunk 0"),
    (["--workers", "0"], "--workers 0"),
    (["--scheduler", "http://x:1"], "not a scheduler address"),
])
def test_reconstruct_bad_cluster_options(tmp_path, capsys, extra, phrase):
    session = tmp_path / "s"
    session.mkdir()
    run_bad(["reconstruct", session, *extra], capsys, phrase)
    assert not (session / "reconstruct").exists()


@pytest.fixture()
def two_sessions(tmp_path):
    """Two folders standing for arm sessions: the cluster options are refused before a session is read."""
    out = []
    for name in ("a", "b"):
        (tmp_path / name).mkdir()
        out.append(tmp_path / name)
    return out


@pytest.mark.parametrize("extra, phrase", [
    (["--workers", "0"], "--workers 0"),
    (["--workers", "-1"], "--workers -1"),
    (["--scheduler", "localhost:8786"], "not a scheduler address"),
    (["--scheduler", "tcp://127.0.0.1:1", "--workers", "2"], "--scheduler and --workers"),
    (["--frames", "0"], "--frames 0"),
    (["--resolution", "13k"], "--resolution '13k'"),
    (["--side", "up"], "--side 'up'"),
])
def test_muscle_capture_batch_bad_options(two_sessions, tmp_path, capsys, extra, phrase):
    run_bad(["muscle", "capture", *two_sessions, "--out", tmp_path / "out", "--no-model", *extra], capsys, phrase)
    assert not (tmp_path / "out").exists()


def test_muscle_capture_batch_bad_inputs(two_sessions, tmp_path, capsys):
    a, b = two_sessions
    out = tmp_path / "out"
    run_bad(["muscle", "capture", a, tmp_path / "nope", "--out", out, "--no-model"], capsys, "no such session folder")
    (tmp_path / "x").mkdir()
    (tmp_path / "x" / "a").mkdir()
    run_bad(["muscle", "capture", a, tmp_path / "x" / "a", "--out", out, "--no-model"], capsys, "rename one")
    (tmp_path / "file").write_text("")
    run_bad(["muscle", "capture", a, b, "--out", tmp_path / "file", "--no-model"], capsys, "not a folder")
    junk = tmp_path / "m.npz"
    junk.write_bytes(b"not a model")
    run_bad(["muscle", "capture", a, b, "--out", out, "--model", junk], capsys, "not a bodystudio arm model")
    assert not out.exists()
    # --force belongs to a batch; a single capture writes a new folder
    run_bad(["muscle", "capture", a, "--out", out, "--no-model", "--force"], capsys, "--force is for a batch")
    assert not out.exists()


def test_muscle_capture_batch_unreachable_scheduler(two_sessions, tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("BODYSTUDIO_SCHEDULER", "tcp://127.0.0.1:1")
    run_bad(["muscle", "capture", *two_sessions, "--out", tmp_path / "out", "--no-model"], capsys,
            "$BODYSTUDIO_SCHEDULER tcp://127.0.0.1:1: cannot reach the scheduler")
    assert not (tmp_path / "out").exists()


def test_muscle_capture_batch_needs_one_shape_per_session(two_sessions, tmp_path, capsys):
    """One --shape for two sessions would give both subjects the same measured shape: refused."""
    shape = "bmi=24,muscularity=0.4,height_m=1.75,arm_length_m=0.55"
    run_bad(["muscle", "capture", *two_sessions, "--out", tmp_path / "out", "--model", tmp_path / "m.npz",
             "--shape", shape], capsys, "--shape: 1 given for 2 sessions")
    assert not (tmp_path / "out").exists()


def test_batch_rig_out_onto_the_scans_folder(scans, capsys):
    """Adversarial pass, round 2: --out SCANS_DIR wrote STEM.glb avatars among the scans (a .glb scan
    replaced by its avatar; the next run took the avatars for scans)."""
    (scans / "b.glb").write_bytes(b"glTF")
    run_bad(["batch", "rig", scans, "--out", scans], capsys, "is the scans folder")
    assert sorted(p.name for p in scans.iterdir()) == ["a.ply", "b.glb"]


@pytest.mark.parametrize("address", ["tcp://10.0.0.5:8786\n", "tcp://10.0.0.5:8786\nrest"])
def test_a_scheduler_address_with_a_line_break_is_refused(address, monkeypatch):
    """mutFF's note: the address rule ended in ``$``, which matches before a final newline, so
    ``"tcp://h:1\\n"`` (an address read from a file with its line end) passed for a scheduler address."""
    monkeypatch.delenv("BODYSTUDIO_SCHEDULER", raising=False)
    with pytest.raises(InputError, match="not a scheduler address"):
        resolve_scheduler(address, None)
    assert resolve_scheduler("tcp://10.0.0.5:8786", None) == "tcp://10.0.0.5:8786"
    assert resolve_scheduler("tls://node-3.lab:8786/", None) == "tls://node-3.lab:8786/"
