"""`loopclosure bench loops`: appearance-only loop detection per stage, the literature's way.

``register(bench)`` adds the ``loops`` command to the ``bench`` command group (wired in
by `evaluation.cli`).  Contract::

    loopclosure bench loops [INPUT] (--relations FILE | --reference TUM |
        --reference-from-log --odometry-noise SEED) [--world box|surface] [--seed N]
        [--stages fft,ring,prefilter,flirt,mrm,fused,flirt-alone] [--max-queries N]
        [--config FILE] [--set key=value ...] [--limit N] [--min-coverage F]
        [--out DIR] [--json]

Without INPUT (or with ``--world``) the simulated world of the embedded demo is
mapped (``box`` by default; the demo's 180-degree laser) and its ground truth is the
reference.  The runner is `evaluation.loop_bench` (protocol in its docstring), the
measures `evaluation.loop_bench_truth`, the table, JSON document and output folder
`evaluation.loop_bench_report`.  ``--json`` prints one object with ``queries``,
``revisits``, ``stages``, ``final`` and ``recall_at_k``.  Progress bars go to stderr.
Bad input (no reference for a log, two references, a reference covering too few
keyframes, an unknown stage) raises `UserError` (one ``error:`` line, exit 2).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import numpy as np
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
from slam.cli.common import stage_progress


def _relations_fn(data: Any, relations: Path) -> Any:
    """Reference of the keyframes from relations (`relations_reference`; NaN = none)."""
    from data.relations import read_relations
    from evaluation.slam_reference import relations_in_range, relations_reference

    rels = read_relations(relations)
    used = relations_in_range(rels, data.stamps)
    if not used:
        raise UserError(f"{relations}: none of its {len(rels)} relations has both stamps "
                        f"among the {len(data.scans)} scans read")

    def reference(result: Any) -> np.ndarray:
        kf = [k.scan_index for k in result.keyframes]
        ref = relations_reference(data.stamps, used, kf, result.odometry_poses)
        out = np.full((len(kf), 3), np.nan)
        pos = {int(s): i for i, s in enumerate(ref.scan_index)}
        for i, s in enumerate(kf):
            if s in pos:
                out[i] = ref.poses[pos[s]]
        return out

    return reference


def _trajectory_fn(data: Any, trajectory: Any) -> Any:
    """Reference of the keyframes from a trajectory stamped like the scans."""
    from evaluation.slam_input import evaluation_stamps
    from evaluation.slam_reference import keyframe_reference

    stamps, _ = evaluation_stamps(data.stamps)

    def reference(result: Any) -> np.ndarray:
        kf = [k.scan_index for k in result.keyframes]
        ref = keyframe_reference(trajectory, stamps, kf)
        out = np.full((len(kf), 3), np.nan)
        pos = {int(s): i for i, s in enumerate(ref.stamps.astype(int))}
        xyt = ref.xytheta()
        for i, s in enumerate(kf):
            if s in pos:
                out[i] = xyt[pos[s]]
        return out

    return reference


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
    json: JsonOption = False,
) -> None:
    """Appearance-only loop detection per stage: recall at 100%/99% precision, AP, recall@K."""
    from evaluation.loop_bench import parse_stages, run_loop_bench
    from evaluation.loop_bench_report import json_document, summary_lines, table_rows
    from slam.config import PipelineConfig
    from slam.config_io import apply_overrides, load_config

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
    with stage_progress(label_width=8, remaining=True) as update:
        if input is None:
            from data.sim import simulate_run
            from data.sim.run import check_world
            from slam.cli.run_command import DEMO_SENSOR

            name = check_world(world or "box")
            run = simulate_run(name, seed=seed, **DEMO_SENSOR)
            truth = run.ground_truth.xytheta()
            scans: list[Any] = run.scans[:limit] if limit else run.scans
            label = f"simulated {name} world (seed {seed})"

            def ref_fn(result: Any) -> np.ndarray:
                return truth[[k.scan_index for k in result.keyframes]]
        else:
            from data.trajectory_io import read_tum
            from evaluation.slam_input import load_input
            from evaluation.slam_reference import logged_reference

            data = load_input(input, limit=limit, odometry_noise=odometry_noise, topic=topic,
                              progress=update)
            scans, label = data.scans, str(input)
            if relations is not None:
                ref_fn = _relations_fn(data, relations)
            elif reference is not None:
                ref_fn = _trajectory_fn(data, read_tum(reference))
            else:
                ref_fn = _trajectory_fn(data, logged_reference(data))
        bench = run_loop_bench(label, scans, cfg, ref_fn, stages=rows, max_queries=max_queries,
                               min_coverage=min_coverage, progress=update)
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
