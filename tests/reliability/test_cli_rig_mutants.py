"""``bodystudio rig SCAN --out A.glb`` and ``synth scan`` through typer's CliRunner with the API replaced by spies
(mutNN).

``rig_to_files`` must hand every option to the fit / weights / reshape / export calls unchanged, record the scan
report, template, verdict and timings in the avatar's metadata, write through one :class:`RunWriter` on the
avatar's layout, and refuse a bad output path (whole message) before any work. The expected calls are written out
by hand; no scan is fitted: the file runs in about a second.
"""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import pytest

from tests.reliability.cli_spies import invoke as _invoke
from tests.reliability.cli_spies import refused as _refused


class Clock:
    def __init__(self, start=10.0, step=1.25):
        self.now, self.step = start, step

    def perf_counter(self):
        t = self.now
        self.now += self.step
        return t


class Writer:
    made = []

    def __init__(self, layout, command, inputs):
        self.layout, self.command, self.inputs, self.exited = layout, command, inputs, 0
        Writer.made.append(self)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.exited += 1
        return False


@pytest.fixture
def rig_api(monkeypatch, tmp_path):
    """The rig API replaced by spies writing their calls to ``ns.log`` (in call order)."""
    import rich.progress

    import bodystudio.cli.rig as cli_rig
    import bodystudio.register.scan as scan_mod
    import bodystudio.rig.evaluate as evaluate
    import bodystudio.rig.export as export
    import bodystudio.rig.pipeline as pipeline
    import bodystudio.rig.plausibility as plausibility
    import bodystudio.rig.reshape as reshape
    import bodystudio.runfolder as runfolder

    monkeypatch.chdir(tmp_path)
    Path("scan.ply").write_text("ply")
    Writer.made = []
    ns = SimpleNamespace(log=[], fit="FIT", verdict={"verdict": "plausible", "warnings": []}, progress=[])
    mesh = SimpleNamespace(vertices="V", faces="F")
    report = SimpleNamespace(as_dict=lambda: {"units": "mm"})
    ns.avatar = SimpleNamespace(metadata={}, bone_names=["root", "spine"])
    ns.reshaped = SimpleNamespace(metadata={}, bone_names=["root", "spine"])

    def load_scan(path):
        ns.log.append(("load_scan", path))
        return mesh, report

    def rig_scan(m, model, weights, stage):
        ns.log.append(("rig_scan", m is mesh, model, weights))
        for s in ("fit", "skeleton", "weights"):
            stage(s)
        return SimpleNamespace(fit=ns.fit, avatar=ns.avatar, seconds={"fit": 2.5})

    def check_rig(fit, V, F, scan, accept):
        ns.log.append(("check_rig", fit, V, F, scan, accept))
        return ns.verdict

    def reshape_avatar(avatar, fit, model, deltas):
        ns.log.append(("reshape", avatar is ns.avatar, fit, model, deltas))
        return ns.reshaped, "X"

    def write_rig(writer, out, avatar, texture, bvh, poses):
        ns.log.append(("write_rig", writer, out, avatar, texture, bvh, poses))
        ns.written_metadata = dict(avatar.metadata)
        return {"n_vertices": 6002, "bones": ["a", "b", "c"], "fit_err_mm_median": 2.345,
                "plausibility": avatar.metadata.get("plausibility")}

    class Progress(rich.progress.Progress):
        def __init__(self, *columns, **kwargs):
            ns.progress_init = (columns, kwargs)
            super().__init__(*columns, **kwargs)

        def add_task(self, description, **kwargs):
            ns.progress.append(("add", description, kwargs))
            return super().add_task(description, **kwargs)

        def update(self, task, **kwargs):
            ns.progress.append(("update", self.tasks[task].description, kwargs))
            return super().update(task, **kwargs)

    monkeypatch.setattr(scan_mod, "load_scan", load_scan)
    monkeypatch.setattr(pipeline, "load_template_model", lambda t: ns.log.append(("template", t)) or f"MODEL {t}")
    monkeypatch.setattr(pipeline, "rig_scan", rig_scan)
    monkeypatch.setattr(plausibility, "check_rig", check_rig)
    monkeypatch.setattr(reshape, "reshape_avatar", reshape_avatar)
    monkeypatch.setattr(export, "write_rig", write_rig)
    monkeypatch.setattr(evaluate, "held_out_poses", lambda names: ("POSES", tuple(names)))
    monkeypatch.setattr(runfolder, "RunWriter", Writer)
    monkeypatch.setattr(rich.progress, "Progress", Progress)
    monkeypatch.setattr(cli_rig, "time", Clock())
    return ns


