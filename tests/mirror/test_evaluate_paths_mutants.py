"""Fast tests of the mirror evaluation's remaining paths (bodystudio.mirror.evaluate; issue 17, second round):
``tracking_scores`` (on stand-ins with an exact answer, and the real IK of the true skeleton against a bound),
``evaluate_mirror``'s default run folder and source body (its loading and the fingerprint refusal) and the
arguments it hands to each score, ``image_scores``' SDK-mask IoU ``fg_iou_raw``, frames without ground truth or
target renders, the other mask's threshold, the size message, the refusals' hints to the end, and
``init_scores``' faces. On the small synthetic session of ``synth_case`` and fake runs of it."""

import functools
import json
import shutil
import types

import numpy as np
import pytest

from bodystudio.capture.session import open_session
from bodystudio.errors import FileFormatError, InputError
from bodystudio.mirror import evaluate as ev
from tests.mirror.synth_case import edit_manifest, small_mirror_session, truth_run, write_fake_run


def _session():
    """The small session (built once per process by ``synth_case``; also the fixture of the direct recheck)."""
    return open_session(small_mirror_session())


@pytest.fixture(scope="module")
def session():
    return _session()




# ------------------------------------------------------------------------------------------ tracking_scores

class _Body:
    def __init__(self, positions):
        self.positions = positions
        self.tracked = np.ones(len(positions), bool)


def _tracking_stand_ins(monkeypatch, bodies):
    """Stand-ins for the frame reader, the IK, posed_joints and kinect_joints whose output is known: the 'model'
    joints of a frame are its SDK joints (so the error is |SDK - truth|); returns the log of the IK calls."""
    import bodystudio.body.kinect as kinect
    import bodystudio.body.skinning as skinning
    import bodystudio.mirror.frames as frames
    import bodystudio.mirror.track as track

    calls = []

    def read(session, i):
        assert session is not None and type(i) is int
        return types.SimpleNamespace(body=lambda player: bodies[i].get(player))

    def ik(skeleton, positions, tracked, version, previous):
        calls.append({"skeleton": skeleton, "positions": positions, "tracked": tracked, "version": version,
                      "previous": previous})
        return {"pose of": positions}

    def posed(skeleton, pose):
        assert skeleton == "SKELETON"
        return pose["pose of"], -pose["pose of"]

    def kj(skeleton, heads, tails, version):
        assert skeleton == "SKELETON" and version == "v1" and np.array_equal(tails, -heads)
        return heads

    monkeypatch.setattr(frames, "read_mirror_frame", read)
    monkeypatch.setattr(track, "ik_pose", ik)
    monkeypatch.setattr(skinning, "posed_joints", posed)
    monkeypatch.setattr(kinect, "kinect_joints", kj)
    return calls


def _tracking_case(monkeypatch):
    """Frames 0-4 of a two-player stand-in session: player 2 tracked in 0, 1, 3, 4; lost in 2 (no SDK body);
    frame 4 has an SDK body the ground truth does not hold (a ghost). The truth joints of player 2 are offset
    from the SDK joints by 3-4-0 cm (5 cm) in frames 0-1 and 6-8-0 cm (10 cm) in frame 3."""
    rng = np.random.default_rng(4)
    sdk = {i: rng.normal(size=(25, 3)) for i in range(5)}
    off = {0: [0.03, 0.04, 0.0], 1: [0.0, 0.03, 0.04], 3: [0.06, 0.0, 0.08]}
    gts = {}
    for i in range(5):
        players = [1, 2] if i != 4 else [1]
        truth2 = sdk[i] + np.asarray(off.get(i, [0.0, 0.0, 0.0]))
        gts[i] = {"players": np.array(players), "kinect_joints": np.stack([sdk[i] + 1.0, truth2])[:len(players)]}
    bodies = {i: {1: _Body(sdk[i] + 5.0), 2: _Body(sdk[i])} for i in range(5)}
    bodies[2] = {1: _Body(sdk[2] + 5.0)}
    session = types.SimpleNamespace(kinect=types.SimpleNamespace(version="v1"),
                                    frame=lambda i: types.SimpleNamespace(gt_mirror=gts[i]))
    source = types.SimpleNamespace(skeleton="SKELETON")
    return session, source, sdk, _tracking_stand_ins(monkeypatch, bodies)


