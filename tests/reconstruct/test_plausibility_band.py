"""trust4's band rule of the reconstruction's self-check (:mod:`bodystudio.reconstruct.plausibility`): the fit's
silhouettes drawn once (``fitted_silhouettes``), the tolerant figures (``silhouette_tolerant_agreement``: the share of
the fit's silhouette within a few pixels of the mask, and of the mask within a few pixels of the fit), and the
verdict's rule that a low IoU whose fit stays inside the mask's band is the masks' noise (warned, not refused).

Hand-made silhouettes whose figures are counted by hand or by scipy's exact Euclidean distance (OpenCV's 5x5
approximation agrees with it at the 3 px band for these shapes), and recorded frame figures at the rule's
boundaries. Fast (about 2 s, most of it numba's first call); the whole-session check is
tests/reliability/test_reconstruct_mask_noise.py.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from scipy import ndimage

from bodystudio.geometry.camera import Camera
from bodystudio.reconstruct import plausibility as P

F_PX = 64.0


def _front_camera(name="a", w=48, h=40):
    """At the origin looking down +z, f = 64 px, principal point (0, 0): (x, y, 2) lands on pixel (32 x, 32 y)."""
    return Camera(name, [[F_PX, 0, 0], [0, F_PX, 0], [0, 0, 1]], None, np.eye(3), np.zeros(3), w, h)


def _square(u0, u1, v0, v1, z=2.0):
    """Two triangles whose projection in :func:`_front_camera` is the pixel rectangle [u0, u1] x [v0, v1]."""
    uv = np.array([[u0, v0], [u1, v0], [u1, v1], [u0, v1]], float)
    return np.c_[uv * z / F_PX, np.full(4, z)], np.array([[0, 1, 2], [0, 2, 3]])


def _rect(rows, cols, shape=(40, 48)):
    m = np.zeros(shape, bool)
    m[rows[0]:rows[1], cols[0]:cols[1]] = True
    return m


def _cam(name="a", width=640, height=480):
    """Only a name and an image size: the tolerant figures of given silhouettes read nothing else."""
    return SimpleNamespace(name=name, width=width, height=height)


def _tolerant(fit, mask, cam=None, **kw):
    cam = cam or _cam()
    return P.silhouette_tolerant_agreement(None, None, [cam], {cam.name: mask}, fitted={cam.name: fit}, **kw)[cam.name]


def _exact(fit, mask, band):
    """(precision, recall) by scipy's exact Euclidean distance."""
    to_mask = ndimage.distance_transform_edt(~mask)
    to_fit = ndimage.distance_transform_edt(~fit)
    return float(np.mean(to_mask[fit] <= band)), float(np.mean(to_fit[mask] <= band))


# --- fitted_silhouettes ------------------------------------------------------------------------------------------

def test_fitted_silhouettes_are_the_meshs_pixels_per_camera_by_name():
    """The square covers the pixel centres of columns and rows 10..29; a wider camera sees the same pixels in its
    own image size; a camera facing away sees nothing."""
    V, F = _square(10, 29, 10, 29)
    away = Camera("away", [[F_PX, 0, 0], [0, F_PX, 0], [0, 0, 1]], None, np.diag([-1.0, 1.0, -1.0]), np.zeros(3),
                  48, 40)
    out = P.fitted_silhouettes(V, F, [_front_camera("a"), _front_camera("b", w=64, h=36), away])
    assert list(out) == ["a", "b", "away"]
    assert out["a"].dtype == bool and np.array_equal(out["a"], _rect((10, 30), (10, 30)))
    assert np.array_equal(out["b"], _rect((10, 30), (10, 30), shape=(36, 64)))
    assert out["away"].shape == (40, 48) and not out["away"].any()
    # float32 vertices and int32 face lists: the same pixels
    again = P.fitted_silhouettes(V.astype(np.float32), F.astype(np.int32).tolist(), [_front_camera("a")])
    assert np.array_equal(again["a"], out["a"])


