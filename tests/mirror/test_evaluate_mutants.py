"""Fast tests of the mirror evaluation's session layer (bodystudio.mirror.evaluate; issue 17): the run folder
refusals one by one, which frames are scored (not reported, passed through, ramping), the band, the shape check,
the defaults of ``evaluate_mirror``. On the small synthetic session of ``synth_case`` and fake runs whose images
are the ground truth, so every score is exact."""

import json
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




@pytest.mark.parametrize("change, error, match, end", [
    (lambda r: r.update(format="other"), FileFormatError, "not a mirror run manifest",
     "run.json: not a mirror run manifest (format != 'bodystudio-mirror-run'); pass the folder "
     "`bodystudio mirror run` wrote"),
    (lambda r: r.update(frames={"index": 1}), FileFormatError, "not a mirror run manifest", "wrote"),
    (lambda r: r.update(session=None), InputError, "made from session None",
     "; evaluate it against its own session"),
    (lambda r: r["frames"].append({"index": 10.0}), FileFormatError, "malformed frame list",
     "run.json: malformed frame list; re-run `bodystudio mirror run`"),
    (lambda r: r["frames"].append(dict(r["frames"][0])), FileFormatError, "malformed frame list", "mirror run`"),
    (lambda r: r["frames"].append("frame"), FileFormatError, "malformed frame list", "mirror run`"),
    (lambda r: r["frames"].append({"index": 99, "status": "ok"}), InputError, r"frames \[99\] are not in",
     "; the run belongs to another session"),
    (lambda r: r["frames"].extend({"index": 99 + k, "status": "ok"} for k in range(6)), InputError,
     r"frames \[99, 100, 101, 102, 103\] are not in", "; the run belongs to another session"),
    (lambda r: r["run"].pop("files"), InputError, r"frames/00000.png is not in run.json \(42 such\)",
     "the run folder is incomplete, re-run `bodystudio mirror run`"),
    (lambda r: r.update(frames=[]), InputError, "holds no frames",
     "run: the run holds no frames; re-run `bodystudio mirror run`"),
    (lambda r: r["run"]["files"].pop("masks/foreground/00011.png"), InputError,
     r"masks/foreground/00011.png is not in run.json \(1 such\)",
     "(1 such); the run folder is incomplete, re-run `bodystudio mirror run`"),
    (lambda r: r.update(edits={"taller": 0.15 + 1e-6}), InputError, "edits",
     "; re-run `bodystudio mirror run` with the session's edits"),
    (lambda r: r.update(edits={"taller": 0.15, "wider": 0.1}), InputError, "edits", "with the session's edits"),
    (lambda r: r.update(player=2), InputError, "re-run with --player 1",
     "run: the run reshapes player 2 but the ground truth edits players [1]; re-run with --player 1"),
])
def test_read_mirror_run_refuses_each_broken_manifest(session, tmp_path, change, error, match, end):
    run_dir = edit_manifest(truth_run(session, tmp_path / "run"), change)
    with pytest.raises(error, match=match) as info:
        ev.read_mirror_run(session, run_dir)
    assert "\n" not in str(info.value) and str(info.value).endswith(end), str(info.value)


def test_read_mirror_run_refuses_missing_interrupted_and_uncommitted_folders(session, tmp_path):
    with pytest.raises(InputError) as info:
        ev.read_mirror_run(session, tmp_path / "nothing")
    assert str(info.value) == (f"--run {tmp_path / 'nothing'}: no such run folder; run `bodystudio mirror run "
                               f"{session.path}` first")
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError) as info:
        ev.read_mirror_run(session, tmp_path / "empty")
    assert str(info.value) == (f"{tmp_path / 'empty' / 'run.json'}: missing, the run folder is incomplete (never "
                               f"committed); re-run `bodystudio mirror run {session.path}`")
    run_dir = truth_run(session, tmp_path / "run")
    (run_dir / ".staging").mkdir()
    (run_dir / ".staging" / "commit.json").write_text("{}")
    with pytest.raises(InputError, match="interrupted") as info:
        ev.read_mirror_run(session, run_dir)
    assert str(run_dir) in str(info.value) and "None" not in str(info.value)
    junk = truth_run(session, tmp_path / "junk")
    (junk / "run.json").write_text("{not json")
    with pytest.raises(FileFormatError, match="mirror run manifest"):
        ev.read_mirror_run(session, junk)


