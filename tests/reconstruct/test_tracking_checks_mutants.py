"""The tracker's plain-Python checks and field reads (``reconstruct.tracking``) in closed form (issue 17).

The lost-track rules (torso joint jump, silhouette share, energy jump, their order and strict thresholds),
``TrackParams``' ranges, the joints' anchors, the fields' bilinear sample, the outside share and the implicit-hull
data term's selection and weights. Tiny inputs, < 1 s each.
"""
from __future__ import annotations

from types import SimpleNamespace as NS

import numpy as np
import pytest

from bodystudio.body.kinect import kinect_joint_names
from bodystudio.errors import InputError
from bodystudio.geometry.camera import Camera
from bodystudio.reconstruct.pose_init import TORSO_JOINTS
from bodystudio.reconstruct.tracking import (
    SilhouetteFields,
    TrackParams,
    energy_jumped,
    joint_anchors,
    lost_track_reason,
    outside_fraction,
    outside_fraction_reference,
    silhouette_data_term,
    torso_joint_jump_m,
)

NAMES = kinect_joint_names("v2")
TORSO = [NAMES.index(n) for n in TORSO_JOINTS]


@pytest.mark.parametrize("name, lo, hi", [("joint_jump_m", 1e-3, 10.0), ("prior_outside_max", 0.0, 1.0),
                                          ("energy_abs", 0.0, 1.0), ("energy_ratio", 1.0, 100.0),
                                          ("iterations", 1, 100), ("min_decrease", 0.0, 1.0),
                                          ("outer_iterations", 0, 100)])
def test_track_params_ranges(name, lo, hi):
    TrackParams(**{name: lo})
    TrackParams(**{name: hi})
    below = lo - (1e-4 if isinstance(lo, float) else 1)
    for bad in (below, hi * 1.01 + 1e-3, float("nan"), float("inf")):
        with pytest.raises(InputError, match=rf"^tracking {name} \S+ is out of range; use a value in "
                                             rf"\[{lo:g}, {hi:g}\]$"):
            TrackParams(**{name: bad})


def test_track_params_defaults():
    p = TrackParams()
    assert (p.joint_jump_m, p.prior_outside_max, p.energy_abs, p.energy_ratio, p.outside_px) == (0.25, 0.25, 0.15,
                                                                                                  2.0, 2.0)


def _joints(rng):
    return rng.uniform(-0.5, 0.5, (25, 3)) + [0, 1, 0]


def test_torso_joint_jump_is_the_median_move_of_the_torso_joints_tracked_in_both():
    rng = np.random.default_rng(3)
    a = _joints(rng)
    b = a.copy()
    moves = np.linspace(0.01, 0.09, len(TORSO))
    b[TORSO, 0] += moves
    others = [i for i in range(25) if i not in TORSO]
    b[others] += 5.0  # the limbs do not count
    assert torso_joint_jump_m(b, a) == pytest.approx(np.median(moves), abs=1e-12)
    # a joint untracked in either frame is left out of the median
    b2, a2 = b.copy(), a.copy()
    b2[TORSO[-1]] = np.nan
    a2[TORSO[-2]] = np.nan
    assert torso_joint_jump_m(b2, a2) == pytest.approx(np.median(moves[:-2]), abs=1e-12)
    b3 = b.copy()
    b3[TORSO[0], 2] = np.nan  # one coordinate is enough to drop it
    assert torso_joint_jump_m(b3, a) == pytest.approx(np.median(moves[1:]), abs=1e-12)
    # 3-D distance, not one axis
    b4 = a.copy()
    b4[TORSO] += [0.03, 0.04, 0.0]
    assert torso_joint_jump_m(b4, a) == pytest.approx(0.05, abs=1e-12)
    assert type(torso_joint_jump_m(b4, a)) is float


def test_torso_joint_jump_is_zero_without_a_common_torso_joint():
    rng = np.random.default_rng(4)
    a = _joints(rng)
    b = a + 1.0
    assert torso_joint_jump_m(None, a) == 0.0 and torso_joint_jump_m(b, None) == 0.0
    b[TORSO[:4]] = np.nan
    a[TORSO[4:]] = np.nan
    assert torso_joint_jump_m(b, a) == 0.0


