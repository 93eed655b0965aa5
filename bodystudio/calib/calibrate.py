"""Multi-camera calibration from ChArUco observations: per-camera intrinsics (Zhang's method via
cv2.calibrateCamera), extrinsics initialised through a camera graph (maximum spanning tree of board
co-visibility), then one bundle adjustment of every camera's intrinsics, distortion and pose and every
board pose (scipy least_squares, sparse Jacobian pattern, robust loss, MAD outlier rejection), and
finally the world frame from the board lying on the floor (bodystudio.calib.world).
"""

from __future__ import annotations

import contextlib
import logging
import time
from dataclasses import dataclass, field

import cv2
import numpy as np
import scipy.sparse
from scipy.sparse.csgraph import breadth_first_order, connected_components, minimum_spanning_tree

from bodystudio.calib.board import CharucoBoardSpec, board_corners
from bodystudio.calib.observations import CharucoObservations
from bodystudio.calib.uncertainty import (
    MAX_CENTER_SIGMA_MM,
    MAX_FOCAL_SIGMA_PCT,
    CalibrationUncertainty,
    camera_quantities,
    camera_verdicts,
    corner_coverage,
    parameter_covariance,
    propagated_covariance,
    view_effect_covariance,
    view_error_basis,
)
from bodystudio.calib.world import floor_board_to_world, mean_rigid, rigid, rigid_inverse, rvec_t_to_rigid
from bodystudio.errors import InputError, SessionError
from bodystudio.geometry.camera import Camera, CameraRig

log = logging.getLogger(__name__)


def _single_thread_blas():
    """The adjustment's matrices are a few hundred wide: multi-threaded BLAS only adds synchronisation
    (measured 5x slower on a loaded 2-core machine), so BLAS runs on one thread inside it."""
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # optional: without it BLAS keeps its default threads
        return contextlib.nullcontext()
    return threadpool_limits(limits=1, user_api="blas")

MIN_VIEW_CORNERS = 6


@dataclass(frozen=True)
class CalibrationOptions:
    """Knobs of :func:`calibrate_cameras`; defaults are what the benchmark measures."""

    # 4: k1 k2 p1 p2 (k3 = 0), 5: also k3. k3 is only observable with boards in the image corners; left free
    # on sparse captures it extrapolates wildly there (measured: 5x worse volume reprojection).
    distortion_terms: int = 4
    loss: str = "soft_l1"
    loss_scale_px: float = 1.0
    outlier_mad_k: float = 6.0  # residual > median + k * 1.4826 * MAD is an outlier
    floor_frame: int | None = 0  # frame number showing the board on the floor; None: reference camera
    # Other boards lying on the floor with it (plane within this angle and offset) refine the floor plane.
    floor_max_angle_deg: float = 5.0
    floor_max_offset_m: float = 0.05
    reference_camera: str | None = None
    max_iterations: int = 200
    # Extra factor on the propagated sigmas (1: none). The covariance itself models what a detector's
    # corner errors are: i.i.d. noise plus a shift/rotation/scale shared by each view's corners, both sizes
    # estimated from the residuals (uncertainty.view_effect_covariance; docs/calibration.md measures it
    # against ground truth). Until that model, an empirical 1.5 stood here.
    sigma_inflation: float = 1.0
    # Verdict thresholds on the propagated 1-sigma (bodystudio.calib.uncertainty).
    max_center_sigma_mm: float = MAX_CENTER_SIGMA_MM
    max_focal_sigma_pct: float = MAX_FOCAL_SIGMA_PCT


