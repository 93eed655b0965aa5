"""The run's subject among the tracker's people (:mod:`bodystudio.capture.subject`), against hand-built cases.

Mutation tests (issue 17, docs/mutation/capture-subject.md): every expected value is worked out by hand from
small bodies of two or three joints (distances 3-4-5 triangles, medians of three), never by re-running the
module. Stand-in frames and sessions (``SimpleNamespace``) keep the file well under a second.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from bodystudio.capture import subject as S

NAMES = ["spine", "head", "hand"]


def _body(player, at=(0.0, 0.0, 0.0), names=NAMES, **extra):
    """A body whose joints are ``at`` shifted by 0, 1 and 2 m along x (so a shift of the body moves every joint)."""
    x, y, z = at
    pos = [[x + k, y, z] for k in range(len(names))]
    return {"player": player, "names": list(names), "positions": pos, **extra}


# ---- frame_bodies ----------------------------------------------------------------------------------------------

def test_frame_bodies_reads_kinect_bodies_and_numbers_unnumbered_ones_player_1():
    b2 = _body(2)
    plain = {"names": NAMES, "positions": [[0, 0, 0]] * 3}
    got = S.frame_bodies(SimpleNamespace(kinect_bodies=[b2, plain], kinect_joints=_body(9)))
    assert [b["player"] for b in got] == [2, 1]
    assert got[0] is b2  # a numbered body is passed as it is
    assert got[1]["names"] == NAMES and got[1]["positions"] == plain["positions"]
    assert "player" not in plain  # the frame's body is not modified


def test_frame_bodies_falls_back_to_kinect_joints_then_to_nobody():
    joints = _body(5)
    assert S.frame_bodies(SimpleNamespace(kinect_joints=joints)) == [joints]
    assert S.frame_bodies(SimpleNamespace(kinect_bodies=None, kinect_joints=joints)) == [joints]
    assert S.frame_bodies(SimpleNamespace(kinect_joints={"names": ["a"], "positions": [[0, 0, 0]]}))[0]["player"] == 1
    assert S.frame_bodies(SimpleNamespace(kinect_joints=None)) == []
    assert S.frame_bodies(SimpleNamespace()) == []
    assert S.frame_bodies(SimpleNamespace(kinect_bodies=[])) == []


# ---- body_distance_m -------------------------------------------------------------------------------------------

def test_body_distance_is_the_median_over_shared_finite_joints():
    a = {"names": ["a", "b", "c", "d"], "positions": [[0, 0, 0], [0, 0, 0], [0, 0, 0], [0, 0, 0]]}
    # per joint distances 5 (3-4-5), 1, 13 (5-12-13): median 5; "d" is not in b
    b = {"names": ["c", "a", "b", "e"], "positions": [[5, 12, 0], [3, 4, 0], [0, 0, 1], [100, 0, 0]]}
    assert S.body_distance_m(a, b) == pytest.approx(5.0)
    assert S.body_distance_m(b, a) == pytest.approx(5.0)
    # two shared joints: the median is their mean (5 and 1 -> 3)
    b2 = {"names": ["a", "b"], "positions": [[3, 4, 0], [0, 0, 1]]}
    assert S.body_distance_m(a, b2) == pytest.approx(3.0)
    # positions given flat are read as (n, 3)
    b3 = {"names": ["a", "b"], "positions": [3, 4, 0, 0, 0, 1]}
    assert S.body_distance_m(a, b3) == pytest.approx(3.0)


def test_body_distance_skips_joints_not_finite_on_either_side_and_is_inf_without_shared_joints():
    nan = float("nan")
    a = {"names": ["a", "b", "c"], "positions": [[0, 0, 0], [nan, 0, 0], [0, 0, 0]]}
    b = {"names": ["a", "b", "c"], "positions": [[1, 0, 0], [0, 0, 0], [0, 0, nan]]}
    assert S.body_distance_m(a, b) == pytest.approx(1.0)  # only "a" counts
    assert S.body_distance_m(b, a) == pytest.approx(1.0)
    a_inf = {"names": ["a", "b"], "positions": [[0, np.inf, 0], [0, 0, 0]]}
    b_far = {"names": ["a", "b"], "positions": [[0, 0, 0], [0, 0, 2]]}
    assert S.body_distance_m(a_inf, b_far) == pytest.approx(2.0)
    assert S.body_distance_m(b_far, a_inf) == pytest.approx(2.0)
    assert S.body_distance_m({"names": ["x"], "positions": [[0, 0, 0]]}, b) == float("inf")
    only_nan = {"names": ["a"], "positions": [[nan, nan, nan]]}
    assert S.body_distance_m(only_nan, b) == float("inf")


def test_body_distance_refuses_names_and_positions_of_different_lengths():
    a = {"names": ["a", "b"], "positions": [[0, 0, 0]]}
    with pytest.raises(ValueError):
        S.body_distance_m(a, _body(1))
    with pytest.raises(ValueError):
        S.body_distance_m(_body(1), a)


# ---- first_player / subject_body -------------------------------------------------------------------------------

def test_first_player_is_the_lowest_id():
    assert S.first_player([_body(4), _body(2), _body(3)]) == 2
    assert S.first_player([]) is None


def test_subject_body_picks_the_players_body_or_the_lowest_id():
    b3, b1, b2 = _body(3), _body(1, at=(5, 0, 0)), _body(2)
    frame = SimpleNamespace(kinect_bodies=[b3, b1, b2])
    assert S.subject_body(frame, 2) is b2
    assert S.subject_body(frame, 3) is b3
    assert S.subject_body(frame, None) is b1
    assert S.subject_body(frame, 6) is None
    assert S.subject_body(SimpleNamespace(kinect_bodies=[]), None) is None
    assert S.subject_body(SimpleNamespace(kinect_bodies=[]), 1) is None


# ---- follow_subject / subject_players ----------------------------------------------------------------------------

def test_subject_is_chosen_at_the_first_frame_with_a_body_and_kept_when_a_lower_id_enters():
    frames = [[], None, [_body(3)], [_body(3, at=(0.02, 0, 0)), _body(1, at=(0.8, 0, 0))],
              [_body(1, at=(0.8, 0, 0)), _body(3, at=(0.04, 0, 0))]]
    got = list(S.follow_subject(frames))
    assert got[0] is None and got[1] is None
    assert [b["player"] for b in got[2:]] == [3, 3, 3]
    assert got[4]["positions"][0][0] == pytest.approx(0.04)
    assert S.subject_players(frames) == [None, None, 3, 3, 3]


def test_the_callers_player_is_followed_from_the_first_frame():
    frames = [[_body(1), _body(2, at=(1, 0, 0))], [_body(2, at=(1, 0, 0))], [_body(1)]]
    assert S.subject_players(frames, player=2) == [2, 2, None]
    # a given player absent at first: nothing to follow from until it appears (no last joints)
    far = (1.0, 0, 0)
    assert S.subject_players([[_body(1)], [_body(2, at=far)], [_body(1)]], player=2) == [None, 2, None]
    # ... and once seen, followed under a new id near its last joints
    assert S.subject_players([[_body(1)], [_body(2, at=far)], [_body(1), _body(4, at=far)]], player=2) == [None, 2, 4]


def test_a_new_id_within_follow_m_of_the_last_joints_is_the_subject_and_keeps_it():
    # the subject (2) is lost at frame 1, comes back as 5 at 0.25 m: still the subject, and followed as 5 after
    frames = [[_body(2)], [_body(5, at=(0.25, 0, 0)), _body(1, at=(2, 0, 0))],
              [_body(2, at=(3, 0, 0)), _body(5, at=(0.3, 0, 0))]]
    assert S.subject_players(frames) == [2, 5, 5]
    # farther than follow_m: not the subject
    frames_far = [[_body(2)], [_body(5, at=(0.35, 0, 0))]]
    assert S.subject_players(frames_far) == [2, None]
    # exactly at follow_m is within (<=)
    assert S.subject_players([[_body(2)], [_body(5, at=(0.25, 0, 0))]], follow_m=0.25) == [2, 5]
    assert S.subject_players([[_body(2)], [_body(5, at=(0.25, 0, 0))]], follow_m=0.2) == [2, None]
    # the default threshold is SUBJECT_FOLLOW_M = 0.3 m
    assert S.SUBJECT_FOLLOW_M == 0.3
    assert S.subject_players([[_body(2)], [_body(5, at=(0.29, 0, 0))]]) == [2, 5]
    assert S.subject_players([[_body(2)], [_body(5, at=(0.31, 0, 0))]]) == [2, None]


def test_the_nearest_of_several_candidates_is_taken_and_the_last_seen_joints_are_the_reference():
    frames = [[_body(2)], [_body(6, at=(0.2, 0, 0)), _body(4, at=(0.1, 0, 0)), _body(5, at=(0.15, 0, 0))]]
    got = list(S.follow_subject(frames))
    assert got[1]["player"] == 4
    # the reference is the last frame's subject, not the first: drift of 0.2 m per frame is followed
    drift = [[_body(2, at=(0.2 * k, 0, 0))] for k in range(3)] + [[_body(7, at=(0.6, 0, 0))]]
    assert S.subject_players(drift) == [2, 2, 2, 7]
    # a frame without the subject does not move the reference (None is not the last body)
    gap = [[_body(2)], [_body(1, at=(5, 0, 0))], [_body(3, at=(0.1, 0, 0))]]
    assert S.subject_players(gap) == [2, None, 3]


def test_follow_subject_is_lazy():
    def frames():
        yield [_body(2)]
        raise AssertionError("read past the frames the caller asked for")

    it = S.follow_subject(frames())
    assert next(it)["player"] == 2


def test_follow_subject_without_the_subject_before_any_body():
    assert S.subject_players([[], [], []]) == [None, None, None]
    assert S.subject_players([]) == []


# ---- session_subject / absent_frames ---------------------------------------------------------------------------

class _Session:
    def __init__(self, bodies_by_frame):
        self.bodies = bodies_by_frame
        self.read = []

    def frame(self, f):
        self.read.append(f)
        return SimpleNamespace(kinect_bodies=self.bodies[f])


def test_session_subject_maps_each_frame_id_to_the_subjects_player():
    sess = _Session({10: [_body(2)], 11: [_body(1, at=(1, 0, 0)), _body(2)], 12: [_body(1, at=(1, 0, 0))],
                     13: []})
    assert S.session_subject(sess, [10, 11, 12, 13]) == {10: 2, 11: 2, 12: None, 13: None}
    assert S.session_subject(sess, (f for f in [11, 12])) == {11: 1, 12: 1}
    assert S.session_subject(sess, [11, 12], player=2) == {11: 2, 12: None}


def test_absent_frames_are_those_with_people_but_not_the_subject():
    sess = _Session({0: [_body(2)], 1: [_body(1, at=(1, 0, 0))], 2: [], 3: [_body(1, at=(1, 0, 0))]})
    players = {0: 2, 1: None, 2: None, 3: 1}
    assert S.absent_frames(players, sess) == [1]


# ---- other_players_removed --------------------------------------------------------------------------------------

def test_other_players_depth_is_zeroed_and_the_input_kept():
    depth = np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]], np.float32)
    mask = np.array([[0, 2, 1], [3, 2, 0]], np.uint8)
    out = S.other_players_removed(depth, mask, 2)
    np.testing.assert_array_equal(out, [[1.0, 2.0, 0.0], [0.0, 5.0, 6.0]])
    assert out.dtype == np.float64
    np.testing.assert_array_equal(depth, [[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]])  # not modified in place


def test_other_players_removed_returns_the_input_itself_when_nothing_to_remove():
    depth = np.arange(6, dtype=np.float64).reshape(2, 3)
    assert S.other_players_removed(depth, None, 2) is depth
    assert S.other_players_removed(depth, np.ones((2, 3), np.uint8), None) is depth
    assert S.other_players_removed(depth, np.array([[0, 2, 2], [0, 0, 2]]), 2) is depth


def test_other_players_removed_refuses_a_mask_of_another_size():
    depth = np.zeros((2, 3))
    with pytest.raises(ValueError, match=r"the player mask is \(2, 3\) pixels, the depth image \(3, 2\)"):
        S.other_players_removed(depth, np.zeros((3, 2), np.uint8), 1)


def test_body_distance_reads_json_nulls_as_joints_not_reported():
    # the joints file's layout (docs/session-format.md): an untracked joint is [null, null, null]
    a = {"names": ["a", "b"], "positions": [[None, None, None], [0, 0, 0]]}
    b = {"names": ["a", "b"], "positions": [[0, 0, 0], [0, 3, 4]]}
    assert S.body_distance_m(a, b) == pytest.approx(5.0)
    assert S.body_distance_m(b, a) == pytest.approx(5.0)


def test_a_subject_found_again_under_a_new_id_is_followed_by_that_id_even_after_a_fast_move():
    # lost as 2, found as 5 at 0.1 m; next frame 5 is 0.6 m away (beyond follow_m) but still player 5
    frames = [[_body(2)], [_body(5, at=(0.1, 0, 0))], [_body(5, at=(0.7, 0, 0))]]
    assert S.subject_players(frames) == [2, 5, 5]


def test_other_players_removed_copies_a_float64_depth_image():
    depth = np.array([[1.0, 2.0]], np.float64)
    out = S.other_players_removed(depth, np.array([[1, 2]]), 1)
    np.testing.assert_array_equal(out, [[1.0, 0.0]])
    np.testing.assert_array_equal(depth, [[1.0, 2.0]])