def test_rig_defaults(rig_api):
    from bodystudio.runfolder import RunLayout

    res = _invoke(["rig", "scan.ply", "--out", "a.glb"])
    assert res.exit_code == 0, (res.output, res.exception)
    (w,) = Writer.made
    assert (w.layout, w.command, w.inputs, w.exited) == (
        RunLayout(Path("."), "a.rig.json", ".a.glb.", "a.glb"), "bodystudio rig",
        {"scan": "scan.ply", "template": "6k", "texture": False}, 1)
    assert rig_api.log == [
        ("load_scan", Path("scan.ply")), ("template", "6k"), ("rig_scan", True, "MODEL 6k", "harmonic"),
        ("check_rig", "FIT", "V", "F", "scan.ply", False),
        ("write_rig", w, Path("a.glb"), rig_api.avatar, False, None, None)]
    # clock: t0 10.0, metadata seconds at 11.25, the description's seconds at 12.5
    assert rig_api.written_metadata == {"scan": {"units": "mm"}, "template": "6k",
                                        "plausibility": {"verdict": "plausible", "warnings": []}, "seconds": 1.25,
                                        "stage_seconds": {"fit": 2.5}}
    assert res.stdout == "wrote a.glb (6002 vertices, 3 bones, fit 2.3 mm, 2.5 s)\n"
    assert res.stderr == ""
    stages = ["load", "fit", "skeleton", "weights", "export"]  # no reshape asked: no reshape task
    assert rig_api.progress == [("add", s, {"total": 1}) for s in stages] + [
        ("update", s, {"completed": 1}) for s in ("load", "fit", "skeleton", "weights", "export")]


def test_rig_progress_tasks_and_columns(rig_api):
    res = _invoke(["rig", "scan.ply", "-o", "a.glb", "--reshape", "stature=+0.05"])
    assert res.exit_code == 0, (res.output, res.exception)
    stages = ["load", "fit", "skeleton", "weights", "reshape", "export"]
    assert rig_api.progress == [("add", s, {"total": 1}) for s in stages] + [
        ("update", s, {"completed": 1}) for s in stages]
    columns, kwargs = rig_api.progress_init
    assert [type(c).__name__ for c in columns] == ["TextColumn", "BarColumn", "TimeElapsedColumn"]
    assert columns[0].text_format == "{task.description:<10}"
    assert kwargs["transient"] is True and kwargs["disable"] is True  # CliRunner's stderr is not a terminal
    assert kwargs["console"].stderr is True


def test_rig_progress_shows_on_a_terminal_only_when_asked(rig_api, monkeypatch):
    import rich.console

    from bodystudio.cli.rig import rig_to_files

    monkeypatch.setattr(rich.console.Console, "is_terminal", property(lambda self: True))
    rig_to_files(Path("scan.ply"), Path("a.glb"))
    assert rig_api.progress_init[1]["disable"] is True
    rig_to_files(Path("scan.ply"), Path("b.glb"), show_progress=True)
    assert rig_api.progress_init[1]["disable"] is False
    res = _invoke(["rig", "scan.ply", "--out", "c.glb"])  # the command asks for the bar
    assert res.exit_code == 0 and rig_api.progress_init[1]["disable"] is False