@dataclass(frozen=True, eq=False)
class CalibrationResult:
    """Calibrated rig in the world frame plus the bundle adjustment's statistics."""

    rig: CameraRig
    board_to_world: np.ndarray  # (F, 4, 4), NaN for frames no camera saw
    observations: CharucoObservations
    inliers: np.ndarray  # (M,) bool
    residuals_px: np.ndarray  # (M, 2) final reprojection residuals
    n_parameters: int
    world_frame: str
    seconds: float
    stages_s: dict = field(default_factory=dict)
    uncertainty: CalibrationUncertainty | None = None

    @property
    def rms_px(self) -> float:
        """RMS of the 2-D reprojection error over inlier observations (pixels)."""
        r = self.residuals_px[self.inliers]
        return float(np.sqrt((r ** 2).sum(1).mean()))

    def per_camera_rms_px(self) -> dict[str, float]:
        out = {}
        for c, name in enumerate(self.observations.camera_names):
            m = self.inliers & (self.observations.camera == c)
            out[name] = float(np.sqrt((self.residuals_px[m] ** 2).sum(1).mean())) if m.any() else float("nan")
        return out

    def expected_rms_px(self, noise_px: float) -> float:
        """RMS the residuals should have for i.i.d. Gaussian corner noise of ``noise_px`` per axis:
        ``sigma * sqrt(2 (m - p) / m)`` with m residuals and p free parameters."""
        m = 2 * int(self.inliers.sum())
        return float(noise_px * np.sqrt(2.0 * (m - self.n_parameters) / m))

    def report(self) -> dict:
        obs = self.observations
        per_cam = {}
        rms = self.per_camera_rms_px()
        for c, name in enumerate(obs.camera_names):
            m = obs.camera == c
            per_cam[name] = {"reproj_rms_px": rms[name], "n_corners": int(m.sum()),
                             "n_outliers": int((m & ~self.inliers).sum()),
                             "n_views": int(len(np.unique(obs.frame[m])))}
        return {"reproj_rms_px": self.rms_px, "n_observations": len(obs), "n_outliers": int((~self.inliers).sum()),
                "n_parameters": self.n_parameters, "world_frame": self.world_frame, "seconds": self.seconds,
                "stages_s": self.stages_s, "cameras": per_cam,
                "uncertainty": self.uncertainty.to_dict() if self.uncertainty is not None else None,
                "board_to_world": {str(fid): T.tolist()
                                   for fid, T in zip(obs.frame_ids, self.board_to_world, strict=True)
                                   if np.isfinite(T[0, 0])}}


# --- vectorised geometry ------------------------------------------------------------------------

def rodrigues(rvecs: np.ndarray) -> np.ndarray:
    """Rotation matrices (n, 3, 3) of axis-angle vectors (n, 3)."""
    rvecs = np.asarray(rvecs, float).reshape(-1, 3)
    theta = np.linalg.norm(rvecs, axis=1)
    small = theta < 1e-12
    k = rvecs / np.where(small, 1.0, theta)[:, None]
    Kx = np.zeros((len(rvecs), 3, 3))
    Kx[:, 0, 1], Kx[:, 0, 2], Kx[:, 1, 2] = -k[:, 2], k[:, 1], -k[:, 0]
    Kx[:, 1, 0], Kx[:, 2, 0], Kx[:, 2, 1] = k[:, 2], -k[:, 1], k[:, 0]
    s, c = np.sin(theta)[:, None, None], np.cos(theta)[:, None, None]
    R = np.eye(3) + s * Kx + (1 - c) * (Kx @ Kx)
    return R


def project_observations(intr: np.ndarray, cam_R: np.ndarray, cam_t: np.ndarray, frame_R: np.ndarray,
                         frame_t: np.ndarray, obs_cam: np.ndarray, obs_frame: np.ndarray,
                         points_board: np.ndarray) -> np.ndarray:
    """Pixels (M, 2) of board points (M, 3) through per-observation frame and camera (OpenCV model).

    ``intr`` is (C, 9): fx, fy, cx, cy, k1, k2, p1, p2, k3.
    """
    Xw = np.einsum("mij,mj->mi", frame_R[obs_frame], points_board) + frame_t[obs_frame]
    Xc = np.einsum("mij,mj->mi", cam_R[obs_cam], Xw) + cam_t[obs_cam]
    x, y = Xc[:, 0] / Xc[:, 2], Xc[:, 1] / Xc[:, 2]
    p = intr[obs_cam]
    k1, k2, p1, p2, k3 = p[:, 4], p[:, 5], p[:, 6], p[:, 7], p[:, 8]
    r2 = x * x + y * y
    radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return np.stack([p[:, 0] * xd + p[:, 2], p[:, 1] * yd + p[:, 3]], axis=1)


# --- initialisation ------------------------------------------------------------------------------

def _object_image_points(obs: CharucoObservations, spec: CharucoBoardSpec, idx: np.ndarray):
    return board_corners(spec)[obs.corner_id[idx]], obs.uv[idx]


def _is_degenerate(points_board: np.ndarray) -> bool:
    """Corners on one line (or too few) give no homography."""
    if len(points_board) < MIN_VIEW_CORNERS:
        return True
    centred = points_board[:, :2] - points_board[:, :2].mean(0)
    sv = np.linalg.svd(centred, compute_uv=False)
    return sv[1] < 1e-3 * max(sv[0], 1e-12)


