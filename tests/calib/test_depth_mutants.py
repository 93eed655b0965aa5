"""RGB-D board calibration against independent references (issue 17, mutation of calib/depth.py).

References: planes through hand-placed points (exact normals, offsets and inlier masks), the depth pixels of a
board whose outline lands on whole pixels written out pixel by pixel, OpenCV's projectPoints for the colour
corners and the distorted outline, the Unnikrishnan-Hebert closed form checked on planes made from a known
rotation and translation, the refined transform's corner-to-plane residuals recomputed from the planes the
fit used, and every refusal's whole line. Inputs are built once (functools.cache); the functions under test
run inside each test.
"""

import functools

import cv2
import numpy as np
import pytest

from bodystudio.calib import depth as dm
from bodystudio.calib.board import CharucoBoardSpec, board_corners, board_image
from bodystudio.calib.world import rigid, rigid_inverse, rotation_angle_deg
from bodystudio.errors import SessionError
from bodystudio.geometry.camera import Camera, RGBDSensor, kinect_v2


def _rotation(rvec):
    return cv2.Rodrigues(np.asarray(rvec, float))[0]


def _cv_project(cam: Camera, P_cam: np.ndarray) -> np.ndarray:
    """Pixels of camera-frame points by OpenCV's projectPoints (the camera's own pose not used)."""
    uv, _ = cv2.projectPoints(P_cam.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), cam.K, cam.dist)
    return uv.reshape(-1, 2)


@functools.cache
def _scene():
    """Kinect v2, the default 10 x 7 board in 4 tilted poses; colour corners exact, depth with the Kinect's noise."""
    spec = CharucoBoardSpec()
    sensor = kinect_v2()
    rng = np.random.default_rng(2)
    poses = dm.rgbd_board_poses(sensor, spec, 4, rng)
    views = dm.synthetic_rgbd_views(sensor, spec, poses, 0.0, rng)
    return spec, sensor, poses, views


# --- planes ----------------------------------------------------------------------------------------------

def _grid_plane(n, d, half=0.5, k=11):
    """Points of the plane n . x + d = 0 on a symmetric k x k grid about its point nearest the origin."""
    n = np.asarray(n, float) / np.linalg.norm(n)
    basis = np.linalg.svd(n[None])[2][1:]
    s = np.linspace(-half, half, k)
    uv = np.stack(np.meshgrid(s, s), -1).reshape(-1, 2)
    return uv @ basis - d * n, n


@pytest.mark.parametrize("z", [2.0, -2.0, 0.75, -0.75])
def test_plane_of_an_exact_grid_faces_the_origin_and_keeps_exact_inliers(z):
    s = np.linspace(-0.5, 0.5, 11)
    grid = np.c_[np.stack(np.meshgrid(s, s), -1).reshape(-1, 2), np.full(121, z)]
    out = np.array([[0.1, 0.2, z + 0.25], [0.0, 0.0, z - 0.25], [0.3, -0.3, z + 1.0], [0.2, 0.1, z - 0.7]])
    n, d, inliers = dm.fit_plane_ransac(np.r_[grid, out], 0.25, np.random.default_rng(0))
    np.testing.assert_allclose(n, [0.0, 0.0, -np.sign(z)], atol=1e-12)
    assert d == pytest.approx(abs(z), abs=1e-12)  # d >= 0: the normal looks at the sensor, also within a metre
    assert inliers.dtype == bool and inliers.tolist() == [True] * 121 + [False] * 4  # 0.25 m exactly is out


def test_plane_of_a_tilted_grid():
    truth_n = np.array([0.3, -0.4, -1.0]) / np.linalg.norm([0.3, -0.4, -1.0])
    pts, _ = _grid_plane(truth_n, 1.7)
    rng = np.random.default_rng(1)
    far = pts[:30] + rng.uniform(0.1, 0.5, (30, 1)) * truth_n  # in front of the board: flying pixels
    n, d, inliers = dm.fit_plane_ransac(np.r_[far, pts], 0.05, rng)
    np.testing.assert_allclose(n, truth_n, atol=1e-12)
    assert d == pytest.approx(1.7, abs=1e-12)
    assert not inliers[:30].any() and inliers[30:].all()


def test_plane_of_three_points_and_the_refusal_below():
    P = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 1.0], [0.0, 1.0, 1.0]])
    n, d, inliers = dm.fit_plane_ransac(P, 0.01, np.random.default_rng(0), iterations=1)  # one distinct draw
    np.testing.assert_allclose(n, [0, 0, -1], atol=1e-12)
    assert d == pytest.approx(1.0, abs=1e-12) and inliers.all()
    with pytest.raises(SessionError) as err:
        dm.fit_plane_ransac(P[:2], 0.01, np.random.default_rng(0))
    assert str(err.value) == ("too few depth points on the board to fit its plane; move the board closer to the "
                              "sensor")


