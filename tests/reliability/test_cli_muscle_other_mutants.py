"""``bodystudio synth arm``, ``muscle model build`` / ``info`` and ``eval muscle`` through typer's CliRunner with
the API replaced by spies (mutKK).

Each option must reach the API unchanged (the CLI defaults equal the API's), each refusal must be an
:class:`InputError` with its whole message raised before any work, and the printed line / JSON must be what the
help promises (written out by hand here). No session is synthesised, no model learnt: about a second.
"""

from __future__ import annotations

import inspect
import json
import math
from pathlib import Path
from types import SimpleNamespace

import pytest

from bodystudio.errors import InputError
from tests.reliability.cli_spies import invoke as _invoke


def _refused(res, message):
    assert isinstance(res.exception, InputError), (res.exit_code, res.output, res.exception)
    assert res.exit_code != 0
    assert str(res.exception) == message


# ------------------------------------------------------------------------------------------ synth arm

class Calls(list):
    pass


@pytest.fixture
def synth_calls(monkeypatch):
    import bodystudio.muscle.synthetic as synthetic

    calls = Calls()
    calls.real = synthetic.synth_arm_session

    class Session(list):
        streams = ["depth", "joints"]

    def spy(out, **kwargs):
        calls.append((out, kwargs))
        return Session(range(kwargs["n_frames"]))

    monkeypatch.setattr(synthetic, "synth_arm_session", spy)
    return calls


def test_synth_arm_defaults(tmp_path, synth_calls):
    res = _invoke(["synth", "arm", tmp_path / "S", "--subject-seed", "3"])
    assert res.exit_code == 0, (res.output, res.exception)
    ((out, kwargs),) = synth_calls
    assert out == tmp_path / "S"
    assert kwargs == dict(subject_seed=3, motion="elbow_flex", n_frames=200, kinect="v2", distance_m=1.0, seed=0,
                          resolution="6k", fps=30.0)
    api = inspect.signature(synth_calls.real).parameters
    for name in ("motion", "n_frames", "kinect", "distance_m", "seed", "resolution", "fps"):
        assert kwargs[name] == api[name].default, name
    assert res.stdout == (f"wrote {tmp_path / 'S'}: 200 frames of elbow_flex at 30 fps (Kinect v2 at 1 m), "
                          "streams depth, joints\n")


def test_synth_arm_every_option(tmp_path, synth_calls):
    res = _invoke(["synth", "arm", tmp_path / "S", "--subject-seed", "2147483647", "--motion", "pronation",
                   "--frames", "2000", "--fps", "240", "--kinect", "v1", "--distance", "3.0", "--seed", "9",
                   "--resolution", "full"])
    assert res.exit_code == 0, (res.output, res.exception)
    assert synth_calls[0][1] == dict(subject_seed=2**31 - 1, motion="pronation", n_frames=2000, kinect="v1",
                                     distance_m=3.0, seed=9, resolution="full", fps=240.0)
    assert res.stdout.startswith(f"wrote {tmp_path / 'S'}: 2000 frames of pronation at 240 fps (Kinect v1 at 3 m)")
    res = _invoke(["synth", "arm", tmp_path / "T", "--subject-seed", "0", "--motion", "abduction", "--frames", "1",
                   "--fps", "1", "--distance", "0.5", "--resolution", "2k"])
    assert res.exit_code == 0, (res.output, res.exception)
    assert synth_calls[1][1]["distance_m"] == 0.5 and synth_calls[1][1]["fps"] == 1.0


@pytest.mark.parametrize("args, message", [
    (["--motion", "squat"], "--motion 'squat': valid: elbow_flex, abduction, pronation"),
    (["--fps", "0.5"], "--fps 0.5: must be in [1, 240]"),
    (["--fps", "241"], "--fps 241.0: must be in [1, 240]"),
    (["--kinect", "v3"], "--kinect 'v3': valid: v1, v2"),
    (["--resolution", "13k"], "--resolution '13k': valid: 6k, 2k, full"),
    (["--frames", "0"], "--frames 0: must be in [1, 2000]"),
    (["--frames", "2001"], "--frames 2001: must be in [1, 2000]"),
    (["--distance", "0.49"], "--distance 0.49: must be in [0.5, 3] m"),
    (["--distance", "3.01"], "--distance 3.01: must be in [0.5, 3] m"),
    (["--subject-seed", "-1"], "--subject-seed -1: must be in [0, 2.14748e+09]"),
    (["--subject-seed", "2147483648"], "--subject-seed 2147483648: must be in [0, 2.14748e+09]"),
])
def test_synth_arm_refusals(tmp_path, synth_calls, args, message):
    args = ["--subject-seed", "1", *args] if "--subject-seed" not in args else args
    _refused(_invoke(["synth", "arm", tmp_path / "S", *args]), message)
    assert synth_calls == []


