"""Session I/O and background subtraction: synthetic session writing, lazy frame reads, segmentation.

Accuracy (silhouette IoU against the ground-truth masks) is reported beside the timings, measured on
the same session.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

from benchmarks.timing import markdown_table, median_seconds


def run(quick: bool = False) -> str:
    from bodystudio.capture.session import open_session
    from bodystudio.capture.silhouettes import background_model, segment_session, segment_silhouette
    from bodystudio.capture.synth import synth_session

    n_cameras, n_frames = (4, 2) if quick else (10, 4)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "session"
        t0 = time.perf_counter()
        synth_session(path, n_cameras=n_cameras, n_frames=n_frames, motion="walk", kinect=None,
                      resolution=(640, 480))
        t_synth = time.perf_counter() - t0
        rows.append([f"synth session, {n_cameras} cameras 640x480, no Kinect (incl. body build)",
                     f"{t_synth / n_frames:.3g} s/frame"])
        session = open_session(path)

        def read_frame():
            frame = session.frame(session.frame_ids[0])
            for cam in session.camera_names:
                frame.images[cam]
                frame.masks[cam]

        t_read = median_seconds(read_frame)
        rows.append([f"read one frame (RGB + mask of {n_cameras} cameras, sha256 checked)",
                     f"{1000 * t_read:.3g} ms"])
        cam = session.camera_names[0]
        model = background_model(session.background_frames(cam))
        image = session.frame(session.frame_ids[0]).images[cam]
        t_seg = median_seconds(lambda: segment_silhouette(image, model))
        rows.append(["segment one 640x480 image (Horprasert + components + holes)", f"{1000 * t_seg:.3g} ms"])
        t0 = time.perf_counter()
        report = segment_session(path)
        t_all = time.perf_counter() - t0
        rows.append([f"segment_session ({report.n_masks} masks, write + manifest update)",
                     f"{t_all:.3g} s"])
        rows.append(["silhouette IoU vs ground truth (mean / min)",
                     f"{report.iou_mean:.4f} / {report.iou_min:.4f}"])
        t_verify = median_seconds(lambda: open_session(path).verify(), repeats=5, warmup=0)
        rows.append([f"verify all {len(session.files)} checksums", f"{1000 * t_verify:.3g} ms"])
    return "## Capture sessions and silhouettes\n\n" + markdown_table(["step", "figure"], rows) + "\n"
