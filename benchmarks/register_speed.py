"""Benchmark: the front end's `register_fast` calls, old `fast_icp` against new, in one
process.

Run from the repository root (the working tree's code on ``PYTHONPATH``)::

    python benchmarks/register_speed.py --baseline REV [--data DIR]
        [--log carmen/intel.clf.bz2] [--limit N] [--repeat R]

The default ``icp2d`` front end processes the first N scans of the log (working tree
code) and its `register_fast` calls (points, local map grid, initial pose, prior)
are recorded.  Revision REV's compiled ICP (``git show``: the modules of `CHAIN` it
has, ``loopclosure/fast_icp.py`` and the kernel modules it imports, each importing
REV's others) is loaded beside the working tree's, on the working tree's other
modules (so only changes to those files are compared), and both replay every call:
the script prints whether every `IcpResult` field is bit-identical, with the prior and
without it, and the CPU microseconds per call of either (R alternate passes, best of
each); then the same for `overlap_screen` of each call's points on its grid from
`SCREEN_OFFSETS` around its initial pose (gate 1 m, reach 0.55 m).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.exact_stage_speed import ROOT, load_revision

#: The compiled ICP's modules, each importing only earlier ones of the chain (and
#: modules outside it): a revision's are loaded in this order.
CHAIN = ("loopclosure/grid_nearest.py", "loopclosure/icp_kernel.py",
         "loopclosure/grid_overlap.py", "loopclosure/fast_icp.py")

#: Offsets [m, m, rad] from each call's initial pose of the guesses `overlap_screen`
#: scores on its grid (the geometric check's screens, on the front end's maps).
SCREEN_OFFSETS = np.array([[0.0, 0.0, 0.0], [0.3, 0.0, 0.0], [0.0, -0.3, 0.0],
                           [0.0, 0.0, 0.1], [-0.5, 0.4, -0.2], [1.0, 1.0, 0.5]])

FIELDS = ("pose", "covariance", "hessian", "sigma", "inlier_ratio", "rms", "fitness",
          "degeneracy", "degenerate_axis", "iterations", "converged", "correspondences",
          "ok", "initial")


def record(log: Path, limit: int) -> list:
    """``(source, grid, initial, kwargs)`` of the front end's `register_fast` calls."""
    import loopclosure.fast_icp as fast
    from data.sources import open_source
    from slam.config import PipelineConfig
    from slam.odometry import make_odometry

    scans = list(open_source(log))
    scans = scans[:limit] if limit > 0 else scans
    cfg = PipelineConfig()
    odo = make_odometry(cfg.odometry, cfg.front_end_config())
    calls: list = []
    original = fast.register_fast

    def recorder(source, target, initial=(0.0, 0.0, 0.0), **kwargs):
        calls.append((source, target, initial, kwargs))
        return original(source, target, initial, **kwargs)

    fast.register_fast = recorder
    try:
        for scan in scans:
            odo.process(scan)
    finally:
        fast.register_fast = original
    return calls


def load_chain(rev: str, folder: Path):
    """Revision `rev`'s `fast_icp`, on `rev`'s modules of `CHAIN` (those it has, e.g.
    none before the kernels left ``fast_icp.py``): while each is loaded, the earlier
    ones stand in for the working tree's under their own names."""
    saved: dict = {}
    module = None
    try:
        for path in CHAIN:
            there = subprocess.run(["git", "cat-file", "-e", f"{rev}:{path}"], cwd=ROOT,
                                   capture_output=True).returncode == 0
            if not there:
                continue
            module = load_revision(rev, path, folder)
            name = path.removesuffix(".py").replace("/", ".")
            saved.setdefault(name, sys.modules.get(name))
            sys.modules[name] = module
    finally:
        for name, original in saved.items():
            if original is None:
                sys.modules.pop(name, None)
            else:
                sys.modules[name] = original
    assert module is not None, f"{rev} has no loopclosure/fast_icp.py"
    return module


def same(a, b) -> bool:
    return all(np.asarray(getattr(a, f)).tobytes() == np.asarray(getattr(b, f)).tobytes()
               for f in FIELDS)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--baseline", required=True, help="a revision")
    parser.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data")
    parser.add_argument("--log", default="carmen/intel.clf.bz2", help="under --data")
    parser.add_argument("--limit", type=int, default=3000, help="first N scans (0: all)")
    parser.add_argument("--repeat", type=int, default=2, help="timed passes per code")
    args = parser.parse_args()
    import loopclosure.fast_icp as now

    with tempfile.TemporaryDirectory() as tmp:
        old = load_chain(args.baseline, Path(tmp))
        calls = record(args.data / args.log, args.limit)
        differ = 0
        for source, grid, initial, kwargs in calls:
            bare = {k: v for k, v in kwargs.items() if k not in ("prior", "prior_covariance")}
            for kw in (kwargs, bare):
                differ += not same(old.register_fast(source, grid, initial, **kw),
                                   now.register_fast(source, grid, initial, **kw))
        best = {"baseline": np.inf, "now": np.inf}
        for _ in range(args.repeat):
            for label, module in (("baseline", old), ("now", now)):
                t0 = time.process_time()
                for source, grid, initial, kwargs in calls:
                    module.register_fast(source, grid, initial, **kwargs)
                best[label] = min(best[label], time.process_time() - t0)
        screens = [(source, grid, np.asarray(initial, dtype=float) + SCREEN_OFFSETS)
                   for source, grid, initial, _ in calls]
        screens_differ = 0
        for source, grid, guesses in screens:
            a = old.overlap_screen(source, grid, guesses, 1.0, 0.55)
            b = now.overlap_screen(source, grid, guesses, 1.0, 0.55)
            screens_differ += not all(x.tobytes() == y.tobytes()
                                      for x, y in zip(a, b, strict=True))
        screen_best = {"baseline": np.inf, "now": np.inf}
        for _ in range(args.repeat):
            for label, module in (("baseline", old), ("now", now)):
                t0 = time.process_time()
                for source, grid, guesses in screens:
                    module.overlap_screen(source, grid, guesses, 1.0, 0.55)
                screen_best[label] = min(screen_best[label], time.process_time() - t0)
    n = max(len(calls), 1)
    old_us, new_us = 1e6 * best["baseline"] / n, 1e6 * best["now"] / n
    print(f"{args.log}: {len(calls)} calls, {differ} of {2 * len(calls)} results differ; "
          f"{old_us:.1f} -> {new_us:.1f} us per call ({old_us / new_us:.2f}x)")
    old_us, new_us = 1e6 * screen_best["baseline"] / n, 1e6 * screen_best["now"] / n
    print(f"overlap_screen: {len(screens)} calls, {screens_differ} differ; "
          f"{old_us:.1f} -> {new_us:.1f} us per call ({old_us / new_us:.2f}x)")


if __name__ == "__main__":
    main()
