"""``bodystudio demo`` (bodystudio/demo.py and cli/demo.py) with every stage's API replaced by spies (mutNN).

What every new user runs first. Each stage must call its API with the demo's documented sizes (the module's
constants, written out here by hand), write its outputs where the report looks for them (read back with json),
and return the summary line the console and the report show (the expected lines are written out by hand from
the spies' values). ``run_stage`` / ``run_demo`` / ``check_demo``: the status of each row, the skip and
dependency rules, the refusals before any output, the report's inputs. No body is built and no stage runs for
real: the whole file runs in about a second.
"""

from __future__ import annotations

import importlib
import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

import bodystudio.demo as demo
from bodystudio.errors import BodyStudioError, InputError
from tests.reliability.cli_spies import spy as _spy

# Every module a spy reaches into (and the demo's own imports), imported before any spy stands: a module imported
# for the first time while a spy stands (monkeypatch imports a dotted target's module) binds the spy for good
# through its ``from ... import`` (calib.synthetic's ``ring_rig`` was left a stand-in for the rest of the session,
# breaking later fixtures).
_SPIED_MODULES = (
    "bodystudio.body", "bodystudio.body.measure", "bodystudio.body.population", "bodystudio.body.statistical",
    "bodystudio.calib.board", "bodystudio.calib.calibrate", "bodystudio.calib.evaluate",
    "bodystudio.calib.observations", "bodystudio.calib.synthetic", "bodystudio.garment.composite",
    "bodystudio.garment.evaluate", "bodystudio.garment.fit", "bodystudio.garment.synthetic",
    "bodystudio.geometry.camera", "bodystudio.geometry.mesh", "bodystudio.mirror.evaluate", "bodystudio.mirror.init",
    "bodystudio.mirror.run", "bodystudio.mirror.synthetic", "bodystudio.muscle.arm", "bodystudio.muscle.capture",
    "bodystudio.muscle.evaluate", "bodystudio.muscle.model", "bodystudio.muscle.synthetic",
    "bodystudio.register.scan", "bodystudio.register.synthetic", "bodystudio.rig.evaluate", "bodystudio.rig.export",
    "bodystudio.rig.pipeline", "bodystudio.viewer.arm", "bodystudio.viewer.avatar", "bodystudio.viewer.mirror",
    "bodystudio.viewer.scene", "bodystudio.viewer.views", "bodystudio.viewer.webgl",
    # and what the demo itself imports inside its stages (their own ``from ... import`` of a spied name)
    "bodystudio.capture.synth", "bodystudio.reconstruct.sequence", "bodystudio.viewer.report", "bodystudio.runfolder",
)
for _name in _SPIED_MODULES:
    importlib.import_module(_name)


class Plotter:
    def __init__(self, name="p"):
        self.name, self.closed = name, 0

    def close(self):
        self.closed += 1


class Progress:
    def __init__(self):
        self.tasks, self.advanced = [], []

    def add_task(self, description, total=None):
        self.tasks.append((description, total))
        return f"task{len(self.tasks)}"

    def advance(self, task):
        self.advanced.append(task)


def _ctx(tmp_path, cameras=3, frames=2, resolution=(200, 100)):
    return demo.DemoContext(tmp_path / "out", cameras, frames, resolution, console=None, progress=Progress())


def _read(path: Path):
    return json.loads(path.read_text())


# ------------------------------------------------------------------------------------------------ small helpers

def test_split_first_frame_by_hand():
    assert demo.split_first_frame([1000.04, 20.0, 30.0, 41.0]) == {"first_frame_ms": 1000.0, "ms_per_frame": 30.3}
    assert demo.split_first_frame([12.36]) == {"first_frame_ms": 12.4, "ms_per_frame": None}
    out = demo.split_first_frame([5.0, 7.25])
    assert out == {"first_frame_ms": 5.0, "ms_per_frame": 7.2} and type(out["first_frame_ms"]) is float


def test_timing_text_by_hand():
    assert demo.timing_text({"first_frame_ms": 3956.4, "ms_per_frame": 267.6}) == (
        "268 ms per frame after the first frame 3956 ms (includes numba compilation)")
    assert demo.timing_text({"first_frame_ms": 500.0, "ms_per_frame": None}) == (
        "first frame 500 ms (includes numba compilation); one frame only, so no warm per-frame time")


def test_check_demo_names_every_failed_stage_and_the_first_message(tmp_path):
    demo.check_demo(tmp_path, tmp_path / "r.html", [{"stage": "a", "status": "done", "summary": "x"},
                                                      {"stage": "b", "status": "skipped", "summary": "y"}])
    rows = [{"stage": "a", "status": "done", "summary": "ok"}, {"stage": "b", "status": "failed", "summary": "boom"},
            {"stage": "c", "status": "failed", "summary": "bang"}]
    with pytest.raises(demo.DemoStageError) as exc:
        demo.check_demo(str(tmp_path), tmp_path / "r.html", rows)
    assert str(exc.value) == (f"stages failed: b, c (b: boom); messages in {tmp_path / 'demo.json'}, report still "
                              f"written to {tmp_path / 'r.html'}")
    assert isinstance(exc.value, BodyStudioError)


def test_demo_constants_are_the_documented_sizes():
    assert (demo.N_POPULATION, demo.PREVIEW_RESOLUTION, demo.POPULATION_SEED) == (3, "2k", 2026)
    assert (demo.CALIBRATION_SIZE, demo.CALIBRATION_POSES) == ((960, 720), 14)
    assert (demo.RIG_SUBJECT, demo.RIG_SCAN_VERTICES, demo.RIG_TEMPLATE) == (3, 20_000, "6k")
    assert (demo.MUSCLE_SUBJECT, demo.MUSCLE_FRAMES, demo.MUSCLE_RESOLUTION, demo.MUSCLE_POPULATION) == (
        7, 10, "2k", 16)
    assert demo.MUSCLE_TRAINING == {"n_subjects": 4, "n_shapes": 2, "n_poses": 8}
    assert (demo.MIRROR_SUBJECT, demo.MIRROR_FRAMES, demo.MIRROR_KINECT) == (3, 22, "v2")
    assert demo.MIRROR_EDITS == {"taller": 0.1, "heavier": 10.0}
    assert (demo.GARMENT_SUBJECT, demo.GARMENT_FRAMES, demo.GARMENT_RESOLUTION, demo.GARMENT_TEXTURE) == (
        21, 8, (240, 320), 128)
    assert [n for n, _ in demo.STAGES] == ["bodies", "session", "calibrate", "reconstruct", "rig", "muscle",
                                           "mirror", "garment"]
    assert [f for _, f in demo.STAGES] == [demo.stage_bodies, demo.stage_session, demo.stage_calibrate,
                                           demo.stage_reconstruct, demo.stage_rig, demo.stage_muscle,
                                           demo.stage_mirror, demo.stage_garment]
    assert demo.STAGE_NEEDS == {"reconstruct": "session"}


# ------------------------------------------------------------------------------------------------ bodies

