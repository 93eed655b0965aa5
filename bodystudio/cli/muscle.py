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

from bodystudio.cli import batch as batch_cli
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
CENTRES = ("sex", "fitted", "regressed")  # model.capture_samples(centre=...)
CAPTURED_RESTS = ("body", "mesh")  # model.extend_arm_model(captured_rest=...)
SHAPE_FORMS = ("body", "linear")  # model.extend_arm_model(shape_form=...)
SUBJECT_ROWS = ("own", "training")  # model.extend_arm_model(subject_rows=...)
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
    frames: int = typer.Option(200, "--frames", help="frames, sampled at --fps"),
    fps: float = typer.Option(30.0, "--fps", help="frame rate the motion is sampled at (the same motion in seconds "
                              "at every rate; recorded as the session's metadata.fps)"),
    kinect: str = typer.Option("v2", "--kinect", help="simulated depth sensor: v1 | v2"),
    distance: float = typer.Option(1.0, "--distance", help="sensor to subject distance (m)"),
    seed: int = typer.Option(0, "--seed", help="motion variation and sensor noise"),
    resolution: str = typer.Option("6k", "--resolution", help="body template of the subject: 6k | 2k | full"),
) -> None:
    """Synthesise a Kinect arm sequence with ground truth (arm meshes, joint angles) per frame."""
    from bodystudio.muscle.export import check_new_output
    from bodystudio.muscle.synthetic import MAX_SYNTH_FPS, MIN_SYNTH_FPS, synth_arm_session

    check_choice("--motion", motion, ARM_MOTIONS)
    check_range("--fps", fps, MIN_SYNTH_FPS, MAX_SYNTH_FPS)
    check_choice("--kinect", kinect, KINECTS)
    check_choice("--resolution", resolution, RESOLUTIONS)
    check_range("--frames", frames, 1, MAX_FRAMES)
    check_range("--distance", distance, *DISTANCE_RANGE_M, " m")
    check_range("--subject-seed", subject_seed, 0, 2**31 - 1)
    check_new_output(out, "session folder")
    session = synth_arm_session(out, subject_seed=subject_seed, motion=motion, n_frames=frames, kinect=kinect,
                                distance_m=distance, seed=seed, resolution=resolution, fps=fps)
    typer.echo(f"wrote {out}: {len(session)} frames of {motion} at {fps:g} fps (Kinect {kinect} at {distance:g} m), "
               f"streams {', '.join(session.streams)}")


def _arm_template(resolution: str, side: str):
    from bodystudio.body import build_body
    from bodystudio.muscle.arm import arm_template

    return arm_template(build_body(resolution=resolution), side)


