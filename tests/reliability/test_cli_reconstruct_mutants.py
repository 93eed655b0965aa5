"""``bodystudio reconstruct SESSION`` through typer's CliRunner with the API replaced by spies (mutNN).

Each option must reach :func:`reconstruct_session` (or, on a cluster, :class:`ReconstructOptions` and
``reconstruct_batch``) unchanged, the CLI's defaults must equal the API's, and every refusal must be an
:class:`InputError` (the console script's one line and exit 2) with its whole message, raised before any work.
The expected calls are written out by hand from the help. No session is read: the file runs in about a second.
"""

from __future__ import annotations

import inspect
from contextlib import contextmanager
from dataclasses import asdict, replace
from pathlib import Path
from types import SimpleNamespace

import pytest

from bodystudio.errors import InputError
from bodystudio.reconstruct.rapid_skin import RapidSkinParams
from tests.reliability.cli_spies import Spy
from tests.reliability.cli_spies import invoke as _invoke
from tests.reliability.cli_spies import refused as _refused

SUMMARY = {"frames": 3, "median_mm": 12.3456, "note": "ok"}


@pytest.fixture
def seq(monkeypatch, tmp_path):
    import bodystudio.reconstruct.sequence as sequence

    monkeypatch.delenv("BODYSTUDIO_SCHEDULER", raising=False)
    monkeypatch.chdir(tmp_path)
    Path("s").mkdir()
    spy = Spy(ret=dict(SUMMARY))
    spy.real = sequence.reconstruct_session
    monkeypatch.setattr(sequence, "reconstruct_session", spy)
    return spy


@pytest.fixture
def cluster(monkeypatch, seq):
    import bodystudio.batch as batch
    import bodystudio.capture.session as session_mod
    import bodystudio.cli.batch as cli_batch
    import bodystudio.reconstruct.sequence as sequence

    ns = SimpleNamespace(log=[])

    @contextmanager
    def client(scheduler, workers, units=None):
        ns.log.append(("client", scheduler, workers, units))
        yield "CLIENT"
        ns.log.append(("client closed",))

    def record(name, ret=None):
        def fn(*args, **kwargs):
            ns.log.append((name, args, kwargs))
            return ret
        return fn

    monkeypatch.setattr(batch, "batch_client", client)
    monkeypatch.setattr(batch, "resolve_scheduler", record("resolve"))
    monkeypatch.setattr(batch, "reconstruct_batch", record("batch", ({"frames": 25, "median_mm": 9.0}, "REPORT")))
    monkeypatch.setattr(cli_batch, "print_cluster", record("print_cluster"))
    monkeypatch.setattr(cli_batch, "print_report", record("print_report"))
    ns.opened = SimpleNamespace(frame_ids=list(range(100, 125)))
    monkeypatch.setattr(session_mod, "open_session", record("open", ns.opened))
    monkeypatch.setattr(sequence, "run_subject", record("subject"))
    return ns


def _call(spy):
    (args, kwargs), = spy.calls
    return args, kwargs


def test_defaults_reach_the_api_as_its_own_defaults(seq):
    res = _invoke(["reconstruct", "s"])
    assert res.exit_code == 0, (res.output, res.exception)
    args, kw = _call(seq)
    assert args == (Path("s"),)
    assert kw == dict(solver="gs", template="13k", joints="tracker", constraints=("silhouette",), frames=None,
                      joints_path=None, warm_start=False, refine_pose=True, score=True, progress=True,
                      bone_lengths="sequence", accept_implausible=False, player=None,
                      params=RapidSkinParams(outer_iterations=8, inner_iterations=8, tau_px=30.0, alpha_px=40.0,
                                             solver="gs", constraints=("silhouette",)),
                      tracking=False, joint_smoothing=0)
    assert kw["params"] == RapidSkinParams()  # the paper's defaults
    api = inspect.signature(seq.real).parameters
    for name in ("solver", "template", "joints", "constraints", "frames", "joints_path", "warm_start", "refine_pose",
                 "score", "bone_lengths", "accept_implausible", "player", "tracking", "joint_smoothing"):
        assert kw[name] == api[name].default, name