def test_lost_track_reasons_in_order_with_strict_thresholds():
    p = TrackParams(joint_jump_m=0.2, prior_outside_max=0.3)
    assert lost_track_reason(True, 5.0, 1.0, p) == "first"
    assert lost_track_reason(False, 0.21, 0.9, p) == "joint_jump"
    assert lost_track_reason(False, 0.2, 0.9, p) == "silhouette"
    assert lost_track_reason(False, 0.2, 0.31, p) == "silhouette"
    assert lost_track_reason(False, 0.2, 0.3, p) is None
    assert lost_track_reason(False, 0.0, 0.0, p) is None


def test_energy_jump_needs_both_the_absolute_and_the_ratio():
    p = TrackParams(energy_abs=0.1, energy_ratio=3.0)
    assert energy_jumped(0.11, None, p) and not energy_jumped(0.1, None, p)
    assert energy_jumped(0.31, 0.1, p)
    assert not energy_jumped(0.3, 0.1, p)  # exactly the ratio
    assert not energy_jumped(0.1, 0.01, p)  # ratio exceeded but not the absolute level
    assert not energy_jumped(0.25, 0.1, p)
    assert energy_jumped(0.101, 0.0, p)
    p2 = TrackParams(energy_abs=0.1, energy_ratio=2.0)
    assert not energy_jumped(0.25, 0.125, p2) and energy_jumped(0.2500001, 0.125, p2)  # exactly the ratio: kept


def test_joint_anchors_are_the_bones_heads_and_tails_moved_by_their_transforms():
    rng = np.random.default_rng(5)
    names = ("pelvis", "spine_01", "upperarm_l", "hand_r")
    heads, tails = rng.normal(size=(4, 3)), rng.normal(size=(4, 3))
    skel = NS(index=names.index, heads=heads, tails=tails)
    T = np.tile(np.eye(4), (4, 1, 1))
    for k in range(4):
        q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        T[k, :3, :3], T[k, :3, 3] = q, rng.normal(size=3)
    T32 = T.astype(np.float32)  # read as float64 (the product of float32 transforms would lose ~1e-7 m)
    T = T32.astype(np.float64)
    bones, rest, targets = joint_anchors(NS(skeleton=skel), T32, ("hand_r", "spine_01"))
    np.testing.assert_array_equal(bones, [3, 1, 3, 1])
    np.testing.assert_array_equal(rest, np.concatenate([heads[[3, 1]], tails[[3, 1]]]))
    expected = [T[b, :3, :3] @ p + T[b, :3, 3] for b, p in zip(bones, rest, strict=True)]
    np.testing.assert_allclose(targets, expected, atol=1e-13, rtol=0)


def _camera_and_fields(margin=6):
    """A 60x40 view straight down the z axis (fx 100, principal point at the centre) of a 20x10 px rectangle."""
    H, W = 40, 60
    cam = Camera.look_at("c0", (0, 0, 2), (0, 0, 0), fx=100.0, width=W, height=H)
    mask = np.zeros((H, W), bool)
    mask[15:25, 20:40] = True
    return cam, SilhouetteFields([cam], {"c0": mask}, margin_px=margin), mask


def test_sample_is_the_bilinear_field_and_its_gradient_in_the_box():
    cam, fields, _mask = _camera_and_fields()
    S = fields.sdf["c0"].astype(np.float64)
    x0, y0 = fields.offset["c0"]
    assert (x0, y0) == (14, 9)
    uv = np.array([[22.25, 17.5], [30.0, 12.75], [15.5, 10.5], [44.4, 29.9]])
    d, g, ok = fields.sample(cam, uv)
    assert d.dtype == np.float64 and g.dtype == np.float64 and ok.all()
    for (u, v), dk, gk in zip(uv, d, g, strict=True):
        uu, vv = u - x0, v - y0
        xi, yi = int(uu), int(vv)
        fx, fy = uu - xi, vv - yi
        s00, s10, s01, s11 = S[yi, xi], S[yi, xi + 1], S[yi + 1, xi], S[yi + 1, xi + 1]
        assert dk == pytest.approx((1 - fy) * ((1 - fx) * s00 + fx * s10) + fy * ((1 - fx) * s01 + fx * s11),
                                   abs=1e-6)
        assert gk[0] == pytest.approx((1 - fy) * (s10 - s00) + fy * (s11 - s01), abs=1e-6)
        assert gk[1] == pytest.approx((1 - fx) * (s01 - s00) + fx * (s11 - s10), abs=1e-6)
    # inside the rectangle negative, outside positive
    assert d[0] < 0 and d[1] > 0


