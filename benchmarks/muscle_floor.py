"""Arm-muscle model (issue 11, seventh pass): the model's own per-vertex floor against the training set's size.

The floor is the model mesh of Eq. 12 with the truth plugged in (the subject's true shape parameters, every
frame's true joint angles and placement, the subject's own rest joints): what no pose or placement fit can go
below (docs/muscle.md, sixth pass: 3.0-3.7 mm median on in-range subjects). Here it is measured for models learned
from ``synthetic.training_dataset(n_subjects=N, n_shapes=S)`` on held-out in-range sessions (per region as
``benchmarks.muscle_regions``), with oracle rows that replace one of the model's parts by the subject's own,
to tell the dataset's size from the model's form (Eq. 6-10):

- ``own rest``: the subject's true rest (base-pose) mesh instead of Eq. 6-9's ``v_base + d_l + d_theta`` (the
  shape space's error removed; what remains is the pose term Eq. 10 and the skinning);
- ``own rest + weights``: also the subject's own skin weights instead of the template's (what remains is Eq. 10's
  linear pose term against the truth's pose-dependent muscle);
- ``rest_pose`` (on the floor row): the floor at the base pose (the shape space alone); and per training set the
  in-sample error (the model on its own training subjects' base-pose meshes).

    python -m benchmarks.muscle_floor --work W --sessions 504:0:200,507:0:200,5:0:24 --train 10x3,20x3,40x3

Sessions as ``benchmarks.muscle_sequences`` makes them (``W/seq_SUBJECT_sNOISE_FRAMES``); models cached in
``W/floor_model_N_S_P.npz``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np


def floor_model(work: Path, n_subjects: int, n_shapes: int, n_poses: int, template):
    from bodystudio.muscle.model import learn_arm_model, load_arm_model, save_arm_model
    from bodystudio.muscle.synthetic import training_dataset

    path = work / f"floor_model_{n_subjects}_{n_shapes}_{n_poses}.npz"
    if not path.is_file():
        t0 = time.perf_counter()
        samples, _ = training_dataset("6k", n_subjects=n_subjects, n_shapes=n_shapes, n_poses=n_poses)
        save_arm_model(path, learn_arm_model(samples, template))
        print(f"learned {path.name}: {len(samples)} meshes, {time.perf_counter() - t0:.0f} s", flush=True)
    return load_arm_model(path, template)


def subject_parts(subject):
    """The subject's own rest mesh (base pose, muscle at rest), skin weights and rest joints (truth side)."""
    from benchmarks.bench_muscle import truth_template
    from bodystudio.muscle.arm import ArmPose
    from bodystudio.muscle.synthetic import MuscleVariation, muscle_displacement

    T = truth_template(subject)
    rest = T.vertices + muscle_displacement(T, subject, ArmPose.rest(), MuscleVariation.from_seed(subject.seed))
    return rest, T.part_weights, T.joints, T


def floor_rows(model, subject, session, frames: int, norm_limit: float) -> dict:
    """Median per-vertex error (mm) by region of the truth-plugged model mesh and its oracle variants
    (``p90`` and ``rest_pose``, the floor at the base pose, on the floor's row)."""
    from benchmarks.bench_muscle import shape_of
    from benchmarks.muscle_regions import region_medians
    from bodystudio.muscle.arm import ArmPose, pose_arm
    from bodystudio.muscle.evaluate import session_ground_truth
    from bodystudio.muscle.model import limit_displacement_norms, model_mesh, pose_displacements

    own_rest, own_w, J, T = subject_parts(subject)
    ids = session.frame_ids[:frames]
    G, visible, _ = session_ground_truth(session, T, ids)
    poses = [ArmPose.from_dict(session.frame(i).gt_arm_pose) for i in ids]
    shape = shape_of(subject)
    plugged, oracle_rest, oracle_both = [], [], []
    for p in poses:
        d_rho = limit_displacement_norms(pose_displacements(model, p.angles), norm_limit)
        plugged.append(model_mesh(model, shape, p, norm_limit, joints=J))
        oracle_rest.append(pose_arm(own_rest + d_rho, model.part_weights, J, p))
        oracle_both.append(pose_arm(own_rest + d_rho, own_w, J, p))
    rest_pose = ArmPose(poses[0].root, np.zeros((3, 3)))
    rest_truth = pose_arm(own_rest, own_w, J, rest_pose)
    rest_only = model_mesh(model, shape, rest_pose, norm_limit, joints=J)
    arm = T.arm_mask
    rest_err = 1000.0 * np.linalg.norm(rest_only - rest_truth, axis=1)[arm]
    rows = {"truth plugged (floor)": region_medians(np.stack(plugged), G, visible, T),
            "own rest": region_medians(np.stack(oracle_rest), G, visible, T),
            "own rest + weights": region_medians(np.stack(oracle_both), G, visible, T)}
    rows["truth plugged (floor)"]["p90"] = round(float(np.percentile(
        1000.0 * np.linalg.norm(np.stack(plugged) - G, axis=2)[:, arm], 90)), 2)
    rows["truth plugged (floor)"]["rest_pose"] = round(float(np.median(rest_err)), 2)
    return rows


