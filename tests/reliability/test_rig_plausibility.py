"""Well-formed but wrong scans for ``bodystudio rig``: a scan with the feet or the head cut off (the scanner's floor or
volume) was rigged with exit 0 (fit error 4.9 mm median, 14.5 mm p90: under the 15 mm "not a human" bound; ankles or a
head invented where the scan has nothing), and so was a person in a pose the fit could not find (p90 38 mm). The
rig's self-check (:mod:`bodystudio.rig.plausibility`: the share of each fitted body region with scan surface nearby,
the fit error's 90th percentile) refuses them with one line, writes nothing, and ``--accept-implausible`` writes
the avatar with the verdict in its rig JSON. A scan in millimetres or with z up was already detected and rigs as
the metre, y-up scan does (pinned here)."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from tests.reliability.conftest import assert_clean_error, run_inprocess

VERTICES = 6000


def _save(path, V, F, keep_faces=None):
    from bodystudio.geometry.mesh import Mesh, save_mesh

    if keep_faces is not None:
        F = F[keep_faces]
        used = np.unique(F)
        remap = np.full(len(V), -1)
        remap[used] = np.arange(len(used))
        V, F = V[used], remap[F]
    save_mesh(path, Mesh(V, F, None))
    return path


@pytest.fixture(scope="module")
def scans(tmp_path_factory):
    import bodystudio.register.synthetic as synthetic

    root = tmp_path_factory.mktemp("rigplaus")
    scan, _ = synthetic.synthetic_scan(11, "a", VERTICES, 1.0, True)
    V, F = scan.vertices, scan.faces
    out = {"clean": _save(root / "clean.ply", V, F),
           "mm-z-up": _save(root / "mm_zup.ply", 1000.0 * V[:, [0, 2, 1]] * np.array([1.0, -1.0, 1.0]), F),
           "feet-cut-off": _save(root / "nofeet.ply", V, F, V[F, 1].min(axis=1) > 0.15),
           "head-cut-off": _save(root / "nohead.ply", V, F, V[F, 1].max(axis=1) < V[:, 1].max() - 0.2)}
    sigma = synthetic.RANDOM_POSE_SIGMA
    try:  # a pose three times the random scans' spread: arms and legs far from the A-pose the fit starts in
        synthetic.RANDOM_POSE_SIGMA = {k: 3.0 * v for k, v in sigma.items()}
        posed, _ = synthetic.synthetic_scan(12, "random", VERTICES, 1.0, True)
    finally:
        synthetic.RANDOM_POSE_SIGMA = sigma
    out["other-pose"] = _save(root / "pose.ply", posed.vertices, posed.faces)
    return out


@pytest.fixture
def one_fit(monkeypatch):
    """One fit attempt (no restarts with other seeds): the self-check after the fit is under test, and a faulty
    scan's restarts cost ~3x the time without changing its verdict (measured: same regions named)."""
    import bodystudio.rig.pipeline as pipeline

    monkeypatch.setattr(pipeline, "FIT_ATTEMPTS", 1)


@pytest.mark.parametrize("name", ["clean", "mm-z-up"])
def test_whole_scan_passes_its_self_check(scans, tmp_path, capfd, name):
    out = tmp_path / "a.glb"
    result = run_inprocess(["rig", scans[name], "--out", out], capfd)
    assert_clean_error(result, 0, "")
    desc = json.loads(out.with_suffix(".rig.json").read_text())
    verdict = desc["plausibility"]
    assert verdict["ok"] and not verdict["warnings"], verdict
    assert min(verdict["coverage"].values()) > 0.7 and verdict["fit_err_mm_p90"] < 4.0
    assert desc["scan"]["units"] == ("mm" if name == "mm-z-up" else "m")


@pytest.mark.parametrize("name, phrase", [
    ("feet-cut-off", "has no feet"),
    ("head-cut-off", "has no head"),
    ("other-pose", "does not fit"),
])
def test_implausible_scan_is_refused_and_nothing_written(scans, tmp_path, capfd, one_fit, name, phrase):
    out = tmp_path / "a.glb"
    result = run_inprocess(["rig", scans[name], "--out", out], capfd)
    if name == "other-pose" and phrase not in result.stderr:
        # The one fit attempt on a scan in another pose lands in a local minimum that depends on the machine's
        # rounding: on some machines it leaves a region below REGION_MISSING (head 0.38 < 0.4 with a p90 of 98 mm),
        # and a missing region is reported before the fit error by design (test_rig_plausibility_mutants). Either
        # way the refusal must carry the fit error over FIT_P90_REFUSE_MM.
        p90 = re.search(r"fit error p90 ([0-9.]+) mm", result.stderr)
        assert p90 and float(p90.group(1)) > 10.0, result.stderr
        phrase = "avatar not written"
    assert_clean_error(result, 2, phrase)
    assert "--accept-implausible" in result.stderr and str(scans[name]) in result.stderr
    assert not out.exists() and not out.with_suffix(".rig.json").exists()


def test_accept_implausible_writes_the_avatar_with_its_verdict(scans, tmp_path, capfd, one_fit):
    out = tmp_path / "a.glb"
    result = run_inprocess(["rig", scans["feet-cut-off"], "--out", out, "--accept-implausible"], capfd)
    assert_clean_error(result, 0, "")
    verdict = json.loads(out.with_suffix(".rig.json").read_text())["plausibility"]
    assert not verdict["ok"] and "has no feet" in verdict["problems"][0]
    assert max(verdict["coverage"]["foot_l"], verdict["coverage"]["foot_r"]) < 0.4


def test_verdict_thresholds_on_region_coverage():
    """rig_plausibility on a fitted body against scans made from it: the whole body is covered, with the feet
    removed the feet are named, with a 4 cm offset nothing is covered and the fit error decides."""
    from types import SimpleNamespace

    from bodystudio.rig.pipeline import load_template_model
    from bodystudio.rig.plausibility import rig_plausibility

    model = load_template_model("6k")
    coeffs = np.zeros(model.n_components)
    V, F, skeleton = model.vertices(coeffs), model.faces, model.skeleton(coeffs)
    fit = SimpleNamespace(weights=model.weights, skeleton=skeleton, vertices=V, fit_err_mm_median=1.0,
                          fit_err_mm_p90=2.0)
    whole = rig_plausibility(fit, V, F)
    assert whole["ok"] and not whole["warnings"] and min(whole["coverage"].values()) > 0.99
    y = V[:, 1] - V[:, 1].min()
    keep = y[F].min(axis=1) > 0.12
    cut = rig_plausibility(fit, V, F[keep], "S.ply")
    assert not cut["ok"] and cut["problems"][0].startswith("S.ply has no feet")
    assert cut["coverage"]["foot_l"] < 0.4 and cut["coverage"]["leg_l"] > 0.6
    bad_fit = SimpleNamespace(**{**vars(fit), "fit_err_mm_p90": 12.0})
    assert "does not fit" in rig_plausibility(bad_fit, V, F)["problems"][0]
    loose = SimpleNamespace(**{**vars(fit), "fit_err_mm_p90": 7.0})
    verdict = rig_plausibility(loose, V, F)
    assert verdict["ok"] and "90th percentile is 7.0 mm" in verdict["warnings"][0]
