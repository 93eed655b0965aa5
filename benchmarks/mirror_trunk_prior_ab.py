"""CPU cost of the pose refinement's E_trunk (MIR12g): ``refine_pose`` with and without it, alternated in one process.

Usage: PYTHONPATH=. python benchmarks/mirror_trunk_prior_ab.py [--rounds 15] [--frames 40 60 80] SESSION

On frames of a synthetic mirror session (player 1, the fitted source body of ``SESSION/mirror/source_body.npz``,
the IK pose, the graph cut's foreground with the background learnt from the frames before the player, the depth
points as the run takes them), each frame's refinement is timed with ``RefineWeights(trunk_rad=None)`` and with the
default (E_trunk on), alternately, one BLAS thread (as the run): the median process CPU ms of each and the
difference, per frame and pooled.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np


def alternate_cpu_ms(steps: dict, rounds: int) -> dict:
    """``{name: (ms without, ms with)}``: each pair warmed up once, then called alternately ``rounds`` times; the
    median process CPU ms of each. (``benchmarks.mirror_image_steps_ab.alternate_cpu_ms`` is the same loop, but
    importing that module points numba's cache at a fresh folder, which would recompile every kernel here.)"""
    def cpu_ms(fn) -> float:
        c = time.process_time()
        fn()
        return (time.process_time() - c) * 1e3

    out = {}
    for name, (a, b) in steps.items():
        a()
        b()
        ta, tb = [], []
        for _ in range(rounds):
            ta.append(cpu_ms(a))
            tb.append(cpu_ms(b))
        out[name] = (float(np.median(ta)), float(np.median(tb)))
    return out


def frame_inputs(session, frames, player: int = 1):
    """Per wanted frame the arguments of ``refine_pose`` after the plan: as ``mirror run`` builds them."""
    from bodystudio.mirror.compose import update_background
    from bodystudio.mirror.foreground import refine_foreground
    from bodystudio.mirror.frames import point_cloud, read_mirror_frame, register_depth_to_color
    from bodystudio.mirror.run import load_source
    from bodystudio.mirror.track import ik_pose

    body, _ = load_source(session)
    background, previous, out = None, None, {}
    for i in session.frame_ids:
        if i > max(frames):
            break
        frame = read_mirror_frame(session, i)
        depth_c, players_c = register_depth_to_color(frame.depth_m, frame.player, session.kinect)
        person = players_c == player
        tracked = frame.body(player)
        if tracked is None:
            background = update_background(background, frame.rgb, players_c > 0)
            continue
        previous = ik_pose(body.skeleton, tracked.positions, tracked.tracked, session.kinect.version,
                           previous=previous)
        fg = refine_foreground(frame.rgb, person, depth_c, background=background)
        background = update_background(background, frame.rgb, fg | (players_c > 0))
        if i in frames:
            points = point_cloud(frame, session.kinect, player)
            out[i] = (previous, fg, tracked.positions, tracked.tracked, points[points[:, 1] > 0.02],
                      (players_c > 0) & ~person)
    return body, out


def main() -> None:
    from bodystudio.capture.session import open_session
    from bodystudio.mirror.refine import RefineWeights, refine_plan, refine_pose

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("session", type=Path)
    parser.add_argument("--frames", type=int, nargs="+", default=[40, 60, 80])
    parser.add_argument("--rounds", type=int, default=15)
    args = parser.parse_args()
    session = open_session(args.session)
    body, inputs = frame_inputs(session, set(args.frames))
    plan = refine_plan(body.vertices, body.faces, body.weights, body.skeleton, session.kinect.version)
    camera, version = session.kinect.color, session.kinect.version
    off = RefineWeights(trunk_rad=None)

    def call(i, weights):
        ik, fg, joints, tracked, points, others = inputs[i]
        return lambda: refine_pose(plan, body.skeleton, ik, camera, fg, joints, tracked, points, others, version,
                                   weights=weights)

    steps = {f"frame {i}": (call(i, off), call(i, RefineWeights())) for i in sorted(inputs)}
    timed = alternate_cpu_ms(steps, args.rounds)
    for name, (a, b) in timed.items():
        print(json.dumps({"frame": name, "without_ms": round(a, 3), "with_ms": round(b, 3),
                          "added_ms": round(b - a, 3)}))
    a, b = (float(np.mean([t[k] for t in timed.values()])) for k in (0, 1))
    print(json.dumps({"mean": True, "without_ms": round(a, 3), "with_ms": round(b, 3), "added_ms": round(b - a, 3)}))


if __name__ == "__main__":
    main()
