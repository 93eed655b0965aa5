"""The init's stature and the SDK's joint distances between the floor and the head (mir12ad): main's init against the
fit that also matches the SDK's distances of ``init.STATURE_BONE_PAIRS`` (thighs, shins, spine, neck, head).

Usage: PYTHONPATH=. python benchmarks/mirror_init_stature.py [--weight 3.0] [--write NAME.npz] SESSION [SESSION ...]

Per synthetic mirror session (with ``gt/mirror/actors.npz``), player 1's init from the session's own observations
(``mirror init``'s frames), once as ``mirror init`` does it (``main``) and once with ``bone_length_weight=--weight``
on the stature pairs (``stature_pairs``). Printed per body (one JSON line per session): the Eq. 4 displacement error,
the rest vertex error, the stature / mass / chest / hip errors of the fitted against the true coefficients
(:func:`benchmarks.mirror_init_posture.init_scores`), the init's CPU seconds, and the error (mm) of the fitted body's
Kinect joint distances of each stature pair against the true body's, with their sum along the body (spine, neck, head
and the mean of the left and right legs: what the stature follows); ``sdk``: the same for the SDK's own means over the
init frames (``init.kinect_bone_lengths``). ``--write NAME.npz``: the option's body saved as ``SESSION/mirror/NAME.npz``
(for ``benchmarks/mirror_refine_end_to_end.py --source``; run it on a session copy).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np


def pair_errors_mm(lengths, true_lengths, keep) -> dict:
    """Each kept pair's length error (mm) and their sum along the body: spine, neck, head and the legs' mean."""
    from bodystudio.mirror.init import BONE_PAIRS

    err = 1e3 * (np.asarray(lengths, float) - np.asarray(true_lengths, float))
    out = {f"{a}-{b}": round(float(err[i]), 1) for i, (a, b) in enumerate(BONE_PAIRS) if keep[i]}
    names = ["-".join(p) for p in BONE_PAIRS]
    legs = [names.index(n) for n in ("HipLeft-KneeLeft", "KneeLeft-AnkleLeft", "HipRight-KneeRight",
                                     "KneeRight-AnkleRight")]
    trunk = [names.index(n) for n in ("SpineBase-SpineShoulder", "SpineShoulder-Neck", "Neck-Head")]
    out["chain"] = round(float(err[trunk].sum() + 0.5 * err[legs].sum()), 1)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sessions", nargs="+", type=Path)
    parser.add_argument("--weight", type=float, default=None,
                        help="the joint-distance weight per frame (default init.STATURE_BONE_LENGTH_WEIGHT)")
    parser.add_argument("--write", default=None, help="save the option's body as SESSION/mirror/NAME.npz")
    args = parser.parse_args()
    from bodystudio.mirror import init as init_mod

    weight = init_mod.STATURE_BONE_LENGTH_WEIGHT if args.weight is None else args.weight
    if not (np.isfinite(weight) and weight > 0):
        parser.error(f"--weight {args.weight}: give a number > 0")
    for path in args.sessions:
        if not (path / "gt" / "mirror" / "actors.npz").is_file():
            parser.error(f"{path}: not a synthetic mirror session (no gt/mirror/actors.npz); make one with "
                         "`bodystudio synth mirror`")
    from benchmarks.mirror_init_posture import init_scores
    from bodystudio.body.statistical import load_statistical_model
    from bodystudio.capture.session import open_session

    model = load_statistical_model("6k", progress=False)
    keep = init_mod.selected_bone_pairs(init_mod.STATURE_BONE_PAIRS)
    for path in args.sessions:
        session = open_session(path)
        actors = np.load(Path(path) / "gt" / "mirror" / "actors.npz")
        obs, sensor = init_mod.collect_observations(session, None, 1, init_mod.DEFAULT_INIT_FRAMES)
        version = obs[0].version
        Jm, Jb = init_mod._model_kinect_joints(model, version)
        pairs = init_mod.bone_pair_indices(version)

        def lengths(c, Jm=Jm, Jb=Jb, pairs=pairs):
            J = Jm + np.tensordot(np.asarray(c, float), Jb, axes=1)
            return np.array([np.linalg.norm(J[a] - J[b]) if a >= 0 and b >= 0 else np.nan for a, b in pairs])

        true_lengths = lengths(actors["source_coeffs"][0])
        kw = dict(view_point=sensor.depth.center, depth_camera=sensor.depth)
        row = {"session": Path(path).name, "weight": weight,
               "sdk": pair_errors_mm(init_mod.kinect_bone_lengths(obs, version)[0], true_lengths, keep)}
        for name, options in (("main", {}), ("stature_pairs", {"bone_length_weight": weight,
                                                               "bone_length_pairs": init_mod.STATURE_BONE_PAIRS})):
            t = time.process_time()
            body = init_mod.initialise_from_observations(obs, model, **kw, **options)
            row[name] = {**init_scores(model, body, actors, session.metadata["edits"]),
                         "cpu_s": round(time.process_time() - t, 2),
                         "pairs_mm": pair_errors_mm(lengths(body.coeffs), true_lengths, keep)}
            if args.write and name == "stature_pairs":
                init_mod.save_source_body(Path(path) / "mirror" / args.write, body, player=1)
        print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
