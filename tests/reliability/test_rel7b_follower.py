"""The follower's jump limit everywhere (rel7b): the mirror, seconds instead of frames, a subject back under a new id.

rel7a bounded whom ``reconstruct`` and ``muscle capture`` follow (``capture.subject.stage_follower``: the id holder only
within 0.6 m + 0.1 m per missed frame, an id holder refused for its distance another person from then on). Three
things it left, each planted here on hand-made bodies (joints only, milliseconds):

1. the mirror (run, init, checks) kept the speed limit alone: a bystander never tracked before, handed the lost actor's
   id 0.85 m away, was taken once the reach had grown past it (3 missed frames) and reshaped with the actor's source
   body. Now the mirror follows with the stages' rule (``capture.subject.session_follower``): those frames pass
   through with the run's "not among the tracked bodies" warning until the actor is found again;
2. the reach grew 0.1 m a frame at any frame rate (1.5 m/s at 15 fps, 6 m/s at 60): now 3 m/s times the frame interval
   from the session's ``metadata.fps`` (``capture.subject.session_step_m``), the same figures at 30 fps;
3. a subject that moved more than 0.3 m while lost and came back under a new id was never found again (reconstruct
   refused the rest of the session): now, while the subject is missed, a body of a new id within
   0.3 m + 3 m/s x the time lost of its last joints is the subject, when no other person stood there the frame before.
"""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from bodystudio.capture import subject as S
from bodystudio.errors import InputError
from tests.reliability.test_rel6b_subject_lost import _body  # one v2 skeleton standing at x

BYSTANDER_DX = 0.85


class _Session:
    """A stand-in session: ``kinect_bodies`` per frame and ``metadata`` (``fps`` when given)."""

    def __init__(self, bodies_by_frame, fps=None, path="S"):
        self.path = Path(path)
        self.metadata = {} if fps is None else {"fps": fps}
        self.frames = {f: SimpleNamespace(frame_id=f, kinect_bodies=b,
                                          kinect_joints=min(b, key=lambda x: x["player"]) if b else None)
                       for f, b in enumerate(bodies_by_frame)}
        self.frame_ids = list(self.frames)

    def frame(self, i):
        return self.frames[i]


def _walk_in(n=14, at=3, lost=8):
    """rel7a's planted case: the subject (player 1, +0.01 m a frame) alone; lost in frames ``at`` .. ``at + lost - 1``
    while a bystander never tracked before is found 0.85 m aside holding id 1; then the subject back under id 2."""
    out = []
    for f in range(n):
        me = _body(1, 0.01 * f)
        if f < at:
            out.append([me])
        elif f < at + lost:
            out.append([_body(1, BYSTANDER_DX)])
        else:
            out.append([_body(1, BYSTANDER_DX), {**me, "player": 2}])
    return out


def test_the_mirror_never_takes_a_bystander_handed_the_actors_id():
    """``mirror.plausibility.followed_players`` (the run's follower, ``capture.subject.session_follower``). Before:
    (1,) from frame 6 on, the bystander (the reach 0.6 + 0.1 x 3 m past its 0.83 m), reshaped as the actor; now
    frames 3-10 have no actor (the run passes them through with its warning) and the actor is found again under id 2.
    """
    from bodystudio.mirror.plausibility import followed_players

    s = _Session(_walk_in())
    assert list(followed_players(s, [1]).values()) == [(1,)] * 3 + [(None,)] * 8 + [(2,)] * 3
    old = S.SubjectFollower(1, step_m=S.SUBJECT_STEP_M)  # the mirror's rule before rel7b, still the class default
    assert [None if b is None else b["player"] for b in map(old.follow, _walk_in())][3:7] == [None, None, None, 1]
    # the lost actor's frames are named with the distance, as reconstruct's refusal names them
    f = S.session_follower(s, 1)
    for i in range(4):
        f.follow(s.frame(i).kinect_bodies)
    assert "player 1 holds the subject's id 0.83 m from its last joints" in f.lost_reason()


def _comes_back(step_x, lost=2, n=6):
    """The subject (player 1) at x = 0, nobody else tracked; its skeleton gone (no body) for ``lost`` frames, then
    back holding id 1 ``step_x`` m away (it moved while untracked)."""
    return [[_body(1, 0.0)]] + [[]] * lost + [[_body(1, step_x)] for _ in range(n - 1 - lost)]


@pytest.mark.parametrize(("fps", "back_m", "found"), [(None, 0.9, False), (30.0, 0.9, False), (30.0, 0.75, True),
                                                      (15.0, 0.9, True), (60.0, 0.75, False)])
def test_the_reach_grows_with_time_not_frames(fps, back_m, found):
    """Lost for 2 frames, back ``back_m`` away under its id: 0.6 m + 3 m/s x 2 frame intervals is 0.8 m at 30 fps (as
    before), 1.0 m at 15 fps (0.9 m followed: before, 0.8 m, refused for good), 0.7 m at 60 fps (0.75 m refused:
    before, 0.8 m, a bystander there taken)."""
    s = _Session(_comes_back(back_m), fps=fps)
    players = S.session_subject(s, s.frame_ids)
    assert players[3] == (1 if found else None)
    assert S.session_step_m(s) == pytest.approx(3.0 / (fps or 30.0))
    assert S.session_step_m(_Session([], fps=30.0)) == S.SUBJECT_STEP_M  # bit for bit at 30 fps
    assert S.subject_step_m(30.0, stride=3) == S.SUBJECT_STEP_M * 3


