"""Arm-muscle capture (issue 11, twelfth pass): where the Sec. 7 refinement moves the unseen side, and the hold.

On the state the eleventh pass cached (``benchmarks.muscle_owners``: ``W/owners_SUBJECT_NAME_200.pkl``, the
per-frame stage, and ``W/owners_SUBJECT_NAME_sequence.pkl``, the joint rest-shape fit's sequence stage at the 20 %
norm limit), the capture's last steps run as ``CaptureOptions()`` runs them: the per-frame pose refit
(``capture.POSE_REFIT``, cached in ``W/hold_SUBJECT_refit.pkl``), the pose smoothing, then the Sec. 7 refinement
(``capture._refinement``) once per variant on the first ``--frames`` frames. Each row is scored against the truth
(``muscle_owners.breakdown``: the issue's figures, the median per region and side) together with two data-side
figures that need no truth:

- ``heldout_mm``: every odd frame refined from its two neighbours' correspondences only (Eq. 13-14 without the frame
  itself), then the root mean Huber point-to-plane residual of the frame's own depth (``refine.depth_energy_mm``'s
  measure) on the refined mesh: does the refinement still fit depth it was not given;
- ``rim_heldout_mm``: the seen vertices nearest the unseen side (the rim belt, normal within 60 deg of
  perpendicular to the sensor's ray) lose their correspondences and count as unseen; their residual against the
  frame's own depth after the refinement (:func:`heldout_rim_mm`): vertices without pairs whose place the depth knows;
- ``unseen_shift_mm``: the median displacement (refined minus model mesh) of the vertices without a correspondence
  in the frame (the part of the result no depth point supports).

Rows: ``model`` (no refinement), the variants (``NAME:KEY=VALUE,...`` over ``CaptureOptions()``; ``default``: as it
is, the hold on since the twelfth pass; the key ``hold_seen='zbuffer'``: the hold on every vertex the model mesh's
z-buffer hides, the facing ones too, instead of ``capture.hold_seen_vertices``). With ``--diagnose`` the refinement
without the hold ("no hold") is added, its change of the back side split by whether the back vertex has a
correspondence of its own (the model's z-buffer disagrees with the truth's) or only follows the ARAP, and the
diagnostic variants of it (no temporal averaging, no normal-agreement weight, no detail smoothing).

    python -m benchmarks.muscle_refine_hold --work W --session 501 --frames 60 --diagnose --variant default
    python -m benchmarks.muscle_refine_hold --work W --session 501 --frames 200 \
        --variant before:refine_unseen_hold=0.0 --variant default

docs/muscle.md "Capture, twelfth pass".
"""

from __future__ import annotations

import argparse
import json
import pickle
import time
from pathlib import Path

import numpy as np

STATE_NAME = "pre05_nl02"


def prepared(work: Path, subject_seed: int, n_frames: int, name: str = STATE_NAME) -> dict:
    """The cached state's first ``n_frames`` frames up to the refinement: depth frames, model meshes, poses, truth."""
    from benchmarks import bench_muscle as bm
    from benchmarks import muscle_owners as mo
    from benchmarks.muscle_energy import work_model
    from bodystudio.muscle import capture as cm
    from bodystudio.muscle.refine import refit_arm_poses_to_depth, skeleton_model_mesh, smooth_arm_poses

    template = bm._template()
    model = work_model(work, template)
    o = cm.CaptureOptions()
    state = mo.capture_state(work, subject_seed, mo.JOINT_FIT, name)
    truth = mo.ground_truth(work, subject_seed)
    state["camera"] = truth["camera"]
    frames = mo.depth_frames(state, template, o)
    poses, base, J, _ = mo.sequence_result(work, subject_seed, name, model, template, state, frames, o)
    path = work / f"hold_{subject_seed}_refit.pkl"
    if path.is_file():
        with open(path, "rb") as fh:
            refit, refit_cpu = pickle.load(fh)
    else:
        kw = dict(cm.POSE_REFIT)
        t0 = time.process_time()
        refit = refit_arm_poses_to_depth(model, poses, frames, base, J, o.norm_limit, o.sequence_huber_m,
                                         state["tracker_t"], kw.pop("tracker_weight"), **kw)
        refit_cpu = time.process_time() - t0
        with open(path, "wb") as fh:
            pickle.dump((refit, refit_cpu), fh, protocol=pickle.HIGHEST_PROTOCOL)
    n = min(n_frames, len(refit))
    smoothed = smooth_arm_poses(refit[:n], o.pose_sigma_frames, degree=o.pose_smoothing_degree)
    meshes = [skeleton_model_mesh(model, p, base, J, o.norm_limit) for p in smoothed]
    cut = {k: (v[:n] if k in ("G", "vis", "gtJ", "poses", "flexion_deg") else v) for k, v in truth.items()}
    return {"template": template, "state": state, "frames": frames[:n], "poses": smoothed, "meshes": meshes,
            "J": J, "truth": cut, "n": n}


