"""Arm-muscle capture (issue 11, fourteenth pass, the model stage): the fitted rest arm against the truth's, and the
capture end to end, per variant of the sequence stage's options.

For a 200-frame benchmark-like session (``muscle_sequences.session_of``: ``sample_arm_subject(SUBJECT)``, noise seed
0, Kinect v2 at 1 m, measured shape, the benchmark's model ``W/model.npz``) the per-frame stage runs once at
``CaptureOptions()`` and its state is cached (``muscle_owners.capture_state``, ``W/owners_SUBJECT_def_200.pkl``); each
variant (``NAME:KEY=VALUE,...`` over ``CaptureOptions()``, options of the sequence stage only: the rest-shape fit and
the sequence fit) re-runs the sequence stage on it (cached: ``W/rest_SUBJECT_NAME_sequence.pkl``), then the last
per-frame pose refit (``capture.POSE_REFIT``), the pose smoothing and the Sec. 7 refinement as ``CaptureOptions()``
does, and is scored against the truth:

- the issue's figures (``evaluate.score_arm_sequence``) and the median per region (``muscle_owners.breakdown``);
- the rest arm: per-vertex distance (mm) of the fitted rest arm from the truth's, both about their own shoulder joint
  (``rest``), its median over the vertices the sensor sees in most frames (``rest_front``) and the others
  (``rest_back``), after removing the mean offset (``rest_centred``: the shape alone), per region
  (``rest_shoulder`` ...), and the rest elbow / wrist joint's distance from the truth's (``rest_elbow_mm``,
  ``rest_wrist_mm``).

    python -m benchmarks.muscle_rest_arm --work W --session 501 --session 504 --session 507 --session 508 \\
        --variant default --variant "graze:body_rest_min_facing_cos=0.3,body_rest_prior_weight=50.0"

With ``--known-poses`` the capture is left out: the truth's joint angles and roots are held, the Kinect depth of
every 2nd frame is cleaned as the capture does (Sec. 4), and ``refine.fit_body_rest_shape`` (the measured arm length
at the capture's weight, no tracker) fits the rest arm from the regression's projection (also the prior's centre);
each variant's keywords are ``prior_weight``, ``min_facing_cos`` and ``stride`` (of those frames). The figures: the
rest arm as above and ``posed`` (the median distance of the posed fitted arm from the truth's, muscle_rest_ceiling's):

    python -m benchmarks.muscle_rest_arm --work W --session 501 --known-poses --variant base:stride=2 \
        --variant graze:stride=2,min_facing_cos=0.3,prior_weight=50.0

With ``--depth-bias`` the pairs' bias instead: every 10th frame's truth mesh paired with its cleaned depth (Sec. 4
at ``CaptureOptions()``' settings, and without the median and Gaussian filters) by ``DepthFrame.plane_pairs`` (the
Sec. 5.2 filters), the signed point-to-plane residual (mm, > 0: the truth in front of the depth's plane, nearer the
sensor) per bin of the truth vertex normal's cosine with the direction to the sensor:

    python -m benchmarks.muscle_rest_arm --work W --session 501 --depth-bias

docs/muscle.md "Capture, fourteenth pass (the rest arm)".
"""

from __future__ import annotations

import argparse
import json
import pickle
import time
from pathlib import Path

import numpy as np


def rest_arm_error(base: np.ndarray, joints: np.ndarray, truth_template, seen: np.ndarray, template) -> dict:
    """The fitted rest arm ``base`` (n, 3) and rest joints (3, 3) against the truth's, each about its own shoulder
    joint (mm): the median over the arm, its mostly-seen (``seen``) and other vertices, per region, without the mean
    offset, and the elbow / wrist joints' distances."""
    from benchmarks.muscle_regions import arm_regions

    arm = template.arm_mask
    d = (np.asarray(base) - joints[0]) - (truth_template.vertices - truth_template.joints[0])
    e = 1000.0 * np.linalg.norm(d, axis=1)
    centred = 1000.0 * np.linalg.norm(d - d[arm].mean(axis=0), axis=1)
    dj = 1000.0 * np.linalg.norm((joints - joints[0]) - (truth_template.joints - truth_template.joints[0]), axis=1)
    out = {"rest": float(np.median(e[arm])), "rest_front": float(np.median(e[arm & seen])),
           "rest_back": float(np.median(e[arm & ~seen])), "rest_centred": float(np.median(centred[arm])),
           "rest_elbow_mm": float(dj[1]), "rest_wrist_mm": float(dj[2])}
    regions = dict(arm_regions(template), wrist=arm & (template.part_weights[:, 3] > 0.1))
    out.update({f"rest_{k}": float(np.median(e[m])) for k, m in regions.items()})
    return out


