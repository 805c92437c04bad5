"""`loopclosure bench slam`: pipeline, wheel odometry and KISS-ICP on one log, side by side.

``register(bench)`` adds the ``slam`` command to the ``bench`` command group (wired in
by `evaluation.cli`).  Contract::

    loopclosure bench slam INPUT [--relations FILE] [--reference TUM | --reference-from-log]
        [--methods pipeline,wheel,kiss-icp] [--config FILE] [--set key=value ...]
        [--odometry-noise SEED] [--limit N] [--out DIR] [--json] [--no-map]
        [--cluster ADDRESS]

The runner and every measure are in `evaluation.slam_benchmark` (read its docstring
for the protocol), the table and the output folder in `evaluation.slam_report`.  The
terminal gets one table, one column per method; ``--json`` prints one JSON object
``{"input", "scans", "methods": [{"method", "wall_s", "ms_per_scan", "relations",
"ate", "loops", ...}], ...}``.  ``--out DIR`` writes ``report.md``, ``results.json``,
``trajectories.png``, ``<method>.tum`` and the pipeline's usual outputs in
``DIR/pipeline/``.  ``--cluster`` (`evaluation.cluster`) runs each method on the log as
one Dask task (the unit of work: one method on one log), the workers reading the log
and writing their files themselves; the table is the same.  Progress bars go to
stderr.  Bad input raises `UserError` / `DataError` (one ``error:`` line, exit 2).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from data.atomic_write import output_dir
from data.errors import UserError
from evaluation.cli_options import (
    ConfigOption,
    JsonOption,
    LimitOption,
    OdometryNoiseOption,
    OverridesOption,
    ReferenceFromLogOption,
    ReferenceOption,
    RelationsOption,
    TopicOption,
    print_table,
)
from evaluation.cluster import ClusterOption
from slam.cli.common import stage_progress


def slam(
    input: Annotated[Path, typer.Argument(help="CARMEN log or ROS bag.")],
    relations: RelationsOption = None,
    reference: ReferenceOption = None,
    reference_from_log: ReferenceFromLogOption = False,
    odometry_noise: OdometryNoiseOption = None,
    methods: Annotated[
        str, typer.Option("--methods", help="Comma-separated: pipeline,wheel,kiss-icp; or all.")
    ] = "all",
    config: ConfigOption = None,
    overrides: OverridesOption = None,
    limit: LimitOption = None,
    topic: TopicOption = None,
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
    cluster: ClusterOption = None,
    json: JsonOption = False,
) -> None:
    """Our pipeline, wheel odometry and KISS-ICP on one log: relations error, ATE, time, loops.

    With ``--cluster`` every method is one Dask task (the same table; only the seconds
    differ).
    """
    from evaluation.cluster import parse_cluster
    from evaluation.slam_benchmark import SlamSource, benchmark
    from evaluation.slam_input import warn_without_odometry
    from evaluation.slam_methods import parse_methods
    from evaluation.slam_report import json_document, summary_lines, table_rows, write_outputs
    from slam.cli.common import print_json
    from slam.config import PipelineConfig
    from slam.config_io import apply_overrides, load_config
    from slam.odometry import FRONT_ENDS

    names = parse_methods(methods)
    parse_cluster(cluster)  # a bad --cluster fails before the log is read
    if reference is not None and reference_from_log:
        raise UserError("give either --reference FILE or --reference-from-log, not both")
    if out is not None:
        output_dir(out)  # a bad --out fails now, not after the runs
    cfg = load_config(PipelineConfig, config) if config else PipelineConfig()
    cfg = apply_overrides(cfg, overrides or [])
    if cfg.odometry not in FRONT_ENDS:
        raise UserError(f"unknown odometry {cfg.odometry!r}; choose {', '.join(FRONT_ENDS)}")
    source = SlamSource(
        str(input), limit=limit, odometry_noise=odometry_noise, topic=topic,
        odom_topic=odom_topic, strict=strict,
        relations=str(relations) if relations is not None else None,
        reference=str(reference) if reference is not None else None,
        reference_from_log=reference_from_log, folder=str(Path.cwd()),
    )
    if cluster is not None and out is not None:
        out = out.resolve()  # the workers write into it from their own folders
    run = dict(source=source, out=out, write_map=not no_map)
    with stage_progress("scans", label_width=9, remaining=True) as update:
        context = source.open(progress=update)
        warn_without_odometry(context.data, names)
        if cluster is None:
            bench = benchmark(context, names, cfg, progress=update, **run)
    if cluster is not None:
        bench = benchmark(context, names, cfg, cluster=cluster, **run)
    paths = write_outputs(bench) if out is not None else {}
    if json:
        doc = json_document(bench)
        if paths:
            doc["outputs"] = {k: str(v) for k, v in paths.items()}
        print_json(doc)
        return
    headers, rows = table_rows(bench)
    print_table(f"bench slam: {input.name}", headers, rows, width=160)
    for line in summary_lines(bench):
        typer.echo(line)
    if paths:
        typer.echo(f"report: {paths['report']}")


def register(bench: typer.Typer) -> None:
    """Add ``slam`` to the ``bench`` command group."""
    bench.command("slam")(slam)