def test_tracking_scores_is_the_mean_joint_distance_in_mm_over_the_tracked_frames(monkeypatch):
    session, source, sdk, calls = _tracking_case(monkeypatch)
    out = ev.tracking_scores(session, source, [0, 1, 2, 3, 4], player=2)
    # frames 0, 1, 3 scored: (50 + 50 + 100) / 3 mm; frame 2 (lost) and 4 (not in the ground truth) skipped
    assert out == {"joint_err_mm": pytest.approx(200.0 / 3.0, abs=1e-9)}
    assert [c["version"] for c in calls] == ["v1"] * 3 and all(c["skeleton"] == "SKELETON" for c in calls)
    for c, i in zip(calls, (0, 1, 3), strict=True):
        assert c["positions"] is not None and np.array_equal(c["positions"], sdk[i]) and c["tracked"].all()
    # the IK starts from the previous frame's pose, from scratch after a frame without the player
    assert calls[0]["previous"] is None and calls[1]["previous"]["pose of"] is calls[0]["positions"]
    assert calls[2]["previous"] is None


def test_tracking_scores_of_player_1_by_default_and_none_without_a_tracked_frame(monkeypatch):
    session, source, sdk, calls = _tracking_case(monkeypatch)
    out = ev.tracking_scores(session, source, [2, 4])  # player 1: SDK + 5 m, truth + 1 m on each axis
    assert out["joint_err_mm"] == pytest.approx(np.linalg.norm([4.0, 4.0, 4.0]) * 1e3, abs=1e-6)
    nothing = ev.tracking_scores(session, source, [2], player=2)
    assert list(nothing) == ["joint_err_mm"] and np.isnan(nothing["joint_err_mm"])
    assert np.isnan(ev.tracking_scores(session, source, [], player=2)["joint_err_mm"])


@functools.cache
def _true_skeleton():
    from bodystudio.body import build_body
    from bodystudio.body.skeleton import Skeleton

    s = _session()
    actors = s.gt_mirror_actors
    rig = build_body(resolution="6k").skeleton
    return Skeleton(tuple(s.gt_subject["bone_names"]), rig.parents, actors["source_heads"][0],
                    actors["source_tails"][0], rig.rolls)


def test_tracking_scores_of_the_true_skeleton_with_the_real_ik(session):
    """The IK against the SDK's noisy joints (1 cm noise, 3 % bone jitter) with the true skeleton: measured
    16.9 mm over the 4 frames; a skeleton 10 cm off in height scores far worse (no frame is skipped)."""
    source = types.SimpleNamespace(skeleton=_true_skeleton())
    err = ev.tracking_scores(session, source, [10, 11, 12, 13])["joint_err_mm"]
    assert 8.0 < err < 25.0
    assert np.isnan(ev.tracking_scores(session, source, list(range(10)))["joint_err_mm"])  # the empty room
    sk = source.skeleton
    squat = types.SimpleNamespace(skeleton=type(sk)(sk.bone_names, sk.parents, sk.heads * [1.0, 0.8, 1.0],
                                                     sk.tails * [1.0, 0.8, 1.0], sk.rolls))
    assert ev.tracking_scores(session, squat, [10, 11, 12, 13])["joint_err_mm"] > 2 * err


# ------------------------------------------------------------------------------------------ evaluate_mirror

def _source_body(session):
    """A SourceBody of the true rest mesh with a consistent stand-in skeleton (the IK is not run here)."""
    from bodystudio.body.skeleton import Skeleton
    from bodystudio.mirror.init import SourceBody

    actors = session.gt_mirror_actors
    sk = Skeleton(("a", "b"), np.array([-1, 0]), np.array([[0.0, 1.0, 0.0], [0.0, 1.2, 0.0]]),
                  np.array([[0.0, 1.2, 0.0], [0.0, 1.4, 0.0]]), np.zeros(2))
    return SourceBody(np.arange(5.0), np.asarray(actors["source_rest_vertices"][0], np.float64), sk, (10,), 1.0)


