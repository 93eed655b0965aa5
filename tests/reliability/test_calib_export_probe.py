"""`calibrate --easymocap / --colmap DIR` checks the files the export writes, not a probe named ``x`` (mutII's
found-not-fixed item: an export folder holding a folder named ``x`` was refused as "DIR/x: is a folder"); a folder in
the place of one of the exported files is refused naming it, before any work."""

import pytest

from tests.reliability.test_calib_cli_mutants import _capture, _files, _refused


@pytest.fixture
def stand_in_solve(monkeypatch):
    import bodystudio.calib.calibrate as calibrate_module
    import bodystudio.calib.observations as observations_module
    from bodystudio.errors import SessionError

    def solve(obs, spec, options):
        raise SessionError("stand-in solve")

    monkeypatch.setattr(observations_module, "detect_capture", lambda folder, spec, progress=None: ("obs", {}))
    monkeypatch.setattr(calibrate_module, "calibrate_cameras", solve)


@pytest.mark.parametrize(("option", "name"), [("--easymocap", "intri.yml"), ("--easymocap", "extri.yml"),
                                              ("--colmap", "cameras.txt"), ("--colmap", "points3D.txt")])
def test_a_folder_where_an_exported_file_goes_is_refused(tmp_path, stand_in_solve, option, name):
    cap = _capture(tmp_path / "cap")
    (tmp_path / "exp" / name).mkdir(parents=True)
    out = tmp_path / "est" / "cameras.json"
    line = _refused("calibrate", cap, "--out", out, option, tmp_path / "exp")
    assert line.startswith(f"error: {option} folder {tmp_path / 'exp' / name}: ") and "is a folder" in line
    assert not out.parent.exists()


def test_an_easymocap_folder_holding_a_folder_named_x_is_accepted(tmp_path, stand_in_solve):
    cap = _capture(tmp_path / "cap")
    (tmp_path / "exp" / "x").mkdir(parents=True)
    out = tmp_path / "est" / "cameras.json"
    assert _refused("calibrate", cap, "--out", out, "--easymocap", tmp_path / "exp") == "error: stand-in solve"
    assert _files(tmp_path / "exp") == ["x"] and not out.exists()
