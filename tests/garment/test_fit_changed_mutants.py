"""Fast tests of the garment fit functions changed since fit.py's first mutation row besides step 4b (issue 17's
mutation tests, docs/mutation/garment-fit.md "The other functions changed since 2d36dc3"): the keyframe file's checks
against the image size and the fitted frames, ``finite_projection``'s near-camera cut, ``_shape_body``'s macro /
local split, ``shape_prior_energy``'s weight and spread, ``nelder_mead_shape``'s energy and tolerances. Stand-ins only.
"""

import json
import logging

import numpy as np
import pytest
import scipy.optimize

from bodystudio.errors import FileFormatError
from bodystudio.garment import fit as gf

BONES = ("Root", "spine_02", "upperarm_l")


def _keys(tmp_path, frames: dict):
    path = tmp_path / "keys.json"
    path.write_text(json.dumps({"frames": frames}))
    return path


def test_keyframes_on_the_image_border_are_inside(tmp_path):
    frames = {"1": {"spine_02": [0, 0], "upperarm_l": [64, 48]},
              "2": {"spine_02": [0.5, 47.5], "upperarm_l": [63.5, 0.5]}}
    got = gf.KeyframeConstraints.load(_keys(tmp_path, frames), BONES, (64, 48), [1, 2])
    assert sorted(got.points) == [1, 2] and np.array_equal(got.points[1]["upperarm_l"], [64, 48])
    for uv in ([-0.01, 3], [64.01, 3], [3, -0.01], [3, 48.01], [3, 48.5]):
        with pytest.raises(FileFormatError, match=r"is outside the 64x48 image; give pixels inside it"):
            gf.KeyframeConstraints.load(_keys(tmp_path, {"1": {"spine_02": uv}}), BONES, (64, 48))
    # the width bounds u, the height v: (60, 3) is inside a 64 x 48 image, (3, 60) is not
    gf.KeyframeConstraints.load(_keys(tmp_path, {"1": {"spine_02": [60, 3]}}), BONES, (64, 48))
    with pytest.raises(FileFormatError, match=r"\[3, 60\] is outside"):
        gf.KeyframeConstraints.load(_keys(tmp_path, {"1": {"spine_02": [3, 60]}}), BONES, (64, 48))


def test_keyframes_off_the_fitted_frames_are_left_out_with_a_warning(tmp_path, caplog):
    path = _keys(tmp_path, {"6": {"spine_02": [3, 4]}, "9": {"spine_02": [5, 6]}, "11": {"upperarm_l": [1, 1]}})
    with caplog.at_level(logging.WARNING, logger="bodystudio.garment.fit"):
        got = gf.KeyframeConstraints.load(path, BONES, (64, 48), np.array([5, 6, 7]))
    assert list(got.points) == [6] and np.array_equal(got.points[6]["spine_02"], [3, 4])
    msgs = [r.getMessage() for r in caplog.records if "keyframes on frames" in r.getMessage()]
    assert msgs == [f"{path}: keyframes on frames [9, 11] are outside the fitted frames; left out"]


def test_no_keyframe_on_a_fitted_frame_names_the_first_five(tmp_path):
    path = _keys(tmp_path, {str(f): {"spine_02": [1, 1]} for f in (20, 21, 22, 23, 24, 25, 26)})
    with pytest.raises(FileFormatError) as e:
        gf.KeyframeConstraints.load(path, BONES, (64, 48), [5, 6, 7])
    assert str(e.value) == (f"{path}: no keyframe is on a fitted frame (keyframes on [20, 21, 22, 23, 24], fitted "
                            "5..7); fix the frame numbers or --frames")
    empty = gf.KeyframeConstraints.load(_keys(tmp_path, {}), BONES, (64, 48), [5, 6, 7])
    assert empty.points == {}


def test_finite_projection_cuts_only_within_5_cm_of_the_camera():
    cam = gf.camera_hypothesis(160, 120)  # at (0, 1, 0), looking along -z
    V = np.array([[0.1, 1.0, -0.5], [0.0, 1.1, -0.06], [0.0, 1.0, -0.04], [0.0, 1.0, 2.0]])
    uv = gf.finite_projection(cam, V, (120, 160))
    np.testing.assert_allclose(uv[:2], cam.project(V[:2]))
    np.testing.assert_allclose(uv[2:], [(-480.0, -360.0)] * 2)


