"""``capture import --masks`` with the masks a real matting tool or camera app exports (adversarial pass 5).

Before: every non-zero pixel was subject, so a JPEG mask's ringing around the silhouette (values 1-30) and a soft
matte edge became subject: a 0/255 ellipse at JPEG quality 90 came back with IoU 0.980, exit 0. Now the subject is the
pixels above half the mask's brightest value (a 0/1 label image keeps its ones)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from tests.reliability.conftest import assert_clean_error, run_inprocess


def _ellipse(w: int, h: int) -> np.ndarray:
    yy, xx = np.mgrid[:h, :w]
    return (xx - w / 2) ** 2 / (0.25 * w) ** 2 + (yy - h / 2) ** 2 / (0.4 * h) ** 2 < 1


@pytest.mark.parametrize(("kind", "min_iou"), [("jpeg", 0.999), ("soft_edge", 0.99), ("labels_0_1", 1.0)])
def test_imported_masks_keep_the_silhouette(studio, tmp_path, capfd, kind, min_iou):
    from bodystudio.capture.session import open_session

    cams = sorted(p.name for p in studio.images.iterdir())
    h, w = cv2.imread(str(next((studio.images / cams[0]).iterdir()))).shape[:2]
    truth = _ellipse(w, h)
    for cam in cams:
        (tmp_path / "masks" / cam).mkdir(parents=True)
        for f in sorted((studio.images / cam).iterdir()):
            if kind == "jpeg":
                cv2.imwrite(str(tmp_path / "masks" / cam / f"{f.stem}.jpg"), truth.astype(np.uint8) * 255,
                            [cv2.IMWRITE_JPEG_QUALITY, 90])
            elif kind == "soft_edge":  # a matte blurred across the edge: 0.5 on the boundary
                soft = cv2.GaussianBlur(truth.astype(np.float32), (0, 0), 2.0)
                cv2.imwrite(str(tmp_path / "masks" / cam / f"{f.stem}.png"), np.rint(soft * 255).astype(np.uint8))
            else:
                cv2.imwrite(str(tmp_path / "masks" / cam / f"{f.stem}.png"), truth.astype(np.uint8))
    out = tmp_path / "S"
    result = run_inprocess(["capture", "import", out, "--cameras", studio.cameras_json, "--images", studio.images,
                            "--masks", tmp_path / "masks"], capfd)
    assert_clean_error(result, 0, "")
    for frame in open_session(out):
        for cam in cams:
            mask = frame.masks[cam]
            assert (mask & truth).sum() / (mask | truth).sum() >= min_iou
