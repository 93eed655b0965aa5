"""The hem matte when the new garment is not the worn one's cut (issue 13, gar13e; docs/garment.md, *The hem matte*).

    python scripts/garment_hem_other_cut.py --work W --subjects 21 3 --garments longsleeve tights

W/sN is a benchmark session (the actor wears a plain T-shirt) and W/fitN its real §4 fit (as for
``scripts/garment_refine_diagnosis.py``). For each other garment the truth is that garment composited on the
session's TRUE fit (``composite.ground_truth_fit``) without the hem matte (for the worn cut that composite is the
true target layer, garment_iou 1.000); the kept fit's full §7 refinement is scored against it with the hem matte off
and on. One JSON line per subject and garment.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def garment_layers(fit, garment: str, pattern: str, texture_size: int, seed: int) -> list:
    """Each frame's garment layer (§6) of ``garment`` on the fit's body, under the fit's lights, with its albedo."""
    from bodystudio.garment.composite import default_lighting
    from bodystudio.garment.garments import dress, pose_garment
    from bodystudio.garment.render import render_garment_layer

    body = fit.body()
    cloth = dress(body, garment, pattern, texture_size, seed)
    light = fit.lighting if fit.lighting is not None else default_lighting(fit.camera)
    out = []
    for i in range(len(fit.frame_ids)):
        pose = fit.pose(i)
        V, _ = body.pose(pose)
        out.append(render_garment_layer(V, body.faces, cloth, pose_garment(cloth, body, pose), fit.camera, light,
                                        fit.albedo, True))
    return out


def main() -> None:
    from bodystudio.capture.session import open_session
    from bodystudio.garment.composite import ground_truth_fit, refine_and_composite
    from bodystudio.garment.fitfile import load_garment_fit

    ap = argparse.ArgumentParser()
    ap.add_argument("--work", type=Path, required=True)
    ap.add_argument("--subjects", nargs="+", default=["21", "3"])
    ap.add_argument("--garments", nargs="+", default=["longsleeve", "tights"])
    args = ap.parse_args()
    for subject in args.subjects:
        session = open_session(args.work / f"s{subject}")
        fitted = load_garment_fit(args.work / f"fit{subject}")
        truth_fit = ground_truth_fit(session)
        cam = session.camera_names[0]
        target = session.gt_garment["target"]
        for garment in args.garments:
            cut = (garment, target["pattern"], session.gt_garment["texture_size"], target["seed"])
            true_layers, fit_layers = garment_layers(truth_fit, *cut), garment_layers(fitted, *cut)
            ious = {"off": [], "on": []}
            applied = 0
            for i, fid in enumerate(fitted.frame_ids):
                image = session.frame(int(fid)).images[cam]
                truth = refine_and_composite(image, truth_fit.masks[i], true_layers[i], hem=False).garment_mask
                for key, hem in (("off", False), ("on", True)):
                    r = refine_and_composite(image, fitted.masks[i], fit_layers[i], hem=hem)
                    applied += int(hem and r.hem_applied)
                    shown = r.garment_mask
                    ious[key].append(float((shown & truth).sum() / max(int((shown | truth).sum()), 1)))
            print(json.dumps({"subject": subject, "garment": garment, "hem_applied_frames": applied,
                              **{k: round(float(np.mean(v)), 4) for k, v in ious.items()},
                              "per_frame_on_minus_off": [round(a - b, 3) for a, b in zip(ious["on"], ious["off"],
                                                                                         strict=True)]}), flush=True)


if __name__ == "__main__":
    main()
