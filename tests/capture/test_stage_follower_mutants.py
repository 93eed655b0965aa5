"""rel7a's ``stage_follower``: the follower of reconstruct and muscle capture with the jump limit (mutOO, < 0.1 s).

Its settings and the reach they give, on bodies moved along x by distances exact in binary: the id holder within
``SUBJECT_JUMP_M + SUBJECT_STEP_M * missed`` of the subject's last joints is taken, beyond it refused (and marked
another person), and with ``step_m`` None taken at any distance as before.
"""

from __future__ import annotations

import numpy as np

from bodystudio.capture import subject as sj

K = np.array([[0.0, 0.0, 2.0], [0.0, 0.5, 2.0], [0.0, 1.0, 2.0]])


def _b(player, dx):
    return {"player": player, "names": ["a", "b", "c"], "positions": (K + [dx, 0.0, 0.0]).tolist()}


def test_stage_follower_settings():
    f = sj.stage_follower()
    assert (f.player, f.follow_m, f.step_m, f.jump_m, f.jumped_is_other, f.chosen) == (
        None, sj.SUBJECT_FOLLOW_M, sj.SUBJECT_STEP_M, sj.SUBJECT_JUMP_M, True, False)
    f = sj.stage_follower(2, 0.25, 0.125)
    assert (f.player, f.follow_m, f.step_m, f.jumped_is_other, f.chosen) == (2, 0.25, 0.125, True, True)
    f = sj.stage_follower(step_m=None)
    assert f.step_m is None and f.jumped_is_other is False


def test_stage_follower_takes_the_id_holder_only_within_the_subjects_reach():
    f = sj.stage_follower()
    assert f.follow([_b(1, 0.0)])["player"] == 1
    assert f.follow([_b(1, 0.625)]) is None  # beyond 0.6 m after no missed frame
    assert "farther than the 0.60 m the subject moves in 1 frame" in f.lost_reason()
    assert f.follow([_b(1, 0.6875)]) is None  # the refused holder is another person from then on
    f = sj.stage_follower()
    f.follow([_b(1, 0.0)])
    assert f.follow([]) is None
    assert f.follow([_b(1, 0.6875)])["player"] == 1  # 0.6 + 0.1 after one missed frame
    f = sj.stage_follower(step_m=None)
    f.follow([_b(1, 0.0)])
    assert f.follow([_b(1, 5.0)])["player"] == 1  # the old rule: at any distance
    f = sj.stage_follower(player=2)
    assert f.follow([_b(1, 0.0), _b(2, 1.0)])["player"] == 2
