"""Garment fixtures: one 2k body and its garments, built once per session."""

import pytest


@pytest.fixture(scope="session")
def garment_body():
    from bodystudio.body import build_body

    return build_body(resolution="2k")


@pytest.fixture(scope="session")
def garments(garment_body):
    from bodystudio.garment.garments import dress

    return {name: dress(garment_body, name, pattern, texture_size=256)
            for name, pattern in (("tights", "checks"), ("skirt", "print"), ("tshirt", "stripes"),
                                  ("longsleeve", "plain"))}


def make_lit_scene(body, shadows: bool):
    """A posed body with a three-colour albedo under one known light (0.8) + ambient 0.25, 240x320 front view."""
    import numpy as np

    from bodystudio.body import Pose
    from bodystudio.garment.lighting import Lighting
    from bodystudio.garment.render import render_body
    from bodystudio.geometry.camera import Camera

    y = body.vertices[:, 1]
    albedo = np.tile([0.8, 0.6, 0.5], (body.n_vertices, 1))
    albedo[y < 0.9] = [0.3, 0.4, 0.7]
    albedo[(y > 0.95) & (y < 1.4)] = [0.7, 0.7, 0.7]
    rot = np.zeros((body.skeleton.n_bones, 3))
    rot[body.skeleton.index("upperarm_l")] = (0, 0, -0.4)
    rot[body.skeleton.index("lowerarm_r")] = (0.9, 0, 0)
    V, _ = body.pose(Pose(rot, np.zeros(3)))
    cam = Camera.look_at("front", (0.3, 1.2, 3.0), (0, 0.9, 0), fx=350, width=240, height=320)
    direction = np.array([0.5, 0.7, 0.5]) / np.linalg.norm([0.5, 0.7, 0.5])
    light = Lighting.single(direction, 0.8, 0.25)
    image, _ = render_body(V, body.faces, cam, light, albedo, shadows=shadows)
    return {"V": V, "F": body.faces, "camera": cam, "light": light, "albedo": albedo,
            "image": np.clip(np.round(image * 255), 0, 255).astype(np.uint8)}


@pytest.fixture(scope="session")
def lit_scene(garment_body):
    return make_lit_scene(garment_body, shadows=False)


@pytest.fixture(scope="session")
def shadowed_scene(garment_body):
    return make_lit_scene(garment_body, shadows=True)
