"""geometry/camera.py against independent references: OpenCV's own projection (cv2.projectPoints with K = I for
the normalised distortion), the Brown-Conrady and pinhole formulas written out per point, central finite
differences for the Jacobians, the cameras.json entries and refusals word for word, and the published sensor
numbers. Every stage projects through this module. No fixture is expensive; the file runs in about a second.
"""

import json
import warnings

import cv2
import numpy as np
import pytest

from bodystudio.errors import FileFormatError, InputError
from bodystudio.geometry import camera as cm
from bodystudio.geometry.camera import Camera, CameraRig

K0 = np.array([[520.0, 0.0, 300.0], [0.0, 480.0, 250.0], [0.0, 0.0, 1.0]])
R0 = cv2.Rodrigues(np.array([0.2, -0.35, 0.1]))[0]
T0 = np.array([0.1, -0.4, 3.0])
DIST = np.array([-0.21, 0.07, 0.0013, -0.0021, -0.012])
XY = np.array([[0.31, -0.22], [-0.45, 0.12], [0.05, 0.4], [0.0, 0.0], [-0.3, -0.35]])


def cv2_distort(xy, dist):
    """OpenCV's distortion of normalised points: projectPoints of (x, y, 1) with K = I and no rotation."""
    P = np.c_[xy, np.ones(len(xy))]
    out, _ = cv2.projectPoints(P, np.zeros(3), np.zeros(3), np.eye(3), np.asarray(dist, float))
    return out.reshape(-1, 2)


def brown_conrady(x, y, k1, k2, p1, p2, k3):
    """The Brown-Conrady model as OpenCV documents it, one point at a time."""
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2 ** 2 + k3 * r2 ** 3
    return x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x), y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y


@pytest.mark.parametrize("which", range(6))
def test_distortion_is_opencvs_term_by_term(which):
    dist = DIST if which == 5 else np.eye(5)[which] * DIST[which] * 10  # each coefficient alone, then all
    got = cm.distort_normalized(XY, dist)
    np.testing.assert_allclose(got, cv2_distort(XY, dist), rtol=0, atol=1e-12)
    np.testing.assert_allclose(got, [brown_conrady(x, y, *dist) for x, y in XY], rtol=0, atol=1e-14)
    assert got.shape == (len(XY), 2)


@pytest.mark.parametrize("which", range(6))
def test_distortion_jacobian_is_the_central_difference_of_opencvs_distortion(which):
    dist = DIST if which == 5 else np.eye(5)[which] * DIST[which] * 10
    J = cm._distortion_jacobian(XY, dist)
    h = 1e-6
    for c in range(2):
        step = np.zeros(2)
        step[c] = h
        fd = (cv2_distort(XY + step, dist) - cv2_distort(XY - step, dist)) / (2 * h)
        np.testing.assert_allclose(J[:, :, c], fd, atol=1e-8)


def test_pinhole_projection_jacobian_is_the_central_difference_of_fx_x_over_z():
    cam = Camera("c", K0, DIST, R0, T0, 640, 480)  # distortion is left out by design
    rng = np.random.default_rng(2)
    V0, J = rng.normal(size=(6, 3)) * 0.3, rng.normal(size=(6, 3, 4))
    V0[:, 2] += 0.5

    def pixels(p):
        Pc = (V0 + np.einsum("nik,k->ni", J, p)) @ R0.T + T0
        return np.c_[K0[0, 0] * Pc[:, 0] / Pc[:, 2], K0[1, 1] * Pc[:, 1] / Pc[:, 2]]  # cx, cy do not move

    got = cm.pinhole_projection_jacobian(cam, V0, J)
    assert got.shape == (6, 2, 4)
    h = 1e-6
    for k in range(4):
        e = np.eye(4)[k] * h
        np.testing.assert_allclose(got[:, :, k], (pixels(e) - pixels(-e)) / (2 * h), rtol=1e-7, atol=1e-5)


def _camera(dist=DIST, K=K0, name="c"):
    return Camera(name, K, dist, R0, T0, 640, 480)


