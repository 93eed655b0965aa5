"""The mirror's self-checks (:mod:`bodystudio.mirror.plausibility`) on hand-made skeletons, sessions and images whose
figures are known by hand: a Kinect v2 / v1 skeleton with twelve distinct segment lengths laid along the axes (a
source body 10 % taller is off by log 1.1 = 0.095 per segment: refused; 5 %: warned; 4 %: passes), sessions of
stand-in frames (other players, untracked joints, frames spread over the run), the init's joint groups and image
edges counted frame by frame, and a colour image whose edges are a known shift away from the registered player
mask. Fast (no synthetic session, no init); the whole-session checks are tests/reliability/test_mirror_plausibility.py.
"""

from __future__ import annotations

import logging
import math
from types import SimpleNamespace

import numpy as np
import pytest

from bodystudio.body.kinect import KINECT_JOINT_SETS, kinect_joint_names, kinect_joints
from bodystudio.errors import ImplausibleResultError
from bodystudio.geometry.camera import Camera, RGBDSensor
from bodystudio.mirror import plausibility as P

# The twelve compared segments (plausibility.SEGMENTS order) and their lengths (metres), all different, each laid
# along one axis from its parent joint so that the length is exact.
LENGTHS = np.array([0.30, 0.20, 0.18, 0.19, 0.28, 0.29, 0.24, 0.25, 0.44, 0.45, 0.42, 0.43])
_LAYOUT = [  # (joint, parent, direction, segment index)
    ("SpineMid", "SpineBase", (0, 1, 0), 0), ("SpineShoulder", "SpineMid", (0, 1, 0), 1),
    ("ShoulderLeft", "SpineShoulder", (1, 0, 0), 2), ("ShoulderRight", "SpineShoulder", (-1, 0, 0), 3),
    ("ElbowLeft", "ShoulderLeft", (1, 0, 0), 4), ("ElbowRight", "ShoulderRight", (-1, 0, 0), 5),
    ("WristLeft", "ElbowLeft", (0, 0, 1), 6), ("WristRight", "ElbowRight", (0, 0, 1), 7),
    ("KneeLeft", "HipLeft", (0, -1, 0), 8), ("KneeRight", "HipRight", (0, -1, 0), 9),
    ("AnkleLeft", "KneeLeft", (0, -1, 0), 10), ("AnkleRight", "KneeRight", (0, -1, 0), 11),
]
V1 = {"SpineBase": "HipCenter", "SpineMid": "Spine", "SpineShoulder": "ShoulderCenter"}


def _joints(scale=1.0, version="v2", lengths=LENGTHS):
    """Kinect joint positions (J, 3) of the hand-made skeleton, segments ``scale`` x ``lengths``; the joints not
    compared (head, hands, feet, neck) lie far away (they must not enter any segment)."""
    pos = {"SpineBase": np.array([0.0, 1.0, 2.5]), "HipLeft": np.array([0.1, 1.0, 2.5]),
           "HipRight": np.array([-0.1, 1.0, 2.5])}
    for joint, parent, d, k in _LAYOUT:
        pos[joint] = pos[parent] + scale * lengths[k] * np.asarray(d, float)
    names = kinect_joint_names(version)
    inv = {v: k for k, v in V1.items()} if version == "v1" else {}
    return np.array([pos.get(inv.get(n, n), np.array([7.0 + i, -5.0 * i, 3.0])) for i, n in enumerate(names)])


def _skeleton(scale=1.0, lengths=LENGTHS):
    """A stand-in game_engine skeleton (bone names, heads, tails) whose Kinect joints (the v2 map) are
    :func:`_joints`: each joint's bone end placed at the joint; ``spine_03``'s head is elsewhere (only its tail is
    SpineShoulder), every other bone end 5 m away."""
    bones = sorted({b for m in KINECT_JOINT_SETS.values() for spec in m.values() for b, _, _ in spec})
    heads = np.tile([5.0, 5.0, 5.0], (len(bones), 1))
    tails = heads.copy()
    J = dict(zip(kinect_joint_names("v2"), _joints(scale, lengths=lengths), strict=True))
    for name, spec in KINECT_JOINT_SETS["v2"].items():
        if len(spec) == 1 and name in J:
            bone, end, _ = spec[0]
            (heads if end == "head" else tails)[bones.index(bone)] = J[name]
    heads[bones.index("spine_03")] = [0.0, 9.0, 0.0]
    return SimpleNamespace(bone_names=bones, heads=heads, tails=tails)


