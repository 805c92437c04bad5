"""Benchmark: the robust back end's time settings against its defaults on one robustness
cell, in one process, interleaved: the fast path's dogleg stall rule
(`slam.fast_path_screen.STALL_WINDOW`), the iSAM2 prefix's relinearisation threshold
(`slam.isam_prefix.RELINEARIZE`) and the stiff-first dogleg
(`slam.least_squares.STIFF_CHOLESKY`).

Run from the repository root::

    python benchmarks/robust_time_options_ab.py input_INTEL_g2o.g2o [--data DIR]
        [--scale 1] [--policy random] [--ratio 50] [--seed 0] [--cache DIR]
        [--runs default,dogleg-off] [--repeat 1]

``--runs``: whole-cell runs of `slam.optimize.optimize` as `benchmarks/robust_modes.py`
calls it (``gnc``, incremental, from the odometry chain), each ``default`` or settings
joined by ``+``: ``dogleg-off`` (``STALL_WINDOW = 0``: the fast path's dogleg not
watched, as before the rule), ``relin-X`` (``RELINEARIZE = X``, tangent units: each iSAM2
solve of the admission's prefix stops once no pose's step exceeds X instead of 1e-3),
``stiff-on`` (``STIFF_CHOLESKY`` on).  With ``--repeat R`` the list of runs is repeated
R times in that order (interleaved).  One line each: ATE against the
outlier-free optimum [m], false loops obeyed (of them, consistent with the outlier-free
graph), true loops rejected, the TLS objective's gap to the clean optimum, wall and CPU
seconds (``time.process_time``), solver; for each run other than the first ``default``:
whether it obeys the same loops, the largest distance between its poses and the first
default's [m] and its CPU over that default's.  An untimed warm-up on the graph's first
200 poses loads numba's kernels first.  ``--ratio 0``: the outlier-free graph, whose
result must be the plain optimum (ATE < 1 mm).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import slam.fast_path_screen as fast_path_screen
import slam.isam_prefix as isam_prefix
import slam.least_squares as least_squares
from benchmarks.robust_cell import cell_outcome, cell_parser, read_cell
from benchmarks.robust_confirm_ab import _head, versus
from slam.optimize import optimize

DEFAULTS = (fast_path_screen.STALL_WINDOW, isam_prefix.RELINEARIZE,
            least_squares.STIFF_CHOLESKY)


def settings(run: str) -> tuple[int, float, bool]:
    """(dogleg stall window, relinearisation threshold, stiff-first dogleg) of a run."""
    window, relinearize, stiff = DEFAULTS
    for part in run.split("+"):
        if part == "dogleg-off":
            window = 0
        elif part == "stiff-on":
            stiff = True
        elif part.startswith("relin-"):
            relinearize = float(part[len("relin-"):])
        elif part != "default":
            raise SystemExit(f"unknown run {run!r}")
    return window, relinearize, stiff


def apply(values: tuple[int, float, bool]) -> None:
    (fast_path_screen.STALL_WINDOW, isam_prefix.RELINEARIZE,
     least_squares.STIFF_CHOLESKY) = values


def main() -> None:
    parser = cell_parser(__doc__.split("\n")[0])
    parser.add_argument("--runs", default="default,dogleg-off")
    parser.add_argument("--repeat", type=int, default=1)
    args = parser.parse_args()
    graph, reference, corrupted, is_false = read_cell(args)
    name = f"{args.graph} x{args.scale:g} {args.policy} {args.ratio:g}% seed {args.seed}"
    optimize(_head(corrupted, 200), "none", "gnc", init="odometry", gnc_start="incremental")
    first = None
    for run in [r for r in args.runs.split(",") if r] * args.repeat:
        apply(settings(run))
        wall, cpu = time.perf_counter(), time.process_time()
        try:
            result = optimize(corrupted, "none", "gnc", init="odometry",
                              gnc_start="incremental")
        finally:
            wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
            apply(DEFAULTS)
        out = cell_outcome(graph, reference, corrupted, is_false, result.poses)
        line = (f"{name} {run}: ATE {out.ate:.3g} m, {len(out.false_obeyed)} F "
                f"({out.consistent}), {out.true_rejected} T, gap {out.gap:+.1f}, "
                f"{wall:.1f} s ({cpu:.1f} s CPU), {result.solver}")
        if first is None and run == "default":
            first = (cpu, out.obeyed, result.poses)
        elif first is not None:
            line += versus("default", first, cpu, out.obeyed, result.poses)
        print(line, flush=True)


if __name__ == "__main__":
    main()
