"""Arm-muscle capture (issue 11, seventh pass): capture settings side by side on benchmark-like held-out sequences.

The benchmark scores one session (subject 501, noise seed 0). To choose a default, the same full pipeline (measured
shape, Kinect v2 at 1 m, elbow flexion with shoulder abduction, 6k template, ``bench_muscle.capture_and_score``)
runs here on sessions of other subjects the tests do not use and on other noise seeds, each setting from scratch:

    python -m benchmarks.muscle_sequences --work W --session 504:0 --session 501:1 --frames 200 \
        --variant unpinned --variant a0t10

``--session SUBJECT:NOISE_SEED`` (``sample_arm_subject(SUBJECT)``, ``synth_arm_session(..., seed=NOISE_SEED)``,
cached in ``W/seq_SUBJECT_sNOISE_FRAMES``); ``--variant NAME`` (one of :data:`VARIANTS`) or
``NAME:KEY=VALUE,...`` (``CaptureOptions`` fields). ``W/model.npz``: the benchmark's model (its prepare step),
learned there when missing (another model, e.g. ``muscle model build --women 5``: its own W, the sessions linked).
The measured shape is given as a user types it (:func:`typed_shape`: the sex ``male`` / ``female``, MakeHuman's
gender rounded; before, the fractional gender, e.g. 0.89, gave a man 11 % of a woman's offset in a model that knows
women). ``--no-shape``: the shape fitted, as ``muscle capture`` without ``--shape``, the sex chosen from the depth when
the model knows women (``..._NAME_noshape.json``; the row's ``sex_fit``). Each run writes
``W/seq_SUBJECT_sNOISE_FRAMES_NAME.json``; the table is printed.
docs/muscle.md "seventh pass".
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

#: the settings compared (``CaptureOptions`` fields over its defaults)
VARIANTS = {
    "default": {},
    # the default before the tenth pass: the model's regressed rest arm and joints, the 50 % norm limit
    "previous_default": {"body_rest_shape": False, "body_rest_rounds": 0, "body_rest_fit_poses": False,
                         "norm_limit": 0.5},
    # the default with the pinned-sequence gate off (placement held, no skeleton, norm limit 0.5): the sixth pass's
    "unpinned": {"sequence_pinned_se_m": 0.0},
    # the sixth pass's best on 501 (``capture.PINNED_SEQUENCE``, a pinned sequence's setting when the gate is on):
    # skeleton and placement fitted, Huber on the depth only, chest pairs off, tracker weight 10, a 5 % norm limit
    # (with the default visibility filter)
    "a0t10": dict(sequence_fit_skeleton=True, sequence_fit_root=True, sequence_depth_huber_only=True,
                  sequence_torso_pair_weight=0.0, sequence_tracker_weight=10.0, norm_limit=0.05),
    # the eighth pass: the rest arm and skeleton from the body model's shape space, the regression projected into it
    # ("body_skeleton"), then fitted to the depth in two rounds alternated with the sequence fit ("body_rest")
    "body_skeleton": {"body_rest_shape": True},
    "body_rest": {"body_rest_shape": True, "body_rest_rounds": 2},
    # the ninth pass: "body_rest" keeps the round with the lowest depth energy (``body_rest_keep_best``, on by
    # default); "body_rest_all_rounds" is the eighth pass's (every round kept); "body_rest_joint" fits the strided
    # frames' angles with the rest shape (``refine.fit_body_rest_shape_and_poses``)
    "body_rest_all_rounds": {"body_rest_shape": True, "body_rest_rounds": 2, "body_rest_keep_best": False},
    "body_rest_joint": {"body_rest_shape": True, "body_rest_rounds": 2, "body_rest_fit_poses": True},
}
KEYS = ("median_mm", "p90_mm", "surface_median_mm", "surface_p90_mm", "front_median_mm", "back_median_mm",
        "bulge_err_mm", "jitter_mm", "cpu_ms_per_frame")


def session_of(work: Path, subject_seed: int, noise_seed: int, n_frames: int, fps: float = 30.0):
    """The subject and its (cached) session; another ``fps`` than 30: the same motion sampled at that rate
    (``W/seq_SUBJECT_sNOISE_FRAMES_FPSfps``)."""
    from benchmarks.bench_muscle import RESOLUTION
    from bodystudio.capture.session import open_session
    from bodystudio.muscle.synthetic import sample_arm_subject, synth_arm_session

    subject = sample_arm_subject(subject_seed)
    path = work / f"seq_{subject_seed}_s{noise_seed}_{n_frames}{_fps_tag(fps)}"
    if not path.is_dir():
        synth_arm_session(path, subject=subject, motion="elbow_flex", n_frames=n_frames, kinect="v2",
                          distance_m=1.0, resolution=RESOLUTION, seed=noise_seed, fps=fps)
    return subject, open_session(path)


def _fps_tag(fps: float) -> str:
    """The session name's suffix of a rate other than 30 fps (none at 30: the cached sessions keep their names)."""
    return "" if fps == 30.0 else f"_{fps:g}fps"


def typed_shape(subject):
    """The subject's measured shape as ``muscle capture --shape`` takes it from a user: BMI, muscularity, height, arm
    length and ``sex=male|female`` (1 / 0: MakeHuman's fractional gender rounded)."""
    from benchmarks import bench_muscle as bm

    return bm.shape_of(subject)  # the benchmark's own measured shape rounds the sex too (mus11z)