def test_camera_stores_read_only_float64_arrays_and_int_sizes():
    whole = Camera("w", K0.astype(int).tolist(), [0, 0, 0, 0, 1], np.eye(3, dtype=int), [[1], [2], [3]], 640, 480)
    for a in (whole.K, whole.dist, whole.R, whole.t):
        assert a.dtype == np.float64
    cam = Camera("c", K0.astype(int).tolist(), None, R0.tolist(), T0.reshape(3, 1).tolist(), 640.0, np.int32(480))
    assert cam.dist.tolist() == [0.0] * 5 and not cam.has_distortion
    for a in (cam.K, cam.dist, cam.R, cam.t):
        assert a.dtype == np.float64 and not a.flags.writeable
    assert cam.t.shape == (3,) and cam.K[0, 0] == 520.0
    assert type(cam.width) is int and type(cam.height) is int and cam.image_size == (640, 480)
    assert type(cam.fx) is float and (cam.fx, cam.fy) == (520.0, 480.0)
    assert _camera().has_distortion and _camera(dist=[0, 0, 0, 0, 1e-9]).has_distortion
    assert type(_camera().has_distortion) is bool
    d = _camera(dist=np.array([[0.1, 0, 0, 0, 0]])).dist  # a (1, 5) row is raveled
    assert d.shape == (5,)


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"K": np.eye(2)}, "camera c: K must be 3x3, got (2, 2)"),
    ({"dist": np.zeros(4)}, "camera c: dist must have 5 entries (k1 k2 p1 p2 k3), got (4,)"),
    ({"R": np.eye(4)}, "camera c: R must be 3x3 and t 3-vector, got (4, 4), (3,)"),
    ({"t": np.zeros(2)}, "camera c: R must be 3x3 and t 3-vector, got (3, 3), (2,)"),
    ({"R": np.diag([1.0, 1.0, -1.0])}, "camera c: R is not a rotation matrix (R R^T != I or det < 0)"),
    ({"R": [[1, 1.5e-6, 0], [0, 1, 0], [0, 0, 1]]}, "camera c: R is not a rotation matrix (R R^T != I or det < 0)"),
    ({"width": 0}, "camera c: image size must be positive, got 0x480"),
    ({"height": -1}, "camera c: image size must be positive, got 640x-1"),
    ({"height": 0}, "camera c: image size must be positive, got 640x0"),
    ({"K": np.where(np.eye(3) == 1, np.inf, 0)}, "camera c: K has non-finite entries"),
    ({"dist": [0, np.nan, 0, 0, 0]}, "camera c: dist has non-finite entries"),
    ({"t": [0, 0, np.inf]}, "camera c: t has non-finite entries"),
])
def test_camera_refusals_word_for_word(kwargs, message):
    args = {"name": "c", "K": K0, "dist": DIST, "R": np.eye(3), "t": np.zeros(3), "width": 640, "height": 480}
    with pytest.raises(InputError) as exc:
        Camera(**{**args, **kwargs})
    assert str(exc.value) == message


def test_a_rotation_off_by_rounding_is_accepted():
    Camera("c", K0, None, np.eye(3) * (1 + 2e-7), np.zeros(3), 640, 480)
    Camera("c", K0, None, [[1, 5e-7, 0], [0, 1, 0], [0, 0, 1]], np.zeros(3), 640, 480)
    Camera("c", K0, None, np.eye(3), np.zeros(3), 1, 1)


def test_centre_extrinsic_and_frame_changes_by_hand():
    cam = _camera()
    np.testing.assert_allclose(cam.center, -R0.T @ T0, atol=1e-15)
    assert cam.center.shape == (3,)
    E = cam.extrinsic
    assert E.shape == (4, 4) and E[3].tolist() == [0, 0, 0, 1]
    np.testing.assert_array_equal(E[:3, :3], R0)
    np.testing.assert_array_equal(E[:3, 3], T0)
    P = np.array([[0.3, 1.2, -0.4], [1.0, 0.0, 2.0]])
    Pc = np.array([R0 @ p + T0 for p in P])
    np.testing.assert_allclose(cam.world_to_camera(P), Pc, atol=1e-15)
    np.testing.assert_allclose(cam.world_to_camera(P[0]), Pc[:1], atol=1e-15)  # one point (3,) -> (1, 3)
    np.testing.assert_allclose(cam.camera_to_world(Pc), P, atol=1e-14)
    np.testing.assert_allclose(cam.camera_to_world(Pc[1].tolist()), P[1:], atol=1e-14)
    np.testing.assert_allclose(cam.world_to_camera(cam.center), 0.0, atol=1e-15)


def pixels_by_hand(cam, P):
    """Pixels of world points, the module docstring's formula written out (skew s = K[0, 1])."""
    out = []
    for p in P:
        x, y, z = cam.R @ p + cam.t
        xd, yd = brown_conrady(x / z, y / z, *cam.dist)
        out.append([cam.K[0, 0] * xd + cam.K[0, 1] * yd + cam.K[0, 2], cam.K[1, 1] * yd + cam.K[1, 2]])
    return np.array(out)


