"""Background subtraction (Rapid Skin Sec. V.A, Horprasert et al. 1999): accuracy against ground-truth masks."""

import json

import numpy as np
import pytest

from bodystudio.capture.silhouettes import (
    SegmentationParams,
    background_model,
    brightness_chromaticity_distortion,
    foreground_pixels,
    mask_iou,
    segment_session,
    segment_silhouette,
    silhouette_scores,
)


def noisy(image, rng, sigma=2.0):
    return np.clip(np.round(image + rng.normal(0, sigma, image.shape)), 0, 255).astype(np.uint8)


@pytest.fixture(scope="module")
def plate():
    rng = np.random.default_rng(1)
    base = rng.uniform(60, 200, (8, 8, 3))
    return np.kron(base, np.ones((10, 10, 1)))  # 80 x 80 blocky coloured background


def test_distortions_of_background_and_its_shadow(plate):
    rng = np.random.default_rng(2)
    model = background_model([noisy(plate, rng) for _ in range(6)])
    alpha, cd = brightness_chromaticity_distortion(plate, model)
    tau_cd = SegmentationParams().tau_cd
    assert np.allclose(alpha, 1.0, atol=0.02) and (cd / model.cd_rms).max() < tau_cd
    alpha, cd = brightness_chromaticity_distortion(0.6 * plate, model)  # a shadow: darker, same chromaticity
    assert np.allclose(alpha, 0.6, atol=0.02) and (cd / model.cd_rms).max() < tau_cd


def test_shadow_is_background_but_a_coloured_object_is_not(plate):
    rng = np.random.default_rng(3)
    model = background_model([noisy(plate, rng) for _ in range(6)])
    image = plate.copy()
    image[:, :40] *= 0.6  # a cast shadow over the left half
    truth = np.zeros(plate.shape[:2], bool)
    truth[20:60, 30:50] = True  # a skin-coloured object straddling the shadow edge
    image[truth] = (200, 150, 120)
    image[20:60, 30:40] *= 0.6
    raw = foreground_pixels(noisy(image, rng), model)
    assert mask_iou(raw, truth) > 0.97
    seg = segment_silhouette(noisy(image, rng), model)
    assert mask_iou(seg, truth) > 0.99
    strict = foreground_pixels(noisy(image, rng), model, SegmentationParams(shadows_are_background=False))
    assert strict[:, :20].mean() > 0.9  # without shadow tolerance the shadow becomes foreground


def test_single_background_frame_and_size_mismatch(plate):
    rng = np.random.default_rng(4)
    model = background_model([noisy(plate, rng)])
    truth = np.zeros(plate.shape[:2], bool)
    truth[10:50, 10:30] = True
    image = plate.copy()
    image[truth] = (30, 160, 60)
    assert mask_iou(segment_silhouette(noisy(image, rng), model), truth) > 0.99
    with pytest.raises(ValueError, match="80x80"):
        brightness_chromaticity_distortion(np.zeros((40, 80, 3)), model)


def test_background_subtraction_reaches_iou_098_on_synthetic_session(small_synth_session, tmp_path):
    """Acceptance (issue 3): segmentation of noisy synthetic renders against the GT masks, IoU >= 0.98."""
    import shutil

    from bodystudio.capture.session import open_session

    path = tmp_path / "s"
    shutil.copytree(small_synth_session, path)
    s = open_session(path)
    assert s.metadata["noise_std"] > 0
    before = silhouette_scores(open_session(path))
    assert before.iou_mean == 1.0  # synthetic sessions start with the ground-truth masks
    report = segment_session(path)
    print("silhouette IoU", json.dumps(report.to_dict()))
    assert silhouette_scores(open_session(path)).to_dict() == report.to_dict()
    assert report.n_masks == len(s.camera_names) * len(s)
    assert report.iou_mean >= 0.98 and report.iou_min >= 0.97
    s = open_session(path)
    s.verify()
    f = s.frame(s.frame_ids[-1])
    cam = s.camera_names[0]
    assert mask_iou(f.masks[cam], f.gt_masks[cam]) >= 0.97  # the written masks are the segmented ones
    assert report.iou_mean < 1.0  # the masks are segmented, not the ground truth copied


@pytest.mark.slow
def test_default_studio_end_to_end_through_the_cli(tmp_path, capsys):
    """The rapid-skin studio (10 cameras, 640x480, Kinect v2, walk) from the CLI, then silhouettes: IoU >= 0.98."""
    from bodystudio.cli.main import main

    out = tmp_path / "studio"
    assert main(["synth", "session", str(out), "--frames", "4", "--motion", "walk"]) == 0
    capsys.readouterr()
    assert main(["capture", "silhouettes", str(out)]) == 0
    report = json.loads(capsys.readouterr().out)
    print("default studio silhouette IoU", report["iou_mean"], report["iou_min"])
    assert report["n_masks"] == 40 and report["iou_mean"] >= 0.98 and report["iou_min"] >= 0.97
    assert main(["capture", "verify", str(out)]) == 0
    capsys.readouterr()
    assert main(["eval", "silhouettes", str(out)]) == 0
    assert json.loads(capsys.readouterr().out)["iou_mean"] == report["iou_mean"]


def test_silhouettes_killed_midway_leave_the_previous_masks(small_synth_session, tmp_path):
    """SIGKILL `segment_session` halfway: the session still opens with its previous (ground-truth) masks,
    the interrupted write is reported, and recovery discards it."""
    import os
    import shutil
    import signal
    import subprocess
    import sys
    import textwrap
    import time

    from bodystudio.capture.session import open_session, recover_session

    path = tmp_path / "s"
    shutil.copytree(small_synth_session, path)
    script = textwrap.dedent(f"""
        import time
        import bodystudio.capture.silhouettes as sil
        real = sil.segment_silhouette
        def slow(*args, **kwargs):
            time.sleep(0.3)
            return real(*args, **kwargs)
        sil.segment_silhouette = slow
        sil.segment_session({str(path)!r})
    """)
    proc = subprocess.Popen([sys.executable, "-c", script], cwd=os.getcwd())
    staged = path / ".staging" / "cam_01" / "mask" / "00000.png"
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and not staged.exists():
            time.sleep(0.05)
        assert proc.poll() is None, "segmentation finished before it could be killed"
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    s = open_session(path)
    assert s.interrupted_write is not None
    s.verify()
    for frame in s:
        for cam in s.camera_names:
            assert np.array_equal(frame.masks[cam], frame.gt_masks[cam])  # the previous state
    assert "discarded" in recover_session(path)
    assert open_session(path).interrupted_write is None
