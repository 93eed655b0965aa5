"""The demo: the main job on the built-in synthetic studio, ending in an HTML report (``bodystudio demo``).

Steps: build and measure bodies (default female, default male, population subjects) -> synthesise a
short session (subject, cameras, Kinect) -> calibrate -> reconstruct -> rig a synthetic scan -> capture a
Kinect arm sequence with the arm-muscle pipeline -> the virtual mirror on a short Kinect session (synthesise,
init, run, eval) -> garment replacement on a short single-camera clip (synthesise, fit, render, eval) -> report.
Every stage runs through its Python API (no subprocesses) and writes under the output folder. A stage
that cannot be imported or raises is a *failure* (every stage exists in this checkout); only stages
the user leaves out with ``skip`` are "skipped". A stage that needs another (reconstruct needs the
session) fails when that one failed and is skipped when that one was skipped.

Timings: numba compiles (or loads from its cache) the hot loops on the first call in a process, so a
first frame costs seconds where later frames cost milliseconds. Stages report the first frame apart
from the per-frame time of the frames after it (``first_frame_ms`` / ``ms_per_frame`` in demo.json).
"""

from __future__ import annotations

import logging
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bodystudio.errors import BodyStudioError, InputError

log = logging.getLogger(__name__)

N_POPULATION = 3
PREVIEW_RESOLUTION = "2k"  # bodies in the report's 3D views: keeps the page a few MB
POPULATION_SEED = 2026


@dataclass
class DemoContext:
    out: Path
    cameras: int
    frames: int
    resolution: tuple[int, int]
    console: object
    progress: object
    bodies: dict = field(default_factory=dict)  # name -> BodyModel (full resolution: exported, measured)
    previews: dict = field(default_factory=dict)  # name -> the same body on the 2k template (3D views)
    session: object = None
    scenes: list = field(default_factory=list)  # (caption, plotter) for the report
    stages: list = field(default_factory=list)  # rows for demo.json


class StageSkipped(Exception):
    """The stage was left out by the user (``skip``) or needs a stage that was."""


class StageDependencyFailed(BodyStudioError):
    """The stage needs another stage's output, and that stage failed."""


class DemoStageError(BodyStudioError):
    """A demo stage failed; the report was still written."""


# ---------------------------------------------------------------------------------------------------
# stages

def stage_bodies(ctx: DemoContext) -> str:
    """Default female and male bodies and a few population subjects: export, measure, screenshot."""
    from bodystudio.body import Phenotype, build_body
    from bodystudio.body.measure import measure_body
    from bodystudio.body.population import sample_population
    from bodystudio.fileio import write_json
    from bodystudio.geometry.mesh import save_mesh

    specs = [("female", Phenotype(gender=0.0), {}), ("male", Phenotype(gender=1.0), {})]
    specs += [(f"subject_{k:02d}", p, local)
              for k, (p, local) in enumerate(sample_population(N_POPULATION, seed=POPULATION_SEED))]
    folder = ctx.out / "bodies"
    task = ctx.progress.add_task("bodies", total=len(specs))
    measurements = {}
    for name, phenotype, local in specs:
        body = build_body(phenotype, local)
        ctx.bodies[name] = body
        ctx.previews[name] = build_body(phenotype, local, resolution=PREVIEW_RESOLUTION)
        save_mesh(folder / f"{name}.ply", body.mesh)
        m = measure_body(body)
        measurements[name] = {"gender": round(phenotype.gender, 3), **{k: round(float(v), 4) for k, v in m.items()}}
        ctx.progress.advance(task)
    write_json(folder / "measurements.json", {"bodies": measurements})
    _print_measurements(ctx.console, measurements)
    _body_screenshots(ctx)
    return f"{len(specs)} bodies exported to {folder} and measured"


def _print_measurements(console, measurements: dict) -> None:
    from rich.table import Table

    columns = [c for c in next(iter(measurements.values())) if c != "muscularity"]
    table = Table(title="body measurements (lengths in m, mass in kg)")
    table.add_column("body", no_wrap=True)
    for c in columns:
        table.add_column(c.removesuffix("_m").removesuffix("_kg").replace("_length", ""), justify="right")
    for name, m in measurements.items():
        table.add_row(name, *(f"{m[c]:.3f}" if isinstance(m[c], float) else str(m[c]) for c in columns))
    console.print(table)


