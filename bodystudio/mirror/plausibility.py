"""Self-checks of the mirror (Real-time Reshaping of Humans) from its own data: does the source body fit the actor?

``mirror run`` reshapes the actor with a source body fitted by ``mirror init`` (§4). A source body of another
person (the init of session A given to session B with ``--source``, or a session folder copied over another)
is well-formed and runs to the end with exit 0, but every frame is then tracked and warped with the wrong
skeleton: the IK (§5) pulls the wrong limb lengths onto the tracked joints and the reshape starts from the
wrong body. The check compares what the run itself sees, the Kinect skeleton's segment lengths over the
session's frames, with the same segments of the source body's skeleton (§4 scaled them to the init's Kinect
skeleton, Eq. 3 refitted them): :func:`source_body_agreement`.
"""

from __future__ import annotations

import logging

import numpy as np

from bodystudio.body.kinect import kinect_joint_names
from bodystudio.body.kinect import kinect_joints as skeleton_kinect_joints
from bodystudio.errors import BodyStudioError, ImplausibleResultError

#: Kinect segments compared (the limbs and spine §4 scales the body's bones to; hands, feet and head left
#: out: their joints are the tracker's noisiest).
SEGMENTS = (
    ("SpineBase", "SpineMid"), ("SpineMid", "SpineShoulder"),
    ("SpineShoulder", "ShoulderLeft"), ("SpineShoulder", "ShoulderRight"),
    ("ShoulderLeft", "ElbowLeft"), ("ShoulderRight", "ElbowRight"),
    ("ElbowLeft", "WristLeft"), ("ElbowRight", "WristRight"),
    ("HipLeft", "KneeLeft"), ("HipRight", "KneeRight"),
    ("KneeLeft", "AnkleLeft"), ("KneeRight", "AnkleRight"),
)
V1_NAMES = {"SpineBase": "HipCenter", "SpineMid": "Spine", "SpineShoulder": "ShoulderCenter"}
#: Median over segments of |log(session length / source length)|. Measured (docs/mirror.md, 30-frame v2 sessions
#: of subjects 3-6, motions arms_raise / walk / arm_flex / turn, init of 90 frames): the source body's own actor
#: 0.015-0.035 (16 cases); a 3-frame init on a Kinect v1 session of the same actor 0.068; another subject's body
#: 0.020-0.170 (48 cases, 32 above 0.08; subjects 4 and 5 have nearly the same skeleton and pass). Above this
#: the run is refused (``--accept-implausible`` forces it).
SOURCE_MISMATCH_REFUSE = 0.08
#: ... and above this it warns.
SOURCE_MISMATCH_WARN = 0.045
#: Frames of the session read for the check (evenly spread; joints files only, cheap).
CHECK_FRAMES = 60


def _segment_index(version: str) -> list[tuple[int, int]]:
    names = kinect_joint_names(version)
    index = {n: i for i, n in enumerate(names)}
    out = []
    for a, b in SEGMENTS:
        if version == "v1":
            a, b = V1_NAMES.get(a, a), V1_NAMES.get(b, b)
        out.append((index.get(a, -1), index.get(b, -1)))
    return out


def segment_lengths(positions: np.ndarray, tracked: np.ndarray | None, version: str) -> np.ndarray:
    """Lengths ``(len(SEGMENTS),)`` of the Kinect skeleton's segments, NaN where a joint is missing or untracked."""
    P = np.asarray(positions, dtype=np.float64)
    ok = np.all(np.isfinite(P), axis=1)
    if tracked is not None:
        ok &= np.asarray(tracked, bool)
    out = np.full(len(SEGMENTS), np.nan)
    for k, (a, b) in enumerate(_segment_index(version)):
        if a >= 0 and b >= 0 and ok[a] and ok[b]:
            out[k] = float(np.linalg.norm(P[b] - P[a]))
    return out


def source_segment_lengths(skeleton, version: str) -> np.ndarray:
    """The source body's skeleton measured as the Kinect would (its Kinect joints in the rest pose)."""
    J = skeleton_kinect_joints(skeleton, skeleton.heads, skeleton.tails, version)
    return segment_lengths(J, None, version)


