"""``bodystudio muscle model extend`` through typer's CliRunner with the API replaced by spies (mutKK).

The model and capture readers, ``capture_samples``, ``extend_arm_model`` and ``save_arm_model`` record their
arguments: each option must reach them unchanged, each capture is checked before anything is learnt, each refusal
is an :class:`InputError` with its whole message, and the shape of each subject comes from where the help says
(``--shape``, else the session's measured subject, else the capture's fitted shape). About a second.
"""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from typer.testing import CliRunner

from bodystudio.errors import BodyStudioError, InputError

JOINTS = np.arange(9.0).reshape(3, 3)


def _invoke(args):
    from bodystudio.cli.main import app

    return CliRunner().invoke(app, ["muscle", "model", "extend", *[str(a) for a in args]])


def _refused(res, message):
    assert isinstance(res.exception, InputError), (res.exit_code, res.output, res.exception)
    assert res.exit_code != 0
    assert str(res.exception) == message


class Capture:
    def __init__(self, folder: Path, n: int, fitted=True, shape=None, session_path=None, same=True):
        from bodystudio.muscle.model import ArmShapeParams

        self.template_key = "6k-left-k"
        self.mode = "full"
        self.poses = [np.zeros(3)]
        self.source_fingerprint = f"fp{n}"
        self.frame_ids = [0, 1, 2]
        self.vertices = np.full((2, 3), float(n))
        self.session_path = session_path
        self.shape = shape if shape is not None else ArmShapeParams(25.0, 0.5, 1.7, 0.6, sex=1.0)
        self.regressed_joints = JOINTS
        self.joints = JOINTS + (1e-3 if fitted else 0.0)
        self.same = same
        self.asked = []

    def is_from(self, session):
        self.asked.append(session)
        return self.same


@pytest.fixture
def spies(tmp_path, monkeypatch):
    import bodystudio.capture.session as session_mod
    import bodystudio.muscle.capture as capture_mod
    import bodystudio.muscle.model as model_mod

    s = SimpleNamespace(model=SimpleNamespace(template_key="6k-left-k"), loaded=[], samples=[], extend=[], save=[],
                        captures={}, sessions={}, joints_asked=[])
    s.real_extend = model_mod.extend_arm_model
    for name in ("C1", "C2"):
        (tmp_path / name).mkdir()
        s.captures[str(tmp_path / name)] = Capture(tmp_path / name, len(s.captures) + 1)
    (tmp_path / "M.npz").write_bytes(b"m")

    def load_model(path):
        s.loaded.append(path)
        return s.model

    def load_capture(folder):
        return s.captures[str(folder)]

    def samples(capture, name, shape, stride, model=None, centre=None):
        s.samples.append(dict(capture=capture, name=name, shape=shape, stride=stride, model=model, centre=centre))
        return [f"{name}-sample"]

    def extend(model, samples, **kwargs):
        s.extend.append(dict(model=model, samples=samples, **kwargs))
        s.extended = SimpleNamespace(subjects=["a"] * 17)
        return s.extended

    def open_session(path):
        if str(path) not in s.sessions:
            raise BodyStudioError(f"{path}: gone")
        return s.sessions[str(path)]

    def model_joints(model, shape):
        s.joints_asked.append((model, shape))
        return JOINTS

    monkeypatch.setattr(model_mod, "load_arm_model", load_model)
    monkeypatch.setattr(capture_mod, "load_arm_capture", load_capture)
    monkeypatch.setattr(model_mod, "capture_samples", samples)
    monkeypatch.setattr(model_mod, "extend_arm_model", extend)
    monkeypatch.setattr(model_mod, "save_arm_model", lambda out, m: s.save.append((out, m)))
    monkeypatch.setattr(model_mod, "model_joints", model_joints)
    monkeypatch.setattr(session_mod, "open_session", open_session)
    return s


def _same_shape(a, b):
    return all(getattr(a, n) == getattr(b, n) for n in ("bmi", "muscularity", "height_m", "arm_length_m", "sex"))


def test_extend_defaults(tmp_path, spies):
    from bodystudio.muscle.model import ArmShapeParams

    c1, c2 = tmp_path / "C1", tmp_path / "C2"
    spies.captures[str(c1)].session_path = tmp_path / "S1"
    spies.sessions[str(tmp_path / "S1")] = SimpleNamespace(
        gt_subject={"arm": {"subject": {"bmi": 30, "muscularity": 0.2, "height_m": 1.6, "arm_length_m": 0.5,
                                        "sex": 0.0}}})
    out = tmp_path / "new.npz"
    res = _invoke([tmp_path / "M.npz", c1, c2, "--out", out])
    assert res.exit_code == 0, (res.output, res.exception)
    assert spies.loaded == [tmp_path / "M.npz"]
    s1, s2 = spies.samples
    assert s1["capture"] is spies.captures[str(c1)] and s2["capture"] is spies.captures[str(c2)]
    assert (s1["name"], s2["name"]) == ("capture_C1", "capture_C2")
    assert _same_shape(s1["shape"], ArmShapeParams(30.0, 0.2, 1.6, 0.5, sex=0.0))
    assert s2["shape"] is spies.captures[str(c2)].shape  # no session: the capture's fitted shape
    assert all(s["stride"] == 5 and s["model"] is spies.model and s["centre"] == "sex" for s in (s1, s2))
    assert spies.captures[str(c1)].asked == [spies.sessions[str(tmp_path / "S1")]]
    (ext,) = spies.extend
    assert ext == dict(model=spies.model, samples=["capture_C1-sample", "capture_C2-sample"], captured_rest="body",
                       shape_form="body", subject_rows="own")
    import inspect

    assert inspect.signature(spies.real_extend).parameters["subject_rows"].default == "own"
    assert spies.save == [(out, spies.extended)]
    assert res.stdout == f"wrote {out}: 17 subjects (2 added from captures), body shape term\n"
    assert res.stderr == (f"{c1}: shape from the measured subject of {tmp_path / 'S1'}\n"
                          f"{c2}: shape from the capture's fitted shape (it names no session)\n")


