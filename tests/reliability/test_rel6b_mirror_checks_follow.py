"""The mirror's self-checks follow the actor as ``mirror run`` does (rel6b; rel6a's note in docs/mirror.md).

rel6a made ``mirror run`` and ``mirror init`` follow their actor by its joints when the Kinect SDK renumbers it
(:class:`bodystudio.capture.subject.SubjectFollower`), but the self-checks (``plausibility.check_source_body``,
``check_registration``, ``check_init``) still read player N by its id: after a swap for most of the session they
measured the other actor, and the run refused the right source body ("it is another person's source body"), the
registration was measured on the other actor's outline, and the init's coverage warned about legs it had seen.

One small synthetic two-actor session (14 frames: 10 of the empty room, then actors 1 and 2 standing apart, subjects
5 and 6, whose skeletons differ by 0.14 per segment: another person's body is refused), actor 1's source body from
the ground truth (no ``mirror init``); copies with the ids planted from frame 11 on (3 of the 4 actor frames).
"""

from __future__ import annotations

import shutil

import pytest

from bodystudio.errors import ImplausibleResultError
from tests.reliability.test_rel6a_mirror import _plant_in_place, _swap, _swap_bodies, _two_actor_studio

ACTOR_FRAMES = [10, 11, 12, 13]
PLANTED = [11, 12, 13]
LEGS = ("KneeLeft", "KneeRight", "AnkleLeft", "AnkleRight")


@pytest.fixture(scope="module")
def studio(tmp_path_factory):
    return _two_actor_studio(tmp_path_factory.mktemp("rel6b_checks"), subject_seed=5, n_frames=14)


def _plant(studio, tmp_path, name, change_mask, change_bodies, frames=PLANTED):
    """A copy of the clean session with the player mask and joints of ``frames`` changed (manifest restamped)."""
    s = tmp_path / name
    shutil.copytree(studio / "clean", s)
    return _plant_in_place(s, change_mask, change_bodies, frames)


@pytest.fixture(scope="module")
def swapped(studio, tmp_path_factory):
    """Ids 1 and 2 swapped in the actor's frames 11-13 (the SDK renumbered both after frame 10)."""
    return _plant(studio, tmp_path_factory.mktemp("swapped"), "swapped", _swap, _swap_bodies)


@pytest.fixture(scope="module")
def gone(studio, tmp_path_factory):
    """Actor 1 gone from frame 11 on (its pixels and body dropped) and actor 2 given id 1."""
    def mask(m):
        out = m.copy()
        out[m == 1], out[m == 2] = 0, 1
        return out

    return _plant(studio, tmp_path_factory.mktemp("gone"), "gone", mask,
                  lambda bs: [{**b, "player": 1} for b in bs if b["player"] == 2])


def _body(studio):
    from bodystudio.mirror.init import load_source_body

    return load_source_body(studio / "body1.npz")


def test_the_source_body_check_follows_a_renumbered_actor(studio, swapped):
    """Ids swapped from frame 11: the check measures actor 1 under id 2 (the clean session's mismatch to the digit,
    3 renumbered frames); before, it measured actor 2 in 3 of 4 frames and refused actor 1's own body."""
    from bodystudio.capture.session import open_session
    from bodystudio.mirror.plausibility import check_source_body

    clean = check_source_body(_body(studio), open_session(studio / "clean"))
    assert clean["ok"] and clean["mismatch"] < 0.045 and clean["renumbered_frames"] == 0
    r = check_source_body(_body(studio), open_session(swapped))
    assert r["ok"] and r["mismatch"] == pytest.approx(clean["mismatch"], abs=1e-12) and r["frames"] == 4
    assert r["renumbered_frames"] == 3


def test_the_source_body_check_never_measures_a_bystander_given_the_id(studio, gone):
    """Actor 1 gone from frame 11 and actor 2 holding id 1: only frame 10 is actor 1's (before: actor 2 measured in
    3 of 4 frames, the run refused)."""
    from bodystudio.capture.session import open_session
    from bodystudio.mirror.plausibility import actor_ids, check_source_body

    s = open_session(gone)
    assert {i: p for i, p in actor_ids(s, 1).items() if i >= 10} == {10: 1, 11: None, 12: None, 13: None}
    r = check_source_body(_body(studio), s)
    assert r["ok"] and r["frames"] == 1 and r["mismatch"] < 0.045
    # actor 2 is another person: its own skeleton against actor 1's body is refused (the check still bites)
    from bodystudio.mirror.plausibility import actor_ids as ids

    with pytest.raises(ImplausibleResultError, match="another person's source body"):
        check_source_body(_body(studio), s, player=2, tracked_as=ids(open_session(studio / "clean"), 2))


def test_the_registration_check_measures_the_followed_actor(studio, swapped, gone):
    """The registration check reads the mask of the id the actor holds: under id 2 after the swap; not at all where
    a bystander holds id 1 (before: the bystander's outline in frames 11-13)."""
    from bodystudio.capture.session import open_session
    from bodystudio.mirror.plausibility import check_registration

    r = check_registration(open_session(swapped))
    assert [(f["frame"], f["player"]) for f in r["frames"]] == [(10, 1), (11, 2), (12, 2), (13, 2)]
    assert r["ok"] and r["offset_px"] <= 4.0
    r = check_registration(open_session(gone))
    assert [f["frame"] for f in r["frames"]] == [10]


def test_the_init_coverage_follows_the_actor(studio, tmp_path):
    """Actor 2's legs untracked in every frame and the ids swapped from frame 11: the init's coverage of actor 1
    (followed under id 2) sees the legs in every frame, no warning; before, it read actor 2 in 3 of 4 frames and
    warned that the init saw player 1's legs in 25 % of them."""
    from bodystudio.capture.session import open_session
    from bodystudio.mirror.plausibility import check_init

    def legless(b):
        if b["player"] != 2:
            return b
        tracked = [t and n not in LEGS for n, t in zip(b["names"], b["tracked"], strict=True)]
        return {**b, "tracked": tracked}

    s = _plant(studio, tmp_path, "legless", lambda m: m, lambda bs: [legless(b) for b in bs], frames=[10])
    s = _plant_in_place(s, _swap, lambda bs: _swap_bodies([legless(b) for b in bs]), PLANTED)
    r = check_init(open_session(s), ACTOR_FRAMES, 1)
    assert r["seen"] == {"legs": 1.0, "head": 1.0} and r["warnings"] == []
    r2 = check_init(open_session(s), ACTOR_FRAMES, 2)  # actor 2 itself: legs never tracked, warned
    assert r2["seen"]["legs"] == 0.0 and "the legs tracked in 0%" in r2["warnings"][0]


def test_mirror_run_keeps_the_right_source_body_after_a_swap(studio, swapped, tmp_path):
    """``mirror run`` on the swapped copy (frames 10, 12, 13): before, refused before the first frame ("it is another
    person's source body", exit 2); now it runs, its plausibility the clean session's."""
    from bodystudio.mirror.run import run_mirror

    doc = run_mirror(swapped, {"taller": 0.16}, None, source=studio / "body1.npz", progress=False, ramp_frames=0,
                     refine_pose=False, run_dir=tmp_path / "run", frames=[10, 12, 13])
    assert [f["tracked_as"] for f in doc["frames"]] == [[1], [2], [2]]
    check = doc["plausibility"]["source_body"]
    assert check["ok"] and check["mismatch"] < 0.045 and check["renumbered_frames"] == 2
    assert [f["player"] for f in doc["plausibility"]["registration"]["frames"]] == [1, 2, 2]