def sequence_of(work: Path, subject_seed: int, name: str, model, template, state: dict, frames: list, o):
    """The sequence stage's poses, rest arm and rest joints for one variant (cached) and its CPU seconds."""
    from bodystudio.muscle import capture as cm

    path = work / f"rest_{subject_seed}_{name}_sequence.pkl"
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


def variant_rows(work: Path, subject_seed: int, variants: dict) -> dict:
    """{variant: figures} for one session (module docstring)."""
    from benchmarks import bench_muscle as bm
    from benchmarks.muscle_energy import work_model
    from benchmarks.muscle_owners import breakdown, capture_state, depth_frames, finish, ground_truth
    from bodystudio.muscle import capture as cm
    from bodystudio.muscle.refine import refit_arm_poses_to_depth

    template = bm._template()
    model = work_model(work, template)
    state = capture_state(work, subject_seed, {}, "def")
    truth = ground_truth(work, subject_seed)
    state["camera"] = truth["camera"]
    seen = truth["vis"].mean(axis=0) > 0.5
    rows = {}
    for name, options in variants.items():
        o = cm.CaptureOptions(**options)
        frames = depth_frames(state, template, o)
        poses, base, J, seq_cpu = sequence_of(work, subject_seed, name, model, template, state, frames, o)
        t0 = time.process_time()
        refit = dict(cm.POSE_REFIT)
        poses = refit_arm_poses_to_depth(model, poses, cm.facing_frames(frames, o.sequence_min_facing_cos), base, J,
                                         o.norm_limit, o.sequence_huber_m,
                                         state["tracker_t"], refit.pop("tracker_weight"), **refit)
        row = breakdown(finish(model, template, frames, state, o, poses, base, J), truth, template)
        row.update(rest_arm_error(base, J, truth["template"], seen, template))
        row["sequence_cpu_s"] = seq_cpu
        row["after_cpu_s"] = time.process_time() - t0
        rows[name] = row
        print(subject_seed, name, json.dumps({k: round(v, 2) for k, v in row.items()}), flush=True)
    return rows