def test_both_agreements_use_the_silhouettes_they_are_given():
    """``fitted`` is used as drawn (no mesh needed): the IoU and the band figures of a given silhouette."""
    cam = _front_camera("a")
    fit = _rect((10, 30), (10, 30))
    mask = _rect((10, 30), (20, 40)).astype(np.uint8) * 255
    assert P.silhouette_agreement(None, None, [cam], {"a": mask}, fitted={"a": fit}) == {"a": 1 / 3}
    out = P.silhouette_tolerant_agreement(None, None, [cam], {"a": mask}, fitted={"a": fit}, tolerance_px_at_640=640)
    assert out == {"a": {"precision": 1.0, "recall": 1.0}}  # a 48 px band at 48 px width
    # drawn from the mesh when not given: the same figures
    V, F = _square(10, 29, 10, 29)
    assert P.silhouette_agreement(V, F, [cam], {"a": mask}) == {"a": 1 / 3}
    assert P.silhouette_tolerant_agreement(V, F, [cam], {"a": mask}, tolerance_px_at_640=640) == out


# --- silhouette_tolerant_agreement ---------------------------------------------------------------------------------

def test_a_fit_4_px_beside_its_mask_is_inside_the_3_px_band_but_for_one_column():
    """At 640 px width the band is 3 px: the fit (columns 10..29) against the mask moved 4 px (14..33): column 10 is
    4 px from the mask, column 11 exactly 3 (inside: the band is closed); the mask's column 33 likewise."""
    fit = _rect((10, 30), (10, 30))
    assert _tolerant(fit, _rect((10, 30), (14, 34))) == {"precision": 0.95, "recall": 0.95}
    assert _tolerant(fit, _rect((10, 30), (13, 33))) == {"precision": 1.0, "recall": 1.0}
    assert _tolerant(fit, _rect((10, 30), (15, 35))) == {"precision": 0.9, "recall": 0.9}
    assert _tolerant(fit, fit.astype(np.uint8) * 255) == {"precision": 1.0, "recall": 1.0}


def test_the_band_scales_with_the_image_width_not_its_height():
    """At 320 px width the band is 1.5 px (2 px apart is outside); at 1280 px 6 px; the height does not count; a
    band given for 640 px scales alike."""
    fit = _rect((10, 30), (10, 30))
    moved2 = _rect((10, 30), (12, 32))
    assert _tolerant(fit, moved2, _cam(width=320, height=480)) == {"precision": 0.95, "recall": 0.95}
    assert _tolerant(fit, moved2, _cam(width=640, height=240)) == {"precision": 1.0, "recall": 1.0}
    moved7 = _rect((10, 30), (17, 37))
    assert _tolerant(fit, moved7, _cam(width=1280, height=480)) == {"precision": 0.95, "recall": 0.95}
    assert _tolerant(fit, moved7, _cam(width=1280, height=960)) == {"precision": 0.95, "recall": 0.95}
    assert _tolerant(fit, _rect((10, 30), (13, 33)), tolerance_px_at_640=1.0) == {"precision": 0.9, "recall": 0.9}
    assert _tolerant(fit, moved2, _cam(width=320), tolerance_px_at_640=4.0) == {"precision": 1.0, "recall": 1.0}
    assert P.TOLERANCE_PX_AT_640 == 3.0


def test_precision_is_the_fits_share_recall_the_masks():
    """A mask holding the fit plus an arm and a foot: all of the fit lies in the mask (precision 1), the mask's arm
    and foot only up to the band (recall 415 / 550 + the foot's share, counted by scipy's exact distance)."""
    fit = _rect((10, 30), (10, 30))
    mask = fit | _rect((10, 15), (30, 45)) | _rect((30, 35), (2, 10))
    p, r = _exact(fit, mask, 3.0)
    assert p == 1.0 and 0.6 < r < 0.9
    assert _tolerant(fit, mask) == {"precision": 1.0, "recall": pytest.approx(r, abs=1e-12)}
    assert _tolerant(mask, fit) == {"precision": pytest.approx(r, abs=1e-12), "recall": 1.0}
    # the arm alone: 15 of its 75 pixels (columns 30..32) within 3 px
    arm = fit | _rect((10, 15), (30, 45))
    assert _tolerant(fit, arm) == {"precision": 1.0, "recall": (400 + 15) / 475}


