"""Arm-muscle capture (issue 11, eleventh pass): which part of the pipeline owns the last millimetres of the median.

For a 200-frame benchmark-like session (``muscle_sequences.session_of``: ``sample_arm_subject(SUBJECT)``, noise seed
0, Kinect v2 at 1 m, measured shape, the benchmark's model) the capture runs up to the sequence stage with the
options given; that state is kept (``W/owners_SUBJECT_NAME.pkl``: the depth points and normals in the template's
space, the per-frame poses, the rest arm, the similarity; ~60 MB), so that the sequence stage, the pose smoothing
and the Sec. 7 refinement (``capture._refinement``) re-run on it alone. Rows (each scored against the truth with
``evaluate.score_arm_sequence`` and broken down by region, side and elbow flexion):

- ``capture``: the pipeline as it is (the options' sequence stage, smoothing, refinement);
- ``true angles``: the capture's rest arm, skeleton and placement, the truth's joint angles per frame;
- ``true placement``: the capture's poses, each frame's root moved so that its posed shoulder is the truth's;
- ``true angles + placement``: both;
- ``true rest, capture poses``: the truth's rest arm and rest joints (moved onto the capture's rest shoulder) with
  the capture's poses;
- ``true rest, poses re-fitted``: the same rest arm, then the sequence fit (``refine.fit_arm_sequence_skeleton``
  with the options' settings) re-fits the angles on it;
- ``all truth``: the truth's rest arm, angles and placement (the model's pose term and the refinement's floor).

Each row goes through the same smoothing (not for the truth's angles) and Sec. 7 refinement.

    python -m benchmarks.muscle_owners --work W --session 501 --session 508 [--pre DIR] \
        [--options body_rest_shape=True,body_rest_rounds=2,body_rest_fit_poses=True,norm_limit=0.2]

With ``--refit NAME:KEY=VALUE,...`` (repeatable; ``none``: the sequence stage's poses as they are) the rows are
instead ``refine.refit_arm_poses_to_depth`` after the sequence stage with those keywords, scored the same way, with
the data-side ``heldout_energy_mm`` (the refit on the even frames only, judged on the odd frames' depth) that chose
``capture.POSE_REFIT``:

    python -m benchmarks.muscle_owners --work W --session 501 --pre DIR --refit none \
        --refit pr:tracker_weight=0.03,prior_weight=0.1,iterations=3

docs/muscle.md "Capture, eleventh pass".
"""

from __future__ import annotations

import argparse
import json
import pickle
import time
from pathlib import Path

import numpy as np

JOINT_FIT = dict(body_rest_shape=True, body_rest_rounds=2, body_rest_fit_poses=True, norm_limit=0.2)
FLEXION_BINS = (0.0, 45.0, 75.0, 105.0, 180.0)  # elbow flexion (deg) of the truth, bin edges


class _Stop(Exception):
    pass