def test_degenerate_draws_are_skipped_not_the_end():
    """18 copies of one point and two others: most 3-point draws span no plane; later ones do."""
    A, B, C = [0.0, 0.0, 2.0], [1.0, 0.0, 2.0], [0.0, 1.0, 2.0]
    P = np.array([A] * 18 + [B, C])
    n, d, inliers = dm.fit_plane_ransac(P, 0.01, np.random.default_rng(3))
    np.testing.assert_allclose(n, [0, 0, -1], atol=1e-12)
    assert d == pytest.approx(2.0, abs=1e-12) and inliers.all()


# --- the board's depth pixels ----------------------------------------------------------------------------

_SPEC_43 = CharucoBoardSpec(4, 3, 0.1, 0.075)  # 0.4 x 0.3 m, centre (0.2, 0.15)


def _pinhole(dist=(0, 0, 0, 0, 0), R=np.eye(3), t=np.zeros(3)):
    return Camera("depth", np.array([[100.0, 0, 32], [0, 100.0, 24], [0, 0, 1]]), dist, R, t, 64, 48)


def _facing(z=2.0):
    """Board -> depth transform: the board's axes along the camera's, its centre on the optical axis at z."""
    return rigid(np.eye(3), [-0.2, -0.15, z])


def test_board_pixels_written_out():
    cam = _pinhole()
    u, v = np.meshgrid(np.arange(64), np.arange(48))
    depth = 2.0 + 0.001 * u + 0.0001 * v  # each pixel its own depth: a transposed look-up shows
    depth[20, 30] = 0.0  # no depth: left out
    # shrink 0.8: the outline spans +-8 px by +-6 px about (32, 24): pixels 24..40 x 18..30, edges included
    pts = dm.board_depth_points(depth, cam, _facing(), _SPEC_43, 0.8)
    expected = [((uu - 32) / 100 * depth[vv, uu], (vv - 24) / 100 * depth[vv, uu], depth[vv, uu])
                for vv in range(18, 31) for uu in range(24, 41) if (uu, vv) != (30, 20)]
    assert pts.shape == (17 * 13 - 1, 3)
    np.testing.assert_allclose(pts, np.array(expected), atol=1e-12)
    # the depth camera's own pose plays no part: board_in_depth is already in its frame
    moved = _pinhole(R=_rotation([0.3, -0.2, 0.1]), t=[1.0, 2.0, 3.0])
    np.testing.assert_allclose(dm.board_depth_points(depth, moved, _facing(), _SPEC_43, 0.8), pts, atol=1e-12)
    # shrink 0.5: +-5 px by +-3.75 px -> 27..37 x 20..28 (20.25 and 27.75 round to 20 and 28)
    half = dm.board_depth_points(np.full((48, 64), 2.0), cam, _facing(), _SPEC_43, 0.5)
    assert half.shape == (11 * 9, 3)
    assert half[:, 0].min() == pytest.approx(-0.1) and half[:, 0].max() == pytest.approx(0.1)
    assert half[:, 1].min() == pytest.approx(-0.08) and half[:, 1].max() == pytest.approx(0.08)


def test_board_pixels_through_a_distorted_lens():
    cam = _pinhole(dist=(-0.2, 0.05, 0.001, -0.002, 0.0))
    depth = np.full((48, 64), 0.9)  # under a metre: any depth above 0 counts
    T = rigid(_rotation([0.2, -0.3, 0.1]), [-0.2, -0.15, 1.5])
    pts = dm.board_depth_points(depth, cam, T, _SPEC_43, 0.85)
    outline = np.array([[0, 0, 0], [0.4, 0, 0], [0.4, 0.3, 0], [0, 0.3, 0.0]])
    outline = np.array([0.2, 0.15, 0]) + 0.85 * (outline - [0.2, 0.15, 0])
    poly = _cv_project(cam, outline @ T[:3, :3].T + T[:3, 3])
    mask = np.zeros((48, 64), np.uint8)
    cv2.fillConvexPoly(mask, np.round(poly).astype(np.int32), 1)
    assert len(pts) == mask.sum() > 100
    np.testing.assert_allclose(pts[:, 2], 0.9)
    uv = _cv_project(cam, pts)  # every point re-projects onto a whole pixel of the mask
    np.testing.assert_allclose(uv, np.round(uv), atol=1e-6)
    assert mask[np.round(uv[:, 1]).astype(int), np.round(uv[:, 0]).astype(int)].all()