def test_projection_with_skew_distortion_and_points_behind_the_camera():
    K = K0.copy()
    K[0, 1] = 3.5
    cam = _camera(K=K)
    rng = np.random.default_rng(1)
    P = cam.camera_to_world(np.c_[rng.uniform(-0.8, 0.8, (12, 2)), rng.uniform(1.0, 4.0, 12)])
    uv, z = cam.project_with_depth(P)
    np.testing.assert_allclose(uv, pixels_by_hand(cam, P), atol=1e-9)
    np.testing.assert_allclose(z, cam.world_to_camera(P)[:, 2], atol=1e-15)
    np.testing.assert_array_equal(cam.project(P), uv)
    # without distortion: K times (x / z, y / z)
    plain = _camera(dist=None, K=K)
    np.testing.assert_allclose(plain.project(P), pixels_by_hand(plain, P), atol=1e-9)
    # behind the camera and on its plane: NaN pixels, the depth kept
    back = cam.camera_to_world([[0.1, 0.2, -1.5], [0.3, 0.1, 0.0], [0.0, 0.0, 1e-3]])
    uv, z = cam.project_with_depth(back)
    assert np.isnan(uv[:2]).all() and np.isfinite(uv[2]).all()
    np.testing.assert_allclose(z, [-1.5, 0.0, 1e-3], atol=1e-12)
    uv, z = plain.project_with_depth(back)
    assert np.isnan(uv[:2]).all() and np.isfinite(uv[2]).all()
    # a point on the camera's plane (x / 0) and at its centre (0 / 0): NaN pixels without a numpy warning
    at_origin = [Camera("o", K0, d, np.eye(3), np.zeros(3), 640, 480) for d in (None, DIST)]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for c in at_origin:
            assert np.isnan(c.project([[0.3, 0.1, 0.0], [0.0, 0.0, 0.0]])).all()


def test_undistortion_inverts_the_distortion_to_the_pinhole_pixels():
    strong = np.array([-0.4, 0.25, 0.004, -0.003, -0.08])  # cv2's fixed point alone stalls in the corners
    cam = Camera("c", K0, strong, np.eye(3), np.zeros(3), 640, 480)
    # out to the corners, where cv2's fixed point alone stops up to 5e-7 short (Newton steps finish it)
    xy = np.array([[x, y] for x in np.linspace(-0.9, 0.9, 13) for y in np.linspace(-0.8, 0.8, 9)])
    for d in (strong, np.array([0.3, 0.2, 0.01, -0.01, 0.1])):  # barrel, then pincushion
        cam = Camera("c", K0, d, np.eye(3), np.zeros(3), 640, 480)
        uv = np.array([brown_conrady(x, y, *d) for x, y in xy]) @ K0[:2, :2].T + K0[:2, 2]
        np.testing.assert_allclose(cam.undistort_points(uv, normalized=True), xy, rtol=0, atol=1e-12)
        np.testing.assert_allclose(cam.undistort_points(uv), xy @ K0[:2, :2].T + K0[:2, 2], rtol=0, atol=1e-9)
    cam = Camera("c", K0, strong, np.eye(3), np.zeros(3), 640, 480)
    uv = np.array([brown_conrady(x, y, *strong) for x, y in xy]) @ K0[:2, :2].T + K0[:2, 2]
    whole = np.round(uv[:5]).astype(int)  # whole pixel numbers are pixels too
    np.testing.assert_allclose(cam.undistort_points(whole), cam.undistort_points(whole.astype(float)), atol=1e-12)
    assert cam.undistort_points(uv[0]).shape == (1, 2)
    assert cam.undistort_points(np.zeros((0, 2))).shape == (0, 2)
    # no distortion: the same pixels (a copy) or K^-1 (u, v, 1)
    plain = Camera("c", K0, None, np.eye(3), np.zeros(3), 640, 480)
    assert plain.undistort_points(whole).dtype == np.float64
    np.testing.assert_array_equal(plain.undistort_points(whole), whole)
    same = plain.undistort_points(uv)
    np.testing.assert_array_equal(same, uv)
    same[0] = -1
    assert uv[0, 0] != -1
    np.testing.assert_allclose(plain.undistort_points(uv, normalized=True),
                               np.c_[(uv[:, 0] - 300.0) / 520.0, (uv[:, 1] - 250.0) / 480.0], atol=1e-15)
    assert plain.undistort_points([]).shape == (0, 2)


