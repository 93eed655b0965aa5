"""``bodystudio eval ...``: score a stage's output against synthetic ground truth, printing JSON.

Stages add their command to :data:`app` from their own CLI module (``@app.command("calib")``).
"""

import typer

app = typer.Typer(no_args_is_help=True)
