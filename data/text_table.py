"""Whitespace-separated text tables: the reading and number-formatting rules of every
text format in `data` (TUM, KITTI, g2o, relations).

Files are plain, gzip or bzip2 (`data.compression.open_text`, latin-1).  A data
line is a non-blank line not starting with ``#``; its tokens are parsed as finite
float64 numbers, and any line that does not parse is a `DataError` naming the
file and the line.  Numbers are written with the shortest round-trip repr, stamps
as ``%.6f`` when that reads back exactly, so write -> read gives the same floats.
"""

from __future__ import annotations

from os import PathLike

import numpy as np
from numpy.typing import ArrayLike, NDArray

from data.compression import open_text
from data.errors import DataError

Array = NDArray[np.float64]
PathArg = str | PathLike[str]

Row = tuple[int, list[str]]
"""A data line: its 1-based line number and its whitespace-separated tokens."""


def read_lines(path: PathArg) -> list[str]:
    """All lines of a plain, gzip or bzip2 text file (latin-1, never fails on stray bytes).

    Raises `DataError` when the file is missing, a directory, or its compressed
    stream is corrupt.
    """
    try:
        with open_text(path) as f:
            return f.read().splitlines()
    except (OSError, EOFError, ValueError) as exc:
        raise DataError(path, f"cannot read: {exc}") from exc


def data_rows(lines: list[str], comment: str = "#") -> list[Row]:
    """``(line number, tokens)`` of every non-blank line not starting with `comment`."""
    rows: list[Row] = []
    for n, line in enumerate(lines, start=1):
        tokens = line.split()
        if tokens and not tokens[0].startswith(comment):
            rows.append((n, tokens))
    return rows


def parse_rows(path: PathArg, rows: list[Row], ncols: int, what: str) -> tuple[NDArray, Array]:
    """Line numbers ``(N,)`` and finite values ``(N, ncols)`` of token rows.

    Vectorised: one numpy conversion for the whole table; only when it fails is
    the table scanned again to name the first bad line.

    Raises:
        DataError: a row without exactly `ncols` tokens, a token that is not a
            number, or a NaN/inf value, naming the line (``what`` names the record).
    """
    linenos = np.fromiter((n for n, _ in rows), dtype=np.int64, count=len(rows))
    counts = np.fromiter((len(t) for _, t in rows), dtype=np.int64, count=len(rows))
    wrong = np.flatnonzero(counts != ncols)
    if wrong.size:
        k = int(wrong[0])
        raise DataError(
            path,
            f"line {linenos[k]}: {what} needs {ncols} values, found {counts[k]}"
            + (f" ({wrong.size} such lines)" if wrong.size > 1 else ""),
        )
    if not rows:
        return linenos, np.zeros((0, ncols))
    try:
        values = np.array([t for _, t in rows], dtype=float)
    except ValueError:
        for n, tokens in rows:
            for tok in tokens:
                try:
                    float(tok)
                except ValueError:
                    raise DataError(path, f"line {n}: {tok!r} is not a number") from None
        raise  # pragma: no cover - numpy and float() disagree
    bad = np.flatnonzero(~np.isfinite(values).all(axis=1))
    if bad.size:
        k = int(bad[0])
        raise DataError(
            path,
            f"line {linenos[k]}: non-finite value (NaN or inf) in {what}"
            + (f" ({bad.size} such lines)" if bad.size > 1 else ""),
        )
    return linenos, values.reshape(len(rows), ncols)


def format_rows(values: ArrayLike) -> list[str]:
    """Rows of a 2-D array as space-separated shortest round-trip reprs of each float."""
    table = np.asarray(values, dtype=float)
    return [" ".join(map(repr, row)) for row in table.tolist()]


def format_stamps(stamps: ArrayLike) -> list[str]:
    """Stamps [s] as ``%.6f`` where that reads back exactly, else the round-trip repr."""
    s = np.asarray(stamps, dtype=float).reshape(-1)
    out = []
    for x in s.tolist():
        fixed = f"{x:.6f}"
        out.append(fixed if float(fixed) == x else repr(x))
    return out