def refine(p: dict, options) -> list[np.ndarray]:
    """``capture._refinement`` on the prepared model meshes (template space)."""
    from bodystudio.muscle import capture as cm

    fr = p["frames"]
    return cm._refinement(p["meshes"], p["poses"], [(f.points, f.normals) for f in fr], [f.tree for f in fr],
                          np.asarray(p["template"].faces, np.int64), fr[0].sensor_center, p["template"].arm_mask,
                          fr[0].adjacency, p["J"], options, cm._Timer(), camera=p["state"]["camera"],
                          similarity=p["state"]["S"])


def frame_pairs(p: dict, options) -> tuple[list, list, list, list]:
    """Each frame's Sec. 7 correspondence vectors, validity and seen vertices (``capture.hold_seen_vertices``; and
    without the facing ones: paired, or shown to the sensor by the model mesh's z-buffer), as ``capture._refinement``
    makes them."""
    from bodystudio.geometry.mesh import vertex_normals
    from bodystudio.muscle import capture as cm
    from bodystudio.muscle.nicp import (
        apply_similarity,
        closest_point_correspondences,
        filter_correspondences,
        plane_targets,
    )

    F = np.asarray(p["template"].faces, np.int64)
    vecs, valid, seen, seen_zbuffer = [], [], [], []
    for M, f in zip(p["meshes"], p["frames"], strict=True):
        pairs = closest_point_correspondences(M, f.points, f.normals, f.tree)
        pairs = filter_correspondences(M, vertex_normals(M, F), pairs, f.sensor_center, f.arm_mask, f.adjacency,
                                       options.nicp.filters)
        visible = cm.model_visible_vertices(apply_similarity(p["state"]["S"], M), F, p["state"]["camera"])
        if options.refine_visible_only:
            pairs.kept &= visible
        vecs.append(np.where(pairs.kept[:, None], plane_targets(M, pairs) - M, 0.0))
        valid.append(pairs.kept)
        seen.append(cm.hold_seen_vertices(M, vertex_normals(M, F), f.sensor_center, pairs.kept, visible))
        seen_zbuffer.append(pairs.kept | visible)
    return vecs, valid, seen, seen_zbuffer


