"""CPU cost of the pose refinement's second Gauss-Newton step (MIR12k): the run's plan, one step and two, alternated.

Usage: PYTHONPATH=. python benchmarks/mirror_refine_steps_ab.py [--rounds 15] [--frames 40 60 80] SESSION

The inputs of ``benchmarks/mirror_trunk_prior_ab.py`` (player 1, the fitted source body, the IK pose, the graph
cut's foreground, the depth points as the run takes them); the plan as the run makes it (``twist_bones=
TWIST_BONES``); ``refine_pose`` with ``iterations=1`` and with ``run.refine_steps(1)`` (a one-player run), called
alternately, one BLAS thread: the median process CPU ms of each and the difference, per frame and pooled.
``--depth-ab`` (MIR12n): instead, the run's one-player steps with the refinement's default depth points (400) and
with the run's (``run.refine_weights(1)``, 2000).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def main() -> None:
    from benchmarks.mirror_trunk_prior_ab import alternate_cpu_ms, frame_inputs
    from bodystudio.capture.session import open_session
    from bodystudio.mirror.refine import TWIST_BONES, RefineWeights, refine_plan, refine_pose
    from bodystudio.mirror.run import refine_steps, refine_weights

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("session", type=Path)
    parser.add_argument("--frames", type=int, nargs="+", default=[40, 60, 80])
    parser.add_argument("--rounds", type=int, default=15)
    parser.add_argument("--depth-ab", action="store_true", help="400 against the run's depth points, the run's steps")
    args = parser.parse_args()
    session = open_session(args.session)
    body, inputs = frame_inputs(session, set(args.frames))
    plan = refine_plan(body.vertices, body.faces, body.weights, body.skeleton, session.kinect.version,
                       twist_bones=TWIST_BONES)
    camera, version = session.kinect.color, session.kinect.version
    steps_one = refine_steps(1)

    def call(i, iterations, weights=RefineWeights()):
        ik, fg, joints, tracked, points, others = inputs[i]
        return lambda: refine_pose(plan, body.skeleton, ik, camera, fg, joints, tracked, points, others, version,
                                   iterations=iterations, weights=weights)

    if args.depth_ab:
        timed = alternate_cpu_ms({f"frame {i}": (call(i, steps_one), call(i, steps_one, refine_weights(1)))
                                  for i in sorted(inputs)}, args.rounds)
        for name, (a, b) in timed.items():
            print(json.dumps({"frame": name, "400_points_ms": round(a, 3), "run_points_ms": round(b, 3),
                              "added_ms": round(b - a, 3)}))
        a, b = (float(np.mean([t[k] for t in timed.values()])) for k in (0, 1))
        print(json.dumps({"mean": True, "400_points_ms": round(a, 3), "run_points_ms": round(b, 3),
                          "added_ms": round(b - a, 3)}))
        return
    timed = alternate_cpu_ms({f"frame {i}": (call(i, 1), call(i, steps_one)) for i in sorted(inputs)}, args.rounds)
    for name, (a, b) in timed.items():
        print(json.dumps({"frame": name, "one_step_ms": round(a, 3), f"{steps_one}_steps_ms": round(b, 3),
                          "added_ms": round(b - a, 3)}))
    a, b = (float(np.mean([t[k] for t in timed.values()])) for k in (0, 1))
    print(json.dumps({"mean": True, "one_step_ms": round(a, 3), f"{steps_one}_steps_ms": round(b, 3),
                      "added_ms": round(b - a, 3)}))


if __name__ == "__main__":
    main()