def test_sample_outside_the_box_reads_the_margin_and_outside_the_image_is_not_ok():
    cam, fields, _mask = _camera_and_fields(margin=6)
    uv = np.array([[2.0, 2.0], [58.9, 38.9], [0.0, 0.0], [59.0, 39.0], [-0.01, 5.0], [5.0, -0.01], [59.01, 5.0],
                   [5.0, 39.01], [np.nan, 5.0], [5.0, np.inf], [13.0, 20.0], [46.5, 20.0]])
    d, g, ok = fields.sample(cam, uv)
    np.testing.assert_array_equal(ok, [True, True, True, True, False, False, False, False, False, False, True,
                                       True])
    # beyond the box (and beyond the image): the margin, no gradient
    np.testing.assert_array_equal(d[:10], 6.0)
    np.testing.assert_array_equal(g[:10], 0.0)
    # past the box's last column (x 45) and left of its first (x 14): the margin
    assert fields.sdf["c0"].shape == (22, 32)
    assert d[11] == 6.0
    assert d[10] == 6.0  # column 13 is left of the box (x0 = 14)


def _project_to(cam, uv, depth=2.0):
    """World points that ``cam`` sees at pixels ``uv`` at ``depth``."""
    x = (np.asarray(uv, float) - cam.K[:2, 2]) / cam.K[0, 0] * depth
    Pc = np.c_[x, np.full(len(x), depth)]
    return cam.camera_to_world(Pc)


def test_outside_fraction_counts_vertices_beyond_outside_px():
    cam, fields, _mask = _camera_and_fields()
    # the rectangle spans x 20..39 (pixel centres; its edge half a pixel out): 1, 2.5 and 4 px beyond its right edge
    uv = np.array([[30.0, 20.0], [25.0, 18.0], [40.5, 20.0], [42.0, 20.0], [43.5, 20.0], [30.0, 29.0]])
    V = _project_to(cam, uv)
    np.testing.assert_allclose(cam.project(V), uv, atol=1e-9)
    d, _, _ = fields.sample(cam, uv)
    np.testing.assert_allclose(d[2:5], [1.0, 2.5, 4.0], atol=1e-6)
    # the share beyond outside_px: 3.5 px beyond the lower edge too
    assert outside_fraction(V, fields, 2.0) == pytest.approx(3 / 6)
    assert outside_fraction(V, fields, 3.0) == pytest.approx(2 / 6)
    assert outside_fraction(V, fields) == pytest.approx(3 / 6)
    assert outside_fraction(V, fields, 0.5) == pytest.approx(4 / 6)
    assert outside_fraction(V.astype(np.float32), fields, 3.0) == pytest.approx(2 / 6)
    for px in (0.5, 2.0, 3.0):
        assert outside_fraction_reference(V, fields, px) == outside_fraction(V, fields, px)
    assert outside_fraction_reference(V, fields) == pytest.approx(3 / 6)
    assert outside_fraction(V[:0], fields) == 0.0 and outside_fraction_reference(V[:0], fields) == 0.0
    assert type(outside_fraction(V, fields)) is float and type(outside_fraction_reference(V, fields)) is float


def test_outside_fraction_any_camera_and_points_behind_or_off_the_image():
    cam, fields, mask = _camera_and_fields()
    cam2 = Camera.look_at("c1", (0, 0, -2), (0, 0, 0), fx=100.0, width=60, height=40)
    two = SilhouetteFields([cam, cam2], {"c0": mask, "c1": np.zeros((40, 60), bool)}, margin_px=6)
    V = _project_to(cam, [[30.0, 20.0], [25.0, 18.0]])
    # the second camera sees no silhouette: every vertex it sees is outside
    assert outside_fraction(V, two) == 1.0 and outside_fraction_reference(V, two) == 1.0
    # a vertex behind the camera or off its image is not counted
    behind = np.array([[0.0, 0.0, 3.0]])
    off = _project_to(cam, [[100.0, 20.0]])
    assert outside_fraction(np.r_[behind, off], fields) == 0.0
    assert outside_fraction_reference(np.r_[behind, off], fields) == 0.0


