"""``bodystudio synth session``, ``capture import / silhouettes / verify / recover`` and ``eval silhouettes``
through typer's CliRunner with the API replaced by spies (mutNN).

Each option must reach the API in its place (the positional calls are written out by hand, the defaults compared
with the API's signature), each printed line / JSON holds the API's figures, and each refusal is an
:class:`InputError` with its whole message before any work. Nothing is rendered or imported: the file runs in about
a second.
"""

from __future__ import annotations

import inspect
from pathlib import Path

import pytest

from tests.reliability.cli_spies import Spy
from tests.reliability.cli_spies import help_text as _help
from tests.reliability.cli_spies import invoke as _invoke
from tests.reliability.cli_spies import refused as _refused


class Session:
    camera_names = ["cam_00", "cam_01", "cam_02"]
    streams = ["rgb", "mask"]

    def __len__(self):
        return 7

    def verify(self):
        return 42


@pytest.fixture(autouse=True)
def _cwd(monkeypatch, tmp_path):
    monkeypatch.chdir(tmp_path)


# ------------------------------------------------------------------------------------------------ synth session

@pytest.fixture
def synth_spy(monkeypatch):
    import bodystudio.capture.synth as synth

    spy = Spy(ret=Session())
    spy.real = synth.synth_session
    monkeypatch.setattr(synth, "synth_session", spy)
    return spy


def test_synth_session_defaults(synth_spy):
    res = _invoke(["synth", "session", "s"])
    assert res.exit_code == 0, (res.output, res.exception)
    assert synth_spy.calls == [((Path("s"), 10, 30, "walk", 7, "v2", (640, 480), True, 0, "full"),
                                {"progress": True})]
    api = list(inspect.signature(synth_spy.real).parameters.values())
    assert tuple(p.default for p in api[1:10]) == (10, 30, "walk", 7, "v2", (640, 480), True, 0, "full")
    assert res.stdout == "wrote s: 3 cameras x 7 frames, streams rgb, mask\n"


def test_synth_session_every_option(synth_spy):
    res = _invoke(["synth", "session", "s", "--cameras", "4", "--frames", "2", "--motion", "turn", "--subject-seed",
                   "0", "--kinect", "v1", "--resolution", "320x240", "--no-noise", "--seed", "3", "--template", "2k"])
    assert res.exit_code == 0, (res.output, res.exception)
    assert synth_spy.calls == [((Path("s"), 4, 2, "turn", 0, "v1", (320, 240), False, 3, "2k"), {"progress": True})]
    for value in ("none",):
        assert _invoke(["synth", "session", f"t{value}", "--kinect", value]).exit_code == 0
        assert synth_spy.calls[-1][0][5] is None


def test_synth_session_refusals(synth_spy):
    Path("full").mkdir()
    (Path("full") / "x").write_text("x")
    _refused(_invoke(["synth", "session", "full"]), "synth session full: exists and is not empty; choose a new folder")
    _refused(_invoke(["synth", "session", "s", "--resolution", "640"]),
             "--resolution '640' must be WIDTHxHEIGHT in pixels, e.g. 640x480")
    for opt in ("--subject-seed", "--seed"):
        assert _invoke(["synth", "session", "s", opt, "-1"]).exit_code == 2
    assert not synth_spy.calls
    assert _invoke(["synth", "session", "s", "--subject-seed", "0", "--seed", "0"]).exit_code == 0
    assert synth_spy.calls[0][0][4] == 0 and synth_spy.calls[0][0][8] == 0


def test_synth_session_help():
    text = _help(["synth", "session"])
    for phrase in ("new session folder", "studio cameras on the ring", "frames to render",
                   "motion name (capture.motion.MOTIONS)", "subject drawn from the population",
                   "simulated Kinect: v1, v2 or none", "studio camera image size WxH", "camera sensor and Kinect noise",
                   "motion variation, noise and background texture", "body template resolution: full, 6k, 2k",
                   "Render a synthetic studio session with ground truth (meshes, joints, poses, masks)."):
        assert f" {phrase} " in f" {text} ", phrase


