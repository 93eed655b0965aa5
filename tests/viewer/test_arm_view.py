"""Arm captures in the viewer: the arm coloured by its per-vertex error, the depth points, every frame in HTML."""

import json

import numpy as np
import pytest

from bodystudio.cli.main import main
from bodystudio.viewer import scene as sc
from bodystudio.viewer.arm import (
    DEPTH_COLOR,
    ArmSequenceView,
    add_arm_time_slider,
    arm_depth_points,
    arm_payload,
    scene_for_arm_sequence,
)


@pytest.fixture(scope="module")
def arm_capture(tmp_path_factory):
    """A 3-frame 2k arm session and its NICP-only capture, through the CLI."""
    root = tmp_path_factory.mktemp("armview")
    assert main(["synth", "arm", str(root / "s"), "--subject-seed", "4", "--frames", "3", "--resolution", "2k"]) == 0
    assert main(["muscle", "capture", str(root / "s"), "--out", str(root / "c"), "--no-model"]) == 0
    return root / "s", root / "c"


def planted_view(session_path, offset_m=0.008):
    """The session's truth with the upper half of the arm (by height) moved ``offset_m`` along +z."""
    from bodystudio.capture.session import open_session

    s = open_session(session_path)
    truth = np.stack([s.frame(f).gt_arm_mesh.vertices for f in s.frame_ids])
    faces = s.frame(0).gt_arm_mesh.faces
    V = truth.copy()
    top = truth[0][:, 1] > np.median(truth[0][:, 1])
    V[:, top, 2] += offset_m
    return ArmSequenceView(session_path, tuple(s.frame_ids), V, faces, truth, s), top


def test_arm_scene_colours_the_planted_error_and_draws_depth(arm_capture, drawn):
    view, top = planted_view(arm_capture[0])
    np.testing.assert_allclose(view.errors_mm(1)[top], 8.0, atol=1e-6)
    assert np.abs(view.errors_mm(1)[~top]).max() < 1e-9
    plotter = scene_for_arm_sequence(view, 1, plotter=sc.make_plotter(window_size=(480, 360)))
    assert {"arm", "truth-arm", "depth"} <= set(plotter.renderer.actors)
    lo, hi = plotter.scalar_bars["error (mm)"].GetLookupTable().GetRange()
    assert (lo, hi) == (0.0, 10.0)
    img = sc.render_image(plotter)
    assert drawn(img).mean() > 0.03
    magenta = np.abs(img.astype(int) - np.array(DEPTH_COLOR) * 255).max(-1) < 40
    assert magenta.sum() > 50  # the depth points are drawn
    # Depth points lie on the true arm (same frame, same studio coordinates).
    P = arm_depth_points(view, 1)
    from bodystudio.geometry.mesh import Mesh

    d = sc.vertex_errors_mm(P, Mesh(view.truth[1], view.faces))
    assert len(P) > 200 and np.mean(d < 5) > 0.4  # the rest is chest and torso inside the box
    plotter.close()


def test_arm_time_slider_and_keys_swap_the_frame(arm_capture):
    view, _ = planted_view(arm_capture[0])
    plotter = scene_for_arm_sequence(view, 0, plotter=sc.make_plotter(window_size=(320, 240)))
    add_arm_time_slider(plotter, view)

    def shown_frame():
        title = plotter.renderer.actors["title"].GetText(2)
        return int(title.split("frame ")[1].split()[0])

    assert shown_frame() == view.frame_ids[0]
    keys = plotter.iren._key_press_event_callbacks
    keys["n"][0]()
    keys["n"][0]()
    assert shown_frame() == view.frame_ids[2]
    keys["n"][0]()  # already at the last frame: stays
    assert shown_frame() == view.frame_ids[2]
    keys["p"][0]()
    assert shown_frame() == view.frame_ids[1]
    (slider,) = plotter.widgets.slider_widgets
    assert slider.GetRepresentation().GetValue() == view.frame_ids[1]
    plotter.close()


def test_arm_payload_has_every_frame(arm_capture):
    view, _ = planted_view(arm_capture[0])
    plotter = scene_for_arm_sequence(view, 0, plotter=sc.make_plotter(window_size=(320, 240)))
    payload = arm_payload(view, plotter, start=2)
    assert [f["id"] for f in payload["frames"]] == [0, 1, 2] and payload["start"] == 2
    assert all(f["colorBars"] for f in payload["frames"])
    plotter.close()


def test_view_opens_an_arm_capture_folder(arm_capture, tmp_path, chromium):
    session, capture = arm_capture
    params = json.loads((capture / "params.json").read_text())
    assert params["session"] == str(session.resolve())
    png, page = tmp_path / "arm.png", tmp_path / "arm.html"
    assert main(["view", str(capture), "--screenshot", str(png), "--frame", "2", "--size", "480x360"]) == 0
    assert main(["view", str(capture), "--html", str(page)]) == 0
    result = chromium(page, size=(900, 700), screenshot=False)  # no picture checked: one Chromium load
    assert result["console"] == [], result["console"]
    assert 'data-viewer-status="ok"' in result["dom"]


def test_view_of_a_bad_frame_is_one_line(arm_capture, tmp_path, capsys):
    assert main(["view", str(arm_capture[1]), "--frame", "7", "--screenshot", str(tmp_path / "x.png")]) == 2
    assert "no frame 7" in capsys.readouterr().err
    assert not (tmp_path / "x.png").exists()


def test_report_of_an_arm_capture_embeds_the_sequence(arm_capture, tmp_path):
    from bodystudio.viewer.report import write_report

    result = write_report(arm_capture[1], tmp_path / "r.html")
    # params.json / manifest.json are data, not metrics; the capture's self-check (plausibility.json) is
    assert result.has_3d and result.tables and all(t.title.startswith("plausibility.json") for t in result.tables)
    text = (tmp_path / "r.html").read_text()
    assert text.count('"id":') >= 3  # one entry per frame for the slider


def test_opened_capture_knows_its_truth_and_arm_vertices(arm_capture):
    from bodystudio.viewer.arm import _title, open_arm_view

    view = open_arm_view(arm_capture[1])
    assert view.truth is not None and view.truth.shape == view.vertices.shape
    assert view.arm_mask is not None and 0 < view.arm_mask.sum() < len(view.arm_mask)
    assert "arm median error" in _title(view, 0)