def _tracking_spy(monkeypatch):
    asked = []

    def tracking(sess, source, frames, player=1):
        asked.append((sess, source, list(frames), player))
        return {"joint_err_mm": 7.0}

    monkeypatch.setattr(ev, "tracking_scores", tracking)
    return asked


def test_evaluate_mirror_defaults_to_the_sessions_run_folder_and_source_body(session, tmp_path, monkeypatch):
    from bodystudio.mirror.init import save_source_body, source_fingerprint

    path = tmp_path / "session"
    shutil.copytree(session.path, path)
    copy = open_session(path)
    body = _source_body(copy)
    run_dir = truth_run(copy, path / "mirror" / "run")
    asked = _tracking_spy(monkeypatch)
    with pytest.raises(InputError) as info:
        ev.evaluate_mirror(str(path))
    assert str(info.value) == (f"{path / 'mirror' / 'source_body.npz'}: missing; run `bodystudio mirror init "
                               f"{copy.path}` (the run needs it too)")
    save_source_body(path / "mirror" / "source_body.npz", body)
    scores = ev.evaluate_mirror(str(path))
    run = json.loads((run_dir / "run.json").read_text())
    assert scores["run"] == str(run_dir) and scores["session"] == str(copy.path) and scores["player"] == 1
    assert scores["run_id"] == run["run"]["run_id"] and isinstance(scores["run_id"], str)
    assert scores["source_fingerprint"] == source_fingerprint(body)
    assert scores["init_stature_err_mm"] < 1e-6 and scores["init_mass_err_kg"] < 1e-6 and scores["warp_iou"] == 1.0
    (s, src, frames, player), = asked
    assert str(s.path) == str(copy.path) and src.coeffs.tolist() == body.coeffs.tolist()
    assert frames == [10, 11, 12, 13] and player == 1
    # a run that records the same body is scored; one that records another is refused, in one line
    edit_manifest(run_dir, lambda r: r.update(source_fingerprint=source_fingerprint(body)))
    assert ev.evaluate_mirror(str(path))["source_fingerprint"] == source_fingerprint(body)
    edit_manifest(run_dir, lambda r: r.update(source_fingerprint="0" * 16))
    with pytest.raises(InputError) as info:
        ev.evaluate_mirror(str(path))
    assert str(info.value) == (f"{run_dir}: the run used another source body than {path / 'mirror' / 'source_body.npz'}"
                               " (mirror init re-run after it, or mirror run --source); re-run `bodystudio mirror "
                               "run` with this one")
    # a source handed in is used as it is (no fingerprint check, none recorded without coefficients)
    plain = types.SimpleNamespace(vertices=body.vertices, faces=copy.gt_mirror_actors["faces"])
    scores = ev.evaluate_mirror(copy, run_dir, source=plain)
    assert scores["source_fingerprint"] is None and asked[-1][1] is plain


