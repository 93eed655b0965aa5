"""The shape side of the mirror's warp (MIR12o): where the fitted source body and its Eq. 4 target miss, and what the
SDK's joint distances in the init's fit (``init.BONE_LENGTH_WEIGHT``) change.

Usage: PYTHONPATH=. python benchmarks/mirror_shape_side.py [--warp] [--stride 4] [--weight 1] SESSION [SESSION ...]

Per synthetic mirror session (with ``gt/``), player 1:

* ``lengths``: the distances of ``init.BONE_PAIRS`` on the true skeleton, and how far off the SDK's mean over the
  init frames (:func:`~bodystudio.mirror.init.kinect_bone_lengths`) and each fitted body's lie;
* per fitted body (``off``: the fit without the distances, the default; ``on``: with them at ``--weight`` per
  frame, the option), from the observations
  ``mirror init`` reads: the rest vertex error (mean translation removed) and its signed normal part per region,
  the Kinect joints' error, the stature and mass errors against the true mesh, and the error of the Eq. 4
  displacement ``B(c_T) - B(c_S)`` against the ground truth's (``reshape.target_coeffs`` on the fitted
  coefficients against the truth's target, the mirror's own edit);
* with ``--warp``: every ``stride``-th tracked frame posed as the run poses it (IK + ``refine_pose``, the run's
  steps), warped by the run's dense warp and scored against the target's true silhouette, for ``off``, ``on``,
  ``off`` with the true displacement, and the true bodies (the shape's ceiling under the run's pose).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def _true_bodies(session, body, player=1):
    from bodystudio.body.skeleton import Skeleton

    actors = np.load(Path(session.path) / "gt" / "mirror" / "actors.npz")
    a = list(actors["players"]).index(player)
    sk = body.skeleton

    def skel(kind):
        return Skeleton(sk.bone_names, sk.parents, actors[f"{kind}_heads"][a], actors[f"{kind}_tails"][a], sk.rolls)

    return (actors["source_rest_vertices"][a].astype(float), skel("source"),
            actors["target_rest_vertices"][a].astype(float), skel("target"))


def shape_errors(session, model, body, truth) -> dict:
    """Rest-shape, joint, attribute and Eq. 4 displacement errors of a fitted ``body`` against ``truth``."""
    from benchmarks.mirror_pose_oracle import REGIONS, vertex_regions
    from bodystudio.body.kinect import kinect_joints
    from bodystudio.geometry.mesh import vertex_normals
    from bodystudio.mirror.reshape import target_coeffs

    Vs, sk_s, Vt, _ = truth
    off = (Vs - body.vertices).mean(0)
    err = body.vertices + off - Vs
    regions = vertex_regions(model.weights, body.skeleton.bone_names)
    normal = 1e3 * np.einsum("ij,ij->i", err, vertex_normals(Vs, model.faces))
    K_fit = kinect_joints(body.skeleton, body.skeleton.heads + off, body.skeleton.tails + off)
    K_true = kinect_joints(sk_s, sk_s.heads, sk_s.tails)
    measured = json.loads((Path(session.path) / "gt" / "phenotype.json").read_text())["actors"][0]["measured"]
    fitted = model.measure(body.coeffs)
    c_t = target_coeffs(model, body.coeffs, session.metadata["edits"])
    displacement = (model.vertices(c_t) - body.vertices) - (Vt - Vs)
    return {"rest err mm": 1e3 * float(np.linalg.norm(err, axis=1).mean()),
            **{f"normal err mm, {r}": float(normal[regions == r].mean()) for r in REGIONS},
            "Kinect joint err mm": 1e3 * float(np.linalg.norm(K_fit - K_true, axis=1).mean()),
            "stature err mm": 1e3 * (fitted["stature_m"] - measured["stature_m"]),
            "mass err kg": fitted["mass_kg"] - measured["mass_kg"],
            "Eq. 4 displacement err mm": 1e3 * float(np.linalg.norm(displacement, axis=1).mean())}


def warp_scores(session, model, bodies: dict, truth, stride: int = 4, player: int = 1) -> dict:
    """Mean warp_iou over every ``stride``-th tracked frame of each (source body, target rest, target skeleton)."""
    from bodystudio.mirror.compose import update_background
    from bodystudio.mirror.evaluate import mask_iou
    from bodystudio.mirror.foreground import refine_foreground
    from bodystudio.mirror.frames import point_cloud, read_mirror_frame, register_depth_to_color
    from bodystudio.mirror.refine import TWIST_BONES, refine_plan, refine_pose
    from bodystudio.mirror.reshape import posed_source_and_target
    from bodystudio.mirror.run import MLS_ALPHA, MLS_RADIUS_PX, N_HANDLES, RIM_COS, refine_steps
    from bodystudio.mirror.track import ik_pose
    from bodystudio.mirror.warp import mls_warp_field, warp_foreground, warp_pairs

    camera, version = session.kinect.color, session.kinect.version
    state = {name: {"plan": refine_plan(b.vertices, b.faces, b.weights, b.skeleton, version, twist_bones=TWIST_BONES),
                    "previous": None, "scores": []} for name, (b, _, _) in bodies.items()}
    background = None
    for i in session.frame_ids:
        frame = read_mirror_frame(session, i)
        depth_c, players_c = register_depth_to_color(frame.depth_m, frame.player, session.kinect)
        tracked = frame.body(player)
        if tracked is None:
            background = update_background(background, frame.rgb, players_c > 0)
            continue
        for name, (b, _, _) in bodies.items():
            state[name]["ik"] = state[name]["previous"] = ik_pose(b.skeleton, tracked.positions, tracked.tracked,
                                                                  version, previous=state[name]["previous"])
        gt = session.frame(i).gt_mirror
        if i % stride or gt is None or player not in list(gt["players"]) or \
                not gt["reported"][list(gt["players"]).index(player)]:
            continue
        person, others = players_c == player, (players_c > 0) & (players_c != player)
        fg = refine_foreground(frame.rgb, person, depth_c, background=background)
        background = update_background(background, frame.rgb, fg | (players_c > 0))
        points = point_cloud(frame, session.kinect, player)
        points = points[points[:, 1] > 0.02]
        true_target = session.frame(i).gt_target_person == player
        for name, (b, Vt_rest, rig) in bodies.items():
            pose = refine_pose(state[name]["plan"], b.skeleton, state[name]["ik"], camera, fg & ~others,
                               tracked.positions, tracked.tracked, points, others, version,
                               iterations=refine_steps(1))
            Vs, Vt = posed_source_and_target(b, Vt_rest, pose, rig)
            p = warp_pairs(Vs, Vt, b.faces, camera, N_HANDLES, rim_cos=RIM_COS, dense=True, closed=True)
            field = mls_warp_field(p.src_uv, p.dst_uv, (camera.height, camera.width), kind="similarity",
                                   alpha=MLS_ALPHA, radius_px=MLS_RADIUS_PX, dense=p.dense, foreground=fg)
            state[name]["scores"].append(mask_iou(warp_foreground(frame.rgb, fg, field)[1] > 0.5, true_target))
    return {f"warp_iou, {name}": float(np.mean(s["scores"])) for name, s in state.items()}


def main() -> None:
    from bodystudio.body.kinect import kinect_joints
    from bodystudio.body.skeleton import Skeleton
    from bodystudio.body.statistical import load_statistical_model
    from bodystudio.capture.session import open_session
    from bodystudio.mirror import init as mirror_init
    from bodystudio.mirror.reshape import target_coeffs, target_skeleton

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sessions", nargs="+", type=Path)
    parser.add_argument("--warp", action="store_true", help="also score the run's warp with each body (slow)")
    parser.add_argument("--stride", type=int, default=4)
    parser.add_argument("--weight", type=float, default=1.0, help="bone_length_weight of the 'on' fit (per frame)")
    args = parser.parse_args()
    model = load_statistical_model("6k", progress=False)
    for path in args.sessions:
        session = open_session(path)
        obs, sensor = mirror_init.collect_observations(session)
        fitted = {name: mirror_init.initialise_from_observations(
            obs, model, view_point=sensor.depth.center, depth_camera=sensor.depth, bone_length_weight=w)
            for name, w in (("off", 0.0), ("on", args.weight))}
        fitted = {name: mirror_init.SourceBody(b.coeffs, b.vertices, b.skeleton, b.frames_used, b.residual_mm,
                                               model.weights, model.faces) for name, b in fitted.items()}
        truth = _true_bodies(session, fitted["off"])
        sk_true = truth[1]
        K_true = kinect_joints(sk_true, sk_true.heads, sk_true.tails)
        lengths, n_frames = mirror_init.kinect_bone_lengths(obs, obs[0].version)
        pairs = mirror_init.bone_pair_indices(obs[0].version)
        print(f"## {path.name}\n\n| pair | true mm | SDK mean - true (frames) | off - true | on - true |")
        print("|---|---|---|---|---|")
        for n, (a, b) in enumerate(pairs):
            true_d = np.linalg.norm(K_true[a] - K_true[b])
            fit_d = {}
            for name, body in fitted.items():
                K = kinect_joints(body.skeleton, body.skeleton.heads, body.skeleton.tails)
                fit_d[name] = np.linalg.norm(K[a] - K[b]) - true_d
            print(f"| {'-'.join(mirror_init.BONE_PAIRS[n])} | {1e3 * true_d:.1f} | {1e3 * (lengths[n] - true_d):+.1f} "
                  f"({n_frames[n]}) | {1e3 * fit_d['off']:+.1f} | {1e3 * fit_d['on']:+.1f} |")
        rows = {name: shape_errors(session, model, body, truth) for name, body in fitted.items()}
        print("\n| score | off | on |\n|---|---|---|")
        for key in rows["off"]:
            print(f"| {key} | {rows['off'][key]:.2f} | {rows['on'][key]:.2f} |")
        if args.warp:
            bodies = {}
            for name, body in fitted.items():
                c_t = target_coeffs(model, body.coeffs, session.metadata["edits"])
                V_t = model.vertices(c_t)
                bodies[name] = (body, V_t, target_skeleton(body, V_t, model, c_t))
            Vs, sk_s, Vt, sk_t = truth
            off, sk = bodies["off"][0], bodies["off"][0].skeleton
            # the truth's change of vertices and joints on the fitted body, the root kept (as target_skeleton)
            heads, tails = sk.heads + sk_t.heads - sk_s.heads, sk.tails + sk_t.tails - sk_s.tails
            roots = np.flatnonzero(np.asarray(sk.parents) < 0)
            heads[roots], tails[roots] = sk.heads[roots], sk.tails[roots]
            bodies["off, true displacement"] = (off, off.vertices + Vt - Vs,
                                                Skeleton(sk.bone_names, sk.parents, heads, tails, sk.rolls))
            bodies["true bodies"] = (mirror_init.SourceBody(off.coeffs, Vs, sk_s, (), 0.0, model.weights, model.faces),
                                     Vt, sk_t)
            for key, value in warp_scores(session, model, bodies, truth, args.stride).items():
                print(f"| {key} | {value:.4f} |")
        print()


if __name__ == "__main__":
    main()