def test_stage_bodies_builds_exports_and_measures(tmp_path, monkeypatch):
    from bodystudio.body import Phenotype

    mp = monkeypatch
    population = [(Phenotype(gender=0.25), {"l1": 0.5}), (Phenotype(gender=0.5), {}),
                  (Phenotype(gender=0.75), {"l3": -0.1})]
    sample = _spy(mp, "bodystudio.body.population.sample_population", ret=population)

    def body(phenotype, local, resolution=None):
        return SimpleNamespace(mesh=("mesh", phenotype.gender, resolution), phenotype=phenotype, local=local,
                               resolution=resolution)

    build = _spy(mp, "bodystudio.body.build_body", fn=body)
    save = _spy(mp, "bodystudio.geometry.mesh.save_mesh")
    values = iter(range(5))

    def measure(b):
        k = next(values)
        return {"stature_m": 1.6 + k / 10 + 0.123456, "mass_kg": 60.0 + k, "muscularity": 0.5}

    measured_bodies = _spy(mp, "bodystudio.body.measure.measure_body", fn=measure)
    printed = _spy(mp, "bodystudio.demo._print_measurements")
    shots = _spy(mp, "bodystudio.demo._body_screenshots")
    ctx = _ctx(tmp_path)
    ctx.console = "CONSOLE"
    summary = demo.stage_bodies(ctx)
    folder = ctx.out / "bodies"
    assert summary == f"5 bodies exported to {folder} and measured"
    assert sample.calls == [((3,), {"seed": 2026})]
    names = ["female", "male", "subject_00", "subject_01", "subject_02"]
    genders = [0.0, 1.0, 0.25, 0.5, 0.75]
    assert [(a[0].gender, a[1], k) for a, k in build.calls] == [
        x for g, (_, loc) in zip(genders, [(0, {}), (0, {})] + population, strict=True)
        for x in ((g, loc, {}), (g, loc, {"resolution": "2k"}))]
    assert list(ctx.bodies) == names and list(ctx.previews) == names
    assert [b.resolution for b in ctx.bodies.values()] == [None] * 5
    assert [b.resolution for b in ctx.previews.values()] == ["2k"] * 5
    assert [(a, k) for a, k in save.calls] == [((folder / f"{n}.ply", ("mesh", g, None)), {})
                                               for n, g in zip(names, genders, strict=True)]
    measured = _read(folder / "measurements.json")
    assert list(measured) == ["bodies"]
    expected = {n: {"gender": g, "stature_m": round(1.6 + k / 10 + 0.123456, 4), "mass_kg": 60.0 + k,
                    "muscularity": 0.5} for k, (n, g) in enumerate(zip(names, genders, strict=True))}
    assert measured["bodies"] == expected
    assert measured["bodies"]["female"]["stature_m"] == 1.7235
    assert printed.calls == [(("CONSOLE", expected), {})]
    assert [a[0] for a, _ in measured_bodies.calls] == list(ctx.bodies.values())  # the full-resolution bodies
    assert shots.calls == [((ctx,), {})]
    assert ctx.progress.tasks == [("bodies", 5)] and ctx.progress.advanced == ["task1"] * 5


def test_stage_bodies_rounds_gender_to_three_places(tmp_path, monkeypatch):
    from bodystudio.body import Phenotype

    mp = monkeypatch
    _spy(mp, "bodystudio.body.population.sample_population", ret=[(Phenotype(gender=0.123456), {})])
    _spy(mp, "bodystudio.body.build_body", fn=lambda p, loc, resolution=None: SimpleNamespace(mesh=None))
    _spy(mp, "bodystudio.geometry.mesh.save_mesh")
    _spy(mp, "bodystudio.body.measure.measure_body", ret={"stature_m": np.float64(1.23456789)})
    _spy(mp, "bodystudio.demo._print_measurements")
    _spy(mp, "bodystudio.demo._body_screenshots")
    ctx = _ctx(tmp_path)
    assert demo.stage_bodies(ctx) == f"3 bodies exported to {ctx.out / 'bodies'} and measured"
    assert _read(ctx.out / "bodies" / "measurements.json")["bodies"]["subject_00"] == {"gender": 0.123,
                                                                                      "stature_m": 1.2346}


def test_print_measurements_table_by_hand():
    from rich.console import Console

    console = Console(record=True, width=200)
    demo._print_measurements(console, {
        "female": {"gender": 0.0, "stature_m": 1.6543, "mass_kg": 61.25, "arm_length_m": 0.5555, "muscularity": 0.5,
                   "n": 3},
        "male": {"gender": 1.0, "stature_m": 1.7771, "mass_kg": 80.0, "arm_length_m": 0.6, "muscularity": 0.5,
                 "n": 4}})
    text = console.export_text()
    lines = [ln for ln in text.splitlines() if ln.strip()]
    assert lines[0].strip() == "body measurements (lengths in m, mass in kg)"
    narrow = Console(record=True, width=50)
    demo._print_measurements(narrow, {"subject_02": {"gender": 0.5, "stature_m": 1.7, "mass_kg": 70.0,
                                                     "chest_m": 0.9, "waist_m": 0.8, "hip_m": 1.0}})
    assert "│ subject_02 │" in narrow.export_text()  # the body's name is never wrapped
    header = lines[2].replace("┃", " ").split()
    assert header == ["body", "gender", "stature", "mass", "arm", "n"]
    female = lines[4].replace("│", " ").split()
    male = lines[5].replace("│", " ").split()
    assert female == ["female", "0.000", "1.654", "61.250", "0.555", "3"]
    assert male == ["male", "1.000", "1.777", "80.000", "0.600", "4"]
    assert "muscularity" not in text
    # numbers are right-aligned, the name column is not
    row = lines[4].split("│")
    assert row[1].startswith(" female") and row[2].endswith("0.000 ") and row[2].startswith("  ")


def test_lineup_places_bodies_side_by_side(monkeypatch):
    mp = monkeypatch
    plotter = Plotter()
    _spy(mp, "bodystudio.viewer.scene.make_plotter", ret=plotter)
    add_mesh = _spy(mp, "bodystudio.viewer.scene.add_mesh")
    floor = _spy(mp, "bodystudio.viewer.scene.add_floor")
    title = _spy(mp, "bodystudio.viewer.scene.add_title")
    front = _spy(mp, "bodystudio.viewer.scene.frame_front")
    faces = np.array([[0, 1, 2]])
    V = np.array([[0.0, 0.0, 0.0], [0.1, 1.0, 0.2], [-0.1, 1.8, -0.3]])
    bodies = {"a": SimpleNamespace(vertices=V, faces=faces),
              "b": SimpleNamespace(vertices=V + [0, 0.1, 0], faces=faces),
              "c": SimpleNamespace(vertices=V, faces=faces)}
    assert demo._lineup_plotter(bodies) is plotter
    assert [k["name"] for _, k in add_mesh.calls] == ["body-a", "body-b", "body-c"]
    for (args, _), dx, b in zip(add_mesh.calls, [-0.9, 0.0, 0.9], bodies.values(), strict=True):
        assert args[0] is plotter
        np.testing.assert_allclose(args[1].vertices, b.vertices + [dx, 0, 0], atol=1e-12)
        assert args[1].faces is faces
    lo, hi = np.array([-1.0, 0.0, -0.3]), np.array([1.0, 1.9, 0.2])
    ((fp, centre), fk), = floor.calls
    assert fp is plotter
    np.testing.assert_allclose(centre, (lo + hi) / 2, atol=1e-12)
    assert fk["size"] == pytest.approx(3.0)
    assert title.calls == [((plotter, "a  |  b  |  c"), {})]
    ((tp, bounds), tk), = front.calls
    assert tp is plotter and tk == {"direction": (0.0, 0.1, 1.0)}
    np.testing.assert_allclose(bounds, [lo, hi], atol=1e-12)


def test_lineup_of_two_bodies_is_centred(monkeypatch):
    mp = monkeypatch
    _spy(mp, "bodystudio.viewer.scene.make_plotter", ret=Plotter())
    add_mesh = _spy(mp, "bodystudio.viewer.scene.add_mesh")
    floor = _spy(mp, "bodystudio.viewer.scene.add_floor")
    for name in ("add_title", "frame_front"):
        _spy(mp, f"bodystudio.viewer.scene.{name}")
    V = np.zeros((3, 3))
    F = np.array([[0, 1, 2]])
    demo._lineup_plotter({"x": SimpleNamespace(vertices=V, faces=F), "y": SimpleNamespace(vertices=V, faces=F)})
    assert [float(a[1].vertices[0, 0]) for a, _ in add_mesh.calls] == pytest.approx([-0.45, 0.45])
    assert floor.calls[0][1]["size"] == pytest.approx(1.9)