def initial_intrinsics(obs: CharucoObservations, spec: CharucoBoardSpec, distortion_terms: int = 4):
    """Per-camera K, dist and board->camera poses ``{(cam, frame): 4x4}`` from Zhang's method.

    Cameras with fewer than 3 usable views start from a pinhole guess (f = image width) and are
    solved by the bundle adjustment through the board poses other cameras see.
    """
    views = obs.views()
    Ks, dists, poses = [], [], {}
    # Zhang's initialisation always fixes k3: the bundle adjustment frees it when asked to.
    flags = cv2.CALIB_FIX_K3
    for c, name in enumerate(obs.camera_names):
        w, h = obs.image_sizes[c]
        keys = [k for k in views if k[0] == c and not _is_degenerate(_object_image_points(obs, spec, views[k])[0])]
        if not keys:
            raise SessionError(f"camera {name}: no image shows at least {MIN_VIEW_CORNERS} board corners off one "
                               "line; capture the board filling part of this camera's view")
        K = np.array([[float(w), 0, (w - 1) / 2], [0, float(w), (h - 1) / 2], [0, 0, 1]])
        dist = np.zeros(5)
        if len(keys) >= 3:
            obj = [_object_image_points(obs, spec, views[k])[0].astype(np.float32) for k in keys]
            img = [_object_image_points(obs, spec, views[k])[1].astype(np.float32) for k in keys]
            rms, K, dist, rvecs, tvecs = cv2.calibrateCamera(obj, img, (w, h), None, None, flags=flags)
            dist = np.asarray(dist, float).ravel()[:5]
            log.info("camera %s: intrinsics from %d views, rms %.3f px", name, len(keys), rms)
        else:
            log.warning("camera %s: only %d board views; intrinsics start from a guess", name, len(keys))
        Ks.append(np.asarray(K, float))
        dists.append(dist)
        for k in keys:
            P, uv = _object_image_points(obs, spec, views[k])
            ok, rvec, tvec = cv2.solvePnP(P, uv, Ks[-1], dists[-1], flags=cv2.SOLVEPNP_IPPE)
            if ok:
                ok, rvec, tvec = cv2.solvePnP(P, uv, Ks[-1], dists[-1], rvec, tvec, useExtrinsicGuess=True,
                                              flags=cv2.SOLVEPNP_ITERATIVE)
            if ok and tvec[2, 0] > 0:
                poses[k] = rvec_t_to_rigid(rvec, tvec)
    return np.array(Ks), np.array(dists), poses


def camera_graph_extrinsics(obs: CharucoObservations, view_poses: dict) -> tuple[np.ndarray, int, np.ndarray]:
    """Camera->root transforms (C, 4, 4) chained along the maximum spanning tree of co-visibility.

    Edge weight = corners the two cameras saw in the same frames; each edge's relative pose is the
    corner-weighted chordal mean over the shared frames. Returns (cam_from_root, root, weights).
    """
    C = obs.n_cameras
    counts = {k: int(((obs.camera == k[0]) & (obs.frame == k[1])).sum()) for k in view_poses}
    frames_of = [{f for (c, f) in view_poses if c == cam} for cam in range(C)]
    W = np.zeros((C, C))
    for i in range(C):
        for j in range(i + 1, C):
            shared = frames_of[i] & frames_of[j]
            W[i, j] = W[j, i] = sum(min(counts[(i, f)], counts[(j, f)]) for f in shared)
    n_comp, labels = connected_components(scipy.sparse.csr_matrix(W > 0), directed=False)
    if n_comp > 1:
        sizes = np.bincount(labels)
        main = int(np.argmax(sizes))
        lonely = [obs.camera_names[c] for c in range(C) if labels[c] != main]
        others = [obs.camera_names[c] for c in range(C) if labels[c] == main]
        raise SessionError(f"camera {lonely[0]} never sees the board together with the other cameras "
                           f"({', '.join(others[:3])}...); capture board poses seen by {lonely[0]} and a "
                           "neighbouring camera at the same time")
    root = int(np.argmax(W.sum(1)))
    cost = np.where(W > 0, 1.0 / np.maximum(W, 1e-9), 0.0)
    tree = minimum_spanning_tree(scipy.sparse.csr_matrix(cost))
    tree = tree + tree.T
    order, parent = breadth_first_order(tree, root, directed=False, return_predecessors=True)
    cam_from_root = np.zeros((C, 4, 4))
    cam_from_root[root] = np.eye(4)
    for c in order[1:]:
        p = parent[c]
        shared = sorted(frames_of[c] & frames_of[p])
        rel = [view_poses[(c, f)] @ rigid_inverse(view_poses[(p, f)]) for f in shared]  # c <- p
        weights = [min(counts[(c, f)], counts[(p, f)]) for f in shared]
        cam_from_root[c] = mean_rigid(rel, weights) @ cam_from_root[p]
    return cam_from_root, root, W