def frame_bodies_or_none(session, i) -> list[dict]:
    """Frame ``i``'s tracked bodies, ``[]`` when its joints file cannot be read: the checks skip a damaged frame, which
    the run passes through with its own warning (rel6a: a self-check that sampled it refused the whole run, one that
    did not let it run; the same damage one frame later gave the other answer)."""
    try:
        return session.frame(i).kinect_bodies or []
    except BodyStudioError:
        return []


def followed_players(session, players, frames=None) -> dict[int, tuple[int | None, ...]]:
    """The Kinect id each of ``players`` (the ids they hold at their first tracked frame) holds in each of ``frames``
    (default the session's), followed by its joints as ``mirror run`` follows its actors
    (:func:`bodystudio.capture.subject.follow_subjects` with the run's
    :func:`~bodystudio.capture.subject.stage_follower`); None where an actor is not found. A frame whose joints
    cannot be read is left out (the run passes it through without following). Joints files only (0.2 ms a frame,
    two actors, load 12).

    rel6b: the checks read player N by its id; after the SDK renumbered the actor for most of a session they measured
    the other actor (refused a right source body, or took the other person's skeleton and mask edges)."""
    from bodystudio.capture.subject import follow_subjects, session_follower

    followers = [session_follower(session, int(p)) for p in players]
    out: dict[int, tuple[int | None, ...]] = {}
    for i in (session.frame_ids if frames is None else frames):
        try:
            bodies = session.frame(int(i)).kinect_bodies or []
        except BodyStudioError:
            continue
        # the run's record of a body (run._tracked_record), in the order it reads them (by id)
        records = sorted(({"player": int(b["player"]), "names": b["names"], "positions": b["positions"]}
                          for b in bodies), key=lambda b: b["player"])
        out[int(i)] = tuple(None if f is None else int(f["player"]) for f in follow_subjects(followers, records))
    return out


def actor_ids(session, player: int = 1, frames=None) -> dict[int, int | None]:
    """``{frame: the id the actor holds}`` for one actor (:func:`followed_players`)."""
    return {i: ids[0] for i, ids in followed_players(session, [player], frames).items()}


def _id_in_frame(i, player, tracked_as) -> int | None:
    """The id to read in frame ``i``: the actor's followed id (``tracked_as``), else ``player`` itself."""
    if tracked_as is None:
        return int(player)
    pid = tracked_as.get(int(i))
    return None if pid is None else int(pid)


def session_segment_lengths(session, player: int = 1, frames=None, max_frames: int = CHECK_FRAMES,
                            tracked_as: dict[int, int | None] | None = None) -> tuple[np.ndarray, str | None, int]:
    """Per segment, the median over the session's frames of the tracked lengths of ``player``; the joint set's
    version (the first known set read; frames with an unknown or another set are skipped) and the number of
    frames measured. ``tracked_as`` (:func:`actor_ids`): the id the actor holds in each frame, read instead of
    ``player`` (frames it leaves out or maps to None are skipped; ``frames`` default: its frames)."""
    ids = list((session.frame_ids if tracked_as is None else tracked_as) if frames is None else frames)
    if len(ids) > max_frames:
        ids = [ids[int(round(k))] for k in np.linspace(0, len(ids) - 1, max_frames)]
    rows, version = [], None
    for i in ids:
        pid = _id_in_frame(i, player, tracked_as)
        if pid is None:
            continue
        for body in frame_bodies_or_none(session, i):
            if int(body["player"]) != pid:
                continue
            names = list(body["names"])
            v = "v2" if names == kinect_joint_names("v2") else "v1" if names == kinect_joint_names("v1") else None
            if v is None or (version is not None and v != version):
                continue  # an unknown joint set, or another set than the frames before: skipped, not the verdict
            version = v
            rows.append(segment_lengths(body["positions"], body["tracked"], version))
    if not rows:
        return np.full(len(SEGMENTS), np.nan), version, 0
    R = np.array(rows)
    with np.errstate(all="ignore"):
        med = np.array([np.median(c[np.isfinite(c)]) if np.isfinite(c).any() else np.nan for c in R.T])
    return med, version, len(rows)


