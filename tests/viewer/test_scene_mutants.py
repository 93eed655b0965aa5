"""scene.py's framing, projection, colour maps and layers checked against independent references (mutMM).

The camera framing is checked through a pinhole written here from the camera's position, focal point, up vector and
view angle (not VTK's matrix), the projection against the same pinhole, the error scale against numpy's percentile,
the distances against a plane's closed form, and the rendered screenshot by decoding the written PNG with PIL and
reading the pixels at projected points.
"""

from __future__ import annotations

import numpy as np
import pytest

from bodystudio.errors import InputError
from bodystudio.geometry.mesh import Mesh
from bodystudio.viewer import scene as sc

SIZE = (400, 300)
V4 = np.array([[-0.5, -0.5, 0.0], [0.5, -0.5, 0.0], [0.5, 0.5, 0.0], [-0.5, 0.5, 0.0]])
F2 = np.array([[0, 1, 2], [0, 2, 3]])


def _pinhole(plotter, points) -> np.ndarray:
    """Pixel (x right, y down) of world points through an ideal pinhole built from the plotter's camera."""
    cam = plotter.camera
    e, f, up = (np.asarray(v, float) for v in (cam.position, cam.focal_point, cam.up))
    fwd = (f - e) / np.linalg.norm(f - e)
    right = np.cross(fwd, up)
    right /= np.linalg.norm(right)
    true_up = np.cross(right, fwd)
    W, H = plotter.window_size
    focal_px = (H / 2) / np.tan(np.radians(cam.view_angle) / 2)
    d = np.asarray(points, float) - e
    z = d @ fwd
    return np.c_[W / 2 + focal_px * (d @ right) / z, H / 2 - focal_px * (d @ true_up) / z]


def _actor_data(plotter, name):
    import pyvista as pv

    mapper = plotter.renderer.actors[name].GetMapper()
    mapper.Update()
    return pv.wrap(mapper.GetInput())


def test_make_plotter_and_polydata():
    plotter = sc.make_plotter(window_size=(321, 123))
    assert list(plotter.window_size) == [321, 123]
    assert np.allclose(plotter.background_color.float_rgb, sc.BACKGROUND, atol=1 / 255)
    assert plotter.off_screen
    assert sc.BACKGROUND_RGB == (41, 43, 51)
    pd = sc.polydata(V4.astype(np.float32), F2.astype(np.int32))
    assert pd.points.dtype == np.float64 and np.array_equal(pd.points, V4)
    assert np.array_equal(pd.faces, [3, 0, 1, 2, 3, 0, 2, 3])
    plotter.close()


def test_egl_is_asked_for_only_without_a_display(monkeypatch):
    for var in ("DISPLAY", "WAYLAND_DISPLAY", "VTK_DEFAULT_OPENGL_WINDOW"):
        monkeypatch.delenv(var, raising=False)
    sc._prefer_egl_offscreen()
    import os

    assert os.environ["VTK_DEFAULT_OPENGL_WINDOW"] == "vtkEGLRenderWindow"
    for var in ("DISPLAY", "WAYLAND_DISPLAY"):
        monkeypatch.delenv("VTK_DEFAULT_OPENGL_WINDOW", raising=False)
        monkeypatch.setenv(var, ":0")
        sc._prefer_egl_offscreen()
        assert "VTK_DEFAULT_OPENGL_WINDOW" not in os.environ
        monkeypatch.delenv(var)
    monkeypatch.setenv("VTK_DEFAULT_OPENGL_WINDOW", "mine")
    sc._prefer_egl_offscreen()
    assert os.environ["VTK_DEFAULT_OPENGL_WINDOW"] == "mine"


