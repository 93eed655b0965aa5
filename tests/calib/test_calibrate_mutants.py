"""Analytic and tiny-case tests of every stage of bodystudio.calib.calibrate (issue 17, mutation testing):
projection against OpenCV, the camera graph and board-pose initialisation on hand-made view poses with a
known weighted answer, the robust losses in closed form, Levenberg-Marquardt on a problem with a known
minimum, the bundle adjustment recovering a perturbed noise-free rig exactly, the MAD threshold, the world
frame and the floor plane. Each test runs in about a second (the bundle adjustment ones share a fixture)."""

import functools
import logging
import re

import cv2
import numpy as np
import pytest

from bodystudio.calib import calibrate as cal
from bodystudio.calib.board import CharucoBoardSpec, board_corners
from bodystudio.calib.evaluate import evaluate_calibration
from bodystudio.calib.observations import CharucoObservations, observations_from_views
from bodystudio.calib.synthetic import calibration_board_poses, floor_board_pose, synthetic_charuco_observations
from bodystudio.calib.world import floor_board_to_world, rigid, rigid_inverse
from bodystudio.errors import InputError, SessionError
from bodystudio.geometry.camera import ring_rig

from .conftest import NOISE_PX


@functools.cache
def _capture():
    """conftest's small capture (4 cameras, 10 boards, 640x480, 0.2 px), cached per process: the inputs do
    not depend on calibrate.py, so mutmut's forked test runs inherit them instead of re-planning the boards."""
    spec = CharucoBoardSpec()
    rig = ring_rig(4, width=640, height=480)
    rng = np.random.default_rng(1)
    poses = calibration_board_poses(rig, spec, 10, rng)
    obs = synthetic_charuco_observations(rig, spec, poses, NOISE_PX, rng)
    return spec, rig, poses, obs


@pytest.fixture(scope="module")
def small_capture():
    return _capture()


@pytest.fixture(scope="module")
def calibrated(small_capture):
    """The whole calibration of the small capture with 12 corners displaced by 15 px (every 97th)."""
    spec, rig, poses, obs = small_capture
    uv = obs.uv.copy()
    bad = np.arange(0, len(uv), 97)
    uv[bad] += [12.0, -9.0]
    dirty = CharucoObservations(obs.camera_names, obs.image_sizes, obs.frame_ids, obs.camera, obs.frame,
                                obs.corner_id, uv)
    records = []

    class Keep(logging.Handler):
        def emit(self, record):
            records.append(record)

    logger = logging.getLogger("bodystudio.calib.calibrate")
    handler, level = Keep(logging.INFO), logger.level
    logger.addHandler(handler)
    logger.setLevel(logging.INFO)
    try:
        res = cal.calibrate_cameras(dirty, spec)
    finally:
        logger.removeHandler(handler)
        logger.setLevel(level)
    return res, bad, [r.getMessage() for r in records]


def _tilted_about_own_x(spec, T, deg):
    """Board pose ``T`` turned by ``deg`` about the board's own x axis through its centre."""
    c = spec.center_m
    return T @ rigid(np.eye(3), c) @ rigid(_rot([1, 0, 0], deg), np.zeros(3)) @ rigid(np.eye(3), -c)


def _T(cam):
    return rigid(cam.R, cam.t)


def _rot(axis, deg):
    axis = np.asarray(axis, float)
    return cv2.Rodrigues(axis / np.linalg.norm(axis) * np.radians(deg))[0]


def _truth(small_capture):
    return _truth_cached()


@functools.cache
def _truth_cached():
    """Noise-free observations of the small capture and the true parameters in the root camera's frame."""
    spec, rig, poses, _ = _capture()
    obs = synthetic_charuco_observations(rig, spec, poses, 0.0, np.random.default_rng(0))
    cams = [rig[n] for n in obs.camera_names]
    intr = np.array([[c.K[0, 0], c.K[1, 1], c.K[0, 2], c.K[1, 2], *c.dist[:5]] for c in cams])
    root = 1
    T_root = _T(cams[root])
    cam_from_root = np.array([_T(c) @ rigid_inverse(T_root) for c in cams])
    boards = np.array([T_root @ P for P in poses])
    return spec, rig, poses, obs, intr, root, cam_from_root, boards


@pytest.fixture(scope="module")
def noise_free_ba(small_capture):
    """Bundle adjustment of the noise-free capture from a perturbed start (k3 held at 0: the truth's is 0)."""
    spec, rig, poses, obs, intr, root, cam_from_root, boards = _truth(small_capture)
    rng = np.random.default_rng(5)
    intr0 = intr.copy()
    intr0[:, :4] *= 1 + rng.uniform(-0.01, 0.01, (len(intr), 4))
    intr0[:, 4:8] += rng.uniform(-0.005, 0.005, (len(intr), 4))
    cams0 = cam_from_root.copy()
    for c in range(len(cams0)):
        if c != root:
            cams0[c] = rigid(_rot(rng.normal(size=3), 0.5), rng.uniform(-0.01, 0.01, 3)) @ cams0[c]
    boards0 = np.array([B @ rigid(_rot(rng.normal(size=3), 0.5), rng.uniform(-0.01, 0.01, 3)) for B in boards])
    mask = np.ones(len(obs), bool)
    mask[::7] = False  # a mask leaves those observations out of the adjustment
    ba = cal.bundle_adjust(obs, spec, intr0, cams0, boards0, root, mask, 4, "linear", 1.0, 50)
    return ba, (spec, rig, poses, obs, intr, root, cam_from_root, boards), (intr0, cams0, boards0, mask)


# --- geometry ------------------------------------------------------------------------------------