def test_evaluate_mirror_hands_the_runs_player_and_band_to_every_score(session, tmp_path, monkeypatch):
    """A run of player 2 (the ground truth edits nobody): the player, the band, the session, the run and the
    scored frames reach image_scores, init_scores and tracking_scores."""
    monkeypatch.setitem(session.metadata, "edits", {})
    run_dir = truth_run(session, tmp_path / "run", edits={}, player=2)
    seen = {}

    def images(sess, rd, run, band_px=ev.BAND_PX):
        seen["images"] = (sess, rd, run, band_px)
        return {"scored_frames": [11, 13], "frames_scored": 2, "fg_iou": 0.5}

    def init(sess, source, player=1):
        seen["init"] = (sess, source, player)
        return {"init_stature_err_mm": 1.0}

    monkeypatch.setattr(ev, "image_scores", images)
    monkeypatch.setattr(ev, "init_scores", init)
    asked = _tracking_spy(monkeypatch)
    source = types.SimpleNamespace(vertices=np.zeros((3, 3)))
    scores = ev.evaluate_mirror(session, run_dir, source=source, band_px=37)
    sess, rd, run, band = seen["images"]
    assert sess is session and rd == run_dir and run["player"] == 2 and band == 37
    assert seen["init"] == (session, source, 2) and asked == [(session, source, [11, 13], 2)]
    assert scores["player"] == 2 and scores["fg_iou"] == 0.5 and scores["frames_scored"] == 2
    assert scores["init_stature_err_mm"] == 1.0 and scores["edits"] == {} and "scored_frames" not in scores
    assert scores["run_id"] == run["run"]["run_id"]
    run.pop("run")  # a manifest without the run block (read_mirror_run refuses it; a stand-in passes it)
    monkeypatch.setattr(ev, "read_mirror_run", lambda sess, rd: run)
    assert ev.evaluate_mirror(session, run_dir, source=source)["run_id"] is None
    assert seen["images"][3] == ev.BAND_PX == 10
    run.pop("player")  # a manifest without the player: player 1
    assert ev.evaluate_mirror(session, run_dir, source=source)["player"] == 1
    assert seen["init"][2] == 1 and asked[-1][3] == 1


# ------------------------------------------------------------------------------------------ image_scores

def test_fg_iou_raw_is_the_sdk_player_mask_against_the_true_person(session, tmp_path):
    from bodystudio.mirror.frames import player_mask_in_color, read_mirror_frame

    run_dir = truth_run(session, tmp_path / "run")
    scores = ev.image_scores(session, run_dir, ev.read_mirror_run(session, run_dir))
    expect = [ev.mask_iou(player_mask_in_color(read_mirror_frame(session, i), session.kinect, 1),
                          session.frame(i).gt_person == 1) for i in (10, 11, 12, 13)]
    assert scores["fg_iou_raw"] == pytest.approx(float(np.mean(expect)), abs=1e-12)
    assert 0.75 < scores["fg_iou_raw"] < 0.95  # measured 0.85: close, not the truth
    # a bystander (player 2) in the SDK's mask is not the run's player: the raw IoU is player 1's mask only
    over = {}
    for i in (10, 11, 12, 13):
        labels = session.frame(i).kinect_player.copy()
        labels[20:120, 20:140] = np.where(session.frame(i).kinect_depth_m[20:120, 20:140] > 0, 2, 0)
        over[i] = {"kinect_player": labels}
    proxy = _Proxy(session, over)
    with_bystander = ev.image_scores(proxy, run_dir, ev.read_mirror_run(session, run_dir))
    assert with_bystander["fg_iou_raw"] == pytest.approx(scores["fg_iou_raw"], abs=1e-12)
    anyone = np.mean([ev.mask_iou(player_mask_in_color(read_mirror_frame(proxy, i), session.kinect, None),
                                  session.frame(i).gt_person == 1) for i in (10, 11, 12, 13)])
    assert anyone < scores["fg_iou_raw"] - 0.05


def test_a_run_of_another_player_than_the_tracked_one_has_nothing_to_score(session, tmp_path):
    run_dir = truth_run(session, tmp_path / "run")
    run = json.loads((run_dir / "run.json").read_text())
    run["player"] = 2
    with pytest.raises(InputError) as info:
        ev.image_scores(session, run_dir, run)
    assert str(info.value) == (f"{run_dir}: none of the run's frames shows player 2 tracked in {session.path}; "
                               "nothing to score")


