"""Which part of the run's pose the reshape's displacement error comes from, and whether a temporal filter lowers it
(MIR12p).

Usage: PYTHONPATH=. python benchmarks/mirror_displacement_error.py [--twisted] [--posture] SESSION

Every tracked frame of player 1 is posed as a one-player run poses it (the IK warm-started by the last one, its limbs
untwisted unless ``--twisted``: before MIR12p; the refinement's two steps against the graph cut's foreground). The
score is the displacement error: the mean distance (mm) between the fitted bodies' ``V_T - V_S`` under a pose and
under the true pose (the run's source placed with the true pose's displacement scores warp_iou 0.956 on 42 against
the run's 0.944 and the true pose's 0.951: ``benchmarks/mirror_image_plane.py``). Printed: the run, the IK, causal
filters of the run's bone rotations (exponential, alpha-beta: a constant-velocity predictor corrected by each
frame), a centred (non-causal) mean over +-k frames, the run with one group of bones (or their swing / their twist
alone) taken from the true pose, and the signed twist error of the arms over the session (mean, spread, and at the
first, middle and last frame). MIR12q: the mean error (bias) of the trunk bones' world rotations in the true pelvis's
rest axes (x: to the body's left, a positive x a forward lean; y: a yaw to the left) for the IK, the run and the IK
on the true rest skeleton (what the fitted skeleton adds), and the
share of the displacement error that is the same in every frame (the norm of its mean over frames, in the true
root's axes); ``--posture``: E_trunk centred on the running mean posture of MIR12q's bones (the run's own
``run.POSTURE_BONES`` are used without it: the same three since mir12ae, () before).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

GROUPS = {
    "root, pelvis": ("Root", "pelvis"),
    "spine": ("spine_01", "spine_02", "spine_03"),
    "neck, head": ("neck_01", "head"),
    "clavicles": ("clavicle_l", "clavicle_r"),
    "upper arms": ("upperarm_l", "upperarm_r"),
    "forearms": ("lowerarm_l", "lowerarm_r"),
    "thighs": ("thigh_l", "thigh_r"),
    "calves": ("calf_l", "calf_r"),
}


def record(session, untwist: bool, player: int = 1, posture_bones=()) -> dict:
    """Per tracked frame: the IK, the run's refined pose and the true pose (the fitted skeleton's), world rotations."""
    from benchmarks.mirror_pose_oracle import pose_from_world, world_rotations
    from bodystudio.body.pose import Pose
    from bodystudio.body.skeleton import Skeleton
    from bodystudio.mirror.compose import update_background
    from bodystudio.mirror.foreground import refine_foreground
    from bodystudio.mirror.frames import point_cloud, read_mirror_frame, register_depth_to_color
    from bodystudio.mirror.refine import TWIST_BONES, refine_plan, refine_pose, updated_posture
    from bodystudio.mirror.run import POSTURE_WINDOW, load_source, refine_steps, refine_weights, untwist_bones
    from bodystudio.mirror.track import ik_pose, untwisted_pose

    body, model = load_source(session)
    sk = body.skeleton
    parents = np.asarray(sk.parents)
    actors = np.load(Path(session.path) / "gt" / "mirror" / "actors.npz")
    a = list(actors["players"]).index(player)
    true_sk = Skeleton(sk.bone_names, sk.parents, actors["source_heads"][a], actors["source_tails"][a], sk.rolls)
    root = int(np.flatnonzero(parents < 0)[0])
    plan = refine_plan(body.vertices, body.faces, body.weights, sk, session.kinect.version, twist_bones=TWIST_BONES)
    rec = {k: [] for k in ("tracked", "ik", "run", "true", "run_t", "true_t", "ik_true_skeleton")}
    previous_true = None
    background, previous, n, posture = None, None, 0, None
    for i in session.frame_ids:
        frame = read_mirror_frame(session, i)
        depth_c, players_c = register_depth_to_color(frame.depth_m, frame.player, session.kinect)
        person = players_c == player
        tracked = frame.body(player)
        if tracked is None:
            background = update_background(background, frame.rgb, players_c > 0)
            previous = previous_true = None
            continue
        n += 1
        points = point_cloud(frame, session.kinect, player)
        points = points[points[:, 1] > 0.02]
        fg = refine_foreground(frame.rgb, person, depth_c, background=background)
        background = update_background(background, frame.rgb, fg | (players_c > 0))
        ik = ik_pose(sk, tracked.positions, tracked.tracked, session.kinect.version, previous=previous)
        if untwist:
            ik = untwisted_pose(sk, ik, untwist_bones())  # as the run (the feet too since mir12aa)
        previous = ik
        # the same IK on the true rest skeleton: what the fitted skeleton adds to the IK's error (MIR12q)
        previous_true = ik_pose(true_sk, tracked.positions, tracked.tracked, session.kinect.version,
                                previous=previous_true)
        pose = refine_pose(plan, sk, ik, session.kinect.color, fg, tracked.positions, tracked.tracked, points,
                           (players_c > 0) & ~person, session.kinect.version, iterations=refine_steps(1),
                           weights=refine_weights(1), posture=posture)
        if posture_bones:
            posture = updated_posture(posture, sk, pose, n, POSTURE_WINDOW, posture_bones)
        gt = session.frame(i).gt_mirror
        if gt is None or player not in list(gt["players"]) or not gt["reported"][list(gt["players"]).index(player)]:
            continue
        k = list(gt["players"]).index(player)
        true_pose = Pose(gt["pose_rotations"][k].astype(float), gt["pose_translations"][k].astype(float))
        W_true = world_rotations(true_sk, true_pose)
        tp = pose_from_world(sk, W_true, true_pose.translation + true_sk.heads[root] - sk.heads[root])
        for key, value in (("tracked", n), ("ik", world_rotations(sk, ik)), ("run", world_rotations(sk, pose)),
                           ("true", world_rotations(sk, tp)), ("run_t", pose.translation),
                           ("true_t", tp.translation), ("ik_true_skeleton", world_rotations(true_sk, previous_true))):
            rec[key].append(value)
    return {k: np.array(v) for k, v in rec.items()}


def _between(a, b):
    """Smallest rotation taking direction ``a`` to ``b``."""
    a, b = a / np.linalg.norm(a), b / np.linalg.norm(b)
    v = np.cross(a, b)
    s = np.linalg.norm(v)
    return np.eye(3) if s < 1e-12 else Rotation.from_rotvec(v / s * np.arctan2(s, a @ b)).as_matrix()


def alpha_beta(W: np.ndarray, restart: np.ndarray, alpha: float, beta: float) -> np.ndarray:
    """Each bone's world rotation filtered causally: predicted by the last estimate turned by its angular velocity,
    corrected by ``alpha`` of the innovation, the velocity by ``beta`` of it (``beta = 0``: exponential smoothing)."""
    out = np.empty_like(W)
    est = vel = None
    for i in range(len(W)):
        z = Rotation.from_matrix(W[i])
        if restart[i]:
            est, vel = z, np.zeros((W.shape[1], 3))
        else:
            pred = Rotation.from_rotvec(vel) * est
            e = (z * pred.inv()).as_rotvec()
            est = Rotation.from_rotvec(alpha * e) * pred
            vel = vel + beta * e
        out[i] = est.as_matrix()
    return out


def centred(W: np.ndarray, restart: np.ndarray, k: int) -> np.ndarray:
    """Each bone's world rotation averaged over the +-k frames around (non-causal: k frames of latency)."""
    out = np.empty_like(W)
    for i in range(len(W)):
        lo = hi = i
        while lo > 0 and not restart[lo] and i - lo < k:
            lo -= 1
        while hi < len(W) - 1 and not restart[hi + 1] and hi - i < k:
            hi += 1
        for b in range(W.shape[1]):
            out[i, b] = Rotation.from_matrix(W[lo:hi + 1, b]).mean().as_matrix()
    return out


