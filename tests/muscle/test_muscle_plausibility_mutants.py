"""Fast analytic tests of the arm capture's self-checks (muscle/plausibility.py), for mutation testing (issue 17).

tests/reliability/test_muscle_plausibility.py builds Kinect sessions and captures them (minutes); here hand-made
arrays: a pinhole depth camera at the origin looking along +z, depth maps with known readings, tracked joints at
known places, figures dicts on each side of every threshold of ``capture_verdict``, a stand-in session for
``session_checks``, and the small helpers (segment distances, regions, medians, the shape range, JSON safety).
"""

from types import SimpleNamespace

import numpy as np
import pytest

W, H, F = 64, 48, 50.0


def _camera():
    from bodystudio.geometry.camera import Camera

    K = np.array([[F, 0.0, W / 2], [0.0, F, H / 2], [0.0, 0.0, 1.0]])
    return Camera("depth", K, np.zeros(5), np.eye(3), np.zeros(3), W, H)


def test_segment_distances():
    from bodystudio.muscle.plausibility import segment_distances

    a, b = np.array([0.0, 0.0, 0.0]), np.array([2.0, 0.0, 0.0])
    P = np.array([[1.0, 3.0, 0.0], [-1.0, 0.0, 0.0], [4.0, 0.0, 4.0], [0.5, 0.0, -0.25], [2.0, 1.0, 0.0]])
    np.testing.assert_allclose(segment_distances(P, a, b), [3.0, 1.0, np.hypot(2.0, 4.0), 0.25, 1.0])
    # a degenerate segment: distance to the point
    np.testing.assert_allclose(segment_distances(P, a, a), np.linalg.norm(P, axis=1))


def test_region_of_vertices():
    from bodystudio.muscle.plausibility import region_of_vertices

    Wt = np.array([[0.7, 0.3, 0, 0], [0.2, 0.5, 0.3, 0], [0, 0.3, 0.6, 0.1], [0, 0, 0.4, 0.6], [0, 0.5, 0.4, 0.1]])
    reg = region_of_vertices(Wt)
    assert list(reg) == ["upperarm", "forearm"]
    assert reg["upperarm"].tolist() == [False, True, False, False, True]
    assert reg["forearm"].tolist() == [False, False, True, False, False]


def test_tracked_arm():
    from bodystudio.muscle.plausibility import tracked_arm

    names = ["Head", "WristLeft", "ShoulderLeft", "ElbowLeft", "ShoulderRight", "ElbowRight"]
    pos = np.arange(18, dtype=float).reshape(6, 3)
    J = tracked_arm({"names": names, "positions": pos.tolist()}, "left")
    np.testing.assert_array_equal(J, pos[[2, 3, 1]])
    assert J.dtype == np.float64
    assert tracked_arm({"names": names, "positions": pos}, "right") is None  # no WristRight
    assert tracked_arm(None, "left") is None


def test_depth_to_tracker_ratio():
    from bodystudio.muscle.plausibility import depth_to_tracker_ratio

    cam = _camera()
    D = np.zeros((H, W))
    # joint 0 at (u, v) = (20, 10), z 1.0: readings 0.95 in the 5x5 window (one zero, one NaN ignored)
    D[8:13, 18:23] = 0.95
    D[10, 20] = 0.0
    D[9, 19] = np.nan
    D[12, 22] = 1.05  # the median of 23 readings stays 0.95
    # joint 1 at (40, 30), z 2.0: window of radius 1 at a border-free place, readings 1.0 and 3.0 -> median 2.0
    D[29:32, 39:42] = 1.0
    D[29:31, 39:42] = 3.0  # 6 x 3.0, 3 x 1.0 -> median 3.0
    # joint 2 behind the camera; joint 3 projects outside the image; joint 4 at (2, 1) (window clipped), z 0.5
    D[0:3, 0:4] = 0.6
    D[4, 0] = 100.0  # outside the clipped window of radius 2 around (2, 1)
    J = np.array([[(20 - W / 2) / F * 1.0, (10 - H / 2) / F * 1.0, 1.0],
                  [(40 - W / 2) / F * 2.0, (30 - H / 2) / F * 2.0, 2.0],
                  [0.0, 0.0, -1.0], [5.0, 0.0, 1.0],
                  [(2 - W / 2) / F * 0.5, (1 - H / 2) / F * 0.5, 0.5],
                  [(60 - W / 2) / F * 1.0, (40 - H / 2) / F * 1.0, 1.0]])  # joint 5: no reading
    r = depth_to_tracker_ratio(D, cam, J)
    np.testing.assert_allclose(r[[0, 4]], [0.95, 0.6 / 0.5])
    assert np.isnan(r[[2, 3, 5]]).all()
    r1 = depth_to_tracker_ratio(D, cam, J, window_px=1)
    np.testing.assert_allclose(r1[1], 3.0 / 2.0)
    D2 = D.copy()
    D2[10, 20] = np.inf  # an infinite reading counts as none
    D2[8:13, 18:23] = np.where(np.isfinite(D2[8:13, 18:23]), D2[8:13, 18:23], np.inf)
    np.testing.assert_allclose(depth_to_tracker_ratio(D2, cam, J)[0], 0.95)
    # the edge of the image: u = w - 1 and v = h - 1 are inside, u = w is not
    J2 = np.array([[(W - 1 - W / 2) / F, (H - 1 - H / 2) / F, 1.0], [(W - W / 2) / F, 0.0, 1.0],
                   [(0 - W / 2) / F, (0 - H / 2) / F, 1.0]])
    D3 = np.full((H, W), 0.9)
    r3 = depth_to_tracker_ratio(D3, cam, J2)
    np.testing.assert_allclose(r3[[0, 2]], [0.9, 0.9])
    assert np.isnan(r3[1])


def test_arm_geometry():
    from bodystudio.geometry.camera import Camera
    from bodystudio.muscle.plausibility import arm_geometry

    cam = _camera()
    d, ang = arm_geometry(np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 3.0], [9.0, 9.0, 9.0]]), cam)
    assert d == pytest.approx(2.0) and ang == pytest.approx(0.0, abs=1e-6)
    d, ang = arm_geometry(np.array([[1.0, 0.0, 1.0], [1.0, 0.0, 1.0], [0, 0, 0]]), cam)
    assert d == pytest.approx(np.sqrt(2.0)) and ang == pytest.approx(45.0)
    d, ang = arm_geometry(np.array([[0.0, 0.0, -1.0], [0.0, 0.0, -1.0], [0, 0, 0]]), cam)
    assert ang == pytest.approx(180.0)
    # a camera away from the origin: the distance from its centre
    moved = Camera("d", cam.K, np.zeros(5), np.eye(3), np.array([0.0, 0.0, -1.0]), W, H)  # centre at z = 1
    d, ang = arm_geometry(np.array([[0.0, 0.0, 2.0], [0.0, 0.0, 4.0], [0, 0, 0]]), moved)
    assert d == pytest.approx(2.0)
    assert arm_geometry(np.zeros((3, 3)), cam) == (0.0, 90.0)


