"""rel7b's figures (docs/plausibility.md "rel7b"): whom the subject follower takes in a real-size two-actor mirror
session when the Kinect SDK loses the actor, planted in the joints only (no images are read; seconds).

Usage: PYTHONPATH=. python -m benchmarks.follower_plants SESSION [SESSION ...]   (e.g. /work/e2e15/YS43 YS46)

Per session, three followers of actor 1 (``capture.subject``): the mirror's rule before rel7b (the speed limit alone,
``SubjectFollower(1, step_m=SUBJECT_STEP_M)``), rel7a's stage follower without re-acquisition
(``stage_follower(1, regain=False)``) and rel7b's (``session_follower``: the stage rule at the session's frame rate,
with re-acquisition under a new id), on

* ``clean``: the session as recorded, with ids 1 and 2 swapped from frame 60 (``mirror_bad_input renumber``'s plant);
  prints the frames where a rule's choice differs from the old mirror's (none: the clean runs are unchanged);
* ``bystander``: actor 2 untracked in frames 55-59, then from frame 60 actor 1 gone and actor 2 holding id 1;
* ``new id``: actor 1 untracked in frames 30..N-1 (actor 2 still tracked), back under id 3 from frame N.

and prints the frames followed on another person (a body more than 5 cm from actor 1's true joints) and the frames
where actor 1 is in view but not followed.
"""

from __future__ import annotations

import sys

from bodystudio.capture.session import open_session
from bodystudio.capture.subject import (
    SUBJECT_STEP_M,
    SubjectFollower,
    body_distance_m,
    follow_subjects,
    session_follower,
    stage_follower,
)


def _rules(session, player=1):
    return {"old mirror": SubjectFollower(player, step_m=SUBJECT_STEP_M),
            "rel7a stage": stage_follower(player, regain=False), "rel7b": session_follower(session, player)}


def _score(session, frames, plant, label):
    for name, f in _rules(session).items():
        wrong = absent = 0
        for i in session.frame_ids:
            body = f.follow(plant(i, frames[i]))
            truth = next((x for x in frames[i] if x["player"] == 1), None)
            planted_in = truth is not None and any(body_distance_m(x, truth) < 1e-9 for x in plant(i, frames[i]))
            if body is not None and (truth is None or body_distance_m(body, truth) > 0.05):
                wrong += 1
            elif body is None and planted_in:
                absent += 1
        print(f"{session.path.name} {label:22s} {name:12s} on another person {wrong:3d} frames, actor in view not "
              f"followed {absent:3d}")


def main(paths) -> None:
    for path in paths:
        s = open_session(path)
        frames = {i: sorted(({"player": int(b["player"]), "names": b["names"], "positions": b["positions"]}
                             for b in (s.frame(i).kinect_bodies or [])), key=lambda b: b["player"])
                  for i in s.frame_ids}
        for swap in (False, True):
            for players in ((1,), (1, 2)):
                old = [SubjectFollower(p, step_m=SUBJECT_STEP_M) for p in players]
                new = [session_follower(s, p) for p in players]
                differ = []
                for i in s.frame_ids:
                    recs = [{**b, "player": 3 - b["player"]} if swap and i >= 60 and b["player"] in (1, 2) else b
                            for b in frames[i]]
                    a, b = follow_subjects(old, recs), follow_subjects(new, recs)
                    if [None if x is None else id(x) for x in a] != [None if x is None else id(x) for x in b]:
                        differ.append(i)
                print(f"{s.path.name} clean{' swapped from 60' if swap else ''} actors {players}: "
                      f"{len(differ)} of {len(s.frame_ids)} frames differ {differ[:5]}")

        def bystander(i, bodies):
            if 55 <= i < 60:
                return [b for b in bodies if b["player"] != 2]
            return [{**b, "player": 1} for b in bodies if b["player"] == 2] if i >= 60 else bodies

        _score(s, frames, bystander, "bystander from 60")
        for hi in (36, 40, 45):
            def new_id(i, bodies, hi=hi):
                if 30 <= i < hi:
                    return [b for b in bodies if b["player"] != 1]
                return [{**b, "player": 3} if b["player"] == 1 and i >= hi else b for b in bodies]

            a = next(b for b in frames[29] if b["player"] == 1)
            c = next(b for b in frames[hi] if b["player"] == 1)
            _score(s, frames, new_id, f"new id at {hi} ({body_distance_m(a, c):.2f} m)")


if __name__ == "__main__":
    main(sys.argv[1:])
