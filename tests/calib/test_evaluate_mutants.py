"""calib/evaluate.py's scores against hand-built references: a ground-truth rig moved by a known similarity or
with known per-camera errors (centre in mm, rotation angle from the trace, focal error in percent), the
reprojection RMS by a per-point loop, and the uncertainty check's z-scores and Mahalanobis distance written out.
Pure numpy, no calibration is run; the file runs in well under a second.
"""

import warnings
from functools import cache
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bodystudio.calib import evaluate as ev
from bodystudio.errors import InputError
from bodystudio.geometry.camera import Camera, CameraRig, kinect_v2


def angle_deg(R):
    """Rotation angle from the trace (exact away from 0 and 180 degrees)."""
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1))))


@cache
def ground_truth():
    cams = [Camera.look_at(f"c{i}", (3 * np.sin(a), 1.2 + 0.3 * i, 3 * np.cos(a)), (0, 1.0, 0), fx=500.0 + 20 * i,
                           fy=505.0 + 20 * i, width=320, height=240, dist=[-0.05 * i, 0.01, 0, 0, 0])
            for i, a in enumerate([0.0, 1.9, 4.1])]
    return CameraRig(cams)


def moved(cam, d_centre, rotvec, dfx=0.0, dfy=0.0):
    """``cam`` with its centre moved by ``d_centre`` (m), turned by ``rotvec`` in its own frame, focal lengths off."""
    R = Rotation.from_rotvec(rotvec).as_matrix() @ cam.R
    K = cam.K.copy()
    K[0, 0] += dfx
    K[1, 1] += dfy
    c = cam.center + d_centre
    return Camera(cam.name, K, cam.dist, R, -R @ c, cam.width, cam.height)


ERRORS = {"c0": ([0.003, 0.0, -0.004], [0.01, 0.0, 0.0], 5.0, -2.0),  # 5 mm, 0.573 deg, 1 %
          "c1": ([0.0, 0.012, 0.0], [0.0, -0.02, 0.01], -1.0, 10.4),  # 12 mm, 1.28 deg, 2 %
          "c2": ([0.0, 0.0, 0.0], [0.0, 0.0, 0.0], 0.0, 0.0)}


def rms_by_hand(e, g, P):
    total, n = 0.0, 0
    for p in P:
        uv_g, z = g.project_with_depth(p[None])
        u, v = uv_g[0]
        if z[0] > 0 and 0 <= u < g.width and 0 <= v < g.height:
            total += float(np.sum((e.project(p[None])[0] - uv_g[0]) ** 2))
            n += 1
    return np.sqrt(total / n) if n else float("nan")


def test_volume_points_fill_the_capture_cylinder_by_area():
    P = ev.volume_points()
    assert P.shape == (2000, 3)
    np.testing.assert_array_equal(P, ev.volume_points(2000, 0))
    rng = np.random.default_rng(0)  # the construction written out: radius by area, then angle, then height
    r, a, y = np.sqrt(rng.random(2000)), rng.uniform(0, 2 * np.pi, 2000), rng.uniform(0.0, 2.2, 2000)
    np.testing.assert_allclose(P, np.c_[r * np.sin(a), y, r * np.cos(a)], atol=1e-15)
    r2 = P[:, 0] ** 2 + P[:, 2] ** 2
    assert r2.max() <= 1.0 and abs(r2.mean() - 0.5) < 0.02  # uniform by area: E[r^2] = 1/2
    assert P[:, 1].min() >= 0.0 and P[:, 1].max() <= 2.2 and P[:, 1].max() > 2.15
    assert ev.volume_points(7, seed=3).shape == (7, 3) and not np.allclose(ev.volume_points(7, 3), ev.volume_points(7))


