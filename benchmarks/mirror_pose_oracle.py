"""What a better pose would buy the mirror: the IK pose with parts of the true pose swapped in, scored by warp_iou.

Usage: PYTHONPATH=. python benchmarks/mirror_pose_oracle.py [--stride 4] [--source NAME.npz] SESSION [SESSION ...]

Per every ``stride``-th frame in which player 1 is tracked (a synthetic mirror session with ``gt/mirror``),
the fitted source body and its target are posed by

* ``IK``: the run's IK pose (:func:`bodystudio.mirror.track.ik_pose`, warm-started frame to frame);
* ``IK swing + true twist``: every bone's direction from the IK, its twist about that direction from the true
  pose (the true world rotation turned by the smallest rotation that takes its bone axis onto the IK's);
  ``(limbs)``: only the upper / lower arms, thighs and calves;
* ``true rotations, IK root``: every bone's true world rotation, the root's rotation and translation from the IK;
* ``true swing, IK twist (limbs)``, ``true spine_01``, ``IK rotations, true root``, ``true pose``: the other
  parts of the pose swapped in the same way (``true pose``: the fitted root head placed on the true one);
* ``true shape, IK pose``: the true rest bodies and skeletons (``gt/mirror/actors.npz``) tracked by the IK;
* ``true vertices``: the ground-truth posed source and target (the image step's ceiling);

and the dense warp of the run (graph-cut foreground) is scored against the target's true silhouette. Also
printed: the source vertex error, the displacement error ``(V_T - V_S)`` against the truth, the bones'
swing / twist errors of each pose (degrees, limbs and spine_01), the largest per-frame gain over the IK and the
depth residual (mean point-to-plane distance of the player's depth points, 2000 of them, to the posed fitted
source: what a depth refinement would minimise).
"""

from __future__ import annotations

import argparse
import contextlib
import time
from pathlib import Path

import numpy as np

from bodystudio.mirror.refine import TRUNK_AND_LIMB_BONES, TWIST_BONES, RefineWeights

#: The refined poses scored (docs/mirror.md, MIR12b): keyword arguments of ``refine_pose`` plus ``mask``
#: ("fg": the graph cut's foreground, "person": the raw SDK player mask), ``plan`` (the swing bones) and
#: ``warm`` (True: refined every tracked frame, warm-started by the previous frame's correction; "every 2nd": refined
#: from the IK on odd frames only, the even (scored) frames take the IK plus the last odd frame's correction).
REFINE_VARIANTS = {
    "refined (the run's --refine-pose)": {},
    "refined, raw player mask": {"mask": "person"},
    "refined, no silhouette": {"mask": "person", "weights": RefineWeights(sil_weight=0.0)},
    "refined, no depth (player mask)": {"mask": "person", "weights": RefineWeights(depth_weight=0.0)},
    "refined, 2 steps (player mask)": {"mask": "person", "iterations": 2},
    "refined, without spine_03, head, hands, feet": {"plan": TRUNK_AND_LIMB_BONES},
    "refined, warm-started by the previous frame's correction": {"warm": True},
    "refined every 2nd frame, the correction carried to the next": {"warm": "every 2nd"},
}

#: Further refined poses of the fitted body that ``--shape --variants NAME ...`` scores (keyword arguments of
#: ``refine_pose``; MIR12g).
SHAPE_ORACLE_VARIANTS: dict[str, dict] = {
    "2 steps": {"iterations": 2},
    "no joints": {"weights": RefineWeights(joint_weight=0.0)},
    "joints x4": {"weights": RefineWeights(joint_weight=4.0)},
    "depth x4": {"weights": RefineWeights(depth_weight=4.0)},
    "silhouette x4": {"weights": RefineWeights(sil_weight=4.0)},
    **{f"trunk {deg} deg": {"weights": RefineWeights(trunk_rad=float(np.radians(deg)))} for deg in (2, 4, 8, 16)},
    "trunk 16 deg and the hands": {"trunk_bones": ("spine_01", "spine_02", "spine_03", "neck_01", "head",
                                                    "clavicle_l", "clavicle_r", "hand_l", "hand_r")},
    "trunk 16 deg without the clavicles": {"trunk_bones": ("spine_01", "spine_02", "spine_03", "neck_01", "head")},
    "trunk 16 deg, spine only": {"trunk_bones": ("spine_01", "spine_02", "spine_03")},
    **{f"trunk {deg} deg, 2 steps": {"weights": RefineWeights(trunk_rad=float(np.radians(deg))), "iterations": 2}
       for deg in (4, 8)},
    # MIR12n: with the true shape too (``--variants-on-true-shape``): what limits the refinement's fit
    "2 steps, no joints": {"iterations": 2, "weights": RefineWeights(joint_weight=0.0)},
    "2 steps, no trunk prior": {"iterations": 2, "weights": RefineWeights(trunk_rad=None)},
    "2 steps, no depth": {"iterations": 2, "weights": RefineWeights(depth_weight=0.0)},
    "2 steps, 2000 depth points": {"iterations": 2, "weights": RefineWeights(depth_samples=2000)},
    "2 steps, no joints, no trunk prior": {"iterations": 2, "weights": RefineWeights(joint_weight=0.0,
                                                                                      trunk_rad=None)},
    "4 steps": {"iterations": 4},
    "2 steps, no silhouette": {"iterations": 2, "weights": RefineWeights(sil_weight=0.0)},
    "2 steps, joints x0.25": {"iterations": 2, "weights": RefineWeights(joint_weight=0.25)},
    "2 steps, 8000 depth points": {"iterations": 2, "weights": RefineWeights(depth_samples=8000)},
    "2 steps, silhouette only": {"iterations": 2, "weights": RefineWeights(depth_weight=0.0, joint_weight=0.0,
                                                                           trunk_rad=None)},
    "2 steps, E_out only": {"iterations": 2, "weights": RefineWeights(depth_weight=0.0, joint_weight=0.0,
                                                                      trunk_rad=None, sil_samples=0)},
    "2 steps, depth only": {"iterations": 2, "weights": RefineWeights(sil_weight=0.0, joint_weight=0.0,
                                                                      trunk_rad=None)},
    "2 steps, joints only": {"iterations": 2, "weights": RefineWeights(sil_weight=0.0, depth_weight=0.0,
                                                                       trunk_rad=None)},
}

