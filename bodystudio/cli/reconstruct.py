"""``bodystudio reconstruct SESSION`` (Rapid Skin per frame) and ``bodystudio eval reconstruct SESSION``."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from bodystudio.cli import eval as eval_cli
from bodystudio.errors import InputError


def _constraints(text: str) -> tuple[str, ...]:
    kinds = tuple(k.strip() for k in text.split(",") if k.strip())
    valid = ("silhouette", "depth")
    bad = [k for k in kinds if k not in valid]
    if bad or not kinds:
        raise InputError(f"--constraints {text!r}: use silhouette, depth or silhouette,depth")
    return kinds


def reconstruct(
    session: Path = typer.Argument(..., help="capture session folder"),
    solver: str = typer.Option("gs", help="gs | jacobi | cholesky | cg"),
    template: str = typer.Option("13k", help="template resolution: 13k | 6k | 2k"),
    joints: str = typer.Option("tracker", help="tracker (session Kinect joints) | file | hull (visual hull)"),
    joints_path: Path | None = typer.Option(None, help="folder of NNNNN.json joint files for --joints file"),
    constraints: str = typer.Option("silhouette", help="silhouette, depth or silhouette,depth"),
    frames: str | None = typer.Option(None, help="frame range A:B (B exclusive)"),
    outer: int = typer.Option(8, help="outer iterations No (contour re-matching), 1..100"),
    inner: int = typer.Option(8, help="inner solver iterations Ni, 1..1000"),
    tau: float = typer.Option(30.0, help="contour search range tau (pixels), 1..500"),
    alpha: float = typer.Option(40.0, help="silhouette weight width alpha (pixels), 1..1000"),
    warm_start: bool = typer.Option(False, help="carry the shape over from earlier frames"),
    refine_pose: bool = typer.Option(True, help="refine the joints' pose by an articulated fit to the silhouettes' "
                                     "visual hull before deforming (--no-refine-pose: the paper's init)"),
    bone_lengths: str = typer.Option("sequence", help="sequence (default: one set of bone lengths per run, the "
                                     "median of the tracked lengths over its frames) | frame (each frame's "
                                     "tracked lengths, which jitter)"),
    joint_smoothing: int = typer.Option(0, help="smooth the tracked joints over time: a line fitted through "
                                        "each joint's positions within this many frames (0: off; 2 measured "
                                        "better on 30 fps sessions; sequential path only)"),
    score: bool = typer.Option(True, help="score against ground truth when the session has it"),
    tracking: bool = typer.Option(False, help="start each frame from the previous frame's pose fitted to its "
                                  "silhouettes, re-initialising from the joints on a lost track (default "
                                  "--no-tracking: every frame from its joints, measured more accurate)"),
    scheduler: str | None = typer.Option(None, "--scheduler", help="run chunks on this dask scheduler "
                                         "(tcp://HOST:8786; default $BODYSTUDIO_SCHEDULER)"),
    workers: int | None = typer.Option(None, "--workers", help="run chunks on a local cluster of N worker processes"),
    chunk: int | None = typer.Option(None, "--chunk", help="frames per work unit on a cluster (default 10)"),
    force: bool = typer.Option(False, "--force", help="on a cluster: redo every chunk, also unchanged ones"),
    accurate: bool = typer.Option(False, "--accurate", help="the accurate setting (reconstruct.presets."
                                  "ACCURATE_SETTINGS): tracking, joint smoothing 2 and the shape prior, the "
                                  "whole body's depth in the pose refinement and a torso hold, each with its "
                                  "guard; measured with --constraints silhouette,depth (docs/reconstruct.md); "
                                  "sequential path only"),
    player: int | None = typer.Option(None, "--player", help="Kinect player id (1-6) of the person to reconstruct "
                                      "(default: the lowest id of the first frame with a tracked body); followed "
                                      "over the run, recorded in run.json (subject_player)"),
    accept_implausible: bool = typer.Option(False, "--accept-implausible", help="write the result even when its "
                                            "self-check finds a camera the fit cannot explain (silhouette IoU "
                                            "< 0.75) or depth that does not fit the body (docs/reconstruct.md)"),
) -> None:
    """Deform the template to every frame's silhouettes (Rapid Skin); writes SESSION/reconstruct/."""
    from rich.console import Console
    from rich.table import Table

    from bodystudio.fileio import check_output_folder
    from bodystudio.reconstruct.rapid_skin import RapidSkinParams
    from bodystudio.reconstruct.sequence import reconstruct_session

    if not session.is_dir():
        raise InputError(f"{session}: no such session folder")
    from bodystudio.reconstruct.sequence import BONE_LENGTHS

    if bone_lengths not in BONE_LENGTHS:
        raise InputError(f"--bone-lengths {bone_lengths!r}: use {' or '.join(BONE_LENGTHS)}")
    if not 0 <= joint_smoothing <= 50:
        raise InputError(f"--joint-smoothing {joint_smoothing}: give a half window of 0..50 frames")
    from bodystudio.capture.session import MAX_PLAYERS

    if player is not None and not 1 <= player <= MAX_PLAYERS:
        raise InputError(f"--player {player}: the Kinect SDK numbers players 1 to {MAX_PLAYERS}")
    if player is not None and joints != "tracker":
        raise InputError(f"--player chooses among the session's tracked bodies; drop it or use --joints tracker "
                         f"(not {joints})")
    import os

    from bodystudio.batch import ENV_SCHEDULER
    from bodystudio.reconstruct.presets import ACCURATE_SETTINGS, accurate_keywords

    on_cluster = scheduler is not None or workers is not None or chunk is not None or os.environ.get(ENV_SCHEDULER)
    if accurate and on_cluster:
        raise InputError("--accurate runs on the sequential path only (it tracks and smooths over neighbouring "
                         f"frames); drop --workers/--scheduler/--chunk (and ${ENV_SCHEDULER}) or drop --accurate")
    if accurate and joint_smoothing not in (0, ACCURATE_SETTINGS["joint_smoothing"]):
        raise InputError(f"--accurate sets --joint-smoothing {ACCURATE_SETTINGS['joint_smoothing']} itself; "
                         f"drop --joint-smoothing {joint_smoothing} or drop --accurate")
    check_output_folder(session / "reconstruct", "reconstruct output")
    params = RapidSkinParams(outer_iterations=outer, inner_iterations=inner, tau_px=tau, alpha_px=alpha,
                             solver=solver, constraints=_constraints(constraints))
    if on_cluster:
        if tracking:
            raise InputError("--tracking runs on the sequential path only; drop --workers/--scheduler/--chunk "
                             f"(and ${ENV_SCHEDULER}) or drop --tracking")
        if joint_smoothing:
            raise InputError("--joint-smoothing runs on the sequential path only (a chunk lacks its neighbours' "
                             f"joints); drop --workers/--scheduler/--chunk (and ${ENV_SCHEDULER}) or "
                             "--joint-smoothing")
        summary = _reconstruct_on_cluster(session, scheduler, workers, chunk, force, frames, params,
                                          template=template, joints=joints, warm_start=warm_start,
                                          refine_pose=refine_pose, score=score, bone_lengths=bone_lengths,
                                          joints_path=str(joints_path) if joints_path else None,
                                          accept_implausible=accept_implausible, player=player)
    else:  # the sequential path stays the default (no cluster start-up, one warm start over the session)
        run_kw = {"params": params, "tracking": tracking, "joint_smoothing": joint_smoothing}
        if accurate:
            run_kw = accurate_keywords(params)
        summary = reconstruct_session(session, solver=solver, template=template, joints=joints,
                                      constraints=params.constraints, frames=frames, joints_path=joints_path,
                                      warm_start=warm_start, refine_pose=refine_pose, score=score,
                                      progress=True, bone_lengths=bone_lengths,
                                      accept_implausible=accept_implausible, player=player, **run_kw)
    table = Table(title=f"Rapid Skin: {session} ({solver}, {template}, {constraints})")
    table.add_column("figure")
    table.add_column("value", justify="right")
    for key, value in summary.items():
        table.add_row(key, f"{value:.2f}" if isinstance(value, float) else str(value))
    Console().print(table)


