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
* ``registered``: :func:`register_to_outline` (below) on the graph cut's foreground;
  ``registered, true fg``: on the true person mask (oracle of the foreground); ``registered xK``: gain K.
Nothing is chosen by the truth: the registered rows see only the frame's foreground and bodies.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import cv2
import numpy as np

from bodystudio.mirror.warp import _area_weighted_normals, _nearest_depth_3x3, _signed_distance

ROWS = ("run", "true pose", "source's image-plane error", "registered", "registered, dilation",
        "registered, true fg", "registered x0.5", "registered, smooth 5", "registered, smooth 80",
        "registered twice", "run + true pose's displacement", "registered + true pose's displacement")


#: Rim test of the outline's vertices: |cos| between the vertex normal and the viewing ray below this.
RIM_COS = 0.3
#: A rim vertex counts as on the source's outline within this many pixels of it.
ON_OUTLINE_PX = 1.0
#: Outline offsets beyond this (pixels) are not the fit's misalignment (hair, a bag, the cut's errors): dropped.
MAX_OFFSET_PX = 6.0
#: Tikhonov weights of the per-bone translations: toward the parent bone's and toward none (per outline vertex
#: they are a fraction of one vertex's row; bones nobody sees take their neighbours' translation).
SMOOTH_WEIGHT = 20.0
RIDGE_WEIGHT = 1.0
#: Huber threshold (pixels) of the one reweighted solve.
HUBER_PX = 1.5


def outline_offsets(uv: np.ndarray, source_mask: np.ndarray, foreground: np.ndarray, origin) -> tuple:
    """Signed outline offsets at image points ``uv`` (n, 2) near the source silhouette's outline.

    ``source_mask`` (h, w) the source body's silhouette on a crop at ``origin`` (x0, y0), ``foreground`` the
    person's mask, full image. Returns ``(offset_px, normal, on_outline)``: how far the foreground's outline lies
    outside the source's along the source's outward normal (its signed distance minus the source's, positive where
    the person reaches beyond the body), the unit outward normal (n, 2) and whether the point lies within
    :data:`ON_OUTLINE_PX` of the source's outline.
    """
    x0, y0 = origin
    h, w = source_mask.shape
    H, W = foreground.shape
    fg = np.zeros((h, w), bool)
    ys, xs = slice(max(y0, 0), min(y0 + h, H)), slice(max(x0, 0), min(x0 + w, W))
    fg[ys.start - y0:ys.stop - y0, xs.start - x0:xs.stop - x0] = foreground[ys, xs]
    sd_s = _signed_distance(source_mask)
    sd_f = _signed_distance(fg)
    x = np.asarray(uv[:, 0], np.float32) - x0
    y = np.asarray(uv[:, 1], np.float32) - y0

    def at(img, dx=0.0, dy=0.0):
        return cv2.remap(img, (x + dx)[None], (y + dy)[None], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)[0]

    s = at(sd_s)
    g = np.stack([at(sd_s, 1.0) - at(sd_s, -1.0), at(sd_s, 0.0, 1.0) - at(sd_s, 0.0, -1.0)], axis=1)
    normal = -g / np.maximum(np.linalg.norm(g, axis=1, keepdims=True), 1e-6)
    inside_crop = (x >= 1) & (x < w - 2) & (y >= 1) & (y < h - 2)
    return (at(sd_f) - s).astype(np.float64), normal.astype(np.float64), inside_crop & (np.abs(s) <= ON_OUTLINE_PX)


def bone_translations(weights: np.ndarray, parents, normal: np.ndarray, offset: np.ndarray,
                      smooth: float = SMOOTH_WEIGHT, ridge: float = RIDGE_WEIGHT, huber_px: float = HUBER_PX,
                      dilation: bool = False):
    """Per-bone 2D translations (B, 2) whose skin-weighted blend moves each outline point by ``offset`` along
    ``normal`` (least squares, point-to-line), tied to the parent bone's translation and to zero. ``dilation``: also
    a per-bone growth along the outline's normal (B,), returned as a third column."""
    Wt = np.asarray(weights, np.float64)
    n, B = Wt.shape
    blocks = [Wt * normal[:, :1], Wt * normal[:, 1:]] + ([Wt] if dilation else [])
    A = np.concatenate(blocks, axis=1)  # (n, 2B or 3B): [t_x, t_y, growth]
    L = np.zeros((B, B))
    for b, p in enumerate(parents):
        if p >= 0:
            L[b, b] += 1
            L[p, p] += 1
            L[b, p] -= 1
            L[p, b] -= 1
    reg = np.kron(np.eye(len(blocks)), smooth * L + ridge * np.eye(B))
    r = np.ones(n)
    t = np.zeros(A.shape[1])
    for _ in range(2):
        Aw = A * r[:, None]
        t = np.linalg.solve(A.T @ Aw + reg, Aw.T @ offset)
        res = np.abs(A @ t - offset)
        r = np.where(res <= huber_px, 1.0, huber_px / np.maximum(res, 1e-9))
    return t.reshape(len(blocks), B).T


