"""``bodystudio view`` and ``report`` from the command line: outputs and one-line errors."""

import json

import numpy as np
import pytest

from bodystudio.cli.main import main
from bodystudio.geometry.mesh import save_mesh


def _one_line_error(capsys, argv, *needles):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "\n" not in err, err
    for n in needles:
        assert n in err, err
    return err


def test_view_screenshot_and_html_of_a_mesh(tmp_path, body_mesh, capsys, drawn):
    from PIL import Image

    mesh_path = tmp_path / "scan.ply"
    save_mesh(mesh_path, body_mesh)
    png, page = tmp_path / "shot.png", tmp_path / "scene.html"
    assert main(["view", str(mesh_path), "--screenshot", str(png), "--html", str(page), "--size", "320x240"]) == 0
    img = np.asarray(Image.open(png).convert("RGB"))
    assert img.shape == (240, 320, 3)
    mask = drawn(img)
    assert mask.sum() > 500
    cols = np.flatnonzero(mask[: int(0.8 * 240)].any(0))  # the body is centred (the floor grid spans below)
    assert abs(cols.mean() - 160) < 40
    assert "bodystudioView" in page.read_text()


def test_view_bad_paths_are_one_line_errors(tmp_path, capsys):
    _one_line_error(capsys, ["view", str(tmp_path / "nothing.ply")], "nothing.ply")
    notes = tmp_path / "notes.txt"
    notes.write_text("hello")
    _one_line_error(capsys, ["view", str(notes)], "notes.txt", "not a session folder or mesh")
    _one_line_error(capsys, ["view", str(tmp_path)], str(tmp_path), "not a session folder")
    broken = tmp_path / "broken.ply"
    broken.write_text("ply\nformat nonsense\n")
    _one_line_error(capsys, ["view", str(broken), "--screenshot", str(tmp_path / "b.png")], "broken.ply")
    assert not (tmp_path / "b.png").exists()


def test_view_incomplete_session_is_one_line_error(tmp_path, capsys):
    never_done = tmp_path / "s1"
    (never_done / ".staging").mkdir(parents=True)
    (never_done / "session.json").write_text("{")  # truncated manifest
    _one_line_error(capsys, ["view", str(never_done), "--screenshot", str(tmp_path / "s.png")], "session.json")
    assert not (tmp_path / "s.png").exists()


def test_view_options_are_checked(tmp_path, body_mesh, capsys):
    mesh_path = tmp_path / "scan.ply"
    save_mesh(mesh_path, body_mesh)
    _one_line_error(capsys, ["view", str(mesh_path), "--screenshot", str(tmp_path / "x.jpg")], "x.jpg", ".png")
    _one_line_error(capsys, ["view", str(mesh_path), "--size", "big", "--screenshot", str(tmp_path / "x.png")],
                    "--size")
    _one_line_error(capsys, ["view", str(mesh_path), "--bone", "upperarm_l", "--screenshot", str(tmp_path / "x.png")],
                    "--bone needs an avatar")
    _one_line_error(capsys, ["view", str(mesh_path), "--frame", "2", "--screenshot", str(tmp_path / "x.png")],
                    "--frame picks a session frame")
    assert not (tmp_path / "x.png").exists()


def test_report_cli(tmp_path, capsys):
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "metrics.json").write_text(json.dumps({"rms_mm": 3.5}))
    assert main(["report", str(tmp_path / "run"), "--out", str(tmp_path / "r.html")]) == 0
    assert "1 tables" in capsys.readouterr().out
    _one_line_error(capsys, ["report", str(tmp_path / "nope"), "--out", str(tmp_path / "r.html")], "nope")


def test_view_without_display_asks_for_offscreen_output(tmp_path, body_mesh, capsys, monkeypatch):
    import sys

    if not sys.platform.startswith("linux"):
        pytest.skip("display detection is for Linux")
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    mesh_path = tmp_path / "scan.ply"
    save_mesh(mesh_path, body_mesh)
    _one_line_error(capsys, ["view", str(mesh_path)], "--screenshot", "--html")
