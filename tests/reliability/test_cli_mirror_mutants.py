"""``bodystudio mirror init`` / ``mirror run`` through typer's CliRunner with the API replaced by spies (mutKK).

Each option must reach the API unchanged, the CLI's defaults must equal the API's, and every refusal must be a
:class:`InputError` (the console script's one line and exit 2) raised before the API is called. The expected
arguments and summaries are written out by hand from the command's help, not recomputed by the CLI's code.
No model is loaded and no session is fitted: the whole file runs in about a second.
"""

from __future__ import annotations

import inspect
import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from bodystudio.errors import InputError
from tests.reliability.cli_spies import invoke as _invoke


def _refused(res, phrase):
    assert isinstance(res.exception, InputError), (res.exit_code, res.output, res.exception)
    assert res.exit_code != 0
    assert phrase in str(res.exception), str(res.exception)
    assert "\n" not in str(res.exception)


# ------------------------------------------------------------------------------------------ mirror run

class RunSpy:
    def __init__(self):
        self.calls = []

    def __call__(self, session, edits, out_video, **kwargs):
        self.calls.append(dict(session=session, edits=edits, out_video=out_video, **kwargs))
        return {"summary": {"frames": 3, "fps": 30.0}, "videos": ["v.mp4"], "edits": {"e": 1}}


@pytest.fixture
def run_spy(monkeypatch):
    import bodystudio.mirror.run as run_mod

    spy = RunSpy()
    spy.real = run_mod.run_mirror
    monkeypatch.setattr(run_mod, "run_mirror", spy)
    return spy


def _session(tmp_path) -> Path:
    s = tmp_path / "sess"
    s.mkdir()
    return s


def test_run_defaults_reach_the_api_as_its_own_defaults(tmp_path, run_spy):
    s = _session(tmp_path)
    res = _invoke(["mirror", "run", s, "--out", tmp_path / "o.mp4"])
    assert res.exit_code == 0, (res.output, res.exception)
    (call,) = run_spy.calls
    assert call == dict(session=s, edits={}, out_video=tmp_path / "o.mp4", source=None, side_by_side=True,
                        progress=True, run_dir=None, player=1, kind="similarity", ramp_frames=30, live=None,
                        live_timeout_s=5.0, correspondence="dense", refine_pose=True, accept_implausible=False,
                        video_preset="veryfast")
    assert type(call["player"]) is int
    api = inspect.signature(run_spy.real).parameters  # the real function's defaults
    for name in ("side_by_side", "kind", "ramp_frames", "live", "live_timeout_s", "correspondence", "refine_pose",
                 "accept_implausible", "video_preset", "run_dir", "source", "player"):
        assert call[name] == api[name].default, name
    printed = json.loads(res.stdout)
    assert printed == {"run": str(s / "mirror" / "run"), "videos": ["v.mp4"], "edits": {"e": 1}, "frames": 3,
                       "fps": 30.0}
    assert res.stdout.startswith('{\n "run"')  # indent=1


def test_run_every_option_reaches_the_api(tmp_path, run_spy):
    s = _session(tmp_path)
    live = tmp_path / "live"
    res = _invoke(["mirror", "run", s, "--out", tmp_path / "o.mp4", "--taller", "0.1", "--heavier", "5",
                   "--muscular", "0.3", "--chest", "0.02", "--waist", "-0.03", "--hips", "0.04",
                   "--source", tmp_path / "a.npz", "--player", "2", "--run", tmp_path / "r", "--warp", "rigid",
                   "--correspondence", "mls", "--no-refine-pose", "--ramp-frames", "7", "--no-side-by-side",
                   "--video-preset", "ultrafast", "--live", live, "--live-timeout", "2.5", "--accept-implausible"])
    assert res.exit_code == 0, (res.output, res.exception)
    (call,) = run_spy.calls
    assert call == dict(session=s, edits={"taller": 0.1, "heavier": 5.0, "muscular": 0.3, "chest": 0.02,
                                          "waist": -0.03, "hips": 0.04},
                        out_video=tmp_path / "o.mp4", source=tmp_path / "a.npz", side_by_side=False, progress=True,
                        run_dir=tmp_path / "r", player=2, kind="rigid", ramp_frames=7, live=str(live),
                        live_timeout_s=2.5, correspondence="mls", refine_pose=False, accept_implausible=True,
                        video_preset="ultrafast")
    assert json.loads(res.stdout)["run"] == str(tmp_path / "r")


