"""Well-formed but wrong inputs a studio produces, planted in a small synthetic session: ``reconstruct`` used to
fit them with exit 0 (a bumped camera: visible-surface median error 39 mm instead of 3 mm; swapped masks:
48 mm; depth 10x off: every depth constraint silently dropped). Its self-check
(:mod:`bodystudio.reconstruct.plausibility`) now refuses them with one line naming the input and the fix,
writes nothing, and ``--accept-implausible`` writes the run with the verdict in run.json."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from bodystudio.capture.faults import bump_camera, scale_depth, swap_masks
from tests.reliability.conftest import assert_clean_error, run_inprocess

ARGS = ["--template", "2k", "--no-score"]


@pytest.fixture(scope="module")
def clean_session(tmp_path_factory):
    from bodystudio.capture.synth import synth_session

    path = tmp_path_factory.mktemp("plaus") / "clean"
    synth_session(path, n_cameras=6, n_frames=1, motion="walk", subject_seed=23, resolution=(320, 240), kinect="v2")
    return path


def _copy(clean: Path, tmp_path: Path, plant=None) -> Path:
    S = Path(shutil.copytree(clean, tmp_path / "S"))
    if plant is not None:
        plant(S)
    return S


def _verdict(S: Path) -> dict:
    return json.loads((S / "reconstruct" / "run.json").read_text())["plausibility"]


def test_clean_session_passes_its_self_check(clean_session, tmp_path, capfd):
    from bodystudio.reconstruct.plausibility import IOU_WARN

    S = _copy(clean_session, tmp_path)
    result = run_inprocess(["reconstruct", S, *ARGS, "--constraints", "silhouette,depth"], capfd)
    assert_clean_error(result, 0, "")
    verdict = _verdict(S)
    assert verdict["ok"] and not verdict["warnings"] and not verdict["problems"]
    assert min(verdict["camera_iou"].values()) >= IOU_WARN + 0.05  # clean views agree with margin
    assert verdict["depth"]["coverage"] > 0.8 and verdict["depth"]["gap_m"] < 0.02
    assert abs(verdict["depth"]["ratio"] - 1.0) < 0.02
    frames = json.loads((S / "reconstruct" / "frames.json").read_text())["frames"]
    assert set(frames[0]["plausibility"]["silhouette_iou"]) == {f"cam_{k:02d}" for k in range(6)}


@pytest.mark.parametrize("plant, phrase, culprit", [
    (bump_camera, "cameras.json", "cam_02"),
    (swap_masks, "masks", None),
    (lambda S: scale_depth(S, 10.0), "--depth-scale", "10x"),
], ids=["camera-bumped-5cm-3deg", "masks-swapped", "depth-10x"])
def test_implausible_input_is_refused_and_nothing_written(clean_session, tmp_path, capfd, plant, phrase, culprit):
    S = _copy(clean_session, tmp_path, plant)
    result = run_inprocess(["reconstruct", S, *ARGS, "--constraints", "silhouette,depth"], capfd)
    assert_clean_error(result, 2, phrase)
    assert "--accept-implausible" in result.stderr
    if culprit == "cam_02":  # named with the camera opposite it (silhouettes cannot tell the two apart)
        named = result.stderr.split("disagree")[0]
        assert "cam_02" in named and "cam_05" in named and "cam_01" not in named, result.stderr
    elif culprit is not None:
        assert culprit in result.stderr, result.stderr
    assert not (S / "reconstruct" / "run.json").exists()
    assert not list((S / "reconstruct").glob("meshes/*.ply")) if (S / "reconstruct").exists() else True


def test_accept_implausible_writes_the_run_with_its_verdict(clean_session, tmp_path, capfd):
    S = _copy(clean_session, tmp_path, swap_masks)
    result = run_inprocess(["reconstruct", S, *ARGS, "--accept-implausible"], capfd)
    assert_clean_error(result, 0, "")
    verdict = _verdict(S)
    assert not verdict["ok"] and verdict["problems"]
    iou = verdict["camera_iou"]
    assert min(iou["cam_01"], iou["cam_03"]) < 0.75, iou


def test_verdict_tells_a_moved_camera_from_a_fit_that_did_not_converge():
    """run_plausibility on recorded figures: low IoU with coherent inputs blames the fit, not the rig; an
    outlier pair of coherences names those cameras; clean figures pass without a warning."""
    from bodystudio.reconstruct.plausibility import run_plausibility

    cams = [f"cam_{k:02d}" for k in range(6)]
    clean = {"silhouette_iou": dict.fromkeys(cams, 0.95), "coherence": dict.fromkeys(cams, 1.0)}
    verdict = run_plausibility([clean, clean])
    assert verdict["ok"] and not verdict["warnings"]
    unconverged = {"silhouette_iou": dict.fromkeys(cams, 0.6), "coherence": dict.fromkeys(cams, 1.0)}
    verdict = run_plausibility([unconverged])
    assert not verdict["ok"] and "did not converge" in verdict["problems"][0]
    moved = {"silhouette_iou": dict.fromkeys(cams, 0.5),
             "coherence": {**dict.fromkeys(cams, 0.84), "cam_02": 0.56, "cam_05": 0.51}}
    verdict = run_plausibility([moved], "S")
    assert verdict["problems"][0].startswith("cameras cam_05, cam_02 disagree") and "S/calibration" in \
        verdict["problems"][0]
    weak = {"silhouette_iou": {**dict.fromkeys(cams, 0.95), "cam_03": 0.8}, "coherence": dict.fromkeys(cams, 1.0)}
    verdict = run_plausibility([weak])
    assert verdict["ok"] and "cam_03" in verdict["warnings"][0]
