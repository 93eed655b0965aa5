"""The mirror loop: per-frame image steps, pass-through of bad frames, run folder + videos committed as one unit."""

import json
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from bodystudio.errors import InputError
from bodystudio.mirror.image_case import cached_image_case, iou
from bodystudio.mirror.run import MirrorInput, live_frame_ids, mirror_frame, mirror_stream
from bodystudio.runfolder import RunLayout, verify_run_files


def _inputs(case):
    nan = np.full_like(case.src_uv, np.nan)
    return ([MirrorInput(i, case.background) for i in range(2)]
            + [MirrorInput(2 + i, case.rgb, case.player_mask, None, case.depth_color, case.src_uv, case.dst_uv)
               for i in range(3)]
            + [MirrorInput(5, case.rgb, case.player_mask, warning="no body tracked"),
               MirrorInput(6, case.rgb, case.player_mask, None, None, case.src_uv[:4], case.dst_uv[:4]),
               MirrorInput(7, case.rgb, case.player_mask, None, None, nan, nan)])


def test_stream_writes_frames_masks_videos_and_run_json(tmp_path):
    import imageio_ffmpeg

    case = cached_image_case()
    run = tmp_path / "run"
    doc = mirror_stream(_inputs(case), run, tmp_path / "out.mp4", manifest={"edits": {"taller": 0.16}})
    status = [(f["index"], f["status"]) for f in doc["frames"]]
    assert status == [(0, "empty"), (1, "empty"), (2, "ok"), (3, "ok"), (4, "ok"), (5, "passed_through"),
                      (6, "passed_through"), (7, "passed_through")]
    assert doc["summary"]["n_warnings"] == 3 and doc["summary"]["n_ok"] == 3
    assert all("edit_fraction" in f for f in doc["frames"])
    assert "finite" in doc["frames"][7]["warning"] and "vertex pairs" in doc["frames"][6]["warning"]
    on_disk = json.loads((run / "run.json").read_text())
    assert on_disk["edits"] == {"taller": 0.16} and on_disk["run"]["files"]
    verify_run_files(RunLayout(run, "run.json"), on_disk["run"])
    for sub in ("frames", "masks/foreground", "masks/warped"):
        assert len(list((run / sub).glob("*.png"))) == 8
    # the mirror's person is the target's silhouette (graph cut + MLS from the SDK-like mask)
    warped = cv2.imread(str(run / "masks/warped/00003.png"), cv2.IMREAD_GRAYSCALE) > 127
    # measured 0.972 (refined mask 0.998; 0.960 with 800 evenly spread candidates and no rim)
    assert iou(warped, case.target_mask) >= 1 - 1.5 * (1 - 0.972)
    fg = cv2.imread(str(run / "masks/foreground/00003.png"), cv2.IMREAD_GRAYSCALE) > 127
    assert iou(fg, case.true_mask) > iou(case.player_mask, case.true_mask) + 0.1
    # pass-through frames are the input, unchanged
    out5 = cv2.imread(str(run / "frames/00005.png"))[..., ::-1]
    assert np.array_equal(out5, case.rgb)
    out3 = cv2.imread(str(run / "frames/00003.png"))[..., ::-1]
    assert not np.array_equal(out3, case.rgb)
    for name, width in (("out.mp4", 640), ("out_side_by_side.mp4", 1280)):
        reader = imageio_ffmpeg.read_frames(str(tmp_path / name))
        meta = reader.__next__()
        assert tuple(meta["size"]) == (width, 480)
        assert sum(1 for _ in reader) == 8
    for step in ("foreground", "warp_field", "warp", "compose", "background", "write"):
        assert doc["summary"]["ms_per_frame"][step] > 0


