"""Benchmark: CPU time of the robust back end (`slam.consistency.incremental_tls`), now
against a baseline revision, in one run.

Run from the repository root::

    python benchmarks/tls_speed.py [--data DIR] [--graphs input_INTEL_g2o.g2o,...]
        [--ratio 50] [--policies random,local] [--seed 0] [--scale 1] [--baseline REV]
        [--profile]

For every graph and policy, false loops are injected as `eval robustness` does
(`evaluation.outlier_policies.inject_false_loops` against the clean optimum), and the
back end is run from the odometry chain twice: as of `--baseline` (``slam/consistency.py``
and ``slam/least_squares.py`` of that git revision, loaded from ``git show`` into
private modules) and as now.  Printed per case: CPU seconds (`time.process_time`,
so the other load on the machine does not count) of both, their ratio, the TLS cost
of both, the number of loops whose decision differs and the position difference
(RMSE after rigid alignment) of the two solutions.  `--profile` prints the 15
costliest functions of the current run.
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import subprocess
import sys
import time
import types
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from data.g2o import read_g2o
from evaluation.outlier_policies import inject_false_loops
from evaluation.robustness import aligned_position_error, clean_optimum
from slam import consistency
from slam.optimize import initial_guess
from slam.pose_graph import PoseGraph, poses_from_values
from slam.variance_components import with_information_scaled

ROOT = Path(__file__).resolve().parents[1]


def baseline_module(revision: str) -> types.ModuleType:
    """`slam.consistency` as of `revision`, with that revision's `slam.least_squares`."""
    modules = {}
    for name in ("least_squares", "consistency"):
        source = subprocess.run(
            ["git", "show", f"{revision}:slam/{name}.py"], cwd=ROOT, check=True,
            capture_output=True, text=True).stdout
        if name == "consistency":
            source = source.replace("from slam.least_squares import",
                                    "from slam._baseline_least_squares import")
        module = types.ModuleType(f"slam._baseline_{name}")
        sys.modules[module.__name__] = module
        exec(compile(source, f"{revision}:slam/{name}.py", "exec"), module.__dict__)
        modules[name] = module
    return modules["consistency"]


def timed(function, *args, **kwargs):
    start = time.process_time()
    result = function(*args, **kwargs)
    return result, time.process_time() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data" / "g2o")
    parser.add_argument("--graphs", default="input_INTEL_g2o.g2o,input_MITb_g2o.g2o")
    parser.add_argument("--ratio", type=float, default=50.0, help="percent false loops")
    parser.add_argument("--policies", default="random,local,grouped,local-grouped")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--scale", type=float, default=1.0, help="odometry information factor")
    parser.add_argument("--baseline", default="d17b4c7", help="git revision to compare with")
    parser.add_argument("--no-baseline", action="store_true", help="time the current code only")
    parser.add_argument("--profile", action="store_true")
    args = parser.parse_args()
    old = None if args.no_baseline else baseline_module(args.baseline)
    ratios = []
    for name in args.graphs.split(","):
        graph = PoseGraph.from_g2o(read_g2o(args.data / name))
        if args.scale != 1.0:
            graph = with_information_scaled(graph, args.scale)
        reference = clean_optimum(graph)
        for policy in args.policies.split(","):
            corrupted, _ = inject_false_loops(
                graph, args.ratio / 100, np.random.default_rng(args.seed), policy,
                group_size=10, reference=reference)
            values = corrupted.gtsam_values(initial_guess(corrupted, "odometry"))
            profiler = cProfile.Profile(time.process_time) if args.profile else None
            if profiler:
                profiler.enable()
            new, t_new = timed(consistency.incremental_tls, corrupted, values)
            if profiler:
                profiler.disable()
            line = (f"{name:22} x{args.scale:<5g} {policy:14} {args.ratio:.0f}%  "
                    f"now {t_new:6.2f} s cpu (cost {new.tls_cost:.4f}, {new.gate})")
            if old is not None:
                was, t_old = timed(old.incremental_tls, corrupted, values)
                differ = int(np.sum((was.weights > 0.5) != (new.weights > 0.5)))
                shift = aligned_position_error(poses_from_values(new.values, graph.dim),
                                               poses_from_values(was.values, graph.dim),
                                               graph.dim)
                ratios.append(t_old / t_new)
                line += (f"  baseline {t_old:6.2f} s cpu (cost {was.tls_cost:.4f})  "
                         f"speed-up {t_old / t_new:4.2f}x  decisions differ {differ}  "
                         f"positions differ {shift:.2e} m")
            print(line, flush=True)
            if profiler:
                pstats.Stats(profiler).sort_stats("tottime").print_stats(15)
    if ratios:
        print(f"speed-up: median {np.median(ratios):.2f}x, min {min(ratios):.2f}x, "
              f"max {max(ratios):.2f}x over {len(ratios)} cases")


if __name__ == "__main__":
    main()