def _body(player=1, scale=1.0, version="v2", untracked=(), nan=()):
    names = kinect_joint_names(version)
    positions = _joints(scale, version)
    tracked = np.ones(len(names), bool)
    for j in untracked:
        tracked[names.index(j)] = False
    for j in nan:
        positions[names.index(j)] = np.nan
    return {"player": player, "names": names, "positions": positions, "tracked": tracked}


class _Session:
    """A stand-in session: ``frames`` maps a frame id to a SimpleNamespace with the Kinect fields read here."""

    def __init__(self, frames, path="SESSION", kinect=None):
        self.frames = frames
        self.frame_ids = list(frames)
        self.path = path
        self.kinect = kinect
        self.reads = []

    def frame(self, i):
        self.reads.append(i)
        return self.frames[i]


def _frame(*bodies, player_mask=None, rgb=None, depth=None):
    return SimpleNamespace(kinect_bodies=list(bodies), kinect_player=player_mask, kinect_rgb=rgb,
                           kinect_depth_m=depth)


# --- segment lengths ---------------------------------------------------------------------------------------------

def test_segment_lengths_of_the_hand_made_skeleton_v2_and_v1():
    assert P.segment_lengths(_joints(), None, "v2") == pytest.approx(LENGTHS, abs=1e-12)
    assert P.segment_lengths(_joints(version="v1"), None, "v1") == pytest.approx(LENGTHS, abs=1e-12)
    assert P.segment_lengths(_joints(1.5), np.ones(25, bool), "v2") == pytest.approx(1.5 * LENGTHS, abs=1e-12)


def test_segment_lengths_are_nan_where_a_joint_is_untracked_or_not_finite():
    names = kinect_joint_names("v2")
    tracked = np.ones(len(names), bool)
    tracked[names.index("ElbowLeft")] = False
    P_ = _joints()
    P_[names.index("KneeRight")] = [np.nan, 0.0, 0.0]
    out = P.segment_lengths(P_, tracked, "v2")
    gone = {4, 6, 9, 11}  # ShoulderLeft-ElbowLeft, ElbowLeft-WristLeft, HipRight-KneeRight, KneeRight-AnkleRight
    assert [k for k in range(12) if np.isnan(out[k])] == sorted(gone)
    keep = [k for k in range(12) if k not in gone]
    assert out[keep] == pytest.approx(LENGTHS[keep], abs=1e-12)
    # an infinite position of a tracked joint is no length either
    P_ = _joints()
    P_[names.index("WristRight")] = [np.inf, 0.0, 0.0]
    assert np.isnan(P.segment_lengths(P_, np.ones(len(names), bool), "v2")[7])
    # a tracked list of 0/1 ints counts as booleans
    assert np.isnan(P.segment_lengths(_joints(), tracked.astype(int), "v2")[4])


def test_source_segment_lengths_measure_the_skeleton_as_the_kinect_would():
    sk = _skeleton(1.2)
    assert P.source_segment_lengths(sk, "v2") == pytest.approx(1.2 * LENGTHS, abs=1e-12)
    expected = P.segment_lengths(kinect_joints(sk, sk.heads, sk.tails, "v1"), None, "v1")
    assert P.source_segment_lengths(sk, "v1") == pytest.approx(expected, abs=1e-12)
    assert P.source_segment_lengths(sk, "v1") == pytest.approx(1.2 * LENGTHS, abs=1e-12)


def test_session_segment_lengths_median_of_one_player_over_frames():
    """Player 1's frames at scales 1.0, 1.1, 0.95 (median 1.0 x); player 2 (twice as tall) and frames without
    bodies are ignored; a joint untracked in one frame leaves that segment's median to the other frames."""
    frames = {0: _frame(_body(2, 2.0), _body(1, 1.0)), 1: _frame(), 2: _frame(_body(2, 2.0)),
              3: _frame(_body(1, 1.1, untracked=("KneeLeft",))), 4: _frame(_body(1, 0.95)), 5: _frame(None)}
    frames[5].kinect_bodies = None
    med, version, n = P.session_segment_lengths(_Session(frames))
    assert version == "v2" and n == 3
    expected = LENGTHS.copy()
    expected[[8, 10]] *= (1.0 + 0.95) / 2  # the knee's segments from frames 0 and 4 only
    assert med == pytest.approx(expected, abs=1e-12)
    med2, _, n2 = P.session_segment_lengths(_Session(frames), player=2)
    assert n2 == 2 and med2 == pytest.approx(2.0 * LENGTHS, abs=1e-12)
    # player given as a string id of the joints file
    frames[6] = _frame(dict(_body(1, 1.2), player="1"))
    assert P.session_segment_lengths(_Session(frames))[2] == 4