def test_rodrigues_of_zero_and_tiny_vectors_is_the_identity():
    R = cal.rodrigues(np.array([[0.0, 0.0, 0.0], [1e-14, -2e-14, 0.0], [0.0, 0.0, np.pi / 2]]))
    np.testing.assert_array_equal(R[0], np.eye(3))
    np.testing.assert_allclose(R[1], np.eye(3), atol=1e-13)
    np.testing.assert_allclose(R[2], [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-15)


def test_project_observations_matches_opencv_with_every_distortion_term():
    rng = np.random.default_rng(2)
    C, F = 2, 3
    intr = np.array([[800.0, 810.0, 330.0, 235.0, -0.12, 0.05, 0.002, -0.003, 0.01],
                     [600.0, 590.0, 300.0, 250.0, 0.08, -0.02, -0.001, 0.004, -0.02]])
    cam_R = np.array([_rot(rng.normal(size=3), 20) for _ in range(C)])
    cam_t = rng.uniform(-0.2, 0.2, (C, 3)) + [0, 0, 3.0]
    frame_R = np.array([_rot(rng.normal(size=3), 30) for _ in range(F)])
    frame_t = rng.uniform(-0.3, 0.3, (F, 3))
    M = 40
    oc, of = rng.integers(0, C, M), rng.integers(0, F, M)
    Pb = np.c_[rng.uniform(-0.5, 0.5, (M, 2)), np.zeros(M)]
    got = cal.project_observations(intr, cam_R, cam_t, frame_R, frame_t, oc, of, Pb)
    for m in range(M):
        Xw = frame_R[of[m]] @ Pb[m] + frame_t[of[m]]
        K = np.array([[intr[oc[m], 0], 0, intr[oc[m], 2]], [0, intr[oc[m], 1], intr[oc[m], 3]], [0, 0, 1]])
        ref = cv2.projectPoints(Xw[None], cv2.Rodrigues(cam_R[oc[m]])[0], cam_t[oc[m]], K, intr[oc[m], 4:9])[0]
        np.testing.assert_allclose(got[m], ref.ravel(), atol=1e-8)


def test_degenerate_views_are_too_few_or_collinear_corners():
    grid = np.c_[np.mgrid[0:3, 0:2].reshape(2, -1).T * 0.1, np.zeros(6)]  # 6 corners, 2 rows
    assert not cal._is_degenerate(grid)
    assert cal._is_degenerate(grid[:5])
    line = np.c_[np.linspace(0, 1, 8), np.zeros(8), np.zeros(8)]
    assert cal._is_degenerate(line)
    # a thin strip: second singular value 2e-3 / 5e-4 of the first (threshold 1e-3)
    for ratio, degenerate in ((2e-3, False), (5e-4, True)):
        strip = line.copy()
        strip[:, 1] = np.tile([1.0, -1.0], 4) * ratio * np.linalg.norm(line[:, 0] - line[:, 0].mean()) / np.sqrt(8)
        assert cal._is_degenerate(strip) == degenerate, ratio
    assert cal._is_degenerate(np.zeros((8, 3)))


# --- initialisation ------------------------------------------------------------------------------

def test_initial_intrinsics_recovers_the_noise_free_cameras(small_capture):
    spec, rig, poses, obs, intr, *_ = _truth(small_capture)
    Ks, dists, view_poses = cal.initial_intrinsics(obs, spec)
    assert Ks.shape == (obs.n_cameras, 3, 3) and dists.shape == (obs.n_cameras, 5)
    np.testing.assert_array_equal(dists[:, 4], 0.0)  # Zhang's initialisation fixes k3
    for c, name in enumerate(obs.camera_names):
        np.testing.assert_allclose(Ks[c], rig[name].K, rtol=5e-3)
        np.testing.assert_allclose(dists[c, :2], rig[name].dist[:2], atol=2e-2)
    assert set(view_poses) == set(obs.views())
    for (c, f), V in view_poses.items():
        truth = _T(rig[obs.camera_names[c]]) @ poses[f]
        np.testing.assert_allclose(V[:3, 3], truth[:3, 3], atol=0.05)
        assert np.degrees(np.linalg.norm(cv2.Rodrigues(V[:3, :3] @ truth[:3, :3].T)[0])) < 0.5


def test_a_camera_with_two_views_starts_from_the_pinhole_guess(small_capture):
    spec, rig, poses, obs, *_ = _truth(small_capture)
    views = obs.views()
    keep = [k for k in sorted(views) if k[0] == 0][:2]
    mask = (obs.camera != 0) | np.isin(obs.frame, [f for _, f in keep])
    sub = obs.subset(mask)
    Ks, dists, view_poses = cal.initial_intrinsics(sub, spec)
    w, h = sub.image_sizes[0]
    np.testing.assert_array_equal(Ks[0], [[w, 0, (w - 1) / 2], [0, w, (h - 1) / 2], [0, 0, 1]])
    np.testing.assert_array_equal(dists[0], np.zeros(5))
    assert {k for k in view_poses if k[0] == 0} <= set(keep)
    np.testing.assert_allclose(Ks[1], rig[sub.camera_names[1]].K, rtol=5e-3)  # the others are solved


def test_a_camera_without_a_usable_view_is_named(small_capture):
    spec, rig, poses, obs, *_ = _truth(small_capture)
    views = {}
    for (c, f), idx in obs.views().items():
        ids, uv = obs.corner_id[idx], obs.uv[idx]
        if c == 2:  # only one row of corners: collinear
            row = board_corners(spec)[ids][:, 1] == board_corners(spec)[ids][0, 1]
            ids, uv = ids[row], uv[row]
        views[(c, f)] = (ids, uv)
    bad = observations_from_views(obs.camera_names, obs.image_sizes, obs.frame_ids, views)
    with pytest.raises(SessionError, match=r"^camera cam_02: no image shows at least 6 board corners off one line"):
        cal.initial_intrinsics(bad, spec)


def _graph_case():
    """3 cameras, 5 frames (frame 4 unseen): W01 = 30 + min(20, 10) = 40, W12 = 25, W02 = 6 (weak)."""
    counts = {(0, 0): 30, (1, 0): 30, (1, 1): 25, (2, 1): 40, (0, 2): 6, (2, 2): 10, (0, 3): 20, (1, 3): 10}
    views = {k: (np.arange(n), np.zeros((n, 2))) for k, n in counts.items()}
    obs = observations_from_views(["a", "b", "c"], [(640, 480)] * 3, range(5), views)
    rng = np.random.default_rng(4)
    T = [rigid(_rot(rng.normal(size=3), 40), rng.uniform(-1, 1, 3)) for _ in range(3)]  # world -> camera
    B = [rigid(_rot(rng.normal(size=3), 40), rng.uniform(-1, 1, 3)) for _ in range(5)]  # board -> world
    view_poses = {(c, f): T[c] @ B[f] for (c, f) in counts}
    return obs, T, B, view_poses


def test_camera_graph_follows_the_heaviest_edges_and_weights_shared_frames_by_corners():
    obs, T, B, view_poses = _graph_case()
    view_poses[(2, 2)] = rigid(_rot([1, 2, 3], 30), [0.5, 0, 0]) @ view_poses[(2, 2)]  # only on the weak edge
    delta = np.array([0.04, -0.02, 0.08])
    view_poses[(0, 3)] = rigid(np.eye(3), delta) @ view_poses[(0, 3)]  # on the heavy edge, weight 10 of 40
    cam_from_root, root, W = cal.camera_graph_extrinsics(obs, view_poses)
    np.testing.assert_array_equal(W, [[0, 40, 6], [40, 0, 25], [6, 25, 0]])
    assert root == 1
    np.testing.assert_allclose(cam_from_root[1], np.eye(4), atol=1e-15)
    np.testing.assert_allclose(cam_from_root[2], T[2] @ rigid_inverse(T[1]), atol=1e-12)
    expected0 = T[0] @ rigid_inverse(T[1])
    np.testing.assert_allclose(cam_from_root[0][:3, :3], expected0[:3, :3], atol=1e-12)
    np.testing.assert_allclose(cam_from_root[0][:3, 3], expected0[:3, 3] + 0.25 * delta, atol=1e-12)


def test_camera_graph_refuses_a_camera_never_seen_with_the_others():
    obs, T, B, view_poses = _graph_case()
    counts = {(0, 0): 30, (1, 0): 30, (2, 4): 12, (0, 3): 20, (1, 3): 10}
    views = {k: (np.arange(n), np.zeros((n, 2))) for k, n in counts.items()}
    lone = observations_from_views(["a", "b", "c"], [(640, 480)] * 3, range(5), views)
    vp = {k: np.eye(4) for k in counts}
    with pytest.raises(SessionError, match=r"^camera c never sees the board together with the other cameras \(a, b"
                                           r"\.\.\.\); capture board poses seen by c and a neighbouring camera"):
        cal.camera_graph_extrinsics(lone, vp)


def test_initial_board_poses_are_the_corner_weighted_mean_over_cameras():
    obs, T, B, view_poses = _graph_case()
    cam_from_root = np.array([T[c] @ rigid_inverse(T[1]) for c in range(3)])
    delta = np.array([0.03, 0.06, -0.09])
    view_poses[(0, 3)] = rigid(np.eye(3), delta) @ view_poses[(0, 3)]  # camera 0: 20 of frame 3's 30 corners
    boards = cal.initial_board_poses(obs, view_poses, cam_from_root)
    assert boards.shape == (5, 4, 4)
    assert np.isnan(boards[4]).all()  # nobody saw frame 4
    for f in range(4):
        expected = T[1] @ B[f]
        np.testing.assert_allclose(boards[f][:3, :3], expected[:3, :3], atol=1e-12)
        shift = (20 / 30) * T[1][:3, :3] @ T[0][:3, :3].T @ delta if f == 3 else 0.0
        np.testing.assert_allclose(boards[f][:3, 3], expected[:3, 3] + shift, atol=1e-12)


# --- robust loss and Levenberg-Marquardt -----------------------------------------------------------

def test_robust_weights_and_costs_in_closed_form():
    s = 2.0
    r = np.array([[2.0, 0.0], [0.0, 2.0 * np.sqrt(3.0)], [4.0, 0.0], [0.0, 0.0]])  # z = 1, 3, 4, 0
    z = np.array([1.0, 3.0, 4.0, 0.0])
    expected_w = {"linear": [1, 1, 1, 1], "soft_l1": 1 / np.sqrt(1 + z), "huber": [1, 1 / np.sqrt(3), 0.5, 1],
                  "cauchy": 1 / (1 + z)}
    expected_rho = {"linear": z, "soft_l1": 2 * (np.sqrt(1 + z) - 1), "huber": [1, 2 * np.sqrt(3) - 1, 3, 0],
                    "cauchy": np.log1p(z)}
    for loss in expected_w:
        np.testing.assert_allclose(cal.robust_weights(r, loss, s), expected_w[loss], rtol=1e-14, err_msg=loss)
        assert cal.robust_cost(r, loss, s) == pytest.approx(0.5 * s * s * np.sum(expected_rho[loss]), rel=1e-14)
        # the IRLS weight is rho'(z): d cost / d z_i = s^2 / 2 * w_i
        for i in range(3):
            h = 1e-6
            rp, rm = r.copy(), r.copy()
            norm = np.linalg.norm(r[i])
            rp[i] *= np.sqrt((norm ** 2 / s ** 2 + h) / (norm ** 2 / s ** 2))
            rm[i] *= np.sqrt((norm ** 2 / s ** 2 - h) / (norm ** 2 / s ** 2))
            dz = (cal.robust_cost(rp, loss, s) - cal.robust_cost(rm, loss, s)) / (2 * h)
            assert dz == pytest.approx(0.5 * s * s * cal.robust_weights(r, loss, s)[i], rel=1e-5), (loss, i)
    with pytest.raises(InputError, match=r"^unknown loss 'l2'; use linear, soft_l1, huber or cauchy$"):
        cal.robust_weights(r, "l2", s)


def _exp_problem(outliers=False):
    t = np.linspace(0, 2, 20)
    a, b = 1.5, -0.8
    y = a * np.exp(b * t)
    if outliers:
        y = y.copy()
        y[[3, 11, 17]] += [2.0, -3.0, 2.5]

    def residuals(x):
        return x[0] * np.exp(x[1] * t) - y

    calls = []

    def jacobian(x):
        calls.append(x.copy())
        e = np.exp(x[1] * t)
        return np.stack([e, x[0] * t * e], axis=1)

    return residuals, jacobian, calls, np.array([a, b])


def test_levenberg_marquardt_finds_the_exact_minimum_and_counts_its_jacobians():
    residuals, jacobian, calls, truth = _exp_problem()
    x0 = np.array([0.5, 0.5])
    x, n_jac, rms = cal.levenberg_marquardt(residuals, jacobian, x0)
    np.testing.assert_allclose(x, truth, atol=1e-9)
    np.testing.assert_array_equal(x0, [0.5, 0.5])  # the start is not modified
    assert rms < 1e-9
    assert n_jac == len(calls) and 3 <= n_jac < 100
    # one iteration: one Jacobian, a step that lowers the cost, and the RMS of that step's residuals
    residuals, jacobian, calls, truth = _exp_problem()
    x1, n1, rms1 = cal.levenberg_marquardt(residuals, jacobian, x0, max_iterations=1)
    assert n1 == 1 == len(calls)
    r0, r1 = residuals(x0).reshape(-1, 2), residuals(x1).reshape(-1, 2)
    assert (r1 ** 2).sum() < (r0 ** 2).sum() and np.linalg.norm(x1 - truth) > 1e-3
    assert rms1 == pytest.approx(np.sqrt((r1 ** 2).sum(1).mean()), rel=1e-12)


def test_levenberg_marquardt_with_a_robust_loss_ignores_gross_outliers():
    residuals, jacobian, _, truth = _exp_problem(outliers=True)
    x_ls, _, _ = cal.levenberg_marquardt(residuals, jacobian, np.array([1.0, -0.5]))
    x_rob, _, _ = cal.levenberg_marquardt(residuals, jacobian, np.array([1.0, -0.5]), "cauchy", 0.1)
    assert np.linalg.norm(x_ls - truth) > 0.05  # least squares is pulled away
    assert np.linalg.norm(x_rob - truth) < 0.02 * np.linalg.norm(x_ls - truth)


# --- bundle adjustment ---------------------------------------------------------------------------

def test_bundle_adjustment_recovers_a_perturbed_noise_free_rig(noise_free_ba):
    ba, (spec, rig, poses, obs, intr, root, cam_from_root, boards), (intr0, cams0, boards0, mask) = noise_free_ba
    C, F = obs.n_cameras, obs.n_frames
    assert ba.n_parameters == C * 8 + 6 * (C - 1) + 6 * F == len(ba.x)
    assert ba.n_intrinsics == 8 and ba.loss == "linear" and ba.loss_scale_px == 1.0
    np.testing.assert_array_equal(ba.mask, mask)
    assert ba.residuals.shape == (mask.sum(), 2) and ba.jacobian.shape == (2 * mask.sum(), ba.n_parameters)
    assert np.sqrt((ba.residuals ** 2).sum(1).mean()) < 1e-6
    np.testing.assert_allclose(ba.intr[:, :4], intr[:, :4], rtol=1e-7)
    np.testing.assert_allclose(ba.intr[:, 4:8], intr[:, 4:8], atol=1e-7)
    np.testing.assert_array_equal(ba.intr[:, 8], 0.0)
    np.testing.assert_array_equal(ba.cam_from_root[root], cam_from_root[root])  # the gauge stays put
    np.testing.assert_allclose(ba.cam_from_root, cam_from_root, atol=1e-7)
    np.testing.assert_allclose(ba.board_poses, boards, atol=1e-7)
    assert 1 <= ba.n_jacobians < 20
    # unpack maps the parameter vector back to the same solution
    full, cams, brd = ba.unpack(ba.x)
    np.testing.assert_array_equal(full, ba.intr)
    np.testing.assert_array_equal(cams, ba.cam_from_root)
    np.testing.assert_array_equal(brd, ba.board_poses)
    np.testing.assert_array_equal(brd[:, 3], np.tile([0.0, 0.0, 0.0, 1.0], (F, 1)))
    np.testing.assert_array_equal(cams[:, 3], np.tile([0.0, 0.0, 0.0, 1.0], (C, 1)))
    # in the same test: mutmut maps a module fixture's calls to the first test using it only
    _check_jacobian_matches_plain_central_differences(noise_free_ba)


def _check_jacobian_matches_plain_central_differences(noise_free_ba):
    ba, (spec, rig, poses, obs, *_), _ = noise_free_ba
    P = board_corners(spec)[obs.corner_id[ba.mask]]

    def res(x):
        full, cams, brd = ba.unpack(x)
        o_c, o_f = obs.camera[ba.mask], obs.frame[ba.mask]
        return (cal.project_observations(full, cams[:, :3, :3], cams[:, :3, 3], brd[:, :3, :3], brd[:, :3, 3],
                                         o_c, o_f, P) - obs.uv[ba.mask]).ravel()

    np.testing.assert_allclose(res(ba.x).reshape(-1, 2), ba.residuals, atol=1e-9)
    cols = np.r_[0:ba.n_parameters:7, ba.n_parameters - 1]
    for k in cols:
        h = 1e-6 * max(1.0, abs(ba.x[k]))
        e = np.zeros_like(ba.x)
        e[k] = h
        num = (res(ba.x + e) - res(ba.x - e)) / (2 * h)
        np.testing.assert_allclose(ba.jacobian[:, k], num, atol=1e-6 * max(1.0, np.abs(num).max()), err_msg=str(k))


def test_bundle_adjustment_frees_k3_and_skips_unseen_frames(small_capture):
    spec, rig, poses, obs, intr, root, cam_from_root, boards = _truth(small_capture)
    boards = boards.copy()
    boards[3] = np.nan  # a frame nobody resolved stays out
    mask = obs.frame != 3
    ba = cal.bundle_adjust(obs, spec, intr, cam_from_root, boards, root, mask, 5, "soft_l1", 1.0, 3)
    C, F = obs.n_cameras, obs.n_frames
    assert ba.n_intrinsics == 9 and ba.n_parameters == C * 9 + 6 * (C - 1) + 6 * (F - 1)
    assert np.isnan(ba.board_poses[3]).all()
    np.testing.assert_allclose(ba.board_poses[np.arange(F) != 3], boards[np.arange(F) != 3], atol=1e-9)
    np.testing.assert_allclose(ba.intr, intr, atol=1e-6)
    assert ba.n_jacobians <= 3


def test_reprojection_residuals_vanish_at_the_truth_and_are_nan_for_unknown_boards(small_capture):
    spec, rig, poses, obs, *_ = _truth(small_capture)
    P = poses.copy()
    P[2] = np.nan
    r = cal.reprojection_residuals(obs, spec, rig, P)
    assert r.shape == (len(obs), 2)
    assert np.isnan(r[obs.frame == 2]).all()
    np.testing.assert_allclose(r[obs.frame != 2], 0.0, atol=1e-9)
    P = poses.copy()
    P[0] = rigid(np.eye(3), [0.0, 0.01, 0.0]) @ P[0]
    assert np.abs(cal.reprojection_residuals(obs, spec, rig, P)[obs.frame == 0]).max() > 0.5


def test_mad_outliers_threshold_is_median_plus_k_robust_sigmas():
    e = np.array([1.0, 2.0, 3.0, 4.0, 5.0, 100.0])  # median 3.5, MAD 1.5, sigma 2.2239
    r = np.c_[np.zeros(6), e]
    np.testing.assert_array_equal(cal.mad_outliers(r, 0.5), [0, 0, 0, 0, 1, 1])  # > 4.612
    np.testing.assert_array_equal(cal.mad_outliers(r, 0.7), [0, 0, 0, 0, 0, 1])  # > 5.057
    np.testing.assert_array_equal(cal.mad_outliers(r, 2.9), [0, 0, 0, 0, 0, 1])
    np.testing.assert_array_equal(cal.mad_outliers(-r, 0.5), [0, 0, 0, 0, 1, 1])
    # MAD 0: the robust sigma is floored at 1e-6 px
    e = np.array([1.0, 1.0, 1.0, 1.0, 1.0, 1.0 + 2e-6, 1.0 + 0.5e-6])
    np.testing.assert_array_equal(cal.mad_outliers(np.c_[e, np.zeros(7)], 1.0), [0, 0, 0, 0, 0, 1, 0])


# --- world frame -----------------------------------------------------------------------------------

def test_world_from_root_by_floor_board_and_by_reference_camera(small_capture):
    spec, rig, poses, obs, intr, root, cam_from_root, boards = _truth(small_capture)
    T_root = _T(rig[obs.camera_names[root]])
    world_T_root, desc = cal.world_from_root(obs, spec, boards, cam_from_root, cal.CalibrationOptions())
    np.testing.assert_allclose(world_T_root, rigid_inverse(T_root), atol=1e-9)
    n_floor = sum(abs(P[1, 2]) > 0.999 and abs(P[1, 3]) < 1e-9 for P in poses)
    assert desc == f"floor board frame 0 (+{n_floor - 1} coplanar floor boards)" and n_floor > 1
    only = boards.copy()
    only[1:] = np.nan
    assert cal.world_from_root(obs, spec, only, cam_from_root, cal.CalibrationOptions())[1] == "floor board frame 0"
    opts = cal.CalibrationOptions(reference_camera="cam_02")
    T, desc = cal.world_from_root(obs, spec, boards, cam_from_root, opts)
    np.testing.assert_array_equal(T, cam_from_root[2])
    assert desc == "camera cam_02"
    with pytest.raises(InputError, match=r"^reference camera 'cam_9' is not in the capture \(cam_00, cam_01"):
        cal.world_from_root(obs, spec, boards, cam_from_root, cal.CalibrationOptions(reference_camera="cam_9"))
    for frame in (None, 99):
        with pytest.raises(SessionError, match=rf"^floor board frame {frame} is not in the capture; capture the board "
                                               r"lying on the floor first \(frame 0\) or choose --reference-camera$"):
            cal.world_from_root(obs, spec, boards, cam_from_root, cal.CalibrationOptions(floor_frame=frame))
    unseen = boards.copy()
    unseen[0] = np.nan
    with pytest.raises(SessionError, match=r"^floor board \(frame 0\) was not found in any camera; capture the"):
        cal.world_from_root(obs, spec, unseen, cam_from_root, cal.CalibrationOptions())


def test_floor_plane_keeps_coplanar_boards_and_drops_tilted_or_raised_ones(small_capture):
    spec = small_capture[0]
    flat = [floor_board_to_world(spec)] + [floor_board_pose(spec, [x, 0.0, z], yaw)
                                           for x, z, yaw in ((1.2, 0.3, 0.4), (-1.0, 0.8, 2.0), (0.1, -1.3, -1.0))]
    tilted = _tilted_about_own_x(spec, floor_board_pose(spec, [0.9, 0.0, -0.9], 0.3), 6.0)  # 6 deg > 5 deg
    raised = rigid(np.eye(3), [0.0, 0.06, 0.0]) @ floor_board_pose(spec, [-0.9, 0.0, -0.9], 0.0)  # 6 cm > 5 cm
    unknown = np.full((4, 4), np.nan)
    poses = np.array(flat + [tilted, raised, unknown])
    Rw = _rot([0.3, 1, -0.2], 25)
    root_T_world = rigid(Rw, [0.2, -0.4, 1.0])  # any root frame: the answer moves with it
    boards = np.array([root_T_world @ P for P in poses])
    T, frames = cal.floor_plane_board_pose(spec, boards, 0)
    assert frames == [0, 1, 2, 3]
    np.testing.assert_allclose(T, boards[0], atol=1e-12)  # coplanar boards: the floor board's own pose
    assert cal.floor_plane_board_pose(spec, boards, 0, 7.0, 0.07)[1] == [0, 1, 2, 3, 4, 5]
    assert cal.floor_plane_board_pose(spec, boards, 0, 7.0, 0.05)[1] == [0, 1, 2, 3, 4]
    assert cal.floor_plane_board_pose(spec, boards, 0, 5.0, 0.07)[1] == [0, 1, 2, 3, 5]
    # any board can be the floor board
    assert cal.floor_plane_board_pose(spec, boards, 2)[1] == [0, 1, 2, 3]
    # alone, with the others unknown, the floor board keeps its pose
    alone = boards.copy()
    alone[1:] = np.nan
    T, frames = cal.floor_plane_board_pose(spec, alone, 0)
    assert frames == [0]
    np.testing.assert_allclose(T, boards[0], atol=1e-12)
    # a floor board 1 cm up and tilted 1 deg about its x axis among flat boards: the plane comes from all of them,
    # the origin is its centre projected onto that plane and x its (projected) x axis
    bent = np.array([rigid(np.eye(3), [0, 0.01, 0]) @ _tilted_about_own_x(spec, flat[0], 1.0)] + flat[1:])
    boards = np.array([root_T_world @ P for P in bent])
    T, frames = cal.floor_plane_board_pose(spec, boards, 0)
    assert frames == [0, 1, 2, 3]
    pts = np.concatenate([board_corners(spec) @ B[:3, :3].T + B[:3, 3] for B in boards])
    n = np.linalg.svd(pts - pts.mean(0))[2][2]
    n = n * np.sign(n @ boards[0][:3, 2])
    np.testing.assert_allclose(T[:3, 2], n, atol=1e-12)
    np.testing.assert_allclose(T[:3, :3].T @ T[:3, :3], np.eye(3), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(T[:3, :3]), 1.0, atol=1e-12)
    x = boards[0][:3, 0] - (boards[0][:3, 0] @ n) * n
    np.testing.assert_allclose(T[:3, 0], x / np.linalg.norm(x), atol=1e-12)
    c = spec.center_m
    c0 = boards[0][:3, :3] @ c + boards[0][:3, 3]
    centre = T[:3, :3] @ c + T[:3, 3]
    np.testing.assert_allclose(centre, c0 - ((c0 - pts.mean(0)) @ n) * n, atol=1e-12)
    assert np.linalg.norm(centre - c0) > 5e-3  # the projection moved it down towards the floor
    # the fitted plane is the floor: within a hair of the flat boards' normal, not the bent board's 3 deg
    flat_n = Rw @ [0.0, 1.0, 0.0]
    tilt = np.degrees(np.arccos(min(1.0, abs(T[:3, 2] @ flat_n))))
    assert 0.01 < tilt < 0.5


# --- the whole calibration ---------------------------------------------------------------------------

@pytest.mark.parametrize("options, message", [
    (cal.CalibrationOptions(sigma_inflation=0.9),
     r"^sigma_inflation must be >= 1 \(1: i.i.d. corner noise\), got 0.9$"),
    (cal.CalibrationOptions(sigma_inflation=float("nan")), r"^sigma_inflation must be >= 1"),
    (cal.CalibrationOptions(distortion_terms=3), r"^distortion_terms must be 4 or 5, got 3$"),
    (cal.CalibrationOptions(distortion_terms=6), r"^distortion_terms must be 4 or 5, got 6$"),
])
def test_calibrate_refuses_bad_options(small_capture, options, message):
    spec, _, _, obs = small_capture
    with pytest.raises(InputError, match=message):
        cal.calibrate_cameras(obs, spec, options)


def test_sigma_inflation_1_is_accepted(small_capture):
    spec, _, _, obs = small_capture
    with pytest.raises(InputError, match=r"^distortion_terms must be 4 or 5, got 3$"):  # the next check
        cal.calibrate_cameras(obs, spec, cal.CalibrationOptions(sigma_inflation=1.0, distortion_terms=3))


def test_calibration_result_statistics_in_closed_form(small_capture):
    spec, rig, poses, obs = small_capture
    M = len(obs)
    res = np.zeros((M, 2))
    res[obs.camera == 0] = [3.0, 4.0]  # 5 px
    res[obs.camera == 1] = [0.0, 1.0]
    inliers = obs.camera != 2
    inliers[np.flatnonzero(obs.camera == 0)[0]] = False
    result = cal.CalibrationResult(rig, poses, obs, inliers, res, 30, "w", 1.0)
    n0, n1, n3 = (inliers & (obs.camera == 0)).sum(), (obs.camera == 1).sum(), (obs.camera == 3).sum()
    assert result.rms_px == pytest.approx(np.sqrt((25 * n0 + n1) / (n0 + n1 + n3)), rel=1e-12)
    per = result.per_camera_rms_px()
    assert per["cam_00"] == pytest.approx(5.0) and per["cam_01"] == pytest.approx(1.0)
    assert np.isnan(per["cam_02"]) and per["cam_03"] == 0.0
    m = 2 * int(inliers.sum())
    assert result.expected_rms_px(0.3) == pytest.approx(0.3 * np.sqrt(2 * (m - 30) / m), rel=1e-12)
    rep = result.report()
    assert set(rep) == {"reproj_rms_px", "n_observations", "n_outliers", "n_parameters", "world_frame", "seconds",
                        "stages_s", "cameras", "uncertainty", "board_to_world"}
    assert rep["reproj_rms_px"] == result.rms_px and rep["seconds"] == 1.0 and rep["stages_s"] == {}
    assert set(rep["cameras"]["cam_00"]) == {"reproj_rms_px", "n_corners", "n_outliers", "n_views"}
    assert rep["cameras"]["cam_00"]["reproj_rms_px"] == per["cam_00"]
    assert rep["n_observations"] == M and rep["n_outliers"] == int((~inliers).sum()) and rep["n_parameters"] == 30
    assert rep["cameras"]["cam_00"]["n_outliers"] == 1
    assert rep["cameras"]["cam_02"]["n_outliers"] == (obs.camera == 2).sum()
    assert rep["cameras"]["cam_01"]["n_corners"] == n1
    assert rep["cameras"]["cam_01"]["n_views"] == len(np.unique(obs.frame[obs.camera == 1]))
    assert rep["uncertainty"] is None and rep["world_frame"] == "w"
    assert set(rep["board_to_world"]) == {str(f) for f in obs.frame_ids}


def test_calibration_uncertainty_is_the_inflated_covariance_of_the_adjustment(small_capture):
    """Result 5.10 of Hartley & Zisserman: fx and fy are parameters of the adjustment, so their sigma is the
    inflation times the square root of the covariance's diagonal; s is the residual sigma over the
    degrees of freedom."""
    from bodystudio.calib.uncertainty import parameter_covariance, view_effect_covariance, view_error_basis

    spec, rig, poses, obs = small_capture
    _, _, _, _, intr, root, cam_from_root, boards = _truth(small_capture)
    inliers = np.ones(len(obs), bool)
    ba = cal.bundle_adjust(obs, spec, intr, cam_from_root, boards, root, inliers, 4, "linear", 1.0, 3)
    world_T_root, _ = cal.world_from_root(obs, spec, ba.board_poses, ba.cam_from_root, cal.CalibrationOptions())
    cams_world = np.array([T @ rigid_inverse(world_T_root) for T in ba.cam_from_root])
    strict = cal.CalibrationOptions(sigma_inflation=3.0, max_center_sigma_mm=1e-3, max_focal_sigma_pct=1e-4)
    u = cal.calibration_uncertainty(obs, spec, ba, cams_world, inliers, strict)
    assert (u.max_center_sigma_mm, u.max_focal_sigma_pct) == (1e-3, 1e-4)
    assert all(c.verdict == "uncertain" for c in u.cameras)  # the thresholds reach the verdicts
    focal, centre = max(c.focal_sigma_pct for c in u.cameras), min(c.center_sigma_mm for c in u.cameras)
    assert focal < centre
    # a focal threshold between the two: all "ok"; swapped into the centre's place it would fail every camera
    loose = cal.CalibrationOptions(sigma_inflation=3.0, max_center_sigma_mm=1e3,
                                   max_focal_sigma_pct=(focal + centre) / 2)
    u_loose = cal.calibration_uncertainty(obs, spec, ba, cams_world, inliers, loose)
    assert all(c.verdict == "ok" for c in u_loose.cameras)
    # the final (linear) pass: corner noise plus a per-view error field, view_effect_covariance's moments
    view = obs.camera[ba.mask] * max(obs.n_frames, 1) + obs.frame[ba.mask]
    cov, s2, t2 = view_effect_covariance(ba.jacobian, ba.residuals.ravel(), view_error_basis(obs.uv[ba.mask], view))
    assert u.residual_sigma_px == pytest.approx(np.sqrt(s2), rel=1e-9)
    assert u.view_sigma_px == pytest.approx(np.sqrt(t2), rel=1e-9)
    assert abs(u.residual_sigma_px / NOISE_PX - 1) < 0.1
    assert u.sigma_inflation == 3.0
    assert [c.name for c in u.cameras] == list(obs.camera_names)
    for c, cam in enumerate(u.cameras):
        assert cam.fx_sigma_px == pytest.approx(3.0 * np.sqrt(cov[8 * c, 8 * c]), rel=1e-4)
        assert cam.fy_sigma_px == pytest.approx(3.0 * np.sqrt(cov[8 * c + 1, 8 * c + 1]), rel=1e-4)
        assert 0.1 < cam.center_sigma_mm < 100
        assert cam.coverage.n_views == len(np.unique(obs.frame[obs.camera == c]))
        assert cam.coverage.fraction > 0.2
    # with a reference camera as the world frame, that camera's centre is exact (the gauge), the others are not
    opts = cal.CalibrationOptions(floor_frame=None, reference_camera="cam_02")
    ref_T_root, _ = cal.world_from_root(obs, spec, ba.board_poses, ba.cam_from_root, opts)
    cams_ref = np.array([T @ rigid_inverse(ref_T_root) for T in ba.cam_from_root])
    u_ref = cal.calibration_uncertainty(obs, spec, ba, cams_ref, inliers, opts)
    assert u_ref.cameras[2].center_sigma_mm < 1e-3
    assert min(u_ref.cameras[c].center_sigma_mm for c in (0, 1, 3)) > 0.1
    # a robust-loss adjustment: the covariance is s^2 (J^T W J)^-1 with the loss's IRLS weights
    ba = cal.bundle_adjust(obs, spec, intr, cam_from_root, boards, root, inliers, 4, "cauchy", 0.2, 3)
    u = cal.calibration_uncertainty(obs, spec, ba, cams_world, inliers, cal.CalibrationOptions(sigma_inflation=1.0))
    w = np.repeat(cal.robust_weights(ba.residuals, "cauchy", 0.2), 2)
    assert w.min() < 0.5  # the weights matter here
    cov, s2 = parameter_covariance(ba.jacobian, ba.residuals.ravel(), w)
    assert u.residual_sigma_px == pytest.approx(np.sqrt(s2), rel=1e-9)
    assert u.cameras[0].fx_sigma_px == pytest.approx(np.sqrt(cov[0, 0]), rel=1e-4)


def test_rig_from_builds_opencv_cameras(small_capture):
    spec, rig, poses, obs, intr, *_ = _truth(small_capture)
    cams = np.array([_T(rig[n]) for n in obs.camera_names])
    out = cal._rig_from(obs, intr, cams)
    for n in obs.camera_names:
        assert out[n].name == n
        np.testing.assert_array_equal(out[n].K, rig[n].K)
        np.testing.assert_array_equal(out[n].dist, rig[n].dist)
        np.testing.assert_array_equal(out[n].R, rig[n].R)
        np.testing.assert_array_equal(out[n].t, rig[n].t)
        assert (out[n].width, out[n].height) == (rig[n].width, rig[n].height)


def _check_rejects_the_planted_outliers_and_recovers_the_rig(small_capture, calibrated):
    """Measured: exactly the 12 planted corners rejected, RMS 0.277 px for 0.276 expected, worst camera
    12.0 mm / 0.61 deg / 0.33 % / 0.54 px volume reprojection; the bounds are ~1.5x that."""
    spec, rig, poses, obs = small_capture
    res, bad, lines = calibrated
    np.testing.assert_array_equal(np.flatnonzero(~res.inliers), bad)
    assert abs(res.rms_px / res.expected_rms_px(NOISE_PX) - 1) < 0.05
    assert res.n_parameters == 4 * 8 + 6 * 3 + 6 * 10
    worst = evaluate_calibration(res.rig, rig)["max"]
    assert worst["center_err_mm"] < 18.0 and worst["rot_err_deg"] < 0.9 and worst["focal_err_pct"] < 0.5
    assert worst["volume_reproj_rms_px"] < 0.8
    # the world frame: the floor boards lie in y = 0, and the boards' poses are in it
    assert res.world_frame == "floor board frame 0 (+3 coplanar floor boards)"
    for f in range(4):
        P = board_corners(spec) @ res.board_to_world[f][:3, :3].T + res.board_to_world[f][:3, 3]
        assert np.abs(P[:, 1]).max() < 0.003, f
    np.testing.assert_allclose(res.board_to_world[:, :3, 3], poses[:, :3, 3], atol=0.02)
    # residuals are those of the final rig and boards, outliers included (not zeroed)
    np.testing.assert_allclose(res.residuals_px, cal.reprojection_residuals(obs.subset(np.ones(len(obs), bool)),
                               spec, res.rig, res.board_to_world) - np.where(
                                   np.isin(np.arange(len(obs)), bad)[:, None], [12.0, -9.0], 0.0), atol=1e-9)
    assert np.linalg.norm(res.residuals_px[bad], axis=1).min() > 10
    assert set(res.stages_s) == {"intrinsics", "camera_graph", "bundle_adjustment", "uncertainty"}
    assert all(v >= 0 for v in res.stages_s.values()) and res.seconds >= sum(res.stages_s.values()) - 1e-9
    assert res.seconds < 900  # a duration, not a clock reading
    assert [c.name for c in res.uncertainty.cameras] == list(obs.camera_names)
    assert res.report()["uncertainty"] == res.uncertainty.to_dict()


def _check_logs_each_stage(small_capture, calibrated):
    spec, rig, poses, obs = small_capture
    res, bad, lines = calibrated
    for name in obs.camera_names:
        assert sum(bool(re.fullmatch(rf"camera {name}: intrinsics from \d+ views, rms \d+\.\d{{3}} px", x))
                   for x in lines) == 1, name
    assert sum(bool(re.fullmatch(r"bundle adjustment \(soft_l1 loss\): [1-9]\d* Jacobians, rms \d+\.\d{4} px", x))
               for x in lines) == 1
    assert sum(bool(re.fullmatch(r"bundle adjustment \(linear loss\): [1-9]\d* Jacobians, rms \d+\.\d{4} px", x))
               for x in lines) == 1
    assert sum(bool(re.fullmatch(rf"bundle adjustment pass 1: [1-9]\d* evaluations, {len(bad)} outliers of "
                                 rf"{len(obs)} corners", x)) for x in lines) == 1
    for cam in res.uncertainty.cameras:
        assert (f"camera {cam.name}: sigma centre {cam.center_sigma_mm:.2f} mm, focal {cam.focal_sigma_pct:.3f} %, "
                f"coverage {100 * cam.coverage.fraction:.0f} % -> {cam.verdict}") in lines
    assert lines[-1] == f"calibrated 4 cameras: reprojection RMS {res.rms_px:.3f} px in {res.seconds:.2f} s"


def test_whole_calibration_of_a_capture_with_planted_outliers(small_capture, calibrated):
    """One test for everything checked on the ``calibrated`` fixture: mutmut maps the functions a module
    fixture calls to the first test using it only, so checks spread over several tests would not run."""
    spec, rig, poses, obs = small_capture
    _check_rejects_the_planted_outliers_and_recovers_the_rig(small_capture, calibrated)
    _check_logs_each_stage(small_capture, calibrated)
    res = calibrated[0]
    # the calibration's own uncertainty: not inflated (the view-effect model), and the true centre error within 4 sigma
    assert res.uncertainty.sigma_inflation == 1.0
    assert res.uncertainty.max_center_sigma_mm == cal.CalibrationOptions().max_center_sigma_mm
    for cam in res.uncertainty.cameras:
        err = np.linalg.norm(res.rig[cam.name].center - rig[cam.name].center) * 1000
        assert err < 4 * cam.center_sigma_mm, cam.name
        ok = cam.center_sigma_mm <= cal.CalibrationOptions().max_center_sigma_mm and \
            cam.focal_sigma_pct <= cal.CalibrationOptions().max_focal_sigma_pct
        assert cam.verdict == ("ok" if ok else "uncertain"), cam.name


def test_a_camera_with_few_views_is_logged(small_capture, caplog):
    spec, rig, poses, obs, *_ = _truth(small_capture)
    keep = [k for k in sorted(obs.views()) if k[0] == 0][:2]
    sub = obs.subset((obs.camera != 0) | np.isin(obs.frame, [f for _, f in keep]))
    with caplog.at_level(logging.INFO, logger="bodystudio.calib.calibrate"):
        cal.initial_intrinsics(sub, spec)
    assert "camera cam_00: only 2 board views; intrinsics start from a guess" in caplog.messages


def test_zero_iterations_return_the_initialisation(small_capture):
    """With max_iterations 0 the adjustment returns its start: the intrinsics are Zhang's, as
    initial_intrinsics gives them (the adjustment would recover from a wrong start, hiding a mix-up there)."""
    spec, rig, poses, obs = small_capture
    res = cal.calibrate_cameras(obs, spec, cal.CalibrationOptions(max_iterations=0))
    Ks, dists, _ = cal.initial_intrinsics(obs, spec)
    for c, name in enumerate(obs.camera_names):
        np.testing.assert_allclose(res.rig[name].K, Ks[c], rtol=1e-7)  # OpenCV repeats itself to ~1e-9
        np.testing.assert_allclose(res.rig[name].dist[:4], dists[c, :4], atol=1e-7)
        assert res.rig[name].dist[4] == 0.0


def test_a_frame_nobody_saw_does_not_stop_the_board_poses_after_it():
    obs, T, B, view_poses = _graph_case()
    cam_from_root = np.array([T[c] @ rigid_inverse(T[1]) for c in range(3)])
    seen = {k: v for k, v in view_poses.items() if k[1] != 1}  # frame 1 unseen, frames 2 and 3 seen
    boards = cal.initial_board_poses(obs, seen, cam_from_root)
    assert np.isnan(boards[[1, 4]]).all()
    for f in (0, 2, 3):
        np.testing.assert_allclose(boards[f], T[1] @ B[f], atol=1e-12)
