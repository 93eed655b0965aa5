"""The subject's plausible motion between frames bounds whom ``reconstruct`` and ``muscle capture`` follow (rel7a).

rel6b's follower in these stages (``capture.subject``, ``step_m=None``) took the body holding the subject's id at any
distance unless another person had stood there the frame before. So the subject lost for a frame and its id given to
a bystander who was *not* tracked the frame before (walking in, or just found by the SDK) was followed: the
bystander's joints 0.85 m aside posed the reconstruction and fed the arm capture, and the follower then kept
following the bystander by its joints. Now (``capture.subject.stage_follower``) the id holder is the subject only
within the subject's reach, the mirror's speed limit: ``SUBJECT_JUMP_M`` (0.6 m) plus ``SUBJECT_STEP_M`` (0.1 m) per
frame the subject was missed; an id holder refused for its distance is another person from then on (followed as
one while it stays), so the reach growing over a long loss never lets it in. The next frames: the subject is found
again by its joints (within 0.3 m of its last, under any id); until then the frames have no subject, which
``reconstruct`` refuses and ``muscle capture`` skips (a bounded number; rel7a) naming the id holder's distance.

Hand-made bodies, stand-in sessions and rel7a's 8-frame 2k arm session (``conftest.rel7a_arm``).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from bodystudio.capture import subject as S
from bodystudio.errors import SessionError
from tests.reliability.test_rel6b_subject_lost import _body  # one v2 skeleton standing at x
from tests.reliability.test_rel7b_follower import _Session  # a stand-in session of bodies per frame
from tests.reliability.test_rel7b_follower import _walk_in as rel7b_walk_in


def _walk_in(n=8, at=3, lost=3):
    """The subject (player 1, walking +0.01 m a frame) alone; lost in frames ``at`` .. ``at + lost - 1`` while a
    bystander never tracked before is found 0.85 m aside and given id 1; then the subject back under id 2."""
    return rel7b_walk_in(n, at, lost)


def _x(body):
    return None if body is None else round(float(np.median(body["positions"][:, 0])), 2)


def test_a_bystander_given_the_lost_subjects_id_is_not_followed():
    """Before (``step_m=None``): [0.0, 0.01, 0.02, 0.85, 0.85, 0.85, 0.85, 0.85] (the bystander from frame 3 on, for
    good). Now the frames without the subject are None and the subject is found again under id 2."""
    assert [_x(b) for b in S.follow_subject(_walk_in(), step_m=None)] == [0.0, 0.01, 0.02] + [0.85] * 5
    assert [_x(b) for b in S.follow_subject(_walk_in())] == [0.0, 0.01, 0.02, None, None, None, 0.06, 0.07]
    assert S.subject_players(_walk_in()) == [1, 1, 1, None, None, None, 2, 2]
    # lost for 8 frames: the reach grows to 0.6 + 0.8 m, but the id holder refused once stays another person
    assert [_x(b) for b in S.follow_subject(_walk_in(n=14, lost=8))] == [0.0, 0.01, 0.02] + [None] * 8 + \
        [0.11, 0.12, 0.13]
    # the mirror's rule before rel7b (the speed limit alone, still the class default) takes it after three missed frames
    mirror = S.SubjectFollower(step_m=S.SUBJECT_STEP_M)
    assert [_x(mirror.follow(b)) for b in _walk_in(n=14, lost=8)][3:7] == [None, None, None, 0.85]


def test_the_subjects_own_motion_and_glitches_within_the_reach_are_followed():
    """A subject moving 0.1 m a frame (3 m/s), a skeleton glitch of 0.5 m for one frame: followed under its id; one
    of 2 m: that frame has no subject and the next, back where it stood, is the subject (rel6b took the glitch)."""
    walk = [[_body(1, 0.1 * f)] for f in range(6)]
    assert [_x(b) for b in S.follow_subject(walk)] == [0.0, 0.1, 0.2, 0.3, 0.4, 0.5]
    glitch = [[_body(1, 0.0)], [_body(1, 0.5)], [_body(1, 0.0)]]
    assert [_x(b) for b in S.follow_subject(glitch)] == [0.0, 0.5, 0.0]
    far = [[_body(1, 0.0)], [_body(1, 2.0)], [_body(1, 0.0)]]
    assert [_x(b) for b in S.follow_subject(far)] == [0.0, None, 0.0]


def test_reconstruct_refuses_the_bystander_naming_its_distance():
    """Before: ``run_subject`` gave player 1 in every frame (the bystander posed frames 3-7, exit 0)."""
    from bodystudio.reconstruct.sequence import run_subject

    s = _Session(_walk_in())
    with pytest.raises(SessionError, match=r"^S/kinect/joints/00003.json: the run's subject \(player 1, the first "
                       r"tracked frame's lowest id\) is not tracked in 3 of 8 frames \(first 3, where the tracker "
                       r"reports player 1: another person; player 1 holds the subject's id 0.83 m from its last "
                       r"joints, farther than the 0.60 m the subject moves in 1 frame\); reconstruct the frames "
                       r"before it \(--frames 0:3\)"):
        run_subject(s, s.frame_ids, "tracker")
    assert run_subject(s, s.frame_ids[:3], "tracker") == {0: 1, 1: 1, 2: 1}


def test_the_arm_tracker_marks_the_frames_without_the_subject():
    from bodystudio.muscle.capture import session_arm_tracker_rows

    rows, problems = session_arm_tracker_rows(_Session(_walk_in()), list(range(8)), "left")
    assert sorted(problems) == [3, 4, 5] and all(rows[f] is None for f in (3, 4, 5))
    assert "player 1 holds the subject's id 0.83 m from its last joints" in problems[3][1]
    assert np.allclose([np.median(rows[f][:, 0]) for f in (0, 1, 2, 6, 7)], [0.0, 0.01, 0.02, 0.06, 0.07])


def test_the_arm_capture_skips_the_frame_the_bystander_holds(rel7a_arm):
    """rel7a's 8-frame arm session, the subject lost in frame 5 and the bystander (not tracked before) given its id
    0.85 m aside, the subject back under id 2 from frame 6: before, the bystander's shoulder, elbow and wrist were the
    tracker's in frame 5 and, followed by its joints, in every frame after. Now frame 5 is skipped, named, and the
    tracker rows of the other frames are the clean session's."""
    from bodystudio.capture.session import open_session
    from bodystudio.muscle.capture import session_arm_tracker, session_arm_tracker_rows

    session = open_session(rel7a_arm.planted)
    ids = session.frame_ids
    rows, problems = session_arm_tracker_rows(session, ids, "left")
    assert sorted(problems) == [5] and "another person; player 1 holds the subject's id 0.86 m" in problems[5][1]
    ref = session_arm_tracker(open_session(rel7a_arm.clean), ids, "left")
    np.testing.assert_allclose(np.stack([rows[f] for f in ids if f != 5]), np.delete(ref, 5, axis=0))
    assert "P/kinect/joints/00005.json: frame 5 skipped (the capture's subject is not tracked" in \
        rel7a_arm.planted_stderr
    params = json.loads((rel7a_arm.cap_planted / "params.json").read_text())
    assert 5 in [s["frame"] for s in params["skipped_frames"]] and 5 not in params["frame_ids"]