def test_session_segment_lengths_v1_unknown_joint_sets_and_nothing_tracked():
    frames = {0: _frame(_body(1, 1.0, version="v1")), 1: _frame(_body(1, 1.3, version="v1"))}
    med, version, n = P.session_segment_lengths(_Session(frames))
    assert version == "v1" and n == 2 and med == pytest.approx(1.15 * LENGTHS, abs=1e-12)
    odd = dict(_body(1), names=list(reversed(kinect_joint_names("v2"))))
    med, version, n = P.session_segment_lengths(_Session({0: _frame(odd)}))
    assert version is None and n == 0 and np.all(np.isnan(med)) and med.shape == (12,)
    # a segment never tracked stays NaN
    med, _, n = P.session_segment_lengths(_Session({0: _frame(_body(untracked=("WristLeft",)))}))
    assert n == 1 and np.isnan(med[6]) and np.isfinite(np.delete(med, 6)).all()


def test_an_odd_joint_set_in_the_last_frame_does_not_silence_the_check():
    """mutB's finding: the version came from the last body read, so a last frame with an unknown (or the other)
    joint set made the whole check NaN and a body of another person passed unseen."""
    odd = dict(_body(1), names=list(reversed(kinect_joint_names("v2"))))
    frames = {0: _frame(_body(1, 1.3)), 1: _frame(_body(1, 1.3)), 2: _frame(odd),
              3: _frame(_body(1, 1.0, version="v1"))}
    med, version, n = P.session_segment_lengths(_Session(frames))
    assert version == "v2" and n == 2 and med == pytest.approx(1.3 * LENGTHS, abs=1e-12)
    r = P.source_body_agreement(SimpleNamespace(skeleton=_skeleton()), _Session(frames))
    assert r["frames"] == 2 and r["scale"] == pytest.approx(1.3, abs=1e-9)


def test_session_segment_lengths_spread_over_the_frames():
    """Frame i at scale 1 + i / 1000; with ``max_frames`` 3 of 100 frames, frames 0, 50 and 99 are read (median:
    frame 50); the default reads 60 frames; ``frames`` restricts the ids."""
    frames = {i: _frame(_body(1, 1.0 + i / 1000)) for i in range(100)}
    s = _Session(frames)
    med, _, n = P.session_segment_lengths(s, max_frames=3)
    assert n == 3 and s.reads == [0, 50, 99] and med == pytest.approx(1.05 * LENGTHS, abs=1e-12)
    s = _Session(frames)
    assert P.session_segment_lengths(s)[2] == 60 == P.CHECK_FRAMES and s.reads[:3] == [0, 2, 3]
    s = _Session(frames)
    med, _, n = P.session_segment_lengths(s, frames=[10, 20, 30])
    assert n == 3 and s.reads == [10, 20, 30] and med == pytest.approx(1.02 * LENGTHS, abs=1e-12)
    # exactly max_frames: every frame
    s = _Session({i: frames[i] for i in range(60)})
    assert P.session_segment_lengths(s)[2] == 60 and s.reads == list(range(60))


# --- source body agreement and its verdict ------------------------------------------------------------------------

def _actor_session(scale=1.0, n=5, player=1, path="SESSION"):
    return _Session({i: _frame(_body(player, scale)) for i in range(n)}, path=path)


def test_source_body_agreement_figures():
    body = SimpleNamespace(skeleton=_skeleton(1.1))
    r = P.source_body_agreement(body, _actor_session())
    assert r["mismatch"] == pytest.approx(math.log(1.1), abs=1e-12) and r["scale"] == pytest.approx(1 / 1.1)
    assert r["frames"] == 5 and list(r["ratios"]) == [f"{a}-{b}" for a, b in P.SEGMENTS]
    assert all(v == pytest.approx(1 / 1.1) for v in r["ratios"].values())
    # one segment off by 2x, one by 0.5x: the median over the segments ignores them
    lengths = LENGTHS.copy()
    lengths[4] *= 2.0
    lengths[9] *= 0.5
    r = P.source_body_agreement(SimpleNamespace(skeleton=_skeleton(lengths=lengths)), _actor_session())
    assert r["mismatch"] == pytest.approx(0.0, abs=1e-12) and r["scale"] == pytest.approx(1.0)
    assert r["ratios"]["ShoulderLeft-ElbowLeft"] == pytest.approx(0.5)
    assert r["ratios"]["HipRight-KneeRight"] == pytest.approx(2.0)