def test_extend_every_option(tmp_path, spies):
    c1, c2 = tmp_path / "C1", tmp_path / "C2"
    out = tmp_path / "new.NPZ"
    res = _invoke([tmp_path / "M.npz", c1, c2, "--out", out, "--shape",
                   "bmi=31,muscularity=0.3,height_m=1.62,arm_length_m=0.55", "--shape",
                   "bmi=22,muscularity=0.5,height_m=1.8,arm_length_m=0.6,sex=female", "--stride", "1000",
                   "--centre", "regressed", "--captured-rest", "mesh", "--shape-form", "linear", "--subject-rows",
                   "training"])
    assert res.exit_code == 0, (res.output, res.exception)
    s1, s2 = spies.samples
    assert (s1["shape"].bmi, s2["shape"].bmi, s2["shape"].sex) == (31.0, 22.0, 0.0)
    assert s1["stride"] == 1000 and s1["centre"] == "regressed"
    assert spies.extend[0]["captured_rest"] == "mesh" and spies.extend[0]["shape_form"] == "linear"
    assert spies.extend[0]["subject_rows"] == "training"
    assert res.stdout.endswith("linear shape term\n")
    assert res.stderr == f"{c1}: shape from --shape\n{c2}: shape from --shape\n"
    res = _invoke([tmp_path / "M.npz", c1, "--out", tmp_path / "b.npz", "--stride", "1", "--centre", "fitted"])
    assert res.exit_code == 0, (res.output, res.exception)
    assert spies.samples[2]["stride"] == 1 and spies.samples[2]["centre"] == "fitted"


@pytest.mark.parametrize("args, message", [
    (["--stride", "0"], "--stride 0: must be in [1, 1000]"),
    (["--stride", "1001"], "--stride 1001: must be in [1, 1000]"),
    (["--centre", "mean"], "--centre 'mean': valid: sex, fitted, regressed"),
    (["--captured-rest", "scan"], "--captured-rest 'scan': valid: body, mesh"),
    (["--shape-form", "pca"], "--shape-form 'pca': valid: body, linear"),
    (["--subject-rows", "all"], "--subject-rows 'all': valid: own, training"),
    (["--shape", "bmi=31,muscularity=0.3,height_m=1.62,arm_length_m=0.55"],
     "--shape: 1 given for 2 captures; give one --shape per capture, in the captures' order (repeat the values for "
     "captures of one subject)"),
])
def test_extend_option_refusals(tmp_path, spies, args, message):
    _refused(_invoke([tmp_path / "M.npz", tmp_path / "C1", tmp_path / "C2", "--out", tmp_path / "o.npz", *args]),
             message)
    assert spies.loaded == [] and spies.extend == []


def test_extend_out_refusals(tmp_path, spies):
    _refused(_invoke([tmp_path / "M.npz", tmp_path / "C1", "--out", tmp_path / "o.npy"]),
             f"--out {tmp_path / 'o.npy'}: an arm model is a .npz file")
    _refused(_invoke([tmp_path / "M.npz", tmp_path / "C1", "--out", tmp_path / "M.npz"]),
             f"{tmp_path / 'M.npz'}: model file already exists; choose a new path or remove it")
    assert spies.loaded == [] and spies.extend == []


def _bad(spies, tmp_path, change):
    change(spies.captures[str(tmp_path / "C2")])
    return _invoke([tmp_path / "M.npz", tmp_path / "C1", tmp_path / "C2", "--out", tmp_path / "o.npz"])