def test_the_summary_table(seq):
    res = _invoke(["reconstruct", "s"])
    lines = res.stdout.splitlines()
    title = " ".join(ln.strip() for ln in lines[:next(k for k, ln in enumerate(lines) if "┏" in ln)])
    assert title == "Rapid Skin: s (gs, 13k, silhouette)"
    rows = [ln.replace("│", " ").split() for ln in res.stdout.splitlines() if "│" in ln]
    assert rows == [["frames", "3"], ["median_mm", "12.35"], ["note", "ok"]]
    header = [ln.replace("┃", " ").split() for ln in res.stdout.splitlines() if "┃" in ln]
    assert header == [["figure", "value"]]
    row = next(ln for ln in res.stdout.splitlines() if "frames" in ln).split("│")
    assert row[2] == "     3 "  # right-aligned


def test_every_option_reaches_the_api(seq, tmp_path):
    res = _invoke(["reconstruct", "s", "--solver", "cg", "--template", "2k", "--joints", "file", "--joints-path",
                   "jp", "--constraints", " depth , silhouette ", "--frames", "2:5", "--outer", "3", "--inner", "4",
                   "--tau", "12.5", "--alpha", "20", "--warm-start", "--no-refine-pose", "--bone-lengths", "frame",
                   "--joint-smoothing", "50", "--no-score", "--tracking", "--accept-implausible"])
    assert res.exit_code == 0, (res.output, res.exception)
    args, kw = _call(seq)
    assert kw == dict(solver="cg", template="2k", joints="file", constraints=("depth", "silhouette"), frames="2:5",
                      joints_path=Path("jp"), warm_start=True, refine_pose=False, score=False, progress=True,
                      bone_lengths="frame", accept_implausible=True, player=None,
                      params=RapidSkinParams(outer_iterations=3, inner_iterations=4, tau_px=12.5, alpha_px=20.0,
                                             solver="cg", constraints=("depth", "silhouette")),
                      tracking=True, joint_smoothing=50)
    lines = res.stdout.splitlines()
    title = " ".join(ln.strip() for ln in lines[:next(k for k, ln in enumerate(lines) if "┏" in ln)])
    assert title == "Rapid Skin: s (cg, 2k,  depth , silhouette )"  # the option as given


def test_player_reaches_the_api_at_both_ends(seq):
    for p in (1, 6):
        res = _invoke(["reconstruct", "s", "--player", str(p), "--joints", "tracker"])
        assert res.exit_code == 0, (res.output, res.exception)
        assert seq.calls[-1][1]["player"] == p


def test_constraints_parsing():
    from bodystudio.cli.reconstruct import _constraints

    assert _constraints("silhouette") == ("silhouette",)
    assert _constraints("silhouette,,depth,") == ("silhouette", "depth")
    for bad in ("", " , ", "silhouette,colour", "Silhouette"):
        with pytest.raises(InputError) as exc:
            _constraints(bad)
        assert str(exc.value) == f"--constraints {bad!r}: use silhouette, depth or silhouette,depth"


def test_accurate_sets_the_presets_over_the_cli_params(seq):
    res = _invoke(["reconstruct", "s", "--accurate", "--constraints", "silhouette,depth", "--outer", "5",
                   "--joint-smoothing", "2"])
    assert res.exit_code == 0, (res.output, res.exception)
    _, kw = _call(seq)
    params = RapidSkinParams(outer_iterations=5, constraints=("silhouette", "depth"), surface_hold_k=1.0,
                             surface_hold_region="torso")
    assert kw["params"] == params
    assert (kw["tracking"], kw["joint_smoothing"], kw["smoothing_guard"], kw["shape_prior"], kw["refine_depth"],
            kw["refine_depth_bones"]) == (True, 2, 0.05, "frame", 3.0, "all")
    assert kw["track_params"].unstretch_head is False
    assert kw["constraints"] == ("silhouette", "depth") and kw["progress"] is True
    res = _invoke(["reconstruct", "s", "--accurate"])
    assert res.exit_code == 0 and seq.calls[-1][1]["joint_smoothing"] == 2