def test_median_figures():
    from bodystudio.muscle.plausibility import _median_figures

    inf, nan = float("inf"), float("nan")
    rows = [{"upperarm": {"residual_mm": 3.0, "explained": 0.9}, "forearm": {"residual_mm": inf, "explained": nan},
             "points_explained": 0.5, "sampling_mm": nan},
            {"upperarm": {"residual_mm": 5.0, "explained": 0.7}, "forearm": {"residual_mm": nan, "explained": nan},
             "points_explained": 0.9, "sampling_mm": 2.0},
            {"upperarm": {"residual_mm": 10.0, "explained": 0.2}, "forearm": {"residual_mm": inf, "explained": nan},
             "points_explained": inf, "sampling_mm": 4.0}]
    out = _median_figures(rows)
    assert out["upperarm"] == {"residual_mm": 5.0, "explained": 0.7}
    assert out["forearm"] == {"residual_mm": inf, "explained": 0.0}
    assert out["points_explained"] == pytest.approx(0.7) and out["sampling_mm"] == pytest.approx(3.0)
    out = _median_figures(rows[:1])
    assert np.isnan(out["sampling_mm"]) and out["points_explained"] == 0.5
    assert set(out) == {"upperarm", "forearm", "points_explained", "sampling_mm"}


def test_shape_extrapolation():
    from bodystudio.muscle.plausibility import shape_extrapolation

    model = SimpleNamespace(shape_range=lambda: {"bmi": (20.0, 30.0), "muscularity": (0.2, 0.6),
                                                 "height_m": (1.6, 1.8), "arm_length_m": (0.7, 0.7)})
    shape = SimpleNamespace(bmi=25.0, muscularity=0.1, height_m=1.9, arm_length_m=0.7000001)
    out = shape_extrapolation(shape, model)
    assert list(out) == ["bmi", "muscularity", "height_m", "arm_length_m"]
    assert out["bmi"] == {"value": 25.0, "range": [20.0, 30.0], "outside": 0.0}
    assert out["muscularity"]["outside"] == pytest.approx(0.25)
    assert out["height_m"]["outside"] == pytest.approx(0.5)
    assert out["arm_length_m"]["outside"] == pytest.approx(100.0, rel=1e-3)  # 1e-7 over a 1e-9 floor
    assert isinstance(out["bmi"]["value"], float)


def test_json_safe():
    from bodystudio.muscle.plausibility import _json_safe

    v = {"a": float("nan"), "b": [1.0, float("inf"), (np.float32(2.5), -np.inf)], "c": {"d": np.float64(3.0)},
         "e": "x", "f": 3}
    out = _json_safe(v)
    assert out == {"a": None, "b": [1.0, None, [2.5, None]], "c": {"d": 3.0}, "e": "x", "f": 3}
    assert type(out["c"]["d"]) is float and type(out["b"][2][0]) is float


# --- capture_verdict ----------------------------------------------------------------------------------

def _clean(**over):
    f = {"depth_to_tracker_ratio": 0.95, "arm_distance_m": {"left": 1.0, "right": 1.3},
         "arm_off_axis_deg": {"left": 5.0, "right": 20.0}, "sampling_at_1m_mm": 2.7, "sampling_at_arm_mm": 2.7,
         "mode": "full", "upperarm": {"residual_mm": 5.0, "explained": 0.9},
         "forearm": {"residual_mm": 6.0, "explained": 0.9}, "points_explained": 0.99, "sampling_mm": 2.5,
         "tracker_joint_residual_mm": {"shoulder": 20.0, "elbow": 15.0, "wrist": 10.0}}
    f.update(over)
    return f


def _verdict(f, side="left", path="s1"):
    from bodystudio.muscle.plausibility import capture_verdict

    return capture_verdict(f, side, path)


def test_verdict_clean_and_thresholds():
    v = _verdict(_clean())
    assert v["ok"] is True and v["problems"] == [] and v["warnings"] == []
    assert v["thresholds"] == {"depth_ratio_range": [0.88, 1.03], "side_nearer_m": 0.15, "far_m": 1.3,
                               "sampling_warn_mm": 3.5, "residual_refuse_mm": 20.0, "points_explained_refuse": 0.8,
                               "residual_warn_mm": 11.0, "points_explained_warn": 0.95,
                               "joint_residual_warn_mm": 45.0, "shape_outside_warn": 0.1,
                               "sex_outside_warn": 0.5}
    assert v["figures"]["upperarm"] == {"residual_mm": 5.0, "explained": 0.9}
    assert _verdict(_clean(sampling_mm=float("nan")))["figures"]["sampling_mm"] is None
    # every threshold's own value passes
    edge = _clean(depth_to_tracker_ratio=1.03, sampling_mm=3.5, points_explained=0.95,
                  upperarm={"residual_mm": 11.0, "explained": 0.9},
                  tracker_joint_residual_mm={"shoulder": 45.0, "elbow": 1.0, "wrist": 1.0})
    assert _verdict(edge)["warnings"] == [] and _verdict(edge)["ok"]
    assert _verdict(_clean(depth_to_tracker_ratio=0.88))["ok"]
    assert _verdict(_clean(arm_distance_m={"left": 1.3, "right": 1.6}))["ok"]  # 1.3 m is inside the window
    assert _verdict({})["ok"] and _verdict({})["warnings"] == []


