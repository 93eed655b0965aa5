"""``mirror run`` follows its actor when the Kinect SDK renumbers them (rel6a; rel5a's note in docs/plausibility.md).

The SDK's player ids are not stable: two actors crossing can swap them, and a freed id goes to whoever is tracked
next. ``mirror run --player N`` read each frame's body of id N, so after a swap it reshaped the bystander with the
actor's source body (exit 0), and frames in which the actor held another id passed through as "nobody in view".
Now each reshaped player is followed by its joints (:class:`bodystudio.capture.subject.SubjectFollower`, the follower
``reconstruct`` / ``muscle capture`` use, with a speed limit on the id holder): a renumbered actor keeps being
reshaped, a bystander never is in their place, and a frame without the actor passes through unchanged with a
warning, counted in run.json (``n_subject_missing``; per frame ``tracked_as``).

Mid-stream faults (audited on a real-size copy of session 47, docs/mirror.md "Bad input"): a damaged depth image,
player mask or colour image in a frame the run's self-checks sampled refused the whole run (the same damage in a
frame they did not sample passed through); a frame whose depth or mask was damaged showed the previous frame's
colour. Each now passes through unchanged with a warning, the run going on.

One small synthetic two-actor session (12 frames: 10 of the empty room, then actors 1 and 2 standing apart), its
source body of player 1 from the ground truth (no ``mirror init``), copies with the ids planted: frame 11 swapped, or
actor 1 gone in frame 11 with actor 2 holding id 1.
"""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from bodystudio.capture.faults import restamp

FRAMES = [10, 11]  # the actors' two frames: 10 as recorded, 11 planted
PLANTED = 11


@pytest.fixture(scope="module")
def studio(tmp_path_factory):
    return _two_actor_studio(tmp_path_factory.mktemp("rel6a_subject"), subject_seed=7, n_frames=12)


def _two_actor_studio(root, subject_seed, n_frames):
    """``root/clean``: a two-actor v1 mirror session standing still; ``root/body1.npz``: actor 1's true shape as
    its source body (standing in for mirror init's fit). rel6b's test file builds its studio with it too."""
    from bodystudio.body.statistical import load_statistical_model
    from bodystudio.mirror import synthetic
    from bodystudio.mirror.init import SourceBody, refit_skeleton, save_source_body

    session = synthetic.synth_mirror_session(root / "clean", subject_seed, n_frames=n_frames, actors=2,
                                             edits={"taller": 0.16}, version="v1", motion="a_pose", walk_in=False)
    model = load_statistical_model("6k", progress=False)
    c = session.gt_mirror_actors["source_coeffs"][0]  # actor 1's true shape stands in for mirror init's fit
    save_source_body(root / "body1.npz", SourceBody(c, model.vertices(c), refit_skeleton(model, c), (10,), 0.0),
                     player=1)
    return root


def _plant(studio, tmp_path, name, change_mask, change_bodies):
    """A copy of the clean session with frame PLANTED's player mask and joints changed (manifest restamped)."""
    s = tmp_path / name
    shutil.copytree(studio / "clean", s)
    return _plant_in_place(s, change_mask, change_bodies, [PLANTED])


def _plant_in_place(s, change_mask, change_bodies, frames):
    """The session copy ``s`` with the player mask and joints of ``frames`` changed (manifest restamped; rel6b's
    test file plants with it too)."""
    import cv2

    for i in frames:
        rel = f"kinect/player/{i:05d}.png"
        mask = cv2.imread(str(s / rel), cv2.IMREAD_UNCHANGED)
        assert set(np.unique(mask)) == {0, 1, 2}
        cv2.imwrite(str(s / rel), change_mask(mask))
        restamp(s, rel)
        rel = f"kinect/joints/{i:05d}.json"
        data = json.loads((s / rel).read_text())
        data["bodies"] = change_bodies(data["bodies"])
        first = min(data["bodies"], key=lambda b: b["player"])  # the single-body fields: the lowest id's
        data.update({k: first[k] for k in ("names", "positions", "tracked")})
        (s / rel).write_text(json.dumps(data))
        restamp(s, rel)
    return s