def test_a_ramp_never_completed_is_refused_with_its_numbers(session, tmp_path):
    run_dir = edit_manifest(truth_run(session, tmp_path / "run"), lambda r: r.update(ramp_frames=30))
    with pytest.raises(InputError) as info:
        ev.image_scores(session, run_dir, ev.read_mirror_run(session, run_dir))
    assert str(info.value) == (f"{run_dir}: the run never reached the whole edit (--ramp-frames 30, 14 tracked "
                               "frames) and the ground truth shows the whole edit; re-run `bodystudio mirror run` "
                               "with --ramp-frames 0")
    # exactly complete on the last frame: that frame is scored; one short and nothing is
    run_dir = edit_manifest(truth_run(session, tmp_path / "run14"), lambda r: r.update(ramp_frames=14))
    assert ev.image_scores(session, run_dir, ev.read_mirror_run(session, run_dir))["scored_frames"] == [13]
    run_dir = edit_manifest(truth_run(session, tmp_path / "run15"),
                             lambda r: (r.update(ramp_frames=15), r["frames"][13].update(status="passed")))
    with pytest.raises(InputError, match=r"--ramp-frames 15, 13 tracked frames"):
        ev.image_scores(session, run_dir, ev.read_mirror_run(session, run_dir))
    # the ramp completed on the last frame, which shows nobody to score: "nothing to score", not "never reached"
    run_dir = edit_manifest(truth_run(session, tmp_path / "last"), lambda r: r.update(ramp_frames=14))
    with pytest.raises(InputError, match="none of the run's frames shows player 1"):
        ev.image_scores(_Proxy(session, {13: {"gt_mirror": None}}), run_dir, ev.read_mirror_run(session, run_dir))
    # a scored frame after the ramp, or a run without ramping frames, is not refused by this rule
    run_dir = edit_manifest(truth_run(session, tmp_path / "late"),
                             lambda r: [r.update(ramp_frames=20)] + [f.update(status="passed")
                                                                     for f in r["frames"][:13]])
    with pytest.raises(InputError, match="never reached"):
        ev.image_scores(session, run_dir, ev.read_mirror_run(session, run_dir))


class _Proxy:
    """The session with some frames' attributes replaced (``over[i]``: name -> value)."""

    def __init__(self, session, over):
        self._s, self._over = session, over

    def __getattr__(self, name):
        return getattr(self._s, name)

    def frame(self, i):
        return _FrameProxy(self._s.frame(i), self._over.get(i, {}))


class _FrameProxy:
    def __init__(self, frame, over):
        self._f, self._over = frame, over

    def __getattr__(self, name):
        return self._over[name] if name in self._over else getattr(self._f, name)


def test_frames_without_ground_truth_are_skipped_not_the_rest(session, tmp_path):
    run_dir = truth_run(session, tmp_path / "run")
    run = ev.read_mirror_run(session, run_dir)
    for key in ("gt_mirror", "gt_person"):
        scores = ev.image_scores(_Proxy(session, {11: {key: None}}), run_dir, run)
        assert scores["scored_frames"] == [10, 12, 13] and scores["fg_iou"] == 1.0, key


def test_sessions_without_target_renders_score_against_the_input(session, tmp_path):
    """Without gt_target_person / gt_target_rgb the target is the true person in the colour image."""
    run_dir = write_fake_run(session, tmp_path / "run", lambda f: f.kinect_rgb, lambda f: f.gt_person == 1,
                             lambda f: f.gt_person == 1)
    run = ev.read_mirror_run(session, run_dir)
    proxy = _Proxy(session, {i: {"gt_target_person": None, "gt_target_rgb": None} for i in session.frame_ids})
    scores = ev.image_scores(proxy, run_dir, run)
    assert scores["warp_iou"] == 1.0 and scores["warp_iou_unwarped"] == 1.0 and scores["psnr_person"] == np.inf
    assert scores["ssim_person"] == pytest.approx(1.0, abs=1e-12)
    with_targets = ev.image_scores(session, run_dir, run)
    assert with_targets["warp_iou"] < 0.9 and with_targets["psnr_person"] < 30.0


def test_the_other_masks_are_read_at_the_half_way_grey_level_too(session, tmp_path):
    """Foreground at 127 is out, warped at 128 is in (test_evaluate_mutants.py checks the opposite pair)."""
    import cv2

    run_dir = truth_run(session, tmp_path / "run")
    for i in session.frame_ids:
        for key, level in (("foreground", 127), ("warped", 128)):
            p = run_dir / "masks" / key / f"{i:05d}.png"
            m = cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)
            cv2.imwrite(str(p), np.where(m > 0, level, 0).astype(np.uint8))
    scores = ev.image_scores(session, run_dir, json.loads((run_dir / "run.json").read_text()))
    assert scores["fg_iou"] == 0.0 and scores["warp_iou"] == 1.0


