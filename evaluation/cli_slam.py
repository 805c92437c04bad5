"""`loopclosure bench slam`: pipeline, wheel odometry and KISS-ICP on one log, side by side.

``register(bench)`` adds the ``slam`` command to the ``bench`` command group (wired in
by `evaluation.cli`).  Contract::

    loopclosure bench slam INPUT [--relations FILE] [--reference TUM | --reference-from-log]
        [--methods pipeline,wheel,kiss-icp] [--config FILE] [--set key=value ...]
        [--odometry-noise SEED] [--limit N] [--out DIR] [--json] [--no-map]

The runner and every measure are in `evaluation.slam_benchmark` (read its docstring
for the protocol), the table and the output folder in `evaluation.slam_report`.  The
terminal gets one table, one column per method; ``--json`` prints one JSON object
``{"input", "scans", "methods": [{"method", "wall_s", "ms_per_scan", "relations",
"ate", "loops", ...}], ...}``.  ``--out DIR`` writes ``report.md``, ``results.json``,
``trajectories.png``, ``<method>.tum`` and the pipeline's usual outputs in
``DIR/pipeline/``.  Progress bars go to stderr.  Bad input raises `UserError` /
`DataError` (one ``error:`` line, exit 2).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from data.atomic_write import output_dir
from data.errors import UserError
from slam.cli.common import stage_progress


def slam(
    input: Annotated[Path, typer.Argument(help="CARMEN log or ROS bag.")],
    relations: Annotated[
        Path | None,
        typer.Option("--relations", help="Relations file (t1 t2 x y z roll pitch yaw)."),
    ] = None,
    reference: Annotated[
        Path | None,
        typer.Option("--reference", help="Reference trajectory (TUM), stamped like the scans "
                     "(or by scan index when the scan stamps are not unique)."),
    ] = None,
    reference_from_log: Annotated[
        bool,
        typer.Option("--reference-from-log", help="The input's logged poses are the reference "
                     "(GMapping-corrected logs; needs --odometry-noise)."),
    ] = False,
    odometry_noise: Annotated[
        int | None,
        typer.Option("--odometry-noise", help="Replace the logged odometry by the simulator's "
                     "drifting wheel odometry of the logged poses, with this seed."),
    ] = None,
    methods: Annotated[
        str, typer.Option("--methods", help="Comma-separated: pipeline,wheel,kiss-icp; or all.")
    ] = "all",
    config: Annotated[
        Path | None, typer.Option("--config", help="YAML file of pipeline parameters.")
    ] = None,
    overrides: Annotated[
        list[str] | None,
        typer.Option("--set", help="Override one parameter, e.g. --set loops.local_max=2."),
    ] = None,
    limit: Annotated[
        int | None, typer.Option("--limit", help="Use only the first N scans.")
    ] = None,
    topic: Annotated[str | None, typer.Option("--topic", help="Scan topic of a bag.")] = None,
    odom_topic: Annotated[
        str | None, typer.Option("--odom-topic", help="nav_msgs/Odometry topic of a bag.")
    ] = None,
    strict: Annotated[bool, typer.Option("--strict", help="Malformed input is an error.")] = False,
    out: Annotated[
        Path | None,
        typer.Option("--out", help="Folder for report.md, results.json, plots, pipeline/."),
    ] = None,
    no_map: Annotated[
        bool, typer.Option("--no-map", help="Skip the pipeline's occupancy map in --out.")
    ] = False,
    json: Annotated[bool, typer.Option("--json", help="Print one JSON object on stdout.")] = False,
) -> None:
    """Our pipeline, wheel odometry and KISS-ICP on one log: relations error, ATE, time, loops."""
    from data.relations import read_relations
    from data.trajectory_io import read_tum
    from evaluation.slam_benchmark import run_slam_benchmark
    from evaluation.slam_input import load_input, warn_without_odometry
    from evaluation.slam_methods import parse_methods
    from evaluation.slam_reference import logged_reference
    from evaluation.slam_report import json_document, summary_lines, table_rows, write_outputs
    from slam.cli.common import print_json
    from slam.config import PipelineConfig
    from slam.config_io import apply_overrides, load_config
    from slam.odometry import FRONT_ENDS

    names = parse_methods(methods)
    if reference is not None and reference_from_log:
        raise UserError("give either --reference FILE or --reference-from-log, not both")
    if out is not None:
        output_dir(out)  # a bad --out fails now, not after the runs
    cfg = load_config(PipelineConfig, config) if config else PipelineConfig()
    cfg = apply_overrides(cfg, overrides or [])
    if cfg.odometry not in FRONT_ENDS:
        raise UserError(f"unknown odometry {cfg.odometry!r}; choose {', '.join(FRONT_ENDS)}")
    rels = read_relations(relations) if relations is not None else None
    ref = read_tum(reference) if reference is not None else None
    with stage_progress("scans", label_width=9, remaining=True) as update:
        data = load_input(input, limit=limit, odometry_noise=odometry_noise, topic=topic,
                          odom_topic=odom_topic, strict=strict, progress=update)
        ref_name = str(reference) if reference is not None else None
        if reference_from_log:
            ref, ref_name = logged_reference(data), "logged poses"
        warn_without_odometry(data, names)
        bench = run_slam_benchmark(
            data, names, cfg, relations=rels,
            relations_file=str(relations) if relations is not None else None,
            reference=ref, reference_name=ref_name, progress=update,
        )
    paths = write_outputs(bench, out, write_map=not no_map) if out is not None else {}
    if json:
        doc = json_document(bench)
        if paths:
            doc["outputs"] = {k: str(v) for k, v in paths.items()}
        print_json(doc)
        return
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    headers, rows = table_rows(bench)
    table = Table(title=escape(f"bench slam: {input.name}"))
    table.add_column(headers[0], no_wrap=True)
    for h in headers[1:]:
        table.add_column(escape(h), justify="right", no_wrap=True)
    for row in rows:
        table.add_row(*[escape(c) for c in row])
    console = Console()
    if not console.is_terminal:  # a pipe or file: no terminal width to wrap the table to
        console = Console(width=160)
    console.print(table)
    for line in summary_lines(bench):
        typer.echo(line)
    if paths:
        typer.echo(f"report: {paths['report']}")


def register(bench: typer.Typer) -> None:
    """Add ``slam`` to the ``bench`` command group."""
    bench.command("slam")(slam)