def initial_board_poses(obs: CharucoObservations, view_poses: dict, cam_from_root: np.ndarray) -> np.ndarray:
    """Board->root transforms (F, 4, 4), corner-weighted mean over the cameras seeing each frame; NaN if none."""
    poses = np.full((obs.n_frames, 4, 4), np.nan)
    for f in range(obs.n_frames):
        keys = [k for k in view_poses if k[1] == f]
        if not keys:
            continue
        Ts = [rigid_inverse(cam_from_root[c]) @ view_poses[(c, f)] for (c, _) in keys]
        weights = [int(((obs.camera == c) & (obs.frame == f)).sum()) for (c, _) in keys]
        poses[f] = mean_rigid(Ts, weights)
    return poses


# --- bundle adjustment ---------------------------------------------------------------------------

def robust_weights(residuals_px: np.ndarray, loss: str, scale_px: float) -> np.ndarray:
    """IRLS weights (M,) of 2-D residuals for a robust loss (``rho'`` of the squared norm / scale^2)."""
    z = (residuals_px ** 2).sum(1) / scale_px ** 2
    if loss == "linear":
        return np.ones(len(z))
    if loss == "soft_l1":
        return 1.0 / np.sqrt(1.0 + z)
    if loss == "huber":
        return np.where(z <= 1.0, 1.0, 1.0 / np.sqrt(np.maximum(z, 1e-300)))
    if loss == "cauchy":
        return 1.0 / (1.0 + z)
    raise InputError(f"unknown loss {loss!r}; use linear, soft_l1, huber or cauchy")


def robust_cost(residuals_px: np.ndarray, loss: str, scale_px: float) -> float:
    z = (residuals_px ** 2).sum(1) / scale_px ** 2
    rho = {"linear": z, "soft_l1": 2 * (np.sqrt(1 + z) - 1), "huber": np.where(z <= 1, z, 2 * np.sqrt(z) - 1),
           "cauchy": np.log1p(z)}[loss]
    return float(0.5 * scale_px ** 2 * rho.sum())


def levenberg_marquardt(residuals, jacobian, x0: np.ndarray, loss: str = "linear", scale_px: float = 1.0,
                        max_iterations: int = 100, tol: float = 1e-12) -> tuple[np.ndarray, int, float]:
    """Levenberg-Marquardt on the normal equations with iteratively reweighted robust loss.

    Bundle adjustment's parameters number in the hundreds, so ``J^T W J`` is small and dense; solving
    it directly was measured ~50x faster here than scipy least_squares' SVD-based trust region.
    Returns (x, number of Jacobians, final RMS of the 2-D residuals).
    """
    x = x0.copy()
    r = residuals(x).reshape(-1, 2)
    cost = robust_cost(r, loss, scale_px)
    lam = 1e-3
    n_jac = 0
    for _ in range(max_iterations):
        J = jacobian(x)
        n_jac += 1
        w = np.repeat(robust_weights(r, loss, scale_px), 2)
        JtW = J.T * w
        A = JtW @ J
        g = JtW @ r.ravel()
        diag = np.maximum(np.diag(A), 1e-12)
        improved = False
        for _ in range(20):
            try:
                step = -np.linalg.solve(A + lam * np.diag(diag), g)
            except np.linalg.LinAlgError:
                lam *= 10
                continue
            x_new = x + step
            r_new = residuals(x_new).reshape(-1, 2)
            cost_new = robust_cost(r_new, loss, scale_px)
            if np.isfinite(cost_new) and cost_new < cost:
                improved = True
                break
            lam *= 10
        if not improved:
            break
        decrease = (cost - cost_new) / max(cost, 1e-300)
        x, r, cost = x_new, r_new, cost_new
        lam = max(lam / 10, 1e-12)
        if decrease < tol or np.linalg.norm(step) < tol * (np.linalg.norm(x) + tol):
            break
    return x, n_jac, float(np.sqrt((r ** 2).sum(1).mean()))