@app.command("capture")
def capture(
    session_paths: list[Path] = typer.Argument(..., metavar="SESSION...", help="Kinect session folder(s) "
                                               "(bodystudio synth arm); several: a batch on a dask cluster"),
    out: Path = typer.Option(..., "--out", help="new output folder: meshes/NNNNN.ply, arm.glb, params.json "
                             "(batch: a folder of OUT/SESSION_NAME/ capture folders and OUT/batch.json)"),
    model_path: Path | None = typer.Option(None, "--model", help="arm model .npz (bodystudio muscle model build)"),
    no_model: bool = typer.Option(False, "--no-model", help="NICP + ARAP only, no model (the paper's Fig. 6a)"),
    no_refine: bool = typer.Option(False, "--no-refine", help="model-based filtering only, no refinement (§7)"),
    resolution: str | None = typer.Option(None, "--resolution", help="arm template: 6k | 2k | full "
                                          "(default: the session's, else 6k)"),
    side: str | None = typer.Option(None, "--side", help="left | right (default: the session's, else left)"),
    frames: int | None = typer.Option(None, "--frames", help="capture only the first N frames"),
    shape: list[str] | None = typer.Option(None, "--shape", help="the subject's measured shape parameters "
                                           "bmi=..,muscularity=..,height_m=..,arm_length_m=..[,sex=male|female] "
                                           "(the paper's Table 1; a batch: once per SESSION, in order; "
                                           "default: fitted from the first frames)"),
    no_sequence_fit: bool = typer.Option(False, "--no-sequence-fit", help="skip the whole-sequence pose fit and "
                                         "the rest arm and skeleton fitted with it in the body model's shape space "
                                         "(docs/muscle.md: better captures with them; the model's regressed rest "
                                         "arm and joints instead)"),
    for_extension: bool = typer.Option(False, "--for-extension", help="capture to extend a model (muscle model "
                                       "extend): the subject's skeleton and the torso placement fitted with the "
                                       "sequence, on the model's regressed rest arm, 50 % norm limit "
                                       "(docs/muscle.md: the extension's best captures)"),
    scheduler: str | None = typer.Option(None, "--scheduler", help="batch: " + batch_cli.SCHEDULER_HELP),
    workers: int | None = typer.Option(None, "--workers", help="batch: " + batch_cli.WORKERS_HELP),
    force: bool = typer.Option(False, "--force", help="batch: redo every sequence, also those already captured"),
    accept_implausible: bool = typer.Option(False, "--accept-implausible", help="write the capture even when its "
                                            "self-check finds it implausible (depth in another unit, the other arm "
                                            "facing the sensor, the arm out of the depth window); the verdict goes "
                                            "to OUT/plausibility.json"),
    skip_bad_frames: bool = typer.Option(True, "--skip-bad-frames/--no-skip-bad-frames", help="skip a frame whose "
                                         "depth image cannot be read or shows no arm, or whose tracker joints are "
                                         "missing, with a warning (named in params.json skipped_frames, no mesh "
                                         "there); refused beyond 25 % of the frames or 5 in a row at 30 fps. "
                                         "--no-skip-bad-frames: the first bad frame refuses the capture"),
) -> None:
    """Capture the arm of a depth session (Arm-Muscle Capture §4-7): per-frame meshes, joint angles, shape.

    Several SESSIONs, or --workers / --scheduler: a batch, one sequence per dask work unit, resumable
    (docs/batch.md); $BODYSTUDIO_SCHEDULER gives the batch's cluster address.
    """
    from bodystudio.muscle.capture import capture_session_arm, session_fps, write_arm_capture
    from bodystudio.muscle.export import check_new_output

    if shape and no_model:
        raise InputError("--shape needs the model (the shape parameters drive it); drop --no-model")
    shapes = [_parse_shape(text) for text in shape or ()]
    if shapes and len(shapes) != len(session_paths):
        raise InputError(f"--shape: {len(shapes)} given for {len(session_paths)} sessions; give one --shape per "
                         "SESSION, in their order (repeat the values for sessions of one subject)")
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
    if resolution is not None:
        check_choice("--resolution", resolution, RESOLUTIONS)
    if side is not None:
        check_choice("--side", side, SIDES)
    mode = "nicp" if no_model else "model" if no_refine else "full"
    if no_sequence_fit and mode == "nicp":
        raise InputError("--no-sequence-fit with --no-model: the sequence fit is a model step; drop one")
    if for_extension and mode == "nicp":
        raise InputError("--for-extension with --no-model: an extension capture needs the model; drop --no-model")
    if for_extension and no_sequence_fit:
        raise InputError("--for-extension with --no-sequence-fit: the extension capture fits the skeleton in the "
                         "sequence fit; drop one")
    if len(session_paths) > 1 or scheduler is not None or workers is not None:
        if accept_implausible:
            raise InputError("--accept-implausible is for a single capture; a batch refuses an implausible "
                             "sequence in its report: capture that SESSION on its own to accept it")
        if not skip_bad_frames:
            raise InputError("--no-skip-bad-frames is for a single capture; a batch skips bad frames (named in each "
                             "unit's params.json): capture that SESSION on its own to refuse them")
        _capture_batch(session_paths, out, model_path, mode, resolution, side, frames, shapes or None, scheduler,
                       workers, force, not no_sequence_fit, for_extension)
        return
    if force:
        raise InputError("--force is for a batch (several SESSIONs or --workers/--scheduler); a single capture "
                         "writes a new --out folder")
    check_new_output(out, "arm capture folder")
    result = capture_session_arm(session_paths[0], model_path, mode, resolution, side, frames,
                                 shapes[0] if shapes else None, sequence_fit=not no_sequence_fit,
                                 for_extension=for_extension, accept_implausible=accept_implausible,
                                 skip_bad_frames=skip_bad_frames)
    fps = session_fps(session_paths[0])
    write_arm_capture(out, result, fps=fps)
    for s in result.skipped:
        typer.echo(f"warning: {s['file']}: frame {s['frame']} skipped ({s['why']}); no mesh for it", err=True)
    for line in (result.plausibility or {}).get("warnings", []):
        typer.echo(f"warning: {line}", err=True)
    if result.sex_fit is not None:
        e = result.sex_fit["energy_mm"]
        typer.echo(f"the subject's sex from the depth: {result.sex_fit['chosen']} (held-out depth energy as a man "
                   f"{e['male']:.3f} mm, as a woman {e['female']:.3f} mm; params.json sex_fit)")
    gaps = f", {len(result.skipped)} skipped (params.json skipped_frames)" if result.skipped else ""
    typer.echo(f"wrote {out}: {result.n_frames} frames ({mode}){gaps}, {result.ms_per_frame:.0f} ms per frame")


