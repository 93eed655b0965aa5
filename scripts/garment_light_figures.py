"""The lighting figures of docs/garment.md (issue 13): §5 re-run on cached fits of hidden subjects, one JSON line
per subject and variant.

    python scripts/garment_light_figures.py --work /tmp/glight [--subjects 3 11 21] [--frames 0:12] [--motion walk]

Each subject: ``synth garment`` (240x320, 2k, ``--motion``, 30 frames) and ``fit_garment_video`` with the true stature
on ``--frames`` (as scripts/garment_fit_figures.py), cached in WORK/fitN once (about 5 min each); then
``estimate_appearance`` on the fitted geometry and on the TRUE geometry (the session's posed meshes and camera)
in each variant, scored like ``eval garment`` (``light_dir_err_deg``, ``light_brightest_dir_err_deg``,
``albedo_err``). Variants: ``grouped`` (chromaticity materials) and ``sparsity`` (the L1 penalty) on/off.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np


def score(lighting, albedo, camera, session) -> dict:
    from bodystudio.garment.evaluate import _angle_deg, principal_light_direction
    from bodystudio.garment.lighting import dominant_light_direction

    gt = session.gt_lighting
    cam_gt = session.cameras[session.camera_names[0]]
    gd, gc = np.asarray(gt["directions"], float), np.asarray(gt["colors"], float)
    out = {}
    for key, fn in (("light_dir_err_deg", principal_light_direction),
                    ("light_brightest_dir_err_deg", dominant_light_direction)):
        out[key] = round(_angle_deg(camera.R @ fn(lighting.directions, lighting.colors), cam_gt.R @ fn(gd, gc)), 2)
    truth = session.gt_appearance_albedo
    k = (albedo * truth).sum(0) / np.maximum((albedo * albedo).sum(0), 1e-12)
    out["albedo_err"] = round(float(np.mean(np.abs(albedo * k - truth))), 4)
    out["ambient"] = round(float(lighting.ambient.mean()), 3)
    out["n_lights"] = len(lighting.colors)
    return out


def main() -> None:
    from bodystudio.capture.session import open_session
    from bodystudio.garment.fit import LIGHT_SPARSITY, estimate_appearance, fit_garment_video
    from bodystudio.garment.fitfile import load_garment_fit
    from bodystudio.garment.synthetic import synth_garment_session

    ap = argparse.ArgumentParser()
    ap.add_argument("--work", type=Path, required=True)
    ap.add_argument("--subjects", type=int, nargs="+", default=[3, 11, 21])
    ap.add_argument("--frames", default="0:12")
    ap.add_argument("--motion", default="walk")
    args = ap.parse_args()
    tag = "" if args.motion == "walk" else f"_{args.motion}"
    variants = {"before (per-vertex, no sparsity)": dict(grouped=False, sparsity=0.0, iterations=3),
                "sparsity only": dict(grouped=False, sparsity=LIGHT_SPARSITY),
                "grouped only": dict(grouped=True, sparsity=0.0),
                "after (grouped + sparsity)": dict(grouped=True, sparsity=LIGHT_SPARSITY)}
    for subject in args.subjects:
        path, fit_dir = args.work / f"s{subject}{tag}", args.work / f"fit{subject}{tag}"
        if not path.exists():
            synth_garment_session(path, subject_seed=subject, n_frames=30, resolution=(240, 320), template="2k",
                                  texture_size=128, motion=args.motion)
        s = open_session(path)
        if not fit_dir.exists():
            fit_garment_video(path, s.gt_subject["stature_m"], fit_dir, frames=args.frames)
        fit = load_garment_fit(fit_dir)
        body = fit.body()
        cam = s.camera_names[0]
        images = np.stack([s.frame(int(f)).images[cam] for f in fit.frame_ids])
        geometries = {
            "fitted": ([body.pose(fit.pose(i))[0] for i in range(len(fit.frame_ids))], body.faces, fit.camera,
                       fit.masks),
            "true": ([s.frame(int(f)).gt_mesh.vertices for f in fit.frame_ids], s.frame(0).gt_mesh.faces,
                     s.cameras[cam], np.stack([s.frame(int(f)).masks[cam] > 0 for f in fit.frame_ids]))}
        for geometry, (posed, F, camera, masks) in geometries.items():
            for name, kw in variants.items():
                t = time.perf_counter()
                albedo, lighting = estimate_appearance(images, masks, posed, F, camera, **kw)
                row = {"subject": subject, "motion": args.motion, "geometry": geometry, "variant": name}
                row.update(score(lighting, albedo, camera, s), wall_s=round(time.perf_counter() - t, 1))
                print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
