"""A garment fit whose fit.json holds a NaN or out-of-range shape value (adversarial pass, round 2): render,
eval and view failed with "phenotype gender=nan is out of range", naming no file. The fit is now refused at
load, naming its folder and the fix."""

from __future__ import annotations

import json
import shutil

import pytest

from bodystudio.errors import FileFormatError


@pytest.fixture(scope="module")
def fit_dir(tmp_path_factory):
    from bodystudio.garment.composite import ground_truth_fit, perturbed_fit
    from bodystudio.garment.fitfile import save_garment_fit
    from bodystudio.garment.synthetic import synth_garment_session

    root = tmp_path_factory.mktemp("adv2gshape")
    session = synth_garment_session(root / "session", subject_seed=3, n_frames=1, resolution=(120, 160),
                                    template="2k", texture_size=64, seed=2)
    save_garment_fit(root / "fit", perturbed_fit(ground_truth_fit(session), pose_deg=0.0, translation_m=0.0), "test")
    return root / "fit"


@pytest.mark.parametrize("key, value", [("phenotype", float("nan")), ("phenotype", 7.0), ("local", float("nan")),
                                        ("local", -3.0)])
def test_bad_shape_values_are_refused_naming_the_fit(fit_dir, tmp_path, key, value):
    from bodystudio.garment.fitfile import load_garment_fit

    bad = shutil.copytree(fit_dir, tmp_path / "fit")
    doc = json.loads((bad / "fit.json").read_text())
    doc[key] = {**doc[key], (next(iter(doc["phenotype"])) if key == "phenotype" else "upperarm-fat-decr-incr"): value}
    (bad / "fit.json").write_text(json.dumps(doc))
    with pytest.raises(FileFormatError, match=f"{bad}: damaged garment fit .*; rerun 'bodystudio garment fit"):
        load_garment_fit(bad)
    assert load_garment_fit(fit_dir).stature_m > 0.5  # the undamaged fit loads