def capture_state(work: Path, subject_seed: int, options: dict, name: str, n_frames: int = 200,
                  pre: Path | None = None) -> dict:
    """The capture's state at the start of the sequence stage (cached in ``W/owners_SUBJECT_NAME.pkl``; ``pre``: a
    folder with an earlier cache ``pre_SUBJECT.pkl`` of the same state to take it from)."""
    path = work / f"owners_{subject_seed}_{name}_{n_frames}.pkl"
    if path.is_file():
        with open(path, "rb") as fh:
            return pickle.load(fh)
    if pre is not None and (pre / f"pre_{subject_seed}.pkl").is_file():
        # an earlier helper's cache of the same state (``capture_arm_sequence`` stopped at the sequence stage, the
        # per-frame stage with ``CaptureOptions()``), its depth frames kept as points and normals
        with open(pre / f"pre_{subject_seed}.pkl", "rb") as fh:
            d = pickle.load(fh)
        saved = {k: d[k] for k in ("shape", "poses", "tracker_t", "base", "J", "known_shape", "S")}
        saved.update(clouds=[(f.points, f.normals) for f in d["frames_t"]], sensor=d["frames_t"][0].sensor_center,
                     per_frame_cpu_s=None, source=str(pre / f"pre_{subject_seed}.pkl"))
        del d
        with open(path, "wb") as fh:
            pickle.dump(saved, fh, protocol=pickle.HIGHEST_PROTOCOL)
        return saved
    from benchmarks import bench_muscle as bm
    from benchmarks.muscle_energy import work_model
    from benchmarks.muscle_sequences import session_of
    from bodystudio.muscle import capture as cm

    template = bm._template()
    model = work_model(work, template)
    subject, session = session_of(work, subject_seed, 0, n_frames)
    saved = {}
    real_alignment, real_stage = cm.rigid_alignment_with_scale, cm.sequence_stage

    def alignment(*a, **k):
        saved["S"] = real_alignment(*a, **k)
        return saved["S"]

    def stage(model, template, shape, poses, frames_t, tracker_t, base, J, o, known_shape=None):
        saved.update(shape=shape, poses=poses, clouds=[(f.points, f.normals) for f in frames_t],
                     sensor=frames_t[0].sensor_center, tracker_t=tracker_t, base=base, J=J, known_shape=known_shape)
        raise _Stop

    cm.rigid_alignment_with_scale, cm.sequence_stage = alignment, stage
    t0 = time.process_time()
    try:
        cm.capture_arm_sequence(session, model, template, cm.CaptureOptions(**options),
                                known_shape=bm.shape_of(subject))
    except _Stop:
        pass
    finally:
        cm.rigid_alignment_with_scale, cm.sequence_stage = real_alignment, real_stage
    saved["per_frame_cpu_s"] = time.process_time() - t0
    with open(path, "wb") as fh:
        pickle.dump(saved, fh, protocol=pickle.HIGHEST_PROTOCOL)
    return saved


def depth_frames(state: dict, template, options) -> list:
    """The state's depth points as ``refine.DepthFrame``s (k-d trees rebuilt)."""
    from scipy.spatial import cKDTree

    from bodystudio.muscle.nicp import vertex_neighbourhoods
    from bodystudio.muscle.refine import DepthFrame

    F = np.asarray(template.faces, np.int64)
    adjacency = vertex_neighbourhoods(F, template.n_vertices, rings=2)
    return [DepthFrame(P, N, cKDTree(P), state["sensor"], template.arm_mask, adjacency, options.nicp.filters, F)
            for P, N in state["clouds"]]


def finish(model, template, frames, state, options, poses, base, J, smooth: bool = True):
    """Pose smoothing, the model meshes, the Sec. 7 refinement: the world meshes (T, n, 3) of the pipeline."""
    from bodystudio.muscle import capture as cm
    from bodystudio.muscle.nicp import apply_similarity
    from bodystudio.muscle.refine import skeleton_model_mesh, smooth_arm_poses

    if smooth and options.pose_sigma_frames > 0:
        poses = smooth_arm_poses(poses, options.pose_sigma_frames, degree=options.pose_smoothing_degree)
    M = [skeleton_model_mesh(model, p, base, J, options.norm_limit) for p in poses]
    out = cm._refinement(M, poses, [(f.points, f.normals) for f in frames], [f.tree for f in frames],
                         np.asarray(template.faces, np.int64), frames[0].sensor_center, template.arm_mask,
                         frames[0].adjacency, J, options, cm._Timer(), camera=state["camera"],
                         similarity=state["S"])
    return np.stack([apply_similarity(state["S"], X) for X in out])


def breakdown(X: np.ndarray, truth: dict, template) -> dict:
    """The issue's figures plus the median per region (``muscle_regions.arm_regions`` and the wrist), per side and
    per elbow-flexion bin of the truth (mm)."""
    from benchmarks.muscle_regions import arm_regions
    from bodystudio.muscle.evaluate import score_arm_sequence

    G, vis, gtJ, flex = truth["G"], truth["vis"], truth["gtJ"], truth["flexion_deg"]
    s = score_arm_sequence(X, G, truth["template"], vis, gtJ)
    arm = template.arm_mask
    err = np.linalg.norm(X - G, axis=2) * 1000.0
    regions = dict(arm_regions(template), wrist=arm & (template.part_weights[:, 3] > 0.1))
    out = {k: s[k] for k in ("median_mm", "p90_mm", "front_median_mm", "back_median_mm", "bulge_err_mm",
                             "jitter_mm")}
    for name, m in regions.items():
        out[f"{name}_front"] = float(np.median(err[:, m][vis[:, m]]))
        out[f"{name}_back"] = float(np.median(err[:, m][~vis[:, m]]))
        out[name] = float(np.median(err[:, m]))
    for lo, hi in zip(FLEXION_BINS[:-1], FLEXION_BINS[1:], strict=True):
        sel = (flex >= lo) & (flex < hi)
        out[f"flex_{lo:.0f}_{hi:.0f}"] = float(np.median(err[sel][:, arm])) if sel.any() else float("nan")
    return out


