"""CPU cost of MIR12h's pose refinement (the spine's twist, the root turned about the centroid), A/B in one process.

Usage: PYTHONPATH=. python benchmarks/mirror_pivot_twist_ab.py [--rounds 15] [--frames 40 60 80]
       [--against OLD_REFINE.py [--old-config]] SESSION

On frames of a synthetic mirror session (player 1, ``SESSION/mirror/source_body.npz``, the IK pose, the graph cut's
foreground, the depth points as the run takes them: ``mirror_trunk_prior_ab.frame_inputs``), each frame's
refinement is timed as before MIR12h (no twist entries, ``ROOT_PIVOT = "head"``) and as the run now refines
(``twist_bones=TWIST_BONES``, the centroid), alternately, one BLAS thread (as the run): the median process CPU ms of
each and the difference, per frame and pooled. ``--against FILE``: the "before" side is another ``refine.py``
(e.g. ``git show main:bodystudio/mirror/refine.py > /tmp/refine_main.py``) imported beside this one, with its
default plan; ``--old-config`` then runs this code as before MIR12h too (what the one-pass projection saves).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def main() -> None:
    from benchmarks.mirror_trunk_prior_ab import alternate_cpu_ms, frame_inputs
    from bodystudio.capture.session import open_session
    from bodystudio.mirror import refine

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("session", type=Path)
    parser.add_argument("--frames", type=int, nargs="+", default=[40, 60, 80])
    parser.add_argument("--rounds", type=int, default=15)
    parser.add_argument("--against", type=Path, default=None, help="another refine.py for the 'before' side")
    parser.add_argument("--old-config", action="store_true", help="with --against: this code without twist, head pivot")
    args = parser.parse_args()
    session = open_session(args.session)
    body, inputs = frame_inputs(session, set(args.frames))
    version = session.kinect.version
    plans = {twist: refine.refine_plan(body.vertices, body.faces, body.weights, body.skeleton, version,
                                       twist_bones=twist) for twist in ((), refine.TWIST_BONES)}
    camera = session.kinect.color

    def call(i, twist, pivot):
        ik, fg, joints, tracked, points, others = inputs[i]

        def refined():
            original = refine.ROOT_PIVOT
            refine.ROOT_PIVOT = pivot
            try:
                return refine.refine_pose(plans[twist], body.skeleton, ik, camera, fg, joints, tracked, points,
                                          others, version)
            finally:
                refine.ROOT_PIVOT = original
        return refined

    steps = {f"frame {i}": (call(i, (), "head"), call(i, refine.TWIST_BONES, "centroid")) for i in sorted(inputs)}
    if args.against is not None:
        import importlib.util
        import sys

        # named after the file: its dataclasses, and numba's cache of its kernels, look the module up by name
        spec = importlib.util.spec_from_file_location(args.against.stem, args.against)
        before = importlib.util.module_from_spec(spec)
        sys.modules[args.against.stem] = before
        spec.loader.exec_module(before)
        plan = before.refine_plan(body.vertices, body.faces, body.weights, body.skeleton, version)

        def call_before(i):
            ik, fg, joints, tracked, points, others = inputs[i]
            return lambda: before.refine_pose(plan, body.skeleton, ik, camera, fg, joints, tracked, points, others,
                                              version)
        mine = (lambda i: call(i, (), "head")) if args.old_config else (lambda i: call(i, refine.TWIST_BONES,
                                                                                      "centroid"))
        steps = {f"frame {i}": (call_before(i), mine(i)) for i in sorted(inputs)}
    timed = alternate_cpu_ms(steps, args.rounds)
    for name, (a, b) in timed.items():
        print(json.dumps({"frame": name, "before_ms": round(a, 3), "mir12h_ms": round(b, 3),
                          "added_ms": round(b - a, 3)}))
    a, b = (float(np.mean([t[k] for t in timed.values()])) for k in (0, 1))
    print(json.dumps({"mean": True, "before_ms": round(a, 3), "mir12h_ms": round(b, 3), "added_ms": round(b - a, 3)}))


if __name__ == "__main__":
    main()
