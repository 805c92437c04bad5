"""Benchmark: FLIRT's RANSAC matching, numba kernel vs numpy, in one run.

Run from the repository root::

    python benchmarks/flirt_speed.py [--data DIR] [--scans N] [--entries M]

Every third of the first N scans of the Intel log (``carmen/intel.clf.bz2``) is one
polygon (its valid end points in the sensor frame [m]) and is described once.  Each
described scan then queries M others (the next scan and M - 1 drawn at random,
seed 0): the place search's shape, which verifies about ten candidates per keyframe.
`FlirtMatcher.distances` runs with ``compiled=True`` and ``compiled=False``
alternately on the same stacks (so machine load hits both alike), after one warm-up
call each (numba's first call loads or compiles the kernel).  Prints CPU ms per query
of each, their ratio, the largest differences of the distances and RANSAC poses, and
how often the nearest entry differs.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.pair_histogram_speed import intel_polygons
from loopclosure.matchers.flirt import FlirtMatcher


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path,
                        default=Path(__file__).resolve().parents[2] / "shared" / "data")
    parser.add_argument("--scans", type=int, default=600)
    parser.add_argument("--entries", type=int, default=10)
    args = parser.parse_args()
    polygons = intel_polygons(args.data, args.scans)
    variants = {"compiled": FlirtMatcher(), "numpy": FlirtMatcher(compiled=False)}
    descs = [variants["numpy"].describe(p) for p in polygons[::3]]
    n = len(descs)
    rng = np.random.default_rng(0)
    queries = []
    for i in range(n):
        others = rng.choice(n, size=min(args.entries, n), replace=False)
        others[0] = (i + 1) % n
        queries.append((descs[i], variants["numpy"].stack([descs[j] for j in others])))
    for m in variants.values():
        m.distances(*queries[0])
    cpu = dict.fromkeys(variants, 0.0)
    out: dict[str, list] = {name: [] for name in variants}
    for query, stacked in queries:
        for name, m in variants.items():
            t = time.process_time()
            dist, pose, _, _ = m._run(query, stacked)
            cpu[name] += time.process_time() - t
            out[name].append((dist, pose))
    for name in variants:
        print(f"{name:9s} {1e3 * cpu[name] / n:8.3f} ms per query "
              f"({n} Intel scans, {args.entries} entries each)")
    print(f"ratio compiled / numpy: {cpu['compiled'] / cpu['numpy']:.3f}")
    pairs = list(zip(out["compiled"], out["numpy"], strict=True))
    d_diff = max(float(np.abs(a[0] - b[0]).max()) for a, b in pairs)
    p_diff = max(float(np.abs(a[1] - b[1]).max()) for a, b in pairs)
    flips = sum(int(np.argmin(a[0]) != np.argmin(b[0])) for a, b in pairs)
    print(f"largest distance difference {d_diff:.2e}, pose difference {p_diff:.2e}; "
          f"nearest entry differs in {flips} of {n} queries")


if __name__ == "__main__":
    main()