def test_a_failed_run_keeps_the_previous_one(tmp_path):
    case = cached_image_case()
    run = tmp_path / "run"
    mirror_stream(_inputs(case)[:3], run, None)
    before = (run / "run.json").read_bytes()

    def broken():
        yield from _inputs(case)[:2]
        raise RuntimeError("camera unplugged")

    with pytest.raises(RuntimeError):
        mirror_stream(broken(), run, None)
    assert (run / "run.json").read_bytes() == before
    assert not (run / ".staging").exists() and not (run / ".lock").exists()


def test_mirror_frame_takes_the_dense_correspondence_when_given():
    """``MirrorInput.dense`` (``mirror run --correspondence dense``, the default) against MLS only: warp_iou of the
    rendered +10 % / +15 kg case through the whole image step (graph-cut foreground) 0.99+ vs 0.97."""
    case = cached_image_case()
    scores = {}
    for name, dense in (("mls", None), ("dense", case.dense)):
        inp = MirrorInput(0, case.rgb, case.player_mask, None, case.depth_color, case.src_uv, case.dst_uv, dense=dense)
        res, _ = mirror_frame(inp, None)
        assert res.status == "ok"
        scores[name] = iou(res.warped, case.target_mask)
    assert scores["dense"] >= 0.98 and scores["dense"] - scores["mls"] >= 0.01, scores


def test_mirror_frame_uses_and_learns_the_background():
    case = cached_image_case((("stature_m", -0.16), ("mass_kg", -15.0)))
    empty, background = mirror_frame(MirrorInput(0, case.background), None)
    assert empty.status == "empty" and background.valid.all()
    res, updated = mirror_frame(MirrorInput(1, case.rgb, case.player_mask, None, None, case.src_uv, case.dst_uv),
                                background)
    assert res.status == "ok"
    hole = case.true_mask & ~cv2.dilate(case.target_mask.astype(np.uint8), np.ones((7, 7))).astype(bool)
    assert hole.sum() > 2000
    assert np.abs(res.output[hole].astype(float) - case.background[hole]).mean() < 3
    assert updated.frames == 2


def test_live_frames_arrive_in_order_and_stop_after_the_timeout(tmp_path):
    from bodystudio.capture.session import stream_path

    def touch(rel):
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_bytes(b"x")

    def recorder():
        for i in range(3):
            for stream in ("kinect_rgb", "kinect_depth", "kinect_player", "kinect_joints"):
                touch(stream_path(stream, i))
            time.sleep(0.05)

    thread = threading.Thread(target=recorder)
    thread.start()
    t0 = time.monotonic()
    ids = list(live_frame_ids(tmp_path, timeout_s=0.5, poll_s=0.01))
    thread.join()
    assert ids == [0, 1, 2]
    assert time.monotonic() - t0 < 5


def test_stream_refuses_bad_options(tmp_path):
    case = cached_image_case()
    with pytest.raises(InputError, match="mp4"):
        mirror_stream(_inputs(case)[:1], tmp_path / "run", tmp_path / "out.avi")
    with pytest.raises(InputError, match="warp"):
        mirror_stream(_inputs(case)[:1], tmp_path / "run", None, kind="thin-plate")
    with pytest.raises(InputError, match="no frames"):
        mirror_stream([], tmp_path / "run", None)
    assert not Path(tmp_path / "run").exists()


@pytest.mark.slow
def test_run_mirror_end_to_end_on_a_synthetic_session(tmp_path):
    """synth mirror -> mirror init -> mirror run -> eval mirror, the edit applied at once (no ramp)."""
    from bodystudio.body.statistical import load_statistical_model
    from bodystudio.mirror import evaluate, init, synthetic
    from bodystudio.mirror.run import run_mirror

    session = synthetic.synth_mirror_session(tmp_path / "s", 3, n_frames=14, edits={"taller": 0.16}, version="v1",
                                             motion="a_pose", walk_in=False)
    body = init.initialise_source_body(session, load_statistical_model("6k", progress=False), n_frames=4)
    init.save_source_body(session.path / "mirror" / "source_body.npz", body)
    doc = run_mirror(session, {"taller": 0.16}, tmp_path / "out.mp4", progress=False, ramp_frames=0)
    assert doc["summary"]["frames"] == 14 and doc["summary"]["n_empty"] >= 10
    scores = evaluate.evaluate_mirror(session, session.path / "mirror" / "run")
    assert scores["fg_iou"] > scores["fg_iou_raw"] + 0.05
    assert scores["warp_iou"] > scores["warp_iou_unwarped"]


