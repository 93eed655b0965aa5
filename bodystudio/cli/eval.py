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
