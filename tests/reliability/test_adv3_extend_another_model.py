"""``muscle model extend --centre regressed|sex`` with a capture made with another model (adversarial pass 3):
the capture's rest mesh sits at the shoulder its own model regressed, but extend recomputed that shoulder from
MODEL, so extending another model of the same arm template (built from other subjects, whose joint regression
differs) centred the capture's meshes on another point, with exit 0. The capture now records its model's regressed
joints (params.json ``regressed_joints``) and the extension uses them, whichever model is extended."""

from __future__ import annotations

import numpy as np
import pytest


@pytest.fixture(scope="module")
def capture_and_models(tmp_path_factory, tiny_arm_model_path):
    from bodystudio.body import build_body
    from bodystudio.cli.main import main
    from bodystudio.muscle.arm import arm_template
    from bodystudio.muscle.capture import capture_session_arm, load_arm_capture, write_arm_capture
    from bodystudio.muscle.model import learn_arm_model, load_arm_model
    from bodystudio.muscle.synthetic import sample_arm_subject, subject_arm_samples

    root = tmp_path_factory.mktemp("adv3ext")
    assert main(["synth", "arm", str(root / "s"), "--subject-seed", "5", "--frames", "3", "--resolution", "2k"]) == 0
    first = load_arm_model(tiny_arm_model_path)
    write_arm_capture(root / "cap", capture_session_arm(root / "s", tiny_arm_model_path, frames=2))
    capture = load_arm_capture(root / "cap")
    samples = [s for seed in (2000, 2001) for s in subject_arm_samples(sample_arm_subject(seed), "2k", n_shapes=1,
                                                                      n_poses=2)]
    other = learn_arm_model(samples, arm_template(build_body(resolution="2k"), "left"), population_size=4)
    return capture, first, other


def test_capture_records_its_models_regressed_joints(capture_and_models):
    from bodystudio.muscle.model import model_joints

    capture, first, _ = capture_and_models
    assert capture.regressed_joints is not None
    assert np.allclose(capture.regressed_joints, model_joints(first, capture.shape), atol=1e-12)


def test_regressed_centre_is_the_capturing_models_shoulder_in_any_model(capture_and_models):
    from bodystudio.muscle.model import capture_samples, model_joints

    capture, first, later = capture_and_models
    moved = np.linalg.norm(model_joints(later, capture.shape)[0] - model_joints(first, capture.shape)[0])
    assert moved > 1e-6  # the later model regresses another shoulder: the case this guards
    for centre in ("regressed", "sex"):
        own = capture_samples(capture, "c", model=first, centre=centre)
        other = capture_samples(capture, "c", model=later, centre=centre)
        for a, b in zip(own, other, strict=True):
            assert (a.rest_origin is None) == (b.rest_origin is None)
            if a.rest_origin is not None:
                assert np.allclose(a.rest_origin, capture.regressed_joints[0], atol=1e-12)
                assert np.allclose(b.rest_origin, a.rest_origin, atol=1e-12)
