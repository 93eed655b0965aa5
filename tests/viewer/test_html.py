"""Standalone HTML: the scene is embedded (no network references) and draws in headless Chromium."""

import base64
import json
import re

import numpy as np
import pytest

from bodystudio.viewer import scene as sc
from bodystudio.viewer.views import scene_for_mesh
from bodystudio.viewer.webgl import save_scene_html


def _payload_from_page(text: str) -> dict:
    m = re.search(r'<script type="application/json" id="view3d-data">(.*?)</script>', text, re.S)
    return json.loads(m.group(1).replace("<\\/", "</"))


def test_payload_carries_the_mesh_and_its_heat_map_colours(body_mesh, tmp_path):
    err = np.linspace(0, 10, body_mesh.n_vertices)
    plotter = sc.make_plotter(window_size=(320, 240))
    sc.add_error_map(plotter, body_mesh, err, clim=(0, 10))
    sc.frame_front(plotter, body_mesh.bounds)
    out = tmp_path / "scene.html"
    save_scene_html(plotter, out)
    text = out.read_text()
    assert not re.search(r'(src|href)\s*=\s*["\']https?:', text)  # opens offline: nothing fetched
    payload = _payload_from_page(text)
    (obj,) = payload["objects"]
    V = np.frombuffer(base64.b64decode(obj["positions"]), "<f4").reshape(-1, 3)
    np.testing.assert_allclose(V, body_mesh.vertices, atol=1e-6)
    indices = obj["indices"]
    if indices.startswith("@"):  # index arrays are stored once in "shared"
        indices = payload["shared"][indices[1:]]
    F = np.frombuffer(base64.b64decode(indices), "<u4").reshape(-1, 3)
    assert len(F) == body_mesh.n_faces
    rgb = np.frombuffer(base64.b64decode(obj["colors"]), np.uint8).reshape(-1, 3).astype(int)
    # The lowest error is the colour map's low end (dark blue in turbo), the highest its high end (red).
    assert rgb[0, 2] > rgb[0, 0] and rgb[-1, 0] > rgb[-1, 2]
    assert payload["colorBars"][0]["title"] == "error (mm)"
    assert payload["colorBars"][0]["max"] == pytest.approx(10.0)


def test_payload_keeps_a_vertex_coloured_mesh_added_after_the_camera(body_mesh):
    """A mesh with RGB vertex colours added after the view was framed (a frame layer swapped in) is exported:
    its mapper's input is only filled when the pipeline runs."""
    from bodystudio.geometry.mesh import Mesh
    from bodystudio.viewer.webgl import scene_payload

    plotter = scene_for_mesh(body_mesh, plotter=sc.make_plotter(window_size=(320, 240)))
    colors = np.tile(np.array([[200, 40, 30]], np.uint8), (body_mesh.n_vertices, 1))
    sc.add_mesh(plotter, Mesh(body_mesh.vertices + [1.0, 0, 0], body_mesh.faces, vertex_colors=colors), name="late")
    objects = {o["name"]: o for o in scene_payload(plotter)["objects"]}
    assert objects["late"]["n"] == body_mesh.n_vertices
    rgb = np.frombuffer(base64.b64decode(objects["late"]["colors"]), np.uint8).reshape(-1, 3)
    assert (rgb == [200, 40, 30]).all()
    plotter.close()


def test_empty_scene_html_is_an_error(tmp_path):
    plotter = sc.make_plotter(window_size=(320, 240))
    with pytest.raises(sc.EmptySceneError):
        save_scene_html(plotter, tmp_path / "empty.html")
    assert not (tmp_path / "empty.html").exists()


def test_scene_html_draws_in_headless_chromium(body_mesh, tmp_path, chromium):
    plotter = scene_for_mesh(body_mesh, plotter=sc.make_plotter(window_size=(320, 240)))
    out = save_scene_html(plotter, tmp_path / "scene.html")
    page = chromium(out, size=(900, 800))
    assert page["console"] == [], page["console"]
    assert 'data-viewer-status="ok"' in page["dom"], page["dom"][-2000:]
    assert 'data-views-drawn="1"' in page["dom"]
    img = page["screenshot"]
    assert img is not None
    # Inside the canvas, the body (light skin colour) shows against the dark background.
    bg = np.array(sc.BACKGROUND_RGB)
    canvas = img[100:700, 50:850].astype(int)
    is_bg = np.abs(canvas - bg).max(-1) <= 6
    assert is_bg.mean() > 0.3  # the canvas cleared to the scene background
    skin = (canvas.mean(-1) > 120) & ~is_bg
    assert skin.sum() > 2000


def test_page_reports_a_browser_without_webgl(body_mesh, tmp_path, chromium):
    # The status check can fail: with WebGL switched off the page records the error and says so.
    plotter = scene_for_mesh(body_mesh, plotter=sc.make_plotter(window_size=(320, 240)))
    out = save_scene_html(plotter, tmp_path / "scene.html")
    page = chromium(out, extra_flags=("--disable-webgl", "--disable-3d-apis"), screenshot=False)
    assert 'data-viewer-status="error: view3d: WebGL is not available' in page["dom"]
    assert "3D view unavailable" in page["dom"]
