"""`loopclosure eval ...` and `loopclosure bench ...`: registered through an entry point.

`register(app)` adds two command groups to the main app, and the demo report to
`loopclosure run` (`evaluation.demo_report`, through the run-reporter hook of
`slam.cli.run_command`); `slam` never imports this module (it sits above `slam` in
the dependency order).  Every `eval` command prints a summary (``--json``: one JSON
object) and, with ``--out DIR``, writes ``report.md``, ``results.json`` and PNG
plots into DIR.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer

from evaluation.cli_options import JsonOption, OutOption
from evaluation.cluster import ClusterOption
from slam.cli.common import print_json
from slam.json_io import write_json

eval_app = typer.Typer(
    help="Measure a result: relations metric, ATE/RPE, robustness to false loops.",
    no_args_is_help=True,
)
bench_app = typer.Typer(
    help="Run a benchmark end to end: place recognition, stripes, landmarks, SLAM.",
    no_args_is_help=True,
)


def _ready(out: Path | None) -> Path | None:
    """`out` made ready for writing (`data.atomic_write.output_dir`), or None."""
    from data.atomic_write import output_dir

    return None if out is None else output_dir(out)


@eval_app.command("relations")
def eval_relations(
    trajectory: Annotated[Path, typer.Option("--trajectory", help="Estimated trajectory (TUM).")],
    relations: Annotated[
        Path, typer.Option("--relations", help="Relations file (t1 t2 x y z roll pitch yaw).")
    ],
    tolerance: Annotated[
        float, typer.Option("--tolerance", help="Stamp match tolerance, seconds.")
    ] = 1e-3,
    json: JsonOption = False,
    out: OutOption = None,
) -> None:
    """Relation-based error (Kümmerle et al. 2009) as Cartographer computes it."""
    from data.errors import UserError, warn
    from data.relations import read_relations
    from data.trajectory_io import read_tum
    from evaluation.relations_metric import relations_metric

    traj = read_tum(trajectory)
    rels = read_relations(relations)
    metric = relations_metric(traj, rels, tolerance)
    if metric.relations_used == 0:
        raise UserError(
            f"{relations}: none of its {len(rels)} relations has both stamps in {trajectory} "
            f"(within {tolerance * 1e3:g} ms)"
        )
    skipped = metric.relations_total - metric.relations_used
    if skipped:
        warn(
            f"{relations}: {skipped} of {metric.relations_total} relations have a stamp not in "
            f"{trajectory} (within {tolerance * 1e3:g} ms): skipped"
        )
    summary = metric.to_json()
    if _ready(out):
        from evaluation.plots import plot_histogram
        from evaluation.report import image, key_values, write_report

        h1 = plot_histogram(out / "relations_translation.png", metric.trans_errors,
                            "translational error [m]", "relations: translational error")
        h2 = plot_histogram(out / "relations_rotation.png", metric.rot_errors_deg,
                            "rotational error [deg]", "relations: rotational error")
        write_json(out / "results.json", summary)
        write_report(out / "report.md", "Relations metric", [
            ("Inputs", f"trajectory `{trajectory}`, relations `{relations}`"),
            ("Result (Cartographer's compute_relations_metrics)",
             "```\n" + metric.cartographer_text() + "\n```\n\n" + key_values(summary)),
            ("Distributions", image(h1, out) + "\n" + image(h2, out)),
        ])
    if json:
        print_json(summary)
    else:
        typer.echo(metric.cartographer_text())
        typer.echo(f"relations used {metric.relations_used} of {metric.relations_total}")


@eval_app.command("ate")
def eval_ate(
    trajectory: Annotated[Path, typer.Option("--trajectory", help="Estimated trajectory (TUM).")],
    reference: Annotated[Path, typer.Option("--reference", help="Reference trajectory (TUM).")],
    max_diff: Annotated[
        float, typer.Option("--max-diff", help="Stamp association tolerance, seconds.")
    ] = 0.01,
    delta: Annotated[float, typer.Option("--delta", help="RPE step.")] = 1.0,
    delta_unit: Annotated[
        str, typer.Option("--delta-unit", help="RPE step unit: frames or m.")
    ] = "frames",
    align: Annotated[bool, typer.Option("--align/--no-align", help="Rigid alignment.")] = True,
    scale: Annotated[bool, typer.Option("--scale", help="Also align scale (Sim3).")] = False,
    json: JsonOption = False,
    out: OutOption = None,
) -> None:
    """Absolute trajectory error after alignment, and relative pose error (as evo)."""
    from data.trajectory_io import read_tum
    from evaluation.trajectory_error import trajectory_errors

    est = read_tum(trajectory)
    ref = read_tum(reference)
    errors = trajectory_errors(
        est, ref, max_diff=max_diff, align=align, with_scale=scale,
        rpe_delta=delta, rpe_unit=delta_unit,
    )
    summary = errors.to_json()
    if _ready(out):
        from evaluation.plots import plot_error_series, plot_trajectories
        from evaluation.report import image, key_values, write_report

        p1 = plot_trajectories(out / "trajectories.png", {
            "reference": ref.poses[:, :2, 3], "estimate (aligned)": errors.aligned.poses[:, :2, 3],
        }, "trajectories")
        p2 = plot_error_series(out / "ate.png", errors.aligned.stamps, errors.ate_errors,
                               "ATE [m]", "absolute trajectory error")
        write_json(out / "results.json", summary)
        write_report(out / "report.md", "Trajectory error", [
            ("Inputs", f"estimate `{trajectory}`, reference `{reference}`"),
            ("Result", key_values(summary)),
            ("Plots", image(p1, out) + "\n" + image(p2, out)),
        ])
    if json:
        print_json(summary)
    else:
        typer.echo(
            f"ATE rmse {errors.ate_rmse:.4f} m (mean {errors.ate_mean:.4f}, max "
            f"{errors.ate_max:.4f}) over {errors.matched} poses; RPE rmse "
            f"{errors.rpe_trans_rmse:.4f} m / {errors.rpe_rot_rmse_deg:.3f} deg "
            f"over {errors.rpe_pairs} pairs"
        )


def _percent_list(text: str, name: str) -> list[float]:
    from data.errors import UserError

    try:
        values = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise UserError(f"{name} must be comma-separated numbers, got {text!r}") from None
    if not values or any(v < 0 or v >= 100 for v in values):
        raise UserError(f"{name} must be percentages in [0, 100), got {text!r}")
    return [v / 100.0 for v in values]


def _robustness_on_cluster(
    g2o: Path, graph: Any, ratios: list[float], kernels: list[str], seed: int,
    policies: list[str], group_size: int, odometry_scale: float, cluster: str,
) -> list[Any]:
    """`run_robustness`'s results, one Dask task per cell (`evaluation.cluster`)."""
    from data.errors import UserError
    from evaluation.cluster import map_tasks
    from evaluation.robustness import robustness_cells, robustness_task

    cells = robustness_cells(str(g2o.resolve()), graph, ratios, kernels, seed=seed,
                             policies=policies, group_size=group_size,
                             odometry_scale=odometry_scale)
    results = []
    for outcome in map_tasks(robustness_task, cells, cluster=cluster,
                             description="robustness"):
        if outcome.status != "done":
            c = outcome.item
            raise UserError(f"robustness cell {c.kernel}, {c.policy} at "
                            f"{100 * c.ratio:.0f}%: {outcome.error}")
        results.append(outcome.value)
    return results


