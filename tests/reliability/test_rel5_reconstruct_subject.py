"""``reconstruct`` and a second person in the Kinect tracker's view (rel5, found by adv4, docs/plausibility.md).

The studio's subject is player 2 from the first frame; from frame 2 a bystander 0.8 m to the side is tracked as
player 1, so the frame's lowest id (``Frame.kinect_joints``) is the bystander. Before: ``reconstruct`` posed the
template on each frame's lowest player (the bystander's joints from frame 2 on, and the run's bone lengths taken
of both people), and a batch chunk starting at frame 2 chose the bystander by itself. Now the run's subject is
chosen once (:mod:`bodystudio.capture.subject`), followed over the frames, used by the sequential path (per frame
and tracked), the bone lengths and every batch chunk, and recorded in run.json (``subject_player``); a frame
where only another person is tracked is refused naming its joints file, and the tracker's player mask keeps
another person's depth pixels out of the depth constraints."""

from __future__ import annotations

import json
import shutil
from dataclasses import asdict

import numpy as np
import pytest

from bodystudio.capture.faults import restamp
from tests.reliability.conftest import assert_clean_error, run_inprocess

FRAMES = 4
ENTERS = 2  # the bystander is tracked from this frame on


@pytest.fixture(scope="module")
def sessions(tmp_path_factory):
    """A clean 2-camera, 4-frame 160x120 walk (the subject: player 2 in every frame) and its copy with the
    bystander (player 1) tracked from frame 2; read-only, copy to modify."""
    from bodystudio.capture.synth import synth_session

    root = tmp_path_factory.mktemp("rel5subject")
    clean = root / "clean"
    synth_session(clean, n_cameras=2, n_frames=FRAMES, motion="walk", subject_seed=7, kinect="v1",
                  resolution=(160, 120), noise=False, template="2k", n_background=1)
    for frame in range(FRAMES):
        _rewrite_joints(clean, frame, lambda data, f=frame: _as_player(data, 2))
    planted = root / "planted"
    shutil.copytree(clean, planted)
    for frame in range(ENTERS, FRAMES):
        _rewrite_joints(planted, frame, _bystander_enters)
    return clean, planted


def _rewrite_joints(session, frame: int, change) -> None:
    rel = f"kinect/joints/{frame:05d}.json"
    data = json.loads((session / rel).read_text())
    change(data)
    (session / rel).write_text(json.dumps(data))
    restamp(session, rel)


def _body(data: dict, player: int, shift=(0.0, 0.0, 0.0)) -> dict:
    return {"player": player, "names": data["names"], "tracked": data["tracked"],
            "positions": [None if p[0] is None else [p[0] + shift[0], p[1] + shift[1], p[2] + shift[2]]
                          for p in data["positions"]]}


def _as_player(data: dict, player: int) -> None:
    data["bodies"] = [_body(data, player)]


def _bystander_enters(data: dict, subject_id: int = 2, bystander_only: bool = False) -> None:
    """A bystander 0.8 m to the side is tracked with a lower id (1) than the subject's: the frame's first body."""
    subject = next(b for b in data["bodies"] if b["player"] == 2)
    subject = {**subject, "player": subject_id}
    other = _body(subject, 1, shift=(0.8, 0.0, -0.3))
    data.update({k: other[k] for k in ("names", "positions", "tracked")})
    data["bodies"] = [other] if bystander_only else [other, subject]


RUN = {"template": "2k", "refine_pose": False}


def _params():
    from bodystudio.reconstruct.rapid_skin import RapidSkinParams

    return RapidSkinParams(outer_iterations=2, inner_iterations=4)


def _meshes(session):
    from bodystudio.geometry.mesh import load_mesh
    from bodystudio.reconstruct.sequence import read_reconstruction

    run, paths = read_reconstruction(session)
    return run, {f: load_mesh(p).vertices for f, p in paths.items()}


