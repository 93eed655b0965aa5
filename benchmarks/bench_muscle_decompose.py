"""Arm-muscle capture (issue 11): where the error comes from, by plugging ground truth into the model mesh.

For each subject (6k template, Kinect v2 at 1 m, elbow flexion, measured shape), the model mesh of Eq. 12
(``model_mesh``) is scored against the truth with one piece at a time taken from the ground truth: the
subject's own rest joints, the regressed joints with the best translation of the whole sequence, the
captured root or the captured joint angles (the full pipeline's model step, ``CaptureOptions()``).
The table is docs/muscle.md's "Error decomposition, second pass".

    python -m benchmarks.bench_muscle_decompose             # subjects 2, 5, 7; 24 frames
    python -m benchmarks.bench_muscle_decompose --quick     # subject 2, 8 frames
    python -m benchmarks.bench_muscle_decompose --work W    # keep the model and sessions in W
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

from benchmarks.timing import markdown_table

SUBJECTS = (2, 5, 7)
FRAMES = 24


def _median(model, shape, poses, G, truth, visible, joints, rest_joints=None, shift=None) -> float:
    from bodystudio.muscle.evaluate import score_arm_sequence
    from bodystudio.muscle.model import model_mesh

    V = np.stack([model_mesh(model, shape, p, 0.9, joints=rest_joints) for p in poses])
    if shift is not None:
        V = V + shift
    return score_arm_sequence(V, G, truth, visible, joints)["median_mm"]


def decompose(work: Path, seed: int, n_frames: int) -> list[float]:
    """Medians (mm) of the model mesh with truth plugged in, in the order of ``ROWS``."""
    from benchmarks.bench_muscle import _template, shape_of, truth_template
    from bodystudio.capture.session import open_session
    from bodystudio.muscle.arm import ArmPose
    from bodystudio.muscle.capture import CaptureOptions, capture_arm_sequence
    from bodystudio.muscle.evaluate import session_ground_truth
    from bodystudio.muscle.model import load_arm_model, model_joints, model_mesh
    from bodystudio.muscle.synthetic import sample_arm_subject, synth_arm_session

    template = _template()
    if not (work / "model.npz").is_file():  # the benchmark's model (bench_muscle's prepare step)
        from bodystudio.muscle.model import learn_arm_model, save_arm_model
        from bodystudio.muscle.synthetic import training_dataset

        save_arm_model(work / "model.npz", learn_arm_model(training_dataset("6k")[0], template))
    model = load_arm_model(work / "model.npz", template)
    subject = sample_arm_subject(seed)
    path = work / f"decompose_{seed}_{n_frames}"
    if not path.is_dir():
        synth_arm_session(path, subject=subject, motion="elbow_flex", n_frames=n_frames, kinect="v2",
                          distance_m=1.0, resolution="6k")
    session = open_session(path)
    truth, shape = truth_template(subject), shape_of(subject)
    ids = session.frame_ids
    G, visible, joints = session_ground_truth(session, truth, ids)
    true_poses = [ArmPose.from_dict(session.frame(i).gt_arm_pose) for i in ids]
    args = (model, shape)
    score = (G, truth, visible, joints)
    own = _median(*args, true_poses, *score, rest_joints=truth.joints)
    Jm = model_joints(model, shape)
    moved = _median(*args, true_poses, *score, rest_joints=Jm + (truth.joints[0] - Jm[0]))
    V = np.stack([model_mesh(model, shape, p, 0.9) for p in true_poses])
    best = (G - V)[:, template.arm_mask].reshape(-1, 3).mean(axis=0)
    best_translation = _median(*args, true_poses, *score, shift=best)
    true_root = _median(*args, true_poses, *score)
    cap = capture_arm_sequence(session, model, template, CaptureOptions(), known_shape=shape)
    S = np.eye(4)
    S[:3, 3] = cap.similarity[2]  # template space -> world (a translation: CaptureOptions' default)
    captured = [ArmPose(S @ p.root, p.angles) for p in cap.poses]
    cap_root = _median(*args, [ArmPose(c.root, g.angles) for g, c in zip(true_poses, captured, strict=True)], *score)
    cap_angles = _median(*args, [ArmPose(g.root, c.angles) for g, c in zip(true_poses, captured, strict=True)], *score,
                         shift=best)
    cap_pose = _median(*args, captured, *score)
    return [own, moved, best_translation, true_root, cap_root, cap_angles, cap_pose]


ROWS = ("true pose, subject's own rest joints",
        "true pose, regressed rest joints moved onto the subject's shoulder",
        "true pose, regressed rest joints, best translation of the sequence",
        "true pose, regressed rest joints, true root (no translation)",
        "captured root + true angles",
        "best translation + captured angles",
        "captured pose (the pipeline's model step)")


def run(quick: bool = False, work: Path | None = None, subjects=None, n_frames: int | None = None) -> str:
    subjects = subjects or ((2,) if quick else SUBJECTS)
    n = n_frames or (8 if quick else FRAMES)
    with tempfile.TemporaryDirectory(prefix="bench_muscle_decompose_") as tmp:
        w = Path(work or tmp)
        w.mkdir(parents=True, exist_ok=True)
        cols = {s: decompose(w, s, n) for s in subjects}
    table = markdown_table(["model mesh from", *(f"subject {s} median mm" for s in subjects)],
                           [[row, *(f"{cols[s][k]:.2f}" for s in subjects)] for k, row in enumerate(ROWS)])
    return (f"## Arm-muscle capture: error decomposition\n\n6k template, Kinect v2 at 1 m, elbow flexion, {n} "
            "frames, measured shape; the model mesh (Eq. 12) with ground truth plugged in one piece at a time, "
            "median over the arm vertices of every frame.\n\n" + table)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--work", type=Path, default=None)
    parser.add_argument("--subjects", default=None, help="comma-separated subject seeds (default 2,5,7)")
    parser.add_argument("--frames", type=int, default=None)
    args = parser.parse_args(argv)
    subjects = tuple(int(s) for s in args.subjects.split(",")) if args.subjects else None
    print(run(args.quick, args.work, subjects, args.frames))


if __name__ == "__main__":
    main()
