"""Benchmark: the robust back end with and without warm starts of the calibrated choice's
and `refine_tls`'s solves (`slam.warm_starts`), on corrupted pose graphs, in one process
(old and new alternately on each cell, so the ratio is measured under the same load).

Run from the repository root::

    python benchmarks/warm_starts_ab.py input_INTEL_g2o.g2o [--data DIR] [--scale 1]
        [--policy random,grouped,local] [--ratio 50] [--seeds 0,1] [--repeat 1]
        [--cache DIR]

``old``: `slam.optimize.optimize` (``gnc``, incremental, from the odometry chain) with
``slam.calibrated_choice.WARM_STARTS`` and ``slam.consistency.WARM_STARTS`` False (each
solve from the candidate's or run's own solution); ``new``: both True (the default).
Prints per cell and variant the CPU seconds of this process in the whole back end, in
`slam.calibrated_choice.calibrated_choices` and in `slam.consistency.refine_tls` (the
calls of `incremental_tls` and `bar_search`) with their solves, the ATE against the
outlier-free optimum [m]; then whether both kept the same loops, the largest position
difference between the two results [m], the ATEs' difference [m] and the CPU ratios old /
new (medians over `--repeat`).  The last line sums the CPU seconds over every cell.
"""

from __future__ import annotations

import sys
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import slam.calibrated_choice as calibrated_choice
import slam.consistency as consistency
import slam.least_squares as least_squares
import slam.offer_back as offer_back
from benchmarks.robust_cell import cell_parser, read_cell
from evaluation.robustness import aligned_position_error
from slam.optimize import optimize

PARTS: dict[str, list[float]] = defaultdict(lambda: [0.0, 0])  # CPU s, solves
_STACK: list[str] = []  # the timed parts under way


def _timed(name: str, function):  # type: ignore[no-untyped-def]
    def wrapped(*args, **kwargs):  # type: ignore[no-untyped-def]
        _STACK.append(name)
        start = time.process_time()
        try:
            return function(*args, **kwargs)
        finally:
            PARTS[name][0] += time.process_time() - start
            _STACK.pop()
    return wrapped


_solve = least_squares.StickySolver._solve


def _counted_solve(self, factors, values):  # type: ignore[no-untyped-def]
    if _STACK:
        PARTS[_STACK[-1]][1] += 1
    return _solve(self, factors, values)


least_squares.StickySolver._solve = _counted_solve  # type: ignore[method-assign]
offer_back.calibrated_choices = _timed("choice", calibrated_choice.calibrated_choices)
consistency.refine_tls = _timed("refine", consistency.refine_tls)


def main() -> None:
    parser = cell_parser(__doc__.split("\n")[0])
    parser.add_argument("--seeds", default=None, help="comma-separated (default: --seed)")
    parser.add_argument("--repeat", type=int, default=1)
    args = parser.parse_args()
    seeds = [args.seed] if args.seeds is None else [int(s) for s in args.seeds.split(",")]
    total = {"old": 0.0, "new": 0.0}
    for policy in args.policy.split(","):
        for seed in seeds:
            args.policy, args.seed = policy, seed
            _, reference, corrupted, _ = read_cell(args)
            cpu: dict[str, list[float]] = {"old": [], "new": []}
            parts: dict[str, dict[str, list[float]]] = {"old": {}, "new": {}}
            results, ates = {}, {}
            for _ in range(args.repeat):
                for name, warm in (("old", False), ("new", True)):
                    calibrated_choice.WARM_STARTS = consistency.WARM_STARTS = warm
                    PARTS.clear()
                    start = time.process_time()
                    result = optimize(corrupted, "none", "gnc", init="odometry",
                                      gnc_start="incremental")
                    cpu[name].append(time.process_time() - start)
                    for part in ("choice", "refine"):
                        parts[name].setdefault(part, []).append(PARTS[part][0])
                    results[name] = result
                    ates[name] = aligned_position_error(result.poses, reference, corrupted.dim)
                    print(f"{args.graph} x{args.scale:g} {policy} {args.ratio:g}% seed {seed} "
                          f"{name}: {cpu[name][-1]:.2f} s CPU, choice "
                          f"{PARTS['choice'][0]:.2f} s ({PARTS['choice'][1]} solves), "
                          f"refine {PARTS['refine'][0]:.2f} s ({PARTS['refine'][1]} solves), "
                          f"ATE {ates[name]:.6g} m, {len(result.loop_outliers)} rejected",
                          flush=True)
            old, new = results["old"], results["new"]
            diff = max(float(np.linalg.norm(old.poses[k][:2] - new.poses[k][:2]))
                       for k in old.poses)

            def ratio(a: list[float], b: list[float]) -> float:
                return float(np.median(a) / max(np.median(b), 1e-12))

            total["old"] += float(np.median(cpu["old"]))
            total["new"] += float(np.median(cpu["new"]))
            print(f"  same loops kept: {old.loop_outliers == new.loop_outliers}; largest "
                  f"position difference {diff:.3g} m; ATE difference "
                  f"{abs(ates['new'] - ates['old']):.3g} m; CPU old/new: all "
                  f"{ratio(cpu['old'], cpu['new']):.2f}, choice "
                  f"{ratio(parts['old']['choice'], parts['new']['choice']):.2f}, refine "
                  f"{ratio(parts['old']['refine'], parts['new']['refine']):.2f}", flush=True)
    print(f"total CPU old {total['old']:.1f} s, new {total['new']:.1f} s, old/new "
          f"{total['old'] / max(total['new'], 1e-12):.2f}", flush=True)


if __name__ == "__main__":
    main()
