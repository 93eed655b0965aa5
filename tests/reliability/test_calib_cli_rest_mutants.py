"""``bodystudio calibrate`` after its checks (the run writer, the uncertainty verdict, the table), ``calib export /
import``, ``synth calibration`` and ``eval calib``, with the detection, the solve and the writers replaced by
stand-ins (mutNN; mutII's test_calib_cli_mutants.py covers the refusals before the run writer).

What is checked against hand-written values: which files the run publishes (read back from disk, the report with
json), the rejected report of an uncertain rig and nothing else, the accepted verdict and its warnings, the stale
rejected report removed, the table's rows, the options handed to the exporters and scorers. About a second.
"""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from bodystudio.calib.board import CharucoBoardSpec, save_board_json
from bodystudio.cli.main import main

SPEC = CharucoBoardSpec(5, 4, 0.04, 0.03)


def _run(*args) -> tuple[int, str, str]:
    with CliRunner().isolation() as (out, err, _):
        code = main([str(a) for a in args])
        return code, out.getvalue().decode(), err.getvalue().decode()


def _capture(root: Path) -> Path:
    for cam in ("cam_00", "cam_01"):
        (root / cam).mkdir(parents=True)
        cv2.imwrite(str(root / cam / "00000.png"), np.full((24, 32), 128, np.uint8))
    save_board_json(root / "board.json", SPEC)
    return root


class Uncertainty:
    def __init__(self, ok=True):
        self._ok = ok
        self.cams = {"cam_00": SimpleNamespace(center_sigma_mm=0.1234, focal_sigma_pct=0.01234,
                                               coverage=SimpleNamespace(fraction=0.456), verdict="ok"),
                     "cam_01": SimpleNamespace(center_sigma_mm=3.456, focal_sigma_pct=0.6789,
                                               coverage=SimpleNamespace(fraction=0.7), verdict="uncertain")}

    @property
    def ok(self):
        return self._ok

    def __getitem__(self, name):
        return self.cams[name]

    def advice(self):
        return ["cam_01: capture the board nearer its corners", "cam_01: more views"]

    def summary(self):
        return "cam_01 uncertain: centre sigma 3.5 mm"


@pytest.fixture
def api(monkeypatch):
    import bodystudio.calib.calibrate as calibrate_module
    import bodystudio.calib.io as io
    import bodystudio.calib.observations as observations
    import bodystudio.calib.render as render
    import bodystudio.calib.uncertainty as uncertainty
    import bodystudio.cli.calib as calib_cli
    import bodystudio.geometry.camera as camera

    ns = SimpleNamespace(log=[], ok=True, tasks=[])
    monkeypatch.setenv("COLUMNS", "200")  # the table's Console() reads its width from here

    def detect(folder, spec, progress=None):
        ns.log.append(("detect", folder, spec.squares_x, progress is not None))
        return ["o"] * 17, {"cam_00": {"frames": 1}}

    def solve(obs, spec, options):
        assert spec.squares_x == 5 and spec.squares_y == 4  # the board read from board.json
        ns.log.append(("solve", len(obs), options.distortion_terms, options.floor_frame, options.reference_camera))
        return SimpleNamespace(
            report=lambda: {"cameras": {"cam_00": {"n_views": 3, "n_corners": 40, "n_outliers": 1,
                                                   "reproj_rms_px": 0.12345},
                                        "cam_01": {"n_views": 2, "n_corners": 30, "n_outliers": 2,
                                                   "reproj_rms_px": 0.5}},
                            "n_outliers": 3, "uncertainty": {"verdict": "ok" if ns.ok else "uncertain"}},
            uncertainty=Uncertainty(ns.ok), rig={"cam_00": SimpleNamespace(fx=800.04, fy=801.06),
                                                 "cam_01": SimpleNamespace(fx=700.0, fy=700.0)},
            seconds=1.25, world_frame="floor board", rms_px=0.45678)

    def write_png(path, image):
        ns.log.append(("png", Path(path).name, image))
        Path(path).write_bytes(b"PNG " + str(image).encode())

    def save_cameras(path, rig):
        ns.log.append(("cameras", Path(path).name, sorted(rig)))
        Path(path).write_text('{"cameras": []}')

    def export(kind):
        def write(folder, rig):
            assert sorted(rig) == ["cam_00", "cam_01"] and rig["cam_00"].fx == 800.04  # the calibrated rig
            ns.log.append((kind, Path(folder).name))
            Path(folder).mkdir(parents=True, exist_ok=True)
            (Path(folder) / f"{kind}.txt").write_text(kind)
        return write

    class Progress(calib_cli.Progress):
        def add_task(self, description, **kw):
            ns.tasks.append(("add", description, kw))
            return super().add_task(description, **kw)

        def update(self, task, **kw):
            ns.tasks.append(("update", kw))
            return super().update(task, **kw)

    monkeypatch.setattr(observations, "detect_capture", detect)
    monkeypatch.setattr(calibrate_module, "calibrate_cameras", solve)
    monkeypatch.setattr(render, "write_png", write_png)
    monkeypatch.setattr(uncertainty, "coverage_image", lambda u: f"coverage ok={u.ok}")
    monkeypatch.setattr(camera, "save_cameras_json", save_cameras)
    monkeypatch.setattr(io, "save_easymocap_yaml", export("easymocap"))
    monkeypatch.setattr(io, "save_colmap_model", export("colmap"))
    monkeypatch.setattr(calib_cli, "Progress", Progress)
    return ns


