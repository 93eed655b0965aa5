"""Fast tests of the garment fit's step 4b wiring (garment/fit.py; issue 17's mutation tests,
docs/mutation/garment-fit.md "Step 4b's wiring"): ``refine_fit_shape`` hands the shape, the tracked poses, the
mattes, the camera, the stature, the template and the clothing allowance to the shape refinement and builds the
refined body; ``refine_garment_fit`` applies it to a finished fit (IoU, stature, warnings, timings and appearance
recomputed, the poses kept); ``fit_warnings`` at its bounds; ``fit_garment_video``'s ``clothing_allowance_m`` checked
and handed on. Every stage stood in: no body is built, no refinement run (tests/garment/test_shape_refine.py runs
the real one on the 2k body).
"""

import itertools
from types import SimpleNamespace

import numpy as np
import pytest

from bodystudio.body.phenotype import Phenotype
from bodystudio.errors import InputError
from bodystudio.garment import fit as gf
from bodystudio.garment.fitfile import GarmentFit
from bodystudio.garment.shape_refine import CLOTHING_ALLOWANCE_M, ShapeRefinement
from tests.garment.test_fit_analytic import stand_in_fit

PH = {**Phenotype().to_dict(), "weight": 0.7, "gender": 0.3}
PH2 = {**PH, "weight": 0.55, "age": 0.6}


def test_fit_warnings_at_their_bounds():
    assert gf.fit_warnings(1.7099, 1.70, np.array([0.8, 0.9])) == []  # under 1 cm off and an IoU of 0.80 are fine
    assert gf.fit_warnings(1.6901, 1.70, np.array([0.8])) == []
    assert gf.fit_warnings(1.7101, 1.70, np.array([0.95])) == [
        "fitted stature 1.710 m differs from the given 1.700 m by over 1 cm"]
    assert gf.fit_warnings(1.6899, 1.70, [0.95]) == [
        "fitted stature 1.690 m differs from the given 1.700 m by over 1 cm"]
    assert gf.fit_warnings(1.70, 1.70, [0.7999, 0.5, 0.81]) == ["2 of 3 frames have a silhouette IoU below 0.80"]
    assert gf.fit_warnings(1.80, 1.70, np.array([0.1])) == [
        "fitted stature 1.800 m differs from the given 1.700 m by over 1 cm",
        "1 of 1 frames have a silhouette IoU below 0.80"]


def test_refine_fit_shape_hands_everything_to_the_refinement_and_builds_the_refined_body(monkeypatch):
    import bodystudio.body as body_mod
    import bodystudio.garment.shape_refine as sr

    calls = {}

    def refine(*args, **kwargs):
        calls["refine"] = (args, kwargs)
        return ShapeRefinement(PH2, {"neck-scale-horiz-decr-incr": 0.2}, (3.0, 1.0), 1)

    def build(phenotype, local, resolution):
        calls["build"] = (phenotype, local, resolution)
        return "REFINED BODY"

    monkeypatch.setattr(sr, "refine_shape_to_silhouettes", refine)
    monkeypatch.setattr(body_mod, "build_body", build)
    reference, xs = np.array([2, 5]), [np.zeros(3), np.ones(3)]
    shape = gf.ShapeFit(PH, {"neck-scale-horiz-decr-incr": 0.1}, "OLD BODY", reference, xs)
    poses, masks = ["pose0", "pose1"], np.zeros((2, 4, 4), bool)
    out = gf.refine_fit_shape(shape, poses, masks, "camera", 1.71, "6k", 0.007)
    args, kwargs = calls["refine"]
    assert args == (PH, {"neck-scale-horiz-decr-incr": 0.1}, "6k", poses, masks, "camera", 1.71)
    assert kwargs == {"allowance_m": 0.007}
    phenotype, local, resolution = calls["build"]
    assert phenotype == Phenotype.from_dict(PH2) and local == {"neck-scale-horiz-decr-incr": 0.2}
    assert resolution == "6k"
    assert out.phenotype == PH2 and out.local == {"neck-scale-horiz-decr-incr": 0.2} and out.body == "REFINED BODY"
    assert out.reference is reference and out.xs is xs


def _finished_fit(lighting=None, n=3):
    rng = np.random.default_rng(0)
    masks = np.zeros((n, 6, 8), bool)
    masks[:, 2:5, 3:6] = True
    return GarmentFit(source="/clips/a.mp4", fps=30.0, frame_ids=np.arange(10, 10 + n), camera="camera",
                      template="6k", bone_names=("Root", "spine_02"), phenotype=PH, local={"neck": 0.1},
                      stature_m=1.70, rotations=rng.normal(0, 0.2, (n, 2, 3)), translations=rng.normal(0, 1, (n, 3)),
                      silhouette_iou=np.zeros(n), masks=masks, lighting=lighting, albedo=None if lighting is None
                      else np.zeros((4, 3)), timings_ms={"pose": 12.5}, warnings=("old",))


