"""The ``bodystudio`` command. Each stage adds its sub-commands from its own ``cli/<stage>.py`` module.

User errors (:class:`bodystudio.errors.BodyStudioError`) become one line on stderr and exit code 2.
"""

from __future__ import annotations

import logging
import sys

import typer
import typer.main

from bodystudio.errors import BodyStudioError, disk_full

app = typer.Typer(no_args_is_help=True, add_completion=False, pretty_exceptions_enable=False,
                  help="bodystudio: multi-camera studio capture, scan fitting and automatic rigging.")


@app.callback()
def _root(verbose: bool = typer.Option(False, "--verbose", "-v", help="log progress details")) -> None:
    logging.basicConfig(level=logging.INFO if verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")


def _register() -> None:
    # Stage modules add their commands to the shared ``synth`` and ``eval`` groups when imported.
    from bodystudio.cli import body, eval, synth

    app.add_typer(body.app, name="body", help="MakeHuman body model: export, info, measure.")
    app.add_typer(synth.app, name="synth", help="Synthetic studio data with ground truth.")
    app.add_typer(eval.app, name="eval", help="Score results against ground truth (JSON).")
    from bodystudio.cli import capture

    app.add_typer(capture.app, name="capture", help="Studio sessions: import recordings, silhouettes, verify.")
    from bodystudio.cli import demo, viewer

    app.command("view")(viewer.view)
    app.command("report")(viewer.report)
    app.command("demo")(demo.demo)
    from bodystudio.cli import reconstruct

    app.command("reconstruct")(reconstruct.reconstruct)
    from bodystudio.cli import rig

    app.command("rig")(rig.rig)
    from bodystudio.cli import calib

    app.command("calibrate")(calib.calibrate)
    from bodystudio.cli import recover

    app.command("recover")(recover.recover)
    app.add_typer(calib.app, name="calib", help="ChArUco boards; rig export/import (EasyMocap, COLMAP).")
    from bodystudio.cli import muscle

    app.add_typer(muscle.app, name="muscle", help="Arm-muscle capture with a depth camera; the arm muscle model.")
    from bodystudio.cli import mirror

    app.add_typer(mirror.app, name="mirror", help="Virtual mirror: fit, track and reshape a person in Kinect video.")
    from bodystudio.cli import batch, garment  # garment also adds ``synth garment``

    app.add_typer(garment.app, name="garment",
                  help="Garment replacement in monocular video: fit the body (§4-5), render the new garment (§6-7).")

    app.add_typer(batch.app, name="batch", help="Batch jobs on a dask cluster: rig a folder of scans (resumable).")


_register()


def _with_click(typer_types: list[type[BaseException]], name: str) -> tuple[type[BaseException], ...]:
    """``typer_types`` plus click's own exception ``name`` when click is installed (typer may vendor it)."""
    found = list(typer_types)
    try:
        import click

        found.append(getattr(click.exceptions, name))
    except ImportError:  # typer without a click dependency
        pass
    return tuple(dict.fromkeys(found))


def click_exception_types() -> tuple[type[BaseException], ...]:
    """The click exception base classes the installed typer raises (its vendored click and/or click itself).

    typer up to 0.2x re-exported click's classes; later releases vendor click as ``typer._click``. Both are
    found through the MRO of ``typer.BadParameter`` instead of naming a module of one typer version.
    """
    return _with_click([c for c in typer.BadParameter.__mro__ if c.__name__ == "ClickException"], "ClickException")


def _abort_types() -> tuple[type[BaseException], ...]:
    return _with_click([typer.Abort], "Abort")


def _exit_types() -> tuple[type[BaseException], ...]:
    return _with_click([typer.Exit], "Exit")


def _argument_usage(param) -> list[str]:
    """Usage piece of one argument in click's classic style: ``OUT``, ``[OUT]``, ``PATHS...``."""
    name = param.metavar or param.name.upper()
    if param.nargs != 1:
        name += "..."
    return [name if param.required else f"[{name}]"]


def plain_usage(command) -> None:
    """Show every argument of ``command`` and its sub-commands as ``OUT`` in usage lines.

    typer 0.29 writes a required argument as ``{out}``, which reads like a placeholder to fill in or a
    set of choices; click and the README write ``OUT``. Each argument's ``get_usage_pieces`` (click's public
    hook for its usage piece) is replaced on the instance, so help panels and error messages stay typer's.
    """
    for param in getattr(command, "params", ()):
        if getattr(param, "param_type_name", "") == "argument":
            param.get_usage_pieces = lambda ctx, p=param: _argument_usage(p)
    for sub in getattr(command, "commands", {}).values():
        plain_usage(sub)


def main(argv: list[str] | None = None) -> int:
    """Entry point: run the app; user errors become one line and exit 2, usage errors click's usage and exit 2."""
    from bodystudio.runfolder import command_read_locks

    try:
        command = typer.main.get_command(app)
        plain_usage(command)
        with command_read_locks():  # the command's shared read locks end with it
            command.main(args=argv, standalone_mode=False, prog_name="bodystudio")
    except BodyStudioError as exc:
        _error_line(f"error: {exc}")
        return 2
    except _exit_types() as exc:
        return exc.exit_code
    except _abort_types():
        _error_line("aborted")
        return 1
    except click_exception_types() as exc:  # usage errors: unknown command/option, missing/malformed argument
        exc.show()
        return exc.exit_code
    except KeyboardInterrupt:
        _error_line("interrupted")
        return 130
    except OSError as exc:
        if not disk_full(exc):
            raise
        # a write outside fileio's atomic helpers (a library writing by name, a video encoder): still one line
        where = exc.filename or "an output file"
        _error_line(f"error: {where}: {exc.strerror or 'no space left on device'} while writing; free space on "
                    "that disk or give an output on another one")
        return 2
    return 0


def _error_line(text: str) -> None:
    """The one error line, on a fresh line even if a progress bar or a C library left a partial one."""
    sys.stdout.flush()
    if sys.stderr.isatty():
        sys.stderr.write("\r\033[K")
    sys.stderr.write(text + "\n")
    sys.stderr.flush()


def run() -> None:
    """Console-script entry point."""
    sys.exit(main())


if __name__ == "__main__":
    run()
