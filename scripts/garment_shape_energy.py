"""Does Eq. 1's shape energy prefer the TRUE shape? The shape figure of docs/garment.md (issue 13).

    python scripts/garment_shape_energy.py --work W [--subjects 3 21] [--motion arm_flex]

On the cached fits of scripts/garment_light_figures.py (WORK/sN session, WORK/fitN fit): for the
stature-matched start, the fitted shape and the TRUE shape (gt/phenotype.json, same 2k template), the 4
reference frames' poses are re-solved for that shape (Eq. 4 with the height term, three starts of 20
evaluations, the best one 20 more, the fit's assumed camera), then ``shape_energy`` (Eq. 1 in the fit's
distance form + stature), the shape prior of the local modifiers (``E_prior``, ``shape_prior_energy``; the fit
minimises the sum) and the silhouette IoU are printed, one JSON line per shape. If the truth does not
have the lowest energy, no optimiser over this energy can get closer to it than the fit does.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np


def main() -> None:
    from bodystudio.body import build_body
    from bodystudio.body.phenotype import Phenotype
    from bodystudio.capture.session import open_session
    from bodystudio.garment import fit as gf
    from bodystudio.garment.evaluate import shape_error_mm
    from bodystudio.garment.fitfile import load_garment_fit

    ap = argparse.ArgumentParser()
    ap.add_argument("--work", type=Path, required=True)
    ap.add_argument("--subjects", type=int, nargs="+", default=[3, 21])
    ap.add_argument("--motion", default="walk")
    args = ap.parse_args()
    tag = "" if args.motion == "walk" else f"_{args.motion}"
    for subject in args.subjects:
        s = open_session(args.work / f"s{subject}{tag}")
        fit = load_garment_fit(args.work / f"fit{subject}{tag}")
        truth, stature = s.gt_subject, s.gt_subject["stature_m"]
        cam, masks = fit.camera, fit.masks
        ref = np.unique(np.linspace(0, len(masks) - 1, 4).round().astype(int))
        targets = [gf.silhouette_target(masks[i]) for i in ref]
        start = gf._stature_matched_height(Phenotype().to_dict(), {}, stature, fit.template)
        modifiers = {"start": {}, "fitted": fit.local, "true": truth.get("local", {})}
        bodies = {"start": build_body(Phenotype.from_dict(start), {}, resolution=fit.template),
                  "fitted": fit.body(),
                  "true": build_body(Phenotype.from_dict(truth["phenotype"]), modifiers["true"],
                                     resolution=fit.template)}
        for name, body in bodies.items():
            t = time.perf_counter()
            space, spheres = gf.pose_space(body), gf.penetration_spheres(body)
            xs = []
            for target in targets:
                problem = gf.PoseProblem(space, cam, target, spheres, with_height=True)
                starts = [gf.fit_frame_pose(x, problem, max_nfev=20) for x in gf.initial_placements(space, cam, target)]
                x = min(starts, key=lambda x, p=problem: float(np.sum(gf.pose_residuals(x, p) ** 2)))
                xs.append(gf.fit_frame_pose(x, problem, max_nfev=20))
            energy = gf.shape_energy(body, xs, cam, targets, stature, space.base)
            iou = np.mean([gf.silhouette_iou(body.pose(space.pose(x))[0], body.faces, cam, masks[i])
                           for x, i in zip(xs, ref, strict=True)])
            err = shape_error_mm(fit, body, truth)
            print(json.dumps({"subject": subject, "shape": name, "shape_err_mm": round(err, 2),
                              "E_shape": round(energy, 4),
                              "E_prior": round(gf.shape_prior_energy(modifiers[name]), 4), "iou": round(float(iou), 4),
                              "wall_s": round(time.perf_counter() - t)}), flush=True)


if __name__ == "__main__":
    main()
