"""Arm-muscle capture (issue 11, fifteenth pass): where the worst 10 % of the vertex-frames lie, and why 507 / 508 miss
the p90 goal that 501 / 504 meet.

On the cached refinement inputs of ``benchmarks.muscle_front --step cache`` (``W/front_SUBJECT_state.pkl``, the
capture at ``CaptureOptions()``), the default refinement (or a variant) is re-run and its per-vertex errors broken down
over the arm vertices of every frame: the share of vertex-frames over the goal's 5 mm (the p90 goal is met when it is
under 10 %) and each category's part of it, by region (:func:`tail_regions`), by frame (the truth's elbow flexion and
shoulder elevation, the sequence's ends), by side (the truth's z-buffer: seen / unseen), and by direction (along the
true surface's normal / tangential, the tangential part along the bone / around it).

    python -m benchmarks.muscle_tail --work W --session 501 --session 504 --session 507 --session 508

The rest-shape fit's outline pairs (docs/muscle.md "Capture, sixteenth pass"):

    python -m benchmarks.muscle_tail --work W --rest-variants --session 508 --session 513 \
        --variant "pop10:body_rest_outline_weight=0.0,body_rest_population_locals=1.0" \
        --variant "ol1x2:body_rest_outline_weight=1.0,body_rest_population_locals=2.0"

docs/muscle.md "Capture, fifteenth pass".
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

GOAL_MM = 5.0
FLEXION_BINS = (0.0, 45.0, 75.0, 105.0, 180.0)
ELEVATION_BINS = (0.0, 40.0, 55.0, 90.0)
END_FRAMES = 10


def tail_regions(template) -> dict:
    """Named, disjoint vertex masks of the arm (``template.arm_mask``) in the rest pose, first match wins:

    ``wrist`` (> 5 % hand weight), ``chest_border`` (> 20 % torso weight, in front of the shoulder joint),
    ``back_border`` (> 20 % torso weight, behind it), ``armpit`` / ``deltoid`` (upper arm within 30 % of its length
    from the shoulder, on the body's side / the outer side and the top), ``elbow_crease`` / ``elbow_back``
    (within 5 cm of the elbow joint, on the inside of its bend / the outside), ``biceps``
    (``evaluate.biceps_region``), ``triceps`` (the upper arm's back), ``upper_arm_sides``, ``forearm``."""
    from bodystudio.muscle.evaluate import biceps_region

    V, pw, (s, e, w) = template.vertices, template.part_weights, template.joints
    arm = template.arm_mask
    z = np.array([0.0, 0.0, 1.0])

    def frame(a0, a1):
        a = (a1 - a0) / np.linalg.norm(a1 - a0)
        t = (V - a0) @ a / np.linalg.norm(a1 - a0)
        r = (V - a0) - np.outer((V - a0) @ a, a)
        r /= np.maximum(np.linalg.norm(r, axis=1, keepdims=True), 1e-12)
        front = z - (z @ a) * a
        front /= np.linalg.norm(front)
        out = np.cross(a, front)
        out *= np.sign(out[0]) if template.side == "left" else -np.sign(out[0])
        return t, r @ front, r @ out

    tu, fu, ou = frame(s, e)
    d_elbow = np.linalg.norm(V - e, axis=1)
    masks = {}
    taken = ~arm

    def add(name, m):
        nonlocal taken
        masks[name] = m & ~taken
        taken = taken | m

    add("wrist", pw[:, 3] > 0.05)
    add("chest_border", (pw[:, 0] > 0.2) & (V[:, 2] >= s[2]))
    add("back_border", pw[:, 0] > 0.2)
    near_shoulder = (pw[:, 1] >= pw[:, 2]) & (tu < 0.3)
    add("armpit", near_shoulder & (ou < -0.3))
    add("deltoid", near_shoulder)
    near_elbow = d_elbow < 0.05
    a_u = (e - s) / np.linalg.norm(e - s)
    inner = (w - e) - ((w - e) @ a_u) * a_u  # the inside of the elbow's bend
    add("elbow_crease", near_elbow & ((V - e) @ inner > 0))
    add("elbow_back", near_elbow)
    add("biceps", biceps_region(template))
    add("triceps", (pw[:, 1] >= pw[:, 2]) & (fu < -0.5))
    add("upper_arm_sides", pw[:, 1] >= pw[:, 2])
    add("forearm", np.ones(len(V), bool))
    return masks


def frame_bins(n_frames: int, noise_seed: int, flexion_deg: np.ndarray) -> dict:
    """Named frame masks: the truth's elbow flexion and shoulder elevation bins (the session's motion,
    ``synthetic.arm_angle_sequence``) and the sequence's first / last frames."""
    from bodystudio.muscle.synthetic import arm_angle_sequence

    elevation = arm_angle_sequence("elbow_flex", n_frames, noise_seed)[:, 1]
    out = {}
    for lo, hi in zip(FLEXION_BINS[:-1], FLEXION_BINS[1:], strict=True):
        out[f"flexion_{lo:.0f}_{hi:.0f}"] = (flexion_deg >= lo) & (flexion_deg < hi)
    for lo, hi in zip(ELEVATION_BINS[:-1], ELEVATION_BINS[1:], strict=True):
        out[f"elevation_{lo:.0f}_{hi:.0f}"] = (elevation >= lo) & (elevation < hi)
    ends = np.zeros(n_frames, bool)
    ends[:END_FRAMES] = ends[-END_FRAMES:] = True
    out["ends"] = ends
    out["middle"] = ~ends
    return out


def error_directions(X: np.ndarray, G: np.ndarray, faces: np.ndarray, gtJ: np.ndarray, part_weights: np.ndarray):
    """Each vertex-frame's error (mm) along the true surface's normal (signed, + outside) and its tangential part
    split along the vertex's bone (shoulder-elbow or elbow-wrist of the truth's posed joints) and around it."""
    from bodystudio.geometry.mesh import vertex_normals

    E = X - G
    NG = np.stack([vertex_normals(g, faces) for g in G])
    en = np.einsum("tnd,tnd->tn", E, NG)
    Et = E - en[..., None] * NG
    fore = part_weights[:, 2] + part_weights[:, 3] > part_weights[:, 1] + part_weights[:, 0]
    a_up = gtJ[:, 1] - gtJ[:, 0]
    a_fo = gtJ[:, 2] - gtJ[:, 1]
    A = np.where(fore[None, :, None], a_fo[:, None, :], a_up[:, None, :])
    A = A / np.linalg.norm(A, axis=2, keepdims=True)
    # the bone direction within the tangent plane
    At = A - np.einsum("tnd,tnd->tn", A, NG)[..., None] * NG
    At /= np.maximum(np.linalg.norm(At, axis=2, keepdims=True), 1e-12)
    along = np.einsum("tnd,tnd->tn", Et, At)
    around = np.linalg.norm(Et - along[..., None] * At, axis=2)
    return 1000 * en, 1000 * along, 1000 * around


def constant_error_removed(X: np.ndarray, G: np.ndarray, template, poses) -> np.ndarray:
    """The estimate with each vertex's error that is constant over the sequence in its part's frame (the truth's
    skinning rotations) removed: what a perfect rest-arm layout would leave (``muscle_front``'s oracle)."""
    from bodystudio.muscle.arm import part_transforms

    W = template.part_weights
    R = []
    for p in poses:
        T = part_transforms(template.joints, p)
        Rv = np.einsum("kp,pij->kij", W, T[:, :3, :3])
        u, _, vt = np.linalg.svd(Rv)
        R.append(u @ vt)
    R = np.stack(R)  # (T, n, 3, 3)
    local = np.einsum("tnji,tnj->tni", R, X - G)
    const = local.mean(axis=0)
    return X - np.einsum("tnij,nj->tni", R, const)


def tail_breakdown(X: np.ndarray, truth: dict, template, noise_seed: int = 0, extra: dict | None = None) -> dict:
    """The share of the arm's vertex-frames over the goal's 5 mm (%), and per category its own share over 5 mm and
    its part of the whole's (percentage points), with the category's share of the vertex-frames."""
    G, vis, gtJ = truth["G"], truth["vis"], truth["gtJ"]
    arm = template.arm_mask
    err = np.linalg.norm(X - G, axis=2) * 1000.0
    over = err > GOAL_MM
    n_all = arm.sum() * len(X)
    out = {"p90_mm": float(np.percentile(err[:, arm], 90)), "median_mm": float(np.median(err[:, arm])),
           "over5_pct": 100.0 * over[:, arm].sum() / n_all}

    en, along, around = error_directions(X, G, template.faces, gtJ, template.part_weights)

    def row(mask_tn):
        m = mask_tn & arm[None]
        n = m.sum()
        return {"share_pct": 100.0 * n / n_all, "over5_pct": 100.0 * over[m].sum() / max(n, 1),
                "part_pp": 100.0 * over[m].sum() / n_all, "median_mm": float(np.median(err[m])) if n else np.nan,
                "normal_signed_mm": float(np.mean(en[m])) if n else np.nan,
                "along_signed_mm": float(np.mean(along[m])) if n else np.nan}

    T = len(X)
    for name, m in tail_regions(template).items():
        out[f"region:{name}"] = row(np.broadcast_to(m[None], (T, len(m))))
    for name, f in frame_bins(T, noise_seed, truth["flexion_deg"]).items():
        out[f"frames:{name}"] = row(np.broadcast_to(f[:, None], (T, len(arm))))
    out["side:seen"] = row(vis)
    out["side:unseen"] = row(~vis)
    sel = over & arm[None]
    out["direction:over5"] = {"normal_abs_mm": float(np.median(np.abs(en[sel]))),
                              "normal_signed_mm": float(np.mean(en[sel])),
                              "along_bone_abs_mm": float(np.median(np.abs(along[sel]))),
                              "along_bone_signed_mm": float(np.mean(along[sel])),
                              "around_bone_mm": float(np.median(around[sel]))}
    sel = arm[None] & np.ones_like(over)
    out["direction:all"] = {"normal_abs_mm": float(np.median(np.abs(en[sel]))),
                            "along_bone_abs_mm": float(np.median(np.abs(along[sel]))),
                            "around_bone_mm": float(np.median(around[sel]))}
    for name, Y in (extra or {}).items():
        e2 = np.linalg.norm(Y - G, axis=2)[:, arm] * 1000.0
        out[f"oracle:{name}"] = {"median_mm": float(np.median(e2)), "p90_mm": float(np.percentile(e2, 90)),
                                 "over5_pct": 100.0 * (e2 > GOAL_MM).mean()}
    return out


def rest_arm_rows(p: dict) -> dict:
    """The capture's rest arm (the sequence stage's, ``front_*_state.pkl``'s ``rest`` / ``rest_joints``) against the
    truth's, both about their own shoulder joint, per :func:`tail_regions` region (mm): the median distance, the
    mean error along the truth's rest normal (+ outside) and along the upper arm (+ towards the elbow); and the rest
    bones' length errors."""
    from bodystudio.geometry.mesh import vertex_normals

    truth = p["truth"]["template"]
    R, J = np.asarray(p["rest"]), np.asarray(p["rest_joints"])
    E = (R - J[0]) - (truth.vertices - truth.joints[0])
    N = vertex_normals(truth.vertices, truth.faces)
    a = (truth.joints[1] - truth.joints[0]) / np.linalg.norm(truth.joints[1] - truth.joints[0])
    out = {}
    for name, m in tail_regions(truth).items():
        out[name] = {"median_mm": 1000 * float(np.median(np.linalg.norm(E[m], axis=1))),
                     "normal_signed_mm": 1000 * float(np.mean(np.einsum("kd,kd->k", E[m], N[m]))),
                     "along_upper_arm_mm": 1000 * float(np.mean(E[m] @ a))}
    arm = truth.arm_mask
    out["arm"] = {"median_mm": 1000 * float(np.median(np.linalg.norm(E[arm], axis=1))),
                  "normal_signed_mm": 1000 * float(np.mean(np.einsum("kd,kd->k", E[arm], N[arm]))),
                  "along_upper_arm_mm": 1000 * float(np.mean(E[arm] @ a))}
    bones = np.linalg.norm(np.diff(J, axis=0), axis=1) - np.linalg.norm(np.diff(truth.joints, axis=0), axis=1)
    out["bones_mm"] = {"upper_arm": 1000 * float(bones[0]), "forearm": 1000 * float(bones[1])}
    return out


def session_tail(work: Path, subject_seed: int, noise_seed: int = 0, variant: dict | None = None,
                 oracles: bool = True) -> dict:
    from benchmarks import muscle_front as mf
    from bodystudio.muscle import capture as cm

    p = mf.load_state(work, subject_seed, noise_seed)
    o = cm.CaptureOptions(**(variant or {}))
    X = mf.to_world(p, mf.refine(p, o))
    Xm = mf.to_world(p, p["model_meshes"])
    truth = p["truth"]
    template = truth["template"]
    extra = {"model_stage": Xm}
    if oracles:
        extra["constant_error_removed"] = constant_error_removed(X, truth["G"], template, truth["poses"])
    out = tail_breakdown(X, truth, template, noise_seed, extra)
    return out


def rest_variant_rows(work: Path, subject_seed: int, variants: dict) -> dict:
    """{variant: tail figures} of the sequence stage re-run per variant of ``CaptureOptions`` on the cached per-frame
    stage (``muscle_owners.capture_state``, ``W/owners_SUBJECT_def_200.pkl``; the sequence stage cached as
    ``muscle_rest_arm.sequence_of``'s ``W/rest_SUBJECT_NAME_sequence.pkl``), then the last pose refit, the pose
    smoothing and the Sec. 7 refinement on its own depth clean-up, as ``capture_arm_frames`` runs them."""
    from scipy.spatial import cKDTree

    from benchmarks import bench_muscle as bm
    from benchmarks.muscle_energy import work_model
    from benchmarks.muscle_owners import capture_state, depth_frames, ground_truth
    from benchmarks.muscle_rest_arm import sequence_of
    from benchmarks.muscle_sequences import session_of
    from bodystudio.muscle import capture as cm
    from bodystudio.muscle.depth import clean_depth, depth_point_cloud
    from bodystudio.muscle.nicp import apply_similarity
    from bodystudio.muscle.refine import refit_arm_poses_to_depth, skeleton_model_mesh, smooth_arm_poses

    template = bm._template()
    model = work_model(work, template)
    state = capture_state(work, subject_seed, {}, "def")
    truth = ground_truth(work, subject_seed)
    _, session = session_of(work, subject_seed, 0, len(truth["G"]))
    raw = [session.frame(f).kinect_depth_m for f in session.frame_ids]
    camera, S = truth["camera"], state["S"]
    Sinv = cm._inverse_similarity(S)
    F = np.asarray(template.faces, np.int64)
    refine_clouds = {}
    rows = {}
    for name, options in variants.items():
        o = cm.CaptureOptions(**options)
        frames = cm.with_outlines(depth_frames(state, template, o), raw, camera, S, template, o)
        poses, base, J, seq_cpu = sequence_of(work, subject_seed, name, model, template, state, frames, o)
        refit = dict(cm.POSE_REFIT)
        poses = refit_arm_poses_to_depth(model, poses, cm.facing_frames(frames, o.sequence_min_facing_cos), base, J,
                                         o.norm_limit, o.sequence_huber_m, state["tracker_t"],
                                         refit.pop("tracker_weight"), **refit)
        if o.pose_sigma_frames > 0:
            poses = smooth_arm_poses(poses, o.pose_sigma_frames, degree=o.pose_smoothing_degree,
                                     shoulder_degree=o.shoulder_smoothing_degree)
        M = [skeleton_model_mesh(model, p, base, J, o.norm_limit) for p in poses]
        d = cm.refinement_depth_options(o)
        if d not in refine_clouds:
            clouds = []
            for depth in raw:
                P, N = depth_point_cloud(clean_depth(depth, d), camera)
                clouds.append((apply_similarity(Sinv, P), N @ S[1]))
            refine_clouds[d] = (clouds, [cKDTree(P) for P, _ in clouds])
        clouds, trees = refine_clouds[d]
        out = cm._refinement(M, poses, clouds, trees, F, frames[0].sensor_center, template.arm_mask,
                             frames[0].adjacency, J, o, cm._Timer(), camera=camera, similarity=S)
        X = np.stack([apply_similarity(S, x) for x in out])
        from bodystudio.muscle.evaluate import score_arm_sequence

        row = tail_breakdown(X, truth, truth["template"])
        row.update({k: v for k, v in score_arm_sequence(X, truth["G"], truth["template"], truth["vis"],
                                                        truth["gtJ"]).items() if k not in row})
        row["rest"] = rest_arm_rows({"truth": truth, "rest": base, "rest_joints": J})
        row["sequence_cpu_s"] = seq_cpu
        rows[name] = row
        short = {k: round(row[k], 2) for k in ("median_mm", "p90_mm", "over5_pct", "front_median_mm",
                                                "back_median_mm", "bulge_err_mm", "jitter_mm")}
        short.update({f"pp_{k[7:]}": round(row[k]["part_pp"], 2) for k in row if k.startswith("region:")})
        print(subject_seed, name, json.dumps(short), flush=True)
    return rows


def print_table(results: dict) -> None:
    subjects = list(results)
    keys = [k for k in results[subjects[0]] if isinstance(results[subjects[0]][k], dict)]
    print("figure", *subjects, sep=" | ")
    for k in ("median_mm", "p90_mm", "over5_pct"):
        print(k, *[f"{results[s][k]:.2f}" for s in subjects], sep=" | ")
    for k in keys:
        cells = []
        for s in subjects:
            r = results[s][k]
            if "share_pct" in r:
                cells.append(f"{r['share_pct']:.1f}% / {r['over5_pct']:.1f}% / {r['part_pp']:.2f} / "
                             f"{r['median_mm']:.2f} / n{r['normal_signed_mm']:+.2f} a{r['along_signed_mm']:+.2f}")
            else:
                cells.append(" ".join(f"{kk}={vv:.2f}" for kk, vv in r.items()))
        print(k, *cells, sep=" | ")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, required=True)
    parser.add_argument("--session", type=int, action="append", required=True, help="subject seed (repeatable)")
    parser.add_argument("--noise-seed", type=int, default=0)
    parser.add_argument("--variant", action="append", default=[],
                        help="NAME or NAME:KEY=VALUE,... over CaptureOptions() (repeatable with --rest-variants)")
    parser.add_argument("--rest-variants", action="store_true",
                        help="re-run the sequence stage per variant on the cached per-frame stage (rest_variant_rows)")
    args = parser.parse_args(argv)
    from benchmarks.muscle_regions import parse_variant
    from bodystudio.errors import InputError
    from bodystudio.muscle.capture import CaptureOptions

    try:
        variants = dict(("default", {}) if v == "default" else parse_variant(v) for v in args.variant or ["default"])
        for kw in variants.values():
            CaptureOptions(**kw)
    except (ValueError, SyntaxError, TypeError, InputError) as exc:
        parser.error(f"--variant: {exc}")
    if args.rest_variants:
        results = {s: rest_variant_rows(args.work, s, variants) for s in args.session}
        (args.work / f"tail_rest_variants_{int(time.time())}.json").write_text(json.dumps(results))
        return
    if len(variants) > 1:
        parser.error("--variant: one variant without --rest-variants")
    name, kw = next(iter(variants.items()))
    results = {}
    for s in args.session:
        t0 = time.process_time()
        results[s] = session_tail(args.work, s, args.noise_seed, kw)
        print(s, f"{time.process_time() - t0:.0f} s CPU", flush=True)
    print_table(results)
    (args.work / f"tail_{name}_{int(time.time())}.json").write_text(json.dumps(results))


if __name__ == "__main__":
    main()
