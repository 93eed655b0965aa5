"""garment/evaluate.py's body-building and folder functions (``fitted_joints``, ``shape_error_mm``, ``fit_errors``,
``evaluate_garment``) on a tiny synthetic session and its oracle fit (issue 17: never mutated).

The session and the oracle fit are built once per process (``functools.cache``; neither is evaluate.py's code);
every test calls the function under test itself (docs/MUTATION.md's blind spot note). The oracle scores zero
where the maths says so (stature, shape, joints, light), a perturbed fit scores what the component functions
say, field by field.
"""

import dataclasses
import functools
import tempfile
from pathlib import Path

import numpy as np
import pytest

from bodystudio.errors import InputError
from bodystudio.garment import evaluate as ge


@functools.cache
def _session_path():
    from bodystudio.garment.synthetic import synth_garment_session

    root = Path(tempfile.mkdtemp(prefix="bodystudio-evalfolder-"))
    synth_garment_session(root / "s", subject_seed=3, n_frames=2, resolution=(64, 80), template="2k",
                          texture_size=16, seed=2, shadows=False, noise=False)
    return root / "s"


def _session():
    from bodystudio.capture.session import open_session

    return open_session(_session_path())


@functools.cache
def _oracle():
    from bodystudio.garment.composite import ground_truth_fit

    return ground_truth_fit(_session())


