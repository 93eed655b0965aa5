"""Where the real fit's shape is wrong at the garment's hem lines (issue 13, gar13c; docs/garment.md).

    python scripts/garment_shape_diagnosis.py --work W --subjects 21 37 3 [--fit-name fit]

W/sN is a benchmark session and W/<fit-name>N its real §4 fit (as for ``scripts/garment_refine_diagnosis.py``).
Per subject one JSON line:

* ``rest``: the fitted rest body against the TRUE shape on the fit's template (same topology, both standing
  on the floor at the origin): per body region the median signed offset (mm) of the fitted vertices along
  the true normals (+ = the fitted body is thicker), girths (chest / waist / hip, mm, fitted minus true) and
  the heights of the elbow, shoulder, hip and knee joints (mm, fitted minus true);
* ``silhouette``: over every fitted frame, the fitted body (posed with the fitted pose) against the person
  matte: pixels of body outside the matte (``extra``) and of matte the body leaves uncovered (``missing``),
  each by the region of the nearest projected fitted vertex, and the mean IoU;
* ``worn``: the same offsets split into vertices under the actor's worn garment and the bare ones (the
  truth's ``appearance`` albedo differs from the skin albedo where the worn garment covers the body).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

REGIONS = ("upperarm", "lowerarm", "hand", "shoulder", "chest", "belly", "hip", "thigh", "calf", "neck", "head",
           "foot")


def region_of(bone: str) -> str:
    for key, name in (("upperarm", "upperarm"), ("lowerarm", "lowerarm"), ("clavicle", "shoulder"),
                      ("spine_03", "chest"), ("spine_02", "belly"), ("spine_01", "belly"), ("pelvis", "hip"),
                      ("thigh", "thigh"), ("calf", "calf"), ("neck", "neck"), ("head", "head"), ("foot", "foot"),
                      ("ball", "foot")):
        if key in bone:
            return name
    return "hand"


def main() -> None:
    from scipy.spatial import cKDTree

    from bodystudio.body import build_body
    from bodystudio.body.measure import measure_body
    from bodystudio.body.phenotype import Phenotype
    from bodystudio.capture.session import open_session
    from bodystudio.garment.fit import model_silhouette
    from bodystudio.garment.fitfile import load_garment_fit
    from bodystudio.geometry.mesh import vertex_normals

    ap = argparse.ArgumentParser()
    ap.add_argument("--work", type=Path, required=True)
    ap.add_argument("--subjects", nargs="+", default=["21", "37", "3"])
    ap.add_argument("--fit-name", default="fit")
    args = ap.parse_args()
    for subject in args.subjects:
        session = open_session(args.work / f"s{subject}")
        fit = load_garment_fit(args.work / f"{args.fit_name}{subject}")
        truth = session.gt_subject
        fitted = fit.body()
        true = build_body(Phenotype.from_dict(truth["phenotype"]), truth["local"], resolution=fit.template)
        bones = list(true.skeleton.bone_names)
        region = np.array([region_of(bones[b]) for b in true.weights.argmax(1)])
        N = vertex_normals(true.vertices, true.faces)
        offset_mm = 1e3 * np.einsum("ij,ij->i", fitted.vertices - true.vertices, N)
        rest = {r: round(float(np.median(offset_mm[region == r])), 1) for r in REGIONS if (region == r).any()}
        mf, mt = measure_body(fitted), measure_body(true)
        girth = {k: round(1e3 * (mf[k] - mt[k]), 1) for k in ("chest_m", "waist_m", "hip_m", "arm_length_m",
                                                             "leg_length_m", "stature_m")}
        joints = {}
        for j in ("upperarm_l", "lowerarm_l", "hand_l", "thigh_l", "calf_l", "neck_01"):
            i = bones.index(j)
            joints[j] = round(float(1e3 * (fitted.skeleton.heads[i, 1] - true.skeleton.heads[i, 1])), 1)
        worn = {}
        if session.gt_appearance_albedo is not None:  # on the truth's own template: nearest rest vertex
            own = build_body(Phenotype.from_dict(truth["phenotype"]), truth["local"], resolution=truth["template"])
            gap = np.abs(session.gt_appearance_albedo - session.gt_albedo).max(1) > 0.02
            covered = gap[cKDTree(own.vertices).query(true.vertices)[1]]
            worn = {"covered": round(float(np.median(offset_mm[covered])), 1),
                    "bare": round(float(np.median(offset_mm[~covered])), 1)}
        extra = dict.fromkeys(REGIONS, 0)
        missing = dict.fromkeys(REGIONS, 0)
        ious = []
        fregion = np.array([region_of(bones[b]) for b in fitted.weights.argmax(1)])
        for i in range(len(fit.frame_ids)):
            V, _ = fitted.pose(fit.pose(i))
            body = model_silhouette(V, fitted.faces, fit.camera)
            matte = np.asarray(fit.masks[i], bool)
            ious.append(float((body & matte).sum() / max((body | matte).sum(), 1)))
            tree = cKDTree(fit.camera.project(V))
            for kind, wrong in (("extra", body & ~matte), ("missing", matte & ~body)):
                ys, xs = np.nonzero(wrong)
                if len(xs):
                    parts = fregion[tree.query(np.column_stack([xs, ys]))[1]]
                    target = extra if kind == "extra" else missing
                    for r in REGIONS:
                        target[r] += int((parts == r).sum())
        print(json.dumps({"subject": subject, "fit": args.fit_name, "phenotype": {k: round(v, 3) for k, v in
                                                                                   fit.phenotype.items()},
                          "rest_offset_mm": rest, "worn_offset_mm": worn, "measure_mm": girth,
                          "joint_height_mm": joints, "silhouette_iou": round(float(np.mean(ious)), 4),
                          "extra_px": {k: v for k, v in extra.items() if v},
                          "missing_px": {k: v for k, v in missing.items() if v}}), flush=True)


if __name__ == "__main__":
    main()
