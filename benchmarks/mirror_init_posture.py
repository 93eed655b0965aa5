"""The init's unposing held at the subject's own posture (mir12v, ``mirror init --unpose-posture``): what it does to
the fitted source body and to the Eq. 4 target's displacement.

Usage: PYTHONPATH=. python benchmarks/mirror_init_posture.py [--bones spine_02 neck_01 head] [--write NAME.npz]
SESSION [SESSION ...]

Per synthetic mirror session (with ``gt/mirror/actors.npz``), player 1's init from the session's own observations
(``mirror init``'s frames), once as ``mirror init`` does it without the posture bones (``main``; since mir12y with
the weighted pool) and once with ``unpose_posture_bones`` (``--bones``,
default :data:`bodystudio.mirror.init.POSTURE_BONES`); printed per body: the error of the Eq. 4 displacement
``B(c_T) - B(c_S)`` of the session's edits against the ground truth's (mean over vertices, mm: what the warp's target
inherits from the fitted shape), the rest vertex error with the mean offset removed, and the model's stature, mass,
chest and hip girth of the fitted against the true coefficients; the posture the option ends with (the bend of each
bone from rest, degrees). ``--write NAME.npz``: the option's body saved as ``SESSION/mirror/NAME.npz`` (for
``benchmarks/mirror_refine_end_to_end.py --source NAME.npz``).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def bend_deg(skeleton, directions) -> np.ndarray:
    """(B,) each bone's bend from its rest direction (degrees)."""
    rest = skeleton.rest_rotations[:, :, 1]
    rest = rest / np.linalg.norm(rest, axis=1, keepdims=True)
    return np.degrees(np.arccos(np.clip(np.einsum("bi,bi->b", rest, directions), -1.0, 1.0)))


def init_scores(model, source, actors, edits) -> dict:
    """The fitted source against the session's truth (player 1): displacement, rest shape and measurements."""
    from bodystudio.mirror.reshape import target_coeffs

    c = np.asarray(source.coeffs, float)
    displacement = model.vertices(target_coeffs(model, c, edits)) - model.vertices(c)
    true_displacement = actors["target_rest_vertices"][0] - actors["source_rest_vertices"][0]
    d = model.vertices(c) - actors["source_rest_vertices"][0]
    fitted, true = model.measure(c), model.measure(actors["source_coeffs"][0])
    err = np.linalg.norm(displacement - true_displacement, axis=1)
    return {"displacement_err_mm": round(1e3 * float(err.mean()), 2),
            "rest_err_mm": round(1e3 * float(np.linalg.norm(d - d.mean(0), axis=1).mean()), 2),
            **{f"{k}_err": round(float(fitted[k] - true[k]) * (1e3 if k.endswith("_m") else 1.0), 2)
               for k in ("stature_m", "mass_kg", "chest_m", "hip_m")}}


def _held_init(init_mod, obs, model, bones, kw):
    """The init with the option, and every refined pose it unposed by (``(body, pose)``, in order)."""
    original, seen = init_mod.refined_init_pose, []

    def recorded(plan, body, o, P, camera, steps, **options):
        pose = original(plan, body, o, P, camera, steps, **options)
        seen.append((body, pose))
        return pose

    init_mod.refined_init_pose = recorded
    try:
        return init_mod.initialise_from_observations(obs, model, unpose_posture_bones=bones, **kw), seen
    finally:
        init_mod.refined_init_pose = original


def main() -> None:
    from bodystudio.body.statistical import load_statistical_model
    from bodystudio.capture.session import open_session
    from bodystudio.mirror import init as init_mod

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sessions", nargs="+", type=Path)
    parser.add_argument("--bones", nargs="+", default=list(init_mod.POSTURE_BONES))
    parser.add_argument("--write", default=None, help="save the option's body as SESSION/mirror/NAME.npz")
    args = parser.parse_args()
    model = load_statistical_model("6k", progress=False)
    for path in args.sessions:
        session = open_session(path)
        actors = np.load(Path(path) / "gt" / "mirror" / "actors.npz")
        edits = session.metadata["edits"]
        obs, sensor = init_mod.collect_observations(session, None, 1, init_mod.DEFAULT_INIT_FRAMES)
        kw = dict(view_point=sensor.depth.center, depth_camera=sensor.depth)
        plain = init_mod.initialise_from_observations(obs, model, unpose_posture_bones=(), **kw)
        held, seen = _held_init(init_mod, obs, model, tuple(args.bones), kw)
        last = seen[-1][0] if seen else None
        posture = {}
        if last is not None:
            mean = init_mod.session_posture(last.skeleton, [q for b, q in seen if b is last], args.bones)
            bends = bend_deg(last.skeleton, mean)
            posture = {n: round(float(bends[last.skeleton.index(n)]), 2) for n in args.bones}
        if args.write:
            init_mod.save_source_body(Path(path) / "mirror" / args.write, held, player=1)
        print(json.dumps({"session": Path(path).name, "frames": list(plain.frames_used),
                          "main": init_scores(model, plain, actors, edits),
                          "unpose_posture": init_scores(model, held, actors, edits),
                          "posture_bend_deg": posture}), flush=True)


if __name__ == "__main__":
    main()