def test_no_board_pixels():
    cam = _pinhole()
    assert dm.board_depth_points(np.zeros((48, 64)), cam, _facing(), _SPEC_43, 0.8).shape == (0, 3)
    one = np.zeros((48, 64))
    one[20, 30] = 0.6
    np.testing.assert_allclose(dm.board_depth_points(one, cam, _facing(), _SPEC_43, 0.8), [[-0.012, -0.024, 0.6]],
                               atol=1e-12)
    behind = rigid(np.eye(3), [-0.2, -0.15, -2.0])  # the outline projects to NaN pixels: nothing drawn
    assert dm.board_depth_points(np.full((48, 64), 2.0), cam, behind, _SPEC_43, 0.8).shape == (0, 3)


# --- poses and the closed form ---------------------------------------------------------------------------

def test_color_board_pose_from_a_subset_of_corners():
    spec, sensor = CharucoBoardSpec(), kinect_v2()
    truth = rigid(_rotation([2.8, 0.3, -0.2]), [-0.4, -0.3, 1.9])
    ids = np.arange(3, 54, 2)
    uv = _cv_project(sensor.color, board_corners(spec)[ids] @ truth[:3, :3].T + truth[:3, 3])
    T = dm.color_board_pose(dm.RGBDBoardView(ids, uv, np.zeros((2, 2))), sensor.color, spec)
    np.testing.assert_allclose(T, truth, atol=1e-8)


def _planes_seen_from_both(R, t, normals_d, offsets_d):
    """The same planes in the colour frame x_c = R x_d + t: n_c = R n_d, d_c = d_d - n_c . t."""
    normals_c = normals_d @ R.T
    return normals_c, offsets_d - normals_c @ t


def test_depth_to_color_from_four_planes():
    R, t = _rotation([0.05, -0.1, 0.03]), np.array([0.052, -0.004, 0.002])
    n_d = np.array([[0.1, 0.2, -1.0], [0.5, 0.0, -1.0], [-0.3, 0.4, -1.0], [0.0, -0.6, -1.0]])
    n_d /= np.linalg.norm(n_d, axis=1, keepdims=True)
    d_d = np.array([1.6, 2.0, 2.3, 1.4])
    n_c, d_c = _planes_seen_from_both(R, t, n_d, d_d)
    T = dm.depth_to_color_from_planes(n_d, d_d, n_c, d_c)
    np.testing.assert_allclose(T[:3, :3], R, atol=1e-12)
    np.testing.assert_allclose(T[:3, 3], t, atol=1e-12)
    np.testing.assert_allclose(T[3], [0, 0, 0, 1])


def test_depth_to_color_rotation_from_normals_in_one_plane():
    """Normals spanning a plane only: Kabsch's SVD may hand back a reflection, which the sign fixes."""
    R = _rotation([0.4, -0.7, 1.1])
    angles = np.radians([0, 50, 110, 200])
    n_d = np.c_[np.cos(angles), np.sin(angles), np.zeros(4)]
    n_c, d_c = _planes_seen_from_both(R, np.zeros(3), n_d, np.ones(4))
    T = dm.depth_to_color_from_planes(n_d, np.ones(4), n_c, d_c)
    np.testing.assert_allclose(T[:3, :3], R, atol=1e-12)


# --- the depth -> colour calibration ---------------------------------------------------------------------

def _spied_calibration(monkeypatch, views, sensor, spec, **kwargs):
    """calibrate_depth_to_color with every plane fit, region and solver call recorded."""
    calls = {"regions": [], "planes": [], "solver": []}
    real_points, real_fit, real_ls = dm.board_depth_points, dm.fit_plane_ransac, dm.least_squares

    def points(depth_m, depth_cam, board_in_depth, spec_, shrink):
        calls["regions"].append((shrink, board_in_depth.copy()))
        return real_points(depth_m, depth_cam, board_in_depth, spec_, shrink)

    def fit(pts, threshold_m, rng, *args, **kw):
        out = real_fit(pts, threshold_m, rng, *args, **kw)
        calls["planes"].append((threshold_m, rng, out[0], out[1], pts[out[2]], len(pts)))
        return out

    def solver(fun, x0, **kw):
        calls["solver"].append(kw)
        calls.setdefault("x0", []).append(x0.copy())
        return real_ls(fun, x0, **kw)

    monkeypatch.setattr(dm, "board_depth_points", points)
    monkeypatch.setattr(dm, "fit_plane_ransac", fit)
    monkeypatch.setattr(dm, "least_squares", solver)
    T, report = dm.calibrate_depth_to_color(views, sensor.depth, sensor.color, spec, **kwargs)
    return T, report, calls