def test_floor_aligned_scores_are_the_hand_computed_errors():
    gt = ground_truth()
    est = CameraRig([moved(gt[n], *ERRORS[n]) for n in gt.names] + [Camera.look_at("extra", (0, 1, 4), (0, 1, 0))])
    report = {"reproj_rms_px": 0.42, "cameras": {"c0": {"reproj_rms_px": 0.3}, "c2": {"reproj_rms_px": 0.7}}}
    out = ev.evaluate_calibration(est, gt, report)
    assert out["align"] == "floor" and list(out["cameras"]) == ["c0", "c1", "c2"]
    P = ev.volume_points()
    for n, (dc, rv, dfx, dfy) in ERRORS.items():
        e, g = est[n], gt[n]
        c = out["cameras"][n]
        assert c["center_err_mm"] == pytest.approx(1000 * np.linalg.norm(dc), abs=1e-9)
        assert c["rot_err_deg"] == pytest.approx(np.degrees(np.linalg.norm(rv)), abs=1e-6)
        assert c["focal_err_pct"] == pytest.approx(100 * max(abs(dfx) / g.fx, abs(dfy) / g.fy), abs=1e-12)
        assert c["volume_reproj_rms_px"] == pytest.approx(rms_by_hand(e, g, P), rel=1e-12, abs=1e-12)
        assert all(type(v) is float for v in c.values())
    assert out["cameras"]["c0"]["reproj_rms_px"] == 0.3 and "reproj_rms_px" not in out["cameras"]["c1"]
    assert out["cameras"]["c1"]["volume_reproj_rms_px"] > 1.0 and out["cameras"]["c2"]["volume_reproj_rms_px"] < 1e-9
    # overall = means over cameras, max = the worst camera; the report's overall RMS passed on
    assert list(out["overall"]) == ["center_err_mm", "rot_err_deg", "focal_err_pct", "volume_reproj_rms_px",
                                    "reproj_rms_px"]
    for k in ("center_err_mm", "rot_err_deg", "focal_err_pct", "volume_reproj_rms_px"):
        vals = [out["cameras"][n][k] for n in ERRORS]
        assert out["overall"][k] == pytest.approx(sum(vals) / 3, abs=1e-12)
        assert out["max"][k] == max(vals)
    assert out["overall"]["reproj_rms_px"] == 0.42 and list(out["max"]) == list(out["overall"])
    assert out["max"]["reproj_rms_px"] == 0.7  # over the cameras the report covers (c1 has none)
    del report["reproj_rms_px"]
    assert ev.evaluate_calibration(est, gt, report)["overall"]["reproj_rms_px"] == pytest.approx(0.5, abs=1e-12)
    # the first camera without a figure: it is still reported
    late = ev.evaluate_calibration(est, gt, {"cameras": {"c1": {"reproj_rms_px": 0.25}}})
    assert late["overall"]["reproj_rms_px"] == 0.25 and late["max"]["reproj_rms_px"] == 0.25


def test_report_without_per_camera_figures_and_no_report():
    gt = ground_truth()
    out = ev.evaluate_calibration(gt, gt, {"reproj_rms_px": 0.5})
    assert out["overall"]["reproj_rms_px"] == 0.5 and "reproj_rms_px" not in out["cameras"]["c0"]
    assert "reproj_rms_px" not in out["max"]
    plain = ev.evaluate_calibration(gt, gt)
    assert "reproj_rms_px" not in plain["overall"]
    assert all(v == 0 for v in plain["max"].values())


def test_a_camera_that_sees_no_volume_point_scores_nan():
    gt = CameraRig([Camera.look_at("away", (0, 1, 5), (0, 1, 10), width=100, height=100)])
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no mean of an empty selection
        out = ev.evaluate_calibration(gt, gt)
    assert np.isnan(out["cameras"]["away"]["volume_reproj_rms_px"]) and out["cameras"]["away"]["center_err_mm"] == 0


def test_volume_points_near_the_camera_count():
    """A camera standing at the volume's edge: in-view points from 5 cm to 2 m deep, all scored."""
    g = Camera.look_at("near", (0.0, 1.1, 1.05), (0.0, 1.0, -1.0), fx=300.0, width=640, height=480)
    e = moved(g, [0.002, 0.0, 0.0], [0.0, 0.004, 0.0])
    P = ev.volume_points()
    uv, z = g.project_with_depth(P)
    seen = g.in_image(uv) & (z > 0)
    assert (z[seen] < 1.0).sum() > 50 and (z[seen] > 1.0).sum() > 50
    out = ev.evaluate_calibration(CameraRig([e]), CameraRig([g]))
    assert out["cameras"]["near"]["volume_reproj_rms_px"] == pytest.approx(rms_by_hand(e, g, P), rel=1e-12)