def test_synth_arm_refuses_an_existing_out(tmp_path, synth_calls):
    (tmp_path / "S").mkdir()
    _refused(_invoke(["synth", "arm", tmp_path / "S", "--subject-seed", "1"]),
             f"{tmp_path / 'S'}: session folder already exists; choose a new path or remove it")
    assert synth_calls == []


# ------------------------------------------------------------------------------------------ model build

@pytest.fixture
def build_spies(monkeypatch):
    import bodystudio.cli.muscle as cli_muscle
    import bodystudio.muscle.model as model_mod
    import bodystudio.muscle.synthetic as synthetic

    calls = {"dataset": [], "template": [], "learn": [], "save": []}
    real = synthetic.training_dataset

    def dataset(*args, **kwargs):
        calls["dataset"].append((args, kwargs))
        return ["s"] * 11, ["subjects"]

    def template(resolution, side):
        calls["template"].append((resolution, side))
        return "TEMPLATE"

    def learn(samples, tmpl, regularization, sex_slopes=None):
        calls["learn"].append((samples, tmpl, regularization, sex_slopes))
        calls["model"] = SimpleNamespace(subjects=["a"] * 15, template_key="6k-left-abc")
        return calls["model"]

    def save(out, model):
        calls["save"].append((out, model))

    monkeypatch.setattr(synthetic, "training_dataset", dataset)
    monkeypatch.setattr(cli_muscle, "_arm_template", template)
    monkeypatch.setattr(model_mod, "learn_arm_model", learn)
    monkeypatch.setattr(model_mod, "save_arm_model", save)
    calls["real"] = real
    return calls


def test_model_build_defaults(tmp_path, build_spies):
    out = tmp_path / "m.npz"
    res = _invoke(["muscle", "model", "build", "--out", out])
    assert res.exit_code == 0, (res.output, res.exception)
    assert build_spies["dataset"] == [(("6k", 10, 3, 24, 0, "left"), {"n_women": 5})]
    assert build_spies["template"] == [("6k", "left")]
    assert build_spies["learn"] == [(["s"] * 11, "TEMPLATE", 1.0, False)]
    assert build_spies["save"] == [(out, build_spies["model"])]
    assert res.stdout == f"wrote {out}: 15 subjects (10 men, 5 women), 11 meshes, template 6k-left-abc\n"


def test_model_build_sex_slopes(tmp_path, build_spies):
    """mus11z's ``--sex-slopes`` reaches ``learn_arm_model`` and the line says so."""
    out = tmp_path / "m.npz"
    res = _invoke(["muscle", "model", "build", "--out", out, "--women", "10", "--sex-slopes"])
    assert res.exit_code == 0, (res.output, res.exception)
    assert build_spies["learn"] == [(["s"] * 11, "TEMPLATE", 1.0, True)]
    assert res.stdout == (f"wrote {out}: 15 subjects (10 men, 10 women, the women's own slopes), 11 meshes, "
                          "template 6k-left-abc\n")


def test_model_build_every_option(tmp_path, build_spies):
    out = tmp_path / "m.NPZ"
    res = _invoke(["muscle", "model", "build", "--out", out, "--resolution", "2k", "--side", "right", "--subjects",
                   "60", "--women", "40", "--shapes", "10", "--poses", "500", "--regularization", "1000000",
                   "--seed", "7"])
    assert res.exit_code == 0, (res.output, res.exception)
    assert build_spies["dataset"] == [(("2k", 60, 10, 500, 7, "right"), {"n_women": 40})]
    assert build_spies["template"] == [("2k", "right")]
    assert build_spies["learn"][0][2:] == (1e6, False)
    assert "(60 men, 40 women)" in res.stdout
    res = _invoke(["muscle", "model", "build", "--out", tmp_path / "n.npz", "--subjects", "2", "--women", "0",
                   "--shapes", "1", "--poses", "1", "--regularization", "0", "--resolution", "full", "--seed",
                   "2147483647"])
    assert res.exit_code == 0, (res.output, res.exception)
    assert build_spies["dataset"][1] == (("full", 2, 1, 1, 2**31 - 1, "left"), {"n_women": 0})


