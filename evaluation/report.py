"""Markdown reports: a title, tables and links to the plots beside them."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from data.atomic_write import output_dir, write_bytes_atomic


def fmt(value: Any, digits: int = 4) -> str:
    """A table cell: floats to `digits` significant digits, None as a dash."""
    if value is None:
        return "-"
    if isinstance(value, float):
        return f"{value:.{digits}g}"
    return str(value)


def table(headers: Sequence[str], rows: Sequence[Sequence[Any]], digits: int = 4) -> str:
    """A GitHub markdown table."""
    lines = ["| " + " | ".join(headers) + " |", "|" + "|".join("---" for _ in headers) + "|"]
    lines += ["| " + " | ".join(fmt(v, digits) for v in row) + " |" for row in rows]
    return "\n".join(lines)


def key_values(values: Mapping[str, Any], digits: int = 5) -> str:
    """A two-column markdown table of named figures."""
    return table(["measure", "value"], [(k, v) for k, v in values.items()], digits)


def write_report(path: Path, title: str, sections: Sequence[tuple[str, str]]) -> Path:
    """Write ``# title`` followed by ``## heading`` + body for each section (atomically).

    The folder of `path` is made if needed.

    Raises:
        DataError: the folder cannot be made or the file cannot be written.
    """
    output_dir(path.parent)
    parts = [f"# {title}", ""]
    for heading, body in sections:
        parts += [f"## {heading}", "", body.rstrip(), ""]
    write_bytes_atomic(path, "\n".join(parts).encode("utf-8"))
    return path


def image(path: Path, relative_to: Path, alt: str = "") -> str:
    """Markdown image link to `path` relative to the report's folder."""
    return f"![{alt}]({path.relative_to(relative_to).as_posix()})"
