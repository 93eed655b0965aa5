"""mus11y's choice between the two captures in ``capture_arm_frames`` (a subject of unknown sex captured as a man and
as a woman, the sex whose held-out depth energy is lower kept), on the tiny capture scene of test_capture_analytic.py
with the sequence stage and the held-out energy stubbed: which run is returned, the ``sex_fit`` record, the margin
passed, a single candidate not scored (issue 17, mutation testing: docs/mutation/muscle-capture.md, "mus11y's sex from
the depth"; the lines planted by hand, docs/mutation/muscle-capture-sex-from-depth-plant.py)."""

import numpy as np
import pytest

from bodystudio.muscle import capture as cap_mod
from bodystudio.muscle.arm import ArmPose
from bodystudio.muscle.capture import CaptureOptions, capture_arm_frames
from bodystudio.muscle.nicp import NicpOptions
from tests.muscle.test_capture_analytic import scene  # noqa: F401  (the tiny capture scene)

pytestmark = pytest.mark.slow  # the tiny capture scene: ~30 s to build, ~6 s a capture (65 s the file)

FAST = dict(shape_frames=2, shape_rounds=1, first_frame_nicp_iterations=3, sequence_rounds=1, sequence_max_nfev=3,
            nicp=NicpOptions(iterations=2), pose_sigma_frames=0.0, mode="model", norm_limit=0.35,
            sequence_huber_m=0.006, pose_refit=False)


def _stub(monkeypatch, energy, sexes=(1.0, 0.0)):
    """The stage turns each pose by 0.01 rad (a man) or 0.02 rad (a woman) per coordinate and moves the rest arm
    ``sex`` mm up; the held-out energy is ``energy[sex]`` of the run whose poses it is given."""
    seen = {"stage": {}, "energy": []}

    def stage(model, template, shape, poses, frames_t, tracker_t, base, J, o, known_shape):
        sex = float(shape.sex)
        out = ([ArmPose(p.root.copy(), p.angles + 0.01 * (2 - sex)) for p in poses], base + [0.0, 0.001 * sex, 0.0],
               J.copy())
        seen["stage"][sex] = out
        return out

    def held_out(model, poses, frames_t, rest, joints, o):
        sex = next(s for s, out in seen["stage"].items() if out[0] is poses)
        assert rest is seen["stage"][sex][1] and joints is seen["stage"][sex][2]
        seen["energy"].append((sex, len(frames_t), o.sex_margin_mm))
        return energy[sex]

    monkeypatch.setattr(cap_mod, "sequence_stage", stage)
    monkeypatch.setattr(cap_mod, "held_out_depth_energy_mm", held_out)
    monkeypatch.setattr(cap_mod, "candidate_sexes", lambda model, o, known_shape=None: sexes)
    return seen


@pytest.mark.parametrize("energy, chosen", [({1.0: 3.5, 0.0: 3.0}, 0.0), ({1.0: 3.0, 0.0: 3.5}, 1.0)])
def test_the_run_of_the_lower_energy_is_kept_and_recorded(monkeypatch, scene, energy, chosen):  # noqa: F811
    s = scene
    seen = _stub(monkeypatch, energy)
    cap = capture_arm_frames(s.depths, s.camera, s.template, s.model, CaptureOptions(sex_margin_mm=0.25, **FAST),
                             s.tracker)
    assert sorted(seen["energy"]) == [(0.0, len(s.depths), 0.25), (1.0, len(s.depths), 0.25)]
    male, female = energy[1.0], energy[0.0]
    assert cap.sex_fit == {"sex": chosen, "chosen": "female" if chosen == 0.0 else "male",
                           "energy_mm": {"male": male, "female": female}, "margin_mm": 0.25, "ambiguous": False}
    assert cap.shape.sex == chosen
    poses = seen["stage"][chosen][0]
    for p, q in zip(cap.poses, poses, strict=True):
        np.testing.assert_array_equal(p.angles, q.angles)


def test_within_the_margin_is_ambiguous(monkeypatch, scene):  # noqa: F811
    s = scene
    _stub(monkeypatch, {1.0: 3.5, 0.0: 3.0})
    cap = capture_arm_frames(s.depths, s.camera, s.template, s.model, CaptureOptions(sex_margin_mm=0.5, **FAST),
                             s.tracker)
    assert cap.sex_fit["ambiguous"] is True and cap.sex_fit["margin_mm"] == 0.5 and cap.shape.sex == 0.0


def test_one_candidate_is_not_scored(monkeypatch, scene):  # noqa: F811
    s = scene
    seen = _stub(monkeypatch, {1.0: 3.5, 0.0: 3.0}, sexes=(0.0,))
    cap = capture_arm_frames(s.depths, s.camera, s.template, s.model, CaptureOptions(**FAST), s.tracker)
    assert seen["energy"] == [] and cap.sex_fit is None and cap.shape.sex == 0.0
    assert list(seen["stage"]) == [0.0]
