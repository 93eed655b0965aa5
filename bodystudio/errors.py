"""User-facing error types. The CLI prints their message as one line and exits with code 2."""

import errno
import os


class BodyStudioError(Exception):
    """Base class of every error caused by user input (files, parameters, environment).

    Its message is one line by construction: a line break that comes in with a quoted value (a JSON key,
    an OpenCV message) is shown as ``\\n``, so the CLI's one error line stays one line.
    """

    def __str__(self) -> str:
        return super().__str__().strip().replace("\r", "\\r").replace("\n", "\\n")


class InputError(BodyStudioError):
    """A parameter, name or value given by the user is invalid."""


class FileFormatError(BodyStudioError):
    """A file exists but cannot be read as what it should be."""


class AssetError(BodyStudioError):
    """The body assets are missing, corrupt or cannot be fetched."""


class SessionError(BodyStudioError):
    """A capture session is incomplete, inconsistent or corrupted."""


class ImplausibleResultError(BodyStudioError):
    """A stage's result failed its own self-check (its inputs disagree with each other): refused, nothing
    written, unless the user forces it (e.g. ``--accept-implausible``)."""


#: errno values meaning "the output's disk (or the user's quota) is full".
DISK_FULL_ERRNOS = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG)


class OutputSpaceError(BodyStudioError, OSError):
    """An output could not be written: its disk or quota is full. Still an ``OSError`` (errno ENOSPC), so code
    that cleans up after a failed write on ``OSError`` does so."""

    def __init__(self, path, reason: str = "no space left on device"):
        super().__init__(f"{os.path.normpath(path)}: {reason} while writing it; the output was not written (a "
                         "previous result stays as it was); free space on that disk or give an output on another one")
        self.errno, self.filename = DISK_FULL_ERRNOS[0], str(path)

    def __str__(self) -> str:  # the message, not OSError's "[Errno 28] ..." built from errno and filename
        return Exception.__str__(self).strip().replace("\r", "\\r").replace("\n", "\\n")


def disk_full(exc: BaseException) -> bool:
    """Whether ``exc`` is a write that failed because the disk or quota is full."""
    return isinstance(exc, OSError) and exc.errno in DISK_FULL_ERRNOS
