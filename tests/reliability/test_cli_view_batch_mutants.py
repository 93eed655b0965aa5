"""``bodystudio view``, ``report`` and ``batch rig`` (with the batch printers) through typer's CliRunner with the
API replaced by spies (mutNN).

Each option reaches the API unchanged, the HTML page gets the right frame payload for each kind of input, the
printed lines hold the API's figures, and each refusal is an :class:`InputError` with its whole message before any
work (no window, no cluster). Nothing is rendered: the file runs in about a second.
"""

from __future__ import annotations

from contextlib import contextmanager
from pathlib import Path
from types import SimpleNamespace

import pytest

from bodystudio.errors import InputError
from tests.reliability.cli_spies import invoke as _invoke
from tests.reliability.cli_spies import refused as _refused
from tests.reliability.cli_spies import spy as _spy


def _help(args) -> str:
    res = _invoke([*args, "--help"])
    return " ".join(res.stdout.replace("│", " ").split())


@pytest.fixture(autouse=True)
def _cwd(monkeypatch, tmp_path):
    monkeypatch.chdir(tmp_path)


# ------------------------------------------------------------------------------------------------ view

class Plotter:
    def __init__(self):
        self.shown, self.closed = [], 0

    def show(self, title):
        self.shown.append(title)

    def close(self):
        self.closed += 1


@pytest.fixture
def view_api(monkeypatch):
    ns = SimpleNamespace(plotter=Plotter(), kind="mesh")
    ns.open = _spy(monkeypatch, "bodystudio.viewer.views.open_viewable",
                   fn=lambda p: SimpleNamespace(kind=ns.kind, data=f"DATA {p}"))
    ns.build = _spy(monkeypatch, "bodystudio.viewer.views.build_view", fn=lambda *a, **k: ns.plotter)
    ns.shot = _spy(monkeypatch, "bodystudio.viewer.scene.save_screenshot")
    ns.html = _spy(monkeypatch, "bodystudio.viewer.webgl.save_scene_html")
    ns.session = _spy(monkeypatch, "bodystudio.viewer.views.session_payload", ret="SESSION PAYLOAD")
    ns.arm = _spy(monkeypatch, "bodystudio.viewer.arm.arm_payload", ret="ARM PAYLOAD")
    ns.garment = _spy(monkeypatch, "bodystudio.viewer.garment.garment_payload", ret="GARMENT PAYLOAD")
    monkeypatch.setenv("DISPLAY", ":0")
    return ns


def test_view_window_defaults(view_api):
    res = _invoke(["view", "m.ply"])
    assert res.exit_code == 0, (res.output, res.exception)
    assert view_api.open.calls == [((Path("m.ply"),), {})]
    (item,), kw = view_api.build.calls[0]
    assert item.data == "DATA m.ply"
    assert kw == dict(bone=None, frame=None, images="image", off_screen=False, window_size=(1024, 768),
                      reference=None, cloud=True)
    assert view_api.plotter.shown == ["bodystudio view m.ply"] and view_api.plotter.closed == 1
    assert not view_api.shot.calls and not view_api.html.calls and res.stdout == ""


def test_view_screenshot_every_option(view_api, monkeypatch):
    monkeypatch.delenv("DISPLAY")
    res = _invoke(["view", "a.glb", "--bone", "upperarm_l", "--frame", "3", "--images", "mask", "--reference", "r.ply",
                   "--screenshot", "o.PNG", "--size", "640x480", "--no-cloud"])
    assert res.exit_code == 0, (res.output, res.exception)
    assert view_api.build.calls[0][1] == dict(bone="upperarm_l", frame=3, images="mask", off_screen=True,
                                              window_size=(640, 480), reference=Path("r.ply"), cloud=False)
    assert view_api.shot.calls == [((view_api.plotter, Path("o.PNG")), {})]
    assert res.stdout == "wrote o.PNG\n" and view_api.plotter.shown == [] and view_api.plotter.closed == 1


