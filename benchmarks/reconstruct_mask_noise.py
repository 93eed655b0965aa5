"""False refusals of reconstruct's self-check (bodystudio/reconstruct/plausibility.py) on clean sessions with
realistic mask noise, and whether the planted faults are still caught under that noise (docs/plausibility.md,
"reconstruct under mask noise").

reconstruct's thresholds were set on the synthetic sessions' ground-truth-like masks (IoU ~0.998 against the
truth). Here the same clean sessions (6 cameras, a 2-frame walk, 2k template, as benchmarks/plausibility_faults.py,
but 640x480 by default: at 320x240 one pixel is ~1 cm on the body) are reconstructed from masks as a studio
makes them:

* ``segmented``: the session's colour frames segmented by background subtraction (capture/silhouettes.py,
  Horprasert against the empty-studio frames), the most honest source;
* ``jitter``: each mask's outline moved by a smooth random field of 1-3 px standard deviation;
* ``shadow``: a floor shadow merged into the mask (an ellipse under the feet, 1.5x the body's width);
* ``holes``: 6-12 small holes (radius 2-4 px) punched in each mask;
* ``limb``: in the first frame, one camera's arm missing (the mask's outer fifth on one side at arm height);
* ``all``: jitter + shadow + holes + limb on the segmented masks;

then ``all`` with cam_02 moved 5 cm / 3 deg and with cam_01 / cam_03's masks swapped (still caught?).

    python -m benchmarks.reconstruct_mask_noise [--subjects 23,24,25] [--cache DIR]
"""

from __future__ import annotations

import argparse
import json
import shutil
import tempfile
from pathlib import Path

import numpy as np

from bodystudio.capture.faults import (
    mask_all_noise,
    mask_holes,
    mask_jitter,
    mask_limb_lost,
    mask_shadow,
    rewrite_masks,
)


def mask_iou_to_truth(S: Path) -> float:
    from bodystudio.capture.session import open_session
    from bodystudio.capture.silhouettes import mask_iou

    session = open_session(S)
    ious = []
    for frame in session:
        for cam, truth in frame.gt_masks.items():
            ious.append(mask_iou(frame.masks[cam], truth))
    return float(np.mean(ious))


def run(S: Path) -> dict:
    from bodystudio.reconstruct.sequence import reconstruct_session

    summary = reconstruct_session(S, template="2k", constraints=("silhouette",), accept_implausible=True)
    verdict = json.loads((S / "reconstruct" / "run.json").read_text())["plausibility"]
    return {"median_mm": summary.get("median_mm"), "p90_mm": summary.get("p90_mm"), "verdict": verdict}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--subjects", default="23,24,25")
    parser.add_argument("--cache", type=Path, default=None)
    parser.add_argument("--resolution", default="640x480")
    parser.add_argument("--variants", default="truth,segmented,jitter,shadow,holes,limb,all,all+moved,all+swapped")
    args = parser.parse_args(argv)
    from bodystudio.capture import faults
    from bodystudio.capture.silhouettes import segment_session
    from bodystudio.capture.synth import synth_session

    cache = args.cache or Path(tempfile.mkdtemp(prefix="masknoise-"))
    cache.mkdir(parents=True, exist_ok=True)
    noises = {"jitter": mask_jitter, "shadow": mask_shadow, "holes": mask_holes, "limb": mask_limb_lost,
              "all": mask_all_noise}
    results = {}
    for subject in (int(s) for s in args.subjects.split(",")):
        clean = cache / f"rec{subject}_6_{args.resolution}"
        if not (clean / "session.json").exists():
            synth_session(clean, n_cameras=6, n_frames=2, motion="walk", subject_seed=subject,
                          resolution=tuple(int(x) for x in args.resolution.split("x")))
        segmented = cache / f"rec{subject}_6_{args.resolution}_segmented_base"
        if not (segmented / "session.json").exists():
            shutil.copytree(clean, segmented, ignore=shutil.ignore_patterns("reconstruct"))
            segment_session(segmented)
        for variant in args.variants.split(","):
            S = cache / f"rec{subject}_6_{args.resolution}_{variant}"
            shutil.rmtree(S, ignore_errors=True)
            src = clean if variant in ("truth", "jitter", "shadow", "holes", "limb") else segmented
            shutil.copytree(src, S, ignore=shutil.ignore_patterns("reconstruct"))
            base = variant.split("+")[0]
            if base in noises:
                rewrite_masks(S, noises[base])
            if variant.endswith("+moved"):
                faults.bump_camera(S)
            if variant.endswith("+swapped"):
                faults.swap_masks(S)
            r = run(S)
            r["mask_iou_to_truth"] = mask_iou_to_truth(S)
            v = r["verdict"]
            results[f"{subject} {args.resolution} {variant}"] = r
            iou, coh = v.get("camera_iou", {}), v.get("camera_coherence", {}) or {"-": float("nan")}
            said = ("REFUSED " + v["problems"][0][:90] if v["problems"] else
                    "warn " + v["warnings"][0][:60] if v["warnings"] else "ok")
            print(f"{subject} {args.resolution} {variant}: masks IoU {r['mask_iou_to_truth']:.3f} | "
                  f"fit median {r['median_mm']} mm | "
                  f"IoU {min(iou.values()):.2f}..{max(iou.values()):.2f} | coherence "
                  f"{min(coh.values()):.2f}..{max(coh.values()):.2f} | {said}", flush=True)
    (cache / f"mask_noise_{args.resolution}.json").write_text(json.dumps(results, indent=1, default=str))


if __name__ == "__main__":
    main()
