"""``bodystudio synth ...``: synthetic studio data with ground truth (sessions, calibration captures, scans).

Stages add their command to :data:`app` from their own CLI module (``@app.command("session")``).
"""

import typer

app = typer.Typer(no_args_is_help=True)