@pytest.mark.parametrize("args, message", [
    (["missing"], "missing: no such session folder"),
    (["s", "--bone-lengths", "median"], "--bone-lengths 'median': use frame or sequence"),
    (["s", "--joint-smoothing", "-1"], "--joint-smoothing -1: give a half window of 0..50 frames"),
    (["s", "--joint-smoothing", "51"], "--joint-smoothing 51: give a half window of 0..50 frames"),
    (["s", "--player", "0"], "--player 0: the Kinect SDK numbers players 1 to 6"),
    (["s", "--player", "7"], "--player 7: the Kinect SDK numbers players 1 to 6"),
    (["s", "--player", "2", "--joints", "hull"],
     "--player chooses among the session's tracked bodies; drop it or use --joints tracker (not hull)"),
    (["s", "--accurate", "--workers", "2"],
     "--accurate runs on the sequential path only (it tracks and smooths over neighbouring frames); drop "
     "--workers/--scheduler/--chunk (and $BODYSTUDIO_SCHEDULER) or drop --accurate"),
    (["s", "--accurate", "--chunk", "3"],
     "--accurate runs on the sequential path only (it tracks and smooths over neighbouring frames); drop "
     "--workers/--scheduler/--chunk (and $BODYSTUDIO_SCHEDULER) or drop --accurate"),
    (["s", "--accurate", "--scheduler", "tcp://h:1"],
     "--accurate runs on the sequential path only (it tracks and smooths over neighbouring frames); drop "
     "--workers/--scheduler/--chunk (and $BODYSTUDIO_SCHEDULER) or drop --accurate"),
    (["s", "--accurate", "--joint-smoothing", "1"],
     "--accurate sets --joint-smoothing 2 itself; drop --joint-smoothing 1 or drop --accurate"),
    (["s", "--constraints", "colour"], "--constraints 'colour': use silhouette, depth or silhouette,depth"),
    (["s", "--workers", "2", "--tracking"],
     "--tracking runs on the sequential path only; drop --workers/--scheduler/--chunk (and $BODYSTUDIO_SCHEDULER) "
     "or drop --tracking"),
    (["s", "--chunk", "4", "--joint-smoothing", "1"],
     "--joint-smoothing runs on the sequential path only (a chunk lacks its neighbours' joints); drop "
     "--workers/--scheduler/--chunk (and $BODYSTUDIO_SCHEDULER) or --joint-smoothing"),
    (["s", "--chunk", "0"], "--chunk 0: give at least 1 frame per work unit"),
])
def test_refusals_before_any_work(cluster, seq, args, message):
    res = _invoke(["reconstruct", *args])
    _refused(res, message)
    assert not seq.calls and not cluster.log


def test_refusals_in_order(seq):
    _refused(_invoke(["reconstruct", "missing", "--bone-lengths", "x"]), "missing: no such session folder")
    _refused(_invoke(["reconstruct", "s", "--bone-lengths", "x", "--joint-smoothing", "99"]),
             "--bone-lengths 'x': use frame or sequence")
    _refused(_invoke(["reconstruct", "s", "--joint-smoothing", "99", "--player", "9"]),
             "--joint-smoothing 99: give a half window of 0..50 frames")
    _refused(_invoke(["reconstruct", "s", "--player", "9", "--joints", "hull"]),
             "--player 9: the Kinect SDK numbers players 1 to 6")


