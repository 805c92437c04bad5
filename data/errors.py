"""User-facing errors and warnings shared by every layer.

A `UserError` is a problem with the user's input (missing file, unknown format,
garbage, wrong topic).  The CLI prints it as one line, ``error: <message>``, and
exits with status 2; it never shows a traceback for it.  Anything else that
escapes is a bug and keeps its traceback.
"""

from __future__ import annotations

import warnings
from os import PathLike


class UserError(Exception):
    """Bad input or bad usage: reported to the user in one line, never a traceback."""


class DataError(UserError):
    """A file that cannot be read as what it claims to be.

    ``str(err)`` is ``"<path>: <what is wrong>"`` so the message always names the file.
    """

    def __init__(self, path: str | PathLike[str] | None, message: str) -> None:
        self.path = None if path is None else str(path)
        self.message = message
        super().__init__(message if self.path is None else f"{self.path}: {message}")


class DataWarning(UserWarning):
    """Recoverable trouble in an input file (skipped lines, recovered index, ...)."""


def warn(message: str) -> None:
    """Emit a `DataWarning`; the CLI prints it as one ``warning:`` line on stderr."""
    warnings.warn(message, DataWarning, stacklevel=2)
