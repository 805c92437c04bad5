"""Benchmark: the final pass's fast path (`slam.optimize._clean_optimum`) on and off.

Run from the repository root::

    python benchmarks/robust_fast_path.py GRAPH.g2o [GRAPH.g2o ...] [--init given,odometry]
        [--repeat 2]

Each graph (e.g. a mapper run's ``graph.g2o``) is solved as the pipeline's final pass
solves it (`optimize` ``gnc``, ``gnc_start="incremental"``) with the fast path off and on,
alternately `--repeat` times in one process, from each start of `--init` (``given``: the
file's poses, close to what a mapper's estimate is; ``odometry``: the chain).  Printed:
CPU and wall seconds of each (the best of the repeats), their ratio, the loops each
rejects, the solver label and the largest position difference between the two solutions
[m].
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from data.g2o import read_g2o
from slam.optimize import optimize
from slam.pose_graph import PoseGraph


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("graphs", nargs="+")
    parser.add_argument("--init", default="given,odometry")
    parser.add_argument("--repeat", type=int, default=2)
    args = parser.parse_args()
    for path in args.graphs:
        graph = PoseGraph.from_g2o(read_g2o(path))
        print(f"{path}: {len(graph.keys)} poses, {len(graph.loops)} loops")
        for init in args.init.split(","):
            best: dict[bool, tuple[float, float]] = {}
            results = {}
            for _ in range(args.repeat):
                for fast in (False, True):
                    cpu, wall = time.process_time(), time.perf_counter()
                    results[fast] = optimize(graph, "none", "gnc", init=init,
                                             gnc_start="incremental", fast_path=fast)
                    cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
                    old = best.get(fast, (np.inf, np.inf))
                    best[fast] = (min(old[0], cpu), min(old[1], wall))
            keys = sorted(graph.keys)
            a = np.array([results[False].poses[k][:2] for k in keys])
            b = np.array([results[True].poses[k][:2] for k in keys])
            diff = float(np.max(np.linalg.norm(a - b, axis=1)))
            for fast in (False, True):
                r = results[fast]
                print(f"  init {init:8s} fast path {'on ' if fast else 'off'}: "
                      f"cpu {best[fast][0]:.2f} s wall {best[fast][1]:.2f} s, "
                      f"{len(r.loop_outliers)} loops rejected, solver {r.solver}")
            print(f"  init {init:8s} speed-up cpu {best[False][0] / best[True][0]:.2f}x "
                  f"wall {best[False][1] / best[True][1]:.2f}x, max position difference "
                  f"{diff:.2g} m", flush=True)


if __name__ == "__main__":
    main()
