"""The calibration's reported uncertainty against independent references (mutation round mutFF, issue 17).

An uncertainty that lies passes a bad calibration as certain, or refuses a good one. Every function of
:mod:`bodystudio.calib.uncertainty` is checked here on small hand-made inputs against a reference written
another way: the covariance from ``np.linalg.inv`` of the weighted normal matrix, the correlated-noise sandwich
``A^-1 J^T Omega J A^-1`` with the hat matrix built densely, Jacobians in closed form, rotation vectors by
scipy, hulls and cells by hand, the advice and verdict lines word for word. Under a second in all.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.spatial.transform import Rotation

from bodystudio.calib.uncertainty import (
    MAX_CENTER_SIGMA_MM,
    MAX_FOCAL_SIGMA_PCT,
    CalibrationUncertainty,
    CameraCoverage,
    CameraUncertainty,
    _finite,
    camera_quantities,
    camera_verdicts,
    corner_coverage,
    coverage_advice,
    coverage_image,
    normal_matrix_inverse,
    parameter_covariance,
    propagated_covariance,
    view_effect_covariance,
    view_error_basis,
)

# ---------------------------------------------------------------------------------------------- covariances


def test_parameter_covariance_weighted_is_s2_times_the_inverse_weighted_normal_matrix():
    rng = np.random.default_rng(3)
    J = rng.normal(size=(9, 3)) * [1.0, 100.0, 0.01]  # badly scaled columns, as intrinsics next to poses
    r = rng.normal(size=9)
    w = rng.uniform(0.1, 2.0, 9)
    cov, s2 = parameter_covariance(J, r.reshape(3, 3), w)
    s2_ref = sum(w[i] * r[i] ** 2 for i in range(9)) / (9 - 3)
    Jw = J * np.sqrt(w)[:, None]
    assert s2 == pytest.approx(s2_ref, rel=1e-12)
    np.testing.assert_allclose(cov, s2_ref * np.linalg.inv(Jw.T @ Jw), rtol=1e-9)
    cov1, s21 = parameter_covariance(J, r)  # no weights: ones
    assert s21 == pytest.approx((r @ r) / 6, rel=1e-12)
    np.testing.assert_allclose(cov1, s21 * np.linalg.inv(J.T @ J), rtol=1e-9)


@pytest.mark.parametrize("n", [2, 3])
def test_parameter_covariance_without_redundancy_is_infinite(n):
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no 0 / 0 on the way
        cov, s2 = parameter_covariance(np.eye(n, 3), np.zeros(n))  # n <= p: an exact fit, residuals 0
    assert s2 == np.inf and cov.shape == (3, 3) and np.all(cov == np.inf)


def test_parameter_covariance_with_one_redundant_observation_and_its_rcond():
    J = np.array([[1.0, 0.0], [0.0, 2.0], [1.0, 1.0]])
    r = np.array([0.5, -0.25, 0.125])
    cov, s2 = parameter_covariance(J, r)  # one degree of freedom
    assert s2 == pytest.approx(0.25 + 0.0625 + 0.015625)
    np.testing.assert_allclose(cov, s2 * np.linalg.inv(J.T @ J), rtol=1e-12)
    twin = np.c_[J[:, :1], J[:, :1]]  # two copies of one column: only their sum is observed
    rcond = 1e-6
    cov, s2 = parameter_covariance(twin, r, rcond=rcond)
    # Jacobi-scaled normal matrix 2 * [[1, 1], [1, 1]] / 2: eigenvalues 0 and 2, scale 1 / sqrt(2)
    u, v = np.array([1.0, 1.0]) / np.sqrt(2), np.array([1.0, -1.0]) / np.sqrt(2)
    expected = s2 * (np.outer(u, u) / 2 + np.outer(v, v) / (rcond * 2)) / 2
    np.testing.assert_allclose(cov, expected, rtol=1e-9)


def test_normal_matrix_inverse_is_the_inverse_of_a_badly_scaled_matrix():
    rng = np.random.default_rng(0)
    J = rng.normal(size=(40, 4)) * [1e3, 1.0, 1e-3, 10.0]
    A = J.T @ J
    np.testing.assert_allclose(normal_matrix_inverse(A), np.linalg.inv(A), rtol=1e-8)


def test_normal_matrix_inverse_keeps_an_unobservable_direction_hugely_uncertain():
    A = np.array([[4.0, 4.0], [4.0, 4.0]])  # only the sum is observed
    d = 0.5  # Jacobi scale 1 / sqrt(4); scaled matrix [[1, 1], [1, 1]]: eigenvalues 0 and 2
    rcond = 1e-6
    u, v = np.array([1.0, 1.0]) / np.sqrt(2), np.array([1.0, -1.0]) / np.sqrt(2)
    expected = (np.outer(u, u) / 2 + np.outer(v, v) / (rcond * 2)) * d * d
    np.testing.assert_allclose(normal_matrix_inverse(A, rcond), expected, rtol=1e-9)
    default = normal_matrix_inverse(A)  # rcond 1e-15
    assert default[0, 0] == pytest.approx(0.25 * (0.25 + 0.25 / 1e-15), rel=1e-6)


def test_normal_matrix_inverse_of_an_unevenly_scaled_rank_deficient_matrix():
    """A = D M D, M with unit diagonal and eigenvalues 0, 1, 2: the Jacobi scaling recovers M exactly, the
    unobservable direction gets 1 / (rcond x 2), the largest eigenvalue (not the middle one)."""
    D = np.diag([0.5, 3.0, 0.1])  # scales below and above 1
    M = np.array([[1.0, 1.0, 0.0], [1.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    rcond = 1e-6
    w, u = np.array([1.0, 1.0, 0.0]) / np.sqrt(2), np.array([1.0, -1.0, 0.0]) / np.sqrt(2)
    e3 = np.array([0.0, 0.0, 1.0])
    inv_m = np.outer(w, w) / 2 + np.outer(e3, e3) + np.outer(u, u) / (rcond * 2)
    Dinv = np.linalg.inv(D)
    np.testing.assert_allclose(normal_matrix_inverse(D @ M @ D, rcond), Dinv @ inv_m @ Dinv, rtol=1e-9)


def test_view_error_basis_by_hand():
    uv = np.array([[0.0, 0.0], [4.0, 0.0], [10.0, 10.0], [0.0, 3.0], [12.0, 10.0], [50.0, 50.0], [7.0, 7.0],
                   [7.5, 7.0]])
    view_of = np.array([5, 5, 2, 5, 2, 9, 11, 11])  # views 2, 5, 9, 11 -> columns 0-3, 4-7, 8-11, 12-15
    B = view_error_basis(uv.ravel(), view_of)  # view 11: two corners half a pixel apart, scaled to unit RMS too
    assert isinstance(B, sp.csc_matrix) and B.shape == (16, 16)
    ref = np.zeros((16, 16))
    for col, v in enumerate((2, 5, 9, 11)):
        idx = [i for i in range(8) if view_of[i] == v]
        c = uv[idx].mean(0)
        rms = np.sqrt(np.mean([np.sum((uv[i] - c) ** 2) for i in idx]))
        for i in idx:
            dx, dy = ((uv[i] - c) / rms) if rms > 0 else (0.0, 0.0)
            for k, (fu, fv) in enumerate(((1, 0), (0, 1), (-dy, dx), (dx, dy))):
                ref[2 * i, 4 * col + k], ref[2 * i + 1, 4 * col + k] = fu, fv
    np.testing.assert_allclose(B.toarray(), ref, atol=1e-12)
    assert np.isfinite(B.toarray()).all()  # a single corner: no rotation or scale, not NaN
    empty = view_error_basis(np.zeros((0, 2)), np.zeros(0, int))
    assert empty.shape == (0, 0)


def _dense_view_effect(J, r, B):
    """The method of moments and the sandwich written densely: H the hat matrix, Omega = s2 I + t2 B B^T."""
    n, p = J.shape
    B = B.toarray() if sp.issparse(B) else B
    H = J @ np.linalg.inv(J.T @ J) @ J.T
    M = B.T @ (np.eye(n) - H) @ B
    lhs = np.array([[n - p, np.trace(M)], [np.trace(M), np.sum(M * M)]])
    rhs = np.array([r @ r, np.sum((B.T @ r) ** 2)])
    s2, t2 = np.linalg.solve(lhs, rhs)
    return s2, t2, B


def _sandwich(J, B, s2, t2):
    A_inv = np.linalg.inv(J.T @ J)
    Omega = s2 * np.eye(len(J)) + t2 * B @ B.T
    return A_inv @ J.T @ Omega @ J @ A_inv


def _problem(seed, t_px, s_px=0.3, n_views=6, per_view=5):
    rng = np.random.default_rng(seed)
    uv = rng.uniform(0, 100, (n_views * per_view, 2))
    view = np.repeat(np.arange(n_views), per_view)
    J = rng.normal(size=(2 * len(uv), 5))
    B = view_error_basis(uv, view)
    e = rng.normal(0, s_px, len(J)) + B @ rng.normal(0, t_px, B.shape[1])
    r = e - J @ np.linalg.lstsq(J, e, rcond=None)[0]
    return J, r, B


@pytest.mark.parametrize("scale", [1.0, 1e-3])  # a small basis: det of the moment equations ~1e-12, still solved
def test_view_effect_covariance_is_the_sandwich_of_its_moment_estimates(scale):
    J, r, B = _problem(1, t_px=1.0)
    B = B * scale
    s2_ref, t2_ref, Bd = _dense_view_effect(J, r, B)
    assert s2_ref > 0 and t2_ref > 0
    cov, s2, t2 = view_effect_covariance(J, r, B)
    assert s2 == pytest.approx(s2_ref, rel=1e-9) and t2 == pytest.approx(t2_ref, rel=1e-9)
    np.testing.assert_allclose(cov, _sandwich(J, Bd, s2_ref, t2_ref), rtol=1e-8)


@pytest.mark.parametrize("seed, t_px, s_px", [(2, 0.0, 0.3), (0, 5.0, 0.0)])
def test_view_effect_covariance_falls_back_to_iid_when_a_moment_estimate_is_not_positive(seed, t_px, s_px):
    J, r, B = _problem(seed, t_px, s_px)
    s2_ref, t2_ref, _ = _dense_view_effect(J, r, B)
    assert min(s2_ref, t2_ref) <= 0 < max(s2_ref, t2_ref)  # one of the two is not positive
    cov, s2, t2 = view_effect_covariance(J, r, B)
    iid = (r @ r) / (len(J) - 5)
    assert t2 == 0.0 and s2 == pytest.approx(iid, rel=1e-12)
    np.testing.assert_allclose(cov, iid * np.linalg.inv(J.T @ J), rtol=1e-8)


def test_view_effect_covariance_without_a_basis_or_redundancy():
    rng = np.random.default_rng(2)
    J, r = rng.normal(size=(8, 3)), rng.normal(size=8)
    cov, s2, t2 = view_effect_covariance(J, r, sp.csc_matrix((8, 0)))  # no view field: det 0
    assert (s2, t2) == (pytest.approx((r @ r) / 5, rel=1e-12), 0.0)
    np.testing.assert_allclose(cov, s2 * np.linalg.inv(J.T @ J), rtol=1e-9)
    cov, s2, t2 = view_effect_covariance(J[:3], r[:3], sp.csc_matrix((3, 4)))
    assert s2 == np.inf and t2 == 0.0 and cov.shape == (3, 3) and np.all(cov == np.inf)
    cov, s2, t2 = view_effect_covariance(J[:4], r[:4], sp.csc_matrix((4, 0)))  # one degree of freedom
    assert s2 == pytest.approx((r[:4] @ r[:4]) / 1, rel=1e-12) and t2 == 0.0  # the residuals as given
    twin = np.c_[J[:, :1], J[:, :1]]  # only the sum of the two parameters is observed
    cov, s2, _ = view_effect_covariance(twin, r, sp.csc_matrix((8, 0)), rcond=1e-6)
    A = twin.T @ twin  # Jacobi scale 1 / sqrt(a), scaled matrix [[1, 1], [1, 1]]
    u, v = np.array([1.0, 1.0]) / np.sqrt(2), np.array([1.0, -1.0]) / np.sqrt(2)
    np.testing.assert_allclose(cov, s2 * (np.outer(u, u) / 2 + np.outer(v, v) / 2e-6) / A[0, 0], rtol=1e-9)


def test_propagated_covariance_is_g_sigma_g_with_the_closed_form_jacobian():
    x = np.array([2.0, -3000.0, 0.5, 7.0])
    cov = np.array([[0.04, 0.01, 0.0, 0.0], [0.01, 0.09, 0.0, 0.0], [0.0, 0.0, 0.01, 0.0], [0.0, 0.0, 0.0, 0.0]])
    seen = []

    def fun(v):
        seen.append(v.copy())
        return np.array([v[0] * v[1], np.sin(v[2]) + v[1] / 1000, v[0] ** 2 + v[3]])

    y, cov_y = propagated_covariance(fun, x, cov)
    G = np.array([[x[1], x[0], 0, 0], [0, 1 / 1000, np.cos(x[2]), 0], [2 * x[0], 0, 0, 1]])
    np.testing.assert_allclose(y, fun(x))
    np.testing.assert_allclose(cov_y, G @ cov @ G.T, rtol=1e-6, atol=1e-12)
    # the steps: +-1e-6 x max(1, |x_k|) on each parameter with a variance, none on x[3] (zero variance)
    steps = [(v - x) for v in seen[1:7]]
    for k, h in ((0, 2e-6), (1, 3e-3), (2, 1e-6)):
        assert np.allclose(steps[2 * k], np.eye(4)[k] * h, rtol=1e-6, atol=0)
        assert np.allclose(steps[2 * k + 1], -np.eye(4)[k] * h, rtol=1e-6, atol=0)
    assert len(seen) == 1 + 6 + 1
    y_const, _ = propagated_covariance(lambda v: [3, 4], x, cov)  # a value of integers comes back as floats
    assert y_const.dtype == np.float64 and y_const.tolist() == [3.0, 4.0]
    y_int, cov_int = propagated_covariance(fun, [2, -3000, 1, 7], cov)  # integer parameters are stepped too
    G1 = np.array([[-3000, 2, 0, 0], [0, 1 / 1000, np.cos(1.0), 0], [4, 0, 0, 1]])
    np.testing.assert_allclose(cov_int, G1 @ cov @ G1.T, rtol=1e-6, atol=1e-12)
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")  # an unobservable (inf) or huge variance is reported, not warned about
        _, inf_y = propagated_covariance(lambda v: v[:2] * 2.0, x[:2], np.diag([np.inf, 1.0]))
        _, huge_y = propagated_covariance(lambda v: v * 1e200, np.array([1.0]), np.array([[1e300]]))
    assert inf_y[0, 0] == np.inf and huge_y[0, 0] == np.inf


def test_camera_quantities_centre_and_rotation_error():
    rot = Rotation.from_rotvec([[0.1, -0.2, 0.3], [0.0, 0.5, 0.0]])
    R = rot.as_matrix()
    t = np.array([[0.1, 0.2, 3.0], [-1.0, 0.0, 2.0]])
    T = np.zeros((2, 4, 4))
    T[:, :3, :3], T[:, :3, 3], T[:, 3, 3] = R, t, 1.0
    intr = np.array([[800.0, 810.0, 320.0, 240.0, 0.1, 0.0], [900.0, 905.0, 330.0, 250.0, 0.0, 0.2]])
    small = Rotation.from_rotvec([[0.0, 0.0, 0.01], [0.002, 0.0, 0.0]])
    ref = (small.inv() * rot).as_matrix()  # R ref^T = small
    q = camera_quantities(intr, T, ref)
    assert q.shape == (2, 10)
    np.testing.assert_allclose(q[:, :4], intr[:, :4])
    np.testing.assert_allclose(q[:, 4:7], [-R[c].T @ t[c] for c in range(2)], atol=1e-12)
    np.testing.assert_allclose(q[:, 7:], small.as_rotvec(), atol=1e-12)


# ---------------------------------------------------------------------------------------------- coverage


def test_corner_coverage_by_hand():
    # view 0: a 60 x 40 rectangle's corners and centre; view 1: two corners (no hull); one corner past the image
    uv = np.array([[10, 10], [70, 10], [70, 50], [10, 50], [40, 30], [639, 479], [0, 0], [700, -5]], float)
    view_of = np.array([0, 0, 0, 0, 0, 1, 1, 1])
    cov = corner_coverage(uv, view_of, 640, 480, grid=(3, 4))
    grid = np.zeros((3, 4), int)
    for u, v in uv:
        grid[min(max(int(v / 480 * 3), 0), 2), min(max(int(u / 640 * 4), 0), 3)] += 1
    assert cov.grid.tolist() == grid.tolist() == [[6, 0, 0, 1], [0, 0, 0, 0], [0, 0, 0, 1]]
    assert cov.fraction == pytest.approx(3 / 12)
    assert cov.regions.tolist() == [[6, 0, 1], [0, 0, 0], [0, 0, 1]]
    assert cov.n_views == 2
    view1 = np.array([[639, 479], [0, 0], [700, -5]], np.float32)
    hull1 = 0.5 * abs((view1[1, 0] - view1[0, 0]) * (view1[2, 1] - view1[0, 1])
                      - (view1[2, 0] - view1[0, 0]) * (view1[1, 1] - view1[0, 1]))
    assert cov.median_view_fraction == pytest.approx((2400 / (640 * 480) + hull1 / (640 * 480)) / 2)
    # the hull of all corners: (0,0), (700,-5), (639,479), (10,50) in that order around
    poly = np.array([[0, 0], [700, -5], [639, 479], [10, 50]], float)
    area = 0.5 * abs(sum(poly[i, 0] * poly[i - 1, 1] - poly[i - 1, 0] * poly[i, 1] for i in range(4)))
    assert cov.hull_fraction == pytest.approx(area / (640 * 480))
    assert cov.grid.dtype.kind == "i" and cov.regions.dtype.kind == "i"  # counts: integers in the report
    # far outside the image on every side: clipped into the border cells, never wrapped around
    far = corner_coverage(np.array([[-300.0, -400.0], [2000.0, 3000.0], [-300.0, 3000.0]]), np.zeros(3, int), 640, 480,
                          grid=(3, 4))
    assert far.grid.tolist() == [[1, 0, 0, 0], [0, 0, 0, 0], [1, 0, 0, 1]]
    assert far.regions.tolist() == [[1, 0, 0], [0, 0, 0], [1, 0, 1]]
    # three views: the median of their own hulls (a view's hull is of its corners only)
    tri = np.array([[0, 0], [64, 0], [0, 48], [0, 0], [128, 0], [0, 96], [0, 0], [320, 0], [0, 240]], float)
    three = corner_coverage(tri, np.repeat([0, 1, 2], 3), 640, 480)
    assert three.median_view_fraction == pytest.approx(0.5 * 128 * 96 / (640 * 480))
    two = corner_coverage(uv[:2], view_of[:2], 640, 480)
    assert two.hull_fraction == 0.0 and two.median_view_fraction == 0.0 and two.grid.shape == (6, 8)
    none = corner_coverage(np.zeros((0, 2)), np.zeros(0, int), 640, 480)
    assert (none.fraction, none.hull_fraction, none.median_view_fraction, none.n_views) == (0.0, 0.0, 0.0, 0)
    assert none.grid.shape == (6, 8) and not none.grid.any() and none.regions.shape == (3, 3)


def _coverage(regions, median=0.3, n_views=10, fraction=0.5):
    return CameraCoverage(np.zeros((6, 8), int), fraction, 0.5, median, n_views, np.array(regions))


def test_coverage_advice_words():
    full = [[5, 5, 5], [5, 5, 5], [5, 5, 5]]
    assert coverage_advice(_coverage(full)) == "add tilted views that other cameras see too"
    top_left_empty = [[0, 0, 0], [0, 5, 5], [0, 5, 5]]
    assert coverage_advice(_coverage(top_left_empty)) == ("add views with the board in the top third, the left third "
                                                          "of the image")
    bottom_right = [[5, 5, 5], [5, 5, 5], [5, 5, 0]]
    assert coverage_advice(_coverage(bottom_right)) == "add views with the board in bottom-right of the image"
    # under 2 % of the corners counts as lacking; the centre cell is never named; at most four parts
    sparse = [[1, 100, 1], [100, 1, 100], [1, 100, 1]]
    assert coverage_advice(_coverage(sparse)) == ("add views with the board in top-left, top-right, bottom-left, "
                                                  "bottom-right of the image")
    five = [[0, 0, 1000], [0, 1000, 1000], [1000, 0, 0]]
    assert coverage_advice(_coverage(five)) == ("add views with the board in top-left, top-centre, middle-left, "
                                                "bottom-centre of the image")
    exactly_two_pct = [[2, 14, 12], [12, 12, 12], [12, 12, 12]]  # 2 / 100 is not under 2 %
    assert coverage_advice(_coverage(exactly_two_pct)) == "add tilted views that other cameras see too"
    one_of_few = [[1, 5, 5], [5, 5, 5], [5, 5, 5]]  # one corner of 41 (2.4 %) is not lacking
    assert coverage_advice(_coverage(one_of_few)) == "add tilted views that other cameras see too"
    assert coverage_advice(_coverage(full, median=0.0549)).startswith("hold the board closer (one view covers 5 % ")
    assert coverage_advice(_coverage(full, median=0.05, n_views=3)) == (
        "hold the board closer (one view covers 5 % of the image); add tilted views (only 3)")
    assert coverage_advice(_coverage(full, median=0.08, n_views=6)) == "add tilted views that other cameras see too"
    assert coverage_advice(_coverage(top_left_empty, median=0.02, n_views=5)) == (
        "add views with the board in the top third, the left third of the image; hold the board closer (one view "
        "covers 2 % of the image); add tilted views (only 5)")
    none = [[0, 0, 0], [0, 0, 0], [0, 0, 0]]
    assert coverage_advice(_coverage(none, n_views=0)).startswith(
        "add views with the board in the top third, the middle third, the bottom third, the left third of the image")


# ---------------------------------------------------------------------------------------------- verdicts


def _block(var_intr, centre_var_m2, rot_var):
    b = np.zeros((10, 10))
    b[np.arange(4), np.arange(4)] = var_intr
    b[4:7, 4:7] = centre_var_m2
    b[7:10, 7:10] = rot_var
    return b


def _quantities_cov(*blocks):
    out = np.zeros((10 * len(blocks), 10 * len(blocks)))
    for c, b in enumerate(blocks):
        out[10 * c:10 * c + 10, 10 * c:10 * c + 10] = b
    return out


def test_camera_verdicts_sigmas_and_thresholds():
    intr = np.array([[1000.0, 2000.0, 320.0, 240.0], [800.0, -400.0, 300.0, 200.0], [500.0, 500.0, 1.0, 1.0]])
    centre0 = np.array([[1e-6, 2e-7, 0.0], [2e-7, 4e-6, 0.0], [0.0, 0.0, 4e-6]])  # trace 9 mm^2: 3 mm
    rot0 = np.diag([np.radians(0.1) ** 2, 0.0, 0.0])
    blocks = [_block([4.0, 1.0, 0.25, 9.0], centre0, rot0),
              _block([1.0, 4.0, -1.0, np.inf], np.diag([0.25e-6, 0, 0]), np.zeros((3, 3))),  # fy 2 / 400 = 0.5 %
              _block([np.nan, 0, 0, 0], np.diag([np.inf, 0, 0]), np.diag([np.nan, 0, 0]))]
    covs = [_coverage([[5] * 3] * 3, fraction=f) for f in (0.25, 0.5, 0.125)]
    out = camera_verdicts(["a", "b", "c"], intr, _quantities_cov(*blocks), covs)
    a, b, c = out
    assert (a.name, a.fx_sigma_px, a.fy_sigma_px, a.cx_sigma_px, a.cy_sigma_px) == ("a", 2.0, 1.0, 0.5, 3.0)
    assert a.focal_sigma_pct == pytest.approx(0.2) and a.center_sigma_mm == pytest.approx(3.0)
    np.testing.assert_allclose(a.center_cov_mm2, centre0 * 1e6)
    assert a.rot_sigma_deg == pytest.approx(0.1) and a.coverage is covs[0]
    assert a.verdict == "uncertain"
    assert a.advice == ("a: centre sigma 3.0 mm, corners cover 25 % of the image: add tilted views that other "
                        "cameras see too")
    assert b.cx_sigma_px == 0.0 and b.cy_sigma_px == np.inf  # a negative variance (round-off) is 0; inf stays
    assert b.focal_sigma_pct == pytest.approx(0.5) and b.center_sigma_mm == pytest.approx(0.5)
    assert b.rot_sigma_deg == 0.0 and b.verdict == "ok" and b.advice == ""  # 0.5 % is within 0.5 %
    assert c.fx_sigma_px == np.inf and c.center_sigma_mm == np.inf and c.rot_sigma_deg == np.inf
    assert c.focal_sigma_pct == np.inf and c.verdict == "uncertain"
    assert c.advice == ("c: centre sigma inf mm, focal sigma inf %, corners cover 12 % of the image: add tilted "
                        "views that other cameras see too")
    # a non-finite covariance between two axes: the sigma is unknown (inf), even with finite variances
    d = _block([1.0, 1.0, 1.0, 1.0], np.diag([1e-6, 1e-6, 1e-6]), np.diag([1e-6, 1e-6, 1e-6]))
    d[4, 5] = d[5, 4] = d[7, 8] = d[8, 7] = np.inf
    (dd,) = camera_verdicts(["d"], intr[:1], _quantities_cov(d), covs[:1])
    assert dd.center_sigma_mm == np.inf and dd.rot_sigma_deg == np.inf
    # the thresholds are inclusive and can be given
    loose = camera_verdicts(["a"], intr[:1], _quantities_cov(blocks[0]), covs[:1],
                            max_center_sigma_mm=a.center_sigma_mm, max_focal_sigma_pct=0.1)
    assert loose[0].advice == "a: focal sigma 0.20 %, corners cover 25 % of the image: add tilted views that other " \
                              "cameras see too"
    ok = camera_verdicts(["a"], intr[:1], _quantities_cov(blocks[0]), covs[:1],
                         max_center_sigma_mm=a.center_sigma_mm, max_focal_sigma_pct=a.focal_sigma_pct)
    assert ok[0].verdict == "ok" and ok[0].advice == ""
    assert MAX_CENTER_SIGMA_MM == 2.0 and MAX_FOCAL_SIGMA_PCT == 0.5
    assert _finite(np.nan) == np.inf and _finite(-np.inf) == np.inf and _finite(np.float32(2.5)) == 2.5


def test_camera_uncertainty_to_dict():
    grid = np.zeros((2, 3), int)
    grid[0, 1] = 4
    coverage = CameraCoverage(grid, 1 / 6, 0.25, 0.125, 7, np.zeros((3, 3), int))
    cam = CameraUncertainty("cam0", 1.5, np.inf, 0.5, 0.25, 0.2, 3.0, np.diag([4.0, -9.0, 1.0]), np.inf, coverage,
                            "uncertain", "cam0: advice")
    assert cam.to_dict() == {
        "fx_sigma_px": 1.5, "fy_sigma_px": None, "cx_sigma_px": 0.5, "cy_sigma_px": 0.25, "focal_sigma_pct": 0.2,
        "center_sigma_mm": 3.0, "center_sigma_xyz_mm": [2.0, 3.0, 1.0], "rot_sigma_deg": None,
        "coverage": {"fraction": 1 / 6, "hull_fraction": 0.25, "median_view_fraction": 0.125, "n_views": 7,
                     "grid_rows_cols": [2, 3], "grid": [[0, 4, 0], [0, 0, 0]]},
        "verdict": "uncertain", "advice": "cam0: advice"}


def _cam(name, centre, focal, verdict):
    cov = _coverage([[5] * 3] * 3)
    return CameraUncertainty(name, 1.0, 1.0, 1.0, 1.0, focal, centre, np.eye(3), 0.1, cov, verdict,
                             "" if verdict == "ok" else f"{name}: fix")


def test_calibration_uncertainty_verdict_summary_and_record():
    good = CalibrationUncertainty([_cam("a", 1.0, 0.1, "ok"), _cam("b", 1.5, 0.2, "ok")], 0.3)
    assert good.ok and good.verdict == "ok" and good.advice() == [] and good["b"].center_sigma_mm == 1.5
    assert good.summary() == "calibration certain: every camera within the thresholds"
    # the worst is by centre sigma over its threshold first, then focal
    one = CalibrationUncertainty([_cam("a", 1.0, 0.1, "ok"), _cam("b", 3.0, 0.1, "uncertain")], 0.3)
    assert not one.ok and one.verdict == "uncertain" and one.advice() == ["b: fix"]
    assert one.summary() == ("calibration uncertain (thresholds: centre sigma 2 mm, focal sigma 0.5 %): b: fix")
    two = CalibrationUncertainty([_cam("a", 3.0, 0.1, "uncertain"), _cam("b", 5.0, 0.1, "uncertain")], 0.3,
                                 max_center_sigma_mm=2.5, max_focal_sigma_pct=0.25)
    assert two.summary() == ("calibration uncertain (thresholds: centre sigma 2.5 mm, focal sigma 0.25 %): b: fix "
                             "(and 1 more camera)")
    tie = [_cam("a", 3.0, 0.9, "uncertain"), _cam("b", 3.0, 2.0, "uncertain"), _cam("c", 1.0, 9.0, "uncertain")]
    three = CalibrationUncertainty(tie, 0.3)
    assert three.summary().endswith(": b: fix (and 2 more cameras)")
    assert CalibrationUncertainty(tie[::-1], 0.3).summary().endswith(": b: fix (and 2 more cameras)")
    rec = two.to_dict()
    assert rec == {"verdict": "uncertain", "residual_sigma_px": 0.3, "sigma_inflation": 1.0, "view_sigma_px": 0.0,
                   "thresholds": {"center_sigma_mm": 2.5, "focal_sigma_pct": 0.25},
                   "advice": ["a: fix", "b: fix"],
                   "cameras": {"a": two["a"].to_dict(), "b": two["b"].to_dict()}}
    assert list(rec["cameras"]) == ["a", "b"]
    assert CalibrationUncertainty([], 0.5, sigma_inflation=1.5, view_sigma_px=0.2).to_dict()["sigma_inflation"] == 1.5
    assert CalibrationUncertainty([], 0.5, view_sigma_px=0.2).to_dict()["view_sigma_px"] == 0.2


def test_coverage_image_tiles():
    import cv2

    g0 = np.zeros((2, 3), int)
    g0[0, 0], g0[1, 2] = 1, 7  # log1p scaled to the largest count
    cams = [CameraUncertainty("A", 1, 1, 1, 1, 0.1, 1.0, np.eye(3), 0.1,
                              CameraCoverage(g0, 2 / 6, 0.1, 0.1, 3, np.zeros((3, 3), int)), "ok", ""),
            CameraUncertainty("B", 1, 1, 1, 1, 0.1, 9.0, np.eye(3), 0.1,
                              CameraCoverage(np.zeros((2, 3), int), 0.0, 0.0, 0.0, 0, np.zeros((3, 3), int)),
                              "uncertain", "B: fix")]
    import warnings

    g1 = np.zeros((2, 3), int)
    g1[1, 1] = 1  # its largest count is 1: full green
    cams.append(CameraUncertainty("C", 1, 1, 1, 1, 0.1, 1.0, np.eye(3), 0.1,
                                  CameraCoverage(g1, 1 / 6, 0.0, 0.0, 1, np.zeros((3, 3), int)), "ok", ""))
    cell = 5
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no division by zero or NaN cast on the way
        img = coverage_image(CalibrationUncertainty(cams, 0.3), cell_px=cell)
        default = coverage_image(CalibrationUncertainty(cams[:1], 0.3))
    th, tw = 2 * cell + 6 + 22, 3 * cell + 6 + 8
    assert img.dtype == np.uint8 and img.shape == (th, 3 * tw, 3)
    assert default.shape == (2 * 16 + 28, 3 * 16 + 14, 3)  # 16 px cells by default
    for k, (g, frame) in enumerate(((g0, (200, 200, 200)), (np.zeros((2, 3), int), (0, 0, 255)), (g1, (200,) * 3))):
        tile = img[:, k * tw:(k + 1) * tw]
        ref = np.full((th, tw, 3), 255, np.uint8)  # white label band and margins
        ref[18:th - 4, 4:tw - 4] = frame
        for r in range(2):
            for c in range(3):
                level = np.log1p(g[r, c]) / np.log1p(max(g.max(), 1))
                colour = (0, int(60 + 195 * level), 0) if g[r, c] else (40, 0, 40)
                ref[21 + r * cell:21 + (r + 1) * cell, 7 + c * cell:7 + (c + 1) * cell] = colour
        cv2.putText(ref, "ABC"[k], (4, 13), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
        assert np.array_equal(tile, ref), k
    assert img[21, 7, 1] == 125 and img[21 + cell, 7 + 2 * cell, 1] == 255  # 1 corner: log 2 / log 8; 7: full