def heldout_mm(p: dict, options, vecs, valid, seen, huber_m: float = 0.004) -> float:
    """Every odd frame refined from its neighbours' correspondences only, scored on its own depth (see above)."""
    from bodystudio.geometry.mesh import vertex_normals
    from bodystudio.muscle.refine import correspondence_weights, posed_joints, refine_surface, unseen_hold_weights

    F = np.asarray(p["template"].faces, np.int64)
    total, count = 0.0, 0
    for i in range(1, p["n"] - 1, 2):
        M = p["meshes"][i]
        # frames i-1 and i+1 are equally far from i: Eq. 14's weights are equal, the mean of the valid ones
        n_ok = valid[i - 1].astype(float) + valid[i + 1]
        ok = n_ok > 0
        c = (vecs[i - 1] * valid[i - 1][:, None] + vecs[i + 1] * valid[i + 1][:, None]) / np.maximum(n_ok, 1)[:, None]
        w = correspondence_weights(c, vertex_normals(M, F), M, posed_joints(p["J"], p["poses"][i]), ok,
                                   options.joint_radius_m, options.joint_gain)
        hold = None if options.refine_unseen_hold <= 0 else unseen_hold_weights(
            M, ok | seen[i], options.refine_unseen_hold, options.refine_unseen_band_m)
        X = refine_surface(M, F, c, w, options.refine_data_weight, options.refine_iterations, hold)
        k, q, n = p["frames"][i].plane_pairs(X)
        r = np.abs(np.einsum("kd,kd->k", X[k] - q, n))
        total += float(np.where(r < huber_m, 0.5 * r * r, huber_m * (r - 0.5 * huber_m)).sum())
        count += len(r)
    return 1000.0 * float(np.sqrt(2.0 * total / max(count, 1)))


def heldout_rim_mm(p: dict, options, vecs, valid, seen, cos_max: float = 0.5, stride: int = 2,
                   huber_m: float = 0.004) -> float:
    """The seen vertices nearest the unseen side held out: in every ``stride``-th frame the paired vertices whose
    normal makes ``|cos| < cos_max`` with the sensor's ray (the rim belt between the seen front and the unseen back)
    lose their correspondences in frames i-1, i, i+1 and count as unseen; the frame is refined without them and the
    root mean Huber point-to-plane residual of those vertices against the frame's own depth is returned (mm). A
    data-side stand-in for the back: vertices without pairs whose place the depth does know."""
    from bodystudio.geometry.mesh import vertex_normals
    from bodystudio.muscle.refine import (
        correspondence_weights,
        posed_joints,
        refine_surface,
        time_consistent_correspondences,
        unseen_hold_weights,
    )

    F = np.asarray(p["template"].faces, np.int64)
    C = p["frames"][0].sensor_center
    total, count = 0.0, 0
    n = p["n"]
    for i in range(1, n - 1, stride):
        M = p["meshes"][i]
        Nv = vertex_normals(M, F)
        ray = M - C
        ray /= np.linalg.norm(ray, axis=1, keepdims=True)
        rim = valid[i] & (np.abs(np.einsum("kd,kd->k", Nv, ray)) < cos_max)
        idx = [i - 1, i, i + 1]
        c, ok = time_consistent_correspondences([vecs[j] * ~rim[:, None] for j in idx],
                                                [valid[j] & ~rim for j in idx], options.sigma_frames)
        w = correspondence_weights(c, Nv, M, posed_joints(p["J"], p["poses"][i]), ok, options.joint_radius_m,
                                   options.joint_gain)
        hold = None if options.refine_unseen_hold <= 0 else unseen_hold_weights(
            M, ok | (seen[i] & ~rim), options.refine_unseen_hold, options.refine_unseen_band_m)
        X = M if options.mode == "model" else refine_surface(M, F, c, w, options.refine_data_weight,
                                                             options.refine_iterations, hold)
        k, q, nq = p["frames"][i].plane_pairs(X)
        sel = rim[k]
        r = np.abs(np.einsum("kd,kd->k", X[k[sel]] - q[sel], nq[sel]))
        total += float(np.where(r < huber_m, 0.5 * r * r, huber_m * (r - 0.5 * huber_m)).sum())
        count += len(r)
    return 1000.0 * float(np.sqrt(2.0 * total / max(count, 1)))


def score(p: dict, meshes: list[np.ndarray]) -> dict:
    from benchmarks import muscle_owners as mo
    from bodystudio.muscle.nicp import apply_similarity

    X = np.stack([apply_similarity(p["state"]["S"], M) for M in meshes])
    return mo.breakdown(X, p["truth"], p["template"])


