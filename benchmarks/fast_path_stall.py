"""Benchmark: the fast path's first solve, in full and given up at a stall, on robustness cells.

Run from the repository root::

    python benchmarks/fast_path_stall.py CELL [CELL ...] [--data DIR] [--cache DIR]
        [--decreases 1e-2,1e-3,1e-4]

Each CELL is ``graph:scale:policy:ratio:seed`` (ratio in %), e.g.
``input_M3500_g2o.g2o:1:random:50:0``.  For each cell (`benchmarks.robust_cell.read_cell`)
the stiffest rung of the fast path's check (`slam.optimize._clean_optimum`: the graph with
every loop, odometry information x the largest factor of the ladder, from the odometry
chain) is solved twice in one process:

* ``old``: `slam.least_squares.solve`, with an iteration hook that records every LM
  iteration (total error before and after, relative decrease, loops above ``c``, CPU
  seconds so far): prints where `slam.fast_path_screen.stalled_solve`'s rule would fire
  for each relative decrease of ``--decreases`` and whether the full solve's result has a
  loop above ``c`` there (the fast path fails at this rung: giving up early changes
  nothing) or not (a change of result);
* ``new``: `slam.fast_path_screen.stalled_solve` at its default decrease, its CPU seconds
  and the ratio new / old; when it does not give up, whether its result equals the full
  solve's bit for bit.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import gtsam

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.robust_cell import fast_path_problem, read_cell
from slam.fast_path_screen import STALL_DECREASE, STALL_LAMBDA, stalled_solve
from slam.least_squares import lm_params, solve


def recorded_solve(factors, values, max_iterations, loop_index, c):  # type: ignore[no-untyped-def]
    """`solve` with the LM iterations recorded: (result, rows); each row is (iteration,
    error before, error after, relative decrease, loops above c, CPU seconds so far, LM's
    lambda)."""
    rows: list[tuple[int, float, float, float, int, float, float]] = []
    start = time.process_time()
    holder: dict[str, gtsam.LevenbergMarquardtOptimizer] = {}
    original = gtsam.LevenbergMarquardtOptimizer

    def hook(iteration: int, before: float, after: float) -> None:
        now = holder["lm"].values()
        above = int(sum(factors.at(k).error(now) > c for k in loop_index))
        rows.append((iteration, before, after, (before - after) / before, above,
                     time.process_time() - start, holder["lm"].lambda_()))

    def make(graph, vals, params):  # type: ignore[no-untyped-def]
        params.iterationHook = hook
        holder["lm"] = original(graph, vals, params)
        return holder["lm"]

    import slam.least_squares as least_squares
    least_squares.gtsam.LevenbergMarquardtOptimizer = make  # type: ignore[assignment]
    try:
        result = solve(factors, values, max_iterations)
    finally:
        least_squares.gtsam.LevenbergMarquardtOptimizer = original  # type: ignore[misc]
    return result, rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("cells", nargs="+")
    parser.add_argument("--data", default="../shared/data/g2o")
    parser.add_argument("--cache", type=Path, default=None)
    parser.add_argument("--decreases", default="1e-2,1e-3,1e-4")
    args = parser.parse_args()
    decreases = [float(x) for x in args.decreases.split(",")]
    _ = lm_params  # the settings both solves share
    for cell in args.cells:
        graph_name, scale, policy, ratio, seed = cell.split(":")
        ns = argparse.Namespace(graph=graph_name, data=args.data, scale=float(scale),
                                policy=policy, ratio=float(ratio), seed=int(seed),
                                cache=args.cache)
        _, _, corrupted, _ = read_cell(ns)
        c, rung, loop_index, values = fast_path_problem(corrupted)
        t0 = time.process_time()
        (result, iterations, used), rows = recorded_solve(rung, values, 100, loop_index, c)
        old_cpu = time.process_time() - t0
        fails = any(rung.at(k).error(result) > c for k in loop_index)
        print(f"{cell}: {len(loop_index)} loops, full solve {used} {iterations} iterations "
              f"{old_cpu:.2f} s CPU, final error {rung.error(result):.6g}, loops above c at "
              f"the end {sum(rung.at(k).error(result) > c for k in loop_index)} "
              f"({'fails' if fails else 'passes'} this rung)", flush=True)
        for x in decreases:
            fire = next((r for r in rows if r[0] >= 1 and 0.0 < r[3] < x
                         and r[6] <= STALL_LAMBDA and 2 * r[4] > len(loop_index)), None)
            if fire is None:
                print(f"  decrease {x:g}: never fires (result unchanged)")
            else:
                print(f"  decrease {x:g}: fires at LM iteration {fire[0]} ({fire[4]} above c, "
                      f"lambda {fire[6]:.2g}, "
                      f"{fire[5]:.2f} s CPU of {old_cpu:.2f}); "
                      f"{'same outcome (rung fails)' if fails else 'CHANGES THE OUTCOME'}")
        t0 = time.process_time()
        new = stalled_solve(rung, values, 100, loop_index, c)
        new_cpu = time.process_time() - t0
        if new is None:
            same = "given up" + ("" if fails else " (CHANGE)")
        else:
            same = ("not given up, " + ("the full solve's result bit for bit"
                    if new[0].equals(result, 0.0) and new[1:] == (iterations, used)
                    else "A DIFFERENT RESULT"))
        print(f"  new (decrease {STALL_DECREASE:g}): {new_cpu:.2f} s CPU, {same}; "
              f"CPU new/old {new_cpu / old_cpu:.3f}", flush=True)


if __name__ == "__main__":
    main()
