"""A real 2-worker LocalCluster (processes) shared by the batch tests, and the quick-rig worker setup."""

import sys
from pathlib import Path

import cloudpickle
import pytest

sys.path.insert(0, str(Path(__file__).parent))
import quickrig  # noqa: E402

# The workers do not have tests/batch on their path: ship the helper module by value.
cloudpickle.register_pickle_by_value(quickrig)


@pytest.fixture(scope="session")
def cluster():
    from bodystudio.batch import batch_client

    with batch_client(workers=2) as client:
        yield client


@pytest.fixture(scope="session")
def batch_session(tmp_path_factory):
    """A 2-camera, 4-frame 160x120 walk with ground truth (read-only: copy to modify)."""
    from bodystudio.capture.synth import synth_session

    path = tmp_path_factory.mktemp("batch") / "s"
    synth_session(path, n_cameras=2, n_frames=4, motion="walk", subject_seed=7, kinect="v2", resolution=(160, 120),
                  noise=False, template="2k", n_background=1)
    return path
