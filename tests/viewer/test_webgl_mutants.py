"""The WebGL page's buffers and markup checked against independent decoders (mutMM).

Every base64 buffer the page reads is decoded with numpy (``np.frombuffer``) and compared with the scene's own
arrays; the embedded PNG textures are decoded with PIL; the colour maps are compared with matplotlib's ``turbo``;
the markup is read back with the standard library's ``html.parser``.
"""

from __future__ import annotations

import base64
import html.parser
import io
import json
from types import SimpleNamespace

import numpy as np
import pytest

from bodystudio.errors import InputError
from bodystudio.geometry.mesh import Mesh
from bodystudio.viewer import scene as sc
from bodystudio.viewer import webgl as wg

V4 = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.5]])
F2 = np.array([[0, 1, 2], [0, 2, 3]])


def _buf(s: str, dtype) -> np.ndarray:
    return np.frombuffer(base64.b64decode(s), dtype)


def _png_of_url(url: str) -> np.ndarray:
    from PIL import Image

    assert url.startswith("data:image/png;base64,")
    return np.asarray(Image.open(io.BytesIO(base64.b64decode(url.split(",", 1)[1]))))


def _turbo(values, lo, hi) -> np.ndarray:
    """matplotlib's turbo sampled at 256 levels, as VTK's lookup table maps a value in [lo, hi] (uint8)."""
    import matplotlib

    t = (np.asarray(values, float) - lo) / (hi - lo)
    idx = np.clip((t * 256).astype(int), 0, 255)
    return np.asarray(matplotlib.colormaps["turbo"].resampled(256)(idx))[:, :3] * 255


def test_b64_buffers_and_png_data_urls_decode_to_the_arrays():
    a = np.arange(12, dtype=np.float64).reshape(3, 4).T * 0.5  # not C-contiguous
    assert np.array_equal(_buf(wg._b64(a, "<f4"), "<f4"), a.astype(np.float32).ravel())
    assert np.array_equal(_buf(wg._b64(np.array([1, 70000]), "<u4"), "<u4"), [1, 70000])
    assert np.array_equal(_buf(wg._b64(np.array([[1, 2, 255]]), np.uint8), np.uint8), [1, 2, 255])
    img = np.random.default_rng(2).integers(0, 256, (4, 6, 3), dtype=np.uint8)[:, ::-1]
    assert np.array_equal(_png_of_url(wg._png_data_url(img)), img)


def test_cells_and_segments_by_hand():
    cells = np.array([3, 0, 1, 2, 2, 3, 4, 1, 5])
    assert [c.tolist() for c in wg._cell_arrays(cells)] == [[0, 1, 2], [3, 4], [5]]
    assert wg._segments(cells, closed=False).tolist() == [[0, 1], [1, 2], [3, 4]]
    assert wg._segments(cells, closed=True).tolist() == [[0, 1], [1, 2], [2, 0], [3, 4], [4, 3]]
    empty = wg._segments(np.array([1, 0]), closed=True)
    assert empty.shape == (0, 2) and empty.dtype == np.int64
    assert wg._cell_arrays(np.array([], dtype=np.int64)) == []
    assert wg._segments(np.array([1, 5, 2, 0, 1]), closed=False).tolist() == [[0, 1]]  # a lone vertex is skipped


def _frustum_camera(name="c0"):
    """A stand-in camera: optical centre at the origin, its far image corners at z = -1."""
    corners = np.array([[-0.4, 0.3, -1.0], [0.4, 0.3, -1.0], [0.4, -0.3, -1.0], [-0.4, -0.3, -1.0]])
    return SimpleNamespace(name=name, center=np.zeros(3), frustum=lambda near, far: np.r_[corners * near, corners])


