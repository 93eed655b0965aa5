"""``bodystudio muscle capture`` through typer's CliRunner with the API replaced by spies (mutKK).

The single capture (``capture_session_arm`` / ``session_fps`` / ``write_arm_capture``) and the batch
(``check_capture_sessions``, ``load_arm_model``, ``resolve_scheduler``, ``batch_client``, ``muscle_batch``) record
their arguments: each option must reach them unchanged, each refusal must be an :class:`InputError` (the console
script's one line and exit 2) raised before any work, with its whole message. The expected calls are written out
by hand from the help. No session is captured and no cluster started: the file runs in about a second.
"""

from __future__ import annotations

import contextlib
import math
from pathlib import Path
from types import SimpleNamespace

import pytest
from typer.testing import CliRunner

from bodystudio.errors import BodyStudioError, InputError


def _invoke(args):
    from bodystudio.cli.main import app

    return CliRunner().invoke(app, ["muscle", "capture", *[str(a) for a in args]])


def _refused(res, phrase, kind=InputError):
    """A refusal with exactly the message ``phrase`` (``~phrase``: a message containing it)."""
    assert isinstance(res.exception, kind), (res.exit_code, res.output, res.exception)
    assert res.exit_code != 0
    if phrase.startswith("~"):
        assert phrase[1:] in str(res.exception), str(res.exception)
    else:
        assert str(res.exception) == phrase


class Spies:
    def __init__(self, root: Path):
        self.root = root
        self.model = root / "arm.npz"
        self.model.write_bytes(b"model")
        self.calls = {"capture": [], "fps": [], "write": [], "sessions": [], "rates": [], "load_model": [],
                      "scheduler": [], "client": [], "batch": [], "cluster": [], "report": []}
        self.plausibility = {"warnings": ["depth in cm?", "arm cut"]}
        self.sex_fit = None
        self.skipped = []  # the frames the capture skipped as bad (rel7a)
        self.frames = {}  # session path -> frame count (open_session); missing: unreadable
        self.errors = []

    # the single capture
    def capture_session_arm(self, *args, **kwargs):
        self.calls["capture"].append((args, kwargs))
        self.result = SimpleNamespace(plausibility=self.plausibility, sex_fit=self.sex_fit, n_frames=7,
                                      ms_per_frame=123.6, skipped=self.skipped)
        return self.result

    def session_fps(self, path):
        self.calls["fps"].append(path)
        return 15.0

    def write_arm_capture(self, out, result, fps=None):
        self.calls["write"].append((out, result, fps))

    # the batch
    def check_capture_sessions(self, paths):
        self.calls["sessions"].append(list(paths))
        return list(paths)

    def open_session(self, path):
        if str(path) not in self.frames:
            raise BodyStudioError(f"{path}: unreadable")
        return SimpleNamespace(path=Path(path), frame_ids=list(range(self.frames[str(path)])))

    def capture_frame_rate(self, session):
        self.calls["rates"].append(session.path)
        return 30.0

    def load_arm_model(self, path):
        self.calls["load_model"].append(path)

    def resolve_scheduler(self, scheduler, workers):
        self.calls["scheduler"].append((scheduler, workers))

    @contextlib.contextmanager
    def batch_client(self, scheduler, workers, units=None):
        self.calls["client"].append((scheduler, workers, units))
        yield "CLIENT"

    def muscle_batch(self, paths, out, client, options, force=False, progress=False, shapes=None):
        self.calls["batch"].append(dict(paths=list(paths), out=out, client=client, options=options, force=force,
                                        progress=progress, shapes=shapes))
        self.report = SimpleNamespace(errors=self.errors,
                                      failure_message=lambda what: f"2 {what} failed: see batch.json")
        return self.report

    def print_cluster(self, client):
        self.calls["cluster"].append(client)

    def print_report(self, report, what):
        assert report is self.report
        self.calls["report"].append(what)

    def nothing_started(self):
        return not any(self.calls[k] for k in ("capture", "write", "client", "batch"))