def _stand_ins(monkeypatch, stature_fit=1.715, ious=(0.9, 0.85, 0.7)):
    log = {}
    body = SimpleNamespace(faces="F", vertices=np.array([[0.0, 0.02, 0.0], [0.1, 0.02 + stature_fit, 0.0]]),
                           pose=lambda p: (np.full((2, 3), float(p.translation[0])), None))
    monkeypatch.setattr(GarmentFit, "body", lambda self: ("FIT BODY", self.template))

    def refine(shape, poses, masks, camera, stature_m, template, allowance_m):
        log["refine"] = (shape, poses, masks, camera, stature_m, template, allowance_m)
        return gf.ShapeFit(PH2, {"neck": 0.3}, body, shape.reference, shape.xs)

    monkeypatch.setattr(gf, "refine_fit_shape", refine)
    it = itertools.cycle(ious)

    def iou(V, F, camera, mask):
        log.setdefault("iou", []).append((float(V[0, 0]), F, camera, mask))
        return next(it)

    monkeypatch.setattr(gf, "silhouette_iou", iou)

    def appearance(images, masks, posed, F, camera):
        log["appearance"] = (images, masks, [float(V[0, 0]) for V in posed], F, camera)
        return "NEW ALBEDO", "NEW LIGHTING"

    monkeypatch.setattr(gf, "estimate_appearance", appearance)
    ticks = iter(np.arange(100.0, 200.0, 0.25))
    monkeypatch.setattr(gf, "time", SimpleNamespace(perf_counter=lambda: float(next(ticks))))
    return log


def test_refine_garment_fit_refines_with_the_fits_poses_and_recomputes_what_depends_on_the_shape(monkeypatch):
    log = _stand_ins(monkeypatch)
    fit = _finished_fit()
    images = np.zeros((3, 6, 8, 3), np.uint8)
    out = gf.refine_garment_fit(fit, images, 1.72)
    shape, poses, masks, camera, stature, template, allowance = log["refine"]
    assert shape.phenotype is fit.phenotype and shape.local is fit.local and shape.body == ("FIT BODY", "6k")
    assert shape.reference.dtype.kind == "i" and len(shape.reference) == 0 and shape.xs == []
    assert len(poses) == 3
    for i, p in enumerate(poses):
        np.testing.assert_array_equal(p.rotations, fit.rotations[i])
        np.testing.assert_array_equal(p.translation, fit.translations[i])
    assert masks is fit.masks and camera == "camera" and stature == 1.72 and template == "6k"
    assert allowance == CLOTHING_ALLOWANCE_M and isinstance(allowance, float)
    # the IoU of each frame's refined, posed body against its own matte
    assert [e[0] for e in log["iou"]] == [float(t) for t in fit.translations[:, 0]]
    assert all(e[1] == "F" and e[2] == "camera" for e in log["iou"])
    assert all(np.array_equal(e[3], m) for e, m in zip(log["iou"], fit.masks, strict=True))
    np.testing.assert_array_equal(out.silhouette_iou, [0.9, 0.85, 0.7])
    assert out.phenotype == PH2 and out.local == {"neck": 0.3}
    assert out.stature_m == pytest.approx(1.715, abs=1e-12)
    assert out.warnings == ("1 of 3 frames have a silhouette IoU below 0.80",)  # 5 mm off the stature is fine
    assert out.warnings == tuple(gf.fit_warnings(1.715, 1.72, np.array([0.9, 0.85, 0.7])))
    assert out.lighting is None and out.albedo is None and "appearance" not in log
    # 0.25 s over 3 frames: 83.3 ms each; the fit's own timings kept, not changed in place
    assert out.timings_ms == {"pose": 12.5, "shape_refinement": 83.3} and fit.timings_ms == {"pose": 12.5}
    np.testing.assert_array_equal(out.rotations, fit.rotations)
    assert out.source == fit.source and out.frame_ids is fit.frame_ids


def test_refine_garment_fit_takes_the_allowance_and_re_estimates_the_appearance(monkeypatch):
    log = _stand_ins(monkeypatch, stature_fit=1.65, ious=(0.95, 0.9, 0.85))
    fit = _finished_fit(lighting="OLD LIGHTING")
    images = np.zeros((3, 6, 8, 3), np.uint8)
    out = gf.refine_garment_fit(fit, images, 1.70, allowance_m=0)
    assert log["refine"][6] == 0.0 and isinstance(log["refine"][6], float)
    imgs, masks, posed, F, camera = log["appearance"]
    assert imgs is images and masks is fit.masks and F == "F" and camera == "camera"
    assert posed == [float(t) for t in fit.translations[:, 0]]
    assert out.albedo == "NEW ALBEDO" and out.lighting == "NEW LIGHTING"
    # ticks 0.25 s apart: the refinement and the appearance each 250 ms over 3 frames, to 0.1 ms
    assert out.timings_ms == {"pose": 12.5, "shape_refinement": 83.3, "appearance": 83.3}
    assert out.warnings == ("fitted stature 1.650 m differs from the given 1.700 m by over 1 cm",)
    gf.refine_garment_fit(fit, images, 1.70, allowance_m=0.012)
    assert log["refine"][6] == 0.012