def _perturbed():
    """The oracle with another shape, a shifted second frame, worse silhouettes, half a mask lost, timings."""
    fit = _oracle()
    T = fit.translations.copy()
    T[1] += [0.05, 0.0, 0.0]
    masks = fit.masks.copy()
    masks[0, : masks.shape[1] // 2] = False
    return dataclasses.replace(fit, phenotype={**fit.phenotype, "weight": 0.9, "height": 0.2}, translations=T,
                               silhouette_iou=np.array([0.93, 0.71]), masks=masks,
                               timings_ms={"pose": 10.0, "shape": 2.5})


def test_fitted_joints_are_the_posed_bone_heads_of_every_frame():
    from bodystudio.body.skinning import posed_joints

    s, fit = _session(), _oracle()
    J = ge.fitted_joints(fit)
    body = fit.body()
    assert J.shape == (2, body.skeleton.n_bones, 3)
    for i, fid in enumerate(fit.frame_ids):
        assert np.array_equal(J[i], posed_joints(body.skeleton, fit.pose(i))[0])
        assert np.abs(J[i] - s.frame(int(fid)).gt_joints["heads"]).max() < 1e-5  # the oracle's are the truth
    moved = ge.fitted_joints(_perturbed())
    # the second frame's root moved 5 cm along x: every joint with it
    from bodystudio.body import build_body
    from bodystudio.body.phenotype import Phenotype

    other = build_body(Phenotype.from_dict(_perturbed().phenotype), fit.local, resolution="2k")
    assert np.array_equal(moved[1], posed_joints(other.skeleton, _perturbed().pose(1))[0])
    assert not np.allclose(moved[0], J[0], atol=1e-3)  # another shape: other joints


def test_shape_error_is_the_mean_vertex_distance_to_the_true_body_in_millimetres():
    from bodystudio.body import build_body
    from bodystudio.body.phenotype import Phenotype

    s, fit = _session(), _oracle()
    subject = s.gt_subject
    assert ge.shape_error_mm(fit, fit.body(), subject) == 0.0
    other = build_body(Phenotype(weight=0.9, height=0.2), {}, resolution="2k")
    truth = build_body(Phenotype.from_dict(subject["phenotype"]), subject["local"], resolution="2k")
    want = 1e3 * np.linalg.norm(other.vertices - truth.vertices, axis=1).mean()
    assert ge.shape_error_mm(fit, other, subject) == pytest.approx(want, rel=1e-12) and want > 5.0
    # no local modifiers in the subject: the macro shape alone
    bare = {"phenotype": subject["phenotype"]}
    plain = build_body(Phenotype.from_dict(subject["phenotype"]), {}, resolution="2k")
    assert subject["local"]  # the sampled subject has some, so the default matters
    want = 1e3 * np.linalg.norm(other.vertices - plain.vertices, axis=1).mean()
    assert ge.shape_error_mm(fit, other, bare) == pytest.approx(want, rel=1e-12)


def test_fit_errors_of_the_oracle_are_zero_where_the_truth_is_the_fit():
    s, fit = _session(), _oracle()
    out = ge.fit_errors(fit, s)
    assert out["frames"] == 2
    body = fit.body()
    assert out["stature_m"] == pytest.approx(np.ptp(body.vertices[:, 1]), abs=1e-12)
    assert out["stature_err_mm"] == pytest.approx(0.0, abs=1e-9) and out["shape_err_mm"] == 0.0
    assert out["joint_err_mm"] < 0.01 and out["joint_err_px"] < 0.01
    assert out["light_dir_err_deg"] < 0.01 and out["light_brightest_dir_err_deg"] < 0.01
    assert out["silhouette_iou"] == pytest.approx(np.mean(fit.silhouette_iou), abs=1e-12)
    assert out["mask_iou_vs_gt"] == 1.0  # the oracle's masks are the session's


def test_fit_errors_of_a_perturbed_fit_are_the_component_scores():
    from bodystudio.capture.silhouettes import mask_iou

    s, fit = _session(), _perturbed()
    out = ge.fit_errors(fit, s)
    body = fit.body()
    stature = float(body.vertices[:, 1].max() - body.vertices[:, 1].min())
    assert out["stature_m"] == stature
    assert out["stature_err_mm"] == pytest.approx(abs(stature - s.gt_subject["stature_m"]) * 1e3, rel=1e-12)
    assert out["stature_err_mm"] > 10
    assert out["shape_err_mm"] == ge.shape_error_mm(fit, body, s.gt_subject) > 5
    for k, v in ge.joint_errors(fit, s).items():
        assert out[k] == v
    for k, v in ge.light_direction_errors(fit, s).items():
        assert out[k] == v
    assert out["albedo_err"] == ge.albedo_error(fit, s)
    assert out["silhouette_iou"] == pytest.approx(0.82, abs=1e-12) and out["silhouette_iou_min"] == 0.71
    want = np.mean([mask_iou(fit.masks[i], s.frame(int(f)).gt_masks["cam_00"]) for i, f in enumerate(fit.frame_ids)])
    assert out["mask_iou_vs_gt"] == pytest.approx(want, abs=1e-12) and 0.5 < want < 0.95
    assert out["ms_per_frame"] == {"pose": 10.0, "shape": 2.5}
    assert set(out) == {"frames", "stature_m", "stature_err_mm", "shape_err_mm", "joint_err_px", "joint_err_px_max",
                        "joint_err_mm", "joint_err_mm_max", *ge.light_direction_errors(fit, s), "albedo_err",
                        "silhouette_iou", "silhouette_iou_min", "mask_iou_vs_gt", "ms_per_frame"}


def test_fit_errors_opens_a_session_given_by_path():
    fit = _perturbed()
    by_path = ge.fit_errors(fit, str(_session_path()))
    assert by_path == ge.fit_errors(fit, _session())


@pytest.mark.parametrize("subject", [None, {"phenotype": {}, "local": {}}])
def test_fit_errors_needs_the_subjects_stature(subject):
    s = _session()
    s.__dict__["gt_subject"] = subject  # the cached property, as a session without (a stature in) gt/phenotype.json
    with pytest.raises(InputError) as e:
        ge.fit_errors(_oracle(), s)
    assert str(e.value) == (f"{s.path}: no gt/phenotype.json with a stature; eval garment needs a synthetic session "
                            "(bodystudio synth garment)")


# --- evaluate_garment ------------------------------------------------------------------------------

def _saved(tmp_path, fit):
    from bodystudio.garment.fitfile import save_garment_fit

    save_garment_fit(tmp_path / "fit", fit, "test")
    return tmp_path / "fit"


def test_evaluate_garment_scores_the_saved_fit_against_its_source(tmp_path):
    import json

    from bodystudio.garment.fitfile import load_garment_fit

    fit_dir = _saved(tmp_path, _perturbed())
    got = ge.evaluate_garment(fit_dir)
    want = ge.fit_errors(load_garment_fit(fit_dir), _session())
    # which fit was scored (fit.json's run id) and that no render was
    want.update(fit_run_id=json.loads((fit_dir / "fit.json").read_text())["run"]["run_id"], render_run_id=None)
    assert got == want
    assert ge.evaluate_garment(str(fit_dir), str(_session_path())) == want


def test_evaluate_garment_refuses_a_source_that_is_not_a_folder(tmp_path):
    fit_dir = _saved(tmp_path, dataclasses.replace(_oracle(), source=str(tmp_path / "clip.mp4")))
    with pytest.raises(InputError) as e:
        ge.evaluate_garment(fit_dir)
    assert str(e.value) == (f"{tmp_path / 'clip.mp4'}: the fit's source is not a session folder; eval garment needs "
                            "the synthetic session (pass --session)")
    # given the session, the fit of a video with the session's frames scores
    assert ge.evaluate_garment(fit_dir, _session_path())["frames"] == 2


def test_evaluate_garment_checks_the_source_first(tmp_path):
    fit = _oracle()
    fit_dir = _saved(tmp_path, dataclasses.replace(fit, source=str(tmp_path / "clip.mp4"),
                                                   frame_ids=np.array([0, 7])))
    with pytest.raises(InputError) as e:
        ge.evaluate_garment(fit_dir, _session_path())
    assert str(e.value) == (f"{fit_dir}: frames [7] of the fit are not in {_session_path()}; pass --session with the "
                            "session the video was made from")


def test_evaluate_garment_adds_the_composites_scores_when_rendered(tmp_path, monkeypatch):
    import bodystudio.garment.composite as comp

    fit_dir = _saved(tmp_path, _perturbed())
    calls = []

    def fake(d, s):
        calls.append((Path(d), s.path))
        return {"garment_iou": 0.5, "frames": 99}

    monkeypatch.setattr(comp, "composite_errors", fake)
    plain = ge.evaluate_garment(fit_dir)
    assert calls == [] and "garment_iou" not in plain
    (fit_dir / "render").mkdir()
    (fit_dir / "render" / "render.json").write_text("{}")
    got = ge.evaluate_garment(fit_dir)
    assert calls == [(fit_dir, _session_path())]
    assert got == {**plain, "garment_iou": 0.5, "frames": 99}  # the composite's keys are added last
    (fit_dir / "render" / "render.json").unlink()
    (fit_dir / "render" / "render.json").mkdir()  # a folder of that name is not a render
    assert "garment_iou" not in ge.evaluate_garment(fit_dir)