def test_rays_and_unproject_through_the_points():
    cam = _camera()
    Pc = np.array([[0.2, -0.3, 2.0], [-0.5, 0.4, 3.5], [0.0, 0.0, 1.0]])
    P = cam.camera_to_world(Pc)
    uv = cam.project(P)
    origins, d = cam.rays(uv)
    np.testing.assert_allclose(origins, np.tile(-R0.T @ T0, (3, 1)), atol=1e-15)
    np.testing.assert_allclose(d, (P - origins) / np.linalg.norm(P - origins, axis=1, keepdims=True), atol=1e-11)
    origins[0] = 99  # a writable copy, not a view of the centre
    assert cam.center[0] != 99
    np.testing.assert_allclose(cam.unproject(uv, Pc[:, 2]), P, atol=1e-11)
    np.testing.assert_allclose(cam.unproject(uv, Pc[:, 2].reshape(3, 1)), P, atol=1e-11)


def test_in_image_is_the_half_open_rectangle():
    cam = _camera()
    uv = np.array([[0, 0], [639.999, 479.999], [640, 10], [10, 480], [-1e-9, 10], [10, -1e-9], [639, 479]])
    assert cam.in_image(uv).tolist() == [True, True, False, False, False, False, True]
    assert cam.in_image(uv.tolist()).tolist() == [True, True, False, False, False, False, True]


def test_frustum_corners_in_order_at_the_default_depths():
    cam = Camera("c", K0, None, np.eye(3), np.zeros(3), 640, 480)
    corners = [[0, 0], [640, 0], [640, 480], [0, 480]]
    want = [[(u - 300) / 520 * z, (v - 250) / 480 * z, z] for z in (0.1, 5.0) for u, v in corners]
    np.testing.assert_allclose(cam.frustum(), want, atol=1e-13)
    np.testing.assert_allclose(cam.frustum(1.0, 2.0)[[0, 4], 2], [1.0, 2.0], atol=1e-13)


def test_to_dict_from_dict_and_with_name():
    cam = _camera()
    d = cam.to_dict()
    assert d == {"K": K0.tolist(), "dist": DIST.tolist(), "R": R0.tolist(), "t": T0.tolist(), "width": 640,
                 "height": 480}
    back = Camera.from_dict("back", json.loads(json.dumps(d)))
    assert back.name == "back" and back.to_dict() == d
    renamed = cam.with_name("other")
    assert renamed.name == "other" and renamed.to_dict() == d
    no_dist = Camera.from_dict("n", {k: v for k, v in d.items() if k != "dist"})
    assert no_dist.dist.tolist() == [0.0] * 5
    with pytest.raises(InputError) as exc:
        Camera.from_dict("m", {k: v for k, v in d.items() if k != "t"})
    assert str(exc.value) == "camera m: missing key 't' (need K, dist, R, t, width, height)"
    with pytest.raises(InputError) as exc:
        Camera.from_dict("m", {**d, "width": "wide"})
    assert str(exc.value) == "camera m: malformed entry (invalid literal for int() with base 10: 'wide')"
    with pytest.raises(InputError) as exc:
        Camera.from_dict("m", {**d, "K": "abc"})
    assert str(exc.value) == "camera m: malformed entry (could not convert string to float: 'abc')"
    with pytest.raises(InputError, match="principal point"):  # the intrinsics are checked
        Camera.from_dict("m", {**d, "width": 100})
    assert str(exc.value).count("(") >= 1