@eval_app.command("robustness")
def eval_robustness(
    g2o: Annotated[Path, typer.Option("--g2o", help="Pose graph (g2o) with true loop edges.")],
    outliers: Annotated[
        str, typer.Option("--outliers", help="False loops as % of loop edges, e.g. 0,10,50.")
    ] = "0,10,25,50",
    kernels: Annotated[
        str,
        typer.Option("--kernels", help="Any of none,huber,cauchy,dcs,gemanmcclure,gnc."),
    ] = "cauchy,dcs,gnc",
    seed: Annotated[int, typer.Option("--seed", help="Seed of the false-loop injection.")] = 0,
    policy: Annotated[
        str,
        typer.Option("--policy", help="False-loop policy: random, local, grouped, local-grouped "
                     "(several with a comma)."),
    ] = "random",
    group_size: Annotated[
        int, typer.Option("--group-size", help="False loops per group (grouped policies).")
    ] = 10,
    odometry_scale: Annotated[
        float, typer.Option("--odometry-scale", help="Factor on the odometry information "
                            "(below 1: looser odometry).")
    ] = 1.0,
    cluster: ClusterOption = None,
    json: JsonOption = False,
    out: OutOption = None,
) -> None:
    """Inject false loop closures and measure each kernel's ATE against the clean optimum.

    With ``--cluster`` every policy x ratio x kernel cell is one Dask task (the same
    figures as the serial run; only the seconds differ).
    """
    from rich.progress import Progress, TimeElapsedColumn

    from data.errors import UserError
    from data.g2o import read_g2o
    from evaluation.cluster import parse_cluster
    from evaluation.outlier_policies import parse_policies
    from evaluation.robustness import run_robustness
    from slam.pose_graph import PoseGraph

    ratios = _percent_list(outliers, "--outliers")
    names = [k.strip() for k in kernels.split(",") if k.strip()]
    policies = parse_policies(policy)
    if group_size < 1:
        raise UserError(f"--group-size must be at least 1, got {group_size}")
    if not odometry_scale > 0:
        raise UserError(f"--odometry-scale must be positive, got {odometry_scale}")
    if cluster is not None:
        parse_cluster(cluster)  # a bad --cluster fails before the clean optimum is solved
    graph = PoseGraph.from_g2o(read_g2o(g2o))
    if cluster is not None:
        results = _robustness_on_cluster(g2o, graph, ratios, names, seed, policies,
                                         group_size, odometry_scale, cluster)
    else:
        with Progress(*Progress.get_default_columns(), TimeElapsedColumn(),
                      transient=True) as bar:
            task = bar.add_task("robustness", total=len(policies) * len(ratios) * len(names))

            def step(message: str) -> None:
                bar.update(task, description=message)
                bar.advance(task)

            results = run_robustness(graph, ratios, names, seed=seed, policies=policies,
                                     group_size=group_size, odometry_scale=odometry_scale,
                                     progress=step)
    rows = [r.to_json() for r in results]
    summary = {"g2o": str(g2o), "seed": seed, "policies": policies, "group_size": group_size,
               "odometry_scale": odometry_scale, "results": rows}
    if _ready(out):
        from evaluation.plots import plot_robustness
        from evaluation.report import image, table, write_report

        lines = [{**r, "kernel": f"{r['kernel']} ({r['policy']})"} for r in rows]
        plot = plot_robustness(out / "robustness.png", lines, f"robustness: {g2o.name}")
        write_json(out / "results.json", summary)
        headers = ["policy", "kernel", "false loops [%]", "false loops", "ATE vs clean [m]",
                   "false obeyed", "true rejected", "seconds"]
        body = [[r["policy"], r["kernel"], 100 * r["outlier_ratio"], r["false_loops"],
                 r["ate_vs_clean_m"],
                 r["false_factors_obeyed"], r["true_factors_rejected"], r["seconds"]] for r in rows]
        write_report(out / "report.md", f"Robustness to false loop closures: {g2o.name}", [
            ("Protocol", "See `evaluation/robustness.py` and `evaluation/outlier_policies.py`: "
             f"policies {', '.join(policies)} (group size {group_size}), odometry information "
             f"x{odometry_scale:g}; false loops carry the information of random true loops; "
             "each kernel starts from odometry; ATE is against the outlier-free optimum after "
             "rigid alignment."),
            ("Results", table(headers, body)),
            ("Plot", image(plot, out)),
        ])
    if json:
        print_json(summary)
    else:
        for r in rows:
            typer.echo(
                f"{r['policy']:>13} {r['kernel']:>13} {100 * r['outlier_ratio']:5.1f}% false: "
                f"ATE vs clean "
                f"{r['ate_vs_clean_m']:.4f} m, {r['false_factors_obeyed']} false obeyed, "
                f"{r['true_factors_rejected']} true rejected, {r['seconds']:.1f} s"
            )


def register(app: typer.Typer) -> None:
    """Add the `eval` and `bench` command groups to `app`, and the demo report to `run`."""
    from evaluation import cli_batch, cli_loops, cli_places, cli_slam, cli_stripes
    from evaluation.demo_report import demo_reporter
    from slam.cli.run_command import add_run_reporter

    add_run_reporter("demo", demo_reporter)
    cli_places.register(bench_app)
    cli_stripes.register(bench_app)
    cli_slam.register(bench_app)
    cli_loops.register(bench_app)
    cli_batch.register(app)
    app.add_typer(eval_app, name="eval")
    app.add_typer(bench_app, name="bench")
