"""Garment rendering: texture lookup, Lambert shading with the estimated lights, the depth buffer, shadows."""

import numpy as np
import pytest

from bodystudio.body import Pose
from bodystudio.garment import garments as gm
from bodystudio.garment.lighting import Lighting
from bodystudio.garment.render import lambert_radiance, render_garment
from bodystudio.geometry.camera import Camera


@pytest.fixture(scope="module")
def arm_across_chest(garment_body):
    from bodystudio.capture.motion import world_to_local_rotvecs

    world = np.zeros((garment_body.skeleton.n_bones, 3))
    world[garment_body.skeleton.index("upperarm_r")] = (-0.6, 0.0, 0.8)
    world[garment_body.skeleton.index("lowerarm_r")] = (0.0, 1.6, 0.0)
    return Pose(world_to_local_rotvecs(garment_body.skeleton, world), np.zeros(3))


@pytest.fixture(scope="module")
def camera():
    return Camera.look_at("front", (0.0, 1.2, 2.5), (0, 1.1, 0), fx=500, width=240, height=320)


def test_lambert_radiance_is_eq7s_model():
    n = np.array([[0, 0, 1.0], [0, 1.0, 0], [0, 0, -1.0]])
    light = Lighting([[0, 0, 1.0], [0, 1, 1.0]], [[0.5, 0.5, 0.5], [0.2, 0.4, 0.0]], [0.1, 0.1, 0.1])
    albedo = np.array([[1.0, 0.5, 0.2]] * 3)
    got = lambert_radiance(n, albedo, light)
    c = np.sqrt(0.5)
    want = albedo * np.array([[0.1 + 0.5 + 0.2 * c, 0.1 + 0.5 + 0.4 * c, 0.1 + 0.5],
                              [0.1 + 0.2 * c, 0.1 + 0.4 * c, 0.1],
                              [0.1, 0.1, 0.1]])
    assert np.allclose(got, want)


def test_unlit_render_shows_the_texture(garments, garment_body, camera):
    g = garments["tshirt"]
    flat = Lighting(np.zeros((0, 3)), np.zeros((0, 3)), [1.0, 1.0, 1.0])
    r = render_garment(garment_body.vertices, garment_body.faces, g, g.vertices, camera, flat)
    assert r.garment_mask.sum() > 2000
    # each garment pixel shows the stripe colour of its rest-pose surface point (rest pose rendered)
    from bodystudio.capture.render import render

    res = render(g.vertices, g.faces, camera)
    P, rc = res.surface_points(g.vertices, g.faces)
    vis = r.garment_mask[rc[:, 0], rc[:, 1]]
    want = gm.cloth_pattern(P[vis], "stripes", gm.cloth_colors(0))
    got = r.image[rc[vis, 0], rc[vis, 1]] / 255.0
    agree = np.mean(np.abs(got - want).max(1) < 0.1)
    assert agree > 0.85, agree  # measured 0.92 (stripe borders blur over a texel)
    assert np.array_equal(np.round(r.garment_rgb[r.garment_mask] * 255), r.image[r.garment_mask].astype(float))


def test_depth_buffer_keeps_an_arm_in_front_of_the_shirt(garments, garment_body, camera, arm_across_chest):
    g = garments["tshirt"]
    Vb, _ = garment_body.pose(arm_across_chest)
    Vg = gm.pose_garment(g, garment_body, arm_across_chest)
    light = Lighting.single((0.3, 0.6, 1.0), 0.7, 0.3)
    r = render_garment(Vb, garment_body.faces, g, Vg, camera, light)
    both = (r.garment_depth > 0) & (r.body_depth > 0)
    arm_in_front = both & (r.body_depth < r.garment_depth - 0.01)
    assert arm_in_front.sum() > 800  # the forearm covers part of the chest: 1195 pixels
    assert not (r.garment_mask & arm_in_front).any()
    shirt_in_front = both & (r.garment_depth < r.body_depth - 0.001)
    assert np.mean(r.garment_mask[shirt_in_front]) > 0.995
    assert np.array_equal(r.garment_mask | r.body_mask, r.depth > 0)
    # the composited depth is the nearer of the two layers
    near = np.where(r.garment_depth > 0, r.garment_depth, np.inf)
    near = np.minimum(near, np.where(r.body_depth > 0, r.body_depth, np.inf))
    assert np.allclose(r.depth[r.depth > 0], near[r.depth > 0], atol=1e-5)


def test_cast_shadows_only_darken(garments, garment_body, camera, arm_across_chest):
    g = garments["tshirt"]
    Vb, _ = garment_body.pose(arm_across_chest)
    Vg = gm.pose_garment(g, garment_body, arm_across_chest)
    light = Lighting.single((0.0, 1.0, 0.5), 0.8, 0.2)  # from above: arm and sleeves shadow the shirt
    lit = render_garment(Vb, garment_body.faces, g, Vg, camera, light)
    shadowed = render_garment(Vb, garment_body.faces, g, Vg, camera, light, shadows=True)
    diff = shadowed.image.astype(int) - lit.image.astype(int)
    assert diff.max() <= 0
    in_shadow = (diff.sum(2) < -30) & shadowed.garment_mask
    assert in_shadow.sum() > 1000  # measured 1494 pixels
