"""Benchmark: where the default ``icp2d`` front end spends its CPU time, per log.

Run from the repository root::

    python benchmarks/front_end_stages.py [--data DIR] [--logs carmen/intel.clf.bz2,...]
        [--limit N]

For every log, the front end of the default pipeline configuration runs over every
scan in file order three times in this process (after a short untimed run that loads
the compiled kernels), timed by ``time.process_time``:

1. plain: nothing instrumented (the front end's CPU seconds);
2. split: the compiled ICP call (``fast_icp._register_kernel``, the lazy map normals
   it resolves included) and the local map's rebuild (``Icp2dOdometry._rebuild_map``)
   timed apart; the rest is Python bookkeeping (prediction, covariances, estimates,
   the wrappers of the compiled calls);
3. normals: every registration made twice on its grid, the second time with the
   normals the first one resolved; the first minus the second is the map normals'
   share (the lazy PCA of the points the scan meets).

It prints seconds and microseconds per scan of each part.  Instrumentation adds a
clock read per call: the parts add up to a little more than the plain time.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from data.sources import open_source
from loopclosure import fast_icp
from slam.config import PipelineConfig
from slam.odometry import icp2d

ROOT = Path(__file__).resolve().parents[1]
LOGS = ("carmen-corrected/orebro-corrected.log.gz,carmen-corrected/freiburg-101-corrected.log.gz,"
        "carmen-corrected/belgioioso-corrected.log.gz")


def run(scans: list[Any]) -> float:
    """CPU seconds of the default front end over `scans`."""
    odometry = icp2d.Icp2dOdometry(PipelineConfig().icp2d)
    start = time.process_time()
    for scan in scans:
        odometry.process(scan)
    return time.process_time() - start


def timed(owner: Any, name: str, clock: dict[str, float], key: str) -> Any:
    """Replace ``owner.name`` by a wrapper adding its CPU seconds to ``clock[key]``;
    returns the original."""
    original = getattr(owner, name)

    def wrapper(*args: Any, **kwargs: Any) -> Any:
        start = time.process_time()
        try:
            return original(*args, **kwargs)
        finally:
            clock[key] += time.process_time() - start

    setattr(owner, name, wrapper)
    return original


def stages(scans: list[Any]) -> dict[str, float]:
    """Plain, kernel, rebuild, rest and normals seconds (module docstring)."""
    out = {"plain": run(scans), "kernel": 0.0, "rebuild": 0.0, "first": 0.0, "again": 0.0}
    kernel = timed(fast_icp, "_register_kernel", out, "kernel")
    rebuild = timed(icp2d.Icp2dOdometry, "_rebuild_map", out, "rebuild")
    try:
        out["split"] = run(scans)
    finally:
        fast_icp._register_kernel = kernel
        icp2d.Icp2dOdometry._rebuild_map = rebuild
    original = fast_icp.register_fast

    def twice(points: Any, grid: Any, *args: Any, **kwargs: Any) -> Any:
        start = time.process_time()
        first = original(points, grid, *args, **kwargs)
        middle = time.process_time()
        again = original(points, grid, *args, **kwargs)
        out["first"] += middle - start
        out["again"] += time.process_time() - middle
        assert np.array_equal(first.pose, again.pose)
        return first

    fast_icp.register_fast = twice
    try:
        run(scans)
    finally:
        fast_icp.register_fast = original
    out["rest"] = out["split"] - out["kernel"] - out["rebuild"]
    out["normals"] = out["first"] - out["again"]
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data")
    parser.add_argument("--logs", default=LOGS, help="comma-separated, under --data")
    parser.add_argument("--limit", type=int, default=0, help="first N scans (0: all)")
    args = parser.parse_args()
    print(f"{'log':<46} {'scans':>6} {'plain s':>8} {'kernel':>7} {'normals':>8} "
          f"{'rebuild':>8} {'rest':>7}   us/scan: plain kernel normals rebuild rest")
    for name in args.logs.split(","):
        scans = list(open_source(str(args.data / name)))
        if args.limit > 0:
            scans = scans[:args.limit]
        run(scans[:30])  # load the kernels
        t = stages(scans)
        us = {k: 1e6 * v / len(scans) for k, v in t.items()}
        print(f"{name:<46} {len(scans):>6} {t['plain']:8.3f} {t['kernel']:7.3f} "
              f"{t['normals']:8.3f} {t['rebuild']:8.3f} {t['rest']:7.3f}   "
              f"{us['plain']:.0f} {us['kernel']:.0f} {us['normals']:.0f} {us['rebuild']:.0f} "
              f"{us['rest']:.0f}", flush=True)


if __name__ == "__main__":
    main()
