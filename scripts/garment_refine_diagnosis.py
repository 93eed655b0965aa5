"""Where the real fit's garment_iou goes: the §7 diagnosis of docs/garment.md (issue 13, gar13b).

    python scripts/garment_refine_diagnosis.py --work W --subjects 21 37 [--true-shape]

W/sN is a benchmark session (``bodystudio synth garment W/sN --subject-seed N --frames 10 --seed N --motion M``,
480x640; the benchmark's motions: 21 walk, 37 arm_flex, 3 walk) and W/fitN its real §4 fit (``bodystudio garment
fit W/sN --stature S --out W/fitN``, S the session's ``gt/phenotype.json`` stature). For each §7 configuration of
``benchmarks/bench_garment.py`` the session's target garment is rendered on the fitted body and refined exactly as
``garment render`` does (``refine_and_composite``), and one JSON line per configuration gives the mean and
per-frame garment_iou and the error pixels split into *missing* (true garment not shown), *extra on background*
and *extra on the body* (the new garment over the actor's skin), each by the body part of the nearest TRUE
posed vertex (arms = upper arms and shoulders, forearms = forearms and hands, collar = neck/head/upper spine,
hem = pelvis/thighs/lower spine, torso). ``--true-shape``
adds the same rows for the TRUE shape (gt/phenotype.json, the fit's 2k template) posed with the fitted pose,
camera, lights and albedo: what the refinement would give with the fit's shape error removed; ``--true-fit`` the
session's ground truth as the fit (true shape, pose, camera, lights; ``composite.ground_truth_fit``): what the §7
steps themselves lose.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path

import numpy as np

CONFIGS = {"full": {}, "no_flow": {"flow": False}, "no_rbf": {"rbf": False}, "no_depth": {"depth": False},
           "no_hem": {"hem": False}, "unrefined": {"flow": False, "rbf": False, "hem": False}}
PARTS = ("arms", "forearms", "collar", "hem", "torso")


def body_part(bone: str) -> str:
    """The region of an error pixel by the bone of the nearest TRUE vertex: ``arms`` the upper arms and shoulders
    (where the sleeves end), ``forearms`` the forearms and hands (bare; an error there is the garment drawn over
    an arm in front of it, or a sleeve far too long), ``collar``, ``hem``, ``torso``."""
    if any(k in bone for k in ("lowerarm", "hand", "thumb", "index", "middle", "ring", "pinky")):
        return "forearms"
    if any(k in bone for k in ("upperarm", "clavicle")):
        return "arms"
    if any(k in bone for k in ("neck", "head", "spine_03")):
        return "collar"
    if any(k in bone for k in ("pelvis", "thigh", "spine_01")):
        return "hem"
    return "torso"


def main() -> None:
    from scipy.spatial import cKDTree

    from bodystudio.body import build_body
    from bodystudio.body.phenotype import Phenotype
    from bodystudio.capture.session import LAYER_GARMENT, open_session
    from bodystudio.garment.composite import default_lighting, refine_and_composite
    from bodystudio.garment.fitfile import MIN_FRAME_IOU, load_garment_fit
    from bodystudio.garment.garments import dress, pose_garment
    from bodystudio.garment.render import render_garment_layer

    ap = argparse.ArgumentParser()
    ap.add_argument("--work", type=Path, required=True)
    ap.add_argument("--subjects", nargs="+", default=["21", "37"])
    ap.add_argument("--configs", nargs="+", default=list(CONFIGS))
    ap.add_argument("--true-shape", action="store_true")
    ap.add_argument("--true-fit", action="store_true",
                    help="also the session's ground truth as the fit (composite.ground_truth_fit): what the §7 steps "
                         "lose with a perfect §4-5 fit")
    args = ap.parse_args()
    for subject in args.subjects:
        session = open_session(args.work / f"s{subject}")
        fitted = load_garment_fit(args.work / f"fit{subject}")
        cam = session.camera_names[0]
        truth_subject = session.gt_subject
        true_body = build_body(Phenotype.from_dict(truth_subject["phenotype"]), truth_subject["local"],
                               resolution=truth_subject["template"])
        bones = np.asarray(true_body.skeleton.names if hasattr(true_body.skeleton, "names")
                           else true_body.skeleton.bone_names, dtype=object)
        part = np.array([body_part(b) for b in bones[true_body.weights.argmax(1)]])
        fits = {"fitted": fitted}
        if args.true_shape:
            fits["true shape, fitted pose"] = replace(fitted, phenotype=dict(truth_subject["phenotype"]),
                                                      local=dict(truth_subject["local"]))
        if args.true_fit:
            from bodystudio.garment.composite import ground_truth_fit

            fits["true fit"] = ground_truth_fit(session)
        target = session.gt_garment["target"]
        for fit_name, fit in fits.items():
            body = fit.body()
            cloth = dress(body, target["name"], target["pattern"], session.gt_garment["texture_size"], target["seed"])
            lighting = fit.lighting if fit.lighting is not None else default_lighting(fit.camera)
            layers = []
            for i in range(len(fit.frame_ids)):
                pose = fit.pose(i)
                V, _ = body.pose(pose)
                layers.append(render_garment_layer(V, body.faces, cloth, pose_garment(cloth, body, pose), fit.camera,
                                                   lighting, fit.albedo if fit_name == "true fit" else fitted.albedo,
                                                   True))
            for name in args.configs:
                ious, errors = [], {k: dict.fromkeys(PARTS, 0) for k in ("missing", "extra_background", "extra_body")}
                for i, fid in enumerate(fit.frame_ids):
                    frame = session.frame(int(fid))
                    labels = frame.gt_target_layers[cam]
                    truth = labels == LAYER_GARMENT
                    shown = np.zeros_like(truth)
                    if fit.silhouette_iou[i] >= MIN_FRAME_IOU:
                        shown = refine_and_composite(frame.images[cam], fit.masks[i], layers[i],
                                                     **CONFIGS[name]).garment_mask
                    ious.append(float((shown & truth).sum() / (shown | truth).sum()))
                    nearest = cKDTree(session.cameras[cam].project(frame.gt_mesh.vertices))
                    extra = shown & ~truth
                    for kind, wrong in (("missing", truth & ~shown), ("extra_background", extra & (labels == 0)),
                                        ("extra_body", extra & (labels == 1))):
                        ys, xs = np.nonzero(wrong)
                        if len(xs):
                            parts = part[nearest.query(np.column_stack([xs, ys]))[1]]
                            for p in PARTS:
                                errors[kind][p] += int((parts == p).sum())
                print(json.dumps({"subject": subject, "fit": fit_name, "refinement": name,
                                  "garment_iou": round(float(np.mean(ious)), 4),
                                  "per_frame": [round(v, 3) for v in ious], "error_px": errors}), flush=True)


if __name__ == "__main__":
    main()
