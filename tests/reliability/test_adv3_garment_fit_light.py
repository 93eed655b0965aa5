"""A garment fit whose fit.json holds malformed lights (adversarial pass 3): the one-line error named fit.json
and what was wrong but, alone among the fit's messages, no fix. Now it ends with the fit's fix, as the others."""

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

    root = tmp_path_factory.mktemp("adv3glight")
    session = synth_garment_session(root / "session", subject_seed=3, n_frames=1, resolution=(120, 160),
                                    template="2k", texture_size=64, seed=2)
    save_garment_fit(root / "fit", perturbed_fit(ground_truth_fit(session), pose_deg=0.0, translation_m=0.0), "test")
    return root / "fit"


@pytest.mark.parametrize("lighting, phrase", [
    ({"directions": [[0.0, 0.0, 1.0]]}, "lights need 'directions' and 'colors'"),
    ({"directions": [[0.0, 0.0, 1.0]], "colors": [[float("nan"), 0.5, 0.5]], "ambient": [0.1, 0.1, 0.1]}, ""),
    ("sunny", "lights need"),
])
def test_malformed_lights_name_the_fit_and_its_fix(fit_dir, tmp_path, lighting, phrase):
    from bodystudio.garment.fitfile import load_garment_fit

    bad = shutil.copytree(fit_dir, tmp_path / "fit")
    doc = json.loads((bad / "fit.json").read_text())
    doc["lighting"] = lighting
    (bad / "fit.json").write_text(json.dumps(doc))
    with pytest.raises(FileFormatError) as err:
        load_garment_fit(bad)
    message = str(err.value)
    assert str(bad / "fit.json") in message and phrase in message and "\n" not in message, message
    assert message.endswith(f"rerun 'bodystudio garment fit ... --out {bad}'"), message