@pytest.mark.parametrize("bounds, window, direction, margin", [
    ([[-0.2, 0.0, -0.1], [0.2, 1.8, 0.1]], (400, 300), (0.0, 0.0, 1.0), 1.0),   # the height decides
    ([[-1.5, 0.5, -0.3], [1.5, 0.9, 0.3]], (300, 400), (0.0, 0.0, 2.0), 1.25),  # the width decides
    ([[-0.1, 0.0, -1.6], [0.1, 0.4, 1.6]], (400, 300), (0.0, 0.0, 1.0), 1.0),   # the depth counts as a width
])
def test_frame_front_box_fit_puts_the_front_face_on_the_window_edge(bounds, window, direction, margin):
    plotter = sc.make_plotter(window_size=window)
    bounds = np.asarray(bounds)
    sc.frame_front(plotter, bounds, direction=direction, margin=margin)
    center = bounds.mean(0)
    assert np.allclose(plotter.camera.focal_point, center) and np.allclose(plotter.camera.up, [0, 1, 0])
    pos = np.asarray(plotter.camera.position)
    assert np.allclose(np.cross(pos - center, direction), 0) and (pos - center) @ direction > 0
    lo, hi = bounds
    half = (hi - lo) / 2
    z_face = hi[2] if half[0] >= half[2] else center[2] + half[2]
    face = np.array([[lo[0], lo[1], z_face], [hi[0], hi[1], z_face]])
    uv = _pinhole(plotter, face)
    W, H = window
    # the face at distance D from the camera: half its size over D tan(a/2) (the ideal pinhole) is 1 / margin
    span = np.abs(uv[1] - uv[0]) / [W, H]
    if half[0] < half[2]:  # the depth is the widest side: the distance is from the box's front at its depth
        D = np.linalg.norm(pos - center) - half[2]
        assert np.isclose(D, margin * half[2] / (np.tan(np.radians(plotter.camera.view_angle) / 2) * W / H))
    else:
        assert np.isclose(span.max(), 1 / margin, atol=1e-9)
    plotter.close()


def test_frame_front_sphere_fit_and_default_bounds():
    plotter = sc.make_plotter(window_size=SIZE)
    bounds = np.array([[1.0, 1.0, 1.0], [1.6, 1.8, 1.0]])  # radius 0.5
    sc.frame_front(plotter, bounds, direction=(0.3, 0.6, 1.0), margin=0.75, fit="sphere")
    center = bounds.mean(0)
    offset = np.asarray(plotter.camera.position) - center
    d = np.array([0.3, 0.6, 1.0]) / np.linalg.norm([0.3, 0.6, 1.0])
    assert np.allclose(offset, 0.75 * 0.5 / np.sin(np.radians(plotter.camera.view_angle) / 2) * d)
    sc.frame_front(plotter, np.zeros((2, 3)), fit="sphere")  # a point: the radius floor of 1 mm
    offset = np.asarray(plotter.camera.position)
    assert np.isclose(np.linalg.norm(offset), 1.1 * 1e-3 / np.sin(np.radians(plotter.camera.view_angle) / 2))
    sc.frame_front(plotter, np.zeros((2, 3)))  # box fit of a point: the 1 mm floor too
    assert np.isclose(np.linalg.norm(plotter.camera.position), 1.1 * 1e-3)
    deep = V4 + [3.0, 1.0, 0.0]
    deep[2:, 2] = 0.4
    sc.add_mesh(plotter, Mesh(deep, F2))
    sc.frame_front(plotter)
    assert np.allclose(plotter.camera.focal_point, [3.0, 1.0, 0.2])  # the scene's box, near to far
    sc.frame_front(plotter, np.array([[0, 0, 0], [1, 2, 0]]), direction=(0, 0, 1))  # integers are fine
    assert np.allclose(plotter.camera.focal_point, [0.5, 1.0, 0.0])
    plotter.close()


def test_project_to_screen_matches_an_ideal_pinhole():
    plotter = sc.make_plotter(window_size=(400, 300))
    plotter.camera_position = [(0.7, 1.3, 2.9), (0.1, 0.9, 0.0), (0.1, 1.0, 0.05)]
    plotter.camera.view_angle = 40.0
    pts = np.random.default_rng(4).uniform(-0.4, 0.4, (20, 3)) + [0.1, 0.9, 0.0]
    assert np.allclose(sc.project_to_screen(plotter, pts), _pinhole(plotter, pts), atol=1e-6)
    assert sc.project_to_screen(plotter, pts[0]).shape == (1, 2)
    plotter.close()