def _swap(mask):
    out = mask.copy()
    out[mask == 1], out[mask == 2] = 2, 1
    return out


def _swap_bodies(bodies):
    return [{**b, "player": 3 - b["player"]} for b in bodies]


def _run(session, studio, tmp_path, name, **kw):
    from bodystudio.mirror.run import run_mirror

    run = tmp_path / name
    doc = run_mirror(session, {"taller": 0.16}, None, source=studio / "body1.npz", progress=False, ramp_frames=0,
                     refine_pose=False, run_dir=run, frames=FRAMES, **kw)
    return doc, run


def _frame(run, i):
    import cv2

    return cv2.imread(str(run / "frames" / f"{i:05d}.png"))


@pytest.fixture(scope="module")
def clean_run(studio, tmp_path_factory):
    return _run(studio / "clean", studio, tmp_path_factory.mktemp("clean_run"), "run")


def test_a_swap_of_ids_keeps_reshaping_the_actor_not_the_bystander(studio, clean_run, tmp_path):
    """Frame 11 with ids 1 and 2 swapped (mask and joints): the run reshapes actor 1 under id 2, the output frame
    equal to the clean session's (before: actor 2 reshaped with actor 1's body, 0.2 m taller, exit 0)."""
    doc0, run0 = clean_run
    swapped = _plant(studio, tmp_path, "swapped", _swap, _swap_bodies)
    doc, run = _run(swapped, studio, tmp_path, "run")
    assert [f["status"] for f in doc["frames"]] == ["ok", "ok"]
    assert [f["tracked_as"] for f in doc["frames"]] == [[1], [2]]
    assert doc["summary"]["n_subject_missing"] == 0
    assert [f["tracked_as"] for f in doc0["frames"]] == [[1], [1]]
    for i in FRAMES:
        assert np.array_equal(_frame(run, i), _frame(run0, i)), i
    # the frame was reshaped at all (not a pass-through that equals by accident)
    from bodystudio.capture.session import open_session

    assert not np.array_equal(_frame(run, PLANTED)[..., ::-1], open_session(swapped).frame(PLANTED).kinect_rgb)


def test_a_bystander_holding_the_actors_id_is_never_reshaped(studio, tmp_path):
    """Actor 1 gone in frame 11 (its pixels and body dropped) and actor 2 given id 1: the frame passes through
    unchanged with a warning naming the player, counted in run.json (before: actor 2 reshaped as player 1)."""
    def mask(m):
        out = m.copy()
        out[m == 1], out[m == 2] = 0, 1
        return out

    def bodies(bs):
        return [{**b, "player": 1} for b in bs if b["player"] == 2]

    gone = _plant(studio, tmp_path, "gone", mask, bodies)
    doc, run = _run(gone, studio, tmp_path, "run")
    f10, f11 = doc["frames"]
    assert f10["status"] == "ok" and f11["status"] == "passed_through"
    assert "player 1 is not among the tracked bodies (players 1)" in f11["warning"]
    assert f11["tracked_as"] == [None] and f11["subject_missing"] is True
    assert doc["summary"]["n_subject_missing"] == 1 and doc["summary"]["n_warnings"] == 1
    from bodystudio.capture.session import open_session

    assert np.array_equal(_frame(run, PLANTED)[..., ::-1], open_session(gone).frame(PLANTED).kinect_rgb)


def test_the_live_mode_follows_the_actor_too(studio, clean_run, tmp_path):
    """``--live FOLDER`` (a recorder's kinect/ streams, read as they arrive) goes through the same follower."""
    _, run0 = clean_run
    swapped = _plant(studio, tmp_path, "swapped", _swap, _swap_bodies)
    from bodystudio.mirror.run import run_mirror

    live = tmp_path / "live"
    (live / "kinect").mkdir(parents=True)
    shutil.copy(swapped / "kinect" / "calibration.json", live / "kinect")
    for stream in ("rgb", "depth", "player", "joints"):  # only the actors' frames: the live run starts at 10
        (live / "kinect" / stream).mkdir()
        for i in FRAMES:
            name = f"{i:05d}.{'json' if stream == 'joints' else 'png'}"
            shutil.copy(swapped / "kinect" / stream / name, live / "kinect" / stream / name)
    doc = run_mirror(swapped, {"taller": 0.16}, None, source=studio / "body1.npz", progress=False, ramp_frames=0,
                     refine_pose=False, run_dir=tmp_path / "run", live=live, live_timeout_s=0.5)
    assert [f["index"] for f in doc["frames"]] == FRAMES
    assert [f["tracked_as"] for f in doc["frames"]] == [[1], [2]]
    assert np.array_equal(_frame(tmp_path / "run", PLANTED), _frame(run0, PLANTED))


