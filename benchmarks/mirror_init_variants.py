"""Variants of ``mirror init``'s source-body fit on synthetic mirror sessions, scored against the true body (mir12w).

Usage: PYTHONPATH=. python benchmarks/mirror_init_variants.py SESSION [SESSION ...] [--variant JSON ...]
       [--shadow DIR --name NAME.npz] [--true]

Per session the init's observations are read once (``collect_observations``, as ``mirror init``), then each
``--variant`` (a JSON object of keyword arguments of ``initialise_from_observations``, e.g. ``'{"frame_choice":
"spread"}'`` or ``'{"passes": 7}'``; ``{}`` is the default init) is fitted and scored against ``gt/mirror/actors.npz``:
the rest vertex error (mean, the mean offset removed), the Eq. 4 target's rest displacement error ``|(V_T - V_S) -
(V_T - V_S)_true|`` for the session's edits, the mean joint (bone head) error, stature and mass errors. Prints one line
per variant with the means over the sessions and one row per session.

``--shadow DIR --name NAME.npz`` also writes each session's body of the (last) variant, or with ``--true`` the true
coefficients' body (the model's vertices and joints for ``gt/mirror/actors.npz``'s ``source_coeffs``: the shape
oracle end to end), as ``DIR/<session>/mirror/NAME.npz`` (+ its ``.json``), where ``DIR/<session>`` is a shadow of the
session (links to its calibration, kinect, gt and session.json, a mirror folder of its own), so that
``benchmarks/mirror_refine_end_to_end.py --source NAME.npz DIR/<session>`` runs the mirror with it without writing
into the session. Example (docs/mirror.md, mir12w): ``--shadow W --name source_true.npz --true S57`` then
``mirror_refine_end_to_end.py --runs refine --source source_true.npz --out OUT W/S57``: 57 0.9464 -> 0.9581.
"""

from __future__ import annotations

import argparse
import json
import shutil
import time
from pathlib import Path

import numpy as np


def shadow_session(session: Path, folder: Path) -> Path:
    """``folder/<session name>``: links to the session's parts and a mirror folder of its own (the session's source
    bodies copied in once), so that a run reads the session and writes nothing into it."""
    shadow = folder / session.name
    (shadow / "mirror").mkdir(parents=True, exist_ok=True)
    for part in ("calibration", "kinect", "gt", "session.json"):
        link = shadow / part
        if not link.exists() and (session / part).exists():
            link.symlink_to((session / part).resolve())
    for f in (session / "mirror").glob("source_body*"):
        if not (shadow / "mirror" / f.name).exists():
            shutil.copy2(f, shadow / "mirror" / f.name)
    return shadow


def score(model, body, actors, edits) -> dict:
    """Errors of a source body against the truth (mm, kg)."""
    from bodystudio.mirror.reshape import target_coeffs

    d = body.vertices - actors["source_rest_vertices"][0]
    dv = model.vertices(target_coeffs(model, body.coeffs, edits)) - body.vertices
    dv_true = actors["target_rest_vertices"][0] - actors["source_rest_vertices"][0]
    m, mt = model.measure(body.coeffs), model.measure(actors["source_coeffs"][0])
    return {"rest_err_mm": 1000 * float(np.linalg.norm(d - d.mean(0), axis=1).mean()),
            "disp_err_mm": 1000 * float(np.linalg.norm(dv - dv_true, axis=1).mean()),
            "joint_err_mm": 1000 * float(np.linalg.norm(body.skeleton.heads - actors["source_heads"][0],
                                                        axis=1).mean()),
            "stature_err_mm": 1000 * (m["stature_m"] - mt["stature_m"]), "mass_err_kg": m["mass_kg"] - mt["mass_kg"]}


def write_source(shadow: Path, name: str, body, model) -> None:
    from bodystudio.mirror.init import save_source_body, source_body_layout
    from bodystudio.runfolder import RunWriter

    out = shadow / "mirror" / name
    m = model.measure(body.coeffs)
    with RunWriter(source_body_layout(out), "benchmarks/mirror_init_variants.py",
                   {"stage": "mirror", "kind": "init"}) as w:
        save_source_body(w.path_for(out.name), body, player=1)
        w.commit({"source_body": f"mirror/{name}", "player": 1, "frames_used": list(body.frames_used),
                  "stature_m": round(m["stature_m"], 4), "mass_kg": round(m["mass_kg"], 2)})


def main() -> None:
    from bodystudio.body.statistical import load_statistical_model
    from bodystudio.capture.session import open_session
    from bodystudio.mirror.init import (
        DEFAULT_INIT_FRAMES,
        SourceBody,
        collect_observations,
        initialise_from_observations,
        knee_joint_frames,
    )

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sessions", nargs="+", type=Path)
    parser.add_argument("--variant", action="append", default=None,
                        help="JSON keyword arguments of initialise_from_observations (repeatable; default: {})")
    parser.add_argument("--shadow", type=Path, default=None, help="folder of shadow sessions to write bodies into")
    parser.add_argument("--name", default=None, help="with --shadow: the body's file name in the shadow's mirror/")
    parser.add_argument("--true", action="store_true", help="with --shadow: write the true coefficients' body")
    args = parser.parse_args()
    if (args.shadow is None) != (args.name is None):
        parser.error("--shadow and --name go together")
    if args.name is not None and not args.name.endswith(".npz"):
        parser.error(f"--name {args.name}: a source body is a .npz file")
    variants = [json.loads(v) for v in (args.variant or ["{}"])]
    model = load_statistical_model("6k", progress=False)
    data = {}
    for p in args.sessions:
        s = open_session(p)
        actors = np.load(p / "gt" / "mirror" / "actors.npz")
        if args.true:
            c = actors["source_coeffs"][0]
            body = SourceBody(c, model.vertices(c), model.skeleton(c), (), 0.0, model.weights, model.faces)
            write_source(shadow_session(p, args.shadow), args.name, body, model)
            print(json.dumps({"session": p.name, "written": args.name,
                              **score(model, body, actors, s.metadata["edits"])}))
            continue
        obs, sensor = collect_observations(s, None, 1, DEFAULT_INIT_FRAMES)
        data[p] = (obs, sensor, actors, s.metadata["edits"], knee_joint_frames(s, obs))  # as `mirror init` (mir12ac)
    for v in variants if data else []:
        rows = []
        t0 = time.process_time()
        for p, (obs, sensor, actors, edits, knee_frames) in data.items():
            body = initialise_from_observations(obs, model, view_point=sensor.depth.center, depth_camera=sensor.depth,
                                                knee_frames=knee_frames, **v)
            rows.append({"session": p.name, **score(model, body, actors, edits)})
            if args.shadow is not None and v is variants[-1]:
                write_source(shadow_session(p, args.shadow), args.name, body, model)
        keys = [k for k in rows[0] if k != "session"]
        mean = {k: float(np.mean([abs(r[k]) if k.endswith(("_mm", "_kg")) and k.startswith(("stature", "mass"))
                                  else r[k] for r in rows])) for k in keys}
        print(json.dumps(v), f"({time.process_time() - t0:.0f} s CPU) mean: "
              + ", ".join(f"{k} {x:.2f}" for k, x in mean.items()) + " (stature / mass: mean abs)", flush=True)
        for r in rows:
            print("   ", r["session"], ", ".join(f"{k} {r[k]:+.2f}" for k in keys), flush=True)


if __name__ == "__main__":
    main()