def test_source_body_agreement_mismatch_is_the_median_of_absolute_logs():
    """Segments at ratios e^0.1 (6 of them) and e^-0.05 (6): median |log| 0.075 (the median log would be 0.025)."""
    lengths = LENGTHS * np.where(np.arange(12) % 2 == 0, math.exp(-0.1), math.exp(0.05))
    r = P.source_body_agreement(SimpleNamespace(skeleton=_skeleton(lengths=lengths)), _actor_session())
    assert r["mismatch"] == pytest.approx(0.075, abs=1e-12)
    assert r["scale"] == pytest.approx((math.exp(-0.05) + math.exp(0.1)) / 2, abs=1e-12)  # numpy's even median


def test_source_body_agreement_without_tracked_joints_or_usable_segments():
    body = SimpleNamespace(skeleton=_skeleton())
    r = P.source_body_agreement(body, _actor_session(player=2))
    assert math.isnan(r["mismatch"]) and math.isnan(r["scale"]) and r["ratios"] == {} and r["frames"] == 0
    flat = _skeleton(lengths=np.zeros(12))
    r = P.source_body_agreement(SimpleNamespace(skeleton=flat), _actor_session(n=4))
    assert math.isnan(r["mismatch"]) and math.isnan(r["scale"]) and r["ratios"] == {} and r["frames"] == 4
    # one source segment of zero length is left out, the others compared
    lengths = LENGTHS.copy()
    lengths[0] = 0.0
    r = P.source_body_agreement(SimpleNamespace(skeleton=_skeleton(lengths=lengths)), _actor_session())
    assert len(r["ratios"]) == 11 and "SpineBase-SpineMid" not in r["ratios"] and r["mismatch"] < 1e-12
    # the check over given frames only
    s = _Session({0: _frame(_body(1, 1.0)), 1: _frame(_body(1, 1.5)), 2: _frame(_body(1, 1.5))})
    r = P.source_body_agreement(SimpleNamespace(skeleton=_skeleton()), s, frames=[0])
    assert r["frames"] == 1 and r["mismatch"] < 1e-12


def _detail(scale, mismatch, worst):
    return (f"the tracked skeleton's segments are {scale:.2f}x the source body's (median), off by "
            f"{math.expm1(mismatch):.0%} per segment (same actor <= 5%); worst {worst}")


def _off(scale, worst):
    """The hand-made skeleton ``scale`` x taller, with the segments of ``worst`` ({index: factor}) further off."""
    lengths = LENGTHS.copy()
    for k, f in worst.items():
        lengths[k] *= f
    return SimpleNamespace(skeleton=_skeleton(scale, lengths=lengths))


def test_another_persons_body_is_refused_with_the_file_and_the_fix():
    """Ten segments 1.1x the session's, ElbowRight-WristRight 1.43x and ShoulderLeft 1.32x: mismatch log 1.1 (the
    median), the worst two named first by |log ratio|."""
    body = _off(1.1, {7: 1.3, 2: 1.2})
    with pytest.raises(ImplausibleResultError) as e:
        P.check_source_body(body, _actor_session(path="S"))
    worst = "ElbowRight-WristRight 0.70x, SpineShoulder-ShoulderLeft 0.76x"
    assert str(e.value) == (f"S/mirror/source_body.npz does not fit player 1 of S: "
                            f"{_detail(1 / 1.1, math.log(1.1), worst)}; it is another person's source body: run "
                            "'bodystudio mirror init S'; or pass --accept-implausible")
    with pytest.raises(ImplausibleResultError, match=r"^other\.npz does not fit player 1 of S: "):
        P.check_source_body(body, _actor_session(path="S"), source="other.npz")


def _logged(caplog):
    """The messages this module's logger wrote, as the user reads them."""
    return [rec.getMessage() for rec in caplog.records if rec.name == "bodystudio.mirror.plausibility"]