def test_the_follower_finds_two_swapped_actors_each_by_their_joints():
    """:func:`follow_subjects`: two followed actors whose ids swap are each found by their joints, one body to
    each; a body holding a follower's id farther than a person moves (``step_m`` per missed frame beyond
    ``follow_m``) is not taken; without ``step_m`` (reconstruct, muscle capture) it is, as before."""
    from bodystudio.capture.subject import SubjectFollower, follow_subjects

    def body(player, x):
        return {"player": player, "names": ["a", "b"], "positions": [[x, 1.0, 2.0], [x, 1.5, 2.0]]}

    a, b = SubjectFollower(1, step_m=0.1), SubjectFollower(2, step_m=0.1)
    assert follow_subjects([a, b], [body(1, 0.0), body(2, 0.8)]) == [body(1, 0.0), body(2, 0.8)]
    got = follow_subjects([a, b], [body(1, 0.78), body(2, 0.03)])  # the ids swapped
    assert [g["player"] for g in got] == [2, 1] and (a.player, b.player) == (2, 1)
    # the actor gone and its id given to someone 1.5 m away: not the actor; the id holder is taken within
    # jump_m + step_m * (frames missed) of the last joints (0.6 m, then 0.7 m after one missed frame)
    lone = SubjectFollower(1, step_m=0.1, jump_m=0.6)
    assert lone.follow([body(1, 0.0)])["player"] == 1
    assert lone.follow([body(1, 1.5)]) is None
    assert lone.follow([body(1, 0.72)]) is None and lone.missed == 2
    assert lone.follow([body(1, 0.78)]) is not None and lone.missed == 0
    assert lone.follow([body(1, 1.3)]) is not None  # a 0.52 m jump under its own id: a glitch, still the actor
    old = SubjectFollower(1)
    old.follow([body(1, 0.0)])
    assert old.follow([body(1, 1.5)]) is not None


def test_mirror_init_follows_the_actor_too(studio, tmp_path):
    """``mirror init --player 1``'s observations (joints, depth points, player masks) read actor 1 under id 2 in the
    swapped frame, as in the clean session (before: actor 2's joints and depth points in the init's fit)."""
    from bodystudio.capture.session import open_session
    from bodystudio.mirror.init import collect_observations

    clean = open_session(studio / "clean")
    swapped = open_session(_plant(studio, tmp_path, "swapped", _swap, _swap_bodies))
    obs0, _ = collect_observations(clean, frames=FRAMES, player=1)
    obs1, _ = collect_observations(swapped, frames=FRAMES, player=1)
    assert [o.frame for o in obs1] == FRAMES
    for a, b in zip(obs0, obs1, strict=True):
        assert np.array_equal(a.points, b.points) and np.array_equal(a.joints, b.joints, equal_nan=True)
        assert np.array_equal(a.player_mask, b.player_mask)


def _put(session, rel, data: bytes):
    (session / rel).write_bytes(data)
    restamp(session, rel)


def _png(image) -> bytes:
    import cv2

    return cv2.imencode(".png", image)[1].tobytes()


def _read(session, rel):
    import cv2

    return cv2.imread(str(session / rel), cv2.IMREAD_UNCHANGED)


def _no_bodies(s):
    rel = f"kinect/joints/{PLANTED:05d}.json"
    _put(s, rel, json.dumps({**json.loads((s / rel).read_text()), "bodies": []}).encode())