def _files(folder: Path) -> list[str]:
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*") if p.is_file())


def test_calibrate_publishes_the_rig_its_coverage_and_the_report(tmp_path, api):
    cap = _capture(tmp_path / "cap")
    out = tmp_path / "est" / "c.json"
    code, stdout, stderr = _run("calibrate", cap, "--out", out, "--distortion-terms", 5)
    assert code == 0, (stdout, stderr)
    assert api.log == [("detect", cap, 5, True), ("solve", 17, 5, 0, None), ("cameras", "c.json", ["cam_00", "cam_01"]),
                       ("png", "c.coverage.png", "coverage ok=True")]
    assert api.tasks == [("add", "bundle adjustment", {"total": None}), ("update", {"total": 1, "completed": 1})]
    assert _files(tmp_path / "est") == ["c.coverage.png", "c.json", "c.report.json"]
    assert (tmp_path / "est" / "c.coverage.png").read_bytes() == b"PNG coverage ok=True"
    report = json.loads((tmp_path / "est" / "c.report.json").read_text())
    assert report["detections"] == {"cam_00": {"frames": 1}} and report["uncertainty"] == {"verdict": "ok"}
    assert report["n_outliers"] == 3 and report["run"]["command"] == "bodystudio calibrate"
    assert report["run"]["producer"] == {"capture": str(cap)}
    rows = [ln.replace("│", " ").split() for ln in stdout.splitlines() if "│" in ln]
    assert rows[0] == ["cam_00", "3", "40", "1", "0.123", "800.0", "801.1", "0.12", "0.012", "46", "ok"]
    assert rows[1] == ["cam_01", "2", "30", "2", "0.500", "700.0", "700.0", "3.46", "0.679", "70", "uncertain"]
    cells = [[c.strip() for c in ln.split("│")[1:-1]] for ln in stdout.splitlines() if "│" in ln]
    assert cells[2] == ["all", "", "17", "3", "0.457", "", "", "", "", "", "ok"]  # each figure in its column
    title = " ".join(ln.strip() for ln in stdout.splitlines()[:next(k for k, ln in enumerate(stdout.splitlines())
                                                                     if "┏" in ln)])
    assert title == "calibration: 17 corners, 3 outliers, 1.2 s, world = floor board"
    header = " ".join(ln.replace("┃", " ") for ln in stdout.splitlines() if "┃" in ln).split()
    assert header == ["camera", "views", "corners", "outliers", "RMS", "px", "fx", "fy", "centre", "sd", "mm", "focal",
                      "sd", "%", "coverage", "%", "verdict"]
    assert stdout.endswith(f"wrote {out}\n") and stderr == ""
    row = next(ln for ln in stdout.splitlines() if "│" in ln and ln.split("│")[1].strip() == "all").split("│")
    assert row[1].endswith(" all ") and row[1].startswith("  ")  # every column right-justified


