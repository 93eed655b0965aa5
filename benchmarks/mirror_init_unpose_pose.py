"""Which bones of the pose ``mirror init`` unposes each frame with are wrong, and what each costs the fit (mir12z).

Usage: PYTHONPATH=. python benchmarks/mirror_init_unpose_pose.py SESSION [SESSION ...]
       [--true-swing BONE [BONE ...]] [--leg-splay] [--knee-hinge-weight W [--knee-hinge-from sdk]]
       [--shadow DIR --name NAME.npz]

Per synthetic mirror session (with ``gt/mirror``), player 1's init from ``mirror init``'s observations
(:func:`bodystudio.mirror.init.initialise_from_observations`, the defaults), recording the pose each fitted frame is
unposed with (:func:`~bodystudio.mirror.init.refined_init_pose`). For the last pass it prints, per bone and averaged
over the fitted frames, the error of the bone's direction against the truth's (the true pose carried onto the fitted
skeleton: every bone's true world rotation, as ``mirror_pose_oracle.py``'s oracles), for the IK pose and the refined
one: the angle (degrees) and its signed components in the subject's pelvis frame (x the body's left, y up, z forward;
mean over frames). Then the init's scores (``mirror_init_posture.init_scores``: the Eq. 4 displacement error, the rest
vertex error, stature, mass, chest and hip girth) and the **posed** error (the fitted body posed by the true pose
against the true posed vertices, every 8th frame from the actor's first; the source silhouette the warp starts from).

``--true-swing BONES`` re-runs the init with those bones' directions taken from the truth in every unposing pose
(their twist, and every other bone, the refined pose's; ``mirror_pose_oracle.oracle_swing``): an oracle of what a
right unposing of those bones is worth. ``--shadow DIR --name NAME.npz`` writes the oracle's body (without
``--true-swing``, the default init's; with ``--leg-splay`` the init's ``leg_splay`` option, mir12ab) as
``DIR/<session>/mirror/NAME.npz`` in a shadow of the session (``mirror_init_variants.shadow_session``: nothing is
written into the session), for ``benchmarks/mirror_refine_end_to_end.py --runs refine --source NAME.npz --out OUT
DIR/<session>``. Example (docs/mirror.md, mir12z): ``S57 --true-swing calf_l calf_r --shadow W --name calves.npz``
(the sessions first: ``--true-swing`` takes every name after it): 57's posed error 15.4 -> 4.6 mm, mass +3.30 -> +1.12
kg, end to end 0.9464 -> 0.9539."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

#: The bones reported (the rig's trunk and limbs).
REPORT_BONES = ("Root", "pelvis", "spine_01", "spine_02", "spine_03", "neck_01", "head", "clavicle_l", "clavicle_r",
                "upperarm_l", "upperarm_r", "lowerarm_l", "lowerarm_r", "hand_l", "hand_r", "thigh_l", "thigh_r",
                "calf_l", "calf_r", "foot_l", "foot_r")


def true_pose(session: Path, frame: int):
    """Player 1's true pose in ``frame`` (``gt/mirror/NNNNN.npz``)."""
    from bodystudio.body.pose import Pose

    g = np.load(session / "gt" / "mirror" / f"{frame:05d}.npz")
    return Pose(g["pose_rotations"][0].astype(float), g["pose_translations"][0].astype(float))


def carried_true_pose(skeleton, actors, pose):
    """The true ``pose`` on ``skeleton`` (the fitted one): every bone's true world rotation, the root head on the
    true one (``mirror_pose_oracle.poses_fitted_true``); and the true world rotations (B, 3, 3)."""
    from benchmarks.mirror_pose_oracle import poses_fitted_true, world_rotations
    from bodystudio.body.skeleton import Skeleton

    true_sk = Skeleton(skeleton.bone_names, skeleton.parents, actors["source_heads"][0], actors["source_tails"][0],
                       skeleton.rolls)
    root = int(np.flatnonzero(np.asarray(skeleton.parents) < 0)[0])
    return poses_fitted_true(type("Fitted", (), {"skeleton": skeleton})(), true_sk, pose, root), \
        world_rotations(true_sk, pose)