@pytest.fixture
def spies(tmp_path, monkeypatch):
    import bodystudio.batch as batch
    import bodystudio.capture.session as session_mod
    import bodystudio.cli.batch as batch_cli
    import bodystudio.muscle.capture as capture_mod
    import bodystudio.muscle.model as model_mod

    s = Spies(tmp_path)
    s.real_capture = capture_mod.capture_session_arm
    for mod, names in ((capture_mod, ("capture_session_arm", "session_fps", "write_arm_capture",
                                      "capture_frame_rate")),
                       (batch, ("check_capture_sessions", "resolve_scheduler", "batch_client", "muscle_batch")),
                       (session_mod, ("open_session",)), (model_mod, ("load_arm_model",)),
                       (batch_cli, ("print_cluster", "print_report"))):
        for name in names:
            monkeypatch.setattr(mod, name, getattr(s, name))
    return s


def _shape(bmi=31.0, muscularity=0.3, height_m=1.62, arm_length_m=0.55, sex=1.0):
    from bodystudio.muscle.model import ArmShapeParams

    return ArmShapeParams(bmi, muscularity, height_m, arm_length_m, sex=sex)


def _same_shape(a, b):
    return all(getattr(a, n) == getattr(b, n) for n in ("bmi", "muscularity", "height_m", "arm_length_m", "sex"))


# ------------------------------------------------------------------------------------------ single capture

def test_single_capture_defaults(spies, tmp_path):
    out = tmp_path / "cap"
    res = _invoke([tmp_path / "S", "--out", out, "--model", spies.model])
    assert res.exit_code == 0, (res.output, res.exception)
    ((args, kwargs),) = spies.calls["capture"]
    assert args == (tmp_path / "S", spies.model, "full", None, None, None, None)
    assert kwargs == dict(sequence_fit=True, for_extension=False, accept_implausible=False, skip_bad_frames=True)
    import inspect

    api = inspect.signature(spies.real_capture).parameters
    for name in ("sequence_fit", "for_extension", "accept_implausible", "skip_bad_frames"):
        assert kwargs[name] == api[name].default, name
    assert spies.calls["fps"] == [tmp_path / "S"]
    assert spies.calls["write"] == [(out, spies.result, 15.0)]
    assert res.stdout == f"wrote {out}: 7 frames (full), 124 ms per frame\n"
    assert res.stderr == "warning: depth in cm?\nwarning: arm cut\n"


def test_single_capture_every_option(spies, tmp_path):
    out = tmp_path / "cap"
    spies.plausibility = None
    spies.sex_fit = {"chosen": "female", "energy_mm": {"male": 1.23456, "female": 0.98765}}
    res = _invoke([tmp_path / "S", "--out", out, "--model", spies.model, "--no-refine", "--resolution", "2k",
                   "--side", "right", "--frames", "12", "--shape",
                   "bmi=31,muscularity=0.3,height_m=1.62,arm_length_m=0.55,sex=female", "--no-sequence-fit",
                   "--accept-implausible"])
    assert res.exit_code == 0, (res.output, res.exception)
    ((args, kwargs),) = spies.calls["capture"]
    assert args[:6] == (tmp_path / "S", spies.model, "model", "2k", "right", 12)
    assert _same_shape(args[6], _shape(sex=0.0))
    assert kwargs == dict(sequence_fit=False, for_extension=False, accept_implausible=True, skip_bad_frames=True)
    assert res.stdout == ("the subject's sex from the depth: female (held-out depth energy as a man 1.235 mm, as a "
                          f"woman 0.988 mm; params.json sex_fit)\nwrote {out}: 7 frames (model), 124 ms per frame\n")
    assert res.stderr == ""


def test_single_capture_no_model_and_for_extension(spies, tmp_path):
    spies.plausibility = {}
    res = _invoke([tmp_path / "S", "--out", tmp_path / "a", "--no-model", "--resolution", "full", "--side", "left"])
    assert res.exit_code == 0, (res.output, res.exception)
    args, kwargs = spies.calls["capture"][0]
    assert args == (tmp_path / "S", None, "nicp", "full", "left", None, None)
    assert res.stdout.endswith("7 frames (nicp), 124 ms per frame\n")
    res = _invoke([tmp_path / "S", "--out", tmp_path / "b", "--model", spies.model, "--for-extension", "--shape",
                   "bmi=20, muscularity=1,height_m=2.3,arm_length_m=0.3"])
    assert res.exit_code == 0, (res.output, res.exception)
    args, kwargs = spies.calls["capture"][1]
    assert args[2] == "full" and _same_shape(args[6], _shape(20.0, 1.0, 2.3, 0.3, 1.0))
    assert kwargs == dict(sequence_fit=True, for_extension=True, accept_implausible=False, skip_bad_frames=True)


