"""Benchmark: the off options of the robust back end against its default on one cell, in
one process: the fast path's stall rule (``optimize(..., stall=True)``,
`slam.fast_path_screen.stalled_solve`) and the nonlinear check of admissions
(``optimize(..., confirm=...)``, `slam.admission.AdmissionPass`).

Run from the repository root::

    python benchmarks/default_options_ab.py input_INTEL_g2o.g2o [--data DIR] [--scale 1]
        [--policy random] [--ratio 50] [--seed 0] [--cache DIR]
        [--runs default,confirm-off] [--stage on|off]

``--stage on``: the fast path alone (`slam.optimize._clean_optimum`, as `optimize` calls
it) with ``stall`` off and on, its CPU seconds each and whether the two results are the
same (both None: the fast path fails and the admission runs; or equal poses, gtsam
``equals`` at tolerance 0).  The admission after a failed fast path starts from the
odometry chain, not from the fast path's result, so when the stage's results are the
same the whole cell's result with ``stall`` on is the default's, bit for bit.

``--runs``: whole-cell runs of `slam.optimize.optimize` as `benchmarks/robust_modes.py`
calls it (``gnc``, incremental, from the odometry chain), each one of ``default``
(the defaults), ``confirm-off``, ``stall-on``, ``stall-off``, ``confirm-off-stall-on``,
``stiff-on`` (the
defaults with ``slam.least_squares.STIFF_CHOLESKY`` on: dogleg by Cholesky, stiff factors'
poses first), ``screen`` (the check of admissions with its linearised leave-one-out
screen, ``confirm="screen"``).  One line each:
ATE against the outlier-free optimum [m], false loops obeyed (of them, consistent with
the outlier-free graph), true loops rejected, TLS objective's gap to the clean optimum,
wall and CPU seconds, solver; then, for each later run, whether it obeys the same loops
as the first and the largest distance between their poses [m].  An untimed warm-up on
the graph's first 200 poses loads numba's kernels first.  ``--ratio 0 --runs ""``: the
fast path alone, without computing the clean optimum.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import slam.least_squares as least_squares
from benchmarks.robust_cell import cell_outcome, cell_parser, read_cell
from benchmarks.robust_confirm_ab import _head, versus
from evaluation.robustness import corrupted_graph
from slam.clean_optimum import _clean_optimum
from slam.consistency import ODOMETRY_LADDER
from slam.optimize import initial_guess, optimize
from slam.pose_graph import PoseGraph, RobustKernel

RUNS = {
    "default": {},
    "confirm-off": {"confirm": False},
    "stall-on": {"stall": True},
    "stall-off": {"stall": False},
    "confirm-off-stall-on": {"confirm": False, "stall": True},
    "stiff-on": {},  # the defaults with slam.least_squares.STIFF_CHOLESKY = True
    "screen": {"confirm": "screen"},
}


def same_stage(a, b) -> bool:  # type: ignore[no-untyped-def]
    """Whether two `_clean_optimum` results are the same: both None, or the same
    iterations and poses equal at tolerance 0."""
    if a is None or b is None:
        return a is None and b is None
    return a[1] == b[1] and a[0].equals(b[0], 0.0)


def fast_path_stage(graph: PoseGraph, stall: bool):  # type: ignore[no-untyped-def]
    """`_clean_optimum` on `graph` as `optimize` calls it by default, with `stall`;
    returns (result, CPU seconds)."""
    factors, loop_index = graph.factor_graph(RobustKernel("none"))
    values = graph.gtsam_values(initial_guess(graph, "odometry"))
    start = time.process_time()
    out = _clean_optimum(graph, factors, loop_index, values, 0.99, 100, True,
                         tuple(ODOMETRY_LADDER), False, stall)
    return out, time.process_time() - start


def main() -> None:
    parser = cell_parser(__doc__.split("\n")[0])
    parser.add_argument("--runs", default="default,confirm-off")
    parser.add_argument("--stage", default="on", choices=("on", "off"))
    args = parser.parse_args()
    if args.ratio == 0 and not [r for r in args.runs.split(",") if r]:
        # The fast path alone at 0%: the cell's graph without its clean optimum (minutes
        # on M3500a), which only the whole-cell figures need.
        corrupted = corrupted_graph(str(Path(args.data) / args.graph), args.scale, 0.0,
                                    args.policy, args.seed, reference={})[2]
    else:
        graph, reference, corrupted, is_false = read_cell(args)
    name = f"{args.graph} x{args.scale:g} {args.policy} {args.ratio:g}% seed {args.seed}"
    optimize(_head(corrupted, 200), "none", "gnc", init="odometry", gnc_start="incremental")
    if args.stage == "on":
        full, cpu_full = fast_path_stage(corrupted, False)
        watched, cpu_watched = fast_path_stage(corrupted, True)
        print(f"{name} fast path: stall off {cpu_full:.1f} s CPU "
              f"({'fails' if full is None else 'passes'}), stall on {cpu_watched:.1f} s CPU "
              f"({'fails' if watched is None else 'passes'}), same: "
              f"{same_stage(full, watched)}, on/off x{cpu_watched / max(cpu_full, 1e-9):.2f}",
              flush=True)
    first = None
    for run in [r for r in args.runs.split(",") if r]:
        least_squares.STIFF_CHOLESKY = run == "stiff-on"
        wall, cpu = time.perf_counter(), time.process_time()
        result = optimize(corrupted, "none", "gnc", init="odometry", gnc_start="incremental",
                          **RUNS[run])
        wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
        least_squares.STIFF_CHOLESKY = False
        out = cell_outcome(graph, reference, corrupted, is_false, result.poses)
        line = (f"{name} {run}: ATE {out.ate:.3g} m, {len(out.false_obeyed)} F "
                f"({out.consistent}), {out.true_rejected} T, gap {out.gap:+.1f}, "
                f"{wall:.1f} s ({cpu:.1f} s CPU), {result.solver}")
        if first is None:
            first = (cpu, out.obeyed, result.poses)
        else:
            line += versus("first", first, cpu, out.obeyed, result.poses)
        print(line, flush=True)


if __name__ == "__main__":
    main()