def test_look_at_axes_intrinsics_and_refusals():
    eye, target = np.array([1.0, 2.0, 3.0]), np.array([0.0, 1.0, -1.0])
    cam = Camera.look_at("l", eye, target, fx=700.0, width=800, height=600)
    forward = (target - eye) / np.linalg.norm(target - eye)
    right = np.cross(forward, [0, 1, 0])
    right /= np.linalg.norm(right)
    np.testing.assert_allclose(cam.R, [right, np.cross(forward, right), forward], atol=1e-15)
    np.testing.assert_allclose(cam.center, eye, atol=1e-14)
    np.testing.assert_allclose(cam.K, [[700, 0, 399.5], [0, 700, 299.5], [0, 0, 1]])
    assert (cam.width, cam.height) == (800, 600) and not cam.has_distortion
    assert cam.R[1] @ [0, 1, 0] < 0  # image down is world down
    other = Camera.look_at("o", eye, target, up=(1.0, 0.0, 0.0), fx=500.0, fy=510.0, cx=10.0, cy=20.0,
                           dist=[0.1, 0, 0, 0, 0])
    np.testing.assert_allclose(other.K, [[500, 0, 10], [0, 510, 20], [0, 0, 1]])
    assert other.dist.tolist() == [0.1, 0, 0, 0, 0] and (other.width, other.height) == (640, 480)
    np.testing.assert_allclose(other.R[0], np.cross(forward, [1, 0, 0]) / np.linalg.norm(np.cross(forward, [1, 0, 0])))
    default = Camera.look_at("d", eye, target)
    assert default.fx == 600.0 and default.fy == 600.0 and (default.width, default.height) == (640, 480)
    eye_list = [1.0, 2.0, 3.0]
    Camera.look_at("l", eye_list, target)
    assert eye_list == [1.0, 2.0, 3.0]
    with pytest.raises(InputError) as exc:
        Camera.look_at("l", eye, eye + 1e-13)
    assert str(exc.value) == "camera l: eye and target coincide"
    Camera.look_at("l", eye, eye + [0, 0, 1e-11])  # near but not the same point
    with pytest.raises(InputError) as exc:
        Camera.look_at("l", eye, eye + [0, 3, 0])
    assert str(exc.value) == "camera l: viewing direction is parallel to up; choose another up vector"
    Camera.look_at("l", eye, eye + [1e-8, 3, 0])  # just off parallel


def test_rig_container_projection_and_dicts():
    a, b = _camera(name="a"), Camera.look_at("b", (0, 1, 3), (0, 1, 0))
    rig = CameraRig([a, b])
    assert rig.names == ["a", "b"] and len(rig) == 2 and list(rig) == [a, b]
    assert rig[0] is a and rig[1] is b and rig["b"] is b and "a" in rig and "z" not in rig
    with pytest.raises(InputError) as exc:
        rig["z"]
    assert str(exc.value) == "no camera named 'z'; the rig has a, b"
    source = {"b": b}
    by_dict = CameraRig(source)
    source["a"] = a
    assert by_dict.names == ["b"]  # a copy of the mapping
    P = np.array([[0.1, 1.0, 0.2], [0.0, 0.8, -0.3]])
    uv = rig.project(P)
    assert uv.shape == (2, 2, 2)
    np.testing.assert_allclose(uv[0], pixels_by_hand(a, P), atol=1e-9)
    np.testing.assert_allclose(uv[1], pixels_by_hand(b, P), atol=1e-9)
    np.testing.assert_allclose(rig.project(P[0])[:, 0], uv[:, 0])
    assert CameraRig().project(P).shape == (0, 2, 2) and CameraRig().centers().shape == (0, 3)
    np.testing.assert_allclose(rig.centers(), [a.center, b.center])
    sub = rig.subset(["b"])
    assert sub.names == ["b"] and sub["b"] is b
    d = rig.to_dict()
    assert d == {"version": 1, "cameras": {"a": a.to_dict(), "b": b.to_dict()}}
    back = CameraRig.from_dict(json.loads(json.dumps(d)))
    assert back.names == ["a", "b"] and back["a"].name == "a" and back["b"].to_dict() == b.to_dict()
    assert CameraRig.from_dict({"cameras": {7: a.to_dict()}}).names == ["7"]


def _checked(**kw):
    K = kw.pop("K", K0)
    args = {"dist": np.zeros(5), "width": 640, "height": 480, **kw}
    return Camera("c", K, args["dist"], np.eye(3), np.zeros(3), args["width"], args["height"])


