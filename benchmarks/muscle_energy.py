"""Arm-muscle capture (issue 11): does the truth beat the sequence fit's answer on the fit's own energy?

For one subject (6k template, Kinect v2 at 1 m, elbow flexion, 24 frames, measured shape) the capture runs up to the
whole-sequence fit (``refine.fit_arm_sequence_skeleton``), whose inputs are kept; the fit's energy is then evaluated
term by term (depth pairs with their Huber loss, tracker joints, angle prior, skeleton prior; every frame re-paired
on its own mesh) at the fitted answer and at the ground truth plugged into the same residual function (true angles,
true placement, the subject's own rest joints moved into the model's rest mesh), and the fit is also started from
the truth. Each row: the variant's energies, the surface error of the model mesh (smoothed, as the pipeline does)
and of the full pipeline (the Sec. 7 refinement after it), the depth energy per part, the placement's error.
docs/muscle.md "fifth pass".

    python -m benchmarks.muscle_energy --work W --subjects 5,603 [--option KEY=VALUE ...] [--from-truth]

``--option``: ``fit_arm_sequence_skeleton`` keywords over the fourth pass's variant (placement and skeleton
fitted, Huber on the depth pairs only), e.g. ``tracker_weight=10.0`` or ``torso_pair_weight=0.0``.
"""

from __future__ import annotations

import argparse
import ast
import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np

# The capture options of the fifth pass's measurements (before the sixth pass's defaults: norm limit 0.9, the
# refinement's pairs not tested for visibility), so that this reproduces its figures.
FIFTH_PASS = dict(norm_limit=0.9, refine_visible_only=False)
FOURTH_PASS = dict(norm_limit=0.9, tracker_weight=30.0, smooth_weight=10.0, rounds=3, max_nfev=15, huber_m=0.004,
                   fit_root=True, fit_skeleton=True, skeleton_prior_weight=100.0, depth_huber_only=True)


def work_model(work: Path, template):
    """The benchmark's arm model in ``work/model.npz`` (bench_muscle's prepare step), learned there when missing."""
    from bodystudio.muscle.model import load_arm_model

    if not (work / "model.npz").is_file():
        from bodystudio.muscle.model import learn_arm_model, save_arm_model
        from bodystudio.muscle.synthetic import training_dataset

        save_arm_model(work / "model.npz", learn_arm_model(training_dataset("6k")[0], template))
    return load_arm_model(work / "model.npz", template)


def subject_session(work: Path, seed: int, n_frames: int):
    """The subject and its session: 601-604 as the benchmark's extension step makes them (noise seed 1)."""
    from benchmarks.bench_muscle import OUT_OF_RANGE, out_of_range_subject
    from bodystudio.capture.session import open_session
    from bodystudio.muscle.synthetic import sample_arm_subject, synth_arm_session

    if 601 <= seed <= 604:
        subject, noise_seed = out_of_range_subject(seed, list(OUT_OF_RANGE)[seed - 601]), 1
    else:
        subject, noise_seed = sample_arm_subject(seed), 0
    path = work / f"energy_{seed}_{n_frames}"
    if not path.is_dir():
        synth_arm_session(path, subject=subject, motion="elbow_flex", n_frames=n_frames, kinect="v2",
                          distance_m=1.0, resolution="6k", seed=noise_seed)
    return subject, open_session(path)


def sequence_fit_inputs(model, template, subject, session, n_frames: int) -> dict:
    """The capture (measured shape) run up to the sequence fit; its inputs and the Sec. 5.1 translation."""
    import bodystudio.muscle.capture as capture
    from benchmarks.bench_muscle import shape_of

    kept = {}
    fit = capture.fit_arm_sequence_skeleton

    def keep(model, shape, poses, frames, joints, *args, **kw):
        kept.update(shape=shape, poses=list(poses), frames=list(frames), joints=np.asarray(joints), tracker=args[1],
                    rest=kw["rest"])
        return fit(model, shape, poses, frames, joints, *args, **kw)

    capture.fit_arm_sequence_skeleton = keep
    try:
        cap = capture.capture_arm_sequence(session, model, template, capture.CaptureOptions(mode="model", **FIFTH_PASS),
                                           known_shape=shape_of(subject), frames=slice(0, n_frames))
    finally:
        capture.fit_arm_sequence_skeleton = fit
    kept["t"] = np.asarray(cap.similarity[2])
    return kept