def test_silhouettes_at_the_image_borders_are_counted_whole():
    """The distances are taken on the box around both silhouettes: a silhouette touching the first or last row or
    column loses nothing (a stray fit pixel in row 0, column 0 or the last row or column is outside the band)."""
    mask = _rect((5, 35), (5, 43))
    base = mask.copy()
    for r, c in ((0, 20), (20, 0), (39, 20), (20, 47)):
        fit = base.copy()
        fit[r, c] = True
        p, _ = _exact(fit, mask, 1.5)
        assert p == (base.sum()) / (base.sum() + 1)
        assert _tolerant(fit, mask, _cam(width=320)) == {"precision": p, "recall": 1.0}, (r, c)
        assert _tolerant(mask, fit, _cam(width=320)) == {"precision": 1.0, "recall": p}, (r, c)
    # the whole image on both sides
    full = np.ones((40, 48), bool)
    assert _tolerant(full, full) == {"precision": 1.0, "recall": 1.0}


@pytest.mark.parametrize("off", [(0, 0), (3, 5), (17, 20)])
def test_figures_of_shapes_anywhere_in_the_image_match_the_exact_distance(off):
    """Irregular shapes (a disc and an L) at several places, band 3 px: the figures of the whole image."""
    yy, xx = np.mgrid[:40, :48]
    disc = (yy - 8 - off[0]) ** 2 + (xx - 9 - off[1]) ** 2 <= 36
    ell = _rect((2 + off[0], 16 + off[0]), (4 + off[1], 8 + off[1])) | _rect((12 + off[0], 16 + off[0]),
                                                                             (4 + off[1], 20 + off[1]))
    p, r = _exact(disc, ell, 3.0)
    assert 0.3 < p < 1.0 and 0.3 < r < 1.0
    assert _tolerant(disc, ell) == {"precision": pytest.approx(p, abs=1e-12), "recall": pytest.approx(r, abs=1e-12)}


def test_empty_silhouettes():
    """Nothing on either side: full agreement; a mask the fit does not reach: precision 1 (nothing of the fit is
    outside), recall 0; a fit with no mask: precision 0, recall 1."""
    empty = np.zeros((40, 48), bool)
    sq = _rect((10, 30), (10, 30))
    assert _tolerant(empty, empty) == {"precision": 1.0, "recall": 1.0}
    assert _tolerant(empty, sq) == {"precision": 1.0, "recall": 0.0}
    assert _tolerant(sq, empty) == {"precision": 0.0, "recall": 1.0}


def test_per_camera_by_name():
    """Each camera against its own mask; a view where both are empty does not end the loop."""
    fit = _rect((10, 30), (10, 30))
    cams = [_cam("e"), _cam("b", width=320), _cam("a")]
    masks = {"a": _rect((10, 30), (14, 34)), "b": _rect((10, 30), (12, 32)), "c": fit, "e": np.zeros((40, 48))}
    out = P.silhouette_tolerant_agreement(None, None, cams, masks,
                                          fitted={"a": fit, "b": fit, "c": ~fit, "e": np.zeros((40, 48), bool)})
    assert out == {"e": {"precision": 1.0, "recall": 1.0}, "b": {"precision": 0.95, "recall": 0.95},
                   "a": {"precision": 0.95, "recall": 0.95}}
    assert list(out) == ["e", "b", "a"]


def test_the_band_distance_is_opencvs_5x5_chamfer():
    """The thresholds (0.95 / 0.65) were measured with OpenCV's 5x5 chamfer distance: a knight's move (2, 1) is
    2.1969 px there (the exact distance 2.236): inside a 2.2 px band."""
    fit = np.zeros((40, 48), bool)
    mask = np.zeros((40, 48), bool)
    fit[10, 10] = True
    mask[12, 11] = True
    assert _tolerant(fit, mask, tolerance_px_at_640=2.2) == {"precision": 1.0, "recall": 1.0}
    assert _exact(fit, mask, 2.2) == (0.0, 0.0)