def test_add_mesh_uses_vertex_colours_only_when_one_per_vertex():
    plotter = sc.make_plotter(window_size=SIZE)
    rgb = np.array([[1, 2, 3, 9], [4, 5, 6, 9], [7, 8, 9, 9], [10, 11, 12, 9]], np.uint8)
    sc.add_mesh(plotter, Mesh(V4, F2, vertex_colors=rgb), name="c", opacity=0.4)
    sc.add_mesh(plotter, Mesh(V4, F2, vertex_colors=rgb[:3]), name="p", color=(0.2, 0.4, 0.6))
    sc.add_mesh(plotter, Mesh(V4, F2), name="d")
    c = _actor_data(plotter, "c")
    assert np.array_equal(c.point_data["rgb"], rgb[:, :3])
    assert plotter.renderer.actors["c"].GetProperty().GetOpacity() == 0.4
    assert plotter.renderer.actors["c"].GetMapper().GetScalarVisibility()
    # the colours go to the screen as they are (not through a colour map), smoothly shaded
    assert plotter.renderer.actors["c"].GetMapper().GetColorModeAsString() == "Default"
    for name in ("c", "p", "d"):
        assert plotter.renderer.actors[name].GetProperty().GetInterpolationAsString() == "Phong"
    assert plotter.renderer.actors["p"].GetProperty().GetOpacity() == 1.0
    sc.add_mesh(plotter, Mesh(V4, F2), name="half", opacity=0.5)
    assert plotter.renderer.actors["half"].GetProperty().GetOpacity() == 0.5
    sc.add_mesh(plotter, Mesh(V4, F2, vertex_colors=rgb[:, :3].astype(np.int64)), name="i")
    assert _actor_data(plotter, "i").point_data["rgb"].dtype == np.uint8
    sc.add_mesh(plotter, Mesh(V4, F2))
    assert "mesh" in plotter.renderer.actors
    assert not plotter.renderer.actors["p"].GetMapper().GetScalarVisibility()
    assert np.allclose(plotter.renderer.actors["p"].GetProperty().GetColor(), (0.2, 0.4, 0.6), atol=1 / 255)
    assert np.allclose(plotter.renderer.actors["d"].GetProperty().GetColor(), sc.MESH_COLOR, atol=1 / 255)
    assert plotter.renderer.actors["d"].GetProperty().GetInterpolation() != 0  # smooth shading: not flat
    plotter.close()


def test_vertex_errors_are_millimetres_to_the_nearest_surface_point():
    plane = Mesh(V4 * 4, F2)
    pts = np.array([[0.1, 0.2, 0.003], [0.0, 0.0, -0.25], [3.0, 0.0, 0.0], [2.0, 2.0, 0.0]])
    expected = [3.0, 250.0, 1000.0, 0.0]  # above, below, beside the edge (x = 2), on the corner
    assert np.allclose(sc.vertex_errors_mm(pts, plane), expected, atol=1e-9)
    p32 = np.array([[0.1, 0.2, 0.0031], [0.3, -0.7, -0.0123]], np.float32)  # float32 points: measured in float64
    got = sc.vertex_errors_mm(p32, plane)
    assert got.dtype == np.float64 and np.array_equal(got, 1000.0 * np.abs(p32[:, 2].astype(np.float64)))