def energy_terms(model, inputs: dict, poses, J, kw: dict, with_skeleton: bool) -> tuple[dict, list]:
    """The sequence fit's energy at ``poses`` and rest joints ``J`` (pairs re-found on each frame's mesh)."""
    from bodystudio.muscle.refine import elbow_axes, posed_joints, skeleton_model_mesh

    hub = kw["huber_m"]
    part = np.argmax(model.part_weights, axis=1)
    depth, per_part, tracker, n_pairs, meshes = 0.0, np.zeros(3), 0.0, 0, []
    for p, fr, tj in zip(poses, inputs["frames"], inputs["tracker"], strict=True):
        M = skeleton_model_mesh(model, p, inputs["rest"], J, kw["norm_limit"])
        meshes.append(M)
        k, q, n = fr.plane_pairs(M)
        a = np.abs(np.einsum("kd,kd->k", M[k] - q, n))
        rho = np.where(a <= hub, a * a, 2 * hub * a - hub * hub)
        depth += float(rho.sum())
        per_part += [float(rho[part[k] == j].sum()) for j in range(3)]
        n_pairs += len(k)
        tracker += kw["tracker_weight"] * float(np.sum((posed_joints(J, p) - tj) ** 2))
    h, _ = elbow_axes(J)
    A = np.array([np.r_[p.angles[0], p.angles[1] @ h] for p in poses])
    prior = kw["smooth_weight"] * 0.09 * float(np.sum((A[:-2] - 2 * A[1:-1] + A[2:]) ** 2))
    skeleton = kw["skeleton_prior_weight"] * float(np.sum((J - inputs["joints"]) ** 2)) if with_skeleton else 0.0
    terms = {"total": depth + tracker + prior + skeleton, "depth": depth, "tracker": tracker, "prior": prior,
             "skeleton": skeleton, "pairs": n_pairs, "depth_torso": per_part[0], "depth_upper_arm": per_part[1],
             "depth_forearm": per_part[2]}
    return {k: (v if k == "pairs" else 1000 * v) for k, v in terms.items()}, meshes


def sequence_case(work: Path, seed: int, n_frames: int) -> SimpleNamespace:
    """One subject's sequence-fit case in ``work``: the benchmark's model, the session and its ground truth
    (``G``, ``visible``, ``true_joints``), the fit's cached inputs (``t``, start joints ``J0``) and the truth in
    the fit's frame: ``J_truth`` (the subject's skeleton moved to the model's regressed shoulder) and
    ``true_poses``."""
    from benchmarks.bench_muscle import _template, truth_template
    from bodystudio.muscle.arm import ArmPose
    from bodystudio.muscle.evaluate import session_ground_truth

    template = _template()
    model = work_model(work, template)
    subject, session = subject_session(work, seed, n_frames)
    truth = truth_template(subject)
    ids = session.frame_ids[:n_frames]
    G, visible, true_joints = session_ground_truth(session, truth, ids)
    inputs = sequence_fit_inputs(model, template, subject, session, n_frames)
    t, J0 = inputs["t"], inputs["joints"]
    shift = truth.joints[0] - J0[0]  # the subject's skeleton moved into the model's rest mesh (regressed shoulder)

    def in_fit_frame(p):
        root = p.root.copy()
        root[:3, 3] += root[:3, :3] @ shift - t
        return ArmPose(root, p.angles)

    true_poses = [in_fit_frame(ArmPose.from_dict(session.frame(i).gt_arm_pose)) for i in ids]
    return SimpleNamespace(model=model, session=session, truth=truth, G=G, visible=visible, true_joints=true_joints,
                           inputs=inputs, t=t, J0=J0, J_truth=truth.joints - shift, true_poses=true_poses)