def back_diagnosis(p: dict, refined: list[np.ndarray], valid: list[np.ndarray]) -> dict:
    """The default refinement's change of the back side (truth-unseen arm vertices, mm), split by whether the vertex
    has a Sec. 7 correspondence of its own in the frame (the model's z-buffer and the filters disagree with the
    truth's visibility) or only follows the ARAP; and the seen side's mean displacement along the sensor's view."""
    from bodystudio.muscle.nicp import apply_similarity

    S, arm = p["state"]["S"], p["template"].arm_mask
    G, vis = p["truth"]["G"], p["truth"]["vis"]
    Xm = np.stack([apply_similarity(S, M) for M in p["meshes"]])
    Xr = np.stack([apply_similarity(S, M) for M in refined])
    em, er = (np.linalg.norm(X - G, axis=2) * 1000.0 for X in (Xm, Xr))
    paired = np.stack(valid)
    back = ~vis & arm[None]
    out = {"back_paired_share": float(paired[back].mean())}
    for label, m in (("back_paired", back & paired), ("back_unpaired", back & ~paired),
                     ("front_paired", vis & arm[None] & paired), ("front_unpaired", vis & arm[None] & ~paired)):
        out[f"{label}_model_mm"] = float(np.median(em[m])) if m.any() else float("nan")
        out[f"{label}_full_mm"] = float(np.median(er[m])) if m.any() else float("nan")
        shift = np.linalg.norm(Xr - Xm, axis=2)[m] * 1000.0
        out[f"{label}_shift_mm"] = float(np.median(shift)) if m.any() else float("nan")
    # the displacement of the back along the direction that would reduce its error (+: towards the truth)
    D, E = Xr - Xm, G - Xm
    along = np.einsum("tnd,tnd->tn", D, E) / np.maximum(np.linalg.norm(E, axis=2), 1e-9) * 1000.0
    out["back_unpaired_towards_truth_mm"] = float(np.median(along[back & ~paired]))
    view = Xm - p["truth"]["camera"].center
    view /= np.linalg.norm(view, axis=2, keepdims=True)
    out["front_shift_along_view_mm"] = float(np.mean(np.einsum("tnd,tnd->tn", D, view)[vis & arm[None]]) * 1000.0)
    out["back_shift_along_view_mm"] = float(np.mean(np.einsum("tnd,tnd->tn", D, view)[back & ~paired]) * 1000.0)
    return out


KEYS = ("median_mm", "p90_mm", "front_median_mm", "back_median_mm", "bulge_err_mm", "jitter_mm", "heldout_mm",
        "rim_heldout_mm", "unseen_shift_mm", "shoulder_back", "biceps_back", "upper_arm_back", "elbow_back",
        "forearm_back", "shoulder_front", "biceps_front", "upper_arm_front", "elbow_front", "forearm_front")


