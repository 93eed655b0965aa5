"""The demo end to end: every available stage runs, bodies are measured, the report loads and draws."""

import json

import numpy as np
import pytest

from bodystudio.demo import run_demo


@pytest.fixture(scope="module")
def full_demo(tmp_path_factory):
    """The whole demo once for the module's slow tests (run, report, the report loaded in headless Chromium).

    The same code path on a smaller scan and template (the rig fit dominates the demo's time), one shape round
    on one reference frame of a 3-frame garment clip, and the muscle and mirror stages at the sizes their own
    tests below check them at (each ran its stage alone before): a 4-frame arm sequence with a small arm model,
    a 13-frame mirror session.
    """
    import functools

    import bodystudio.demo as demo
    import bodystudio.garment.fit as garment_fit

    from .conftest import run_chromium

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(demo, "RIG_TEMPLATE", "2k")
        mp.setattr(demo, "RIG_SCAN_VERTICES", 8000)
        mp.setattr(demo, "GARMENT_FRAMES", 3)
        mp.setattr(demo, "GARMENT_RESOLUTION", (120, 160))
        mp.setattr(garment_fit, "estimate_shape",
                   functools.partial(garment_fit.estimate_shape, n_reference=1, rounds=0))
        mp.setattr(demo, "MUSCLE_FRAMES", 4)
        mp.setattr(demo, "MUSCLE_TRAINING", {"n_subjects": 2, "n_shapes": 1, "n_poses": 4})
        mp.setattr(demo, "MUSCLE_POPULATION", 4)
        mp.setattr(demo, "MIRROR_FRAMES", 13)
        out = tmp_path_factory.mktemp("demo") / "demo"
        report, stages = run_demo(out, cameras=4, frames=2, resolution=(160, 120))
    page = run_chromium(report, size=(1200, 1100), screenshot=False)  # skips where Chromium is not installed
    return out, report, stages, page


@pytest.mark.slow
def test_demo_runs_the_available_stages_and_writes_a_report(full_demo):
    out, report, stages, page = full_demo
    status = {r["stage"]: r["status"] for r in stages}
    assert status["bodies"] == "done"
    assert "failed" not in status.values(), stages
    measured = json.loads((out / "bodies" / "measurements.json").read_text())["bodies"]
    assert set(measured) >= {"female", "male"}
    assert 1.4 < measured["female"]["stature_m"] < measured["male"]["stature_m"] < 2.0
    assert (out / "bodies" / "male.ply").is_file()
    assert page["console"] == [], page["console"]
    assert 'data-viewer-status="ok"' in page["dom"]
    text = report.read_text()
    if status.get("reconstruct") == "done":
        assert (out / "session" / "reconstruct" / "frames.json").is_file()
        assert "Error per frame" in text and "Error histogram" in text
    if status.get("calibrate") == "done":
        assert "Calibration residuals" in text
    if status.get("rig") == "done":
        assert (out / "rig" / "avatar.glb").is_file() and "Solver convergence" in text
    assert status["muscle"] == "done"
    assert (out / "muscle" / "capture" / "arm.glb").is_file() and "arm-muscle capture" in text
    assert status["garment"] == "done"
    scores = json.loads((out / "garment_fit" / "eval.json").read_text())
    assert scores["stature_err_mm"] < 10 and scores["garment_iou"] > 0.5, scores
    assert (out / "garment.mp4").stat().st_size > 0 and "Garment: before / after" in text


