"""The lighting figures of docs/garment.md (issue 13): §5 re-run on cached fits of hidden subjects, one JSON line
per subject and variant.

    python scripts/garment_light_figures.py --work /tmp/glight [--subjects 3 11 21] [--frames 0:12] [--motion walk]
                                            [--normals] [--variants before sparsity grouped after]
                                            [--geometry fitted true]

Each subject: ``synth garment`` (240x320, 2k, ``--motion``, 30 frames) and ``fit_garment_video`` with the true stature
on ``--frames`` (as scripts/garment_fit_figures.py), cached in WORK/fitN once (about 5 min each); then
``estimate_appearance`` on the fitted geometry and on the TRUE geometry (the session's posed meshes and camera)
in each variant, scored like ``eval garment`` (``light_dir_err_deg``, ``light_brightest_dir_err_deg``,
``albedo_err``). Variants: ``grouped`` (chromaticity materials) and ``sparsity`` (the L1 penalty) on/off.
``--normals`` first prints where the fitted geometry is wrong: per body part (the bone of each vertex's largest
skin weight), the angle between the fitted body's normal and the TRUE body's normal seen at the same pixel
(both in their camera's frame; pixels inside both silhouettes, every 2nd fitted frame), median and the share
above 20 deg.
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


PARTS = {"torso": ("pelvis", "spine", "neck", "head", "clavicle"),
         "arms": ("upperarm", "lowerarm", "hand", "thumb", "index", "middle", "ring", "pinky"),
         "legs": ("thigh", "calf", "foot", "ball")}


def pixel_normals(V, F, camera):
    """Per pixel of the rasterised body: its interpolated vertex normal in the camera's frame, and the
    triangle id (-1 off the body)."""
    from bodystudio.capture.render import render, vertex_normals_area_weighted

    res = render(V, F, camera)
    tri = np.clip(res.triangle_id, 0, None)
    n = np.einsum("hwj,hwjd->hwd", res.barycentric.astype(float), vertex_normals_area_weighted(V, F)[F[tri]])
    n /= np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12)
    return n @ np.asarray(camera.R).T, np.where(res.mask.astype(bool), res.triangle_id, -1)


def normal_errors(body, posed, camera, true_posed, true_F, true_camera) -> dict:
    """Fitted vs TRUE normals at the same pixels, per body part: ``{part: (median deg, share > 20 deg, pixels)}``."""
    names = body.skeleton.bone_names
    bone_part = np.array([next((k for k, v in PARTS.items() if n.startswith(v)), "other") for n in names])
    vertex_part = bone_part[np.asarray(body.weights).argmax(1)]
    errs, parts = [], []
    for V, T in zip(posed, true_posed, strict=True):
        n, tri = pixel_normals(V, body.faces, camera)
        g, gtri = pixel_normals(T, true_F, true_camera)
        both = (tri >= 0) & (gtri >= 0)
        errs.append(np.degrees(np.arccos(np.clip((n[both] * g[both]).sum(-1), -1, 1))))
        parts.append(vertex_part[body.faces[tri[both], 0]])
    e, p = np.concatenate(errs), np.concatenate(parts)
    out = {k: e[p == k] for k in PARTS if np.any(p == k)} | {"all": e}
    return {k: (round(float(np.median(v)), 1), round(float(np.mean(v > 20)), 2), len(v)) for k, v in out.items()}


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
    ap.add_argument("--normals", action="store_true", help="also the fitted-vs-true normal error per body part")
    ap.add_argument("--variants", nargs="+", choices=("before", "sparsity", "grouped", "after"),
                    default=["before", "sparsity", "grouped", "after"])
    ap.add_argument("--geometry", nargs="+", choices=("fitted", "true"), default=["fitted", "true"])
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
        if args.normals:
            every = slice(None, None, 2)
            err = normal_errors(body, geometries["fitted"][0][every], fit.camera, geometries["true"][0][every],
                                geometries["true"][1], geometries["true"][2])
            print(json.dumps({"subject": subject, "motion": args.motion,
                              "normal_err_deg (median, share > 20 deg, pixels)": err,
                              "local": {k: round(v, 2) for k, v in fit.local.items()}}), flush=True)
        for geometry in args.geometry:
            posed, F, camera, masks = geometries[geometry]
            for name, kw in variants.items():
                if name.split(" ")[0] not in args.variants:
                    continue
                t = time.perf_counter()
                albedo, lighting = estimate_appearance(images, masks, posed, F, camera, **kw)
                row = {"subject": subject, "motion": args.motion, "geometry": geometry, "variant": name}
                row.update(score(lighting, albedo, camera, s), wall_s=round(time.perf_counter() - t, 1))
                print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
