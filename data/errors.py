"""The project's exceptions and warnings, shared by every layer.

Every error the project raises on purpose derives from `LoopClosureError`, so a
library caller can catch them all in one ``except``.  A `UserError` is a caller's
mistake (a bad parameter value, an unknown name, a missing file, a wrong topic); it
is also a `ValueError`, as Python's own functions raise for bad arguments.  A
`DataError` is a file that cannot be read as what it claims to be, and names the
file.  The CLI prints either as one line, ``error: <message>``, and exits with
status 2, never with a traceback.  Anything else that escapes is a bug and keeps
its traceback.
"""

from __future__ import annotations

import warnings
from os import PathLike


class LoopClosureError(Exception):
    """Base of every error the project raises on purpose."""


class UserError(LoopClosureError, ValueError):
    """Bad input or bad usage: reported to the user in one line, never a traceback.

    The message names the parameter or file at fault and what would be accepted.
    """


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
