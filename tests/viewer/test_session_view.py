"""Sessions in the viewer: frusta with images, Kinect cloud, ground truth, error maps, report, bad sessions."""

import shutil

import numpy as np
import pytest

from bodystudio.capture.synth import synth_session
from bodystudio.cli.main import main
from bodystudio.geometry.mesh import Mesh, save_mesh
from bodystudio.viewer import scene as sc
from bodystudio.viewer.views import KINECT_COLOR, kinect_points, scene_for_session

pytestmark = pytest.mark.slow  # synthesising the session takes ~20 s on 2 shared cores


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    path = tmp_path_factory.mktemp("viewer") / "session"
    return synth_session(path, n_cameras=2, n_frames=2, resolution=(160, 120), template="2k",
                         n_background=1)


def test_session_scene_shows_body_cameras_and_cloud(session, drawn):
    plotter = scene_for_session(session, 1, plotter=sc.make_plotter(window_size=(480, 360)))
    payload_names = set(plotter.renderer.actors)
    assert {"camera-cam_00", "camera-cam_00-image", "camera-cam_01-image", "kinect", "gt"} <= payload_names
    img = sc.render_image(plotter)
    gt = session.frame(1).gt_mesh
    uv = sc.project_to_screen(plotter, gt.vertices)
    (u0, v0), (u1, v1) = uv.min(0).astype(int), uv.max(0).astype(int)
    assert drawn(img[v0:v1, u0:u1]).mean() > 0.2  # the body is where the camera sees it
    # Kinect points lie on the body's surface (depth is in the studio frame).
    P = kinect_points(session, session.frame(1))
    assert len(P) > 100
    assert np.median(sc.vertex_errors_mm(P, gt)) < 30
    green = np.abs(img.astype(int) - np.array(KINECT_COLOR) * 255).max(-1) < 40
    assert green.sum() > 20
    plotter.close()


def test_reconstruction_is_coloured_by_error_and_reported(session, tmp_path):
    from bodystudio.viewer.report import write_report

    gt = session.frame(0).gt_mesh
    recon = Mesh(gt.vertices + 0.004 * gt.vertex_normals, gt.faces)
    out = session.path / "reconstruct" / "meshes" / "00000.ply"
    save_mesh(out, recon)
    try:
        plotter = scene_for_session(session, 0, plotter=sc.make_plotter(window_size=(320, 240)))
        assert "error (mm)" in plotter.scalar_bars
        lo, hi = plotter.scalar_bars["error (mm)"].GetLookupTable().GetRange()
        assert 3.0 < hi < 8.0  # the 4 mm offset sets the colour range
        plotter.close()
        result = write_report(session.path, tmp_path / "report.html")
        assert any(p.title.startswith("Error histogram") for p in result.plots)
        (table,) = [t for t in result.tables if "reconstruction vs ground truth" in t.title]
        assert table.rows[0][0] == 0 and table.rows[0][1] == pytest.approx(4.0, abs=0.5)
        assert result.has_3d
    finally:
        shutil.rmtree(session.path / "reconstruct")


def test_session_with_missing_file_is_one_line_error(session, tmp_path, capsys):
    broken = tmp_path / "broken"
    shutil.copytree(session.path, broken)
    (broken / "cam_01" / "rgb" / "00001.png").unlink()
    assert main(["view", str(broken), "--screenshot", str(tmp_path / "s.png")]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "00001.png" in err and "incomplete" in err
    assert not (tmp_path / "s.png").exists()


def test_session_html_has_every_frame_and_draws_in_chromium(session, tmp_path, chromium):
    import base64
    import json
    import re

    assert main(["view", str(session.path), "--html", str(tmp_path / "s.html"), "--frame", "1"]) == 0
    text = (tmp_path / "s.html").read_text()
    payload = json.loads(re.search(r'id="view3d-data">(.*?)</script>', text, re.S).group(1).replace("<\\/", "</"))
    assert [f["id"] for f in payload["frames"]] == session.frame_ids and payload["start"] == 1
    for f in payload["frames"]:  # each frame carries its own ground-truth mesh
        (gt,) = [o for o in f["objects"] if o["name"] == "gt"]
        V = np.frombuffer(base64.b64decode(gt["positions"]), "<f4").reshape(-1, 3)
        np.testing.assert_allclose(V, session.frame(f["id"]).gt_mesh.vertices, atol=1e-5)
    assert 'type="range" id="view3d-frame" min="0" max="1" value="1"' in text
    page = chromium(tmp_path / "s.html", size=(900, 800), screenshot=False)  # no picture checked: one load
    assert page["console"] == [], page["console"]
    assert 'data-viewer-status="ok"' in page["dom"]


def test_time_slider_swaps_the_frame(session):
    from vtkmodules.util.numpy_support import vtk_to_numpy

    from bodystudio.viewer.views import add_time_slider

    plotter = scene_for_session(session, 0, plotter=sc.make_plotter(window_size=(320, 240)))
    add_time_slider(plotter, session)
    (slider,) = plotter.widgets.slider_widgets

    def gt_points():
        return vtk_to_numpy(plotter.renderer.actors["gt"].GetMapper().GetInput().GetPoints().GetData()).copy()

    np.testing.assert_allclose(gt_points(), session.frame(0).gt_mesh.vertices, atol=1e-9)
    slider.GetRepresentation().SetValue(1.0)
    slider.InvokeEvent("EndInteractionEvent")
    np.testing.assert_allclose(gt_points(), session.frame(1).gt_mesh.vertices, atol=1e-9)
    assert "frame 1" in plotter.renderer.actors["title"].GetText(2)
    # Keys p / n step back and forth (the callbacks pyvista would call on a key press).
    keys = plotter.iren._key_press_event_callbacks
    keys["p"][0]()
    np.testing.assert_allclose(gt_points(), session.frame(0).gt_mesh.vertices, atol=1e-9)
    keys["p"][0]()  # already at the first frame: stays
    assert "frame 0" in plotter.renderer.actors["title"].GetText(2)
    keys["n"][0]()
    assert "frame 1" in plotter.renderer.actors["title"].GetText(2)
    plotter.close()