def known_pose_rows(work: Path, subject_seed: int, variants: dict) -> dict:
    """{variant: figures} of the rest-shape fit with the truth's poses held (module docstring, ``--known-poses``)."""
    from dataclasses import replace

    from scipy.spatial import cKDTree

    from benchmarks import bench_muscle as bm
    from benchmarks.muscle_energy import work_model
    from benchmarks.muscle_sequences import session_of
    from bodystudio.muscle.arm import ArmPose
    from bodystudio.muscle.capture import CaptureOptions
    from bodystudio.muscle.depth import clean_depth, depth_point_cloud
    from bodystudio.muscle.evaluate import visible_vertices
    from bodystudio.muscle.model import (
        body_shape_space,
        model_joints,
        model_rest_vertices,
        project_to_body_space,
    )
    from bodystudio.muscle.nicp import vertex_neighbourhoods
    from bodystudio.muscle.refine import DepthFrame, fit_body_rest_shape, skeleton_model_mesh

    template = bm._template()
    model = work_model(work, template)
    subject, session = session_of(work, subject_seed, 0, 200)
    truth, shape = bm.truth_template(subject), bm.shape_of(subject)
    space = body_shape_space(template)
    o = CaptureOptions()
    F = np.asarray(template.faces, np.int64)
    adjacency = vertex_neighbourhoods(F, len(template.vertices), rings=2)
    camera = session.kinect.depth
    frames, poses, meshes, vis = [], [], [], []
    for fid in session.frame_ids[::2]:
        fr = session.frame(fid)
        P, N = depth_point_cloud(clean_depth(fr.kinect_depth_m, o.depth), camera)
        frames.append(DepthFrame(P, N, cKDTree(P), camera.center, template.arm_mask, adjacency, o.nicp.filters, F))
        poses.append(ArmPose.from_dict(fr.gt_arm_pose))
        meshes.append(np.asarray(fr.gt_arm_mesh.vertices, np.float64))
        vis.append(visible_vertices(meshes[-1], F, camera))
    seen = np.mean(vis, axis=0) > 0.5
    shoulder = truth.joints[0]
    mean, sigma = space.prior(shape)
    x_reg = project_to_body_space(space, model_rest_vertices(model, shape), model_joints(model, shape), mean, sigma)

    def figures(x, shift):
        rest, J = space.rest_and_joints(x, shoulder)
        d = []
        for p, G in zip(poses, meshes, strict=True):
            root = p.root.copy()
            root[:3, 3] += shift
            M = skeleton_model_mesh(model, ArmPose(root, p.angles), rest, J, o.norm_limit)
            d.append(np.linalg.norm(M - G, axis=1)[template.arm_mask])
        return {"posed": 1000.0 * float(np.median(d)), **rest_arm_error(rest, J, truth, seen, template)}

    rows = {"regression": figures(x_reg, np.zeros(3))}
    for name, kw in variants.items():
        stride = int(kw.get("stride", 2))
        fr = [replace(f, min_facing_cos=float(kw.get("min_facing_cos", 0.0))) for f in frames[::stride]]
        x, shift = fit_body_rest_shape(space, model, poses[::stride], fr, x_reg, shoulder, x_reg, sigma,
                                       float(kw.get("prior_weight", o.body_rest_prior_weight)), o.norm_limit,
                                       o.sequence_huber_m, o.body_rest_iterations, True, shape.arm_length_m,
                                       o.body_rest_arm_length_weight)
        rows[name] = figures(x, shift)
    for name, row in rows.items():
        print(subject_seed, name, json.dumps({k: round(v, 2) for k, v in row.items()}), flush=True)
    return rows


FACING_BINS = ((0.9, 1.01), (0.7, 0.9), (0.5, 0.7), (0.3, 0.5), (0.0, 0.3))


def depth_bias_rows(work: Path, subject_seed: int, frame_step: int = 10) -> dict:
    """{depth clean-up: {cosine bin: (pairs, mean, median residual mm)}} (module docstring, ``--depth-bias``)."""
    from scipy.spatial import cKDTree

    from benchmarks import bench_muscle as bm
    from benchmarks.muscle_sequences import session_of
    from bodystudio.geometry.mesh import vertex_normals
    from bodystudio.muscle.capture import CaptureOptions
    from bodystudio.muscle.depth import DepthCleanupOptions, clean_depth, depth_point_cloud
    from bodystudio.muscle.nicp import vertex_neighbourhoods
    from bodystudio.muscle.refine import DepthFrame

    template = bm._template()
    _, session = session_of(work, subject_seed, 0, 200)
    camera = session.kinect.depth
    o = CaptureOptions()
    F = np.asarray(template.faces, np.int64)
    adjacency = vertex_neighbourhoods(F, template.n_vertices, rings=2)
    cleanups = {"cleaned (Sec. 4)": o.depth, "no median / Gaussian": DepthCleanupOptions(median_px=1,
                                                                                         gaussian_sigma_px=0.0)}
    out = {}
    for label, depth_options in cleanups.items():
        r_all, c_all = [], []
        for fid in list(session.frame_ids)[::frame_step]:
            fr = session.frame(fid)
            G = np.asarray(fr.gt_arm_mesh.vertices, np.float64)
            P, N = depth_point_cloud(clean_depth(fr.kinect_depth_m, depth_options), camera)
            frame = DepthFrame(P, N, cKDTree(P), camera.center, template.arm_mask, adjacency, o.nicp.filters, F)
            k, q, n = frame.plane_pairs(G)
            to_sensor = camera.center - G[k]
            r_all.append(1000.0 * np.einsum("kd,kd->k", G[k] - q, n))
            c_all.append(np.einsum("kd,kd->k", vertex_normals(G, F)[k], to_sensor)
                         / np.linalg.norm(to_sensor, axis=1))
        r, c = np.concatenate(r_all), np.concatenate(c_all)
        out[label] = {f"{lo:.1f}-{min(hi, 1.0):.1f}": (int(m.sum()), float(r[m].mean()), float(np.median(r[m])))
                      for lo, hi in FACING_BINS for m in [(c >= lo) & (c < hi)] if m.any()}
        print(subject_seed, label, json.dumps(out[label]), flush=True)
    return out