def test_similarity_alignment_removes_a_moved_and_scaled_world():
    gt = ground_truth()
    s, Q, b = 1.7, Rotation.from_rotvec([0.3, -0.2, 0.5]).as_matrix(), np.array([0.4, -1.0, 2.0])
    est = []
    for g in gt:  # the same cameras in a world x' = s Q x + b: centres move, rotations turn by Q
        R = g.R @ Q.T
        est.append(Camera(g.name, g.K, g.dist, R, -R @ (s * Q @ g.center + b), g.width, g.height))
    est = CameraRig(est)
    floor = ev.evaluate_calibration(est, gt)
    assert floor["align"] == "floor" and floor["overall"]["rot_err_deg"] == pytest.approx(angle_deg(Q), abs=1e-6)
    for g in gt:
        assert floor["cameras"][g.name]["center_err_mm"] == \
            pytest.approx(1000 * np.linalg.norm(s * Q @ g.center + b - g.center), rel=1e-9)
    sim = ev.evaluate_calibration(est, gt, align="similarity")
    assert sim["align"] == "similarity"
    for k in ("center_err_mm", "rot_err_deg", "focal_err_pct", "volume_reproj_rms_px"):
        assert sim["max"][k] == pytest.approx(0.0, abs=1e-6), k
    aligned = ev._aligned(est, gt)
    for g in gt:
        a = aligned[g.name]
        assert a.name == g.name
        np.testing.assert_allclose(a.center, g.center, atol=1e-9)
        np.testing.assert_allclose(a.R, g.R, atol=1e-12)
        np.testing.assert_array_equal(a.K, g.K)
        np.testing.assert_array_equal(a.dist, g.dist)
        assert (a.width, a.height) == (g.width, g.height)


def test_similarity_alignment_uses_only_the_ground_truths_cameras():
    gt = ground_truth()
    extra = Camera.look_at("extra", (9.0, 1.0, -4.0), (0, 1, 0))
    est = CameraRig(list(gt) + [extra])
    aligned = ev._aligned(est, gt)
    assert aligned.names == ["c0", "c1", "c2", "extra"]
    np.testing.assert_allclose(aligned["extra"].center, extra.center, atol=1e-9)  # the identity: it stays
    np.testing.assert_allclose(aligned["c1"].center, gt["c1"].center, atol=1e-9)


def test_refusals_word_for_word():
    gt = ground_truth()
    with pytest.raises(InputError) as exc:
        ev.evaluate_calibration(gt.subset(["c0", "c2"]), gt)
    assert str(exc.value) == "camera c1 of the ground truth is missing from the estimate; calibrate it too"
    with pytest.raises(InputError) as exc:
        ev.evaluate_calibration(gt, gt, align="umeyama")
    assert str(exc.value) == "align must be 'floor' or 'similarity', got 'umeyama'"


def test_rgbd_sensor_errors_by_hand():
    gt = kinect_v2()
    D = gt.depth_to_color.copy()
    turn = Rotation.from_rotvec([0.0, 0.02, 0.0]).as_matrix()
    D[:3, :3] = turn @ D[:3, :3]
    D[:3, 3] += [0.003, -0.004, 0.0]
    est = SimpleNamespace(depth_to_color=D, depth=moved(gt.depth, [0.0, 0.0, 0.01], [0.0, 0.0, 0.03]),
                          color=moved(gt.color, [0.02, 0.0, 0.0], [0.05, 0.0, 0.0]))
    out = ev.evaluate_rgbd_sensor(est, gt)
    assert out == pytest.approx({"depth_to_color_t_err_mm": 5.0, "depth_to_color_rot_err_deg": np.degrees(0.02),
                                 "color_center_err_mm": 20.0, "color_rot_err_deg": np.degrees(0.05),
                                 "depth_center_err_mm": 10.0, "depth_rot_err_deg": np.degrees(0.03)}, abs=1e-6)
    assert list(out) == ["depth_to_color_t_err_mm", "depth_to_color_rot_err_deg", "color_center_err_mm",
                         "color_rot_err_deg", "depth_center_err_mm", "depth_rot_err_deg"]
    assert all(type(v) is float for v in out.values())


def _uncertain(name, sig=(2.0, 2.0, 1.0, 1.0), cov=None, verdict="ok", center_sigma=3.0):
    return SimpleNamespace(name=name, fx_sigma_px=sig[0], fy_sigma_px=sig[1], cx_sigma_px=sig[2], cy_sigma_px=sig[3],
                           center_cov_mm2=np.diag([4.0, 9.0, 16.0]) if cov is None else np.asarray(cov, float),
                           center_sigma_mm=center_sigma, verdict=verdict)