def run_case(work: Path, subject_seed: int, noise_seed: int, n_frames: int, name: str, options: dict,
             fps: float = 30.0, shape_given: bool = True) -> dict:
    """One capture, scored; ``shape_given=False`` fits the shape (``muscle capture`` without ``--shape``: the sex taken
    as male) instead of passing the subject's measured one."""
    from benchmarks import bench_muscle as bm
    from benchmarks.muscle_energy import work_model

    out = work / (f"seq_{subject_seed}_s{noise_seed}_{n_frames}{_fps_tag(fps)}_{name}"
                  f"{'' if shape_given else '_noshape'}.json")
    if out.is_file():
        return json.loads(out.read_text())
    claim = out.with_suffix(".running")  # another process on the same work folder runs this case: skip it
    try:
        os.close(os.open(claim, os.O_CREAT | os.O_EXCL))
    except FileExistsError:
        print(f"{out.name}: running in another process ({claim.name}); skipped", flush=True)
        return None
    template = bm._template()
    model = work_model(work, template)
    subject, session = session_of(work, subject_seed, noise_seed, n_frames, fps)
    bm.CAPTURE_OVERRIDES.clear()
    bm.CAPTURE_OVERRIDES.update(options)
    try:
        capture, scores = bm.capture_and_score(session, model, template, bm.truth_template(subject), "full",
                                               known_shape=typed_shape(subject) if shape_given else None)
    finally:
        bm.CAPTURE_OVERRIDES.clear()
    row = {"subject": subject_seed, "noise_seed": noise_seed, "frames": n_frames, "fps": fps,
           "variant": name if shape_given else f"{name} (no --shape)",
           "options": {k: repr(v) for k, v in options.items()}, **{k: scores.get(k) for k in KEYS},
           "sex": float(capture.shape.sex), "sex_fit": capture.sex_fit}
    out.write_text(json.dumps(row))
    claim.unlink()
    return row


def render(rows: list[dict]) -> str:
    from benchmarks.timing import markdown_table

    return markdown_table(["session", "variant", *KEYS],
                          [[f"{r['subject']}:{r['noise_seed']} ({r['frames']}{_fps_label(r)})", r["variant"],
                            *(f"{r[k]:.0f}" if k.endswith("per_frame") else f"{r[k]:.2f}" for k in KEYS)]
                           for r in rows])


def _fps_label(row: dict) -> str:
    fps = row.get("fps", 30.0)
    return "" if fps == 30.0 else f" at {fps:g} fps"


def parse_session(text: str) -> tuple[int, int]:
    """``SUBJECT:NOISE_SEED`` -> (subject seed, noise seed), both >= 0."""
    parts = text.split(":")
    if len(parts) != 2 or not all(p.strip().isdigit() for p in parts):
        raise ValueError(f"--session {text!r}: needs SUBJECT:NOISE_SEED, two whole numbers >= 0 (e.g. 504:0)")
    return int(parts[0]), int(parts[1])


def parse_variant(text: str) -> tuple[str, dict]:
    """A named variant of :data:`VARIANTS`, or NAME:KEY=VALUE,... as ``muscle_regions`` reads it."""
    from benchmarks.muscle_regions import parse_variant as parse_options

    name, _, items = text.partition(":")
    if not items:
        if name not in VARIANTS:
            raise ValueError(f"unknown variant {name!r} (known: {', '.join(VARIANTS)}; or NAME:KEY=VALUE,...)")
        return name, dict(VARIANTS[name])
    return parse_options(text)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, required=True)
    parser.add_argument("--session", action="append", default=[], help="SUBJECT:NOISE_SEED (repeatable)")
    parser.add_argument("--frames", type=int, default=200)
    parser.add_argument("--fps", type=float, default=30.0, help="the sessions' frame rate (the same motion in seconds; "
                        "e.g. --frames 100 --fps 15 is the 200-frame 30 fps motion sampled at 15 fps)")
    parser.add_argument("--variant", action="append", default=[], help="NAME or NAME:KEY=VALUE,... (repeatable)")
    parser.add_argument("--no-shape", action="store_true",
                        help="fit the shape instead of giving the measured one (muscle capture without --shape)")
    args = parser.parse_args(argv)
    try:
        variants = [parse_variant(v) for v in (args.variant or list(VARIANTS))]
        sessions = [parse_session(s) for s in (args.session or ["501:1"])]
    except (ValueError, SyntaxError) as exc:
        parser.error(str(exc))
    from bodystudio.muscle.synthetic import MAX_SYNTH_FPS, MIN_SYNTH_FPS

    if not MIN_SYNTH_FPS <= args.fps <= MAX_SYNTH_FPS:  # NaN too
        parser.error(f"--fps {args.fps:g}: must be in [{MIN_SYNTH_FPS:g}, {MAX_SYNTH_FPS:g}]")
    args.work.mkdir(parents=True, exist_ok=True)
    rows = [run_case(args.work, s, n, args.frames, name, opts, args.fps, not args.no_shape)
            for s, n in sessions for name, opts in variants]
    print(render([r for r in rows if r is not None]))


if __name__ == "__main__":
    main()