def test_shape_body_takes_macro_names_and_phenotype_keys_as_phenotype(monkeypatch):
    import bodystudio.body as body_mod

    monkeypatch.setattr(body_mod, "build_body", lambda ph, loc, resolution: (ph, loc, resolution))
    from bodystudio.body.phenotype import Phenotype

    ph0 = Phenotype().to_dict()
    _, ph, loc = gf._shape_body(np.array([1.4, -0.3, 1.7]), ("age", "weight", "neck-scale-horiz-decr-incr"), ph0, {},
                                "2k")
    assert ph["age"] == 1.0 and ph["weight"] == 0.0 and loc == {"neck-scale-horiz-decr-incr": 1.0}
    # a macro name the given phenotype lacks is still a phenotype value
    no_weight = {k: v for k, v in ph0.items() if k != "weight"}
    _, ph, loc = gf._shape_body(np.array([0.4]), ("weight",), no_weight, {}, "2k")
    assert ph["weight"] == 0.4 and loc == {}


def test_shape_prior_energy_takes_its_weight_and_spread():
    local = {gf.LOCAL_PARAMETERS[0]: 0.3, gf.LOCAL_PARAMETERS[5]: -0.6, "other": 5.0}
    expected = gf.SHAPE_PRIOR_WEIGHT * ((0.3 / gf.LOCAL_PRIOR_SD) ** 2 + (0.6 / gf.LOCAL_PRIOR_SD) ** 2)
    assert gf.shape_prior_energy(local) == pytest.approx(expected, rel=1e-12)
    assert gf.shape_prior_energy(local, weight=2.0, sd=0.15) == pytest.approx(2.0 * (4.0 + 16.0), rel=1e-12)
    assert gf.shape_prior_energy(local, sd=0.6) == pytest.approx(gf.SHAPE_PRIOR_WEIGHT * (0.25 + 1.0), rel=1e-12)


def _stand_in_stage(monkeypatch, energy_of, log):
    def shape_body(values, names, phenotype, local, template):
        return ("body", tuple(values)), {**phenotype, "v": list(values)}, {gf.LOCAL_PARAMETERS[0]: float(values[1])}

    def shape_energy(body, xs, camera, targets, stature_m, base):
        v = np.array(body[1])
        log.append(v)
        return energy_of(v)

    monkeypatch.setattr(gf, "_shape_body", shape_body)
    monkeypatch.setattr(gf, "shape_energy", shape_energy)


def test_nelder_mead_adds_the_prior_of_the_local_modifiers(monkeypatch):
    log = []
    _stand_in_stage(monkeypatch, lambda v: float((v[0] - 0.3) ** 2), log)  # the silhouettes see only the macro
    ph, loc = gf.nelder_mead_shape(("weight", gf.LOCAL_PARAMETERS[0]), np.array([0.5, 0.4]), {}, {}, "xs", "cam",
                                   "targets", 1.7, "2k", "base", max_evals=400)
    assert abs(ph["v"][0] - 0.3) < 0.01 and abs(loc[gf.LOCAL_PARAMETERS[0]]) < 0.05, (ph, loc)


def test_nelder_mead_stops_on_both_tolerances(monkeypatch):
    """A steep energy: the simplex is within xatol 1e-3 long before the energies are within fatol 1e-4."""
    log = []

    def steep(v):
        return float(1e4 * np.sum((v - [0.31, -0.22]) ** 2))

    _stand_in_stage(monkeypatch, lambda v: steep(v) - gf.shape_prior_energy({gf.LOCAL_PARAMETERS[0]: v[1]}), log)
    gf.nelder_mead_shape(("weight", gf.LOCAL_PARAMETERS[0]), np.array([0.5, 0.0]), {}, {}, "xs", "cam", "targets", 1.7,
                         "2k", "base", max_evals=2000)
    simplex = np.array([[0.5, 0.0], [0.65, 0.0], [0.5, 0.3]])
    ref = scipy.optimize.minimize(steep, [0.5, 0.0], method="Nelder-Mead",
                                  options={"maxfev": 2000, "initial_simplex": simplex, "xatol": 1e-3, "fatol": 1e-4})
    loose = scipy.optimize.minimize(steep, [0.5, 0.0], method="Nelder-Mead",
                                    options={"maxfev": 2000, "initial_simplex": simplex, "xatol": 1e-3, "fatol": 1.0})
    assert loose.nfev < ref.nfev  # the case separates the tolerances
    assert len(log) == ref.nfev