def test_body_screenshots_paths_bones_and_scenes(tmp_path, monkeypatch):
    mp = monkeypatch
    lineup, rigged, skeleton = Plotter("lineup"), Plotter("rigged"), Plotter("skeleton")
    lineup_spy = _spy(mp, "bodystudio.demo._lineup_plotter", ret=lineup)
    _spy(mp, "bodystudio.viewer.avatar.avatar_from_body", fn=lambda b: ("avatar", b))
    shots = _spy(mp, "bodystudio.viewer.scene.save_screenshot")
    scenes = iter([rigged, skeleton])
    scene = _spy(mp, "bodystudio.viewer.views.scene_for_avatar", fn=lambda *a, **k: next(scenes))
    female = SimpleNamespace(skeleton=SimpleNamespace(bone_names=["root", "spine", "upperarm_l"]))
    ctx = _ctx(tmp_path)
    ctx.previews = {"female": female, "male": "M"}
    demo._body_screenshots(ctx)
    assert lineup_spy.calls == [((ctx.previews,), {})]
    s = ctx.out / "screenshots"
    assert shots.calls == [((lineup, s / "bodies.png"), {}), ((rigged, s / "female_weights.png"), {}),
                           ((skeleton, s / "male_skeleton.png"), {})]
    assert scene.calls == [((("avatar", female),), {"bone": "upperarm_l",
                                                    "title": "female: skin weights of upperarm_l"}),
                           ((("avatar", "M"),), {"title": "male: skeleton"})]
    assert (lineup.closed, rigged.closed, skeleton.closed) == (0, 1, 0)
    assert ctx.scenes == [("bodies", lineup), ("male: skeleton", skeleton)]


def test_body_screenshots_without_upperarm_takes_the_second_bone(tmp_path, monkeypatch):
    mp = monkeypatch
    _spy(mp, "bodystudio.demo._lineup_plotter", ret=Plotter())
    _spy(mp, "bodystudio.viewer.avatar.avatar_from_body", fn=lambda b: b)
    _spy(mp, "bodystudio.viewer.scene.save_screenshot")
    scene = _spy(mp, "bodystudio.viewer.views.scene_for_avatar", fn=lambda *a, **k: Plotter())
    ctx = _ctx(tmp_path)
    ctx.previews = {"female": SimpleNamespace(skeleton=SimpleNamespace(bone_names=["root", "spine", "neck"])),
                    "male": "M"}
    demo._body_screenshots(ctx)
    assert scene.calls[0][1] == {"bone": "spine", "title": "female: skin weights of spine"}


# ------------------------------------------------------------------------------------------------ session

def test_stage_session_calls_synth_with_the_context(tmp_path, monkeypatch):
    synth = _spy(monkeypatch, "bodystudio.capture.synth.synth_session", ret="SESSION")
    ctx = _ctx(tmp_path, cameras=5, frames=7, resolution=(64, 48))
    assert demo.stage_session(ctx) == f"5 cameras x 7 frames with Kinect in {ctx.out / 'session'}"
    assert synth.calls == [((ctx.out / "session",), dict(n_cameras=5, n_frames=7, motion="walk", kinect="v2",
                                                         resolution=(64, 48), n_background=2, progress=False))]
    assert ctx.session == "SESSION"


def test_stage_session_starts_a_rerun_fresh_and_keeps_an_empty_folder(tmp_path, monkeypatch):
    _spy(monkeypatch, "bodystudio.capture.synth.synth_session", ret="S")
    ctx = _ctx(tmp_path)
    (ctx.out / "session" / "frames").mkdir(parents=True)
    (ctx.out / "session" / "old.json").write_text("{}")
    demo.stage_session(ctx)
    assert not (ctx.out / "session").exists()
    (ctx.out / "session").mkdir()
    demo.stage_session(ctx)
    assert (ctx.out / "session").is_dir()


# ------------------------------------------------------------------------------------------------ calibrate

def _calibration_spies(mp, report=None, overall=None):
    rig = "ESTIMATED RIG"
    result = SimpleNamespace(
        report=lambda: dict(report if report is not None else {"uncertainty": {"verdict": "trustworthy"}, "n": 1}),
        residuals_px=np.array([[3.0, 4.0], [0.1, 0.2], [1.0, 1.0], [0.123456, 0.0]]),
        inliers=np.array([True, False, True, True]), rig=rig, rms_px=0.45678)
    spies = SimpleNamespace(
        ring=_spy(mp, "bodystudio.geometry.camera.ring_rig", fn=lambda n, **k: ("RING", n, k)),
        write=_spy(mp, "bodystudio.calib.synthetic.write_synthetic_calibration"),
        board=_spy(mp, "bodystudio.calib.board.load_board_json", ret="SPEC"),
        detect=_spy(mp, "bodystudio.calib.observations.detect_capture", ret=("OBS", "QUALITY")),
        calibrate=_spy(mp, "bodystudio.calib.calibrate.calibrate_cameras", ret=result),
        gt=_spy(mp, "bodystudio.geometry.camera.load_cameras_json", ret="TRUE RIG"),
        evaluate=_spy(mp, "bodystudio.calib.evaluate.evaluate_calibration",
                      ret={"overall": overall if overall is not None else {"center_err_mm": 6.5}, "x": 1}),
        save=_spy(mp, "bodystudio.geometry.camera.save_cameras_json"))
    return spies


def test_stage_calibrate_by_hand(tmp_path, monkeypatch):
    sp = _calibration_spies(monkeypatch)
    ctx = _ctx(tmp_path, cameras=3)
    summary = demo.stage_calibrate(ctx)
    folder = ctx.out / "calibration"
    capture = folder / "capture"
    assert summary == ("3 cameras from 14 board poses: reprojection RMS 0.457 px, camera centre error 6 mm, "
                       "uncertainty verdict: trustworthy")
    assert sp.ring.calls == [((3,), {"width": 960, "height": 720})]
    assert sp.write.calls == [((capture,), dict(n_cameras=3, n_poses=14, seed=0, width=960, height=720,
                                                rig=("RING", 3, {"width": 960, "height": 720})))]
    assert sp.board.calls == [((capture / "board.json",), {})]
    assert sp.detect.calls == [((capture, "SPEC"), {})]
    assert sp.calibrate.calls == [(("OBS", "SPEC"), {})]
    assert sp.gt.calls == [((capture / "gt" / "cameras.json",), {})]
    report = {"uncertainty": {"verdict": "trustworthy"}, "n": 1, "residuals_px": [5.0, 1.4142, 0.1235]}
    (rig, true_rig, rep), k = sp.evaluate.calls[0]
    assert (rig, true_rig, rep, k) == ("ESTIMATED RIG", "TRUE RIG", report, {})
    assert sp.save.calls == [((folder / "cameras.json", "ESTIMATED RIG"), {})]
    assert _read(folder / "report.json") == report
    assert _read(folder / "eval.json") == {"overall": {"center_err_mm": 6.5}, "x": 1}


def test_stage_calibrate_without_a_centre_error_says_nan(tmp_path, monkeypatch):
    _calibration_spies(monkeypatch, report={"uncertainty": {"verdict": "uncertain"}}, overall={})
    assert demo.stage_calibrate(_ctx(tmp_path, cameras=2)) == (
        "2 cameras from 14 board poses: reprojection RMS 0.457 px, camera centre error nan mm, "
        "uncertainty verdict: uncertain")
    sp = _calibration_spies(monkeypatch)
    sp.evaluate.ret = {}
    assert "camera centre error nan mm" in demo.stage_calibrate(_ctx(tmp_path, cameras=2))


# ------------------------------------------------------------------------------------------------ reconstruct