def _lineup_plotter(bodies: dict):
    """All bodies side by side (1 m apart along x), facing the viewer."""
    from bodystudio.geometry.mesh import Mesh
    from bodystudio.viewer import scene as sc

    plotter = sc.make_plotter()
    offsets = (np.arange(len(bodies)) - (len(bodies) - 1) / 2) * 0.9
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for dx, (name, body) in zip(offsets, bodies.items(), strict=True):
        V = body.vertices + [dx, 0.0, 0.0]
        sc.add_mesh(plotter, Mesh(V, body.faces), name=f"body-{name}")
        lo, hi = np.minimum(lo, V.min(0)), np.maximum(hi, V.max(0))
    sc.add_floor(plotter, (lo + hi) / 2, size=float(hi[0] - lo[0]) + 1.0)
    sc.add_title(plotter, "  |  ".join(bodies))
    sc.frame_front(plotter, np.stack([lo, hi]), direction=(0.0, 0.1, 1.0))
    return plotter


def _body_screenshots(ctx: DemoContext) -> None:
    from bodystudio.viewer.avatar import avatar_from_body
    from bodystudio.viewer.scene import save_screenshot
    from bodystudio.viewer.views import scene_for_avatar

    shots = ctx.out / "screenshots"
    lineup = _lineup_plotter(ctx.previews)
    save_screenshot(lineup, shots / "bodies.png")
    ctx.scenes.append(("bodies", lineup))
    female = ctx.previews["female"]
    bone = "upperarm_l" if "upperarm_l" in female.skeleton.bone_names else female.skeleton.bone_names[1]
    rigged = scene_for_avatar(avatar_from_body(female), bone=bone, title=f"female: skin weights of {bone}")
    save_screenshot(rigged, shots / "female_weights.png")
    rigged.close()
    skeleton = scene_for_avatar(avatar_from_body(ctx.previews["male"]), title="male: skeleton")
    save_screenshot(skeleton, shots / "male_skeleton.png")
    ctx.scenes.append(("male: skeleton", skeleton))


def stage_session(ctx: DemoContext) -> str:
    """A short synthetic studio session: subject, ring of cameras, Kinect."""
    from bodystudio.capture.synth import synth_session

    path = ctx.out / "session"
    if path.exists() and any(path.iterdir()):
        import shutil

        shutil.rmtree(path)  # the demo owns its output folder; a rerun starts fresh
    ctx.session = synth_session(path, n_cameras=ctx.cameras, n_frames=ctx.frames, motion="walk", kinect="v2",
                                resolution=ctx.resolution, n_background=2, progress=False)
    return f"{ctx.cameras} cameras x {ctx.frames} frames with Kinect in {path}"


CALIBRATION_SIZE = (960, 720)  # at 640x480 the floor board is often missed and the adjustment is ill-conditioned
CALIBRATION_POSES = 14  # 4 cameras x 16 poses at 960x720 measured 6.5 mm centre error, 0.5 deg


def stage_calibrate(ctx: DemoContext) -> str:
    """Calibrate a synthetic ChArUco capture of the studio ring and score it against the true cameras."""
    from bodystudio.calib.board import load_board_json
    from bodystudio.calib.calibrate import calibrate_cameras
    from bodystudio.calib.evaluate import evaluate_calibration
    from bodystudio.calib.observations import detect_capture
    from bodystudio.calib.synthetic import write_synthetic_calibration
    from bodystudio.fileio import write_json
    from bodystudio.geometry.camera import load_cameras_json, ring_rig, save_cameras_json

    folder = ctx.out / "calibration"
    capture = folder / "capture"
    w, h = CALIBRATION_SIZE
    write_synthetic_calibration(capture, n_cameras=ctx.cameras, n_poses=CALIBRATION_POSES, seed=0, width=w, height=h,
                                rig=ring_rig(ctx.cameras, width=w, height=h))
    spec = load_board_json(capture / "board.json")
    obs, _quality = detect_capture(capture, spec)
    result = calibrate_cameras(obs, spec)
    report = result.report()
    residuals = np.linalg.norm(result.residuals_px[result.inliers], axis=1)
    report["residuals_px"] = [round(float(r), 4) for r in residuals]
    scores = evaluate_calibration(result.rig, load_cameras_json(capture / "gt" / "cameras.json"), report)
    save_cameras_json(folder / "cameras.json", result.rig)
    write_json(folder / "report.json", report)
    write_json(folder / "eval.json", scores)
    overall = scores.get("overall", {})
    # The demo's capture is deliberately small: say what the calibration's own uncertainty verdict is.
    return (f"{ctx.cameras} cameras from {CALIBRATION_POSES} board poses: reprojection RMS "
            f"{result.rms_px:.3f} px, camera centre error {overall.get('center_err_mm', float('nan')):.0f} mm, "
            f"uncertainty verdict: {report['uncertainty']['verdict']}")


