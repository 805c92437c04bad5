"""`loopclosure run`: map a log or bag (or the embedded simulated demo) and write the results."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer

from slam.cli.common import print_json, write_json

DEMO_SENSOR = {"fov_deg": 180.0, "beams": 181, "max_range": 12.0, "noise_sigma": 0.02}
"""The demo's laser: a SICK-like 180-degree scanner (the simulator's default is 360)."""


def run(
    input: Annotated[
        Path | None,
        typer.Argument(help="CARMEN log or ROS bag; omit to run the embedded simulated demo."),
    ] = None,
    out: Annotated[Path, typer.Option("--out", help="Output folder.")] = Path("out"),
    topic: Annotated[str | None, typer.Option("--topic", help="Scan topic of a bag.")] = None,
    odom_topic: Annotated[
        str | None, typer.Option("--odom-topic", help="nav_msgs/Odometry topic of a bag.")
    ] = None,
    odometry: Annotated[
        str | None, typer.Option("--odometry", help="Front end: icp2d, kiss-icp or wheel.")
    ] = None,
    config: Annotated[
        Path | None, typer.Option("--config", help="YAML file of parameters (config.yaml).")
    ] = None,
    overrides: Annotated[
        list[str] | None,
        typer.Option("--set", help="Override one parameter, e.g. --set loops.local_max=2."),
    ] = None,
    no_map: Annotated[bool, typer.Option("--no-map", help="Skip the occupancy map.")] = False,
    strict: Annotated[bool, typer.Option("--strict", help="Malformed input is an error.")] = False,
    json: Annotated[bool, typer.Option("--json", help="Print summary.json on stdout.")] = False,
) -> None:
    """Map a log or bag: trajectory, pose graph, loop closures, occupancy map, summary."""
    from data.errors import UserError
    from slam.config import PipelineConfig
    from slam.config_io import apply_overrides, dump_config, load_config
    from slam.pipeline import Mapper

    cfg = load_config(PipelineConfig, config) if config else PipelineConfig()
    if odometry:
        overrides = [f"odometry={odometry}", *(overrides or [])]
    cfg = apply_overrides(cfg, overrides or [])
    from slam.odometry import FRONT_ENDS

    if cfg.odometry not in FRONT_ENDS:
        raise UserError(f"unknown odometry {cfg.odometry!r}; choose {', '.join(FRONT_ENDS)}")
    out.mkdir(parents=True, exist_ok=True)
    dump_config(cfg, out / "config.yaml")

    demo = None
    if input is None:
        from data.sim import simulate_run

        typer.echo("no input given: running the embedded demo (simulated box world)", err=True)
        demo = simulate_run("box", seed=0, **DEMO_SENSOR)
        scans: Any = demo.scans
        total = len(demo.scans)
        source_name = "simulated box world (seed 0)"
    else:
        from data.sources import open_source

        source = open_source(input, topic=topic, odom_topic=odom_topic, strict=strict)
        total = source.info().scans
        scans = source
        source_name = str(input)

    start = time.perf_counter()
    mapper = Mapper(cfg)
    result = _run_with_progress(mapper, scans, total)
    from slam.results import write_results

    summary = write_results(
        out, result, source_name, wall_s=time.perf_counter() - start, write_map=not no_map,
        map_config=cfg.map,
    )
    if demo is not None:
        summary["demo"] = _demo_report(result, demo)
        write_json(out / "summary.json", summary)
    if json:
        print_json(summary)
    else:
        _print_summary(summary, out)


def _run_with_progress(mapper: Any, scans: Any, total: int | None) -> Any:
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    columns = [
        TextColumn("mapping"), BarColumn(), MofNCompleteColumn(),
        TextColumn("scans  {task.fields[kf]} keyframes  {task.fields[loops]} loops"),
        TimeElapsedColumn(), TimeRemainingColumn(),
    ]
    with Progress(*columns, transient=True) as bar:
        task = bar.add_task("mapping", total=total, kf=0, loops=0)

        def progress(n: int, keyframes: int, loops: int) -> None:
            if n % 10 == 0 or n == total:
                bar.update(task, completed=n, kf=keyframes, loops=loops)

        return mapper.run(scans, progress=progress)


def _demo_report(result: Any, demo: Any) -> dict[str, Any]:
    """ATE before/after loop closure and loop precision/recall against ground truth."""
    from data.types import Trajectory
    from evaluation.loop_metrics import LoopProposal, evaluate_loops
    from evaluation.trajectory_error import trajectory_errors

    gt = demo.ground_truth
    after = trajectory_errors(Trajectory.from_xytheta(result.scan_stamps, result.scan_poses), gt)
    before = trajectory_errors(
        Trajectory.from_xytheta(result.scan_stamps, result.odometry_poses), gt
    )
    proposals = [
        LoopProposal(e.stamp_match, e.stamp_query, e.candidate.relative,
                     e.candidate.verification.fitness if e.candidate.verification else 0.0,
                     e.candidate.accepted and not e.rejected_by_gnc)
        for e in result.loops
    ]
    stamps = np.array([k.stamp for k in result.keyframes])
    loops = evaluate_loops(proposals, gt, stamps)
    return {
        "ate_before_loop_closure_m": before.ate_rmse,
        "ate_after_loop_closure_m": after.ate_rmse,
        "loop_precision": loops.precision,
        "loop_recall": loops.recall,
        "loops_true_positive": loops.true_positives,
        "loops_false_positive": loops.false_positives,
    }


def _print_summary(summary: dict[str, Any], out: Path) -> None:
    typer.echo(
        f"{summary['scans']} scans, {summary['keyframes']} keyframes, "
        f"{summary['loops_proposed']} loop candidates, {summary['loops_accepted']} accepted, "
        f"{summary['loops_rejected_by_gnc']} rejected by GNC; {summary['wall_s']:.1f} s, "
        f"peak {summary['peak_rss_mb']:.0f} MB"
        + ("  (interrupted)" if summary.get("interrupted") else "")
    )
    demo = summary.get("demo")
    if demo:
        typer.echo(
            f"ATE against ground truth: {demo['ate_before_loop_closure_m']:.4f} m before loop "
            f"closure, {demo['ate_after_loop_closure_m']:.4f} m after"
        )
        typer.echo(
            f"loop closures: precision {demo['loop_precision']:.3f}, recall "
            f"{demo['loop_recall']:.3f} ({demo['loops_true_positive']} true, "
            f"{demo['loops_false_positive']} false)"
        )
    typer.echo(f"results in {out}/")


def register(app: typer.Typer) -> None:
    """Add `run` to `app`."""
    app.command()(run)