def source_body_agreement(body, session, player: int = 1, frames=None,
                          tracked_as: dict[int, int | None] | None = None) -> dict:
    """How well the source body's skeleton fits the actor the session tracks: ``mismatch`` (median over the
    segments of |log(session / source length)|), ``scale`` (median ratio: a body of another stature shows
    here), the per-segment ``ratios`` and the ``frames`` measured. ``mismatch`` is NaN without tracked joints.
    ``tracked_as``: the actor's id per frame (:func:`actor_ids`; None: ``player`` by its id)."""
    seen, version, n = session_segment_lengths(session, player, frames, tracked_as=tracked_as)
    if version is None or n == 0:
        return {"mismatch": float("nan"), "scale": float("nan"), "ratios": {}, "frames": 0}
    mine = source_segment_lengths(body.skeleton, version)
    ok = np.isfinite(seen) & np.isfinite(mine) & (mine > 1e-6)
    if not ok.any():
        return {"mismatch": float("nan"), "scale": float("nan"), "ratios": {}, "frames": n}
    ratio = seen[ok] / mine[ok]
    names = [f"{a}-{b}" for (a, b), keep in zip(SEGMENTS, ok, strict=True) if keep]
    return {"mismatch": float(np.median(np.abs(np.log(ratio)))), "scale": float(np.median(ratio)),
            "ratios": {k: float(r) for k, r in zip(names, ratio, strict=True)}, "frames": n}


def check_source_body(body, session, player: int = 1, accept_implausible: bool = False, source=None,
                      tracked_as: dict[int, int | None] | None = None) -> dict:
    """:func:`source_body_agreement` as ``mirror run``'s verdict (``ok``, ``warnings``, ``problems``); raises
    :class:`~bodystudio.errors.ImplausibleResultError` (one line: the source file and the fix) on a body of
    another person unless ``accept_implausible``. A session without tracked joints of ``player`` is judged
    elsewhere (the run refuses it), so it passes here with ``mismatch`` NaN. The actor is ``player`` at its first
    tracked frame, followed as the run follows it (``tracked_as``, default :func:`actor_ids` over the session)."""
    if tracked_as is None:
        tracked_as = actor_ids(session, player)
    report = source_body_agreement(body, session, player, tracked_as=tracked_as)
    report["renumbered_frames"] = sum(1 for p in tracked_as.values() if p is not None and p != int(player))
    report.update({"mismatch_warn": SOURCE_MISMATCH_WARN, "mismatch_refuse": SOURCE_MISMATCH_REFUSE,
                   "warnings": [], "problems": []})
    mismatch = report["mismatch"]
    where = source if source is not None else f"{session.path}/mirror/source_body.npz"
    worst = sorted(report["ratios"].items(), key=lambda kv: -abs(np.log(kv[1])))[:2]
    detail = (f"the tracked skeleton's segments are {report['scale']:.2f}x the source body's (median), off by "
              f"{np.expm1(mismatch):.0%} per segment (same actor <= {np.expm1(SOURCE_MISMATCH_WARN):.0%}); "
              f"worst {', '.join(f'{k} {v:.2f}x' for k, v in worst)}")
    if np.isfinite(mismatch) and mismatch > SOURCE_MISMATCH_REFUSE:
        report["problems"].append(f"{where} does not fit player {player} of {session.path}: {detail}; it is another "
                                  f"person's source body: run 'bodystudio mirror init {session.path}'")
    elif np.isfinite(mismatch) and mismatch > SOURCE_MISMATCH_WARN:
        report["warnings"].append(f"{where} fits player {player} of {session.path} loosely: {detail}")
    return _verdict(report, accept_implausible)


