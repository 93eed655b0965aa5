"""Analytic checks of garment/render.py (§6 of Garment Replacement: the garment rendered with the estimated
lights and a depth buffer): flat quads in front of a pinhole camera, so every shaded pixel has an exact value.

Written for mutation testing (issue 17; tests/garment/test_render.py dresses a 2k body per session). A plane
facing the camera under one directional light has radiance ``albedo * (ambient + cos * colour)`` everywhere;
the z-buffer order, the two-sided normals, the texture lookup, the background, the separate depth layers and
the cast shadow of one quad on another are each pinned on 40 x 40 pixel images.
"""

import re

import numpy as np
import pytest

from bodystudio.capture.render import SKIN_COLOR
from bodystudio.errors import InputError
from bodystudio.garment import render as gr
from bodystudio.garment.garments import Garment
from bodystudio.garment.lighting import Lighting
from bodystudio.geometry.camera import Camera

LIGHT = Lighting([[0.0, 0.6, 0.8]], [[0.5, 0.4, 0.3]], [0.1, 0.2, 0.05])
COS = 0.8  # the light's cosine on a plane facing +z


def exact(message):
    return "^" + re.escape(str(message)) + "$"


def camera(size=40):
    return Camera.look_at("c", (0.0, 0.0, 3.0), (0.0, 0.0, 0.0), fx=100.0, width=size, height=size)


def quad(half, z, flip=False, centre=(0.0, 0.0)):
    """A square of side 2 ``half`` in the plane z, facing +z (the camera) unless ``flip``."""
    x, y = centre
    V = np.array([[x - half, y - half, z], [x + half, y - half, z], [x + half, y + half, z], [x - half, y + half, z]])
    F = np.array([[0, 1, 2], [0, 2, 3]])
    return V, (F[:, ::-1].copy() if flip else F)


def garment_quad(half=0.2, z=0.2, colour=(200, 100, 50), flip=False):
    V, F = quad(half, z, flip)
    uv = (V[:, :2] - V[:, :2].min(0)) / (2 * half)  # [0, 1]^2
    texture = np.empty((4, 4, 3), np.uint8)
    texture[:] = colour
    return Garment("g", V, F, uv, texture, np.ones((4, 1)), np.arange(4))


def lit(albedo, cos=COS, light=LIGHT):
    return np.asarray(albedo) * (light.ambient + cos * light.colors[0])


# ------------------------------------------------------------------------------------------ shading model


def test_lambert_radiance_clamps_back_lights_and_multiplies_visibility():
    light = Lighting([[0, 0, 1.0], [1.0, 0, 0]], [[0.5, 0.5, 0.5], [0.2, 0.4, 0.6]], [0.1, 0.0, 0.2])
    n = np.array([[0, 0, 1.0], [-1.0, 0, 0], [0.6, 0, 0.8]])
    albedo = np.array([[1.0, 0.5, 0.25], [0.5, 0.5, 0.5], [1.0, 1.0, 1.0]])
    want = albedo * np.array([[0.1 + 0.5, 0.5, 0.2 + 0.5],  # facing light 0, light 1 at 90 degrees
                              [0.1, 0.0, 0.2],  # both lights behind: ambient only
                              [0.1 + 0.4 + 0.12, 0.4 + 0.24, 0.2 + 0.4 + 0.36]])
    assert np.abs(gr.lambert_radiance(n, albedo, light) - want).max() < 1e-15
    vis = np.array([[0.0, 1.0], [1.0, 1.0], [1.0, 0.0]])  # light 0 blocked for row 0, light 1 for row 2
    want_vis = albedo * np.array([[0.1, 0.0, 0.2], [0.1, 0.0, 0.2], [0.1 + 0.4, 0.4, 0.2 + 0.4]])
    assert np.abs(gr.lambert_radiance(n, albedo, light, vis) - want_vis).max() < 1e-15


