"""``reconstruct`` and ``muscle capture`` when the Kinect SDK renumbers the subject mid-session (rel6b).

rel5a's follower (:mod:`bodystudio.capture.subject`), changed by rel6a to prefer the body nearest the subject's last
joints, takes the body holding the subject's id at any distance in these stages (``step_m=None``). Planted in
real-size sessions (``benchmarks/subject_swap.py``, docs/plausibility.md "rel6b"): a bystander 0.8 m aside tracked
throughout, and from one frame on

* the ids exchanged while both are tracked: followed by the joints (the results equal the two-person run's);
* the subject lost for one frame while the bystander is given its id, then back under the other id: before, the
  follower took the bystander as the id holder and then kept following it (nearest to its last joints) for the
  rest of the session: the bystander's arm fed to the arm capture, the bystander's joints to the reconstruction.
  Now a body where another person stood a frame before is never the subject: the frame has no subject, which both
  stages refuse in one line naming the joints file (reconstruct: ``--frames A:B``; muscle: the gap), and the
  subject is found again under its new id by its joints.

Hand-made bodies and stand-in sessions; milliseconds.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from bodystudio.capture import subject as S
from bodystudio.errors import SessionError


def _names():
    from bodystudio.body.kinect import kinect_joint_names

    return kinect_joint_names("v2")


def _body(player, x=0.0):
    """A v2 skeleton standing at ``x`` (joints 0.05 m apart along y)."""
    names = _names()
    pos = np.array([[x, 0.05 * k, 1.0] for k in range(len(names))])
    return {"player": player, "names": names, "positions": pos, "tracked": np.ones(len(names), bool)}


SUBJECT_X, BYSTANDER_X = 0.0, 0.85


def _frames(case, n=6, at=3, lost=1):
    """Bodies per frame: subject player 1 and bystander player 2, from ``at`` on the ``case`` (``lost``: the subject
    not tracked in ``lost`` frames from ``at``)."""
    out = []
    for f in range(n):
        subject, bystander = _body(1, SUBJECT_X + 0.01 * f), _body(2, BYSTANDER_X)
        if case in ("swap", "lost") and f >= at:
            subject["player"], bystander["player"] = 2, 1
        out.append([bystander] if case == "lost" and at <= f < at + lost else [subject, bystander])
    return out


def _x(body):
    return None if body is None else round(float(np.median(body["positions"][:, 0])), 2)


def test_the_follower_never_takes_a_bystander_given_the_lost_subjects_id():
    """Lost for one frame, the bystander holding id 1: before [0.0, 0.01, 0.02, 0.85, 0.85, 0.85] (the bystander
    followed for the rest of the session); now the frame has no subject and the subject is found again."""
    xs = [_x(b) for b in S.follow_subject(_frames("lost"))]
    assert xs == [0.0, 0.01, 0.02, None, 0.04, 0.05]
    assert S.subject_players(_frames("lost")) == [1, 1, 1, None, 2, 2]
    # lost for two frames: the bystander is followed as the other person (it stands where it stood)
    assert [_x(b) for b in S.follow_subject(_frames("lost", lost=2))] == [0.0, 0.01, 0.02, None, None, 0.05]
    # a swap while both are tracked: followed by the joints (held, rel6a)
    assert [_x(b) for b in S.follow_subject(_frames("swap"))] == [0.0, 0.01, 0.02, 0.03, 0.04, 0.05]
    # one person whose skeleton jumps 2 m under its id (a tracker glitch): the id holder at any distance in rel6b;
    # since rel7a beyond the subject's reach (0.6 m + 0.1 m a missed frame) the frame has no subject, and the next
    # frame back where it stood is the subject again (tests/reliability/test_rel7a_follower_jump.py); step_m=None
    # keeps the old rule
    glitch = [[_body(1, 0.0)], [_body(1, 2.0)], [_body(1, 0.0)]]
    assert [_x(b) for b in S.follow_subject(glitch)] == [0.0, None, 0.0]
    assert [_x(b) for b in S.follow_subject(glitch, step_m=None)] == [0.0, 2.0, 0.0]


def test_the_mirror_followers_keep_their_actors():
    """follow_subjects (mirror run): two actors, actor 1 lost in frame 3 and actor 2 given id 1: actor 1 missing
    there (the speed limit already refused the far id holder; the other-person rule agrees), actor 2 kept."""
    followers = [S.SubjectFollower(1, step_m=S.SUBJECT_STEP_M), S.SubjectFollower(2, step_m=S.SUBJECT_STEP_M)]
    seen = [[_x(b) for b in S.follow_subjects(followers, bodies)] for bodies in _frames("lost")]
    assert seen == [[0.0, 0.85], [0.01, 0.85], [0.02, 0.85], [None, 0.85], [0.04, 0.85], [0.05, 0.85]]


class _Session:
    def __init__(self, bodies_by_frame, path="SESSION"):
        self.path = path
        self.frames = {f: SimpleNamespace(frame_id=f, kinect_bodies=b,
                                          kinect_joints=min(b, key=lambda x: x["player"]) if b else None)
                       for f, b in enumerate(bodies_by_frame)}
        self.frame_ids = list(self.frames)

    def frame(self, i):
        return self.frames[i]


def test_reconstruct_refuses_the_frame_without_its_subject():
    """Before: frames 3-5 reconstructed on the bystander (``subject_players`` 1, 1, 1 there, exit 0)."""
    from pathlib import Path

    from bodystudio.reconstruct.sequence import run_subject

    s = _Session(_frames("lost"), path=Path("S"))
    with pytest.raises(SessionError, match=r"^S/kinect/joints/00003.json: the run's subject \(player 1, the first "
                       r"tracked frame's lowest id\) is not tracked in 1 of 6 frames \(first 3, where the tracker "
                       r"reports player 1: another person\); reconstruct the frames before it \(--frames 0:3\)"):
        run_subject(s, s.frame_ids, "tracker")
    assert run_subject(_Session(_frames("swap")), list(range(6)), "tracker") == {0: 1, 1: 1, 2: 1, 3: 2, 4: 2, 5: 2}


def test_the_arm_capture_refuses_the_frame_without_its_subject():
    """Before: the bystander's shoulder, elbow and wrist (0.85 m aside) fed to the arm capture from frame 3 on."""
    from pathlib import Path

    from bodystudio.muscle.capture import session_arm_tracker

    s = _Session(_frames("lost"), path=Path("S"))
    with pytest.raises(SessionError, match=r"^S/kinect/joints/00003.json: the capture's subject \(the first frame's "
                       r"person, followed by its joints\) is not tracked in 1 of 6 frames \(first 3, where the tracker "
                       r"reports player 1: another person\); the arm capture needs the subject in every frame, or "
                       r"capture the 3 frames before it \(--frames 3\)$"):
        session_arm_tracker(s, s.frame_ids, "left")
    arm = session_arm_tracker(_Session(_frames("swap")), list(range(6)), "left")
    assert np.allclose(np.median(arm[:, :, 0], axis=1), 0.01 * np.arange(6))
