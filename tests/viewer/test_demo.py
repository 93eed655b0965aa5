"""The demo end to end: every available stage runs, bodies are measured, the report loads and draws."""

import json

import pytest

from bodystudio.cli.demo import run_demo


@pytest.mark.slow
def test_demo_runs_the_available_stages_and_writes_a_report(tmp_path, chromium):
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
    if status.get("reconstruct") == "done":
        assert (out / "session" / "reconstruct" / "frames.json").is_file()
        assert "Error per frame" in report.read_text()