def test_frame_plausibility_records_precision_and_recall_from_the_mesh():
    """A square mesh seen by a 640x480 camera against a mask with an arm: IoU 400 / 475, precision 1, recall
    415 / 475, each under its own key."""
    V, F = _square(10, 29, 10, 29)
    cam = _front_camera("a", w=640, h=480)
    mask = _rect((10, 30), (10, 30), shape=(480, 640)) | _rect((10, 15), (30, 45), shape=(480, 640))
    out = P.frame_plausibility(V, F, [cam], {"a": mask})
    assert out == {"silhouette_iou": {"a": 400 / 475}, "silhouette_precision_tol": {"a": 1.0},
                   "silhouette_recall_tol": {"a": 415 / 475}}


# --- run_plausibility: the band rule -------------------------------------------------------------------------------

def _frame(iou, prec=None, rec=None, coh=None):
    out = {"silhouette_iou": iou}
    if prec is not None:
        out["silhouette_precision_tol"] = prec
    if rec is not None:
        out["silhouette_recall_tol"] = rec
    if coh is not None:
        out["coherence"] = coh
    return out


NOISY_A = ("camera a: the masks hold regions the fit does not explain (silhouette IoU a 0.70) although the fit lies "
           "inside them up to 3 px (at 640 px width; a 0.99 of its silhouette; a 0.80 of the masks): shadows, holes "
           "or a lost limb in the segmentation; check the masks")


def test_a_low_iou_inside_the_band_is_the_masks_noise_warned_not_refused():
    r = P.run_plausibility([_frame({"a": 0.7, "b": 0.95}, {"a": 0.99, "b": 1.0}, {"a": 0.8, "b": 1.0},
                                   {"a": 0.95, "b": 1.0, "c": 1.0})], "S")
    assert r["ok"] and r["problems"] == [] and r["warnings"] == [NOISY_A]
    assert r["camera_precision_tol"] == {"a": 0.99, "b": 1.0} and r["camera_recall_tol"] == {"a": 0.8, "b": 1.0}
    # without the band figures the same IoU is refused (older runs keep the IoU rule)
    r = P.run_plausibility([_frame({"a": 0.7, "b": 0.95}, coh={"a": 0.95, "b": 1.0, "c": 1.0})], "S")
    assert not r["ok"] and "camera_precision_tol" not in r and "camera_recall_tol" not in r


@pytest.mark.parametrize("prec, rec, noisy", [
    (0.95, 0.65, True), (0.9499, 0.9, False), (1.0, 0.6499, False), (0.96, 0.66, True),
])
def test_band_rule_boundaries(prec, rec, noisy):
    """At the thresholds (precision 0.95, recall 0.65) the view is trusted; just below, its low IoU is refused."""
    r = P.run_plausibility([_frame({"a": 0.7, "b": 0.95}, {"a": prec, "b": 1.0}, {"a": rec, "b": 1.0})], "S")
    assert r["ok"] == noisy
    if noisy:
        assert r["warnings"][0].startswith("camera a: the masks hold regions") and r["problems"] == []
    else:
        assert r["warnings"] == [] and "the fit's silhouette IoU a 0.70" in r["problems"][0]
    assert (P.TOLERANT_PRECISION_TRUST, P.TOLERANT_RECALL_TRUST) == (0.95, 0.65)


def test_a_camera_without_band_figures_is_not_trusted():
    """Band figures of another camera only: camera a's low IoU is refused (missing figures count as 0)."""
    for prec, rec in (({"b": 1.0}, {"a": 1.0, "b": 1.0}), ({"a": 1.0, "b": 1.0}, {"b": 1.0})):
        r = P.run_plausibility([_frame({"a": 0.7, "b": 0.95}, prec, rec)])
        assert not r["ok"] and "IoU a 0.70" in r["problems"][0]


