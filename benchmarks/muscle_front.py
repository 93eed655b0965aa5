"""Arm-muscle capture (issue 11, fourteenth pass): why the seen (front) side is 2.6 mm off, and the biceps bulge.

``--step cache``: the whole capture of a session at ``CaptureOptions()`` (measured shape, as the benchmark runs it),
with the inputs of its Sec. 7 refinement (``capture._refinement``: the model meshes, poses, depth clouds in the
template's space, rest joints, the Sec. 5.1 similarity) saved to ``W/front_SUBJECT_state.pkl`` and the end-to-end
scores to ``W/front_SUBJECT_state.json`` (``--noise-seed N``: the session ``W/seq_SUBJECT_sN_200``, files
``front_SUBJECT_sN_state.*``). ``--step variants``: the refinement alone re-run on that state per variant
(``NAME:KEY=VALUE,...`` over ``CaptureOptions()``), scored against the truth, with ``--diagnose`` the front side's
error split into its part along the true surface's normal and its tangential part (sliding, which no depth pair can
see), the share of front vertices with a Sec. 7 pair, and the pairs' residuals against the true surface.

    python -m benchmarks.muscle_front --work W --session 501 --step cache
    python -m benchmarks.muscle_front --work W --session 501 --step variants --diagnose --variant default

docs/muscle.md "Capture, fourteenth pass".
"""

from __future__ import annotations

import argparse
import json
import pickle
import time
from pathlib import Path

import numpy as np


def state_path(work: Path, subject_seed: int, noise_seed: int = 0) -> Path:
    tag = f"{subject_seed}" if noise_seed == 0 else f"{subject_seed}_s{noise_seed}"
    return work / f"front_{tag}_state.pkl"


def ground_truth(work: Path, subject_seed: int, noise_seed: int, n_frames: int) -> dict:
    """``muscle_owners.ground_truth`` of the session with ``noise_seed`` (its motion differs from seed 0's)."""
    from benchmarks import muscle_owners as mo

    if noise_seed == 0:
        return mo.ground_truth(work, subject_seed, n_frames)
    from benchmarks import bench_muscle as bm
    from benchmarks.muscle_sequences import session_of
    from bodystudio.muscle.arm import ArmPose
    from bodystudio.muscle.evaluate import session_ground_truth
    from bodystudio.muscle.refine import elbow_axes

    subject, session = session_of(work, subject_seed, noise_seed, n_frames)
    truth = bm.truth_template(subject)
    ids = list(session.frame_ids)
    G, vis, gtJ = session_ground_truth(session, truth, ids)
    poses = [ArmPose.from_dict(session.frame(i).gt_arm_pose) for i in ids]
    h, _ = elbow_axes(truth.joints)
    flex = np.array([np.degrees(abs(p.angles[1] @ h)) for p in poses])
    return {"G": G, "vis": vis, "gtJ": gtJ, "poses": poses, "template": truth, "flexion_deg": flex,
            "camera": session.kinect.depth, "subject": subject}


def step_cache(work: Path, subject_seed: int, n_frames: int = 200, noise_seed: int = 0) -> dict:
    """Capture the session end to end at ``CaptureOptions()`` and keep the refinement's inputs."""
    from benchmarks import bench_muscle as bm
    from benchmarks.muscle_energy import work_model
    from benchmarks.muscle_sequences import session_of
    from bodystudio.muscle import capture as cm

    out = state_path(work, subject_seed, noise_seed).with_suffix(".json")
    if out.is_file() and state_path(work, subject_seed, noise_seed).is_file():
        return json.loads(out.read_text())
    template = bm._template()
    model = work_model(work, template)
    subject, session = session_of(work, subject_seed, noise_seed, n_frames)
    real = cm._refinement
    kept = {}

    def keep(model_meshes, poses, clouds_t, trees, F, C, arm, adjacency, joints, o, timer, camera=None,
             similarity=None):
        kept.update(model_meshes=model_meshes, poses=poses, clouds_t=clouds_t, F=F, C=C, arm=arm,
                    joints=joints, camera=camera, similarity=similarity)
        return real(model_meshes, poses, clouds_t, trees, F, C, arm, adjacency, joints, o, timer, camera, similarity)

    real_stage = cm.sequence_stage

    def keep_rest(*args, **kwargs):
        poses, rest, J = real_stage(*args, **kwargs)
        kept.update(rest=rest, rest_joints=J)  # the model meshes' rest arm (``skeleton_model_mesh``)
        return poses, rest, J

    cm._refinement, cm.sequence_stage = keep, keep_rest
    try:
        capture, scores = bm.capture_and_score(session, model, template, bm.truth_template(subject), "full",
                                               known_shape=bm.shape_of(subject))
    finally:
        cm._refinement, cm.sequence_stage = real, real_stage
    kept["frame_ids"] = list(capture.frame_ids)
    kept["timings_ms"] = capture.timings_ms
    with open(state_path(work, subject_seed, noise_seed), "wb") as fh:
        pickle.dump(kept, fh, protocol=pickle.HIGHEST_PROTOCOL)
    out.write_text(json.dumps(scores))
    return scores


