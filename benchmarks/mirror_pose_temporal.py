"""Where the refined pose's remaining error sits and what a temporal start or prior buys (MIR12h).

Usage: PYTHONPATH=. python benchmarks/mirror_pose_temporal.py [--stride 4] [--variants NAME ...] [--per-frame F]
       SESSION [SESSION ...]

Every tracked frame of player 1 of a synthetic mirror session (``gt/mirror``) is refined as the run does (the IK
warm-started by the last IK, the graph cut's foreground, the player's depth points), and by each variant of
:data:`VARIANTS`, each keeping its own state from frame to frame; every ``stride``-th frame is scored: warp_iou of the
run's dense warp against the target's true silhouette, the displacement error, the root rotation error (total, its
yaw about the vertical and the rest) and the trunk / limb swing errors against the true pose. Nothing here selects
by the truth: the variants run as the run would, the truth only scores them.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import time
from pathlib import Path

import numpy as np

from bodystudio.mirror.refine import RefineWeights

#: name -> keyword arguments of ``refine_pose`` plus ``twist`` (the plan's twist bones; the run's
#: :data:`~bodystudio.mirror.refine.TWIST_BONES` when not given), ``pivot`` (``refine.ROOT_PIVOT``; the run's when not
#: given), ``joint_bias`` (the Kinect joints less the running mean of their offset from the refined body's, in the
#: frame of the bone carrying each), ``start`` ("ik": the frame's IK pose; "previous": the last
#: frame's refined pose) and ``ik_from`` ("ik": the IK warm-started by the last IK, as the run; "refined": by the
#: last refined pose).
VARIANTS: dict[str, dict] = {
    "refined (the run)": {},
    "before MIR12h (root head pivot, no twist)": {"pivot": "head", "twist": ()},
    "centroid pivot, no twist": {"twist": ()},
    "twist spine_01-02, root head pivot": {"pivot": "head"},
    "2 steps, before MIR12h": {"pivot": "head", "twist": (), "iterations": 2},
    "2 steps": {"iterations": 2},
    "start: previous refined": {"start": "previous"},
    "IK warm-started by the refined pose": {"ik_from": "refined"},
    "joint bias removed": {"joint_bias": True},
    "twist spine_01": {"twist": ("spine_01",)},
    "twist spine_01-03": {"twist": ("spine_01", "spine_02", "spine_03")},
    "twist spine_01-02, neck": {"twist": ("spine_01", "spine_02", "neck_01")},
    "twist spine_01-02, thighs": {"twist": ("spine_01", "spine_02", "thigh_l", "thigh_r")},
    "twist spine_01-02, clavicles": {"twist": ("spine_01", "spine_02", "clavicle_l", "clavicle_r")},
    "trunk 8 deg": {"weights": RefineWeights(trunk_rad=float(np.radians(8.0)))},
    "joints x0.5": {"weights": RefineWeights(joint_weight=0.5)},
    "depth x2": {"weights": RefineWeights(depth_weight=2.0)},
    "3 steps": {"iterations": 3},
    "2 steps, 1000 depth points": {"iterations": 2, "weights": RefineWeights(depth_samples=1000)},
    "2 steps, joints x0.5": {"iterations": 2, "weights": RefineWeights(joint_weight=0.5)},
    "2 steps, depth x2": {"iterations": 2, "weights": RefineWeights(depth_weight=2.0)},
    "2 steps, silhouette x2": {"iterations": 2, "weights": RefineWeights(sil_weight=2.0)},
    "2 steps, 2000 depth points": {"iterations": 2, "weights": RefineWeights(depth_samples=2000)},
    "3 steps, 1000 depth points": {"iterations": 3, "weights": RefineWeights(depth_samples=1000)},
    "3 steps, 2000 depth points, 1200 outline pixels": {"iterations": 3, "weights": RefineWeights(
        depth_samples=2000, sil_samples=1200)},
    "4 steps, 2000 depth points, 1200 outline pixels": {"iterations": 4, "weights": RefineWeights(
        depth_samples=2000, sil_samples=1200)},
}


#: The CLI's edit ramp (tracked frames): ``eval mirror`` scores the frames after it, also printed apart.
RAMP_FRAMES = 30


class JointBias:
    """Running mean of each Kinect joint's offset from the refined body's joint, in the frame of the bone that
    carries it (experiment; the first bone of the joint's definition)."""

    def __init__(self, skeleton, version, min_frames=10):
        from bodystudio.body.kinect import KINECT_JOINT_SETS, kinect_joint_names

        self.bones = np.array([skeleton.bone_names.index(KINECT_JOINT_SETS[version][n][0][0])
                               for n in kinect_joint_names(version)])
        self.sum = np.zeros((len(self.bones), 3))
        self.count = np.zeros(len(self.bones))
        self.version, self.min_frames, self.skeleton = version, min_frames, skeleton
        self.W = None

    def corrected(self, K, tracked):
        if self.W is None or self.count.max() < self.min_frames:
            return K
        mean = self.sum / np.maximum(self.count, 1)[:, None]
        return K - np.einsum("kij,kj->ki", self.W[self.bones], mean)

    def update(self, pose, K, tracked):
        from benchmarks.mirror_pose_oracle import world_rotations
        from bodystudio.mirror.track import posed_kinect_joints

        self.W = world_rotations(self.skeleton, pose)
        P = posed_kinect_joints(self.skeleton, pose, self.version)
        off = np.einsum("kji,kj->ki", self.W[self.bones], K - P)
        ok = np.asarray(tracked, bool) & np.all(np.isfinite(K), axis=1)
        self.sum[ok] += off[ok]
        self.count[ok] += 1


@contextlib.contextmanager
def _root_pivot(pivot: str):
    """``refine.ROOT_PIVOT`` set to ``pivot`` while the block runs."""
    from bodystudio.mirror import refine

    original = refine.ROOT_PIVOT
    refine.ROOT_PIVOT = pivot
    try:
        yield
    finally:
        refine.ROOT_PIVOT = original


def root_rotation_errors(W_est: np.ndarray, W_true: np.ndarray) -> tuple[float, float, float]:
    """Root rotation error (degrees): total, its yaw (about the world vertical) and the tilt (what is left)."""
    from scipy.spatial.transform import Rotation

    E = Rotation.from_matrix(W_est @ W_true.T).as_rotvec()
    total = np.degrees(np.linalg.norm(E))
    return float(total), float(np.degrees(abs(E[1]))), float(np.degrees(np.hypot(E[0], E[2])))


def score(session, variants: dict[str, dict], stride: int = 4, player: int = 1, per_frame=None) -> dict:
    from benchmarks.mirror_pose_oracle import SWING_GROUPS, pose_from_world, swing_twist_errors, world_rotations
    from bodystudio.body.pose import Pose
    from bodystudio.body.skeleton import Skeleton
    from bodystudio.mirror.compose import update_background
    from bodystudio.mirror.evaluate import mask_iou
    from bodystudio.mirror.foreground import refine_foreground
    from bodystudio.mirror.frames import point_cloud, read_mirror_frame, register_depth_to_color
    from bodystudio.mirror.refine import ROOT_PIVOT, TWIST_BONES, refine_plan, refine_pose
    from bodystudio.mirror.reshape import posed_source_and_target, target_coeffs, target_skeleton
    from bodystudio.mirror.run import MLS_ALPHA, MLS_RADIUS_PX, N_HANDLES, RIM_COS, load_source
    from bodystudio.mirror.track import ik_pose
    from bodystudio.mirror.warp import mls_warp_field, warp_foreground, warp_pairs

    body, model = load_source(session)
    c_target = target_coeffs(model, body.coeffs, session.metadata["edits"])
    target_rest = model.vertices(c_target)
    rig = target_skeleton(body, target_rest, model, c_target)
    sk = body.skeleton
    actors = np.load(Path(session.path) / "gt" / "mirror" / "actors.npz")
    a = list(actors["players"]).index(player)
    true_sk = Skeleton(sk.bone_names, sk.parents, actors["source_heads"][a], actors["source_tails"][a], sk.rolls)
    camera, faces = session.kinect.color, body.faces
    root = int(np.flatnonzero(np.asarray(sk.parents) < 0)[0])
    plans = {}
    for kw in variants.values():
        twist = kw.get("twist", TWIST_BONES)
        if twist not in plans:
            plans[twist] = refine_plan(body.vertices, faces, body.weights, sk, session.kinect.version,
                                       twist_bones=twist)
    state = {name: {"ik": None, "refined": None, "bias": JointBias(sk, session.kinect.version)}
             for name in ["IK", *variants]}
    background, rows, ms, n_tracked = None, [], {name: [] for name in variants}, 0
    for i in session.frame_ids:
        frame = read_mirror_frame(session, i)
        depth_c, players_c = register_depth_to_color(frame.depth_m, frame.player, session.kinect)
        person = players_c == player
        tracked = frame.body(player)
        if tracked is None:
            background = update_background(background, frame.rgb, players_c > 0)
            for s in state.values():
                s["ik"] = s["refined"] = None
            continue
        n_tracked += 1
        points = point_cloud(frame, session.kinect, player)
        points = points[points[:, 1] > 0.02]
        fg = refine_foreground(frame.rgb, person, depth_c, background=background)
        others = (players_c > 0) & ~person
        background = update_background(background, frame.rgb, fg | (players_c > 0))
        poses = {}
        for name in ["IK", *variants]:
            kw = dict(variants.get(name, {}))
            s = state[name]
            ik_from = kw.pop("ik_from", "ik")
            start_from = kw.pop("start", "ik")
            debias = kw.pop("joint_bias", False)
            K = s["bias"].corrected(tracked.positions, tracked.tracked) if debias else tracked.positions
            prev = s["refined"] if ik_from == "refined" and s["refined"] is not None else s["ik"]
            ik = ik_pose(sk, K, tracked.tracked, session.kinect.version, previous=prev)
            s["ik"] = ik
            if name == "IK":
                poses[name] = ik
                continue
            start = s["refined"] if start_from == "previous" and s["refined"] is not None else ik
            plan = plans[kw.pop("twist", TWIST_BONES)]
            t0 = time.process_time()
            with _root_pivot(kw.pop("pivot", ROOT_PIVOT)):
                pose = refine_pose(plan, sk, start, camera, fg, K, tracked.tracked, points, others,
                                   session.kinect.version, **kw)
            ms[name].append(1e3 * (time.process_time() - t0))
            if debias:
                s["bias"].update(pose, tracked.positions, tracked.tracked)
            s["refined"] = poses[name] = pose
        gt = session.frame(i).gt_mirror
        if i % stride or gt is None or player not in list(gt["players"]):
            continue
        k = list(gt["players"]).index(player)
        if not gt["reported"][k]:
            continue
        true_pose = Pose(gt["pose_rotations"][k].astype(float), gt["pose_translations"][k].astype(float))
        W_true = world_rotations(true_sk, true_pose)
        poses["true pose"] = pose_from_world(sk, W_true, true_pose.translation + true_sk.heads[root] - sk.heads[root])
        true_target = session.frame(i).gt_target_person == player
        Vs_t, Vt_t = gt["source_vertices"][k].astype(float), gt["target_vertices"][k].astype(float)
        row = {"session": Path(session.path).name, "frame": int(i), "tracked": n_tracked}
        for name, pose in poses.items():
            Vs, Vt = posed_source_and_target(body, target_rest, pose, rig)
            p = warp_pairs(Vs, Vt, faces, camera, N_HANDLES, rim_cos=RIM_COS, dense=True)
            field = mls_warp_field(p.src_uv, p.dst_uv, (camera.height, camera.width), kind="similarity",
                                   alpha=MLS_ALPHA, radius_px=MLS_RADIUS_PX, dense=p.dense)
            row[name] = mask_iou(warp_foreground(frame.rgb, fg, field)[1] > 0.5, true_target)
            row[f"{name}: displacement err mm"] = 1e3 * np.linalg.norm((Vt - Vs) - (Vt_t - Vs_t), axis=1).mean()
            row[f"{name}: source vertex err mm"] = 1e3 * np.linalg.norm(Vs - Vs_t, axis=1).mean()
            W = world_rotations(sk, pose)
            tot, yaw, tilt = root_rotation_errors(W[root], W_true[root])
            row[f"{name}: root rot err deg (total, yaw, tilt)"] = (tot, yaw, tilt)
            from scipy.spatial.transform import Rotation

            row[f"{name}: root yaw signed deg"] = float(np.degrees(
                Rotation.from_matrix(W[root] @ W_true[root].T).as_rotvec()[1]))
            if name == "refined (the run)":
                dt = 1e3 * np.linalg.norm(pose.translation - poses["IK"].translation)
                dr = np.degrees(np.linalg.norm((Rotation.from_rotvec(pose.rotations)
                                                * Rotation.from_rotvec(poses["IK"].rotations).inv()).as_rotvec(),
                                               axis=1))
                row[f"{name}: step mm, max deg, mean deg"] = (dt, float(dr.max()), float(dr.mean()))
            for group in ("spine_01", "neck, head", "upper arms", "thighs", "calves"):
                idx = [sk.bone_names.index(n) for n in SWING_GROUPS[group]]
                row[f"{name}: swing err deg, {group}"] = float(np.mean(swing_twist_errors(sk, W, W_true, idx)[0]))
        rows.append(row)
        if per_frame is not None:
            with open(per_frame, "a") as f:
                f.write(json.dumps(row) + "\n")
    out = {"frames": len(rows), **{f"{n}: refine ms CPU": float(np.median(v)) for n, v in ms.items()}}
    late = [r for r in rows if r["tracked"] > RAMP_FRAMES]
    for key in rows[0]:
        if key in ("session", "frame", "tracked"):
            continue
        vals = np.array([r[key] for r in rows], float)
        out[key] = tuple(vals.mean(0)) if vals.ndim > 1 else float(vals.mean())
        if ":" not in key and late:  # warp_iou over the frames `eval mirror` scores after the CLI's ramp
            out[f"{key} (after the ramp)"] = float(np.mean([r[key] for r in late]))
    return out


def main() -> None:
    from bodystudio.capture.session import open_session

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sessions", nargs="+", type=Path)
    parser.add_argument("--stride", type=int, default=4)
    parser.add_argument("--variants", nargs="*", default=None, choices=sorted(VARIANTS))
    parser.add_argument("--per-frame", type=Path, default=None)
    args = parser.parse_args()
    variants = VARIANTS if args.variants is None else {k: VARIANTS[k] for k in args.variants}
    results = {p.name: score(open_session(p), variants, args.stride, per_frame=args.per_frame)
               for p in args.sessions}
    keys = list(next(iter(results.values())))
    print("| score | " + " | ".join(results) + " |")
    print("|---|" + "---|" * len(results))

    def fmt(v):
        return " / ".join(f"{x:.3g}" for x in v) if isinstance(v, tuple) else f"{v:.4g}"

    for key in keys:
        print(f"| {key} | " + " | ".join(fmt(r[key]) for r in results.values()) + " |")


if __name__ == "__main__":
    main()