@dataclass(frozen=True, eq=False)
class BundleAdjustment:
    """Solution of :func:`bundle_adjust` with what its covariance needs: the parameter vector ``x``
    (per camera fx fy cx cy + distortion, then the free cameras' and the boards' rvec, t), the Jacobian
    and residuals at ``x`` (over the ``mask``-ed observations), the loss, and ``unpack`` mapping any
    parameter vector to (intr (C, 9), cam_from_root (C, 4, 4), board_poses (F, 4, 4))."""

    intr: np.ndarray
    cam_from_root: np.ndarray
    board_poses: np.ndarray
    n_parameters: int
    n_jacobians: int
    x: np.ndarray
    jacobian: np.ndarray  # (2M, P) at x
    residuals: np.ndarray  # (M, 2) at x
    mask: np.ndarray  # (len(obs),) bool: the observations the rows belong to
    loss: str
    loss_scale_px: float
    unpack: object  # callable x -> (intr, cam_from_root, board_poses)
    n_intrinsics: int  # parameters per camera at the start of x


def bundle_adjust(obs: CharucoObservations, spec: CharucoBoardSpec, intr: np.ndarray, cam_from_root: np.ndarray,
                  board_poses: np.ndarray, root: int, mask: np.ndarray, distortion_terms: int = 4,
                  loss: str = "soft_l1", loss_scale_px: float = 1.0, max_iterations: int = 200) -> BundleAdjustment:
    """One bundle adjustment over all intrinsics (fx fy cx cy + distortion), camera poses (root fixed:
    the gauge) and board poses: robust Levenberg-Marquardt with a grouped finite-difference Jacobian.
    """
    C, F = obs.n_cameras, obs.n_frames
    n_intr = 4 + distortion_terms
    cam_free = np.array([c for c in range(C) if c != root], int)
    frame_free = np.flatnonzero(np.isfinite(board_poses[:, 0, 0]))
    o_cam, o_frame = obs.camera[mask], obs.frame[mask]
    Pb = board_corners(spec)[obs.corner_id[mask]]
    uv = obs.uv[mask]
    cam_slot = np.full(C, -1)
    cam_slot[cam_free] = np.arange(len(cam_free))
    frame_slot = np.full(F, -1)
    frame_slot[frame_free] = np.arange(len(frame_free))
    off_ext = C * n_intr
    off_frame = off_ext + 6 * len(cam_free)
    n_params = off_frame + 6 * len(frame_free)

    def rvt(T):
        return np.r_[cv2.Rodrigues(T[:3, :3])[0].ravel(), T[:3, 3]]

    x0 = np.concatenate([intr[:, :n_intr].ravel()] + [rvt(cam_from_root[c]) for c in cam_free]
                        + [rvt(board_poses[f]) for f in frame_free])

    def unpack(x):
        full = np.zeros((C, 9))
        full[:, :n_intr] = x[:off_ext].reshape(C, n_intr)
        ext = x[off_ext:off_frame].reshape(-1, 6)
        cam_R = np.repeat(np.eye(3)[None], C, 0)
        cam_t = np.zeros((C, 3))
        cam_R[cam_free] = rodrigues(ext[:, :3])
        cam_t[cam_free] = ext[:, 3:]
        cam_R[root], cam_t[root] = cam_from_root[root][:3, :3], cam_from_root[root][:3, 3]
        fr = x[off_frame:].reshape(-1, 6)
        frame_R = np.zeros((F, 3, 3))
        frame_t = np.zeros((F, 3))
        frame_R[frame_free] = rodrigues(fr[:, :3])
        frame_t[frame_free] = fr[:, 3:]
        return full, cam_R, cam_t, frame_R, frame_t

    def residuals(x):
        return (project_observations(*unpack(x), o_cam, o_frame, Pb) - uv).ravel()

    # Column groups for finite differences: parameter k of every camera touches disjoint rows (each
    # corner belongs to one camera), so all cameras' k-th parameters are perturbed at once; likewise for
    # board poses. 9 + 6 + 6 groups, i.e. 42 residual evaluations per central-difference Jacobian.
    groups = [np.arange(C) * n_intr + k for k in range(n_intr)]
    groups += [off_ext + np.arange(len(cam_free)) * 6 + k for k in range(6)]
    groups += [off_frame + np.arange(len(frame_free)) * 6 + k for k in range(6)]
    M = len(uv)
    col_cam = np.full(n_params, -1)
    col_frame = np.full(n_params, -1)
    col_cam[:off_ext] = np.repeat(np.arange(C), n_intr)
    col_cam[off_ext:off_frame] = np.repeat(cam_free, 6)
    col_frame[off_frame:] = np.repeat(frame_free, 6)
    row_cam, row_frame = np.repeat(o_cam, 2), np.repeat(o_frame, 2)

    def jacobian(x):
        """Dense Jacobian by grouped central differences (the problem has at most a few hundred parameters)."""
        J = np.zeros((2 * M, n_params))
        for g in groups:
            if len(g) == 0:
                continue
            h = 1e-6 * np.maximum(1.0, np.abs(x[g]))
            xp, xm = x.copy(), x.copy()
            xp[g] += h
            xm[g] -= h
            diff = residuals(xp) - residuals(xm)
            # Scatter each row's difference to the one column of the group it depends on.
            if col_cam[g[0]] >= 0:
                owner = np.full(C, -1)
                owner[col_cam[g]] = np.arange(len(g))
                k = owner[row_cam]
            else:
                owner = np.full(F, -1)
                owner[col_frame[g]] = np.arange(len(g))
                k = owner[row_frame]
            rows = np.flatnonzero(k >= 0)
            J[rows, g[k[rows]]] = diff[rows] / (2 * h[k[rows]])
        return J

    def unpack_rigid(x):
        full, cam_R, cam_t, frame_R, frame_t = unpack(x)
        cams = np.zeros((C, 4, 4))
        cams[:, :3, :3], cams[:, :3, 3], cams[:, 3, 3] = cam_R, cam_t, 1.0
        boards = np.full((F, 4, 4), np.nan)
        boards[frame_free, :3, :3], boards[frame_free, :3, 3] = frame_R[frame_free], frame_t[frame_free]
        boards[frame_free, 3] = [0.0, 0.0, 0.0, 1.0]
        return full, cams, boards

    with _single_thread_blas():
        x, nfev, rms = levenberg_marquardt(residuals, jacobian, x0, loss, loss_scale_px, max_iterations)
        J = jacobian(x)
    log.info("bundle adjustment (%s loss): %d Jacobians, rms %.4f px", loss, nfev, rms)
    full, cams, boards = unpack_rigid(x)
    return BundleAdjustment(full, cams, boards, n_params, nfev, x, J, residuals(x).reshape(-1, 2), mask.copy(),
                            loss, loss_scale_px, unpack_rigid, n_intr)


