"""Bad input to ``bodystudio garment render``: one-line errors, exit 2, nothing written; a killed render
leaves the previous DIR/render/ (and the previous video) intact."""

import sys
from pathlib import Path

import pytest

from .conftest import assert_clean_error, run_inprocess

sys.path.insert(0, str(Path(__file__).parent))
from kill_harness import read_events, run_child, snapshot  # noqa: E402


@pytest.fixture(scope="module")
def fit_dir(tmp_path_factory):
    """The oracle fit of a 2-frame 120x160 synthetic garment session (2k body), lights turned 10 deg."""
    from bodystudio.garment.composite import ground_truth_fit, perturbed_fit
    from bodystudio.garment.fitfile import save_garment_fit
    from bodystudio.garment.synthetic import synth_garment_session

    root = tmp_path_factory.mktemp("grender")
    session = synth_garment_session(root / "session", subject_seed=3, n_frames=2, resolution=(120, 160),
                                    template="2k", texture_size=64, seed=2)
    save_garment_fit(root / "fit", perturbed_fit(ground_truth_fit(session), pose_deg=0.0, translation_m=0.0), "test")
    return root / "fit"


def test_render_writes_frames_masks_video_and_json(fit_dir, tmp_path, capfd, monkeypatch):
    import json

    out = tmp_path / "out.mp4"
    r = run_inprocess(["garment", "render", fit_dir, "--garment", "skirt", "--texture", "checks", "--out", out], capfd)
    assert_clean_error(r, 0, "")
    doc = json.loads((fit_dir / "render" / "render.json").read_text())
    assert doc["garment"] == "skirt" and doc["options"] == {"flow": True, "rbf": True, "depth": True, "hem": True,
                                                                 "shadows": True}
    assert set(doc["ms_per_frame"]) == {"render", "flow", "rbf", "composite", "write"}
    assert sorted(p.name for p in (fit_dir / "render" / "frames").iterdir()) == ["00000.png", "00001.png"]
    assert len(list((fit_dir / "render" / "garment_masks").iterdir())) == 2
    assert out.stat().st_size > 1000 and out.read_bytes()[4:8] == b"ftyp"
    from bodystudio.garment import refine

    def never(*args, **kwargs):
        raise AssertionError("a step switched off ran")

    # the switched-off steps are not run (was: their per-frame ms < 5, a wall-clock bound that failed under load)
    monkeypatch.setattr(refine, "garment_motion_correction", never)
    monkeypatch.setattr(refine, "silhouette_rbf_warp", never)
    monkeypatch.setattr(refine, "hem_matte", never)
    monkeypatch.setattr(refine, "worn_garment_probability", never)
    r = run_inprocess(["garment", "render", fit_dir, "--out", out, "--no-flow", "--no-rbf", "--no-depth", "--no-hem"],
                      capfd)
    assert_clean_error(r, 0, "")
    doc = json.loads((fit_dir / "render" / "render.json").read_text())
    assert doc["options"] == {"flow": False, "rbf": False, "depth": False, "hem": False, "shadows": True}
    assert doc["n_flow_applied"] == 0 and doc["n_hem_applied"] == 0


@pytest.mark.parametrize("case, phrase", [
    ("missing", "no such fit folder"),
    ("empty", "fit.json: not found; run 'bodystudio garment fit"),
    ("not_a_fit", "not a garment fit"),
])
def test_no_fit_in_dir(tmp_path, capfd, case, phrase):
    d = tmp_path / "fit"
    if case != "missing":
        d.mkdir()
    if case == "not_a_fit":
        (d / "fit.json").write_text('{"format": "something-else"}')
    out = tmp_path / "out.mp4"
    r = run_inprocess(["garment", "render", d, "--out", out], capfd)
    assert_clean_error(r, 2, phrase)
    assert not out.exists() and not (d / "render").exists()