def test_a_noisy_view_between_the_iou_thresholds_gets_the_noise_warning_not_the_weak_one():
    """IoU 0.8 (warned by the IoU rule alone): inside the band, the masks are blamed; outside it, the weak-camera
    warning; at IoU 0.85 nothing to explain."""
    fr = _frame({"a": 0.8, "b": 0.95}, {"a": 0.99, "b": 1.0}, {"a": 0.8, "b": 1.0})
    r = P.run_plausibility([fr])
    assert r["ok"] and len(r["warnings"]) == 1 and r["warnings"][0].startswith("camera a: the masks hold")
    fr = _frame({"a": 0.8, "b": 0.95}, {"a": 0.9, "b": 1.0}, {"a": 0.8, "b": 1.0})
    assert P.run_plausibility([fr])["warnings"] == [
        "camera a agree less with the fit or the other cameras (silhouette IoU a 0.80; coherence -); the calibration "
        "or masks may be off"]
    fr = _frame({"a": 0.85, "b": 0.95}, {"a": 0.5, "b": 1.0}, {"a": 0.5, "b": 1.0})
    assert P.run_plausibility([fr])["warnings"] == []
    fr = _frame({"a": 0.85, "b": 0.95}, {"a": 0.99, "b": 1.0}, {"a": 0.8, "b": 1.0})  # inside the band: still nothing
    assert P.run_plausibility([fr])["warnings"] == []


def test_noisy_cameras_listed_together_and_a_low_coherence_still_warned():
    """Two noisy views, named in order; one of them also less coherent (0.85): named in the weak warning too."""
    fr = _frame({"b": 0.72, "a": 0.7, "c": 0.95}, {"a": 0.99, "b": 0.97, "c": 1.0}, {"a": 0.8, "b": 0.9, "c": 1.0},
                {"a": 0.95, "b": 0.85, "c": 1.0})
    r = P.run_plausibility([fr], "S")
    assert r["ok"] and r["warnings"] == [
        "cameras a, b: the masks hold regions the fit does not explain (silhouette IoU a 0.70, b 0.72) although the "
        "fit lies inside them up to 3 px (at 640 px width; a 0.99, b 0.97 of its silhouette; a 0.80, b 0.90 of the "
        "masks): shadows, holes or a lost limb in the segmentation; check the masks",
        "camera b agree less with the fit or the other cameras (silhouette IoU b 0.72; coherence b 0.85); the "
        "calibration or masks may be off"]


def test_a_refused_view_beside_a_noisy_one_names_only_the_refused():
    """One view inside the band (a), one outside it (b, refused): the problem names b's IoU only, and no warning
    is given."""
    fr = _frame({"a": 0.6, "b": 0.5, "c": 0.95}, {"a": 0.99, "b": 0.8, "c": 1.0}, {"a": 0.9, "b": 0.4, "c": 1.0},
                {"a": 1.0, "b": 0.95, "c": 1.0})
    r = P.run_plausibility([fr], "S")
    assert not r["ok"] and r["warnings"] == []
    assert r["problems"] == [
        "the fit does not explain the silhouettes although the cameras agree with each other (the fit's silhouette "
        "IoU b 0.50, trusted >= 0.75; the share of each mask the other cameras' visual hull explains 0.95..1.00, "
        "consistent views ~1.0): it did not converge or started from wrong joints; raise --outer/--inner, check the "
        "joints (--joints)"]


def test_band_figures_are_medians_over_frames():
    frames = [_frame({"a": 0.7}, {"a": 0.99}, {"a": 0.7}), _frame({"a": 0.72}, {"a": 0.9}, {"a": 0.9}),
              _frame({"a": 0.74}, {"a": 0.97}, {"a": 0.66}), {}]
    r = P.run_plausibility(frames)
    assert r["camera_iou"] == {"a": 0.72} and r["camera_precision_tol"] == {"a": 0.97}
    assert r["camera_recall_tol"] == {"a": 0.7} and r["ok"]