def test_run_zero_edits_are_left_out(tmp_path, run_spy):
    s = _session(tmp_path)
    res = _invoke(["mirror", "run", s, "--out", tmp_path / "o.mp4", "--taller", "0", "--heavier", "-2",
                   "--hips", "0.0", "--side-by-side", "--refine-pose"])
    assert res.exit_code == 0, (res.output, res.exception)
    (call,) = run_spy.calls
    assert call["edits"] == {"heavier": -2.0}
    assert call["side_by_side"] is True and call["refine_pose"] is True


def test_run_several_players_get_lists(tmp_path, run_spy):
    s = _session(tmp_path)
    res = _invoke(["mirror", "run", s, "--out", tmp_path / "o.mp4", "--player", "3", "--player", "1",
                   "--source", tmp_path / "b.npz", "--source", tmp_path / "a.npz"])
    assert res.exit_code == 0, (res.output, res.exception)
    assert run_spy.calls[0]["player"] == [3, 1]
    assert run_spy.calls[0]["source"] == [tmp_path / "b.npz", tmp_path / "a.npz"]
    res = _invoke(["mirror", "run", s, "--out", tmp_path / "o.mp4", "--player", "2", "--player", "4"])
    assert res.exit_code == 0, (res.output, res.exception)
    assert run_spy.calls[1]["player"] == [2, 4] and run_spy.calls[1]["source"] is None


@pytest.mark.parametrize("args, phrase", [
    (["--source", "a.npz"], "--source given 1 times for 2 players; give one --source per --player"),
    (["--source", "a.npz", "--source", "b.npz", "--source", "c.npz"], "--source given 3 times for 2 players"),
])
def test_run_refuses_sources_not_one_per_player(tmp_path, run_spy, args, phrase):
    s = _session(tmp_path)
    res = _invoke(["mirror", "run", s, "--out", tmp_path / "o.mp4", "--player", "1", "--player", "2", *args])
    _refused(res, phrase)
    assert run_spy.calls == []


def test_run_refuses_a_missing_session_and_a_file(tmp_path, run_spy):
    _refused(_invoke(["mirror", "run", tmp_path / "nope", "--out", tmp_path / "o.mp4"]),
             f"{tmp_path / 'nope'}: no such session folder")
    (tmp_path / "f").write_text("x")
    _refused(_invoke(["mirror", "run", tmp_path / "f", "--out", tmp_path / "o.mp4"]), "no such session folder")
    assert run_spy.calls == []


@pytest.mark.parametrize("value, ok", [("0.05", False), ("0.1", True), ("3600", True), ("3601", False),
                                       ("-1", False)])
def test_run_live_timeout_bounds(tmp_path, run_spy, value, ok):
    s = _session(tmp_path)
    res = _invoke(["mirror", "run", s, "--out", tmp_path / "o.mp4", "--live-timeout", value])
    if ok:
        assert res.exit_code == 0, (res.output, res.exception)
        assert run_spy.calls[0]["live_timeout_s"] == float(value)
    else:
        _refused(res, f"--live-timeout {float(value)}: use 0.1..3600 seconds")
        assert run_spy.calls == []


def _write_run_json(folder: Path, text: str) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "run.json").write_text(text)