def test_pixel_attributes_interpolate_with_the_barycentrics():
    from bodystudio.capture.render import render

    V, F = quad(0.5, 0.0)
    res = render(V, F, camera())
    rows, cols = np.nonzero(res.mask)
    P = gr._pixel_attributes(res, F, rows, cols, V)
    # the surface point of each pixel is where its ray meets the plane z = 0: (col - 19.5, 19.5 - row) * 3 / 100
    assert np.abs(P[:, 0] - (cols - 19.5) * 0.03).max() < 1e-5
    assert np.abs(P[:, 1] - (19.5 - rows) * 0.03).max() < 1e-5 and np.abs(P[:, 2]).max() < 1e-7
    attr = np.array([[1.0, 0.0], [0.0, 1.0], [2.0, 3.0], [5.0, -1.0]])
    got = gr._pixel_attributes(res, F, rows, cols, attr)
    b = res.barycentric[rows, cols].astype(np.float64)
    want = np.einsum("kj,kjd->kd", b, attr[F[res.triangle_id[rows, cols]]])
    assert np.array_equal(got, want) and got.shape == (len(rows), 2)


# ------------------------------------------------------------------------------------------ render_body


@pytest.mark.parametrize("flip", [False, True])
def test_a_plane_facing_the_camera_has_the_lambert_radiance_everywhere(flip):
    """Normals are turned towards the camera (two-sided): a plane wound either way shades the same."""
    V, F = quad(0.5, 0.0, flip)
    albedo = np.tile([0.6, 0.5, 0.4], (4, 1))
    image, res = gr.render_body(V, F, camera(), LIGHT, albedo)
    assert image.shape == (40, 40, 3) and image.dtype == np.float64
    assert res.mask.sum() == 34 * 34  # +-0.5 m at 3 m and f = 100 px: +-16.7 px about the centre
    assert np.abs(image[res.mask] - lit([0.6, 0.5, 0.4])).max() < 1e-6
    assert np.all(image[~res.mask] == 0)


def test_render_body_interpolates_the_per_vertex_albedo_and_shades_a_tilted_plane():
    V, F = quad(0.5, 0.0)
    tilt = np.radians(30)  # turned about y by 30 degrees: normal (sin, 0, cos)
    R = np.array([[np.cos(tilt), 0, np.sin(tilt)], [0, 1, 0], [-np.sin(tilt), 0, np.cos(tilt)]])
    V = V @ R.T
    albedo = np.array([[0.2, 0.2, 0.2], [0.8, 0.2, 0.2], [0.8, 0.8, 0.2], [0.2, 0.8, 0.2]])
    image, res = gr.render_body(V, F, camera(), LIGHT, albedo)
    rows, cols = np.nonzero(res.mask)
    a = gr._pixel_attributes(res, F, rows, cols, albedo)
    cos = np.array([np.sin(tilt), 0, np.cos(tilt)]) @ LIGHT.directions[0]
    assert np.abs(image[rows, cols] - a * (LIGHT.ambient + cos * LIGHT.colors[0])).max() < 1e-12
    assert np.ptp(a[:, 0]) > 0.5  # the albedo does vary over the plane


def test_render_body_with_shadows_darkens_what_a_blocker_hides_from_the_light():
    """A small quad 0.25 m in front of a wall, light along (0.6, 0, 0.8): its shadow on the wall is the quad
    moved by -0.25 * (0.6 / 0.8) ... the wall points whose ray towards the light meets the blocker."""
    wall_V, wall_F = quad(0.5, 0.0)
    block_V, block_F = quad(0.1, 0.25, centre=(-0.3, 0.25))
    V = np.vstack([wall_V, block_V])
    F = np.vstack([wall_F, block_F + 4])
    light = Lighting([[0.6, 0.0, 0.8]], [[0.5, 0.5, 0.5]], [0.1, 0.1, 0.1])
    albedo = np.full((8, 3), 0.5)
    plain, res = gr.render_body(V, F, camera(), light, albedo)
    shadowed, _ = gr.render_body(V, F, camera(), light, albedo, shadows=True)
    on_wall = res.mask & (res.triangle_id < 2)
    rows, cols = np.nonzero(on_wall)
    P = gr._pixel_attributes(res, F, rows, cols, V)
    hit = P + (0.25 / 0.8) * np.array([0.6, 0.0, 0.8])  # where the ray reaches the blocker's plane
    inside = (np.abs(hit[:, 0] + 0.3) < 0.1 - 0.01) & (np.abs(hit[:, 1] - 0.25) < 0.1 - 0.01)
    outside = (np.abs(hit[:, 0] + 0.3) > 0.1 + 0.01) | (np.abs(hit[:, 1] - 0.25) > 0.1 + 0.01)
    assert inside.sum() > 10
    assert np.abs(shadowed[rows[inside], cols[inside]] - 0.5 * 0.1).max() < 1e-6  # ambient only
    assert np.abs(shadowed[rows[outside], cols[outside]] - plain[rows[outside], cols[outside]]).max() < 1e-12
    assert np.abs(plain[rows, cols] - 0.5 * (0.1 + 0.8 * 0.5)).max() < 1e-6


