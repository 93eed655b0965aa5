"""Where the mirror's end-to-end warp_iou is lost: each stage swapped for its ground truth, one at a time.

Usage: PYTHONPATH=. python benchmarks/mirror_warp_decomposition.py [--stride 4] [--cache DIR]
[--skeleton source|eq3|model] [SESSION ...]

Without SESSION, the two MIR-SYNTH sessions of docs/mirror.md ("Where the end-to-end warp_iou was lost") are
synthesised into ``--cache`` (kept for the next run): subject 41 walking in and doing ``arms_raise``,
``--taller 0.17 --heavier 15``, and subject 42 walking in and walking in place, ``--taller -0.17 --heavier
-15``, 100 frames each (neither subject is used by the tests). A session without ``mirror/source_body.npz``
is initialised first (``bodystudio mirror init``'s defaults). Then every ``stride``-th frame in which the
tracker reports player 1 is scored against ``gt/target/person`` with the run's own functions (IK, posing,
vertex pairs, graph cut, MLS warp), with these inputs:

* ``pipeline``: the fitted, IK-posed source and target, the graph-cut foreground (``mirror run
  --correspondence mls``); ``pipeline, dense``: the same with the dense correspondence (``mirror run``'s default);
* ``true vertices`` (``, dense``): the posed vertices of ``gt/mirror`` (the image steps' ceiling), MLS only / dense;
* ``true vertices, dense, true foreground``: the same warping the true person mask;
* ``true positions + fitted displacement``: the true source and true source + (fitted V_T - V_S);
* ``fitted positions + true displacement``: the fitted source and fitted source + (true V_T - V_S);
* ``pipeline, true foreground``: the pipeline's pairs warping the true person mask;

and prints the means with the fitted bodies' silhouette IoU and vertex / displacement errors. ``--skeleton``
(:func:`decompose`) tracks with the source body's skeleton as written (default), Eq. 3's or the model's joints.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

#: (folder name, subject seed, edits, motion) of the default sessions.
DEFAULT_SESSIONS = (("mirror-warp-41", 41, {"taller": 0.17, "heavier": 15.0}, "arms_raise"),
                    ("mirror-warp-42", 42, {"taller": -0.17, "heavier": -15.0}, "walk"))


def decompose(session, stride: int = 4, player: int = 1, skeleton: str = "source") -> dict[str, float]:
    """Mean scores over every ``stride``-th tracked frame of ``session`` (see the module docstring).

    ``skeleton``: ``source`` tracks with the source body's skeleton as ``mirror init`` wrote it and builds the
    target's by the run's :func:`target_skeleton`; ``eq3`` / ``model`` first replace the source skeleton by
    Eq. 3's (``refit_skeleton``) / the statistical model's joint regressor (``model.skeleton(coeffs)``).
    """
    from bodystudio.capture.render import render
    from bodystudio.mirror.compose import update_background
    from bodystudio.mirror.evaluate import mask_iou
    from bodystudio.mirror.foreground import refine_foreground
    from bodystudio.mirror.frames import read_mirror_frame, register_depth_to_color
    from bodystudio.mirror.init import SourceBody, initialise_source_body, refit_skeleton, save_source_body
    from bodystudio.mirror.reshape import posed_source_and_target, target_coeffs, target_skeleton
    from bodystudio.mirror.run import MLS_ALPHA, MLS_RADIUS_PX, N_HANDLES, RIM_COS, load_source
    from bodystudio.mirror.track import ik_pose
    from bodystudio.mirror.warp import mls_warp_field, warp_foreground, warp_pairs

    source_path = Path(session.path) / "mirror" / "source_body.npz"
    if not source_path.is_file():
        source_path.parent.mkdir(exist_ok=True)
        save_source_body(source_path, initialise_source_body(session, player=player))
    body, model = load_source(session)
    if skeleton != "source":
        sk = refit_skeleton(model, body.coeffs) if skeleton == "eq3" else model.skeleton(body.coeffs)
        body = SourceBody(body.coeffs, body.vertices, sk, body.frames_used, body.residual_mm, body.weights,
                          body.faces)
    c_target = target_coeffs(model, body.coeffs, session.metadata["edits"])
    target_rest = model.vertices(c_target)
    target_rig = target_skeleton(body, target_rest, model, c_target)
    camera, faces = session.kinect.color, body.faces
    background, previous, rows = None, None, []
    for i in session.frame_ids:
        frame = read_mirror_frame(session, i)
        depth_c, players_c = register_depth_to_color(frame.depth_m, frame.player, session.kinect)
        person = players_c == player
        tracked = frame.body(player)
        if tracked is None:
            background = update_background(background, frame.rgb, players_c > 0)
            continue
        previous = pose = ik_pose(body.skeleton, tracked.positions, tracked.tracked, session.kinect.version,
                                  previous=previous)
        gt = session.frame(i).gt_mirror
        if i % stride or gt is None or player not in list(gt["players"]):
            continue
        k = list(gt["players"]).index(player)
        if not gt["reported"][k]:
            continue
        Vs_f, Vt_f = posed_source_and_target(body, target_rest, pose, target_rig)
        Vs_t, Vt_t = gt["source_vertices"][k].astype(float), gt["target_vertices"][k].astype(float)
        true_person = session.frame(i).gt_person == player
        true_target = session.frame(i).gt_target_person == player
        fg = refine_foreground(frame.rgb, person, depth_c, background=background)
        background = update_background(background, frame.rgb, fg | (players_c > 0))

        def warp_iou(A, B, mask, rgb=frame.rgb, target=true_target, dense=False):
            p = warp_pairs(A, B, faces, camera, N_HANDLES, rim_cos=RIM_COS, dense=dense)
            field = mls_warp_field(p.src_uv, p.dst_uv, (camera.height, camera.width), kind="similarity",
                                   alpha=MLS_ALPHA, radius_px=MLS_RADIUS_PX, dense=p.dense)
            return mask_iou(warp_foreground(rgb, mask, field)[1] > 0.5, target)

        rows.append({
            "pipeline": warp_iou(Vs_f, Vt_f, fg),
            "pipeline, dense": warp_iou(Vs_f, Vt_f, fg, dense=True),
            "true vertices": warp_iou(Vs_t, Vt_t, fg),
            "true vertices, dense": warp_iou(Vs_t, Vt_t, fg, dense=True),
            "true vertices, dense, true foreground": warp_iou(Vs_t, Vt_t, true_person, dense=True),
            "true positions + fitted displacement": warp_iou(Vs_t, Vs_t + (Vt_f - Vs_f), fg),
            "fitted positions + true displacement": warp_iou(Vs_f, Vs_f + (Vt_t - Vs_t), fg),
            "pipeline, true foreground": warp_iou(Vs_f, Vt_f, true_person),
            "unwarped": mask_iou(true_person, true_target),
            "fg_iou (SDK mask)": mask_iou(fg, true_person),
            "fg_iou_raw": mask_iou(person, true_person),
            "fitted source silhouette IoU": mask_iou(render(Vs_f, faces, camera).mask, true_person),
            "fitted target silhouette IoU": mask_iou(render(Vt_f, faces, camera).mask, true_target),
            "source vertex error mm": 1e3 * np.linalg.norm(Vs_f - Vs_t, axis=1).mean(),
            "target vertex error mm": 1e3 * np.linalg.norm(Vt_f - Vt_t, axis=1).mean(),
            "displacement error mm": 1e3 * np.linalg.norm((Vt_f - Vs_f) - (Vt_t - Vs_t), axis=1).mean(),
        })
    if not rows:
        raise SystemExit(f"{session.path}: no frame with player {player} tracked and ground truth")
    return {"frames": len(rows), **{key: float(np.mean([r[key] for r in rows])) for key in rows[0]}}


def main() -> None:
    from bodystudio.capture.session import open_session
    from bodystudio.mirror.synthetic import synth_mirror_session

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sessions", nargs="*", type=Path)
    parser.add_argument("--stride", type=int, default=4)
    parser.add_argument("--skeleton", choices=("source", "eq3", "model"), default="source")
    parser.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "bodystudio-mirror-warp")
    args = parser.parse_args()
    paths = list(args.sessions)
    if not paths:
        args.cache.mkdir(parents=True, exist_ok=True)
        for name, seed, edits, motion in DEFAULT_SESSIONS:
            path = args.cache / name
            if not path.exists():
                synth_mirror_session(path, seed, n_frames=100, edits=edits, motion=motion)
            paths.append(path)
    results = {p.name: decompose(open_session(p), args.stride, skeleton=args.skeleton) for p in paths}
    keys = list(next(iter(results.values())))
    print("| score | " + " | ".join(results) + " |")
    print("|---|" + "---|" * len(results))
    for key in keys:
        print(f"| {key} | " + " | ".join(f"{r[key]:.4g}" for r in results.values()) + " |")


if __name__ == "__main__":
    main()
