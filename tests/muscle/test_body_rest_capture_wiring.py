"""The capture's wiring of the body rest shape (``CaptureOptions.body_rest_*`` -> ``refine.fit_body_rest_shape``;
issue 17, mutation testing of mus11c): the arguments test_body_rest_shape.py's capture test does not check (the
prior's spread, the placement switch, the measured arm length and its weight, the rounds only with the switch on)."""

import numpy as np

from bodystudio.muscle import model as model_mod
from tests.muscle.test_capture_analytic import Spies, scene  # noqa: F401  (the tiny capture scene)

FAST = dict(shape_frames=2, shape_rounds=1, first_frame_nicp_iterations=3, sequence_rounds=1, sequence_max_nfev=3,
            pose_sigma_frames=0.0)


def test_the_body_rest_fit_gets_the_priors_spread_the_placement_switch_and_the_measured_arm_length(
        monkeypatch, scene):  # noqa: F811
    from bodystudio.muscle.capture import CaptureOptions, capture_arm_frames
    from bodystudio.muscle.nicp import NicpOptions

    s = scene
    spies = Spies(monkeypatch, ("fit_body_rest_shape", "fit_arm_sequence_skeleton"))
    proj = Spies(monkeypatch, ("project_to_body_space",), module=model_mod)
    # the held-pose fit (the joint fit, the default, has its own wiring tests in test_sequence_stage_stop_mutants.py)
    o = CaptureOptions(mode="model", body_rest_shape=True, body_rest_rounds=1, body_rest_frame_stride=1,
                       body_rest_iterations=1, body_rest_fit_placement=False, body_rest_arm_length_weight=7.0,
                       body_rest_fit_poses=False, nicp=NicpOptions(iterations=2), **FAST)
    capture_arm_frames(s.depths, s.camera, s.template, s.model, o, s.tracker, known_shape=s.shape)
    (p,) = proj["project_to_body_space"]
    (fb,) = spies["fit_body_rest_shape"]
    space = fb.args[0]
    from bodystudio.muscle.capture import body_rest_local_sigma

    mean, sigma = space.prior(s.shape, body_rest_local_sigma(o, space))
    np.testing.assert_array_equal(p.args[3], mean)  # the projection starts at the measured sex / muscularity's prior
    np.testing.assert_array_equal(p.args[4], sigma)
    np.testing.assert_array_equal(fb.args[7], sigma)
    assert len(fb.args[2]) == len(s.depths)  # stride 1: every frame
    assert fb.args[11:15] == (1, False, s.shape.arm_length_m, 7.0)
    # the rest mesh's shoulder stays where the model's regressed one sits (the joints the projection was given)
    np.testing.assert_array_equal(fb.args[5], p.args[2][0])
    assert np.abs(fb.args[5]).max() > 1e-3
    _, J0 = space.rest_and_joints(p.out, fb.args[5])
    np.testing.assert_allclose(fb.args[5], spies["fit_arm_sequence_skeleton"][0].args[4][0], atol=1e-12)
    np.testing.assert_allclose(J0[0], fb.args[5], atol=1e-12)


def test_body_rest_rounds_act_only_with_the_switch_on(monkeypatch, scene):  # noqa: F811
    from bodystudio.muscle.capture import CaptureOptions, capture_arm_frames
    from bodystudio.muscle.nicp import NicpOptions

    s = scene
    spies = Spies(monkeypatch, ("fit_body_rest_shape", "fit_arm_sequence_skeleton"))
    proj = Spies(monkeypatch, ("project_to_body_space",), module=model_mod)
    o = CaptureOptions(mode="model", body_rest_shape=False, body_rest_rounds=2, nicp=NicpOptions(iterations=2),
                       **FAST)
    capture_arm_frames(s.depths, s.camera, s.template, s.model, o, s.tracker, known_shape=s.shape)
    assert not spies["fit_body_rest_shape"] and not proj["project_to_body_space"]
    assert len(spies["fit_arm_sequence_skeleton"]) == 1  # no extra rounds
