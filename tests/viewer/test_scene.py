"""Offscreen rendering: the mesh lands where the camera should see it, colour bars exist, empty is an error."""

import numpy as np
import pytest

from bodystudio.errors import InputError
from bodystudio.geometry.mesh import Mesh
from bodystudio.viewer import scene as sc
from bodystudio.viewer.views import scene_for_avatar, scene_for_mesh

SIZE = (320, 240)


def _box_corners(bounds: np.ndarray) -> np.ndarray:
    lo, hi = bounds
    return np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])


def _screen_box(plotter, bounds):
    uv = sc.project_to_screen(plotter, _box_corners(bounds))
    return uv.min(0), uv.max(0)


def test_mesh_pixels_fall_inside_its_projected_bounding_box(body_mesh, drawn):
    # Shift the body off-centre so a renderer that ignored the camera would fail the test.
    mesh = body_mesh.with_vertices(body_mesh.vertices + [0.4, 0.0, 0.0])
    plotter = sc.make_plotter(window_size=SIZE)
    sc.add_mesh(plotter, mesh)
    sc.frame_front(plotter, mesh.bounds + [[-0.6, 0, 0], [0.2, 0, 0]])  # the body sits right of centre
    img = sc.render_image(plotter)
    assert img.shape == (SIZE[1], SIZE[0], 3)
    (u0, v0), (u1, v1) = _screen_box(plotter, mesh.bounds)
    ys, xs = np.nonzero(drawn(img))
    assert len(xs) > 500
    margin = 2
    assert xs.min() >= u0 - margin and xs.max() <= u1 + margin
    assert ys.min() >= v0 - margin and ys.max() <= v1 + margin
    # The body fills a fair part of its box (it is not a speck) and lies right of the image centre.
    box_area = (u1 - u0) * (v1 - v0)
    assert len(xs) > 0.15 * box_area
    assert xs.mean() > SIZE[0] / 2
    plotter.close()