def test_calibrate_exports_in_the_same_run(tmp_path, api):
    cap = _capture(tmp_path / "cap")
    out = tmp_path / "est" / "cameras.json"
    code, stdout, stderr = _run("calibrate", cap, "--out", out, "--easymocap", tmp_path / "emc", "--colmap",
                                tmp_path / "cm", "--reference-camera", "cam_01")
    assert code == 0, (stdout, stderr)
    assert api.log[1] == ("solve", 17, 4, None, "cam_01")
    assert [e[0] for e in api.log[2:]] == ["cameras", "png", "easymocap", "colmap"]
    assert _files(tmp_path / "emc") == ["easymocap.txt"] and _files(tmp_path / "cm") == ["colmap.txt"]
    report = json.loads((tmp_path / "est" / "cameras.report.json").read_text())
    assert set(report["run"]["files"]) >= {"cameras.json", "cameras.coverage.png", "../emc/easymocap.txt",
                                           "../cm/colmap.txt"}


def test_accepted_warnings_are_printed_as_given(tmp_path, api, monkeypatch):
    """Advice is plain text: no markup, no highlighting, never wrapped (on a colour terminal too)."""
    from rich.console import Console

    import bodystudio.cli.calib as calib_cli

    api.ok = False
    long = "cam_01: [bold]12 views[/bold] of 40 cover the image's corners; capture " + "more " * 12 + "views"
    monkeypatch.setattr(Uncertainty, "advice", lambda self: [long])
    monkeypatch.setattr(calib_cli, "console", Console(stderr=True, force_terminal=True, color_system="standard",
                                                      width=60))
    cap = _capture(tmp_path / "cap")
    code, stdout, stderr = _run("calibrate", cap, "--out", tmp_path / "est" / "c.json", "--accept-uncertain")
    assert code == 0, stderr
    assert f"warning: {long}\n" in stderr and "\x1b[" not in stderr.split("warning:")[1].split("\n")[0]


def test_an_uncertain_rig_writes_only_its_rejected_report(tmp_path, api):
    api.ok = False
    cap = _capture(tmp_path / "cap")
    out = tmp_path / "est" / "c.json"
    code, stdout, stderr = _run("calibrate", cap, "--out", out, "--easymocap", tmp_path / "emc")
    assert code == 2 and stdout == ""
    assert stderr == (f"error: cam_01 uncertain: centre sigma 3.5 mm; {out} not written (report: "
                      f"{tmp_path / 'est' / 'c.rejected.json'}); capture those views or pass --accept-uncertain\n")
    assert _files(tmp_path / "est") == ["c.rejected.coverage.png", "c.rejected.json"]
    assert not (tmp_path / "emc").exists() or _files(tmp_path / "emc") == []
    rejected = json.loads((tmp_path / "est" / "c.rejected.json").read_text())
    assert rejected["uncertainty"] == {"verdict": "uncertain"} and rejected["detections"] == {"cam_00": {"frames": 1}}
    assert (tmp_path / "est" / "c.rejected.coverage.png").read_bytes() == b"PNG coverage ok=False"
    # accepted: the verdict says so, each advice line is a warning, and the stale rejected report goes
    code, stdout, stderr = _run("calibrate", cap, "--out", out, "--accept-uncertain")
    assert code == 0, (stdout, stderr)
    assert stderr == ("warning: cam_01: capture the board nearer its corners\nwarning: cam_01: more views\n")
    assert _files(tmp_path / "est") == ["c.coverage.png", "c.json", "c.report.json"]
    report = json.loads((tmp_path / "est" / "c.report.json").read_text())
    assert report["uncertainty"] == {"verdict": "uncertain (accepted)"}
    assert [ln.replace("│", " ").split() for ln in stdout.splitlines() if " all " in ln][0][-3:] == [
        "0.457", "uncertain", "(accepted)"]


# ------------------------------------------------------------------------------------------------ export / import