def session_rows(work: Path, subject_seed: int, n_frames: int, variants: dict, diagnose: bool = False) -> dict:
    from bodystudio.muscle import capture as cm

    p = prepared(work, subject_seed, n_frames)
    base = cm.CaptureOptions()
    vecs, valid, seen_facing, seen_zbuffer = frame_pairs(p, base)
    rows = {"model": score(p, p["meshes"])}
    rows["model"]["unseen_shift_mm"] = 0.0
    rows["model"]["rim_heldout_mm"] = heldout_rim_mm(p, cm.CaptureOptions(mode="model"), vecs, valid, seen_facing)
    print(subject_seed, "model", json.dumps({k: round(rows["model"].get(k, float("nan")), 3) for k in KEYS}),
          flush=True)
    todo = dict(variants)
    if diagnose:
        import bodystudio.muscle.capture as capture_module

        todo = {"no hold": {"refine_unseen_hold": 0.0}, **todo}
    real_seen = cm.hold_seen_vertices
    for label, kw in todo.items():
        kw = dict(kw)
        zbuffer = kw.pop("hold_seen", "facing") == "zbuffer"  # the hold on every vertex the z-buffer hides
        seen = seen_zbuffer if zbuffer else seen_facing
        o = cm.CaptureOptions(**kw)
        if zbuffer:
            cm.hold_seen_vertices = lambda M, N, C, paired, visible: paired if visible is None else paired | visible
        try:
            t0 = time.process_time()
            out = refine(p, o)
            cpu = time.process_time() - t0
        finally:
            cm.hold_seen_vertices = real_seen
        r = score(p, out)
        r["refine_cpu_ms_per_frame"] = 1000.0 * cpu / p["n"]
        unpaired = ~np.stack(valid) & p["template"].arm_mask[None]
        shift = np.linalg.norm(np.stack(out) - np.stack(p["meshes"]), axis=2) * 1000.0
        r["unseen_shift_mm"] = float(np.median(shift[unpaired]))
        r["heldout_mm"] = heldout_mm(p, o, vecs, valid, seen)
        r["rim_heldout_mm"] = heldout_rim_mm(p, o, vecs, valid, seen)
        if diagnose and label == "no hold":
            r.update(back_diagnosis(p, out, valid))
        rows[label] = r
        print(subject_seed, label, json.dumps({k: round(v, 3) for k, v in r.items() if isinstance(v, float)}),
              flush=True)
    if diagnose:
        rows.update(_diagnostic_rows(p, capture_module, subject_seed))
    return rows


def _diagnostic_rows(p: dict, cm, subject_seed: int) -> dict:
    """The refinement without the hold (as it was before the twelfth pass) with one of its parts taken out: the
    temporal average (sigma -> 0.05 frames), the normal-agreement weight (every valid pair weight 1, the joint factor
    kept), the detail smoothing (off)."""
    rows = {}
    real = cm.correspondence_weights

    def flat(vectors, normals, vertices, joints, valid, joint_radius_m=0.06, joint_gain=1.0, min_length_m=1e-3):
        w = real(np.zeros_like(vectors), normals, vertices, joints, valid, joint_radius_m, joint_gain, 1.0)
        return w

    off = {"refine_unseen_hold": 0.0}
    for label, kw, patch in (("no temporal average", {"sigma_frames": 0.05, **off}, None),
                             ("no normal-agreement weight", off, flat),
                             ("no detail smoothing", {"detail_sigma_frames": 0.0, **off}, None)):
        if patch is not None:
            cm.correspondence_weights = patch
        try:
            out = refine(p, cm.CaptureOptions(**kw))
        finally:
            cm.correspondence_weights = real
        rows[label] = score(p, out)
        print(subject_seed, label,
              json.dumps({k: round(rows[label].get(k, float("nan")), 3) for k in KEYS}), flush=True)
    return rows


def render(results: dict, keys: tuple = KEYS) -> str:
    from benchmarks.timing import markdown_table

    rows = [[f"{s}", label, *(f"{r.get(k, float('nan')):.2f}" for k in keys)]
            for s, res in results.items() for label, r in res.items()]
    return markdown_table(["session", "row", *keys], rows)


def main(argv: list[str] | None = None) -> None:
    from benchmarks.muscle_regions import parse_variant

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, required=True)
    parser.add_argument("--session", action="append", type=int, default=[], help="subject seed (repeatable)")
    parser.add_argument("--frames", type=int, default=60)
    parser.add_argument("--variant", action="append", default=[], help="NAME:KEY=VALUE,... or 'default'")
    parser.add_argument("--diagnose", action="store_true")
    parser.add_argument("--tag", default="")
    args = parser.parse_args(argv)
    variants = dict(("default", {}) if v == "default" else parse_variant(v) for v in args.variant)
    results = {}
    for s in args.session or [501]:
        results[s] = session_rows(args.work, s, args.frames, variants, args.diagnose)
        (args.work / f"hold_{s}_{args.frames}{args.tag}.json").write_text(json.dumps(results[s]))
    print(render(results))


if __name__ == "__main__":
    main()