# ------------------------------------------------------------------------------------------ render_garment


def test_garment_in_front_of_the_body_wins_the_z_buffer_and_keeps_its_texture():
    body_V, body_F = quad(0.5, 0.0)
    g = garment_quad()
    out = gr.render_garment(body_V, body_F, g, g.vertices, camera(), LIGHT)
    # the garment: +-0.2 m at 2.8 m -> +-7.1 px; its pixels are textured (200, 100, 50) under the light
    assert out.garment_mask.sum() == 14 * 14
    want_g = lit(np.array([200, 100, 50]) / 255.0)
    assert np.abs(out.garment_rgb[out.garment_mask] - want_g).max() < 1e-6
    assert out.garment_rgb.dtype == np.float32 and np.all(out.garment_rgb[~out.garment_mask] == 0)
    assert np.array_equal(out.image[out.garment_mask], np.tile(np.round(want_g * 255), (14 * 14, 1)))
    # the body: the rest of its square, in the default skin colour
    assert out.body_mask.sum() == 34 * 34 - 14 * 14 and not (out.body_mask & out.garment_mask).any()
    want_b = np.clip(np.round(lit(SKIN_COLOR) * 255), 0, 255)
    assert np.array_equal(out.image[out.body_mask], np.tile(want_b, (out.body_mask.sum(), 1)))
    assert out.image.dtype == np.uint8 and np.all(out.image[~(out.body_mask | out.garment_mask)] == 0)
    # depth: the nearest surface; each layer alone keeps its own (the body behind the garment too)
    assert np.allclose(out.depth[out.garment_mask], 2.8) and np.allclose(out.depth[out.body_mask], 3.0)
    assert np.allclose(out.body_depth[out.garment_mask], 3.0) and np.allclose(out.garment_depth[out.garment_mask], 2.8)
    assert np.all(out.garment_depth[out.body_mask] == 0) and np.all(out.depth[~out.body_mask & ~out.garment_mask] == 0)


def test_body_in_front_of_the_garment_hides_it():
    """An arm across the chest: a body quad nearer the camera than the garment covers it."""
    wall_V, wall_F = quad(0.5, 0.0)
    arm_V, arm_F = quad(0.1, 0.5)
    body_V, body_F = np.vstack([wall_V, arm_V]), np.vstack([wall_F, arm_F + 4])
    g = garment_quad()
    out = gr.render_garment(body_V, body_F, g, g.vertices, camera(), LIGHT)
    arm = np.zeros((40, 40), bool)
    arm[20 - 4:20 + 4, 20 - 4:20 + 4] = True  # +-0.1 m at 2.5 m -> +-4 px
    assert np.array_equal(out.body_mask & arm, arm) and not (out.garment_mask & arm).any()
    assert out.garment_mask.sum() == 14 * 14 - 8 * 8
    assert np.allclose(out.depth[arm], 2.5) and np.allclose(out.garment_depth[arm], 2.8)


def test_render_garment_body_albedo_background_and_refusals():
    body_V, body_F = quad(0.5, 0.0)
    g = garment_quad()
    bg = np.zeros((40, 40, 3), np.uint8)
    bg[..., 1] = 77
    albedo = np.tile([0.3, 0.6, 0.9], (4, 1))
    out = gr.render_garment(body_V, body_F, g, g.vertices + [0.0, 0.0, 0.0], camera(), LIGHT, background=bg,
                            body_albedo=albedo)
    empty = ~(out.body_mask | out.garment_mask)
    assert np.all(out.image[empty] == [0, 77, 0])
    want_b = np.round(lit([0.3, 0.6, 0.9]) * 255)
    assert np.array_equal(out.image[out.body_mask], np.tile(want_b, (out.body_mask.sum(), 1)))
    assert bg[..., 1].max() == 77 and bg[..., 0].max() == 0  # the caller's background is not written to
    # a bright light saturates at 255 instead of wrapping
    hot = Lighting([[0, 0, 1.0]], [[3.0, 3.0, 3.0]], [0, 0, 0])
    assert np.all(gr.render_garment(body_V, body_F, g, g.vertices, camera(), hot).image[out.body_mask] == 255)
    with pytest.raises(InputError, match=exact("posed garment vertices must be (4, 3), got (3, 3)")):
        gr.render_garment(body_V, body_F, g, g.vertices[:3], camera(), LIGHT)
    with pytest.raises(InputError, match=exact("background must be (40, 40, 3) for camera c, got (40, 41, 3)")):
        gr.render_garment(body_V, body_F, g, g.vertices, camera(), LIGHT, background=np.zeros((40, 41, 3)))


