"""Benchmark: the place description's compiled paths vs numpy, in one run.

Run from the repository root::

    python benchmarks/describe_speed.py [--data DIR] [--scans N]

Every scan of the first N of the Intel log (``carmen/intel.clf.bz2``) is one polygon
(the sensor origin and its valid end points, sensor frame [m]).  Each polygon is
described by FLIRT (interest points and beta-grids) and by the surface-pair
histogram, once with ``compiled=True`` (numba kernels) and once with
``compiled=False`` (numpy), alternately (so machine load hits both alike), after
one warm-up call each.  Prints CPU ms per describe, the compiled / numpy ratio,
the largest descriptor differences, and for FLIRT how many beta-grid bins differ:
the compiled beta-grid finds a sector from signs of cross products, numpy from an
arctangent, so a chord sample on a sector border to within rounding may fall on
either side.

Virtual scans: every third of those scans' end points, with the next 14 even-numbered
scans' end points each shifted by a seeded random offset (0.3 m standard deviation:
a local map of about 2,400 points in a keyframe's frame), give a 360-beam, 20 m
`virtual_scan` with ``compiled=True`` and ``compiled=False``, alternately; prints the
CPU ratio and the largest range difference.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.pair_histogram_speed import intel_polygons
from data.carmen import CarmenLog
from loopclosure.matchers.flirt import FlirtMatcher
from loopclosure.matchers.pair_histogram import PairHistogramMatcher
from loopclosure.virtual_scan import virtual_scan


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path,
                        default=Path(__file__).resolve().parents[2] / "shared" / "data")
    parser.add_argument("--scans", type=int, default=600)
    args = parser.parse_args()
    polygons = intel_polygons(args.data, args.scans)
    pairs = {True: PairHistogramMatcher(), False: PairHistogramMatcher(compiled=False)}
    flirt = {True: FlirtMatcher(), False: FlirtMatcher(compiled=False)}
    for variants in (pairs, flirt):
        for m in variants.values():
            m.describe(polygons[0])
    cpu = {(name, c): 0.0 for name in ("pairs", "flirt") for c in (True, False)}
    out: dict[tuple[str, bool], list] = {key: [] for key in cpu}
    for poly in polygons:
        for name, variants in (("pairs", pairs), ("flirt", flirt)):
            for compiled, m in variants.items():
                t = time.process_time()
                out[name, compiled].append(m.describe(poly))
                cpu[name, compiled] += time.process_time() - t
    n = len(polygons)
    for name in ("pairs", "flirt"):
        fast, slow = cpu[name, True], cpu[name, False]
        print(f"{name}: compiled {1e3 * fast / n:.3f} ms, numpy {1e3 * slow / n:.3f} ms per "
              f"describe ({n} Intel scans); ratio {fast / slow:.3f}")
    diff = max(float(np.abs(a - b).max()) for a, b in zip(out["pairs", True],
                                                          out["pairs", False], strict=True))
    print(f"pairs: largest descriptor difference {diff:.2e}")
    same_points = all(np.array_equal(a.points, b.points)
                      for a, b in zip(out["flirt", True], out["flirt", False], strict=True))
    occ = [np.abs(a.occupancy - b.occupancy)
           for a, b in zip(out["flirt", True], out["flirt", False], strict=True)]
    bins = sum(int((o > 1e-12).sum()) for o in occ)
    total = sum(o.size for o in occ)
    polys = sum(bool((o > 1e-12).any()) for o in occ)
    print(f"flirt: same interest points {same_points}; beta-grid bins differing {bins} of "
          f"{total} in {polys} of {n} scans; largest occupancy difference "
          f"{max(float(o.max()) for o in occ):.3g}")
    virtual_scans(args.data, args.scans)


def virtual_scans(data: Path, count: int) -> None:
    """Time `virtual_scan` compiled vs numpy on local maps of Intel scans (docstring)."""
    scans = []
    for scan in CarmenLog(data / "carmen" / "intel.clf.bz2"):
        scans.append(scan.points())
        if len(scans) >= count:
            break
    rng = np.random.default_rng(0)
    maps = [np.vstack([scans[i + k] + rng.normal(0.0, 0.3, 2) for k in range(0, 30, 2)])
            for i in range(0, len(scans) - 30, 3)]
    for compiled in (True, False):
        virtual_scan(maps[0], 360, 20.0, compiled=compiled)
    cpu = {True: 0.0, False: 0.0}
    diff = 0.0
    for m in maps:
        ranges = {}
        for compiled in (True, False):
            t = time.process_time()
            ranges[compiled] = virtual_scan(m, 360, 20.0, compiled=compiled).ranges
            cpu[compiled] += time.process_time() - t
        diff = max(diff, float(np.abs(ranges[True] - ranges[False]).max()))
    n = len(maps)
    print(f"virtual scans: compiled {1e3 * cpu[True] / n:.3f} ms, numpy "
          f"{1e3 * cpu[False] / n:.3f} ms per scan ({n} local maps of "
          f"{np.mean([len(m) for m in maps]):.0f} points); ratio "
          f"{cpu[True] / cpu[False]:.3f}; largest range difference {diff:.2e} m")


if __name__ == "__main__":
    main()