def test_demo_bodies_only_measures_and_reports(tmp_path, drawn):
    from PIL import Image

    out = tmp_path / "demo"
    report, stages = run_demo(out, skip=("session", "calibrate", "reconstruct", "rig", "muscle", "mirror", "garment"),
                              with_3d=False)
    assert [r["status"] for r in stages] == ["done"] + ["skipped"] * 7
    measured = json.loads((out / "bodies" / "measurements.json").read_text())["bodies"]
    assert len(measured) == 5
    assert 1.4 < measured["female"]["stature_m"] < measured["male"]["stature_m"] < 2.0
    lineup = np.asarray(Image.open(out / "screenshots" / "bodies.png").convert("RGB"))
    # Five bodies side by side: in the lowest quarter of the skin-coloured rows (legs) the skin splits
    # into at least five separate runs of columns. The title (top rows) is left out.
    skin = drawn(lineup) & (lineup.mean(-1) > 120)
    skin[: lineup.shape[0] // 12] = False
    rows = np.flatnonzero(skin.any(1))
    legs = skin[rows[0] + 3 * (rows[-1] - rows[0]) // 4: rows[-1]].any(0)
    assert np.count_nonzero(np.diff(legs.astype(int)) == 1) >= 5
    text = report.read_text()
    assert "stature_m" in text and "subject_02" in text


def test_demo_bad_skip_is_one_line(tmp_path):
    from bodystudio.errors import InputError

    with pytest.raises(InputError, match="not a demo stage"):
        run_demo(tmp_path / "d", skip=("nope",))
    assert not (tmp_path / "d").exists()


def _raise_import(ctx):
    from bodystudio.not_a_module import nothing  # noqa: F401  (a stage whose module is missing)


def test_demo_stage_that_fails_to_import_is_a_failure_with_exit_2(tmp_path, monkeypatch, capsys):
    import bodystudio.demo as demo
    from bodystudio.cli.main import main

    monkeypatch.setattr(demo, "STAGES", [("session", _raise_import), ("reconstruct", demo.stage_reconstruct)])
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out), "--no-3d"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "stages failed: session, reconstruct" in err[0] and "ModuleNotFoundError" in err[0]
    rows = json.loads((out / "demo.json").read_text())["stages"]
    assert [r["status"] for r in rows] == ["failed", "failed"]
    assert "needs the session stage, which failed" in rows[1]["summary"]
    assert (out / "report.html").is_file()


def test_demo_stage_needing_a_skipped_stage_is_skipped(tmp_path, monkeypatch):
    import bodystudio.demo as demo

    monkeypatch.setattr(demo, "STAGES", [("session", _raise_import), ("reconstruct", demo.stage_reconstruct)])
    _, stages = run_demo(tmp_path / "d", skip=("session",), with_3d=False)
    assert [r["status"] for r in stages] == ["skipped", "skipped"]
    assert "needs the session stage, which was skipped" in stages[1]["summary"]


def test_first_frame_timing_is_reported_apart():
    from bodystudio.demo import split_first_frame, timing_text

    t = split_first_frame([3956.0, 270.0, 264.0])
    assert t == {"first_frame_ms": 3956.0, "ms_per_frame": 267.0}
    assert timing_text(t).startswith("267 ms per frame after the first frame 3956 ms")
    assert split_first_frame([500.0])["ms_per_frame"] is None


@pytest.mark.slow
def test_demo_muscle_stage_captures_scores_and_reports(full_demo):
    """The muscle stage of the whole demo (4 frames, a 2-subject model of 4 poses, population 4)."""
    out, report, stages, page = full_demo
    assert {r["stage"]: r for r in stages}["muscle"]["status"] == "done", stages
    scores = json.loads((out / "muscle" / "eval.json").read_text())
    assert 0 < scores["median_mm"] < 50 and len(scores["per_frame"]) == 4
    assert (out / "screenshots" / "arm_capture.png").is_file()
    text = report.read_text()
    assert "Error per frame (muscle/eval.json)" in text and "front_median_mm" in text
    # the capture's params.json and manifest are data, not metrics tables (the mirror run's own metadata
    # says "similarity" in this report, so the capture's keys and files are looked for instead)
    assert "muscle/capture/params.json" not in text and "muscle/capture/manifest.json" not in text
    assert "template_key" not in text
    assert page["console"] == [], page["console"]
    assert 'data-viewer-status="ok"' in page["dom"]


@pytest.mark.slow
def test_demo_mirror_stage_synthesises_fits_runs_scores_and_reports(full_demo):
    """The demo's mirror stage on a 13-frame session (3 with the actor): init, run and eval ran, the report shows
    before/after. Slow since it shares the whole demo's run (it ran the mirror stage alone before, ~20 s)."""
    out, report, stages, _ = full_demo
    row = {r["stage"]: r for r in stages}["mirror"]
    assert row["status"] == "done", stages
    assert "warp_iou" in row["summary"] and "init stature" in row["summary"]
    scores = json.loads((out / "mirror_session" / "mirror" / "eval.json").read_text(),
                        parse_constant=lambda c: pytest.fail(f"non-strict JSON constant {c}"))
    assert scores["frames_scored"] == 3 and scores["warp_iou"] > scores["warp_iou_unwarped"]
    assert scores["fg_iou"] > scores["fg_iou_raw"]
    assert (out / "mirror.mp4").stat().st_size > 0 and (out / "screenshots" / "mirror.png").is_file()
    text = report.read_text()
    assert "Mirror: before / after" in text and text.count('alt="mirror_session frame') == 3