@pytest.fixture(scope="module")
def clean_run(sessions, tmp_path_factory):
    """The clean session's sequential reconstruction (meshes by frame, run.json)."""
    from bodystudio.reconstruct.sequence import reconstruct_session

    S = tmp_path_factory.mktemp("rel5clean") / "S"
    shutil.copytree(sessions[0], S)
    reconstruct_session(S, params=_params(), **RUN)
    return _meshes(S)


def test_the_subject_is_chosen_once_and_followed():
    """The shared choice over per-frame bodies: the first frame's lowest id, followed by its id; a body near the
    subject's last joints under a new id is the subject tracked again; a frame with only someone else is None."""
    from bodystudio.capture.subject import subject_players

    def body(player, x):
        return {"player": player, "names": ["SpineBase", "Head"], "positions": np.array([[x, 1.0, 2.0],
                                                                                          [x, 1.6, 2.0]])}

    frames = [[body(2, 0.0)], [body(2, 0.02)], [body(1, 0.8), body(2, 0.04)], [body(1, 0.8), body(5, 0.06)],
              [body(1, 0.8)], [body(5, 0.3)]]
    assert subject_players(frames) == [2, 2, 2, 5, None, 5]
    assert subject_players(frames, player=1) == [None, None, 1, 1, 1, None]
    assert subject_players([[], [body(3, 0.0), body(4, 1.0)], [body(4, 1.0)]]) == [None, 3, None]


def test_a_chunk_after_the_bystander_enters_gets_the_runs_subject(sessions):
    """Chosen over the chunk's own frames the subject would be the bystander; the run's choice is player 2."""
    from bodystudio.capture.session import open_session
    from bodystudio.capture.subject import session_subject
    from bodystudio.reconstruct.sequence import run_subject

    planted = open_session(sessions[1])
    assert planted.frame(ENTERS).kinect_joints["player"] == 1  # the frame's lowest id is the bystander
    assert run_subject(planted, list(range(FRAMES)), "tracker") == {f: 2 for f in range(FRAMES)}
    assert session_subject(planted, [2, 3]) == {2: 1, 3: 1}  # what a chunk choosing by itself would take
    assert run_subject(planted, list(range(FRAMES)), "hull") is None


@pytest.mark.parametrize("tracking", [False, True], ids=["per-frame", "tracking"])
def test_reconstruct_follows_the_subject_not_the_lowest_player(sessions, tmp_path, tracking):
    """Per frame and tracked, the planted session gives the clean session's meshes to rounding (before: frames 2-3
    posed on the bystander 0.8 m away, and frames 0-1 with bone lengths of both people); run.json records player 2."""
    from bodystudio.reconstruct.sequence import reconstruct_session

    clean, planted = tmp_path / "clean", tmp_path / "planted"
    shutil.copytree(sessions[0], clean)
    shutil.copytree(sessions[1], planted)
    for S in (clean, planted):
        reconstruct_session(S, params=_params(), tracking=tracking, accept_implausible=True, **RUN)
    (run, got), (_, want) = _meshes(planted), _meshes(clean)
    assert run["subject_player"] == 2 and "subject_players" not in run
    for f in range(FRAMES):
        assert np.max(np.abs(got[f] - want[f])) < 1e-9, f"frame {f}"


def test_batch_chunks_use_the_runs_subject(sessions, clean_run, tmp_path, monkeypatch):
    """``reconstruct --workers`` with chunks of 2: the chunk 00002-00003 starts where the bystander is the lowest
    id; each chunk gets the run's subject from the client (a stand-in client runs the chunks in this process)."""
    import bodystudio.batch as batch
    from bodystudio.batch import BatchReport, ReconstructOptions, reconstruct_batch

    class Client:
        def submit(self, fn, *args, **kwargs):
            return fn(*args)

    def run_units(client, units, submit, record_path, force, progress, describe, previous):
        for unit in units:
            submit(unit)
        return BatchReport(record=record_path, status={u["name"]: "done" for u in units})

    monkeypatch.setattr(batch, "_run_units", run_units)
    S = tmp_path / "S"
    shutil.copytree(sessions[1], S)
    options = ReconstructOptions(template="2k", refine_pose=False, params=asdict(_params()))
    reconstruct_batch(S, Client(), options, chunk=2)
    (run, got), want = _meshes(S), clean_run[1]
    assert run["subject_player"] == 2 and run["batch"]["units"] == ["00000-00001", "00002-00003"]
    for f in range(FRAMES):
        assert np.max(np.abs(got[f] - want[f])) < 1e-9, f"frame {f}"