# ------------------------------------------------------------------------------------------------ capture import

@pytest.fixture
def import_spy(monkeypatch):
    import bodystudio.capture.importer as importer

    spy = Spy(ret=Session())
    spy.real = importer.import_recording
    monkeypatch.setattr(importer, "import_recording", spy)
    return spy


def test_import_defaults(import_spy):
    res = _invoke(["capture", "import", "s"])
    assert res.exit_code == 0, (res.output, res.exception)
    assert import_spy.calls == [((Path("s"),) + (None,) * 11 + ("studio",), {"progress": True})]
    api = list(inspect.signature(import_spy.real).parameters.values())
    assert tuple(p.default for p in api[1:13]) == (None,) * 11 + ("studio",)
    assert res.stdout == "wrote s: 3 cameras x 7 frames, streams rgb, mask\n"


def test_import_every_option_in_its_place(import_spy):
    res = _invoke(["capture", "import", "s", "--cameras", "c.json", "--images", "im", "--videos", "vid",
                   "--timestamps", "ts", "--backgrounds", "bg", "--tum", "tum", "--kinect-calibration", "k.json",
                   "--depth-scale", "5000", "--joints", "j.csv", "--frames", "12", "--masks", "m",
                   "--joints-frame", "kinect-sdk"])
    assert res.exit_code == 0, (res.output, res.exception)
    assert import_spy.calls == [((Path("s"), Path("c.json"), Path("im"), Path("vid"), Path("ts"), Path("bg"),
                                  Path("tum"), Path("k.json"), 5000.0, Path("j.csv"), 12, Path("m"), "kinect-sdk"),
                                 {"progress": True})]
    names = list(inspect.signature(import_spy.real).parameters)[1:13]
    assert names == ["cameras", "images", "videos", "timestamps", "backgrounds", "tum", "kinect_calibration",
                     "depth_scale", "joints", "n_frames", "masks", "joints_frame"]


def test_import_refuses_a_full_folder(import_spy):
    Path("full").mkdir()
    (Path("full") / "x").write_text("x")
    _refused(_invoke(["capture", "import", "full"]),
             "capture import full: exists and is not empty; choose a new folder")
    assert not import_spy.calls


def test_import_help():
    text = _help(["capture", "import"])
    for phrase in ("cameras.json, or a folder / file of EasyMocap intri.yml+extri.yml",
                   "folder with one image folder per camera", "folder with one video per camera (<cam>.avi ...)",
                   "folder with <cam>.txt frame times (s)", "empty-studio frames per camera",
                   "TUM RGB-D folder (depth.txt, rgb.txt, depth/, rgb/)", "Kinect calibration JSON",
                   "depth units per metre (TUM: 5000)", "tracker joints: JSON folder, .json or .csv",
                   "import at most this many frames", "existing silhouettes: one image folder per camera",
                   "studio, or kinect-sdk (camera space)"):
        assert f" {phrase} " in f" {text} ", phrase


# ------------------------------------------------------------------------------------------------ silhouettes

class Report:
    def to_dict(self):
        return {"iou_mean": 0.95, "cameras": {"cam_00": 0.9}}


@pytest.fixture
def seg_spy(monkeypatch):
    import bodystudio.capture.silhouettes as silhouettes

    spy = Spy(ret=Report())
    monkeypatch.setattr(silhouettes, "segment_session", spy)
    Path("s").mkdir()
    return spy


def test_silhouettes_defaults_and_json(seg_spy):
    from bodystudio.capture.silhouettes import SegmentationParams

    res = _invoke(["capture", "silhouettes", "s"])
    assert res.exit_code == 0, (res.output, res.exception)
    assert seg_spy.calls == [((Path("s"), SegmentationParams(tau_cd=4.0, close_px=0, open_px=0)), {"progress": True})]
    assert seg_spy.calls[0][0][1] == SegmentationParams()
    assert res.stdout == '{\n  "iou_mean": 0.95,\n  "cameras": {\n    "cam_00": 0.9\n  }\n}\n'


