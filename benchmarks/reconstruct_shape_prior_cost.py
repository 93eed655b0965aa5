"""CPU cost of issue 15's body-shape prior on tracked frames, alternated with the default in one process.

Usage: PYTHONPATH=. python benchmarks/reconstruct_shape_prior_cost.py SESSION [--frames 0:4] [--repeats 3]

SESSION: one of ``reconstruct_worst_ab.py``'s 30 fps sessions (silhouettes + depth, 13K, tracking, no scoring).
Prints ``time.process_time`` of each whole run (one thread) and the median per setting.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

SETTINGS = {"default": {}, "sp3": {"shape_prior": "frame", "shape_prior_outer": 3},
            "f2sp3": {"shape_prior": "frame", "shape_prior_outer": 3, "shape_prior_first_outer": 2}}


def main() -> None:
    import numba
    from threadpoolctl import threadpool_limits

    from bodystudio.reconstruct.rapid_skin import RapidSkinParams
    from bodystudio.reconstruct.sequence import reconstruct_session

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("session")
    ap.add_argument("--frames", default="0:4")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    numba.set_num_threads(1)
    cons = ("silhouette", "depth")

    def run(**kw):
        reconstruct_session(args.session, template="13k", constraints=cons, params=RapidSkinParams(constraints=cons),
                            frames=args.frames, tracking=True, score=False, accept_implausible=True, **kw)

    cpu = {k: [] for k in SETTINGS}
    with threadpool_limits(1):
        run(**SETTINGS["sp3"])  # warm-up: the shape space's cache, numba
        for rep in range(args.repeats):
            for name, kw in SETTINGS.items():
                t = time.process_time()
                run(**kw)
                cpu[name].append(time.process_time() - t)
                print(f"{name:8s} {rep} {cpu[name][-1]:.2f} s", flush=True)
    for name in SETTINGS:
        print(f"{name:8s} median {np.median(cpu[name]):.2f} s CPU for frames {args.frames}")


if __name__ == "__main__":
    main()