def test_output_folder_checked_before_any_work(seq):
    Path("s/reconstruct").write_text("a file")
    _refused(_invoke(["reconstruct", "s", "--constraints", "bad"]),
             "reconstruct output s/reconstruct: exists and is a file, not a folder; choose a folder path")
    assert not seq.calls


def test_environment_scheduler_is_a_cluster(cluster, seq, monkeypatch):
    monkeypatch.setenv("BODYSTUDIO_SCHEDULER", "tcp://env:8786")
    _refused(_invoke(["reconstruct", "s", "--accurate"]),
             "--accurate runs on the sequential path only (it tracks and smooths over neighbouring frames); drop "
             "--workers/--scheduler/--chunk (and $BODYSTUDIO_SCHEDULER) or drop --accurate")
    res = _invoke(["reconstruct", "s"])
    assert res.exit_code == 0, (res.output, res.exception)
    assert not seq.calls and cluster.log[0] == ("resolve", (None, None), {})
    monkeypatch.setenv("BODYSTUDIO_SCHEDULER", "")
    res = _invoke(["reconstruct", "s"])
    assert res.exit_code == 0 and len(seq.calls) == 1  # an empty variable is no scheduler


def test_cluster_defaults(cluster, seq):
    from bodystudio.batch import ReconstructOptions

    res = _invoke(["reconstruct", "s", "--workers", "3"])
    assert res.exit_code == 0, (res.output, res.exception)
    assert not seq.calls
    params = RapidSkinParams()
    opts = ReconstructOptions(solver="gs", params=asdict(params), template="13k", joints="tracker", warm_start=False,
                              refine_pose=True, score=True, bone_lengths="sequence", joints_path=None)
    assert cluster.log == [
        ("resolve", (None, 3), {}),
        ("open", (Path("s"),), {}),
        ("subject", (cluster.opened, list(range(100, 125)), "tracker", None), {}),
        ("client", None, 3, 3),
        ("print_cluster", ("CLIENT",), {}),
        ("batch", (Path("s"), "CLIENT", opts), dict(frames=None, chunk=10, force=False, progress=True,
                                                    accept_implausible=False, player=None)),
        ("client closed",),
        ("print_report", ("REPORT", "reconstruct s"), {}),
    ]
    rows = [ln.replace("│", " ").split() for ln in res.stdout.splitlines() if "│" in ln]
    assert rows == [["frames", "25"], ["median_mm", "9.00"]]


def test_cluster_every_option(cluster, seq):
    from bodystudio.batch import ReconstructOptions

    res = _invoke(["reconstruct", "s", "--scheduler", "tcp://h:8786", "--chunk", "1", "--force", "--frames", "103:107",
                   "--solver", "jacobi", "--template", "6k", "--joints", "file", "--joints-path", "jp",
                   "--warm-start", "--no-refine-pose", "--no-score", "--bone-lengths", "frame", "--outer", "2",
                   "--constraints", "depth", "--accept-implausible"])
    assert res.exit_code == 0, (res.output, res.exception)
    params = RapidSkinParams(outer_iterations=2, solver="jacobi", constraints=("depth",))
    opts = ReconstructOptions(solver="jacobi", params=asdict(params), template="6k", joints="file", warm_start=True,
                              refine_pose=False, score=False, bone_lengths="frame", joints_path="jp")
    log = cluster.log
    assert log[0] == ("resolve", ("tcp://h:8786", None), {})
    assert log[2][1][1:] == ([103, 104, 105, 106], "file", None)
    assert log[3] == ("client", "tcp://h:8786", None, 4)
    assert log[5] == ("batch", (Path("s"), "CLIENT", opts), dict(frames="103:107", chunk=1, force=True,
                                                                 progress=True, accept_implausible=True, player=None))