def test_accepted_refusal_and_warning_and_pass(caplog):
    s = _actor_session(path="S")
    with caplog.at_level(logging.WARNING, logger="bodystudio.mirror.plausibility"):
        r = P.check_source_body(SimpleNamespace(skeleton=_skeleton(1.1)), s, accept_implausible=True)
    assert r["ok"] is False and len(r["problems"]) == 1 and r["warnings"] == []
    assert r["mismatch_warn"] == 0.045 and r["mismatch_refuse"] == 0.08
    assert r["problems"][0] in caplog.text
    assert _logged(caplog) == [r["problems"][0]]
    with caplog.at_level(logging.WARNING, logger="bodystudio.mirror.plausibility"):
        r = P.check_source_body(_off(1.05, {5: 1.2, 10: 0.9}), s)
    worst = "ShoulderRight-ElbowRight 0.79x, KneeLeft-AnkleLeft 1.06x"
    assert r["ok"] is True and r["problems"] == []
    assert r["warnings"] == [f"S/mirror/source_body.npz fits player 1 of S loosely: "
                             f"{_detail(1 / 1.05, math.log(1.05), worst)}"]
    assert r["warnings"][0] in caplog.text
    assert _logged(caplog)[-1] == r["warnings"][0]
    r = P.check_source_body(SimpleNamespace(skeleton=_skeleton(1.04)), s)
    assert r["ok"] is True and r["warnings"] == [] and r["problems"] == []
    assert r["mismatch"] == pytest.approx(math.log(1.04))


@pytest.mark.parametrize("mismatch, verdict", [(0.0801, "refuse"), (0.0799, "warn"), (0.0451, "warn"),
                                               (0.0449, "ok")])
def test_source_mismatch_boundaries(mismatch, verdict):
    r = P.check_source_body(SimpleNamespace(skeleton=_skeleton(math.exp(mismatch))), _actor_session(),
                            accept_implausible=True)
    assert bool(r["problems"]) == (verdict == "refuse") and bool(r["warnings"]) == (verdict == "warn")


def test_a_session_without_the_player_passes_here_and_another_player_is_checked():
    body = SimpleNamespace(skeleton=_skeleton())
    r = P.check_source_body(body, _actor_session(player=2))
    assert r["ok"] and math.isnan(r["mismatch"]) and r["warnings"] == [] and r["problems"] == []
    r = P.check_source_body(SimpleNamespace(skeleton=_skeleton(1.2)), _actor_session(player=2), accept_implausible=True)
    assert r["ok"]  # player 1 is not in the session
    with pytest.raises(ImplausibleResultError, match="does not fit player 2 of"):
        P.check_source_body(SimpleNamespace(skeleton=_skeleton(1.2)), _actor_session(player=2), player=2)


# --- the init's coverage ----------------------------------------------------------------------------------------

def _edges_mask(player=1, top=0, bottom=0, left=0, right=0, shape=(40, 50)):
    m = np.zeros(shape, np.uint8)
    m[0, :top] = player
    m[-1, :bottom] = player
    m[:left, 0] = player
    m[:right, -1] = player
    return m


def test_init_coverage_counts_joint_groups_and_image_edges_per_frame():
    frames = {
        0: _frame(_body(1), player_mask=_edges_mask(top=8, left=7)),
        1: _frame(_body(1, untracked=("AnkleRight",)), player_mask=_edges_mask(top=9, bottom=8, right=8)),
        2: _frame(_body(1, nan=("Head",)), _body(2), player_mask=_edges_mask(player=2, top=20)),
        3: _frame(_body(2)),  # the player not in this frame: not counted
        4: _frame(_body(1), player_mask=None),
    }
    r = P.init_coverage(_Session(frames), [0, 1, 2, 3, 4])
    assert r == {"frames": 5, "seen": {"legs": 0.75, "head": 0.75},
                 "cut": {"top": 0.5, "bottom": 0.25, "left": 0.0, "right": 0.25}}
    r = P.init_coverage(_Session(frames), ["0", 2])
    assert r == {"frames": 2, "seen": {"legs": 1.0, "head": 0.5}, "cut": {"top": 0.5, "bottom": 0.0, "left": 0.0,
                                                                         "right": 0.0}}
    r = P.init_coverage(_Session(frames), [3], player=1)
    assert r == {"frames": 1, "seen": {"legs": 0.0, "head": 0.0}, "cut": {"top": 0.0, "bottom": 0.0, "left": 0.0,
                                                                         "right": 0.0}}
    r = P.init_coverage(_Session(frames), [2, 3], player=2)
    assert r["seen"] == {"legs": 1.0, "head": 1.0} and r["cut"]["top"] == 0.5


def test_init_coverage_needs_every_joint_of_a_group_by_name():
    """A v1 body lacks no group joint; a joint set without 'Head' leaves the head unseen."""
    b = _body(1, version="v1")
    assert P.init_coverage(_Session({0: _frame(b)}), [0])["seen"] == {"legs": 1.0, "head": 1.0}
    names = list(b["names"])
    names[names.index("Head")] = "Skull"
    b2 = dict(b, names=names)
    assert P.init_coverage(_Session({0: _frame(b2)}), [0])["seen"] == {"legs": 1.0, "head": 0.0}