@pytest.mark.parametrize("args, phrase", [
    (["--garment", "poncho"], "--garment 'poncho': valid: tights, skirt, tshirt, longsleeve"),
    (["--texture", "paisley"], "--texture 'paisley': valid: stripes, checks, print, plain"),
    (["--seed", "-1"], "--seed -1: must be in [0, 2^32)"),
    (["--seed", "99999999999"], "--seed 99999999999: must be in"),
])
def test_unknown_garment_or_texture(fit_dir, tmp_path, capfd, args, phrase):
    before = snapshot(fit_dir)
    out = tmp_path / "out.mp4"
    r = run_inprocess(["garment", "render", fit_dir, "--out", out, *args], capfd)
    assert_clean_error(r, 2, phrase)
    assert not out.exists() and snapshot(fit_dir) == before


def test_unwritable_out(fit_dir, tmp_path, capfd):
    before = snapshot(fit_dir)
    (tmp_path / "a_file").write_text("x")
    for out, phrase in ((tmp_path / "a_file" / "out.mp4", "a_file"), (tmp_path / "out.avi", "must be an .mp4"),
                        (tmp_path / "folder.mp4", "folder.mp4")):
        if out.name == "folder.mp4":
            out.mkdir()
        r = run_inprocess(["garment", "render", fit_dir, "--out", out], capfd)
        assert_clean_error(r, 2, phrase)
    assert snapshot(fit_dir) == before


def test_killed_render_leaves_the_old_render(fit_dir, tmp_path):
    import shutil

    work = tmp_path / "work"
    shutil.copytree(fit_dir, work / "fit")
    out = work / "out.mp4"
    args = ["garment", "render", str(work / "fit"), "--out", str(out), "--texture", "plain"]
    log = tmp_path / "events.json"
    assert run_child(args, work, event_log=log).returncode == 0
    old_render, old_video = snapshot(work / "fit" / "render"), out.read_bytes()
    events = read_events(log)  # the child counts every os.replace under work/, read locks included
    commit = next(k + 1 for k, e in enumerate(events) if e.endswith("commit.json"))
    # the child dies inside the k-th os.replace, before it happens: mid-staging, at the commit record, after it
    for kill_at in (2, commit, commit + 1):
        args[-1] = "stripes"
        proc = run_child(args, work, kill_at=kill_at)
        assert proc.returncode == -9, proc.stderr[-500:]
        if kill_at <= commit:  # before the commit point: the old result is untouched
            assert snapshot(work / "fit" / "render") == old_render and out.read_bytes() == old_video
        r = run_child(["recover", str(work / "fit" / "render")], work)
        assert r.returncode == 0, r.stderr[-500:]
        if kill_at <= commit:
            assert snapshot(work / "fit" / "render") == old_render and out.read_bytes() == old_video
        else:  # the commit record was written: recovery completes the new render
            import json

            assert json.loads((work / "fit" / "render" / "render.json").read_text())["texture"] == "stripes"
            assert out.read_bytes() != old_video


def test_unfitted_frames_pass_through(fit_dir, tmp_path, capfd):
    """A frame whose fit missed the silhouette is copied unchanged; a fit with no fitted frame is refused."""
    import json
    from dataclasses import replace

    import cv2
    import numpy as np

    from bodystudio.capture.session import open_session
    from bodystudio.garment.fitfile import load_garment_fit, save_garment_fit

    fit = load_garment_fit(fit_dir)
    d = tmp_path / "fit"
    save_garment_fit(d, replace(fit, silhouette_iou=np.array([0.95, 0.3])), "test")
    r = run_inprocess(["garment", "render", d, "--out", tmp_path / "o.mp4"], capfd)
    assert_clean_error(r, 0, "")
    doc = json.loads((d / "render" / "render.json").read_text())
    assert [f["status"] for f in doc["frames"]] == ["ok", "passed_through"] and doc["n_passed_through"] == 1
    frame = open_session(fit.source).frame(1).images["cam_00"]
    assert np.array_equal(cv2.imread(str(d / "render" / "frames" / "00001.png"))[..., ::-1], frame)
    assert doc["frames"][0]["garment_px"] > 100 and doc["frames"][1]["garment_px"] == 0
    # the flow gate's decision per frame (options.flow is only what was asked), and in the printed line
    assert doc["frames"][1]["flow_applied"] is False and doc["n_flow_applied"] == int(doc["frames"][0]["flow_applied"])
    assert f"flow correction used in {doc['n_flow_applied']} of them" in r.stdout
    e = tmp_path / "fit_none"
    save_garment_fit(e, replace(fit, silhouette_iou=np.array([0.2, 0.3])), "test")
    r = run_inprocess(["garment", "render", e, "--out", tmp_path / "n.mp4"], capfd)
    assert_clean_error(r, 2, "no frame of the fit matches")
    assert not (e / "render").exists() and not (tmp_path / "n.mp4").exists()