def test_extend_capture_refusals(tmp_path, spies):
    c2 = tmp_path / "C2"
    _refused(_invoke([tmp_path / "M.npz", tmp_path / "C1", tmp_path / "none", "--out", tmp_path / "o.npz"]),
             f"{tmp_path / 'none'}: no such arm capture folder")
    _refused(_bad(spies, tmp_path, lambda c: setattr(c, "template_key", "2k-left-k")),
             f"{c2}: captured on arm template 2k-left-k, the model's is 6k-left-k; capture with the model's "
             "--resolution and --side")
    spies.captures[str(c2)].template_key = "6k-left-k"
    _refused(_bad(spies, tmp_path, lambda c: setattr(c, "mode", "nicp")),
             f"{c2}: captured with --no-model (no joint angles); capture with --model")
    spies.captures[str(c2)].mode = "model"
    _refused(_bad(spies, tmp_path, lambda c: setattr(c, "poses", [None])),
             f"{c2}: captured with --no-model (no joint angles); capture with --model")
    spies.captures[str(c2)].poses = [np.zeros(3)]
    _refused(_bad(spies, tmp_path, lambda c: setattr(c, "source_fingerprint", "fp1")),
             f"{c2}: a capture of the same recording as {tmp_path / 'C1'} (same depth frames); each subject is added "
             "once: drop one of them")
    assert spies.samples == [] and spies.extend == []  # every capture checked before anything is learnt
    assert _bad(spies, tmp_path, lambda c: setattr(c, "frame_ids", [0, 1])).exit_code == 0  # other frames: kept


def test_extend_recording_key_without_fingerprint(tmp_path, spies):
    for c in spies.captures.values():
        c.source_fingerprint = None
    res = _invoke([tmp_path / "M.npz", tmp_path / "C1", tmp_path / "C2", "--out", tmp_path / "o.npz"])
    assert res.exit_code == 0, (res.output, res.exception)  # other meshes
    spies.captures[str(tmp_path / "C2")].vertices = spies.captures[str(tmp_path / "C1")].vertices.astype(np.float32)
    _refused(_invoke([tmp_path / "M.npz", tmp_path / "C1", tmp_path / "C2", "--out", tmp_path / "p.npz"]),
             f"{tmp_path / 'C2'}: a capture of the same recording as {tmp_path / 'C1'} (same depth frames); each "
             "subject is added once: drop one of them")


def test_recording_key_by_hand():
    import hashlib

    from bodystudio.cli.muscle import _recording_key

    c = SimpleNamespace(source_fingerprint="abc", frame_ids=(3, 4), vertices=None)
    assert _recording_key(c) == "abc:[3, 4]"
    v = np.arange(6, dtype=np.float32).reshape(3, 2).T  # not contiguous, float32
    c = SimpleNamespace(source_fingerprint=None, frame_ids=[0], vertices=v)
    assert _recording_key(c) == hashlib.sha256(np.array(v, np.float64, order="C").tobytes()).hexdigest()


def test_measured_subject_fallbacks(tmp_path, spies):
    c1 = tmp_path / "C1"
    cap = spies.captures[str(c1)]

    def run():
        res = _invoke([tmp_path / "M.npz", c1, "--out", tmp_path / f"o{len(spies.extend)}.npz"])
        assert res.exit_code == 0, (res.output, res.exception)
        assert spies.samples[-1]["shape"] is cap.shape
        return res.stderr.splitlines()[0]

    cap.session_path = tmp_path / "S"
    assert run() == f"{c1}: shape from the capture's fitted shape ({tmp_path / 'S'} cannot be opened)"
    spies.sessions[str(tmp_path / "S")] = SimpleNamespace(gt_subject=None)
    cap.same = False
    assert run() == f"{c1}: shape from the capture's fitted shape ({tmp_path / 'S'} is now another recording)"
    cap.same = None  # a capture from before the fingerprint: the session's subject is read
    assert run() == f"{c1}: shape from the capture's fitted shape ({tmp_path / 'S'} records no measured subject)"
    spies.sessions[str(tmp_path / "S")] = SimpleNamespace(gt_subject={"arm": {}})
    assert run().endswith("records no measured subject)")
    spies.sessions[str(tmp_path / "S")] = SimpleNamespace(gt_subject={"arm": {"subject": {}}})
    assert run().endswith("records no measured subject)")


def test_fitted_skeleton_note(tmp_path, spies):
    c1 = tmp_path / "C1"
    cap = spies.captures[str(c1)]
    note = (f"{c1}: captured without --for-extension (no fitted skeleton, so --centre changes nothing); captures "
            "made with it extend the model more (docs/muscle.md)")

    def notes():
        res = _invoke([tmp_path / "M.npz", c1, "--out", tmp_path / f"o{len(spies.extend)}.npz"])
        assert res.exit_code == 0, (res.output, res.exception)
        return res.stderr.splitlines()[1:]

    assert notes() == []  # joints 1 mm off the regression: a fitted skeleton
    assert spies.joints_asked == []  # the capture's own regression used
    cap.joints = JOINTS + 2e-7
    assert notes() == []
    cap.joints = JOINTS + 5e-8
    assert notes() == [note]
    cap.joints = None
    assert notes() == [note]
    cap.joints = JOINTS + 1e-3
    cap.shape = None
    assert notes() == [note]
    from bodystudio.muscle.model import ArmShapeParams

    cap.shape = ArmShapeParams(25.0, 0.5, 1.7, 0.6)
    cap.regressed_joints = None  # a capture made before it was recorded: the model regresses it
    cap.joints = JOINTS
    assert notes() == [note]
    assert spies.joints_asked == [(spies.model, cap.shape)]
    cap.joints = JOINTS * (1 + 1e-7)  # relative tolerance 0: off by up to 8e-7
    assert notes() == []
