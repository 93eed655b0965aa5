"""The run's subject among the Kinect body tracker's people: chosen once per run, followed across frames.

The Kinect SDKs track up to six people and number them 1..6 (the ``player`` of each body in
``kinect/joints/NNNNN.json``, the pixel values of ``kinect/player/NNNNN.png``; docs/session-format.md). A stage
that took each frame's lowest player id (:attr:`bodystudio.capture.session.Frame.kinect_joints`) fitted a second
person who came into view with a lower id than the subject's from that frame on (adversarial pass 4: the arm
capture, then ``reconstruct``). Here the subject is chosen once, at the run's first frame with a tracked body (its
lowest id, or the id the caller gives), and followed frame to frame by its id; where that id is gone, a body
whose joints lie within :data:`SUBJECT_FOLLOW_M` of the subject's last joints is the subject tracked again under
a new id (the SDK numbers a person anew after losing them), and otherwise the frame has no subject: None, for the
caller to report, never another person.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Sequence

import numpy as np

#: A body whose joints lie this close (median over the joints both report, metres) to the subject's last tracked
#: joints is the subject under a new player id; two people stand further apart than this (shoulder to shoulder
#: their spines ~0.5 m), and a person moves ~0.05 m between frames at 30 fps.
SUBJECT_FOLLOW_M = 0.3


def frame_bodies(frame) -> list[dict]:
    """A frame's tracked bodies (``[{"player", "names", "positions", ...}]``, :attr:`Frame.kinect_bodies`); a frame
    object with only ``kinect_joints`` gives that one body; ``[]`` when nobody is tracked. A body without a player
    id is player 1, as the session reader reads the single-body layout."""
    bodies = getattr(frame, "kinect_bodies", None)
    if bodies is None:
        joints = getattr(frame, "kinect_joints", None)
        bodies = [] if joints is None else [joints]
    return [b if "player" in b else {**b, "player": 1} for b in bodies]


def body_distance_m(a: dict, b: dict) -> float:
    """Median distance (metres) between two bodies' joints of the same name that both report (finite); inf
    when they share none."""
    if tuple(a["names"]) == tuple(b["names"]):  # one joint set (every frame of a run): the arrays row by row
        xa = np.asarray(a["positions"], np.float64).reshape(-1, 3)
        xb = np.asarray(b["positions"], np.float64).reshape(-1, 3)
        if len(xa) == len(xb) == len(a["names"]) and len(set(a["names"])) == len(xa):
            both = np.isfinite(xa).all(axis=1) & np.isfinite(xb).all(axis=1)
            # the mirror follows its actors every frame: a followed actor among 2 bodies 0.14 instead of 0.89 ms a
            # frame with the dicts below (rel6a, load 10 on 2 cores)
            return float(np.median(np.linalg.norm(xa[both] - xb[both], axis=1))) if both.any() else float("inf")
    pa = dict(zip(a["names"], np.asarray(a["positions"], np.float64).reshape(-1, 3), strict=True))
    pb = dict(zip(b["names"], np.asarray(b["positions"], np.float64).reshape(-1, 3), strict=True))
    d = [float(np.linalg.norm(pa[n] - pb[n])) for n in pa if n in pb and np.all(np.isfinite(pa[n]))
         and np.all(np.isfinite(pb[n]))]
    return float(np.median(d)) if d else float("inf")


def first_player(bodies: Sequence[dict]) -> int | None:
    """The subject a run chooses at its first frame with a tracked body: the lowest player id there (None: nobody
    tracked)."""
    return min((b["player"] for b in bodies), default=None)


#: How fast (metres per second, median over the joints) a person moves at most: 3 m/s, a run across the studio.
#: The follower's reach grows by this times the frame interval per frame the subject was missed
#: (:func:`subject_step_m`; rel7b: before, 0.1 m a frame at any frame rate, 1.5 m/s at 15 fps).
SUBJECT_SPEED_M_S = 3.0
#: The frame rate a session without ``metadata.fps`` was recorded at (the readers' assumption).
DEFAULT_FPS = 30.0
#: How far (metres, median over the joints) a person moves at most between two frames at 30 fps (3 m/s). The
#: mirror (:class:`SubjectFollower` with ``step_m``) takes a body holding the subject's id only within
#: ``jump_m + step_m * (frames the subject was missed)`` of its last joints: further, it is another person the SDK
#: gave the id (a freed id goes to whoever is tracked next), never the subject.
SUBJECT_STEP_M = 0.1
#: How far the subject's own skeleton may jump between two frames under the same id (a tracker glitch, a fit that
#: flips; session 46's synthetic walk-in lands 0.43 m at frame 44, and a 0.3 m reach dropped 2 of its frames), and
#: less than two people stand apart (the two-actor sessions: ~1.0 m).
SUBJECT_JUMP_M = 0.6


def subject_step_m(fps: float | None = None, stride: int = 1) -> float:
    """How far the subject moves at most between two followed frames, ``stride`` frames apart at ``fps``:
    :data:`SUBJECT_SPEED_M_S` times the interval (None: :data:`DEFAULT_FPS`). :data:`SUBJECT_STEP_M` times
    ``stride`` at 30 fps exactly (the rel7a figures unchanged); ValueError for a rate that is no positive number."""
    rate = DEFAULT_FPS if fps is None else float(fps)
    if isinstance(fps, bool) or not np.isfinite(rate) or rate <= 0:
        raise ValueError(f"frame rate {fps!r} is not a positive number of frames per second")
    return SUBJECT_STEP_M * max(int(stride), 1) * (DEFAULT_FPS / rate)


def session_step_m(session, stride: int = 1) -> float:
    """:func:`subject_step_m` at ``session``'s recorded frame rate (``metadata.fps``; 30 without one, as the readers
    assume). A rate that is no number in 1..240 fps is refused naming session.json (InputError)."""
    from pathlib import Path

    from bodystudio.errors import InputError

    metadata = getattr(session, "metadata", None)
    fps = metadata.get("fps") if isinstance(metadata, dict) else None
    if fps is None:
        return subject_step_m(None, stride)
    ok = isinstance(fps, int | float) and not isinstance(fps, bool) and 1.0 <= float(fps) <= 240.0
    if not ok:
        raise InputError(f"{Path(session.path) / 'session.json'}: metadata.fps {fps!r} is not a frame rate in "
                         "1..240; fix it or re-import the recording (bodystudio capture import records it)")
    return subject_step_m(float(fps), stride)


class SubjectFollower:
    """One subject followed frame by frame (:func:`follow_subject` over a whole run; the mirror steps one per actor
    through a live stream, :func:`follow_subjects`).

    ``player``: the subject's id (None: the first frame with a body chooses, :func:`first_player`). Each frame the
    subject is the body nearest its last joints within ``follow_m`` (under whatever id: the SDK renumbers a person it
    lost, and two crossing actors can swap ids); where none is that near, the body holding the subject's current id,
    when ``step_m`` is None (the behaviour of reconstruct and muscle capture) or it lies within
    ``max(follow_m, jump_m) + step_m * missed`` of the last joints (``missed``: frames since the subject was last
    seen), and never one within ``follow_m`` of another person's joints in the frame before (``others``: a body of
    another id, followed as long as it stays; the SDK gave that person the subject's id while the subject was lost;
    rel6b: reconstruct and muscle capture, which take the id holder at any distance, followed the bystander from then
    on);
    otherwise the frame has no subject (None). ``player`` follows the id the subject holds, ``last`` its last
    tracked body.

    ``regain`` (rel7b, with ``step_m``): while the subject is missed, a body of another id lying within
    ``follow_m + step_m * missed`` of its last joints is the subject tracked again under a new id, when it stood
    nowhere near another person in the frame before (a body nobody else held: the SDK's new track of the subject);
    tier 2, after the bodies near its last joints and the id holder. Without it a subject that moved more than
    ``follow_m`` while lost and came back under a new id was never found again."""

    def __init__(self, player: int | None = None, follow_m: float = SUBJECT_FOLLOW_M, step_m: float | None = None,
                 jump_m: float = SUBJECT_JUMP_M, jumped_is_other: bool = False, regain: bool = False):
        self.player, self.follow_m, self.step_m, self.jump_m = player, float(follow_m), step_m, float(jump_m)
        self.jumped_is_other = bool(jumped_is_other)
        self.regain = bool(regain) and step_m is not None
        self.chosen = player is not None
        self.last: dict | None = None
        self.missed = 0
        self.others: list[dict] = []  # the other people's bodies in the frame before
        # the id holder refused in the last frame for lying beyond the reach: {"player", "distance_m", "reach_m",
        # "body"} (None: no such refusal)
        self.refused: dict | None = None

    def candidates(self, bodies: Sequence[dict]) -> list[tuple[int, float, int]]:
        """``(tier, distance m, index)`` of the bodies that may be the subject, best first: tier 0 the bodies within
        ``follow_m`` of its last joints (nearest first; before it was ever seen, the body holding its id), tier 1
        the body holding its id farther away (only within the ``step_m`` reach when that is set, or when it shares no
        finite joint with the last ones)."""
        self.refused = None
        if not self.chosen:
            return []
        if self.last is None:
            return [(0, 0.0, k) for k, b in enumerate(bodies) if b["player"] == self.player][:1]
        dist = [body_distance_m(b, self.last) for b in bodies]
        near = sorted((0, d, k) for k, d in enumerate(dist) if d <= self.follow_m)
        holder = next((k for k, b in enumerate(bodies) if b["player"] == self.player), None)
        if holder is not None and all(k != holder for _, _, k in near):
            reach = np.inf if self.step_m is None else max(self.follow_m, self.jump_m) + self.step_m * self.missed
            # another person where they stood a frame before, now holding the subject's id: not the subject
            other = any(body_distance_m(bodies[holder], o) <= self.follow_m for o in self.others)
            # no joint in common with the last ones (all NaN): nothing tells it apart, the id decides
            if not other and (dist[holder] <= reach or not np.isfinite(dist[holder])):
                near.append((1, dist[holder], holder))
            elif not other:
                self.refused = {"player": bodies[holder]["player"], "distance_m": float(dist[holder]),
                                "reach_m": float(reach), "body": bodies[holder]}
        if self.regain and self.missed > 0:
            radius = self.follow_m + self.step_m * self.missed
            taken = {k for _, _, k in near}
            near += sorted((2, d, k) for k, d in enumerate(dist) if k not in taken and k != holder
                           and self.follow_m < d <= radius
                           and not any(body_distance_m(bodies[k], o) <= self.follow_m for o in self.others))
        return near

    def see_others(self, bodies: Sequence[dict], mine: dict | None) -> None:
        """Remember this frame's other people for :meth:`candidates` in the next: the bodies other than the subject's
        (``mine``) that hold another id, or stand where another person stood a frame before (a body refused only for
        the speed limit while holding the subject's id may be the subject coming back: not marked)."""
        prev = self.others
        jumped = self.refused["body"] if self.jumped_is_other and self.refused is not None else None
        self.others = [b for b in bodies if b is not mine and (b["player"] != self.player or b is jumped or any(
            body_distance_m(b, o) <= self.follow_m for o in prev))]

    def lost_reason(self) -> str:
        """Why the last frame had no subject though its id was held (rel7a), as a clause for the callers' messages
        (``""`` when the id holder was not refused for its distance)."""
        r = self.refused
        if r is None:
            return ""
        frames = max(self.missed, 1)  # the frames since the subject was last seen, this one included
        return (f"; player {r['player']} holds the subject's id {r['distance_m']:.2f} m from its last joints, farther "
                f"than the {r['reach_m']:.2f} m the subject moves in {frames} frame{'s' if frames > 1 else ''}")

    def take(self, body: dict | None) -> dict | None:
        """Record this frame's subject (None: not found) and return it."""
        if body is None:
            self.missed += 1
        else:
            self.player, self.missed, self.chosen = body["player"], 0, True
            if np.isfinite(np.asarray(body["positions"], np.float64)).all(axis=-1).any():
                self.last = body  # a body without a finite joint leaves the reference where it was
        return body

    def follow(self, bodies: Sequence[dict]) -> dict | None:
        """The subject's body in this frame's ``bodies`` (:func:`frame_bodies`), or None."""
        bodies = list(bodies or [])
        if not self.chosen and bodies:
            self.player, self.chosen = first_player(bodies), True
        best = self.candidates(bodies)
        mine = bodies[best[0][2]] if best else None
        self.see_others(bodies, mine)
        return self.take(mine)


def follow_subjects(followers: Sequence[SubjectFollower], bodies: Sequence[dict]) -> list[dict | None]:
    """Each follower's body in one frame, no body given to two: the (tier, distance) best pairs first, so two actors
    who swapped ids are each found by their joints. Advances every follower (:meth:`SubjectFollower.take`)."""
    bodies = list(bodies or [])
    pairs = sorted((c[0], c[1], c[2], j) for j, f in enumerate(followers) for c in f.candidates(bodies))
    found: list[dict | None] = [None] * len(followers)
    used: set[int] = set()
    for _, _, k, j in pairs:
        if found[j] is None and k not in used:
            found[j] = bodies[k]
            used.add(k)
    for f, b in zip(followers, found, strict=True):
        f.see_others(bodies, b)
    return [f.take(b) for f, b in zip(followers, found, strict=True)]


def stage_follower(player: int | None = None, follow_m: float = SUBJECT_FOLLOW_M,
                   step_m: float | None = SUBJECT_STEP_M, regain: bool = True) -> SubjectFollower:
    """The follower of ``reconstruct``, ``muscle capture`` (rel7a) and the mirror (rel7b): the id holder only within
    the subject's reach (``SUBJECT_JUMP_M`` + ``step_m`` per missed frame, the speed limit; :func:`session_step_m`
    gives ``step_m`` at the session's frame rate), and an id holder refused for its distance is another person from
    then on (followed as one while it stays), so a lost subject's id given to a bystander who was not tracked the
    frame before is never taken, however long the subject stays lost. ``regain``: a lost subject is found again under
    a new id within ``follow_m + step_m * missed`` (:class:`SubjectFollower`). Before rel7a these stages took the id
    holder at any distance (``step_m`` None: that old rule, without ``regain``)."""
    return SubjectFollower(player, follow_m, step_m, jumped_is_other=step_m is not None, regain=regain)


def session_follower(session, player: int | None = None, stride: int = 1) -> SubjectFollower:
    """:func:`stage_follower` at ``session``'s frame rate (:func:`session_step_m`, frames ``stride`` apart): the one
    follower of ``reconstruct``, ``muscle capture`` and the mirror's run, init and checks (rel7b)."""
    return stage_follower(player, step_m=session_step_m(session, stride))


def follow_subject(bodies_by_frame: Iterable[Sequence[dict]], player: int | None = None,
                   follow_m: float = SUBJECT_FOLLOW_M, step_m: float | None = SUBJECT_STEP_M,
                   ) -> Iterator[dict | None]:
    """The subject's body in each frame of ``bodies_by_frame`` (each a list of bodies, :func:`frame_bodies`),
    lazily: frames are read only as far as the caller iterates. ``player``: the subject's id; None chooses it at the
    first frame with a body (:func:`first_player`). A frame yields the body nearest the subject's last joints within
    ``follow_m`` (:func:`body_distance_m`), whose id the subject keeps from then on, else the body holding the
    subject's id within the subject's reach (:func:`stage_follower`; ``step_m`` None: at any distance), otherwise
    None (the subject is not in the frame)."""
    follower = stage_follower(player, follow_m, step_m)
    for bodies in bodies_by_frame:
        yield follower.follow(bodies)


def subject_players(bodies_by_frame: Iterable[Sequence[dict]], player: int | None = None,
                    follow_m: float = SUBJECT_FOLLOW_M, step_m: float | None = SUBJECT_STEP_M) -> list[int | None]:
    """The subject's player id in each frame (:func:`follow_subject`; None where the subject is not tracked)."""
    return [None if body is None else body["player"]
            for body in follow_subject(bodies_by_frame, player, follow_m, step_m)]


def subject_body(frame, player: int | None) -> dict | None:
    """The frame's body of ``player`` (:func:`subject_players`; None: the frame's lowest id, as
    :attr:`Frame.kinect_joints`), or None when that player is not tracked in the frame."""
    bodies = frame_bodies(frame)
    if player is None:
        return min(bodies, key=lambda b: b["player"], default=None)
    return next((b for b in bodies if b["player"] == player), None)


def session_subject(session, frame_ids: Sequence[int], player: int | None = None,
                    step_m: float | None | str = "session", reasons: dict | None = None) -> dict[int, int | None]:
    """``{frame id: the subject's player id}`` over a run's frames (:func:`stage_follower`, read from each frame's
    ``kinect/joints``; None where the subject is absent). Computed once per run: a batch chunk that starts after a
    second person came into view gets the run's subject, not the lowest id of its own first frame. ``reasons``: filled
    with ``{frame: SubjectFollower.lost_reason()}`` where the subject is absent. ``step_m`` "session": the step at the
    session's frame rate (:func:`session_step_m`)."""
    follower = stage_follower(player, step_m=session_step_m(session) if step_m == "session" else step_m)
    out: dict[int, int | None] = {}
    for f in frame_ids:
        body = follower.follow(frame_bodies(session.frame(f)))
        out[f] = None if body is None else body["player"]
        if body is None and reasons is not None:
            reasons[f] = follower.lost_reason()
    return out


def absent_frames(players: dict[int, int | None], session) -> list[int]:
    """The frames of ``players`` (:func:`session_subject`) where the tracker reports people but not the subject:
    the run must not take one of them instead (frames with nobody tracked are the joints reader's to refuse)."""
    return [f for f, p in players.items() if p is None and frame_bodies(session.frame(f))]


def other_players_removed(depth_m: np.ndarray, player_mask: np.ndarray | None, player: int | None) -> np.ndarray:
    """The depth image without the pixels the body tracker gives to another person (``kinect/player``: 0 nobody,
    k = player k): 0 (no reading) there, so no depth constraint pairs the subject's template with them. Unchanged
    without a player mask or a subject id, or where the mask shows nobody else; ValueError when the mask is not the
    depth image's size."""
    if player_mask is None or player is None:
        return depth_m
    mask = np.asarray(player_mask)
    if mask.shape != np.shape(depth_m):
        raise ValueError(f"the player mask is {mask.shape[::-1]} pixels, the depth image {np.shape(depth_m)[::-1]}")
    others = (mask > 0) & (mask != player)
    if not others.any():
        return depth_m
    out = np.array(depth_m, dtype=np.float64, copy=True)
    out[others] = 0.0
    return out
