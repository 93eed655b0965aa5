"""Arm-muscle capture (issue 11, sixth pass): per-vertex error by region, and the tracker placement prior's weight.

For one subject (6k template, Kinect v2 at 1 m, elbow flexion, measured shape; sessions as
``benchmarks.muscle_energy``) the capture runs up to the whole-sequence fit, whose inputs are kept; then each
variant of the fit (``fit_arm_sequence_skeleton`` keywords over the fifth pass's best variant: skeleton and
placement fitted, Huber on the depth pairs only, chest pairs off, tracker weight 10) runs with the +-5 frame
smoothing and the Sec. 7 refinement, and is scored per region: front / back (seen / unseen by the sensor),
shoulder (arm vertices with > 20 % torso weight), biceps (``evaluate.biceps_region``), the rest of the upper arm,
elbow (> 20 % on both arm parts), forearm. Rows: the model mesh with the truth plugged in (true angles and
placement, the subject's own rest joints moved into the model's rest mesh: the model's own floor), and per
variant its fitted skeleton with the true pose, its model stage and the full pipeline (the pipeline's norm limit
and refinement options, ``CaptureOptions()``). docs/muscle.md "sixth pass".

    python -m benchmarks.muscle_regions --work W --subjects 5,7,602,603 --variant default \
        --variant prior30:placement_prior_m=0.012 [--variant NAME:KEY=VALUE,KEY=VALUE ...]

``placement_prior_m=L``: ``tracker_placement_weight = refine.tracker_placement_prior_weight(tracker, L)``;
``default``: the pipeline's default sequence fit (placement held, regressed skeleton, Huber on every residual,
tracker weight 30).
"""

from __future__ import annotations

import argparse
import ast
import json
from pathlib import Path

import numpy as np

BEST_FIFTH_PASS = dict(norm_limit=0.9, tracker_weight=10.0, smooth_weight=10.0, rounds=3, max_nfev=15, huber_m=0.004,
                       fit_root=True, fit_skeleton=True, skeleton_prior_weight=100.0, depth_huber_only=True,
                       torso_pair_weight=0.0)
DEFAULT = dict(BEST_FIFTH_PASS, tracker_weight=30.0, fit_root=False, fit_skeleton=False, depth_huber_only=False,
               torso_pair_weight=1.0)


def arm_regions(template) -> dict:
    """Named vertex masks of the arm (see the module docstring)."""
    from bodystudio.muscle.evaluate import biceps_region

    arm, pw = template.arm_mask, template.part_weights
    biceps = biceps_region(template)
    return {"shoulder": arm & (pw[:, 0] > 0.2), "biceps": arm & biceps,
            "upper_arm": arm & (pw[:, 1] > 0.8) & ~biceps, "elbow": arm & (pw[:, 1] > 0.2) & (pw[:, 2] > 0.2),
            "forearm": arm & (pw[:, 2] > 0.8)}


def region_medians(estimate: np.ndarray, truth: np.ndarray, visible: np.ndarray, template) -> dict:
    """Median per-vertex error (mm) over the arm, its seen and unseen vertices and each :func:`arm_regions` region."""
    arm = template.arm_mask
    err = np.linalg.norm(np.asarray(estimate) - truth, axis=2) * 1000.0
    out = {"all": np.median(err[:, arm]), "front": np.median(err[:, arm][visible[:, arm]]),
           "back": np.median(err[:, arm][~visible[:, arm]])}
    out.update({name: np.median(err[:, m]) for name, m in arm_regions(template).items()})
    return {k: round(float(v), 2) for k, v in out.items()}