def test_silhouettes_options(seg_spy):
    from bodystudio.capture.silhouettes import SegmentationParams

    res = _invoke(["capture", "silhouettes", "s", "--tau-cd", "6.5", "--close", "3", "--open", "2"])
    assert res.exit_code == 0, (res.output, res.exception)
    assert seg_spy.calls[0][0][1] == SegmentationParams(tau_cd=6.5, close_px=3, open_px=2)


def test_silhouettes_refusals(seg_spy):
    _refused(_invoke(["capture", "silhouettes", "none"]), "none: no such session folder")
    Path("f").write_text("x")
    _refused(_invoke(["capture", "silhouettes", "f"]), "f: no such session folder")
    assert not seg_spy.calls


def test_silhouettes_help():
    text = _help(["capture", "silhouettes"])
    for phrase in ("chromaticity-distortion threshold (normalised)", "morphological closing kernel (px, 0 = none)",
                   "morphological opening kernel (px, 0 = none)",
                   "Segment the subject by background subtraction and write cam_NN/mask/ (prints JSON, IoU if GT)."):
        assert f" {phrase} " in f" {text} ", phrase


def test_eval_silhouettes(monkeypatch):
    import bodystudio.capture.session as session_mod
    import bodystudio.capture.silhouettes as silhouettes

    opened = Spy(ret="OPENED")
    scores = Spy(ret=Report())
    monkeypatch.setattr(session_mod, "open_session", opened)
    monkeypatch.setattr(silhouettes, "silhouette_scores", scores)
    res = _invoke(["eval", "silhouettes", "s"])
    assert res.exit_code == 0, (res.output, res.exception)
    assert opened.calls == [((Path("s"),), {})] and scores.calls == [(("OPENED",), {})]
    assert res.stdout == '{\n  "iou_mean": 0.95,\n  "cameras": {\n    "cam_00": 0.9\n  }\n}\n'


# ------------------------------------------------------------------------------------------------ verify / recover

def test_verify_line(monkeypatch):
    import bodystudio.capture.session as session_mod

    opened = Spy(ret=Session())
    monkeypatch.setattr(session_mod, "open_session", opened)
    res = _invoke(["capture", "verify", "s"])
    assert res.exit_code == 0, (res.output, res.exception)
    assert opened.calls == [((Path("s"),), {})]
    assert res.stdout == "s: 42 files ok (3 cameras x 7 frames)\n"


def test_recover_line_and_refusal(monkeypatch):
    import bodystudio.capture.session as session_mod

    rec = Spy(ret="finished the interrupted write")
    monkeypatch.setattr(session_mod, "recover_session", rec)
    _refused(_invoke(["capture", "recover", "s"]), "s: no such session folder")
    assert not rec.calls
    Path("s").mkdir()
    res = _invoke(["capture", "recover", "s"])
    assert res.exit_code == 0, (res.output, res.exception)
    assert rec.calls == [((Path("s"),), {})]
    assert res.stdout == "s: finished the interrupted write\n"


def test_verify_recover_help():
    assert " Check every file of a session against the manifest's sha256. " in _help(["capture", "verify"])
    assert " Finish or discard a write that was interrupted (power loss, kill). " in _help(["capture", "recover"])
    assert " IoU of the session's masks against its ground-truth masks (JSON). " in _help(["eval", "silhouettes"])



def test_silhouettes_refuses_a_read_only_session_before_segmenting(seg_spy, monkeypatch):
    """The masks are written into the session: a session on a read-only mount is refused, naming it."""
    import errno

    import bodystudio.fileio as fileio

    def read_only(*args, **kwargs):
        raise OSError(errno.EROFS, "Read-only file system")

    monkeypatch.setattr(fileio.tempfile, "mkstemp", read_only)
    _refused(_invoke(["capture", "silhouettes", "s"]),
             "session s: cannot write in s (Read-only file system); choose a writable place")
    assert not seg_spy.calls