def load_state(work: Path, subject_seed: int, noise_seed: int = 0) -> dict:
    """The cached refinement inputs of a session (``step_cache``) with the truth (world) and the depth trees."""
    from scipy.spatial import cKDTree

    from bodystudio.muscle.nicp import vertex_neighbourhoods

    with open(state_path(work, subject_seed, noise_seed), "rb") as fh:
        p = pickle.load(fh)
    p["trees"] = [cKDTree(P) for P, _ in p["clouds_t"]]
    p["adjacency"] = vertex_neighbourhoods(p["F"], len(p["model_meshes"][0]), rings=2)
    p["truth"] = ground_truth(work, subject_seed, noise_seed, len(p["model_meshes"]))
    p["work"], p["subject_seed"], p["noise_seed"] = work, subject_seed, noise_seed
    return p


def refinement_clouds(p: dict, options) -> tuple[list, list]:
    """The clouds and k-d trees the refinement pairs with: the cached ones, or the session's raw depth cleaned with the
    refinement's own filters (``capture.refinement_depth_options``), as ``capture_arm_frames`` makes them."""
    from scipy.spatial import cKDTree

    from benchmarks.muscle_sequences import session_of
    from bodystudio.muscle import capture as cm
    from bodystudio.muscle.depth import clean_depth, depth_point_cloud
    from bodystudio.muscle.nicp import apply_similarity

    o = cm.refinement_depth_options(options)
    if o == options.depth:
        return p["clouds_t"], p["trees"]
    key = ("clouds", o)
    if key not in p:
        for old in [k for k in p if isinstance(k, tuple) and k[0] == "clouds"]:
            del p[old]  # one option's clouds at a time (~0.4 GB per 200 frames)
        if "raw" not in p:
            _, session = session_of(p["work"], p["subject_seed"], p["noise_seed"], len(p["model_meshes"]))
            p["raw"] = [session.frame(f).kinect_depth_m for f in p["frame_ids"]]
        Sinv = cm._inverse_similarity(p["similarity"])
        clouds = []
        for d in p["raw"]:
            P, N = depth_point_cloud(clean_depth(d, o), p["camera"])
            clouds.append((apply_similarity(Sinv, P), N @ p["similarity"][1]))
        p[key] = (clouds, [cKDTree(P) for P, _ in clouds])
    return p[key]


def refine(p: dict, options) -> list[np.ndarray]:
    """``capture._refinement`` on the cached state (template space)."""
    from bodystudio.muscle import capture as cm

    clouds, trees = refinement_clouds(p, options)
    return cm._refinement(p["model_meshes"], p["poses"], clouds, trees, p["F"], p["C"], p["arm"],
                          p["adjacency"], p["joints"], options, cm._Timer(), camera=p["camera"],
                          similarity=p["similarity"])


def to_world(p: dict, meshes) -> np.ndarray:
    from bodystudio.muscle.nicp import apply_similarity

    return np.stack([apply_similarity(p["similarity"], M) for M in meshes])