@pytest.mark.parametrize("kind, payload", [("mesh", None), ("session", "SESSION PAYLOAD"), ("arm", "ARM PAYLOAD"),
                                           ("garment", "GARMENT PAYLOAD")])
def test_view_html_payload_per_kind(view_api, monkeypatch, kind, payload):
    monkeypatch.delenv("DISPLAY")
    view_api.kind = kind
    res = _invoke(["view", "dir/x", "--html", "v.html", "--frame", "5", "--images", "none", "--no-cloud"])
    assert res.exit_code == 0, (res.output, res.exception)
    assert view_api.html.calls == [((view_api.plotter, Path("v.html")), {"title": "bodystudio view x",
                                                                        "payload": payload})]
    if kind == "session":
        assert view_api.session.calls == [(("DATA dir/x", view_api.plotter), {"images": "none", "cloud": False,
                                                                             "start": 5})]
    if kind == "arm":
        assert view_api.arm.calls == [(("DATA dir/x", view_api.plotter), {"cloud": False, "start": 5})]
    if kind == "garment":
        assert view_api.garment.calls == [(("DATA dir/x", view_api.plotter), {"start": 5})]
    assert res.stdout == "wrote v.html\n" and view_api.plotter.closed == 1


def test_view_screenshot_and_html_together(view_api):
    res = _invoke(["view", "m.ply", "--html", "v.htm", "--screenshot", "s.png"])
    assert res.exit_code == 0, (res.output, res.exception)
    assert res.stdout == "wrote s.png\nwrote v.htm\n" and view_api.build.calls[0][1]["off_screen"] is True


def test_view_closes_the_plotter_when_saving_fails(view_api):
    def boom(*a, **k):
        raise InputError("disk says no")

    view_api.shot.fn = boom
    _refused(_invoke(["view", "m.ply", "--screenshot", "s.png"]), "disk says no")
    assert view_api.plotter.closed == 1


@pytest.mark.parametrize("args, message", [
    (["--screenshot", "s.jpg"], "--screenshot s.jpg: unsupported output format; use .png"),
    (["--html", "v.txt"], "--html v.txt: unsupported output format; use .html or .htm"),
    (["--size", "63x100", "--html", "v.html"], "--size '63x100' is not WxH between 64 and 8192, e.g. 1024x768"),
])
def test_view_refusals_before_opening(view_api, args, message):
    _refused(_invoke(["view", "m.ply", *args]), message)
    assert not view_api.open.calls and not view_api.build.calls


def test_view_without_a_display(view_api, monkeypatch):
    monkeypatch.delenv("DISPLAY")
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    _refused(_invoke(["view", "m.ply"]), "no display to open a window ($DISPLAY is not set); add --screenshot "
             "OUT.png or --html OUT.html, or run under a desktop / ssh -X")
    assert not view_api.build.calls
    monkeypatch.setenv("WAYLAND_DISPLAY", "wayland-0")
    assert _invoke(["view", "m.ply"]).exit_code == 0


def test_has_display(monkeypatch):
    import sys

    from bodystudio.cli.viewer import has_display

    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    assert has_display() is False
    monkeypatch.setenv("DISPLAY", "")
    assert has_display() is False
    monkeypatch.setenv("DISPLAY", ":1")
    assert has_display() is True
    monkeypatch.delenv("DISPLAY")
    monkeypatch.setattr(sys, "platform", "darwin")
    assert has_display() is True


def test_parse_size_by_hand():
    from bodystudio.cli.viewer import _parse_size

    assert _parse_size("64x8192") == (64, 8192) and _parse_size("8192X64") == (8192, 64)
    for bad in ("63x64", "64x63", "8193x64", "64x8193", "64", "x", "1x2x3"):
        with pytest.raises(InputError) as exc:
            _parse_size(bad)
        assert str(exc.value) == f"--size {bad!r} is not WxH between 64 and 8192, e.g. 1024x768"
    with pytest.raises(InputError) as exc:
        _parse_size("1x1", "--resolution")
    assert str(exc.value).startswith("--resolution '1x1' is not")


