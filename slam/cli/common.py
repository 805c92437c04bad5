"""Helpers shared by the CLI command modules: JSON output, option types."""

from __future__ import annotations

import json
import math
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np


def _plain(obj: Any) -> Any:
    """JSON-serialisable copy of `obj` (numpy scalars/arrays, paths, NaN -> null)."""
    if isinstance(obj, dict):
        return {str(k): _plain(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_plain(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _plain(obj.tolist())
    if isinstance(obj, np.generic):
        return _plain(obj.item())
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, Path):
        return str(obj)
    return obj


def to_json_text(obj: Any, indent: int | None = 2) -> str:
    """`obj` as JSON text; numpy values converted, non-finite floats become null."""
    return json.dumps(_plain(obj), indent=indent)


def print_json(obj: Any) -> None:
    """Write `obj` as one JSON document on stdout."""
    sys.stdout.write(to_json_text(obj) + "\n")
    sys.stdout.flush()


def write_json(path: Path, obj: Any) -> None:
    """Write `obj` as JSON to `path` atomically (temporary file, then rename)."""
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(to_json_text(obj) + "\n")
    tmp.replace(path)


@contextmanager
def stage_progress(
    unit: str | None = None, *, label_width: int = 0, remaining: bool = False
) -> Iterator[Callable[[str, int, int], None]]:
    """Rich progress bars on stderr, one per stage, shown on a terminal only.

    Yields ``update(stage, done, total)``: the first call for a stage adds its bar.
    `unit` is printed after the counts (e.g. ``"scans"``), `label_width` pads the stage
    names so the bars line up, `remaining` adds an estimated time remaining.
    """
    from rich.console import Console
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        ProgressColumn,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    console = Console(stderr=True)
    label = f"{{task.description:<{label_width}}}" if label_width else "{task.description}"
    columns: list[ProgressColumn] = [TextColumn(label), BarColumn(), MofNCompleteColumn()]
    if unit:
        columns.append(TextColumn(unit))
    columns.append(TimeElapsedColumn())
    if remaining:
        columns.append(TimeRemainingColumn())
    bar = Progress(*columns, console=console, transient=True, disable=not console.is_terminal)
    tasks: dict[str, int] = {}

    def update(stage: str, done: int, total: int) -> None:
        if stage not in tasks:
            tasks[stage] = bar.add_task(stage, total=total)
        bar.update(tasks[stage], completed=done, total=total)

    with bar:
        yield update
