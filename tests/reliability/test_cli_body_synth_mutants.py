"""``bodystudio body export / info / measure / assets``, ``synth mirror`` and ``recover`` through typer's CliRunner
with the API replaced by spies (mutNN).

Each option reaches the API unchanged, each printed line / JSON holds the API's figures (rounded as the help says,
read back with ``json.loads``), and each refusal is a one-line error with its whole message before any work. No
body is built: the file runs in about a second.
"""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from bodystudio.errors import FileFormatError, InputError
from tests.reliability.cli_spies import help_text as _help
from tests.reliability.cli_spies import invoke as _invoke
from tests.reliability.cli_spies import refused as _refused
from tests.reliability.cli_spies import spy as _spy


@pytest.fixture(autouse=True)
def _cwd(monkeypatch, tmp_path):
    monkeypatch.chdir(tmp_path)


# ------------------------------------------------------------------------------------------------ parse_assignments

def test_parse_assignments_by_hand():
    from bodystudio.cli.body import parse_assignments

    assert parse_assignments(None, "--local") == {}
    assert parse_assignments([" a-b =0.5", "c=-1", "d=1e-1"], "--local") == {"a-b": 0.5, "c": -1.0, "d": 0.1}
    for bad in ("a", "=0.5", " =1", "a=", "a=b", "a:0.5", "x=1=2"):
        with pytest.raises(InputError) as exc:
            parse_assignments([bad], "--local")
        assert str(exc.value) == (f"--local {bad!r} is not NAME=VALUE with a number, e.g. "
                                  "upperarm-fat-decr-incr=0.5")
    with pytest.raises(InputError) as exc:
        parse_assignments(["a=1", " a =2"], "--x")
    assert str(exc.value) == "--x a: given twice; give each once"


# ------------------------------------------------------------------------------------------------ body export

class Body:
    def __init__(self):
        self.vertices = np.array([[0.0, 0.1, 0.0], [0.0, 1.23456, 0.0], [0.1, 0.5, 0.0]])
        self.faces = np.array([[0, 1, 2], [0, 2, 1]])
        self.n_vertices = 3
        self.skeleton = SimpleNamespace(bone_names=["root", "spine"], n_bones=2)
        self.posed = []

    def pose(self, pose, method):
        self.posed.append((pose, method))
        return self.vertices + 1.0, "joints"


@pytest.fixture
def export_api(monkeypatch):
    body = Body()
    ns = SimpleNamespace(body=body, build=_spy(monkeypatch, "bodystudio.body.build_body", ret=body),
                         load_pose=_spy(monkeypatch, "bodystudio.body.load_pose", ret="POSE"),
                         save=_spy(monkeypatch, "bodystudio.geometry.mesh.save_mesh"))
    return ns


def test_body_export_defaults(export_api):
    res = _invoke(["body", "export", "b.ply"])
    assert res.exit_code == 0, (res.output, res.exception)
    (phenotype, local), kw = export_api.build.calls[0]
    assert (phenotype.gender, phenotype.age, phenotype.muscle, phenotype.weight, phenotype.height,
            phenotype.proportions) == (0.5,) * 6
    assert (phenotype.african, phenotype.asian, phenotype.caucasian) == pytest.approx((1 / 3,) * 3, abs=1e-15)
    assert local == {} and kw == {"resolution": "full", "rig": "game_engine"}
    assert not export_api.load_pose.calls and not export_api.body.posed
    (out, mesh), _ = export_api.save.calls[0]
    assert out == Path("b.ply")
    np.testing.assert_array_equal(mesh.vertices, export_api.body.vertices)
    np.testing.assert_array_equal(mesh.faces, export_api.body.faces)
    assert res.stdout == "wrote b.ply (3 vertices, 2 triangles, stature 1.235 m)\n"


