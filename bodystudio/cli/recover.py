"""``bodystudio recover PATH``: finish or discard interrupted multi-file writes (:mod:`bodystudio.runfolder`)."""

from __future__ import annotations

from pathlib import Path

import typer


def recover(path: Path = typer.Argument(..., help="session or reconstruct folder, avatar .glb, or cameras.json "
                                                  "whose write was interrupted")) -> None:
    """Complete a write killed after its commit point, or discard one killed before it (the previous result stays)."""
    from bodystudio.runfolder import recover as run

    for line in run(path):
        typer.echo(line)