@pytest.mark.parametrize("layout, ok", [
    ("missing", True),
    ("empty", True),
    ("hidden-only", True),
    ("mirror-run", True),
    ("other-format", False),
    ("no-format", False),
    ("bad-json", False),
    ("list-json", False),
    ("file", False),
    ("unreadable-run-json", False),
])
@pytest.mark.parametrize("given", [True, False])
def test_run_folder_check(tmp_path, run_spy, layout, ok, given):
    s = _session(tmp_path)
    run = tmp_path / "r" if given else s / "mirror" / "run"
    if layout == "empty":
        run.mkdir(parents=True)
    elif layout == "hidden-only":
        run.mkdir(parents=True)
        (run / ".lock").write_text("")
    elif layout == "mirror-run":
        _write_run_json(run, json.dumps({"format": "bodystudio-mirror-run"}))
    elif layout == "other-format":
        _write_run_json(run, json.dumps({"format": "bodystudio-reconstruction"}))
    elif layout == "no-format":
        _write_run_json(run, json.dumps({"frames": []}))
    elif layout == "bad-json":
        _write_run_json(run, "{not json")
    elif layout == "list-json":
        _write_run_json(run, json.dumps(["bodystudio-mirror-run"]))
    elif layout == "file":
        run.mkdir(parents=True)
        (run / "mesh.ply").write_text("x")
    elif layout == "unreadable-run-json":
        (run / "run.json").mkdir(parents=True)  # a folder named run.json: OSError on read
    args = ["mirror", "run", s, "--out", tmp_path / "o.mp4"] + (["--run", run] if given else [])
    res = _invoke(args)
    if ok:
        assert res.exit_code == 0, (res.output, res.exception)
        assert len(run_spy.calls) == 1
    else:
        first = "mesh.ply" if layout == "file" else "run.json"
        _refused(res, f"--run {run}: holds other files ({first}, ...), not a mirror run; give a new or empty "
                      "folder, or a previous `mirror run` folder")
        assert run_spy.calls == []


def test_run_folder_check_reads_utf8(tmp_path, monkeypatch):
    """run.json is read as UTF-8 whatever the locale (a non-ASCII value in a previous run's record)."""
    from bodystudio.cli.mirror_run import _check_run_folder

    run = tmp_path / "r"
    _write_run_json(run, json.dumps({"format": "bodystudio-mirror-run", "note": "\u00e9t\u00e9"},
                                    ensure_ascii=False))
    real = Path.read_text

    def strict(self, encoding=None, errors=None):
        assert encoding == "utf-8", encoding
        return real(self, encoding=encoding, errors=errors)

    monkeypatch.setattr(Path, "read_text", strict)
    _check_run_folder(run)  # no error


# ------------------------------------------------------------------------------------------ mirror init

class InitSpies:
    def __init__(self, path: Path, n_frames: int = 1000, frames_used=(4, 5, 6, 7, 8, 9, 10, 11)):
        self.session = SimpleNamespace(path=path, frame_ids=list(range(n_frames)))
        self.frames_used = tuple(frames_used)
        self.calls = {"open": [], "model": [], "init": [], "measure": [], "check": [], "save": []}

    def open_session(self, p):
        self.calls["open"].append(p)
        return self.session

    def load_model(self, resolution, progress=True):
        self.calls["model"].append((resolution, progress))
        spies = self

        class Model:
            def measure(self, coeffs):
                spies.calls["measure"].append(coeffs)
                return {"stature_m": 1.234567, "mass_kg": 70.12789, "chest_m": 1.0}

        self.model = Model()
        return self.model

    def initialise(self, s, model, **kwargs):
        self.calls["init"].append((s, model, kwargs))
        self.source = SimpleNamespace(coeffs=np.array([0.5, -0.25]), frames_used=self.frames_used,
                                      residual_mm=12.3456)
        return self.source

    def check_init(self, s, frames_used, player):
        self.calls["check"].append((s, frames_used, player))
        return {"seen": 0.9, "cut": 0.125, "warnings": ["arms cut"], "extra": 1}

    def save(self, path, source, player=1):
        self.calls["save"].append((Path(path), source, player))
        Path(path).write_bytes(b"body")


@pytest.fixture
def init_spies(tmp_path, monkeypatch):
    import bodystudio.body.statistical as statistical
    import bodystudio.capture.session as session_mod
    import bodystudio.mirror.init as init_mod
    import bodystudio.mirror.plausibility as plaus

    spies = InitSpies(tmp_path / "sess")
    spies.session.path.mkdir()
    spies.real_initialise = init_mod.initialise_source_body
    # the CLI leaves --unpose-posture to the API's default (False before mir12y; None = the posture bones' default
    # since, main c3872cc): the summary records the setting used
    default = inspect.signature(init_mod.initialise_source_body).parameters["unpose_posture"].default
    spies.unpose_default = default
    spies.unpose_used = bool(getattr(init_mod, "UNPOSE_POSTURE_BONES", ())) if default is None else default
    monkeypatch.setattr(session_mod, "open_session", spies.open_session)
    monkeypatch.setattr(statistical, "load_statistical_model", spies.load_model)
    monkeypatch.setattr(init_mod, "initialise_source_body", spies.initialise)
    monkeypatch.setattr(init_mod, "save_source_body", spies.save)
    monkeypatch.setattr(plaus, "check_init", spies.check_init)
    return spies