def test_view_help():
    text = _help(["view"])
    for phrase in ("show the skin weights of this bone (avatars)", "session (or garment fit) frame to show first",
                   "what camera frusta show: image | mask | none", "ground-truth mesh: colour PATH by error (mm)",
                   "render offscreen to this PNG and exit", "write a standalone HTML page of the scene and exit",
                   "window / screenshot size WxH", "show the Kinect point cloud (sessions, arm captures)",
                   "Open a session, mesh, scan or avatar in the 3D viewer (or save a screenshot / HTML page)."):
        assert f" {phrase} " in f" {text} ", phrase


# ------------------------------------------------------------------------------------------------ report

def test_report_line_and_options(monkeypatch):
    result = SimpleNamespace(path=Path("r.html"), tables=[1, 2], plots=[1], screenshots=[1, 2, 3], has_3d=True)
    write = _spy(monkeypatch, "bodystudio.viewer.report.write_report", ret=result)
    res = _invoke(["report", "run", "--out", "r.html"])
    assert res.exit_code == 0, (res.output, res.exception)
    assert write.calls == [((Path("run"), Path("r.html")), {"with_3d": True})]
    assert res.stdout == "wrote r.html (2 tables, 1 plots, 3 screenshots, a 3D view)\n"
    result.has_3d = False
    res = _invoke(["report", "run", "--out", "r.HTM", "--no-3d"])
    assert write.calls[1] == ((Path("run"), Path("r.HTM")), {"with_3d": False})
    assert res.stdout.endswith("3 screenshots, no 3D view)\n")
    _refused(_invoke(["report", "run", "--out", "r.pdf"]), "--out r.pdf: unsupported output format; use .html or .htm")
    assert len(write.calls) == 2
    text = _help(["report"])
    for phrase in ("a run folder (e.g. the demo's output) or a session folder", "the report page to write (.html)",
                   "leave out the embedded 3D view",
                   "Write one self-contained HTML report: metrics tables, plots, screenshots and a 3D view."):
        assert f" {phrase} " in f" {text} ", phrase


# ------------------------------------------------------------------------------------------------ batch rig

class Report:
    def __init__(self, errors=None):
        self.status = {"a": "done", "b": "skipped", "c": "failed"}
        self.errors = errors if errors is not None else {}
        self.seconds = {"a": 12.345}
        self.wall_s = 20.06
        self.record = Path("out/batch.json")

    def count(self, status):
        return list(self.status.values()).count(status)

    def failure_message(self, what):
        return f"1 of 3 {what} failed; see out/batch.json"


@pytest.fixture
def batch_api(monkeypatch):
    import bodystudio.batch as batch

    ns = SimpleNamespace(log=[], report=Report())
    Path("scans").mkdir()

    ns.client = SimpleNamespace(scheduler_info=lambda: {"address": "tcp://x:1", "workers": {"w1": 1, "w2": 2}})
    ns.dashboard = []

    @contextmanager
    def client(scheduler, workers, units=None):
        ns.log.append(("client", scheduler, workers, units))
        yield ns.client

    monkeypatch.setattr(batch, "batch_client", client)
    monkeypatch.setattr(batch, "list_scans", lambda d: ns.log.append(("list", d)) or ["a.ply", "b.ply", "c.ply"])
    monkeypatch.setattr(batch, "resolve_scheduler", lambda s, w: ns.log.append(("resolve", s, w)))
    monkeypatch.setattr(batch, "dashboard_link", lambda c: ns.dashboard.append(c) or "http://x:8787/status")

    def rig_batch(scans_dir, out, client, **kw):
        assert client is ns.client
        ns.log.append(("rig", scans_dir, out, kw))
        return ns.report

    monkeypatch.setattr(batch, "rig_batch", rig_batch)
    return ns