def _reconstruct(tmp_path, monkeypatch, summary, frames_ms):
    ctx = _ctx(tmp_path)
    session = tmp_path / "sess"
    (session / "reconstruct").mkdir(parents=True)
    (session / "reconstruct" / "frames.json").write_text(json.dumps({"frames": [{"ms_per_frame": m}
                                                                                for m in frames_ms]}))
    ctx.session = SimpleNamespace(path=session)
    spy = _spy(monkeypatch, "bodystudio.reconstruct.sequence.reconstruct_session", ret=dict(summary))
    return ctx, spy


def test_stage_reconstruct_by_hand(tmp_path, monkeypatch):
    ctx, spy = _reconstruct(tmp_path, monkeypatch, {"frames": 3, "median_mm": 12.34}, [4000.0, 300.0, 200.0])
    assert demo.stage_reconstruct(ctx) == (
        "3 frames, 250 ms per frame after the first frame 4000 ms (includes numba compilation), visible median "
        "error 12.3 mm")
    assert spy.calls == [((tmp_path / "sess",), dict(solver="gs", template="2k", joints="tracker",
                                                     constraints=("silhouette", "depth"), progress=False))]
    assert _read(ctx.out / "reconstruct_summary.json") == {"frames": 3, "median_mm": 12.34, "first_frame_ms": 4000.0,
                                                           "ms_per_frame": 250.0}


def test_stage_reconstruct_without_a_median_or_warm_frames(tmp_path, monkeypatch):
    ctx, _ = _reconstruct(tmp_path, monkeypatch, {"frames": 1}, [900.0])
    assert demo.stage_reconstruct(ctx) == (
        "1 frames, first frame 900 ms (includes numba compilation); one frame only, so no warm per-frame time")
    assert _read(ctx.out / "reconstruct_summary.json") == {"frames": 1, "first_frame_ms": 900.0,
                                                           "ms_per_frame": None}


# ------------------------------------------------------------------------------------------------ rig

class RunWriterSpy:
    made = []

    def __init__(self, layout, command, inputs):
        self.layout, self.command, self.inputs, self.entered, self.exited = layout, command, inputs, 0, 0
        RunWriterSpy.made.append(self)

    def __enter__(self):
        self.entered += 1
        return self

    def __exit__(self, *exc):
        self.exited += 1
        return False


def _rig_spies(mp, scores, bone_names=("root", "spine", "upperarm_l")):
    RunWriterSpy.made = []
    scan = SimpleNamespace(n_vertices=19876)
    report = SimpleNamespace(as_dict=lambda: {"units": "m"}, to_canonical="TO_CANONICAL")
    fit = SimpleNamespace(history=[10.12345, 3.0004], fit_err_mm_median=2.345)
    rigged = SimpleNamespace(metadata={"old": 1})
    avatar = SimpleNamespace(bone_names=list(bone_names))
    views = iter([Plotter("weights"), Plotter("skeleton")])
    return SimpleNamespace(
        synthetic=_spy(mp, "bodystudio.register.synthetic.synthetic_scan", ret=(scan, "GT")),
        save_scan=_spy(mp, "bodystudio.register.synthetic.save_synthetic_scan"),
        load_scan=_spy(mp, "bodystudio.register.scan.load_scan", ret=("MESH", report)),
        template=_spy(mp, "bodystudio.rig.pipeline.load_template_model", ret="TEMPLATE"),
        rig=_spy(mp, "bodystudio.rig.pipeline.rig_scan",
                 ret=SimpleNamespace(avatar=rigged, seconds={"fit": 1.5}, fit=fit)),
        layout=_spy(mp, "bodystudio.rig.export.rig_layout", fn=lambda glb: ("LAYOUT", glb)),
        writer=mp.setattr("bodystudio.runfolder.RunWriter", RunWriterSpy),
        write=_spy(mp, "bodystudio.rig.export.write_rig"),
        evaluate=_spy(mp, "bodystudio.rig.evaluate.evaluate_rig", ret=dict(scores)),
        load_avatar=_spy(mp, "bodystudio.viewer.avatar.load_avatar", ret=avatar),
        scene=_spy(mp, "bodystudio.viewer.views.scene_for_avatar", fn=lambda *a, **k: next(views)),
        shot=_spy(mp, "bodystudio.viewer.scene.save_screenshot"),
        scan=scan, rigged=rigged, avatar=avatar)


def test_stage_rig_by_hand(tmp_path, monkeypatch):
    sp = _rig_spies(monkeypatch, {"joint_err_mm_mean": 17.26})
    ctx = _ctx(tmp_path)
    folder = ctx.out / "rig"
    glb = folder / "avatar.glb"
    assert demo.stage_rig(ctx) == (f"19876-vertex scan rigged to {glb}: fit 2.3 mm median, joint error 17.3 mm mean")
    assert sp.synthetic.calls == [((3, "a"), dict(n_vertices=20000, noise_mm=1.0, holes=True))]
    assert sp.save_scan.calls == [((folder / "scan.ply", sp.scan, "GT"), {})]
    assert sp.load_scan.calls == [((folder / "scan.ply",), {})]
    assert sp.template.calls == [(("6k",), {})]
    assert sp.rig.calls == [(("MESH", "TEMPLATE"), {})]
    assert sp.rigged.metadata == {"old": 1, "scan": {"units": "m"}, "template": "6k", "stage_seconds": {"fit": 1.5}}
    (w,) = RunWriterSpy.made
    assert (w.layout, w.command, w.inputs) == (("LAYOUT", glb), "bodystudio demo",
                                               {"scan": str(folder / "scan.ply"), "template": "6k"})
    assert (w.entered, w.exited) == (1, 1)
    assert sp.write.calls == [((w, glb, sp.rigged), {})]
    assert sp.evaluate.calls == [((sp.rigged, "GT", "TO_CANONICAL"), {})]
    assert _read(folder / "eval.json") == {"joint_err_mm_mean": 17.26, "fit_history_mm": [10.123, 3.0],
                                           "stage_seconds": {"fit": 1.5}}
    assert sp.load_avatar.calls == [((glb,), {})]
    assert sp.scene.calls == [((sp.avatar,), {"bone": "upperarm_l",
                                              "title": "rigged scan: skin weights of upperarm_l"}),
                              ((sp.avatar,), {"title": "rigged scan: transferred skeleton"})]
    (p1, s1), _ = sp.shot.calls[0]
    (p2, s2), _ = sp.shot.calls[1]
    assert (p1.name, s1, p2.name, s2) == ("weights", ctx.out / "screenshots" / "avatar_weights.png", "skeleton",
                                          ctx.out / "screenshots" / "avatar_skeleton.png")
    assert (p1.closed, p2.closed) == (1, 0)
    assert ctx.scenes == [("rigged scan (avatar.glb): skeleton", p2)]


def test_stage_rig_second_bone_and_no_joint_error(tmp_path, monkeypatch):
    sp = _rig_spies(monkeypatch, {}, bone_names=("root", "spine_01", "x"))
    ctx = _ctx(tmp_path)
    assert demo.stage_rig(ctx).endswith(": fit 2.3 mm median, joint error nan mm mean")
    assert sp.scene.calls[0][1] == {"bone": "spine_01", "title": "rigged scan: skin weights of spine_01"}


# ------------------------------------------------------------------------------------------------ muscle