def energies(work: Path, seed: int, n_frames: int = 24, options: dict | None = None,
             from_truth: bool = False) -> dict:
    """Energy terms (x 1000) at the truth, the fit's start and its answer (and, optionally, started from the truth)."""
    from bodystudio.muscle.capture import CaptureOptions, _refinement, _Timer
    from bodystudio.muscle.evaluate import score_arm_sequence
    from bodystudio.muscle.refine import fit_arm_sequence_skeleton, skeleton_model_mesh, smooth_arm_poses

    kw = {**FOURTH_PASS, **(options or {})}
    c = sequence_case(work, seed, n_frames)
    model, truth, G, visible, true_joints = c.model, c.truth, c.G, c.visible, c.true_joints
    inputs, t, J0, J_truth, true_poses = c.inputs, c.t, c.J0, c.J_truth, c.true_poses

    def median(meshes):
        return score_arm_sequence(np.stack(meshes) + t, G, truth, visible, true_joints)["median_mm"]

    out = {"seed": seed, "options": {k: repr(v) for k, v in (options or {}).items()}}
    e, m = energy_terms(model, inputs, true_poses, J_truth, kw, True)
    out["truth"] = {**e, "model_median_mm": median(m)}
    e, m = energy_terms(model, inputs, inputs["poses"], J0, kw, kw["fit_skeleton"])
    out["start"] = {**e, "model_median_mm": median(m)}
    args = (model, inputs["shape"], inputs["poses"], inputs["frames"], J0)
    poses, J = fit_arm_sequence_skeleton(*args, tracker_joints=inputs["tracker"], rest=inputs["rest"], **kw)
    e, m = energy_terms(model, inputs, poses, J, kw, kw["fit_skeleton"])
    smoothed = smooth_arm_poses(poses, CaptureOptions().pose_sigma_frames,
                                degree=CaptureOptions().pose_smoothing_degree)
    meshes = [skeleton_model_mesh(model, p, inputs["rest"], J, kw["norm_limit"]) for p in smoothed]
    f = inputs["frames"][0]
    refined = _refinement(meshes, smoothed, [(fr.points, fr.normals) for fr in inputs["frames"]],
                          [fr.tree for fr in inputs["frames"]], f.faces, f.sensor_center, f.arm_mask, f.adjacency, J,
                          CaptureOptions(**FIFTH_PASS), _Timer())
    full = score_arm_sequence(np.stack(refined) + t, G, truth, visible, true_joints)
    out["fit"] = {**e, "model_median_mm": median(m), "smoothed_model_median_mm": median(meshes),
                  "full_median_mm": full["median_mm"], "full_p90_mm": full["p90_mm"],
                  "full_bulge_err_mm": full["bulge_err_mm"],
                  "placement_minus_truth_mm": (1000 * (poses[0].root[:3, 3] - true_poses[0].root[:3, 3])).tolist(),
                  "joints_minus_truth_mm": (1000 * (J - J_truth)).tolist()}
    if from_truth and kw["fit_skeleton"] and kw["fit_root"]:
        poses, J = fit_arm_sequence_skeleton(model, inputs["shape"], true_poses, inputs["frames"], J0,
                                             tracker_joints=inputs["tracker"], rest=inputs["rest"],
                                             start_joints=J_truth, **kw)
        e, m = energy_terms(model, inputs, poses, J, kw, True)
        out["from_truth"] = {**e, "model_median_mm": median(m),
                             "placement_minus_truth_mm": (1000 * (poses[0].root[:3, 3]
                                                                  - true_poses[0].root[:3, 3])).tolist()}
    return out


def render(rows: list[dict]) -> str:
    from benchmarks.timing import markdown_table

    cells = []
    for r in rows:
        for at in ("truth", "start", "fit", "from_truth"):
            if at not in r:
                continue
            e = r[at]
            cells.append([str(r["seed"]), at, f"{e['total']:.0f}", f"{e['depth']:.1f}", f"{e['depth_torso']:.1f}",
                          f"{e['tracker']:.0f}", f"{e['prior']:.1f}", f"{e['skeleton']:.1f}",
                          f"{e['model_median_mm']:.2f}",
                          f"{e['full_median_mm']:.2f}" if "full_median_mm" in e else ""])
    return markdown_table(["subject", "at", "energy x1e3", "depth (Huber)", "of it torso", "tracker", "angle prior",
                           "skeleton prior", "model mesh median mm", "full pipeline median mm"], cells)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, required=True)
    parser.add_argument("--subjects", default="5,603")
    parser.add_argument("--frames", type=int, default=24)
    parser.add_argument("--option", action="append", default=[], help="fit_arm_sequence_skeleton KEY=VALUE")
    parser.add_argument("--from-truth", action="store_true")
    args = parser.parse_args(argv)
    options = {}
    for item in args.option:
        key, _, value = item.partition("=")
        if key not in FOURTH_PASS and key not in ("torso_pair_weight", "free_joints"):
            parser.error(f"--option {item}: unknown key {key!r}")
        try:
            options[key] = ast.literal_eval(value)
        except (ValueError, SyntaxError):
            parser.error(f"--option {item}: {value!r} is not a Python literal")
    args.work.mkdir(parents=True, exist_ok=True)
    rows = [energies(args.work, int(s), args.frames, options, args.from_truth) for s in args.subjects.split(",")]
    print(render(rows))
    print(json.dumps(rows))


if __name__ == "__main__":
    main()
