"""The garment-fit figures of docs/garment.md: hidden subjects fitted and scored, one JSON line each.

    python scripts/garment_fit_figures.py --work /tmp/gfit-figures [--subjects 3 11 21] [--frames 0:12]
        [--focal-px 487.9 341.5]

Each subject: ``synth garment`` (240x320, 2k, walk, 30 frames), ``fit_garment_video`` with the true stature
on ``--frames``, ``fit_errors``; with ``--focal-px`` the first subject is fitted again at each focal length.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path


def main() -> None:
    from bodystudio.capture.session import open_session
    from bodystudio.garment.evaluate import fit_errors
    from bodystudio.garment.fit import fit_garment_video
    from bodystudio.garment.synthetic import synth_garment_session

    ap = argparse.ArgumentParser()
    ap.add_argument("--work", type=Path, required=True)
    ap.add_argument("--subjects", type=int, nargs="+", default=[3, 11, 21])
    ap.add_argument("--frames", default="0:12")
    ap.add_argument("--focal-px", type=float, nargs="*", default=[])
    args = ap.parse_args()
    runs = [(s, None) for s in args.subjects] + [(args.subjects[0], f) for f in args.focal_px]
    for subject, focal in runs:
        path = args.work / f"s{subject}"
        if not path.exists():
            synth_garment_session(path, subject_seed=subject, n_frames=30, resolution=(240, 320), template="2k",
                                  texture_size=128)
        s = open_session(path)
        t = time.perf_counter()
        fit = fit_garment_video(path, s.gt_subject["stature_m"], None, frames=args.frames, focal_px=focal)
        scores = fit_errors(fit, s)
        scores.update(subject=subject, focal_px=fit.camera.fx, true_focal_px=s.cameras["cam_00"].fx,
                      wall_s=time.perf_counter() - t)
        print(json.dumps(scores), flush=True)


if __name__ == "__main__":
    main()
