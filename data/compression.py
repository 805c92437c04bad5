"""Open plain, gzip and bzip2 files transparently, by content rather than by name."""

from __future__ import annotations

import bz2
import gzip
import io
from pathlib import Path
from typing import IO

from data.errors import DataError

_GZIP_MAGIC = b"\x1f\x8b"
_BZIP2_MAGIC = b"BZh"


def read_magic(path: str | Path, size: int = 16) -> bytes:
    """First `size` bytes of the file (raises `DataError` when it cannot be opened)."""
    path = Path(path)
    if not path.exists():
        raise DataError(path, "no such file or directory")
    if path.is_dir():
        raise DataError(path, "is a directory, expected a file")
    try:
        with path.open("rb") as f:
            return f.read(size)
    except OSError as exc:
        raise DataError(path, f"cannot open: {exc.strerror or exc}") from exc


def compression_of(path: str | Path) -> str:
    """``"gzip"``, ``"bzip2"`` or ``"none"`` from the file's magic bytes."""
    magic = read_magic(path, 3)
    if magic.startswith(_GZIP_MAGIC):
        return "gzip"
    if magic.startswith(_BZIP2_MAGIC):
        return "bzip2"
    return "none"


def open_binary(path: str | Path) -> IO[bytes]:
    """Decompressing binary reader for a plain, ``.gz`` or ``.bz2`` file."""
    kind = compression_of(path)
    if kind == "gzip":
        return gzip.open(path, "rb")
    if kind == "bzip2":
        return bz2.open(path, "rb")
    return open(path, "rb")


def open_text(path: str | Path, encoding: str = "latin-1") -> IO[str]:
    """Decompressing text reader (latin-1 by default: never fails on stray bytes)."""
    return io.TextIOWrapper(open_binary(path), encoding=encoding, newline=None)