def test_rig_every_option(rig_api):
    rig_api.verdict = {"verdict": "implausible", "warnings": ["feet cut off", "odd pose"]}
    res = _invoke(["rig", "scan.ply", "--out", "o/a.GLB", "--reshape", "stature=+0.05,mass=-5", "--template", "13k",
                   "--texture", "--weights", "barycentric", "--bvh", "o/poses.bvh", "--accept-implausible"])
    assert res.exit_code == 0, (res.output, res.exception)
    (w,) = Writer.made
    assert w.inputs == {"scan": "scan.ply", "template": "13k", "texture": True}
    assert rig_api.log == [
        ("load_scan", Path("scan.ply")), ("template", "13k"), ("rig_scan", True, "MODEL 13k", "barycentric"),
        ("check_rig", "FIT", "V", "F", "scan.ply", True),
        ("reshape", True, "FIT", "MODEL 13k", {"stature_m": 0.05, "mass_kg": -5.0}),
        ("write_rig", w, Path("o/a.GLB"), rig_api.reshaped, True, Path("o/poses.bvh"),
         ("POSES", ("root", "spine")))]
    assert rig_api.written_metadata["plausibility"]["verdict"] == "implausible"
    assert res.stderr == "warning: feet cut off\nwarning: odd pose\n"
    assert res.stdout == "wrote o/a.GLB (6002 vertices, 3 bones, fit 2.3 mm, 2.5 s)\n"


def test_rig_without_a_fit_has_no_verdict(rig_api):
    rig_api.fit = None
    res = _invoke(["rig", "scan.ply", "--out", "a.glb"])
    assert res.exit_code == 0, (res.output, res.exception)
    assert [e[0] for e in rig_api.log] == ["load_scan", "template", "rig_scan", "write_rig"]
    assert "plausibility" not in rig_api.written_metadata and res.stderr == ""


def test_rig_to_files_returns_the_description_with_its_seconds(rig_api):
    from bodystudio.cli.rig import rig_to_files

    desc = rig_to_files(Path("scan.ply"), Path("a.glb"))
    (w,) = Writer.made
    assert w.inputs == {"scan": "scan.ply", "template": "6k", "texture": False}
    assert rig_api.log[-1] == ("write_rig", w, Path("a.glb"), rig_api.avatar, False, None, None)
    assert desc == {"n_vertices": 6002, "bones": ["a", "b", "c"], "fit_err_mm_median": 2.345,
                    "plausibility": {"verdict": "plausible", "warnings": []}, "seconds": 2.5}
    assert rig_api.log[1] == ("template", "6k") and rig_api.log[2][3] == "harmonic"
    assert rig_api.log[3][5] is False


def test_rig_to_files_defaults_are_the_cli_defaults():
    import inspect

    from bodystudio.cli.rig import rig, rig_to_files

    api = {n: p.default for n, p in inspect.signature(rig_to_files).parameters.items()}
    assert api == {"scan": inspect.Parameter.empty, "out": inspect.Parameter.empty, "reshape": None,
                   "template": "6k", "texture": False, "weights": "harmonic", "bvh": None, "show_progress": False,
                   "accept_implausible": False}
    cli = {n: p.default.default for n, p in inspect.signature(rig).parameters.items() if n not in ("scan", "out")}
    assert cli == {"reshape": None, "template": "6k", "texture": False, "weights": "harmonic", "bvh": None,
                   "accept_implausible": False}


@pytest.mark.parametrize("args, message", [
    (["--out", "a.gltf"], "--out a.gltf: the avatar is written as glTF binary; give a .glb path"),
    (["--out", "a"], "--out a: the avatar is written as glTF binary; give a .glb path"),
    (["--out", "d.glb"], "--out d.glb: is a folder; give a file path"),
    (["--out", "r.glb"], "--out r.rig.json: is a folder; give a file path"),
    (["--out", "f/a.glb"], "--out f/a.glb: {cwd}/f is a file, not a folder; choose another place"),
    (["--out", "a.glb", "--bvh", "p.txt"], "--bvh p.txt: unsupported output format; use .bvh"),
    (["--out", "a.glb", "--bvh", "d.bvh"], "--bvh d.bvh: is a folder; give a file path"),
    (["--out", "a.glb", "--reshape", "height=+3"], "--reshape stature_m=+3: change outside the population's "
     "plausible span [-0.3, +0.3] m; lengths are in metres, mass in kg"),
])
def test_rig_refusals_before_any_work(rig_api, args, message):
    Path("d.glb").mkdir()
    Path("r.rig.json").mkdir()
    Path("d.bvh").mkdir()
    Path("f").write_text("a file")
    res = _invoke(["rig", "scan.ply", *args])
    _refused(res, message.format(cwd=Path.cwd()))
    assert rig_api.log == [] and Writer.made == []