def test_init_defaults_reach_the_api(init_spies):
    s = init_spies.session.path
    res = _invoke(["mirror", "init", s])
    assert res.exit_code == 0, (res.output, res.exception)
    assert init_spies.calls["open"] == [s]
    assert init_spies.calls["model"] == [("6k", False)]
    ((sess, model, kwargs),) = init_spies.calls["init"]
    assert sess is init_spies.session and model is init_spies.model
    assert kwargs == dict(player=1, n_frames=90, silhouette_shape=False, trunk_refit=False,
                          unpose_posture=init_spies.unpose_default)
    api = inspect.signature(init_spies.real_initialise).parameters
    for name in ("player", "n_frames", "silhouette_shape", "trunk_refit", "unpose_posture"):
        assert kwargs[name] == api[name].default, name
    np.testing.assert_array_equal(init_spies.calls["measure"][0], [0.5, -0.25])
    assert init_spies.calls["check"] == [(init_spies.session, init_spies.frames_used, 1)]
    ((path, source, player),) = init_spies.calls["save"]
    assert path.name == "source_body.npz" and player == 1 and source is init_spies.source
    expected = {"source_body": "mirror/source_body.npz", "player": 1, "resolution": "6k", "silhouette_shape": False,
                "silhouette_frames": 0, "trunk_refit": False, "unpose_posture": init_spies.unpose_used,
                "frames_used": [4, 5, 6, 7, 8, 9, 10, 11], "residual_mm": 12.35, "stature_m": 1.2346,
                "mass_kg": 70.13, "coverage": {"seen": 0.9, "cut": 0.125}, "warnings": ["arms cut"]}
    assert json.loads(res.stdout) == expected
    assert (s / "mirror" / "source_body.npz").read_bytes() == b"body"
    manifest = json.loads((s / "mirror" / "source_body.json").read_text())
    assert {k: manifest[k] for k in expected} == expected
    assert manifest["run"]["command"] == "bodystudio mirror init"
    assert manifest["run"]["producer"] == {"stage": "mirror", "kind": "init"}
    assert not [p.name for p in (s / "mirror").iterdir() if p.name.startswith(".")]  # lock and staging gone


def test_init_every_option_reaches_the_api(init_spies):
    s = init_spies.session.path
    res = _invoke(["mirror", "init", s, "--frames", "12", "--player", "2", "--resolution", "2k",
                   "--silhouette-shape", "--trunk-refit", "--unpose-posture"])
    assert res.exit_code == 0, (res.output, res.exception)
    assert init_spies.calls["model"] == [("2k", False)]
    assert init_spies.calls["init"][0][2] == dict(player=2, n_frames=12, silhouette_shape=True, trunk_refit=True,
                                                  unpose_posture=True)
    assert init_spies.calls["check"][0][2] == 2
    assert init_spies.calls["save"][0][0].name == "source_body_player2.npz"
    assert (s / "mirror" / "source_body_player2.npz").read_bytes() == b"body"
    assert init_spies.calls["save"][0][2] == 2
    printed = json.loads(res.stdout)
    assert printed["source_body"] == "mirror/source_body_player2.npz"
    assert (printed["player"], printed["resolution"]) == (2, "2k")
    assert printed["silhouette_shape"] is True and printed["trunk_refit"] is True
    assert printed["unpose_posture"] is True
    assert printed["silhouette_frames"] == 6  # SILHOUETTE_FRAMES of the 8 frames used
    assert json.loads((s / "mirror" / "source_body_player2.json").read_text())["player"] == 2
    assert not (s / "mirror" / "source_body.npz").exists()


def test_init_no_unpose_posture(init_spies):
    res = _invoke(["mirror", "init", init_spies.session.path, "--no-unpose-posture", "--no-trunk-refit",
                   "--no-silhouette-shape"])
    assert res.exit_code == 0, (res.output, res.exception)
    assert init_spies.calls["init"][0][2] == dict(player=1, n_frames=90, silhouette_shape=False, trunk_refit=False,
                                                  unpose_posture=False)
    assert json.loads(res.stdout)["unpose_posture"] is False