def test_single_capture_skipped_frames_and_no_skip_bad_frames(spies, tmp_path):
    """rel7a: the skipped frames are warned about one line each (file, frame, why) and counted in the summary;
    --no-skip-bad-frames reaches the API; a batch refuses it (each unit skips, as the default)."""
    spies.plausibility = None
    spies.skipped = [{"frame": 4, "position": 4, "file": "S/kinect/depth/00004.png", "why": "unreadable image"}]
    res = _invoke([tmp_path / "S", "--out", tmp_path / "a", "--model", spies.model])
    assert res.exit_code == 0, (res.output, res.exception)
    assert res.stderr == "warning: S/kinect/depth/00004.png: frame 4 skipped (unreadable image); no mesh for it\n"
    assert res.stdout == f"wrote {tmp_path / 'a'}: 7 frames (full), 1 skipped (params.json skipped_frames), 124 ms " \
        "per frame\n"
    res = _invoke([tmp_path / "S", "--out", tmp_path / "b", "--model", spies.model, "--no-skip-bad-frames"])
    assert res.exit_code == 0, (res.output, res.exception)
    assert spies.calls["capture"][1][1]["skip_bad_frames"] is False
    res = _invoke([tmp_path / "S", tmp_path / "T", "--out", tmp_path / "c", "--model", spies.model,
                   "--no-skip-bad-frames"])
    _refused(res, "--no-skip-bad-frames is for a single capture; a batch skips bad frames (named in each unit's "
                  "params.json): capture that SESSION on its own to refuse them")
    assert len(spies.calls["capture"]) == 2 and not spies.calls["batch"]


M = "{model}"