def reprojection_residuals(obs: CharucoObservations, spec: CharucoBoardSpec, rig: CameraRig,
                           board_to_world: np.ndarray) -> np.ndarray:
    """(M, 2) residual pixels of every observation under a rig and board poses (NaN where a pose is unknown)."""
    out = np.full((len(obs), 2), np.nan)
    P = board_corners(spec)
    for c, name in enumerate(obs.camera_names):
        cam = rig[name]
        for f in range(obs.n_frames):
            m = (obs.camera == c) & (obs.frame == f)
            if m.any() and np.isfinite(board_to_world[f, 0, 0]):
                T = board_to_world[f]
                out[m] = cam.project(P[obs.corner_id[m]] @ T[:3, :3].T + T[:3, 3]) - obs.uv[m]
    return out


def mad_outliers(residuals_px: np.ndarray, k: float) -> np.ndarray:
    """Mask of residual norms above median + k * 1.4826 * MAD (robust sigma)."""
    e = np.linalg.norm(residuals_px, axis=1)
    med = np.median(e)
    mad = 1.4826 * np.median(np.abs(e - med))
    return e > med + k * max(mad, 1e-6)


def world_from_root(obs: CharucoObservations, spec: CharucoBoardSpec, board_poses: np.ndarray,
                    cam_from_root: np.ndarray, options: CalibrationOptions) -> tuple[np.ndarray, str]:
    """4x4 root->world transform from the floor board (or the reference camera) and its description."""
    if options.reference_camera is not None:
        if options.reference_camera not in obs.camera_names:
            raise InputError(f"reference camera {options.reference_camera!r} is not in the capture "
                             f"({', '.join(obs.camera_names)})")
        c = obs.camera_names.index(options.reference_camera)
        return cam_from_root[c], f"camera {options.reference_camera}"
    if options.floor_frame is None or options.floor_frame not in obs.frame_ids:
        raise SessionError(f"floor board frame {options.floor_frame} is not in the capture; capture the board "
                           "lying on the floor first (frame 0) or choose --reference-camera")
    f = obs.frame_ids.index(options.floor_frame)
    if not np.isfinite(board_poses[f, 0, 0]):
        raise SessionError(f"floor board (frame {options.floor_frame}) was not found in any camera; capture the "
                           "board lying flat on the floor where the upper cameras see it, or choose --reference-camera")
    floor = floor_plane_board_pose(spec, board_poses, f, options.floor_max_angle_deg, options.floor_max_offset_m)
    others = len(floor[1]) - 1
    desc = f"floor board frame {options.floor_frame}" + (f" (+{others} coplanar floor boards)" if others else "")
    return floor_board_to_world(spec) @ rigid_inverse(floor[0]), desc


