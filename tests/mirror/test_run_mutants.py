"""The mirror run's functions changed since the first mutation row (issue 17, docs/mutation/mirror-run.md,
"Re-measure of the changed functions"): each player's source-body file and the player it records, the warp pairs
of one or several actors, and a live recorder's dropped frame; stand-ins only, no session is run."""

import json
import os
import time
from types import SimpleNamespace

import numpy as np
import pytest

from bodystudio.errors import FileFormatError, InputError
from bodystudio.mirror import run as run_mod


def test_source_body_path_is_player_ones_file_or_a_numbered_one(tmp_path):
    assert run_mod.source_body_path(tmp_path) == tmp_path / "mirror" / "source_body.npz"
    assert run_mod.source_body_path(str(tmp_path), 1) == tmp_path / "mirror" / "source_body.npz"
    assert run_mod.source_body_path(tmp_path, "1") == tmp_path / "mirror" / "source_body.npz"
    assert run_mod.source_body_path(tmp_path, 2) == tmp_path / "mirror" / "source_body_player2.npz"
    assert run_mod.source_body_path(tmp_path, np.int64(6)) == tmp_path / "mirror" / "source_body_player6.npz"


def _npz(path, **arrays):
    np.savez(path, vertices=np.zeros((3, 3)), **arrays)
    return path


def test_source_body_player_from_the_file_or_the_summary_beside_it(tmp_path):
    assert run_mod.source_body_player(_npz(tmp_path / "a.npz", player=np.int64(3))) == 3
    b = _npz(tmp_path / "b.npz")
    assert run_mod.source_body_player(b) is None  # neither says
    (tmp_path / "b.json").write_text(json.dumps({"player": 4}), encoding="utf-8")
    assert run_mod.source_body_player(str(b)) == 4
    for odd in ({"player": True}, {"player": "2"}, {"player": 2.0}, {"other": 1}, [2], "x"):
        (tmp_path / "b.json").write_text(json.dumps(odd), encoding="utf-8")
        assert run_mod.source_body_player(b) is None, odd
    (tmp_path / "b.json").write_text("{not json", encoding="utf-8")
    assert run_mod.source_body_player(b) is None
    # the file's own entry wins over the summary
    c = _npz(tmp_path / "c.npz", player=np.int64(1))
    (tmp_path / "c.json").write_text(json.dumps({"player": 5}), encoding="utf-8")
    assert run_mod.source_body_player(c) == 1
    # an unreadable or missing file: None (load_source_body names the problem)
    (tmp_path / "bad.npz").write_bytes(b"not a zip")
    (tmp_path / "bad.json").write_text(json.dumps({"player": 2}), encoding="utf-8")
    assert run_mod.source_body_player(tmp_path / "bad.npz") is None
    assert run_mod.source_body_player(tmp_path / "missing.npz") is None
    np.savez(tmp_path / "obj.npz", player=np.array([{"a": 1}], dtype=object))
    assert run_mod.source_body_player(tmp_path / "obj.npz") is None  # pickled arrays are refused


def test_check_source_player_refuses_another_players_body_in_one_line(tmp_path):
    p2 = _npz(tmp_path / "two.npz", player=np.int64(2))
    run_mod.check_source_player(p2, 2)
    run_mod.check_source_player(p2, "2")
    run_mod.check_source_player(_npz(tmp_path / "none.npz"), 5)  # records no player: accepted
    msg = (f"^{p2}: the source body of player 2, not of player 1; run 'bodystudio mirror init SESSION --player 1' "
           "\\(it writes mirror/source_body.npz\\) or give player 1's body$")
    with pytest.raises(InputError, match=msg):
        run_mod.check_source_player(p2, 1)
    with pytest.raises(InputError, match="not of player 3; run 'bodystudio mirror init SESSION --player 3' \\(it "
                       "writes mirror/source_body_player3.npz\\) or give player 3's body$"):
        run_mod.check_source_player(p2, 3)


def test_frame_pairs_one_actor_or_several_with_the_runs_settings(monkeypatch):
    calls = []

    def stand_in(kind):
        return lambda *a, **kw: calls.append((kind, a, kw)) or kind

    monkeypatch.setattr(run_mod, "warp_pairs", stand_in("one"))
    monkeypatch.setattr(run_mod, "actors_warp_pairs", stand_in("several"))
    s1, t1, s2, t2, faces, cam = (object() for _ in range(6))
    assert run_mod.frame_pairs([s1], [t1], faces, cam) == "one"
    assert calls[-1] == ("one", (s1, t1, faces, cam, run_mod.N_HANDLES),
                         {"rim_cos": run_mod.RIM_COS, "dense": run_mod.CORRESPONDENCE == "dense", "closed": True})
    assert run_mod.frame_pairs([s1], [t1], faces, cam, "sparse") == "one" and calls[-1][2]["dense"] is False
    assert run_mod.frame_pairs([s1], [t1], faces, cam, "dense") == "one" and calls[-1][2]["dense"] is True
    assert run_mod.frame_pairs([s1, s2], [t1, t2], faces, cam, "dense") == "several"
    assert calls[-1] == ("several", ([s1, s2], [t1, t2], faces, cam, run_mod.N_HANDLES),
                         {"rim_cos": run_mod.RIM_COS, "dense": True, "closed": True})
    assert run_mod.frame_pairs([s1, s2], [t1, t2], faces, cam, "sparse") == "several"
    assert calls[-1][2]["dense"] is False
    assert (run_mod.N_HANDLES, run_mod.RIM_COS) == (400, 0.3)


