"""Commands about input data: `info`, `convert`, `simulate`."""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Annotated, TypeVar

import typer

from slam.cli.common import print_json

TopicOption = Annotated[
    str | None, typer.Option("--topic", help="Scan topic of a bag (auto-detected if unique).")
]
StrictOption = Annotated[
    bool, typer.Option("--strict", help="Treat malformed lines or messages as errors.")
]
T = TypeVar("T")
JsonOption = Annotated[bool, typer.Option("--json", help="Print one JSON object on stdout.")]


def info(
    path: Annotated[Path, typer.Argument(help="CARMEN log, ROS1/ROS2/MCAP bag, or g2o graph.")],
    topic: TopicOption = None,
    strict: StrictOption = False,
    json: JsonOption = False,
) -> None:
    """Describe what is in a log, a bag or a pose graph."""
    from data.sources import describe

    summary = describe(path, topic=topic, strict=strict).to_json()
    if json:
        print_json(summary)
        return
    width = max(len(k) for k in summary)
    for key, value in summary.items():
        if value is None:
            continue
        if isinstance(value, dict):
            typer.echo(f"{key:<{width}}  " + ", ".join(f"{k}: {v}" for k, v in value.items()))
        elif isinstance(value, float):
            typer.echo(f"{key:<{width}}  {value:.6g}")
        else:
            typer.echo(f"{key:<{width}}  {value}")


def convert(
    input: Annotated[Path, typer.Argument(help="Any supported scan log or bag.")],
    output: Annotated[Path, typer.Argument(help="Output ROS2 bag folder (must not exist).")],
    format: Annotated[
        str, typer.Option("--format", help="ros2 (sqlite3 storage) or mcap.")
    ] = "ros2",
    topic: TopicOption = None,
    strict: StrictOption = False,
) -> None:
    """Convert a log or bag to a ROS2 bag with /scan, /odom and /tf."""
    from data.errors import UserError
    from data.rosbag import write_ros2_bag
    from data.sources import open_source

    storage = {"ros2": "sqlite3", "sqlite3": "sqlite3", "mcap": "mcap"}.get(format)
    if storage is None:
        raise UserError(f"unknown --format {format!r}; use ros2 or mcap")
    source = open_source(input, topic=topic, strict=strict)
    count = write_ros2_bag(_progress(source, "converting"), output, storage=storage)
    typer.echo(f"wrote {count} scans to {output} ({storage})")


def simulate(
    out: Annotated[Path, typer.Option("--out", help="Output folder.")],
    world: Annotated[str, typer.Option("--world", help="box or surface.")] = "box",
    seed: Annotated[int, typer.Option("--seed", help="Random seed.")] = 0,
    fov: Annotated[float, typer.Option("--fov", help="Laser field of view, degrees.")] = 360.0,
    json: JsonOption = False,
) -> None:
    """Simulate a robot run with loops: a CARMEN log plus groundtruth.tum and world.json."""
    from data.atomic_write import output_dir
    from data.sim import simulate_run, write_run

    output_dir(out)
    run = simulate_run(world, seed=seed, fov_deg=fov)
    files = write_run(run, out)
    summary = {**run.summary(), "files": {k: str(v) for k, v in files.items()}}
    if json:
        print_json(summary)
        return
    for key, value in summary.items():
        typer.echo(f"{key}: {value}")


def _progress(items: Iterable[T], label: str) -> Iterator[T]:
    """Yield `items` while a spinner counts them on stderr."""
    from rich.progress import Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

    with Progress(
        SpinnerColumn(),
        TextColumn(f"{label} " + "{task.completed} scans"),
        TimeElapsedColumn(),
        transient=True,
    ) as bar:
        task = bar.add_task(label, total=None)
        for item in items:
            yield item
            bar.advance(task)


def register(app: typer.Typer) -> None:
    """Add the data commands to `app`."""
    app.command()(info)
    app.command()(convert)
    app.command()(simulate)
