"""Does ``mirror init`` settle? The Eq. 4 displacement error, stature and mass after every pass (mir12x).

Usage: PYTHONPATH=. python benchmarks/mirror_init_settle.py SESSION [SESSION ...] [--passes 8]
[--variants main weighted fixed relaxed] [--write NAME.npz] [--seeds 0 1 2 ...]

Per synthetic mirror session (with ``gt/mirror/actors.npz``), player 1's init from the session's own observations
(``mirror init``'s frames) run for ``--passes`` passes per variant; the coefficients after pass k are what
``passes=k`` returns (nothing in a pass depends on the pass count). Variants: ``main`` (main's init before mir12y: a
fresh random subset of MAX_POOLED_POINTS depth points per pass), ``weighted`` (``weighted_pool``: every point, each
weighted MAX_POOLED_POINTS / N), ``fixed`` (``fixed_pool``: the same subset every pass), ``relaxed``
(``pass_relaxation=0.5`` with the fixed pool), ``posture`` / ``weighted-posture`` (mir12v's ``--unpose-posture`` bones,
alone / with the weighted pool; the latter ``mirror init``'s default since mir12y), ``splay`` (mir12ab's
``leg_splay`` on main's old init). Printed per session and variant:
the error of the Eq. 4 displacement ``B(c_T) - B(c_S)`` against the truth's (mean over vertices, mm) after each pass,
the stature (mm) and mass (kg) errors after each pass, and the CPU seconds of the whole init. ``--write NAME.npz``: the
first variant's body of ``--passes`` passes saved as ``SESSION/mirror/NAME.npz`` (for
``benchmarks/mirror_refine_end_to_end.py --source``; run it on a session copy).
``--seeds`` (mir12y): each variant that draws random subsets is run once per ``pool_seed`` (0: ``mirror init``'s
draw), and a ``summary`` line per session and variant gives the mean, standard deviation, min and max over the seeds
of the last pass's displacement error, stature and mass errors (a variant that draws nothing runs once).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

# every variant spelled out in full: the default changed to "weighted-posture" (mir12y), "main" stays main's old init
_PLAIN = {"weighted_pool": False, "unpose_posture_bones": ()}
VARIANTS = {"main": _PLAIN, "weighted": {**_PLAIN, "weighted_pool": True}, "fixed": {**_PLAIN, "fixed_pool": True},
            "relaxed": {**_PLAIN, "fixed_pool": True, "pass_relaxation": 0.5},
            "weighted-posture": {"weighted_pool": True, "unpose_posture_bones": ("spine_02", "neck_01", "head")},
            "posture": {**_PLAIN, "unpose_posture_bones": ("spine_02", "neck_01", "head")},
            "splay": {**_PLAIN, "leg_splay": True}}


def main() -> None:
    from benchmarks.mirror_init_posture import init_scores
    from bodystudio.body.statistical import load_statistical_model
    from bodystudio.capture.session import open_session
    from bodystudio.mirror import init as init_mod

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sessions", nargs="+", type=Path)
    parser.add_argument("--passes", type=int, default=8)
    parser.add_argument("--variants", nargs="+", default=["main", "weighted"], choices=sorted(VARIANTS))
    parser.add_argument("--write", default=None, help="save the first variant's body as SESSION/mirror/NAME.npz")
    parser.add_argument("--seeds", nargs="+", type=int, default=[0], help="pool_seed values of the drawing variants")
    args = parser.parse_args()
    model = load_statistical_model("6k", progress=False)
    refit = init_mod.refit_skeleton
    for path in args.sessions:
        session = open_session(path)
        actors = np.load(Path(path) / "gt" / "mirror" / "actors.npz")
        edits = session.metadata["edits"]
        obs, sensor = init_mod.collect_observations(session, None, 1, init_mod.DEFAULT_INIT_FRAMES)
        knee_frames = init_mod.knee_joint_frames(session, obs)  # as `mirror init` (mir12ac)
        for variant in args.variants:
            draws = args.seeds if not VARIANTS[variant].get("weighted_pool") else args.seeds[:1]
            last = []
            for seed in draws:
                per_pass = []

                def recorded(m, coeffs, per_pass=per_pass):
                    per_pass.append(np.array(coeffs))
                    return refit(m, coeffs)

                init_mod.refit_skeleton = recorded
                try:
                    start = time.process_time()
                    body = init_mod.initialise_from_observations(obs, model, view_point=sensor.depth.center,
                                                                 depth_camera=sensor.depth, passes=args.passes,
                                                                 pool_seed=seed, knee_frames=knee_frames,
                                                                 **VARIANTS[variant])
                    cpu_s = time.process_time() - start
                finally:
                    init_mod.refit_skeleton = refit
                scores = [init_scores(model, type("Fit", (), {"coeffs": c}), actors, edits) for c in per_pass]
                if args.write and variant == args.variants[0] and seed == draws[0]:
                    init_mod.save_source_body(Path(path) / "mirror" / args.write, body, player=1)
                last.append([scores[-1][k] for k in ("displacement_err_mm", "stature_m_err", "mass_kg_err")])
                print(json.dumps({"session": Path(path).name, "variant": variant, "seed": seed,
                                  "cpu_s": round(cpu_s, 1),
                                  "displacement_err_mm": [s["displacement_err_mm"] for s in scores],
                                  "stature_err_mm": [s["stature_m_err"] for s in scores],
                                  "mass_err_kg": [s["mass_kg_err"] for s in scores]}), flush=True)
            if len(args.seeds) > 1:
                v = np.array(last)
                print(json.dumps({"summary": Path(path).name, "variant": variant, "draws": len(v), **{
                    name: {"mean": round(float(v[:, i].mean()), 2), "sd": round(float(v[:, i].std()), 2),
                           "min": round(float(v[:, i].min()), 2), "max": round(float(v[:, i].max()), 2)}
                    for i, name in enumerate(("displacement_err_mm", "stature_err_mm", "mass_err_kg"))}}),
                      flush=True)


if __name__ == "__main__":
    main()