def test_error_map_draws_a_colour_bar_with_the_colour_map(body_mesh):
    import matplotlib

    rng = np.random.default_rng(0)
    err = rng.uniform(0, 20, body_mesh.n_vertices)
    plotter = sc.make_plotter(window_size=(400, 300))
    sc.add_error_map(plotter, body_mesh, err, clim=(0.0, 20.0))
    sc.frame_front(plotter, body_mesh.bounds)
    img = sc.render_image(plotter)
    assert "error (mm)" in plotter.scalar_bars
    h, w = img.shape[:2]
    cmap = (np.asarray(matplotlib.colormaps[sc.ERROR_CMAP](np.linspace(0, 1, 64)))[:, :3] * 255).astype(int)

    def colour_map_pixels(image):
        strip = image[int(0.3 * h):int(0.7 * h), int(0.85 * w):].reshape(-1, 3).astype(int)
        dist = np.abs(strip[:, None, :] - cmap[None]).max(-1)
        close = dist.min(1) <= 12
        return close.sum(), np.unique(dist.argmin(1)[close] // 16)

    count, segments = colour_map_pixels(img)
    assert count > 100  # a bar of colour-map colours right of the body
    assert len(segments) >= 3  # low, middle and high parts of the map all appear
    # Without an error map there is no bar: the same strip has no colour-map pixels.
    plain = sc.make_plotter(window_size=(400, 300))
    sc.add_mesh(plain, body_mesh)
    sc.frame_front(plain, body_mesh.bounds)
    assert colour_map_pixels(sc.render_image(plain))[0] < 5
    plotter.close()
    plain.close()


def test_empty_scene_is_an_error_and_writes_nothing(tmp_path):
    plotter = sc.make_plotter(window_size=SIZE)
    out = tmp_path / "empty.png"
    with pytest.raises(sc.EmptySceneError, match="empty"):
        sc.save_screenshot(plotter, out)
    assert not out.exists()
    plotter.close()


def test_scene_looking_away_is_blank_and_an_error(body_mesh, tmp_path):
    plotter = sc.make_plotter(window_size=SIZE)
    sc.add_mesh(plotter, body_mesh)
    plotter.camera_position = [(0, 1, 5), (0, 1, 10), (0, 1, 0)]  # looking away from the body
    with pytest.raises(sc.EmptySceneError, match="blank"):
        sc.save_screenshot(plotter, tmp_path / "away.png")
    assert not (tmp_path / "away.png").exists()
    plotter.close()


def test_vertex_errors_measure_a_known_offset(body_mesh):
    # Pushing every vertex 5 mm out along its normal puts it ~5 mm from the original surface.
    moved = body_mesh.vertices + 0.005 * body_mesh.vertex_normals
    err = sc.vertex_errors_mm(moved, body_mesh)
    assert np.median(err) == pytest.approx(5.0, abs=0.3)
    assert sc.vertex_errors_mm(body_mesh.vertices, body_mesh).max() < 1e-6


def test_skeleton_and_skin_weights(body_2k):
    from bodystudio.viewer.avatar import avatar_from_body

    avatar = avatar_from_body(body_2k)
    plotter = scene_for_avatar(avatar, plotter=sc.make_plotter(window_size=SIZE), bone="upperarm_l")
    img = sc.render_image(plotter)
    assert "weight upperarm_l" in plotter.scalar_bars
    # Skin weights: the upper arm is red-ish (weight 1), the legs blue-ish (weight 0) in coolwarm.
    arm = body_2k.weights[:, body_2k.skeleton.index("upperarm_l")] > 0.9
    uv = sc.project_to_screen(plotter, body_2k.vertices[arm]).astype(int)
    px = img[np.clip(uv[:, 1], 0, SIZE[1] - 1), np.clip(uv[:, 0], 0, SIZE[0] - 1)].astype(int)
    assert np.mean(px[:, 0] > px[:, 2] + 30) > 0.5
    with pytest.raises(InputError, match="unknown bone"):
        scene_for_avatar(avatar, plotter=sc.make_plotter(window_size=SIZE), bone="tail")
    # Skeleton: drawing it changes pixels, shifting them towards bone yellow (R, G up against B).
    def skin(bones: bool):
        p = sc.make_plotter(window_size=SIZE)
        sc.add_mesh(p, avatar.mesh, opacity=0.3)
        if bones:
            sc.add_skeleton(p, avatar.heads, avatar.tails)
        sc.frame_front(p, avatar.mesh.bounds)
        return sc.render_image(p).astype(int)

    with_bones, without = skin(True), skin(False)
    changed = np.abs(with_bones - without).max(-1) > 30
    assert changed.sum() > 30
    dr, dg, db = (with_bones[changed] - without[changed]).mean(0)
    assert dr > db + 20 and dg > db + 20
    plotter.close()


def test_mesh_scene_with_reference_colours_by_error(body_mesh, drawn):
    """A mesh pushed out along its normals by 0 mm at the feet rising to 8 mm at the head: the scene colours
    each vertex by its distance to the reference, so the head is drawn in the map's hot end, the feet cold."""
    V = body_mesh.vertices
    height = (V[:, 1] - V[:, 1].min()) / np.ptp(V[:, 1])
    offset_mm = 8.0 * height
    moved = Mesh(V + 0.001 * offset_mm[:, None] * body_mesh.vertex_normals, body_mesh.faces)
    plotter = scene_for_mesh(moved, plotter=sc.make_plotter(window_size=SIZE), reference=body_mesh, key_help=False,
                             floor=False)
    assert "error (mm)" in plotter.scalar_bars
    shown = np.asarray(plotter.actors["error"].mapper.dataset.point_data["error (mm)"])
    np.testing.assert_allclose(shown, sc.vertex_errors_mm(moved.vertices, body_mesh), atol=1e-9)
    # the distances are the offsets (a few concave vertices find a nearer piece of the reference)
    assert np.median(np.abs(shown - offset_mm)) < 0.05 and np.percentile(np.abs(shown - offset_mm), 90) < 0.5
    img = sc.render_image(plotter).astype(int)
    mask = drawn(img)
    rows = np.nonzero(mask.any(1))[0]
    top, bottom = rows.min() + (rows.max() - rows.min()) // 6, rows.max() - (rows.max() - rows.min()) // 6
    head = img[:top][mask[:top]].mean(0)
    feet = img[bottom:][mask[bottom:]].mean(0)
    # turbo: red at the top of the range, blue at the bottom (shading scales both ends alike)
    assert head[0] > head[2] + 40 and feet[2] > feet[0] + 30, (head, feet)  # measured (108, 52, 45), (48, 50, 96)
    plotter.close()
