"""What a depth capture could give the dataset extension at best (issue 11 §4, sixth pass).

A depth sensor sees the skin's surface, and through the motion where the joints sit in it; it does not see
where along the skin each template vertex lies. The benchmark's held-out error is per vertex (each model
vertex against the same vertex of the truth), so a rest-shape residual that slides vertices along the skin
counts in it but cannot be captured. This splits each added subject's ground-truth rest residual (its rest
mesh on its own shoulder minus the original model's ``v_base + d_l + d_theta``, Eq. 6-9 of Arm-Muscle Capture)
into

* its mean over the arm (a translation: where the skin sits relative to the shoulder joint),
* the rest's component along the model mesh's vertex normals (what the depth shows), and
* the rest's tangential component (vertices sliding along the skin: what no depth capture shows),

and extends the original model with one base-pose mesh per added subject (601-604, the benchmark's) built from
parts of it; the held-out sets A / B and their figures are the benchmark's extension step's. The row
"translation + normal" is a perfect depth capture's ceiling. Each row also gives the held-out change of the
point-to-surface error (both ways), which does not count the vertices' layout along the skin.

    python -m benchmarks.muscle_extension_ceiling --work W   # W/model.npz from bench_muscle --step prepare
"""

from __future__ import annotations

import argparse
import json
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
    shape_of,
)

#: the parts of the truth's rest residual each extension keeps (women / men alike)
VARIANTS = {"truth (all parts)": ("translation", "normal", "tangential"),
            "translation + normal (a perfect depth capture)": ("translation", "normal"),
            "translation": ("translation",), "normal": ("normal",), "tangential": ("tangential",)}


def rest_residual_parts(residual: np.ndarray, rest_vertices: np.ndarray, faces: np.ndarray,
                        arm_mask: np.ndarray) -> dict[str, np.ndarray]:
    """A rest-shape residual (n, 3) as translation + normal + tangential parts (each (n, 3), summing to it).

    The translation is the residual's mean over the arm vertices; the normal part is the remainder's
    component along the vertex normals of ``rest_vertices`` (the mesh the residual departs from); the
    tangential part is what is left (vertices sliding along the skin)."""
    from bodystudio.geometry.mesh import vertex_normals

    r = np.asarray(residual, dtype=np.float64)
    t = r[arm_mask].mean(axis=0)
    N = vertex_normals(np.asarray(rest_vertices, dtype=np.float64), faces)
    x = r - t
    normal = (x * N).sum(axis=1, keepdims=True) * N
    return {"translation": np.broadcast_to(t, r.shape).copy(), "normal": normal, "tangential": x - normal}


def model_surface_error_mm(model, samples) -> float:
    """Median point-to-surface distance (both ways, arm vertices, mm) of the model meshes of ``samples`` (true
    shape, pose and own joints, no norm limit) to the samples' meshes: the held-out error without the
    tangential layout of the vertices (``evaluate.surface_distances``)."""
    from bodystudio.muscle.evaluate import surface_distances
    from bodystudio.muscle.model import model_mesh

    d = [surface_distances(model_mesh(model, s.shape, s.pose, 0.0, joints=s.joints), s.vertices, model.faces,
                           model.arm_mask) for s in samples]
    return 1000.0 * float(np.median(np.concatenate(d)))


def main(argv: list[str] | None = None) -> None:
    from bodystudio.muscle import model as M
    from bodystudio.muscle.arm import ArmPose
    from bodystudio.muscle.synthetic import sample_arm_subject, subject_arm_samples

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, required=True, help="folder with model.npz (bench_muscle --step prepare)")
    args = parser.parse_args(argv)
    model = M.load_arm_model(args.work / "model.npz", _template())
    labels = list(OUT_OF_RANGE)
    parts = []
    for seed, label in zip(EXTENSION_SEEDS, labels, strict=True):
        subj = out_of_range_subject(seed, label)
        shape = shape_of(subj)
        base = subject_arm_samples(subj, RESOLUTION, n_shapes=1, n_poses=0, seed=3)[0]
        expected = model.base_vertices + M.length_displacements(model, shape) + M.shape_displacements(model, shape)
        r = M.unposed_sample(base, model.part_weights, None) - expected
        parts.append((seed, shape, base.joints, expected, rest_residual_parts(r, expected, model.faces,
                                                                               model.arm_mask)))
    held = []
    for name, seeds in (*HELD_OUT_SETS, ("in range", (IN_RANGE_SEED,))):
        for seed, label in zip(seeds, labels, strict=False):
            subj = (sample_arm_subject(seed, gender="male", bmi_range=(22.0, 26.0)) if name == "in range"
                    else out_of_range_subject(seed, label))
            held.append((name, seed, subject_arm_samples(subj, RESOLUTION, n_shapes=1, n_poses=12, seed=2)))
    original = {seed: M.model_error_mm(model, t, use_sample_joints=True)["median_mm"] for _, seed, t in held}
    original_surface = {seed: model_surface_error_mm(model, t) for _, seed, t in held}
    results = {}
    for variant, keep in VARIANTS.items():
        samples = [M.ArmSample(f"truth_{seed}", shape, E + sum(p[k] for k in keep) + J[0], ArmPose.rest(), J)
                   for seed, shape, J, E, p in parts]
        extended = M.extend_arm_model(model, samples)
        change = {seed: 100.0 * (M.model_error_mm(extended, t, use_sample_joints=True)["median_mm"]
                                 / original[seed] - 1.0) for _, seed, t in held}
        surface = {seed: 100.0 * (model_surface_error_mm(extended, t) / original_surface[seed] - 1.0)
                   for _, seed, t in held}
        means = {name: float(np.mean([change[s] for n, s, _ in held if n == name])) for name, _ in HELD_OUT_SETS}
        surface_means = {name: float(np.mean([surface[s] for n, s, _ in held if n == name]))
                         for name, _ in HELD_OUT_SETS}
        results[variant] = {"mean_change_pct": means, "change_pct": change, "surface_mean_change_pct": surface_means,
                            "surface_change_pct": surface}
        print(f"{variant:48s} " + "  ".join(f"set {k} {v:+6.1f} %" for k, v in means.items()) + "   "
              + " ".join(f"{s}:{c:+.0f}" for s, c in change.items()) + "   surface: "
              + "  ".join(f"set {k} {v:+6.1f} %" for k, v in surface_means.items()), flush=True)
    sizes = {seed: {k: 1000 * float(np.median(np.linalg.norm(v[model.arm_mask], axis=1))) for k, v in p.items()}
             for seed, _, _, _, p in parts}
    for seed, s in sizes.items():
        print(f"{seed}: median |part| mm " + ", ".join(f"{k} {v:.2f}" for k, v in s.items()))
    (args.work / "extension_ceiling.json").write_text(json.dumps({"results": results, "part_sizes_mm": sizes},
                                                                 indent=1))


if __name__ == "__main__":
    main()