@pytest.mark.parametrize("which", ["foreground", "warped", "frames"])
def test_each_image_of_another_size_is_refused_with_both_sizes(session, tmp_path, which):
    h, w = session.frame(10).gt_person.shape
    cut = {k: (lambda x: x[:-2]) if k == which else (lambda x: x) for k in ("frames", "foreground", "warped")}
    run_dir = write_fake_run(session, tmp_path / "run", lambda f: cut["frames"](f.gt_target_rgb),
                             lambda f: cut["foreground"](f.gt_person == 1),
                             lambda f: cut["warped"](f.gt_target_person == 1))
    with pytest.raises(FileFormatError) as info:
        ev.image_scores(session, run_dir, ev.read_mirror_run(session, run_dir))
    oh = h - 2 if which == "frames" else h
    assert str(info.value) == (f"{run_dir / 'frames' / '00010.png'}: image size {w}x{oh} is not the session's "
                               f"colour {w}x{h}; re-run the mirror")


# ------------------------------------------------------------------------------------------ read_mirror_run

def test_an_unparsable_manifest_is_named_as_the_mirror_run_manifest(session, tmp_path):
    run_dir = truth_run(session, tmp_path / "run")
    (run_dir / "run.json").write_text("{not json")
    with pytest.raises(FileFormatError) as info:
        ev.read_mirror_run(session, run_dir)
    assert str(info.value).startswith(f"{run_dir / 'run.json'}: not a valid mirror run manifest (")


def test_the_player_hint_names_the_edited_player(session, tmp_path, monkeypatch):
    run_dir = truth_run(session, tmp_path / "run")
    monkeypatch.setitem(session.metadata, "edited_players", [3])
    with pytest.raises(InputError) as info:
        ev.read_mirror_run(session, run_dir)
    assert str(info.value).endswith("the run reshapes player 1 but the ground truth edits players [3]; "
                                    "re-run with --player 3")
    monkeypatch.setitem(session.metadata, "edited_players", [])
    with pytest.raises(InputError) as info:
        ev.read_mirror_run(session, run_dir)
    assert str(info.value).endswith("edits players []; re-run with --player 1")


# ------------------------------------------------------------------------------------------ init_scores

def test_init_scores_measure_the_sources_own_faces(session):
    """Faces handed with the source are the ones measured (half the triangles: another volume, so another mass)."""
    from bodystudio.body.measure import measure_attributes

    actors = session.gt_mirror_actors
    V, F = np.asarray(actors["source_rest_vertices"][0]), np.asarray(actors["faces"])
    half = F[: len(F) // 2]
    out = ev.init_scores(session, types.SimpleNamespace(vertices=V, faces=half))
    m = measure_attributes(V, half)
    assert out["init_mass_kg"] == pytest.approx(m["mass_kg"], abs=1e-12)
    assert abs(out["init_mass_kg"] - measure_attributes(V, F)["mass_kg"]) > 1.0


def test_init_scores_of_a_full_resolution_body_find_the_full_template(session):
    from bodystudio.body.makehuman import load_base
    from bodystudio.body.measure import measure_attributes
    from bodystudio.body.model import template_topology

    base = load_base()
    V = np.asarray(base.vertices[: base.n_body], np.float64)
    _, F = template_topology("full")
    assert len(V) == 13380
    out = ev.init_scores(session, types.SimpleNamespace(vertices=V))
    assert out["init_mass_kg"] == pytest.approx(measure_attributes(V, F)["mass_kg"], abs=1e-12)
    with pytest.raises(InputError) as info:
        ev.init_scores(session, types.SimpleNamespace(vertices=V[:-1]))
    assert str(info.value) == ("source body with 13379 vertices is in no body template; rerun `bodystudio mirror "
                               "init`")