def test_run_mirror_with_pose_refinement(tmp_path, monkeypatch):
    """``--refine-pose``: the pose is refined after the graph cut (its time in run.json), the warp scores at
    least as well as the IK's on a small synthetic session, and a frame whose refinement fails passes through."""
    from bodystudio.body.statistical import load_statistical_model
    from bodystudio.errors import InputError
    from bodystudio.mirror import evaluate, init, refine, synthetic
    from bodystudio.mirror.run import run_mirror

    session = synthetic.synth_mirror_session(tmp_path / "s", 5, n_frames=15, edits={"taller": 0.12}, version="v1",
                                             motion="walk", walk_in=False)
    body = init.initialise_source_body(session, load_statistical_model("6k", progress=False), n_frames=3)
    init.save_source_body(session.path / "mirror" / "source_body.npz", body)
    scores = {}
    for refined in (False, True):
        run = tmp_path / f"run_{refined}"
        doc = run_mirror(session, {"taller": 0.12}, None, progress=False, ramp_frames=0, run_dir=run,
                         refine_pose=refined)
        assert doc["refine_pose"] is refined
        ms = doc["summary"]["ms_per_frame"]
        assert ("refine_pose" in ms) is refined and all(k in ms for k in ("bodies", "pairs", "foreground"))
        scores[refined] = evaluate.evaluate_mirror(session, run)["warp_iou"]
    assert scores[True] > scores[False] - 0.005, scores

    real, calls = refine.refine_pose, []

    def failing(*args, **kwargs):
        calls.append(1)
        if len(calls) == 2:
            raise InputError("planted failure")
        return real(*args, **kwargs)

    monkeypatch.setattr(refine, "refine_pose", failing)
    doc = run_mirror(session, {"taller": 0.12}, None, progress=False, ramp_frames=0, run_dir=tmp_path / "fail",
                     refine_pose=True)
    failed = [f for f in doc["frames"] if f["status"] == "passed_through"]
    assert len(failed) == 1 and "pose refinement failed: planted failure" in failed[0]["warning"]
    assert doc["summary"]["n_ok"] == len(calls) - 1


def test_late_pairs_are_called_with_the_refined_foreground_and_timed_apart(monkeypatch):
    """A frame carrying ``late_pairs`` (``--refine-pose``) gets the graph cut's foreground; the callback's time
    is not booked to the foreground step; too few pairs from it pass the frame through."""
    import bodystudio.mirror.run as run_mod
    from bodystudio.mirror.warp import WarpPairs

    case = cached_image_case(None, 0, 1)
    seen, offset = {}, [0.0]
    real = time.perf_counter
    monkeypatch.setattr(run_mod.time, "perf_counter", lambda: real() + offset[0])

    def late(fg, timings, n=None):
        seen["fg"] = fg.copy()
        offset[0] += 1000.0  # the callback "takes" 1000 s on the run's clock
        timings["pairs"] = 50.0
        k = len(case.src_uv) if n is None else n
        return WarpPairs(case.src_uv[:k], case.dst_uv[:k], np.arange(k), None)

    inp = MirrorInput(2, case.rgb, case.player_mask, None, case.depth_color, late_pairs=late)
    res, _ = mirror_frame(inp, None)
    assert res.status == "ok" and np.array_equal(seen["fg"], res.foreground)
    assert res.timings_ms["pairs"] == 50.0
    assert all(res.timings_ms[k] < 1e6 for k in ("foreground", "warp_field", "warp", "compose", "background"))
    assert iou(res.warped, case.target_mask) > iou(res.foreground, case.target_mask)
    res, _ = mirror_frame(MirrorInput(3, case.rgb, case.player_mask, None, case.depth_color,
                                      late_pairs=lambda fg, t: late(fg, t, 4)), None)
    assert res.status == "passed_through" and "visible vertex pairs" in res.warning