def stage_reconstruct(ctx: DemoContext) -> str:
    """Rapid Skin over the session: template deformed to silhouettes and Kinect depth, frame by frame."""
    import json

    from bodystudio.fileio import write_json
    from bodystudio.reconstruct.sequence import reconstruct_session

    summary = reconstruct_session(ctx.session.path, solver="gs", template="2k", joints="tracker",
                                  constraints=("silhouette", "depth"), progress=False)
    frames = json.loads((ctx.session.path / "reconstruct" / "frames.json").read_text())["frames"]
    timing = split_first_frame([r["ms_per_frame"] for r in frames])
    summary.update(timing)  # the mean over all frames would show numba's compilation as a per-frame cost
    write_json(ctx.out / "reconstruct_summary.json", summary)
    err = f", visible median error {summary['median_mm']:.1f} mm" if "median_mm" in summary else ""
    return f"{summary['frames']} frames, {timing_text(timing)}{err}"


def split_first_frame(ms: list[float]) -> dict:
    """Per-frame time without the first frame, which carries numba's compilation (or cache load)."""
    out = {"first_frame_ms": round(float(ms[0]), 1)}
    out["ms_per_frame"] = round(float(np.mean(ms[1:])), 1) if len(ms) > 1 else None
    return out


def timing_text(timing: dict) -> str:
    """``first frame X ms (numba compilation), then Y ms per frame`` for the stage summary."""
    first = f"first frame {timing['first_frame_ms']:.0f} ms (includes numba compilation)"
    if timing["ms_per_frame"] is None:
        return first + "; one frame only, so no warm per-frame time"
    return f"{timing['ms_per_frame']:.0f} ms per frame after the {first}"


RIG_SUBJECT = 3  # population subject of the synthetic scan
RIG_SCAN_VERTICES = 20_000
RIG_TEMPLATE = "6k"


def stage_rig(ctx: DemoContext) -> str:
    """Rig a synthetic scan: fit the body model, transfer skeleton and skin weights, export glTF, score."""
    from bodystudio.fileio import write_json
    from bodystudio.register.scan import load_scan
    from bodystudio.register.synthetic import save_synthetic_scan, synthetic_scan
    from bodystudio.rig.evaluate import evaluate_rig
    from bodystudio.rig.export import rig_layout, write_rig
    from bodystudio.rig.pipeline import load_template_model, rig_scan
    from bodystudio.runfolder import RunWriter
    from bodystudio.viewer.avatar import load_avatar
    from bodystudio.viewer.scene import save_screenshot
    from bodystudio.viewer.views import scene_for_avatar

    folder = ctx.out / "rig"
    scan, gt = synthetic_scan(RIG_SUBJECT, "a", n_vertices=RIG_SCAN_VERTICES, noise_mm=1.0, holes=True)
    save_synthetic_scan(folder / "scan.ply", scan, gt)
    mesh, scan_report = load_scan(folder / "scan.ply")
    result = rig_scan(mesh, load_template_model(RIG_TEMPLATE))
    rigged = result.avatar
    rigged.metadata.update(scan=scan_report.as_dict(), template=RIG_TEMPLATE, stage_seconds=result.seconds)
    glb = folder / "avatar.glb"
    # The same committed run as `bodystudio rig`: avatar.glb and avatar.rig.json (its manifest, with checksums).
    with RunWriter(rig_layout(glb), "bodystudio demo", {"scan": str(folder / "scan.ply"),
                                                         "template": RIG_TEMPLATE}) as writer:
        write_rig(writer, glb, rigged)
    scores = evaluate_rig(rigged, gt, scan_report.to_canonical)
    scores["fit_history_mm"] = [round(float(h), 3) for h in result.fit.history]  # convergence plot
    scores["stage_seconds"] = result.seconds
    write_json(folder / "eval.json", scores)
    avatar = load_avatar(glb)  # what a user's glTF viewer sees
    bone = "upperarm_l" if "upperarm_l" in avatar.bone_names else avatar.bone_names[1]
    view = scene_for_avatar(avatar, bone=bone, title=f"rigged scan: skin weights of {bone}")
    save_screenshot(view, ctx.out / "screenshots" / "avatar_weights.png")
    view.close()
    view = scene_for_avatar(avatar, title="rigged scan: transferred skeleton")
    save_screenshot(view, ctx.out / "screenshots" / "avatar_skeleton.png")
    ctx.scenes.append(("rigged scan (avatar.glb): skeleton", view))
    return (f"{scan.n_vertices}-vertex scan rigged to {glb}: fit {result.fit.fit_err_mm_median:.1f} mm median, "
            f"joint error {scores.get('joint_err_mm_mean', float('nan')):.1f} mm mean")