def test_render_garment_shadows_of_the_garment_on_the_body():
    body_V, body_F = quad(0.5, 0.0)
    g = garment_quad(half=0.1, z=0.25)
    light = Lighting([[0.6, 0.0, 0.8]], [[0.5, 0.5, 0.5]], [0.1, 0.1, 0.1])
    plain = gr.render_garment(body_V, body_F, g, g.vertices, camera(), light)
    shadowed = gr.render_garment(body_V, body_F, g, g.vertices, camera(), light, shadows=True)
    from bodystudio.capture.render import render

    res = render(body_V, body_F, camera())
    rows, cols = np.nonzero(plain.body_mask)
    P = gr._pixel_attributes(res, body_F, rows, cols, body_V)
    hit = P + (0.25 / 0.8) * np.array([0.6, 0.0, 0.8])
    inside = (np.abs(hit[:, :2]) < 0.09).all(1)
    outside = (np.abs(hit[:, :2]) > 0.11).any(1)
    assert inside.sum() > 10
    want = np.round(np.array(SKIN_COLOR) * 0.1 * 255)
    assert np.array_equal(shadowed.image[rows[inside], cols[inside]], np.tile(want, (inside.sum(), 1)))
    assert np.array_equal(shadowed.image[rows[outside], cols[outside]], plain.image[rows[outside], cols[outside]])
    assert np.array_equal(shadowed.image[plain.garment_mask], plain.image[plain.garment_mask])  # lit side


# ------------------------------------------------------------------------------------------ layers


def test_garment_layer_keeps_the_cloth_hidden_behind_the_body():
    wall_V, wall_F = quad(0.5, 0.0)
    arm_V, arm_F = quad(0.1, 0.5)
    body_V, body_F = np.vstack([wall_V, arm_V]), np.vstack([wall_F, arm_F + 4])
    g = garment_quad()
    layer = gr.render_garment_layer(body_V, body_F, g, g.vertices, camera(), LIGHT)
    assert layer.mask.sum() == 14 * 14  # whole, the arm's part included
    want_g = lit(np.array([200, 100, 50]) / 255.0)
    assert layer.rgb.dtype == np.float32 and np.abs(layer.rgb[layer.mask] - want_g).max() < 1e-6
    assert np.all(layer.rgb[~layer.mask] == 0)
    assert np.allclose(layer.depth[layer.mask], 2.8) and np.all(layer.depth[~layer.mask] == 0)
    # the body alone: wall and arm, skin coloured, its own depth
    assert layer.body_mask.sum() == 34 * 34
    assert layer.body_image.dtype == np.float32
    assert np.abs(layer.body_image[layer.body_mask] - lit(SKIN_COLOR)).max() < 1e-6
    assert np.all(layer.body_image[~layer.body_mask] == 0)
    arm = np.zeros((40, 40), bool)
    arm[16:24, 16:24] = True
    assert np.allclose(layer.body_depth[arm], 2.5) and np.allclose(layer.body_depth[layer.body_mask & ~arm], 3.0)
    albedo = np.tile([0.3, 0.6, 0.9], (8, 1))
    own = gr.render_garment_layer(body_V, body_F, g, g.vertices, camera(), LIGHT, body_albedo=albedo)
    assert np.abs(own.body_image[own.body_mask] - lit([0.3, 0.6, 0.9])).max() < 1e-6
    with pytest.raises(InputError, match=exact("posed garment vertices must be (4, 3), got (4, 2)")):
        gr.render_garment_layer(body_V, body_F, g, g.vertices[:, :2], camera(), LIGHT)