def _check_frame_rates(session_paths) -> None:
    """Every session's frame rate one the capture's temporal filters serve (``capture.capture_frame_rate``), before
    a batch starts: a 5 fps sequence is refused in one line, not as a failed unit after the others ran."""
    from bodystudio.capture.session import open_session
    from bodystudio.errors import BodyStudioError
    from bodystudio.muscle.capture import capture_frame_rate

    for path in session_paths:
        try:
            session = open_session(path)
        except BodyStudioError:
            continue  # the unit reports an unreadable session itself (batch.sequence_inputs_sha256)
        capture_frame_rate(session)


def _capture_batch(session_paths, out, model_path, mode, resolution, side, frames, shapes, scheduler, workers,
                   force, sequence_fit: bool = True, for_extension: bool = False) -> None:
    """``muscle capture S1 S2 ... --out DIR``: each sequence a work unit on a dask cluster (bodystudio.batch)."""
    from dataclasses import asdict

    from bodystudio.batch import (
        BatchError,
        MuscleOptions,
        batch_client,
        check_capture_sessions,
        muscle_batch,
        resolve_scheduler,
    )
    from bodystudio.fileio import check_output_folder

    # refuse bad input before starting a cluster
    check_capture_sessions(session_paths)
    _check_frame_rates(session_paths)
    if frames is not None:
        _check_frames_in_sessions(session_paths, frames)
    check_output_folder(out, "--out")
    if model_path is not None:
        from bodystudio.muscle.model import load_arm_model

        load_arm_model(model_path)  # junk is refused here, not once per sequence on the workers
    resolve_scheduler(scheduler, workers)
    options = MuscleOptions(mode=mode, resolution=resolution, side=side, frames=frames,
                            model=None if model_path is None else str(model_path.resolve()), sequence_fit=sequence_fit,
                            for_extension=for_extension)
    with batch_client(scheduler, workers, units=len(session_paths)) as client:
        batch_cli.print_cluster(client)
        report = muscle_batch(session_paths, out, client, options, force=force, progress=True,
                              shapes=None if shapes is None else [asdict(s) for s in shapes])
    batch_cli.print_report(report, f"muscle capture ({len(session_paths)} sequences)")
    if report.errors:
        raise BatchError(report.failure_message("sequences"))


