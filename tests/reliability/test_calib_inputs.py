"""`bodystudio calibrate`: bad options and under-constrained captures give one line and exit 2, and
leave no rig (or the previous complete one) behind; --accept-uncertain writes the rig with its sigmas."""

import json

import pytest

from bodystudio.calib.synthetic import write_synthetic_calibration
from bodystudio.cli.main import main


@pytest.fixture(scope="module")
def weak_capture(tmp_path_factory):
    """Issue 16's case: 4 cameras x 12 poses at 640x480, seed 0 (0.41 px RMS, centres 70 mm off)."""
    cap = tmp_path_factory.mktemp("calib") / "cap"
    write_synthetic_calibration(cap, 4, 12, seed=0, width=640, height=480)
    return cap


def _run(args, capsys):
    code = main(["calibrate", *map(str, args)])
    err = capsys.readouterr().err.strip()
    return code, err


def _one_line(err):
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1, err
    return lines[0]


@pytest.mark.parametrize(("extra", "phrase"), [
    (["--reference-camera", "cam_99"], "--reference-camera cam_99: no such camera"),
    (["--floor-frame", "99"], "--floor-frame 99: no camera has this frame"),
    (["--distortion-terms", "7"], "--distortion-terms must be 4"),
    (["--board", "/nonexistent/board.json"], "board description not found"),
])
def test_bad_options_are_one_line(weak_capture, tmp_path, capsys, extra, phrase):
    out = tmp_path / "est" / "cameras.json"
    code, err = _run([weak_capture, "--out", out, *extra], capsys)
    assert code == 2
    assert phrase in _one_line(err)
    assert not out.exists()


def test_uncertain_calibration_exits_2_and_keeps_the_previous_rig(weak_capture, tmp_path, capsys):
    out = tmp_path / "est" / "cameras.json"
    out.parent.mkdir()
    out.write_text('{"previous": true}')
    code, err = _run([weak_capture, "--out", out], capsys)
    assert code == 2
    line = _one_line(err)
    assert line.startswith("error: calibration uncertain") and "--accept-uncertain" in line
    assert "centre sigma" in line and "add" in line
    assert out.read_text() == '{"previous": true}'  # untouched: nothing a later command reads changed
    assert not (tmp_path / "est" / "cameras.report.json").exists()
    rejected = json.loads((tmp_path / "est" / "cameras.rejected.json").read_text())
    unc = rejected["uncertainty"]
    assert unc["verdict"] == "uncertain"
    assert all(c["center_sigma_mm"] > 2.0 for c in unc["cameras"].values())
    assert (tmp_path / "est" / "cameras.rejected.coverage.png").is_file()


def test_accept_uncertain_writes_the_rig_with_its_sigmas(weak_capture, tmp_path, capsys):
    out = tmp_path / "est" / "cameras.json"
    code, err = _run([weak_capture, "--out", out, "--accept-uncertain"], capsys)
    assert code == 0, err
    assert out.is_file() and (tmp_path / "est" / "cameras.coverage.png").is_file()
    report = json.loads((tmp_path / "est" / "cameras.report.json").read_text())
    assert report["uncertainty"]["verdict"] == "uncertain (accepted)"
    cam = report["uncertainty"]["cameras"]["cam_00"]
    for key in ("fx_sigma_px", "fy_sigma_px", "cx_sigma_px", "cy_sigma_px", "center_sigma_mm", "focal_sigma_pct"):
        assert cam[key] > 0
    assert 0 < cam["coverage"]["fraction"] <= 1 and cam["advice"].startswith("cam_00: centre sigma")
    assert err.count("warning: cam_") == 4
