"""rel6b's ``plausibility.followed_players`` / ``actor_ids`` / ``_id_in_frame`` and the self-checks' ``tracked_as``,
on hand-built stand-in sessions (mutLL).

Two actors stand 1 m apart; in the frames a case names the SDK swaps their ids, or loses actor 1 and gives its id to
someone else. Each frame's expected ids are worked out by hand from the follower's rules (the body nearest the last
joints within 0.3 m; else the id holder within the mirror's speed limit, 0.6 m + 0.1 m a missed frame, and never
where another person stood a frame before). Actor 1's skeleton is the hand-made one at scale 1, actor 2's at 1.5, so
the segment lengths a check reports say whose joints it read.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from bodystudio.errors import FileFormatError
from bodystudio.mirror import plausibility as P
from tests.mirror.test_plausibility_mirror_mutants import (
    LENGTHS,
    _body,
    _edges_mask,
    _frame,
    _sensor,
    _Session,
    _skeleton,
)


def _at(player, dx, scale=1.0, **kw):
    """``_body(player, scale)`` moved ``dx`` m along x."""
    b = _body(player, scale, **kw)
    return {**b, "positions": b["positions"] + np.array([dx, 0.0, 0.0])}


def _a1(player, f):
    """Actor 1 (scale 1) in frame ``f``, walking 0.02 m a frame, holding id ``player``."""
    return _at(player, 0.02 * f, 1.0)


def _a2(player, f):
    """Actor 2 (scale 1.5) standing 1 m aside, holding id ``player``."""
    return _at(player, 1.0, 1.5)


def _swap_session():
    """Frames 0-1 as given, 2-4 the ids swapped (both tracked), frame 5 back."""
    ids = {0: (1, 2), 1: (1, 2), 2: (2, 1), 3: (2, 1), 4: (2, 1), 5: (1, 2)}
    return _Session({f: _frame(_a2(b, f), _a1(a, f)) for f, (a, b) in ids.items()})


class _Damaged:
    @property
    def kinect_bodies(self):
        raise FileFormatError("kinect/joints/00003.json: truncated")


def test_followed_players_follow_a_swap_by_the_joints():
    s = _swap_session()
    out = P.followed_players(s, [1, 2])
    assert out == {0: (1, 2), 1: (1, 2), 2: (2, 1), 3: (2, 1), 4: (2, 1), 5: (1, 2)}
    assert all(type(k) is int for k in out) and all(type(p) is int for ids in out.values() for p in ids)
    # the actors given in the other order: each tuple in that order
    assert P.followed_players(_swap_session(), [2, 1])[3] == (1, 2)
    # frames: only those, in the order given (numpy integers and strings of the ids taken as ints)
    s = _swap_session()
    out = P.followed_players(s, [np.int64(1)], frames=[np.int64(0), 1, "2"])
    assert out == {0: (1,), 1: (1,), 2: (2,)} and s.reads == [0, 1, 2]
    assert P.actor_ids(_swap_session(), 2) == {0: 2, 1: 2, 2: 1, 3: 1, 4: 1, 5: 2}
    assert P.actor_ids(_swap_session()) == {0: 1, 1: 1, 2: 2, 3: 2, 4: 2, 5: 1}
    # frames given: the follower starts there (id 1 in frame 2 is actor 2, followed from then on)
    assert P.actor_ids(_swap_session(), 1, [2, 3, 5]) == {2: 1, 3: 1, 5: 2}


def test_followed_players_use_the_mirrors_speed_limit_and_the_other_person_rule():
    # actor 1 lost in frame 2; a newcomer 0.8 m from actor 1's last place gets id 1 (nobody stood there): beyond the
    # speed limit's 0.6 m (reconstruct's follower, without it, would take it); actor 1 back as id 3 in frame 3
    frames = {0: _frame(_a1(1, 0), _a2(2, 0)), 1: _frame(_a1(1, 1), _a2(2, 1)),
              2: _frame(_at(1, -0.78), _a2(2, 2)), 3: _frame(_a1(3, 3), _a2(2, 3))}
    assert P.followed_players(_Session(frames), [1, 2]) == {0: (1, 2), 1: (1, 2), 2: (None, 2), 3: (3, 2)}
    # a damaged joints file: the frame left out, the actors followed on
    frames[2] = _Damaged()
    assert P.followed_players(_Session(frames), [1, 2]) == {0: (1, 2), 1: (1, 2), 3: (3, 2)}
    # actor 2 leaves after frame 0, and in frame 1 someone where actor 2 stood holds id 1 while actor 1 is lost
    frames = {0: _frame(_a1(1, 0), _a2(2, 0)), 1: _frame(_at(1, 1.05)), 2: _frame(_a1(4, 2))}
    assert P.followed_players(_Session(frames), [1]) == {0: (1,), 1: (None,), 2: (4,)}
    # an empty frame, and a frame whose bodies are None: nobody found there
    frames = {0: _frame(_a1(1, 0)), 1: _frame(), 2: SimpleNamespace(kinect_bodies=None), 3: _frame(_a1(1, 3))}
    assert P.followed_players(_Session(frames), [1]) == {0: (1,), 1: (None,), 2: (None,), 3: (1,)}


def test_id_in_frame():
    assert P._id_in_frame(7, "2", None) == 2
    assert P._id_in_frame("3", 1, {3: np.int64(2), 4: None}) == 2
    assert type(P._id_in_frame("3", 1, {3: np.int64(2)})) is int
    assert P._id_in_frame(4, 1, {3: 2, 4: None}) is None
    assert P._id_in_frame(5, 1, {3: 2}) is None  # a frame the follower left out: nobody, not the given id


def test_segment_lengths_read_the_followed_id_and_skip_the_frames_without_the_actor():
    s = _swap_session()
    tracked = P.actor_ids(s, 1)
    med, version, n = P.session_segment_lengths(s, 1, tracked_as=tracked)
    assert version == "v2" and n == 6 and med == pytest.approx(LENGTHS, abs=1e-12)
    # by its id alone player 1 is actor 2 in frames 2-4: the median of 1.0 x 3 and 1.5 x 3 frames
    med, _, n = P.session_segment_lengths(_swap_session(), 1)
    assert n == 6 and med == pytest.approx(1.25 * LENGTHS, abs=1e-12)
    # the frames default to tracked_as's; a frame mapped to None is skipped; frames= overrides
    s = _swap_session()
    med, _, n = P.session_segment_lengths(s, 1, tracked_as={1: 1, 3: 1, 4: None})
    assert n == 2 and s.reads == [1, 3] and med == pytest.approx(1.25 * LENGTHS, abs=1e-12)
    s = _swap_session()
    _, _, n = P.session_segment_lengths(s, 1, frames=[0, 2], tracked_as={0: 1, 1: 1, 2: 2})
    assert n == 2 and s.reads == [0, 2]
    # the frames spread over are tracked_as's (the actor's 10 of a 100-frame session), not the session's
    s = _Session({i: _frame(_a1(1, 0)) for i in range(100)})
    _, _, n = P.session_segment_lengths(s, 1, max_frames=5, tracked_as={i: 1 for i in range(90, 100)})
    assert n == 5 and s.reads == [90, 92, 94, 97, 99]


def test_source_body_check_follows_the_actor_and_counts_the_renumbered_frames():
    body = SimpleNamespace(skeleton=_skeleton(1.0))
    r = P.check_source_body(body, _swap_session(), 1)
    assert r["ok"] and r["frames"] == 6 and r["mismatch"] == pytest.approx(0.0, abs=1e-12)
    assert r["renumbered_frames"] == 3
    r2 = P.check_source_body(SimpleNamespace(skeleton=_skeleton(1.5)), _swap_session(), 2, True)
    assert r2["renumbered_frames"] == 3 and r2["mismatch"] == pytest.approx(0.0, abs=1e-12)
    # given tracked_as: used as it is (None entries not counted as renumbered)
    r3 = P.check_source_body(body, _swap_session(), 1, tracked_as={0: 1, 1: None, 2: 2, 3: 2})
    assert r3["renumbered_frames"] == 2 and r3["frames"] == 3 and r3["mismatch"] == pytest.approx(0.0, abs=1e-12)
    a = P.source_body_agreement(SimpleNamespace(skeleton=_skeleton(1.5)), _swap_session(), 1,
                                tracked_as={2: 1, 3: 1})  # id 1 is actor 2 there
    assert a["frames"] == 2 and a["scale"] == pytest.approx(1.0) and a["mismatch"] == pytest.approx(0.0, abs=1e-12)
    a = P.source_body_agreement(body, _swap_session(), 1)  # no tracked_as: by the id
    assert a["mismatch"] == pytest.approx(math.log(1.25), abs=1e-12)


def test_init_coverage_and_check_init_read_the_followed_id_and_its_mask():
    # actor 2's legs untracked; the ids swapped from frame 2; each frame's player mask holds the followed actor's id
    # on the top edge (8 px: a cut) in frame 2 only
    def frame(f, a, b):
        m = _edges_mask(player=a, top=8 if f == 2 else 0)
        return _frame(_a1(a, f), _a2(b, f) | {"tracked": np.array(
            [n not in ("KneeLeft", "AnkleLeft") for n in _a2(b, f)["names"]])}, player_mask=m)

    ids = {0: (1, 2), 1: (1, 2), 2: (2, 1), 3: (2, 1)}
    frames = {f: frame(f, a, b) for f, (a, b) in ids.items()}
    r = P.init_coverage(_Session(frames), [0, 1, 2, 3], 1, {0: 1, 1: 1, 2: 2, 3: 2})
    assert r == {"frames": 4, "seen": {"legs": 1.0, "head": 1.0},
                 "cut": {"top": 0.25, "bottom": 0.0, "left": 0.0, "right": 0.0}}
    r = P.init_coverage(_Session(frames), [0, 1, 2, 3], 1, {0: 1, 1: None, 2: 2})
    assert r["frames"] == 4 and r["cut"]["top"] == 0.5 and r["seen"]["legs"] == 1.0  # over frames 0 and 2
    # by the id: actor 2's legs in frames 2-3, and the mask (id 2 there) never read as player 1's
    r = P.init_coverage(_Session(frames), [0, 1, 2, 3], 1)
    assert r["seen"]["legs"] == 0.5 and r["cut"]["top"] == 0.0
    r = P.check_init(_Session(frames, path="S"), [0, 1, 2, 3], 1)
    assert r["warnings"] == [] and r["seen"]["legs"] == 1.0
    # the follower runs over the session's frames up to the last init frame: frames [2, 3] alone follow the swap
    s = _Session(frames, path="S")
    r = P.check_init(s, [2, 3], 1)
    assert r["seen"]["legs"] == 1.0 and r["frames"] == 2
    # ... and to the last one included: [3] alone is actor 1 under id 2
    assert P.check_init(_Session(frames, path="S"), ["3"], 1)["seen"]["legs"] == 1.0
    assert P.check_init(_Session(frames, path="S"), [], 1)["frames"] == 0


def _reg_swap_session():
    """The registration stand-in (colour and depth cameras coincide): two bright rectangles on a grey colour image,
    actor 1's mask exactly on the left one (shift 0), actor 2's on the right one moved 5 px right, so reading actor
    2's mask measures a 5 px shift (-5 back). The ids swap from frame 2."""
    rgb = np.full((120, 160, 3), 40, np.uint8)
    rgb[30:90, 15:45] = 200
    rgb[30:90, 95:125] = 200
    frames = {}
    for f in range(4):
        a, b = (1, 2) if f < 2 else (2, 1)
        player = np.zeros((120, 160), np.uint8)
        player[30:90, 15:45] = a
        player[30:90, 100:130] = b
        depth = np.where(player > 0, 2.0, 3.0)
        frames[f] = _frame(_a1(a, f), _a2(b, f), player_mask=player, rgb=rgb.copy(), depth=depth)
    return _Session(frames, path="S", kinect=_sensor())