#: Joint groups the init must have seen: without them the source body's legs (stature) or head come from the
#: statistical model's prior, not from the actor.
INIT_REQUIRED_JOINTS = {"legs": ("KneeLeft", "KneeRight", "AnkleLeft", "AnkleRight"), "head": ("Head",)}
#: A group tracked (all its joints) in fewer than this share of the init frames makes the source body untrusted.
INIT_MIN_SEEN = 0.5
#: The player mask running along an image edge for at least this many pixels in a frame: the actor is cut.
BORDER_PX = 8


def init_coverage(session, frames, player: int = 1, tracked_as: dict[int, int | None] | None = None) -> dict:
    """What the init (§4) saw of the actor in its ``frames``: per joint group of
    :data:`INIT_REQUIRED_JOINTS` the share of frames in which all its joints were tracked, and the share of
    frames in which the player mask touches the depth image's edge (``cut``, per edge). ``tracked_as``: the
    actor's id per frame (:func:`actor_ids`; None: ``player`` by its id)."""
    frames = [int(f) for f in frames]
    seen = {g: 0 for g in INIT_REQUIRED_JOINTS}
    cut = {"top": 0, "bottom": 0, "left": 0, "right": 0}
    n = 0
    for i in frames:
        pid = _id_in_frame(i, player, tracked_as)
        if pid is None:
            continue
        frame = session.frame(i)
        bodies = [b for b in frame_bodies_or_none(session, i) if int(b["player"]) == pid]
        if not bodies:
            continue
        n += 1
        names = list(bodies[0]["names"])
        tracked = np.asarray(bodies[0]["tracked"], bool) & np.all(np.isfinite(bodies[0]["positions"]), axis=1)
        for group, joints in INIT_REQUIRED_JOINTS.items():
            if all(j in names and tracked[names.index(j)] for j in joints):
                seen[group] += 1
        try:
            mask = frame.kinect_player
        except BodyStudioError:  # a damaged mask: the frame's edges are not known
            mask = None
        if mask is not None:
            mine = np.asarray(mask) == pid
            for edge, line in (("top", mine[0]), ("bottom", mine[-1]), ("left", mine[:, 0]), ("right", mine[:, -1])):
                if np.count_nonzero(line) >= BORDER_PX:
                    cut[edge] += 1
    n = max(n, 1)
    return {"frames": len(frames), "seen": {g: v / n for g, v in seen.items()},
            "cut": {e: v / n for e, v in cut.items()}}


def check_init(session, frames, player: int = 1) -> dict:
    """:func:`init_coverage` as ``mirror init``'s verdict: ``warnings`` when a joint group was tracked in fewer
    than :data:`INIT_MIN_SEEN` of the init frames or the actor was cut by an image edge in most of them (the
    source body's missing part is then the statistical model's guess). A warning, not a refusal: measured on
    subject 5, legs out of view below the knees (or the hips) in every init frame moved the fitted stature by
    +5 (+16) mm and the mass by -2.2 (-0.7) kg, subject 3 below the knees -8 mm and -0.7 kg (docs/mirror.md).
    The actor is ``player`` at the session's first tracked frame, followed up to the last of ``frames`` as the init
    follows it (:func:`actor_ids`; rel6b: read by id, a swap measured the other actor)."""
    frames = [int(f) for f in frames]
    last = max(frames, default=-1)
    tracked_as = actor_ids(session, player, [f for f in session.frame_ids if int(f) <= last])
    report = init_coverage(session, frames, player, tracked_as)
    warnings = []
    missing = [g for g, v in report["seen"].items() if v < INIT_MIN_SEEN]
    cut = [e for e, v in report["cut"].items() if v >= INIT_MIN_SEEN]
    if missing or cut:
        what = []
        if missing:
            what.append(" and ".join(f"the {g} tracked in {report['seen'][g]:.0%}" for g in missing))
        if cut:
            what.append(" and ".join(f"the actor cut by the image's {e} edge in {report['cut'][e]:.0%}" for e in cut))
        warnings.append(f"{session.path}: the init saw only part of player {player} ({'; '.join(what)} of its "
                        f"{report['frames']} frames): the source body's unseen part is the model's guess; record "
                        "the actor fully in view (2-3 m from the Kinect) for the first seconds")
    report.update({"min_seen": INIT_MIN_SEEN, "warnings": warnings})
    for line in warnings:
        logging.getLogger(__name__).warning("%s", line)
    return report


