"""Benchmark: the fast path's first LM solve, iteration by iteration, with a CPU cap.

Run from the repository root::

    python benchmarks/fast_path_lm_trace.py GRAPH [--data DIR] [--cache DIR] [--scale S]
        [--policy P] [--ratio R] [--seed N] [--cap SECONDS] [--tries]

Solves the stiffest rung of the fast path's check (`slam.optimize._clean_optimum`: every
loop in, odometry information x the largest factor of `slam.consistency.ODOMETRY_LADDER`,
from the odometry chain) with `slam.least_squares.solve`'s LM settings, and prints after
every LM iteration: the total error before and after (gtsam units), the relative
decrease, LM's lambda after it, the number of damped linear solves the iteration made
(from lambda's change: gtsam multiplies it by the lambda factor after each rejected try
and divides it by that factor after the accepted one), the loops above ``c``, the CPU
seconds of the iteration, and what `slam.fast_path_screen.stalled_solve`'s LM rule tests
(`is_stall` at `STALL_DECREASE`, lambda at most `STALL_LAMBDA`, most loops above ``c``).
Also times one linearisation and one elimination (multifrontal Cholesky, no damping) of
the rung at the start, to split an iteration's cost.  `--cap`: CPU seconds at most
(`benchmarks.robust_cell.cpu_cap`).  `--tries`: gtsam's own TRYLAMBDA trace to stdout.
"""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path

import gtsam

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.robust_cell import CpuCapped, cell_parser, cpu_cap, fast_path_problem, read_cell
from slam.fast_path_screen import STALL_DECREASE, STALL_LAMBDA, is_stall
from slam.least_squares import lm_params


def main() -> None:
    parser = cell_parser(__doc__.splitlines()[0])
    parser.add_argument("--cap", type=float, default=300.0)
    parser.add_argument("--tries", action="store_true")
    parser.add_argument("--iterations", type=int, default=100)
    args = parser.parse_args()
    _, _, corrupted, is_false = read_cell(args)
    c, rung, loop_index, values = fast_path_problem(corrupted)
    loops = [rung.at(k) for k in loop_index]
    print(f"{args.graph} x{args.scale:g} {args.policy} {args.ratio:g}% s{args.seed}: "
          f"{len(values.keys())} poses, {len(loop_index)} loops ({int(is_false.sum())} false), "
          f"c = {c:.4g}, start error {rung.error(values):.6g}, loops above c at the start "
          f"{sum(f.error(values) > c for f in loops)}", flush=True)

    t0 = time.process_time()
    linear = rung.linearize(values)
    t1 = time.process_time()
    ordering = gtsam.Ordering.ColamdNonlinearFactorGraph(rung)
    linear.eliminateMultifrontal(ordering)
    t2 = time.process_time()
    print(f"one linearisation {t1 - t0:.2f} s CPU, one multifrontal Cholesky elimination "
          f"{t2 - t1:.2f} s CPU", flush=True)

    params = lm_params(args.iterations)
    if args.tries:
        params.setVerbosityLM("TRYLAMBDA")
    state = {"lambda": params.getlambdaInitial(), "cpu": time.process_time()}
    factor = params.getlambdaFactor()
    holder: list[gtsam.LevenbergMarquardtOptimizer] = []

    def hook(iteration: int, before: float, after: float) -> None:
        lm = holder[0]
        now = lm.values()
        above = sum(f.error(now) > c for f in loops)
        lam = lm.lambda_()
        # accepted try: lambda / factor; each rejected try before it: lambda * factor
        solves = round(math.log(lam / state["lambda"], factor)) + 2
        cpu = time.process_time()
        stall = is_stall(iteration, before, after, STALL_DECREASE)
        print(f"  it {iteration:3d}: error {before:.6g} -> {after:.6g} "
              f"(rel {(before - after) / before:.3g}), lambda {lam:.3g}, "
              f"{solves} linear solves, above c {above}/{len(loops)} "
              f"({'most' if 2 * above > len(loops) else 'not most'}), "
              f"{cpu - state['cpu']:.2f} s CPU; rule: decrease<{STALL_DECREASE:g} "
              f"{stall}, lambda<={STALL_LAMBDA:g} {lam <= STALL_LAMBDA} -> "
              f"{'FIRES' if stall and lam <= STALL_LAMBDA and 2 * above > len(loops) else '-'}",
              flush=True)
        state["lambda"], state["cpu"] = lam, cpu

    params.iterationHook = hook
    start = time.process_time()
    try:
        with cpu_cap(args.cap):
            lm = gtsam.LevenbergMarquardtOptimizer(rung, values, params)
            holder.append(lm)
            result = lm.optimize()
        above = sum(f.error(result) > c for f in loops)
        print(f"LM ended: {lm.iterations()} iterations, error {rung.error(result):.6g}, "
              f"above c {above}, {time.process_time() - start:.1f} s CPU")
    except CpuCapped:
        print(f"capped at {time.process_time() - start:.1f} s CPU")
    except RuntimeError as error:
        print(f"LM raised ({error.__class__.__name__}) after "
              f"{time.process_time() - start:.1f} s CPU")


if __name__ == "__main__":
    main()