def floor_plane_board_pose(spec: CharucoBoardSpec, board_poses: np.ndarray, f: int, max_angle_deg: float = 5.0,
                           max_offset_m: float = 0.05) -> tuple[np.ndarray, list[int]]:
    """The floor board's pose (board -> root) with its plane replaced by the least-squares plane through
    the corners of every board lying on the floor with it, and those frames.

    A board counts as lying on the floor when its plane is within ``max_angle_deg`` of the floor board's
    and all its corners are within ``max_offset_m`` of that plane. The floor board ``f`` keeps defining
    the origin (its centre, projected onto the fitted plane) and the x axis (its x axis, projected); the
    fitted plane gives y. With the floor board alone this is exactly its own pose. Several boards spread
    over the floor, each seen less obliquely, pin the floor's tilt far better than one board seen at
    ~65 degrees by the upper cameras (measured in docs/calibration.md).
    """
    corners = board_corners(spec)
    T0 = board_poses[f]
    n0 = T0[:3, 2]
    c0 = T0[:3, :3] @ spec.center_m + T0[:3, 3]
    frames, pts = [], []
    for g, T in enumerate(board_poses):
        if not np.isfinite(T[0, 0]):
            continue
        P = corners @ T[:3, :3].T + T[:3, 3]
        angle = np.degrees(np.arccos(np.clip(abs(T[:3, 2] @ n0), -1.0, 1.0)))
        if g == f or (angle < max_angle_deg and np.abs((P - c0) @ n0).max() < max_offset_m):
            frames.append(g)
            pts.append(P)
    P = np.concatenate(pts)
    mean = P.mean(0)
    n = np.linalg.svd(P - mean, full_matrices=False)[2][2]
    n = n if n @ n0 > 0 else -n
    x = T0[:3, 0] - (T0[:3, 0] @ n) * n
    x /= np.linalg.norm(x)
    R = np.stack([x, np.cross(n, x), n], axis=1)
    center = c0 - ((c0 - mean) @ n) * n
    return rigid(R, center - R @ spec.center_m), frames


def calibrate_cameras(obs: CharucoObservations, spec: CharucoBoardSpec,
                      options: CalibrationOptions | None = None) -> CalibrationResult:
    """Calibrate every camera of a capture: Zhang intrinsics, camera-graph extrinsics, robust bundle
    adjustment with MAD outlier rejection and a final least-squares pass, world frame from the floor board."""
    options = options or CalibrationOptions()
    if not options.sigma_inflation >= 1.0:
        raise InputError(f"sigma_inflation must be >= 1 (1: i.i.d. corner noise), got {options.sigma_inflation}")
    if options.distortion_terms not in (4, 5):
        raise InputError(f"distortion_terms must be 4 or 5, got {options.distortion_terms}")
    t0 = time.perf_counter()
    stages = {}
    Ks, dists, view_poses = initial_intrinsics(obs, spec, options.distortion_terms)
    stages["intrinsics"] = time.perf_counter() - t0
    cam_from_root, root, _ = camera_graph_extrinsics(obs, view_poses)
    boards = initial_board_poses(obs, view_poses, cam_from_root)
    stages["camera_graph"] = time.perf_counter() - t0 - stages["intrinsics"]
    intr = np.concatenate([Ks[:, 0, 0:1], Ks[:, 1, 1:2], Ks[:, 0, 2:3], Ks[:, 1, 2:3], dists], axis=1)
    intr[:, 4 + options.distortion_terms:] = 0.0
    # Views whose pose could not be initialised (and frames nobody resolved) stay out of the adjustment.
    usable = np.array([(c, f) in view_poses for c, f in zip(obs.camera, obs.frame, strict=True)], bool)
    usable &= np.isfinite(boards[obs.frame, 0, 0])
    t1 = time.perf_counter()
    ba = bundle_adjust(obs, spec, intr, cam_from_root, boards, root, usable, options.distortion_terms, options.loss,
                       options.loss_scale_px, options.max_iterations)
    intr, cams, boards, nfev1 = ba.intr, ba.cam_from_root, ba.board_poses, ba.n_jacobians
    rig_root = _rig_from(obs, intr, cams)
    residuals = reprojection_residuals(obs, spec, rig_root, boards)
    inliers = usable & ~mad_outliers(np.nan_to_num(residuals, nan=1e6), options.outlier_mad_k)
    inliers &= usable
    log.info("bundle adjustment pass 1: %d evaluations, %d outliers of %d corners", nfev1,
             int((usable & ~inliers).sum()), int(usable.sum()))
    ba = bundle_adjust(obs, spec, intr, cams, boards, root, inliers, options.distortion_terms, "linear", 1.0,
                       options.max_iterations)
    intr, cams, boards, n_params = ba.intr, ba.cam_from_root, ba.board_poses, ba.n_parameters
    stages["bundle_adjustment"] = time.perf_counter() - t1
    world_T_root, world_desc = world_from_root(obs, spec, boards, cams, options)
    root_T_world = rigid_inverse(world_T_root)
    cams_world = np.array([T @ root_T_world for T in cams])
    boards_world = np.array([world_T_root @ T for T in boards])
    rig = _rig_from(obs, intr, cams_world)
    residuals = reprojection_residuals(obs, spec, rig, boards_world)
    residuals = np.where(np.isfinite(residuals), residuals, 0.0)
    t2 = time.perf_counter()
    with _single_thread_blas():
        uncertainty = calibration_uncertainty(obs, spec, ba, cams_world, inliers, options)
    stages["uncertainty"] = time.perf_counter() - t2
    seconds = time.perf_counter() - t0
    result = CalibrationResult(rig, boards_world, obs, inliers, residuals, n_params, world_desc, seconds, stages,
                               uncertainty)
    log.info("calibrated %d cameras: reprojection RMS %.3f px in %.2f s", obs.n_cameras, result.rms_px, seconds)
    return result