LIMBS = ("upperarm_l", "upperarm_r", "lowerarm_l", "lowerarm_r", "thigh_l", "thigh_r", "calf_l", "calf_r")


def world_rotations(skeleton, pose) -> np.ndarray:
    """(B, 3, 3) rotation each bone applies in world axes (rest-world to posed-world), skeleton independent."""
    from bodystudio.body.skinning import forward_kinematics

    G = forward_kinematics(skeleton, pose)[:, :3, :3]
    return G @ np.transpose(skeleton.rest_rotations, (0, 2, 1))


def pose_from_world(skeleton, W: np.ndarray, translation):
    """The Pose of ``skeleton`` whose bones turn by the world rotations ``W`` (B, 3, 3)."""
    from scipy.spatial.transform import Rotation

    from bodystudio.body.pose import Pose

    Rr = skeleton.rest_rotations
    rel = np.empty_like(W)
    for j, p in enumerate(skeleton.parents):
        rel[j] = W[j] if p < 0 else W[p].T @ W[j]
    local = np.transpose(Rr, (0, 2, 1)) @ rel @ Rr
    return Pose(Rotation.from_matrix(local).as_rotvec(), np.asarray(translation, float))


def swing_twist_errors(skeleton, W_est, W_true, bones) -> tuple[np.ndarray, np.ndarray]:
    """Swing (bone direction) and twist (about it) angles of ``W_est`` against ``W_true``, degrees, per bone."""
    from bodystudio.body.ik import rotation_between

    swing, twist = [], []
    for j in bones:
        a = skeleton.rest_rotations[j][:, 1]
        d_e, d_t = W_est[j] @ a, W_true[j] @ a
        swing.append(np.degrees(np.arctan2(np.linalg.norm(np.cross(d_e, d_t)), d_e @ d_t)))  # exact near 0
        aligned = rotation_between(d_t, d_e) @ W_true[j]
        x_e, x_a = W_est[j] @ skeleton.rest_rotations[j][:, 0], aligned @ skeleton.rest_rotations[j][:, 0]
        twist.append(np.degrees(np.arctan2(np.cross(x_a, x_e) @ d_e, x_a @ x_e)))
    return np.array(swing), np.abs(np.array(twist))


def oracle_twist(skeleton, W_ik, W_true, bones) -> np.ndarray:
    """World rotations with the IK's bone directions and the true twist for ``bones`` (the IK's elsewhere)."""
    from bodystudio.body.ik import rotation_between

    W = W_ik.copy()
    for j in bones:
        a = skeleton.rest_rotations[j][:, 1]
        W[j] = rotation_between(W_true[j] @ a, W_ik[j] @ a) @ W_true[j]
    return W


def oracle_swing(skeleton, W_ik, W_true, bones) -> np.ndarray:
    """World rotations with the true bone directions and the IK's twist for ``bones`` (the IK's elsewhere)."""
    from bodystudio.body.ik import rotation_between

    W = W_ik.copy()
    for j in bones:
        a = skeleton.rest_rotations[j][:, 1]
        W[j] = rotation_between(W_ik[j] @ a, W_true[j] @ a) @ W_ik[j]
    return W


