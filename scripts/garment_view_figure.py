"""Figure of docs/garment.md's viewer section: ``bodystudio view FIT --screenshot`` of a garment fit folder (the
fitted body, the garment, the estimated and true light arrows, the before/after strip), and the report of the
same folder, with timings.

Usage: python scripts/garment_view_figure.py [--out docs] [--keep DIR]   (about a minute; writes
garment_view.png; development subject 11, 6 frames at 240x320, the perturbed oracle fit of
docs/garment.md's render section, lights turned 10 deg)
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path


def view_figure(out: Path, work: Path, subject: int = 11, frames: int = 6) -> None:
    from bodystudio.cli.main import main
    from bodystudio.garment.composite import ground_truth_fit, perturbed_fit, render_garment_video
    from bodystudio.garment.fitfile import save_garment_fit
    from bodystudio.garment.synthetic import synth_garment_session
    from bodystudio.viewer.report import write_report

    s = synth_garment_session(work / "session", subject_seed=subject, n_frames=frames, resolution=(240, 320),
                              template="2k", seed=2)
    save_garment_fit(work / "fit", perturbed_fit(ground_truth_fit(s), seed=0), "scripts/garment_view_figure.py")
    target = s.gt_garment["target"]
    render_garment_video(work / "fit", target["name"], target["pattern"], None, seed=target["seed"],
                         texture_size=s.gt_garment["texture_size"], min_frame_iou=0.0)
    t0 = time.perf_counter()
    assert main(["view", str(work / "fit"), "--frame", "3", "--screenshot", str(out / "garment_view.png")]) == 0
    t1 = time.perf_counter()
    result = write_report(work, work / "report.html")
    t2 = time.perf_counter()
    size = (work / "report.html").stat().st_size / 1e6
    print(f"view --screenshot {t1 - t0:.1f} s; report {t2 - t1:.1f} s, {size:.1f} MB, "
          f"{len(result.garments[0].strips)} strips, notes {result.garments[0].notes}")
    scores = result.garments[0].scores
    print({k: round(scores[k], 3) for k in ("light_dir_err_deg", "garment_iou", "psnr_person") if k in scores})


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("docs"))
    parser.add_argument("--keep", type=Path, default=None, help="keep the session, fit and report in this folder")
    args = parser.parse_args()
    if args.keep is not None:
        args.keep.mkdir(parents=True, exist_ok=True)
        view_figure(args.out, args.keep)
    else:
        with tempfile.TemporaryDirectory() as tmp:
            view_figure(args.out, Path(tmp))