def _scene():
    plotter = sc.make_plotter(window_size=(320, 240))
    err = np.array([0.0, 2.5, 5.0, 10.0])
    sc.add_error_map(plotter, Mesh(V4, F2), err, clim=(0.0, 10.0), name="heat")
    sc.add_mesh(plotter, Mesh(V4 + [2.0, 0, 0], F2), color=(0.1, 0.2, 0.3), opacity=0.5, name="solid")
    rgb = np.array([[10, 20, 30], [40, 50, 60], [70, 80, 90], [200, 210, 220]], np.uint8)
    sc.add_mesh(plotter, Mesh(V4 + [4.0, 0, 0], F2, vertex_colors=rgb), name="rgb")
    sc.add_point_cloud(plotter, V4 + [0, 2.0, 0], point_size=4.0, name="cloud")
    sc.add_floor(plotter, np.zeros(3), size=2.0, name="floor")
    image = np.random.default_rng(7).integers(0, 256, (6, 8, 3), dtype=np.uint8)
    sc.add_camera(plotter, _frustum_camera(), image, far=1.0)
    hidden = sc.add_mesh(plotter, Mesh(V4, F2), name="hidden").renderer.actors["hidden"]
    hidden.SetVisibility(False)
    return plotter, err, rgb, image


def test_scene_payload_buffers_decode_to_the_scene():
    plotter, err, rgb, image = _scene()
    payload = wg.scene_payload(plotter)
    objects = {o["name"]: o for o in payload["objects"]}
    assert set(objects) == {"heat", "solid", "rgb", "cloud", "floor", "camera-c0", "camera-c0-image"}
    heat = objects["heat"]
    assert heat["n"] == 4 and heat["mode"] == "triangles" and heat["count"] == 6
    assert np.array_equal(_buf(heat["positions"], "<f4").reshape(-1, 3), V4.astype(np.float32))
    assert np.array_equal(_buf(heat["indices"], "<u4").reshape(-1, 3), F2)
    colors = _buf(heat["colors"], np.uint8).reshape(-1, 3)
    assert np.abs(colors - _turbo(err, 0.0, 10.0)).max() <= 1.0  # the turbo scale over the clim
    assert heat["opacity"] == 1.0 and heat["lighting"] is True
    solid = objects["solid"]
    assert "colors" not in solid and solid["opacity"] == 0.5
    assert np.allclose(solid["color"], [0.1, 0.2, 0.3], atol=1 / 255)
    assert np.array_equal(_buf(solid["positions"], "<f4").reshape(-1, 3), (V4 + [2.0, 0, 0]).astype(np.float32))
    assert np.array_equal(_buf(objects["rgb"]["colors"], np.uint8).reshape(-1, 3), rgb)
    cloud = objects["cloud"]
    assert cloud["mode"] == "points" and cloud["pointSize"] == 4.0 and "indices" not in cloud
    assert np.array_equal(_buf(cloud["positions"], "<f4").reshape(-1, 3), (V4 + [0, 2.0, 0]).astype(np.float32))
    floor = objects["floor"]
    P = _buf(floor["positions"], "<f4").reshape(-1, 3)
    seg = _buf(floor["indices"], "<u4").reshape(-1, 2)
    assert floor["mode"] == "lines" and floor["count"] == seg.size == 12 * 12 * 8 and floor["opacity"] == 0.35
    lengths = np.linalg.norm(P[seg[:, 0]] - P[seg[:, 1]], axis=1)
    assert np.allclose(lengths, 2.0 / 12, atol=1e-6)  # every edge of every grid cell, closed, no diagonal
    frustum = objects["camera-c0"]
    fseg = _buf(frustum["indices"], "<u4").reshape(-1, 2)
    assert frustum["mode"] == "lines"
    assert fseg.tolist() == [[0, 1], [0, 2], [0, 3], [0, 4], [1, 2], [2, 3], [3, 4], [4, 1]]
    tex = objects["camera-c0-image"]
    assert np.array_equal(_png_of_url(tex["texture"]), image)
    assert np.array_equal(_buf(tex["uv"], "<f4").reshape(-1, 2), [[0, 1], [1, 1], [1, 0], [0, 0]])
    assert tex["lighting"] is False and tex["mode"] == "triangles"
    cam = plotter.camera
    assert payload["camera"] == {"position": list(cam.position), "focal": list(cam.focal_point), "up": list(cam.up),
                                 "viewAngle": float(cam.view_angle)}
    assert payload["background"] == list(sc.BACKGROUND)
    (bar,) = payload["colorBars"]
    assert (bar["title"], bar["min"], bar["max"]) == ("error (mm)", 0.0, 10.0)
    assert len(bar["colors"]) == 32
    assert np.abs(np.array(bar["colors"]) - _turbo(np.linspace(0, 10, 32), 0.0, 10.0)).max() <= 1.0
    plotter.close()