def main() -> None:
    from benchmarks.mirror_pose_oracle import pose_from_world
    from bodystudio.capture.session import open_session
    from bodystudio.mirror.reshape import posed_source_and_target, target_coeffs, target_skeleton
    from bodystudio.mirror.run import load_source

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("session", type=Path)
    parser.add_argument("--twisted", action="store_true", help="the IK's warm-started twist (before MIR12p)")
    parser.add_argument("--posture", action="store_true", help="E_trunk centred on the running mean posture")
    args = parser.parse_args()
    session = open_session(args.session)
    from bodystudio.mirror.run import POSTURE_BONES

    rec = record(session, untwist=not args.twisted,  # the run's running posture (on since mir12ae) or MIR12q's
                 posture_bones=("spine_02", "neck_01", "head") if args.posture else POSTURE_BONES)
    body, model = load_source(session)
    sk = body.skeleton
    c_t = target_coeffs(model, body.coeffs, session.metadata["edits"])
    target_rest = model.vertices(c_t)
    rig = target_skeleton(body, target_rest, model, c_t)
    names = list(sk.bone_names)
    restart = np.r_[True, np.diff(rec["tracked"]) != 1]
    n = len(restart)

    def displacement(W, t):
        Vs, Vt = posed_source_and_target(body, target_rest, pose_from_world(sk, W, t), rig)
        return Vt - Vs

    truth = [displacement(rec["true"][i], rec["true_t"][i]) for i in range(n)]

    def err_mm(W):
        return float(np.mean([1e3 * np.linalg.norm(displacement(W[i], rec["run_t"][i]) - truth[i], axis=1).mean()
                              for i in range(n)]))

    rows = {"the run": err_mm(rec["run"]), "the IK": err_mm(rec["ik"])}
    for a in (0.5, 0.7):
        rows[f"exponential {a}"] = err_mm(alpha_beta(rec["run"], restart, a, 0.0))
    for a, b in ((0.5, 0.2), (0.7, 0.4), (0.8, 0.3)):
        rows[f"alpha-beta {a} / {b}"] = err_mm(alpha_beta(rec["run"], restart, a, b))
    for k in (1, 2):
        rows[f"centred +-{k} (non-causal)"] = err_mm(centred(rec["run"], restart, k))
    rest_dir = sk.tails - sk.heads
    rest_dir = rest_dir / np.linalg.norm(rest_dir, axis=1, keepdims=True)
    for group, bones in GROUPS.items():
        idx = [names.index(b) for b in bones]
        whole, swing, twist = rec["run"].copy(), rec["run"].copy(), rec["run"].copy()
        whole[:, idx] = rec["true"][:, idx]
        for i in range(n):
            for j in idx:
                d_run, d_true = rec["run"][i, j] @ rest_dir[j], rec["true"][i, j] @ rest_dir[j]
                swing[i, j] = _between(d_run, d_true) @ rec["run"][i, j]
                twist[i, j] = _between(d_true, d_run) @ rec["true"][i, j]
        rows[f"true {group} (swing / twist alone)"] = (err_mm(whole), err_mm(swing), err_mm(twist))
    pelvis = names.index("pelvis")
    print("| bone | IK: mean rotation error deg (x, y, z) | the run | the IK on the true rest skeleton |")
    print("|---|---|---|---|")
    for bone in ("Root", "spine_01", "spine_02", "spine_03", "neck_01", "head"):
        j = names.index(bone)
        row = []
        for key in ("ik", "run", "ik_true_skeleton"):
            Wp = rec["true"][:, pelvis]
            E = np.transpose(Wp, (0, 2, 1)) @ rec[key][:, j] @ np.transpose(rec["true"][:, j], (0, 2, 1)) @ Wp
            row.append(np.degrees(Rotation.from_matrix(E).as_rotvec()).mean(0))
        print("| " + " | ".join([bone] + [" / ".join(f"{x:+.2f}" for x in r) for r in row]) + " |")
    errors = [1e3 * (displacement(rec["run"][i], rec["run_t"][i]) - truth[i]) @ rec["true"][i, 0] for i in range(n)]
    print(f"\nthe run's displacement error: {np.mean([np.linalg.norm(e, axis=1).mean() for e in errors]):.2f} mm, "
          f"its mean over frames (a bias): {np.linalg.norm(np.mean(errors, axis=0), axis=1).mean():.2f} mm\n")
    print(f"| {args.session.name}{' (twisted)' if args.twisted else ''}{' (posture)' if args.posture else ''}, "
          f"{n} frames | displacement err mm |")
    print("|---|---|")
    for name, v in rows.items():
        print(f"| {name} | {' / '.join(f'{x:.2f}' for x in np.atleast_1d(v))} |")
    print("\n| bone | twist err deg: mean, spread | first / middle / last frame |\n|---|---|---|")
    for bone in ("upperarm_l", "lowerarm_l", "upperarm_r", "lowerarm_r"):
        j = names.index(bone)
        tw = []
        for i in range(n):
            d_run, d_true = rec["run"][i, j] @ rest_dir[j], rec["true"][i, j] @ rest_dir[j]
            residual = rec["run"][i, j] @ (_between(d_true, d_run) @ rec["true"][i, j]).T
            tw.append(np.degrees(Rotation.from_matrix(residual).as_rotvec() @ d_run))
        tw = np.array(tw)
        print(f"| {bone} | {tw.mean():+.1f}, {tw.std():.1f} | {tw[0]:+.1f} / {tw[n // 2]:+.1f} / {tw[-1]:+.1f} |")


if __name__ == "__main__":
    main()
