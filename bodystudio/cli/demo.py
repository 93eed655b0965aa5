"""``bodystudio demo --out DIR``: the main job on the built-in synthetic studio (:mod:`bodystudio.demo`)."""

from __future__ import annotations

from pathlib import Path

import typer

from bodystudio.demo import STAGES


def demo(
    out: Path = typer.Option(Path("demo-out"), "--out", help="output folder"),
    cameras: int = typer.Option(4, "--cameras", help="studio cameras in the synthetic session"),
    frames: int = typer.Option(3, "--frames", help="frames in the synthetic session"),
    resolution: str = typer.Option("320x240", "--resolution", help="camera image size WxH"),
    no_3d: bool = typer.Option(False, "--no-3d", help="leave the 3D views out of the report"),
    skip: list[str] | None = typer.Option(None, "--skip", help="stage to leave out (repeat): " + ", ".join(
        n for n, _ in STAGES if n != "bodies")),
) -> None:
    """Run the main job on the built-in synthetic studio and write an HTML report (exit 2 if a stage fails)."""
    from bodystudio.cli.viewer import _parse_size
    from bodystudio.demo import check_demo, run_demo
    from bodystudio.fileio import check_output_folder

    check_output_folder(out, "demo --out")
    report, stages = run_demo(out, cameras, frames, _parse_size(resolution, "--resolution"), with_3d=not no_3d,
                              skip=tuple(skip or ()))
    typer.echo(f"report: {report.resolve()}")
    check_demo(out, report, stages)