@pytest.mark.parametrize("mm", [-0.001, 0.0301, float("nan"), float("inf")])
def test_a_clothing_allowance_outside_0_to_30_mm_is_refused_before_anything_is_read(tmp_path, mm):
    with pytest.raises(InputError) as e:
        gf.fit_garment_video(tmp_path / "missing.mp4", 1.7, tmp_path / "o", clothing_allowance_m=mm)
    assert str(e.value) == (f"--clothing-mm {1e3 * mm:g}: give the worn clothes' thickness in mm, between 0 and 30")
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("given, expected", [(None, CLOTHING_ALLOWANCE_M), (0.0, 0.0), (0.03, 0.03), (0.011, 0.011)])
def test_the_clothing_allowance_reaches_step_4b(tmp_path, monkeypatch, given, expected):
    log, pf, shape, light = stand_in_fit(monkeypatch)
    fit = gf.fit_garment_video("clip.mp4", 1.72, clothing_allowance_m=given)
    assert log["refine"][6] == expected
    assert log["refine"][4] == 1.72 and log["refine"][5] == "2k"
    assert "shape_refinement" in fit.timings_ms


def test_without_shape_refinement_step_4b_is_skipped_whatever_the_allowance(tmp_path, monkeypatch):
    log, pf, shape, light = stand_in_fit(monkeypatch)
    fit = gf.fit_garment_video("clip.mp4", 1.72, shape_refinement=False, clothing_allowance_m=0.02)
    assert "refine" not in log and "shape_refinement" not in fit.timings_ms
    with pytest.raises(InputError, match="--clothing-mm 40"):
        gf.fit_garment_video("clip.mp4", 1.72, shape_refinement=False, clothing_allowance_m=0.04)


# --- the rest of fit_garment_video, measured with step 4b's lines (the function as a whole) ---------------------

@pytest.mark.parametrize("stature", [0.5, 1.0, 2.5])
def test_statures_from_half_a_metre_to_two_and_a_half_are_fitted(monkeypatch, stature):
    log, pf, shape, light = stand_in_fit(monkeypatch)
    gf.fit_garment_video("clip.mp4", stature)
    assert log["shape"][2] == stature


@pytest.mark.parametrize("stature", [None, float("nan"), float("inf"), 0.4999, 2.5001, 3.0])
def test_an_implausible_stature_is_refused_by_name(tmp_path, stature):
    with pytest.raises(InputError) as e:
        gf.fit_garment_video(tmp_path / "missing.mp4", stature, tmp_path / "o")
    assert str(e.value) == f"--stature {stature}: give the actor's stature in metres, between 0.5 and 2.5"


def test_an_unknown_template_is_refused_with_the_valid_ones(tmp_path):
    from bodystudio.body.model import RESOLUTIONS

    with pytest.raises(InputError) as e:
        gf.fit_garment_video(tmp_path / "missing.mp4", 1.7, template="9k")
    assert str(e.value) == f"--template '9k': valid: {', '.join(RESOLUTIONS)}"


def _keyframes(tmp_path, monkeypatch, frames: dict):
    import json

    import bodystudio.body as body_mod

    monkeypatch.setattr(body_mod, "build_body", lambda resolution: SimpleNamespace(
        skeleton=SimpleNamespace(bone_names=("Root", "spine_02"))))
    path = tmp_path / "keys.json"
    path.write_text(json.dumps({"frames": frames}))
    return path


def test_keyframes_are_checked_against_the_image_size_and_the_fitted_frames(tmp_path, monkeypatch):
    from bodystudio.errors import FileFormatError

    log, pf, shape, light = stand_in_fit(monkeypatch)  # 64 x 48 frames 5, 6, 7
    with pytest.raises(FileFormatError, match=r"joint spine_02 at frame 6: \[70, 3\] is outside the 64x48 image"):
        gf.fit_garment_video("clip.mp4", 1.7, keyframes=_keyframes(tmp_path, monkeypatch, {"6": {"spine_02": [70, 3]}}))
    with pytest.raises(FileFormatError, match=r"no keyframe is on a fitted frame \(keyframes on \[9\], fitted 5..7\)"):
        gf.fit_garment_video("clip.mp4", 1.7, keyframes=_keyframes(tmp_path, monkeypatch, {"9": {"spine_02": [3, 4]}}))
    assert "shape" not in log  # refused before the shape fit


def test_the_fit_keeps_the_recordings_fingerprint(monkeypatch):
    from dataclasses import replace

    import bodystudio.garment.person as person

    log, pf, shape, light = stand_in_fit(monkeypatch)
    monkeypatch.setattr(person, "person_frames", lambda source, frames, background: replace(pf, fingerprint="video:ab"))
    assert gf.fit_garment_video("clip.mp4", 1.72).source_fingerprint == "video:ab"
