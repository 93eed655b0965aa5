"""``muscle capture S1 S2 --frames N`` with N beyond a session's frames (adversarial pass, round 2).

Before: the cluster started, the short session's unit failed on its worker and the batch left OUT/ with a
batch.json behind; now the batch is refused before any cluster starts, with one line naming the session's
frame count, and OUT/ is not created. The single capture refused it already (muscle.capture)."""

from __future__ import annotations

import shutil

import pytest

from bodystudio.cli.main import main

from .conftest import assert_clean_error, run_inprocess


@pytest.fixture(scope="module")
def two_sessions(tmp_path_factory):
    root = tmp_path_factory.mktemp("adv2arm")
    a = root / "a"
    assert main(["synth", "arm", str(a), "--subject-seed", "5", "--frames", "3", "--resolution", "2k"]) == 0
    shutil.copytree(a, root / "b")
    return a, root / "b"


def test_batch_frames_beyond_a_session_are_refused_before_the_cluster(two_sessions, tmp_path, capfd):
    a, b = two_sessions
    out = tmp_path / "caps"
    result = run_inprocess(["muscle", "capture", a, b, "--out", out, "--no-model", "--frames", "4", "--workers", "1"],
                           capfd)
    assert_clean_error(result, 2, "has 3 frames")
    assert not out.exists()