def test_video_source_shorter_than_the_fit(fit_dir, tmp_path, capfd):
    """A fit naming a frame the video does not have fails mid-run with one line; nothing is published."""
    from dataclasses import replace

    import imageio_ffmpeg
    import numpy as np

    from bodystudio.capture.session import open_session
    from bodystudio.garment.fitfile import load_garment_fit, save_garment_fit

    fit = load_garment_fit(fit_dir)
    video = tmp_path / "actor.mp4"
    w = imageio_ffmpeg.write_frames(str(video), (120, 160), fps=30, macro_block_size=8, ffmpeg_log_level="error")
    w.send(None)
    for i in range(2):
        w.send(np.ascontiguousarray(open_session(fit.source).frame(i).images["cam_00"]))
    w.close()
    d = tmp_path / "fit"
    save_garment_fit(d, replace(fit, source=str(video), frame_ids=np.array([0, 7])), "test")
    r = run_inprocess(["garment", "render", d, "--out", tmp_path / "o.mp4"], capfd)
    assert_clean_error(r, 2, "frame 7 of the fit is missing from the video")
    assert not (d / "render").exists() and not (tmp_path / "o.mp4").exists()
    (tmp_path / "junk.mp4").write_bytes(b"\x00" * 500)
    save_garment_fit(d, replace(fit, source=str(tmp_path / "junk.mp4")), "test")
    r = run_inprocess(["garment", "render", d, "--out", tmp_path / "o.mp4"], capfd)
    assert_clean_error(r, 2, "cannot read the video")
    assert not (d / "render").exists() and not (tmp_path / "o.mp4").exists()


def test_eval_refuses_a_render_of_another_garment_or_cloth(fit_dir, tmp_path, capfd):
    """The true render shows the session's target garment with its own cloth seed: a render of another
    garment, texture or seed cannot be scored against it (a PSNR of 12 dB would look like a bad fit)."""
    import json

    target = json.loads((fit_dir.parent / "session" / "gt" / "garment.json").read_text())["target"]
    out = tmp_path / "o.mp4"
    r = run_inprocess(["garment", "render", fit_dir, "--garment", target["name"], "--texture", target["pattern"],
                       "--seed", str(target["seed"] + 1), "--out", out, "--no-flow", "--no-rbf"], capfd)
    assert_clean_error(r, 0, "")
    r = run_inprocess(["eval", "garment", fit_dir], capfd)
    assert_clean_error(r, 2, f"--seed {target['seed']}")
    r = run_inprocess(["garment", "render", fit_dir, "--garment", target["name"], "--texture", target["pattern"],
                       "--seed", str(target["seed"]), "--out", out, "--no-flow", "--no-rbf"], capfd)
    r = run_inprocess(["eval", "garment", fit_dir], capfd)
    assert_clean_error(r, 0, "")
    scores = json.loads(r.stdout)
    assert scores["garment_iou"] > 0.8 and scores["psnr_person"] > 18, scores
