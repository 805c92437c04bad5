"""The project's one way to write a file or make an output folder.

Every output file goes through a temporary file in the same directory that is
renamed over the target (``os.replace``) only once it is complete and flushed: an
interrupted run, a full disk or a write error leaves the previous file (or none),
never half a file, and no temporary file behind.  A written file gets the mode of
the file it replaces, else what ``open()`` would give (``0o666`` less the umask).

Every failure is a `DataError` naming the path, so the CLI reports it as one
``error:`` line with exit status 2.
"""

from __future__ import annotations

import bz2
import contextlib
import gzip
import os
import tempfile
from collections.abc import Iterator
from os import PathLike
from pathlib import Path
from typing import IO

from data.errors import DataError, UserError

PathArg = str | PathLike[str]

__all__ = ["atomic_output", "output_dir", "write_bytes_atomic", "write_text_atomic"]


def _file_mode(target: Path) -> int:
    """Permission bits for a written file: the old file's, else what ``open()`` would give."""
    try:
        return target.stat().st_mode & 0o777
    except OSError:
        mask = os.umask(0)
        os.umask(mask)
        return 0o666 & ~mask


def _parent(target: Path) -> Path:
    parent = target.parent if str(target.parent) else Path(".")
    if not parent.is_dir():
        raise DataError(target, f"cannot write: directory {parent} does not exist")
    return parent


@contextlib.contextmanager
def atomic_output(path: PathArg, mode: str = "w", encoding: str = "utf-8") -> Iterator[IO]:
    """A file object whose content replaces `path` when the ``with`` block ends cleanly.

    `mode` is ``"w"`` (text, `encoding`, ``\\n`` line ends) or ``"wb"``.  When the block
    raises, the temporary file is removed and `path` is left as it was.

    Raises:
        DataError: the directory is missing or the file cannot be written.
    """
    if mode not in ("w", "wb"):
        raise UserError(f"atomic_output: mode must be 'w' or 'wb', got {mode!r}")
    target = Path(path)
    parent = _parent(target)
    tmp: str | None = None
    try:
        fd, tmp = tempfile.mkstemp(dir=parent, prefix=f".{target.name}.", suffix=".tmp")
        if mode == "wb":
            handle: IO = os.fdopen(fd, "wb")
        else:
            handle = os.fdopen(fd, "w", encoding=encoding, newline="\n")
        with handle:
            yield handle
            handle.flush()
            os.fsync(handle.fileno())
        os.chmod(tmp, _file_mode(target))  # mkstemp makes 0600; give the usual mode
        os.replace(tmp, target)
        tmp = None
    except OSError as exc:
        raise DataError(target, f"cannot write: {exc.strerror or exc}") from exc
    finally:
        if tmp is not None:
            with contextlib.suppress(OSError):
                os.unlink(tmp)


def write_bytes_atomic(path: PathArg, data: bytes) -> Path:
    """Write `data` to `path` atomically (module docstring); returns the path."""
    target = Path(path)
    with atomic_output(target, "wb") as f:
        f.write(data)
    return target


def write_text_atomic(path: PathArg, text: str) -> Path:
    """Write `text` as UTF-8 to `path` atomically; returns the path.

    A path ending in ``.gz`` or ``.bz2`` is compressed accordingly (gzip with a zero
    time stamp, so equal text gives equal bytes).
    """
    target = Path(path)
    data = text.encode("utf-8")
    suffix = target.suffix.lower()
    if suffix == ".gz":
        data = gzip.compress(data, mtime=0)
    elif suffix == ".bz2":
        data = bz2.compress(data)
    return write_bytes_atomic(target, data)


def output_dir(path: PathArg) -> Path:
    """Make the output folder `path` (and its parents) if needed; returns it.

    Raises:
        DataError: `path` exists and is not a folder, or it cannot be created or
            written to (a read-only or missing parent, a virtual file system).
    """
    out = Path(path)
    if out.exists() and not out.is_dir():
        raise DataError(out, "output folder exists and is not a folder")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise DataError(out, f"cannot create the output folder: {exc.strerror or exc}") from exc
    try:  # a folder that exists may still refuse files (read-only mount, /proc, /sys)
        fd, probe = tempfile.mkstemp(dir=out, prefix=".write-test.", suffix=".tmp")
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise DataError(out, f"cannot write into the output folder: {exc.strerror or exc}") from exc
    return out