def test_data_term_selects_seen_agreeing_not_deep_points_with_huber_and_inside_weights():
    best = np.array([0.01, -0.02, 0.10, -0.2, 0.02, np.nan, -np.inf, 0.05, -0.05])
    G = np.array([[0, 0, 1.0], [0, 0, 1.0], [0, 0, 2.0], [0, 0, 1.0], [0, 0, 1.0], [0, 0, 1.0], [0, 0, 1.0],
                  [0, 0, 1e-10], [0, 0, 1.0]])
    N = np.array([[0, 0, 1.0], [0, 0.9, 0.3], [0, 0, 1.0], [0, 0, 1.0], [0, 1.0, 0.1], [0, 0, 1.0], [0, 0, 1.0],
                  [0, 0, 1.0], [0, 0.98, 0.2]])
    V = np.arange(27.0).reshape(9, 3)

    def hull(X):
        assert X is V
        return best, G

    params = TrackParams(inside_weight=0.25, inside_m=0.1, robust_m=0.03)
    use, r, w, Gu = silhouette_data_term(NS(implicit_hull=hull), params)(V, N)
    # 0 agrees; 1 cos 0.3 > 0.2; 2 outside by 0.1 (Huber); 3 deeper than inside_m; 4 cos 0.0995 < 0.2;
    # 5, 6 unseen; 7 no gradient; 8 cos exactly 0.2 (not above)
    n8 = N[8] / np.linalg.norm(N[8])
    assert n8[2] == pytest.approx(0.2, abs=0.005)
    np.testing.assert_array_equal(use, [0, 1, 2])
    np.testing.assert_array_equal(r, best[[0, 1, 2]])
    np.testing.assert_allclose(w, [1.0, 0.25, 0.03 / 0.10], atol=1e-12)
    np.testing.assert_array_equal(Gu, G[[0, 1, 2]])
    # the inside limit is strict: a point exactly inside_m deep is left out
    best2 = np.array([-0.1, -0.0999])
    G2 = np.array([[0, 0, 1.0], [0, 0, 1.0]])
    use2, r2, w2, _ = silhouette_data_term(NS(implicit_hull=lambda V: (best2, G2)), params)(
        np.zeros((2, 3)), np.array([[0, 0, 1.0], [0, 0, 1.0]]))
    np.testing.assert_array_equal(use2, [1])
    np.testing.assert_allclose(w2, [0.25 * 0.03 / 0.0999], atol=1e-12)


def test_data_term_normal_test_scales_with_the_gradient_and_the_edges_of_its_guards():
    # N.G against 0.2 |G|: |G| 2 with N.G 0.3 fails (0.3 < 0.4); |G| 0.5 with N.G 0.15 passes (> 0.1);
    # |G| exactly 1e-9 is no gradient; a residual of exactly 0 is outside (weight 1)
    best = np.array([0.01, 0.01, 0.01, 0.0, 0.01])
    G = np.array([[0, 0, 2.0], [0, 0, 0.5], [0, 0, 1e-9], [0, 0, 1.0], [0, 0, 1.0]])
    N = np.array([[0, 0.989, 0.15], [0, 0.954, 0.3], [0, 0, 1.0], [0, 0, 1.0], [0, 0, 1.0]])
    params = TrackParams(inside_weight=0.25, robust_m=0.03)
    use, r, w, _ = silhouette_data_term(NS(implicit_hull=lambda V: (best, G)), params)(np.zeros((5, 3)), N)
    np.testing.assert_array_equal(use, [1, 3, 4])
    np.testing.assert_array_equal(w, [1.0, 1.0, 1.0])


def test_fields_defaults_and_a_missing_mask():
    cam, _fields, mask = _camera_and_fields()
    f = SilhouetteFields([cam], {"c0": mask})
    assert f.margin_px == 48.0 and f.offset["c0"] == (0, 0)  # 48 px reach the image's edges here
    with pytest.raises(InputError, match=r"^tracking: no mask for camera c0$"):
        SilhouetteFields([cam], {"c1": mask})