@pytest.fixture
def rig_io(monkeypatch):
    import bodystudio.calib.io as io
    import bodystudio.geometry.camera as camera

    ns = SimpleNamespace(log=[])
    monkeypatch.setattr(camera, "load_cameras_json", lambda p: ns.log.append(("load", Path(p).name)) or "RIG")
    monkeypatch.setattr(camera, "save_cameras_json", lambda p, rig: ns.log.append(("save", Path(p).name, rig)))
    monkeypatch.setattr(io, "save_easymocap_yaml", lambda d, rig: ns.log.append(("easymocap", Path(d).name, rig)))
    monkeypatch.setattr(io, "save_colmap_model", lambda d, rig: ns.log.append(("colmap", Path(d).name, rig)))
    monkeypatch.setattr(io, "load_easymocap_yaml", lambda d: ns.log.append(("read easymocap", Path(d).name)) or
                        ["a", "b"])
    monkeypatch.setattr(io, "load_colmap_model", lambda d: ns.log.append(("read colmap", Path(d).name)) or ["a"])
    return ns


def test_export_writes_each_model_asked_for(tmp_path, rig_io):
    code, out, err = _run("calib", "export", tmp_path / "c.json", "--easymocap", tmp_path / "e")
    assert code == 0 and out == f"wrote {tmp_path / 'e'}/intri.yml, extri.yml\n", err
    assert rig_io.log == [("load", "c.json"), ("easymocap", "e", "RIG")]
    code, out, err = _run("calib", "export", tmp_path / "c.json", "--colmap", tmp_path / "m")
    assert code == 0 and out == f"wrote COLMAP model {tmp_path / 'm'}\n", err
    assert rig_io.log[2:] == [("load", "c.json"), ("colmap", "m", "RIG")]


def test_import_reads_easymocap_or_colmap(tmp_path, rig_io):
    (tmp_path / "emc").mkdir()
    (tmp_path / "emc" / "intri.yml").write_text("%YAML:1.0")
    code, out, err = _run("calib", "import", tmp_path / "emc", "--out", tmp_path / "a.json")
    assert code == 0 and out == f"wrote {tmp_path / 'a.json'} (2 cameras)\n", err
    assert rig_io.log == [("read easymocap", "emc"), ("save", "a.json", ["a", "b"])]
    (tmp_path / "cm").mkdir()
    (tmp_path / "cm" / "intri.yml").mkdir()  # a folder of that name is not EasyMocap's file
    code, out, err = _run("calib", "import", tmp_path / "cm", "--out", tmp_path / "b.json")
    assert code == 0 and out == f"wrote {tmp_path / 'b.json'} (1 cameras)\n", err
    assert rig_io.log[2:] == [("read colmap", "cm"), ("save", "b.json", ["a"])]


# ------------------------------------------------------------------------------------------------ synth calibration

def test_synth_calibration_defaults_and_options(tmp_path, monkeypatch):
    import bodystudio.calib.synthetic as synthetic

    calls = []

    def write(out, cameras, poses, seed, width, height, progress=None, kinect=None):
        calls.append((Path(out).name, cameras, poses, seed, width, height, progress is not None, kinect))
        return {"cameras": cameras, "poses": poses}

    monkeypatch.setattr(synthetic, "write_synthetic_calibration", write)
    code, out, err = _run("synth", "calibration", tmp_path / "c")
    assert code == 0, err
    assert calls == [("c", 10, 30, 0, 1280, 960, True, None)]
    assert out == '{"cameras": 10, "poses": 30}\n'
    code, out, err = _run("synth", "calibration", tmp_path / "d", "--cameras", "3", "--poses", "5", "--seed", "0",
                          "--width", "640", "--height", "480", "--kinect", "v1")
    assert code == 0 and calls[1] == ("d", 3, 5, 0, 640, 480, True, "v1"), err
    code, out, err = _run("synth", "calibration", tmp_path / "e", "--seed", "-1")
    assert code == 2 and len(calls) == 2


# ------------------------------------------------------------------------------------------------ eval calib

@pytest.fixture
def scorers(monkeypatch):
    import bodystudio.calib.evaluate as evaluate
    import bodystudio.calib.io as io
    import bodystudio.capture.session as session
    import bodystudio.geometry.camera as camera

    ns = SimpleNamespace(log=[])
    monkeypatch.setattr(io, "check_calibration_outputs", lambda est, rep: ns.log.append(("check", Path(est).name,
                                                                                          rep)) or {"rep": 1})
    monkeypatch.setattr(camera, "load_cameras_json", lambda p: f"RIG {Path(p).name}")
    monkeypatch.setattr(evaluate, "evaluate_calibration", lambda est, gt, rep, align: ns.log.append(
        ("score", est, gt, rep, align)) or {"overall": {"center_err_mm": 1.5}})
    monkeypatch.setattr(session, "load_kinect_calibration", lambda p: f"KINECT {Path(p).name}")
    monkeypatch.setattr(evaluate, "evaluate_rgbd_sensor", lambda est, gt: ns.log.append(("kinect", est, gt)) or
                        {"depth_err_mm": 2.0})
    return ns


