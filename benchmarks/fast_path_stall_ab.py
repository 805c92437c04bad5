"""Benchmark: the default robust back end on one cell with the fast path's first solve in
full (``old``) and given up at a stall (``new``, `slam.fast_path_screen.stalled_solve`),
in one process.

Run from the repository root::

    python benchmarks/fast_path_stall_ab.py input_M3500_g2o.g2o [--data DIR] [--scale 1]
        [--policy random] [--ratio 50] [--seed 0] [--cache DIR] [--order old,new]

``new`` replaces the solve of the stiffest rung of `slam.optimize._clean_optimum` (its
first call of `slam.least_squares.solve` in a run) by `stalled_solve`; when that gives up,
the rung is reported solved at its start (the odometry chain, where a loop is above ``c``:
checked), so the fast path fails there as the full solve's result would have it fail.
Prints for each: CPU seconds, ATE against the outlier-free optimum [m], false loops
obeyed, true loops rejected, solver; then whether both kept the same loops, the largest
position difference [m], the ATEs' difference [m] and the CPU ratio new / old.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import slam.clean_optimum as optimize_module  # the fast path's `solve` is patched
from benchmarks.robust_cell import cell_parser, read_cell
from evaluation.robustness import aligned_position_error
from slam.fast_path_screen import stalled_solve
from slam.innovation import tls_threshold
from slam.optimize import default_outlier_residual, optimize
from slam.pose_graph import RobustKernel, whitened_residual

FULL = optimize_module.solve


def main() -> None:
    parser = cell_parser(__doc__.split("\n")[0])
    parser.add_argument("--order", default="old,new")
    args = parser.parse_args()
    graph, reference, corrupted, is_false = read_cell(args)
    threshold = default_outlier_residual(graph.dim)
    c = tls_threshold(graph.dim)
    _, loop_index = corrupted.factor_graph(RobustKernel("none"))
    calls = {"n": 0, "given_up": 0}

    def first_stalled(factors, values, max_iterations, *rest, **kw):  # type: ignore[no-untyped-def]
        calls["n"] += 1
        if calls["n"] > 1:
            return FULL(factors, values, max_iterations, *rest, **kw)
        out = stalled_solve(factors, values, max_iterations, loop_index, c)
        if out is not None:
            return out
        calls["given_up"] += 1
        assert any(factors.at(k).error(values) > c for k in loop_index)
        return values, 0, "lm"

    results, ates, cpu = {}, {}, {}
    for name in args.order.split(","):
        optimize_module.solve = first_stalled if name == "new" else FULL  # type: ignore[assignment]
        calls.update(n=0, given_up=0)
        start = time.process_time()
        result = optimize(corrupted, "none", "gnc", init="odometry", gnc_start="incremental")
        cpu[name] = time.process_time() - start
        results[name] = result
        residuals = np.array([whitened_residual(k, result.poses, graph.dim)
                              for k in corrupted.loops])
        obeyed = residuals <= threshold
        ates[name] = aligned_position_error(result.poses, reference, graph.dim)
        print(f"{args.graph} x{args.scale:g} {args.policy} {args.ratio:g}% seed {args.seed} "
              f"{name}: ATE {ates[name]:.3g} m, {int((obeyed & is_false).sum())} false obeyed, "
              f"{int((~obeyed & ~is_false).sum())} true rejected, {cpu[name]:.1f} s CPU "
              f"({result.solver}; fast path given up early: {calls['given_up']})", flush=True)
    optimize_module.solve = FULL  # type: ignore[assignment]
    old, new = results["old"], results["new"]
    same = old.loop_outliers == new.loop_outliers and old.solver == new.solver
    diff = max(float(np.linalg.norm(old.poses[k][:2] - new.poses[k][:2])) for k in old.poses)
    print(f"same loops kept: {same}; largest position difference {diff:.3g} m; ATE "
          f"difference {abs(ates['new'] - ates['old']):.3g} m; CPU new/old "
          f"{cpu['new'] / cpu['old']:.2f} ({cpu['old']:.1f} -> {cpu['new']:.1f} s)", flush=True)


if __name__ == "__main__":
    main()