def _check_frames_in_sessions(session_paths, frames: int) -> None:
    """``--frames N`` of a batch against every session, before a cluster starts (a shorter session failed on
    its worker only). A session that cannot be opened is left to its unit, which fails naming why."""
    from bodystudio.capture.session import open_session
    from bodystudio.errors import BodyStudioError

    for path in session_paths:
        try:
            n = len(open_session(path).frame_ids)
        except BodyStudioError:
            continue
        if frames > n:
            raise InputError(f"--frames {frames}: {path} has {n} frames; give at most {n} (--frames applies to "
                             "every SESSION of the batch)")


EVAL_KEYS = ("median_mm", "p90_mm", "surface_median_mm", "surface_p90_mm", "front_median_mm", "back_median_mm",
             "bulge_err_mm", "jitter_mm", "ms_per_frame")


def evaluate_capture_folder(folder: Path, session_path: Path | None = None) -> dict:
    """Issue 11's figures of a written arm capture folder against its session's ground truth."""
    from bodystudio.capture.session import open_session
    from bodystudio.muscle.capture import load_arm_capture
    from bodystudio.muscle.evaluate import evaluate_arm_capture
    from bodystudio.muscle.synthetic import session_arm_template

    if not Path(folder).is_dir():
        raise InputError(f"{folder}: no such arm capture folder; make one with `bodystudio muscle capture`")
    capture = load_arm_capture(folder)
    source = session_path or capture.session_path
    if source is None:
        raise InputError(f"{folder}: params.json names no session; pass --session SESSION")
    session = open_session(source)
    check_capture_source(folder, capture, session)
    return evaluate_arm_capture(capture, session, session_arm_template(session))


def check_capture_source(folder: Path, capture, session) -> None:
    """Refuse to score a capture against the ground truth of another recording than the one it was captured
    from (its depth frames' fingerprint, written by the capture, differs): such a score would be meaningless.
    Captures written before the fingerprint existed are scored as before."""
    if capture.is_from(session) is False:
        raise InputError(f"{folder}: captured from another recording than {session.path} (its depth frames "
                         f"differ); pass --session with the session it was captured from "
                         f"({capture.session_path or 'named in params.json'})")


@eval_cli.app.command("muscle")
def eval_muscle(
    folder: Path = typer.Argument(..., metavar="DIR", help="arm capture folder (bodystudio muscle capture)"),
    session_path: Path | None = typer.Option(None, "--session", help="the captured session (default: the one "
                                             "recorded in DIR/params.json)"),
) -> None:
    """Score an arm capture against the session's ground truth; prints JSON (errors in mm)."""
    scores = evaluate_capture_folder(folder, session_path)
    out = {k: _score(scores[k]) for k in EVAL_KEYS if k in scores}
    out.update({k: _score(v) if isinstance(v, float) else v for k, v in scores.items() if k not in out})
    typer.echo(json.dumps(out, allow_nan=False))


def _score(value) -> float | None:
    """A score rounded to 0.001; None (JSON null) where it is undefined (e.g. jitter_mm of a 2-frame capture:
    it needs three frames), never NaN, which is not JSON."""
    value = float(value)
    return round(value, 3) if math.isfinite(value) else None


# --- the model ------------------------------------------------------------------------------------------

def _parse_shape(text: str):
    """``bmi=31,muscularity=0.3,height_m=1.62,arm_length_m=0.55[,sex=female]`` -> ArmShapeParams (sex: male
    when not given, the original training set's)."""
    from bodystudio.muscle.model import SHAPE_NAMES, ArmShapeParams, parse_sex

    names = (*SHAPE_NAMES, "sex")
    values = {}
    for part in text.split(","):
        name, eq, value = part.partition("=")
        name = name.strip()
        if not eq or name not in names:
            raise InputError(f"--shape {text!r}: names are {', '.join(names)} (sex optional: male | female)")
        if name in values:  # 'bmi=20,bmi=31' captured with BMI 31, the 20 dropped without a word (rel6b)
            raise InputError(f"--shape {text!r}: {name} is given twice; give each once")
        if name == "sex":
            values[name] = parse_sex(value, f"--shape {text!r}")
            continue
        try:
            values[name] = float(value)
        except ValueError:
            raise InputError(f"--shape {text!r}: write NAME=VALUE pairs for {', '.join(names)}") from None
    shape = ArmShapeParams.from_dict(values, "--shape")
    for name, lo, hi in (("bmi", 10, 60), ("muscularity", 0, 1), ("height_m", 1.0, 2.3), ("arm_length_m", 0.3, 1.0)):
        check_range(f"--shape {name}", getattr(shape, name), lo, hi)
    return shape