def _muscle_spies(mp):
    subject = SimpleNamespace(bmi=24.56, muscularity=0.3, height_m=1.8, arm_length_m=0.61, gender=0.0,
                              summary=lambda: {"bmi": 24.56})
    model = SimpleNamespace(subjects=["s1", "s2", "s3"])
    capture = SimpleNamespace(n_frames=10)
    errors = {0: np.array([1.0, 2.0, 100.0, 4.0]), 1: np.array([5.0, 6.0, 100.0, 9.0])}
    view = SimpleNamespace(frame_ids=[3, 8], errors_mm=lambda k: errors[k])
    truth = SimpleNamespace(arm_mask=np.array([True, True, False, True]))
    plotter = Plotter("arm")
    return SimpleNamespace(
        sample=_spy(mp, "bodystudio.muscle.synthetic.sample_arm_subject", ret=subject),
        synth=_spy(mp, "bodystudio.muscle.synthetic.synth_arm_session", ret="ARM SESSION"),
        body=_spy(mp, "bodystudio.body.build_body", ret="MEAN BODY"),
        template=_spy(mp, "bodystudio.muscle.arm.arm_template", fn=lambda b, side: truth if b == "SUBJECT BODY"
                      else ("TEMPLATE", b, side)),
        training=_spy(mp, "bodystudio.muscle.synthetic.training_dataset", ret=("SAMPLES", "X")),
        learn=_spy(mp, "bodystudio.muscle.model.learn_arm_model", ret=model),
        save=_spy(mp, "bodystudio.muscle.model.save_arm_model"),
        capture=_spy(mp, "bodystudio.muscle.capture.capture_arm_sequence", ret=capture),
        write=_spy(mp, "bodystudio.muscle.capture.write_arm_capture"),
        subject_body=_spy(mp, "bodystudio.muscle.synthetic.subject_body", ret="SUBJECT BODY"),
        evaluate=_spy(mp, "bodystudio.muscle.evaluate.evaluate_arm_capture",
                      ret={"median_mm": 3.456, "p90_mm": 7.89, "back_median_mm": 4.44, "bulge_err_mm": 1.05,
                           "ms_per_frame": 123.5}),
        view=_spy(mp, "bodystudio.viewer.arm.open_arm_view", ret=view),
        scene=_spy(mp, "bodystudio.viewer.arm.scene_for_arm_sequence", fn=lambda v, f, p: p),
        plotter=_spy(mp, "bodystudio.viewer.scene.make_plotter", ret=plotter),
        shot=_spy(mp, "bodystudio.viewer.scene.save_screenshot"),
        payload=_spy(mp, "bodystudio.viewer.arm.arm_payload", ret={"payload": 1}),
        subject=subject, model=model, capture_result=capture, truth=truth, arm_view=view, arm_plotter=plotter)


def test_stage_muscle_by_hand(tmp_path, monkeypatch):
    from bodystudio.muscle.capture import CaptureOptions
    from bodystudio.muscle.model import ArmShapeParams

    sp = _muscle_spies(monkeypatch)
    ctx = _ctx(tmp_path)
    folder = ctx.out / "muscle"
    (folder / "capture").mkdir(parents=True)
    (folder / "stale.txt").write_text("old run")
    summary = demo.stage_muscle(ctx)
    assert summary == ("10 frames of elbow flexion, subject BMI 24.6: median 3.5 mm, p90 7.9 mm, back 4.4 mm, "
                       f"bulge error 1.1 mm, 124 ms per frame; {folder / 'capture' / 'arm.glb'}")
    assert not (folder / "stale.txt").exists()
    assert sp.sample.calls == [((7,), {})]
    assert sp.synth.calls == [((folder / "session",), dict(subject=sp.subject, motion="elbow_flex", n_frames=10,
                                                           kinect="v2", distance_m=1.0, resolution="2k"))]
    assert sp.body.calls == [((), {"resolution": "2k"})]
    assert sp.template.calls == [(("MEAN BODY", "left"), {}), (("SUBJECT BODY", "left"), {})]
    assert sp.training.calls == [(("2k",), {"n_subjects": 4, "n_shapes": 2, "n_poses": 8})]
    assert sp.learn.calls == [(("SAMPLES", ("TEMPLATE", "MEAN BODY", "left")), {"population_size": 16})]
    assert sp.save.calls == [((folder / "arm_model.npz", sp.model), {})]
    (args, kwargs), = sp.capture.calls
    assert args[:3] == ("ARM SESSION", sp.model, ("TEMPLATE", "MEAN BODY", "left"))
    assert args[3] == CaptureOptions(mode="full") and len(args) == 4
    assert kwargs == {"known_shape": ArmShapeParams(24.56, 0.3, 1.8, 0.61, sex=0.0)}
    assert sp.write.calls == [((folder / "capture", sp.capture_result), {})]
    assert sp.subject_body.calls == [((sp.subject, "2k"), {})]
    assert sp.evaluate.calls == [((sp.capture_result, "ARM SESSION", sp.truth), {})]
    assert sp.view.calls == [((folder / "capture",), {})]
    assert _read(folder / "eval.json") == {"median_mm": 3.456, "p90_mm": 7.89, "back_median_mm": 4.44,
                                           "bulge_err_mm": 1.05, "ms_per_frame": 123.5,
                                           "per_frame": [{"frame": 3, "median_err_mm": 2.0},
                                                         {"frame": 8, "median_err_mm": 6.0}],
                                           "subject": {"bmi": 24.56}, "model_subjects": 3}
    assert sp.scene.calls == [((sp.arm_view, 8, sp.arm_plotter), {})]
    assert sp.shot.calls == [((sp.arm_plotter, ctx.out / "screenshots" / "arm_capture.png"), {})]
    assert sp.payload.calls == [((sp.arm_view, sp.arm_plotter), {"start": 8})]
    assert sp.arm_plotter.closed == 1
    assert ctx.scenes == [("arm-muscle capture: arm coloured by error vs truth, Kinect depth points (slider: frame)",
                           {"payload": 1})]


def test_stage_muscle_per_frame_median_is_rounded_to_microns(tmp_path, monkeypatch):
    sp = _muscle_spies(monkeypatch)
    sp.arm_view.errors_mm = lambda k: np.array([1.23456, 1.0, 0.0, 2.0])
    sp.arm_view.frame_ids = [5]
    ctx = _ctx(tmp_path)
    demo.stage_muscle(ctx)
    assert _read(ctx.out / "muscle" / "eval.json")["per_frame"] == [{"frame": 5, "median_err_mm": 1.235}]
    assert sp.scene.calls[0][0][1] == 5 and sp.payload.calls[0][1] == {"start": 5}


# ------------------------------------------------------------------------------------------------ mirror

def _mirror_spies(mp, scores, run):
    plotter = Plotter("mirror")
    return SimpleNamespace(
        synth=_spy(mp, "bodystudio.mirror.synthetic.synth_mirror_session", ret="MIRROR SESSION"),
        model=_spy(mp, "bodystudio.body.statistical.load_statistical_model", ret="MODEL"),
        init=_spy(mp, "bodystudio.mirror.init.initialise_source_body", ret="SOURCE"),
        save=_spy(mp, "bodystudio.mirror.init.save_source_body"),
        run=_spy(mp, "bodystudio.mirror.run.run_mirror", ret=run),
        evaluate=_spy(mp, "bodystudio.mirror.evaluate.evaluate_mirror", ret=dict(scores)),
        view=_spy(mp, "bodystudio.viewer.mirror.open_mirror_view", ret="MIRROR VIEW"),
        scene=_spy(mp, "bodystudio.viewer.mirror.scene_for_mirror", fn=lambda v, f, p: p),
        plotter=_spy(mp, "bodystudio.viewer.scene.make_plotter", ret=plotter),
        shot=_spy(mp, "bodystudio.viewer.scene.save_screenshot"),
        payload=_spy(mp, "bodystudio.viewer.webgl.scene_payload", fn=lambda p: {"closed_then": p.closed}),
        mirror_plotter=plotter)


MIRROR_SCORES = {"init_stature_err_mm": 12.34, "init_mass_err_kg": 1.234, "fg_iou": 0.98765, "fg_iou_raw": 0.91234,
                 "warp_iou": 0.95555, "warp_iou_unwarped": 0.81111, "psnr_person": 31.26, "ms_per_frame_total": 45.6}