@pytest.mark.parametrize(("camera_kw", "message"), [
    ({"width": 65537}, "camera c: image size 65537x480 must be whole pixel counts 1-65536"),
    ({"height": 65537}, "camera c: image size 640x65537 must be whole pixel counts 1-65536"),
    ({"K": [[0.0, 0, 300], [0, 480, 250], [0, 0, 1]]}, "camera c: focal lengths fx=0, fy=480 must be > 0 (pixels)"),
    ({"K": [[520.0, 0, 300], [0, -1, 250], [0, 0, 1]]}, "camera c: focal lengths fx=520, fy=-1 must be > 0 (pixels)"),
    ({"K": [[520.0, 0, 300], [0, 0, 250], [0, 0, 1]]}, "camera c: focal lengths fx=520, fy=0 must be > 0 (pixels)"),
    ({"K": [[520.0, 0, -0.5], [0, 480, 250], [0, 0, 1]]},
     "camera c: principal point (-0.5, 250) lies outside the 640x480 image; check K and the image size"),
    ({"K": [[520.0, 0, 640.5], [0, 480, 250], [0, 0, 1]]},
     "camera c: principal point (640.5, 250) lies outside the 640x480 image; check K and the image size"),
    ({"K": [[520.0, 0, 300], [0, 480, -1], [0, 0, 1]]},
     "camera c: principal point (300, -1) lies outside the 640x480 image; check K and the image size"),
    ({"K": [[520.0, 0, 300], [0, 480, 481], [0, 0, 1]]},
     "camera c: principal point (300, 481) lies outside the 640x480 image; check K and the image size"),
    ({"K": [[520.0, 0, 300], [2.0, 480, 250], [0, 0, 1]]},
     "camera c: K must be [[fx, s, cx], [0, fy, cy], [0, 0, 1]], got [[520.0, 0.0, 300.0], [2.0, 480.0, 250.0], "
     "[0.0, 0.0, 1.0]]"),
    ({"K": [[520.0, 0, 300], [0, 480, 250], [0, 0, 2]]},
     "camera c: K must be [[fx, s, cx], [0, fy, cy], [0, 0, 1]], got [[520.0, 0.0, 300.0], [0.0, 480.0, 250.0], "
     "[0.0, 0.0, 2.0]]"),
    ({"K": [[520.0, 0, 300], [0, 480, 250], [0.5, 0, 1]]}, "camera c: K must be"),
    ({"K": [[520.0, 0, 300], [0, 480, 250], [0, 0.5, 1]]}, "camera c: K must be"),
    ({"dist": [0, 0, 0, 0, -100.5]},
     "camera c: distortion [0.0, 0.0, 0.0, 0.0, -100.5] is implausibly large (|k| > 100); recalibrate"),
])
def test_check_intrinsics_refusals_word_for_word(camera_kw, message):
    with pytest.raises(InputError) as exc:
        cm.check_intrinsics(_checked(**camera_kw))
    assert str(exc.value).startswith(message)
    if not message.endswith("must be"):
        assert str(exc.value) == message


def test_check_intrinsics_accepts_the_bounds():
    for kw in ({"width": 65536, "height": 1, "K": [[520.0, 7.0, 0], [0, 480, 0], [0, 0, 1]]},
               {"width": 1, "height": 65536, "K": [[1e-9, 0, 1], [0, 1e-9, 65536], [0, 0, 1]]},
               {"dist": [100, -100, 0, 0, 100]}):
        cam = _checked(**kw)
        assert cm.check_intrinsics(cam) is cam
    cam = _checked()
    object.__setattr__(cam, "width", 640.0)  # not a whole pixel count
    with pytest.raises(InputError, match="image size 640.0x480 must be whole"):
        cm.check_intrinsics(cam)
    object.__setattr__(cam, "width", np.int64(640))
    assert cm.check_intrinsics(cam) is cam
    object.__setattr__(cam, "width", 0)
    with pytest.raises(InputError, match="image size 0x480 must be whole"):
        cm.check_intrinsics(cam)