@model_app.command("build")
def model_build(
    out: Path = typer.Option(..., "--out", help="new model file (.npz)"),
    resolution: str = typer.Option("6k", "--resolution", help="arm template: 6k | 2k | full"),
    side: str = typer.Option("left", "--side", help="left | right"),
    subjects: int = typer.Option(10, "--subjects", help="training men (BMI 20-28, as the paper's)"),
    women: int = typer.Option(5, "--women", help="training women besides the men (the population's women's BMI, "
                              "17.5-23.5): a model that knows a woman's arm, given her sex with --shape (the "
                              "default since mus11x; 0: men only, the paper's and the benchmark's; docs/muscle.md, "
                              "\"Women in the capture\")"),
    shapes: int = typer.Option(3, "--shapes", help="base-pose meshes per subject"),
    poses: int = typer.Option(24, "--poses", help="posed meshes per subject"),
    regularization: float = typer.Option(1.0, "--regularization", help="Tikhonov weight of Eq. 6-10"),
    seed: int = typer.Option(0, "--seed", help="training subjects and poses"),
    sex_slopes: bool = typer.Option(False, "--sex-slopes", help="the women's own slopes: the shape term's interaction "
                                    "(1 - sex) x z(BMI, muscularity, height, arm length), learned from the training "
                                    "women (needs --women > 0; off: the slopes shared by both sexes; docs/muscle.md, "
                                    "\"Women's own slopes\")"),
) -> None:
    """Learn the statistical arm model (§6.1) from the synthetic high-fidelity training dataset."""
    from bodystudio.muscle.model import learn_arm_model, save_arm_model
    from bodystudio.muscle.synthetic import training_dataset

    check_choice("--resolution", resolution, RESOLUTIONS)
    check_choice("--side", side, SIDES)
    check_range("--subjects", subjects, 2, 100)
    check_range("--women", women, 0, 100)
    if subjects + women > 100:
        raise InputError(f"--subjects {subjects} --women {women}: {subjects + women} training subjects; at most 100 "
                         "in all")
    check_range("--shapes", shapes, 1, 10)
    check_range("--poses", poses, 1, 500)
    check_range("--regularization", regularization, 0.0, 1e6)
    check_range("--seed", seed, 0, 2**31 - 1)
    if sex_slopes and women == 0:
        raise InputError("--sex-slopes: the women's own slopes are learned from the training women; give --women > 0 "
                         "(or leave --sex-slopes out)")
    if sex_slopes and regularization == 0:
        raise InputError("--sex-slopes --regularization 0: the women's own slopes need a regularization > 0")
    if out.suffix.lower() != ".npz":
        raise InputError(f"--out {out}: an arm model is a .npz file")
    from bodystudio.muscle.export import check_new_output

    check_new_output(out, "model file")
    samples, _ = training_dataset(resolution, subjects, shapes, poses, seed, side, n_women=women)
    model = learn_arm_model(samples, _arm_template(resolution, side), regularization, sex_slopes=sex_slopes)
    save_arm_model(out, model)
    slopes = ", the women's own slopes" if sex_slopes else ""
    typer.echo(f"wrote {out}: {len(model.subjects)} subjects ({subjects} men, {women} women{slopes}), "
               f"{len(samples)} meshes, template {model.template_key}")


