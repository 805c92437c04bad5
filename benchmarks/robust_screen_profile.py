"""Diagnosis: where one corrupted cell's robust solve spends its CPU time, by function.

Run from the repository root::

    python benchmarks/robust_screen_profile.py input_M3500_g2o.g2o [--data DIR]
        [--scale 0.01] [--policy random] [--ratio 50] [--seed 0] [--cache DIR]
        [--confirm exact|screen] [--cap 300] [--top 25] [--out FILE.prof]

Runs `slam.optimize.optimize` (``gnc``, incremental, from the odometry chain, as
`benchmarks/default_options_ab.py` does) under cProfile, stopped after ``--cap`` CPU
seconds of the process (`benchmarks.robust_cell.cpu_cap`; cProfile's own overhead is
inside that budget), and prints the ``--top`` functions by cumulative time and by own
time; ``--out`` keeps the raw statistics for ``pstats``.
"""

from __future__ import annotations

import cProfile
import pstats
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.robust_cell import CpuCapped, cell_parser, cpu_cap, read_cell
from slam.optimize import optimize


def main() -> None:
    parser = cell_parser(__doc__.split("\n")[0])
    parser.add_argument("--confirm", default="screen", choices=("exact", "screen"))
    parser.add_argument("--cap", type=float, default=300.0)
    parser.add_argument("--top", type=int, default=25)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    corrupted = read_cell(args)[2]
    profile = cProfile.Profile()
    began = time.process_time()
    status = "finished"
    try:
        with cpu_cap(args.cap):
            profile.enable()
            optimize(corrupted, "none", "gnc", init="odometry", gnc_start="incremental",
                     confirm=True if args.confirm == "exact" else args.confirm)
    except CpuCapped:
        status = "capped"
    finally:
        profile.disable()
    print(f"{args.graph} x{args.scale:g} {args.policy} {args.ratio:g}% seed {args.seed} "
          f"confirm {args.confirm}: {status} at {time.process_time() - began:.1f} s CPU")
    if args.out is not None:
        profile.dump_stats(str(args.out))
    stats = pstats.Stats(profile).strip_dirs()
    stats.sort_stats("cumulative").print_stats(args.top)
    stats.sort_stats("tottime").print_stats(args.top)


if __name__ == "__main__":
    main()