KNOWN_POSE_KEYS = {"prior_weight", "min_facing_cos", "stride"}
COLUMNS = ("median_mm", "p90_mm", "front_median_mm", "back_median_mm", "bulge_err_mm", "jitter_mm", "rest",
           "rest_front", "rest_back", "rest_centred", "rest_elbow_mm", "rest_wrist_mm", "sequence_cpu_s")


def render(results: dict, columns: tuple = COLUMNS) -> str:
    from benchmarks.timing import markdown_table

    rows = [[f"{s}", name, *(f"{r.get(k, float('nan')):.2f}" for k in columns)]
            for s, res in results.items() for name, r in res.items()]
    names = {name for res in results.values() for name in res}
    for name in sorted(names):
        have = [res[name] for res in results.values() if name in res]
        if len(have) == len(results) > 1:
            rows.append(["mean", name, *(f"{np.mean([r[k] for r in have]):.2f}" for k in columns)])
    return markdown_table(["session", "variant", *columns], rows)


def main(argv: list[str] | None = None) -> None:
    from benchmarks.muscle_regions import parse_variant

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, required=True)
    parser.add_argument("--session", action="append", type=int, default=[], help="subject seed (repeatable)")
    parser.add_argument("--variant", action="append", default=[], help="NAME[:KEY=VALUE,...] over CaptureOptions() "
                        "(sequence-stage options only; 'default': CaptureOptions()); with --known-poses the keys "
                        "prior_weight, min_facing_cos, stride")
    parser.add_argument("--known-poses", action="store_true", help="the rest-shape fit alone, the truth's poses held")
    parser.add_argument("--depth-bias", action="store_true", help="the truth's pairs' residuals per facing angle")
    args = parser.parse_args(argv)
    from bodystudio.errors import InputError
    from bodystudio.muscle.capture import CaptureOptions

    try:
        variants = dict(parse_variant(v) for v in (args.variant or ["default"]))
        for options in variants.values():
            if args.known_poses:
                if set(options) - KNOWN_POSE_KEYS:
                    raise ValueError(f"unknown keys {sorted(set(options) - KNOWN_POSE_KEYS)} with --known-poses "
                                     f"(use {', '.join(sorted(KNOWN_POSE_KEYS))})")
            else:
                CaptureOptions(**options)
    except (ValueError, SyntaxError, TypeError, InputError) as exc:
        parser.error(f"--variant: {exc}")
    args.work.mkdir(parents=True, exist_ok=True)
    results = {}
    if args.depth_bias:
        from benchmarks.timing import markdown_table

        rows = []
        for s in args.session or [501]:
            for label, bins in depth_bias_rows(args.work, s).items():
                rows += [[f"{s}", label, b, f"{n}", f"{mean:+.2f}", f"{med:+.2f}"]
                         for b, (n, mean, med) in bins.items()]
        print(markdown_table(["session", "depth", "cos", "pairs", "mean mm", "median mm"], rows))
        return
    if args.known_poses:
        for s in args.session or [501]:
            results[s] = known_pose_rows(args.work, s, variants)
        print(render(results, ("posed", *COLUMNS[6:12])))
        return
    for s in args.session or [501]:
        results[s] = variant_rows(args.work, s, variants)
        path = args.work / f"rest_{s}.json"
        kept = json.loads(path.read_text()) if path.is_file() else {}
        path.write_text(json.dumps({**kept, **results[s]}))
    print(render(results))


if __name__ == "__main__":
    main()