def test_the_session_refusal_names_the_commands(tmp_path):
    fake = types.SimpleNamespace(path=tmp_path, metadata={}, streams=[], kinect=None)
    with pytest.raises(InputError) as info:
        ev.check_mirror_session(fake)
    assert str(info.value) == (f"{tmp_path}: not a synthetic mirror session (no mirror ground truth); "
                               "`bodystudio eval mirror` scores runs on sessions from `bodystudio synth mirror`")


def test_read_mirror_run_accepts_the_edits_to_round_off_and_zero_edits_left_out(session, tmp_path):
    run_dir = edit_manifest(truth_run(session, tmp_path / "run"),
                             lambda r: r.update(edits={"taller": 0.15 + 1e-10, "wider": 0.0}))
    run = ev.read_mirror_run(session, run_dir)
    assert run["format"] == ev.RUN_FORMAT and [f["index"] for f in run["frames"]] == session.frame_ids
    run_dir = edit_manifest(truth_run(session, tmp_path / "run2"), lambda r: r.pop("player"))
    run = ev.read_mirror_run(session, run_dir)
    assert "player" not in run  # player 1 is the default
    assert ev.image_scores(session, run_dir, run)["scored_frames"] == [10, 11, 12, 13]
    # a listed file the scores do not need is not checked (a missing one does not refuse the run)
    run_dir = edit_manifest(truth_run(session, tmp_path / "run3"),
                             lambda r: r["run"]["files"].update({"log/unused.txt": "0" * 64}))
    assert ev.read_mirror_run(session, run_dir)["frames"]


def test_frames_the_tracker_did_not_report_or_passed_through_are_counted_right(session, tmp_path):
    run_dir = edit_manifest(truth_run(session, tmp_path / "run"),
                             lambda r: r["frames"][12].update(status="passed"))
    scores = ev.image_scores(session, run_dir, ev.read_mirror_run(session, run_dir))
    # frames 0-9 hold no actor (nothing reported), 10-13 are scored; 12 passed through
    assert scores["scored_frames"] == [10, 11, 12, 13] and scores["frames_scored"] == 4
    assert scores["frames_passed_through"] == 1 and scores["frames_ramping"] == 0
    assert scores["fg_iou"] == 1.0 and scores["warp_iou"] == 1.0 and scores["psnr_person"] == float("inf")
    assert 0.4 < scores["warp_iou_unwarped"] < 0.9


def test_the_band_limits_the_psnr_to_the_person(session, tmp_path):
    """Output = target render with every pixel farther than 30 px from both people set to black: a 10 px band
    sees no difference (infinite PSNR), the whole frame would."""
    import cv2

    def output(f):
        near = ev.person_band(f.gt_person == 1, f.gt_target_person == 1, 30)
        rgb = f.gt_target_rgb.copy()
        rgb[~near] = 0
        return rgb

    run_dir = write_fake_run(session, tmp_path / "run", output, lambda f: f.gt_person == 1,
                             lambda f: f.gt_target_person == 1)
    run = ev.read_mirror_run(session, run_dir)
    assert ev.image_scores(session, run_dir, run)["psnr_person"] == float("inf")
    wide = ev.image_scores(session, run_dir, run, band_px=60)
    assert wide["psnr_person"] < 40.0 and wide["ssim_person"] < 1.0
    # PSNR pooled over the scored frames' band pixels and channels, by hand
    sse, count = 0.0, 0
    for i in wide["scored_frames"]:
        f = session.frame(i)
        band = ev.person_band(f.gt_person == 1, f.gt_target_person == 1, 60)
        out = cv2.cvtColor(cv2.imread(str(run_dir / "frames" / f"{i:05d}.png")), cv2.COLOR_BGR2RGB)
        d = out.astype(float)[band] - f.gt_target_rgb.astype(float)[band]
        sse, count = sse + (d * d).sum(), count + d.size
    assert wide["psnr_person"] == pytest.approx(10 * np.log10(255.0**2 / (sse / count)), abs=1e-9)


