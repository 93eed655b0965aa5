"""``--workers`` beyond the batch's work units (adversarial pass, round 2): ``reconstruct S --frames 0:1
--workers 3`` started three worker processes (imports, memory) for one chunk; ``--workers 64`` on a laptop
started 64. The local cluster now has at most one worker per work unit, and says so."""

from __future__ import annotations

import shutil

import pytest

from .conftest import run_inprocess


@pytest.mark.slow  # a local cluster and one reconstructed frame (~1 min on an idle machine)
def test_local_cluster_has_no_more_workers_than_units(studio, tmp_path, capfd):
    session = shutil.copytree(studio.session, tmp_path / "S")
    result = run_inprocess(["reconstruct", session, "--template", "2k", "--frames", "0:1", "--outer", "1", "--inner",
                            "2", "--no-refine-pose", "--no-score", "--joints", "hull", "--workers", "3",
                            "--accept-implausible"], capfd)  # 1 x 2 iterations: a fit the self-check refuses
    assert result.crashed is None and result.rc == 0, result.text[-1500:]
    assert ": 1 workers;" in result.stderr, result.stderr[-800:]
    assert (session / "reconstruct" / "run.json").is_file()
