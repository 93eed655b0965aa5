"""Cameras: projection against OpenCV, project/unproject round trips, cameras.json I/O, layouts."""

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bodystudio.errors import FileFormatError, InputError
from bodystudio.geometry.camera import (
    Camera,
    CameraRig,
    kinect_v1,
    kinect_v2,
    load_cameras_json,
    ring_rig,
    save_cameras_json,
)


def _random_camera(rng, dist_scale=1.0):
    eye = rng.uniform(-3, 3, 3) + np.array([0, 1, 0])
    eye[2] += 4.0
    target = rng.uniform(-0.3, 0.3, 3) + np.array([0, 0.9, 0])
    dist = np.array([-0.1, 0.03, 0.001, -0.001, -0.005]) * dist_scale
    return Camera.look_at("c", eye, target, fx=rng.uniform(400, 900), width=640, height=480, dist=dist)


def test_project_matches_cv2_projectpoints():
    rng = np.random.default_rng(0)
    for _ in range(5):
        cam = _random_camera(rng)
        P = rng.uniform(-0.5, 0.5, (200, 3)) + np.array([0, 0.9, 0])
        rvec, _ = cv2.Rodrigues(cam.R)
        ref, _ = cv2.projectPoints(P, rvec, cam.t, cam.K, cam.dist)
        np.testing.assert_allclose(cam.project(P), ref.reshape(-1, 2), atol=1e-8)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), scale=st.floats(0.0, 1.5))
def test_project_unproject_round_trip(seed, scale):
    rng = np.random.default_rng(seed)
    cam = _random_camera(rng, scale)
    P = rng.uniform(-0.6, 0.6, (50, 3)) + np.array([0, 0.9, 0])
    uv, z = cam.project_with_depth(P)
    np.testing.assert_allclose(cam.unproject(uv, z), P, atol=1e-7)
    origins, dirs = cam.rays(uv)
    np.testing.assert_allclose(np.linalg.norm(dirs, axis=1), 1.0, atol=1e-12)
    # the ray through the projection passes through the point
    along = np.einsum("ij,ij->i", P - origins, dirs)
    np.testing.assert_allclose(origins + along[:, None] * dirs, P, atol=1e-7)


def test_look_at_orientation_and_center():
    cam = Camera.look_at("front", eye=(0, 1, 3), target=(0, 1, 0), fx=500)
    np.testing.assert_allclose(cam.center, [0, 1, 3], atol=1e-12)
    uv = cam.project(np.array([[0, 1, 0], [0.5, 1, 0], [0, 1.5, 0]]))
    np.testing.assert_allclose(uv[0], [319.5, 239.5], atol=1e-9)
    assert uv[1, 0] > uv[0, 0]  # world +x is image right when looking towards -z
    assert uv[2, 1] < uv[0, 1]  # world up is image up


def test_frustum_corners_project_to_image_corners():
    cam = _random_camera(np.random.default_rng(3))
    corners = cam.frustum(0.5, 4.0)
    uv, z = cam.project_with_depth(corners)
    np.testing.assert_allclose(z, [0.5] * 4 + [4.0] * 4, atol=1e-9)
    expected = np.array([[0, 0], [640, 0], [640, 480], [0, 480]], float)
    np.testing.assert_allclose(uv, np.r_[expected, expected], atol=1e-5)


def test_cameras_json_round_trip_and_errors(tmp_path):
    rig = ring_rig(4)
    path = tmp_path / "cameras.json"
    save_cameras_json(path, rig)
    back = load_cameras_json(path)
    assert back.names == rig.names
    P = np.random.default_rng(1).uniform(-0.3, 0.3, (20, 3)) + [0, 1, 0]
    np.testing.assert_allclose(back.project(P), rig.project(P), atol=1e-12)
    bad = tmp_path / "bad.json"
    bad.write_text('{"version": 1, "cameras": {"cam_00": {"K": [[1,0,0],[0,1,0],[0,0,1]]}}}')
    with pytest.raises(FileFormatError, match="bad.json"):
        load_cameras_json(bad)
    with pytest.raises(FileFormatError, match="missing.json"):
        load_cameras_json(tmp_path / "missing.json")
    with pytest.raises(InputError):
        Camera("x", np.eye(3), np.zeros(5), np.diag([1.0, 1.0, -1.0]), np.zeros(3), 10, 10)


def test_ring_rig_sees_the_capture_volume():
    rig = ring_rig(10)
    assert len(rig) == 10 and rig.names[0] == "cam_00" and isinstance(rig, CameraRig)
    # corners of a 2 m diameter, 2.1 m tall volume around the subject project inside every image
    ang = np.linspace(0, 2 * np.pi, 16, endpoint=False)
    pts = np.array([[np.cos(a) * 0.6, y, np.sin(a) * 0.6] for a in ang for y in (0.0, 2.0)])
    uv = rig.project(pts)
    for cam, uvc in zip(rig, uv, strict=True):
        assert cam.in_image(uvc).all(), cam.name
    radii = np.linalg.norm(rig.centers()[:, [0, 2]], axis=1)
    np.testing.assert_allclose(radii, 3.0)


@pytest.mark.parametrize("sensor", [kinect_v2(), kinect_v1("640x480"), kinect_v1("320x240")])
def test_kinect_sensors_face_the_subject(sensor):
    chest = np.array([[0.0, 1.2, 0.1]])
    for cam in (sensor.depth, sensor.color):
        uv, z = cam.project_with_depth(chest)
        assert cam.in_image(uv).all() and 2.0 < z[0] < 3.0
    # the depth->colour extrinsic maps depth-camera points to colour-camera points
    Pd = sensor.depth.world_to_camera(chest)
    Pc = (sensor.depth_to_color[:3, :3] @ Pd.T).T + sensor.depth_to_color[:3, 3]
    np.testing.assert_allclose(Pc, sensor.color.world_to_camera(chest), atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(sensor.projector.center - sensor.depth.center), sensor.baseline_m)