@pytest.mark.parametrize("fps", [0, -30, float("nan"), "30", True, 1e6])
def test_a_session_frame_rate_that_is_no_rate_is_refused(fps):
    with pytest.raises(InputError, match=r"^S/session.json: metadata.fps .* is not a frame rate in 1..240; fix it "
                       r"or re-import the recording"):
        S.session_step_m(_Session([], fps=fps))


def _moved_away(back_x=0.5, lost=3, n=8, bystander=True):
    """The subject (player 1) at x = 0; lost for ``lost`` frames (a bystander 0.85 m aside holding id 1 from then on
    when ``bystander``), then back under id 2 ``back_x`` m from where it was lost."""
    by = [_body(1, BYSTANDER_DX)] if bystander else []
    return [[_body(1, 0.0)]] * 3 + [by] * lost + [by + [_body(2, back_x)]] * (n - 3 - lost)


def test_a_subject_back_under_a_new_id_farther_than_0_3_m_is_found():
    """Lost 3 frames (the bystander holding its id), back under id 2 0.5 m away: before, never found (frames 6-7 None:
    reconstruct refused the rest of the session); now found within 0.3 + 0.1 x 3 m."""
    s = _Session(_moved_away())
    assert list(S.session_subject(s, s.frame_ids).values()) == [1, 1, 1, None, None, None, 2, 2]
    # nobody else in view while it was lost: the same
    s = _Session(_moved_away(bystander=False))
    assert list(S.session_subject(s, s.frame_ids).values())[6:] == [2, 2]
    # before (rel7a's stage follower, no regain): lost for good
    old = S.SubjectFollower(step_m=S.SUBJECT_STEP_M, jumped_is_other=True)
    assert [None if b is None else b["player"] for b in map(old.follow, _moved_away())][6:] == [None, None]


def test_regain_takes_no_one_out_of_reach_or_another_person():
    """A new id 0.85 m away one frame after the loss (radius 0.4 m) is not the subject, nor ever after (another person
    from the next frame); a person tracked before under another id who walks onto the subject's last place is not
    the subject either (within 0.3 m of where another person stood the frame before)."""
    early = [[_body(1, 0.0)]] * 3 + [[]] + [[_body(3, BYSTANDER_DX)]] * 6
    assert S.subject_players(early)[3:] == [None] * 7
    walker = [[_body(1, 0.0), _body(2, 1.2)]] * 3 + [[_body(2, max(1.2 - 0.25 * k, 0.45))] for k in range(1, 6)]
    assert S.subject_players(walker)[3:] == [None] * 5
    # the mirror's two actors: a lost actor never takes the other actor's body
    a, b = S.stage_follower(1), S.stage_follower(2)
    two = [[_body(1, 0.0), _body(2, 1.0)]] * 2 + [[_body(2, 1.0)]] * 3 + [[_body(2, 1.0), _body(3, 0.4)]]
    got = [S.follow_subjects([a, b], bodies) for bodies in two]
    assert [tuple(None if x is None else x["player"] for x in g) for g in got] == \
        [(1, 2), (1, 2), (None, 2), (None, 2), (None, 2), (3, 2)]


def test_mirror_run_passes_the_bystanders_frames_through_with_a_warning(monkeypatch):
    """``mirror.run.session_inputs`` (the run's loop, its frame reader and body steps stood in by
    tests/mirror/test_run_analytic.py's harness) on rel7a's walk-in: before, frames 6-10 reshaped the bystander as
    player 1 (``tracked_as`` (1,), pairs from its pose); now they pass through with the run's warning, the first naming
    the bystander's distance, and the actor is reshaped again under id 2 from frame 11."""
    from tests.mirror import test_run_analytic as T

    walk = _walk_in()

    def read(self, session, i):
        bodies = tuple(SimpleNamespace(player=b["player"], names=tuple(b["names"]), positions=b["positions"],
                                       tracked=b["tracked"]) for b in walk[i])
        player = np.zeros((T.CH, T.CW), np.uint8)
        for b in bodies:  # the actor's pixels left, the bystander's right
            player[(slice(2, 6), slice(4, 8)) if np.median(b.positions[:, 0]) < 0.5 else (slice(8, 10),
                                                                                         slice(12, 14))] = b.player
        return SimpleNamespace(rgb=np.full((T.CH, T.CW, 3), i, np.uint8), depth_m=np.ones((T.CH, T.CW)),
                               player=player, seen=(slice(None), slice(0, T.CW)), bodies=bodies,
                               body=lambda p: next((b for b in bodies if b.player == p), None))

    monkeypatch.setattr(T._Frames, "read", read)
    out, _ = T._session_inputs(monkeypatch, {i: {} for i in range(len(walk))}, ramp_frames=0)
    assert [o.tracked_as for o in out] == [(1,)] * 3 + [(None,)] * 8 + [(2,)] * 3
    assert all(o.warning is None and o.src_uv is not None for o in out[:3] + out[11:])
    assert all(o.subject_missing and o.src_uv is None and "player 1 is not among the tracked bodies (players 1)"
               in o.warning and o.warning.endswith("the frame passes through unchanged") for o in out[3:11])
    assert "player 1 holds the subject's id 0.83 m from its last joints, farther than the 0.60 m" in out[3].warning
    assert not out[11].person_mask[8:10, 12:14].any() and out[11].person_mask[2:6, 4:8].all()