def subject_rows(work: Path, seed: int, n_frames: int, variants: dict) -> dict:
    from benchmarks.muscle_energy import sequence_case
    from bodystudio.muscle.capture import CaptureOptions, _refinement, _Timer
    from bodystudio.muscle.evaluate import score_arm_sequence
    from bodystudio.muscle.refine import (
        fit_arm_sequence_skeleton,
        skeleton_model_mesh,
        smooth_arm_poses,
        tracker_placement_prior_weight,
    )

    c = sequence_case(work, seed, n_frames)
    model, session, truth, G, visible, true_joints = c.model, c.session, c.truth, c.G, c.visible, c.true_joints
    inputs, t, J0, true_poses = c.inputs, c.t, c.J0, c.true_poses
    tracker = np.asarray(inputs["tracker"])

    norm_limit = CaptureOptions().norm_limit

    def meshes_of(poses, J):
        return np.stack([skeleton_model_mesh(model, p, inputs["rest"], J, norm_limit) for p in poses]) + t

    rows = {"truth plugged (model floor)": region_medians(meshes_of(true_poses, c.J_truth), G, visible,
                                                          truth)}
    for name, options in variants.items():
        kw = dict(DEFAULT if name == "default" else BEST_FIFTH_PASS, norm_limit=norm_limit)
        options = dict(options)
        length = options.pop("placement_prior_m", 0.0)
        kw.update(options)
        if length > 0:
            kw["tracker_placement_weight"] = tracker_placement_prior_weight(tracker, length)
        poses, J = fit_arm_sequence_skeleton(model, inputs["shape"], inputs["poses"], inputs["frames"], J0,
                                             tracker_joints=tracker, rest=inputs["rest"], **kw)
        smoothed = smooth_arm_poses(poses, CaptureOptions().pose_sigma_frames,
                                    degree=CaptureOptions().pose_smoothing_degree)
        model_stage = meshes_of(smoothed, J) - t
        f = inputs["frames"][0]
        full = np.stack(_refinement(list(model_stage), smoothed, [(fr.points, fr.normals) for fr in inputs["frames"]],
                                    [fr.tree for fr in inputs["frames"]], f.faces, f.sensor_center, f.arm_mask,
                                    f.adjacency, J, CaptureOptions(), _Timer(), camera=session.kinect.depth,
                                    similarity=(1.0, np.eye(3), t))) + t
        rows[f"{name}: true pose, fitted skeleton"] = region_medians(meshes_of(true_poses, J), G, visible, truth)
        rows[f"{name}: model stage"] = region_medians(model_stage + t, G, visible, truth)
        rows[f"{name}: full pipeline"] = region_medians(full, G, visible, truth)
        scores = score_arm_sequence(full, G, truth, visible, true_joints)
        rows[f"{name}: full pipeline"].update(p90=round(scores["p90_mm"], 2), bulge=round(scores["bulge_err_mm"], 2),
                                              jitter=round(scores["jitter_mm"], 2))
    return {"seed": seed, "rows": rows}


def render(results: list[dict]) -> str:
    from benchmarks.timing import markdown_table

    keys = ["all", "front", "back", "shoulder", "biceps", "upper_arm", "elbow", "forearm"]
    cells = [[str(r["seed"]), name] + [f"{row[k]:.2f}" for k in keys]
             for r in results for name, row in r["rows"].items()]
    return markdown_table(["subject", "row"] + keys, cells)


def parse_variant(text: str) -> tuple[str, dict]:
    name, _, items = text.partition(":")
    options = {}
    for item in filter(None, items.split(",")):
        key, _, value = item.partition("=")
        options[key] = ast.literal_eval(value)
    return name, options


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, required=True)
    parser.add_argument("--subjects", default="5,7,602,603")
    parser.add_argument("--frames", type=int, default=24)
    parser.add_argument("--variant", action="append", default=[], help="NAME[:KEY=VALUE,...] (NAME default: the "
                        "pipeline's default fit; others: over the fifth pass's best variant)")
    args = parser.parse_args(argv)
    try:
        variants = dict(parse_variant(v) for v in (args.variant or ["default", "prior30:placement_prior_m=0.012"]))
    except (ValueError, SyntaxError) as exc:
        parser.error(f"--variant: {exc}")
    args.work.mkdir(parents=True, exist_ok=True)
    results = [subject_rows(args.work, int(s), args.frames, variants) for s in args.subjects.split(",")]
    print(render(results))
    print(json.dumps(results))


if __name__ == "__main__":
    main()
