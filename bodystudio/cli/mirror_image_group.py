"""Stand-in ``bodystudio mirror`` group holding ``run`` until MIR-BODY's ``cli/mirror.py`` (with ``init``) lands;
then ``run`` is registered there with one line and this file goes."""

import typer

from bodystudio.cli.mirror_run import mirror_run

app = typer.Typer(no_args_is_help=True)
app.command("run")(mirror_run)
