"""The muscle capture's wiring of the last per-frame pose refit (``CaptureOptions.pose_refit``, ``capture.POSE_REFIT``;
mus11g) and mus11f's refusal of ``personal_rounds`` next to the body rest shape's rounds (issue 17, mutation testing;
branch mutP). The sequence stage and the refit are stubbed with known answers, so each argument, the order of the
steps and what the capture returns are checked exactly on the tiny capture scene of test_capture_analytic.py."""

import numpy as np
import pytest

from bodystudio.errors import InputError
from bodystudio.muscle import capture as cap_mod
from bodystudio.muscle.arm import ArmPose
from bodystudio.muscle.capture import POSE_REFIT, CaptureOptions, apply_similarity, capture_arm_frames
from bodystudio.muscle.nicp import NicpOptions
from bodystudio.muscle.refine import DepthFrame, skeleton_model_mesh
from tests.muscle.test_capture_analytic import scene  # noqa: F401  (the tiny capture scene)

FAST = dict(shape_frames=2, shape_rounds=1, first_frame_nicp_iterations=3, sequence_rounds=1, sequence_max_nfev=3,
            nicp=NicpOptions(iterations=2), pose_sigma_frames=0.0, mode="model", norm_limit=0.35,
            sequence_huber_m=0.006)


def _stub(monkeypatch):
    """The sequence stage returns its poses turned by 0.01 rad per coordinate, the rest arm 1 mm up and the joints
    2 mm along x; the refit returns its poses' angles times 1.1. Both record what they got."""
    seen = {"refit": []}

    def stage(model, template, shape, poses, frames_t, tracker_t, base, J, o, known_shape):
        out = ([ArmPose(p.root.copy(), p.angles + 0.01) for p in poses], base + [0.0, 0.001, 0.0],
               J + [0.002, 0.0, 0.0])
        seen["stage"] = out
        return out

    def refit(*args, **kw):
        seen["refit"].append((args, kw))
        return [ArmPose(p.root.copy(), 1.1 * p.angles) for p in args[1]]

    monkeypatch.setattr(cap_mod, "sequence_stage", stage)
    monkeypatch.setattr(cap_mod, "refit_arm_poses_to_depth", refit)
    return seen


def test_the_capture_hands_the_sequence_stages_result_to_the_refit_and_returns_its_poses(monkeypatch, scene):  # noqa: F811
    s = scene
    seen = _stub(monkeypatch)
    before = dict(POSE_REFIT)
    o = CaptureOptions(**FAST)
    assert o.pose_refit
    cap = capture_arm_frames(s.depths, s.camera, s.template, s.model, o, s.tracker, known_shape=s.shape)
    assert POSE_REFIT == before  # the capture pops from its own copy
    (args, kw), = seen["refit"]
    poses, base, J = seen["stage"]
    assert args[0] is s.model and len(args) == 9
    for p, q in zip(args[1], poses, strict=True):
        np.testing.assert_array_equal(p.angles, q.angles)
    assert len(args[2]) == len(s.depths) and all(isinstance(f, DepthFrame) for f in args[2])
    np.testing.assert_array_equal(args[3], base)
    np.testing.assert_array_equal(args[4], J)
    assert args[5:7] == (0.35, 0.006)  # the options' norm limit and the sequence fit's Huber threshold
    np.testing.assert_allclose(args[7] + cap.similarity[2], s.tracker, atol=1e-9)  # the tracker, template space
    assert args[8] == POSE_REFIT["tracker_weight"]
    assert kw == {"prior_weight": POSE_REFIT["prior_weight"], "iterations": POSE_REFIT["iterations"]}
    # its poses are the capture's, and the meshes (the output in mode "model", and the "model" stage) are posed
    # with them on the stage's rest arm and skeleton at the options' norm limit
    for p, q in zip(cap.poses, poses, strict=True):
        np.testing.assert_allclose(p.angles, 1.1 * q.angles, atol=1e-15)
    want = np.stack([apply_similarity(cap.similarity, skeleton_model_mesh(s.model, ArmPose(q.root, 1.1 * q.angles),
                                                                          base, J, 0.35)) for q in poses])
    np.testing.assert_allclose(cap.vertices, want, atol=1e-12)
    np.testing.assert_allclose(cap.stages["model"], want, atol=1e-12)
    assert "pose_refit" in cap.timings_ms and cap.timings_ms["pose_refit"] >= 0.0


def test_the_refit_is_skipped_when_off_or_without_a_model(monkeypatch, scene):  # noqa: F811
    s = scene
    seen = _stub(monkeypatch)
    off = capture_arm_frames(s.depths, s.camera, s.template, s.model, CaptureOptions(**{**FAST, "pose_refit": False}),
                             s.tracker, known_shape=s.shape)
    assert seen["refit"] == [] and "pose_refit" not in off.timings_ms
    for p, q in zip(off.poses, seen["stage"][0], strict=True):
        np.testing.assert_array_equal(p.angles, q.angles)
    nicp = capture_arm_frames(s.depths, s.camera, s.template, None,
                              CaptureOptions(**{**FAST, "mode": "nicp", "pose_refit": True}))
    assert seen["refit"] == [] and "pose_refit" not in nicp.timings_ms


# --- mus11f: personal_rounds next to the body rest shape's rounds -------------------------------------------------


@pytest.mark.parametrize("kw", [dict(personal_rounds=1), dict(personal_rounds=2, body_rest_rounds=1),
                                dict(personal_rounds=1, body_rest_rounds=1, body_rest_shape=True)])
def test_personal_rounds_with_the_body_rest_rounds_are_refused(kw):
    with pytest.raises(InputError, match="personal_rounds and the body rest shape's rounds are two rest-shape fits "
                                         "and only one runs; set body_rest_shape=False to use personal_rounds"):
        CaptureOptions(**kw)


@pytest.mark.parametrize("kw", [dict(), dict(personal_rounds=1, body_rest_shape=False),
                                dict(personal_rounds=1, body_rest_rounds=0), dict(personal_rounds=0),
                                dict(personal_rounds=0, body_rest_rounds=1)])
def test_one_rest_shape_fit_alone_is_accepted(kw):
    o = CaptureOptions(**kw)
    assert o.personal_rounds == kw.get("personal_rounds", 0)
    assert CaptureOptions().body_rest_shape and CaptureOptions().body_rest_rounds == 2  # the defaults (mus11f)