def ground_truth(work: Path, subject_seed: int, n_frames: int = 200) -> dict:
    from benchmarks import bench_muscle as bm
    from benchmarks.muscle_sequences import session_of
    from bodystudio.muscle.arm import ArmPose
    from bodystudio.muscle.evaluate import session_ground_truth

    subject, session = session_of(work, subject_seed, 0, n_frames)
    truth = bm.truth_template(subject)
    ids = list(session.frame_ids)
    cached = work / f"owners_{subject_seed}_truth_{n_frames}.npz"
    if cached.is_file():
        with np.load(cached) as z:
            G, vis, gtJ = z["G"], z["vis"], z["gtJ"]
    else:
        G, vis, gtJ = session_ground_truth(session, truth, ids)
        np.savez(cached, G=G, vis=vis, gtJ=gtJ)
    poses = [ArmPose.from_dict(session.frame(i).gt_arm_pose) for i in ids]
    from bodystudio.muscle.refine import elbow_axes

    h, _ = elbow_axes(truth.joints)
    flex = np.array([np.degrees(abs(p.angles[1] @ h)) for p in poses])
    return {"G": G, "vis": vis, "gtJ": gtJ, "poses": poses, "template": truth, "flexion_deg": flex,
            "camera": session.kinect.depth, "subject": subject}


def truth_in_template_space(truth: dict, S) -> tuple[list, np.ndarray]:
    """The truth's poses and per-frame posed joints mapped into the capture's template space (``S``: template ->
    world, a translation by default)."""
    from bodystudio.muscle import capture as cm
    from bodystudio.muscle.arm import ArmPose
    from bodystudio.muscle.nicp import apply_similarity

    s, R, t = S
    A = np.eye(4)
    A[:3, :3] = R.T / s
    A[:3, 3] = -(R.T @ t) / s
    poses = [ArmPose(A @ p.root, p.angles) for p in truth["poses"]]
    gtJ = np.stack([apply_similarity(cm._inverse_similarity(S), j) for j in truth["gtJ"]])
    return poses, gtJ


def with_shoulders(poses: list, J: np.ndarray, shoulders: np.ndarray) -> list:
    """Each pose's root translated so that its posed rest shoulder lands on ``shoulders[k]``."""
    from bodystudio.muscle.arm import ArmPose
    from bodystudio.muscle.refine import posed_joints

    out = []
    for p, target in zip(poses, shoulders, strict=True):
        root = p.root.copy()
        root[:3, 3] += target - posed_joints(J, p)[0]
        out.append(ArmPose(root, p.angles))
    return out


def sequence_result(work: Path, subject_seed: int, name: str, model, template, state: dict, frames: list, o):
    """The sequence stage's poses, rest arm and rest joints on the cached state (cached too) and its CPU seconds."""
    from bodystudio.muscle import capture as cm

    path = work / f"owners_{subject_seed}_{name}_sequence.pkl"
    if path.is_file():
        with open(path, "rb") as fh:
            return pickle.load(fh)
    t0 = time.process_time()
    poses, base, J = cm.sequence_stage(model, template, state["shape"], state["poses"], frames, state["tracker_t"],
                                       state["base"], state["J"], o, state["known_shape"])
    out = (poses, base, J, time.process_time() - t0)
    with open(path, "wb") as fh:
        pickle.dump(out, fh, protocol=pickle.HIGHEST_PROTOCOL)
    return out


