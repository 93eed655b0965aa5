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


@pytest.fixture(scope="session")
def tiny_arm_model_path(tmp_path_factory):
    """A statistical arm model on the 2k left arm from two synthetic subjects and a 3-body population, saved
    as .npz (fast; for tests where the model's numbers do not matter). Read-only: copy to modify."""
    from bodystudio.body import build_body
    from bodystudio.muscle.arm import arm_template
    from bodystudio.muscle.model import learn_arm_model, save_arm_model
    from bodystudio.muscle.synthetic import sample_arm_subject, subject_arm_samples

    samples = subject_arm_samples(sample_arm_subject(1000), "2k", n_shapes=1, n_poses=2)
    samples += subject_arm_samples(sample_arm_subject(1001), "2k", n_shapes=1, n_poses=2)
    model = learn_arm_model(samples, arm_template(build_body(resolution="2k"), "left"), population_size=3)
    path = tmp_path_factory.mktemp("arm_model") / "tiny.npz"
    save_arm_model(path, model)
    return path
