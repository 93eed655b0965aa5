"""The self-checks' clean and faulty figures (docs/plausibility.md): plant each fault, run the stage, print its verdict.

Usage: PYTHONPATH=. python benchmarks/plausibility_faults.py reconstruct [--cache DIR] [--subject 23] [--cameras 6]
       PYTHONPATH=. python benchmarks/plausibility_faults.py mirror [--cache DIR] [--subjects 3,4,5,6]

``reconstruct``: a 2-frame walk (320x240, Kinect v2, 2k template) clean, with cam_02 moved 5 cm / 3 deg, with
the masks of cam_01 and cam_03 swapped and with the depth 10x (depth constraints); prints the visible-surface
errors against ground truth beside the self-check's per-camera IoU, coherence, depth figures and verdict.
``mirror``: 30-frame sessions of each subject (walk_in off), each initialised; prints every source body against
every session (the skeleton mismatch) and each session's depth-to-colour registration, clean and with the
colour camera 10 px off. Sessions are made in ``--cache`` (or a temporary folder) when missing.
"""

from __future__ import annotations

import argparse
import itertools
import json
import shutil
import tempfile
from pathlib import Path


def reconstruct(cache: Path, subject: int, cameras: int) -> None:
    from bodystudio.capture import faults
    from bodystudio.capture.synth import synth_session
    from bodystudio.reconstruct.sequence import reconstruct_session

    clean = cache / f"rec{subject}_{cameras}"
    if not (clean / "session.json").exists():
        synth_session(clean, n_cameras=cameras, n_frames=2, motion="walk", subject_seed=subject, resolution=(320, 240))
    cases = {"clean": None, "camera-moved": faults.bump_camera, "masks-swapped": faults.swap_masks,
             "depth-10x": lambda S: faults.scale_depth(S, 10.0)}
    for name, plant in cases.items():
        S = cache / f"rec{subject}_{cameras}_{name}"
        shutil.rmtree(S, ignore_errors=True)
        shutil.copytree(clean, S, ignore=shutil.ignore_patterns("reconstruct"))
        if plant is not None:
            plant(S)
        constraints = ("silhouette", "depth") if name.startswith("depth") else ("silhouette",)
        s = reconstruct_session(S, template="2k", constraints=constraints, accept_implausible=True)
        verdict = json.loads((S / "reconstruct" / "run.json").read_text())["plausibility"]
        figures = {k: ({c: round(v, 2) for c, v in verdict[k].items()} if isinstance(verdict.get(k), dict) else None)
                   for k in ("camera_iou", "camera_coherence", "depth")}
        print(f"{name}: median {s['median_mm']:.1f} mm p90 {s['p90_mm']:.1f} mm | {json.dumps(figures)} | "
              f"ok {verdict['ok']} | {verdict['problems'][:1] or verdict['warnings'][:1]}", flush=True)


def mirror(cache: Path, subjects: list[int]) -> None:
    from bodystudio.capture import faults
    from bodystudio.capture.session import open_session
    from bodystudio.mirror.init import initialise_source_body, load_source_body, save_source_body
    from bodystudio.mirror.plausibility import depth_color_registration, source_body_agreement
    from bodystudio.mirror.synthetic import synth_mirror_session

    for s in subjects:
        S = cache / f"mirror{s}"
        if not (S / "session.json").exists():
            synth_mirror_session(S, s, n_frames=30, walk_in=False)
        if not (S / "mirror" / "source_body.npz").exists():
            save_source_body(S / "mirror" / "source_body.npz", initialise_source_body(open_session(S)))
    for a, b in itertools.product(subjects, subjects):
        r = source_body_agreement(load_source_body(cache / f"mirror{a}" / "mirror" / "source_body.npz"),
                                  open_session(cache / f"mirror{b}"))
        print(f"source body {a} on session {b}{' (same actor)' if a == b else ''}: mismatch {r['mismatch']:.3f} "
              f"scale {r['scale']:.3f}", flush=True)
    for s in subjects:
        shifted = cache / f"mirror{s}_colour10px"
        if not (shifted / "session.json").exists():
            shutil.copytree(cache / f"mirror{s}", shifted)
            shutil.rmtree(shifted / "mirror")  # the init's output, not the session's (gt/mirror stays)
            faults.shift_colour_camera(shifted, 10.0)
        for S in (cache / f"mirror{s}", shifted):
            r = depth_color_registration(open_session(S))
            print(f"{S.name}: registration offset {r['offset_px']:.1f} px, per frame "
                  f"{[(f['dx'], f['dy']) for f in r['frames']]}", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("stage", choices=("reconstruct", "mirror"))
    parser.add_argument("--cache", type=Path, default=None)
    parser.add_argument("--subject", type=int, default=23)
    parser.add_argument("--cameras", type=int, default=6)
    parser.add_argument("--subjects", default="3,4,5,6")
    args = parser.parse_args()
    cache = args.cache or Path(tempfile.mkdtemp(prefix="plausibility-"))
    cache.mkdir(parents=True, exist_ok=True)
    if args.stage == "reconstruct":
        reconstruct(cache, args.subject, args.cameras)
    else:
        mirror(cache, [int(x) for x in args.subjects.split(",")])


if __name__ == "__main__":
    main()