def test_a_frame_without_the_subject_is_refused(sessions, tmp_path, capfd):
    """Frames 2-3 track only the bystander: refused in one line naming frame 2's joints file and the frames to
    reconstruct instead (before: the bystander reconstructed with exit 0); nothing written."""
    S = tmp_path / "S"
    shutil.copytree(sessions[0], S)
    for frame in range(ENTERS, FRAMES):
        _rewrite_joints(S, frame, lambda data: _bystander_enters(data, bystander_only=True))
    result = run_inprocess(["reconstruct", S, "--template", "2k", "--no-refine-pose", "--outer", "1", "--inner",
                            "2", "--no-score"], capfd)
    assert_clean_error(result, 2, "the run's subject (player 2")
    assert "kinect/joints/00002.json" in result.stderr and "2 of 4 frames" in result.stderr
    assert "--frames 0:2" in result.stderr
    assert not (S / "reconstruct").exists()


def test_the_subject_under_a_new_id_is_followed_and_recorded(sessions, tmp_path):
    """The tracker numbers the subject anew (player 3) at frame 2 where the bystander gets 1: followed by its
    joints, and run.json records the ids per frame."""
    from bodystudio.capture.session import open_session
    from bodystudio.reconstruct.sequence import run_subject, subject_record

    S = tmp_path / "S"
    shutil.copytree(sessions[0], S)
    for frame in range(ENTERS, FRAMES):
        _rewrite_joints(S, frame, lambda data: _bystander_enters(data, subject_id=3))
    subject = run_subject(open_session(S), list(range(FRAMES)), "tracker")
    assert subject == {0: 2, 1: 2, 2: 3, 3: 3}
    assert subject_record(subject) == {"subject_player": 2, "subject_players": {"0": 2, "1": 2, "2": 3, "3": 3}}


def test_another_players_depth_pixels_are_not_used():
    """The tracker's player mask: another person's pixels read as no depth; the subject's and nobody's stay."""
    from bodystudio.capture.subject import other_players_removed

    depth = np.full((2, 3), 2.0)
    mask = np.array([[0, 2, 2], [1, 1, 0]], np.uint8)
    got = other_players_removed(depth, mask, 2)
    np.testing.assert_array_equal(got, [[2.0, 2.0, 2.0], [0.0, 0.0, 2.0]])
    assert np.all(depth == 2.0)  # the frame's image is not changed in place
    assert other_players_removed(depth, None, 2) is depth and other_players_removed(depth, mask, None) is depth
    with pytest.raises(ValueError, match="player mask"):
        other_players_removed(depth, mask[:, :2], 2)