def _touch(root, rel, age_s=0.0):
    p = root / rel
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_bytes(b"x")
    t = time.time() - age_s
    os.utime(p, (t, t))


def _frame(root, i, age_s=0.0, streams=("kinect_rgb", "kinect_depth", "kinect_player")):
    from bodystudio.capture.session import stream_path

    for s in streams:
        _touch(root, stream_path(s, i), age_s)


def test_complete_later_frame_is_the_next_settled_complete_one(tmp_path):
    later = run_mod._complete_later_frame
    assert later(tmp_path, 0, 0.3) is None
    _frame(tmp_path, 2, age_s=10)
    assert later(tmp_path, 0, 0.3) == 2 and later(tmp_path, 1, 0.3) == 2
    assert later(tmp_path, 2, 0.3) is None and later(tmp_path, 3, 0.3) is None  # only frames after i
    assert later(tmp_path, 0, 60.0) is None  # not settled yet: frame 0 may still come
    _frame(tmp_path, 5, age_s=10, streams=("kinect_rgb", "kinect_depth"))  # no player mask
    assert later(tmp_path, 3, 0.3) is None
    _frame(tmp_path, 7, age_s=10)
    assert later(tmp_path, 3, 0.3) is None  # the first later frame (5) decides: incomplete
    assert later(tmp_path, 5, 0.3) == 7
    _frame(tmp_path, 9, age_s=0.0)
    assert later(tmp_path, 7, 5.0) is None  # fresh


def test_live_frame_ids_skip_a_dropped_frame_and_log_it(tmp_path, caplog):
    import logging

    _frame(tmp_path, 0, age_s=10)
    _frame(tmp_path, 1, age_s=10, streams=("kinect_rgb",))  # dropped by the recorder
    _frame(tmp_path, 2, age_s=10)
    _frame(tmp_path, 3, age_s=10)
    with caplog.at_level(logging.WARNING, logger=run_mod.log.name):
        ids = list(run_mod.live_frame_ids(tmp_path, timeout_s=0.05, poll_s=0.01, settle_s=0.3))
    assert ids == [0, 2, 3]
    assert [r.getMessage() for r in caplog.records if "arrived" in r.getMessage()] == \
        ["live frame 1 never arrived complete (frame 2 did); skipped"]


def test_a_frame_settles_on_its_colour_images_age_not_its_depths(tmp_path):
    from bodystudio.capture.session import stream_path

    _frame(tmp_path, 4, age_s=10, streams=("kinect_depth", "kinect_player"))
    _touch(tmp_path, stream_path("kinect_rgb", 4))  # colour fresh, depth and mask old: not settled
    assert run_mod._complete_later_frame(tmp_path, 0, 5.0) is None
    _touch(tmp_path, stream_path("kinect_rgb", 4), age_s=10)
    assert run_mod._complete_later_frame(tmp_path, 0, 5.0) == 4