def test_body_export_every_option(export_api):
    res = _invoke(["body", "export", "b.GLB", "--gender", "1", "--age", "0.25", "--muscle", "0.1", "--weight", "0.2",
                   "--height", "0.3", "--proportions", "0.4", "--african", "0.6", "--asian", "0.3", "--caucasian",
                   "0.1", "--local", "a=0.5", "--local", "b=-0.25", "--pose", "p.json", "--resolution", "2k",
                   "--rig", "cmu_mb", "--skinning", "dqs"])
    assert res.exit_code == 0, (res.output, res.exception)
    (phenotype, local), kw = export_api.build.calls[0]
    assert (phenotype.gender, phenotype.age, phenotype.muscle, phenotype.weight, phenotype.height,
            phenotype.proportions) == (1.0, 0.25, 0.1, 0.2, 0.3, 0.4)
    assert (phenotype.african, phenotype.asian, phenotype.caucasian) == pytest.approx((0.6, 0.3, 0.1))
    assert local == {"a": 0.5, "b": -0.25} and kw == {"resolution": "2k", "rig": "cmu_mb"}
    assert export_api.load_pose.calls == [((Path("p.json"), ["root", "spine"]), {})]
    assert export_api.body.posed == [("POSE", "dqs")]
    (out, mesh), _ = export_api.save.calls[0]
    np.testing.assert_array_equal(mesh.vertices, export_api.body.vertices + 1.0)
    assert res.stdout == "wrote b.GLB (3 vertices, 2 triangles, stature 1.235 m)\n"  # the rest pose's stature


def test_body_export_refusals(export_api):
    _refused(_invoke(["body", "export", "b.stl"]), "body export b.stl: unsupported output format; use .ply or .obj or "
             ".glb")
    _refused(_invoke(["body", "export", "b.ply", "--local", "a"]),
             "--local 'a' is not NAME=VALUE with a number, e.g. upperarm-fat-decr-incr=0.5")
    assert not export_api.build.calls and not export_api.save.calls


def test_body_export_help():
    text = _help(["body", "export"])
    for phrase in ("output mesh: .ply, .obj or .glb", "0 female .. 1 male",
                   "0 = 1 year, 0.1875 = 10, 0.5 = 25, 1 = 90 years (piecewise linear)", "0 uncommon .. 1 ideal",
                   "ethnic weight in [0, 1] (the three are normalised to sum 1)",
                   "local modifier NAME=VALUE in [-1, 1] (repeat)",
                   "pose JSON (axis-angle 'rotations' or MPFB 'bone_rotations')", "full | 6k | 2k",
                   "game_engine | default | default_no_toes | cmu_mb", "lbs | dqs",
                   "Build a body from phenotype and local modifiers, optionally pose it, and write the mesh."):
        assert f" {phrase} " in f" {text} ", phrase


# ------------------------------------------------------------------------------------------------ body info

def test_body_info_json(monkeypatch):
    sizes = {"full": 13380, "6k": 6002, "2k": 2502}

    def build(resolution="full", rig="game_engine"):
        b = Body()
        b.n_vertices = sizes[resolution]
        b.faces = np.zeros((sizes[resolution] * 2, 3))
        b.vertices = np.array([[0, 1.6 + len(resolution) / 100 + 0.000049, 0]])
        b.skeleton = SimpleNamespace(n_bones={"game_engine": 53, "cmu_mb": 31}[rig])
        b.rig = rig
        return b

    build_spy = _spy(monkeypatch, "bodystudio.body.build_body", fn=build)
    measure = _spy(monkeypatch, "bodystudio.body.measure.measure_body",
                   ret={"stature_m": 1.612345, "mass_kg": 60.00004})
    res = _invoke(["body", "info"])
    assert res.exit_code == 0, (res.output, res.exception)
    out = json.loads(res.stdout)
    assert list(out.items()) == [
        ("full", {"vertices": 13380, "faces": 26760, "joints": 53}),
        ("6k", {"vertices": 6002, "faces": 12004, "joints": 53}),
        ("2k", {"vertices": 2502, "faces": 5004, "joints": 53}),
        ("default_body", {"stature_m": 1.62, "rig": "game_engine",
                          "attributes": {"stature_m": 1.6123, "mass_kg": 60.0}})]
    assert build_spy.calls[:3] == [((), {"resolution": r, "rig": "game_engine"}) for r in ("full", "6k", "2k")]
    assert build_spy.calls[3] == ((), {"rig": "game_engine"})
    assert measure.calls[0][0][0].rig == "game_engine"
    assert res.stdout.startswith('{\n  "full": {\n    "vertices"')
    res = _invoke(["body", "info", "--rig", "cmu_mb"])
    out = json.loads(res.stdout)
    assert out["6k"]["joints"] == 31 and out["default_body"]["rig"] == "cmu_mb"
    assert build_spy.calls[-1] == ((), {"rig": "cmu_mb"})


