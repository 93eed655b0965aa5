"""Kinect depth constraints: cleaning, projective association and point-to-plane pull (our extension)."""

import numpy as np
import pytest

from bodystudio.capture.render import render_depth
from bodystudio.errors import InputError
from bodystudio.geometry.camera import Camera
from bodystudio.geometry.mesh import vertex_normals
from bodystudio.reconstruct.depth import depth_constraints, depth_observation
from bodystudio.reconstruct.rapid_skin import RapidSkinParams, deform_to_observations


@pytest.fixture(scope="module")
def sphere_scene():
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=4, radius=0.30)
    V = np.asarray(m.vertices, float) + [0.0, 1.0, 0.0]
    F = np.asarray(m.faces, np.int64)
    cam = Camera.look_at("depth", (0.0, 1.0, 2.5), (0.0, 1.0, 0.0), fx=365.0, width=256, height=212)
    V_gt = (V - [0.0, 1.0, 0.0]) * (0.32 / 0.30) + [0.0, 1.0, 0.0]
    D = render_depth(V_gt, F, cam).astype(np.float64)
    D[100:104, 100:104] = 9.0  # out of range
    assert D[110, 120] > 0
    D[110, 120] -= 0.2  # a flying pixel
    return V, F, cam, V_gt, D


def test_observation_is_cleaned_and_in_the_studio_frame(sphere_scene):
    V, F, cam, V_gt, D = sphere_scene
    obs = depth_observation(D, cam)
    assert obs.n_points > 5000
    assert not obs.valid[101, 101] and not obs.valid[110, 120]
    r = np.linalg.norm(obs.points[obs.valid] - [0.0, 1.0, 0.0], axis=1)
    assert np.all(np.abs(r - 0.32) < 0.004)  # points lie on the rendered sphere
    n = obs.normals[obs.valid]
    radial = (obs.points[obs.valid] - [0.0, 1.0, 0.0]) / r[:, None]
    assert np.median(np.sum(n * radial, axis=1)) > 0.99
    with pytest.raises(InputError, match="mismatch"):
        depth_observation(D[:100], cam)


def test_depth_constraints_pull_the_front_onto_the_surface(sphere_scene):
    V, F, cam, V_gt, D = sphere_scene
    obs = depth_observation(D, cam)
    dep = depth_constraints(V, vertex_normals(V, F), obs)
    assert len(dep) > 300
    # only vertices facing the sensor
    assert np.all(V[dep.vertex, 2] > 0.0)
    result = deform_to_observations(V, F, [cam], None, RapidSkinParams(constraints=("depth",)), depth=obs)
    front = V[:, 2] > 0.2
    before = np.abs(np.linalg.norm(V[front] - [0, 1, 0], axis=1) - 0.32)
    after = np.abs(np.linalg.norm(result.vertices[front] - [0, 1, 0], axis=1) - 0.32)
    assert np.median(before) > 0.019
    assert np.median(after) < 0.004
