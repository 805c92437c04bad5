"""`loopclosure batch INPUT... --out DIR`: map many logs or bags, serially or on Dask.

Each input goes into ``DIR/<name>/`` with the files of `loopclosure run`
(`evaluation.batch`); ``DIR/batch.json`` and ``DIR/batch.md`` hold one row per input.
``--cluster`` (`evaluation.cluster`) runs the inputs on a Dask cluster; the table
is the same.  Exit status: 0 when every input was mapped, 1 when any failed (its
row holds the error line), 130 when Ctrl-C stopped the batch (the rows of the
inputs finished by then are written, the others are marked ``interrupted``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from evaluation.cli_options import (
    ConfigOption,
    JsonOption,
    LimitOption,
    OverridesOption,
    TopicOption,
)
from evaluation.cluster import ClusterOption, parse_cluster
from slam.cli.common import print_json

EXIT_FAILED = 1
EXIT_INTERRUPTED = 130


def batch(
    inputs: Annotated[
        list[str],
        typer.Argument(help="CARMEN logs or ROS bags: files, folders of them, or patterns."),
    ],
    out: Annotated[Path, typer.Option("--out", help="Output folder (one subfolder per input).")],
    cluster: ClusterOption = None,
    config: ConfigOption = None,
    overrides: OverridesOption = None,
    odometry: Annotated[
        str | None, typer.Option("--odometry", help="Front end: icp2d, kiss-icp or wheel.")
    ] = None,
    topic: TopicOption = None,
    odom_topic: Annotated[
        str | None, typer.Option("--odom-topic", help="nav_msgs/Odometry topic of a bag.")
    ] = None,
    relations_dir: Annotated[
        Path | None,
        typer.Option("--relations-dir", help="Folder of <name>.relations files: the "
                     "relations error of each input that has one."),
    ] = None,
    reference_dir: Annotated[
        Path | None,
        typer.Option("--reference-dir", help="Folder of <name>.tum reference trajectories: "
                     "the ATE of each input that has one."),
    ] = None,
    limit: LimitOption = None,
    no_map: Annotated[bool, typer.Option("--no-map", help="Skip the occupancy maps.")] = False,
    strict: Annotated[bool, typer.Option("--strict", help="Malformed input is an error.")] = False,
    json: JsonOption = False,
) -> None:
    """Map many logs or bags, each as `loopclosure run` would; a table of all the runs."""
    from data.atomic_write import output_dir
    from data.errors import UserError
    from evaluation.batch import expand_inputs, make_jobs, run_batch, write_batch
    from slam.cli.run_command import _config

    parse_cluster(cluster)  # a bad --cluster fails before anything is written
    if limit is not None and limit < 1:
        raise UserError(f"--limit must be at least 1, got {limit}")
    cfg = _config(config, odometry, overrides)
    paths = expand_inputs(inputs)
    output_dir(out)
    jobs = make_jobs(paths, out, cfg, relations_dir=relations_dir, reference_dir=reference_dir,
                     topic=topic, odom_topic=odom_topic, strict=strict, write_map=not no_map,
                     limit=limit)
    result = run_batch(jobs, cluster)
    json_path, md_path = write_batch(out, result)
    if json:
        print_json(result.to_json())
    else:
        for r in result.rows:
            typer.echo(_line(r))
        typer.echo(f"{len(result.rows) - result.failed} of {len(result.rows)} inputs mapped in "
                   f"{result.wall_s:.1f} s ({result.cluster}); table in {md_path}, "
                   f"rows in {json_path}")
    if result.interrupted:
        raise typer.Exit(EXIT_INTERRUPTED)
    if result.failed:
        for r in result.rows:
            if r["status"] == "failed":
                typer.echo(f"error: {r['error']}", err=True)
        raise typer.Exit(EXIT_FAILED)


def _line(row: dict) -> str:
    if row["status"] != "done":
        return f"{row['name']}: {row['status']}: {row['error']}"
    text = (f"{row['name']}: {row['scans']} scans, {row['keyframes']} keyframes, "
            f"{row['loops_accepted']} loops, {row['wall_s']:.1f} s, "
            f"peak {row['peak_rss_mb']:.0f} MB")
    if row["relations"]:
        text += (f", relations {row['relations']['trans_abs_mean']:.4f} m / "
                 f"{row['relations']['rot_abs_mean_deg']:.3f} deg")
    if row["ate"]:
        text += f", ATE {row['ate']['rmse_m']:.4f} m"
    if row["eval_error"]:
        text += f" (not evaluated: {row['eval_error']})"
    return text


def register(app: typer.Typer) -> None:
    """Add `batch` to `app`."""
    app.command("batch")(batch)