# A short arm sequence on the 2k template and a small model keep the muscle stage to ~half a minute;
# `bodystudio muscle model build` and benchmarks/bench_muscle.py run the full-size versions.
MUSCLE_SUBJECT = 7  # arm subject of the demo sequence (population seed; not a training subject)
MUSCLE_FRAMES = 10
MUSCLE_RESOLUTION = "2k"
MUSCLE_TRAINING = {"n_subjects": 4, "n_shapes": 2, "n_poses": 8}
MUSCLE_POPULATION = 16  # bodies behind the model's length/joint regressions (the CLI's default is 40)


def stage_muscle(ctx: DemoContext) -> str:
    """Arm-muscle capture: a Kinect arm sequence with bulging muscles, a small arm model, the full pipeline.

    The subject's shape parameters are given to the capture as measured (the paper's Table 1).
    """
    import shutil

    from bodystudio.body import build_body
    from bodystudio.fileio import write_json
    from bodystudio.muscle.arm import arm_template
    from bodystudio.muscle.capture import CaptureOptions, capture_arm_sequence, write_arm_capture
    from bodystudio.muscle.evaluate import evaluate_arm_capture
    from bodystudio.muscle.model import ArmShapeParams, learn_arm_model, save_arm_model
    from bodystudio.muscle.synthetic import sample_arm_subject, subject_body, synth_arm_session, training_dataset
    from bodystudio.viewer.arm import arm_payload, open_arm_view, scene_for_arm_sequence
    from bodystudio.viewer.scene import make_plotter, save_screenshot

    folder = ctx.out / "muscle"
    if folder.exists():
        shutil.rmtree(folder)  # the demo owns its output folder; a rerun starts fresh
    subject = sample_arm_subject(MUSCLE_SUBJECT)
    session = synth_arm_session(folder / "session", subject=subject, motion="elbow_flex", n_frames=MUSCLE_FRAMES,
                                kinect="v2", distance_m=1.0, resolution=MUSCLE_RESOLUTION)
    template = arm_template(build_body(resolution=MUSCLE_RESOLUTION), "left")
    samples, _ = training_dataset(MUSCLE_RESOLUTION, **MUSCLE_TRAINING)
    model = learn_arm_model(samples, template, population_size=MUSCLE_POPULATION)
    save_arm_model(folder / "arm_model.npz", model)
    measured = ArmShapeParams(subject.bmi, subject.muscularity, subject.height_m, subject.arm_length_m,
                              sex=subject.gender)
    capture = capture_arm_sequence(session, model, template, CaptureOptions(mode="full"), known_shape=measured)
    write_arm_capture(folder / "capture", capture)
    truth_template = arm_template(subject_body(subject, MUSCLE_RESOLUTION), "left")
    scores = evaluate_arm_capture(capture, session, truth_template)
    view = open_arm_view(folder / "capture")
    per_frame = [{"frame": f, "median_err_mm": round(float(np.median(view.errors_mm(k)[truth_template.arm_mask])), 3)}
                 for k, f in enumerate(view.frame_ids)]
    write_json(folder / "eval.json", {**scores, "per_frame": per_frame, "subject": subject.summary(),
                                      "model_subjects": len(model.subjects)})
    k_last = len(view.frame_ids) - 1
    plotter = scene_for_arm_sequence(view, view.frame_ids[k_last], make_plotter())
    save_screenshot(plotter, ctx.out / "screenshots" / "arm_capture.png")
    payload = arm_payload(view, plotter, start=view.frame_ids[k_last])
    plotter.close()
    ctx.scenes.append(("arm-muscle capture: arm coloured by error vs truth, Kinect depth points "
                       "(slider: frame)", payload))
    return (f"{capture.n_frames} frames of elbow flexion, subject BMI {subject.bmi:.1f}: median "
            f"{scores['median_mm']:.1f} mm, p90 {scores['p90_mm']:.1f} mm, back {scores['back_median_mm']:.1f} mm, "
            f"bulge error {scores['bulge_err_mm']:.1f} mm, {scores['ms_per_frame']:.0f} ms per frame; "
            f"{folder / 'capture' / 'arm.glb'}")