def score(session, stride: int = 4, player: int = 1, source=None, refine_only: bool = False) -> dict[str, float]:
    """Mean scores over every ``stride``-th tracked frame of ``session`` (see the module docstring)."""
    from scipy.spatial import cKDTree

    from bodystudio.body.pose import Pose
    from bodystudio.body.skeleton import Skeleton
    from bodystudio.geometry.mesh import vertex_normals
    from bodystudio.mirror.compose import update_background
    from bodystudio.mirror.evaluate import mask_iou
    from bodystudio.mirror.foreground import refine_foreground
    from bodystudio.mirror.frames import point_cloud, read_mirror_frame, register_depth_to_color
    from bodystudio.mirror.init import SourceBody
    from bodystudio.mirror.refine import refine_plan, refine_pose
    from bodystudio.mirror.reshape import posed_source_and_target, target_coeffs, target_skeleton
    from bodystudio.mirror.run import MLS_ALPHA, MLS_RADIUS_PX, N_HANDLES, RIM_COS, load_source
    from bodystudio.mirror.track import ik_pose
    from bodystudio.mirror.warp import mls_warp_field, warp_foreground, warp_pairs

    body, model = load_source(session, source)
    c_target = target_coeffs(model, body.coeffs, session.metadata["edits"])
    target_rest = model.vertices(c_target)
    target_rig = target_skeleton(body, target_rest, model, c_target)
    sk = body.skeleton
    actors = np.load(Path(session.path) / "gt" / "mirror" / "actors.npz")
    a = list(actors["players"]).index(player)
    true_sk = Skeleton(sk.bone_names, sk.parents, actors["source_heads"][a], actors["source_tails"][a], sk.rolls)
    true_body = SourceBody(body.coeffs, actors["source_rest_vertices"][a].astype(float), true_sk, body.frames_used,
                           body.residual_mm, body.weights, body.faces)
    true_target_rest = actors["target_rest_vertices"][a].astype(float)
    true_target_rig = Skeleton(sk.bone_names, sk.parents, actors["target_heads"][a], actors["target_tails"][a],
                               sk.rolls)
    previous_true_shape = None
    camera, faces = session.kinect.color, body.faces
    limbs = [sk.index(b) for b in LIMBS]
    spine = [sk.index("spine_01")]
    non_root = [j for j in range(sk.n_bones) if sk.parents[j] >= 0]
    root = int(np.flatnonzero(np.asarray(sk.parents) < 0)[0])
    background, previous, rows = None, None, []
    plans = {None: refine_plan(body.vertices, faces, body.weights, sk, session.kinect.version,
                               twist_bones=TWIST_BONES)}  # the run's plan (MIR12h)
    for kw in REFINE_VARIANTS.values():
        if "plan" in kw:
            plans[kw["plan"]] = refine_plan(body.vertices, faces, body.weights, sk, session.kinect.version,
                                            swing_bones=kw["plan"])
    refine_ms: dict[str, list[float]] = {}
    corrections: dict[str, tuple] = {}
    for i in session.frame_ids:
        frame = read_mirror_frame(session, i)
        depth_c, players_c = register_depth_to_color(frame.depth_m, frame.player, session.kinect)
        person = players_c == player
        tracked = frame.body(player)
        if tracked is None:
            background = update_background(background, frame.rgb, players_c > 0)
            continue
        pose_ik = ik_pose(sk, tracked.positions, tracked.tracked, session.kinect.version, previous=previous)
        previous = pose_ik
        warm = {}
        if any("warm" in kw for kw in REFINE_VARIANTS.values()):
            fg_w = refine_foreground(frame.rgb, person, depth_c, background=background)
            pts_w = point_cloud(frame, session.kinect, player)
            pts_w = pts_w[pts_w[:, 1] > 0.02]
            for rname, kw in REFINE_VARIANTS.items():
                if "warm" not in kw:
                    continue
                if kw["warm"] == "every 2nd" and i % 2 == 0:  # not refined: the last frame's correction
                    warm[rname] = corrected_pose(pose_ik, corrections.get(rname))
                    continue
                start = pose_ik if kw["warm"] == "every 2nd" else corrected_pose(pose_ik, corrections.get(rname))
                warm[rname] = refine_pose(plans[None], sk, start, camera, fg_w, tracked.positions, tracked.tracked,
                                          pts_w, (players_c > 0) & ~person, session.kinect.version)
                corrections[rname] = pose_correction(pose_ik, warm[rname])
        pose_true_shape = ik_pose(true_sk, tracked.positions, tracked.tracked, session.kinect.version,
                                  previous=previous_true_shape)
        previous_true_shape = pose_true_shape
        gt = session.frame(i).gt_mirror
        if i % stride or gt is None or player not in list(gt["players"]):
            continue
        k = list(gt["players"]).index(player)
        if not gt["reported"][k]:
            continue
        true_pose = Pose(gt["pose_rotations"][k].astype(float), gt["pose_translations"][k].astype(float))
        W_true, W_ik = world_rotations(true_sk, true_pose), world_rotations(sk, pose_ik)
        # the fitted root head placed where the true one is
        true_translation = true_pose.translation + true_sk.heads[root] - sk.heads[root]
        points = point_cloud(frame, session.kinect, player)
        points = points[points[:, 1] > 0.02][:: max(1, len(points) // 2000)]  # the floor under the feet
        fg = refine_foreground(frame.rgb, person, depth_c, background=background)
        others = (players_c > 0) & ~person
        refined = {}
        for rname, kw in REFINE_VARIANTS.items():
            if "warm" in kw:
                refined[rname] = warm[rname]
                continue
            kw = dict(kw)
            mask = fg if kw.pop("mask", "fg") == "fg" else person
            plan = plans[kw.pop("plan", None)]
            t0 = time.process_time()
            refined[rname] = refine_pose(plan, sk, pose_ik, camera, mask, tracked.positions, tracked.tracked,
                                         points, others, session.kinect.version, **kw)
            refine_ms.setdefault(rname, []).append(1e3 * (time.process_time() - t0))
        poses = {
            "IK": pose_ik,
            **refined,
            "IK swing + true twist (limbs)": pose_from_world(sk, oracle_twist(sk, W_ik, W_true, limbs),
                                                             pose_ik.translation),
            "IK swing + true twist": pose_from_world(sk, oracle_twist(sk, W_ik, W_true, non_root),
                                                     pose_ik.translation),
            "true swing, IK twist (limbs)": pose_from_world(sk, oracle_swing(sk, W_ik, W_true, limbs),
                                                            pose_ik.translation),
            "true spine_01": pose_from_world(sk, _replace(W_ik, W_true, spine), pose_ik.translation),
            "true rotations, IK root": pose_from_world(sk, _replace(W_ik, W_true, non_root), pose_ik.translation),
            "IK rotations, true root": pose_from_world(sk, _replace(W_ik, W_true, [root]), true_translation),
            "true pose": pose_from_world(sk, W_true, true_translation),
        }
        if refine_only:
            poses = {name: poses[name] for name in ("IK", *refined, "true rotations, IK root", "true pose")}
        Vs_t, Vt_t = gt["source_vertices"][k].astype(float), gt["target_vertices"][k].astype(float)
        true_target = session.frame(i).gt_target_person == player
        background = update_background(background, frame.rgb, fg | (players_c > 0))

        def warp_iou(A, B, rgb=frame.rgb, fg=fg, true_target=true_target):
            p = warp_pairs(A, B, faces, camera, N_HANDLES, rim_cos=RIM_COS, dense=True)
            field = mls_warp_field(p.src_uv, p.dst_uv, (camera.height, camera.width), kind="similarity",
                                   alpha=MLS_ALPHA, radius_px=MLS_RADIUS_PX, dense=p.dense)
            return mask_iou(warp_foreground(rgb, fg, field)[1] > 0.5, true_target)

        def depth_residual_mm(V, points=points):
            """Mean point-to-plane distance of the depth points to their nearest vertices (those within 5 cm)."""
            d, idx = cKDTree(V).query(points)
            keep = d < 0.05
            N = vertex_normals(V, faces)[idx[keep]]
            return 1e3 * float(np.mean(np.abs(np.einsum("ij,ij->i", points[keep] - V[idx[keep]], N))))

        row = {"true vertices": warp_iou(Vs_t, Vt_t), "true vertices: depth residual mm": depth_residual_mm(Vs_t)}
        if not refine_only:
            Vs, Vt = posed_source_and_target(true_body, true_target_rest, pose_true_shape, true_target_rig)
            row["true shape, IK pose"] = warp_iou(Vs, Vt)
            row["true shape, IK pose: displacement err mm"] = 1e3 * np.linalg.norm((Vt - Vs) - (Vt_t - Vs_t),
                                                                                  axis=1).mean()
        for name, pose in poses.items():
            Vs, Vt = posed_source_and_target(body, target_rest, pose, target_rig)
            W = world_rotations(sk, pose)
            sw, tw = swing_twist_errors(sk, W, W_true, limbs)
            sw_s, _ = swing_twist_errors(sk, W, W_true, spine)
            row[name] = warp_iou(Vs, Vt)
            row[f"{name}: depth residual mm"] = depth_residual_mm(Vs)
            if name != "IK":
                row[f"{name}: gain over IK, max per frame"] = row[name] - row["IK"]
            row[f"{name}: source vertex err mm"] = 1e3 * np.linalg.norm(Vs - Vs_t, axis=1).mean()
            row[f"{name}: displacement err mm"] = 1e3 * np.linalg.norm((Vt - Vs) - (Vt_t - Vs_t), axis=1).mean()
            row[f"{name}: limb swing / twist deg"] = (sw.mean(), tw.mean())
            row[f"{name}: spine_01 swing deg"] = sw_s.mean()
        rows.append(row)
    out = {"frames": len(rows), **{f"{k}: ms CPU": float(np.median(v)) for k, v in refine_ms.items()}}
    for key in rows[0]:
        vals = np.array([r[key] for r in rows], float)
        out[key] = float(vals.max()) if key.endswith("max per frame") else \
            tuple(vals.mean(0)) if vals.ndim > 1 else float(vals.mean())
    return out


#: Body regions of the shape oracle's per-region rows, by the vertex's dominant skin-weight bone.
#: Parts of the true pose swapped into the refined one by ``--shape --swap-parts`` (MIR12g): world rotations of
#: these bones (their children keep theirs); ``root``: the Root's rotation and its true head (the root's rotation
#: alone swings the body about the floor point: 28-38 mm of vertex error).
REFINED_SWAPS = {"root": ("Root",),
                 "pelvis and spine": ("pelvis", "spine_01", "spine_02", "spine_03"),
                 "neck and head": ("neck_01", "head"), "arms": ("clavicle_l", "clavicle_r", "upperarm_l", "upperarm_r",
                                                               "lowerarm_l", "lowerarm_r", "hand_l", "hand_r"),
                 "legs": ("thigh_l", "thigh_r", "calf_l", "calf_r", "foot_l", "foot_r")}

#: Bone groups whose swing error ``--shape`` reports (MIR12g).
SWING_GROUPS = {"spine_01": ("spine_01",), "spine_02, spine_03": ("spine_02", "spine_03"),
                "neck, head": ("neck_01", "head"), "clavicles": ("clavicle_l", "clavicle_r"),
                "upper arms": ("upperarm_l", "upperarm_r"), "forearms": ("lowerarm_l", "lowerarm_r"),
                "thighs": ("thigh_l", "thigh_r"), "calves": ("calf_l", "calf_r")}

REGIONS = {"torso": ("pelvis", "spine_01", "spine_02", "spine_03", "clavicle_l", "clavicle_r"),
           "head, neck": ("neck_01", "head"),
           "arms": ("upperarm_l", "upperarm_r", "lowerarm_l", "lowerarm_r"),
           "thighs": ("thigh_l", "thigh_r"), "calves, feet": ("calf_l", "calf_r", "foot_l", "foot_r", "ball_l",
                                                               "ball_r")}


def vertex_regions(weights: np.ndarray, bone_names) -> np.ndarray:
    """(n,) region name per vertex (:data:`REGIONS` by the dominant bone, ``"other"`` for hands and the rest)."""
    by_bone = {b: r for r, bones in REGIONS.items() for b in bones}
    return np.array([by_bone.get(bone_names[j], "other") for j in np.argmax(weights, axis=1)])


def signed_distance_px(mask: np.ndarray) -> np.ndarray:
    """Signed distance to the outline of ``mask`` (pixels; positive outside, negative inside)."""
    import cv2

    m = mask.astype(np.uint8)
    return (cv2.distanceTransform(1 - m, cv2.DIST_L2, 5) - cv2.distanceTransform(m, cv2.DIST_L2, 5)).astype(float)


def score_shape(session, stride: int = 4, player: int = 1, source=None, refine_steps=(1,), per_frame=None,
                fitted_variants=None, swap_parts: bool = False, variants_on_true: bool = False,
                from_true: bool = False, true_fg: bool = False, all_depth: bool = False) -> dict[str, float]:
    """What a better *shape* would buy (MIR12c): the fitted and the true rest bodies, each posed by its own IK,
    its own refined pose (``refine_pose`` as the run) and the true pose; plus, per body region, where the
    fitted body posed by the true pose misses: the signed distance (px, + outside) of its projected rim vertices
    to the true silhouette and the signed normal error of its vertices (mm, + the fitted surface outside).

    ``per_frame``: a path; each scored frame's row is written there as JSON lines (``frame``: its index).
    ``fitted_variants``: name -> keyword arguments of ``refine_pose`` (MIR12g), further refined poses of the fitted
    body scored as ``fitted shape, NAME``; ``swap_parts``: also the fitted body's refined pose with one part of the
    true pose swapped in (:data:`REFINED_SWAPS`)."""
    from bodystudio.body.pose import Pose
    from bodystudio.body.skeleton import Skeleton
    from bodystudio.geometry.mesh import vertex_normals
    from bodystudio.mirror.compose import update_background
    from bodystudio.mirror.evaluate import mask_iou
    from bodystudio.mirror.foreground import refine_foreground
    from bodystudio.mirror.frames import point_cloud, read_mirror_frame, register_depth_to_color
    from bodystudio.mirror.init import SourceBody
    from bodystudio.mirror.refine import refine_plan, refine_pose
    from bodystudio.mirror.reshape import posed_source_and_target, target_coeffs, target_skeleton
    from bodystudio.mirror.run import MLS_ALPHA, MLS_RADIUS_PX, N_HANDLES, RIM_COS, load_source
    from bodystudio.mirror.track import ik_pose
    from bodystudio.mirror.warp import mls_warp_field, warp_foreground, warp_pairs

    body, model = load_source(session, source)
    c_target = target_coeffs(model, body.coeffs, session.metadata["edits"])
    target_rest = model.vertices(c_target)
    sk = body.skeleton
    actors = np.load(Path(session.path) / "gt" / "mirror" / "actors.npz")
    a = list(actors["players"]).index(player)
    true_sk = Skeleton(sk.bone_names, sk.parents, actors["source_heads"][a], actors["source_tails"][a], sk.rolls)
    true_body = SourceBody(body.coeffs, actors["source_rest_vertices"][a].astype(float), true_sk, body.frames_used,
                           body.residual_mm, body.weights, body.faces)
    bodies = {"fitted shape": (body, target_rest, target_skeleton(body, target_rest, model, c_target)),
              "true shape": (true_body, actors["target_rest_vertices"][a].astype(float),
                             Skeleton(sk.bone_names, sk.parents, actors["target_heads"][a], actors["target_tails"][a],
                                      sk.rolls))}
    camera, faces = session.kinect.color, body.faces
    root = int(np.flatnonzero(np.asarray(sk.parents) < 0)[0])
    plans = {name: refine_plan(b.vertices, faces, b.weights, b.skeleton, session.kinect.version,
                               twist_bones=TWIST_BONES)
             for name, (b, _, _) in bodies.items()}
    regions = vertex_regions(body.weights, sk.bone_names)
    background, previous, rows = None, {}, []
    for i in session.frame_ids:
        frame = read_mirror_frame(session, i)
        depth_c, players_c = register_depth_to_color(frame.depth_m, frame.player, session.kinect)
        person = players_c == player
        tracked = frame.body(player)
        if tracked is None:
            background = update_background(background, frame.rgb, players_c > 0)
            continue
        ik = {}
        for name, (b, _, _) in bodies.items():
            ik[name] = previous[name] = ik_pose(b.skeleton, tracked.positions, tracked.tracked,
                                                session.kinect.version, previous=previous.get(name))
        gt = session.frame(i).gt_mirror
        if i % stride or gt is None or player not in list(gt["players"]):
            continue
        k = list(gt["players"]).index(player)
        if not gt["reported"][k]:
            continue
        true_pose = Pose(gt["pose_rotations"][k].astype(float), gt["pose_translations"][k].astype(float))
        points = point_cloud(frame, session.kinect, player)
        points = points[points[:, 1] > 0.02][:: 1 if all_depth else max(1, len(points) // 2000)]
        fg = refine_foreground(frame.rgb, person, depth_c, background=background)
        if true_fg:  # MIR12n: the true person mask instead of the graph cut's
            fg = session.frame(i).gt_person == player
        others = (players_c > 0) & ~person
        true_target = session.frame(i).gt_target_person == player
        true_source = session.frame(i).gt_person == player
        background = update_background(background, frame.rgb, fg | (players_c > 0))
        Vs_t = gt["source_vertices"][k].astype(float)

        def warp_iou(A, B, rgb=frame.rgb, fg=fg, true_target=true_target):
            p = warp_pairs(A, B, faces, camera, N_HANDLES, rim_cos=RIM_COS, dense=True)
            field = mls_warp_field(p.src_uv, p.dst_uv, (camera.height, camera.width), kind="similarity",
                                   alpha=MLS_ALPHA, radius_px=MLS_RADIUS_PX, dense=p.dense)
            return mask_iou(warp_foreground(rgb, fg, field)[1] > 0.5, true_target)

        row = {"true vertices": warp_iou(Vs_t, gt["target_vertices"][k].astype(float))}
        for name, (b, Vt_rest, t_rig) in bodies.items():
            translation = true_pose.translation + true_sk.heads[root] - b.skeleton.heads[root]
            poses = {"IK": ik[name]}
            for n_steps in refine_steps:
                poses["refined pose" if n_steps == 1 else f"refined pose, {n_steps} steps"] = refine_pose(
                    plans[name], b.skeleton, ik[name], camera, fg, tracked.positions, tracked.tracked, points, others,
                    session.kinect.version, iterations=n_steps)
            if name == "fitted shape" or variants_on_true:
                for vname, kwargs in (fitted_variants or {}).items():
                    kwargs = dict(kwargs)
                    with _trunk_bones(kwargs.pop("trunk_bones", None)):
                        poses[vname] = refine_pose(plans[name], b.skeleton, ik[name], camera, fg, tracked.positions,
                                                   tracked.tracked, points, others, session.kinect.version, **kwargs)
            poses["true pose"] = pose_from_world(b.skeleton, world_rotations(true_sk, true_pose), translation)
            if from_true:  # MIR12n: is the energy's minimum biased away from the true pose, or is it the start?
                poses["refined from the true pose, 2 steps"] = refine_pose(
                    plans[name], b.skeleton, poses["true pose"], camera, fg, tracked.positions, tracked.tracked,
                    points, others, session.kinect.version, iterations=2)
                for vname, kwargs in (fitted_variants or {}).items():
                    kwargs = dict(kwargs)
                    with _trunk_bones(kwargs.pop("trunk_bones", None)):
                        poses[f"from the true pose, {vname}"] = refine_pose(
                            plans[name], b.skeleton, poses["true pose"], camera, fg, tracked.positions,
                            tracked.tracked, points, others, session.kinect.version, **kwargs)
            W_true = world_rotations(true_sk, true_pose)
            if name == "fitted shape" and swap_parts:  # the refined pose with one part's true world rotations
                last = max(refine_steps)  # the swaps go into the pose of the most steps scored
                refined = poses["refined pose" if last == 1 else f"refined pose, {last} steps"]
                W_ref = world_rotations(b.skeleton, refined)
                for part, bone_names in REFINED_SWAPS.items():
                    idx = [sk.bone_names.index(n) for n in bone_names]
                    poses[f"refined, true {part}"] = pose_from_world(b.skeleton, _replace(W_ref, W_true, idx),
                                                                     translation if part == "root" else
                                                                     refined.translation)
            for pname, pose in poses.items():
                Vs, Vt = posed_source_and_target(b, Vt_rest, pose, t_rig)
                row[f"{name}, {pname}"] = warp_iou(Vs, Vt)
                row[f"{name}, {pname}: displacement err mm"] = 1e3 * np.linalg.norm(
                    (Vt - Vs) - (gt["target_vertices"][k] - Vs_t), axis=1).mean()
                if name == "fitted shape":  # where the pose is off: bone swing against the true pose (degrees)
                    W = world_rotations(b.skeleton, pose)
                    for group, bone_names in SWING_GROUPS.items():
                        idx = [sk.bone_names.index(n) for n in bone_names]
                        row[f"{name}, {pname}: swing err deg, {group}"] = float(np.mean(
                            swing_twist_errors(sk, W, W_true, idx)[0]))
                    R_err = W[root] @ W_true[root].T
                    row[f"{name}, {pname}: root rotation err deg"] = float(np.degrees(np.arccos(np.clip(
                        (np.trace(R_err) - 1) / 2, -1, 1))))
                row[f"{name}, {pname}: source vertex err mm"] = 1e3 * np.linalg.norm(Vs - Vs_t, axis=1).mean()
                row[f"{name}, {pname}: source silhouette IoU"] = mask_iou(
                    _silhouette(Vs, faces, camera), true_source)
        # where the fitted body, posed by the true pose, misses the true silhouette and surface
        Vs, _ = posed_source_and_target(body, target_rest, poses_fitted_true(body, true_sk, true_pose, root),
                                        bodies["fitted shape"][2])
        sd = signed_distance_px(true_source)
        err_n = 1e3 * np.einsum("ij,ij->i", Vs - Vs_t, vertex_normals(Vs_t, faces))
        for name, V in (("fitted shape, true pose", Vs), ("true vertices", Vs_t)):
            d_rim, rim = _rim_distances(V, faces, camera, sd, others)
            for region in REGIONS:
                sel = regions[rim] == region
                row[f"{name}, {region}: rim silhouette distance px (+ outside)"] = \
                    float(np.mean(d_rim[sel])) if sel.any() else 0.0
                if name != "true vertices":
                    row[f"{name}, {region}: normal err mm (+ outside)"] = float(np.mean(err_n[regions == region]))
        rows.append(row)
        if per_frame is not None:
            import json

            with open(per_frame, "a") as f:
                f.write(json.dumps({"session": Path(session.path).name, "frame": int(i), **row}) + "\n")
    out = {"frames": len(rows)}
    for key in rows[0]:
        out[key] = float(np.mean([r[key] for r in rows]))
    return out


#: Temporal filters of the refined poses scored by ``--temporal`` (MIR12g): name -> (kind, parameter). ``centred``:
#: the mean over +-k frames (not causal: a bound on what smoothing can buy); ``ema``: x_t = a m_t + (1 - a) x_{t-1};
#: ``alpha-beta``: the constant-velocity alpha-beta filter with (alpha, beta).
TEMPORAL_FILTERS = {"refined (the run)": ("none", None), "centred mean +-1": ("centred", 1),
                    "centred mean +-2": ("centred", 2), "centred mean +-4": ("centred", 4),
                    "ema 0.5": ("ema", 0.5), "alpha-beta 0.5 / 0.1": ("alpha-beta", (0.5, 0.1)),
                    "alpha-beta 0.3 / 0.05": ("alpha-beta", (0.3, 0.05))}


def filter_sequence(X: np.ndarray, kind: str, param) -> np.ndarray:
    """Rows of ``X`` (T, D) (the frames' pose vectors) filtered over time by ``kind`` (see TEMPORAL_FILTERS)."""
    X = np.asarray(X, float)
    if kind == "none":
        return X.copy()
    if kind == "centred":
        return np.array([X[max(0, t - param): t + param + 1].mean(0) for t in range(len(X))])
    out = np.empty_like(X)
    x, v = X[0].copy(), np.zeros(X.shape[1])
    out[0] = x
    for t in range(1, len(X)):
        if kind == "ema":
            x = param * X[t] + (1 - param) * x
        else:
            a, b = param
            pred = x + v
            r = X[t] - pred
            x, v = pred + a * r, v + b * r
        out[t] = x
    return out


def score_temporal(session, stride: int = 4, player: int = 1, source=None, filters=None) -> dict[str, float]:
    """What smoothing the refined poses over time buys (MIR12g): the fitted body's IK pose refined every tracked
    frame (as the run), the sequence of poses (local rotation vectors and the root translation) filtered by each
    of ``filters`` (:data:`TEMPORAL_FILTERS`), every ``stride``-th frame scored by the run's dense warp."""
    from bodystudio.body.pose import Pose
    from bodystudio.mirror.compose import update_background
    from bodystudio.mirror.evaluate import mask_iou
    from bodystudio.mirror.foreground import refine_foreground
    from bodystudio.mirror.frames import point_cloud, read_mirror_frame, register_depth_to_color
    from bodystudio.mirror.refine import refine_plan, refine_pose
    from bodystudio.mirror.reshape import posed_source_and_target, target_coeffs, target_skeleton
    from bodystudio.mirror.run import MLS_ALPHA, MLS_RADIUS_PX, N_HANDLES, RIM_COS, load_source
    from bodystudio.mirror.track import ik_pose
    from bodystudio.mirror.warp import mls_warp_field, warp_foreground, warp_pairs

    filters = TEMPORAL_FILTERS if filters is None else filters
    body, model = load_source(session, source)
    c_target = target_coeffs(model, body.coeffs, session.metadata["edits"])
    target_rest = model.vertices(c_target)
    rig = target_skeleton(body, target_rest, model, c_target)
    camera, faces = session.kinect.color, body.faces
    plan = refine_plan(body.vertices, faces, body.weights, body.skeleton, session.kinect.version,
                       twist_bones=TWIST_BONES)
    background, previous, seq, scored = None, None, [], []
    for i in session.frame_ids:
        frame = read_mirror_frame(session, i)
        depth_c, players_c = register_depth_to_color(frame.depth_m, frame.player, session.kinect)
        person = players_c == player
        tracked = frame.body(player)
        if tracked is None:
            background = update_background(background, frame.rgb, players_c > 0)
            seq = []  # a gap in the tracking restarts the filters
            continue
        previous = ik = ik_pose(body.skeleton, tracked.positions, tracked.tracked, session.kinect.version,
                                previous=previous)
        points = point_cloud(frame, session.kinect, player)
        points = points[points[:, 1] > 0.02]
        fg = refine_foreground(frame.rgb, person, depth_c, background=background)
        others = (players_c > 0) & ~person
        background = update_background(background, frame.rgb, fg | (players_c > 0))
        pose = refine_pose(plan, body.skeleton, ik, camera, fg, tracked.positions, tracked.tracked, points, others,
                           session.kinect.version)
        seq.append(np.r_[pose.rotations.ravel(), pose.translation])
        gt = session.frame(i).gt_mirror
        if i % stride or gt is None or player not in list(gt["players"]):
            continue
        k = list(gt["players"]).index(player)
        if not gt["reported"][k]:
            continue
        scored.append((i, len(seq) - 1, id(seq), frame.rgb, fg, session.frame(i).gt_target_person == player))
        scored[-1] = scored[-1] + (seq,)
    rows = []
    for i, t, _, rgb, fg, true_target, s in scored:
        row = {"frame": int(i)}
        X = np.array(s)
        for name, (kind, param) in filters.items():
            x = filter_sequence(X[: t + 1] if kind != "centred" else X, kind, param)[t]
            pose = Pose(x[:-3].reshape(-1, 3), x[-3:])
            Vs, Vt = posed_source_and_target(body, target_rest, pose, rig)
            p = warp_pairs(Vs, Vt, faces, camera, N_HANDLES, rim_cos=RIM_COS, dense=True)
            field = mls_warp_field(p.src_uv, p.dst_uv, (camera.height, camera.width), kind="similarity",
                                   alpha=MLS_ALPHA, radius_px=MLS_RADIUS_PX, dense=p.dense)
            row[name] = mask_iou(warp_foreground(rgb, fg, field)[1] > 0.5, true_target)
        rows.append(row)
    out = {"frames": len(rows)}
    for key in filters:
        out[key] = float(np.mean([r[key] for r in rows]))
    out["per frame"] = rows
    return out


@contextlib.contextmanager
def _trunk_bones(bones):
    """``refine.TRUNK_BONES`` set to ``bones`` while the block runs (None: as it is)."""
    from bodystudio.mirror import refine

    original = refine.TRUNK_BONES
    if bones is not None:
        refine.TRUNK_BONES = tuple(bones)
    try:
        yield
    finally:
        refine.TRUNK_BONES = original


def poses_fitted_true(body, true_sk, true_pose, root):
    """The true pose on the fitted skeleton: every bone's true world rotation, the root head on the true one."""
    return pose_from_world(body.skeleton, world_rotations(true_sk, true_pose),
                           true_pose.translation + true_sk.heads[root] - body.skeleton.heads[root])


def _rim_distances(V, faces, camera, signed_distance, others) -> tuple[np.ndarray, np.ndarray]:
    """Signed silhouette distance (px) at the projections of the rim vertices of ``V`` (normal within 12 degrees
    of perpendicular to the viewing ray, not on another player) and the rim's vertex mask."""
    from bodystudio.geometry.mesh import vertex_normals

    uv, _ = camera.project_with_depth(V)
    N = vertex_normals(V, faces)
    ray = V - camera.center
    cos = np.einsum("ij,ij->i", N, ray) / np.linalg.norm(ray, axis=1)
    inside = np.all((uv >= 0) & (uv < [camera.width - 1, camera.height - 1]), axis=1)
    px = np.clip(np.nan_to_num(uv).astype(int), 0, [camera.width - 1, camera.height - 1])
    rim = inside & (np.abs(cos) < 0.2) & ~others[px[:, 1], px[:, 0]]
    return signed_distance[px[rim, 1], px[rim, 0]], rim


def _silhouette(V, faces, camera) -> np.ndarray:
    from bodystudio.capture.render import render

    return render(V, faces, camera).mask


def pose_correction(ik, refined) -> tuple[np.ndarray, np.ndarray]:
    """What the refinement changed: per bone the rotation ``C_j = R_refined,j R_ik,j^-1`` (rotation vectors,
    (B, 3)) and the root translation's change, to warm-start the next frame (``corrected_pose``)."""
    from scipy.spatial.transform import Rotation

    C = Rotation.from_rotvec(refined.rotations) * Rotation.from_rotvec(ik.rotations).inv()
    return C.as_rotvec(), refined.translation - ik.translation


def corrected_pose(ik, correction: tuple[np.ndarray, np.ndarray] | None):
    """The IK pose of a frame with the previous frame's refinement ``correction`` applied: the refinement's
    warm start, so that the IK's slowly changing bias (spine_01's swing, the root's depth) is not re-learnt
    from the IK each frame."""
    if correction is None:
        return ik
    from scipy.spatial.transform import Rotation

    from bodystudio.body.pose import Pose

    rot = Rotation.from_rotvec(correction[0]) * Rotation.from_rotvec(ik.rotations)
    return Pose(rot.as_rotvec(), ik.translation + correction[1])


def _replace(W_ik, W_true, bones) -> np.ndarray:
    W = W_ik.copy()
    W[bones] = W_true[bones]
    return W


def main() -> None:
    from bodystudio.capture.session import open_session

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sessions", nargs="+", type=Path)
    parser.add_argument("--stride", type=int, default=4)
    parser.add_argument("--source", default=None, help="source body .npz name inside SESSION/mirror/")
    parser.add_argument("--refine-only", action="store_true",
                        help="only the IK, the refined poses (REFINE_VARIANTS), true rotations and the true pose")
    parser.add_argument("--shape", action="store_true",
                        help="the shape oracle (MIR12c): fitted and true rest bodies under the IK, refined and true "
                             "pose, and per body region where the fitted body misses")
    parser.add_argument("--refine-steps", type=int, nargs="+", default=[1],
                        help="with --shape: the pose refinement's Gauss-Newton steps scored (the run's: 1)")
    parser.add_argument("--variants", nargs="*", default=[], choices=sorted(SHAPE_ORACLE_VARIANTS),
                        help="with --shape: further refined poses of the fitted body (SHAPE_ORACLE_VARIANTS)")
    parser.add_argument("--variants-on-true-shape", action="store_true",
                        help="with --shape --variants: the variants' refined poses of the true shape too")
    parser.add_argument("--all-depth", action="store_true",
                        help="with --shape: every depth point of the player (the run's), not every n-th of 2000")
    parser.add_argument("--true-fg", action="store_true",
                        help="with --shape: the true person mask as the foreground (refinement and warp)")
    parser.add_argument("--from-true", action="store_true",
                        help="with --shape: also the refinement (2 steps) started from the true pose")
    parser.add_argument("--swap-parts", action="store_true",
                        help="with --shape: the refined pose with one part of the true pose swapped in (REFINED_SWAPS)")
    parser.add_argument("--temporal", action="store_true",
                        help="the refined poses smoothed over time by each of TEMPORAL_FILTERS (MIR12g)")
    parser.add_argument("--per-frame", type=Path, default=None,
                        help="with --shape: append each scored frame's row to this file (JSON lines)")
    args = parser.parse_args()
    results = {}
    for p in args.sessions:
        src = None if args.source is None else p / "mirror" / args.source
        if args.temporal:
            results[p.name] = score_temporal(open_session(p), args.stride, source=src)
            rows = results[p.name].pop("per frame")
            if args.per_frame is not None:
                import json

                with open(args.per_frame, "a") as f:
                    for r in rows:
                        f.write(json.dumps({"session": p.name, **r}) + "\n")
            continue
        if args.shape:
            results[p.name] = score_shape(open_session(p), args.stride, source=src,
                                          refine_steps=tuple(args.refine_steps), per_frame=args.per_frame,
                                          fitted_variants={k: SHAPE_ORACLE_VARIANTS[k] for k in args.variants},
                                          swap_parts=args.swap_parts,
                                          variants_on_true=args.variants_on_true_shape, from_true=args.from_true,
                                          true_fg=args.true_fg, all_depth=args.all_depth)
        else:
            results[p.name] = score(open_session(p), args.stride, source=src, refine_only=args.refine_only)
    keys = list(next(iter(results.values())))
    print("| score | " + " | ".join(results) + " |")
    print("|---|" + "---|" * len(results))

    def fmt(v):
        return " / ".join(f"{x:.3g}" for x in v) if isinstance(v, tuple) else f"{v:.4g}"

    for key in keys:
        print(f"| {key} | " + " | ".join(fmt(r[key]) for r in results.values()) + " |")


if __name__ == "__main__":
    main()