def test_init_silhouette_frames_are_at_most_the_frames_used(tmp_path, monkeypatch, init_spies):
    init_spies.frames_used = (3, 4, 5)
    res = _invoke(["mirror", "init", init_spies.session.path, "--silhouette-shape"])
    assert res.exit_code == 0, (res.output, res.exception)
    assert json.loads(res.stdout)["silhouette_frames"] == 3


@pytest.mark.parametrize("args, phrase", [
    (["--frames", "0"], "--frames 0: must be in [1, 900]"),
    (["--frames", "901"], "--frames 901: must be in [1, 900]"),
    (["--player", "0"], "--player 0: the Kinect SDK numbers players 1 to 6"),
    (["--player", "7"], "--player 7: the Kinect SDK numbers players 1 to 6"),
    (["--resolution", "13k"], "--resolution '13k': valid: 6k, 2k"),
])
def test_init_refuses_out_of_range_options(init_spies, args, phrase):
    res = _invoke(["mirror", "init", init_spies.session.path, *args])
    _refused(res, phrase)
    assert init_spies.calls["open"] == [] and init_spies.calls["init"] == []


@pytest.mark.parametrize("args", [["--frames", "1"], ["--frames", "900"], ["--player", "6"],
                                  ["--resolution", "2k"]])
def test_init_accepts_the_range_ends(init_spies, args):
    res = _invoke(["mirror", "init", init_spies.session.path, *args])
    assert res.exit_code == 0, (res.output, res.exception)
    assert len(init_spies.calls["init"]) == 1


def test_init_refuses_more_frames_than_the_session_has(init_spies):
    init_spies.session.frame_ids = list(range(40))
    s = init_spies.session.path
    _refused(_invoke(["mirror", "init", s, "--frames", "41"]), f"--frames 41: {s} has 40 frames; give at most 40")
    assert init_spies.calls["init"] == []
    res = _invoke(["mirror", "init", s, "--frames", "40"])
    assert res.exit_code == 0, (res.output, res.exception)
    assert init_spies.calls["init"][0][2]["n_frames"] == 40
    res = _invoke(["mirror", "init", s, "--force"])  # the default 90 is not checked against the 40 frames
    assert res.exit_code == 0, (res.output, res.exception)
    assert init_spies.calls["init"][1][2]["n_frames"] == 90


@pytest.mark.parametrize("player", [1, 2])
def test_init_refuses_to_replace_without_force(init_spies, player):
    s = init_spies.session.path
    assert _invoke(["mirror", "init", s, "--player", player]).exit_code == 0
    name = "source_body.npz" if player == 1 else f"source_body_player{player}.npz"
    before = (s / "mirror" / name.replace(".npz", ".json")).read_bytes()
    res = _invoke(["mirror", "init", s, "--player", player])
    of = "" if player == 1 else f" of player {player}"
    _refused(res, f"{s / 'mirror' / name}: a source body{of} exists already; pass --force to replace it (then "
                  "re-run `bodystudio mirror run`: runs made from the old body no longer match)")
    assert len(init_spies.calls["init"]) == 1 and len(init_spies.calls["model"]) == 1
    assert (s / "mirror" / name.replace(".npz", ".json")).read_bytes() == before
    res = _invoke(["mirror", "init", s, "--player", player, "--force"])
    assert res.exit_code == 0, (res.output, res.exception)
    assert len(init_spies.calls["save"]) == 2


def test_init_refuses_a_folder_in_the_source_body_place(init_spies):
    s = init_spies.session.path
    (s / "mirror" / "source_body.npz").mkdir(parents=True)
    _refused(_invoke(["mirror", "init", s, "--force"]),
             f"source body {s / 'mirror' / 'source_body.npz'}: is a folder; give a file path")
    assert init_spies.calls["init"] == []


def test_source_body_layout_by_hand(tmp_path):
    from bodystudio.cli.mirror import source_body_layout

    one = source_body_layout(tmp_path)
    assert (one.root, one.manifest, one.prefix) == (tmp_path / "mirror", "source_body.json", ".source_body.npz.")
    assert one.what == str(tmp_path / "mirror" / "source_body.npz")
    three = source_body_layout(tmp_path, 3)
    assert (three.root, three.manifest) == (tmp_path / "mirror", "source_body_player3.json")
    assert three.prefix == ".source_body_player3.npz."