@pytest.mark.parametrize("args, message", [
    (["--resolution", "13k"], "--resolution '13k': valid: 6k, 2k, full"),
    (["--side", "up"], "--side 'up': valid: left, right"),
    (["--subjects", "1"], "--subjects 1: must be in [2, 100]"),
    (["--subjects", "101"], "--subjects 101: must be in [2, 100]"),
    (["--women", "-1"], "--women -1: must be in [0, 100]"),
    (["--women", "101"], "--women 101: must be in [0, 100]"),
    (["--subjects", "60", "--women", "41"], "--subjects 60 --women 41: 101 training subjects; at most 100 in all"),
    (["--shapes", "0"], "--shapes 0: must be in [1, 10]"),
    (["--shapes", "11"], "--shapes 11: must be in [1, 10]"),
    (["--poses", "0"], "--poses 0: must be in [1, 500]"),
    (["--poses", "501"], "--poses 501: must be in [1, 500]"),
    (["--regularization", "-0.5"], "--regularization -0.5: must be in [0, 1e+06]"),
    (["--regularization", "1000001"], "--regularization 1000001.0: must be in [0, 1e+06]"),
    (["--seed", "-1"], "--seed -1: must be in [0, 2.14748e+09]"),
    (["--seed", "2147483648"], "--seed 2147483648: must be in [0, 2.14748e+09]"),
])
def test_model_build_refusals(tmp_path, build_spies, args, message):
    _refused(_invoke(["muscle", "model", "build", "--out", tmp_path / "m.npz", *args]), message)
    assert build_spies["dataset"] == [] and build_spies["save"] == []


def test_model_build_refuses_an_out_not_npz_or_existing(tmp_path, build_spies):
    _refused(_invoke(["muscle", "model", "build", "--out", tmp_path / "m.npy"]),
             f"--out {tmp_path / 'm.npy'}: an arm model is a .npz file")
    (tmp_path / "m.npz").write_bytes(b"x")
    _refused(_invoke(["muscle", "model", "build", "--out", tmp_path / "m.npz"]),
             f"{tmp_path / 'm.npz'}: model file already exists; choose a new path or remove it")
    assert build_spies["dataset"] == []


def test_arm_template_builds_the_body_at_the_resolution(monkeypatch):
    import bodystudio.body as body
    import bodystudio.muscle.arm as arm
    from bodystudio.cli.muscle import _arm_template

    monkeypatch.setattr(body, "build_body", lambda resolution: f"body-{resolution}")
    monkeypatch.setattr(arm, "arm_template", lambda b, side: (b, side))
    assert _arm_template("2k", "right") == ("body-2k", "right")


# ------------------------------------------------------------------------------------------ model info

@pytest.mark.parametrize("form", ["body", "linear"])
@pytest.mark.parametrize("n_subjects", [0, 2])
def test_model_info(tmp_path, monkeypatch, form, n_subjects):
    import bodystudio.muscle.model as model_mod

    subjects = [{"name": f"s{k}"} for k in range(n_subjects)]
    model = SimpleNamespace(template_key="6k-left-x", version=3, n_vertices=812, regularization=0.5,
                            shape_form=form, sex_slopes=n_subjects == 2, body_weight=0.25, subjects=subjects,
                            shape_range=lambda: {"bmi": [20.0, 28.0]})
    seen = []
    monkeypatch.setattr(model_mod, "load_arm_model", lambda p: seen.append(p) or model)
    res = _invoke(["muscle", "model", "info", tmp_path / "m.npz"])
    assert res.exit_code == 0, (res.output, res.exception)
    assert seen == [tmp_path / "m.npz"]
    expected = {"template_key": "6k-left-x", "version": 3, "n_vertices": 812, "regularization": 0.5,
                "shape_form": form, "sex_slopes": n_subjects == 2, **({"body_weight": 0.25} if form == "body" else {}),
                "n_subjects": n_subjects,
                "shape_range": {"bmi": [20.0, 28.0]} if n_subjects else {}, "subjects": subjects}
    assert json.loads(res.stdout) == expected
    assert list(json.loads(res.stdout)) == list(expected)
    assert res.stdout.startswith('{\n  "template_key"')  # indent=2


# ------------------------------------------------------------------------------------------ eval muscle