# A short mirror session keeps the mirror stage to seconds: the actor stands in place from the first frame
# after the 10 empty-room frames; init fits the frames it has, the run reshapes them all.
MIRROR_SUBJECT = 3
MIRROR_FRAMES = 22  # 10 empty-room frames (the background) + 12 with the actor
MIRROR_EDITS = {"taller": 0.1, "heavier": 10.0}
MIRROR_KINECT = "v2"


def stage_mirror(ctx: DemoContext) -> str:
    """The virtual mirror (issue 12): synthesise a short Kinect session with the truth of the edits, fit the
    source body (§4), reshape every frame (§5) and score the run against the truth (``eval mirror``)."""
    import shutil

    from bodystudio.body.statistical import load_statistical_model
    from bodystudio.fileio import write_json
    from bodystudio.mirror.evaluate import evaluate_mirror
    from bodystudio.mirror.init import initialise_source_body, save_source_body
    from bodystudio.mirror.run import run_mirror
    from bodystudio.mirror.synthetic import N_BACKGROUND_FRAMES, synth_mirror_session
    from bodystudio.viewer.mirror import open_mirror_view, scene_for_mirror
    from bodystudio.viewer.scene import make_plotter, save_screenshot
    from bodystudio.viewer.webgl import scene_payload

    folder = ctx.out / "mirror_session"
    if folder.exists():
        shutil.rmtree(folder)  # the demo owns its output folder; a rerun starts fresh
    task = ctx.progress.add_task("mirror", total=4)
    session = synth_mirror_session(folder, MIRROR_SUBJECT, n_frames=MIRROR_FRAMES, edits=MIRROR_EDITS,
                                   version=MIRROR_KINECT, motion="arms_raise", walk_in=False)
    ctx.progress.advance(task)
    model = load_statistical_model("6k", progress=False)
    # every frame with the actor (the CLI's default, every 3rd of 90, would leave 4 of this short session)
    source = initialise_source_body(session, model, frames=range(N_BACKGROUND_FRAMES, MIRROR_FRAMES))
    save_source_body(folder / "mirror" / "source_body.npz", source)
    ctx.progress.advance(task)
    run = run_mirror(session, MIRROR_EDITS, ctx.out / "mirror.mp4", progress=False, ramp_frames=0)
    ctx.progress.advance(task)
    scores = evaluate_mirror(session)
    write_json(folder / "mirror" / "eval.json", scores)
    ctx.progress.advance(task)
    view = open_mirror_view(folder)
    plotter = scene_for_mirror(view, None, make_plotter())
    save_screenshot(plotter, ctx.out / "screenshots" / "mirror.png")
    ctx.scenes.append(("mirror: input | mirror output | truth behind the fitted source body", scene_payload(plotter)))
    plotter.close()
    summary = run.get("summary", {}) if isinstance(run, dict) else {}
    psnr = "identical" if scores.get("psnr_person_identical") else f"{scores['psnr_person']:.1f} dB"
    return (f"{MIRROR_FRAMES - N_BACKGROUND_FRAMES} frames, taller +{MIRROR_EDITS['taller']:g} m, heavier "
            f"+{MIRROR_EDITS['heavier']:g} kg: init stature {scores['init_stature_err_mm']:.1f} mm / mass "
            f"{scores['init_mass_err_kg']:.2f} kg off, fg_iou {scores['fg_iou']:.3f} (SDK mask "
            f"{scores['fg_iou_raw']:.3f}), warp_iou {scores['warp_iou']:.3f} (unwarped "
            f"{scores['warp_iou_unwarped']:.3f}), PSNR {psnr}, {scores.get('ms_per_frame_total') or float('nan'):.0f} "
            f"ms per frame (image steps); {summary.get('frames', '?')} frames to {ctx.out / 'mirror.mp4'}")