def score(p: dict, X: np.ndarray) -> dict:
    from benchmarks import muscle_owners as mo

    return mo.breakdown(X, p["truth"], p["truth"]["template"])


def sec7_pairs(p: dict, options) -> tuple[list, list]:
    """Each frame's Sec. 7 correspondence targets (template space, NaN where no pair) and pair masks, as
    ``capture._refinement`` makes them before the temporal average."""
    from bodystudio.geometry.mesh import vertex_normals
    from bodystudio.muscle import capture as cm
    from bodystudio.muscle.nicp import (
        apply_similarity,
        closest_point_correspondences,
        filter_correspondences,
        plane_targets,
    )
    from bodystudio.muscle.refine import edge_on_pairs

    targets, kept = [], []
    clouds, trees = refinement_clouds(p, options)
    for M, (P, N), tree in zip(p["model_meshes"], clouds, trees, strict=True):
        pairs = closest_point_correspondences(M, P, N, tree)
        pairs = filter_correspondences(M, vertex_normals(M, p["F"]), pairs, p["C"], p["arm"], p["adjacency"],
                                       options.nicp.filters)
        if options.refine_visible_only:
            pairs.kept &= cm.model_visible_vertices(apply_similarity(p["similarity"], M), p["F"], p["camera"])
        if options.refine_min_facing_cos > 0:
            pairs.kept &= ~edge_on_pairs(M, vertex_normals(M, p["F"]), p["C"], options.refine_min_facing_cos)
        targets.append(np.where(pairs.kept[:, None], plane_targets(M, pairs), np.nan))
        kept.append(pairs.kept)
    return targets, kept


def front_diagnosis(p: dict, X_model: np.ndarray, X_full: np.ndarray, options) -> dict:
    """The seen side's error split (mm): along the true surface's normal and tangential (sliding along the skin, which
    no depth pair sees), the share of seen vertices with a Sec. 7 pair, the pairs' targets against the truth (signed
    along the true normal: + outside), binned by how squarely the true surface faces the sensor (|cos| of its normal
    with the view ray)."""
    from bodystudio.geometry.mesh import vertex_normals

    G, vis = p["truth"]["G"], p["truth"]["vis"]
    F, arm = p["F"], p["arm"]
    front = vis & arm[None]
    NG = np.stack([vertex_normals(g, F) for g in G])
    out = {}
    for label, X in (("model", X_model), ("full", X_full)):
        e = X - G
        en = np.einsum("tnd,tnd->tn", e, NG)
        et = np.linalg.norm(e - en[..., None] * NG, axis=2)
        out[f"{label}_front_normal_mm"] = float(np.median(np.abs(en[front]))) * 1000
        out[f"{label}_front_signed_normal_mm"] = float(np.mean(en[front])) * 1000
        out[f"{label}_front_tangential_mm"] = float(np.median(et[front])) * 1000
    targets, kept = sec7_pairs(p, options)
    K = np.stack(kept)
    T = to_world(p, [np.where(np.isnan(t), m, t) for t, m in zip(targets, p["model_meshes"], strict=True)])
    out["front_paired_share"] = float(K[front].mean())
    out["back_paired_share"] = float(K[~vis & arm[None]].mean())
    paired = front & K
    r = np.einsum("tnd,tnd->tn", T - G, NG)
    rm = np.einsum("tnd,tnd->tn", X_model - G, NG)
    rf = np.einsum("tnd,tnd->tn", X_full - G, NG)
    out["pair_target_abs_normal_mm"] = float(np.median(np.abs(r[paired]))) * 1000
    out["pair_target_signed_normal_mm"] = float(np.mean(r[paired])) * 1000
    out["pair_model_abs_normal_mm"] = float(np.median(np.abs(rm[paired]))) * 1000
    out["pair_full_abs_normal_mm"] = float(np.median(np.abs(rf[paired]))) * 1000
    out["unpaired_front_model_abs_normal_mm"] = float(np.median(np.abs(rm[front & ~K]))) * 1000
    out["unpaired_front_full_abs_normal_mm"] = float(np.median(np.abs(rf[front & ~K]))) * 1000
    view = G - p["camera"].center
    view /= np.linalg.norm(view, axis=2, keepdims=True)
    cos = np.abs(np.einsum("tnd,tnd->tn", NG, view))
    for lo, hi in ((0.0, 0.25), (0.25, 0.5), (0.5, 0.75), (0.75, 1.01)):
        b = front & (cos >= lo) & (cos < hi)
        bp = b & K
        out[f"cos{lo:.2f}_share_of_front"] = float(b.sum() / max(front.sum(), 1))
        out[f"cos{lo:.2f}_paired_share"] = float(K[b].mean()) if b.any() else float("nan")
        out[f"cos{lo:.2f}_target_signed_mm"] = float(np.mean(r[bp])) * 1000 if bp.any() else float("nan")
        out[f"cos{lo:.2f}_target_abs_mm"] = float(np.median(np.abs(r[bp]))) * 1000 if bp.any() else float("nan")
        out[f"cos{lo:.2f}_model_abs_mm"] = float(np.median(np.abs(rm[b]))) * 1000 if b.any() else float("nan")
        out[f"cos{lo:.2f}_full_abs_mm"] = float(np.median(np.abs(rf[b]))) * 1000 if b.any() else float("nan")
    return out


