"""`loopclosure bench loops`: appearance-only loop detection per stage, the literature's way.

``register(bench)`` adds the ``loops`` command to the ``bench`` command group (wired in
by `evaluation.cli`).  Contract::

    loopclosure bench loops [INPUT] (--relations FILE | --reference TUM |
        --reference-from-log --odometry-noise SEED) [--world box|surface] [--seed N]
        [--stages fft,ring,prefilter,flirt,mrm,fused,flirt-alone] [--max-queries N]
        [--config FILE] [--set key=value ...] [--limit N] [--min-coverage F]
        [--out DIR] [--json] [--cluster ADDRESS]

Without INPUT (or with ``--world``) the simulated world of the embedded demo is
mapped (``box`` by default; the demo's 180-degree laser) and its ground truth is the
reference.  The runner is `evaluation.loop_bench` (protocol in its docstring), the
measures `evaluation.loop_bench_truth`, the table, JSON document and output folder
`evaluation.loop_bench_report`.  ``--json`` prints one object with ``queries``,
``revisits``, ``stages``, ``final`` and ``recall_at_k``.  ``--cluster``
(`evaluation.cluster`) runs each stage block (the unit of work: the cascade, and each
``NAME-alone`` row) as one Dask task; the rows are the same.  Progress bars go to stderr.
Bad input (no reference for a log, two references, a reference covering too few
keyframes, an unknown stage) raises `UserError` (one ``error:`` line, exit 2).
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
from evaluation.loop_bench_input import relations_reference_fn, trajectory_reference_fn
from slam.cli.common import stage_progress

_relations_fn = relations_reference_fn  # the names other scripts import
_trajectory_fn = trajectory_reference_fn


def loops(
    input: Annotated[
        Path | None, typer.Argument(help="CARMEN log or ROS bag (none: a simulated world).")
    ] = None,
    relations: RelationsOption = None,
    reference: ReferenceOption = None,
    reference_from_log: ReferenceFromLogOption = False,
    odometry_noise: OdometryNoiseOption = None,
    world: Annotated[
        str | None, typer.Option("--world", help="Simulated world: box or surface.")
    ] = None,
    seed: Annotated[int, typer.Option("--seed", help="Seed of the simulated world.")] = 0,
    stages: Annotated[
        str | None,
        typer.Option("--stages", help="Comma-separated rows: fft,ring,prefilter, the verifiers, "
                     "fused, NAME-alone (e.g. flirt-alone); default all of them."),
    ] = None,
    max_queries: Annotated[
        int | None,
        typer.Option("--max-queries", help="Query only N keyframes, spread evenly (quick runs)."),
    ] = None,
    min_coverage: Annotated[
        float, typer.Option("--min-coverage", help="Least fraction of keyframes the reference "
                            "must cover.")
    ] = 0.5,
    config: ConfigOption = None,
    overrides: OverridesOption = None,
    limit: LimitOption = None,
    topic: TopicOption = None,
    out: Annotated[
        Path | None,
        typer.Option("--out", help="Folder for report.md, results.json, queries.csv, plots."),
    ] = None,
    cluster: ClusterOption = None,
    json: JsonOption = False,
) -> None:
    """Appearance-only loop detection per stage: recall at 100%/99% precision, AP, recall@K.

    With ``--cluster`` every stage block (the cascade, each NAME-alone row) is one Dask
    task (the same rows; only the seconds differ).
    """
    from evaluation.cluster import parse_cluster
    from evaluation.loop_bench import loop_benchmark, parse_stages
    from evaluation.loop_bench_input import LoopSource
    from evaluation.loop_bench_report import json_document, summary_lines, table_rows
    from slam.config import PipelineConfig
    from slam.config_io import apply_overrides, load_config

    parse_cluster(cluster)  # a bad --cluster fails before any work
    given = [relations is not None, reference is not None, reference_from_log]
    if sum(given) > 1:
        raise UserError("give one of --relations, --reference and --reference-from-log")
    if input is not None and world is not None:
        raise UserError("give either INPUT or --world, not both")
    if input is not None and not any(given):
        raise UserError(f"{input}: bench loops needs a reference: --relations FILE, "
                        "--reference TUM or --reference-from-log --odometry-noise SEED")
    if input is None and any(given):
        raise UserError("--relations, --reference and --reference-from-log need an INPUT log")
    if not 0.0 < min_coverage <= 1.0:
        raise UserError(f"--min-coverage must be in (0, 1], got {min_coverage}")
    if out is not None:
        output_dir(out)  # a bad --out fails now, not after the run
    cfg = load_config(PipelineConfig, config) if config else PipelineConfig()
    cfg = apply_overrides(cfg, overrides or [])
    rows = parse_stages(stages, cfg)
    source = LoopSource(
        str(input) if input is not None else None, world=world, seed=seed, limit=limit,
        odometry_noise=odometry_noise, topic=topic,
        relations=str(relations) if relations is not None else None,
        reference=str(reference) if reference is not None else None,
        reference_from_log=reference_from_log, folder=str(Path.cwd()),
    )
    run = dict(stages=rows, max_queries=max_queries, min_coverage=min_coverage, source=source)
    with stage_progress(label_width=8, remaining=True) as update:
        inp = source.open(progress=update)
        if cluster is None:
            bench = loop_benchmark(inp, cfg, progress=update, **run)
    if cluster is not None:
        bench = loop_benchmark(inp, cfg, cluster=cluster, **run)
    label = inp.label
    paths: dict[str, Path] = {}
    if out is not None:
        from evaluation.loop_bench_report import write_outputs

        paths = write_outputs(bench, out)
    if json:
        from slam.cli.common import print_json

        doc = json_document(bench)
        if paths:
            doc["outputs"] = {k: str(v) for k, v in paths.items()}
        print_json(doc)
        return
    from evaluation.loop_bench_report import TABLE_HEADERS

    print_table(f"bench loops: {Path(label).name}", TABLE_HEADERS, table_rows(bench), width=120)
    for line in summary_lines(bench):
        typer.echo(line)
    if paths:
        typer.echo(f"report: {paths['report']}")


def register(bench: typer.Typer) -> None:
    """Add ``loops`` to the ``bench`` command group."""
    bench.command("loops")(loops)