def test_scene_payload_selects_actors_and_refuses_an_empty_scene():
    plotter, *_ = _scene()
    assert [o["name"] for o in wg.scene_payload(plotter, include={"heat", "cloud", "hidden"})["objects"]] == [
        "heat", "cloud"]
    names = [o["name"] for o in wg.scene_payload(plotter, exclude={"heat", "floor"})["objects"]]
    assert names == ["solid", "rgb", "cloud", "camera-c0", "camera-c0-image"]
    with pytest.raises(sc.EmptySceneError) as exc:
        wg.scene_payload(plotter, include=set())
    assert str(exc.value) == "nothing to export: the scene is empty; give a mesh, avatar or session with data"
    assert wg.scene_payload(plotter, include=set(), allow_empty=True)["objects"] == []
    plotter.close()


def test_scene_payload_wireframe_and_line_only_meshes():
    import pyvista as pv

    plotter = sc.make_plotter(window_size=(320, 240))
    plotter.add_mesh(sc.polydata(V4, F2), style="wireframe", name="wire")
    plotter.add_mesh(pv.PolyData(V4, lines=np.array([3, 0, 1, 2])), name="polyline")
    plotter.add_mesh(pv.PolyData(V4[:2]), name="verts")
    plotter.add_mesh(sc.polydata(V4, F2), style="points", point_size=7, name="pts")
    both = pv.PolyData(V4)  # a vertex per point, and a line
    both.lines = np.array([2, 0, 1])
    plotter.add_mesh(both, name="both")
    plotter.add_mesh(pv.Cube().cast_to_unstructured_grid(), name="ug")
    sc.add_point_cloud(plotter, V4[:1], name="one")
    objects = {o["name"]: o for o in wg.scene_payload(plotter)["objects"]}
    wire = _buf(objects["wire"]["indices"], "<u4").reshape(-1, 2)
    assert wire.tolist() == [[0, 1], [1, 2], [2, 0], [0, 2], [2, 3], [3, 0]]
    assert objects["wire"]["count"] == 12 and objects["wire"]["mode"] == "lines"
    assert _buf(objects["polyline"]["indices"], "<u4").reshape(-1, 2).tolist() == [[0, 1], [1, 2]]
    assert objects["polyline"]["count"] == 4
    assert objects["verts"]["mode"] == "points" and "indices" not in objects["verts"] and objects["verts"]["count"] == 0
    assert objects["pts"]["mode"] == "points" and objects["pts"]["pointSize"] == 7.0 and "count" not in objects["pts"]
    assert objects["both"]["mode"] == "lines" and _buf(objects["both"]["indices"], "<u4").tolist() == [0, 1]
    ug = objects["ug"]  # not a PolyData: its surface, triangulated
    assert ug["mode"] == "triangles" and ug["count"] == 6 * 2 * 3 and ug["n"] >= 8
    assert objects["one"]["n"] == 1 and objects["one"]["mode"] == "points"
    plotter.close()


def test_actor_colors_follow_the_mapper_range_and_single_colours_have_none():
    plotter = sc.make_plotter(window_size=(320, 240))
    values = np.array([1.0, 3.0, 5.0, 9.0])
    pd = sc.polydata(V4, F2)
    pd.point_data["v"] = values
    plotter.add_mesh(pd, scalars="v", cmap="turbo", clim=[1.0, 9.0], name="v", scalar_bar_args={"title": "v bar"})
    plotter.add_mesh(sc.polydata(V4, F2), color="red", name="plain")
    objects = {o["name"]: o for o in wg.scene_payload(plotter)["objects"]}
    got = _buf(objects["v"]["colors"], np.uint8).reshape(-1, 3)
    assert np.abs(got - _turbo(values, 1.0, 9.0)).max() <= 1.0
    assert "colors" not in objects["plain"]
    import matplotlib

    (bar,) = wg.scene_payload(plotter)["colorBars"]
    assert (bar["title"], bar["min"], bar["max"]) == ("v bar", 1.0, 9.0)
    turbo = matplotlib.colormaps["turbo"].resampled(256)
    idx = np.minimum((np.arange(32) / 31 * 256).astype(int), 255)  # 32 samples from the low to the high end
    expected = np.array([turbo(i)[:3] for i in idx]) * 255
    assert np.abs(np.array(bar["colors"]) - expected).max() <= 1.0
    lut = plotter.renderer.actors["v"].GetMapper().GetLookupTable()
    for k, entry in ((0, 0), (-1, 255)):  # the ends are the table's own colours in 0-255
        assert bar["colors"][k] == [int(round(255 * c)) for c in lut.GetTableValue(entry)[:3]]
    for colour, v in zip(bar["colors"], np.linspace(1.0, 9.0, 32), strict=True):  # each sample, 8 bits exactly
        rgb = [0.0, 0.0, 0.0]
        lut.GetColor(v, rgb)
        assert colour == [int(round(255 * c)) for c in rgb]
    plotter.close()


