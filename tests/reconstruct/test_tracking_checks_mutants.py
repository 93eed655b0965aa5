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


def test_joint_anchors_are_the_bones_heads_and_tails_moved_by_their_transforms():
    rng = np.random.default_rng(5)
    names = ("pelvis", "spine_01", "upperarm_l", "hand_r")
    heads, tails = rng.normal(size=(4, 3)), rng.normal(size=(4, 3))
    skel = NS(index=names.index, heads=heads, tails=tails)
    T = np.tile(np.eye(4), (4, 1, 1))
    for k in range(4):
        q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        T[k, :3, :3], T[k, :3, 3] = q, rng.normal(size=3)
    bones, rest, targets = joint_anchors(NS(skeleton=skel), T.astype(np.float32).astype(np.float64),
                                         ("hand_r", "spine_01"))
    np.testing.assert_array_equal(bones, [3, 1, 3, 1])
    np.testing.assert_array_equal(rest, np.concatenate([heads[[3, 1]], tails[[3, 1]]]))
    expected = [T[b, :3, :3] @ p + T[b, :3, 3] for b, p in zip(bones, rest, strict=True)]
    np.testing.assert_allclose(targets, expected, atol=1e-12)


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
    fields = NS(implicit_hull=lambda V: (best, G))
    params = TrackParams(inside_weight=0.25, inside_m=0.1, robust_m=0.03)
    use, r, w, Gu = silhouette_data_term(fields, params)(np.zeros((9, 3)), N)
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
