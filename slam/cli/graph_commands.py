"""`loopclosure optimize`: optimise a g2o pose graph with a robust loop kernel or GNC."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import numpy as np
import typer

from slam.cli.common import print_json


def optimize(
    graph: Annotated[Path, typer.Argument(help="Input g2o file (SE2 or SE3).")],
    out: Annotated[Path, typer.Option("--out", help="Optimised g2o file to write.")],
    kernel: Annotated[
        str,
        typer.Option(
            "--kernel", help="Loop-closure kernel: none, huber, cauchy, dcs, gemanmcclure or gnc."
        ),
    ] = "cauchy",
    scale: Annotated[
        float | None, typer.Option("--scale", help="Kernel scale (whitened units).")
    ] = None,
    init: Annotated[
        str,
        typer.Option("--init", help="Initial guess: given, odometry or lago (2D; the default)."),
    ] = "auto",
    trajectory: Annotated[
        Path | None,
        typer.Option("--trajectory", help="Also write the optimised poses as TUM (stamp = id)."),
    ] = None,
    json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
) -> None:
    """Optimise a pose graph; loop edges (j != i + 1) get the robust kernel."""
    from data.g2o import read_g2o, write_g2o
    from data.trajectory_io import write_tum
    from data.types import Trajectory
    from slam.optimize import optimize as solve
    from slam.pose_graph import PoseGraph, RobustKernel

    data = read_g2o(graph)
    pose_graph = PoseGraph.from_g2o(data)
    method = "gnc" if kernel == "gnc" else "lm"
    robust = RobustKernel("none" if kernel == "gnc" else kernel, scale)
    if init == "auto":
        init = "lago" if pose_graph.dim == 2 else "given"
    result = solve(pose_graph, robust, method, init=init)
    write_g2o(out, pose_graph.to_g2o(result.poses))
    if trajectory is not None:
        keys = pose_graph.keys
        if pose_graph.dim == 2:
            traj = Trajectory.from_xytheta(keys, np.array([result.poses[k] for k in keys]))
        else:
            traj = Trajectory(np.array(keys, float), np.stack([result.poses[k] for k in keys]))
        write_tum(trajectory, traj)
    rejected = result.loop_outliers
    summary = {
        "input": str(graph),
        "output": str(out),
        "dim": pose_graph.dim,
        "vertices": len(pose_graph.initial),
        "odometry_edges": len(pose_graph.odometry),
        "loop_edges": len(pose_graph.loops),
        "kernel": kernel,
        "scale": robust.effective_scale if kernel not in ("none", "gnc") else None,
        "init": init,
        "solver": result.solver,
        "iterations": result.iterations,
        "initial_error": result.initial_error,
        "final_error": result.final_error,
        "loops_rejected": len(rejected),
        "rejected_loops": [[pose_graph.loops[i].i, pose_graph.loops[i].j] for i in rejected],
        "seconds": result.seconds,
    }
    if json:
        print_json(summary)
        return
    typer.echo(
        f"{summary['vertices']} poses, {summary['odometry_edges']} odometry and "
        f"{summary['loop_edges']} loop edges; kernel {kernel}, init {init}, solver "
        f"{result.solver}"
    )
    typer.echo(
        f"error {result.initial_error:.6g} -> {result.final_error:.6g} in {result.seconds:.2f} s; "
        f"{len(rejected)} loop edges rejected"
    )
    typer.echo(f"wrote {out}")


def register(app: typer.Typer) -> None:
    """Add the graph commands to `app`."""
    app.command()(optimize)
