"""Benchmark: the admission passes' whole-prefix solves with and without the cuts that
skip repeated ones, on one robustness cell, in one process, interleaved.

Run from the repository root::

    python benchmarks/robust_solve_cuts_ab.py input_INTEL_g2o.g2o [--data DIR]
        [--scale 1] [--policy random] [--ratio 50] [--seed 0] [--cache DIR]
        [--runs old,default] [--repeat 1]

``--runs``: whole-cell runs of `slam.optimize.optimize` (``gnc``, incremental, from the
odometry chain), each ``default`` or settings joined by ``+``: ``share-off`` (an undo
hypothesis solves its first prefix again, `slam.admission_undo.SHARE_FIRST_SOLVE`
False), ``adopt-off`` (a loop turned back by the nonlinear check is taken out of the
pass's iSAM2 and solved again rather than adopting its leave-one-out copy,
`slam.admission.ADOPT_LEAVE_ONE_OUT` False), ``fork-off`` (no snapshot kept where the
calibrated pass forks, `slam.admission.FORK_SNAPSHOT` False), ``snap-N``
(`slam.admission.SNAPSHOTS = N`), ``relin-X`` (`slam.isam_prefix.RELINEARIZE = X`),
``ladder-stop`` (`slam.consistency.LADDER_STOP`), ``bar-agree``
(`slam.consistency.BAR_AGREE`); ``old`` is
``share-off+adopt-off+fork-off+snap-2`` (the code before these cuts).  One line per run: ATE
against the outlier-free optimum [m], false loops obeyed (of them consistent with the
outlier-free graph), true loops rejected, CPU seconds (``time.process_time``), iSAM2
prefix solves (`IsamPrefix.solve` calls) and batch solves (`StickySolver` solves, memo
hits apart), peak resident memory so far [MB]; each run after the first is compared with
the first (same loops, largest position difference [m], CPU ratio); ``--cap S`` stops a
run after S seconds of its CPU (`benchmarks.robust_cell.cpu_cap`), reported unfinished.
An untimed warm-up
on the graph's first 200 poses loads numba's kernels first.
"""

from __future__ import annotations

import resource
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import slam.admission as admission
import slam.admission_undo as admission_undo
import slam.consistency as consistency
import slam.isam_prefix as isam_prefix
import slam.least_squares as least_squares
from benchmarks.robust_cell import (
    capped_gnc,
    cell_outcome,
    cell_parser,
    read_cell,
)
from benchmarks.robust_confirm_ab import _head, versus
from slam.optimize import optimize

NAMES = ("share", "adopt", "fork", "snapshots", "relinearize", "ladder_stop", "bar_agree")
DEFAULTS = (admission_undo.SHARE_FIRST_SOLVE, admission.ADOPT_LEAVE_ONE_OUT,
            admission.FORK_SNAPSHOT, admission.SNAPSHOTS, isam_prefix.RELINEARIZE,
            consistency.LADDER_STOP, consistency.BAR_AGREE)
COUNTS = {"isam": 0, "batch": 0}
_solve = isam_prefix.IsamPrefix.solve
_inner = least_squares.StickySolver._solve


def _counted_solve(self):  # type: ignore[no-untyped-def]
    COUNTS["isam"] += 1
    return _solve(self)


def _counted_inner(self, factors, values):  # type: ignore[no-untyped-def]
    COUNTS["batch"] += 1
    return _inner(self, factors, values)


def settings(run: str) -> dict[str, object]:
    """The module settings of a run (`NAMES` -> value)."""
    chosen = dict(zip(NAMES, DEFAULTS, strict=True))
    for part in run.replace("old", "share-off+adopt-off+fork-off+snap-2").split("+"):
        if part == "share-off":
            chosen["share"] = False
        elif part == "adopt-off":
            chosen["adopt"] = False
        elif part == "fork-off":
            chosen["fork"] = False
        elif part.startswith("snap-"):
            chosen["snapshots"] = int(part[len("snap-"):])
        elif part == "ladder-stop":
            chosen["ladder_stop"] = True
        elif part == "bar-agree":
            chosen["bar_agree"] = True
        elif part.startswith("relin-"):
            chosen["relinearize"] = float(part[len("relin-"):])
        elif part != "default":
            raise SystemExit(f"unknown run {run!r}")
    return chosen


def apply(chosen: dict[str, object]) -> None:
    admission_undo.SHARE_FIRST_SOLVE = chosen["share"]
    admission.ADOPT_LEAVE_ONE_OUT = chosen["adopt"]
    admission.FORK_SNAPSHOT = chosen["fork"]
    admission.SNAPSHOTS = chosen["snapshots"]
    isam_prefix.RELINEARIZE = chosen["relinearize"]
    consistency.LADDER_STOP = chosen["ladder_stop"]
    consistency.BAR_AGREE = chosen["bar_agree"]


def main() -> None:
    parser = cell_parser(__doc__.split("\n")[0])
    parser.add_argument("--runs", default="old,default")
    parser.add_argument("--repeat", type=int, default=1)
    parser.add_argument("--cap", type=float, default=0.0)
    args = parser.parse_args()
    graph, reference, corrupted, is_false = read_cell(args)
    name = f"{args.graph} x{args.scale:g} {args.policy} {args.ratio:g}% seed {args.seed}"
    optimize(_head(corrupted, 200), "none", "gnc", init="odometry", gnc_start="incremental")
    isam_prefix.IsamPrefix.solve = _counted_solve  # type: ignore[method-assign]
    least_squares.StickySolver._solve = _counted_inner  # type: ignore[method-assign]
    first = None
    for run in [r for r in args.runs.split(",") if r] * args.repeat:
        apply(settings(run))
        COUNTS.update(isam=0, batch=0)
        cpu = time.process_time()
        try:
            result = capped_gnc(corrupted, args.cap)
        finally:
            cpu = time.process_time() - cpu
            apply(dict(zip(NAMES, DEFAULTS, strict=True)))
        if result is None:
            print(f"{name} {run}: not finished in {args.cap:g} s CPU "
                  f"({COUNTS['isam']} iSAM2 solves, {COUNTS['batch']} batch solves so far)",
                  flush=True)
            continue
        out = cell_outcome(graph, reference, corrupted, is_false, result.poses)
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        line = (f"{name} {run}: ATE {out.ate:.3g} m, {len(out.false_obeyed)} F "
                f"({out.consistent}), {out.true_rejected} T, {cpu:.1f} s CPU, "
                f"{COUNTS['isam']} iSAM2 solves, {COUNTS['batch']} batch solves, "
                f"peak {peak:.0f} MB")
        if first is None:
            first = (cpu, out.obeyed, result.poses, run, result.loop_outliers)
        else:
            line += versus(first[3], first[:3], cpu, out.obeyed, result.poses)
            line += f", same decisions {result.loop_outliers == first[4]}"
        print(line, flush=True)


if __name__ == "__main__":
    main()