def test_body_info_modifiers(monkeypatch):
    base = _spy(monkeypatch, "bodystudio.body.makehuman.load_base", ret=SimpleNamespace(data_dir="D"))
    mods = _spy(monkeypatch, "bodystudio.body.phenotype.local_modifiers", ret={"b-x": 1, "a-y": 2, "c": 3})
    build = _spy(monkeypatch, "bodystudio.body.build_body")
    res = _invoke(["body", "info", "--modifiers"])
    assert res.exit_code == 0, (res.output, res.exception)
    assert res.stdout == "a-y\nb-x\nc\n" and mods.calls == [(("D",), {})] and base.calls and not build.calls


def test_body_info_help():
    text = _help(["body", "info"])
    for phrase in ("list the local modifier names", "rig whose joints are counted",
                   "Vertex, face and joint counts of each template resolution, and the default body's stature."):
        assert f" {phrase} " in f" {text} ", phrase


# ------------------------------------------------------------------------------------------------ body measure

def test_body_measure_json(monkeypatch):
    from bodystudio.body.measure import MESH_ATTRIBUTE_NAMES

    mesh = SimpleNamespace(vertices="V", faces="F")
    load = _spy(monkeypatch, "bodystudio.geometry.mesh.load_mesh", ret=mesh)
    values = {k: 1.0 + k_i + 0.123456 for k_i, k in enumerate(MESH_ATTRIBUTE_NAMES)}
    values["extra"] = 9.0
    attrs = _spy(monkeypatch, "bodystudio.body.measure.measure_attributes", ret=values)
    res = _invoke(["body", "measure", "m.ply"])
    assert res.exit_code == 0, (res.output, res.exception)
    assert load.calls == [((Path("m.ply"),), {})] and attrs.calls == [(("V", "F"), {"resolution": None})]
    assert list(json.loads(res.stdout).items()) == [(k, round(1.0 + k_i + 0.123456, 5))
                                                    for k_i, k in enumerate(MESH_ATTRIBUTE_NAMES)]
    assert json.loads(res.stdout)[MESH_ATTRIBUTE_NAMES[0]] == 1.12346
    assert res.stdout.startswith('{\n  "')
    _invoke(["body", "measure", "m.ply", "--resolution", "6k"])
    assert attrs.calls[1] == (("V", "F"), {"resolution": "6k"})


def test_body_measure_wrong_topology_names_the_file(monkeypatch):
    _spy(monkeypatch, "bodystudio.geometry.mesh.load_mesh", ret=SimpleNamespace(vertices="V", faces="F"))

    def refuse(*a, **k):
        raise InputError("123 vertices is not a template's count")

    _spy(monkeypatch, "bodystudio.body.measure.measure_attributes", fn=refuse)
    _refused(_invoke(["body", "measure", "m.ply"]), "m.ply: 123 vertices is not a template's count", FileFormatError)