def test_cluster_units_round_up_and_the_player_is_passed(cluster, seq):
    res = _invoke(["reconstruct", "s", "--chunk", "7", "--player", "4"])
    assert res.exit_code == 0, (res.output, res.exception)
    assert cluster.log[3] == ("client", None, None, 4)  # 25 frames in chunks of 7
    assert cluster.log[2][1][2:] == ("tracker", 4)
    assert cluster.log[5][2]["player"] == 4 and cluster.log[5][2]["chunk"] == 7
    res = _invoke(["reconstruct", "s", "--chunk", "5"])
    assert cluster.log[-5] == ("client", None, None, 5)
    res = _invoke(["reconstruct", "s", "--workers", "2", "--frames", "100:121"])  # 21 frames, 10 per unit
    assert cluster.log[-5] == ("client", None, 2, 3) and cluster.log[-3][2]["chunk"] == 10
    assert cluster.log[-6][1][0] is cluster.opened


def test_cluster_frames_refused_before_the_cluster(cluster, seq):
    res = _invoke(["reconstruct", "s", "--workers", "2", "--frames", "900:901"])
    assert isinstance(res.exception, InputError), res.output
    assert [e[0] for e in cluster.log] == ["resolve", "open"]


def test_help_states_the_defaults():
    res = _invoke(["reconstruct", "--help"])
    text = " ".join(res.stdout.replace("│", " ").split())
    for phrase in ("gs | jacobi | cholesky | cg", "template resolution: 13k | 6k | 2k",
                   "outer iterations No (contour re-matching), 1..100", "inner solver iterations Ni, 1..1000",
                   "contour search range tau (pixels), 1..500", "silhouette weight width alpha (pixels), 1..1000",
                   "frames per work unit on a cluster (default 10)", "Kinect player id (1-6)",
                   "Deform the template to every frame's silhouettes (Rapid Skin); writes SESSION/reconstruct/.",
                   "capture session folder", "tracker (session Kinect joints) | file | hull (visual hull)",
                   "folder of NNNNN.json joint files for --joints file", "silhouette, depth or silhouette,depth",
                   "frame range A:B (B exclusive)", "carry the shape over from earlier frames",
                   "refine the joints' pose by an articulated fit to the silhouettes' visual hull before deforming "
                   "(--no-refine-pose: the paper's init)",
                   "sequence (default: one set of bone lengths per run, the median of the tracked lengths over its "
                   "frames) | frame (each frame's tracked lengths, which jitter)",
                   "smooth the tracked joints over time: a line fitted through each joint's positions within this "
                   "many frames (0: off; 2 measured better on 30 fps sessions; sequential path only)",
                   "score against ground truth when the session has it",
                   "start each frame from the previous frame's pose fitted to its silhouettes, re-initialising from "
                   "the joints on a lost track (default --no-tracking: every frame from its joints, measured more "
                   "accurate)",
                   "run chunks on this dask scheduler (tcp://HOST:8786; default $BODYSTUDIO_SCHEDULER)",
                   "run chunks on a local cluster of N worker processes",
                   "on a cluster: redo every chunk, also unchanged ones",
                   "the accurate setting (reconstruct.presets.A…",  # rich cuts the long word
                   "tracking, joint smoothing 2 and the shape prior, the whole body's depth in the pose refinement "
                   "and a torso hold, each with its guard; "
                   "measured with --constraints silhouette,depth (docs/reconstruct.md); sequential path only",
                   "Kinect player id (1-6) of the person to reconstruct (default: the lowest id of the first frame "
                   "with a tracked body); followed over the run, recorded in run.json (subject_player)",
                   "write the result even when its self-check finds a camera the fit cannot explain (silhouette IoU "
                   "< 0.75) or depth that does not fit the body (docs/reconstruct.md)"):
        assert f" {phrase} " in f" {text} ", phrase


def test_accurate_keywords_match_the_presets_module():
    from bodystudio.reconstruct.presets import ACCURATE_SETTINGS

    assert ACCURATE_SETTINGS["joint_smoothing"] == 2
    assert replace(RapidSkinParams(), surface_hold_k=1.0, surface_hold_region="torso") != RapidSkinParams()