def test_run_reshapes_two_players_each_with_its_own_body(tmp_path):
    """``mirror init --player N`` writes each player's body into its own file (which records the player);
    ``mirror run --player 1 --player 2`` reshapes both in one pass (one graph cut, the pairs of both from one
    ``run.frame_pairs`` call, as the bench's two-actor path), each as well as a run of that player alone; a body
    paired with another player is refused with a one-line error."""
    from bodystudio.cli.main import main
    from bodystudio.errors import InputError
    from bodystudio.mirror import evaluate, synthetic
    from bodystudio.mirror.run import run_mirror, source_body_path, source_body_player

    session = synthetic.synth_mirror_session(tmp_path / "s", 7, n_frames=14, actors=2, edits={"taller": 0.16},
                                             version="v1", motion="a_pose", walk_in=False, edited_players=(1, 2))
    for p in (1, 2):
        assert main(["mirror", "init", str(session.path), "--player", str(p), "--frames", "3"]) == 0
        assert source_body_player(source_body_path(session.path, p)) == p
    assert source_body_path(session.path, 2).name == "source_body_player2.npz"
    assert json.loads((session.path / "mirror" / "source_body_player2.json").read_text())["player"] == 2
    run2 = tmp_path / "both"
    assert main(["mirror", "run", str(session.path), "--player", "1", "--player", "2", "--taller", "0.16",
                 "--ramp-frames", "0", "--out", str(tmp_path / "both.mp4"), "--run", str(run2)]) == 0
    doc = json.loads((run2 / "run.json").read_text())
    assert doc["players"] == [1, 2] and doc["player"] == 1 and set(doc["source_fingerprints"]) == {"1", "2"}
    assert (tmp_path / "both_side_by_side.mp4").is_file()
    ok = [f for f in doc["frames"] if f["status"] == "ok"]
    assert len(ok) >= 3 and all(f["players"] == [1, 2] for f in ok)
    for p in (1, 2):
        alone = tmp_path / f"alone{p}"
        run_mirror(session, {"taller": 0.16}, None, progress=False, ramp_frames=0, run_dir=alone, player=p)
        both = evaluate.image_scores(session, run2, dict(doc, player=p))
        single = evaluate.image_scores(session, alone, dict(json.loads((alone / "run.json").read_text()), player=p))
        assert both["warp_iou"] > both["warp_iou_unwarped"] + 0.02, (p, both)
        # the actors overlap in the image: together they warp within 0.01 of one at a time (0.922 / 0.926 and
        # 0.896 / 0.905 when written); the graph cut of both as well as of one (0.994 / 0.992, 0.993 / 0.988)
        assert both["warp_iou"] > single["warp_iou"] - 0.015, (p, both["warp_iou"], single["warp_iou"])
        assert both["fg_iou"] > single["fg_iou"] - 0.005 and both["fg_iou"] > both["fg_iou_raw"] + 0.1, (p, both)
    # eval mirror of player 2's run reads player 2's body (its fingerprint is the run's)
    assert evaluate.evaluate_mirror(session, tmp_path / "alone2")["player"] == 2
    # another player's body is refused: by its recorded player, given as --source or found in the session
    with pytest.raises(InputError, match="source_body_player2.npz: the source body of player 2, not of player 1"):
        run_mirror(session, {"taller": 0.16}, None, progress=False, run_dir=tmp_path / "x",
                   source=source_body_path(session.path, 2))
    with pytest.raises(InputError, match="a player is given twice"):
        run_mirror(session, {}, None, progress=False, player=[2, 2])
    with pytest.raises(InputError, match="--source given 1 times for 2 players"):
        run_mirror(session, {}, None, progress=False, player=[1, 2], source=[source_body_path(session.path, 1)])
