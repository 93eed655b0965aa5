"""The tracked frame's deformation under several matching schedules, alternated in one process (issue 15, rec15e).

Usage: PYTHONPATH=. python benchmarks/reconstruct_schedule_ab.py [--cache DIR] [--rounds 8] [--threads 1|2]
       [--variants 'exact=;keep1=cheap_iterations:1,keep_outline:True,gate:reuse']

Walk s31 frame 1 (10 cameras 640x480, 13K template, 30 fps; the session of ``reconstruct_tracked_frame.py``),
posed by the tracking fit from frame 0's pose; then Algorithm 1 with No = 3 (a tracked frame's) from that
posed template, once per variant per round, the variants in turn (the same load on each). Each variant is a
set of :class:`MatchSchedule` fields. Prints each variant's constraint counts per outer iteration and its
largest vertex difference from the first variant (round 0), then the deformation's CPU ms (median and minimum
over the rounds after the first). The fields are the exact ones (``--chamfer``: the 5x5 chamfer ones).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

import bodystudio  # noqa: F401  (first: its OMP_WAIT_POLICY default must precede numba's threads)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", type=Path, default=None, help="session folder to reuse (made when missing)")
    ap.add_argument("--rounds", type=int, default=8)
    ap.add_argument("--threads", type=int, default=1, choices=(1, 2))
    ap.add_argument("--chamfer", action="store_true")
    ap.add_argument("--variants", default="exact=;keep1=cheap_iterations:1,keep_outline:True,gate:reuse")
    args = ap.parse_args()
    import numba
    from threadpoolctl import threadpool_limits

    from benchmarks.reconstruct_worst_ab import parse_variants
    from bodystudio.body import build_body
    from bodystudio.capture.session import open_session
    from bodystudio.capture.synth import synth_session
    from bodystudio.geometry.laplacian import cotangent_weights
    from bodystudio.reconstruct.pose_init import initialise_pose, pose_template
    from bodystudio.reconstruct.rapid_skin import RapidSkinParams, deform_to_observations
    from bodystudio.reconstruct.sequence import frame_joints
    from bodystudio.reconstruct.silhouette import MatchSchedule
    from bodystudio.reconstruct.tracking import SilhouetteFields, TrackParams, track_bone_transforms

    path = args.cache or Path(tempfile.mkdtemp()) / "walk31"
    if not (path / "session.json").exists():
        synth_session(path, n_cameras=10, n_frames=3, motion="walk", subject_seed=31, template="full", fps=30.0)
    numba.set_num_threads(min(args.threads, numba.config.NUMBA_NUM_THREADS))
    session = open_session(path)
    cams = list(session.cameras)
    body, fit_body = build_body(resolution="full"), build_body(resolution="2k")
    T0 = initialise_pose(fit_body, frame_joints(session, session.frame(session.frame_ids[0]), "tracker",
                                                None)).bone_transforms
    rest_delta = cotangent_weights(body.vertices, body.faces)
    frame = session.frame(session.frame_ids[1])
    masks = {n: frame.masks[n] for n in frame.masks}
    fields = SilhouetteFields(cams, masks, exact=not args.chamfer)
    P = pose_template(body, track_bone_transforms(fit_body, T0, fields, TrackParams()), 1.0).vertices
    variants = {name: MatchSchedule(**kw) for name, kw in parse_variants(args.variants)}
    times: dict[str, list[float]] = {name: [] for name in variants}
    first = None
    with threadpool_limits(1):
        for rnd in range(args.rounds + 1):
            for name, schedule in variants.items():
                params = RapidSkinParams(outer_iterations=3, matching=schedule)
                t = time.process_time()
                r = deform_to_observations(P, body.faces, cams, masks, params, delta=rest_delta, fields=fields)
                times[name].append(1000 * (time.process_time() - t))
                if rnd == 0:
                    first = r.vertices if first is None else first
                    print(f"{name:16s} matches {r.n_silhouette}, max |dV| from the first variant "
                          f"{1000 * np.abs(r.vertices - first).max():.1f} mm")
    print(f"deformation (No = 3), CPU ms, {numba.get_num_threads()} numba thread(s), {args.rounds} rounds")
    for name, v in times.items():
        v = np.array(v[1:])
        print(f"{name:16s} median {np.median(v):6.1f}  min {v.min():6.1f}")


if __name__ == "__main__":
    main()
