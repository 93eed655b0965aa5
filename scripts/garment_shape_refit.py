"""The fit's shape and pose refinements (steps 4b-4c of ``garment fit``) applied to cached fits (issue 13, gar13c,
gar13d; docs/garment.md).

    python scripts/garment_shape_refit.py --work W --subjects 37 21 3 --name refined [--clothing-mm 4]
                                          [--no-pose-refinement]

W/sN is a session and W/fitN its §4 fit written before the refinement existed (``garment fit ... --no-shape-refinement``
gives the same). For each subject the shape is refined against every frame's silhouette with the fit's poses held
then (step 4c, unless ``--no-pose-refinement``) every pose is refined on the refined shape,
and §5's appearance is re-estimated on the refined body (``garment.fit.refine_garment_fit``, what ``garment fit``
does after its pose step), and the result is written as the fit folder W/<name>N; one JSON line per subject gives
``eval garment``'s fit scores and the seconds taken. Score the render with
``python scripts/garment_refine_diagnosis.py --work W2`` on a folder W2 holding sN and fitN -> W/<name>N.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path


def main() -> None:
    from bodystudio.capture.session import open_session
    from bodystudio.garment.evaluate import fit_errors
    from bodystudio.garment.fit import refine_garment_fit
    from bodystudio.garment.fitfile import load_garment_fit, save_garment_fit
    from bodystudio.garment.person import person_frames
    from bodystudio.garment.shape_refine import CLOTHING_ALLOWANCE_M

    ap = argparse.ArgumentParser()
    ap.add_argument("--work", type=Path, required=True)
    ap.add_argument("--subjects", nargs="+", default=["37", "21", "3"])
    ap.add_argument("--name", default="refined")
    ap.add_argument("--clothing-mm", type=float, default=1e3 * CLOTHING_ALLOWANCE_M)
    ap.add_argument("--no-pose-refinement", action="store_true", help="step 4b only (gar13c's fits)")
    args = ap.parse_args()
    for subject in args.subjects:
        fit = load_garment_fit(args.work / f"fit{subject}")
        session = open_session(args.work / f"s{subject}")
        frames = person_frames(str(args.work / f"s{subject}"), None, None)
        t0 = time.perf_counter()
        refined = refine_garment_fit(fit, frames.images, session.gt_subject["stature_m"], args.clothing_mm / 1e3,
                                     pose_refinement=not args.no_pose_refinement)
        seconds = time.perf_counter() - t0
        save_garment_fit(args.work / f"{args.name}{subject}", refined, "scripts/garment_shape_refit.py")
        scores = fit_errors(refined, session)
        print(json.dumps({"subject": subject, "clothing_mm": args.clothing_mm, "seconds": round(seconds, 1),
                          **{k: scores[k] for k in ("stature_err_mm", "shape_err_mm", "silhouette_iou",
                                                    "joint_err_px", "joint_err_mm", "light_dir_err_deg",
                                                    "albedo_err")}}), flush=True)


if __name__ == "__main__":
    main()