def test_registration_reads_the_followed_actors_mask():
    r = P.check_registration(_reg_swap_session(), 1)
    assert [(row["frame"], row["player"], row["dx"]) for row in r["frames"]] == [(0, 1, 0), (1, 1, 0), (2, 2, 0),
                                                                                  (3, 2, 0)]
    assert r["offset_px"] == 0.0 and r["ok"]
    # by the id: half the frames read actor 2's mask
    r = P.depth_color_registration(_reg_swap_session(), 1)
    assert [(row["player"], row["dx"]) for row in r["frames"]] == [(1, 0), (1, 0), (1, -5), (1, -5)]
    # tracked_as given: its frames only, None skipped
    r = P.depth_color_registration(_reg_swap_session(), 1, tracked_as={1: 1, 2: None, 3: 2})
    assert [(row["frame"], row["player"], row["dx"]) for row in r["frames"]] == [(1, 1, 0), (3, 2, 0)]
    # actor 2 followed by default: its shifted outline in every frame, 5 px (a warning, under the 6 px refusal)
    r = P.check_registration(_reg_swap_session(), 2)
    assert [(row["player"], row["dx"]) for row in r["frames"]] == [(2, -5), (2, -5), (1, -5), (1, -5)]
    assert r["offset_px"] == 5.0 and r["ok"] and len(r["warnings"]) == 1
    r = P.check_registration(_reg_swap_session(), 2, tracked_as={0: 2, 3: 1})
    assert [(row["frame"], row["player"], row["dx"]) for row in r["frames"]] == [(0, 2, -5), (3, 1, -5)]
