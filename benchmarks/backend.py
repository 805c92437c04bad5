"""Benchmark: batch and incremental optimisation of the shared g2o pose graphs, in one run.

Run from the repository root::

    python benchmarks/backend.py [--data DIR] [--repeat N]

For M3500 and INTEL (``g2o/input_*_g2o.g2o``) the script prints:

* **batch**: `slam.optimize.optimize` with Levenberg-Marquardt and no kernel from the
  LAGO initialisation (the best of `--repeat` runs, so import and first-call costs do not
  count), its solver (LM, or the dogleg-QR fallback that INTEL's 1e12 information
  entries need), iterations and final error; then the same with the Cauchy kernel on
  loop edges and with GNC;
* **incremental**: `slam.optimize.IncrementalSmoother` (gtsam ISAM2) fed the graph in
  vertex order as a mapper would: a pose with its odometry edge, then the loop edges
  that close on it, one `update` per pose; total seconds, milliseconds per pose
  (mean and the slowest 1%), and the position difference of its final estimate from
  the batch solution;

and finally the ratio of incremental to batch time per graph.  The goal: M3500 batch
under 1 s.
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
from slam.pose_graph import PoseGraph, relative_compose
from slam.smoothers import IncrementalSmoother


def batch(graph: PoseGraph, kernel: str, method: str, repeat: int) -> tuple[float, object]:
    """Best wall time of `repeat` solves, and the last result."""
    best, result = np.inf, None
    for _ in range(repeat):
        start = time.perf_counter()
        result = optimize(graph, kernel, method, init="lago")
        best = min(best, time.perf_counter() - start)
    return best, result


def incremental(graph: PoseGraph) -> tuple[float, np.ndarray, dict[int, np.ndarray]]:
    """Feed `graph` to iSAM2 pose by pose; total seconds, per-pose seconds, estimate."""
    smoother = IncrementalSmoother(dim=graph.dim, kernel="none")
    loops_by_key: dict[int, list] = {}
    for c in graph.loops:
        loops_by_key.setdefault(max(c.i, c.j), []).append(c)
    odometry = {c.j: c for c in graph.odometry}
    keys = sorted(graph.initial)
    estimate: dict[int, np.ndarray] = {}
    per_pose = []
    start = time.perf_counter()
    previous = None
    for key in keys:
        tick = time.perf_counter()
        if previous is None:
            smoother.add_pose(key, graph.initial[key])
        else:
            c = odometry[key]
            smoother.add_pose(key, relative_compose(estimate[previous], c.measurement, graph.dim))
            smoother.add_odometry(c.i, c.j, c.measurement, c.information)
        for c in loops_by_key.get(key, []):
            smoother.add_loop(c.i, c.j, c.measurement, c.information)
        smoother.update()
        estimate = smoother.estimate()
        per_pose.append(time.perf_counter() - tick)
        previous = key
    return time.perf_counter() - start, np.array(per_pose), estimate


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path,
                        default=Path(__file__).resolve().parents[2] / "shared" / "data")
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    ratios = {}
    for name in ("M3500", "INTEL"):
        path = args.data / "g2o" / f"input_{name}_g2o.g2o"
        if not path.exists():
            print(f"{path} not found: skipped")
            continue
        graph = PoseGraph.from_g2o(read_g2o(path))
        print(f"\n{name}: {len(graph.initial)} poses, {len(graph.odometry)} odometry and "
              f"{len(graph.loops)} loop edges")
        times = {}
        for kernel, method in (("none", "lm"), ("cauchy", "lm"), ("none", "gnc")):
            seconds, result = batch(graph, kernel, method, args.repeat)
            times[(kernel, method)] = seconds
            print(f"  batch {method:<3} kernel {kernel:<6} {seconds:8.3f} s  solver "
                  f"{result.solver:<12} iterations {result.iterations:4d}  "
                  f"final error {result.final_error:.4g}")
        reference = batch(graph, "none", "lm", 1)[1].poses
        total, per_pose, estimate = incremental(graph)
        keys = sorted(reference)
        diff = np.array([np.linalg.norm(np.asarray(estimate[k])[:2] - np.asarray(
            reference[k])[:2]) for k in keys])
        print(f"  iSAM2 {total:8.3f} s total, {1e3 * per_pose.mean():.2f} ms per pose "
              f"(99th percentile {1e3 * np.percentile(per_pose, 99):.2f} ms), "
              f"max position difference from batch {diff.max():.4f} m")
        ratios[name] = total / times[("none", "lm")]
    print("\nincremental / batch time (whole graph, pose by pose vs one solve)")
    for name, ratio in ratios.items():
        print(f"  {name:<6} {ratio:.2f}")


if __name__ == "__main__":
    main()
