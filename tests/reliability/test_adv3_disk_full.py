"""Every output when the disk is full (adversarial pass 3). A write that failed with ENOSPC escaped as a
traceback (exit 1) from every command; ``synth calibration`` left the images it had written (no board.json,
no ground truth) and ``synth scan`` wrote its ground truth before the scan, so a full disk at the scan left a
new subject's ground truth beside the previous scan. Now: one line naming the file, exit 2, and nothing of
the failed run is left (a previous result stays as it was). The disk is made full by an ``os.fsync`` that
fails with ENOSPC after ``n`` files (what a full disk does to a delayed write), or by a library write."""

from __future__ import annotations

import errno
import os

import pytest

from .conftest import assert_clean_error, run_inprocess


def _disk_full_after(monkeypatch, n_files: int) -> None:
    real, calls = os.fsync, [0]

    def fsync(fd):
        calls[0] += 1
        if calls[0] > n_files:
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(fd)

    monkeypatch.setattr(os, "fsync", fsync)


def _tree(folder):
    return sorted((p.relative_to(folder).as_posix(), p.read_bytes()) for p in folder.rglob("*") if p.is_file())


@pytest.mark.parametrize("n_files", [0, 3])
def test_synth_calibration_leaves_nothing(tmp_path, capfd, monkeypatch, n_files):
    _disk_full_after(monkeypatch, n_files)
    out = tmp_path / "cal"
    result = run_inprocess(["synth", "calibration", out, "--cameras", "4", "--poses", "4", "--width", "320",
                            "--height", "240"], capfd)
    assert_clean_error(result, 2, "No space left on device while writing")
    assert str(out) in result.stderr
    assert not out.exists(), _tree(out)


def test_synth_calibration_commits_a_manifest(tmp_path, capfd):
    out = tmp_path / "cal"
    result = run_inprocess(["synth", "calibration", out, "--cameras", "4", "--poses", "4", "--width", "320",
                            "--height", "240"], capfd)
    assert result.rc == 0, result.text[-800:]
    import json

    manifest = json.loads((out / "capture.json").read_text())
    listed = set(manifest["run"]["files"])
    assert {"board.json", "gt/cameras.json", "cam_00/00000.png", "cam_03/00003.png"} <= listed
    assert not (out / ".staging").exists() and not (out / ".lock").exists()


def test_synth_scan_keeps_the_previous_scan_and_truth(tmp_path, capfd, monkeypatch):
    scan = tmp_path / "scan.ply"
    assert run_inprocess(["synth", "scan", scan, "--vertices", "5000", "--subject-seed", "1"], capfd).rc == 0
    before = _tree(tmp_path)
    _disk_full_after(monkeypatch, 1)  # the ground truth's arrays written, the scan not
    result = run_inprocess(["synth", "scan", scan, "--vertices", "5000", "--subject-seed", "2"], capfd)
    assert_clean_error(result, 2, "No space left on device while writing")
    assert _tree(tmp_path) == before


@pytest.mark.parametrize("args", [["body", "export", "{t}/b.ply", "--resolution", "2k"],
                                  ["view", "{scan}", "--html", "{t}/v.html"]])
def test_single_file_outputs(studio, tmp_path, capfd, monkeypatch, args):
    _disk_full_after(monkeypatch, 0)
    result = run_inprocess([a.format(t=tmp_path, scan=studio.scan) for a in args], capfd)
    assert_clean_error(result, 2, "No space left on device while writing")
    assert not any(tmp_path.iterdir())


def test_a_library_write_is_one_line_too(tmp_path, capfd, monkeypatch):
    """A write that bypasses the atomic helpers (a library writing by file name) and fails with ENOSPC."""
    import bodystudio.geometry.mesh as mesh

    def save_mesh(path, *args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device", str(path))

    monkeypatch.setattr(mesh, "save_mesh", save_mesh)
    result = run_inprocess(["body", "export", tmp_path / "b.ply", "--resolution", "2k"], capfd)
    assert_clean_error(result, 2, "No space left on device while writing")
    assert "b.ply" in result.stderr