def test_fields_read_a_0_255_mask_as_a_bool_one_and_have_exact_values():
    cam, fields, mask = _camera_and_fields()
    f255 = SilhouetteFields([cam], {"c0": mask.astype(np.uint8) * 255}, margin_px=6)
    np.testing.assert_array_equal(f255.sdf["c0"], fields.sdf["c0"])
    f1 = SilhouetteFields([cam], {"c0": mask.astype(np.uint8)}, margin_px=6)
    np.testing.assert_array_equal(f1.sdf["c0"], fields.sdf["c0"])
    S = fields.sdf["c0"]
    x0, y0 = fields.offset["c0"]
    # column 30 down through the rectangle (rows 15..24): outside 2.5, 1.5, 0.5; inside -0.5, -1.5, ..., -4.5
    col = S[:, 30 - x0]
    np.testing.assert_array_equal(col[12 - y0:20 - y0], [2.5, 1.5, 0.5, -0.5, -1.5, -2.5, -3.5, -4.5])
    np.testing.assert_array_equal(col[20 - y0:28 - y0], [-4.5, -3.5, -2.5, -1.5, -0.5, 0.5, 1.5, 2.5])
    # row 20 towards the right edge (column 39, the rectangle's last): inside -3.5 .. -0.5, then outside
    np.testing.assert_array_equal(S[20 - y0, 36 - x0:42 - x0], [-3.5, -2.5, -1.5, -0.5, 0.5, 1.5])
    np.testing.assert_array_equal(S[20 - y0, 18 - x0:24 - x0], [1.5, 0.5, -0.5, -1.5, -2.5, -3.5])
    assert S.dtype == np.float32 and fields._packed_sdf.dtype == np.float32


