"""``eval mirror`` on a session folder that was moved after the run (adversarial pass 3): run.json records the
session's absolute path, and the evaluation refused the moved pair although it is the same recording. The run
now also records the recording's fingerprint (the manifest digests of the Kinect files it read): a moved pair
whose fingerprints agree evaluates; a run put beside another recording is still refused."""

from __future__ import annotations

import shutil

import pytest

from bodystudio.cli.main import main

from .conftest import run_bad


@pytest.fixture(scope="module")
def run_pair(tmp_path_factory):
    root = tmp_path_factory.mktemp("adv3mov")
    s = root / "s"
    assert main(["synth", "mirror", str(s), "--subject-seed", "3", "--frames", "12", "--no-walk-in",
                 "--taller", "0.1"]) == 0
    assert main(["mirror", "init", str(s), "--resolution", "2k", "--frames", "1"]) == 0
    assert main(["mirror", "run", str(s), "--taller", "0.1", "--ramp-frames", "0",
                 "--out", str(root / "o.mp4")]) == 0
    return s


def test_moved_session_with_its_run_evaluates(run_pair, tmp_path, capsys):
    moved = tmp_path / "elsewhere" / "s"
    shutil.copytree(run_pair, moved)
    capsys.readouterr()
    assert main(["eval", "mirror", str(moved)]) == 0, capsys.readouterr().err
    assert '"init_stature_err_mm"' in capsys.readouterr().out


def test_run_beside_another_session_is_refused(run_pair, tmp_path, capsys):
    other = tmp_path / "other"
    assert main(["synth", "mirror", str(other), "--subject-seed", "4", "--frames", "12", "--no-walk-in",
                 "--taller", "0.1"]) == 0
    shutil.copytree(run_pair / "mirror", other / "mirror")
    capsys.readouterr()
    run_bad(["eval", "mirror", str(other)], capsys, "this run was made from session")