def owner_rows(work: Path, subject_seed: int, options: dict, name: str, pre: Path | None = None,
               refit_rest: bool = True) -> dict:
    """The rows of the module docstring for one session: {row name: breakdown} (``refit_rest=False``: without the
    costly "true rest, poses re-fitted" row)."""
    from benchmarks import bench_muscle as bm
    from benchmarks.muscle_energy import work_model
    from bodystudio.muscle import capture as cm
    from bodystudio.muscle.arm import ArmPose
    from bodystudio.muscle.refine import fit_arm_sequence_skeleton, smooth_arm_poses

    template = bm._template()
    model = work_model(work, template)
    o = cm.CaptureOptions(**options)
    state = capture_state(work, subject_seed, options, name, pre=pre)
    truth = ground_truth(work, subject_seed)
    state["camera"] = truth["camera"]
    frames = depth_frames(state, template, o)
    poses, base, J, seq_cpu = sequence_result(work, subject_seed, name, model, template, state, frames, o)
    true_poses, true_J = truth_in_template_space(truth, state["S"])
    rows = {}

    def row(label, *args, **kw):
        t1 = time.process_time()
        rows[label] = breakdown(finish(model, template, frames, state, o, *args, **kw), truth, template)
        rows[label]["cpu_s"] = round(time.process_time() - t1, 1)
        print(subject_seed, label, json.dumps({k: round(v, 2) for k, v in rows[label].items()}), flush=True)

    row("capture", poses, base, J)
    rows["capture"]["sequence_stage_cpu_s"] = round(seq_cpu, 1)
    smoothed = smooth_arm_poses(poses, o.pose_sigma_frames, degree=o.pose_smoothing_degree) \
        if o.pose_sigma_frames > 0 else poses
    shoulders = true_J[:, 0]
    angles_true = [ArmPose(p.root, g.angles) for p, g in zip(smoothed, true_poses, strict=True)]
    row("true angles", angles_true, base, J, smooth=False)
    row("true placement", with_shoulders(poses, J, shoulders), base, J)
    row("true angles + placement", with_shoulders(angles_true, J, shoulders), base, J, smooth=False)
    tt = truth["template"]
    base_t = tt.vertices - tt.joints[0] + J[0]
    J_t = tt.joints - tt.joints[0] + J[0]
    row("true rest, capture poses", poses, base_t, J_t)
    if not refit_rest:
        row("all truth", with_shoulders(true_poses, J_t, shoulders), base_t, J_t, smooth=False)
        return rows
    tracker_weight = cm.sequence_tracker_weight(o, model, poses, frames, base_t, J_t, state["tracker_t"])
    refit, _ = fit_arm_sequence_skeleton(
        model, state["shape"], poses, frames, J_t, o.norm_limit, state["tracker_t"], tracker_weight,
        o.sequence_smooth_weight, o.sequence_rounds, o.sequence_max_nfev, o.sequence_huber_m, o.sequence_fit_root,
        False, o.sequence_skeleton_prior_weight, o.sequence_depth_huber_only, rest=base_t,
        torso_pair_weight=o.sequence_torso_pair_weight)
    row("true rest, poses re-fitted", refit, base_t, J_t)
    row("all truth", with_shoulders(true_poses, J_t, shoulders), base_t, J_t, smooth=False)
    return rows


def heldout_energy_mm(model, frames: list, poses: list, base, J, o) -> float:
    """The depth energy (``refine.depth_energy_mm``) of the odd frames with each odd frame's angles the mean of its
    two even neighbours' (a data-side figure: the even frames' poses judged on depth they were not refitted to)."""
    from bodystudio.muscle.arm import ArmPose
    from bodystudio.muscle.refine import depth_energy_mm

    odd = range(1, len(poses) - 1, 2)
    mid = [ArmPose(poses[k].root, 0.5 * (poses[k - 1].angles + poses[k + 1].angles)) for k in odd]
    return depth_energy_mm(model, mid, [frames[k] for k in odd], base, J, o.norm_limit, o.sequence_huber_m)