def bone_direction_errors(skeleton, pose, W_true, bones) -> tuple[np.ndarray, np.ndarray]:
    """Per bone of ``bones`` (indices): the angle (degrees) between its direction under ``pose`` and under the true
    world rotations ``W_true``, and the difference of the two unit directions in the true pelvis frame (degrees,
    small-angle: x left, y up, z forward)."""
    from benchmarks.mirror_pose_oracle import world_rotations

    W = world_rotations(skeleton, pose)
    pelvis = skeleton.bone_names.index("pelvis")
    angle, parts = [], []
    for j in bones:
        axis = skeleton.rest_rotations[j][:, 1]
        d, t = W[j] @ axis, W_true[j] @ axis
        angle.append(np.degrees(np.arctan2(np.linalg.norm(np.cross(d, t)), d @ t)))
        parts.append(np.degrees(W_true[pelvis].T @ (d - t)))
    return np.array(angle), np.array(parts)


def posed_error_mm(model, coeffs, session: Path, actors, frames) -> float:
    """The body of ``coeffs`` (the model's joints) posed by the true pose of ``frames`` against the true posed
    vertices: mean vertex distance, mm."""
    from bodystudio.body.model import BodyModel

    skeleton = model.skeleton(coeffs)
    body = BodyModel(model.vertices(coeffs), model.faces, skeleton, model.weights, model.resolution, model.rig)
    err = []
    for f in frames:
        V, _ = body.pose(carried_true_pose(skeleton, actors, true_pose(session, f))[0])
        g = np.load(session / "gt" / "mirror" / f"{f:05d}.npz")
        err.append(np.linalg.norm(V - g["source_vertices"][0], axis=1).mean())
    return 1000.0 * float(np.mean(err))


def recorded_init(init_mod, obs, model, sensor, session: Path, actors, true_swing=(), **options):
    """The default init of ``obs``, and every ``(body, observation, pose)`` it unposed by, in order; with
    ``true_swing`` (bone names) those bones' directions replaced by the truth's in each pose."""
    from benchmarks.mirror_pose_oracle import oracle_swing, pose_from_world, world_rotations

    original, seen = init_mod.refined_init_pose, []
    swing = [list(model.bone_names).index(b) for b in true_swing]

    def recorded(plan, body, o, P, camera, steps, **options):
        pose = original(plan, body, o, P, camera, steps, **options)
        if swing:
            _, W_true = carried_true_pose(body.skeleton, actors, true_pose(session, o.frame))
            W = oracle_swing(body.skeleton, world_rotations(body.skeleton, pose), W_true, swing)
            pose = pose_from_world(body.skeleton, W, pose.translation)
        seen.append((body, o, pose))
        return pose

    init_mod.refined_init_pose = recorded
    try:
        fitted = init_mod.initialise_from_observations(obs, model, view_point=sensor.depth.center,
                                                       depth_camera=sensor.depth, **options)
    finally:
        init_mod.refined_init_pose = original
    return fitted, seen