@pytest.mark.parametrize("args, phrase", [
    (["--no-model", "--shape", "bmi=31,muscularity=0.3,height_m=1.62,arm_length_m=0.55"],
     "--shape needs the model (the shape parameters drive it); drop --no-model"),
    ([M, "--shape", "bmi=31,muscularity=0.3,height_m=1.62,arm_length_m=0.55", "--shape",
      "bmi=31,muscularity=0.3,height_m=1.62,arm_length_m=0.55"],
     "--shape: 2 given for 1 sessions; give one --shape per SESSION, in their order (repeat the values for sessions "
     "of one subject)"),
    (["--no-model", "--no-refine"], "--no-model and --no-refine: choose one (--no-model is NICP + ARAP without the "
     "model, --no-refine the model without the refinement)"),
    (["--no-model", M], "--no-model with --model: choose one"),
    ([], "muscle capture needs --model MODEL.npz (make one with `bodystudio muscle model build`) or --no-model"),
    (["--model", "{t}/none.npz"], "--model {t}/none.npz: no such file; make one with `bodystudio muscle model build`"),
    (["--model", "{t}"], "--model {t}: no such file; make one with `bodystudio muscle model build`"),
    ([M, "--frames", "0"], "--frames 0: must be in [1, 2000]"),
    ([M, "--frames", "2001"], "--frames 2001: must be in [1, 2000]"),
    ([M, "--resolution", "13k"], "--resolution '13k': valid: 6k, 2k, full"),
    ([M, "--side", "up"], "--side 'up': valid: left, right"),
    (["--no-model", "--no-sequence-fit"], "--no-sequence-fit with --no-model: the sequence fit is a model step; "
     "drop one"),
    (["--no-model", "--for-extension"], "--for-extension with --no-model: an extension capture needs the model; "
     "drop --no-model"),
    ([M, "--for-extension", "--no-sequence-fit"], "--for-extension with --no-sequence-fit: the extension capture "
     "fits the skeleton in the sequence fit; drop one"),
    ([M, "--force"], "--force is for a batch (several SESSIONs or --workers/--scheduler); a single capture writes a "
     "new --out folder"),
    ([M, "--workers", "2", "--accept-implausible"], "--accept-implausible is for a single capture; a batch refuses "
     "an implausible sequence in its report: capture that SESSION on its own to accept it"),
    ([M, "--scheduler", "tcp://h:8786", "--accept-implausible"], "--accept-implausible is for a single capture; a "
     "batch refuses an implausible sequence in its report: capture that SESSION on its own to accept it"),
    ([M, "--shape", "bmi=31,muscularity=0.3,height_m=1.62"], "~--shape: needs bmi, muscularity, height_m, "
     "arm_length_m"),
    ([M, "--shape", "bmi=31,muscle=0.3"], "--shape 'bmi=31,muscle=0.3': names are bmi, muscularity, height_m, "
     "arm_length_m, sex (sex optional: male | female)"),
    ([M, "--shape", "bmi31"], "--shape 'bmi31': names are bmi, muscularity, height_m, arm_length_m, sex (sex optional: "
     "male | female)"),
    ([M, "--shape", "bmi==31,muscularity=0.3,height_m=1.62,arm_length_m=0.55"],
     "--shape 'bmi==31,muscularity=0.3,height_m=1.62,arm_length_m=0.55': write NAME=VALUE pairs for bmi, muscularity, "
     "height_m, arm_length_m, sex"),
    ([M, "--shape", "bmi=x,muscularity=0.3,height_m=1.62,arm_length_m=0.55"],
     "--shape 'bmi=x,muscularity=0.3,height_m=1.62,arm_length_m=0.55': write NAME=VALUE pairs for bmi, muscularity, "
     "height_m, arm_length_m, sex"),
    ([M, "--shape", "bmi=31,muscularity=0.3,height_m=1.62,arm_length_m=0.55,sex=robot"],
     "~--shape 'bmi=31,muscularity=0.3,height_m=1.62,arm_length_m=0.55,sex=robot': sex 'robot'"),
])
def test_single_capture_refusals(spies, tmp_path, args, phrase):
    args = [a.replace("{t}", str(tmp_path)) for a in args]
    args = [x for a in args for x in (["--model", str(spies.model)] if a == M else [a])]
    res = _invoke([tmp_path / "S", "--out", tmp_path / "cap", *args])
    _refused(res, phrase.replace("{t}", str(tmp_path)))
    assert spies.nothing_started()


def test_single_capture_refuses_an_existing_out(spies, tmp_path):
    (tmp_path / "cap").mkdir()
    res = _invoke([tmp_path / "S", "--out", tmp_path / "cap", "--model", spies.model])
    _refused(res, f"{tmp_path / 'cap'}: arm capture folder already exists; choose a new path or remove it")
    (tmp_path / "f").write_text("x")
    res = _invoke([tmp_path / "S", "--out", tmp_path / "f" / "cap", "--model", spies.model])
    _refused(res, f"arm capture folder {tmp_path / 'f' / 'cap'}: {tmp_path / 'f'} is a file, not a folder; choose "
                  "another place")
    assert spies.nothing_started()


@pytest.mark.parametrize("name, lo, hi, below, above", [
    ("bmi", "10", "60", "9.99", "60.01"), ("muscularity", "0", "1", "-0.01", "1.01"),
    ("height_m", "1.0", "2.3", "0.99", "2.31"), ("arm_length_m", "0.3", "1.0", "0.29", "1.01"),
])
def test_shape_ranges(name, lo, hi, below, above):
    from bodystudio.cli.muscle import _parse_shape

    base = {"bmi": "31", "muscularity": "0.3", "height_m": "1.62", "arm_length_m": "0.55"}
    for value in (lo, hi):
        text = ",".join(f"{k}={value if k == name else v}" for k, v in base.items())
        assert getattr(_parse_shape(text), name) == float(value)
    for value in (below, above, "nan", "inf"):
        text = ",".join(f"{k}={value if k == name else v}" for k, v in base.items())
        with pytest.raises(InputError) as err:
            _parse_shape(text)
        assert str(err.value) == f"--shape {name} {float(value)}: must be in [{float(lo):g}, {float(hi):g}]"