class _Tree(html.parser.HTMLParser):
    def __init__(self, text):
        super().__init__()
        self.tags, self.text = [], {}
        self._open = []
        self.feed(text)

    def handle_starttag(self, tag, attrs):
        self.tags.append((tag, dict(attrs)))
        self._open.append(len(self.tags) - 1)

    def handle_endtag(self, tag):
        while self._open:
            k = self._open.pop()
            if self.tags[k][0] == tag:
                break

    def handle_data(self, data):
        if self._open:
            self.text[self._open[-1]] = self.text.get(self._open[-1], "") + data

    def find(self, tag, **attrs):
        return [(k, a) for k, (t, a) in enumerate(self.tags) if t == tag and all(a.get(x) == v
                                                                                 for x, v in attrs.items())]


def test_color_bar_html_runs_top_to_bottom_and_shows_the_range():
    bar = {"title": "err <mm>", "min": 0.04, "max": 12.35, "colors": [[0, 0, 0], [1, 2, 3], [250, 251, 252]]}
    t = _Tree(wg._color_bar_html(bar))
    (k, _), = t.find("span", **{"class": "t"})
    assert t.text[k] == "err <mm>"
    (k, grad), = t.find("div", **{"class": "grad"})
    assert grad["style"] == "background:linear-gradient(rgb(250,251,252),rgb(1,2,3),rgb(0,0,0))"
    assert t.text[t.find("span", **{"class": "hi"})[0][0]] == "12.3"  # .1f of 12.35 (binary 12.3499...)
    assert t.text[t.find("span", **{"class": "lo"})[0][0]] == "0.0"


def test_share_repeated_indices_stores_each_long_array_once():
    long_a, long_b, short = "A" * 4096, "B" * 5000, "C" * 4095
    payload = {"objects": [{"name": "o1", "indices": long_a}, {"name": "o2", "indices": short},
                           {"name": "o3"}, {"name": "o4", "indices": long_a}],
               "frames": [{"id": 3, "objects": [{"indices": long_b}, {"indices": long_a}]}], "camera": {"x": 1}}
    out = wg.share_repeated_indices(payload)
    assert out["shared"] == {"0": long_a, "1": long_b}
    assert [o.get("indices") for o in out["objects"]] == ["@0", short, None, "@0"]
    assert [o["indices"] for o in out["frames"][0]["objects"]] == ["@1", "@0"]
    assert out["frames"][0]["id"] == 3 and out["camera"] == {"x": 1} and out["objects"][0]["name"] == "o1"
    assert payload["objects"][0]["indices"] == long_a and "shared" not in payload  # the input is left alone
    assert wg.share_repeated_indices({"objects": []}) == {"objects": [], "shared": {}}
    assert "frames" not in wg.share_repeated_indices({"objects": []})
    assert wg.share_repeated_indices({"camera": 1}) == {"camera": 1, "objects": [], "shared": {}}


