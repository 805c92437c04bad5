"""Benchmark: the fast path's watched first solve at several stall decreases, in one process.

Run from the repository root::

    python benchmarks/fast_path_stall_decrease.py GRAPH [--data DIR] [--cache DIR]
        [--scale S] [--policy P] [--ratio R] [--seed N] [--decreases 1e-3,1e-2]
        [--cap SECONDS]

For each relative decrease of ``--decreases`` (in that order), runs
`slam.fast_path_screen.stalled_solve` on the stiffest rung of the fast path's check
(`slam.optimize._clean_optimum`: every loop in, odometry information x the largest factor
of `slam.consistency.ODOMETRY_LADDER`, from the odometry chain) with that ``decrease``, and
prints its CPU seconds, whether it gave up, and, when it did not, whether its result has a
loop above ``c`` (the rung fails) and equals the first run's result bit for bit (values at
tolerance 0, iterations, solver).  Unlike `benchmarks/fast_path_stall.py` it never runs the
full solve, so it fits cells whose full solve takes many minutes.  ``--cap``: CPU seconds
per run at most (`benchmarks.robust_cell.cpu_cap`; 0: none).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.robust_cell import CpuCapped, cell_parser, cpu_cap, fast_path_problem, read_cell
from slam.fast_path_screen import stalled_solve


def main() -> None:
    parser = cell_parser(__doc__.splitlines()[0])
    parser.add_argument("--decreases", default="1e-3,1e-2")
    parser.add_argument("--cap", type=float, default=0.0)
    args = parser.parse_args()
    _, _, corrupted, _ = read_cell(args)
    c, rung, loop_index, values = fast_path_problem(corrupted)
    print(f"{args.graph} x{args.scale:g} {args.policy} {args.ratio:g}% s{args.seed}: "
          f"{len(loop_index)} loops", flush=True)
    first = None
    for decrease in (float(x) for x in args.decreases.split(",")):
        start = time.process_time()
        try:
            with cpu_cap(args.cap):
                solved = stalled_solve(rung, values, 100, loop_index, c, decrease)
        except CpuCapped:
            print(f"  decrease {decrease:g}: capped at {time.process_time() - start:.1f} s CPU",
                  flush=True)
            continue
        cpu = time.process_time() - start
        if solved is None:
            what = "given up"
        else:
            fails = any(rung.at(k).error(solved[0]) > c for k in loop_index)
            what = (f"not given up, {solved[2]} {solved[1]} iterations, rung "
                    f"{'fails' if fails else 'passes'}")
            if first is None:
                first = solved
            else:
                same = first[0].equals(solved[0], 0.0) and first[1:] == solved[1:]
                what += ", the first result bit for bit" if same else ", A DIFFERENT RESULT"
        print(f"  decrease {decrease:g}: {cpu:.1f} s CPU, {what}", flush=True)


if __name__ == "__main__":
    main()