def _board_in_color(sensor, pose):
    """Board -> colour-camera transform of a board -> world pose."""
    return sensor.color.extrinsic @ pose


def test_depth_to_color_is_the_refined_plane_fit(monkeypatch):
    spec, sensor, poses, views = _scene()
    rng = np.random.default_rng(5)
    T, report, calls = _spied_calibration(monkeypatch, views, sensor, spec, rng=rng)
    G = sensor.depth_to_color
    # the closed form alone is 2.2 mm off on these views; the corner-to-plane refinement 0.5 mm
    assert 1000 * np.linalg.norm(T[:3, 3] - G[:3, 3]) < 1.0
    assert rotation_angle_deg(T[:3, :3] @ G[:3, :3].T) < 0.02
    # two passes over the four views: the board region shrunk to 0.6, then 0.85 of its size
    assert [s for s, _ in calls["regions"]] == [0.6] * 4 + [0.85] * 4
    for (_, region), pose in zip(calls["regions"][:4], poses, strict=True):  # first pass: T = identity
        np.testing.assert_allclose(region, _board_in_color(sensor, pose), atol=1e-6)
    assert all(c[0] == 0.02 and c[1] is rng for c in calls["planes"])
    assert calls["solver"] == [{"loss": "soft_l1", "f_scale": 0.005}] * 2
    from bodystudio.calib.world import rvec_t_to_rigid

    for x0 in calls["x0"]:  # each pass starts from the closed form: 5.4 and 2.2 mm, 0.03 and 0.02 deg off
        start = rvec_t_to_rigid(x0[:3], x0[3:])
        assert 1000 * np.linalg.norm(start[:3, 3] - G[:3, 3]) < 10
        assert rotation_angle_deg(start[:3, :3] @ G[:3, :3].T) < 0.1
    last = calls["planes"][4:]
    assert report["n_views"] == 4
    expected_rms = [1000 * np.sqrt(np.mean((q @ n + d) ** 2)) for _, _, n, d, q, _ in last]
    assert report["plane_rms_mm"] == pytest.approx(expected_rms, rel=1e-12)
    assert all(r > 1.0 for r in expected_rms)
    # the corners (true board poses) moved into the depth frame by T^-1, against the last pass's planes
    Tinv = rigid_inverse(T)
    res = []
    for (_, _, n, d, _, _), pose in zip(last, poses, strict=True):
        X = board_corners(spec) @ _board_in_color(sensor, pose)[:3, :3].T + _board_in_color(sensor, pose)[:3, 3]
        res.append((X @ Tinv[:3, :3].T + Tinv[:3, 3]) @ n + d)
    res = np.concatenate(res)
    assert report["corner_to_plane_rms_mm"] == pytest.approx(1000 * np.sqrt(np.mean(res ** 2)), rel=1e-6)
    # T minimises the soft-l1 corner-to-plane cost: no small step of its six parameters lowers it
    def cost(M):
        Minv = rigid_inverse(M)
        r = np.concatenate([(board_corners(spec) @ _board_in_color(sensor, p)[:3, :3].T
                             + _board_in_color(sensor, p)[:3, 3]) @ Minv[:3, :3].T @ n + Minv[:3, 3] @ n + d
                            for (_, _, n, d, _, _), p in zip(last, poses, strict=True)])
        z = (r / 0.005) ** 2
        return np.sum(2 * (np.sqrt(1 + z) - 1))
    base = cost(T)
    for k in range(6):
        for step in (-1e-4, 1e-4):
            dx = np.zeros(6)
            dx[k] = step
            M = rigid(_rotation(dx[:3]) @ T[:3, :3], T[:3, 3] + dx[3:])
            assert cost(M) > base


def test_depth_to_color_initial_guess_picks_the_first_region(monkeypatch):
    spec, sensor, poses, views = _scene()
    G = sensor.depth_to_color
    T, report, calls = _spied_calibration(monkeypatch, views, sensor, spec, initial=G, plane_threshold_m=0.03)
    for (_, region), pose in zip(calls["regions"][:4], poses, strict=True):
        np.testing.assert_allclose(region, rigid_inverse(G) @ _board_in_color(sensor, pose), atol=1e-6)
    assert all(c[0] == 0.03 for c in calls["planes"])
    assert 1000 * np.linalg.norm(T[:3, 3] - G[:3, 3]) < 1.0


def _with_depth(view, depth):
    return dm.RGBDBoardView(view.corner_ids, view.corners_px, depth)


