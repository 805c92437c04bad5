"""Diagnosis: how many full-graph solves each stage of the robust back end makes on one
corrupted pose graph, and their CPU seconds.

Run from the repository root::

    python benchmarks/robust_solve_count.py input_INTEL_g2o.g2o [--data DIR] [--scale 1]
        [--policy random] [--ratio 50] [--seed 0] [--cache DIR] [--depth 4] [--memo N]
        [--stiff] [--cold]

Runs `slam.optimize.optimize` (``gnc``, incremental, from the odometry chain) with
`slam.least_squares.StickySolver` wrapped: every call is attributed to the chain of
`slam` functions that made it (innermost `--depth` frames), counted as a memo hit or a
solve, with the solve's CPU seconds and dogleg iterations (QR path).  Prints one line per
chain, most expensive first, then the totals (the clean optimum's solves, when the cache
lacks it, are not counted).  `--cold`: the calibrated choice's and `refine_tls`'s solves
from their own starts (``slam.calibrated_choice.WARM_STARTS`` and
``slam.consistency.WARM_STARTS`` False) instead of the nearest solution held.
"""

from __future__ import annotations

import sys
import time
import traceback
from collections import defaultdict
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import slam.calibrated_choice as calibrated_choice
import slam.consistency as consistency
import slam.least_squares as least_squares
from benchmarks.robust_cell import cell_parser, read_cell
from slam.optimize import optimize

STATS: dict[str, list[float]] = defaultdict(lambda: [0, 0, 0.0, 0])  # solves, hits, CPU s, its
ITERATIONS = [0]  # dogleg iterations of the solve under way
_dogleg_qr = least_squares.dogleg_qr


class _Counted:
    """A dogleg optimiser whose iterations are added to `ITERATIONS`."""

    def __init__(self, optimizer) -> None:  # type: ignore[no-untyped-def]
        self.optimizer = optimizer

    def optimize(self):  # type: ignore[no-untyped-def]
        result = self.optimizer.optimize()
        ITERATIONS[0] += self.optimizer.iterations()
        return result

    def iterations(self) -> int:
        return self.optimizer.iterations()


least_squares.dogleg_qr = lambda *a, **k: _Counted(_dogleg_qr(*a, **k))
DEPTH = [4]
_call = least_squares.StickySolver.__call__
_solve = least_squares.StickySolver._solve
_STATE = {"solved": False}


def _chain() -> str:
    frames = [f for f in traceback.extract_stack()[:-2] if "/slam/" in f.filename]
    names = [f"{Path(f.filename).stem}.{f.name}" for f in frames]
    return " > ".join(names[-DEPTH[0]:])


def _counted_call(self, factors, values):  # type: ignore[no-untyped-def]
    _STATE["solved"] = False
    ITERATIONS[0] = 0
    start = time.process_time()
    result = _call(self, factors, values)
    entry = STATS[_chain()]
    if _STATE["solved"]:
        entry[0] += 1
        entry[2] += time.process_time() - start
        entry[3] += ITERATIONS[0]
    else:
        entry[1] += 1
    return result


def _counted_solve(self, factors, values):  # type: ignore[no-untyped-def]
    _STATE["solved"] = True
    return _solve(self, factors, values)


least_squares.StickySolver.__call__ = _counted_call  # type: ignore[method-assign]
least_squares.StickySolver._solve = _counted_solve  # type: ignore[method-assign]


def main() -> None:
    parser = cell_parser(__doc__.split("\n")[0])
    parser.add_argument("--depth", type=int, default=4)
    parser.add_argument("--memo", type=int, default=None,
                        help="solutions each solver remembers (default: the module's)")
    parser.add_argument("--stiff", action="store_true", help="STIFF_CHOLESKY on")
    parser.add_argument("--cold", action="store_true", help="WARM_STARTS off")
    args = parser.parse_args()
    DEPTH[0] = args.depth
    if args.memo is not None:
        least_squares.MEMO_ENTRIES = args.memo
    least_squares.STIFF_CHOLESKY = args.stiff
    calibrated_choice.WARM_STARTS = consistency.WARM_STARTS = not args.cold
    _, _, corrupted, _ = read_cell(args)
    STATS.clear()  # the clean optimum's solves
    start = time.process_time()
    result = optimize(corrupted, "none", "gnc", init="odometry", gnc_start="incremental")
    total = time.process_time() - start
    solves = sum(v[0] for v in STATS.values())
    seconds = sum(v[2] for v in STATS.values())
    for chain, (n, hits, cpu, its) in sorted(STATS.items(), key=lambda kv: -kv[1][2]):
        print(f"{n:4d} solves {hits:3d} hits {its:4d} dogleg its {cpu:7.2f} s  {chain}")
    print(f"total: {solves} solves, {seconds:.1f} s CPU in solves of {total:.1f} s CPU; "
          f"{len(result.loop_outliers)} loops decided", flush=True)


if __name__ == "__main__":
    main()