def test_body_measure_help():
    text = _help(["body", "measure"])
    for phrase in ("rest-pose body mesh in bodystudio's topology (full, 6k or 2k template)",
                   "full | 6k | 2k (default: detected from the vertex count)",
                   "Print the mesh's stature, mass, chest/waist/hip girths, arm and leg length as JSON."):
        assert f" {phrase} " in f" {text} ", phrase


# ------------------------------------------------------------------------------------------------ body assets

@pytest.fixture
def assets_api(monkeypatch):
    monkeypatch.delenv("BODYSTUDIO_MAKEHUMAN_DIR", raising=False)
    return SimpleNamespace(
        fetch=_spy(monkeypatch, "bodystudio.body.assets.fetch_assets"),
        targets=_spy(monkeypatch, "bodystudio.body.assets.compiled_targets_path", ret=Path("T.npz")),
        data=_spy(monkeypatch, "bodystudio.body.assets.makehuman_data_dir", ret=Path("MH")))


def test_body_assets(assets_api, monkeypatch):
    res = _invoke(["body", "assets"])
    assert res.exit_code == 0, (res.output, res.exception)
    assert not assets_api.fetch.calls and len(assets_api.targets.calls) == 1
    assert res.stdout == "body assets ready: MH (compiled targets: T.npz)\n"
    res = _invoke(["body", "assets", "--force", "--quiet"])
    assert res.stdout == "" and assets_api.fetch.calls == [((), {"force": True})]
    assert len(assets_api.targets.calls) == 2
    monkeypatch.setenv("BODYSTUDIO_MAKEHUMAN_DIR", "/somewhere")
    _invoke(["body", "assets", "--force"])
    assert len(assets_api.fetch.calls) == 1  # a user's own MPFB2 folder is never re-downloaded
    monkeypatch.setenv("BODYSTUDIO_MAKEHUMAN_DIR", "")
    _invoke(["body", "assets", "--force"])
    assert len(assets_api.fetch.calls) == 2
    assert " download and extract again " in _help(["body", "assets"])


# ------------------------------------------------------------------------------------------------ synth mirror

@pytest.fixture
def mirror_spy(monkeypatch):
    class S:
        def __len__(self):
            return 40

    return _spy(monkeypatch, "bodystudio.mirror.synthetic.synth_mirror_session", ret=S())


def test_synth_mirror_defaults(mirror_spy):
    res = _invoke(["synth", "mirror", "m", "--subject-seed", "3"])
    assert res.exit_code == 0, (res.output, res.exception)
    assert mirror_spy.calls == [((Path("m"), 3), dict(n_frames=120, actors=1, edits={}, version="v2",
                                                     motion="arms_raise", seed=0, progress=True, walk_in=True))]
    assert res.stdout == "wrote m: 40 frames, 1 actor(s), Kinect v2, edits: none\n"


def test_synth_mirror_every_option(mirror_spy):
    res = _invoke(["synth", "mirror", "m", "--subject-seed", "0", "--frames", "11", "--actors", "2", "--kinect", "v1",
                   "--motion", "t_pose", "--seed", "5", "--taller", "0.1", "--heavier", "-5", "--muscular", "0.2",
                   "--chest", "0.03", "--waist", "-0.02", "--hips", "0", "--no-walk-in", "--no-progress"])
    assert res.exit_code == 0, (res.output, res.exception)
    edits = {"taller": 0.1, "heavier": -5.0, "muscular": 0.2, "chest": 0.03, "waist": -0.02}
    assert mirror_spy.calls == [((Path("m"), 0), dict(n_frames=11, actors=2, edits=edits, version="v1",
                                                     motion="t_pose", seed=5, progress=False, walk_in=False))]
    assert list(mirror_spy.calls[0][1]["edits"]) == ["taller", "heavier", "muscular", "chest", "waist"]
    assert res.stdout == ("wrote m: 40 frames, 2 actor(s), Kinect v1, edits: taller +0.1, heavier -5, muscular +0.2, "
                          "chest +0.03, waist -0.02\n")