KEYS = ("median_mm", "p90_mm", "front_median_mm", "back_median_mm", "bulge_err_mm", "jitter_mm",
        "biceps_front", "biceps_back", "forearm_front", "shoulder_front", "upper_arm_front", "elbow_front",
        "wrist_front")


def step_variants(work: Path, subject_seed: int, variants: dict, diagnose: bool = False, noise_seed: int = 0) -> dict:
    from bodystudio.muscle import capture as cm

    p = load_state(work, subject_seed, noise_seed)
    Xm = to_world(p, p["model_meshes"])
    rows = {"model": score(p, Xm)}
    for name, kw in variants.items():
        o = cm.CaptureOptions(**kw)
        t0 = time.process_time()
        X = to_world(p, refine(p, o))
        cpu = time.process_time() - t0
        rows[name] = score(p, X)
        rows[name]["refine_cpu_ms_per_frame"] = 1000 * cpu / len(X)
        if diagnose:
            rows[name].update(front_diagnosis(p, Xm, X, o))
    for name, r in rows.items():
        shown = r if diagnose else {k: r[k] for k in (*KEYS, "refine_cpu_ms_per_frame") if k in r}
        print(subject_seed, name, json.dumps({k: round(v, 3) for k, v in shown.items()}), flush=True)
    return rows


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, required=True)
    parser.add_argument("--session", type=int, action="append", required=True, help="subject seed (repeatable)")
    parser.add_argument("--step", choices=("cache", "variants"), default="cache")
    parser.add_argument("--frames", type=int, default=200)
    parser.add_argument("--noise-seed", type=int, default=0)
    parser.add_argument("--variant", action="append", default=[], help="NAME or NAME:KEY=VALUE,... (repeatable)")
    parser.add_argument("--diagnose", action="store_true")
    args = parser.parse_args(argv)
    if args.noise_seed < 0:
        parser.error(f"--noise-seed {args.noise_seed}: needs a whole number >= 0")
    if args.step == "variants":
        from benchmarks.muscle_regions import parse_variant
        from bodystudio.errors import InputError
        from bodystudio.muscle.capture import CaptureOptions

        try:
            variants = dict(("default", {}) if v == "default" else parse_variant(v)
                            for v in args.variant or ["default"])
            for kw in variants.values():
                CaptureOptions(**kw)
        except (ValueError, SyntaxError, TypeError, InputError) as exc:
            parser.error(f"--variant: {exc}")
        results = {s: step_variants(args.work, s, variants, args.diagnose, args.noise_seed) for s in args.session}
        (args.work / f"front_variants_{int(time.time())}.json").write_text(json.dumps(results))
        return
    for s in args.session:
        t0 = time.process_time()
        print(s, step_cache(args.work, s, args.frames, args.noise_seed), f"{time.process_time() - t0:.0f} s CPU",
              flush=True)


if __name__ == "__main__":
    main()
