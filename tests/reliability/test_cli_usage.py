"""Usage lines name arguments the way click and the README do (``OUT``), not typer 0.29's ``{out}`` (issue 16)."""

from __future__ import annotations

import typer.main

from bodystudio.cli.main import app, plain_usage

from .conftest import run_subprocess


def _commands(command, path):
    yield path, command
    for name, sub in getattr(command, "commands", {}).items():
        yield from _commands(sub, [*path, name])


def test_missing_argument_usage_line_through_the_console_script():
    res = run_subprocess(["rig"])
    assert res.rc == 2
    assert "Usage: bodystudio rig [OPTIONS] SCAN\n" in res.stderr, res.stderr
    assert "{" not in res.stderr


def test_help_usage_line_through_the_console_script():
    res = run_subprocess(["body", "export", "--help"])
    assert res.rc == 0
    assert "Usage: bodystudio body export [OPTIONS] OUT" in res.stdout, res.stdout
    assert "{out}" not in res.stdout


def test_every_usage_line_is_plain():
    """Every command of the tree: arguments upper case, no braces; a required argument without brackets."""
    root = typer.main.get_command(app)
    plain_usage(root)
    n_args = 0
    for path, command in _commands(root, ["bodystudio"]):
        ctx = command.context_class(command, info_name=" ".join(path))
        usage = command.get_usage(ctx)
        assert "{" not in usage and "}" not in usage, usage
        for p in command.params:
            if p.param_type_name == "argument":
                n_args += 1
                name = (p.metavar or p.name.upper()) + ("..." if p.nargs != 1 else "")
                assert (name if p.required else f"[{name}]") in usage, (usage, p.name)
    assert n_args >= 20