def test_views_without_enough_depth_are_left_out(monkeypatch):
    spec, sensor, poses, views = _scene()
    # 50 depth pixels on a 10 x 5 grid 8 px apart about the board's centre (inside both passes' regions) are
    # enough; 49 are not
    u, v = np.round(sensor.depth.project((poses[0][:3, :3] @ spec.center_m + poses[0][:3, 3])[None])[0]).astype(int)
    patch = np.zeros_like(views[0].depth_m)
    rows, cols = np.ix_(v + 8 * np.arange(-2, 3), u + 8 * np.arange(-5, 5) + 4)
    patch[rows, cols] = views[0].depth_m[rows, cols]
    assert (patch > 0).sum() == 50
    T, report, calls = _spied_calibration(monkeypatch, [_with_depth(views[0], patch)] + views[1:], sensor, spec)
    assert report["n_views"] == 4 and len(report["plane_rms_mm"]) == 4
    assert [c[5] for c in calls["planes"]][::4] == [50, 50]
    patch[v, u + 4] = 0.0
    T, report = dm.calibrate_depth_to_color([_with_depth(views[0], patch)] + views[1:], sensor.depth, sensor.color,
                                            spec)
    assert report["n_views"] == 3 and len(report["plane_rms_mm"]) == 3


def test_depth_calibration_refusals():
    spec, sensor, poses, views = _scene()
    with pytest.raises(SessionError) as err:
        dm.calibrate_depth_to_color(views[:2], sensor.depth, sensor.color, spec)
    assert str(err.value) == ("depth calibration needs at least 3 board poses seen by colour and depth, got 2; "
                              "capture the board tilted in different directions")
    empty = [_with_depth(views[0], np.zeros_like(views[0].depth_m))] + views[1:3]
    with pytest.raises(SessionError) as err:
        dm.calibrate_depth_to_color(empty, sensor.depth, sensor.color, spec)
    assert str(err.value) == ("the board was found in depth in only 2 poses; capture it within the depth camera's "
                              "range (0.5-4.5 m) in at least 3 tilted poses")
    T, report = dm.calibrate_depth_to_color(views[:3], sensor.depth, sensor.color, spec)  # 3 are enough
    assert report["n_views"] == 3
    again, _ = dm.calibrate_depth_to_color(views[:3], sensor.depth, sensor.color, spec)  # a seeded default generator
    np.testing.assert_array_equal(again, T)


# --- the Kinect in the studio ----------------------------------------------------------------------------

def test_sensor_to_studio_from_exact_corners(monkeypatch):
    spec, sensor, poses, views = _scene()
    starts, real = [], cv2.solvePnP

    def pnp(*args, **kwargs):  # copies: OpenCV writes its answer into the start's arrays
        starts.append(([np.array(a) if isinstance(a, np.ndarray) else a for a in args], kwargs))
        return real(*args, **kwargs)

    monkeypatch.setattr(cv2, "solvePnP", pnp)
    W = dm.sensor_to_studio(sensor.color, spec, views, list(poses))
    np.testing.assert_allclose(W, sensor.color.extrinsic, atol=1e-7)
    # the last PnP (all corners) starts from the first view's pose, which exact corners make the true one
    args, kwargs = starts[-1]
    assert len(args[0]) == 4 * spec.n_corners and kwargs == {"useExtrinsicGuess": True}
    np.testing.assert_allclose(cv2.Rodrigues(np.asarray(args[4]))[0], sensor.color.R, atol=1e-7)
    np.testing.assert_allclose(np.asarray(args[5]).ravel(), sensor.color.t, atol=1e-7)
    monkeypatch.undo()
    with pytest.raises(ValueError):  # a pose per view: one short is an error, not a silent cut
        dm.sensor_to_studio(sensor.color, spec, views, list(poses[:3]))
    # a view the studio did not see (NaN pose) adds nothing, the first one included (it was the start: NaN out)
    unseen = [*poses[:2], np.full((4, 4), np.nan), *poses[3:]]
    np.testing.assert_allclose(dm.sensor_to_studio(sensor.color, spec, views, unseen), W, atol=1e-7)
    first_unseen = [np.full((4, 4), np.nan), *poses[1:]]
    np.testing.assert_allclose(dm.sensor_to_studio(sensor.color, spec, views, first_unseen), W, atol=1e-7)
    mixed = [poses[0], *poses[1:]]
    mixed[1] = np.full((4, 4), np.nan)  # the start is the first shared view's own pose, not the next one's
    np.testing.assert_allclose(dm.sensor_to_studio(sensor.color, spec, views, mixed), W, atol=1e-7)
    partly = poses[0].copy()
    partly[1, 3] = np.nan
    np.testing.assert_allclose(dm.sensor_to_studio(sensor.color, spec, views, [partly, *poses[1:]]), W, atol=1e-7)
    with pytest.raises(SessionError) as err:
        dm.sensor_to_studio(sensor.color, spec, views, [np.full((4, 4), np.nan)] * 4)
    assert str(err.value) == ("no Kinect colour view shares a board pose with the studio cameras; capture boards "
                              "seen by the Kinect and the studio at the same time")