def test_eval_calib_defaults_options_and_json(tmp_path, scorers):
    code, out, err = _run("eval", "calib", tmp_path / "e.json", tmp_path / "g.json")
    assert code == 0, err
    assert scorers.log == [("check", "e.json", None), ("score", "RIG e.json", "RIG g.json", {"rep": 1}, "floor")]
    assert out == '{\n  "overall": {\n    "center_err_mm": 1.5\n  }\n}\n'
    code, out, err = _run("eval", "calib", tmp_path / "e.json", tmp_path / "g.json", "--report", tmp_path / "r.json",
                          "--align", "similarity", "--kinect", tmp_path / "ke.json", "--kinect", tmp_path / "kg.json")
    assert code == 0, err
    assert scorers.log[2:] == [("check", "e.json", tmp_path / "r.json"),
                               ("score", "RIG e.json", "RIG g.json", {"rep": 1}, "similarity"),
                               ("kinect", "KINECT ke.json", "KINECT kg.json")]
    assert json.loads(out) == {"overall": {"center_err_mm": 1.5}, "kinect": {"depth_err_mm": 2.0}}
    code, out, err = _run("eval", "calib", tmp_path / "e.json", tmp_path / "g.json", "--kinect", tmp_path / "k.json")
    assert code == 2 and out == "" and err == ("error: --kinect needs the estimated and the ground-truth "
                                               "calibration.json: give it twice\n")


@pytest.mark.parametrize("option, name", [("--easymocap", "intri.yml"), ("--easymocap", "extri.yml"),
                                          ("--colmap", "cameras.txt"), ("--colmap", "images.txt"),
                                          ("--colmap", "points3D.txt")])
def test_calibrate_refuses_an_export_folder_whose_file_is_a_folder(tmp_path, api, option, name):
    """Each file the export writes is checked before the run: a folder in its place is refused, naming it."""
    cap = _capture(tmp_path / "cap")
    target = tmp_path / "model"
    (target / name).mkdir(parents=True)
    code, stdout, stderr = _run("calibrate", cap, "--out", tmp_path / "est" / "c.json", option, target)
    assert (code, stdout) == (2, "")
    assert stderr == f"error: {option} folder {target / name}: is a folder; give a file path\n"
    assert api.log == [] and not (tmp_path / "est").exists()
    # a folder of another export's file name is not in the way (the COLMAP check refuses other files itself)
    if option == "--easymocap":
        (tmp_path / "m2" / "images.txt").mkdir(parents=True)
        code, stdout, stderr = _run("calibrate", cap, "--out", tmp_path / "est" / "c.json", option, tmp_path / "m2")
        assert code == 0, stderr


def test_calibrate_progress_goes_to_stderr_and_only_on_a_terminal(tmp_path, api, monkeypatch):
    import bodystudio.cli.calib as calib_cli

    made = []
    base = calib_cli.Progress

    class Recording(base):
        def __init__(self, *columns, **kwargs):
            made.append((columns, kwargs))
            super().__init__(*columns, **kwargs)

    monkeypatch.setattr(calib_cli, "Progress", Recording)
    cap = _capture(tmp_path / "cap")
    assert _run("calibrate", cap, "--out", tmp_path / "a" / "c.json")[0] == 0
    (columns, kwargs), = made
    assert [type(c).__name__ for c in columns] == ["TextColumn", "BarColumn", "MofNCompleteColumn",
                                                   "TimeElapsedColumn"]
    assert columns[0].text_format == "{task.description}"
    assert kwargs == {"console": calib_cli.console, "transient": True, "disable": True}
    assert calib_cli.console.stderr is True
    monkeypatch.setattr(type(calib_cli.console), "is_terminal", property(lambda self: True))
    assert _run("calibrate", cap, "--out", tmp_path / "b" / "c.json")[0] == 0
    assert made[1][1]["disable"] is False