#: Largest shift (pixels) searched between the depth-registered player mask and the colour image's edges.
REGISTRATION_SEARCH_PX = 14
#: Median over the checked frames of the best shift's length: above this the depth and colour images are
#: misregistered and the run is refused (the foreground, seeded by the registered player mask, and the warp then
#: carry a band of background). Measured (docs/mirror.md): clean sessions 0-3 px (subjects 3, 5), the colour
#: camera's principal point 10 px off in kinect/calibration.json: 9-11 px.
REGISTRATION_REFUSE_PX = 6.0
#: ... above this it warns.
REGISTRATION_WARN_PX = 4.0
#: Frames (with the player in view, evenly spread) the registration check reads.
REGISTRATION_FRAMES = 6


def registration_offset(rgb: np.ndarray, mask: np.ndarray, radius_px: int = REGISTRATION_SEARCH_PX
                        ) -> tuple[int, int, float]:
    """The shift ``(dx, dy)`` (pixels) that moves the outline of ``mask`` (the player mask registered into the
    colour image) onto the strongest colour edges: the mean Sobel gradient magnitude along the shifted outline,
    maximised over ``+-radius_px``. With depth and colour registered the outline lies on the person's edge, shift
    ~0; returns the shift and its edge strength relative to no shift's."""
    import cv2

    grey = np.asarray(rgb, dtype=np.float32).mean(axis=2)
    G = np.hypot(cv2.Sobel(grey, cv2.CV_32F, 1, 0, ksize=3), cv2.Sobel(grey, cv2.CV_32F, 0, 1, ksize=3))
    m = cv2.morphologyEx(np.asarray(mask, np.uint8), cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    outline = m & ~cv2.erode(m, np.ones((3, 3), np.uint8))
    ys, xs = np.nonzero(outline)
    H, W = G.shape
    r = int(radius_px)
    keep = (ys >= r) & (ys < H - r) & (xs >= r) & (xs < W - r)
    ys, xs = ys[keep], xs[keep]
    if len(ys) == 0:
        return 0, 0, 1.0
    shifts = [(dx, dy) for dy in range(-r, r + 1) for dx in range(-r, r + 1)]
    score = np.array([G[ys + dy, xs + dx].mean() for dx, dy in shifts])
    k = int(np.argmax(score))
    zero = score[shifts.index((0, 0))]
    return shifts[k][0], shifts[k][1], float(score[k] / max(zero, 1e-9))


def depth_color_registration(session, player: int = 1, n_frames: int = REGISTRATION_FRAMES,
                             tracked_as: dict[int, int | None] | None = None) -> dict:
    """:func:`registration_offset` over up to ``n_frames`` frames with ``player`` tracked: the per-frame shifts, their
    median ``offset_px`` (length of the median shift) and ``shift`` (median dx, dy). ``tracked_as``: the actor's id
    per frame (:func:`actor_ids`; None: ``player`` by its id over the session's frames)."""
    from bodystudio.mirror.frames import register_depth_to_color

    ids = session.frame_ids if tracked_as is None else list(tracked_as)
    pids = {int(i): _id_in_frame(i, player, tracked_as) for i in ids}
    with_player = [i for i in ids if pids[int(i)] is not None
                   and any(int(b["player"]) == pids[int(i)] for b in frame_bodies_or_none(session, i))]
    if not with_player:
        return {"offset_px": float("nan"), "shift": None, "frames": []}
    picks = sorted({with_player[int(round(k))] for k in np.linspace(0, len(with_player) - 1,
                                                                   min(n_frames, len(with_player)))})
    rows, images = [], []
    for i in picks:
        frame = session.frame(i)
        try:  # a damaged frame is skipped here; the run passes it through with its own warning
            rgb, depth, players = frame.kinect_rgb, frame.kinect_depth_m, frame.kinect_player
            if rgb is None or depth is None or players is None:  # no player mask: nothing to register (the run decides)
                continue
            _, players_c = register_depth_to_color(depth, players, session.kinect)
        except BodyStudioError:
            continue
        mask = players_c == pids[int(i)]
        if np.count_nonzero(mask) < 500 or mask.shape != rgb.shape[:2]:
            continue
        dx, dy, gain = registration_offset(rgb, mask)
        rows.append({"frame": int(i), "player": pids[int(i)], "dx": int(dx), "dy": int(dy),
                     "edge_gain": round(gain, 3)})
        images.append((rgb, mask))
    if not rows:
        return {"offset_px": float("nan"), "shift": None, "frames": []}
    shift = (float(np.median([r["dx"] for r in rows])), float(np.median([r["dy"] for r in rows])))
    out = {"offset_px": float(np.hypot(*shift)), "shift": list(shift), "frames": rows}
    if out["offset_px"] > REGISTRATION_WARN_PX:
        # misregistered: the same search on the colour images mirrored left-right (an exporter's or a webcam
        # driver's "mirror" setting), which a recalibration would not fix
        flipped = [registration_offset(np.ascontiguousarray(rgb[:, ::-1]), mask)[:2] for rgb, mask in images]
        out["offset_mirrored_px"] = float(np.hypot(*np.median(np.asarray(flipped, float), axis=0)))
    return out


def check_registration(session, player: int = 1, accept_implausible: bool = False,
                       tracked_as: dict[int, int | None] | None = None) -> dict:
    """:func:`depth_color_registration` as ``mirror run``'s verdict; raises
    :class:`~bodystudio.errors.ImplausibleResultError` above :data:`REGISTRATION_REFUSE_PX` unless
    ``accept_implausible``. The actor followed as the run follows it (``tracked_as``, default :func:`actor_ids`)."""
    if tracked_as is None:
        tracked_as = actor_ids(session, player)
    report = depth_color_registration(session, player, tracked_as=tracked_as)
    report.update({"warn_px": REGISTRATION_WARN_PX, "refuse_px": REGISTRATION_REFUSE_PX, "warnings": [],
                   "problems": []})
    offset = report["offset_px"]
    if np.isfinite(offset) and offset > REGISTRATION_WARN_PX:
        dx, dy = report["shift"]
        mirrored = report.get("offset_mirrored_px", float("inf"))
        if mirrored <= REGISTRATION_WARN_PX:
            line = (f"{session.path}/kinect/rgb: the colour images are mirrored left-right (the depth registered "
                    f"into them lands {offset:.0f} px off the person's edges, {mirrored:.0f} px when they are "
                    f"flipped, over {len(report['frames'])} frames): re-import the Kinect colour stream unmirrored")
        else:
            line = (f"{session.path}/kinect/calibration.json: the depth registered into the colour image lands "
                    f"{offset:.0f} px off the person's edges (shift {dx:+.0f}, {dy:+.0f} px over "
                    f"{len(report['frames'])} frames; registered <= {REGISTRATION_WARN_PX:.0f} px): the colour "
                    "camera's intrinsics or depth_to_color are off; re-calibrate the Kinect (bodystudio calib kinect)")
        (report["problems"] if offset > REGISTRATION_REFUSE_PX else report["warnings"]).append(line)
    return _verdict(report, accept_implausible)


def _verdict(report: dict, accept_implausible: bool) -> dict:
    """Close a check's ``report``: ``ok`` set, the first problem raised as one line unless
    ``accept_implausible``, every warning and accepted problem logged."""
    report["ok"] = not report["problems"]
    if report["problems"] and not accept_implausible:
        raise ImplausibleResultError(f"{report['problems'][0]}; or pass --accept-implausible")
    for line in report["warnings"] + report["problems"]:
        logging.getLogger(__name__).warning("%s", line)
    return report