def test_check_init_warns_about_unseen_groups_and_cut_edges(caplog):
    frames = {i: _frame(_body(1, untracked=("KneeLeft",) if i < 3 else ()),
                        player_mask=_edges_mask(bottom=10 if i < 2 else 0)) for i in range(4)}
    with caplog.at_level(logging.WARNING, logger="bodystudio.mirror.plausibility"):
        r = P.check_init(_Session(frames, path="S"), range(4))
    assert r["warnings"] == ["S: the init saw only part of player 1 (the legs tracked in 25%; the actor cut by the "
                             "image's bottom edge in 50% of its 4 frames): the source body's unseen part is the "
                             "model's guess; record the actor fully in view (2-3 m from the Kinect) for the first "
                             "seconds"]
    assert r["min_seen"] == 0.5 and r["warnings"][0] in caplog.text
    assert _logged(caplog) == r["warnings"]
    assert r["seen"] == {"legs": 0.25, "head": 1.0}
    # half the frames is enough for a group (>= 0.5), an edge cut in half of them warns (>= 0.5)
    frames = {i: _frame(_body(1, untracked=("Head", "KneeLeft") if i < 2 else ()),
                        player_mask=_edges_mask(left=8 if i < 1 else 0)) for i in range(4)}
    r = P.check_init(_Session(frames, path="S"), range(4))
    assert r["warnings"] == []
    frames[1].kinect_player = _edges_mask(left=8)
    r = P.check_init(_Session(frames, path="S"), range(4))
    assert r["warnings"] == ["S: the init saw only part of player 1 (the actor cut by the image's left edge in 50% "
                             "of its 4 frames): the source body's unseen part is the model's guess; record the "
                             "actor fully in view (2-3 m from the Kinect) for the first seconds"]
    # both groups missing, two edges: joined with "and"
    frames = {0: _frame(_body(2, untracked=("Head",)), player_mask=_edges_mask(2, top=8, right=8))}
    r = P.check_init(_Session(frames, path="S"), [0], player=2)
    assert r["warnings"][0].startswith("S: the init saw only part of player 2 (the head tracked in 0%; the actor cut "
                                       "by the image's top edge in 100% and the actor cut by the image's right edge "
                                       "in 100% of its 1 frames)")
    frames = {0: _frame(_body(1, untracked=("Head", "AnkleLeft")))}
    r = P.check_init(_Session(frames, path="S"), [0])
    assert "(the legs tracked in 0% and the head tracked in 0% of its 1 frames)" in r["warnings"][0]
    assert P.check_init(_Session({0: _frame(_body(1))}, path="S"), [0])["warnings"] == []


# --- depth / colour registration ----------------------------------------------------------------------------------

def _scene(shift=(0, 0), size=(120, 160), box=(30, 90, 50, 110)):
    """A grey image with a bright rectangle (rows box[0]:box[1], columns box[2]:box[3]) and the player mask of the
    same rectangle moved by ``shift`` (dx, dy) pixels."""
    rgb = np.full((*size, 3), 40, np.uint8)
    r0, r1, c0, c1 = box
    rgb[r0:r1, c0:c1] = 200
    dx, dy = shift
    mask = np.zeros(size, bool)
    mask[r0 + dy:r1 + dy, c0 + dx:c1 + dx] = True
    return rgb, mask


@pytest.mark.parametrize("shift, gain", [((0, 0), 1.0), ((3, -2), 59.06), ((-5, 4), 59.06), ((0, 7), 2.1935)])
def test_registration_offset_finds_the_shift_back_onto_the_edges(shift, gain):
    """The shift back is exact; the edge gain (the best shift's mean Sobel magnitude over the unshifted one's) is
    large when the unshifted outline misses both edges of a corner, ~2 when it still lies on one side's edges."""
    rgb, mask = _scene(shift)
    dx, dy, g = P.registration_offset(rgb, mask)
    assert (dx, dy) == (-shift[0], -shift[1])
    assert g == pytest.approx(gain, rel=2e-3)


def test_registration_offset_gain_without_any_edge_under_the_outline():
    """No colour edge under the unshifted outline (a flat image but for a faint step 10 px right of the mask): the
    gain is the best score over 1e-9, not over 1."""
    rgb = np.full((120, 160, 3), 100, np.uint8)
    rgb[:, 80:] = 101
    mask = np.zeros((120, 160), bool)
    mask[30:90, 40:70] = True
    dx, _, gain = P.registration_offset(rgb, mask)
    assert dx in (10, 11) and gain > 1e8