@model_app.command("extend")
def model_extend(
    model_path: Path = typer.Argument(..., metavar="MODEL", help="arm model (.npz)"),
    captures: list[Path] = typer.Argument(..., metavar="CAPTURES...", help="arm capture folders to add"),
    out: Path = typer.Option(..., "--out", help="new model file (.npz)"),
    shape: list[str] | None = typer.Option(None, "--shape", help="shape of a captured subject: "
                                           "bmi=..,muscularity=..,height_m=..,arm_length_m=..[,sex=male|female]; "
                                           "once per capture, in their order (default: the session's "
                                           "measured subject, else the capture's fitted shape)"),
    stride: int = typer.Option(5, "--stride", help="use every N-th captured frame"),
    centre: str = typer.Option("sex", "--centre", help="where each captured rest mesh is centred: sex (a "
                               "woman's fitted shoulder, a man's regressed one) | fitted | regressed (the "
                               "shoulder the capture's own model regresses, recorded in the capture; MODEL "
                               "for captures made before it was recorded); only with --captured-rest mesh (body "
                               "rows put the shoulder where the body model does); docs/muscle.md"),
    captured_rest: str = typer.Option("body", "--captured-rest", help="each captured subject's shape row: body (its "
                                      "rest mesh's nearest arm of the body model's shape space: the shoulder and "
                                      "the vertices' layout along the skin, which a depth capture does not see, "
                                      "from the body model) | mesh (the captured rest mesh as it is); "
                                      "docs/muscle.md"),
    shape_form: str = typer.Option("body", "--shape-form", help="the extended model's shape term: body (the rows' "
                                   "body-space parameters regressed on the shape numbers, the weight macro solved from "
                                   "the BMI, the rest mesh made by the body model, a linear term for what it "
                                   "leaves; a linear MODEL's rows are refitted so) | linear (the paper's Eq. 6-7: "
                                   "one linear map from the shape numbers to the vertices); docs/muscle.md"),
    subject_rows: str = typer.Option("own", "--subject-rows", help="how much each added subject weighs in the shape "
                                     "regression: own (its one row: a third of a training subject of the benchmark's "
                                     "model) | training (as many rows as one of MODEL's training subjects); "
                                     "docs/muscle.md"),
) -> None:
    """Dataset extension (issue 11 §4): add captured subjects to a model and re-learn it.

    Captures made with ``muscle capture --for-extension`` (the subject's skeleton fitted) extend it most.
    """
    from bodystudio.muscle.capture import load_arm_capture
    from bodystudio.muscle.export import check_new_output
    from bodystudio.muscle.model import capture_samples, extend_arm_model, load_arm_model, save_arm_model

    check_range("--stride", stride, 1, 1000)
    check_choice("--centre", centre, CENTRES)
    check_choice("--captured-rest", captured_rest, CAPTURED_RESTS)
    check_choice("--shape-form", shape_form, SHAPE_FORMS)
    check_choice("--subject-rows", subject_rows, SUBJECT_ROWS)
    if out.suffix.lower() != ".npz":
        raise InputError(f"--out {out}: an arm model is a .npz file")
    shapes = [_parse_shape(text) for text in shape or ()]
    if shapes and len(shapes) != len(captures):
        raise InputError(f"--shape: {len(shapes)} given for {len(captures)} captures; give one --shape per "
                         "capture, in the captures' order (repeat the values for captures of one subject)")
    check_new_output(out, "model file")
    model = load_arm_model(model_path)
    loaded, seen = [], {}
    for folder in captures:  # every capture checked before anything is printed or learnt
        if not folder.is_dir():
            raise InputError(f"{folder}: no such arm capture folder")
        capture = load_arm_capture(folder)
        if capture.template_key != model.template_key:
            raise InputError(f"{folder}: captured on arm template {capture.template_key}, the model's is "
                             f"{model.template_key}; capture with the model's --resolution and --side")
        if capture.mode == "nicp" or capture.poses[0] is None:
            raise InputError(f"{folder}: captured with --no-model (no joint angles); capture with --model")
        recording = _recording_key(capture)
        if recording in seen:
            raise InputError(f"{folder}: a capture of the same recording as {seen[recording]} (same depth frames); "
                             "each subject is added once: drop one of them")
        seen[recording] = folder
        loaded.append(capture)
    samples = []
    for k, (folder, capture) in enumerate(zip(captures, loaded, strict=True)):
        subject_shape, where = (shapes[k], "--shape") if shapes else _measured_subject(capture)
        if subject_shape is None:
            subject_shape = capture.shape
        typer.echo(f"{folder}: shape from {where}", err=True)
        if not _has_fitted_skeleton(capture, model):
            typer.echo(f"{folder}: captured without --for-extension (no fitted skeleton, so --centre changes "
                       "nothing); captures made with it extend the model more (docs/muscle.md)", err=True)
        samples += capture_samples(capture, f"capture_{folder.resolve().name}", subject_shape, stride,
                                   model=model, centre=centre)
    extended = extend_arm_model(model, samples, captured_rest=captured_rest, shape_form=shape_form,
                                subject_rows=subject_rows)
    save_arm_model(out, extended)
    typer.echo(f"wrote {out}: {len(extended.subjects)} subjects ({len(captures)} added from captures), "
               f"{shape_form} shape term")


