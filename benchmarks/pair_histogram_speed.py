"""Benchmark: the surface-pair histogram's describe, numba kernel vs numpy, in one run.

Run from the repository root::

    python benchmarks/pair_histogram_speed.py [--data DIR] [--scans N]

The first N scans of the Intel log (``carmen/intel.clf.bz2``)
are read once; each scan's valid end points (sensor frame [m]) are one polygon.
`PairHistogramMatcher.describe` runs on all of them with ``compiled=True`` and with
``compiled=False``, alternately (so machine load hits both alike), after one warm-up
call each (numba's first call loads or compiles the kernel).  Prints CPU ms per
describe of each, their ratio, and the largest difference of the descriptors.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from data.carmen import CarmenLog
from loopclosure.matchers.pair_histogram import PairHistogramMatcher
from loopclosure.polygon import Polygon


def intel_polygons(data: Path, count: int) -> list[Polygon]:
    """The first `count` Intel scans with >= 3 valid beams, each as the polygon of the
    sensor origin and its valid end points (sensor frame [m])."""
    polygons = []
    for scan in CarmenLog(data / "carmen" / "intel.clf.bz2"):
        ok = scan.valid
        pts = np.column_stack([scan.ranges[ok] * np.cos(scan.angles[ok]),
                               scan.ranges[ok] * np.sin(scan.angles[ok])])
        if len(pts) >= 3:
            polygons.append(Polygon(np.vstack([[0.0, 0.0], pts])))
        if len(polygons) >= count:
            break
    return polygons


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path,
                        default=Path(__file__).resolve().parents[2] / "shared" / "data")
    parser.add_argument("--scans", type=int, default=400)
    args = parser.parse_args()
    polygons = intel_polygons(args.data, args.scans)
    variants = {"compiled": PairHistogramMatcher(), "numpy": PairHistogramMatcher(compiled=False)}
    cpu = dict.fromkeys(variants, 0.0)
    out: dict[str, list] = {name: [] for name in variants}
    for m in variants.values():
        m.describe(polygons[0])
    for poly in polygons:
        for name, m in variants.items():
            t = time.process_time()
            out[name].append(m.describe(poly))
            cpu[name] += time.process_time() - t
    n = len(polygons)
    for name in variants:
        print(f"{name:9s} {1e3 * cpu[name] / n:8.3f} ms per describe ({n} Intel scans)")
    print(f"ratio compiled / numpy: {cpu['compiled'] / cpu['numpy']:.3f}")
    pairs = zip(out["compiled"], out["numpy"], strict=True)
    diff = max(float(np.abs(a - b).max()) for a, b in pairs)
    print(f"largest descriptor difference: {diff:.2e}")


if __name__ == "__main__":
    main()