@pytest.mark.parametrize("flip", [False, True])
def test_garment_layer_normals_face_the_camera(flip):
    body_V, body_F = quad(0.5, 0.0)
    g = garment_quad(flip=flip)
    layer = gr.render_garment_layer(body_V, body_F, g, g.vertices, camera(), LIGHT)
    assert np.abs(layer.rgb[layer.mask] - lit(np.array([200, 100, 50]) / 255.0)).max() < 1e-6


def test_garment_layer_shadows_garment_by_body_and_body_by_itself_only():
    """A body blocker between the light and the garment shadows the garment; the garment never shadows the
    body layer (the body layer is the actor as filmed)."""
    wall_V, wall_F = quad(0.5, 0.0)
    block_V, block_F = quad(0.1, 0.6, centre=(0.3, 0.0))  # body part near the camera, off to the side
    body_V, body_F = np.vstack([wall_V, block_V]), np.vstack([wall_F, block_F + 4])
    g = garment_quad(half=0.3, z=0.2)
    light = Lighting([[0.6, 0.0, 0.8]], [[0.5, 0.5, 0.5]], [0.1, 0.1, 0.1])
    plain = gr.render_garment_layer(body_V, body_F, g, g.vertices, camera(), light)
    shad = gr.render_garment_layer(body_V, body_F, g, g.vertices, camera(), light, shadows=True)
    from bodystudio.capture.render import render

    cloth = render(g.vertices, g.faces, camera())
    rows, cols = np.nonzero(cloth.mask)
    P = gr._pixel_attributes(cloth, g.faces, rows, cols, g.vertices)
    hit = P + (0.4 / 0.8) * np.array([0.6, 0.0, 0.8])  # at the blocker's plane z = 0.6
    inside = (np.abs(hit[:, 0] - 0.3) < 0.09) & (np.abs(hit[:, 1]) < 0.09)
    outside = (np.abs(hit[:, 0] - 0.3) > 0.11) | (np.abs(hit[:, 1]) > 0.11)
    assert inside.sum() > 5
    want = np.array([200, 100, 50]) / 255.0 * 0.1
    assert np.abs(shad.rgb[rows[inside], cols[inside]] - want).max() < 1e-6
    assert np.array_equal(shad.rgb[rows[outside], cols[outside]], plain.rgb[rows[outside], cols[outside]])
    # the wall behind the garment would be in the garment's shadow, but the body layer ignores the garment;
    # the blocker's own shadow on the wall does count (the body shadows itself)
    res = render(wall_V, wall_F, camera())
    wr, wc = np.nonzero(res.mask & ~np.isclose(plain.body_depth, 2.4, atol=1e-3))
    Pw = gr._pixel_attributes(res, wall_F, wr, wc, wall_V)
    to_block = Pw + (0.6 / 0.8) * np.array([0.6, 0.0, 0.8])
    in_block = (np.abs(to_block[:, 0] - 0.3) < 0.09) & (np.abs(to_block[:, 1]) < 0.09)
    free = (np.abs(to_block[:, 0] - 0.3) > 0.11) | (np.abs(to_block[:, 1]) > 0.11)
    assert in_block.sum() > 5
    assert np.abs(shad.body_image[wr[in_block], wc[in_block]] - np.array(SKIN_COLOR) * 0.1).max() < 1e-6
    assert np.array_equal(shad.body_image[wr[free], wc[free]], plain.body_image[wr[free], wc[free]])


def test_empty_views_render_nothing():
    """A mesh behind the camera: no pixel, zero images (the shading's empty-selection branch)."""
    V, F = quad(0.5, 5.0)  # behind the camera at z = 3
    image, res = gr.render_body(V, F, camera(), LIGHT, np.full((4, 3), 0.5))
    assert not res.mask.any() and not image.any()
    g = Garment("g", V.copy(), F, np.zeros((4, 2)), np.zeros((2, 2, 3), np.uint8), np.ones((4, 1)), np.arange(4))
    out = gr.render_garment(V, F, g, g.vertices, camera(), LIGHT, shadows=True)
    assert not out.image.any() and not out.garment_mask.any() and not out.body_mask.any()
    layer = gr.render_garment_layer(V, F, g, g.vertices, camera(), LIGHT, shadows=True)
    assert not layer.mask.any() and not layer.rgb.any() and not layer.body_image.any()
    rgb, rc = gr.shade_visible_surface(res, V, F, np.zeros_like(V), camera(), LIGHT, res.mask, None)
    assert rgb.shape == (0, 3) and rc.shape == (0, 2) and rc.dtype == np.int64