def calibration_uncertainty(obs: CharucoObservations, spec: CharucoBoardSpec, ba: BundleAdjustment,
                            cams_world: np.ndarray, inliers: np.ndarray,
                            options: CalibrationOptions) -> CalibrationUncertainty:
    """Per-camera 1-sigma of fx, fy, cx, cy, centre and rotation in the world frame, Result 5.10 of
    Hartley & Zisserman (``s^2 (J^T W J)^-1`` of the final adjustment) propagated (Result 5.6) through
    ``C = -R^T t`` and the world frame the floor boards (or the reference camera) define from the
    adjusted parameters: the root camera is the adjustment's gauge, the world frame is not fixed by it.
    """
    if ba.loss == "linear":  # the final pass: corner errors correlated within a view (view_effect_covariance)
        view = obs.camera[ba.mask] * max(obs.n_frames, 1) + obs.frame[ba.mask]
        cov_x, s2, t2 = view_effect_covariance(ba.jacobian, ba.residuals.ravel(),
                                               view_error_basis(obs.uv[ba.mask], view))
    else:
        weights = np.repeat(robust_weights(ba.residuals, ba.loss, ba.loss_scale_px), 2)
        (cov_x, s2), t2 = parameter_covariance(ba.jacobian, ba.residuals.ravel(), weights), 0.0
    cov_x = cov_x * options.sigma_inflation ** 2
    reference_R = cams_world[:, :3, :3].copy()

    def quantities(x: np.ndarray) -> np.ndarray:
        intr_x, cams_x, boards_x = ba.unpack(x)
        world_T_root_x, _ = world_from_root(obs, spec, boards_x, cams_x, options)
        return camera_quantities(intr_x, cams_x @ rigid_inverse(world_T_root_x), reference_R).ravel()

    _, cov_q = propagated_covariance(quantities, ba.x, cov_x)
    coverages = [corner_coverage(obs.uv[inliers & (obs.camera == c)], obs.frame[inliers & (obs.camera == c)],
                                 *obs.image_sizes[c]) for c in range(obs.n_cameras)]
    intr_now = ba.intr
    cams = camera_verdicts(obs.camera_names, intr_now, cov_q, coverages, options.max_center_sigma_mm,
                           options.max_focal_sigma_pct)
    result = CalibrationUncertainty(cams, float(np.sqrt(s2)), options.max_center_sigma_mm,
                                    options.max_focal_sigma_pct, options.sigma_inflation, float(np.sqrt(t2)))
    for cam in result.cameras:
        log.info("camera %s: sigma centre %.2f mm, focal %.3f %%, coverage %.0f %% -> %s", cam.name,
                 cam.center_sigma_mm, cam.focal_sigma_pct, 100 * cam.coverage.fraction, cam.verdict)
    return result


def _rig_from(obs: CharucoObservations, intr: np.ndarray, cam_T: np.ndarray) -> CameraRig:
    cams = {}
    for c, name in enumerate(obs.camera_names):
        fx, fy, cx, cy = intr[c, :4]
        K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])
        w, h = obs.image_sizes[c]
        cams[name] = Camera(name, K, intr[c, 4:9], cam_T[c][:3, :3], cam_T[c][:3, 3], w, h)
    return CameraRig(cams)
