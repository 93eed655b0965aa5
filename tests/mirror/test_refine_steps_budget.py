"""MIR12k: the pose refinement takes two Gauss-Newton steps when the run reshapes one player, one per player when it
reshapes several (the second step paid for by the dense warp's dropped MLS solve; two players keep 30 fps)."""

import numpy as np
import pytest

from bodystudio.mirror import run as run_mod
from bodystudio.mirror.refine import ITERATIONS


def test_one_player_gets_two_steps_several_get_one_each():
    assert ITERATIONS == 1  # refine_pose's own default stays one step (init, oracle scripts)
    assert run_mod.REFINE_STEPS_ONE_PLAYER == 2
    assert run_mod.refine_steps(1) == 2
    assert [run_mod.refine_steps(n) for n in (2, 3, 6)] == [1, 1, 1]


@pytest.mark.parametrize("several", [False, True])
def test_session_inputs_pass_the_steps_to_every_refinement(monkeypatch, several):
    """The frames' ``late_pairs`` refine each present player's pose with ``refine_steps(players reshaped)`` steps."""
    from test_run_mutants import _two_player_session

    from bodystudio.mirror import frames as frames_mod
    from bodystudio.mirror import refine as refine_mod

    session, b1, b2, model, rec, blocks, spec = _two_player_session(monkeypatch)
    for b in (b1, b2):
        b.weights = f"w{b.p}"
    monkeypatch.setattr(refine_mod, "refine_plan", lambda *a, **kw: "plan")
    monkeypatch.setattr(frames_mod, "point_cloud", lambda frame, sensor, p: np.array([[0.0, 0.5, 2.0]]))
    steps = []

    def refine_pose(*args, iterations=refine_mod.ITERATIONS, **kwargs):
        steps.append(iterations)
        return args[2]

    monkeypatch.setattr(refine_mod, "refine_pose", refine_pose)
    monkeypatch.setattr(refine_mod, "updated_posture", lambda posture, *a, **kw: posture)  # stand-in poses
    players, bodies = ([1, 2], [b1, b2]) if several else (1, b1)
    for o in run_mod.session_inputs(session, bodies, model, {"taller": 1.0}, players, 2, [0, 5], refine=True):
        if o.late_pairs is not None:
            o.late_pairs(np.ones(o.rgb.shape[:2], bool), {})
    assert steps and set(steps) == ({1} if several else {2})


def test_one_player_gets_more_depth_points_several_the_default():
    """MIR12n: a one-player run's refinement reads 2000 depth points a step, several players keep the default 400."""
    from bodystudio.mirror.refine import RefineWeights

    assert RefineWeights().depth_samples == 400  # refine_pose's own default (init, oracle scripts) is unchanged
    assert run_mod.REFINE_DEPTH_SAMPLES_ONE_PLAYER == 2000
    tilt = run_mod.PELVIS_TILT_RAD  # E_upright, the run's since mir12ae (test_mirror_refine_pelvis_tilt_options)
    assert run_mod.refine_weights(1) == RefineWeights(depth_samples=2000, pelvis_tilt_rad=tilt)
    assert all(run_mod.refine_weights(n) == RefineWeights(pelvis_tilt_rad=tilt) for n in (2, 3))


@pytest.mark.parametrize("several", [False, True])
def test_session_inputs_pass_the_weights_to_every_refinement(monkeypatch, several):
    """The frames' ``late_pairs`` refine each present player with ``refine_weights(players reshaped)``."""
    from test_run_mutants import _two_player_session

    from bodystudio.mirror import frames as frames_mod
    from bodystudio.mirror import refine as refine_mod

    session, b1, b2, model, rec, blocks, spec = _two_player_session(monkeypatch)
    for b in (b1, b2):
        b.weights = f"w{b.p}"
    monkeypatch.setattr(refine_mod, "refine_plan", lambda *a, **kw: "plan")
    monkeypatch.setattr(frames_mod, "point_cloud", lambda frame, sensor, p: np.array([[0.0, 0.5, 2.0]]))
    seen = []

    def refine_pose(*args, weights=refine_mod.RefineWeights(), **kwargs):
        seen.append(weights.depth_samples)
        return args[2]

    monkeypatch.setattr(refine_mod, "refine_pose", refine_pose)
    monkeypatch.setattr(refine_mod, "updated_posture", lambda posture, *a, **kw: posture)  # stand-in poses
    players, bodies = ([1, 2], [b1, b2]) if several else (1, b1)
    for o in run_mod.session_inputs(session, bodies, model, {"taller": 1.0}, players, 2, [0, 5], refine=True):
        if o.late_pairs is not None:
            o.late_pairs(np.ones(o.rgb.shape[:2], bool), {})
    assert seen and set(seen) == ({400} if several else {2000})