def test_stage_mirror_by_hand(tmp_path, monkeypatch):
    sp = _mirror_spies(monkeypatch, MIRROR_SCORES, {"summary": {"frames": 12}})
    ctx = _ctx(tmp_path)
    folder = ctx.out / "mirror_session"
    folder.mkdir(parents=True)
    (folder / "stale.txt").write_text("old")
    summary = demo.stage_mirror(ctx)
    assert summary == ("12 frames, taller +0.1 m, heavier +10 kg: init stature 12.3 mm / mass 1.23 kg off, fg_iou "
                       "0.988 (SDK mask 0.912), warp_iou 0.956 (unwarped 0.811), PSNR 31.3 dB, 46 ms per frame "
                       f"(image steps); 12 frames to {ctx.out / 'mirror.mp4'}")
    assert not (folder / "stale.txt").exists()
    assert sp.synth.calls == [((folder, 3), dict(n_frames=22, edits={"taller": 0.1, "heavier": 10.0}, version="v2",
                                                 motion="arms_raise", walk_in=False))]
    assert sp.model.calls == [(("6k",), {"progress": False})]
    assert sp.init.calls == [(("MIRROR SESSION", "MODEL"), {"frames": range(10, 22)})]
    assert sp.save.calls == [((folder / "mirror" / "source_body.npz", "SOURCE"), {})]
    assert sp.run.calls == [(("MIRROR SESSION", {"taller": 0.1, "heavier": 10.0}, ctx.out / "mirror.mp4"),
                             {"progress": False, "ramp_frames": 0})]
    assert sp.evaluate.calls == [(("MIRROR SESSION",), {})]
    assert _read(folder / "mirror" / "eval.json") == MIRROR_SCORES
    assert sp.view.calls == [((folder,), {})]
    assert sp.scene.calls == [(("MIRROR VIEW", None, sp.mirror_plotter), {})]
    assert sp.shot.calls == [((sp.mirror_plotter, ctx.out / "screenshots" / "mirror.png"), {})]
    assert ctx.scenes == [("mirror: input | mirror output | truth behind the fitted source body", {"closed_then": 0})]
    assert sp.mirror_plotter.closed == 1
    assert ctx.progress.tasks == [("mirror", 4)] and ctx.progress.advanced == ["task1"] * 4


def test_stage_mirror_identical_psnr_no_timing_and_no_run_summary(tmp_path, monkeypatch):
    scores = dict(MIRROR_SCORES, psnr_person=None, psnr_person_identical=True, ms_per_frame_total=None)
    _mirror_spies(monkeypatch, scores, "not a dict")
    ctx = _ctx(tmp_path)
    assert demo.stage_mirror(ctx) == (
        "12 frames, taller +0.1 m, heavier +10 kg: init stature 12.3 mm / mass 1.23 kg off, fg_iou 0.988 (SDK mask "
        "0.912), warp_iou 0.956 (unwarped 0.811), PSNR identical, nan ms per frame (image steps); ? frames to "
        f"{ctx.out / 'mirror.mp4'}")
    sp = _mirror_spies(monkeypatch, dict(MIRROR_SCORES, psnr_person_identical=False), {"videos": []})
    assert "PSNR 31.3 dB" in demo.stage_mirror(ctx) and "; ? frames to" in demo.stage_mirror(ctx)
    assert sp.run.calls


# ------------------------------------------------------------------------------------------------ garment

def test_stage_garment_by_hand(tmp_path, monkeypatch):
    mp = monkeypatch
    ctx = _ctx(tmp_path)
    for name in ("garment_session", "garment_fit"):
        (ctx.out / name).mkdir(parents=True)
        (ctx.out / name / "stale.txt").write_text("old")
    session = SimpleNamespace(path=tmp_path / "gs", gt_subject={"stature_m": np.float32(1.75)},
                              gt_garment={"target": {"name": "tshirt", "pattern": "stripes", "seed": 5}})

    def synth(path, **kwargs):
        assert not (ctx.out / "garment_session").exists() and not (ctx.out / "garment_fit").exists()
        return session

    synth_spy = _spy(mp, "bodystudio.garment.synthetic.synth_garment_session", fn=synth)
    fit = _spy(mp, "bodystudio.garment.fit.fit_garment_video")
    render = _spy(mp, "bodystudio.garment.composite.render_garment_video")
    scores = {"stature_err_mm": 4.56, "light_dir_err_deg": 7.89, "silhouette_iou": 0.9345, "garment_iou": 0.8766,
              "psnr_person": 27.55}
    evaluate = _spy(mp, "bodystudio.garment.evaluate.evaluate_garment", ret=dict(scores))
    (ctx.out / "garment_fit").mkdir(parents=True, exist_ok=True)
    fit_dir = ctx.out / "garment_fit"
    fit.fn = lambda *a, **k: fit_dir.mkdir(exist_ok=True)
    summary = demo.stage_garment(ctx)
    assert summary == ("8 frames 240x320, tshirt (stripes): stature 4.6 mm off, dominant light 7.9 deg off, fit IoU "
                       f"0.934, garment_iou 0.877, PSNR 27.6 dB; video {ctx.out / 'garment.mp4'}")
    assert synth_spy.calls == [((ctx.out / "garment_session",), dict(subject_seed=21, n_frames=8, resolution=(240, 320),
                                                                     template="2k", texture_size=128, seed=1))]
    ((path, stature, out_dir), kw), = fit.calls
    assert (path, out_dir, kw) == (tmp_path / "gs", fit_dir, {"template": "2k"})
    assert stature == pytest.approx(1.75) and type(stature) is float
    assert render.calls == [((fit_dir, "tshirt", "stripes", ctx.out / "garment.mp4"), {"seed": 5, "texture_size": 128})]
    assert evaluate.calls == [((fit_dir,), {})]
    assert _read(fit_dir / "eval.json") == scores
    assert ctx.progress.tasks == [("garment", 4)] and ctx.progress.advanced == ["task1"] * 4


# ------------------------------------------------------------------------------------------------ session views

def test_session_views_put_the_session_first(tmp_path, monkeypatch):
    mp = monkeypatch
    plotter = Plotter("session")
    scene = _spy(mp, "bodystudio.viewer.views.scene_for_session", ret=plotter)
    shot = _spy(mp, "bodystudio.viewer.scene.save_screenshot")
    payload = _spy(mp, "bodystudio.viewer.views.session_payload", fn=lambda *a, **k: {"closed_then": plotter.closed})
    ctx = _ctx(tmp_path)
    ctx.session = SimpleNamespace(frame_ids=[4, 9, 13])
    ctx.scenes = [("other", "X")]
    demo._session_views(ctx)
    assert scene.calls == [((ctx.session, 13), {})]
    assert shot.calls == [((plotter, ctx.out / "screenshots" / "session.png"), {})]
    assert payload.calls == [((ctx.session, plotter), {"start": 13})]
    assert plotter.closed == 1
    assert ctx.scenes == [("session: cameras with images, Kinect cloud, ground truth and reconstruction error "
                           "(slider: frame)", {"closed_then": 0}), ("other", "X")]


# ------------------------------------------------------------------------------------------------ run_stage

class Clock:
    """``time`` for the demo module: perf_counter steps by ``step`` seconds per reading."""

    def __init__(self, start=100.0, step=1.256):
        self.now, self.step = start, step

    def perf_counter(self):
        t = self.now
        self.now += self.step
        return t


def _fail_input(ctx):
    raise InputError("the input is bad; give a good one")


def _fail_bug(ctx):
    raise ValueError("boom")


def test_run_stage_done_row_and_seconds(tmp_path, monkeypatch):
    monkeypatch.setattr(demo, "time", Clock(100.0, 2.3456))
    ctx = _ctx(tmp_path)
    seen = []
    row = demo.run_stage(ctx, "bodies", lambda c: seen.append(c) or "all good", ())
    assert list(row.items()) == [("stage", "bodies"), ("status", "done"), ("seconds", 2.35), ("summary", "all good")]
    assert seen == [ctx]