def test_calibrated_sensor_keeps_its_intrinsics_and_gets_its_poses(monkeypatch):
    spec, sensor, poses, views = _scene()
    generators, real = [], dm.calibrate_depth_to_color

    def planes(views_, depth_cam, color, spec_, rng=None):
        generators.append(rng)
        return real(views_, depth_cam, color, spec_, rng)

    monkeypatch.setattr(dm, "calibrate_depth_to_color", planes)
    from dataclasses import replace

    sensor = replace(sensor, baseline_m=0.08, depth_range_m=(0.6, 4.0))  # not the Kinect's defaults
    rng = np.random.default_rng(5)
    est, report = dm.calibrate_rgbd_sensor(sensor, spec, views, list(poses), rng)
    assert generators == [rng]  # the caller's generator reaches the plane fits
    T, G = est.depth_to_color, sensor.depth_to_color
    assert 1000 * np.linalg.norm(T[:3, 3] - G[:3, 3]) < 1.0 and rotation_angle_deg(T[:3, :3] @ G[:3, :3].T) < 0.02
    assert report["n_views"] == 4 and report["corner_to_plane_rms_mm"] < 0.2
    assert (est.name, est.version, est.baseline_m, est.depth_range_m) == (sensor.name, sensor.version,
                                                                        sensor.baseline_m, sensor.depth_range_m)
    for got, cam in ((est.color, sensor.color), (est.depth, sensor.depth)):
        assert (got.name, got.width, got.height) == (cam.name, cam.width, cam.height)
        np.testing.assert_array_equal(got.K, cam.K)
        np.testing.assert_array_equal(got.dist, cam.dist)
    np.testing.assert_allclose(est.color.extrinsic, sensor.color.extrinsic, atol=1e-7)
    # world -> depth = (depth -> colour)^-1 world -> colour: the depth camera where it really is
    np.testing.assert_allclose(est.depth.extrinsic, rigid_inverse(T) @ sensor.color.extrinsic, atol=1e-7)
    assert 1000 * np.linalg.norm(est.depth.center - sensor.depth.center) < 1.0
    alone, _ = dm.calibrate_rgbd_sensor(sensor, spec, views, rng=np.random.default_rng(5))
    np.testing.assert_allclose(alone.depth_to_color, T, atol=1e-12)  # the same generator: the same fit
    assert alone.color is sensor.color and alone.depth is sensor.depth  # no studio poses: the poses stay


# --- synthetic views and poses ---------------------------------------------------------------------------

def test_synthetic_views_project_the_visible_corners():
    spec, sensor, poses, _ = _scene()
    views = dm.synthetic_rgbd_views(sensor, spec, poses[:2], 0.0, np.random.default_rng(8))
    assert len(views) == 2
    [other] = dm.synthetic_rgbd_views(sensor, spec, poses[:1], 0.0, np.random.default_rng(9))
    assert (other.depth_m != views[0].depth_m).mean() > 0.2  # the Kinect's noise, not only its quantisation
    for view, pose in zip(views, poses[:2], strict=True):
        assert view.corner_ids.tolist() == list(range(spec.n_corners))
        P = board_corners(spec) @ _board_in_color(sensor, pose)[:3, :3].T + _board_in_color(sensor, pose)[:3, 3]
        np.testing.assert_allclose(view.corners_px, _cv_project(sensor.color, P), atol=1e-6)
        assert view.depth_m.shape == (sensor.depth.height, sensor.depth.width)
    # the depth: the board's plane in the depth camera, within the Kinect's noise at 1.4-2.5 m
    D = rigid_inverse(sensor.depth_to_color) @ _board_in_color(sensor, poses[0])
    pts = dm.board_depth_points(views[0].depth_m, sensor.depth, D, spec, 0.8)
    n = D[:3, 2]
    dist = pts @ n - D[:3, 3] @ n
    assert len(pts) > 5000 and np.median(np.abs(dist)) < 0.01 and np.abs(np.mean(dist)) < 0.003