def test_verdict_depth_ratio():
    v = _verdict(_clean(depth_to_tracker_ratio=9.5), path="/data/s1")
    assert v["ok"] is False
    assert v["problems"] == [
        "the depth where the tracked left arm's joints are reads 9.5x their distance, 9.50 m: no arm in range of the "
        "0.5-1.3 m depth window (a consistent session: 0.94-0.98): the depth is in another unit or the tracker "
        "belongs to another recording; check the unit of /data/s1/kinect/depth (re-import with the right "
        "--depth-scale) and /data/s1/kinect/calibration.json"]
    v = _verdict(_clean(depth_to_tracker_ratio=1.048))
    assert v["problems"][0].startswith("the depth where the tracked left arm's joints are reads 1.05x their distance "
                                       "(a consistent")
    v = _verdict(_clean(depth_to_tracker_ratio=0.87))
    assert len(v["problems"]) == 1 and "reads 0.87x their distance (a" in v["problems"][0]
    v = _verdict(_clean(depth_to_tracker_ratio=0.45, arm_distance_m={"left": 1.0, "right": 1.3}))
    assert "0.45 m: no arm in range" in v["problems"][0]
    v = _verdict(_clean(depth_to_tracker_ratio=0.2, arm_distance_m={"left": 2.5, "right": 2.8}), path=None)
    assert "reads 0.2x their distance, 0.50 m: no arm" in v["problems"][0]  # 0.5 is not inside (strict)
    assert "unit of kinect/depth" in v["problems"][0]
    v = _verdict(_clean(depth_to_tracker_ratio=0.5, arm_distance_m={"left": 2.6, "right": 2.8}))
    assert "reads 0.5x their distance, 1.30 m: no arm" in v["problems"][0]  # 1.3 is not inside (strict)
    v = _verdict(_clean(depth_to_tracker_ratio=0.5, arm_distance_m={"left": 1.0, "right": 1.3}))
    assert "0.50 m: no arm in range" in v["problems"][0]
    v = _verdict(_clean(depth_to_tracker_ratio=1.2, arm_distance_m={"right": 1.0}))
    assert "reads 1.2x their distance (a" in v["problems"][0]
    assert _verdict(_clean(depth_to_tracker_ratio=float("nan")))["ok"]
    v = _verdict(_clean(depth_to_tracker_ratio=2.0), side="right")
    assert v["problems"][0].startswith("the depth where the tracked right arm's joints are reads 2x their "
                                       "distance, 2.60 m")


def test_verdict_side_and_distance():
    v = _verdict(_clean(arm_distance_m={"left": 1.35, "right": 1.2},
                        arm_off_axis_deg={"left": 30.0, "right": 4.0}))
    assert v["problems"] == [
        "the Kinect faces the right arm (1.20 m away, 4 deg off its axis) while the capture is of the left arm "
        "(1.35 m, 30 deg): the session records the right arm; capture it with --side right and a model built with "
        "--side right"]
    v = _verdict(_clean(arm_distance_m={"left": 1.3, "right": 1.0}, arm_off_axis_deg={"left": 1.0, "right": 2.0}),
                 side="right")
    assert v["ok"]  # the other arm farther
    v = _verdict(_clean(arm_distance_m={"left": 1.0, "right": 1.2}, arm_off_axis_deg={"left": 1.0, "right": 2.0}),
                 side="right")
    assert v["problems"][0].startswith("the Kinect faces the left arm (1.00 m away, 1 deg")
    v = _verdict(_clean(arm_distance_m={"left": 0.5, "right": 0.649}, arm_off_axis_deg={"left": 1.0, "right": 2.0}),
                 side="right")
    assert v["ok"]  # 0.149 m nearer is not enough
    v = _verdict(_clean(arm_distance_m={"left": 0.5, "right": 0.65}, arm_off_axis_deg={"left": 1.0, "right": 2.0}),
                 side="right")
    assert not v["ok"]  # exactly 0.15 m nearer
    v = _verdict(_clean(arm_distance_m={"left": 1.6, "right": 1.9}, sampling_at_arm_mm=4.4))
    assert v["problems"] == [
        "the left arm is 1.60 m from the Kinect, beyond the capture's depth window (up to 1.3 m); there the depth "
        "samples the arm every 4.4 mm against 2.7 mm at 1 m, too sparse for the model's few-millimetre accuracy: "
        "record with the sensor about 1 m from the arm"]
    v = _verdict({"arm_distance_m": {"left": 1.6}})
    assert "every nan mm against nan mm at 1 m" in v["problems"][0]
    from bodystudio.muscle.plausibility import capture_verdict

    v = capture_verdict(_clean(arm_distance_m={"left": 1.6, "right": 1.9}), "left", "s", far_m=2.0)
    assert v["ok"] and v["thresholds"]["far_m"] == 2.0
    v = capture_verdict(_clean(depth_to_tracker_ratio=0.5, arm_distance_m={"left": 1.0, "right": 1.3}), "left", "s",
                        near_m=0.4)
    assert "0.50 m: no arm" not in v["problems"][0] and "0.4-1.3 m" not in v["problems"][0]
    v = capture_verdict(_clean(depth_to_tracker_ratio=0.5, arm_distance_m={"left": 0.7, "right": 1.3}), "left", "s",
                        near_m=0.4)
    assert "0.35 m: no arm in range of the 0.4-1.3 m depth window" in v["problems"][0]


def test_verdict_sampling_warns():
    v = _verdict(_clean(sampling_mm=3.6))
    assert v["ok"] and v["warnings"] == [
        "the depth samples the arm every 3.6 mm (at 1 m: 2.7 mm); the capture's accuracy was measured at about 1 m: "
        "expect larger errors, or record closer"]
    assert "(at 1 m: nan mm)" in _verdict({"sampling_mm": 4.0})["warnings"][0]


def test_verdict_depth_residuals():
    v = _verdict(_clean(forearm={"residual_mm": 20.5, "explained": 0.1}), path="p")
    assert v["problems"] == ["the fitted forearm does not explain the depth (its visible skin is 20 mm from the depth "
                             "points, median; consistent captures <= 9.1 mm): check p/kinect/calibration.json and "
                             "the arm side"]
    assert v["warnings"] == []  # no warning next to a problem
    assert _verdict(_clean(upperarm={"residual_mm": 20.0, "explained": 0.5}))["ok"]
    v = _verdict(_clean(points_explained=0.79))
    assert v["problems"] == ["the fitted arm explains 79% of the depth points around the tracked arm (consistent "
                             "captures >= 98%): check s1/kinect/calibration.json and the arm side"]
    assert _verdict(_clean(points_explained=float("nan")))["ok"]
    v = _verdict(_clean(points_explained=0.8))
    assert v["ok"] and len(v["warnings"]) == 1
    v = _verdict(_clean(upperarm={"residual_mm": 13.04, "explained": 0.6}, points_explained=0.912))
    assert v["ok"] and v["warnings"] == [
        "the fitted arm explains the depth less well than a consistent capture (visible skin upperarm 13.0 mm, "
        "forearm 6.0 mm from the depth points, 91% of the arm's points explained; consistent <= 9.1 mm, >= 98%): "
        "the body tracker may be out of sync with the depth (s1/kinect/joints) or the calibration off; the fitted "
        "shape and poses are suspect"]
    v = _verdict(_clean(forearm={"residual_mm": 11.01, "explained": 0.6}))
    assert len(v["warnings"]) == 1 and "forearm 11.0 mm" in v["warnings"][0]
    # the ablations (model only, NICP only) keep their figures without a verdict on them
    for mode in ("model", "nicp"):
        v = _verdict(_clean(mode=mode, forearm={"residual_mm": 50.0, "explained": 0.1}, points_explained=0.5))
        assert v["ok"] and v["warnings"] == [], mode
    v = _verdict(_clean(points_explained=0.9, upperarm=None, forearm=None))
    assert v["warnings"][0].startswith("the fitted arm explains the depth less well than a consistent capture "
                                       "(visible skin  from the depth points, 90% of")
    # a problem elsewhere silences the residual warning
    v = _verdict(_clean(points_explained=0.9, sampling_mm=2.0, arm_distance_m={"left": 1.6, "right": 1.9}))
    assert len(v["problems"]) == 1 and v["warnings"] == []