def test_error_map_scale_is_zero_to_the_98th_percentile_and_its_bar():
    plotter = sc.make_plotter(window_size=SIZE)
    mesh = Mesh(np.random.default_rng(1).uniform(0, 1, (50, 3)), np.array([[0, 1, 2]]))
    err = np.arange(50, dtype=float) ** 1.5
    sc.add_error_map(plotter, mesh, err.reshape(-1, 1), name="e")
    mapper = plotter.renderer.actors["e"].GetMapper()
    assert np.allclose(mapper.GetScalarRange(), (0.0, np.percentile(err, 98)))
    import matplotlib

    lut = mapper.GetLookupTable()
    turbo = matplotlib.colormaps["turbo"].resampled(256)
    assert lut.GetNumberOfTableValues() == 256
    for k in (0, 60, 128, 200, 255):  # the turbo scale, low end dark blue, high end dark red
        assert np.allclose(lut.GetTableValue(k)[:3], turbo(k)[:3], atol=1 / 255)
    assert plotter.renderer.actors["e"].GetProperty().GetInterpolationAsString() == "Phong"
    sc.add_error_map(plotter, mesh, err)
    assert "error" in plotter.renderer.actors
    assert np.array_equal(_actor_data(plotter, "e").point_data["error (mm)"], err)
    bar = plotter.scalar_bars["error (mm)"]
    assert bar.GetTitle() == "error (mm)" and bar.GetLabelFormat() == "%.1f" and bar.GetNumberOfLabels() == 5
    assert np.allclose(bar.GetPosition(), (0.86, 0.2)) and np.isclose(bar.GetWidth(), 0.08)
    assert np.isclose(bar.GetHeight(), 0.6)
    sc.add_error_map(plotter, mesh, np.zeros(50), name="z", title="flat")
    assert np.allclose(plotter.renderer.actors["z"].GetMapper().GetScalarRange(), (0.0, 1e-3))
    sc.add_error_map(plotter, mesh, err, clim=(2.0, 3.0), name="c", title="given")
    assert np.allclose(plotter.renderer.actors["c"].GetMapper().GetScalarRange(), (2.0, 3.0))
    with pytest.raises(InputError) as exc:
        sc.add_error_map(plotter, mesh, err[:49])
    assert str(exc.value) == "error map has 49 values for 50 vertices"
    assert sc._bar_args("t") == dict(title="t", vertical=True, position_x=0.86, position_y=0.2, width=0.08,
                                     height=0.6, n_labels=5, fmt="%.1f", color="white", title_font_size=14,
                                     label_font_size=12)
    plotter.close()


def test_skin_weights_show_one_bones_column_on_zero_to_one():
    plotter = sc.make_plotter(window_size=SIZE)
    W = np.array([[1.0, 0.0, 0.0], [0.2, 0.7, 0.1], [0.0, 0.5, 0.5], [0.0, 0.0, 1.0]])
    sc.add_skin_weights(plotter, Mesh(V4, F2), W, ["a", "b", "c"], "b", name="w")
    sc.add_skin_weights(plotter, Mesh(V4, F2), W, ["a", "b", "c"], "a")
    assert "weights" in plotter.renderer.actors
    assert np.array_equal(_actor_data(plotter, "w").point_data["weight b"], W[:, 1])
    assert np.allclose(plotter.renderer.actors["w"].GetMapper().GetScalarRange(), (0.0, 1.0))
    assert plotter.scalar_bars["weight b"].GetLabelFormat() == "%.2f"
    import matplotlib

    lut = plotter.renderer.actors["w"].GetMapper().GetLookupTable()
    cool = matplotlib.colormaps["coolwarm"].resampled(256)
    for k in (0, 128, 255):
        assert np.allclose(lut.GetTableValue(k)[:3], cool(k)[:3], atol=1 / 255)
    assert plotter.renderer.actors["w"].GetProperty().GetInterpolationAsString() == "Phong"
    with pytest.raises(InputError) as exc:
        sc.add_skin_weights(plotter, Mesh(V4, F2), W, ("a", "b", "c"), "d")
    assert str(exc.value) == "unknown bone 'd'; valid bones: a, b, c"
    plotter.close()


