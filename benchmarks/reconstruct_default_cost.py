"""CPU cost of issue 15's candidate defaults against the current one, alternated in one process.

Usage: PYTHONPATH=. python benchmarks/reconstruct_default_cost.py SESSION [--frames 0:6] [--repeats 3]
       [--constraints sil|sil,depth]

SESSION: one of ``reconstruct_worst_ab.py``'s 30 fps sessions (13K, no scoring). Settings: ``default`` (per-frame
initialisation, the defaults), ``js2`` (per-frame, ``joint_smoothing=2``), ``js2rdn3`` (per-frame, js 2 and the
neck's depth term in the pose refinement, ``refine_depth=3``), ``tracked`` (``tracking=True`` with js 2 and the
early-fitted shape prior, rec15d's best tracked setting) and ``cand`` (``tracked`` with the whole body's depth term
in the refinement, its silhouette guard 0.05 and the torso's surface hold, k 1; rec15g), ``cand_sg`` (with the
joint smoothing's guard 0.05 as well). Prints
``time.process_time`` of each whole run (one thread) and the median per setting, per frame.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

TRACKED = {"tracking": True, "joint_smoothing": 2, "shape_prior": "frame", "shape_prior_outer": 3,
           "shape_prior_first_outer": 2}
SETTINGS = {"default": {}, "js2": {"joint_smoothing": 2}, "js2rdn3": {"joint_smoothing": 2, "refine_depth": 3.0},
            "tracked": TRACKED,
            "cand": {**TRACKED, "refine_depth": 3.0, "refine_depth_bones": "all", "refine_depth_guard": 0.05,
                     "params": {"surface_hold_k": 1.0, "surface_hold_region": "torso"}}}
SETTINGS["cand_sg"] = {**SETTINGS["cand"], "smoothing_guard": 0.05}


def main() -> None:
    import numba
    from threadpoolctl import threadpool_limits

    from bodystudio.reconstruct.rapid_skin import RapidSkinParams
    from bodystudio.reconstruct.sequence import parse_frames, reconstruct_session

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("session")
    ap.add_argument("--frames", default="0:6")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--constraints", default="sil,depth")
    args = ap.parse_args()
    numba.set_num_threads(1)
    cons = {"sil": ("silhouette",), "sil,depth": ("silhouette", "depth")}[args.constraints]

    def run(params=None, **kw):
        reconstruct_session(args.session, template="13k", constraints=cons,
                            params=RapidSkinParams(constraints=cons, **(params or {})), frames=args.frames, score=False,
                            accept_implausible=True, **kw)

    from bodystudio.capture.session import open_session

    n = len(parse_frames(args.frames, open_session(args.session).frame_ids))
    cpu = {k: [] for k in SETTINGS}
    with threadpool_limits(1):
        run(**SETTINGS["tracked"])  # warm-up: the shape space's cache, numba
        for rep in range(args.repeats):
            for name, kw in SETTINGS.items():
                t = time.process_time()
                run(**kw)
                cpu[name].append(time.process_time() - t)
                print(f"{name:8s} {rep} {cpu[name][-1]:.2f} s", flush=True)
    for name in SETTINGS:
        med = float(np.median(cpu[name]))
        print(f"{name:8s} median {med:.2f} s CPU for {n} frames, {1000 * med / n:.0f} ms per frame", flush=True)


if __name__ == "__main__":
    main()