def test_verdict_joints_and_shape():
    v = _verdict(_clean(tracker_joint_residual_mm={"shoulder": 20.0, "elbow": 61.4, "wrist": 50.0}))
    assert v["ok"] and v["warnings"] == ["the fitted elbow is 61 mm from the body tracker's (median over frames; "
                                         "consistent captures <= 27 mm): the tracker or the fit is off"]
    shape = {"bmi": {"value": 32.0, "range": [18.5, 30.0], "outside": 0.174},
             "muscularity": {"value": 0.5, "range": [0.0, 1.0], "outside": 0.0},
             "height_m": {"value": 1.905, "range": [1.5, 1.9], "outside": 0.0125}}
    v = _verdict(_clean(shape=shape))
    assert v["ok"] and v["warnings"] == [
        "the subject lies outside the model's training range, so the model extrapolates (bmi 32 (trained on "
        "18.5-30)): its muscle shapes are less certain; extend the model with such subjects (muscle model extend)"]
    v = _verdict(_clean(shape=shape, shape_given=True))
    assert "(bmi 32 (trained on 18.5-30); height_m 1.91 (trained on 1.5-1.9))" in v["warnings"][0]
    shape["bmi"]["outside"] = 0.1
    assert _verdict(_clean(shape=shape))["warnings"] == []


def test_refuse_and_check_before_capture():
    from bodystudio.errors import ImplausibleResultError
    from bodystudio.muscle import plausibility as mp

    bad = mp.capture_verdict(_clean(points_explained=0.5), "left", "s9")
    with pytest.raises(ImplausibleResultError) as e:
        mp._refuse(bad, "s9", False)
    assert str(e.value) == f"s9: arm capture not written, {bad['problems'][0]}; or pass --accept-implausible"
    assert mp._refuse(bad, "s9", True) is None
    assert mp._refuse(mp.capture_verdict(_clean(), "left", "s9"), "s9", False) is None


class _Session:
    """A stand-in session: frames with a depth map and tracker joints; ``kinect.depth`` the camera."""

    def __init__(self, frames, path="sess"):
        self.kinect = SimpleNamespace(depth=_camera())
        self.frames, self.path, self.asked = frames, path, []

    def frame(self, fid):
        self.asked.append(fid)
        return self.frames[fid]


def _joints_at(z_left, z_right, x_left=-0.2, x_right=0.2):
    names = ["ShoulderLeft", "ElbowLeft", "WristLeft", "ShoulderRight", "ElbowRight", "WristRight"]
    P = [[x_left, -0.1, z_left], [x_left, 0.0, z_left], [x_left, 0.1, z_left],
         [x_right, -0.1, z_right], [x_right, 0.0, z_right], [x_right, 0.1, z_right]]
    return {"names": names, "positions": P}


def test_session_checks_and_before_capture():
    from bodystudio.errors import ImplausibleResultError
    from bodystudio.muscle import plausibility as mp

    frames = {}
    for fid, scale in zip(range(7), (0.95, 0.95, 0.96, 0.94, 0.95, 9.0, 9.0), strict=True):
        frames[fid] = SimpleNamespace(kinect_joints=_joints_at(1.0, 1.3), kinect_depth_m=np.full((H, W), scale))
    frames[1] = SimpleNamespace(kinect_joints=None, kinect_depth_m=np.full((H, W), 5.0))  # skipped: no joints
    frames[2] = SimpleNamespace(kinect_joints=_joints_at(1.0, 1.3), kinect_depth_m=None)  # skipped: no depth
    s = _Session(frames)
    out = mp.session_checks(s, list(range(7)), "left")
    assert s.asked == [0, 1, 2, 3, 4]  # the first RATIO_FRAMES frames
    assert out["depth_to_tracker_ratio"] == pytest.approx(0.95)
    assert out["sampling_at_1m_mm"] == pytest.approx(1000.0 / F)
    mid = np.array([-0.2, -0.05, 1.0])
    assert out["arm_distance_m"]["left"] == pytest.approx(np.linalg.norm(mid))
    assert out["arm_distance_m"]["right"] == pytest.approx(np.linalg.norm([0.2, -0.05, 1.3]))
    assert out["arm_off_axis_deg"]["left"] == pytest.approx(np.degrees(np.arccos(1.0 / np.linalg.norm(mid))))
    assert out["sampling_at_arm_mm"] == pytest.approx(1000.0 * np.linalg.norm(mid) / F)
    assert mp.check_before_capture(s, range(7), "left") == out
    # the geometry of the first frame with joints only: frame 3's arms elsewhere do not count
    frames[3] = SimpleNamespace(kinect_joints=_joints_at(2.0, 2.0), kinect_depth_m=np.full((H, W), 1.9))
    out3 = mp.session_checks(_Session(frames), list(range(7)), "left")
    assert out3["arm_distance_m"]["left"] == pytest.approx(np.linalg.norm(mid))
    assert out3["depth_to_tracker_ratio"] == pytest.approx(0.95)  # 6 of 12 readings 0.95, 3 of 0.95*, 3 of 0.95
    # the wrong unit: refused before the capture, unless accepted
    bad = {0: SimpleNamespace(kinect_joints=_joints_at(1.0, 1.3), kinect_depth_m=np.full((H, W), 9.0))}
    with pytest.raises(ImplausibleResultError, match=r"^sess: arm capture not written, the depth where"):
        mp.check_before_capture(_Session(bad), [0], "left")
    assert mp.check_before_capture(_Session(bad), [0], "left", accept_implausible=True)["depth_to_tracker_ratio"] \
        == pytest.approx(9.0)
    # the right arm: its own distance
    out_r = mp.session_checks(_Session(bad), [0], "right")
    assert out_r["sampling_at_arm_mm"] == pytest.approx(1000.0 * np.linalg.norm([0.2, -0.05, 1.3]) / F)
    # tracked, but no reading where the arm is: NaN ratio; no joints at all: no ratio
    empty = {0: SimpleNamespace(kinect_joints=_joints_at(1.0, 1.3), kinect_depth_m=np.zeros((H, W)))}
    assert np.isnan(mp.session_checks(_Session(empty), [0], "left")["depth_to_tracker_ratio"])
    none = {0: SimpleNamespace(kinect_joints=None, kinect_depth_m=np.zeros((H, W)))}
    out_n = mp.session_checks(_Session(none), [0], "left")
    assert out_n == {"sampling_at_1m_mm": pytest.approx(1000.0 / F)}
    # only the other arm tracked: geometry without this side's sampling
    one = {0: SimpleNamespace(kinect_joints={"names": _joints_at(1, 1)["names"][3:],
                                             "positions": _joints_at(1.0, 1.3)["positions"][3:]},
                              kinect_depth_m=np.full((H, W), 0.95))}
    assert mp.session_checks(_Session(one), [0], "left") == {"sampling_at_1m_mm": pytest.approx(1000.0 / F)}
    s_none = _Session({})
    s_none.kinect = None
    assert mp.session_checks(s_none, [0], "left") == {}


