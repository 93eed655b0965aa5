"""``bodystudio batch rig SCANS_DIR --out DIR``: many scans on a dask cluster (issue 14), and the shared
cluster options of the batch-capable commands (``reconstruct --workers/--scheduler``)."""

from __future__ import annotations

from pathlib import Path

import typer

app = typer.Typer(no_args_is_help=True)

SCHEDULER_HELP = "dask scheduler address tcp://HOST:8786 (default $BODYSTUDIO_SCHEDULER; else a local cluster)"
WORKERS_HELP = "local cluster of N single-threaded worker processes (default: one per core)"


def print_cluster(client) -> None:
    """One stderr line: where the work runs and the dashboard link."""
    from bodystudio.batch import dashboard_link

    info = client.scheduler_info()
    link = dashboard_link(client)
    typer.echo(f"cluster {info.get('address')}: {len(info.get('workers', {}))} workers; dashboard "
               f"{link or 'not served (install bokeh for the dashboard)'}", err=True)


def print_report(report, what: str) -> None:
    from rich.console import Console
    from rich.table import Table

    table = Table(title=f"{what}: {report.count('done')} done, {report.count('skipped')} unchanged (skipped), "
                        f"{report.count('failed')} failed in {report.wall_s:.1f} s; record {report.record}")
    table.add_column("unit")
    table.add_column("status")
    table.add_column("seconds / error")
    for name, status in report.status.items():
        detail = report.errors.get(name) or (f"{report.seconds[name]:.1f}" if name in report.seconds else "")
        table.add_row(name, status, detail)
    Console(stderr=True).print(table)


@app.command("rig")
def batch_rig(scans_dir: Path = typer.Argument(..., help="folder of body scans (PLY, OBJ, GLB/GLTF, STL)"),
              out: Path = typer.Option(..., "--out", "-o", help="folder of avatars STEM.glb and batch.json"),
              template: str = typer.Option("6k", "--template", help="model template: 6k, 13k (or 2k)"),
              scheduler: str = typer.Option(None, "--scheduler", help=SCHEDULER_HELP),
              workers: int = typer.Option(None, "--workers", help=WORKERS_HELP),
              force: bool = typer.Option(False, "--force", help="redo every scan, also those already rigged")) -> None:
    """Rig every scan of a folder on a dask cluster; resumable (unchanged scans are skipped)."""
    from bodystudio.batch import BatchError, batch_client, list_scans, resolve_scheduler, rig_batch
    from bodystudio.errors import InputError
    from bodystudio.fileio import check_output_folder

    # refuse bad input before starting a cluster
    scans = list_scans(scans_dir)
    if template not in ("6k", "13k", "2k"):
        raise InputError(f"--template {template!r}: use 6k, 13k or 2k")
    check_output_folder(out, "--out")
    from bodystudio.fileio import check_not_an_input

    # the avatars (STEM.glb) among the scans would replace a .glb scan, and be taken for scans next time
    check_not_an_input(out, {"the scans folder": scans_dir})
    resolve_scheduler(scheduler, workers)
    with batch_client(scheduler, workers, units=len(scans)) as client:
        print_cluster(client)
        report = rig_batch(scans_dir, out, client, template=template, force=force, progress=True)
    print_report(report, f"batch rig {scans_dir}")
    if report.errors:
        raise BatchError(report.failure_message("scans"))
