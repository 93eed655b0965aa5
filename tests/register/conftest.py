"""Small synthetic scans shared by the register and rig tests (subjects 11-12; benchmarks use 101-103)."""

import pytest


@pytest.fixture(scope="session")
def small_scan(tmp_path_factory):
    """(path, scan Mesh, ground truth) of subject 12 in the T-pose, ~6000 vertices, 1 mm noise, holes."""
    from bodystudio.register.synthetic import save_synthetic_scan, synthetic_scan

    scan, gt = synthetic_scan(12, "t", 6000, 1.0, True)
    path = tmp_path_factory.mktemp("scans") / "s12.ply"
    save_synthetic_scan(path, scan, gt)
    return path, scan, gt