def test_depth_to_tracker_ratio_window_and_readings():
    """One reading at a time around a joint at (u, v) = (20, 10), z 1 m: counted inside the 5x5 window only;
    non-finite readings count as none; a window clipped at the image's top-left corner; a moved camera."""
    from bodystudio.geometry.camera import Camera
    from bodystudio.muscle.plausibility import depth_to_tracker_ratio

    cam = _camera()
    J = np.array([[(20 - W / 2) / F, (10 - H / 2) / F, 1.0]])
    for dv, du in ((0, 0), (-2, -2), (2, 2), (-2, 2), (2, -2), (-3, 0), (3, 0), (0, -3), (0, 3), (3, 3)):
        D = np.zeros((H, W))
        D[10 + dv, 20 + du] = 0.9
        r = depth_to_tracker_ratio(D, cam, J)[0]
        if max(abs(dv), abs(du)) <= 2:
            assert r == pytest.approx(0.9), (dv, du)
        else:
            assert np.isnan(r), (dv, du)
        r3 = depth_to_tracker_ratio(D, cam, J, window_px=3)[0]
        assert r3 == pytest.approx(0.9), (dv, du)
    for bad in (np.nan, np.inf, -np.inf):
        D = np.zeros((H, W))
        D[10, 20] = 0.8
        D[11, 21] = bad
        assert depth_to_tracker_ratio(D, cam, J)[0] == pytest.approx(0.8), bad
    # float32 depth: the median of two readings is taken in float64
    D = np.zeros((H, W), np.float32)
    D[10, 20], D[11, 21] = 0.1, 0.2
    want = (float(np.float32(0.1)) + float(np.float32(0.2))) / 2.0
    assert depth_to_tracker_ratio(D, cam, J)[0] == want
    # the corner: the window starts at row / column 0
    Jc = np.array([[(1 - W / 2) / F, (1 - H / 2) / F, 1.0]])
    D = np.zeros((H, W))
    D[0, 0] = 0.7
    assert depth_to_tracker_ratio(D, cam, Jc)[0] == pytest.approx(0.7)
    # the bottom edge: v = h is outside
    Jb = np.array([[(20 - W / 2) / F, (H - H / 2) / F, 1.0]])
    D = np.full((H, W), 0.9)
    assert np.isnan(depth_to_tracker_ratio(D, cam, Jb)[0])
    # a camera 1 m along +z (centre (0, 0, 1)): the joint's distance is from the centre
    moved = Camera("d", cam.K, np.zeros(5), np.eye(3), np.array([0.0, 0.0, -1.0]), W, H)
    Jm = np.array([[(20 - W / 2) / F * 2.0, (10 - H / 2) / F * 2.0, 3.0]])
    D = np.zeros((H, W))
    D[10, 20] = 1.8
    assert depth_to_tracker_ratio(D, moved, Jm)[0] == pytest.approx(0.9)


def test_segment_and_geometry_edges():
    from scipy.spatial.transform import Rotation

    from bodystudio.geometry.camera import Camera
    from bodystudio.muscle.plausibility import arm_geometry, segment_distances, tracked_arm

    a, b = np.array([1.0, 1.0, 0.0]), np.array([1.5, 1.0, 0.0])  # a short segment away from the origin
    P = np.array([[1.25, 2.0, 0.0], [0.0, 1.0, 0.0], [2.0, 1.0, 0.0], [1.4, 1.0, 0.3]])
    np.testing.assert_allclose(segment_distances(P, a, b), [1.0, 1.0, 0.5, 0.3])
    cam = _camera()
    d, ang = arm_geometry(np.array([[0.5, 0.0, 0.5], [0.5, 0.0, 0.5], [0, 0, 0]]), cam)
    assert d == pytest.approx(np.sqrt(0.5)) and ang == pytest.approx(45.0)
    # a mid point along the rotated optical axis whose cosine rounds to 1 + 2e-16: clipped, 0 and 180 deg
    R = Rotation.random(random_state=1).as_matrix()
    rot = Camera("r", cam.K, np.zeros(5), R, np.zeros(3), W, H)
    mid = 1.1 * R[2]
    assert arm_geometry(np.array([mid, mid, mid]), rot)[1] == 0.0
    assert arm_geometry(np.array([-mid, -mid, -mid]), rot)[1] == 180.0
    names = ["ShoulderLeft", "ElbowLeft", "WristLeft"]
    J = tracked_arm({"names": names, "positions": [[1, 2, 3], [4, 5, 6], [7, 8, 9]]}, "left")
    assert J.dtype == np.float64


def test_verdict_default_mode_and_both_regions():
    base = _clean()
    del base["mode"]
    v = _verdict({**base, "upperarm": {"residual_mm": 25.0, "explained": 0.1}})
    assert v["problems"] == ["the fitted upperarm does not explain the depth (its visible skin is 25 mm from the depth "
                             "points, median; consistent captures <= 9.1 mm): check s1/kinect/calibration.json and "
                             "the arm side"]
    v = _verdict({**base, "points_explained": 0.5})
    assert len(v["problems"]) == 1
    v = _verdict(_clean(upperarm={"residual_mm": 20.0, "explained": 0.5}))
    assert v["ok"] and len(v["warnings"]) == 1 and "upperarm 20.0 mm" in v["warnings"][0]


def test_before_capture_message_names_side_and_session():
    from bodystudio.errors import ImplausibleResultError
    from bodystudio.muscle import plausibility as mp

    bad = {0: SimpleNamespace(kinect_joints=_joints_at(1.0, 1.3), kinect_depth_m=np.full((H, W), 9.0))}
    with pytest.raises(ImplausibleResultError) as e:
        mp.check_before_capture(_Session(bad, path="/data/s7"), [0], "right")
    msg = str(e.value)
    assert msg.startswith("/data/s7: arm capture not written, the depth where the tracked right arm's joints")
    assert "check the unit of /data/s7/kinect/depth" in msg


# --- frame_depth_agreement with the depth pipeline stubbed -----------------------------------------------