def test_masks_are_read_at_the_half_way_grey_level(session, tmp_path):
    """The run's masks are PNGs thresholded above 127: 128 is in, 127 is out."""
    run_dir = write_fake_run(session, tmp_path / "run", lambda f: f.gt_target_rgb, lambda f: f.gt_person == 1,
                             lambda f: f.gt_target_person == 1)
    import cv2

    for i in session.frame_ids:
        for key, level in (("foreground", 128), ("warped", 127)):
            p = run_dir / "masks" / key / f"{i:05d}.png"
            m = cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)
            cv2.imwrite(str(p), np.where(m > 0, level, 0).astype(np.uint8))
    run = ev.read_mirror_run(session, run_dir) if False else json.loads((run_dir / "run.json").read_text())
    scores = ev.image_scores(session, run_dir, run)
    assert scores["fg_iou"] == 1.0 and scores["warp_iou"] == 0.0


def test_an_output_of_another_size_is_refused(session, tmp_path):
    run_dir = write_fake_run(session, tmp_path / "run", lambda f: f.gt_target_rgb[:-2], lambda f: f.gt_person == 1,
                             lambda f: f.gt_target_person == 1)
    with pytest.raises(FileFormatError, match="is not the session's colour"):
        ev.image_scores(session, run_dir, ev.read_mirror_run(session, run_dir))


def test_a_run_of_the_empty_room_only_has_nothing_to_score(session, tmp_path):
    run_dir = truth_run(session, tmp_path / "run", frames=list(range(10)))
    with pytest.raises(InputError, match="none of the run's frames shows player 1 tracked"):
        ev.image_scores(session, run_dir, ev.read_mirror_run(session, run_dir))


def test_without_a_ramp_frames_before_the_first_tracked_one_are_not_ramping(session, tmp_path):
    def lost(r):
        for f in r["frames"][:10]:
            f["status"] = "lost"
        r.pop("ramp_frames", None)

    run_dir = edit_manifest(truth_run(session, tmp_path / "run"), lost)
    scores = ev.image_scores(session, run_dir, ev.read_mirror_run(session, run_dir))
    assert scores["frames_ramping"] == 0 and scores["scored_frames"] == [10, 11, 12, 13]


def test_the_ramp_counts_tracked_frames_only(session, tmp_path):
    """Frames 0-9 are 'ok' in the fake run; with frame 10 passed through, a ramp of 12 ends at frame 12."""
    run_dir = edit_manifest(truth_run(session, tmp_path / "run", extra={"ramp_frames": 12}),
                             lambda r: r["frames"][10].update(status="lost"))
    scores = ev.image_scores(session, run_dir, ev.read_mirror_run(session, run_dir))
    assert scores["scored_frames"] == [12, 13] and scores["frames_ramping"] == 12


def test_actor_truth_and_its_refusal(session):
    assert ev.actor_truth(session, 1)["player"] == 1 and "measured" in ev.actor_truth(session, 1)
    with pytest.raises(InputError, match="no ground truth of player 4"):
        ev.actor_truth(session, 4)


def test_init_scores_refuse_a_body_of_no_template(session):
    with pytest.raises(InputError, match="source body with 5 vertices is in no body template"):
        ev.init_scores(session, types.SimpleNamespace(vertices=np.zeros((5, 3))))


def test_check_mirror_session_refuses_other_sessions(tmp_path, session):
    assert ev.check_mirror_session(session) is session
    assert ev.check_mirror_session(str(session.path)).path == session.path
    fake = types.SimpleNamespace(path=tmp_path, metadata={"generator": "bodystudio synth mirror"}, streams=[],
                                 kinect=object())
    with pytest.raises(InputError, match="not a synthetic mirror session"):
        ev.check_mirror_session(fake)
    fake = types.SimpleNamespace(path=tmp_path, metadata=None, streams=["gt_person"], kinect=object())
    with pytest.raises(InputError, match="not a synthetic mirror session"):
        ev.check_mirror_session(fake)
    fake = types.SimpleNamespace(path=tmp_path, metadata={"generator": "bodystudio synth mirror"},
                                 streams=["gt_person"], kinect=None)
    with pytest.raises(InputError, match="not a synthetic mirror session"):
        ev.check_mirror_session(fake)


