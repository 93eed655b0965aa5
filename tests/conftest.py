"""Shared fixtures. The body model is expensive to load, so it is session-scoped."""

import pytest


@pytest.fixture(scope="session")
def default_body():
    from bodystudio.body import build_body

    return build_body()


@pytest.fixture(scope="session")
def body_2k():
    from bodystudio.body import build_body

    return build_body(resolution="2k")


@pytest.fixture(scope="session")
def small_synth_session(tmp_path_factory):
    """A noisy 4-camera, 3-frame, 320x240 synthetic studio session with a Kinect v1 (read-only: copy to modify)."""
    from bodystudio.capture.synth import synth_session

    path = tmp_path_factory.mktemp("synth") / "session"
    synth_session(path, n_cameras=4, n_frames=3, motion="arms_raise", subject_seed=7, kinect="v1",
                  resolution=(320, 240))
    return path
