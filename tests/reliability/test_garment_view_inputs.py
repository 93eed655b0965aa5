"""Garment fit folders as input to ``bodystudio view`` and ``bodystudio report``: a damaged or unfinished fit is
one error line (exit 2, no output written); an incomplete one (no render, source gone, damaged render.json) is
shown with what is there, saying what is missing."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from .conftest import assert_clean_error, run_inprocess


@pytest.fixture(scope="module")
def video_fit(tmp_path_factory):
    """A 2-frame fit folder written through fitfile.py: the default 2k body standing 3 m in front of the assumed
    camera, two lights, no albedo, its source video gone and no render."""
    from bodystudio.body import build_body
    from bodystudio.body.phenotype import Phenotype
    from bodystudio.garment.fit import camera_hypothesis
    from bodystudio.garment.fitfile import GarmentFit, save_garment_fit
    from bodystudio.garment.lighting import Lighting

    root = tmp_path_factory.mktemp("gview-inputs")
    body = build_body(resolution="2k")
    n, B = 2, body.skeleton.n_bones
    fit = GarmentFit(source=str(root / "gone.mp4"), fps=30.0, frame_ids=np.array([4, 5]),
                     camera=camera_hypothesis(120, 160), template="2k", bone_names=tuple(body.skeleton.bone_names),
                     phenotype=Phenotype().to_dict(), local={}, stature_m=1.7, rotations=np.zeros((n, B, 3)),
                     translations=np.tile([0.0, 0.0, -3.0], (n, 1)), silhouette_iou=np.full(n, 0.9),
                     masks=np.zeros((n, 160, 120), bool),
                     lighting=Lighting(np.array([[0.3, 0.8, 0.5], [-0.5, 0.2, 0.8]]), np.array([[0.6] * 3, [0.2] * 3]),
                                       np.full(3, 0.2)))
    save_garment_fit(root / "fit", fit, "test")
    return root / "fit"


def _copy(fit_dir, tmp_path):
    return shutil.copytree(fit_dir, tmp_path / "fit")


@pytest.mark.parametrize("damage, phrase", [
    ("garbage", "damaged garment fit"),
    ("other-format", "not a garment fit"),
    ("no-poses", "damaged garment fit"),
    ("no-mask", "00005.png: missing or unreadable"),
    ("damaged-mask", "00004.png: unreadable image"),
    ("interrupted", "interrupted"),
])
def test_view_damaged_fit_is_one_line(video_fit, tmp_path, capfd, damage, phrase):
    from bodystudio.garment.fitfile import FIT_JSON
    from bodystudio.runfolder import RunLayout

    d = _copy(video_fit, tmp_path)
    if damage == "garbage":
        (d / "fit.json").write_text("{ not json")
    elif damage == "other-format":
        (d / "fit.json").write_text('{"format": "something-else"}')
    elif damage == "no-poses":
        (d / "poses.npz").unlink()
    elif damage == "no-mask":
        (d / "masks" / "00005.png").unlink()
    elif damage == "damaged-mask":
        (d / "masks" / "00004.png").write_bytes((d / "masks" / "00004.png").read_bytes()[:40])
    else:  # killed between the commit record and the swap
        record = RunLayout(d, FIT_JSON, ".", str(d)).commit_record
        record.parent.mkdir(parents=True, exist_ok=True)
        record.write_text("{}")
    shot = tmp_path / "v.png"
    assert_clean_error(run_inprocess(["view", d, "--screenshot", shot], capfd), 2, phrase)
    assert not shot.exists()


@pytest.mark.parametrize("args, phrase", [
    (["--frame", "7"], "--frame 7: not a frame of the fit"),
    (["--bone", "upperarm_l"], "--bone needs an avatar"),
    (["--reference", "{fit}/fit.json"], "--reference colours a mesh"),
])
def test_view_fit_bad_options_are_one_line(video_fit, tmp_path, capfd, args, phrase):
    shot = tmp_path / "v.png"
    args = [a.replace("{fit}", str(video_fit)) for a in args]
    assert_clean_error(run_inprocess(["view", video_fit, "--screenshot", shot, *args], capfd), 2, phrase)
    assert not shot.exists()


def test_view_fit_without_source_or_render_still_shows_body_and_lights(video_fit, tmp_path, capfd):
    shot, page = tmp_path / "v.png", tmp_path / "v.html"
    r = run_inprocess(["view", video_fit, "--frame", "5", "--screenshot", shot, "--html", page], capfd)
    assert_clean_error(r, 0, "")
    text = page.read_text()
    assert "fitted-body" in text and "lights-estimated" in text and "garment-strip" not in text


def test_report_on_incomplete_fit_says_what_is_missing(video_fit, tmp_path, capfd):
    d = _copy(video_fit, tmp_path)
    (d / "render").mkdir()
    (d / "render" / "render.json").write_text("{ not json")
    out = tmp_path / "r.html"
    assert_clean_error(run_inprocess(["report", d, "--out", out], capfd), 0, "")
    text = out.read_text()
    assert "Garment: before / after" in text and "render not shown" in text and "gone.mp4 is gone" in text
    assert "not scored" in text


def test_report_on_damaged_fit_still_renders(video_fit, tmp_path, capfd):
    d = _copy(video_fit, tmp_path)
    (d / "poses.npz").write_bytes(b"not a zip")
    out = tmp_path / "r.html"
    assert_clean_error(run_inprocess(["report", tmp_path, "--out", out], capfd), 0, "")
    assert "not shown: " in out.read_text() and "damaged garment fit" in out.read_text()