# A short, small clip keeps the garment stage to about a minute and a half of CPU (the shape fit's Nelder-Mead
# dominates); `bodystudio garment fit` and benchmarks/bench_garment.py run the full-size versions.
GARMENT_SUBJECT = 21
GARMENT_FRAMES = 8
GARMENT_RESOLUTION = (240, 320)  # (width, height) as synth_garment_session takes it: a portrait camera
GARMENT_TEXTURE = 128


def stage_garment(ctx: DemoContext) -> str:
    """Garment replacement (issue 13): a single-camera clip of an actor in their own clothes, the monocular fit
    (§4-5: shape from the silhouettes and the given stature, pose per frame, albedo and lighting), the session's
    target garment rendered with the estimated lights and composited (§6-7), scored against the true render of
    the actor wearing it (``eval garment``). The report shows input | composite | truth."""
    import shutil

    from bodystudio.fileio import write_json
    from bodystudio.garment.composite import render_garment_video
    from bodystudio.garment.evaluate import evaluate_garment
    from bodystudio.garment.fit import fit_garment_video
    from bodystudio.garment.synthetic import synth_garment_session

    for name in ("garment_session", "garment_fit"):
        if (ctx.out / name).exists():
            shutil.rmtree(ctx.out / name)  # the demo owns its output folder; a rerun starts fresh
    task = ctx.progress.add_task("garment", total=4)
    session = synth_garment_session(ctx.out / "garment_session", subject_seed=GARMENT_SUBJECT,
                                    n_frames=GARMENT_FRAMES, resolution=GARMENT_RESOLUTION, template="2k",
                                    texture_size=GARMENT_TEXTURE, seed=1)
    ctx.progress.advance(task)
    stature = float(session.gt_subject["stature_m"])  # the user-given stature of §4
    fit_dir = ctx.out / "garment_fit"
    fit_garment_video(session.path, stature, fit_dir, template="2k")
    ctx.progress.advance(task)
    target = session.gt_garment["target"]
    render_garment_video(fit_dir, target["name"], target["pattern"], ctx.out / "garment.mp4", seed=target["seed"],
                         texture_size=GARMENT_TEXTURE)
    ctx.progress.advance(task)
    scores = evaluate_garment(fit_dir)
    write_json(fit_dir / "eval.json", scores)
    ctx.progress.advance(task)
    return (f"{GARMENT_FRAMES} frames {GARMENT_RESOLUTION[0]}x{GARMENT_RESOLUTION[1]}, {target['name']} "
            f"({target['pattern']}): stature {scores['stature_err_mm']:.1f} mm off, dominant light "
            f"{scores['light_dir_err_deg']:.1f} deg off, fit IoU {scores['silhouette_iou']:.3f}, garment_iou "
            f"{scores['garment_iou']:.3f}, PSNR {scores['psnr_person']:.1f} dB; video {ctx.out / 'garment.mp4'}")


def _session_views(ctx: DemoContext) -> None:
    """Screenshot and 3D view of the session (with the reconstruction's error map when it ran)."""
    from bodystudio.viewer.scene import save_screenshot
    from bodystudio.viewer.views import scene_for_session, session_payload

    frame = ctx.session.frame_ids[-1]
    plotter = scene_for_session(ctx.session, frame)
    save_screenshot(plotter, ctx.out / "screenshots" / "session.png")
    payload = session_payload(ctx.session, plotter, start=frame)  # every frame, with a slider
    plotter.close()
    ctx.scenes.insert(0, ("session: cameras with images, Kinect cloud, ground truth and reconstruction "
                          "error (slider: frame)", payload))


STAGES: list[tuple[str, Callable[[DemoContext], str]]] = [
    ("bodies", stage_bodies),
    ("session", stage_session),
    ("calibrate", stage_calibrate),
    ("reconstruct", stage_reconstruct),
    ("rig", stage_rig),
    ("muscle", stage_muscle),
    ("mirror", stage_mirror),
    ("garment", stage_garment),
]

#: stage -> the stage whose output it needs
STAGE_NEEDS: dict[str, str] = {"reconstruct": "session"}