def held_out_samples_error(model, subject) -> float:
    """``model_error_mm`` (no norm limit, own joints) of the subject's 1 base-pose + 12 random-pose truth meshes."""
    from benchmarks.bench_muscle import RESOLUTION
    from bodystudio.muscle.model import model_error_mm
    from bodystudio.muscle.synthetic import subject_arm_samples

    test = subject_arm_samples(subject, RESOLUTION, n_shapes=1, n_poses=12, seed=2)
    return round(model_error_mm(model, test, use_sample_joints=True)["median_mm"], 2)


def in_sample_error(model, n_subjects: int, n_shapes: int, n_checked: int = 8) -> float:
    """Mean over (up to) ``n_checked`` of the model's own training subjects of the median error (mm, own joints) of
    their training base-pose meshes: what the shape regression leaves on the data it was fitted to."""
    from bodystudio.muscle.model import model_error_mm
    from bodystudio.muscle.synthetic import TRAINING_BMI_RANGE, sample_arm_subject, subject_arm_samples

    errs = []
    for i in range(0, n_subjects, max(1, n_subjects // n_checked)):  # training_dataset's subjects and shapes, seed 0
        subject = sample_arm_subject(1000 + i, gender="male", bmi_range=TRAINING_BMI_RANGE)
        errs.append(model_error_mm(model, subject_arm_samples(subject, "6k", n_shapes, 0, 0),
                                   use_sample_joints=True)["median_mm"])
    return round(float(np.mean(errs)), 2)


def _whole_numbers(text: str, sep: str, count, option: str, form: str) -> tuple[int, ...]:
    parts = text.split(sep)
    counts = count if isinstance(count, tuple) else (count,)
    if len(parts) not in counts or not all(p.strip().isdigit() and int(p) >= 0 for p in parts):
        raise ValueError(f"{option} {text!r}: needs {form}, whole numbers")
    return tuple(int(p) for p in parts)


def main(argv: list[str] | None = None) -> None:
    from benchmarks.bench_muscle import _template
    from benchmarks.muscle_sequences import session_of
    from bodystudio.muscle.capture import CaptureOptions

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, required=True)
    parser.add_argument("--sessions", default="504:0:200,507:0:200,508:0:200",
                        help="SUBJECT:NOISE_SEED:FRAMES,... (in-range subjects the training set does not hold)")
    parser.add_argument("--train", default="10x3,20x3,40x3", help="N_SUBJECTSxN_SHAPES[xN_POSES],... (poses 24)")
    parser.add_argument("--norm-limit", type=float, default=CaptureOptions().norm_limit)
    args = parser.parse_args(argv)
    try:
        sessions = [_whole_numbers(s, ":", 3, "--sessions", "SUBJECT:NOISE_SEED:FRAMES")
                    for s in args.sessions.split(",")]
        configs = [_whole_numbers(c, "x", (2, 3), "--train", "N_SUBJECTSxN_SHAPES[xN_POSES]")
                   for c in args.train.split(",")]
    except ValueError as exc:
        parser.error(str(exc))
    if not 0.0 <= args.norm_limit <= 1.0:
        parser.error(f"--norm-limit {args.norm_limit}: needs a value in [0, 1] (0: no limit)")
    args.work.mkdir(parents=True, exist_ok=True)
    template = _template()
    results = []
    for cfg in configs:
        n_sub, n_sh = cfg[0], cfg[1]
        n_po = cfg[2] if len(cfg) > 2 else 24
        model = floor_model(args.work, n_sub, n_sh, n_po, template)
        print(json.dumps({"train": f"{n_sub}x{n_sh}x{n_po}", "in_sample_base_pose_median_mm":
                          in_sample_error(model, n_sub, n_sh)}), flush=True)
        for subj_seed, noise, frames in sessions:
            subject, session = session_of(args.work, subj_seed, noise, frames)
            rows = floor_rows(model, subject, session, frames, args.norm_limit)
            res = {"train": f"{n_sub}x{n_sh}x{n_po}", "subject": subj_seed, "frames": frames, "rows": rows,
                   "random_poses_median_mm": held_out_samples_error(model, subject)}
            results.append(res)
            print(json.dumps(res), flush=True)
    keys = ["all", "front", "back", "shoulder", "biceps", "upper_arm", "elbow", "forearm"]
    print("| training set | subject | row | " + " | ".join(keys) + " |")
    for r in results:
        for name, row in r["rows"].items():
            print(f"| {r['train']} | {r['subject']} ({r['frames']}) | {name} | "
                  + " | ".join(f"{row[k]:.2f}" for k in keys) + " |")


if __name__ == "__main__":
    main()