def test_shape_sex_default_and_names():
    from bodystudio.cli.muscle import _parse_shape

    s = _parse_shape(" bmi =22,muscularity= 0.5 ,height_m=1.8,arm_length_m=0.6")
    assert _same_shape(s, _shape(22.0, 0.5, 1.8, 0.6, 1.0))
    assert _parse_shape("sex=f,bmi=22,muscularity=0.5,height_m=1.8,arm_length_m=0.6").sex == 0.0
    assert _parse_shape("bmi=22,muscularity=0.5,height_m=1.8,arm_length_m=0.6,sex=0.25").sex == 0.25


def test_check_range_and_choice():
    from bodystudio.cli.muscle import check_choice, check_range

    assert check_range("--x", 2, 2, 3) == 2 and check_range("--x", 3.0, 2, 3) == 3.0
    for bad in (1.999, 3.001, math.nan, math.inf, "2.5", None):
        with pytest.raises(InputError) as err:
            check_range("--x", bad, 2, 3, " m")
        assert str(err.value) == f"--x {bad}: must be in [2, 3] m"
    assert check_choice("--c", "b", ("a", "b")) == "b"
    with pytest.raises(InputError) as err:
        check_choice("--c", "B", ("a", "b"))
    assert str(err.value) == "--c 'B': valid: a, b"


def test_check_range_message_formats_bounds():
    from bodystudio.cli.muscle import check_range

    with pytest.raises(InputError) as err:
        check_range("--r", 2e6, 0.0, 1e6)
    assert str(err.value) == "--r 2000000.0: must be in [0, 1e+06]"


# ------------------------------------------------------------------------------------------ the batch

def test_batch_of_two_sessions(spies, tmp_path):
    a, b = tmp_path / "A", tmp_path / "B"
    spies.frames = {str(a): 40, str(b): 30}
    out = tmp_path / "batch"
    res = _invoke([a, b, "--out", out, "--model", spies.model, "--frames", "30", "--resolution", "2k", "--side",
                   "right", "--no-refine", "--shape", "bmi=31,muscularity=0.3,height_m=1.62,arm_length_m=0.55",
                   "--shape", "bmi=22,muscularity=0.5,height_m=1.8,arm_length_m=0.6,sex=female", "--force"])
    assert res.exit_code == 0, (res.output, res.exception)
    from bodystudio.batch import MuscleOptions

    assert spies.calls["sessions"] == [[a, b]]
    assert spies.calls["rates"] == [a, b]
    assert spies.calls["load_model"] == [spies.model]
    assert spies.calls["scheduler"] == [(None, None)]
    assert spies.calls["client"] == [(None, None, 2)]
    assert spies.calls["cluster"] == ["CLIENT"]
    ((call,),) = [spies.calls["batch"]]
    assert call == dict(paths=[a, b], out=out, client="CLIENT",
                        options=MuscleOptions(mode="model", resolution="2k", side="right", frames=30,
                                              model=str(spies.model.resolve()), sequence_fit=True,
                                              for_extension=False),
                        force=True, progress=True,
                        shapes=[{"bmi": 31.0, "muscularity": 0.3, "height_m": 1.62, "arm_length_m": 0.55, "sex": 1.0},
                                {"bmi": 22.0, "muscularity": 0.5, "height_m": 1.8, "arm_length_m": 0.6, "sex": 0.0}])
    assert spies.calls["report"] == ["muscle capture (2 sequences)"]
    assert spies.calls["capture"] == []


