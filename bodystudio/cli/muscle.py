"""``bodystudio muscle ...`` (model build / extend / info, capture), ``synth arm`` and ``eval muscle``.

A thin layer over :mod:`bodystudio.muscle`: options are checked here (ranges, output paths, before any
work starts), the work is one API call, and multi-file outputs appear as one unit
(:func:`bodystudio.muscle.export.staged_output_folder`).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import typer

from bodystudio.cli import eval as eval_cli
from bodystudio.cli import synth
from bodystudio.errors import InputError

app = typer.Typer(no_args_is_help=True)
model_app = typer.Typer(no_args_is_help=True)
app.add_typer(model_app, name="model", help="The statistical arm deformation model: build, extend, info.")

ARM_MOTIONS = ("elbow_flex", "abduction", "pronation")
KINECTS = ("v1", "v2")
RESOLUTIONS = ("6k", "2k", "full")
SIDES = ("left", "right")
DISTANCE_RANGE_M = (0.5, 3.0)  # Kinect v1 sees from 0.5 m (v2 also); beyond 3 m the arm is a few pixels wide
MAX_FRAMES = 2000  # the .glb's weights track is T^2 floats


def check_choice(option: str, value: str, valid: tuple[str, ...]) -> str:
    if value not in valid:
        raise InputError(f"{option} {value!r}: valid: {', '.join(valid)}")
    return value


def check_range(option: str, value: float, lo: float, hi: float, unit: str = "") -> float:
    if not (isinstance(value, (int, float)) and math.isfinite(value) and lo <= value <= hi):
        raise InputError(f"{option} {value}: must be in [{lo:g}, {hi:g}]{unit}")
    return value


@synth.app.command("arm")
def synth_arm(
    out: Path = typer.Argument(..., help="new session folder"),
    subject_seed: int = typer.Option(..., "--subject-seed", help="arm subject drawn from the population (seed)"),
    motion: str = typer.Option("elbow_flex", "--motion", help="elbow_flex | abduction | pronation"),
    frames: int = typer.Option(200, "--frames", help="frames at 30 fps"),
    kinect: str = typer.Option("v2", "--kinect", help="simulated depth sensor: v1 | v2"),
    distance: float = typer.Option(1.0, "--distance", help="sensor to subject distance (m)"),
    seed: int = typer.Option(0, "--seed", help="motion variation and sensor noise"),
    resolution: str = typer.Option("6k", "--resolution", help="body template of the subject: 6k | 2k | full"),
) -> None:
    """Synthesise a Kinect arm sequence with ground truth (arm meshes, joint angles) per frame."""
    from bodystudio.muscle.export import check_new_output
    from bodystudio.muscle.synthetic import synth_arm_session

    check_choice("--motion", motion, ARM_MOTIONS)
    check_choice("--kinect", kinect, KINECTS)
    check_choice("--resolution", resolution, RESOLUTIONS)
    check_range("--frames", frames, 1, MAX_FRAMES)
    check_range("--distance", distance, *DISTANCE_RANGE_M, " m")
    check_range("--subject-seed", subject_seed, 0, 2**31 - 1)
    check_new_output(out, "session folder")
    session = synth_arm_session(out, subject_seed=subject_seed, motion=motion, n_frames=frames, kinect=kinect,
                                distance_m=distance, seed=seed, resolution=resolution)
    typer.echo(f"wrote {out}: {len(session)} frames of {motion} (Kinect {kinect} at {distance:g} m), "
               f"streams {', '.join(session.streams)}")


def _arm_template(resolution: str, side: str):
    from bodystudio.body import build_body
    from bodystudio.muscle.arm import arm_template

    return arm_template(build_body(resolution=resolution), side)


def _session_arm(session) -> dict:
    """The session's arm block (side, resolution) when it is a synthetic arm session, else {}."""
    gt = session.gt_subject or {}
    return gt.get("arm") or {}


@app.command("capture")
def capture(
    session_path: Path = typer.Argument(..., metavar="SESSION", help="Kinect session folder (bodystudio synth arm)"),
    out: Path = typer.Option(..., "--out", help="new output folder: meshes/NNNNN.ply, arm.glb, params.json"),
    model_path: Path | None = typer.Option(None, "--model", help="arm model .npz (bodystudio muscle model build)"),
    no_model: bool = typer.Option(False, "--no-model", help="NICP + ARAP only, no model (the paper's Fig. 6a)"),
    no_refine: bool = typer.Option(False, "--no-refine", help="model-based filtering only, no refinement (§7)"),
    resolution: str | None = typer.Option(None, "--resolution", help="arm template: 6k | 2k | full "
                                          "(default: the session's, else 6k)"),
    side: str | None = typer.Option(None, "--side", help="left | right (default: the session's, else left)"),
    frames: int | None = typer.Option(None, "--frames", help="capture only the first N frames"),
) -> None:
    """Capture the arm of a depth session (Arm-Muscle Capture §4-7): per-frame meshes, joint angles, shape."""
    from bodystudio.capture.session import open_session
    from bodystudio.muscle.capture import CaptureOptions, capture_arm_sequence, write_arm_capture
    from bodystudio.muscle.export import check_new_output

    if no_model and no_refine:
        raise InputError("--no-model and --no-refine: choose one (--no-model is NICP + ARAP without the model, "
                         "--no-refine the model without the refinement)")
    if no_model and model_path is not None:
        raise InputError("--no-model with --model: choose one")
    if not no_model and model_path is None:
        raise InputError("muscle capture needs --model MODEL.npz (make one with `bodystudio muscle model build`) "
                         "or --no-model")
    if model_path is not None and not model_path.is_file():
        raise InputError(f"--model {model_path}: no such file; make one with `bodystudio muscle model build`")
    if frames is not None:
        check_range("--frames", frames, 1, MAX_FRAMES)
    check_new_output(out, "arm capture folder")
    session = open_session(session_path)
    arm = _session_arm(session)
    resolution = check_choice("--resolution", resolution or arm.get("resolution", "6k"), RESOLUTIONS)
    side = check_choice("--side", side or arm.get("side", "left"), SIDES)
    template = _arm_template(resolution, side)
    model = None
    if model_path is not None:
        from bodystudio.muscle.model import load_arm_model

        model = load_arm_model(model_path, template)
    mode = "nicp" if no_model else "model" if no_refine else "full"
    result = capture_arm_sequence(session, model, template, CaptureOptions(mode=mode),
                                  frames=None if frames is None else slice(0, frames))
    write_arm_capture(out, result)
    typer.echo(f"wrote {out}: {result.n_frames} frames ({mode}), {result.ms_per_frame:.0f} ms per frame")


EVAL_KEYS = ("median_mm", "p90_mm", "front_median_mm", "back_median_mm", "bulge_err_mm", "jitter_mm", "ms_per_frame")


@eval_cli.app.command("muscle")
def eval_muscle(
    folder: Path = typer.Argument(..., metavar="DIR", help="arm capture folder (bodystudio muscle capture)"),
    session_path: Path | None = typer.Option(None, "--session", help="the captured session (default: the one "
                                             "recorded in DIR/params.json)"),
) -> None:
    """Score an arm capture against the session's ground truth; prints JSON (errors in mm)."""
    from bodystudio.muscle.evaluate import evaluate_arm_capture_folder

    scores = evaluate_arm_capture_folder(folder, session_path)
    out = {k: round(float(scores[k]), 3) for k in EVAL_KEYS if k in scores}
    out.update({k: round(v, 3) if isinstance(v, float) else v for k, v in scores.items() if k not in out})
    typer.echo(json.dumps(out))