def _grid(n=6, z=1.0, step=0.04):
    """A flat n x n vertex grid at depth ``z`` facing the camera, two triangles per cell."""
    xs = (np.arange(n) - (n - 1) / 2) * step
    X, Y = np.meshgrid(xs, xs)
    V = np.c_[X.ravel(), Y.ravel(), np.full(n * n, z)]
    Fc = []
    for i in range(n - 1):
        for j in range(n - 1):
            a = i * n + j
            Fc += [[a, a + 1, a + n], [a + 1, a + n + 1, a + n]]
    return V, np.array(Fc)


@pytest.fixture()
def depth_stubs():
    return SimpleNamespace(points=np.zeros((0, 3)), vis=None, options=[], depths=[], fail=False)


def _stub_depth(monkeypatch, st):
    from bodystudio.errors import InputError

    st.points, st.vis, st.options, st.depths, st.fail = np.zeros((0, 3)), None, [], [], False  # built once by
    # the direct recheck: every test starts from a fresh state
    from bodystudio.muscle import depth as md
    from bodystudio.muscle import evaluate as me

    def clean(depth, options):
        st.depths.append(depth)
        st.options.append(options)
        if st.fail:
            raise InputError("depth: no arm in range")
        return "cleaned"

    def cloud(d, camera):
        assert d == "cleaned"
        return st.points, None

    monkeypatch.setattr(md, "clean_depth", clean)
    monkeypatch.setattr(md, "depth_point_cloud", cloud)
    monkeypatch.setattr(me, "visible_vertices", lambda V, F, cam: st.vis.copy())