def test_rig_refuses_to_write_over_its_inputs(rig_api):
    Path("scan.glb").write_bytes(b"glTF")
    _refused(_invoke(["rig", "scan.glb", "--out", "scan.glb"]),
             "--out scan.glb: is the scan; writing it would replace that input, choose another path")
    Path("s.bvh").write_text("x")
    _refused(_invoke(["rig", "s.bvh", "--out", "a.glb", "--bvh", "s.bvh"]),
             "--bvh s.bvh: is the scan; writing it would replace that input, choose another path")
    assert rig_api.log == []


def test_rig_refuses_a_bvh_that_is_the_avatar(rig_api):
    Path("a.glb").write_bytes(b"glTF")
    Path("a.bvh").symlink_to("a.glb")
    _refused(_invoke(["rig", "scan.ply", "--out", "a.glb", "--bvh", "a.bvh"]),
             "--bvh a.bvh: is --out; writing it would replace that input, choose another path")
    assert rig_api.log == []


def test_rig_help():
    res = _invoke(["rig", "--help"])
    text = " ".join(res.stdout.replace("│", " ").split())
    for phrase in ("body scan: PLY, OBJ, GLB/GLTF or STL", "avatar .glb (a .rig.json is written beside it)",
                   "model template: 6k, 13k (or 2k)", "skin weight transfer: harmonic or barycentric",
                   "--texture", "--vertex-colors", "-o", "also write a BVH of sample poses on the avatar's skeleton",
                   "Rig a body scan: fit the body model, transfer skeleton and skin weights, export glTF."):
        assert f" {phrase} " in f" {text} ", phrase


# ------------------------------------------------------------------------------------------------ synth scan

@pytest.fixture
def synth_api(monkeypatch, tmp_path):
    import bodystudio.register.synthetic as synthetic

    monkeypatch.chdir(tmp_path)
    ns = SimpleNamespace(log=[])
    scan = SimpleNamespace(n_vertices=99876)

    def synthetic_scan(*args):
        ns.log.append(("scan", args))
        return scan, "GT"

    def save(out, s, gt):
        ns.log.append(("save", out, s is scan, gt))
        return Path("gt-folder")

    monkeypatch.setattr(synthetic, "synthetic_scan", synthetic_scan)
    monkeypatch.setattr(synthetic, "save_synthetic_scan", save)
    return ns


def test_synth_scan_defaults_and_options(synth_api):
    res = _invoke(["synth", "scan", "s.ply"])
    assert res.exit_code == 0, (res.output, res.exception)
    assert synth_api.log == [("scan", (0, "a", 100_000, 1.0, True)), ("save", Path("s.ply"), True, "GT")]
    assert res.stdout == "wrote s.ply (99876 vertices) and gt-folder/\n"
    res = _invoke(["synth", "scan", "s.STL", "--subject-seed", "4", "--pose", "t", "--vertices", "5000",
                   "--noise-mm", "0.5", "--no-holes"])
    assert res.exit_code == 0, (res.output, res.exception)
    assert synth_api.log[2] == ("scan", (4, "t", 5000, 0.5, False))


@pytest.mark.parametrize("out, setup, message", [
    ("s.txt", None, "synth scan s.txt: unsupported output format; use .ply or .obj or .glb or .stl"),
    ("d.ply", "dir", "synth scan d.ply: is a folder; give a file path"),
    ("s.ply", "gtfile", "synth scan ground truth s.gt: exists and is a file, not a folder; choose a folder path"),
])
def test_synth_scan_refusals(synth_api, out, setup, message):
    if setup == "dir":
        Path("d.ply").mkdir()
    if setup == "gtfile":
        Path("s.gt").write_text("x")
    _refused(_invoke(["synth", "scan", out]), message)
    assert synth_api.log == []


def test_synth_scan_refuses_a_negative_subject(synth_api):
    res = _invoke(["synth", "scan", "s.ply", "--subject-seed", "-1"])
    assert res.exit_code == 2 and synth_api.log == []
    res = _invoke(["synth", "scan", "s.ply", "--subject-seed", "0"])
    assert res.exit_code == 0 and synth_api.log[0] == ("scan", (0, "a", 100_000, 1.0, True))