def test_skeleton_tubes_follow_the_bones_and_joints_sit_on_the_heads():
    plotter = sc.make_plotter(window_size=SIZE)
    heads = np.array([[0.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    tails = np.array([[0.0, 1.0, 0.0], [0.5, 1.0, 0.0]])
    sc.add_skeleton(plotter, heads, tails, radius=0.01, name="sk")
    assert set(plotter.renderer.actors) >= {"sk-bones", "sk-joints"}
    tube = np.asarray(_actor_data(plotter, "sk-bones").points)

    def to_segment(p, a, b):
        t = np.clip((p - a) @ (b - a) / ((b - a) @ (b - a)), 0, 1)
        return np.linalg.norm(p - (a + t[:, None] * (b - a)), axis=1)

    d0, d1 = to_segment(tube, heads[0], tails[0]), to_segment(tube, heads[1], tails[1])
    on = np.isclose(d0, 0.01, atol=1e-3) | np.isclose(d1, 0.01, atol=1e-3)
    assert on.all()  # a tube of the radius around each of the two bones, nowhere else
    assert np.ptp(tube[:, 0]) > 0.5 and np.ptp(tube[:, 1]) > 1.0
    joints = np.asarray(_actor_data(plotter, "sk-joints").points)
    near = np.linalg.norm(joints[:, None] - heads[None], axis=2).min(1)
    assert np.allclose(near, 0.018, atol=1e-3)  # spheres of 1.8 radii on the heads
    for head in heads:  # a sphere on each head
        assert np.linalg.norm(joints - head, axis=1).min() < 0.02
    assert np.allclose(plotter.renderer.actors["sk-bones"].GetProperty().GetColor(), sc.BONE_COLOR, atol=1 / 255)
    assert np.allclose(plotter.renderer.actors["sk-joints"].GetProperty().GetColor(), sc.JOINT_COLOR, atol=1 / 255)
    assert len(tube) == 2 * 2 * 8 * 2  # 8 sides at each end of each bone, once more for the caps
    assert len(joints) == 2 * (10 * (10 - 2) + 2)  # a 10 x 10 sphere on each head
    sc.add_skeleton(plotter, heads, tails)
    default = np.asarray(_actor_data(plotter, "skeleton-bones").points)
    assert np.isclose(np.abs(default[:, 2]).max(), 0.008, atol=1e-6)  # the default radius is 8 mm
    n = len(plotter.renderer.actors)
    sc.add_skeleton(plotter, np.zeros((0, 3)), np.zeros((0, 3)))
    assert len(plotter.renderer.actors) == n
    plotter.close()


def test_point_cloud_drops_non_finite_points_and_keeps_matching_colours():
    plotter = sc.make_plotter(window_size=SIZE)
    pts = np.array([[0.0, 0.0, 0.0], [np.nan, 0, 0], [1.0, 0.0, 0.0], [0.0, np.inf, 0.0], [2.0, 0.0, 0.0]])
    rgb = np.array([[1, 2, 3], [4, 5, 6], [7, 8, 9]], np.uint8)
    rgba = np.c_[rgb, [9, 9, 9]].astype(np.int64)
    sc.add_point_cloud(plotter, pts.astype(np.float32), rgba, point_size=6.0, name="c")
    data = _actor_data(plotter, "c")
    assert np.array_equal(data.points, pts[[0, 2, 4]].astype(np.float32)) and data.points.dtype == np.float64
    assert np.array_equal(data.point_data["rgb"], rgb) and data.point_data["rgb"].dtype == np.uint8
    assert plotter.renderer.actors["c"].GetMapper().GetColorModeAsString() == "Default"
    prop = plotter.renderer.actors["c"].GetProperty()
    assert prop.GetPointSize() == 6.0 and prop.GetRepresentation() == 0
    sc.add_point_cloud(plotter, pts, rgb[:2], name="d", color=(0.1, 0.5, 0.9))
    assert not plotter.renderer.actors["d"].GetMapper().GetScalarVisibility()
    assert np.allclose(plotter.renderer.actors["d"].GetProperty().GetColor(), (0.1, 0.5, 0.9), atol=1 / 255)
    assert plotter.renderer.actors["d"].GetProperty().GetPointSize() == 3.0
    assert plotter.renderer.actors["d"].GetProperty().GetRepresentation() == 0
    sc.add_point_cloud(plotter, pts)
    assert "cloud" in plotter.renderer.actors
    n = len(plotter.renderer.actors)
    sc.add_point_cloud(plotter, np.full((2, 3), np.nan))
    assert len(plotter.renderer.actors) == n
    plotter.close()


def _camera(name="k"):
    from types import SimpleNamespace

    def frustum(near, far):
        c = np.array([[-0.4, 0.3, -1.0], [0.4, 0.3, -1.0], [0.4, -0.3, -1.0], [-0.4, -0.3, -1.0]])
        return np.r_[c * near, c * far] + [1.0, 2.0, 3.0]

    return SimpleNamespace(name=name, center=np.array([1.0, 2.0, 3.0]), frustum=frustum)


def test_camera_frustum_lines_and_image_texture():
    plotter = sc.make_plotter(window_size=SIZE)
    image = np.arange(4 * 6, dtype=np.uint8).reshape(4, 6) * 10
    sc.add_camera(plotter, _camera(), image, far=0.5, color=(0.2, 0.3, 0.4))
    lines = _actor_data(plotter, "camera-k")
    corners = _camera().frustum(0.05, 0.5)[4:]
    assert np.allclose(lines.points, np.r_[[[1.0, 2.0, 3.0]], corners])
    assert np.array_equal(lines.lines, [2, 0, 1, 2, 0, 2, 2, 0, 3, 2, 0, 4, 5, 1, 2, 3, 4, 1])
    assert np.allclose(plotter.renderer.actors["camera-k"].GetProperty().GetColor(), (0.2, 0.3, 0.4), atol=1 / 255)
    assert plotter.renderer.actors["camera-k"].GetProperty().GetLineWidth() == 2
    quad = _actor_data(plotter, "camera-k-image")
    assert np.allclose(quad.points, corners) and np.array_equal(quad.faces, [4, 0, 1, 2, 3])
    assert np.array_equal(quad.active_texture_coordinates, [[0, 1], [1, 1], [1, 0], [0, 0]])
    assert not plotter.renderer.actors["camera-k-image"].GetProperty().GetLighting()
    sc.add_cameras(plotter, [_camera("a"), _camera("b")], {"b": image}, far=0.7)
    assert "camera-a" in plotter.renderer.actors and "camera-a-image" not in plotter.renderer.actors
    assert "camera-b-image" in plotter.renderer.actors
    assert np.allclose(_actor_data(plotter, "camera-a").points[1:], _camera().frustum(0.05, 0.7)[4:])
    sc.add_cameras(plotter, [_camera("c")])
    assert np.allclose(_actor_data(plotter, "camera-c").points[1:], _camera().frustum(0.05, 0.35)[4:])
    sc.add_camera(plotter, _camera(), name="named")
    assert "named" in plotter.renderer.actors
    assert np.allclose(_actor_data(plotter, "named").points[1:], _camera().frustum(0.05, 0.35)[4:])
    texture = plotter.renderer.actors["camera-k-image"].GetTexture()
    import pyvista as pv

    tex = pv.wrap(texture.GetInput())
    nx, ny, _ = tex.dimensions
    pixels = np.asarray(tex.active_scalars).reshape(ny, nx, -1)[::-1, :, :3]
    assert np.array_equal(pixels, np.repeat(image[:, :, None], 3, axis=2))  # the picture, top row first
    plotter.close()


def test_rgb_image_turns_masks_floats_and_greys_into_rgb():
    mask = np.array([[True, False]])
    assert np.array_equal(sc._rgb_image(mask), [[[255, 255, 255], [0, 0, 0]]])
    unit = np.array([[0.0, 0.5, 1.0]])
    assert np.array_equal(sc._rgb_image(unit)[0, :, 0], [0, 127, 255])
    big = np.array([[0.0, 100.0, 300.0, -5.0]])
    assert np.array_equal(sc._rgb_image(big)[0, :, 1], [0, 100, 255, 0])
    rgba = np.arange(2 * 2 * 4, dtype=np.uint8).reshape(2, 2, 4)
    out = sc._rgb_image(rgba)
    assert np.array_equal(out, rgba[..., :3]) and out.flags["C_CONTIGUOUS"] and out.dtype == np.uint8
    assert sc._rgb_image(np.array([[1.0]], np.float32))[0, 0, 2] == 255
    assert np.array_equal(sc._rgb_image(np.array([[0.0, 1.0, 2.0]]))[0, :, 0], [0, 1, 2])  # over 1: already 0-255
    assert np.array_equal(sc._rgb_image(np.array([[0, 1]], np.uint8))[0, :, 0], [0, 1])  # integers are not scaled
    assert np.array_equal(sc._rgb_image(np.array([[7]], np.uint16)), [[[7, 7, 7]]])


def test_floor_title_and_key_help():
    plotter = sc.make_plotter(window_size=SIZE)
    sc.add_floor(plotter, np.array([0.5, 9.0, -0.25]), size=2.4, name="f")
    pts = np.asarray(_actor_data(plotter, "f").points)
    assert np.allclose(pts.min(0), [-0.7, 0.0, -1.45]) and np.allclose(pts.max(0), [1.7, 0.0, 0.95])
    assert len(pts) == 13 * 13
    prop = plotter.renderer.actors["f"].GetProperty()
    assert prop.GetRepresentation() == 1 and np.isclose(prop.GetOpacity(), 0.35)
    sc.add_floor(plotter, np.zeros(3))
    assert np.ptp(np.asarray(_actor_data(plotter, "floor").points)[:, 0]) == pytest.approx(3.0)
    sc.add_title(plotter, "T")
    sc.add_key_help(plotter)
    texts = {name: a for name, a in plotter.renderer.actors.items() if name in ("title", "key-help")}
    assert set(texts) == {"title", "key-help"}
    assert np.allclose(plotter.renderer.actors["floor"].GetProperty().GetColor(), (0.45, 0.45, 0.5), atol=1 / 255)
    # pyvista's corner text: font size // 2 as the scale factor (9 -> 4, 11 -> 5), white
    assert texts["key-help"].GetLinearFontScaleFactor() == 4 and texts["title"].GetLinearFontScaleFactor() == 5
    assert texts["key-help"].GetTextProperty().GetColor() == (1.0, 1.0, 1.0)
    assert texts["title"].GetTextProperty().GetColor() == (1.0, 1.0, 1.0)
    assert texts["key-help"].GetText(0) == sc.KEY_HELP and texts["title"].GetText(2) == "T"
    plotter.close()


def test_visible_points_count_only_shown_actors():
    plotter = sc.make_plotter(window_size=SIZE)
    assert sc.visible_points(plotter) == 0
    sc.add_mesh(plotter, Mesh(V4, F2), name="a")
    sc.add_point_cloud(plotter, V4[:3], name="b")
    assert sc.visible_points(plotter) == 7
    plotter.renderer.actors["a"].SetVisibility(False)
    assert sc.visible_points(plotter) == 3
    plotter.add_text("text only")
    assert sc.visible_points(plotter) == 3
    plotter.close()


def test_screenshot_pixels_at_projected_points(tmp_path, caplog):
    from PIL import Image

    plotter = sc.make_plotter(window_size=SIZE)
    red = np.tile(np.array([[230, 20, 20]], np.uint8), (4, 1))
    plotter.add_mesh(sc.polydata(V4, F2), scalars=red, rgb=True, lighting=False, name="quad")
    sc.frame_front(plotter, np.array([[-1.0, -1.0, 0.0], [1.0, 1.0, 0.0]]))
    out = tmp_path / "s.PNG"
    import logging

    with caplog.at_level(logging.INFO, logger="bodystudio.viewer.scene"):
        img = sc.save_screenshot(plotter, out)
    assert [r.getMessage() for r in caplog.records] == [f"wrote {out} (400x300)"]
    assert img.shape == (SIZE[1], SIZE[0], 3) and img.dtype == np.uint8
    assert np.array_equal(np.asarray(Image.open(out).convert("RGB")), img)
    inside = sc.project_to_screen(plotter, np.array([[0.0, 0.0, 0.0], [0.4, 0.4, 0.0], [-0.4, -0.3, 0.0]]))
    for x, y in np.round(inside).astype(int):
        assert np.abs(img[y, x].astype(int) - [230, 20, 20]).max() <= 3
    outside = sc.project_to_screen(plotter, np.array([[0.8, 0.8, 0.0], [-0.8, 0.0, 0.0]]))
    for x, y in np.round(outside).astype(int):
        assert np.abs(img[y, x].astype(int) - sc.BACKGROUND_RGB).max() <= 2
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.PNG"]
    with pytest.raises(InputError) as exc:
        sc.save_screenshot(plotter, tmp_path / "s.jpg")
    assert str(exc.value) == f"{tmp_path / 's.jpg'}: screenshots are PNG; give a path ending in .png"
    plotter.close()


@pytest.mark.parametrize("offset, blank", [(3, False), (2, True)])
def test_a_view_within_two_levels_of_the_background_is_blank(offset, blank):
    plotter = sc.make_plotter(window_size=(64, 48))
    colour = np.tile(np.array(sc.BACKGROUND_RGB, np.uint8) + np.array([0, 0, offset], np.uint8), (4, 1))
    plotter.add_mesh(sc.polydata(V4 * 10, F2), scalars=colour, rgb=True, lighting=False, name="quad")
    sc.frame_front(plotter, np.array([[-1.0, -1.0, 0.0], [1.0, 1.0, 0.0]]))
    if blank:
        with pytest.raises(sc.EmptySceneError):
            sc.render_image(plotter)
    else:
        img = sc.render_image(plotter)
        assert np.abs(img.astype(int) - sc.BACKGROUND_RGB).max() == offset
    plotter.close()


def test_render_refuses_an_empty_or_a_blank_view(tmp_path):
    plotter = sc.make_plotter(window_size=SIZE)
    with pytest.raises(sc.EmptySceneError) as exc:
        sc.render_image(plotter)
    assert str(exc.value) == "nothing to draw: the scene is empty; give a mesh, avatar or session with data"
    sc.add_mesh(plotter, Mesh(V4, F2))
    plotter.camera_position = [(0, 0, 5), (0, 0, 10), (0, 1, 0)]  # looking away
    with pytest.raises(sc.EmptySceneError) as exc:
        sc.render_image(plotter)
    assert str(exc.value) == "the rendered image is blank: nothing in the scene is in view"
    with pytest.raises(sc.EmptySceneError):
        sc.save_screenshot(plotter, tmp_path / "x.png")
    assert not (tmp_path / "x.png").exists()
    plotter.close()


def test_frame_slider_snaps_to_the_nearest_frame_and_keys_step_within_the_ends():
    from types import SimpleNamespace

    shown, values, keys, renders = [], [], {}, []
    rep = SimpleNamespace(SetValue=values.append)
    made = {}

    def add_slider_widget(callback, rng, value, **kw):
        made.update(callback=callback, rng=rng, value=value, kw=kw)
        return SimpleNamespace(GetRepresentation=lambda: rep)

    plotter = SimpleNamespace(add_slider_widget=add_slider_widget, add_key_event=lambda k, f: keys.__setitem__(k, f),
                              render=lambda: renders.append(1))
    assert sc.add_frame_slider(plotter, iter([10, 20, 40]), 1, shown.append) is plotter
    keys["n"]()  # a key before any slider move steps from the start frame
    assert shown == [2] and values == [40]
    shown.clear()
    values.clear()
    renders.clear()
    assert (made["rng"], made["value"]) == ([10, 40], 20)
    assert made["kw"] == dict(title="frame", fmt="%.0f", pointa=(0.25, 0.92), pointb=(0.75, 0.92), style="modern")
    made["callback"](29.0)  # nearer 20 than 40
    made["callback"](31.0)
    assert shown == [1, 2]
    keys["n"]()  # already at the last frame: stays
    keys["p"]()
    keys["p"]()
    keys["p"]()  # at the first: stays
    assert shown == [1, 2, 2, 1, 0, 0] and values == [40, 20, 10, 10] and len(renders) == 4
    keys["n"]()
    assert shown[-1] == 1 and values[-1] == 20
