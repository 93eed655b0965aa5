"""How much of the pose's warp loss lies in the image plane, and what a 2D registration of the bodies to the
person's outline takes back (MIR12p).

Usage: PYTHONPATH=. python benchmarks/mirror_image_plane.py [--stride 2] [--rows NAME ...] [--per-frame F]
       SESSION [SESSION ...]

Every tracked frame of player 1 of a synthetic mirror session is refined as a one-player run does (the IK
warm-started by the last IK and its limbs untwisted, the graph cut's foreground, two Gauss-Newton steps, 2000 depth
points); every ``stride``-th frame is warped with the run's dense field (extras carried, as the run) for each row and
scored against the target's true silhouette (warp_iou), the source body's silhouette against the true person (source
IoU) and the target body's against the true target (target IoU). Rows:

* ``run``: the run's bodies;
* ``true pose``: the fitted bodies under the true pose (oracle);
* ``source's image-plane error``: both of the run's bodies moved parallel to the image plane, each vertex by its
  source vertex's projection error against the true pose (oracle: what a perfect 2D registration of the source
  reaches; the rest of the true pose's gain is the displacement's own error, along the ray);
* ``run + true pose's displacement``: the run's source, the target at the source plus the true pose's
  ``V_T - V_S`` (oracle: the displacement's share); ``registered + true pose's displacement``: the same after the
  registration;
* ``registered``: :func:`bodystudio.mirror.image_plane.register_to_outline` on the graph cut's foreground;
  ``registered, true fg``: on the true person mask (oracle of the foreground); ``registered xK``: gain K.
Nothing is chosen by the truth: the registered rows see only the frame's foreground and bodies.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from bodystudio.mirror.image_plane import image_plane_shift, register_to_outline

ROWS = ("run", "true pose", "source's image-plane error", "registered", "registered, dilation",
        "registered, true fg", "registered x0.5", "registered, smooth 5", "registered, smooth 80",
        "registered twice", "run + true pose's displacement", "registered + true pose's displacement")


def _source_zbuffer(Vs, faces, camera, dense):
    from bodystudio.capture.render import render_silhouette_depth
    from bodystudio.mirror.warp import crop_camera, facing_faces

    x0, y0 = dense.origin
    h, w = dense.source_mask.shape
    uv, z = camera.project_with_depth(Vs)
    F = np.asarray(faces, np.int64)
    front = facing_faces(np.where((z > 0)[:, None], uv, np.nan), F)
    return render_silhouette_depth(Vs, F[front], crop_camera(camera, x0, y0, w, h))


def score(session, rows, stride: int = 2, player: int = 1, per_frame=None) -> dict:
    from benchmarks.mirror_pose_oracle import pose_from_world, world_rotations
    from bodystudio.body.pose import Pose
    from bodystudio.body.skeleton import Skeleton
    from bodystudio.mirror.compose import update_background
    from bodystudio.mirror.evaluate import mask_iou
    from bodystudio.mirror.foreground import refine_foreground
    from bodystudio.mirror.frames import point_cloud, read_mirror_frame, register_depth_to_color
    from bodystudio.mirror.refine import TWIST_BONES, refine_plan, refine_pose
    from bodystudio.mirror.reshape import posed_source_and_target, target_coeffs, target_skeleton
    from bodystudio.mirror.run import (
        MLS_ALPHA,
        MLS_RADIUS_PX,
        N_HANDLES,
        RIM_COS,
        load_source,
        refine_steps,
        refine_weights,
        untwist_bones,
    )
    from bodystudio.mirror.track import ik_pose, untwisted_pose
    from bodystudio.mirror.warp import mls_warp_field, warp_foreground, warp_pairs

    body, model = load_source(session, player=player) if player != 1 else load_source(session)
    c_target = target_coeffs(model, body.coeffs, session.metadata["edits"])
    target_rest = model.vertices(c_target)
    rig = target_skeleton(body, target_rest, model, c_target)
    sk = body.skeleton
    parents = np.asarray(sk.parents)
    actors = np.load(Path(session.path) / "gt" / "mirror" / "actors.npz")
    a = list(actors["players"]).index(player)
    true_sk = Skeleton(sk.bone_names, sk.parents, actors["source_heads"][a], actors["source_tails"][a], sk.rolls)
    camera, faces = session.kinect.color, body.faces
    root = int(np.flatnonzero(parents < 0)[0])
    plan = refine_plan(body.vertices, faces, body.weights, sk, session.kinect.version, twist_bones=TWIST_BONES)
    weights = np.asarray(body.weights, np.float64)
    background, out_rows, n_tracked, previous = None, [], 0, None
    for i in session.frame_ids:
        frame = read_mirror_frame(session, i)
        depth_c, players_c = register_depth_to_color(frame.depth_m, frame.player, session.kinect)
        person = players_c == player
        tracked = frame.body(player)
        if tracked is None:
            background = update_background(background, frame.rgb, players_c > 0)
            previous = None
            continue
        n_tracked += 1
        points = point_cloud(frame, session.kinect, player)
        points = points[points[:, 1] > 0.02]
        others = (players_c > 0) & ~person
        fg = refine_foreground(frame.rgb, person, depth_c, background=background)
        background = update_background(background, frame.rgb, fg | (players_c > 0))
        ik = ik_pose(sk, tracked.positions, tracked.tracked, session.kinect.version, previous=previous)
        if untwist_bones():  # as the run (MIR12p; the feet too since mir12aa)
            ik = untwisted_pose(sk, ik, untwist_bones())
        previous = ik
        pose = refine_pose(plan, sk, ik, camera, fg, tracked.positions, tracked.tracked, points, others,
                           session.kinect.version, iterations=refine_steps(1), weights=refine_weights(1))
        gt = session.frame(i).gt_mirror
        if n_tracked % stride or gt is None or player not in list(gt["players"]):
            continue
        k = list(gt["players"]).index(player)
        if not gt["reported"][k]:
            continue
        true_pose = Pose(gt["pose_rotations"][k].astype(float), gt["pose_translations"][k].astype(float))
        W_true = world_rotations(true_sk, true_pose)
        tp = pose_from_world(sk, W_true, true_pose.translation + true_sk.heads[root] - sk.heads[root])
        true_target = session.frame(i).gt_target_person == player
        true_person = session.frame(i).gt_person == player
        Vs_r, Vt_r = posed_source_and_target(body, target_rest, pose, rig)
        Vs_p, Vt_p = posed_source_and_target(body, target_rest, tp, rig)
        base = warp_pairs(Vs_r, Vt_r, faces, camera, N_HANDLES, rim_cos=RIM_COS, dense=True, closed=True)
        zbuf = None
        row = {"session": Path(session.path).name, "frame": int(i), "tracked": n_tracked}
        for name in rows:
            p = None
            if name == "run":
                Vs, Vt, p = Vs_r, Vt_r, base
            elif name == "true pose":
                Vs, Vt = Vs_p, Vt_p
            elif name.startswith("run + true pose's displacement"):
                Vs, Vt = Vs_r, Vs_r + (Vt_p - Vs_p)
            elif name == "source's image-plane error":
                shift = camera.project(Vs_p) - camera.project(Vs_r)
                Vs, Vt = image_plane_shift(Vs_r, shift, camera), image_plane_shift(Vt_r, shift, camera)
            else:
                if zbuf is None:
                    zbuf = _source_zbuffer(Vs_r, faces, camera, base.dense)
                kw = {}
                mask = true_person if "true fg" in name else fg
                if " x" in name:
                    kw["gain"] = float(name.split(" x")[1])
                if "dilation" in name:
                    kw["dilation"] = True
                if "smooth" in name:
                    kw["smooth"] = float(name.split("smooth ")[1])
                Vs, Vt, info = register_to_outline(Vs_r, Vt_r, faces, weights, parents, camera, mask, zbuf[0],
                                                   zbuf[1], base.dense.origin, **kw)
                if name.endswith("true pose's displacement"):
                    Vt = Vs + (Vt_p - Vs_p)
                if name == "registered twice":
                    p1 = warp_pairs(Vs, Vt, faces, camera, N_HANDLES, rim_cos=RIM_COS, dense=True, closed=True)
                    z1 = _source_zbuffer(Vs, faces, camera, p1.dense)
                    Vs, Vt, info = register_to_outline(Vs, Vt, faces, weights, parents, camera, mask, z1[0], z1[1],
                                                       p1.dense.origin)
                row[f"{name}: outline vertices"] = info["outline_vertices"]
                row[f"{name}: mean |offset| px"] = info["mean_abs_offset_px"]
            if p is None:
                p = warp_pairs(Vs, Vt, faces, camera, N_HANDLES, rim_cos=RIM_COS, dense=True, closed=True)
            field = mls_warp_field(p.src_uv, p.dst_uv, (camera.height, camera.width), kind="similarity",
                                   alpha=MLS_ALPHA, radius_px=MLS_RADIUS_PX, dense=p.dense, foreground=fg)
            row[name] = mask_iou(warp_foreground(frame.rgb, fg, field)[1] > 0.5, true_target)
            x0, y0 = p.dense.origin
            h, w = p.dense.source_mask.shape
            src = np.zeros_like(true_person)
            src[y0:y0 + h, x0:x0 + w] = p.dense.source_mask
            tgt = np.zeros_like(true_person)
            tgt[y0:y0 + h, x0:x0 + w] = np.isfinite(p.dense.source_uv[..., 0])
            row[f"{name}: source IoU"] = mask_iou(src, true_person)
            row[f"{name}: target IoU"] = mask_iou(tgt, true_target)
        out_rows.append(row)
        if per_frame is not None:
            with open(per_frame, "a") as f:
                f.write(json.dumps(row) + "\n")
    out = {"frames": len(out_rows)}
    for key in out_rows[0]:
        if key in ("session", "frame", "tracked"):
            continue
        out[key] = float(np.mean([r[key] for r in out_rows]))
    return out


def main() -> None:
    from bodystudio.capture.session import open_session

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sessions", nargs="+", type=Path)
    parser.add_argument("--stride", type=int, default=2)
    parser.add_argument("--rows", nargs="*", default=list(ROWS), choices=ROWS)
    parser.add_argument("--per-frame", type=Path, default=None)
    args = parser.parse_args()
    results = {p.name: score(open_session(p), args.rows, args.stride, per_frame=args.per_frame)
               for p in args.sessions}
    keys = list(next(iter(results.values())))
    print("| score | " + " | ".join(results) + " |")
    print("|---|" + "---|" * len(results))
    for key in keys:
        print(f"| {key} | " + " | ".join(f"{r[key]:.4f}" for r in results.values()) + " |")


if __name__ == "__main__":
    main()