def test_synthetic_views_noise_and_skipped_poses():
    spec, sensor, poses, _ = _scene()
    away = poses[0].copy()
    away[:3, :3] = away[:3, :3] @ _rotation([0, np.pi, 0])  # printed face turned away from the sensor
    rng = np.random.default_rng(7)
    views = dm.synthetic_rgbd_views(sensor, spec, np.array([poses[0], away, *poses[1:]]), 0.5, rng)
    assert len(views) == 4
    err = np.concatenate([v.corners_px - _cv_project(sensor.color, board_corners(spec) @ _board_in_color(
        sensor, p)[:3, :3].T + _board_in_color(sensor, p)[:3, 3]) for v, p in zip(views, poses, strict=True)])
    assert 0.45 < err.std() < 0.55 and abs(err.mean()) < 0.05


def test_board_poses_in_front_of_the_sensor():
    spec, sensor = CharucoBoardSpec(), kinect_v2()
    poses = dm.rgbd_board_poses(sensor, spec, 40, np.random.default_rng(11))
    c = sensor.color
    assert poses.shape == (40, 4, 4)
    centres = poses[:, :3, :3] @ spec.center_m + poses[:, :3, 3] - c.center
    forward, right, down = centres @ c.R[2], centres @ c.R[0], centres @ c.R[1]
    assert forward.min() >= 1.4 and forward.max() <= 2.5 and forward.min() < 1.55 and forward.max() > 2.3
    assert np.abs(right).max() <= 0.25 and np.ptp(right) > 0.35
    assert np.abs(down).max() <= 0.2 and np.ptp(down) > 0.28
    normals = -poses[:, :3, 2]  # the printed face's direction
    tilt = np.c_[normals @ c.R[0], normals @ c.R[1]] / (normals @ -c.R[2])[:, None]  # the two drawn tilts
    assert (np.abs(tilt.mean(0)) < 0.15).all() and ((0.2 < tilt.std(0)) & (tilt.std(0) < 0.45)).all()
    assert abs(np.corrcoef(tilt.T)[0, 1]) < 0.5
    # the roll about the face's normal, from the board's x axis against the level "right" of board_pose_facing
    z = poses[:, :3, 2]
    level = np.cross(z, [0.0, 1.0, 0.0])
    level /= np.linalg.norm(level, axis=1, keepdims=True)
    down_axis = np.cross(z, level)
    roll = np.arctan2(np.sum(poses[:, :3, 0] * down_axis, 1), np.sum(poses[:, :3, 0] * level, 1))
    assert np.abs(roll).max() <= 0.3 and np.ptp(roll) > 0.4
    from bodystudio.calib.render import visible_corners

    assert all(visible_corners(c, spec, T).all() for T in poses)


# --- capture folders -------------------------------------------------------------------------------------

@functools.cache
def _flat_board_png():
    spec = CharucoBoardSpec(5, 4, 0.04, 0.03)
    ok, buf = cv2.imencode(".png", board_image(spec, px_per_m=1000.0, margin_m=0.02))
    return spec, buf.tobytes()


def _capture_folder(root, frames):
    from bodystudio.capture.kinect import write_depth_png

    spec, png = _flat_board_png()
    (root / "kinect" / "rgb").mkdir(parents=True)
    (root / "kinect" / "depth").mkdir(parents=True)
    blank = cv2.imencode(".png", np.full((200, 240), 255, np.uint8))[1].tobytes()
    for name, board, depth in frames:
        (root / "kinect" / "rgb" / f"{name}.png").write_bytes(png if board else blank)
        if depth is not None:
            write_depth_png(root / "kinect" / "depth" / f"{name}.png", depth)
    return spec


def test_capture_folder_views(tmp_path):
    depth = np.full((4, 6), 1.25)
    depth[1, 2] = 0.0
    spec = _capture_folder(tmp_path, [("00003", True, depth), ("00001", False, depth), ("00010", True, depth * 2),
                                      ("00000_preview", True, None)])  # not a frame: skipped, not the end
    frames, views = dm.detect_rgbd_capture(tmp_path, spec)
    assert frames == [3, 10] and all(type(f) is int for f in frames)
    for view, scale in zip(views, (1, 2), strict=True):
        assert view.corner_ids.tolist() == list(range(12))
        expected = np.array([[20 + 40 * (i + 1) - 0.5, 20 + 40 * (j + 1) - 0.5] for j in range(3) for i in range(4)])
        np.testing.assert_allclose(view.corners_px, expected, atol=0.05)
        assert view.depth_m.dtype == np.float64
        np.testing.assert_allclose(view.depth_m, depth * scale, atol=1e-12)
    # the default needs 6 corners: a 3 x 4 board has exactly 6
    small = CharucoBoardSpec(3, 4, 0.04, 0.03)
    cv2.imwrite(str(tmp_path / "kinect" / "rgb" / "00001.png"), board_image(small, px_per_m=1000.0, margin_m=0.02))
    frames, views = dm.detect_rgbd_capture(tmp_path, small)
    assert frames == [1] and views[0].corner_ids.tolist() == list(range(6))
    with pytest.raises(SessionError) as err:
        dm.detect_rgbd_capture(tmp_path, spec, min_corners=13)
    assert str(err.value) == (f"camera kinect: no ChArUco board found in {tmp_path / 'kinect' / 'rgb'}; capture the "
                              "board in front of the Kinect")


