"""The fit's shape refinement (step 4b of ``garment fit``) applied to cached fits (issue 13, gar13c; docs/garment.md).

    python scripts/garment_shape_refit.py --work W --subjects 37 21 3 --name refined [--clothing-mm 4]

W/sN is a session and W/fitN its §4 fit written before the refinement existed (``garment fit ... --no-shape-refinement``
gives the same). For each subject the shape is refined against every frame's silhouette with the fit's poses held
(``refine_shape_to_silhouettes``), §5's appearance is re-estimated on the refined body, exactly as ``garment fit``
does after its pose step, and the result is written as the fit folder W/<name>N; one JSON line per subject gives
``eval garment``'s fit scores and the refinement's energies and seconds. Score the render with
``python scripts/garment_refine_diagnosis.py --work W2`` on a folder W2 holding sN and fitN -> W/<name>N.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np


def main() -> None:
    from bodystudio.capture.session import open_session
    from bodystudio.garment.evaluate import fit_errors
    from bodystudio.garment.fit import body_stature, estimate_appearance, silhouette_iou
    from bodystudio.garment.fitfile import load_garment_fit, save_garment_fit
    from bodystudio.garment.person import person_frames
    from bodystudio.garment.shape_refine import CLOTHING_ALLOWANCE_M, REFINE_ITERATIONS, refine_shape_to_silhouettes

    ap = argparse.ArgumentParser()
    ap.add_argument("--work", type=Path, required=True)
    ap.add_argument("--subjects", nargs="+", default=["37", "21", "3"])
    ap.add_argument("--name", default="refined")
    ap.add_argument("--clothing-mm", type=float, default=1e3 * CLOTHING_ALLOWANCE_M)
    ap.add_argument("--iterations", type=int, default=REFINE_ITERATIONS)
    args = ap.parse_args()
    for subject in args.subjects:
        fit = load_garment_fit(args.work / f"fit{subject}")
        session = open_session(args.work / f"s{subject}")
        stature = session.gt_subject["stature_m"]
        poses = [fit.pose(i) for i in range(len(fit.frame_ids))]
        t0 = time.perf_counter()
        r = refine_shape_to_silhouettes(fit.phenotype, fit.local, fit.template, poses, fit.masks, fit.camera, stature,
                                        iterations=args.iterations, allowance_m=args.clothing_mm / 1e3)
        seconds = time.perf_counter() - t0
        refined = replace(fit, phenotype=r.phenotype, local=r.local)
        body = refined.body()
        posed = [body.pose(p)[0] for p in poses]
        ious = np.array([silhouette_iou(V, body.faces, fit.camera, m) for V, m in zip(posed, fit.masks, strict=True)])
        frames = person_frames(str(args.work / f"s{subject}"), None, None)
        albedo, lighting = estimate_appearance(frames.images, frames.masks, posed, body.faces, fit.camera)
        refined = replace(refined, albedo=albedo, lighting=lighting, silhouette_iou=ious, stature_m=body_stature(body))
        save_garment_fit(args.work / f"{args.name}{subject}", refined, "scripts/garment_shape_refit.py")
        scores = fit_errors(refined, session)
        print(json.dumps({"subject": subject, "clothing_mm": args.clothing_mm, "refine_s": round(seconds, 1),
                          "energies": [round(e, 3) for e in r.energies],
                          **{k: scores[k] for k in ("stature_err_mm", "shape_err_mm", "silhouette_iou",
                                                    "light_dir_err_deg", "albedo_err")}}), flush=True)


if __name__ == "__main__":
    main()
