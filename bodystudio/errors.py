"""User-facing error types. The CLI prints their message as one line and exits with code 2."""


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