# ------------------------------------------------------------------------------------------ posed, shadowed, curved


def tilt_y(V, degrees):
    t = np.radians(degrees)
    R = np.array([[np.cos(t), 0, np.sin(t)], [0, 1, 0], [-np.sin(t), 0, np.cos(t)]])
    return V @ R.T


def test_posed_garment_is_shaded_with_its_posed_normals():
    """The garment's rest pose faces the camera; posed, it is turned by 40 degrees: the shading follows the
    posed normals (cosine with the light of the turned normal), in both renderers."""
    body_V, body_F = quad(0.5, -0.5)
    g = garment_quad()
    posed = tilt_y(g.vertices, 40.0)
    n = tilt_y(np.array([[0.0, 0.0, 1.0]]), 40.0)[0]
    want = lit(np.array([200, 100, 50]) / 255.0, cos=n @ LIGHT.directions[0])
    out = gr.render_garment(body_V, body_F, g, posed, camera(), LIGHT)
    assert out.garment_mask.sum() > 50 and np.abs(out.garment_rgb[out.garment_mask] - want).max() < 1e-6
    layer = gr.render_garment_layer(body_V, body_F, g, posed, camera(), LIGHT)
    assert np.abs(layer.rgb[layer.mask] - want).max() < 1e-6


def test_a_full_white_background_stays_255():
    body_V, body_F = quad(0.1, 0.0)
    g = garment_quad(half=0.05)
    bg = np.full((40, 40, 3), 255, np.uint8)
    bg[..., 1] = 254
    out = gr.render_garment(body_V, body_F, g, g.vertices, camera(), LIGHT, background=bg)
    empty = ~(out.body_mask | out.garment_mask)
    assert np.all(out.image[empty] == [255, 254, 255])


def test_render_garment_shadows_the_garment_too():
    """A body part between the light and the garment: with ``shadows`` the garment's pixels behind it (seen from
    the light) get the ambient only."""
    wall_V, wall_F = quad(0.5, -0.3)
    block_V, block_F = quad(0.1, 0.6, centre=(0.3, 0.0))
    body_V, body_F = np.vstack([wall_V, block_V]), np.vstack([wall_F, block_F + 4])
    g = garment_quad(half=0.3, z=0.2)
    light = Lighting([[0.6, 0.0, 0.8]], [[0.5, 0.5, 0.5]], [0.1, 0.1, 0.1])
    plain = gr.render_garment(body_V, body_F, g, g.vertices, camera(), light)
    shad = gr.render_garment(body_V, body_F, g, g.vertices, camera(), light, shadows=True)
    from bodystudio.capture.render import render

    both = render(np.vstack([body_V, g.vertices]), np.vstack([body_F, g.faces + 8]), camera())
    rows, cols = np.nonzero(plain.garment_mask)
    P = gr._pixel_attributes(both, np.vstack([body_F, g.faces + 8]), rows, cols, np.vstack([body_V, g.vertices]))
    hit = P + (0.4 / 0.8) * np.array([0.6, 0.0, 0.8])
    inside = (np.abs(hit[:, 0] - 0.3) < 0.09) & (np.abs(hit[:, 1]) < 0.09)
    assert inside.sum() > 5
    want = np.round(np.array([200, 100, 50]) * 0.1)
    assert np.array_equal(shad.image[rows[inside], cols[inside]], np.tile(want, (inside.sum(), 1)))
    assert not np.array_equal(shad.image[rows[inside], cols[inside]], plain.image[rows[inside], cols[inside]])