def test_registration_offset_search_radius_and_an_outline_near_the_border():
    rgb, mask = _scene((9, 0))
    assert P.registration_offset(rgb, mask)[:2] == (-9, 0)
    # within +-4 px: the farthest shift in the edges' direction (the Sobel reaches the edge from 1 px)
    assert P.registration_offset(*_scene((-5, -5)), radius_px=4)[:2] == (4, 4)
    assert P.registration_offset(*_scene((-5, 0)), radius_px=4)[:2] == (4, 0)
    # the outline on rows 14 and 106, columns 14 and 146 (the search radius from the border: 14 px of 120 x 160):
    # the outline pixels kept are those every shift can read; the edges 1 px down and 2 px right
    rgb, mask = _scene((-2, -1), box=(15, 108, 16, 149))
    ys, xs = np.nonzero(mask)
    assert (ys.min(), ys.max(), xs.min(), xs.max()) == (14, 106, 14, 146)
    assert P.registration_offset(rgb, mask)[:2] == (2, 1)
    # a mask whose outline lies within the search radius of the image border everywhere: no shift
    rgb, mask = _scene(box=(5, 115, 5, 155))
    assert P.registration_offset(rgb, mask) == (0, 0, 1.0)
    assert P.registration_offset(rgb, np.zeros((120, 160), bool)) == (0, 0, 1.0)


def test_registration_offset_ignores_specks_of_the_mask():
    """A one-pixel speck of the mask (opened away) far from any edge would pull the mean edge strength."""
    rgb, mask = _scene((0, 0))
    for y, x in [(10, 20), (100, 20), (15, 140)]:
        mask[y, x] = True
    dx, dy, gain = P.registration_offset(rgb, mask)
    assert (dx, dy) in [(0, 0), (-1, 0), (0, -1), (-1, -1)] and gain < 1.05


def _sensor(w=160, h=120, f=150.0):
    cam = Camera("k_depth", [[f, 0, w / 2], [0, f, h / 2], [0, 0, 1]], None, np.eye(3), np.zeros(3), w, h)
    col = Camera("k_color", cam.K, None, np.eye(3), np.zeros(3), w, h)
    return RGBDSensor("k", "v2", cam, col, np.eye(4))


def _reg_session(shifts, players=None, path="S"):
    """Frames whose depth and colour cameras coincide (the registration maps a pixel onto itself): frame i's
    player mask is the rectangle moved by ``shifts[i]`` from the colour image's."""
    frames = {}
    for i, s in enumerate(shifts):
        rgb, mask = _scene(s)
        depth = np.where(mask, 2.0, 3.0)
        player = mask.astype(np.uint8)
        bodies = [_body(1)] if players is None or players[i] else [_body(2)]
        frames[i] = _frame(*bodies, player_mask=player, rgb=rgb, depth=depth)
    return _Session(frames, path=path, kinect=_sensor())


def test_depth_color_registration_is_the_median_shift_over_the_frames():
    s = _reg_session([(0, 0), (5, 0), (5, 0), (6, 1), (5, 0), (6, 0), (8, 8), (0, 0)])
    r = P.depth_color_registration(s, n_frames=6)
    picked = [row["frame"] for row in r["frames"]]
    assert picked == [0, 1, 3, 4, 6, 7]  # linspace(0, 7, 6) rounded
    dxs = sorted(row["dx"] for row in r["frames"])
    assert r["shift"] == [float(np.median(dxs)), float(np.median([row["dy"] for row in r["frames"]]))]
    assert r["offset_px"] == pytest.approx(math.hypot(*r["shift"]))
    assert -6 <= r["shift"][0] <= -4
    # the id each frame's mask was read under (rel6b: the actor followed, tests/reliability/test_rel6b_*)
    assert all(set(row) == {"frame", "player", "dx", "dy", "edge_gain"} and row["player"] == 1 for row in r["frames"])
    g = P.registration_offset(*_scene((5, 0)))[2]
    assert r["frames"][1]["edge_gain"] == round(g, 3) and round(g, 3) != round(g, 4)
    assert P.depth_color_registration(s)["frames"][0]["frame"] == 0 and len(P.depth_color_registration(s)["frames"]) \
        == P.REGISTRATION_FRAMES == 6