def test_run_stage_skip_and_failures(tmp_path, monkeypatch, caplog):
    import logging

    monkeypatch.setattr(demo, "time", Clock(0.0, 0.5))
    ctx = _ctx(tmp_path)
    called = []
    row = demo.run_stage(ctx, "rig", lambda c: called.append(1), ("garment", "rig"))
    assert row == {"stage": "rig", "status": "skipped", "seconds": 0.5, "summary": "skipped (--skip)"} and not called
    row = demo.run_stage(ctx, "calibrate", _fail_input, ("rig",))
    assert row == {"stage": "calibrate", "status": "failed", "seconds": 0.5,
                   "summary": "the input is bad; give a good one"}
    with caplog.at_level(logging.DEBUG, logger="bodystudio.demo"):
        row = demo.run_stage(ctx, "muscle", _fail_bug, ())
    assert row == {"stage": "muscle", "status": "failed", "seconds": 0.5, "summary": "ValueError: boom"}
    (record,) = [r for r in caplog.records if r.name == "bodystudio.demo"]
    assert record.levelno == logging.DEBUG
    msg = record.getMessage()
    assert msg.startswith("stage muscle failed:\nTraceback (most recent call last):\n") and msg.endswith(
        "ValueError: boom\n")


def test_run_stage_needs(tmp_path, monkeypatch):
    monkeypatch.setattr(demo, "time", Clock(0.0, 0.25))
    ctx = _ctx(tmp_path)
    called = []

    def fn(c):
        called.append(c)
        return "built"

    row = demo.run_stage(ctx, "reconstruct", fn, ())
    assert row == {"stage": "reconstruct", "status": "failed", "seconds": 0.25,
                   "summary": "needs the session stage, which failed"}
    ctx.stages = [{"stage": "session", "status": "skipped"}]
    row = demo.run_stage(ctx, "reconstruct", fn, ())
    assert row == {"stage": "reconstruct", "status": "skipped", "seconds": 0.25,
                   "summary": "needs the session stage, which was skipped"}
    ctx.stages = [{"stage": "session", "status": "failed"}]
    assert demo.run_stage(ctx, "reconstruct", fn, ())["summary"] == "needs the session stage, which failed"
    assert not called
    ctx.stages = [{"stage": "bodies", "status": "failed"}, {"stage": "session", "status": "done"}]
    assert demo.run_stage(ctx, "reconstruct", fn, ())["status"] == "done" and called == [ctx]
    # a stage with no need runs whatever failed before it
    assert demo.run_stage(ctx, "rig", fn, ("reconstruct",))["summary"] == "built"
    monkeypatch.setattr(demo, "STAGE_NEEDS", {"rig": "bodies"})
    assert demo.run_stage(ctx, "rig", fn, ())["summary"] == "needs the bodies stage, which failed"


def test_stage_dependency_failed_is_a_user_error():
    assert issubclass(demo.StageDependencyFailed, BodyStudioError)
    assert issubclass(demo.DemoStageError, BodyStudioError)
    assert not issubclass(demo.StageSkipped, BodyStudioError)


# ------------------------------------------------------------------------------------------------ run_demo

@pytest.fixture
def fake_run(monkeypatch):
    """``run_demo`` with four stand-in stages, the report writer and the session views replaced by spies."""
    import rich.progress

    made = []

    class RecordingProgress(rich.progress.Progress):
        def __init__(self, *columns, **kwargs):
            made.append(self)
            self.init = (columns, kwargs)
            self.calls_log = []
            super().__init__(*columns, **kwargs)

        def add_task(self, description, **kwargs):
            self.calls_log.append(("add_task", description, kwargs))
            return super().add_task(description, **kwargs)

        def update(self, task, **kwargs):
            self.calls_log.append(("update", task, kwargs))
            return super().update(task, **kwargs)

        def advance(self, task, *args):
            self.calls_log.append(("advance", task))
            return super().advance(task, *args)

    monkeypatch.setattr(rich.progress, "Progress", RecordingProgress)
    monkeypatch.setattr(demo, "time", Clock(0.0, 1.26))
    plotters = [Plotter("a"), Plotter("b")]

    def stage_a(ctx):
        ctx.session = "SESSION"
        ctx.scenes += [("a plot", plotters[0]), ("a payload", {"dict": 1}), ("b plot", plotters[1])]
        return "A done"

    def stage_c(ctx):
        raise InputError("C broke")

    stages = [("a", stage_a), ("b", lambda ctx: "B done"), ("c", stage_c), ("d", lambda ctx: "D done")]
    monkeypatch.setattr(demo, "STAGES", stages)
    monkeypatch.setattr(demo, "STAGE_NEEDS", {})
    report = _spy(monkeypatch, "bodystudio.viewer.report.write_report",
                  fn=lambda out, path, **kw: SimpleNamespace(path=Path("REPORT")))
    views = _spy(monkeypatch, "bodystudio.demo._session_views")
    return SimpleNamespace(made=made, plotters=plotters, report=report, views=views)


def _console():
    from rich.console import Console

    return Console(record=True, width=150, force_terminal=True, color_system="standard")


def test_run_demo_rows_report_and_console(tmp_path, fake_run):
    console = _console()
    out = tmp_path / "a" / "b"
    path, stages = demo.run_demo(out, 2, 5, (80, 60), with_3d=False, console=console, skip=("d",))
    assert path == Path("REPORT")
    assert stages == [{"stage": "a", "status": "done", "seconds": 1.26, "summary": "A done"},
                      {"stage": "b", "status": "done", "seconds": 1.26, "summary": "B done"},
                      {"stage": "c", "status": "failed", "seconds": 1.26, "summary": "C broke"},
                      {"stage": "d", "status": "skipped", "seconds": 1.26, "summary": "skipped (--skip)"}]
    assert _read(out / "demo.json") == {"stages": stages}
    (args, kw), = fake_run.report.calls
    assert args == (out, out / "report.html")
    notes = ["a: done, A done", "b: done, B done", "c: failed, C broke", "d: skipped, skipped (--skip)"]
    assert kw == {"with_3d": False, "title": "bodystudio demo", "scenes": [
        ("a plot", fake_run.plotters[0]), ("a payload", {"dict": 1}), ("b plot", fake_run.plotters[1])],
        "notes": notes}
    (ctx,), _ = fake_run.views.calls[0]
    assert len(fake_run.views.calls) == 1 and ctx.session == "SESSION"
    assert (ctx.out, ctx.cameras, ctx.frames, ctx.resolution, ctx.console) == (out, 2, 5, (80, 60), console)
    assert [p.closed for p in fake_run.plotters] == [1, 1]
    text = console.export_text(clear=False)
    for line in ("a: done (1.3 s) A done", "b: done (1.3 s) B done", "c: failed (1.3 s) C broke",
                 "d: skipped (1.3 s) skipped (--skip)"):
        assert line + "\n" in text, text
    styled = console.export_text(styles=True)
    assert "\x1b[32ma: done\x1b[0m \x1b[1m(\x1b[0m\x1b[1;36m1.3\x1b[0m s" in styled
    assert "\x1b[31mc: failed\x1b[0m" in styled
    assert "\x1b[33md: skipped\x1b[0m" in styled, styled
    (progress,) = fake_run.made
    columns, kwargs = progress.init
    assert kwargs == {"console": console, "transient": False}
    assert [type(c).__name__ for c in columns] == ["TextColumn", "BarColumn", "TextColumn", "TimeElapsedColumn"]
    assert (columns[0].text_format, columns[2].text_format) == ("{task.description:<12}",
                                                               "{task.completed}/{task.total}")
    assert ctx.progress is progress
    task = progress.calls_log[0][2:]
    assert progress.calls_log[0][:2] == ("add_task", "demo") and task == ({"total": 5},)
    tid = next(iter(progress.tasks)).id
    assert progress.calls_log[1:] == [
        ("update", tid, {"description": "demo: a"}), ("advance", tid), ("update", tid, {"description": "demo: b"}),
        ("advance", tid), ("update", tid, {"description": "demo: c"}), ("advance", tid),
        ("update", tid, {"description": "demo: d"}), ("advance", tid), ("update", tid, {"description": "demo: report"}),
        ("advance", tid)]
    assert "demo: report" in text and "5/5" in text


