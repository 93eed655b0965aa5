"""rel6b's "other person" rule of the subject follower (``SubjectFollower.see_others``, its use in ``candidates``,
``follow`` and ``follow_subjects``), on hand-built frames whose distances are exact in binary (mutLL).

A body holding the subject's id is never the subject when it stands within ``follow_m`` of another person's joints
in the frame before. Each case spells out which bodies a frame marks as "others" and which body each frame gives,
worked out by hand from the docstring (bodies are rigid copies moved along x, so every joint distance, and so the
median, is the x offset).
"""

from __future__ import annotations

import numpy as np

from bodystudio.capture import subject as S

NAMES = ("SpineBase", "SpineMid", "Neck", "Head", "ShoulderLeft")


def _body(player, x):
    """A five-joint body at ``x`` (m): the joints 0.25 m apart along y, all at depth 2 m."""
    return {"player": player, "names": NAMES, "positions": np.array([[x, 0.25 * k, 2.0] for k in range(5)])}


def _x(body):
    return None if body is None else float(body["positions"][0, 0])


def test_the_follower_defaults_to_the_0_3_m_rule_and_no_others():
    f = S.SubjectFollower(1)
    assert f.follow_m == 0.3 and S.SUBJECT_FOLLOW_M == 0.3 and f.others == []
    # at the default 0.3 m: a body 0.25 m from another person's last place is marked, one 0.375 m away is not
    bystander = _body(2, 1.0)
    f.see_others([bystander], None)
    near, far = _body(1, 1.25), _body(1, 1.375)
    f.see_others([near, far], None)
    assert f.others == [near]


def test_see_others_marks_other_ids_and_leaves_the_subjects_body_out():
    f = S.SubjectFollower(1, follow_m=0.5)
    mine, other, third = _body(1, 0.0), _body(2, 1.0), _body(3, -2.0)
    f.see_others([mine, other, third], mine)
    assert len(f.others) == 2 and f.others[0] is other and f.others[1] is third
    # the subject's own body is left out by identity, not by equality: an equal copy holding id 1 is not "another
    # person" either (nobody stood anywhere a frame before)
    twin = _body(1, 0.0)
    f.see_others([mine, twin], mine)
    assert f.others == []
    # no subject found: the bodies of other ids are the others, a body holding the subject's id is not (it may be
    # the subject coming back)
    f.see_others([_body(1, 5.0), other], None)
    assert len(f.others) == 1 and f.others[0] is other


def test_see_others_keeps_a_body_standing_where_another_stood_inclusive_at_follow_m():
    f = S.SubjectFollower(1, follow_m=0.5)
    f.see_others([_body(2, 1.0)], None)
    prev = f.others
    at, beyond = _body(1, 1.5), _body(1, 1.75)  # 0.5 m (exactly follow_m) and 0.75 m from the other person
    f.see_others([at, beyond], None)
    assert len(f.others) == 1 and f.others[0] is at
    assert prev is not f.others  # a new list each frame: the frame before's people, not every frame's
    # the next frame compares with this frame's others only: the person at 1.0 is gone, so a body at 1.0 holding
    # the subject's id is 0.5 m from `at` (kept) ...
    back = _body(1, 1.0)
    f.see_others([back], None)
    assert len(f.others) == 1 and f.others[0] is back
    # ... and one 1.0 m from every other person of the frame before is not
    f.see_others([_body(1, 3.0)], None)
    assert f.others == []


def test_candidates_refuse_the_id_holder_standing_where_another_person_stood():
    # the subject at x = 0, a bystander (id 2) at x = 1; then the subject is lost and the bystander holds id 1
    for x_holder, expect in ((1.5, []), (1.75, [(1, 1.75, 0)])):
        f = S.SubjectFollower(1, follow_m=0.5)  # step_m None: the id holder at any distance (reconstruct's)
        assert _x(f.follow([_body(1, 0.0), _body(2, 1.0)])) == 0.0
        assert [(t, d, k) for t, d, k in f.candidates([_body(1, x_holder)])] == expect
    # with nobody else a frame before, the far id holder is the subject (a tracker glitch)
    f = S.SubjectFollower(1, follow_m=0.5)
    f.follow([_body(1, 0.0)])
    assert f.candidates([_body(1, 1.5)]) == [(1, 1.5, 0)]
    # a body within follow_m of the subject's last joints stays tier 0 even where another person stood
    f = S.SubjectFollower(1, follow_m=0.5)
    f.follow([_body(1, 0.0), _body(2, 0.75)])
    assert f.candidates([_body(2, 0.25)]) == [(0, 0.25, 0)]


def test_follow_two_frames_then_the_subject_back_under_a_new_id():
    f = S.SubjectFollower(None, follow_m=0.5)
    frames = [[_body(1, 0.0), _body(2, 1.0)],   # the subject (lowest id) and a bystander
              [_body(1, 1.0)],                  # the subject lost, the bystander given id 1, where it stood
              [_body(1, 1.0)],                  # still there: still the other person (it stands where it stood)
              [_body(1, 1.0), _body(4, 0.25)]]  # the subject back as id 4, 0.25 m from its last place
    got = [_x(f.follow(b)) for b in frames]
    assert got == [0.0, None, None, 0.25]
    assert f.player == 4 and f.missed == 0
    # the bystander stays "the other person" after the subject is back
    assert len(f.others) == 1 and _x(f.others[0]) == 1.0


def test_follow_subjects_gives_each_follower_its_own_others():
    a, b = S.SubjectFollower(1, follow_m=0.5, step_m=S.SUBJECT_STEP_M), S.SubjectFollower(2, follow_m=0.5)
    bodies = [_body(1, 0.0), _body(2, 2.0)]
    assert [_x(x) for x in S.follow_subjects([a, b], bodies)] == [0.0, 2.0]
    assert len(a.others) == 1 and a.others[0] is bodies[1]
    assert len(b.others) == 1 and b.others[0] is bodies[0]
    # actor 1 lost, a third person given id 1 where actor 2 stood: actor 2 found by its joints, nobody for actor 1
    # (the id holder is 0.25 m from actor 2's last place: the other-person rule refuses it before the speed limit)
    frame = [_body(1, 2.25), _body(2, 2.0)]
    assert [_x(x) for x in S.follow_subjects([a, b], frame)] == [None, 2.0]
    assert [_x(o) for o in a.others] == [2.25, 2.0] and [_x(o) for o in b.others] == [2.25]
    # without the speed limit, the id holder where actor 2 stood is still not actor 1
    c, d = S.SubjectFollower(1, follow_m=0.5), S.SubjectFollower(2, follow_m=0.5)
    S.follow_subjects([c, d], [_body(1, 0.0), _body(2, 2.0)])
    assert [_x(x) for x in S.follow_subjects([c, d], [_body(1, 2.25), _body(3, 2.0)])] == [None, 2.0]
    assert d.player == 3
