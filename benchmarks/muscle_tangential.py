"""Arm-muscle capture (issue 11, fifteenth pass): the seen side's tangential error, split by what owns it.

On the cached state of ``muscle_rest_arm`` (the per-frame stage at ``CaptureOptions()``,
``W/owners_SUBJECT_def_200.pkl``, and a variant's sequence stage, ``W/rest_SUBJECT_NAME_sequence.pkl``) the capture
is finished as ``CaptureOptions()`` finishes it (the last pose refit ``capture.POSE_REFIT``, the pose smoothing, the
Sec. 7 refinement with its own depth clean-up) and its front error (the vertices the truth's z-buffer sees) split
along the true normal and tangentially. Then:

- **the truth's skin sliding** (``synthetic.muscle_displacement``'s tangential slide over the contracting biceps):
  its size on the front and the capture scored against the truth without it (how much of the error it is);
- **the per-frame pose per degree of freedom**: each frame's smoothed angles against the truth's (both about the
  capture's root; the truth's poses mapped into the template's space, ``muscle_owners.truth_in_template_space``),
  the shoulder's error split into its twist about the rest upper arm's axis (humeral rotation) and its swing
  (the upper arm's direction), the elbow's into its hinge flexion, the forearm's twist and the rest (deg, rms over
  frames and their sequence mean, the part a constant offset would hold);
- **oracle rows**: the capture with one of those pieces replaced by the truth's (per frame, or its sequence-constant
  part only), through the same Sec. 7 refinement: the median it would gain.

    python -m benchmarks.muscle_tangential --work W --session 501 --session 504 --session 507 --session 508

With ``--variant NAME:KEY=VALUE,...`` (the pose smoothing's ``pose_sigma_frames`` / ``pose_smoothing_degree``) the
capture is finished with those settings too (``--no-oracles``: only the capture and the variants):

    python -m benchmarks.muscle_tangential --work W --session 501 --no-oracles \
        --variant q5:pose_smoothing_degree=2,pose_sigma_frames=5

``--name NAME`` picks the sequence stage ``W/rest_SUBJECT_NAME_sequence.pkl`` (``default``: ``CaptureOptions()``'s;
made by ``muscle_rest_arm`` if missing). docs/muscle.md "Capture, fifteenth pass".
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation


def split_front(X: np.ndarray, G: np.ndarray, normals: np.ndarray, front: np.ndarray) -> dict:
    """Median front error (mm) of ``X`` against ``G`` (T, n, 3), all / along the true normal / tangential."""
    e = X - G
    en = np.einsum("tnd,tnd->tn", e, normals)
    et = np.linalg.norm(e - en[..., None] * normals, axis=2)
    return {"front": 1000.0 * float(np.median(np.linalg.norm(e, axis=2)[front])),
            "front_normal": 1000.0 * float(np.median(np.abs(en[front]))),
            "front_tangential": 1000.0 * float(np.median(et[front]))}


def swing_twist(R: Rotation, axis: np.ndarray) -> tuple[Rotation, float]:
    """``R = swing * twist`` with ``twist`` about ``axis`` (applied first): (swing, twist angle in rad)."""
    q = R.as_quat()  # x, y, z, w
    p = (q[:3] @ axis) * axis
    tw = np.r_[p, q[3]]
    n = np.linalg.norm(tw)
    if n < 1e-12:
        return R, 0.0
    tw /= n
    twist = Rotation.from_quat(tw)
    angle = 2.0 * np.arctan2(tw[:3] @ axis, tw[3])
    return R * twist.inv(), float((angle + np.pi) % (2 * np.pi) - np.pi)


def pose_errors(capture: list, truth: list, J: np.ndarray) -> dict:
    """Per-frame angle errors (deg, (T,) each) of ``capture`` against ``truth`` (ArmPoses in one space, the truth's
    shoulder re-expressed about the capture's root): shoulder twist about the rest upper arm, its swing, the elbow's
    hinge, forearm twist and the rest of the elbow; plus the truth's angles about the capture's root (the oracle's)."""
    from bodystudio.muscle.refine import elbow_axes

    s, e, _ = J
    u = (e - s) / np.linalg.norm(e - s)
    h, f = elbow_axes(J)
    g = np.cross(h, f)
    out = {k: [] for k in ("shoulder_twist", "shoulder_swing", "elbow_hinge", "elbow_twist", "elbow_other")}
    out["shoulder_true"], out["elbow_true"] = [], []
    for c, t in zip(capture, truth, strict=True):
        Rc = Rotation.from_rotvec(c.angles[0])
        # the truth's upper arm in the capture's root frame: root_c^-1 root_t R_t
        Rt = Rotation.from_matrix(c.root[:3, :3].T @ t.root[:3, :3]) * Rotation.from_rotvec(t.angles[0])
        E = Rc.inv() * Rt
        swing, twist = swing_twist(E, u)
        out["shoulder_twist"].append(np.degrees(twist))
        out["shoulder_swing"].append(np.degrees(np.linalg.norm(swing.as_rotvec())))
        Ee = (Rotation.from_rotvec(c.angles[1]).inv() * Rotation.from_rotvec(t.angles[1])).as_rotvec()
        out["elbow_hinge"].append(np.degrees(Ee @ h))
        out["elbow_twist"].append(np.degrees(Ee @ f))
        out["elbow_other"].append(np.degrees(Ee @ g))
        out["shoulder_true"].append(Rt.as_rotvec())
        out["elbow_true"].append(t.angles[1])
    return {k: np.asarray(v) for k, v in out.items()}


def with_pieces(capture: list, truth: list, J: np.ndarray, pieces: set, constant: bool = False) -> list:
    """The capture's poses with the named pieces of the truth's put in (``shoulder_twist``, ``shoulder_swing``,
    ``elbow_hinge``, ``elbow_rest``: the elbow's twist and off-hinge part); ``constant``: only each piece's sequence
    mean error (a fixed offset) corrected."""
    from bodystudio.muscle.arm import ArmPose
    from bodystudio.muscle.refine import elbow_axes

    s, e, _ = J
    u = (e - s) / np.linalg.norm(e - s)
    h, _ = elbow_axes(J)
    sh, el = [], []
    for c, t in zip(capture, truth, strict=True):
        Rc = Rotation.from_rotvec(c.angles[0])
        Rt = Rotation.from_matrix(c.root[:3, :3].T @ t.root[:3, :3]) * Rotation.from_rotvec(t.angles[0])
        swing, twist = swing_twist(Rc.inv() * Rt, u)
        sh.append((swing.as_rotvec(), twist))
        Ee = (Rotation.from_rotvec(c.angles[1]).inv() * Rotation.from_rotvec(t.angles[1])).as_rotvec()
        el.append(Ee)
    if constant:
        mean_swing = np.mean([a for a, _ in sh], axis=0)
        mean_twist = float(np.mean([b for _, b in sh]))
        mean_el = np.mean(el, axis=0)
        sh = [(mean_swing, mean_twist)] * len(sh)
        el = [mean_el] * len(el)
    out = []
    for c, (sw, tw), Ee in zip(capture, sh, el, strict=True):
        R = Rotation.from_rotvec(c.angles[0])
        if "shoulder_swing" in pieces:
            R = R * Rotation.from_rotvec(sw)
        if "shoulder_twist" in pieces:
            R = R * Rotation.from_rotvec(u * tw)
        corr = np.zeros(3)
        if "elbow_hinge" in pieces:
            corr += (Ee @ h) * h
        if "elbow_rest" in pieces:
            corr += Ee - (Ee @ h) * h
        Re = Rotation.from_rotvec(c.angles[1]) * Rotation.from_rotvec(corr)
        out.append(ArmPose(c.root, np.vstack([R.as_rotvec(), Re.as_rotvec(), c.angles[2]])))
    return out


def truth_without_slide(truth: dict, ids: list, session) -> np.ndarray:
    """The world truth meshes (T, n, 3) with the skin slide of ``synthetic.muscle_displacement`` taken out."""
    from bodystudio.muscle import synthetic as sy
    from bodystudio.muscle.arm import pose_arm

    T, subject = truth["template"], truth["subject"]
    var = sy.MuscleVariation.from_seed(subject.seed)
    out = []
    saved = sy.SKIN_SLIDE
    try:
        for p, G in zip(truth["poses"], truth["G"], strict=True):
            sy.SKIN_SLIDE = saved
            d = sy.muscle_displacement(T, subject, p, var)
            sy.SKIN_SLIDE = 0.0
            d0 = sy.muscle_displacement(T, subject, p, var)
            slide_world = (pose_arm(T.vertices + d, T.part_weights, T.joints, p)
                           - pose_arm(T.vertices + d0, T.part_weights, T.joints, p))
            out.append(G - slide_world)
    finally:
        sy.SKIN_SLIDE = saved
    return np.stack(out)


def refinement_frames(work: Path, subject_seed: int, state: dict, frames: list, o) -> list:
    """The depth frames the Sec. 7 refinement pairs with: the session's depth cleaned with the refinement's own
    filters (``capture.refinement_depth_options``) in the template's space, as ``capture_arm_sequence`` makes them."""
    from dataclasses import replace

    from scipy.spatial import cKDTree

    from benchmarks.muscle_sequences import session_of
    from bodystudio.muscle import capture as cm
    from bodystudio.muscle.depth import clean_depth, depth_point_cloud
    from bodystudio.muscle.nicp import apply_similarity

    d = cm.refinement_depth_options(o)
    if d == o.depth:
        return frames
    _, session = session_of(work, subject_seed, 0, len(frames))
    Sinv = cm._inverse_similarity(state["S"])
    out = []
    for fr, fid in zip(frames, session.frame_ids, strict=True):
        P, N = depth_point_cloud(clean_depth(session.frame(fid).kinect_depth_m, d), state["camera"])
        P = apply_similarity(Sinv, P)
        out.append(replace(fr, points=P, normals=N @ state["S"][1], tree=cKDTree(P)))
    return out


def session_rows(work: Path, subject_seed: int, name: str = "default", variants: dict | None = None,
                 oracles: bool = True) -> dict:
    """The rows of the module docstring for one session; ``variants`` ({name: CaptureOptions keywords} of the pose
    smoothing, ``pose_sigma_frames`` / ``pose_smoothing_degree``): the capture finished with each instead."""
    from benchmarks import bench_muscle as bm
    from benchmarks.muscle_energy import work_model
    from benchmarks.muscle_owners import breakdown, capture_state, depth_frames, ground_truth, truth_in_template_space
    from benchmarks.muscle_rest_arm import sequence_of
    from benchmarks.muscle_sequences import session_of
    from bodystudio.geometry.mesh import vertex_normals
    from bodystudio.muscle import capture as cm
    from bodystudio.muscle.nicp import apply_similarity
    from bodystudio.muscle.refine import refit_arm_poses_to_depth, skeleton_model_mesh, smooth_arm_poses

    template = bm._template()
    model = work_model(work, template)
    state = capture_state(work, subject_seed, {}, "def")
    truth = ground_truth(work, subject_seed)
    state["camera"] = truth["camera"]
    o = cm.CaptureOptions()
    frames = depth_frames(state, template, o)
    poses, base, J, _ = sequence_of(work, subject_seed, name, model, template, state, frames, o)
    refit = dict(cm.POSE_REFIT)
    poses = refit_arm_poses_to_depth(model, poses, cm.facing_frames(frames, o.sequence_min_facing_cos), base, J,
                                     o.norm_limit, o.sequence_huber_m, state["tracker_t"],
                                     refit.pop("tracker_weight"), **refit)
    rframes = refinement_frames(work, subject_seed, state, frames, o)
    true_poses, _ = truth_in_template_space(truth, state["S"])
    G, vis = truth["G"], truth["vis"]
    F = np.asarray(template.faces, np.int64)
    front = vis & template.arm_mask[None]
    NG = np.stack([vertex_normals(g, F) for g in G])
    rows = {}

    def row(label, p, opts=o):
        M = [skeleton_model_mesh(model, q, base, J, opts.norm_limit) for q in p]
        out = cm._refinement(M, p, [(f.points, f.normals) for f in rframes], [f.tree for f in rframes], F,
                             frames[0].sensor_center, template.arm_mask, frames[0].adjacency, J, opts, cm._Timer(),
                             camera=state["camera"], similarity=state["S"])
        X = np.stack([apply_similarity(state["S"], x) for x in out])
        r = breakdown(X, truth, template)
        r.update(split_front(X, G, NG, front))
        err = pose_errors(p, true_poses, J)
        r.update({f"{k}_rms_deg": float(np.sqrt(np.mean(err[k] ** 2)))
                  for k in ("shoulder_twist", "shoulder_swing", "elbow_hinge", "elbow_twist")})
        rows[label] = r
        print(subject_seed, label, json.dumps({k: round(v, 2) for k, v in r.items() if not k.startswith("flex_")}),
              flush=True)
        return X

    smoothed = smooth_arm_poses(poses, o.pose_sigma_frames, degree=o.pose_smoothing_degree,
                                shoulder_degree=o.shoulder_smoothing_degree)
    X = row("capture", smoothed)
    for label, kw in (variants or {}).items():
        ov = cm.CaptureOptions(**kw)
        row(label, smooth_arm_poses(poses, ov.pose_sigma_frames, degree=ov.pose_smoothing_degree,
                                    shoulder_degree=ov.shoulder_smoothing_degree), ov)
    if not oracles:
        return rows
    _, sess = session_of(work, subject_seed, 0, 200)
    G0 = truth_without_slide(truth, list(sess.frame_ids), sess)
    slide = 1000.0 * np.linalg.norm(G - G0, axis=2)
    rows["slide"] = {"front_slide_median": float(np.median(slide[front])),
                     "front_slide_p90": float(np.percentile(slide[front], 90)),
                     "front_slide_max": float(slide[front].max()),
                     **{f"vs_noslide_{k}": v for k, v in split_front(X, G0, NG, front).items()}}
    print(subject_seed, "slide", json.dumps({k: round(v, 2) for k, v in rows["slide"].items()}), flush=True)
    err = pose_errors(smoothed, true_poses, J)
    stats = {}
    for k in ("shoulder_twist", "shoulder_swing", "elbow_hinge", "elbow_twist", "elbow_other"):
        v = err[k]
        stats[f"{k}_rms_deg"] = float(np.sqrt(np.mean(v ** 2)))
        stats[f"{k}_mean_deg"] = float(np.mean(v))
        stats[f"{k}_sd_deg"] = float(np.std(v))
    rows["angles"] = stats
    print(subject_seed, "angles", json.dumps({k: round(v, 2) for k, v in stats.items()}), flush=True)
    for label, pieces in (("true shoulder twist", {"shoulder_twist"}), ("true shoulder swing", {"shoulder_swing"}),
                          ("true elbow hinge", {"elbow_hinge"}), ("true elbow rest", {"elbow_rest"}),
                          ("true angles", {"shoulder_twist", "shoulder_swing", "elbow_hinge", "elbow_rest"})):
        row(label, with_pieces(smoothed, true_poses, J, pieces))
    row("true angles, constant part", with_pieces(smoothed, true_poses, J,
                                                  {"shoulder_twist", "shoulder_swing", "elbow_hinge", "elbow_rest"},
                                                  constant=True))
    return rows


SMOOTHING_KEYS = {"pose_sigma_frames", "pose_smoothing_degree", "shoulder_smoothing_degree"}
COLUMNS = ("median_mm", "p90_mm", "front", "front_normal", "front_tangential", "back_median_mm", "bulge_err_mm",
           "jitter_mm", "elbow_hinge_rms_deg", "shoulder_twist_rms_deg")


def main(argv: list[str] | None = None) -> None:
    from benchmarks.timing import markdown_table

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, required=True)
    parser.add_argument("--session", action="append", type=int, default=[], help="subject seed (repeatable)")
    parser.add_argument("--name", default="default", help="the sequence stage W/rest_SUBJECT_NAME_sequence.pkl")
    parser.add_argument("--variant", action="append", default=[], help="NAME:KEY=VALUE,... CaptureOptions keywords "
                        "of the pose smoothing (pose_sigma_frames, pose_smoothing_degree): the capture finished "
                        "with them too")
    parser.add_argument("--no-oracles", action="store_true", help="the capture and the variants only")
    args = parser.parse_args(argv)
    from benchmarks.muscle_regions import parse_variant
    from bodystudio.errors import InputError
    from bodystudio.muscle.capture import CaptureOptions

    try:
        variants = dict(parse_variant(v) for v in args.variant)
        for kw in variants.values():
            if set(kw) - SMOOTHING_KEYS:
                raise ValueError(f"unknown keys {sorted(set(kw) - SMOOTHING_KEYS)} (use "
                                 f"{', '.join(sorted(SMOOTHING_KEYS))})")
            CaptureOptions(**kw)
    except (ValueError, SyntaxError, TypeError, InputError) as exc:
        parser.error(f"--variant: {exc}")
    table = []
    for s in args.session or [501]:
        rows = session_rows(args.work, s, args.name, variants, not args.no_oracles)
        path = args.work / f"tangential_{s}_{args.name}.json"
        kept = json.loads(path.read_text()) if path.is_file() else {}
        path.write_text(json.dumps({**kept, **rows}))
        table += [[f"{s}", label, *(f"{r.get(k, float('nan')):.2f}" for k in COLUMNS)]
                  for label, r in rows.items() if "median_mm" in r]
    print(markdown_table(["session", "row", *COLUMNS], table))


if __name__ == "__main__":
    main()