def test_eval_muscle_prints_rounded_scores(tmp_path, monkeypatch):
    import bodystudio.cli.muscle as cli_muscle

    seen = []
    scores = {"p90_mm": 2.34567, "median_mm": 1.23449, "jitter_mm": math.nan, "ms_per_frame": 150.0,
              "extra_mm": 0.12345, "n_frames": 7, "label": "x", "inf_mm": math.inf}
    monkeypatch.setattr(cli_muscle, "evaluate_capture_folder", lambda f, s: seen.append((f, s)) or dict(scores))
    res = _invoke(["eval", "muscle", tmp_path / "cap", "--session", tmp_path / "S"])
    assert res.exit_code == 0, (res.output, res.exception)
    assert seen == [(tmp_path / "cap", tmp_path / "S")]
    printed = json.loads(res.stdout)
    assert printed == {"median_mm": 1.234, "p90_mm": 2.346, "jitter_mm": None, "ms_per_frame": 150.0,
                       "extra_mm": 0.123, "n_frames": 7, "label": "x", "inf_mm": None}
    assert list(printed)[:4] == ["median_mm", "p90_mm", "jitter_mm", "ms_per_frame"]  # EVAL_KEYS' order first
    res = _invoke(["eval", "muscle", tmp_path / "cap"])
    assert res.exit_code == 0 and seen[1] == (tmp_path / "cap", None)
    scores["per_frame_mm"] = [1.0, math.nan]  # not a float: passed on as it is; never printed as NaN (not JSON)
    res = _invoke(["eval", "muscle", tmp_path / "cap"])
    assert res.exit_code != 0 and "NaN" not in res.stdout


class _Capture:
    def __init__(self, session_path, same=True):
        self.session_path = session_path
        self.same = same
        self.asked = []

    def is_from(self, session):
        self.asked.append(session)
        return self.same


@pytest.fixture
def eval_spies(monkeypatch):
    import bodystudio.capture.session as session_mod
    import bodystudio.muscle.capture as capture_mod
    import bodystudio.muscle.evaluate as evaluate_mod
    import bodystudio.muscle.synthetic as synthetic

    s = SimpleNamespace(capture=_Capture(Path("/rec/S")), opened=[], evaluated=[])
    s.loaded = []
    monkeypatch.setattr(capture_mod, "load_arm_capture", lambda folder: s.loaded.append(folder) or s.capture)

    def open_session(p):
        s.opened.append(p)
        return SimpleNamespace(path=Path(p))

    monkeypatch.setattr(session_mod, "open_session", open_session)
    monkeypatch.setattr(synthetic, "session_arm_template", lambda session: ("T", session.path))
    monkeypatch.setattr(evaluate_mod, "evaluate_arm_capture",
                        lambda c, session, t: s.evaluated.append((c, session.path, t)) or {"median_mm": 1.0})
    return s


def test_evaluate_capture_folder(tmp_path, eval_spies):
    from bodystudio.cli.muscle import evaluate_capture_folder

    assert evaluate_capture_folder(tmp_path) == {"median_mm": 1.0}
    assert eval_spies.loaded == [tmp_path]
    assert eval_spies.opened == [Path("/rec/S")]
    assert eval_spies.evaluated == [(eval_spies.capture, Path("/rec/S"), ("T", Path("/rec/S")))]
    assert [a.path for a in eval_spies.capture.asked] == [Path("/rec/S")]  # the opened session's fingerprint
    evaluate_capture_folder(tmp_path, tmp_path / "other")
    assert eval_spies.opened[1] == tmp_path / "other"


def test_evaluate_capture_folder_refusals(tmp_path, eval_spies):
    from bodystudio.cli.muscle import evaluate_capture_folder

    with pytest.raises(InputError) as err:
        evaluate_capture_folder(tmp_path / "none")
    assert str(err.value) == (f"{tmp_path / 'none'}: no such arm capture folder; make one with `bodystudio muscle "
                              "capture`")
    (tmp_path / "f").write_text("x")
    with pytest.raises(InputError):
        evaluate_capture_folder(tmp_path / "f")
    eval_spies.capture = _Capture(None)
    with pytest.raises(InputError) as err:
        evaluate_capture_folder(tmp_path)
    assert str(err.value) == f"{tmp_path}: params.json names no session; pass --session SESSION"
    eval_spies.capture = _Capture(Path("/rec/S"), same=False)
    with pytest.raises(InputError) as err:
        evaluate_capture_folder(tmp_path, tmp_path / "B")
    assert str(err.value) == (f"{tmp_path}: captured from another recording than {tmp_path / 'B'} (its depth frames "
                              "differ); pass --session with the session it was captured from (/rec/S)")
    eval_spies.capture = _Capture(None, same=False)
    with pytest.raises(InputError) as err:
        evaluate_capture_folder(tmp_path, tmp_path / "B")
    assert str(err.value).endswith("captured from (named in params.json)")
    eval_spies.capture = _Capture(Path("/rec/S"), same=None)  # a capture from before the fingerprint: scored
    assert evaluate_capture_folder(tmp_path) == {"median_mm": 1.0}
    assert len(eval_spies.evaluated) == 1


def test_score():
    from bodystudio.cli.muscle import _score

    assert _score(1.23449) == 1.234 and _score(1.2346) == 1.235 and _score(3) == 3.0
    assert isinstance(_score(3), float)
    assert _score(math.nan) is None and _score(-math.inf) is None and _score(math.inf) is None