def test_viewer_fragment_embeds_the_payload_and_a_frame_slider():
    payload = {"objects": [{"name": "</script><b>", "indices": "X" * 5000}], "colorBars": [
        {"title": "e", "min": 0.0, "max": 2.0, "colors": [[1, 1, 1]]}],
        "frames": [{"id": 10, "objects": []}, {"id": 20, "objects": []}, {"id": 30, "objects": []}], "start": 1}
    text = wg.viewer_fragment(payload, "v_1")
    t = _Tree(text)
    (_, canvas), = t.find("canvas")
    assert canvas == {"id": "v_1", "width": "1024", "height": "768"}
    (k, _), = t.find("script", id="v_1-data", type="application/json")
    data = json.loads(t.text[k].replace("<\\/", "</"))
    assert data == wg.share_repeated_indices(payload) and "</" not in t.text[k]
    (_, rng), = t.find("input", id="v_1-frame")
    assert (rng["type"], rng["min"], rng["max"], rng["value"], rng["step"]) == ("range", "0", "2", "1", "1")
    assert t.text[t.find("span", id="v_1-frame-label")[0][0]] == "20"
    assert t.find("div", **{"class": "bs-bar"}) and "bodystudioMount(\"v_1\");" in text
    assert t.text[t.find("div", **{"class": "bs-help"})[0][0]] == (
        "drag: rotate, shift+drag: pan, wheel: zoom, double-click: reset")
    two_bars = {"objects": [], "colorBars": [{"title": t, "min": 0.0, "max": 1.0, "colors": [[1, 1, 1]]} for t in "ab"]}
    tb = _Tree(wg.viewer_fragment(two_bars, "b"))
    (k, _), = tb.find("div", **{"class": "bs-view"})
    assert not tb.text.get(k, "").strip() and len(tb.find("div", **{"class": "bs-bar"})) == 2  # no loose text
    one_text = wg.viewer_fragment({"objects": [], "frames": [{"id": 1, "objects": []}]}, "w")
    assert one_text.split('double-click: reset</div></div>\n', 1)[1].startswith('<script type="application/json"')
    assert text.split('double-click: reset</div></div>\n', 1)[1].startswith('<div class="bs-frames">')
    one = _Tree(one_text)
    assert one.find("input") == [] and one.find("div", **{"class": "bs-bar"}) == []
    k0 = _Tree(wg.viewer_fragment({"objects": [], "frames": [{"id": 5, "objects": []}, {"id": 6, "objects": []}]}, "w"))
    assert k0.find("input")[0][1]["value"] == "0" and k0.text[k0.find("span", id="w-frame-label")[0][0]] == "5"
    with pytest.raises(InputError) as exc:
        wg.viewer_fragment({}, "bad-id")
    assert str(exc.value) == "view id 'bad-id' must be an identifier"


def test_scene_html_page_and_its_atomic_save(tmp_path, caplog):
    plotter, *_ = _scene()
    payload = {"objects": [{"name": "given"}], "camera": {}}
    page = wg.scene_html(plotter, "T <1>", payload)
    t = _Tree(page)
    assert t.text[t.find("title")[0][0]] == "T <1>" and t.text[t.find("h1")[0][0]] == "T <1>"
    (k, _), = t.find("script", id="view3d-data")
    assert json.loads(t.text[k])["objects"] == [{"name": "given"}]
    assert page.startswith('<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">')
    assert wg.VIEWER_CSS in page and wg.STATUS_JS in page and wg.VIEWER_JS in page and page.endswith("</html>\n")
    css = "body{margin:0;background:#1d1e23;color:#eee;font-family:sans-serif}h1{font-size:16px;margin:8px 12px}"
    assert t.text[t.find("style")[0][0]] == wg.VIEWER_CSS + css
    bare = _Tree(wg.page_head("x"))
    assert bare.text[bare.find("style")[0][0]] == wg.VIEWER_CSS
    own = wg.scene_html(plotter)
    (k, _), = _Tree(own).find("script", id="view3d-data")
    assert {o["name"] for o in json.loads(_Tree(own).text[k + 0])["objects"]} >= {"heat", "floor"}
    assert _Tree(own).text[_Tree(own).find("title")[0][0]] == "bodystudio view"
    out = wg.save_scene_html(plotter, tmp_path / "v.HTM", "T", payload)
    assert out == tmp_path / "v.HTM" and out.read_text() == wg.scene_html(plotter, "T", payload)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["v.HTM"]
    import logging

    with caplog.at_level(logging.INFO, logger="bodystudio.viewer.webgl"):
        saved = wg.save_scene_html(plotter, tmp_path / "w.html")
    text = saved.read_text()
    assert text == wg.scene_html(plotter)  # the plotter's own scene, titled "bodystudio view"
    assert [r.getMessage() for r in caplog.records] == [f"wrote {saved} ({len(text) / 1e6:.1f} MB)"]
    with pytest.raises(InputError) as exc:
        wg.save_scene_html(plotter, tmp_path / "v.txt")
    assert str(exc.value) == f"{tmp_path / 'v.txt'}: HTML export needs a path ending in .html"
    plotter.close()