def test_cameras_json_round_trip_and_refusals_word_for_word(tmp_path):
    rig = CameraRig([_camera(name="a"), Camera.look_at("b", (0, 1, 3), (0, 1, 0))])
    path = tmp_path / "cameras.json"
    cm.save_cameras_json(path, rig)
    assert json.loads(path.read_text()) == rig.to_dict()
    back = cm.load_cameras_json(path)
    assert back.names == ["a", "b"] and back["a"].to_dict() == rig["a"].to_dict()
    doc = rig.to_dict()
    del doc["version"]  # the version defaults to 1
    path.write_text(json.dumps(doc))
    assert cm.load_cameras_json(path).names == ["a", "b"]
    path.write_text("{not json")
    with pytest.raises(FileFormatError) as exc:
        cm.load_cameras_json(path)
    assert str(exc.value).startswith(f"{path}: not a valid cameras.json (")
    cases = [
        ([1, 2], "cameras.json needs a top-level object with a 'cameras' mapping; regenerate it with `bodystudio "
                 "synth` or calibration"),
        ({"cameras": []}, "cameras.json needs a top-level object with a 'cameras' mapping"),
        ({"version": 2, "cameras": {}}, "cameras.json version 2 is not supported (expected 1); regenerate the file"),
        ({"version": 1, "cameras": {}}, "cameras.json lists no cameras; add at least one entry"),
        ({"cameras": {"x": {"K": K0.tolist()}}},
         "camera x: missing key 'dist' (need K, dist, R, t, width, height); fix the entry or regenerate the file"),
        ({"cameras": {"x": {**rig["a"].to_dict(), "width": 100}}}, "camera x: principal point (300, 250) lies outside"),
        ({"cameras": {"x": 5}}, "camera x: malformed entry ("),
    ]
    cases[4][0]["cameras"]["x"] = {"K": K0.tolist(), "R": np.eye(3).tolist(), "width": 640, "height": 480}
    cases[4] = (cases[4][0], "camera x: missing key 't' (need K, dist, R, t, width, height); fix the entry or "
                             "regenerate the file")
    for doc, message in cases:
        path.write_text(json.dumps(doc))
        with pytest.raises(FileFormatError) as exc:
            cm.load_cameras_json(path)
        assert str(exc.value).startswith(f"{path}: {message}"), str(exc.value)
    path.write_text(json.dumps({"cameras": {"x": {**rig["a"].to_dict(), "R": [[1, 0, 0], [0, 1, 0], [0, 0, -1]]}}}))
    with pytest.raises(FileFormatError) as exc:
        cm.load_cameras_json(path)
    assert str(exc.value) == f"{path}: camera x: R is not a rotation matrix (R R^T != I or det < 0); fix the entry " \
                             "or regenerate the file"


def test_ring_rig_layout_by_hand():
    rig = cm.ring_rig(5, width=320, height=200, radius=2.5, heights=(0.8, 1.9, 1.5), target=(0.1, 1.0, -0.2),
                      volume_height=2.0)
    assert rig.names == ["cam_00", "cam_01", "cam_02", "cam_03", "cam_04"]
    assert [c.name for c in rig] == rig.names
    target = np.array([0.1, 1.0, -0.2])
    for i, cam in enumerate(rig):
        a = 2 * np.pi * i / 5
        eye = [2.5 * np.sin(a), (0.8, 1.9, 1.5)[i % 3], 2.5 * np.cos(a)]
        np.testing.assert_allclose(cam.center, eye, atol=1e-12)
        f = 0.5 * 200 * (np.linalg.norm(eye - target) - 0.8) / (0.5 * 2.0 + 0.1)
        np.testing.assert_allclose([cam.fx, cam.fy], [f, f], rtol=1e-12)
        np.testing.assert_allclose(cam.project(target[None]), [[159.5, 99.5]], atol=1e-9)
        assert cam.dist.tolist() == list(cm.STUDIO_DISTORTION) and (cam.width, cam.height) == (320, 200)
        assert cam.R[1] @ [0, 1, 0] < 0
    assert rig["cam_01"].center[0] > 0  # counter-clockwise seen from above: cam_01 towards +x
    default = cm.ring_rig()
    assert len(default) == 10 and default["cam_03"].width == 640 and default["cam_03"].height == 480
    np.testing.assert_allclose(np.linalg.norm(default.centers()[:, [0, 2]], axis=1), 3.0)
    np.testing.assert_allclose(default.centers()[:, 1], [1.0, 2.2] * 5, atol=1e-12)
    np.testing.assert_allclose(default["cam_00"].project([[0.0, 0.9, 0.0]]), [[319.5, 239.5]], atol=1e-9)
    d0 = np.linalg.norm(default["cam_00"].center - [0, 0.9, 0])
    assert default["cam_00"].fx == pytest.approx(0.5 * 480 * (d0 - 0.8) / 1.2, rel=1e-12)
    fixed = cm.ring_rig(2, fx=321.0, distortion=(0.0,) * 5)
    assert [c.fx for c in fixed] == [321.0, 321.0] and not fixed[0].has_distortion
    with pytest.raises(InputError) as exc:
        cm.ring_rig(0)
    assert str(exc.value) == "ring_rig needs at least one camera, got n=0"
    assert len(cm.ring_rig(1)) == 1


