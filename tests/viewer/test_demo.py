"""The demo end to end: every available stage runs, bodies are measured, the report loads and draws."""

import json

import numpy as np
import pytest

from bodystudio.cli.demo import run_demo


@pytest.mark.slow
def test_demo_runs_the_available_stages_and_writes_a_report(tmp_path, chromium, monkeypatch):
    import bodystudio.cli.demo as demo

    # The same code path on a smaller scan and template: the rig fit dominates the demo's time.
    monkeypatch.setattr(demo, "RIG_TEMPLATE", "2k")
    monkeypatch.setattr(demo, "RIG_SCAN_VERTICES", 8000)
    out = tmp_path / "demo"
    report, stages = run_demo(out, cameras=4, frames=2, resolution=(160, 120))
    status = {r["stage"]: r["status"] for r in stages}
    assert status["bodies"] == "done"
    assert "failed" not in status.values(), stages
    measured = json.loads((out / "bodies" / "measurements.json").read_text())["bodies"]
    assert set(measured) >= {"female", "male"}
    assert 1.4 < measured["female"]["stature_m"] < measured["male"]["stature_m"] < 2.0
    assert (out / "bodies" / "male.ply").is_file()
    page = chromium(report, size=(1200, 1100))
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


def test_demo_bodies_only_measures_and_reports(tmp_path, drawn):
    from PIL import Image

    out = tmp_path / "demo"
    report, stages = run_demo(out, skip=("session", "calibrate", "reconstruct", "rig"), with_3d=False)
    assert [r["status"] for r in stages] == ["done", "skipped", "skipped", "skipped", "skipped"]
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