def test_uncertainty_consistency_z_scores_and_mahalanobis_by_hand():
    gt = CameraRig([Camera("a", [[500.0, 0, 160], [0, 505, 120], [0, 0, 1]], None, np.eye(3), np.zeros(3), 320, 240),
                    Camera("b", [[500.0, 0, 160], [0, 505, 120], [0, 0, 1]], None, np.eye(3), [1.0, 0, 0], 320, 240)])

    def est_of(g, dK, dc_m):
        K = g.K + dK
        return Camera(g.name, K, None, g.R, -g.R @ (g.center + dc_m), g.width, g.height)

    est = CameraRig([est_of(gt["a"], [[6.0, 0, -3.0], [0, -2.0, 1.5], [0, 0, 0]], [0.002, -0.003, 0.004]),
                     est_of(gt["b"], [[1.0, 0, 0], [0, 1.0, 0], [0, 0, 0]], [0.0, 0.0, 0.0])])
    cov_a = [[4.0, 1.0, 0.0], [1.0, 9.0, 0.0], [0.0, 0.0, 16.0]]
    unc = SimpleNamespace(cameras=[_uncertain("a", cov=cov_a, verdict="uncertain", center_sigma=5.4),
                                   _uncertain("b", sig=(0.5, 0.0, 1.0, 1.0)),
                                   _uncertain("c", sig=(2.0, 2.0, 1.0, 4.0))])
    gt = CameraRig(list(gt) + [gt["a"].with_name("c")])
    est = CameraRig(list(est) + [est_of(gt["c"], [[7.0, 0, 0], [0, 0, 0], [0, 0, 0]], [0.0, 0.0, 0.0])])
    out = ev.uncertainty_consistency(est, gt, unc)
    a = out["a"]
    d = np.array([2.0, -3.0, 4.0])
    assert a == pytest.approx({"fx_err_px": 6.0, "fy_err_px": -2.0, "cx_err_px": -3.0, "cy_err_px": 1.5,
                               "fx_sigma_px": 2.0, "fy_sigma_px": 2.0, "cx_sigma_px": 1.0, "cy_sigma_px": 1.0,
                               "fx_z": 3.0, "fy_z": 1.0, "cx_z": 3.0, "cy_z": 1.5,
                               "center_err_mm": np.sqrt(29.0), "center_sigma_mm": 5.4,
                               "center_mahalanobis2": d @ np.linalg.inv(cov_a) @ d, "verdict": "uncertain",
                               "within_3sigma": True}, abs=1e-9)
    assert list(a) == ["fx_err_px", "fy_err_px", "cx_err_px", "cy_err_px", "fx_sigma_px", "fy_sigma_px",
                       "cx_sigma_px", "cy_sigma_px", "fx_z", "fy_z", "cx_z", "cy_z", "center_err_mm",
                       "center_sigma_mm", "center_mahalanobis2", "verdict", "within_3sigma"]
    assert a["within_3sigma"] is True and a["fx_z"] == 3.0  # |z| = 3 exactly is within
    b = out["b"]
    assert b["fx_z"] == 2.0 and b["fy_z"] == float("inf") and b["within_3sigma"] is False  # a zero sigma
    assert b["center_mahalanobis2"] == 0.0
    c = out["c"]
    assert c["fx_z"] == 3.5 and c["center_mahalanobis2"] == 0.0 and c["within_3sigma"] is False  # 3.5 sigma is out
    assert list(out) == ["a", "b", "c"]
    assert all(type(v) is float for k, v in b.items() if k not in ("verdict", "within_3sigma"))


@pytest.mark.parametrize(("dc_m", "cov", "maha2", "within"), [
    ([0.0, 0.0, 0.0101], np.diag([1.0, 1.0, 8.0]), 102.01 / 8.0, True),  # 12.75 <= 14.156
    ([0.0, 0.0, 0.011], np.diag([1.0, 1.0, 8.0]), 121.0 / 8.0, False),  # 15.1 > 14.156
    ([0.0, 0.0, 5e-10], np.diag([1.0, 1.0, 0.0]), 0.0, True),  # singular: 5e-7 mm counts as no error
    ([0.0, 0.0, 5e-10], np.diag([1.0, np.inf, 1.0]), 0.0, True),  # non-finite: the same
    ([0.0, 0.0, 2e-6], np.diag([1.0, 1.0, 0.0]), float("inf"), False),  # singular, 2e-3 mm off: unbounded
    ([0.0, 0.0, 2e-6], np.diag([np.nan, 1.0, 1.0]), float("inf"), False),
])
def test_mahalanobis_bound_and_degenerate_covariances(dc_m, cov, maha2, within):
    g = Camera("a", [[500.0, 0, 160], [0, 505, 120], [0, 0, 1]], None, np.eye(3), np.zeros(3), 320, 240)
    e = Camera("a", g.K, None, g.R, -(g.center + dc_m), 320, 240)
    unc = SimpleNamespace(cameras=[_uncertain("a", cov=cov)])
    out = ev.uncertainty_consistency(CameraRig([e]), CameraRig([g]), unc)
    assert out["a"]["center_mahalanobis2"] == pytest.approx(maha2, rel=1e-9)
    assert out["a"]["within_3sigma"] is within
    assert ev.CHI2_3DOF_3SIGMA == 14.156