def test_garment_layer_self_shadow_of_one_garment_part_on_another():
    """A garment of two quads, a small one in front of a large one: the front part shadows the back part in the
    layer (occluders are body and garment together)."""
    back_V, back_F = quad(0.3, 0.2)
    front_V, front_F = quad(0.08, 0.45, centre=(0.1, 0.0))
    V = np.vstack([back_V, front_V])
    F = np.vstack([back_F, front_F + 4])
    uv = np.full((8, 2), 0.5)
    texture = np.full((4, 4, 3), 200, np.uint8)
    g = Garment("two", V, F, uv, texture, np.ones((8, 1)), np.arange(8))
    body_V, body_F = quad(0.5, -0.5)
    light = Lighting([[0.6, 0.0, 0.8]], [[0.5, 0.5, 0.5]], [0.1, 0.1, 0.1])
    layer = gr.render_garment_layer(body_V, body_F, g, V, camera(), light, shadows=True)
    from bodystudio.capture.render import render

    cloth = render(V, F, camera())
    rows, cols = np.nonzero(cloth.mask & (cloth.triangle_id < 2))
    P = gr._pixel_attributes(cloth, F, rows, cols, V)
    hit = P + (0.25 / 0.8) * np.array([0.6, 0.0, 0.8])  # at the front part's plane z = 0.45
    inside = (np.abs(hit[:, 0] - 0.1) < 0.07) & (np.abs(hit[:, 1]) < 0.07)
    outside = (np.abs(hit[:, 0] - 0.1) > 0.09) | (np.abs(hit[:, 1]) > 0.09)
    assert inside.sum() > 3
    assert np.abs(layer.rgb[rows[inside], cols[inside]] - 200 / 255 * 0.1).max() < 1e-6
    assert np.abs(layer.rgb[rows[outside], cols[outside]] - 200 / 255 * (0.1 + 0.8 * 0.5)).max() < 1e-6


def tent(apex_z=0.3):
    """Four triangles from a square's corners to a raised centre: vertex normals differ within each triangle, so
    the interpolated normals are shorter than one until normalised."""
    V = np.array([[-0.3, -0.3, 0], [0.3, -0.3, 0], [0.3, 0.3, 0], [-0.3, 0.3, 0], [0, 0, apex_z]])
    F = np.array([[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]])
    return V, F


def test_interpolated_normals_are_normalised_before_shading():
    V, F = tent()
    N = gr.vertex_normals_area_weighted(V, F)
    from bodystudio.capture.render import render

    res = render(V, F, camera())
    rows, cols = np.nonzero(res.mask)
    n = gr._pixel_attributes(res, F, rows, cols, N)
    assert np.linalg.norm(n, axis=1).min() < 0.95  # the case the normalisation is for
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    want = lit(np.array([0.5, 0.5, 0.5]), cos=np.clip(n @ LIGHT.directions[0], 0, None)[:, None])
    image, _ = gr.render_body(V, F, camera(), LIGHT, np.full((5, 3), 0.5))
    assert np.abs(image[rows, cols] - want).max() < 1e-6
    g = Garment("tent", V, F, np.full((5, 2), 0.5), np.full((4, 4, 3), 255, np.uint8), np.ones((5, 1)), np.arange(5))
    body_V, body_F = quad(0.5, -0.5)
    layer = gr.render_garment_layer(body_V, body_F, g, V, camera(), LIGHT)
    n_g = gr._pixel_attributes(res, F, rows, cols, g.normals())
    n_g /= np.linalg.norm(n_g, axis=1, keepdims=True)
    want_layer = lit(np.ones(3), cos=np.clip(n_g @ LIGHT.directions[0], 0, None)[:, None])
    assert np.abs(layer.rgb[rows, cols] - want_layer).max() < 1e-6


@pytest.mark.parametrize("degrees", [75.0, 80.0])
def test_normals_seen_at_a_grazing_angle_are_still_turned_to_the_camera(degrees):
    """A plane wound away from the camera and turned by 75-80 degrees: n . (P - C) is between 0 and 1 m, and the
    normal must still be flipped (the test is the sign, not a threshold)."""
    V, F = quad(0.5, 0.0, flip=True)
    V = tilt_y(V, degrees)
    image, res = gr.render_body(V, F, camera(), LIGHT, np.full((4, 3), 0.6))
    n = tilt_y(np.array([[0.0, 0.0, 1.0]]), degrees)[0]
    assert res.mask.sum() > 10
    assert np.abs(image[res.mask] - lit([0.6, 0.6, 0.6], cos=max(n @ LIGHT.directions[0], 0))).max() < 1e-6
    g = garment_quad(half=0.5, z=0.0, flip=True)
    layer = gr.render_garment_layer(*quad(0.1, -1.0), g, tilt_y(g.vertices, degrees), camera(), LIGHT)
    want = lit(np.array([200, 100, 50]) / 255.0, cos=max(n @ LIGHT.directions[0], 0))
    assert np.abs(layer.rgb[layer.mask] - want).max() < 1e-6