def main(argv=None) -> int:
    from benchmarks.mirror_init_posture import init_scores
    from benchmarks.mirror_init_variants import shadow_session
    from bodystudio.body.statistical import load_statistical_model
    from bodystudio.capture.session import open_session
    from bodystudio.mirror import init as init_mod
    from bodystudio.mirror.track import ik_pose

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sessions", nargs="+", type=Path)
    parser.add_argument("--true-swing", nargs="+", default=[], metavar="BONE")
    parser.add_argument("--leg-splay", action="store_true", help="the init's leg_splay option (mir12ab)")
    parser.add_argument("--knee-hinge-weight", type=float, default=None,
                        help="the init's knee_hinge_weight option (mir12ab; 0: off; default: the init's)")
    parser.add_argument("--knee-hinge-from", choices=("refined", "sdk"), default=None,
                        help="where the knee hinge's rows come from (the init's knee_hinge_from; mir12ac: sdk, the "
                             "SDK joints' rest knee angle)")
    parser.add_argument("--shadow", type=Path, default=None)
    parser.add_argument("--name", default=None)
    args = parser.parse_args(argv)
    if (args.shadow is None) != (args.name is None):
        parser.error("--shadow and --name go together (the shadow folder and the body's file name)")
    if args.name is not None and (not args.name.endswith(".npz") or "/" in args.name or args.name.startswith(".")):
        parser.error(f"--name {args.name!r}: give a plain file name ending in .npz, e.g. calves.npz")
    for path in args.sessions:
        if not (path / "gt" / "mirror" / "actors.npz").is_file():
            parser.error(f"{path}: not a synthetic mirror session with ground truth (gt/mirror/actors.npz missing)")
    model = load_statistical_model("6k", progress=False)
    names = list(model.bone_names)
    unknown = [b for b in args.true_swing if b not in names]
    if unknown:
        parser.error(f"--true-swing: unknown bone(s) {unknown}; e.g. calf_l calf_r (the rig's bone names)")
    bones = [names.index(b) for b in REPORT_BONES]
    for path in args.sessions:
        session = open_session(path)
        actors = np.load(path / "gt" / "mirror" / "actors.npz")
        obs, sensor = init_mod.collect_observations(session, None, 1, init_mod.DEFAULT_INIT_FRAMES)
        weight = init_mod.KNEE_HINGE_WEIGHT if args.knee_hinge_weight is None else args.knee_hinge_weight
        source = init_mod.KNEE_HINGE_FROM if args.knee_hinge_from is None else args.knee_hinge_from
        fitted, seen = recorded_init(init_mod, obs, model, sensor, path, actors, tuple(args.true_swing),
                                      **({"leg_splay": True} if args.leg_splay else {}),
                                      knee_hinge_weight=weight, knee_hinge_from=source,
                                      knee_frames=init_mod.knee_joint_frames(session, obs) if source == "sdk" else None)
        last = seen[-len(fitted.frames_used):]
        table = {"ik": [], "refined": []}
        for body, o, pose in last:
            carried, W_true = carried_true_pose(body.skeleton, actors, true_pose(path, o.frame))
            table["refined"].append(bone_direction_errors(body.skeleton, pose, W_true, bones))
            ik = ik_pose(body.skeleton, o.joints, o.tracked, o.version)
            table["ik"].append(bone_direction_errors(body.skeleton, ik, W_true, bones))
        print(f"{path.name}: the last pass's unposing pose against the truth, {len(last)} frames "
              f"{fitted.frames_used[0]}-{fitted.frames_used[-1]}"
              + (f" (true swing: {' '.join(args.true_swing)})" if args.true_swing else ""))
        print(f"  {'bone':11s} {'IK deg':>7s} {'refined':>7s}   refined signed (x left, y up, z forward)")
        for i, b in enumerate(REPORT_BONES):
            ik_a = np.mean([a[i] for a, _ in table["ik"]])
            ref_a = np.mean([a[i] for a, _ in table["refined"]])
            part = np.mean([p[i] for _, p in table["refined"]], axis=0)
            print(f"  {b:11s} {ik_a:7.1f} {ref_a:7.1f}   {part[0]:+5.1f} {part[1]:+5.1f} {part[2]:+5.1f}")
        ids = sorted(int(p.stem) for p in (path / "gt" / "mirror").glob("[0-9]*.npz"))
        ids = [f for f in ids if f >= obs[0].frame][::8]
        scores = init_scores(model, fitted, actors, session.metadata["edits"])
        scores["posed_err_mm"] = round(posed_error_mm(model, fitted.coeffs, path, actors, ids), 2)
        print("  " + " ".join(f"{k} {v}" for k, v in scores.items()), flush=True)
        if args.shadow is not None:
            shadow = shadow_session(path, args.shadow)
            init_mod.save_source_body(shadow / "mirror" / args.name, fitted, player=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
