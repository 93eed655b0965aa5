"""``bodystudio eval ...``: score a stage's output against synthetic ground truth, printing JSON.

Stages add their command to :data:`app` from their own CLI module (``@app.command("calib")``);
``eval mirror`` (issue 12) lives here.
"""

from __future__ import annotations

import json
from pathlib import Path

import typer

app = typer.Typer(no_args_is_help=True)


@app.command("mirror")
def eval_mirror(
    session: Path = typer.Argument(..., help="synthetic mirror session (bodystudio synth mirror)"),
    run: Path = typer.Option(None, "--run", help="run folder of `bodystudio mirror run` (default SESSION/mirror/run)"),
) -> None:
    """Score a mirror run against the session's ground truth: init, tracking, foreground, warp, PSNR/SSIM, timings."""
    from bodystudio.mirror.evaluate import evaluate_mirror

    scores = evaluate_mirror(session, run)
    # strict JSON (RFC 8259): an infinite PSNR (output identical to the target) is null + psnr_person_identical
    typer.echo(json.dumps(scores, indent=2, allow_nan=False))


@app.command("garment")
def eval_garment(
    fit_dir: Path = typer.Argument(..., help="fit folder of `bodystudio garment fit`"),
    session: Path = typer.Option(None, "--session", help="synthetic session (default: the fit's source)"),
) -> None:
    """Score a garment fit against the synthetic session's ground truth (JSON): stature, joints, light, albedo,
    silhouette IoU, ms per frame; plus the composite's scores when DIR/render/render.json exists."""
    from bodystudio.garment.evaluate import evaluate_garment

    typer.echo(json.dumps(evaluate_garment(fit_dir, session), indent=2, allow_nan=False))