def test_batch_of_one_session_by_workers_no_model(spies, tmp_path):
    a = tmp_path / "A"
    res = _invoke([a, "--out", tmp_path / "o", "--no-model", "--workers", "3", "--scheduler", "tcp://h:1"])
    assert res.exit_code == 0, (res.output, res.exception)
    from bodystudio.batch import MuscleOptions

    call = spies.calls["batch"][0]
    assert call["options"] == MuscleOptions(mode="nicp", resolution=None, side=None, frames=None, model=None,
                                            sequence_fit=True, for_extension=False)
    assert call["shapes"] is None and call["force"] is False
    assert spies.calls["load_model"] == [] and spies.calls["rates"] == []  # the unreadable session left to its unit
    assert spies.calls["scheduler"] == [("tcp://h:1", 3)]
    assert spies.calls["client"] == [("tcp://h:1", 3, 1)]
    res = _invoke([a, "--out", tmp_path / "o2", "--model", spies.model, "--workers", "1", "--for-extension",
                   "--no-refine"])
    assert res.exit_code == 0, (res.output, res.exception)
    assert spies.calls["batch"][1]["options"] == MuscleOptions(mode="model", model=str(spies.model.resolve()),
                                                               sequence_fit=True, for_extension=True)
    res = _invoke([a, "--out", tmp_path / "o3", "--model", spies.model, "--workers", "1", "--no-sequence-fit"])
    assert res.exit_code == 0, (res.output, res.exception)
    assert spies.calls["batch"][2]["options"] == MuscleOptions(mode="full", model=str(spies.model.resolve()),
                                                               sequence_fit=False, for_extension=False)


def test_batch_frames_longer_than_a_session_refused(spies, tmp_path):
    a, b, c = tmp_path / "A", tmp_path / "B", tmp_path / "C"
    spies.frames = {str(a): 40, str(c): 25}  # B unreadable: left to its unit
    res = _invoke([a, b, c, "--out", tmp_path / "o", "--model", spies.model, "--frames", "26"])
    _refused(res, f"--frames 26: {c} has 25 frames; give at most 25 (--frames applies to every SESSION of the "
                  "batch)")
    assert spies.calls["client"] == [] and spies.calls["batch"] == []
    res = _invoke([a, b, c, "--out", tmp_path / "o", "--model", spies.model, "--frames", "25"])
    assert res.exit_code == 0, (res.output, res.exception)
    assert spies.calls["batch"][0]["options"].frames == 25


def test_batch_refuses_an_out_file_and_a_bad_frame_rate(spies, tmp_path, monkeypatch):
    (tmp_path / "file").write_text("x")
    res = _invoke([tmp_path / "A", tmp_path / "B", "--out", tmp_path / "file", "--no-model"])
    _refused(res, f"--out {tmp_path / 'file'}: exists and is a file, not a folder; choose a folder path")
    assert spies.calls["client"] == []
    import bodystudio.muscle.capture as capture_mod

    def slow(session):
        raise InputError(f"{session.path}: 5 fps")

    monkeypatch.setattr(capture_mod, "capture_frame_rate", slow)
    spies.frames = {str(tmp_path / "B"): 10}  # A unreadable (left to its unit), B at 5 fps: still checked
    res = _invoke([tmp_path / "A", tmp_path / "B", "--out", tmp_path / "o", "--no-model"])
    _refused(res, f"{tmp_path / 'B'}: 5 fps")
    assert spies.calls["client"] == []


def test_batch_errors_are_a_batch_error(spies, tmp_path):
    from bodystudio.batch import BatchError

    spies.errors = ["x", "y"]
    res = _invoke([tmp_path / "A", tmp_path / "B", "--out", tmp_path / "o", "--no-model"])
    _refused(res, "2 sequences failed: see batch.json", BatchError)
    assert spies.calls["report"] == ["muscle capture (2 sequences)"]


def test_batch_shape_count_and_model_checked_before_the_cluster(spies, tmp_path, monkeypatch):
    res = _invoke([tmp_path / "A", tmp_path / "B", "--out", tmp_path / "o", "--model", spies.model, "--shape",
                   "bmi=31,muscularity=0.3,height_m=1.62,arm_length_m=0.55"])
    _refused(res, "~--shape: 1 given for 2 sessions")
    import bodystudio.muscle.model as model_mod

    def junk(path):
        raise InputError(f"{path}: not an arm model")

    monkeypatch.setattr(model_mod, "load_arm_model", junk)
    res = _invoke([tmp_path / "A", tmp_path / "B", "--out", tmp_path / "o", "--model", spies.model])
    _refused(res, f"{spies.model}: not an arm model")
    assert spies.calls["client"] == [] and spies.calls["scheduler"] == []
