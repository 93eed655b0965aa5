"""Algorithm 1's gated deformation on one and two numba threads (issue 15: the cameras on the second core).

Usage: PYTHONPATH=. python benchmarks/reconstruct_threads.py [--cache DIR] [--repeats 6]

The frame of the benchmark's per-step CPU table (walk s31 frame 1 at 30 fps, 10 cameras 640x480, 13K
template, pose from the distance-field fit); BLAS on one thread. One and two numba threads alternate in one
process so machine load hits both alike; prints the median CPU and wall ms of each and the largest vertex
difference between them (0 expected: the matching's ``prange`` over cameras and the gate's over points
compute each value as the serial loop does). Wall time is the figure on an idle machine only.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np

import bodystudio  # noqa: F401  (first: its OMP_WAIT_POLICY default must precede numba's threads)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", type=Path, default=None, help="session folder to reuse (made when missing)")
    ap.add_argument("--repeats", type=int, default=6)
    args = ap.parse_args()
    import numba
    from threadpoolctl import threadpool_limits

    from benchmarks.reconstruct_gate_ab import step_table_frame
    from bodystudio.reconstruct.rapid_skin import RapidSkinParams, deform_to_observations

    P, body, cams, masks, fields, rest = step_table_frame(args.cache)
    threads = (1, min(2, numba.config.NUMBA_NUM_THREADS))
    ms: dict[int, list] = {n: [] for n in threads}
    out = {}
    with threadpool_limits(1):
        for rep in range(args.repeats + 1):  # the first run compiles
            for n in threads:
                numba.set_num_threads(n)
                t, w = time.process_time(), time.perf_counter()
                r = deform_to_observations(P, body.faces, cams, masks, RapidSkinParams(), delta=rest, fields=fields)
                if rep:
                    ms[n].append((1000 * (time.process_time() - t), 1000 * (time.perf_counter() - w)))
                out[n] = r.vertices
    for n, v in ms.items():
        print(f"{n} numba thread(s): deformation {statistics.median(x[0] for x in v):.1f} ms CPU, "
              f"{statistics.median(x[1] for x in v):.1f} ms wall")
    print("max |dV| one vs two threads:", float(np.abs(out[threads[0]] - out[threads[-1]]).max()))


if __name__ == "__main__":
    main()
