"""reconstruct's self-check on clean sessions with realistic mask noise (benchmarks/reconstruct_mask_noise.py):
the segmentation's 1-3 px edge jitter, a floor shadow merged into the masks, small holes and an arm lost in one
view together lowered a good fit's silhouette IoU to 0.67-0.75 (fit 8-9 mm median against 2.2 mm on clean
masks, a moved camera 35-38 mm) and the run was refused as a fit that "did not converge". The check now also
measures the fit against each mask up to a 3 px band: the noisy views are warned about (the masks), not refused,
and a moved camera or swapped masks under the same noise are still refused."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from bodystudio.capture.faults import bump_camera, mask_all_noise, rewrite_masks, swap_masks
from tests.reliability.conftest import assert_clean_error, run_inprocess

ARGS = ["--template", "2k", "--no-score"]


@pytest.fixture(scope="module")
def noisy_session(tmp_path_factory):
    from bodystudio.capture.synth import synth_session

    path = tmp_path_factory.mktemp("masknoise") / "noisy"
    synth_session(path, n_cameras=6, n_frames=1, motion="walk", subject_seed=23, resolution=(640, 480))
    rewrite_masks(path, mask_all_noise)
    return path


def _copy(src: Path, tmp_path: Path, plant=None) -> Path:
    S = Path(shutil.copytree(src, tmp_path / "S"))
    if plant is not None:
        plant(S)
    return S


def test_noisy_masks_of_a_clean_session_are_warned_about_not_refused(noisy_session, tmp_path, capfd):
    S = _copy(noisy_session, tmp_path)
    result = run_inprocess(["reconstruct", S, *ARGS], capfd)
    assert_clean_error(result, 0, "")
    verdict = json.loads((S / "reconstruct" / "run.json").read_text())["plausibility"]
    assert verdict["ok"] and not verdict["problems"]
    assert min(verdict["camera_iou"].values()) < 0.8  # the IoU alone would have refused some views
    assert min(verdict["camera_precision_tol"].values()) >= 0.95
    assert any("shadows, holes or a lost limb" in w for w in verdict["warnings"]), verdict["warnings"]


@pytest.mark.parametrize("plant, phrase", [(bump_camera, "cameras.json"), (swap_masks, "masks")],
                         ids=["camera-moved", "masks-swapped"])
def test_faults_under_the_same_noise_are_still_refused(noisy_session, tmp_path, capfd, plant, phrase):
    S = _copy(noisy_session, tmp_path, plant)
    result = run_inprocess(["reconstruct", S, *ARGS], capfd)
    assert_clean_error(result, 2, phrase)
    assert not (S / "reconstruct" / "run.json").exists()


def test_verdict_with_and_without_the_tolerant_figures():
    """Recorded figures (640x480 sessions 23 and 24): a low IoU with the fit inside every mask's band is a warning;
    a view whose fit leaves its mask's band is refused; frames without the tolerant figures (older runs) keep the
    IoU rule."""
    from bodystudio.reconstruct.plausibility import run_plausibility

    cams = [f"cam_{k:02d}" for k in range(6)]
    noisy = {"silhouette_iou": dict.fromkeys(cams, 0.7), "coherence": dict.fromkeys(cams, 0.94),
             "silhouette_precision_tol": dict.fromkeys(cams, 0.994), "silhouette_recall_tol": dict.fromkeys(cams, 0.8)}
    verdict = run_plausibility([noisy])
    assert verdict["ok"] and "shadows, holes or a lost limb" in verdict["warnings"][0]
    moved = {**noisy, "silhouette_iou": {**noisy["silhouette_iou"], "cam_02": 0.2},
             "silhouette_precision_tol": {**noisy["silhouette_precision_tol"], "cam_02": 0.83},
             "silhouette_recall_tol": {**noisy["silhouette_recall_tol"], "cam_02": 0.31}}
    verdict = run_plausibility([moved], "S")
    assert not verdict["ok"] and "cam_02 0.20" in verdict["problems"][0]
    legacy = {"silhouette_iou": dict.fromkeys(cams, 0.7), "coherence": dict.fromkeys(cams, 0.94)}
    assert not run_plausibility([legacy])["ok"]
