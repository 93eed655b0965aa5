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
    score: bool = typer.Option(True, help="score against ground truth when the session has it"),
) -> None:
    """Deform the template to every frame's silhouettes (Rapid Skin); writes SESSION/reconstruct/."""
    from rich.console import Console
    from rich.table import Table

    from bodystudio.fileio import check_output_folder
    from bodystudio.reconstruct.rapid_skin import RapidSkinParams
    from bodystudio.reconstruct.sequence import reconstruct_session

    if not session.is_dir():
        raise InputError(f"{session}: no such session folder")
    check_output_folder(session / "reconstruct", "reconstruct output")
    params = RapidSkinParams(outer_iterations=outer, inner_iterations=inner, tau_px=tau, alpha_px=alpha,
                             solver=solver, constraints=_constraints(constraints))
    summary = reconstruct_session(session, solver=solver, template=template, joints=joints,
                                  constraints=params.constraints, frames=frames, joints_path=joints_path,
                                  params=params, warm_start=warm_start, refine_pose=refine_pose, score=score,
                                  progress=True)
    table = Table(title=f"Rapid Skin: {session} ({solver}, {template}, {constraints})")
    table.add_column("figure")
    table.add_column("value", justify="right")
    for key, value in summary.items():
        table.add_row(key, f"{value:.2f}" if isinstance(value, float) else str(value))
    Console().print(table)


@eval_cli.app.command("reconstruct")
def eval_reconstruct(session: Path = typer.Argument(..., help="session folder with a reconstruct/ result")) -> None:
    """Score SESSION/reconstruct/ meshes against ground truth; prints JSON."""
    from bodystudio.reconstruct.sequence import evaluate_session

    s = evaluate_session(session)
    keys = ("median_mm", "p90_mm", "hausdorff_mm", "pct_under_10mm", "iou_min", "ms_per_frame")
    out = {k: round(s[k], 3) for k in keys if k in s}
    out.update({k: round(v, 3) if isinstance(v, float) else v for k, v in s.items() if k not in out})
    typer.echo(json.dumps(out))