def _reconstruct_on_cluster(session, scheduler, workers, chunk, force, frames, params, accept_implausible=False,
                            player=None, **options) -> dict:
    """``--workers/--scheduler/--chunk``: chunks of frames on a dask cluster (bodystudio.batch)."""
    from dataclasses import asdict

    from bodystudio.batch import ReconstructOptions, batch_client, reconstruct_batch, resolve_scheduler
    from bodystudio.cli.batch import print_cluster, print_report

    if chunk is not None and chunk < 1:
        raise InputError(f"--chunk {chunk}: give at least 1 frame per work unit")
    resolve_scheduler(scheduler, workers)
    from bodystudio.capture.session import open_session
    from bodystudio.reconstruct.sequence import parse_frames, run_subject

    opened = open_session(session)
    selected = parse_frames(frames, opened.frame_ids)  # refused before a cluster starts
    run_subject(opened, selected, options["joints"], player)  # a frame without the run's subject too
    opts = ReconstructOptions(solver=params.solver, params=asdict(params), **options)
    units = -(-len(selected) // (chunk or 10))
    with batch_client(scheduler, workers, units=units) as client:
        print_cluster(client)
        summary, report = reconstruct_batch(session, client, opts, frames=frames, chunk=chunk or 10, force=force,
                                            progress=True, accept_implausible=accept_implausible, player=player)
    print_report(report, f"reconstruct {session}")
    return summary


@eval_cli.app.command("reconstruct")
def eval_reconstruct(session: Path = typer.Argument(..., help="session folder with a reconstruct/ result")) -> None:
    """Score SESSION/reconstruct/ meshes against ground truth; prints JSON."""
    from bodystudio.reconstruct.sequence import evaluate_session

    s = evaluate_session(session)
    keys = ("median_mm", "p90_mm", "hausdorff_mm", "pct_under_10mm", "iou_min", "ms_per_frame")
    out = {k: round(s[k], 3) for k in keys if k in s}
    out.update({k: round(v, 3) if isinstance(v, float) else v for k, v in s.items() if k not in out})
    typer.echo(json.dumps(out))