@pytest.mark.parametrize(("make", "want"), [
    (lambda: cm.kinect_v2(), {"version": "v2", "depth": (512, 424, 365.0, 255.5, 211.5, [0.09, -0.27, 0, 0, 0.09]),
                              "color": (1920, 1080, 1060.0, 959.5, 539.5, [0.02, -0.03, 0, 0, 0]), "offset": 0.052}),
    (lambda: cm.kinect_v1(), {"version": "v1", "depth": (640, 480, 580.0, 319.5, 239.5, [0] * 5),
                              "color": (640, 480, 525.0, 319.5, 239.5, [0] * 5), "offset": 0.025}),
    (lambda: cm.kinect_v1("320x240"), {"version": "v1", "depth": (320, 240, 290.0, 159.5, 119.5, [0] * 5),
                                       "color": (640, 480, 525.0, 319.5, 239.5, [0] * 5), "offset": 0.025}),
])
def test_kinect_sensors_carry_the_published_numbers(make, want):
    s = make()
    assert s.name == "kinect" and s.version == want["version"] and s.baseline_m == 0.075
    assert s.depth_range_m == (0.5, 4.5)
    assert (s.depth.name, s.color.name) == ("kinect_depth", "kinect_color")
    for cam, (w, h, f, cx, cy, dist) in ((s.depth, want["depth"]), (s.color, want["color"])):
        assert (cam.width, cam.height) == (w, h)
        np.testing.assert_allclose(cam.K, [[f, 0, cx], [0, f, cy], [0, 0, 1]])
        np.testing.assert_allclose(cam.dist, dist)
    np.testing.assert_allclose(s.depth.center, [0.0, 1.0, 2.6], atol=1e-12)
    np.testing.assert_allclose(s.depth.project([[0.0, 0.95, 0.0]]), [want["depth"][3:5]], atol=1e-9)
    np.testing.assert_array_equal(s.color.R, s.depth.R)
    # the colour camera sits offset along the depth camera's +x axis (world -x here: it faces -z)
    np.testing.assert_allclose(s.color.center - s.depth.center, s.depth.R[0] * want["offset"], atol=1e-12)
    T = np.eye(4)
    T[0, 3] = -want["offset"]
    np.testing.assert_allclose(s.depth_to_color, T, atol=1e-15)
    proj = s.projector
    assert proj.name == "kinect_depth_projector" and not proj.has_distortion
    np.testing.assert_array_equal(proj.K, s.depth.K)
    np.testing.assert_array_equal(proj.R, s.depth.R)
    assert (proj.width, proj.height) == (s.depth.width, s.depth.height)
    np.testing.assert_allclose(proj.center - s.depth.center, s.depth.R[0] * 0.075, atol=1e-12)
    d = s.to_dict()
    assert d == {"name": "kinect", "version": want["version"], "depth": s.depth.to_dict(), "color": s.color.to_dict(),
                 "depth_to_color": T.tolist(), "baseline_m": 0.075, "depth_range_m": [0.5, 4.5]}
    back = cm.RGBDSensor.from_dict(json.loads(json.dumps(d)))
    assert back.to_dict() == d and back.depth.name == "kinect_depth" and back.color.name == "kinect_color"
    assert back.depth_range_m == (0.5, 4.5) and type(back.baseline_m) is float


def test_kinect_placement_name_and_resolution_refusal():
    s = cm.kinect_v2(eye=(0.5, 1.2, 3.0), target=(0.1, 1.0, 0.0), name="k2")
    assert s.depth.name == "k2_depth" and s.color.name == "k2_color" and s.name == "k2"
    np.testing.assert_allclose(s.depth.center, [0.5, 1.2, 3.0], atol=1e-12)
    np.testing.assert_allclose(s.depth.project([[0.1, 1.0, 0.0]]), [[255.5, 211.5]], atol=1e-9)
    s1 = cm.kinect_v1("320x240", eye=(0.5, 1.2, 3.0), target=(0.1, 1.0, 0.0), name="k1")
    assert s1.name == "k1" and s1.color.name == "k1_color"
    np.testing.assert_allclose(s1.depth.project([[0.1, 1.0, 0.0]]), [[159.5, 119.5]], atol=1e-9)
    with pytest.raises(InputError) as exc:
        cm.kinect_v1("1280x960")
    assert str(exc.value) == "kinect_v1 depth_resolution must be one of 640x480, 320x240, got '1280x960'"
    other = cm.RGBDSensor("s", "v2", s.depth, s.color, np.eye(4), baseline_m=0.1, depth_range_m=(0.4, 3.0))
    assert other.to_dict()["depth_range_m"] == [0.4, 3.0] and other.to_dict()["baseline_m"] == 0.1
    back = cm.RGBDSensor.from_dict(json.loads(json.dumps(other.to_dict())))
    assert back.depth_range_m == (0.4, 3.0) and back.baseline_m == 0.1 and back.name == "s"
    assert back.version == "v2" and back.depth_to_color.dtype == np.float64