def test_run_demo_without_a_session_skips_its_views(tmp_path, fake_run, monkeypatch):
    monkeypatch.setattr(demo, "STAGES", [("b", lambda ctx: "B done")])
    path, stages = demo.run_demo(tmp_path / "o", console=_console())
    assert not fake_run.views.calls and [r["status"] for r in stages] == ["done"]
    assert fake_run.report.calls[0][1]["with_3d"] is True


def test_run_demo_defaults_are_the_cli_defaults(tmp_path, fake_run):
    import inspect

    api = inspect.signature(demo.run_demo).parameters
    assert [(n, p.default) for n, p in api.items() if p.default is not inspect.Parameter.empty] == [
        ("cameras", 4), ("frames", 3), ("resolution", (320, 240)), ("with_3d", True), ("console", None), ("skip", ())]
    demo.run_demo(tmp_path / "o", console=_console())
    (ctx,), _ = fake_run.views.calls[0]
    assert (ctx.cameras, ctx.frames, ctx.resolution) == (4, 3, (320, 240))


def test_run_demo_makes_its_own_console(tmp_path, fake_run, monkeypatch):
    import sys

    import rich.console

    made = []
    real = rich.console.Console

    def console(*args, **kwargs):
        made.append((args, kwargs))
        return real(record=True, **kwargs)

    monkeypatch.setattr(rich.console, "Console", console)
    monkeypatch.setattr(sys.stdout, "isatty", lambda: False, raising=False)
    demo.run_demo(tmp_path / "o")
    assert made == [((), {"width": 120})]
    monkeypatch.setattr(sys.stdout, "isatty", lambda: True, raising=False)
    demo.run_demo(tmp_path / "o2")
    assert made[1] == ((), {})


def test_run_demo_refusals_before_any_output(tmp_path, fake_run, monkeypatch):
    monkeypatch.setattr(demo, "STAGES", [("bodies", None), ("session", None), ("rig", None)])
    out = tmp_path / "new"
    cases = [
        (dict(skip=("rig", "nope", "zap")), "--skip nope: not a demo stage; stages are bodies, session, rig"),
        (dict(cameras=0), "need at least one camera and one frame, got --cameras 0 --frames 3"),
        (dict(frames=0, cameras=2), "need at least one camera and one frame, got --cameras 2 --frames 0"),
        (dict(cameras=-1, frames=-2), "need at least one camera and one frame, got --cameras -1 --frames -2"),
    ]
    for kwargs, message in cases:
        with pytest.raises(InputError) as exc:
            demo.run_demo(out, console=_console(), **kwargs)
        assert str(exc.value) == message
        assert not out.exists()
    afile = tmp_path / "file"
    afile.write_text("x")
    with pytest.raises(InputError) as exc:
        demo.run_demo(str(afile), console=_console())
    assert str(exc.value) == f"{afile}: exists and is not a folder; choose a folder for the demo output"
    assert not fake_run.report.calls


def test_run_demo_accepts_one_camera_and_one_frame(tmp_path, fake_run, monkeypatch):
    monkeypatch.setattr(demo, "STAGES", [("b", lambda ctx: f"{ctx.cameras} {ctx.frames}")])
    out = tmp_path / "x" / "y"
    _, stages = demo.run_demo(str(out), cameras=1, frames=1, console=_console())
    assert stages[0]["summary"] == "1 1" and (out / "demo.json").is_file()
    assert fake_run.report.calls[0][0] == (out, out / "report.html")
    demo.run_demo(out, console=_console())  # an existing folder is fine


# ------------------------------------------------------------------------------------------------ the CLI

def _invoke(args):
    from typer.testing import CliRunner

    from bodystudio.cli.main import app

    return CliRunner().invoke(app, [str(a) for a in args])


@pytest.fixture
def cli_spy(monkeypatch):
    rows = [{"stage": "bodies", "status": "done", "summary": "ok"}]
    spy = _spy(monkeypatch, "bodystudio.demo.run_demo", fn=lambda out, *a, **k: (Path(out) / "report.html", rows))
    spy.rows = rows
    return spy


def test_cli_demo_defaults(tmp_path, cli_spy, monkeypatch):
    monkeypatch.chdir(tmp_path)
    res = _invoke(["demo"])
    assert res.exit_code == 0, (res.output, res.exception)
    assert cli_spy.calls == [((Path("demo-out"), 4, 3, (320, 240)), {"with_3d": True, "skip": ()})]
    assert res.stdout == f"report: {tmp_path.resolve() / 'demo-out' / 'report.html'}\n"


def test_cli_demo_every_option(tmp_path, cli_spy):
    res = _invoke(["demo", "--out", tmp_path / "o", "--cameras", "6", "--frames", "2", "--resolution", "640X480",
                   "--no-3d", "--skip", "rig", "--skip", "garment"])
    assert res.exit_code == 0, (res.output, res.exception)
    assert cli_spy.calls == [((tmp_path / "o", 6, 2, (640, 480)), {"with_3d": False, "skip": ("rig", "garment")})]


def test_cli_demo_failed_stage_is_exit_2_after_the_report_line(tmp_path, cli_spy):
    cli_spy.rows.append({"stage": "rig", "status": "failed", "summary": "no scan"})
    res = _invoke(["demo", "--out", tmp_path / "o"])
    assert isinstance(res.exception, demo.DemoStageError)
    assert res.stdout == f"report: {(tmp_path / 'o' / 'report.html').resolve()}\n"
    assert str(res.exception) == (f"stages failed: rig (rig: no scan); messages in {tmp_path / 'o' / 'demo.json'}, "
                                  f"report still written to {tmp_path / 'o' / 'report.html'}")


def test_cli_demo_refuses_a_file_as_out_before_running(tmp_path, cli_spy):
    f = tmp_path / "f"
    f.write_text("x")
    res = _invoke(["demo", "--out", f])
    assert isinstance(res.exception, InputError)
    assert str(res.exception) == f"demo --out {f}: exists and is a file, not a folder; choose a folder path"
    assert not cli_spy.calls


def test_cli_demo_help_names_every_stage_but_bodies():
    res = _invoke(["demo", "--help"])
    text = " ".join(res.stdout.replace("│", " ").split())
    assert " stage to leave out (repeat): session, calibrate, reconstruct, rig, muscle, mirror, garment " in f" {text} "
    for phrase in ("output folder", "studio cameras in the synthetic session", "frames in the synthetic session",
                   "camera image size WxH", "leave the 3D views out of the report",
                   "Run the main job on the built-in synthetic studio and write an HTML report (exit 2 if a stage "
                   "fails)."):
        assert f" {phrase} " in f" {text} ", phrase


@pytest.mark.parametrize("value", ["63x240", "320x63", "8193x240", "320x8193", "320", "axb", "320x240x3"])
def test_cli_demo_refuses_a_bad_resolution_naming_its_own_option(tmp_path, cli_spy, value):
    res = _invoke(["demo", "--out", tmp_path / "o", "--resolution", value])
    assert isinstance(res.exception, InputError)
    assert str(res.exception) == f"--resolution {value!r} is not WxH between 64 and 8192, e.g. 1024x768"
    assert not cli_spy.calls and not (tmp_path / "o").exists()


@pytest.mark.parametrize("value, size", [("64x64", (64, 64)), ("8192x8192", (8192, 8192))])
def test_cli_demo_accepts_the_resolution_bounds(tmp_path, cli_spy, value, size):
    res = _invoke(["demo", "--out", tmp_path / "o", "--resolution", value])
    assert res.exit_code == 0, (res.output, res.exception)
    assert cli_spy.calls[0][0][3] == size
