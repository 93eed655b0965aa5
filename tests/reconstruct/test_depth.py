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


@pytest.fixture(scope="module")
def far_front_scene():
    """A template sphere (r 0.30 m) whose body is 7 cm bigger (r 0.37 m), beyond the default pairing distance
    (5 cm) and the observation-side occlusion margin (4 cm), with a 'limb' sphere in front of both that the
    template has too; one depth sensor in front."""
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=4, radius=1.0)
    S, Fs = np.asarray(m.vertices, float), np.asarray(m.faces, np.int64)
    centre, limb_c, limb_r = np.array([0.0, 1.0, 0.0]), np.array([0.0, 1.0, 0.44]), 0.06
    V = np.vstack([S * 0.30 + centre, S * limb_r + limb_c])
    F = np.vstack([Fs, Fs + len(S)])
    V_gt = np.vstack([S * 0.37 + centre, S * limb_r + limb_c])
    cam = Camera.look_at("depth", (0.0, 1.0, 2.5), (0.0, 1.0, 0.0), fx=365.0, width=256, height=212)
    obs = depth_observation(render_depth(V_gt, F, cam).astype(np.float64), cam)
    return V, F, len(S), obs


def test_depth_reach_pulls_a_front_the_default_pairing_cannot(far_front_scene):
    """Issue 15: the largest errors of the surface the sensor sees (a chest 5 cm inside the body) got no depth
    pair at all; with ``depth_reach_m`` (default 10 cm) the template's own front surface pairs up to 10 cm."""
    V, F, n_torso, obs = far_front_scene
    front = np.zeros(len(V), bool)
    front[:n_torso] = (V[:n_torso, 2] > 0.24) & (np.hypot(V[:n_torso, 0], V[:n_torso, 1] - 1.0) > 0.12)

    def front_error_mm(V_out):
        return 1000 * np.abs(np.linalg.norm(V_out[front] - [0.0, 1.0, 0.0], axis=1) - 0.37)

    old = deform_to_observations(V, F, [obs.camera], None, RapidSkinParams(constraints=("depth",), depth_reach_m=0.0),
                                 depth=obs)
    new = deform_to_observations(V, F, [obs.camera], None, RapidSkinParams(constraints=("depth",)), depth=obs)
    assert np.median(front_error_mm(old.vertices)) > 60.0  # measured 70 mm: nothing pairs
    assert np.median(front_error_mm(new.vertices)) < 5.0  # measured 0.6 mm (p90 1.6 mm)


def test_depth_reach_never_pairs_a_vertex_its_own_limb_hides(far_front_scene):
    """The far pairs take visibility from the template's own depth raster: the torso behind the template's
    limb must not be pulled onto the limb's surface (which the observation-side test would allow once the
    pairing reaches past the gap)."""
    from bodystudio.reconstruct.depth import model_front_vertices

    V, F, n_torso, obs = far_front_scene
    N = vertex_normals(V, F)
    dep = depth_constraints(V, N, obs, F=F, reach_m=0.20)
    cam = obs.camera
    uv, z = cam.project_with_depth(V)
    px = np.round(uv).astype(np.int64)
    behind_limb = np.zeros(len(V), bool)
    behind_limb[:n_torso] = (np.hypot(V[:n_torso, 0], V[:n_torso, 1] - 1.0) < 0.04) & (V[:n_torso, 2] > 0.25)
    assert behind_limb.sum() >= 3
    assert not model_front_vertices(V, F, cam, z[behind_limb], px[behind_limb]).any()
    assert not np.isin(np.flatnonzero(behind_limb), dep.vertex).any()
    # the limb's own front and the torso around it do pair
    assert np.isin(np.arange(n_torso, len(V)), dep.vertex).sum() > 20
    assert np.isin(np.flatnonzero(~behind_limb[:n_torso] & (V[:n_torso, 2] > 0.2)), dep.vertex).sum() > 100