def refit_rows(work: Path, subject_seed: int, options: dict, name: str, variants: dict, pre: Path | None = None,
               frames_step: int = 1) -> dict:
    """The sequence stage's result, then ``refine.refit_arm_poses_to_depth`` with each variant's keywords, scored like
    :func:`owner_rows`' rows, with the held-out depth energy (:func:`heldout_energy_mm`: the refit on the even frames
    only, judged on the odd ones) and the refit's CPU seconds."""
    from benchmarks import bench_muscle as bm
    from benchmarks.muscle_energy import work_model
    from bodystudio.muscle import capture as cm
    from bodystudio.muscle.refine import refit_arm_poses_to_depth

    template = bm._template()
    model = work_model(work, template)
    o = cm.CaptureOptions(**options)
    state = capture_state(work, subject_seed, options, name, pre=pre)
    truth = ground_truth(work, subject_seed)
    state["camera"] = truth["camera"]
    frames = depth_frames(state, template, o)
    poses, base, J, _ = sequence_result(work, subject_seed, name, model, template, state, frames, o)
    tracker = state["tracker_t"]
    rows = {}
    for label, kw in variants.items():
        kw = dict(kw)
        tw = kw.pop("tracker_weight", 0.0)
        common = dict(norm_limit=o.norm_limit, huber_m=o.sequence_huber_m, **kw)
        if label == "none":
            refit, cpu = poses, 0.0
            even = poses
        else:
            t0 = time.process_time()
            refit = refit_arm_poses_to_depth(model, poses, frames, base, J, tracker_joints=tracker,
                                             tracker_weight=tw, **common)
            cpu = time.process_time() - t0
            even = list(poses)
            ev = list(range(0, len(poses), 2))
            for k, p in zip(ev, refit_arm_poses_to_depth(model, [poses[k] for k in ev], [frames[k] for k in ev],
                                                         base, J, tracker_joints=None if tracker is None else
                                                         tracker[ev], tracker_weight=tw, **common), strict=True):
                even[k] = p
        r = breakdown(finish(model, template, frames, state, o, refit, base, J), truth, template)
        r["heldout_energy_mm"] = heldout_energy_mm(model, frames, even, base, J, o)
        r["refit_cpu_ms_per_frame"] = 1000.0 * cpu / len(poses)
        rows[label] = r
        print(subject_seed, label, json.dumps({k: round(v, 3) for k, v in r.items()}), flush=True)
    return rows


COLUMNS = ("median_mm", "p90_mm", "front_median_mm", "back_median_mm", "shoulder", "biceps", "upper_arm", "elbow",
           "forearm", "wrist", "flex_0_45", "flex_45_75", "flex_75_105", "flex_105_180", "bulge_err_mm")


def render(results: dict, columns: tuple = COLUMNS) -> str:
    from benchmarks.timing import markdown_table

    rows = [[f"{s}", label, *(f"{r.get(k, float('nan')):.2f}" for k in columns)]
            for s, res in results.items() for label, r in res.items()]
    return markdown_table(["session", "row", *columns], rows)


def main(argv: list[str] | None = None) -> None:
    from benchmarks.muscle_regions import parse_variant

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, required=True)
    parser.add_argument("--session", action="append", type=int, default=[], help="subject seed (repeatable)")
    parser.add_argument("--options", default=",".join(f"{k}={v}" for k, v in JOINT_FIT.items()),
                        help="KEY=VALUE,... CaptureOptions fields (default: the joint rest-shape fit, norm limit 0.2)")
    parser.add_argument("--name", default="joint_nl02", help="the cached state's name")
    parser.add_argument("--pre", type=Path, default=None, help="a folder with an earlier cache pre_SUBJECT.pkl of "
                        "the per-frame state (the per-frame stage with CaptureOptions())")
    parser.add_argument("--no-rest-refit", action="store_true", help="leave out the 'true rest, poses re-fitted' row")
    parser.add_argument("--refit", action="append", default=[], help="NAME:KEY=VALUE,... keywords of "
                        "refine.refit_arm_poses_to_depth (and tracker_weight); 'none': the sequence stage's poses. "
                        "Given: these rows instead of the decomposition")
    args = parser.parse_args(argv)
    _, options = parse_variant("x:" + args.options)
    args.work.mkdir(parents=True, exist_ok=True)
    results = {}
    if args.refit:
        variants = dict(parse_variant(v) for v in args.refit)
        for s in args.session or [501]:
            results[s] = refit_rows(args.work, s, options, args.name, variants, args.pre)
            tag = "_".join(variants)[:80]
            (args.work / f"refit_{s}_{args.name}_{tag}.json").write_text(json.dumps(results[s]))
        print(render(results, COLUMNS + ("heldout_energy_mm", "refit_cpu_ms_per_frame")))
        return
    for s in args.session or [501]:
        results[s] = owner_rows(args.work, s, options, args.name, args.pre, not args.no_rest_refit)
        (args.work / f"owners_{s}_{args.name}.json").write_text(json.dumps(results[s]))
    print(render(results))


if __name__ == "__main__":
    main()