def test_too_few_late_pairs_pass_the_frame_through_with_its_masks_and_timings(monkeypatch):
    """``--refine-pose``: when the late pairs are too few, the frame passes through as it came in (its colour
    image, the person's mask as foreground, the step timings so far) and the background model learns away from
    the person and the bystanders, exactly as on a frame that failed before the graph cut."""
    from bodystudio.mirror.compose import update_background
    from bodystudio.mirror.warp import WarpPairs

    h, w = 60, 80
    wall = np.full((h, w, 3), 90, np.uint8)
    person = np.zeros((h, w), bool)
    person[10:40, 20:40] = True
    others = np.zeros((h, w), bool)
    others[15:35, 60:75] = True
    rgb = wall.copy()
    rgb[person] = (220, 30, 30)
    rgb[others] = (20, 20, 230)
    bg0 = update_background(None, wall // 2, np.zeros((h, w), bool))
    monkeypatch.setattr(run_mod, "refine_foreground", lambda rgb, person, depth, **kw: person.copy())

    def late(fg, timings):
        timings["pairs"] = 50.0
        return WarpPairs(np.zeros((4, 2)), np.zeros((4, 2)), np.arange(4), None)

    inp = run_mod.MirrorInput(3, rgb, person, others, np.ones((h, w), np.float32), late_pairs=late,
                              timings_ms={"read": 1.5})
    res, bg = run_mod.mirror_frame(inp, bg0)
    assert res.status == "passed_through" and res.warning == "only 4 visible vertex pairs (need 12)"
    assert res.index == 3
    np.testing.assert_array_equal(res.output, rgb)
    np.testing.assert_array_equal(res.foreground, person)
    np.testing.assert_array_equal(res.warped, person)
    assert res.timings_ms["read"] == 1.5 and res.timings_ms["pairs"] == 50.0
    assert {"foreground", "background"} <= set(res.timings_ms)
    want = update_background(bg0, rgb, person | others)
    np.testing.assert_array_equal(bg.valid, want.valid)
    np.testing.assert_array_equal(bg.image, want.image)
    np.testing.assert_array_equal(bg.image[others], bg0.image[others])  # bystanders are not learnt


def test_load_source_names_the_players_init_and_refuses_another_players_file(tmp_path):
    session = SimpleNamespace(path=tmp_path)
    with pytest.raises(FileFormatError, match=f"source_body_player2.npz: source body not found; run 'bodystudio "
                       f"mirror init {tmp_path} --player 2' first \\(or give --source\\)$"):
        run_mod.load_source(session, player=2)
    with pytest.raises(FileFormatError, match=f"source_body.npz: source body not found; run 'bodystudio "
                       f"mirror init {tmp_path}' first"):
        run_mod.load_source(session, player=1)
    (tmp_path / "mirror").mkdir()
    two = _npz(tmp_path / "mirror" / "source_body_player2.npz", player=np.int64(2))
    with pytest.raises(InputError, match="the source body of player 2, not of player 1; "):
        run_mod.load_source(session, two, player=1)
    with pytest.raises(InputError, match="the source body of player 2, not of player 3; "):
        run_mod.load_source(session, str(two), player=3)


@pytest.mark.parametrize("with_groups", [False, True])
def test_late_pairs_get_the_refined_foreground_and_drive_the_warp(monkeypatch, with_groups):
    """``--refine-pose``: the late callback gets the graph cut's foreground and the frame's timings; its pairs,
    dense correspondence and (several players) groups drive the warp; the frame keeps its index, and the
    background model learns away from the foreground, the person and the bystanders, honouring the unseen mask."""
    from bodystudio.mirror.compose import update_background

    h, w = 120, 160  # the MLS grid's size
    wall = np.zeros((h, w, 3), np.uint8)
    wall[..., 0] = (np.arange(w)[None] * 3).astype(np.uint8)
    wall[..., 1] = 100
    person = np.zeros((h, w), bool)
    person[15:45, 25:45] = True
    others = np.zeros((h, w), bool)
    others[20:40, 62:75] = True
    rgb = wall.copy()
    rgb[person] = (220, 30, 30)
    rgb[others] = (20, 20, 230)
    unseen = np.zeros((h, w), bool)
    unseen[:, :6] = True
    bg0 = update_background(None, wall // 2, np.zeros((h, w), bool))
    refined = person.copy()
    refined[15:18, 25:45] = False  # the graph cut's answer differs from the SDK mask
    cut_options = []
    monkeypatch.setattr(run_mod, "refine_foreground", lambda *a, **kw: cut_options.append(kw) or refined)
    real_field, fields = run_mod.mls_warp_field, []
    monkeypatch.setattr(run_mod, "mls_warp_field",
                        lambda src, dst, shape, **kw: fields.append((src, dst, shape, kw))
                        or real_field(src, dst, shape, **dict(kw, dense=None)))
    ys, xs = np.mgrid[17:45:5, 26:45:5]
    src = np.column_stack([xs.ravel(), ys.ravel()]).astype(float)[:run_mod.MIN_PAIRS]  # just enough pairs
    dst = src + [4.0, 0.0]
    own_groups = np.zeros(len(src), int)
    late_groups = np.ones(len(src), int)
    dense = object()  # the late pairs' dense correspondence (a stand-in: the field is computed without it)
    seen = {}

    def late(fg, timings):
        seen["fg"], seen["timings"] = fg, timings
        timings["pairs"] = 50.0
        pairs = SimpleNamespace(src_uv=src, dst_uv=dst, dense=dense)
        if with_groups:
            pairs.groups = late_groups
        return pairs

    inp = run_mod.MirrorInput(9, rgb, person, others, np.ones((h, w), np.float32), late_pairs=late,
                              timings_ms={"read": 1.5}, pair_groups=own_groups, unseen=unseen, players=(1,),
                              person_labels=person.astype(np.uint8) if with_groups else None)
    res, bg = run_mod.mirror_frame(inp, bg0, kind="affine")
    assert res.status == "ok" and res.index == 9 and res.warning is None
    assert seen["fg"] is refined and seen["timings"]["read"] == 1.5
    assert res.timings_ms["pairs"] == 50.0 and res.timings_ms["read"] == 1.5
    (got_src, got_dst, shape, kw), = fields
    assert got_src is src and got_dst is dst and shape == (h, w) and kw["dense"] is dense and kw["kind"] == "affine"
    assert kw["groups"] is (late_groups if with_groups else own_groups)
    assert ("labels" in cut_options[0]) is with_groups  # several players: the graph cut gets their labels
    if with_groups:
        assert cut_options[0]["labels"] is inp.person_labels
    np.testing.assert_array_equal(res.foreground, refined)
    moved = np.zeros((h, w), bool)
    moved[18:45, 29:49] = True
    assert (res.warped ^ moved).sum() <= 0.05 * moved.sum()  # the person moved 4 px right
    want = update_background(bg0, rgb, refined | person | others, unverified=unseen)
    np.testing.assert_array_equal(bg.image, want.image)
    np.testing.assert_array_equal(bg.valid, want.valid)


def _several_players(tmp_path, monkeypatch, sizes=(5, 5)):
    """run_mirror with its steps replaced by recorders, bodies that carry a skeleton (so the plausibility
    checks run) and recorders for the fingerprints and checks."""
    import bodystudio.mirror.frames as frames
    import bodystudio.mirror.init as init
    import bodystudio.mirror.plausibility as plausibility

    (tmp_path / "mirror").mkdir(exist_ok=True)
    for name in ("source_body.npz", "source_body_player2.npz", "source_body_player3.npz"):
        (tmp_path / "mirror" / name).write_bytes(b"x")  # unreadable: records no player
    session = SimpleNamespace(path=tmp_path, kinect="kinect", metadata={"fps": 15}, manifest={"run": {"run_id": "r"}},
                              frame_ids=[0, 1, 2], files={})
    got = {"load": [], "body": [], "reg": []}
    bodies = {p: SimpleNamespace(vertices=np.zeros((n, 3)), coeffs=np.full(2, p), skeleton="skel", p=p)
              for p, n in zip((1, 2, 3), sizes + (5,), strict=True)}

    def load(sess, source=None, player=1):
        assert sess is session
        got["load"].append((source, player))
        return bodies[player], f"model{player}"

    monkeypatch.setattr(run_mod, "load_source", load)
    monkeypatch.setattr(run_mod, "session_inputs", lambda *a: got.update(inputs=a) or "INPUTS")
    monkeypatch.setattr(run_mod, "mirror_stream", lambda *a, **kw: got.update(stream=a) or "DOC")
    monkeypatch.setattr(init, "source_fingerprint", lambda b: f"fp{b.p}")
    monkeypatch.setattr(frames, "recording_fingerprint", lambda s, ids: f"rec{list(ids)}")
    # each actor followed over the run's frames (rel6b): here every frame's ids as given, recorded per check
    monkeypatch.setattr(plausibility, "followed_players",
                        lambda s, players, ids: {i: tuple(10 * p + i for p in players) for i in ids})
    got["tracked"] = []
    monkeypatch.setattr(plausibility, "check_source_body",
                        lambda b, s, p, accept, src, tracked_as: got["body"].append((b.p, s, p, accept, src))
                        or got["tracked"].append((p, tracked_as)) or {"b": p})
    monkeypatch.setattr(plausibility, "check_registration",
                        lambda s, p, accept, tracked_as: got["reg"].append((s, p, accept))
                        or got["tracked"].append((p, tracked_as)) or {"r": p})
    return session, got, bodies


def test_run_mirror_several_players_are_checked_loaded_and_recorded(tmp_path, monkeypatch):
    session, got, bodies = _several_players(tmp_path, monkeypatch)
    for player, msg in (([], "^--player: give at least one Kinect player id \\(1..6\\)$"),
                        ([1, 7], "^--player 7: a Kinect player id is 1..6$"),
                        ([0, 2], "^--player 0: a Kinect player id is 1..6$"),
                        ([2, 1, 2], "^--player 2 --player 1 --player 2: a player is given twice; give each once$")):
        with pytest.raises(InputError, match=msg):
            run_mod.run_mirror(session, {}, None, player=player)
    with pytest.raises(InputError, match="^--source given 1 times for 2 players; give one --source per --player "
                       "\\(in the same order\\), or none to read each player's body from the session$"):
        run_mod.run_mirror(session, {}, None, player=[1, 2], source=[tmp_path / "mirror" / "source_body.npz"])
    (tmp_path / "mirror" / "source_body_player3.npz").unlink()
    with pytest.raises(FileFormatError, match=f"source_body_player3.npz: source body not found; run 'bodystudio mirror "
                       f"init {tmp_path} --player 3' first \\(or give --source\\)$"):
        run_mod.run_mirror(session, {}, None, player=[1, 3])
    with pytest.raises(FileFormatError, match=f"source_body.npz: source body not found; run 'bodystudio mirror "
                       f"init {tmp_path}' first"):
        run_mod.run_mirror(session, {}, None, player=[2, 1], source=[None, tmp_path / "none" / "source_body.npz"])
    recorded = _npz(tmp_path / "mirror" / "p1.npz", player=np.int64(1))
    with pytest.raises(InputError, match="the source body of player 1, not of player 2; "):
        run_mod.run_mirror(session, {}, None, player=[1, 2], source=[None, recorded])
    with pytest.raises(InputError, match="^--source given 1 times for 2 players"):
        run_mod.run_mirror(session, {}, None, player=[1, 2], source=str(recorded))
    assert got["load"] == []  # every check before any body is loaded

    doc = run_mod.run_mirror(session, {"taller": 0.1}, None, player=[2, 1], ramp_frames=4, frames=[1, 2],
                             progress=False, accept_implausible=True)
    assert doc == "DOC" and got["load"] == [(None, 2), (None, 1)]
    assert got["inputs"] == (session, [bodies[2], bodies[1]], "model2", {"taller": 0.1}, [2, 1], 4, [1, 2],
                             run_mod.CORRESPONDENCE, True)
    manifest = got["stream"][6]
    assert manifest["player"] == 2 and manifest["players"] == [2, 1]
    assert manifest["source_fingerprint"] == "fp2" and manifest["source_fingerprints"] == {"2": "fp2", "1": "fp1"}
    assert manifest["session_fingerprint"] == "rec[1, 2]"
    assert manifest["plausibility"] == {"2": {"source_body": {"b": 2}, "registration": {"r": 2}},
                                        "1": {"source_body": {"b": 1}, "registration": {"r": 1}}}
    assert got["body"] == [(2, session, 2, True, None), (1, session, 1, True, None)]
    assert got["reg"] == [(session, 2, True), (session, 1, True)]
    # each check gets its own player's followed ids over the run's frames
    assert got["tracked"] == [(2, {1: 21, 2: 22}), (2, {1: 21, 2: 22}), (1, {1: 11, 2: 12}), (1, {1: 11, 2: 12})]

    # the files given: loaded as given, and their paths reach the plausibility check (a string path too)
    got["load"].clear(), got["body"].clear()
    one, two = str(tmp_path / "mirror" / "source_body.npz"), tmp_path / "mirror" / "source_body_player2.npz"
    run_mod.run_mirror(session, {}, None, player=(np.int64(1), 2), source=[one, two], progress=False)
    assert got["load"] == [(one, 1), (two, 2)]
    assert got["body"] == [(1, session, 1, False, one), (2, session, 2, False, two)]
    assert got["inputs"][4] == [1, 2] and got["stream"][6]["players"] == [1, 2]

    # one player as a numpy integer is one player (not a list), its plausibility not per player
    got["load"].clear(), got["body"].clear()
    run_mod.run_mirror(session, {}, None, player=np.int64(2), progress=False)
    assert got["load"] == [(None, 2)] and got["inputs"][1] is bodies[2] and got["inputs"][4] == 2
    manifest = got["stream"][6]
    assert "players" not in manifest and "source_fingerprints" not in manifest
    assert manifest["plausibility"] == {"source_body": {"b": 2}, "registration": {"r": 2}}
    assert manifest["source_fingerprint"] == "fp2" and got["body"] == [(2, session, 2, False, None)]
    # player 2 alone with its file given: that file is loaded and checked
    got["load"].clear(), got["body"].clear()
    run_mod.run_mirror(session, {}, None, player=2, source=str(two), progress=False)
    assert got["load"] == [(str(two), 2)] and got["body"] == [(2, session, 2, False, str(two))]
    # bodies given as objects: no path reaches the plausibility check
    got["load"].clear(), got["body"].clear()
    objs = [object(), object()]
    run_mod.run_mirror(session, {}, None, player=[1, 2], source=objs, progress=False)
    assert got["load"] == [(objs[0], 1), (objs[1], 2)]
    assert got["body"] == [(1, session, 1, False, None), (2, session, 2, False, None)]


def test_run_mirror_refuses_players_bodies_of_different_models(tmp_path, monkeypatch):
    session, got, bodies = _several_players(tmp_path, monkeypatch, sizes=(5, 6))
    with pytest.raises(InputError, match="^players 1, 2: their source bodies come from different statistical "
                       "models \\(6k / 2k\\); run 'bodystudio mirror init' for each with the same --resolution$"):
        run_mod.run_mirror(session, {}, None, player=[1, 2])
    del bodies[3].coeffs  # a stand-in body without coefficients has no fingerprint
    run_mod.run_mirror(session, {}, None, player=[1, 3])  # the same size: accepted
    assert got["inputs"][4] == [1, 3] and got["stream"][6]["source_fingerprints"] == {"1": "fp1", "3": None}


def test_stream_records_the_players_reshaped_in_each_frame(tmp_path, monkeypatch):
    """A run of several players records, per frame, who was reshaped: all of them on an "ok" frame, nobody on a
    frame that passed through; a one-player run has no such entry."""
    statuses = {0: "ok", 1: "passed_through", 2: "ok"}

    def frame(inp, background, kind, options):
        rgb = inp.rgb.copy()
        mask = np.zeros(rgb.shape[:2], bool)
        return run_mod.FrameResult(inp.index, rgb, mask, mask, statuses[inp.index],
                                   None if statuses[inp.index] == "ok" else "w", {}), background

    monkeypatch.setattr(run_mod, "mirror_frame", frame)
    inputs = [run_mod.MirrorInput(i, np.full((16, 24, 3), 10, np.uint8), players=(2, 1)) for i in range(3)]
    doc = run_mod.mirror_stream(inputs, tmp_path / "run", None, progress=False)
    assert [f["players"] for f in doc["frames"]] == [[2, 1], [], [2, 1]]
    assert [f["status"] for f in doc["frames"]] == ["ok", "passed_through", "ok"]
    doc = run_mod.mirror_stream([run_mod.MirrorInput(0, np.full((16, 24, 3), 10, np.uint8))], tmp_path / "r1",
                                None, progress=False)
    assert "players" not in doc["frames"][0]


def _at(p, i):
    """Player ``p``'s joints in frame ``i``: 10 p m along x, the frame index added to the first joint only (the ik
    stand-in reads both from it); the players stand still and 10 m apart, so the run follows each by its joints."""
    positions = np.full((25, 3), 10.0 * p)
    positions[0, 0] += i
    return positions


def _two_player_session(monkeypatch):
    """Stand-ins for the frames and body steps of two players (1, 2) and a bystander (3); they record their calls."""
    from bodystudio.mirror import frames as frames_mod
    from bodystudio.mirror import reshape as reshape_mod
    from bodystudio.mirror import track as track_mod

    h, w = 12, 16
    blocks = {1: (slice(2, 6), slice(2, 6)), 2: (slice(2, 6), slice(9, 13)), 3: (slice(8, 10), slice(0, 3))}
    # frame -> (players in the mask, players tracked, player whose IK fails)
    spec = {0: ({1, 2, 3}, {1, 2}, None), 1: ({1, 3}, {1}, None), 2: ({1, 2}, {1}, None), 3: ({1}, {1, 2}, None),
            4: ({1, 2}, {1, 2}, 2), 5: ({1, 2}, {1, 2}, None), 6: ({2}, {2}, None),
            7: ({3}, set(), None), 8: ({1, 2}, {1}, None)}  # 7 and 8 without any depth

    camera = SimpleNamespace(height=h, width=w)
    session = SimpleNamespace(path="S", frame_ids=sorted(spec), kinect=SimpleNamespace(color=camera, version="v2"))
    b1 = SimpleNamespace(coeffs=np.zeros(1), vertices=np.full((3, 3), 1.0), skeleton="sk1", faces="faces", p=1)
    b2 = SimpleNamespace(coeffs=np.full(1, 0.5), vertices=np.full((3, 3), 5.5), skeleton="sk2", faces="faces", p=2)
    model = SimpleNamespace(vertices=lambda c: np.full((3, 3), 1.0 + 9.0 * c[0]))
    rec = {"ik": [], "rig": [], "pairs": []}

    def read(sess, i):
        player = np.zeros((h, w), np.uint8)
        for p in spec[i][0]:
            player[blocks[p]] = p
        bodies = {p: SimpleNamespace(player=p, names=tuple(f"j{k}" for k in range(25)), positions=_at(p, i),
                                     tracked=np.ones(25, bool)) for p in spec[i][1]}
        return SimpleNamespace(rgb=np.full((h, w, 3), i, np.uint8), depth_m=np.full((h, w), float(i < 7)),
                               player=player, body=bodies.get, bodies=tuple(bodies[p] for p in sorted(bodies)))

    def ik(skeleton, positions, tracked, version, previous=None):
        p, i = divmod(int(positions[0, 0]), 10)
        rec["ik"].append((skeleton, i, previous))
        if spec[i][2] == p:
            raise InputError("pelvis not tracked")
        return f"pose{p}.{i}"

    def rig(b, target_rest, m, coeffs):
        rec["rig"].append((b.p, float(target_rest[0, 0]), float(coeffs[0])))
        return ("rig", b.p)

    def pairs(kind):
        def call(Vs, Vt, faces, cam, n, rim_cos=None, dense=False, closed=False):
            rec["pairs"].append((kind, [v[0, 0] for v in Vs] if kind == "several" else Vs[0, 0]))
            rec.setdefault("dense", []).append(dense)
            m = 2 * len(Vs) if kind == "several" else 2
            return SimpleNamespace(src_uv=np.zeros((m, 2)), dst_uv=np.ones((m, 2)), dense=None,
                                   groups=np.repeat([0, 1], 2) if kind == "several" else None)
        return call

    monkeypatch.setattr(frames_mod, "read_mirror_frame", read)
    monkeypatch.setattr(frames_mod, "register_depth_to_color", lambda d, p, s: (np.full(p.shape, 0.8), p))
    monkeypatch.setattr(track_mod, "ik_pose", ik)

    def untwisted(skeleton, pose, bones):  # the run's untwisting (MIR12p), recorded, as the identity
        rec.setdefault("untwisted", []).append((skeleton, pose, bones))
        return pose

    monkeypatch.setattr(track_mod, "untwisted_pose", untwisted)

    def upright(skeleton, pose):  # the bodies' upright root (MIR12s), recorded, as the identity
        rec.setdefault("upright", []).append((skeleton, pose))
        return pose

    monkeypatch.setattr(track_mod, "upright_root", upright)
    monkeypatch.setattr(reshape_mod, "target_coeffs", lambda m, c, e: c + e["taller"])
    monkeypatch.setattr(reshape_mod, "posed_source_and_target", lambda b, vt, pose, r: (b.vertices, vt))
    monkeypatch.setattr(reshape_mod, "target_skeleton", rig)
    monkeypatch.setattr(run_mod, "warp_pairs", pairs("one"))
    monkeypatch.setattr(run_mod, "actors_warp_pairs", pairs("several"))
    return session, b1, b2, model, rec, blocks, spec


def test_session_inputs_reshape_several_players_each_on_its_own(monkeypatch):
    """Two players (and a bystander, player 3): both masks are the person, each pixel labelled with its player,
    the pairs of both from one call with their groups; each player's ramp and IK run on their own; a player out
    of view is left out; one in view but untracked, tracked with an empty mask, or failing the IK passes the frame
    through naming the player."""
    session, b1, b2, model, rec, blocks, spec = _two_player_session(monkeypatch)
    h, w = 12, 16
    with pytest.raises(InputError, match="^session_inputs: 2 players but 1 source bodies$"):
        list(run_mod.session_inputs(session, [b1], model, {"taller": 1.0}, [1, 2]))
    with pytest.raises(InputError, match="^session_inputs: 0 players but 0 source bodies$"):
        list(run_mod.session_inputs(session, [], model, {"taller": 1.0}, []))
    out = list(run_mod.session_inputs(session, [b1, b2], model, {"taller": 1.0}, (1, np.int64(2)), 2))
    assert [o.index for o in out] == list(range(9))
    o = out[0]
    person = np.zeros((h, w), bool)
    person[blocks[1]] = person[blocks[2]] = True
    np.testing.assert_array_equal(o.person_mask, person)
    others = np.zeros((h, w), bool)
    others[blocks[3]] = True
    np.testing.assert_array_equal(o.others_mask, others)
    labels = np.zeros((h, w), np.uint8)
    labels[blocks[1]], labels[blocks[2]] = 1, 2
    assert o.person_labels.dtype == np.uint8
    np.testing.assert_array_equal(o.person_labels, labels)
    assert o.warning is None and o.players == (1, 2) and o.edit_fraction == 0.5
    np.testing.assert_array_equal(o.pair_groups, [0, 0, 1, 1])
    # player 1 alone in view: reshaped alone, by the one-actor call; labels still per player
    assert out[1].warning is None and out[1].players == (1,) and out[1].pair_groups is None
    assert out[1].edit_fraction == 1.0
    assert out[2].warning == "player 2 is in the mask but no body is tracked" and out[2].players == ()
    assert out[3].warning == "body 2 is tracked but its player mask is empty" and out[3].players == ()
    assert out[4].warning == "tracking player 2 failed: pelvis not tracked" and out[4].players == ()
    assert out[5].warning is None and out[5].players == (1, 2) and out[5].edit_fraction == 1.0
    # each player's ramp over its own tracked frames (V_T = 10 for player 1, 14.5 for player 2), the IK warm-started
    # from that player's last pose
    assert out[6].warning is None and out[6].players == (2,)  # player 1 out of view, player 2 still reshaped
    # without depth: a frame with nobody to reshape is empty, not a warning; an untracked player's warning stays
    assert out[7].warning is None and out[7].src_uv is None and out[7].players == ()
    assert out[8].warning == "player 2 is in the mask but no body is tracked"
    assert rec["pairs"] == [("several", [1.0, 5.5]), ("one", 1.0), ("several", [1.0, 5.5]), ("one", 5.5)]
    assert rec["rig"] == [(1, 5.5, 0.5), (2, 10.0, 1.0), (1, 10.0, 1.0), (1, 10.0, 1.0), (2, 14.5, 1.5),
                          (2, 14.5, 1.5)]
    assert rec["ik"] == [("sk1", 0, None), ("sk2", 0, None), ("sk1", 1, "pose1.0"), ("sk1", 4, "pose1.1"),
                         ("sk2", 4, "pose2.0"), ("sk1", 5, "pose1.1"), ("sk2", 5, "pose2.0"), ("sk2", 6, "pose2.5")]
    assert rec["dense"] == [run_mod.CORRESPONDENCE == "dense"] * 4
    # every pose the IK gives is untwisted on its own skeleton with the run's limbs (MIR12p)
    assert [(sk, pose) for sk, pose, _ in rec["untwisted"]] == [
        ("sk1", "pose1.0"), ("sk2", "pose2.0"), ("sk1", "pose1.1"), ("sk1", "pose1.4"), ("sk1", "pose1.5"),
        ("sk2", "pose2.5"), ("sk2", "pose2.6")]
    assert {bones for _, _, bones in rec["untwisted"]} == {run_mod.UNTWIST_BONES + ("foot_l", "foot_r")}  # mir12aa
    # each body is posed with an upright root on its own skeleton (MIR12s), once per reshaped player and frame
    assert [sk for sk, _ in rec["upright"]] == ["sk1", "sk2", "sk1", "sk1", "sk2", "sk2"]
    # the correspondence asked reaches the pairs; an edit of 2 ramps the coefficients by s (c_T - c_S)
    rec["rig"].clear()
    list(run_mod.session_inputs(session, [b1, b2], model, {"taller": 2.0}, [1, 2], 2, [0], "mls"))
    assert rec["dense"][-1] is False and rec["pairs"][-1][0] == "several"
    assert rec["rig"] == [(1, 10.0, 1.0), (2, 14.5, 1.5)]  # s = 1/2: V_S + (V_T - V_S) / 2, c_S + (c_T - c_S) / 2
    # one player (2) of the same frames: no labels, no players list, not even on the frames that pass through
    out = list(run_mod.session_inputs(session, b2, model, {"taller": 1.0}, 2, 2, [0, 2, 4]))
    assert [o.warning for o in out] == [None, "player 2 is in the mask but no body is tracked",
                                        "tracking failed: pelvis not tracked"]
    assert all(o.players is None and o.person_labels is None for o in out)


@pytest.mark.parametrize("several", [False, True])
def test_session_inputs_refine_each_pose_against_its_own_foreground(monkeypatch, several):
    """``refine``: each player gets a refinement plan of its body; the frame carries ``late_pairs``, which refines
    each pose against the cut's foreground without the other players' pixels (one player: without the others),
    the player's point cloud above the floor, its joints and the other players as occluders, then poses the
    bodies; a failing refinement names the player (several) and the refinement time is booked on its own."""
    from bodystudio.mirror import frames as frames_mod
    from bodystudio.mirror import refine as refine_mod

    session, b1, b2, model, rec, blocks, spec = _two_player_session(monkeypatch)
    for b in (b1, b2):
        b.weights = f"w{b.p}"
    h, w = 12, 16
    plans, refined = [], []
    plan_kwargs = []
    monkeypatch.setattr(refine_mod, "refine_plan",
                        lambda *a, **kw: plans.append(a) or plan_kwargs.append(kw) or f"plan{a[3][-1]}")
    cloud = np.array([[0.0, 0.01, 2.0], [0.0, 0.5, 2.0], [0.0, 0.03, 2.0], [0.0, 0.02, 2.0]])
    def point_cloud(frame, sensor, p):
        assert sensor is session.kinect and frame.rgb.shape == (h, w, 3)
        return cloud + [p, 0.0, 0.0]

    monkeypatch.setattr(frames_mod, "point_cloud", point_cloud)

    def refine_pose(plan, skeleton, pose, camera, fg, positions, tracked, points, occluders, version, iterations,
                    weights, posture=None):
        refined.append(dict(plan=plan, skeleton=skeleton, pose=pose, camera=camera, fg=fg.copy(), posture=posture,
                            joints=positions[0, 0], tracked=tracked, points=points, occluders=occluders.copy(),
                            version=version, iterations=iterations, depth_samples=weights.depth_samples))
        if pose == "pose2.5":
            raise InputError("no silhouette")
        if pose == "pose1.5" and not several:
            raise InputError("no cut")
        return pose + "+r"

    monkeypatch.setattr(refine_mod, "refine_pose", refine_pose)
    postures = []  # E_trunk's centre: each player's running posture of its refined poses (run.POSTURE_BONES, mir12ae)

    def updated_posture(posture, skeleton, pose, frames, window, bones):
        postures.append((posture, skeleton, pose, frames, window, bones))
        return f"posture{frames}:{pose}"

    monkeypatch.setattr(refine_mod, "updated_posture", updated_posture)
    players, bodies = ([1, 2], [b1, b2]) if several else (1, b1)
    out = list(run_mod.session_inputs(session, bodies, model, {"taller": 1.0}, players, 2, [0, 5], refine=True))
    assert [p[3] for p in plans] == (["sk1", "sk2"] if several else ["sk1"])
    assert all(p[0] is b.vertices and p[1] == "faces" and p[2] == b.weights and p[4] == "v2"
               for p, b in zip(plans, [b1, b2], strict=False))
    # the run's plan refines the spine's twist too (MIR12h)
    assert plan_kwargs == [{"twist_bones": refine_mod.TWIST_BONES}] * len(plans)
    o = out[0]
    assert o.src_uv is None and o.late_pairs is not None and o.edit_fraction == 0.5
    assert o.players == ((1, 2) if several else None)
    fg = np.ones((h, w), bool)
    timings = {"foreground": 3.0}
    pairs = o.late_pairs(fg, timings)
    assert len(pairs.src_uv) == (4 if several else 2)
    assert [r["plan"] for r in refined] == (["plan1", "plan2"] if several else ["plan1"])
    assert [r["pose"] for r in refined] == (["pose1.0", "pose2.0"] if several else ["pose1.0"])
    assert [r["joints"] for r in refined] == ([10.0, 20.0] if several else [10.0])
    # the first refinement of each player holds the trunk at rest, and its refined pose starts the running posture
    assert [r["posture"] for r in refined] == ([None, None] if several else [None])
    assert postures == [(None, sk, p + "+r", 1, run_mod.POSTURE_WINDOW, ("spine_02", "neck_01", "head"))
                        for sk, p in ((("sk1", "pose1.0"), ("sk2", "pose2.0")) if several else (("sk1", "pose1.0"),))]
    r1 = refined[0]
    assert r1["skeleton"] == "sk1" and r1["camera"] is session.kinect.color and r1["version"] == "v2"
    # two Gauss-Newton steps when the run reshapes one player, one each for several (MIR12k, run.refine_steps)
    assert [r["iterations"] for r in refined] == ([1, 1] if several else [2])
    assert [r["depth_samples"] for r in refined] == ([400, 400] if several else [2000])  # MIR12n
    assert r1["tracked"].dtype == bool and r1["tracked"].all()
    np.testing.assert_array_equal(r1["points"], cloud[[1, 2]] + [1, 0, 0])  # above 2 cm: not the floor
    mask = {p: np.zeros((h, w), bool) for p in blocks}
    for p, blk in blocks.items():
        mask[p][blk] = True
    if several:  # each player's foreground: the cut's without the other players (the bystander too)
        np.testing.assert_array_equal(r1["occluders"], mask[2] | mask[3])
        np.testing.assert_array_equal(r1["fg"], ~(mask[2] | mask[3]))
        np.testing.assert_array_equal(refined[1]["occluders"], mask[1] | mask[3])
        np.testing.assert_array_equal(refined[1]["fg"], ~(mask[1] | mask[3]))
    else:  # one player: the others (players 2 and 3 here) are the occluders, the cut's foreground as it is
        np.testing.assert_array_equal(r1["occluders"], mask[2] | mask[3])
        np.testing.assert_array_equal(r1["fg"], fg)
    assert timings["foreground"] == 3.0 and {"refine_pose", "bodies", "pairs"} <= set(timings)
    assert timings["refine_pose"] >= 0.0
    # the refined pose poses the bodies
    assert rec["pairs"][-1] == (("several", [1.0, 5.5]) if several else ("one", 1.0))
    # on a stand-in clock (1 s a tick): each player's refinement and bodies are summed, the pairs timed once
    ticks, cpu_ticks = iter(range(100, 1000)), iter(range(100, 1000))
    monkeypatch.setattr(run_mod, "time", SimpleNamespace(perf_counter=lambda: float(next(ticks)),
                                                         process_time=lambda: 2.0 * next(cpu_ticks)))
    timings = {}
    for k in ("refine_pose", "bodies", "pairs"):
        o.cpu_ms.pop(k, None)
    o.late_pairs(fg, timings)
    n = 2 if several else 1
    assert timings == {"refine_pose": 1000.0 * n, "bodies": 1000.0 * n, "pairs": 1000.0}
    # and their CPU ms (2 s a reading) in the frame's cpu_ms, beside its read, register and ik
    assert {k: o.cpu_ms[k] for k in ("refine_pose", "bodies", "pairs")} == \
        {"refine_pose": 2000.0 * n, "bodies": 2000.0 * n, "pairs": 2000.0}
    assert {"read", "register", "ik"} <= set(o.cpu_ms)
    if several:
        with pytest.raises(InputError, match="^pose refinement of player 2 failed: no silhouette$"):
            out[1].late_pairs(fg, {})
    else:
        with pytest.raises(InputError, match="^pose refinement failed: no cut$"):
            out[1].late_pairs(fg, {})


def test_session_inputs_pose_the_bodies_with_the_tilted_root_when_upright_is_off(monkeypatch):
    """``run.UPRIGHT_ROOT = False`` (before MIR12s): the bodies take the IK's pose as it is, no upright_root call."""
    session, b1, b2, model, rec, _, _ = _two_player_session(monkeypatch)
    monkeypatch.setattr(run_mod, "UPRIGHT_ROOT", False)
    out = list(run_mod.session_inputs(session, [b1, b2], model, {"taller": 1.0}, [1, 2], 2, [0, 1]))
    assert [o.warning for o in out] == [None, None] and "upright" not in rec
    monkeypatch.setattr(run_mod, "UPRIGHT_ROOT", True)
    list(run_mod.session_inputs(session, [b1, b2], model, {"taller": 1.0}, [1, 2], 2, [0, 1]))
    assert [sk for sk, _ in rec["upright"]] == ["sk1", "sk2", "sk1"]
