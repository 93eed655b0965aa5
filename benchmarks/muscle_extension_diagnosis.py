"""Why the held-out men gain little from the dataset extension, even from ground-truth meshes (issue 11 §4,
seventh pass).

For each held-out subject of the benchmark's extension step (sets A and B, and the in-range 620) the model-only
error (median mm over the arm, ground-truth meshes, own rest joints, as ``bench_muscle``) of

* the original model (Eq. 6-10 learned from the 10 training men),
* the model extended with the ground-truth meshes of the added subjects 601-604 (the step's "truth meshes"),
* the same with the held-out subject's *own* base-pose mesh added as well (the regression's capacity: how much
  of a subject's own row the linear Eq. 6-7 with its Tikhonov weights keeps),
* the original model's rest mesh plus the same-group added subject's rest residual (that residual transferred
  whole: what the extension could give the subject if rows of one group carried over to another subject of it),

and the subject's rest residual (its rest mesh on its own shoulder minus ``v_base + d_l + d_theta``: the error's
source, the pose term being 0.1-0.2 mm, seventh pass of the capture) with its mean (a translation) and the cosine
between it and the same-group added subject's residual.

    python -m benchmarks.muscle_extension_diagnosis --work W   # W/model.npz from bench_muscle --step prepare
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import numpy as np

from benchmarks.bench_muscle import (
    EXTENSION_SEEDS,
    HELD_OUT_SETS,
    IN_RANGE_SEED,
    OUT_OF_RANGE,
    RESOLUTION,
    _template,
    out_of_range_subject,
)
from benchmarks.timing import markdown_table


def rest_residual(model, sample) -> np.ndarray:
    """A base-pose ground-truth mesh's rest residual (n, 3): its unposed mesh on its own shoulder minus Eq. 6-9."""
    from bodystudio.muscle.model import length_displacements, shape_displacements, unpose_arm

    shape = sample.shape
    predicted = model.base_vertices + length_displacements(model, shape) + shape_displacements(model, shape)
    return unpose_arm(sample.vertices, model.part_weights, sample.joints, sample.pose) - sample.joints[0] - predicted


def transferred_error_mm(model, samples, residual) -> float:
    """Median error of ``samples`` with the original rest mesh plus ``residual`` (the pose term and LBS the model's)."""
    from bodystudio.muscle.arm import pose_arm
    from bodystudio.muscle.model import limit_displacement_norms, model_rest_vertices, pose_displacements

    errs = []
    for s in samples:
        rest = model_rest_vertices(model, s.shape, s.joints) + residual
        d_rho = limit_displacement_norms(pose_displacements(model, s.pose.angles), 0.0)
        V = pose_arm(rest + d_rho, model.part_weights, s.joints, s.pose)
        errs.append(np.linalg.norm((V - s.vertices)[model.arm_mask], axis=1))
    return float(1000 * np.median(np.concatenate(errs)))


def diagnosis(work: Path) -> list[dict]:
    from bodystudio.muscle.model import extend_arm_model, load_arm_model, model_error_mm
    from bodystudio.muscle.synthetic import sample_arm_subject, subject_arm_samples

    model = load_arm_model(work / "model.npz", _template())
    labels = list(OUT_OF_RANGE)
    added = {label: subject_arm_samples(out_of_range_subject(seed, label), RESOLUTION, n_shapes=1, n_poses=8,
                                        seed=3, name=f"truth_{seed}") for seed, label in zip(EXTENSION_SEEDS, labels,
                                                                                            strict=True)}
    extended = extend_arm_model(model, [s for group in added.values() for s in group])
    cases = [(name, seed, label) for name, seeds in HELD_OUT_SETS for seed, label in zip(seeds, labels, strict=True)]
    rows = []
    for name, seed, label in [*cases, ("", IN_RANGE_SEED, "in range")]:
        subj = (sample_arm_subject(seed, gender="male", bmi_range=(22.0, 26.0)) if label == "in range"
                else out_of_range_subject(seed, label))
        test = subject_arm_samples(subj, RESOLUTION, n_shapes=1, n_poses=12, seed=2)
        own = extend_arm_model(extended, [replace(test[0], subject="held_out_own_row")])
        r = rest_residual(model, test[0])[model.arm_mask]
        row = {"seed": seed, "set": name, "label": label,
               "original": model_error_mm(model, test, use_sample_joints=True)["median_mm"],
               "extended": model_error_mm(extended, test, use_sample_joints=True)["median_mm"],
               "own_row": model_error_mm(own, test, use_sample_joints=True)["median_mm"],
               "residual_mm": float(1000 * np.median(np.linalg.norm(r, axis=1))),
               "translation_mm": float(1000 * np.linalg.norm(r.mean(axis=0)))}
        if label in added:
            g = rest_residual(model, added[label][0])
            ga = g[model.arm_mask]
            row["cosine"] = float((r * ga).sum() / np.linalg.norm(r) / np.linalg.norm(ga))
            row["transferred"] = transferred_error_mm(model, test, g)
        rows.append(row)
    return rows


def table(rows: list[dict]) -> str:
    def pct(h, key):
        return f"{h[key]:.2f} ({100 * (h[key] / h['original'] - 1):+.0f} %)" if key in h else "-"

    return markdown_table(
        ["held-out subject", "set", "original mm", "truth extension mm", "+ its own row mm",
         "same-group residual transferred mm", "cosine with it", "rest residual mm", "its translation mm"],
        [[f"{h['seed']} ({h['label']})", h["set"], f"{h['original']:.2f}", pct(h, "extended"), pct(h, "own_row"),
          pct(h, "transferred"), f"{h['cosine']:.2f}" if "cosine" in h else "-", f"{h['residual_mm']:.2f}",
          f"{h['translation_mm']:.1f}"] for h in rows])


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, required=True, help="folder with the benchmark's model.npz")
    args = parser.parse_args(argv)
    print(table(diagnosis(args.work)))


if __name__ == "__main__":
    main()
