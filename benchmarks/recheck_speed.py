"""Benchmark: the segment re-check's covariances from selected entries of H^-1 against
full solves.

Run from the repository root::

    python benchmarks/recheck_speed.py GRAPH.g2o [GRAPH.g2o ...] [--repeat 3]
        [--false-loops RATIO --policy random|local|grouped|local-grouped --seed 0]

Each graph (e.g. a mapper run's ``graph.g2o``) is brought to where the final pass's fast
path re-checks it (`slam.optimize._clean_optimum`: the plain least-squares optimum over
every loop, solved down the odometry ladder from the file's poses), then
`slam.segment_recheck.segment_recheck` (with its group test) runs there with
``slam.innovation.SELECTED_INVERSE`` off (full SuperLU solves of ``H^-1 B^T``, the
earlier path) and on (`slam.selected_inverse`), alternately `--repeat` times in one
process; then the whole final pass (`slam.optimize.optimize`, ``gnc`` with
``gnc_start="incremental"``) once each way.  Printed: CPU and wall seconds of each (best
of the repeats), the ratio new / old, whether the re-check's decisions (loops removed,
suspects, groups tested and their verdicts, loops re-admitted) are equal, the largest
relative difference of its innovations (``rho``, ``delta``) and the largest position
difference between the two final-pass solutions [m].

`--false-loops`: that fraction of each graph's loops is made false first
(`evaluation.outlier_policies.inject_false_loops` with `--policy` and `--seed`), so that
the re-check removes loops and groups and its decisions are compared where they matter;
the final pass (the whole incremental admission on such a graph: minutes) is then
skipped.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from data.g2o import read_g2o
from evaluation.outlier_policies import inject_false_loops
from slam import innovation
from slam.consistency import LM_BUDGET, ODOMETRY_LADDER, needs_qr
from slam.least_squares import StickySolver, solve
from slam.optimize import optimize
from slam.pose_graph import PoseGraph, RobustKernel
from slam.segment_recheck import SegmentRecheck, segment_recheck
from slam.variance_components import with_information_scaled


def _start(graph: PoseGraph):
    """The stated least-squares optimum solved down the odometry ladder (`_clean_optimum`)
    and the solver state the fast path re-checks with."""
    factors, loop_index = graph.factor_graph(RobustKernel("none"))
    result = graph.gtsam_values(graph.initial)
    used = "lm"
    for factor in sorted(ODOMETRY_LADDER, reverse=True):
        rung = factors if factor == 1.0 else with_information_scaled(
            graph, factor).factor_graph(RobustKernel("none"))[0]
        result, _, used = solve(rung, result, 100)
    unit = [factors.at(k) for k in loop_index]
    return result, unit, used == "dogleg-qr" or needs_qr(graph, result)


def _recheck(graph: PoseGraph, values, unit, dogleg: bool) -> SegmentRecheck:
    solver = StickySolver(lm_budget=LM_BUDGET, sticky=False)
    solver.dogleg = dogleg
    return segment_recheck(graph, values, np.ones(len(graph.loops)), solver=solver,
                           unit=unit)


def _decisions(check: SegmentRecheck) -> tuple:
    groups = check.groups
    return (check.removed, check.suspects,
            None if groups is None else ([(t.loops, t.removed) for t in groups.tested],
                                         groups.readmitted, groups.rounds))


def _innovations(check: SegmentRecheck) -> np.ndarray:
    tested = [] if check.groups is None else check.groups.tested
    return np.concatenate([check.leave_one_out, check.against_rest,
                           [t.rho for t in tested], [t.delta for t in tested]])


def _timed(selected: bool, run, *args, **kwargs):
    innovation.SELECTED_INVERSE = selected
    cpu, wall = time.process_time(), time.perf_counter()
    out = run(*args, **kwargs)
    return out, time.process_time() - cpu, time.perf_counter() - wall


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("graphs", nargs="+")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--false-loops", type=float, default=0.0)
    parser.add_argument("--policy", default="random")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    for path in args.graphs:
        graph = PoseGraph.from_g2o(read_g2o(path))
        if args.false_loops > 0:
            graph, _ = inject_false_loops(graph, args.false_loops,
                                          np.random.default_rng(args.seed), args.policy)
        print(f"{path}: {len(graph.keys)} poses, {len(graph.loops)} loops "
              f"({args.false_loops:g} false, {args.policy})")
        values, unit, dogleg = _start(graph)
        _recheck(graph, values, unit, dogleg)  # compiles the kernels (cached per machine)
        best = {False: (np.inf, np.inf), True: (np.inf, np.inf)}
        checks = {}
        for _ in range(args.repeat):
            for selected in (False, True):
                checks[selected], cpu, wall = _timed(selected, _recheck, graph, values,
                                                     unit, dogleg)
                best[selected] = (min(best[selected][0], cpu), min(best[selected][1], wall))
        old, new = checks[False], checks[True]
        a, b = _innovations(old), _innovations(new)
        scale = np.maximum(np.abs(a), 1e-300)
        rel = float(np.max(np.abs(a - b) / scale, initial=0.0))
        for selected, label in ((False, "full solves"), (True, "selected  ")):
            print(f"  segment_recheck {label}: cpu {best[selected][0]:.3f} s "
                  f"wall {best[selected][1]:.3f} s")
        print(f"  segment_recheck new/old: cpu {best[True][0] / best[False][0]:.3f} "
              f"wall {best[True][1] / best[False][1]:.3f}; decisions equal "
              f"{_decisions(old) == _decisions(new)} (removed {new.removed}); "
              f"max relative difference of rho/delta {rel:.2g}")
        if args.false_loops > 0:
            continue
        results, times = {}, {}
        for selected in (False, True):
            results[selected], cpu, wall = _timed(selected, optimize, graph, "none", "gnc",
                                                  init="given", gnc_start="incremental")
            times[selected] = (cpu, wall)
        keys = sorted(graph.keys)
        pa = np.array([results[False].poses[k] for k in keys])
        pb = np.array([results[True].poses[k] for k in keys])
        diff = float(np.max(np.linalg.norm(pa[:, :2] - pb[:, :2], axis=1)))
        print(f"  final pass cpu old {times[False][0]:.2f} s new {times[True][0]:.2f} s "
              f"(new/old {times[True][0] / times[False][0]:.3f}), solver "
              f"{results[True].solver}, loops rejected old "
              f"{results[False].loop_outliers} new {results[True].loop_outliers}, max "
              f"position difference {diff:.2g} m, max angle difference "
              f"{float(np.max(np.abs(pa[:, 2] - pb[:, 2]))):.2g} rad", flush=True)
    innovation.SELECTED_INVERSE = True


if __name__ == "__main__":
    main()