def test_depth_color_registration_skips_frames_it_cannot_use():
    s = _reg_session([(5, 0)] * 4, players=[False, True, True, True])  # frame 0 has only player 2
    r = P.depth_color_registration(s, n_frames=2)
    assert [row["frame"] for row in r["frames"]] == [1, 3]
    s.frames[1].kinect_rgb = None  # no colour image
    s.frames[3].kinect_player = np.zeros_like(s.frames[3].kinect_player)  # the player not in the mask
    r = P.depth_color_registration(s, n_frames=3)
    assert [row["frame"] for row in r["frames"]] == [2]
    s.frames[2].kinect_depth_m = None
    r = P.depth_color_registration(s, n_frames=3)
    assert math.isnan(r["offset_px"]) and r["shift"] is None and r["frames"] == []
    r = P.depth_color_registration(s, player=3)
    assert math.isnan(r["offset_px"]) and r["shift"] is None and r["frames"] == []


def test_depth_color_registration_needs_500_mask_pixels_of_the_colour_images_size():
    s = _reg_session([(5, 0)])
    small = np.zeros((120, 160), np.uint8)
    small[40:60, 60:84] = 1  # 480 pixels
    s.frames[0].kinect_player = small
    assert P.depth_color_registration(s)["frames"] == []
    small[:] = 0
    small[40:60, 60:85] = 1  # 500: enough
    s.frames[0].kinect_player = small
    s.frames[0].kinect_depth_m = np.where(small > 0, 2.0, 3.0)
    assert len(P.depth_color_registration(s)["frames"]) == 1
    small[40:61, 60:84] = 1  # 504
    s.frames[0].kinect_depth_m = np.where(small > 0, 2.0, 3.0)
    assert len(P.depth_color_registration(s)["frames"]) == 1
    s.frames[0].kinect_rgb = np.zeros((100, 160, 3), np.uint8)  # another size than the colour camera's
    assert P.depth_color_registration(s)["frames"] == []


def test_check_registration_warns_and_refuses_with_the_calibration_file(caplog):
    ok = P.check_registration(_reg_session([(0, 0)] * 3))
    assert ok["ok"] and ok["warnings"] == [] and ok["problems"] == [] and ok["offset_px"] <= 1.5
    assert (ok["warn_px"], ok["refuse_px"]) == (4.0, 6.0)
    with pytest.raises(ImplausibleResultError) as e:
        P.check_registration(_reg_session([(9, 0)] * 3))
    msg = str(e.value)
    assert msg.startswith("S/kinect/calibration.json: the depth registered into the colour image lands ")
    assert msg.endswith("px): the colour camera's intrinsics or depth_to_color are off; re-calibrate the Kinect "
                        "(bodystudio calib kinect); or pass --accept-implausible")
    r = P.check_registration(_reg_session([(9, 0)] * 3), accept_implausible=True)
    dx, dy = r["shift"]
    assert r["problems"] == [f"S/kinect/calibration.json: the depth registered into the colour image lands "
                             f"{r['offset_px']:.0f} px off the person's edges (shift {dx:+.0f}, {dy:+.0f} px over 3 "
                             "frames; registered <= 4 px): the colour camera's intrinsics or depth_to_color are off; "
                             "re-calibrate the Kinect (bodystudio calib kinect)"]
    assert not r["ok"] and r["warnings"] == []
    with caplog.at_level(logging.WARNING, logger="bodystudio.mirror.plausibility"):
        r = P.check_registration(_reg_session([(5, 0)] * 3))
    assert r["ok"] and r["problems"] == [] and len(r["warnings"]) == 1 and r["warnings"][0] in caplog.text
    assert 4.0 < r["offset_px"] <= 6.0
    none = P.check_registration(_reg_session([(5, 0)] * 2, players=[False, False]))
    assert none["ok"] and math.isnan(none["offset_px"]) and none["warnings"] == []


@pytest.mark.parametrize("offset, verdict", [(4.0, "ok"), (4.01, "warn"), (6.0, "warn"), (6.01, "refuse")])
def test_registration_boundaries(monkeypatch, offset, verdict):
    monkeypatch.setattr(P, "depth_color_registration",
                        lambda session, player=1, tracked_as=None: {"offset_px": offset, "shift": [offset, 0.0],
                                                                    "frames": [{}]})
    r = P.check_registration(_Session({}, path="S"), accept_implausible=True)
    assert bool(r["problems"]) == (verdict == "refuse") and bool(r["warnings"]) == (verdict == "warn")


def test_check_registration_of_another_player(monkeypatch):
    seen = []
    monkeypatch.setattr(P, "depth_color_registration",
                        lambda session, player=1, tracked_as=None: seen.append(player)
                        or {"offset_px": 0.0, "shift": [0.0, 0.0], "frames": []})
    P.check_registration(_Session({}), player=3)
    assert seen == [3]
