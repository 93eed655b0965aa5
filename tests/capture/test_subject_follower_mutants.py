"""rel6a's subject follower (:class:`bodystudio.capture.subject.SubjectFollower`, :func:`follow_subjects`, the
changed :func:`follow_subject` / :func:`subject_players` / :func:`session_subject` and ``body_distance_m``'s
one-joint-set path) against hand-worked cases.

Mutation tests (issue 17, docs/mutation/capture-subject.md, "rel6a's SubjectFollower"): the distances are exact in
binary (0.25, 0.5, 0.75, 0.875 m; 3-4-12 triangles), every expected value is worked out by hand; a survivor here
would be a bystander taken for the actor (reshaped, reconstructed) or the actor dropped. Well under a second.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from bodystudio.capture import subject as S

NAMES = ["spine", "head", "hand"]
NAN = float("nan")


def _body(player, x=0.0, names=NAMES, positions=None):
    """A body at ``x`` along the x axis (every joint moved by ``x``; joints 1 m apart along y)."""
    pos = positions if positions is not None else [[x, float(k), 0.0] for k in range(len(names))]
    return {"player": player, "names": list(names), "positions": pos}


# ---- body_distance_m's one-joint-set path ------------------------------------------------------------------------

def test_one_joint_set_distance_is_the_median_of_the_row_distances():
    a = _body(1, positions=[[0, 0, 0], [0, 0, 0], [0, 0, 0]])
    b = _body(2, positions=[[3, 0, 0], [0, 4, 0], [0, 0, 12]])  # rows 3, 4, 12: median 4, mean 6.33
    assert S.body_distance_m(a, b) == 4.0
    assert S.body_distance_m(b, a) == 4.0
    flat = {"player": 2, "names": NAMES, "positions": [3, 0, 0, 0, 4, 0, 0, 0, 12]}  # a flat list of 9
    assert S.body_distance_m(a, flat) == 4.0


def test_one_joint_set_skips_a_row_with_any_coordinate_not_finite_on_either_side():
    a = _body(1, positions=[[0, 0, 0], [0, 0, 0], [0, 0, 0]])
    b = _body(2, positions=[[3, 0, 0], [0, 4, NAN], [0, 0, 12]])  # row 1 half-reported: left out
    assert S.body_distance_m(a, b) == 7.5  # median of 3 and 12
    a2 = _body(1, positions=[[np.inf, 0, 0], [0, 0, 0], [0, 0, 0]])
    assert S.body_distance_m(a2, _body(2, positions=[[3, 0, 0], [0, 4, 0], [0, 0, 12]])) == 8.0  # 4, 12
    none = _body(2, positions=[[NAN, 0, 0], [0, NAN, 0], [0, 0, NAN]])
    assert S.body_distance_m(a, none) == float("inf")
    assert S.body_distance_m(none, a) == float("inf")


def test_repeated_names_take_the_dict_path_last_row_wins():
    names = ["a", "a", "b"]
    a = _body(1, names=names, positions=[[0, 0, 0], [0, 0, 0], [0, 0, 0]])
    b = _body(2, names=names, positions=[[100, 0, 0], [0, 3, 0], [0, 0, 5]])  # "a" is its last row: 3; "b": 5
    assert S.body_distance_m(a, b) == 4.0  # the rows would give median(100, 3, 5) = 5


def test_same_names_with_positions_of_another_length_are_refused():
    a = _body(1, positions=[[0, 0, 0], [0, 0, 0]])  # three names, two rows
    b = _body(2, positions=[[1, 0, 0], [0, 1, 0]])
    with pytest.raises(ValueError):
        S.body_distance_m(a, b)
    c = _body(2, positions=[[1, 0, 0], [0, 1, 0], [0, 0, 1], [0, 0, 2]])  # four rows
    with pytest.raises(ValueError):
        S.body_distance_m(_body(1), c)
    with pytest.raises(ValueError):  # one row against three (a row-by-row path would index out of range)
        S.body_distance_m(_body(1, positions=[[0, 0, 0]]), _body(2))
    rep = ["a", "a", "b"]  # repeated names, two rows each: three names, two rows
    with pytest.raises(ValueError):
        S.body_distance_m(_body(1, names=rep, positions=[[0, 0, 0], [1, 0, 0]]),
                          _body(2, names=rep, positions=[[0, 0, 0], [1, 0, 0]]))
    same = ["a", "a", "a"]  # one name three times: one row against three is refused, not compared row by row
    with pytest.raises(ValueError, match="zip"):
        S.body_distance_m(_body(1, names=same, positions=[[0, 0, 0]]),
                          _body(2, names=same, positions=[[0, 0, 0], [1, 0, 0], [2, 0, 0]]))


def test_dict_path_subtracts_and_reads_json_nulls_when_the_names_differ():
    a = _body(1, positions=[[1, 1, 1], [2, 2, 2], [5, 5, 5]])
    b = {"player": 2, "names": ["hand", "spine", "head"],  # another order: the dict path
         "positions": [[5, 5, 17], [4, 1, 1], [None, None, None]]}  # hand 12, spine 3, head not reported
    assert S.body_distance_m(a, b) == 7.5
    assert S.body_distance_m(b, a) == 7.5


# ---- SubjectFollower ---------------------------------------------------------------------------------------------

def test_follower_defaults():
    f = S.SubjectFollower()
    assert (f.player, f.follow_m, f.step_m, f.jump_m, f.chosen, f.last, f.missed) == (None, 0.3, None, 0.6, False,
                                                                                         None, 0)
    assert S.SUBJECT_JUMP_M == 0.6 and S.SUBJECT_STEP_M == 0.1 and S.SUBJECT_FOLLOW_M == 0.3
    g = S.SubjectFollower(3, follow_m=1, step_m=0.125, jump_m=2)
    assert (g.player, g.follow_m, g.step_m, g.jump_m, g.chosen) == (3, 1.0, 0.125, 2.0, True)
    assert isinstance(g.follow_m, float) and isinstance(g.jump_m, float)
    assert S.SubjectFollower(0).chosen is True  # id 0 is an id


def test_candidates_before_a_choice_and_before_a_sighting():
    assert S.SubjectFollower().candidates([_body(1)]) == []
    f = S.SubjectFollower(2)
    assert f.candidates([_body(1), _body(2, 5.0), _body(2, 9.0)]) == [(0, 0.0, 1)]  # the id's first holder only
    assert f.candidates([_body(1)]) == []


def test_candidates_tier0_within_follow_m_inclusive_nearest_first_then_the_far_holder():
    f = S.SubjectFollower(7, follow_m=0.5, step_m=None)
    f.take(_body(7, 0.0))
    bodies = [_body(1, 0.5), _body(2, 0.25), _body(3, 0.625), _body(7, 4.0)]
    assert f.candidates(bodies) == [(0, 0.25, 1), (0, 0.5, 0), (1, 4.0, 3)]  # no step_m: the holder at any range
    assert f.candidates([_body(7, 0.25), _body(1, 0.5)]) == [(0, 0.25, 0), (0, 0.5, 1)]  # holder near: not twice


def test_the_holders_reach_is_max_of_follow_and_jump_plus_step_per_missed_frame():
    f = S.SubjectFollower(7, follow_m=0.25, step_m=0.125, jump_m=0.5)
    f.take(_body(7, 0.0))
    assert f.candidates([_body(7, 0.5)]) == [(1, 0.5, 0)]  # 0.5 = jump_m, inclusive
    assert f.candidates([_body(7, 0.625)]) == []
    f.take(None)
    f.take(None)
    assert f.missed == 2
    assert f.candidates([_body(7, 0.75)]) == [(1, 0.75, 0)]  # 0.5 + 2 * 0.125
    assert f.candidates([_body(7, 0.875)]) == []
    g = S.SubjectFollower(7, follow_m=0.5, step_m=0.125, jump_m=0.25)  # follow_m the larger
    g.take(_body(7, 0.0))
    g.take(None)
    g.take(None)
    assert g.candidates([_body(7, 0.75)]) == [(1, 0.75, 0)]
    assert g.candidates([_body(7, 0.875)]) == []
    assert g.candidates([_body(9, 0.75)]) == []  # not the holder, beyond follow_m


def test_a_holder_without_a_finite_joint_is_the_subject_by_its_id():
    f = S.SubjectFollower(7, follow_m=0.25, step_m=0.125, jump_m=0.5)
    f.take(_body(7, 0.0))
    blind = _body(7, positions=[[NAN, NAN, NAN]] * 3)
    assert f.candidates([_body(1, 3.0), blind]) == [(1, float("inf"), 1)]
    assert f.follow([_body(1, 3.0), blind]) is blind
    assert f.last["positions"][0] == [0.0, 0.0, 0.0]  # the reference stays where it was
    assert f.missed == 0


def test_take_records_the_subject_and_counts_missed_frames():
    f = S.SubjectFollower()
    assert f.take(None) is None and f.missed == 1 and f.chosen is False and f.last is None
    assert f.take(None) is None and f.missed == 2
    b = _body(4, 1.0)
    assert f.take(b) is b
    assert (f.player, f.last, f.missed, f.chosen) == (4, b, 0, True)
    half = _body(5, positions=[[NAN, 0, 0], [NAN, NAN, NAN], [0, NAN, 0]])  # no joint finite in all three
    f.take(None)
    assert f.take(half) is half and (f.player, f.last, f.missed) == (5, b, 0)
    one = _body(6, positions=[[NAN, NAN, NAN], [1, 2, 3], [NAN, NAN, NAN]])  # one finite joint: the reference
    assert f.take(one) is one and f.last is one and f.player == 6
    nulls = _body(7, positions=[[None, None, None], [1, 2, 3], [None, 0, 0]])  # JSON nulls: not reported
    assert f.take(nulls) is nulls and f.last is nulls
    blind = _body(8, positions=[[None, None, None]] * 3)
    assert f.take(blind) is blind and f.last is nulls and f.player == 8
    flat = _body(9, positions=[0, 0, 0, 1, 2, 3, 0, 1, 0])  # a flat list of finite numbers: the reference
    assert f.take(flat) is flat and f.last is flat


def test_follow_chooses_the_lowest_id_then_follows_by_joints_and_survives_none():
    f = S.SubjectFollower()
    assert f.follow(None) is None and f.chosen is False and f.missed == 1
    b3, b2 = _body(3, 0.0), _body(2, 5.0)
    assert f.follow([b3, b2]) is b2 and f.player == 2 and f.missed == 0
    moved = _body(6, 5.25)  # renumbered, 0.25 m away: tier 0
    assert f.follow([_body(2, 9.0), moved]) is moved and f.player == 6
    assert f.follow([]) is None and f.missed == 1


# ---- follow_subjects ---------------------------------------------------------------------------------------------

def test_two_actors_who_swap_ids_are_each_found_by_their_joints():
    a, b = S.SubjectFollower(1, step_m=0.1), S.SubjectFollower(2, step_m=0.1)
    S.follow_subjects([a, b], [_body(1, 0.0), _body(2, 2.0)])
    bodies = [_body(2, 0.25), _body(1, 2.25)]  # ids swapped
    got = S.follow_subjects([a, b], bodies)
    assert got[0] is bodies[0] and got[1] is bodies[1]
    assert (a.player, b.player) == (2, 1)


def test_no_body_goes_to_two_followers_the_nearer_wins_and_the_other_is_advanced():
    a, b = S.SubjectFollower(1, 0.5, step_m=None), S.SubjectFollower(2, 0.5, step_m=None)
    S.follow_subjects([a, b], [_body(1, 0.0), _body(2, 0.5)])
    one = _body(5, 0.375)  # 0.375 from a, 0.125 from b, both within follow_m: the nearer, b, takes it
    assert S.follow_subjects([a, b], [one]) == [None, one]
    assert (a.missed, b.missed, b.player) == (1, 0, 5)
    assert S.follow_subjects([a, b], None) == [None, None] and (a.missed, b.missed) == (2, 1)


def test_a_tier0_body_beats_another_followers_nearer_id_holder():
    a, b = S.SubjectFollower(1, step_m=None), S.SubjectFollower(2, step_m=None)
    S.follow_subjects([a, b], [_body(1, 0.0), _body(2, 3.0)])
    x = _body(1, 2.875)  # holds a's id far away (tier 1 for a, 2.875 m), 0.125 m from b (tier 0)
    y = _body(7, 9.0)
    assert S.follow_subjects([a, b], [y, x]) == [None, x]
    assert (a.missed, b.player) == (1, 1)


def test_tier_before_distance_across_followers_with_different_reach():
    a = S.SubjectFollower(1, follow_m=0.5, step_m=None)
    b = S.SubjectFollower(2, follow_m=0.25, step_m=None)
    S.follow_subjects([a, b], [_body(1, 0.0), _body(2, 0.875)])
    x = _body(2, 0.5)  # a's tier 0 at 0.5; b's id holder at 0.375 (tier 1, nearer but a lower tier)
    assert S.follow_subjects([a, b], [x]) == [x, None]
    assert (a.player, b.missed) == (2, 1)


# ---- follow_subject, subject_players, session_subject pass step_m --------------------------------------------

def _frames():
    return [[_body(1, 0.0)], [_body(1, 2.0)], [_body(1, 2.0625)]]  # the id jumps 2 m (another person), then stays


def test_follow_subject_passes_follow_m_and_step_m():
    assert [b is not None for b in S.follow_subject(_frames(), step_m=None)] == [True, True, True]  # the id rules
    # the default since rel7a: the stages' follower, the id holder within the subject's reach (stage_follower)
    assert [b is not None for b in S.follow_subject(_frames())] == [True, False, False]
    assert [b is not None for b in S.follow_subject(_frames(), step_m=0.1)] == [True, False, False]
    far = [[_body(1, 0.0)], [_body(4, 0.5)]]
    assert list(S.follow_subject(far, follow_m=0.5))[1]["player"] == 4
    assert list(S.follow_subject(far))[1] is None
    assert S.subject_players(_frames(), step_m=0.1) == [1, None, None]
    assert S.subject_players(_frames(), step_m=None) == [1, 1, 1]
    assert S.subject_players(_frames()) == [1, None, None]
    assert S.subject_players(far, 1, 0.5) == [1, 4]


def test_session_subject_passes_step_m():
    frames = {10 + k: SimpleNamespace(kinect_bodies=bodies) for k, bodies in enumerate(_frames())}
    session = SimpleNamespace(frame=lambda f: frames[f])
    assert S.session_subject(session, [10, 11, 12], step_m=0.1) == {10: 1, 11: None, 12: None}
    assert S.session_subject(session, [10, 11, 12], step_m=None) == {10: 1, 11: 1, 12: 1}
    assert S.session_subject(session, [10, 11, 12]) == {10: 1, 11: None, 12: None}
    assert S.session_subject(session, [10, 11, 12], 1, 0.1) == {10: 1, 11: None, 12: None}
