"""Helpers shared by the CLI command modules: JSON output, progress bars.

`to_json_text` and `write_json` live in `slam.json_io` (the library writes JSON too);
they are re-exported here for the command modules.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

from slam.json_io import to_json_text, write_json

__all__ = ["print_json", "stage_progress", "to_json_text", "write_json"]


def print_json(obj: Any) -> None:
    """Write `obj` as one JSON document on stdout."""
    sys.stdout.write(to_json_text(obj) + "\n")
    sys.stdout.flush()


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
