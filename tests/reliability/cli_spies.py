"""What the CLI mutation tests share (mutNN, mutKK): the command run through typer's CliRunner, a refusal checked
word for word, a spy that records its calls, and a command's help text as one line."""

from __future__ import annotations

from typer.testing import CliRunner

from bodystudio.errors import InputError


def invoke(args):
    """``bodystudio ARGS`` through typer's CliRunner (each argument as a string)."""
    from bodystudio.cli.main import app

    return CliRunner().invoke(app, [str(a) for a in args])


def refused(res, message, kind=InputError):
    """The command raised ``kind`` with exactly ``message``."""
    assert isinstance(res.exception, kind), (res.exit_code, res.output, res.exception)
    assert str(res.exception) == message


class Spy:
    """A stand-in that records every call's arguments and returns ``ret`` (or ``fn``'s result)."""

    def __init__(self, ret=None, fn=None):
        self.calls, self.ret, self.fn = [], ret, fn

    def __call__(self, *args, **kwargs):
        self.calls.append((args, kwargs))
        return self.fn(*args, **kwargs) if self.fn is not None else self.ret


def spy(mp, target, ret=None, fn=None):
    """A :class:`Spy` set on ``target`` with pytest's monkeypatch ``mp``."""
    s = Spy(ret, fn)
    mp.setattr(target, s)
    return s


def help_text(args) -> str:
    """``bodystudio ARGS --help`` as one line, words separated by single spaces and framed by spaces (so a check for
    " phrase " matches the help's own words, not text wrapped around them)."""
    res = invoke([*args, "--help"])
    return " " + " ".join(res.stdout.replace("│", " ").split()) + " "