def test_frame_depth_agreement_figures(depth_stubs, monkeypatch):
    from bodystudio.muscle.depth import DepthCleanupOptions
    from bodystudio.muscle.plausibility import frame_depth_agreement

    st = depth_stubs
    _stub_depth(monkeypatch, st)
    cam = _camera()
    V, Fc = _grid()
    n = len(V)
    # each vertex's depth point dz behind it (the grid step 40 mm >> dz): upper half 4 mm, the rest 8 or 15 mm
    dz = np.where(np.arange(n) < n // 2, 0.004, np.where(np.arange(n) % 2 == 0, 0.008, 0.015))
    far = np.array([[0.0, 0.0, 2.5], [0.5, 0.5, 1.0]])  # two points away from the arm
    st.points = np.r_[V + np.c_[np.zeros((n, 2)), dz], far]
    st.vis = np.ones(n, bool)
    st.vis[[0, n - 1]] = False  # two hidden vertices
    regions = {"upperarm": np.arange(n) < n // 2, "forearm": np.arange(n) >= n // 2}
    tracked = np.array([[0.0, -0.2, 1.0], [0.0, 0.0, 1.0], [0.0, 0.2, 1.0]])
    out = frame_depth_agreement(V, Fc, regions, "D", cam, tracked)
    assert st.depths == ["D"] and st.options[0] == DepthCleanupOptions()
    up = regions["upperarm"] & st.vis
    fo = regions["forearm"] & st.vis
    assert out["upperarm"] == {"residual_mm": pytest.approx(4.0), "explained": 1.0, "vertices": int(up.sum())}
    assert out["forearm"]["residual_mm"] == pytest.approx(float(np.median(1000 * dz[fo])))
    assert out["forearm"]["explained"] == pytest.approx(float(np.mean(dz[fo] <= 0.010)))
    assert out["forearm"]["vertices"] == int(fo.sum()) == n // 2 - 1
    # the arm's points: within 6 cm of the tracked bones (the segment x = 0, z = 1, |y| <= 0.2)
    P = st.points
    near = (np.hypot(P[:, 0], P[:, 2] - 1.0) <= 0.06) & (np.abs(P[:, 1]) <= 0.2)
    assert 0 < near.sum() < n
    assert out["arm_points"] == int(near.sum())
    assert out["points_explained"] == pytest.approx(float(np.mean(dz[near[:n]] <= 0.010)))
    z_med = float(np.median(st.points[near, 2]))
    assert out["sampling_mm"] == pytest.approx(1000.0 * z_med / F)
    assert isinstance(out["arm_points"], int) and isinstance(out["upperarm"]["vertices"], int)
    # custom options are passed on
    opts = DepthCleanupOptions(near_m=0.2)
    frame_depth_agreement(V, Fc, regions, "D", cam, tracked, opts)
    assert st.options[-1] is opts
    # without the tracker: the points within 6 cm of the fitted vertices (the far ones are not)
    out2 = frame_depth_agreement(V, Fc, regions, "D", cam, None)
    assert out2["arm_points"] == n
    assert out2["points_explained"] == pytest.approx(float(np.mean(dz <= 0.010)))
    # a region with no visible vertex
    st.vis = np.zeros(n, bool)
    st.vis[n - 2] = True
    out3 = frame_depth_agreement(V, Fc, regions, "D", cam, tracked)
    assert np.isnan(out3["upperarm"]["residual_mm"]) and np.isnan(out3["upperarm"]["explained"])
    assert out3["upperarm"]["vertices"] == 0 and out3["forearm"]["vertices"] == 1
    # no arm point near the tracked bones: nothing explained, no sampling
    out4 = frame_depth_agreement(V, Fc, regions, "D", cam, tracked + [5.0, 0.0, 0.0])
    assert out4["points_explained"] == 0.0 and np.isnan(out4["sampling_mm"]) and out4["arm_points"] == 0


def test_frame_depth_agreement_no_depth(depth_stubs, monkeypatch):
    from bodystudio.muscle.plausibility import frame_depth_agreement

    st = depth_stubs
    _stub_depth(monkeypatch, st)
    cam = _camera()
    V, Fc = _grid()
    n = len(V)
    st.vis = np.arange(n) % 3 == 0
    regions = {"upperarm": np.arange(n) < 10, "forearm": np.arange(n) >= 10}
    for fail in (True, False):  # the cleanup refuses (no arm in range), or no point at all
        st.fail = fail
        out = frame_depth_agreement(V, Fc, regions, "D", cam, None)
        assert out == {"upperarm": {"residual_mm": float("inf"), "explained": 0.0,
                                    "vertices": int((st.vis & regions["upperarm"]).sum())},
                       "forearm": {"residual_mm": float("inf"), "explained": 0.0,
                                   "vertices": int((st.vis & regions["forearm"]).sum())},
                       "points_explained": 0.0, "sampling_mm": pytest.approx(float("nan"), nan_ok=True),
                       "arm_points": 0}
        assert np.isnan(out["sampling_mm"])


def test_point_to_mesh():
    from bodystudio.muscle.plausibility import _point_to_mesh_m

    V, Fc = _grid()
    P = np.array([[0.0, 0.0, 1.003], [0.01, 0.02, 0.95], [0.3, 0.0, 1.0]], np.float32)
    d = _point_to_mesh_m(P, V.astype(np.float32), Fc.astype(np.int32))
    np.testing.assert_allclose(d, [0.003, 0.05, 0.3 - 0.1], atol=1e-6)
    assert d.dtype == np.float64


def test_frame_depth_agreement_edges(depth_stubs, monkeypatch):
    """Thresholds met exactly (10 mm, 6 cm count), a bent tracked arm (shoulder-elbow and elbow-wrist, not
    shoulder-wrist), one depth point only, a moved camera's sampling, the stubs' arguments."""
    from bodystudio.geometry.camera import Camera
    from bodystudio.muscle import depth as md
    from bodystudio.muscle import evaluate as me
    from bodystudio.muscle.plausibility import frame_depth_agreement

    st = depth_stubs
    _stub_depth(monkeypatch, st)
    seen = []
    monkeypatch.setattr(md, "depth_point_cloud", lambda d, camera: (seen.append(camera), st.points)[1:] + (None,))
    monkeypatch.setattr(me, "visible_vertices", lambda V, Fc, cam: (seen.append((V, Fc, cam)), st.vis.copy())[1])
    cam = Camera("d", _camera().K, np.zeros(5), np.eye(3), np.array([0.0, 0.0, -1.0]), W, H)  # centre z = 1
    V, Fc = _grid(z=0.0, step=0.5)  # vertices 0.5 m apart, the plane z = 0
    n = len(V)
    regions = {"upperarm": np.ones(n, bool), "forearm": np.zeros(n, bool)}
    st.vis = np.ones(n, bool)
    # depth points: one exactly 10 mm from vertex 0, one 9.995 mm from vertex 1 (the plane's corners), the rest 20 mm
    dz = np.full(n, 0.02)
    dz[0], dz[1] = 0.01, 0.009995
    st.points = V + np.c_[np.zeros((n, 2)), dz]
    out = frame_depth_agreement(V, Fc, regions, "D", cam, None)
    assert out["upperarm"]["explained"] == pytest.approx(2 / n)
    assert out["points_explained"] == pytest.approx(2 / n)  # the same two, by the point-to-mesh distance
    assert seen[0] is cam and seen[1][0] is not None and seen[1][1] is Fc and seen[1][2] is cam
    np.testing.assert_allclose(seen[1][0], V)
    # sampling along the optical axis from the camera centre (z = 1; the points lie behind it here: negative)
    assert out["sampling_mm"] == pytest.approx(1000.0 * float(np.median(st.points[:, 2] - 1.0)) / F)
    # exactly 6 cm from the fitted vertices counts (no tracker); 6 cm from the tracked upper arm counts
    o = np.zeros(3)  # the grid's middle vertex
    Vo, Fo = _grid(n=5, z=0.0, step=0.5)
    assert np.all(Vo[12] == o)
    regions5 = {"upperarm": np.ones(25, bool), "forearm": np.zeros(25, bool)}
    st.vis = np.ones(25, bool)
    st.points = np.array([[0.06, 0.0, 0.0], [0.0601, 0.0, 0.0]])
    out = frame_depth_agreement(Vo, Fo, regions5, "D", cam, None)
    assert out["arm_points"] == 1
    elbow = np.array([0.0, 1.0, 0.0])
    tracked = np.array([o, elbow, elbow + [1.0, 0.0, 0.0]])  # bent 90 deg at the elbow
    st.points = np.array([[0.06, 0.5, 0.0],  # exactly 6 cm off the upper arm
                          [0.5, 0.95, 0.0]])  # 5 cm off the forearm (both far from the shoulder-wrist line)
    out = frame_depth_agreement(Vo, Fo, regions5, "D", cam, tracked)
    assert out["arm_points"] == 2
    # one depth point is a depth point
    st.points = np.array([[0.0, 0.0, 0.005]])
    out = frame_depth_agreement(Vo, Fo, regions5, "D", cam, None)
    assert out["arm_points"] == 1 and out["points_explained"] == 1.0
    want = 1000.0 * float(np.median(np.linalg.norm(Vo - st.points[0], axis=1)))
    assert out["upperarm"]["residual_mm"] == pytest.approx(want)


# --- capture_checks / check_after_capture on a stand-in capture ----------------------------------------

def _row(k):
    return {"upperarm": {"residual_mm": 2.0 + k, "explained": 0.9}, "forearm": {"residual_mm": 3.0 + k,
                                                                                  "explained": 0.8},
            "points_explained": 0.99, "sampling_mm": 2.5, "arm_points": 10}


def _capture_case(monkeypatch, n=7, mode="full", stages=True, shape=True):
    from bodystudio.muscle import plausibility as mp

    seen = []

    def agreement(vertices, faces, regions, depth, camera, tracked):
        seen.append((vertices, faces, sorted(regions), depth, camera, None if tracked is None else tracked.copy()))
        return _row(vertices if isinstance(vertices, int) else 100 + vertices[0])

    monkeypatch.setattr(mp, "frame_depth_agreement", agreement)
    fitted = np.full((n, 3, 3), 0.1)
    fitted[:, 1, 0] += 0.0501234  # the fitted elbow 50.12 mm from the tracker's, the others on it
    monkeypatch.setattr(mp, "fitted_world_joints", lambda c: fitted if c.joints is not None else None)
    names = ["ShoulderLeft", "ElbowLeft", "WristLeft"]
    frames = {10 + k: SimpleNamespace(kinect_joints={"names": names, "positions": np.full((3, 3), 0.1)},
                                      kinect_depth_m=f"D{10 + k}") for k in range(n)}
    session = _Session(frames, path="sp")
    template = SimpleNamespace(part_weights=np.array([[0, 1, 0, 0], [0, 0, 1, 0]]), side="left")
    capture = SimpleNamespace(n_frames=n, frame_ids=[10 + k for k in range(n)], vertices=list(range(n)), faces="F",
                              mode=mode, joints="J", stages={"model": [[k] for k in range(n)]} if stages else None,
                              shape=SimpleNamespace(bmi=25.0, muscularity=0.9, height_m=1.8, arm_length_m=0.7)
                              if shape else None)
    model = SimpleNamespace(subjects=[1], shape_range=lambda: {"bmi": (20.0, 30.0), "muscularity": (0.0, 0.5),
                                                               "height_m": (1.6, 1.9), "arm_length_m": (0.6, 0.8)})
    return mp, capture, session, template, model, seen


def test_capture_checks_on_a_stand_in(monkeypatch):
    mp, capture, session, template, model, seen = _capture_case(monkeypatch)
    out = mp.capture_checks(capture, session, template, model, max_frames=4, shape_given=True)
    # 4 frames evenly spaced over 7: 0, 2, 4, 6
    assert session.asked == [10, 12, 14, 16]
    real = [s for s in seen if isinstance(s[0], int)]
    assert [s[0] for s in real] == [0, 2, 4, 6] and [s[3] for s in real] == ["D10", "D12", "D14", "D16"]
    assert all(s[1] == "F" and s[2] == ["forearm", "upperarm"] and s[4] is session.kinect.depth for s in real)
    np.testing.assert_array_equal(real[0][5], np.full((3, 3), 0.1))
    stage = [s for s in seen if not isinstance(s[0], int)]
    assert [s[0] for s in stage] == [[0], [2], [4], [6]] and [s[3] for s in stage] == ["D10", "D12", "D14", "D16"]
    assert all(s[1] == "F" and s[4] is session.kinect.depth for s in stage)
    np.testing.assert_array_equal(stage[0][5], np.full((3, 3), 0.1))
    assert out["frames_checked"] == 4 and out["mode"] == "full"
    assert out["upperarm"] == {"residual_mm": 2.0 + 3.0, "explained": 0.9}  # median of 2, 4, 6, 8
    assert out["forearm"]["residual_mm"] == 3.0 + 3.0 and out["points_explained"] == 0.99
    assert out["model_only"] == {"upperarm": {"residual_mm": 2.0 + 103.0, "explained": 0.9},
                                 "forearm": {"residual_mm": 3.0 + 103.0, "explained": 0.8}}
    assert out["tracker_joint_residual_mm"] == {"shoulder": 0.0, "elbow": 50.12, "wrist": 0.0}
    assert out["shape"]["muscularity"]["outside"] == pytest.approx(0.8) and out["shape_given"] is True
    # defaults: up to 40 frames (all 7 here), shape not given
    mp2, capture, session, template, model, seen = _capture_case(monkeypatch)
    out = mp2.capture_checks(capture, session, template, model)
    assert out["frames_checked"] == 7 and session.asked == list(range(10, 17)) and out["shape_given"] is False
    # no model stage / another mode / no model / no shape / a model without subjects / no fitted joints
    mp3, capture, session, template, model, seen = _capture_case(monkeypatch, mode="model", shape=False)
    capture.joints = None
    out = mp3.capture_checks(capture, session, template, model)
    assert "model_only" not in out and "shape" not in out and "tracker_joint_residual_mm" not in out
    assert out["mode"] == "model"
    mp4, capture, session, template, model, seen = _capture_case(monkeypatch, stages=False)
    out = mp4.capture_checks(capture, session, template, SimpleNamespace(subjects=[]))
    assert "model_only" not in out and "shape" not in out
    assert "shape" not in mp4.capture_checks(capture, session, template, None)
    capture.stages = {}
    assert "model_only" not in mp4.capture_checks(capture, session, template, None)
    # a frame without the tracked arm: no joint residual from it, the depth check still runs untracked
    mp5, capture, session, template, model, seen = _capture_case(monkeypatch, n=2, stages=False)
    session.frames[11] = SimpleNamespace(kinect_joints=None, kinect_depth_m="D11")
    out = mp5.capture_checks(capture, session, template, model)
    assert seen[-1][5] is None and out["tracker_joint_residual_mm"]["elbow"] == 50.12
    # the default: at most 40 frames; a model without a subjects attribute gives no shape figures
    mp7, capture, session, template, model, seen = _capture_case(monkeypatch, n=45, stages=False)
    out = mp7.capture_checks(capture, session, template, SimpleNamespace(shape_range=model.shape_range))
    assert out["frames_checked"] == 40 and "shape" not in out
    # a single frame
    mp6, capture, session, template, model, seen = _capture_case(monkeypatch, n=1, stages=False)
    assert mp6.capture_checks(capture, session, template, model)["frames_checked"] == 1


def test_check_after_capture(monkeypatch, caplog):
    import logging

    from bodystudio.errors import ImplausibleResultError

    mp, capture, session, template, model, seen = _capture_case(monkeypatch)
    before = {"depth_to_tracker_ratio": 0.95, "sampling_at_1m_mm": 2.7}
    with caplog.at_level(logging.INFO, logger="bodystudio.muscle.plausibility"):
        v = mp.check_after_capture(capture, session, template, model, before)
    assert v["ok"] and v["figures"]["depth_to_tracker_ratio"] == 0.95 and v["figures"]["frames_checked"] == 7
    assert v["figures"]["shape_given"] is False
    assert v["warnings"] and v["warnings"][0].startswith("the fitted elbow is 50 mm")
    msgs = [r.getMessage() for r in caplog.records if r.name == "bodystudio.muscle.plausibility"]
    assert msgs == [f"sp: {w}" for w in v["warnings"]]
    v = mp.check_after_capture(capture, session, template, model, before, shape_given=True)
    assert v["figures"]["shape_given"] is True
    # a problem (the depth in another unit) refuses the capture, naming the session and the capture's side
    bad = {**before, "depth_to_tracker_ratio": 5.0}
    with pytest.raises(ImplausibleResultError, match=r"^sp: arm capture not written, the depth where the tracked left"):
        mp.check_after_capture(capture, session, template, model, bad)
    v = mp.check_after_capture(capture, session, template, model, bad, accept_implausible=True)
    assert "check the unit of sp/kinect/depth" in v["problems"][0]
    n0 = len(caplog.records)  # (no caplog.clear(): the direct recheck's caplog has none)
    with caplog.at_level(logging.INFO, logger="bodystudio.muscle.plausibility"):
        v = mp.check_after_capture(capture, session, template, model, bad, accept_implausible=True)
    assert not v["ok"]
    msgs = [r.getMessage() for r in caplog.records[n0:] if r.name == "bodystudio.muscle.plausibility"]
    assert msgs[-1] == f"sp: {v['problems'][0]}" and len(msgs) == len(v["warnings"]) + len(v["problems"])


def test_fitted_world_joints(monkeypatch):
    from bodystudio.muscle import nicp, refine
    from bodystudio.muscle.plausibility import fitted_world_joints

    monkeypatch.setattr(refine, "posed_joints", lambda joints, p: joints * p)
    monkeypatch.setattr(nicp, "apply_similarity", lambda sim, X: sim * X + 1.0)
    J = np.arange(9.0).reshape(3, 3)
    cap = SimpleNamespace(joints=J, poses=[1.0, 2.0], similarity=10.0)
    out = fitted_world_joints(cap)
    np.testing.assert_allclose(out, np.stack([10.0 * J + 1.0, 20.0 * J + 1.0]))
    assert fitted_world_joints(SimpleNamespace(joints=None, poses=[1.0], similarity=1.0)) is None
    assert fitted_world_joints(SimpleNamespace(joints=J, poses=[], similarity=1.0)) is None
    assert fitted_world_joints(SimpleNamespace(joints=J, poses=[None], similarity=1.0)) is None
