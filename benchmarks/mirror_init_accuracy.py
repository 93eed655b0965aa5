"""Accuracy of the mirror's source-body initialisation (§4) on held-out synthetic subjects.

Usage: PYTHONPATH=. python benchmarks/mirror_init_accuracy.py [--set sessions|walk] [--subjects 201 202 ...]
       [--cache DIR] [--silhouette-shape] [--session PATH ...] [--passes N] [--unpose-refine-steps N]

``sessions`` (default): each subject (population seeds 201.. are used neither by the tests nor by the
model's training) is synthesised as a mirror session (``synth_mirror_session(out, seed, n_frames=120,
motion="arms_raise")``: furnished room, actor walking in, the SDK-like player mask with jittery edges,
Kinect v2 noise model) and ``bodystudio mirror init``'s steps run on it (``collect_observations`` +
``initialise_from_observations``); the source body is scored as ``eval mirror`` scores it. ``--cache DIR``
keeps the sessions for the next run. ``walk``: the subject walks in front of a simulated Kinect v2 with no
room (``mirror.init_case.synthetic_scene``: every 6th frame of a 90-frame walk). Prints a table and timings.
``--silhouette-shape``: ``mirror init --silhouette-shape`` (the shape then refined against the silhouettes,
MIR12c; sessions only), with the rest vertex error against the true rest mesh (mean, translation removed).
``--session PATH ...``: score these existing synthetic mirror sessions instead of synthesising subjects.
``--passes 3 --unpose-refine-steps 0``: the initialisation before MIR12i (3 passes, each frame unposed by its IK pose).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from bodystudio.body.statistical import load_statistical_model
from bodystudio.mirror.init import (
    INIT_PASSES,
    UNPOSE_REFINE_STEPS,
    collect_observations,
    initialise_from_observations,
)


def session_row(seed: int, model, cache: Path, passes: int, silhouette_shape: bool = False, path: Path | None = None,
                refine_steps: int = UNPOSE_REFINE_STEPS):
    from bodystudio.capture.session import open_session
    from bodystudio.mirror.evaluate import init_scores
    from bodystudio.mirror.init import SILHOUETTE_FRAMES
    from bodystudio.mirror.synthetic import synth_mirror_session

    if path is None:
        path = cache / f"mirror-init-{seed}"
        if not path.exists():
            synth_mirror_session(path, seed, n_frames=120, motion="arms_raise")
    session = open_session(path)
    t0 = time.process_time()
    obs, sensor = collect_observations(session, silhouettes=silhouette_shape)
    t1 = time.process_time()
    src = initialise_from_observations(obs, model, view_point=sensor.depth.center, passes=passes,
                                       depth_camera=sensor.depth, unpose_refine_steps=refine_steps,
                                       camera=sensor.color if silhouette_shape else None,
                                       silhouette_frames=SILHOUETTE_FRAMES if silhouette_shape else 0)
    t2 = time.process_time()
    s = init_scores(session, src)
    true_rest = np.load(Path(path) / "gt" / "mirror" / "actors.npz")["source_rest_vertices"][0].astype(float)
    d = src.vertices - true_rest
    vertex_mm = 1e3 * np.linalg.norm(d - d.mean(0), axis=1).mean()
    return (s["true_stature_m"], 1e3 * (s["init_stature_m"] - s["true_stature_m"]), s["true_mass_kg"],
            s["init_mass_kg"] - s["true_mass_kg"], src.residual_mm, t1 - t0, t2 - t1, vertex_mm)


def walk_row(seed: int, model, frames: int, passes: int, motion: str = "walk", refine_steps: int = UNPOSE_REFINE_STEPS):
    from bodystudio.mirror.init_case import synthetic_scene

    sc = synthetic_scene(seed, n_frames=frames // 6, motion=motion, frame_stride=6, seed=seed)
    t0 = time.process_time()
    src = initialise_from_observations(sc.observations, model, view_point=sc.sensor.depth.center, passes=passes,
                                       depth_camera=sc.sensor.depth, unpose_refine_steps=refine_steps)
    dt = time.process_time() - t0
    m = model.measure(src.coeffs)
    return (sc.truth["stature_m"], 1e3 * (m["stature_m"] - sc.truth["stature_m"]), sc.truth["mass_kg"],
            m["mass_kg"] - sc.truth["mass_kg"], src.residual_mm, 0.0, dt, float("nan"))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--set", choices=("sessions", "walk"), default="sessions")
    ap.add_argument("--subjects", type=int, nargs="+", default=[201, 202, 203, 204, 205, 206])
    ap.add_argument("--frames", type=int, default=90, help="walk set: frames of the walk (every 6th is used)")
    ap.add_argument("--passes", type=int, default=INIT_PASSES)
    ap.add_argument("--unpose-refine-steps", type=int, default=UNPOSE_REFINE_STEPS,
                    help="refine_pose steps of each frame's pose before the inverse LBS (0: the IK's, before MIR12i)")
    ap.add_argument("--motion", default="walk", help="walk set: the motion (capture.motion)")
    ap.add_argument("--cache", type=Path, default=None, help="sessions: keep the synthetic sessions here")
    ap.add_argument("--silhouette-shape", action="store_true", help="sessions: mirror init --silhouette-shape")
    ap.add_argument("--session", type=Path, nargs="+", default=None, help="score these existing mirror sessions")
    args = ap.parse_args()
    model = load_statistical_model("6k", progress=False)
    tmp = None
    if args.set == "sessions" and args.cache is None and not args.session:
        tmp = tempfile.TemporaryDirectory(prefix="mirror-init-")
        args.cache = Path(tmp.name)
    rows = []
    print(f"set {args.set}")
    print("| subject | stature m | err mm | mass kg | err kg | residual mm | read CPU s | fit CPU s | vertex err mm |")
    print("|---|---|---|---|---|---|---|---|---|")
    for seed in args.session or args.subjects:
        if args.session:
            r = session_row(0, model, args.cache, args.passes, args.silhouette_shape, path=seed,
                            refine_steps=args.unpose_refine_steps)
        else:
            r = session_row(seed, model, args.cache, args.passes, args.silhouette_shape,
                            refine_steps=args.unpose_refine_steps) if args.set == "sessions" else \
                walk_row(seed, model, args.frames, args.passes, args.motion, args.unpose_refine_steps)
        rows.append(r)
        name = seed.name if args.session else seed
        print(f"| {name} | {r[0]:.3f} | {r[1]:.1f} | {r[2]:.1f} | {r[3]:.2f} | {r[4]:.1f} | {r[5]:.2f} | {r[6]:.2f} "
              f"| {r[7]:.1f} |", flush=True)
    r = np.array(rows)
    print(f"mean |err|: stature {np.abs(r[:, 1]).mean():.1f} mm (max {np.abs(r[:, 1]).max():.1f}), "
          f"mass {np.abs(r[:, 3]).mean():.2f} kg (max {np.abs(r[:, 3]).max():.2f}, mean signed {r[:, 3].mean():+.2f}); "
          f"CPU s mean read {r[:, 5].mean():.2f} fit {r[:, 6].mean():.2f}")
    if tmp is not None:
        tmp.cleanup()


if __name__ == "__main__":
    main()