def _nan_joints(s):
    rel = f"kinect/joints/{PLANTED:05d}.json"
    data = json.loads((s / rel).read_text())
    for b in data["bodies"]:
        b["positions"] = [[float("nan")] * 3 for _ in b["positions"]]
    _put(s, rel, json.dumps(data).encode())


def _truncated(stream):
    def plant(s):
        rel = f"kinect/{stream}/{PLANTED:05d}.png"
        data = (s / rel).read_bytes()
        _put(s, rel, data[: len(data) // 2])
    return plant


def _depth_resized(s):
    import cv2

    rel = f"kinect/depth/{PLANTED:05d}.png"
    _put(s, rel, _png(cv2.resize(_read(s, rel), (160, 120), interpolation=cv2.INTER_NEAREST)))


def _depth_zero(s):
    rel = f"kinect/depth/{PLANTED:05d}.png"
    _put(s, rel, _png(np.zeros_like(_read(s, rel))))


def _mask(change):
    def plant(s):
        rel = f"kinect/player/{PLANTED:05d}.png"
        _put(s, rel, _png(change(_read(s, rel))))
    return plant


#: Mid-stream faults in frame 11 of a recorded session (audited on a real-size copy of session 47, docs/mirror.md
#: "Bad input"): each passes the frame through unchanged with a warning, the run goes on (exit 0).
FAULTS = [
    ("no-body-tracked", _no_bodies, "player 1 is in the mask but no body is tracked"),
    ("joints-nan", _nan_joints, "tracking failed: no tracked pelvis joints"),
    ("depth-truncated", _truncated("depth"), "depth/00011.png: unreadable image (truncated"),
    ("depth-other-size", _depth_resized, "depth/00011.png: image is 160x120 but kinect/calibration.json says"),
    ("depth-none-measured", _depth_zero, "depth missing (no depth measurement in the frame)"),
    ("mask-value-9", _mask(lambda m: np.where(m > 0, 9, 0).astype(np.uint8)), "values 0...6, got uint8 up to 9"),
    ("mask-empty", _mask(np.zeros_like), "body 1 is tracked but its player mask is empty"),
    ("colour-truncated", _truncated("rgb"), "rgb/00011.png: unreadable image (truncated"),
]


@pytest.mark.parametrize("case, plant, phrase", FAULTS, ids=[f[0] for f in FAULTS])
def test_a_bad_frame_mid_stream_passes_through_with_a_warning(case, plant, phrase, studio, tmp_path):
    from bodystudio.capture.session import open_session

    s = tmp_path / "s"
    shutil.copytree(studio / "clean", s)
    plant(s)
    doc, run = _run(s, studio, tmp_path, "run")
    f10, f11 = doc["frames"]
    assert f10["status"] == "ok" and f11["status"] == "passed_through" and phrase in f11["warning"], f11
    assert doc["summary"]["n_warnings"] == 1
    # unchanged: the frame's own colour image (an unreadable one: the last frame's, as a live mirror shows)
    shown = 10 if case == "colour-truncated" else PLANTED
    assert np.array_equal(_frame(run, PLANTED)[..., ::-1], open_session(studio / "clean").frame(shown).kinect_rgb)


def test_a_file_missing_from_a_recorded_session_is_one_line_and_nothing_is_written(studio, tmp_path, capfd):
    """A recorded session whose manifest lists a file that is gone is refused up front (the session is incomplete),
    in one line, exit 2, no run folder and no video."""
    from .conftest import assert_clean_error, run_inprocess

    s = tmp_path / "s"
    shutil.copytree(studio / "clean", s)
    shutil.copy(studio / "body1.npz", s / "body1.npz")
    (s / f"kinect/depth/{PLANTED:05d}.png").unlink()
    result = run_inprocess(["mirror", "run", s, "--source", s / "body1.npz", "--out", tmp_path / "o.mp4",
                            "--no-refine-pose", "--accept-implausible"], capfd)
    assert_clean_error(result, 2, f"kinect/depth/{PLANTED:05d}.png: missing (listed in session.json)")
    assert not (s / "mirror").exists() and not (tmp_path / "o.mp4").exists()
