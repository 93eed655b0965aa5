"""Accuracy of the mirror's source-body initialisation (§4) on held-out synthetic subjects.

Usage: PYTHONPATH=. python benchmarks/mirror_init_accuracy.py [--subjects 201 202 ...] [--frames 90]

Each subject (population seed not used by the tests or the model's training) walks in front of a
simulated Kinect v2 (depth noise model, SDK joint noise); the initialisation runs on the frames and
the fitted body's stature and mass are compared with the true body's. Prints a table and the timing.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "mirror"))

from scene import synthetic_scene  # noqa: E402

from bodystudio.body.statistical import load_statistical_model  # noqa: E402
from bodystudio.mirror.init import initialise_from_observations  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--subjects", type=int, nargs="+", default=[201, 202, 203, 204, 205])
    ap.add_argument("--frames", type=int, default=90)
    ap.add_argument("--motion", default="walk")
    ap.add_argument("--passes", type=int, default=3)
    args = ap.parse_args()
    model = load_statistical_model("6k", progress=False)
    rows = []
    print("subject  stature_m  err_mm  mass_kg  err_kg  residual_mm  init_s  frames_used")
    for seed in args.subjects:
        # the scene renders every 3rd frame of the sequence; the init uses at most 15 of them anyway
        sc = synthetic_scene(seed, n_frames=args.frames // 6, motion=args.motion, frame_stride=6, seed=seed)
        t0 = time.process_time()
        src = initialise_from_observations(sc.observations, model, view_point=sc.sensor.depth.center,
                                           passes=args.passes)
        dt = time.process_time() - t0
        m = model.measure(src.coeffs)
        es, em = 1000 * (m["stature_m"] - sc.truth["stature_m"]), m["mass_kg"] - sc.truth["mass_kg"]
        rows.append((es, em, dt))
        print(f"{seed:7d}  {sc.truth['stature_m']:9.3f}  {es:6.1f}  {sc.truth['mass_kg']:7.1f}  {em:6.2f}  "
              f"{src.residual_mm:11.1f}  {dt:6.2f}  {len(src.frames_used):3d}")
    r = np.array(rows)
    print(f"mean |err|: stature {np.abs(r[:, 0]).mean():.1f} mm (max {np.abs(r[:, 0]).max():.1f}), "
          f"mass {np.abs(r[:, 1]).mean():.2f} kg (max {np.abs(r[:, 1]).max():.2f}); "
          f"init CPU s mean {r[:, 2].mean():.2f}")


if __name__ == "__main__":
    main()