def test_fields_of_a_concave_mask_and_at_the_image_corner():
    H, W = 40, 60
    cam = Camera.look_at("c0", (0, 0, 2), (0, 0, 0), fx=100.0, width=W, height=H)
    mask = np.zeros((H, W), bool)
    mask[0:12, 0:4] = True  # an L at the top-left corner: the box clipped to the image
    mask[8:12, 0:14] = True
    f = SilhouetteFields([cam], {"c0": mask}, margin_px=6)
    assert f.offset["c0"] == (0, 0) and f.sdf["c0"].shape == (18, 20)
    import cv2

    full = cv2.distanceTransform((~mask).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE) - 0.5
    inside = 0.5 - cv2.distanceTransform(mask.astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    exact = np.where(mask, inside, full)[:18, :20]
    np.testing.assert_allclose(f.sdf["c0"], exact, atol=1e-5)
    assert f.sdf["c0"][2, 10] == 5.5  # in the L's bay: 6 px below to the mask, not the 1 px ring's 0.5


def test_fields_of_no_camera():
    f = SilhouetteFields([], {})
    assert f._packed_sdf.shape == (0, 1, 1)
    cam, _fields, _mask = _camera_and_fields()
    empty = SilhouetteFields([cam], {"c0": np.zeros((40, 60), bool)}, margin_px=6)
    assert empty.offset["c0"] == (0, 0) and empty.sdf["c0"].shape == (40, 60)
    assert outside_fraction(np.zeros((2, 3)), f) == 0.0


def test_sample_at_the_box_edges_and_a_two_pixel_box():
    cam, fields, _mask = _camera_and_fields(margin=6)
    S = fields.sdf["c0"]
    # box x 14..45, y 9..30: u = 0 and v = 0 are inside, u = W - 1 and v = H - 1 are not (no neighbour)
    uv = np.array([[14.0, 20.0], [30.0, 9.0], [14.5, 9.5], [45.0, 20.0], [30.0, 30.0], [30.0, 30.5]])
    d, _g, ok = fields.sample(cam, uv)
    assert ok.all()
    assert d[0] == S[20 - 9, 0] and d[1] == S[0, 30 - 14]
    assert d[2] == pytest.approx(np.mean(S[0:2, 0:2]), abs=1e-6)
    np.testing.assert_array_equal(d[3:], 6.0)
    H, W = 40, 60
    cam2 = Camera.look_at("c0", (0, 0, 2), (0, 0, 0), fx=100.0, width=W, height=H)
    tiny = np.zeros((H, W), bool)
    tiny[10:12, 20:22] = True
    # no margin: a silhouette filling its box has no outside pixel to measure from (its inside read ~1e19): refused
    with pytest.raises(InputError, match="margin_px must be >= 1"):
        SilhouetteFields([cam2], {"c0": tiny}, margin_px=0)
    f = SilhouetteFields([cam2], {"c0": tiny}, margin_px=1)
    assert f.sdf["c0"].shape == (4, 4)
    # one pixel of margin: off the box the margin (1), the 2x2 square's pixel centres half a pixel inside
    d, g, ok = f.sample(cam2, np.array([[5.0, 5.0], [-1.0, 5.0], [20.0, 10.0], [21.0, 11.0]]))
    np.testing.assert_array_equal(d, [1.0, 1.0, -0.5, -0.5])
    np.testing.assert_array_equal(g[:3], 0.0)  # flat inside the square; the last one reads the ring beyond it
    np.testing.assert_array_equal(ok, [True, False, True, True])


def test_outside_fraction_beyond_the_box_reads_the_margin_and_the_threshold_is_strict():
    cam, fields, _mask = _camera_and_fields(margin=6)
    # beyond the box's right side and below it (inside the image): the margin (6 px), outside
    far = _project_to(cam, [[50.0, 20.0], [30.0, 35.0]])
    assert outside_fraction(far, fields, 2.0) == 1.0 and outside_fraction(far, fields, 6.0) == 0.0
    assert outside_fraction_reference(far, fields, 2.0) == 1.0
    # exactly at the threshold: not outside
    V = _project_to(cam, [[41.5, 20.0]])
    d, _, _ = fields.sample(cam, cam.project(V))
    assert d[0] == pytest.approx(2.0, abs=1e-6)
    assert outside_fraction_reference(V, fields, float(d[0])) == 0.0
    assert outside_fraction_reference(V, fields, float(d[0]) - 1e-6) == 1.0


def test_outside_fraction_reference_takes_any_camera_whatever_their_order():
    cam, _fields, mask = _camera_and_fields()
    cam2 = Camera.look_at("c1", (0, 0, -2), (0, 0, 0), fx=100.0, width=60, height=40)
    masks = {"c0": mask, "c1": np.zeros((40, 60), bool)}
    V = _project_to(cam, [[30.0, 20.0], [25.0, 18.0]])
    for order in ([cam, cam2], [cam2, cam]):
        f = SilhouetteFields(order, masks, margin_px=6)
        assert outside_fraction_reference(V, f) == 1.0 and outside_fraction(V, f) == 1.0


def test_implicit_hull_is_the_fields_distance_in_metres_at_the_points_depth():
    cam, fields, _mask = _camera_and_fields()
    uv = np.array([[42.0, 20.0], [30.0, 20.0], [40.5, 18.0]])
    for depth in (2.0, 1.5):
        V = _project_to(cam, uv, depth)
        best, G = fields.implicit_hull(V)
        d, _, _ = fields.sample(cam, uv)
        np.testing.assert_allclose(best, d * depth / 100.0, atol=1e-9)
        assert G.shape == (3, 3) and np.all(np.isfinite(G))
        # the gradient across the right edge points along +x (away from the silhouette)
        assert G[0, 0] > 0 and abs(G[0, 1]) < 1e-9
    best32, _ = fields.implicit_hull(V.astype(np.float32).astype(np.float64))
    np.testing.assert_allclose(fields.implicit_hull(V.astype(np.float32))[0], best32, atol=1e-12)


def test_hull_gate_keeps_a_match_whose_ray_point_is_no_farther_out_than_its_vertex_plus_the_gate():
    cam, fields, _mask = _camera_and_fields()
    V = _project_to(cam, [[30.0, 20.0], [41.0, 20.0], [25.0, 18.0]])
    # rays through points 0.5 / 3 / 8 px beyond the right edge (and one inside), along the view direction
    targets = _project_to(cam, [[40.0, 20.0], [42.5, 20.0], [47.5, 20.0], [30.0, 22.0]])
    vertex = np.array([0, 1, 2, 0])
    direction = np.tile([0.0, 1.0, 0.0], (4, 1))
    origin = targets - 0.3 * direction  # q (the ray point nearest the vertex) has the vertex's height
    for gate in (0.0, 0.02, 0.05):
        P = V[vertex]
        q = origin + np.sum((P - origin) * direction, axis=1, keepdims=True) * direction
        h_v, _ = fields.implicit_hull(P)
        h_q, _ = fields.implicit_hull(q)
        expected = ~(h_q > np.maximum(h_v, 0.0) + gate)
        got = fields.hull_gate(V, vertex, origin, direction, gate)
        np.testing.assert_array_equal(got, expected)
        uv, z = cam.project_with_depth(V)
        got2 = fields.hull_gate(V, vertex, origin, direction, gate, projected=(uv[None], z[None]))
        np.testing.assert_array_equal(got2, expected)
    assert not expected.all() and expected.any()
