"""Command-line options and the result table that several `eval` / `bench` commands share.

Each option is a typed ``Annotated`` alias (typer reads the option from it), so a
command declares ``json: JsonOption = False`` and every command spells, documents
and parses the option the same way.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Annotated

import typer

JsonOption = Annotated[bool, typer.Option("--json", help="Print one JSON object on stdout.")]
OutOption = Annotated[
    Path | None, typer.Option("--out", help="Folder for report.md, results.json and plots.")
]
RelationsOption = Annotated[
    Path | None,
    typer.Option("--relations", help="Relations file (t1 t2 x y z roll pitch yaw); the "
                 "reference is fitted to them."),
]
ReferenceOption = Annotated[
    Path | None,
    typer.Option("--reference", help="Reference trajectory (TUM), stamped like the scans "
                 "(or by scan index when the scan stamps are not unique)."),
]
ReferenceFromLogOption = Annotated[
    bool,
    typer.Option("--reference-from-log", help="The input's logged poses are the reference "
                 "(GMapping-corrected logs; needs --odometry-noise)."),
]
OdometryNoiseOption = Annotated[
    int | None,
    typer.Option("--odometry-noise", help="Replace the logged odometry by the simulator's "
                 "drifting wheel odometry of the logged poses, with this seed."),
]
ConfigOption = Annotated[
    Path | None, typer.Option("--config", help="YAML file of pipeline parameters.")
]
OverridesOption = Annotated[
    list[str] | None,
    typer.Option("--set", help="Override one parameter, e.g. --set loops.local_max=2."),
]
LimitOption = Annotated[int | None, typer.Option("--limit", help="Use only the first N scans.")]
TopicOption = Annotated[str | None, typer.Option("--topic", help="Scan topic of a bag.")]


def print_table(
    title: str, headers: Sequence[str], rows: Sequence[Sequence[str]], width: int
) -> None:
    """A result table on stdout: first column left, the others right-aligned.

    `width` [characters] is used when stdout is not a terminal (a pipe or a file has
    no width to wrap the table to).
    """
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    table = Table(title=escape(title))
    table.add_column(headers[0], no_wrap=True)
    for h in headers[1:]:
        table.add_column(escape(h), justify="right", no_wrap=True)
    for row in rows:
        table.add_row(*[escape(c) for c in row])
    console = Console()
    if not console.is_terminal:
        console = Console(width=width)
    console.print(table)