def image_plane_shift(V: np.ndarray, shift_px: np.ndarray, camera) -> np.ndarray:
    """``V`` (n, 3) moved parallel to the image plane so that each projects ``shift_px`` (n, 2) further (pinhole)."""
    Xc = V @ camera.R.T + camera.t
    d = np.zeros_like(Xc)
    d[:, 0] = shift_px[:, 0] * Xc[:, 2] / camera.K[0, 0]
    d[:, 1] = shift_px[:, 1] * Xc[:, 2] / camera.K[1, 1]
    return V + d @ camera.R


def register_to_outline(Vs: np.ndarray, Vt: np.ndarray, faces: np.ndarray, weights: np.ndarray, parents, camera,
                        foreground: np.ndarray, source_mask: np.ndarray, source_depth: np.ndarray, origin,
                        gain: float = 1.0, **kw) -> tuple[np.ndarray, np.ndarray, dict]:
    """Source and target vertices moved in the image plane by the source outline's registration to ``foreground``.

    ``source_mask`` / ``source_depth`` the source body's silhouette and z-buffer on the crop at ``origin``.
    Returns the moved ``(Vs, Vt)`` and a dict of diagnostics (outline vertices used, mean |offset| before).
    """
    uv, z = camera.project_with_depth(Vs)
    N = _area_weighted_normals(Vs, np.asarray(faces, np.int64))
    ray = Vs - camera.center
    cos = np.abs(np.einsum("ij,ij->i", N, ray)) / np.maximum(
        np.linalg.norm(N, axis=1) * np.linalg.norm(ray, axis=1), 1e-12)
    x0, y0 = origin
    col = np.clip(np.round(uv[:, 0] - x0), 0, source_mask.shape[1] - 1).astype(np.int64)
    row = np.clip(np.round(uv[:, 1] - y0), 0, source_mask.shape[0] - 1).astype(np.int64)
    visible = z <= _nearest_depth_3x3(source_depth, row, col) + 0.02
    cand = np.flatnonzero((cos < RIM_COS) & visible & (z > 0))
    offset, normal, on = outline_offsets(uv[cand], source_mask, foreground, origin)
    keep = on & (np.abs(offset) <= MAX_OFFSET_PX)
    ids = cand[keep]
    info = {"outline_vertices": int(len(ids)), "mean_abs_offset_px": float(np.abs(offset[keep]).mean())
            if len(ids) else 0.0}
    if len(ids) < 20:
        return Vs, Vt, info
    t = bone_translations(weights[ids], parents, normal[keep], offset[keep], **kw)
    Wt = np.asarray(weights, np.float64)
    shift = gain * (Wt @ t[:, :2])
    if t.shape[1] == 3:  # growth along each vertex's projected normal (the rim's full, a front-facing one's none)
        Np = _projected_normals(Vs, N, camera)
        shift_s = shift + gain * (Wt @ t[:, 2])[:, None] * Np
        Np_t = _projected_normals(Vt, _area_weighted_normals(Vt, np.asarray(faces, np.int64)), camera)
        shift_t = shift + gain * (Wt @ t[:, 2])[:, None] * Np_t
        return image_plane_shift(Vs, shift_s, camera), image_plane_shift(Vt, shift_t, camera), info
    return image_plane_shift(Vs, shift, camera), image_plane_shift(Vt, shift, camera), info


def _projected_normals(V, N, camera) -> np.ndarray:
    """Each vertex's unit normal turned into the camera frame, its image-plane part (n, 2): length 1 on the rim."""
    Nc = (N / np.maximum(np.linalg.norm(N, axis=1, keepdims=True), 1e-12)) @ camera.R.T
    return Nc[:, :2]


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
        UNTWIST_BONES,
        load_source,
        refine_steps,
        refine_weights,
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
        if UNTWIST_BONES:  # as the run (MIR12p)
            ik = untwisted_pose(sk, ik, UNTWIST_BONES)
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
