"""The ``bodystudio`` command. Each stage adds its sub-commands from its own ``cli/<stage>.py`` module.

User errors (:class:`bodystudio.errors.BodyStudioError`) become one line on stderr and exit code 2.
"""

from __future__ import annotations

import logging
import sys

import typer

from bodystudio.errors import BodyStudioError

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
    app.add_typer(calib.app, name="calib", help="ChArUco boards; rig export/import (EasyMocap, COLMAP).")
    from bodystudio.cli import muscle

    app.add_typer(muscle.app, name="muscle", help="Arm-muscle capture with a depth camera; the arm muscle model.")


_register()


def main(argv: list[str] | None = None) -> int:
    """Entry point: run the app, turning user errors into one line and exit code 2."""
    try:
        app(args=argv, standalone_mode=False)
    except BodyStudioError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except typer.Exit as exc:
        return exc.exit_code
    except typer.Abort:
        print("aborted", file=sys.stderr)
        return 1
    except Exception as exc:  # click usage errors
        import click

        if isinstance(exc, click.ClickException):
            exc.show()
            return exc.exit_code
        raise
    return 0


def run() -> None:
    """Console-script entry point."""
    sys.exit(main())


if __name__ == "__main__":
    run()