def _has_fitted_skeleton(capture, model) -> bool:
    """Whether the capture's rest joints are a fitted skeleton (``--for-extension``), not the model's regression."""
    import numpy as np

    from bodystudio.muscle.model import ArmShapeParams, model_joints

    if capture.joints is None or not isinstance(capture.shape, ArmShapeParams):
        return False
    regressed = capture.regressed_joints  # the capture's own model's (another model regresses other joints)
    if regressed is None:
        regressed = model_joints(model, capture.shape)
    return not np.allclose(capture.joints, regressed, rtol=0, atol=1e-7)


def _recording_key(capture) -> str:
    """What a capture was made from: its depth frames' fingerprint and frame ids (two captures of one recording,
    a copied folder included, would add one subject twice), else a hash of its meshes."""
    import hashlib

    import numpy as np

    if capture.source_fingerprint is not None:
        return f"{capture.source_fingerprint}:{list(capture.frame_ids)}"
    return hashlib.sha256(np.ascontiguousarray(capture.vertices, np.float64).tobytes()).hexdigest()


def _measured_subject(capture):
    """The measured shape of a capture's subject from its session's ground truth (a synthetic session records
    it) and where it came from; (None, why not) when the session is gone, is another recording than the one
    captured, or records no subject: the capture's fitted shape is used then."""
    from bodystudio.capture.session import open_session
    from bodystudio.errors import BodyStudioError
    from bodystudio.muscle.model import ArmShapeParams

    if capture.session_path is None:
        return None, "the capture's fitted shape (it names no session)"
    try:
        session = open_session(capture.session_path)
    except BodyStudioError:
        return None, f"the capture's fitted shape ({capture.session_path} cannot be opened)"
    if capture.is_from(session) is False:
        return None, f"the capture's fitted shape ({capture.session_path} is now another recording)"
    subject = (session.gt_subject or {}).get("arm", {}).get("subject")
    if not subject:
        return None, f"the capture's fitted shape ({capture.session_path} records no measured subject)"
    return ArmShapeParams.from_dict(subject), f"the measured subject of {capture.session_path}"


@model_app.command("info")
def model_info(model_path: Path = typer.Argument(..., metavar="MODEL", help="arm model (.npz)")) -> None:
    """Print the model's template, version, subjects and the range of their shape parameters (JSON)."""
    from bodystudio.muscle.model import load_arm_model

    model = load_arm_model(model_path)
    info = {"template_key": model.template_key, "version": model.version, "n_vertices": model.n_vertices,
            "regularization": model.regularization, "shape_form": model.shape_form, "sex_slopes": model.sex_slopes,
            **({"body_weight": model.body_weight} if model.shape_form == "body" else {}),
            "n_subjects": len(model.subjects),
            "shape_range": model.shape_range() if model.subjects else {}, "subjects": model.subjects}
    typer.echo(json.dumps(info, indent=2))
