"""The tracked frame's step table (issue 15's frame time): CPU of the whole process, CPU of the main thread and
wall, per step, on one or two numba threads.

Usage: PYTHONPATH=. python benchmarks/reconstruct_tracked_frame.py [--cache DIR] [--repeats 9] [--threads 1|2]
       [--compare] [--constraints sil|sil,depth] [--compare-depth] [--compare-tau]

A tracked frame as ``reconstruct_frames`` runs it (``--tracking``, ``TrackParams()``): walk s31 frame 1 at 30 fps
(10 cameras 640x480, 13K template) from frame 0's pose as the prior: read the masks, distance fields, the
lost-track prior check, the tracking fit to the energy's plateau, the energy check, the 13K posing and the
deformation (No = 3, gate); BLAS on one thread. Prints the median and the minimum over ``--repeats`` frames of
each step. With two numba threads the main thread's CPU is its share of every ``prange`` plus everything
serial: the frame's wall on an idle two-core machine when the split is even (a waiting thread burns nothing
under ``OMP_WAIT_POLICY=PASSIVE``). On a loaded machine compare trees by running this script alternately
with ``PYTHONPATH`` on each (docs/reconstruct.md, rec15c); ``--compare`` alternates the default tracked frame
frame by frame with the exact one (exact distance fields, every outline drawn: the tracker before rec15e's
trade-offs) in one process. ``--constraints sil,depth`` adds the Kinect depth (issue 15's accuracy goals are for
silhouettes + depth): its PNG in the read step, the depth observation (cleaning, unprojection, normals) as a
step, and the depth constraints in every outer iteration of the deformation; ``--compare-depth`` alternates it
with the numpy depth path before rec15f (:func:`depth_observation_reference`, :func:`depth_constraints_reference`);
``--compare-tau`` with the run's 30 px contour search (``TrackParams(tau_px=0)``, before rec15l's 15 px);
``--compare-track 'outer_iterations:3,inner_iterations:0'`` with those :class:`TrackParams` fields (numbers) over the
default (here: the tracked frame's 3 x 8 sweeps before rec15n's 2 x 40).
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
    ap.add_argument("--repeats", type=int, default=9)
    ap.add_argument("--threads", type=int, default=1, choices=(1, 2))
    ap.add_argument("--compare", action="store_true",
                    help="alternate frame by frame with the exact tracked frame (exact fields, every matching drawn)")
    ap.add_argument("--constraints", default="sil", choices=("sil", "sil,depth"))
    ap.add_argument("--compare-depth", action="store_true",
                    help="with --constraints sil,depth: alternate with the numpy depth path (before rec15f)")
    ap.add_argument("--compare-tau", action="store_true",
                    help="alternate with the run's 30 px contour search on the tracked frame (before rec15l)")
    ap.add_argument("--compare-track", default=None, metavar="K:V,...",
                    help="alternate with these TrackParams fields over the default, e.g. 'outer_iterations:3,"
                         "inner_iterations:0' (the tracked frame before rec15n)")
    args = ap.parse_args()
    use_depth = args.constraints == "sil,depth"
    import numba
    from threadpoolctl import threadpool_limits

    from bodystudio.body import build_body
    from bodystudio.capture.session import open_session
    from bodystudio.capture.synth import synth_session
    from bodystudio.geometry.laplacian import cotangent_weights
    from bodystudio.reconstruct import rapid_skin
    from bodystudio.reconstruct.depth import depth_constraints, depth_observation

    try:
        from bodystudio.reconstruct.depth import depth_constraints_reference, depth_observation_reference
    except ImportError:  # a tree before rec15f (PYTHONPATH on it, for the A/B of whole trees): its path is numpy's
        depth_constraints_reference, depth_observation_reference = depth_constraints, depth_observation
    from bodystudio.reconstruct.pose_init import initialise_pose, pose_template
    from bodystudio.reconstruct.rapid_skin import RapidSkinParams, deform_to_observations
    from bodystudio.reconstruct.sequence import frame_joints
    from bodystudio.reconstruct.silhouette import MatchSchedule
    from bodystudio.reconstruct.tracking import SilhouetteFields, TrackParams, outside_fraction, track_bone_transforms

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
    sensor = session.kinect.depth if use_depth else None
    configs = {"default": (TrackParams(), False)}
    if args.compare:
        configs = {"exact (before rec15e)": (TrackParams(matching=MatchSchedule(), exact_fields=True), False),
                   **configs}
    if args.compare_depth and use_depth:
        configs = {"numpy depth (before rec15f)": (TrackParams(), True), **configs}
    if args.compare_tau:
        configs = {"tau 30 px (before rec15l)": (TrackParams(tau_px=0), False), **configs}
    if args.compare_track:
        kv = {k: float(v) if "." in v else int(v)
              for k, _, v in (item.partition(":") for item in args.compare_track.split(","))}
        configs = {f"TrackParams({args.compare_track})": (TrackParams(**kv), False), **configs}

    def clocks():
        return np.array([time.process_time(), time.thread_time(), time.perf_counter()])

    def timed(steps, name, f, *a):
        t = clocks()
        out = f(*a)
        steps[name] = 1000 * (clocks() - t)
        return out

    def frame(track, reference_depth):
        run = RapidSkinParams()
        params = RapidSkinParams(outer_iterations=track.outer_iterations or run.outer_iterations,
                                 # the tracked frame's sweeps as reconstruct_frames sets them (rec15n)
                                 inner_iterations=getattr(track, "inner_iterations", 0) or run.inner_iterations,
                                 matching=track.matching,
                                 constraints=("silhouette", "depth") if use_depth else ("silhouette",),
                                 # the tracked frame's search range as reconstruct_frames sets it (rec15l)
                                 tau_px=min(run.tau_px, getattr(track, "tau_px", 0) or run.tau_px))
        rapid_skin.depth_constraints = depth_constraints_reference if reference_depth else depth_constraints
        observe = depth_observation_reference if reference_depth else depth_observation
        steps: dict[str, np.ndarray] = {}
        fr = open_session(path).frame(session.frame_ids[1])
        masks = timed(steps, "read masks (10 PNG)", lambda: {n: fr.masks[n] for n in fr.masks})
        depth = None
        if use_depth:
            D = timed(steps, "read depth (PNG)", lambda: fr.kinect_depth_m)
            depth = timed(steps, "depth observation", observe, D, sensor)
        fields = timed(steps, "distance fields", SilhouetteFields, cams, masks, 48, track.exact_fields)
        timed(steps, "lost-track prior check", lambda: outside_fraction(pose_template(fit_body, T0).vertices, fields))
        T = timed(steps, "tracking fit (to the plateau)", track_bone_transforms, fit_body, T0, fields, track)
        timed(steps, "energy check", lambda: outside_fraction(pose_template(fit_body, T).vertices, fields))
        P = timed(steps, "pose 13K (LBS)", pose_template, body, T, 1.0)
        what = "matching, gate, depth, GS" if use_depth else "matching, gate, GS"
        timed(steps, f"deformation (No = {params.outer_iterations}: {what})",
              deform_to_observations, P.vertices, body.faces, cams, masks, params, depth, rest_delta, None, None, None,
              fields)
        steps["whole tracked frame"] = sum(steps.values())
        return steps

    runs: dict[str, dict[str, list]] = {c: {} for c in configs}
    with threadpool_limits(1):
        for track, reference_depth in configs.values():
            frame(track, reference_depth)  # compiles
        for _ in range(args.repeats):
            for cname, (track, reference_depth) in configs.items():  # alternated frame by frame: the same load
                for name, v in frame(track, reference_depth).items():
                    runs[cname].setdefault(name, []).append(v)
    rapid_skin.depth_constraints = depth_constraints
    for cname, steps in runs.items():
        print(f"{cname}: {numba.get_num_threads()} numba thread(s), {args.repeats} frames; ms: median (min)")
        print(f"{'step':48s} {'CPU':>15s} {'main thread CPU':>17s} {'wall':>15s}")
        for name, v in steps.items():
            med, lo = np.median(np.array(v), axis=0), np.min(np.array(v), axis=0)
            print(f"{name:48s} " + " ".join(f"{m:7.1f} ({n:5.1f})" for m, n in zip(med, lo, strict=True)))


if __name__ == "__main__":
    main()
