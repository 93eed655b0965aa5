"""Variants of the silhouette shape refinement (MIR12c) from a session's existing source body.

Usage: PYTHONPATH=. python benchmarks/mirror_shape_refine_variants.py [--source source_body.npz] [--views 6]
       [--iterations 3] [--weights "mass_kg=0,stature_mm=0,joint_pose=False,..."] [--write NAME.npz] SESSION [...]

Per synthetic mirror session: the source body's frames (``frames_used``), each with the graph cut's foreground
(a background model from every earlier frame without a player), the player's depth points and joints, ``--views``
of them evenly spread; ``refine_shape_to_silhouettes`` from the body's coefficients with the ``ShapeWeights``
fields given in ``--weights``. Prints the rest vertex error against the true rest mesh (mean, translation removed),
the stature and mass errors (the model's measures of the projected true mesh), the mean coefficient error in
population sigmas, before -> after, and the CPU time; ``--write`` saves the refined body into ``SESSION/mirror/``
for ``mirror_pose_oracle.py --shape --source`` (docs/mirror.md, MIR12c).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np


def main() -> None:
    from bodystudio.body.statistical import load_statistical_model
    from bodystudio.capture.session import open_session
    from bodystudio.mirror import shape_refine as sr
    from bodystudio.mirror.compose import update_background
    from bodystudio.mirror.foreground import refine_foreground
    from bodystudio.mirror.frames import point_cloud, read_mirror_frame, register_depth_to_color
    from bodystudio.mirror.init import SourceBody, load_source_body, save_source_body

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("sessions", nargs="+", type=Path)
    ap.add_argument("--source", default="source_body.npz", help="source body .npz inside SESSION/mirror/")
    ap.add_argument("--views", type=int, default=6)
    ap.add_argument("--iterations", type=int, default=3)
    ap.add_argument("--weights", default="", help="ShapeWeights fields, e.g. 'mass_kg=0,joint_pose=False'")
    ap.add_argument("--write", default=None, help="save the refined body as SESSION/mirror/NAME")
    args = ap.parse_args()
    fields = {}
    for item in filter(None, args.weights.split(",")):
        key, value = item.split("=")
        fields[key.strip()] = value.strip() == "True" if value.strip() in ("True", "False") else float(value)
    weights = sr.ShapeWeights(**fields)
    m = load_statistical_model("6k", progress=False)
    for path in args.sessions:
        session = open_session(path)
        true_rest = np.load(path / "gt" / "mirror" / "actors.npz")["source_rest_vertices"][0].astype(float)
        c_true = m.project(true_rest)
        src = load_source_body(path / "mirror" / args.source, m)
        background, views = None, []
        for i in session.frame_ids:
            if i > max(src.frames_used):
                break
            frame = read_mirror_frame(session, i)
            depth_c, players_c = register_depth_to_color(frame.depth_m, frame.player, session.kinect)
            if i in src.frames_used:
                body = frame.body(1)
                fg = refine_foreground(frame.rgb, players_c == 1, depth_c, background=background)
                points = point_cloud(frame, session.kinect, 1)
                views.append(sr.SilhouetteView(fg, (players_c > 0) & (players_c != 1), points[points[:, 1] > 0.02],
                                               body.positions, body.tracked, "v2" if len(body.names) == 25 else "v1"))
            elif not frame.bodies:
                background = update_background(background, frame.rgb, players_c > 0)
        views = [views[i] for i in np.unique(np.linspace(0, len(views) - 1, args.views).round().astype(int))]
        t0 = time.process_time()
        c = sr.refine_shape_to_silhouettes(m, src.coeffs, views, session.kinect.color, iterations=args.iterations,
                                           weights=weights)
        cpu = time.process_time() - t0

        def vertex_mm(coeffs, true_rest=true_rest):
            d = m.vertices(coeffs) - true_rest
            return 1e3 * np.linalg.norm(d - d.mean(0), axis=1).mean()

        sigma_err = [np.abs((x - c_true) / m.stddev).mean() for x in (src.coeffs, c)]
        t, a, b = m.measure(c_true), m.measure(src.coeffs), m.measure(c)
        print(f"{path.name}: {len(views)} frames, {cpu:.2f} s CPU; rest vertex err {vertex_mm(src.coeffs):.1f} -> "
              f"{vertex_mm(c):.1f} mm; stature err {1e3 * (a['stature_m'] - t['stature_m']):.1f} -> "
              f"{1e3 * (b['stature_m'] - t['stature_m']):.1f} mm; mass err {a['mass_kg'] - t['mass_kg']:.2f} -> "
              f"{b['mass_kg'] - t['mass_kg']:.2f} kg; coefficient err {sigma_err[0]:.2f} -> {sigma_err[1]:.2f} sigma",
              flush=True)
        if args.write:
            save_source_body(path / "mirror" / args.write,
                             SourceBody(c, m.vertices(c), m.skeleton(c), src.frames_used, src.residual_mm))


if __name__ == "__main__":
    main()
