"""A garment fit folder whose albedo.npy holds NaN (adversarial pass): ``garment render`` exited 0 with a
render built on it and ``eval garment`` of that render ended in a JSON traceback (NaN scores). The fit is
now refused at load with one line naming the fix."""

import shutil

import numpy as np
import pytest

from .conftest import run_bad


@pytest.fixture(scope="module")
def fit_dir(tmp_path_factory):
    """The oracle fit of a 2-frame 120x160 synthetic garment session, with a per-vertex albedo."""
    from bodystudio.garment.composite import ground_truth_fit, perturbed_fit
    from bodystudio.garment.fitfile import save_garment_fit
    from bodystudio.garment.synthetic import synth_garment_session

    root = tmp_path_factory.mktemp("advgf")
    session = synth_garment_session(root / "session", subject_seed=3, n_frames=2, resolution=(120, 160),
                                    template="2k", texture_size=64, seed=2)
    fit = perturbed_fit(ground_truth_fit(session), pose_deg=0.0, translation_m=0.0)
    if fit.albedo is None:
        from dataclasses import replace

        fit = replace(fit, albedo=np.full((2502, 3), 0.5))
    save_garment_fit(root / "fit", fit, "test")
    return root / "fit"


@pytest.mark.parametrize("damage, phrase", [
    (lambda a: a.__setitem__(0, np.nan), "not finite"),
    (lambda a: a.__setitem__(5, np.inf), "not finite"),
])
def test_render_refuses_a_fit_with_a_broken_albedo(fit_dir, tmp_path, capsys, damage, phrase):
    bad = tmp_path / "fit"
    shutil.copytree(fit_dir, bad)
    albedo = np.load(bad / "albedo.npy")
    damage(albedo)
    np.save(bad / "albedo.npy", albedo)
    out = tmp_path / "g.mp4"
    run_bad(["garment", "render", bad, "--out", out, "--no-flow"], capsys, phrase)
    assert not out.exists() and not (bad / "render").exists()
    run_bad(["eval", "garment", bad], capsys, phrase)


@pytest.mark.parametrize("fps", [float("nan"), 0.0, 1e6])
def test_render_refuses_a_fit_without_a_frame_rate(fit_dir, tmp_path, capsys, fps):
    """fps NaN in fit.json: garment render failed with 'ffmpeg could not write ... check the disk space' on a
    staging path; now one line naming fit.json's value and the fix."""
    import json

    bad = tmp_path / "fit"
    shutil.copytree(fit_dir, bad)
    doc = json.loads((bad / "fit.json").read_text())
    doc["fps"] = fps
    (bad / "fit.json").write_text(json.dumps(doc))
    out = tmp_path / "g.mp4"
    run_bad(["garment", "render", bad, "--out", out, "--no-flow"], capsys, "is not a frame rate in 1..240")
    assert not out.exists() and not (bad / "render").exists()