def _with_player_mask(S, label_band: bool) -> None:
    """Add a ``kinect/player`` stream: the subject's depth pixels player 2; in frames 2-3 a band across the chest
    (a third of the body's pixels) 3 cm nearer, labelled player 1 (a bystander's arm in front of the subject) when
    ``label_band``, else left the subject's."""
    from bodystudio.capture.session import encode_png, open_session

    session = open_session(S)
    (S / "kinect" / "player").mkdir()
    for f in session.frame_ids:
        D = session.frame(f).kinect_depth_m
        mask = np.where(D > 0, 2, 0).astype(np.uint8)
        if f >= ENTERS:
            rows = np.nonzero((D > 0).any(axis=1))[0]
            band = np.zeros(D.shape, bool)
            band[rows.min() + (rows.max() - rows.min()) // 4:rows.min() + (rows.max() - rows.min()) * 9 // 20] = True
            band &= D > 0
            mask[band] = 1 if label_band else 2
            rel = f"kinect/depth/{f:05d}.png"
            (S / rel).write_bytes(encode_png(np.round(np.where(band, D - 0.03, D) * 1000).astype(np.uint16)))
            restamp(S, rel)
        rel = f"kinect/player/{f:05d}.png"
        (S / rel).write_bytes(encode_png(mask))
        restamp(S, rel)
    manifest = json.loads((S / "session.json").read_text())
    manifest["streams"].append("kinect_player")
    (S / "session.json").write_text(json.dumps(manifest))


def test_the_depth_constraints_leave_another_players_pixels_out(sessions, tmp_path):
    """With a player mask, the depth pixels the tracker gives to the bystander pair with no template vertex:
    frames 2-3 get ~200 fewer depth constraints per iteration than the same pixels labelled the subject's
    (measured 599 / 619 against 808 / 811 at the first iteration), frames 0-1 the same."""
    from bodystudio.reconstruct.rapid_skin import RapidSkinParams
    from bodystudio.reconstruct.sequence import reconstruct_session

    params = RapidSkinParams(outer_iterations=2, inner_iterations=4, constraints=("silhouette", "depth"))
    counts = {}
    for label_band in (True, False):
        S = tmp_path / f"band{int(label_band)}"
        shutil.copytree(sessions[0], S)
        _with_player_mask(S, label_band)
        reconstruct_session(S, template="2k", refine_pose=False, params=params, accept_implausible=True,
                            score=False)
        counts[label_band] = [r["n_depth"] for r in json.loads((S / "reconstruct/frames.json").read_text())["frames"]]
    bystander, subject = counts[True], counts[False]
    assert bystander[:ENTERS] == subject[:ENTERS]
    for f in range(ENTERS, FRAMES):
        assert all(b < s - 150 for b, s in zip(bystander[f], subject[f], strict=True)), (f, bystander[f], subject[f])


@pytest.mark.parametrize("args, phrase", [
    (["--player", "0"], "--player 0: the Kinect SDK numbers players 1 to 6"),
    (["--player", "7"], "--player 7: the Kinect SDK numbers players 1 to 6"),
    (["--player", "1", "--joints", "hull"], "--player chooses among the session's tracked bodies"),
    (["--player", "3"], "the run's subject (player 3, given) is not tracked in 4 of 4 frames"),
], ids=["zero", "seven", "hull", "absent"])
def test_player_option_out_of_range_or_absent_is_refused(sessions, tmp_path, capfd, args, phrase):
    """``reconstruct --player N`` (new): out of the SDK's 1..6, with joints that are not the tracker's, or a player
    the session never tracks: one line, exit 2, nothing written."""
    S = tmp_path / "S"
    shutil.copytree(sessions[0], S)
    result = run_inprocess(["reconstruct", S, "--template", "2k", "--no-refine-pose", "--outer", "1", "--inner",
                            "2", *args], capfd)
    assert_clean_error(result, 2, phrase)
    assert not (S / "reconstruct").exists()


def test_player_option_chooses_the_bystander_when_asked(sessions, tmp_path, capfd):
    """``--player 1`` on the planted session: frames 0-1 have no player 1 (only the subject), so refused naming
    frame 0 and the fix; on frames 2-3 alone (--frames 2:4) the bystander is reconstructed, and run.json says so."""
    S = tmp_path / "S"
    shutil.copytree(sessions[1], S)
    base = ["reconstruct", S, "--template", "2k", "--no-refine-pose", "--outer", "1", "--inner", "2", "--no-score",
            "--player", "1", "--accept-implausible"]
    refused = run_inprocess(base, capfd)
    assert_clean_error(refused, 2, "the run's subject (player 1, given) is not tracked in 2 of 4 frames (first 0")
    result = run_inprocess([*base, "--frames", "2:4"], capfd)
    assert_clean_error(result, 0, "")
    assert json.loads((S / "reconstruct" / "run.json").read_text())["subject_player"] == 1
