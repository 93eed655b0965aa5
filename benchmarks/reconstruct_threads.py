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
import tempfile
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

    from bodystudio.body import build_body
    from bodystudio.capture.session import open_session
    from bodystudio.capture.synth import synth_session
    from bodystudio.geometry.laplacian import cotangent_weights
    from bodystudio.reconstruct.articulated_fit import refine_bone_transforms
    from bodystudio.reconstruct.pose_init import initialise_pose, pose_template
    from bodystudio.reconstruct.rapid_skin import RapidSkinParams, deform_to_observations
    from bodystudio.reconstruct.sequence import frame_joints
    from bodystudio.reconstruct.tracking import SilhouetteFields, TrackParams, silhouette_data_term

    path = args.cache or Path(tempfile.mkdtemp()) / "walk31"
    if not (path / "session.json").exists():
        synth_session(path, n_cameras=10, n_frames=3, motion="walk", subject_seed=31, template="full", fps=30.0)
    session = open_session(path)
    cams = list(session.cameras)
    body, fit_body = build_body(resolution="full"), build_body(resolution="2k")
    frame = session.frame(session.frame_ids[1])
    masks = {n: np.asarray(frame.masks[n]) for n in frame.masks}
    J = frame_joints(session, frame, "tracker", None)
    fields = SilhouetteFields(cams, masks)
    T = refine_bone_transforms(fit_body, initialise_pose(fit_body, J).bone_transforms, None,
                               data_term=silhouette_data_term(fields, TrackParams()))
    P = pose_template(body, T, initialise_pose(body, J).global_scale).vertices
    rest = cotangent_weights(body.vertices, body.faces)
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