def run_stage(ctx: DemoContext, name: str, fn: Callable[[DemoContext], str], skip: tuple[str, ...]) -> dict:
    """Run one stage; returns its row (stage, status done/failed/skipped, seconds, summary).

    An import error or any exception is a failure with its message; only ``skip`` (or a needed stage
    that was skipped) makes a stage "skipped".
    """
    t0 = time.perf_counter()
    try:
        if name in skip:
            raise StageSkipped("skipped (--skip)")
        need = STAGE_NEEDS.get(name)
        if need is not None:
            done = {r["stage"]: r["status"] for r in ctx.stages}.get(need)
            if done == "skipped":
                raise StageSkipped(f"needs the {need} stage, which was skipped")
            if done != "done":
                raise StageDependencyFailed(f"needs the {need} stage, which failed")
        summary = fn(ctx)
        status = "done"
    except StageSkipped as exc:
        status, summary = "skipped", str(exc)
    except BodyStudioError as exc:
        status, summary = "failed", str(exc)
    except Exception as exc:  # an import error or a stage bug: a failure, and the other stages still run
        status, summary = "failed", f"{type(exc).__name__}: {exc}"
        log.debug("stage %s failed:\n%s", name, traceback.format_exc())
    return {"stage": name, "status": status, "seconds": round(time.perf_counter() - t0, 2), "summary": summary}


def run_demo(out: Path, cameras: int = 4, frames: int = 3, resolution: tuple[int, int] = (320, 240),
             with_3d: bool = True, console=None, skip: tuple[str, ...] = ()) -> tuple[Path, list[dict]]:
    """Run every stage (except ``skip``) into ``out`` and write ``out/report.html``.

    Returns the report's path and one row per stage (stage, status, seconds, summary); a failed stage
    does not stop the others (the report shows what ran), the caller decides the exit status.
    """
    import sys

    from rich.console import Console
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    from bodystudio.fileio import write_json
    from bodystudio.viewer.report import write_report

    unknown = [s for s in skip if s not in dict(STAGES)]
    if unknown:
        raise InputError(f"--skip {unknown[0]}: not a demo stage; stages are {', '.join(n for n, _ in STAGES)}")
    if cameras < 1 or frames < 1:
        raise InputError(f"need at least one camera and one frame, got --cameras {cameras} --frames {frames}")
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: exists and is not a folder; choose a folder for the demo output")
    out.mkdir(parents=True, exist_ok=True)
    # Without a terminal rich assumes 80 columns, which truncates the measurement table in logs.
    console = console or (Console() if sys.stdout.isatty() else Console(width=120))
    with Progress(TextColumn("{task.description:<12}"), BarColumn(), TextColumn("{task.completed}/{task.total}"),
                  TimeElapsedColumn(), console=console, transient=False) as progress:
        ctx = DemoContext(out, cameras, frames, resolution, console, progress)
        overall = progress.add_task("demo", total=len(STAGES) + 1)
        for name, fn in STAGES:
            progress.update(overall, description=f"demo: {name}")
            row = run_stage(ctx, name, fn, skip)
            ctx.stages.append(row)
            style = {"done": "green", "failed": "red"}.get(row["status"], "yellow")
            console.print(f"[{style}]{name}: {row['status']}[/] ({row['seconds']:.1f} s) {row['summary']}")
            progress.advance(overall)
        progress.update(overall, description="demo: report")
        if ctx.session is not None:
            _session_views(ctx)
        write_json(out / "demo.json", {"stages": ctx.stages})
        notes = [f"{r['stage']}: {r['status']}, {r['summary']}" for r in ctx.stages]
        report = write_report(out, out / "report.html", with_3d=with_3d, title="bodystudio demo",
                              scenes=ctx.scenes, notes=notes)
        progress.advance(overall)
    for _, scene in ctx.scenes:
        if not isinstance(scene, dict):
            scene.close()
    return report.path, ctx.stages


def check_demo(out: Path, report: Path, stages: list[dict]) -> None:
    """Raise :class:`DemoStageError` (exit 2 from the CLI) naming the failed stages, if any failed."""
    failed = [r["stage"] for r in stages if r["status"] == "failed"]
    if failed:
        first = next(r for r in stages if r["status"] == "failed")
        raise DemoStageError(f"stages failed: {', '.join(failed)} ({first['stage']}: {first['summary']}); "
                             f"messages in {Path(out) / 'demo.json'}, report still written to {report}")