def test_batch_rig_defaults_and_printed_lines(batch_api):
    res = _invoke(["batch", "rig", "scans", "--out", "out"])
    assert res.exit_code == 0, (res.output, res.exception)
    assert batch_api.log == [("list", Path("scans")), ("resolve", None, None), ("client", None, None, 3),
                             ("rig", Path("scans"), Path("out"), {"template": "6k", "force": False,
                                                                  "progress": True})]
    err = res.stderr
    assert err.startswith("cluster tcp://x:1: 2 workers; dashboard http://x:8787/status\n")
    text = " ".join(err.replace("│", " ").replace("┃", " ").split())
    assert ("batch rig scans: 1 done, 1 unchanged (skipped), 1 failed in 20.1 s; record out/batch.json") in text
    assert "unit status seconds / error" in text
    assert "a done 12.3" in text and "b skipped" in text and "c failed" in text
    rows = [ln.replace("│", " ").split() for ln in err.splitlines() if "│" in ln]
    assert rows == [["a", "done", "12.3"], ["b", "skipped"], ["c", "failed"]]  # no time, no error: empty
    assert res.stdout == "" and batch_api.dashboard == [batch_api.client]


def test_batch_rig_accepts_each_template(batch_api):
    for template in ("6k", "13k", "2k"):
        res = _invoke(["batch", "rig", "scans", "--out", f"out{template}", "--template", template])
        assert res.exit_code == 0, (res.output, res.exception)
        assert batch_api.log[-1][3]["template"] == template


def test_batch_rig_options_and_failure(batch_api):
    batch_api.report = Report(errors={"c": "no body found"})
    res = _invoke(["batch", "rig", "scans", "-o", "out", "--template", "13k", "--scheduler", "tcp://h:1",
                   "--workers", "2", "--force"])
    from bodystudio.batch import BatchError

    assert isinstance(res.exception, BatchError)
    assert str(res.exception) == "1 of 3 scans failed; see out/batch.json"
    assert batch_api.log[1:] == [("resolve", "tcp://h:1", 2), ("client", "tcp://h:1", 2, 3),
                                 ("rig", Path("scans"), Path("out"), {"template": "13k", "force": True,
                                                                      "progress": True})]
    assert "c failed no body found" in " ".join(res.stderr.replace("│", " ").split())


def test_batch_rig_refusals_before_the_cluster(batch_api):
    _refused(_invoke(["batch", "rig", "scans", "--out", "out", "--template", "4k"]),
             "--template '4k': use 6k, 13k or 2k")
    Path("f").write_text("x")
    _refused(_invoke(["batch", "rig", "scans", "--out", "f"]),
             "--out f: exists and is a file, not a folder; choose a folder path")
    _refused(_invoke(["batch", "rig", "scans", "--out", "scans"]),
             "--out scans: is the scans folder; writing it would replace that input, choose another path")
    assert [e[0] for e in batch_api.log] == ["list"] * 3


def test_print_cluster_without_a_dashboard(monkeypatch, capsys):
    import bodystudio.batch as batch
    from bodystudio.cli.batch import print_cluster

    monkeypatch.setattr(batch, "dashboard_link", lambda c: None)
    print_cluster(SimpleNamespace(scheduler_info=lambda: {}))
    assert capsys.readouterr().err == ("cluster None: 0 workers; dashboard not served (install bokeh for the "
                                       "dashboard)\n")


def test_batch_rig_help():
    text = _help(["batch", "rig"])
    for phrase in ("folder of body scans (PLY, OBJ, GLB/GLTF, STL)", "folder of avatars STEM.glb and batch.json",
                   "model template: 6k, 13k (or 2k)",
                   "dask scheduler address tcp://HOST:8786 (default $BODYSTUDIO_SCHEDULER; else a local cluster)",
                   "local cluster of N single-threaded worker processes (default: one per core)",
                   "redo every scan, also those already rigged",
                   "Rig every scan of a folder on a dask cluster; resumable (unchanged scans are skipped)."):
        assert f" {phrase} " in f" {text} ", phrase