def test_evaluate_mirror_needs_the_source_body_and_reports_the_timings(session, tmp_path):
    run_dir = edit_manifest(truth_run(session, tmp_path / "run"),
                             lambda r: r["summary"].update(ms_per_frame={"a": 2, "b": 3.5}, fps_wall=12.5))
    with pytest.raises(InputError, match="source_body.npz: missing; run `bodystudio mirror init"):
        ev.evaluate_mirror(session, run_dir)
    # the tracking score on a stand-in: record which frames it is asked for
    asked = []

    def tracking(sess, source, frames, player=1):
        asked.append((list(frames), player))
        return {"joint_err_mm": 7.0}

    import bodystudio.mirror.evaluate as mod

    actors = session.gt_mirror_actors
    source = types.SimpleNamespace(vertices=actors["source_rest_vertices"][0], faces=actors["faces"])
    orig = mod.tracking_scores
    mod.tracking_scores = tracking
    try:
        scores = ev.evaluate_mirror(session, run_dir, source=source)
    finally:
        mod.tracking_scores = orig
    assert asked == [([10, 11, 12, 13], 1)] and scores["joint_err_mm"] == 7.0
    assert scores["ms_per_frame"] == {"a": 2.0, "b": 3.5} and scores["ms_per_frame_total"] == 5.5
    assert scores["fps"] == 12.5 and scores["player"] == 1 and scores["edits"] == {"taller": 0.15}
    assert scores["run"] == str(run_dir) and scores["session"] == str(session.path)
    assert "scored_frames" not in scores and scores["frames_scored"] == 4
    assert scores["psnr_person"] is None and scores["psnr_person_identical"] is True
    run_dir2 = edit_manifest(truth_run(session, tmp_path / "run2"), lambda r: r.pop("summary"))
    mod.tracking_scores = tracking
    try:
        scores = ev.evaluate_mirror(session, run_dir2, source=source)
    finally:
        mod.tracking_scores = orig
    assert scores["ms_per_frame"] == {} and scores["ms_per_frame_total"] is None and scores["fps"] is None


def test_init_scores_are_the_stature_and_mass_differences_of_the_rest_mesh(session):
    """The true source body scores 0; 1 % taller (y scaled about the floor) is 1 % of the stature and about 1 % of
    the mass; faces come from the template of the vertex count when the source has none; the fields are named."""
    from bodystudio.body.measure import measure_attributes

    actors = session.gt_mirror_actors
    V, F = actors["source_rest_vertices"][0], actors["faces"]
    exact = ev.init_scores(session, types.SimpleNamespace(vertices=V, faces=F))
    truth = ev.actor_truth(session, 1)["measured"]
    assert exact["init_stature_err_mm"] < 1e-6 and exact["init_mass_err_kg"] < 1e-6
    assert exact["true_stature_m"] == truth["stature_m"] and exact["true_mass_kg"] == truth["mass_kg"]
    scaled = V * np.array([1.0, 1.01, 1.0])
    off = ev.init_scores(session, types.SimpleNamespace(vertices=scaled))  # faces from the template
    m = measure_attributes(scaled, F)
    assert off["init_stature_m"] == pytest.approx(m["stature_m"], abs=1e-12)
    assert off["init_mass_kg"] == pytest.approx(m["mass_kg"], abs=1e-9)
    assert off["init_stature_err_mm"] == pytest.approx(abs(m["stature_m"] - truth["stature_m"]) * 1e3, abs=1e-9)
    assert off["init_mass_err_kg"] == pytest.approx(abs(m["mass_kg"] - truth["mass_kg"]), abs=1e-9)
    assert off["init_stature_err_mm"] == pytest.approx(truth["stature_m"] * 10.0, rel=0.02)
    shrunk = ev.init_scores(session, types.SimpleNamespace(vertices=V * np.array([1.0, 0.99, 1.0]), faces=F))
    assert shrunk["init_stature_err_mm"] > 5.0 and shrunk["init_mass_err_kg"] > 0.1  # absolute values