def test_capture_folder_refusals(tmp_path):
    spec = CharucoBoardSpec(5, 4, 0.04, 0.03)
    (tmp_path / "a" / "kinect" / "rgb").mkdir(parents=True)
    for folder in (tmp_path / "a", tmp_path / "b"):
        with pytest.raises(SessionError) as err:
            dm.detect_rgbd_capture(folder, spec)
        assert str(err.value) == (f"{folder}: no kinect/rgb and kinect/depth folders; record the boards with the "
                                  "Kinect too")
    (tmp_path / "c" / "kinect" / "depth").mkdir(parents=True)
    with pytest.raises(SessionError):
        dm.detect_rgbd_capture(tmp_path / "c", spec)
    _capture_folder(tmp_path / "d", [("00000", True, np.ones((2, 2))), ("00001", True, None)])
    with pytest.raises(SessionError) as err:
        dm.detect_rgbd_capture(tmp_path / "d", spec)
    path = tmp_path / "d" / "kinect" / "depth" / "00001.png"
    assert str(err.value) == (f"camera kinect: frame 00001 has a colour image but no depth image ({path}); "
                              "export both streams")
    _capture_folder(tmp_path / "e", [("00000", False, np.ones((2, 2)))])
    with pytest.raises(SessionError, match="no ChArUco board found"):
        dm.detect_rgbd_capture(tmp_path / "e", spec)


def _small_sensor():
    K_d = np.array([[60.0, 0, 39.5], [0, 60.0, 29.5], [0, 0, 1]])
    K_c = np.array([[250.0, 0, 79.5], [0, 250.0, 59.5], [0, 0, 1]])
    color = Camera("kinect_rgb", K_c, None, np.eye(3), np.zeros(3), 160, 120)
    D = rigid(np.eye(3), [0.05, 0.0, 0.0])
    Wd = rigid_inverse(D) @ color.extrinsic
    depth = Camera("kinect_depth", K_d, None, Wd[:3, :3], Wd[:3, 3], 80, 60)
    return RGBDSensor("kinect", "v1", depth, color, D)


def test_synthetic_kinect_folder(tmp_path):
    from bodystudio.calib.render import board_pose_facing, render_board_depth, render_board_view
    from bodystudio.capture.kinect import quantized_disparity_depth, read_depth_png

    sensor, spec = _small_sensor(), CharucoBoardSpec(3, 4, 0.1, 0.075)  # 6 corners: just enough to count
    seen = board_pose_facing([0.0, 0.0, 1.5], [0, 0, -1.0], 0.1, spec)
    away = board_pose_facing([0.0, 0.0, 1.5], [0, 0, 1.0], 0.0, spec)

    class Progress:
        def __init__(self):
            self.calls = []

        def add_task(self, description, total):
            self.calls.append(("add", description, total))
            return "task-1"

        def advance(self, task):
            self.calls.append(("advance", task))

    progress = Progress()
    n = dm.write_synthetic_kinect_views(tmp_path, sensor, spec, np.array([seen, away]), np.random.default_rng(4),
                                        progress)
    assert n == 1
    assert progress.calls == [("add", "rendering Kinect colour + depth", 2), ("advance", "task-1"),
                              ("advance", "task-1")]
    rng = np.random.default_rng(4)
    for f, T in enumerate((seen, away)):
        rgb = cv2.imread(str(tmp_path / "kinect" / "rgb" / f"{f:05d}.png"), cv2.IMREAD_UNCHANGED)
        assert np.array_equal(rgb, render_board_view(sensor.color, spec, T, rng))
        z = quantized_disparity_depth(render_board_depth(sensor.depth, spec, T), sensor.depth.fx, sensor.baseline_m,
                                      rng)
        np.testing.assert_allclose(read_depth_png(tmp_path / "kinect" / "depth" / f"{f:05d}.png"), z, atol=5e-4)
    [view] = dm.synthetic_rgbd_views(sensor, spec, np.array([seen, away]), 0.0, np.random.default_rng(4))
    assert view.corner_ids.tolist() == list(range(6))  # 6 visible corners are enough for a view
    again = dm.write_synthetic_kinect_views(tmp_path / "q", sensor, spec, np.array([seen]), np.random.default_rng(4))
    assert again == 1  # no progress bar
