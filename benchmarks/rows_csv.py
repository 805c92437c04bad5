"""The benchmarks' CSV output: a list of dict rows written with their keys as header."""

from __future__ import annotations

import csv
from pathlib import Path


def write_rows(path: str | Path, rows: list[dict]) -> None:
    """Write `rows` to `path` as CSV, the first row's keys as the header (in order).
    Nothing is written when `rows` is empty."""
    if not rows:
        return
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