@pytest.mark.parametrize("args, message", [
    (["--actors", "0"], "--actors 0: a mirror session has 1 or 2 actors"),
    (["--actors", "3"], "--actors 3: a mirror session has 1 or 2 actors"),
    (["--kinect", "v3"], "--kinect 'v3': valid: v1, v2"),
    (["--motion", "dance"], "--motion 'dance': valid: arms_raise, walk, turn, arm_flex, a_pose, t_pose"),
    (["--frames", "10"], "--frames 10: must be in [11, 9000] (the first 10 show the empty room)"),
    (["--frames", "9001"], "--frames 9001: must be in [11, 9000] (the first 10 show the empty room)"),
    (["--subject-seed", "-1"], "--subject-seed -1: must be in [0, 2147483646]"),
    (["--subject-seed", "2147483647"], "--subject-seed 2147483647: must be in [0, 2147483646]"),
    (["--seed", "-1"], "--seed -1: must be in [0, 2147483647]"),
    (["--seed", "2147483648"], "--seed 2147483648: must be in [0, 2147483647]"),
    (["--taller", "nan"], "--taller nan: must be a finite number"),
    (["--hips", "inf"], "--hips inf: must be a finite number"),
    (["--heavier", "-inf"], "--heavier -inf: must be a finite number"),
    (["--taller", "5"], "edit taller=5.0 is out of range: use -0.3 to +0.3 m"),
])
def test_synth_mirror_refusals(mirror_spy, args, message):
    base = ["synth", "mirror", "m", "--subject-seed", "1"]
    res = _invoke(base + args)
    assert isinstance(res.exception, InputError), (res.output, res.exception)
    assert str(res.exception) == message
    assert not mirror_spy.calls


def test_synth_mirror_bounds_accepted(mirror_spy):
    for args in (["--frames", "9000", "--subject-seed", "2147483646", "--seed", "2147483647"],
                 ["--frames", "11", "--subject-seed", "0", "--seed", "0", "--actors", "2"]):
        res = _invoke(["synth", "mirror", "m", *args])
        assert res.exit_code == 0, (res.output, res.exception)
    Path("full").mkdir()
    (Path("full") / "x").write_text("x")
    _refused(_invoke(["synth", "mirror", "full", "--subject-seed", "1"]),
             "session folder full: exists and is not empty; choose a new folder")
    assert len(mirror_spy.calls) == 2


def test_synth_mirror_help():
    text = _help(["synth", "mirror"])
    for phrase in ("actor 1 from the population (seed); actor 2: +1",
                   "frames at 30 fps; the first 10 show the empty room", "1 or 2 actors",
                   "v1 (depth 320x240) | v2 (depth 512x424); colour 640x480",
                   "arms_raise | walk | turn | arm_flex | a_pose | t_pose", "motion variation and sensor noise",
                   "edit: stature change (m)", "edit: mass change (kg)", "edit: muscularity change (model units)",
                   "edit: chest girth change (m)", "edit: waist girth change (m)", "edit: hip girth change (m)",
                   "actors walk in (else appear in place)", "progress bar on a terminal"):
        assert f" {phrase} " in f" {text} ", phrase


# ------------------------------------------------------------------------------------------------ recover

def test_recover_prints_each_line(monkeypatch):
    rec = _spy(monkeypatch, "bodystudio.runfolder.recover", ret=["finished a", "discarded b"])
    res = _invoke(["recover", "x.glb"])
    assert res.exit_code == 0, (res.output, res.exception)
    assert rec.calls == [((Path("x.glb"),), {})] and res.stdout == "finished a\ndiscarded b\n"
    text = _help(["recover"])
    assert " session or reconstruct folder, avatar .glb, or cameras.json whose write was interrupted " in text
    assert (" Complete a write killed after its commit point, or discard one killed before it (the previous result "
            "stays). ") in text
