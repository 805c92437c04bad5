"""Benchmark: the compiled surface-pair histogram, a revision's kernel module against the
working tree's, in one process, on the scans of a log.

Run from the repository root (the working tree's code on ``PYTHONPATH``)::

    python benchmarks/pair_kernel_ab.py --baseline REV [--data DIR]
        [--log carmen-corrected/freiburg-101-corrected.log.gz] [--every K] [--repeat R]

Revision REV's `loopclosure/matchers/pair_kernel.py` is loaded under another module
name (`benchmarks.shape_context_kernel_ab.load_revision`).  Every `--every`-th scan of
the log becomes a polygon (`loopclosure.polygon.polygon_from_scan`) and its surface
samples (`PairHistogramMatcher`'s default configuration, at most ``max_samples``); both
sides build each sample set's histogram with the angle-bin table
(`pair_histogram_compiled`) and with the counting kernel (`_pair_kernel_counting`, the
fallback for angle bins too many for a table).  The script prints whether every
histogram is equal to the bit, and the best-of-R CPU seconds (``time.process_time``)
of the table path of either side, run alternately, with their ratio (baseline / now:
above 1 is faster now).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.shape_context_kernel_ab import load_revision
from data import open_source
from data.types import Scan
from loopclosure.matchers import pair_kernel
from loopclosure.matchers.pair_histogram import PairHistogramConfig, polygon_samples
from loopclosure.polygon import polygon_from_scan


def sample_sets(log: Path, every: int) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """The surface samples ``(points, normals, weights)`` of every `every`-th scan's
    polygon, thinned as `PairHistogramMatcher.describe` thins them."""
    cfg = PairHistogramConfig()
    out = []
    for k, scan in enumerate(open_source(log)):
        if k % every or not isinstance(scan, Scan):
            continue
        v = np.asarray(polygon_from_scan(scan).vertices, float)
        pts, nrm, w = polygon_samples(v, step=cfg.step, max_edge=cfg.max_edge,
                                      max_range=cfg.max_range)
        if len(pts) > cfg.max_samples:
            stride = -(-len(pts) // cfg.max_samples)
            pts, nrm, w = pts[::stride], nrm[::stride], w[::stride] * stride
        out.append((pts, nrm, w))
    return out


def tables(module, sets):  # type: ignore[no-untyped-def]
    """Every sample set's histogram by `module`'s `pair_histogram_compiled`."""
    cfg = PairHistogramConfig()
    return [module.pair_histogram_compiled(p, n, w, max_distance=cfg.max_distance,
                                           n_distance=cfg.n_distance, n_angle=cfg.n_angle)
            for p, n, w in sets]


def counted(module, sets):  # type: ignore[no-untyped-def]
    """Every sample set's histogram by `module`'s counting kernel."""
    cfg = PairHistogramConfig()
    edges = np.sin(np.arange(1, cfg.n_angle) * (0.5 * np.pi / cfg.n_angle))
    out = []
    for p, n, w in sets:
        hist = np.zeros(cfg.n_distance * cfg.n_angle)
        module._pair_kernel_counting(np.ascontiguousarray(p), np.ascontiguousarray(n),
                                     np.ascontiguousarray(w), float(cfg.max_distance),
                                     cfg.n_distance, cfg.n_angle, edges, hist)
        out.append(hist)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--baseline", required=True)
    parser.add_argument("--data", default="../shared/data")
    parser.add_argument("--log", default="carmen-corrected/freiburg-101-corrected.log.gz")
    parser.add_argument("--every", type=int, default=10)
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    sets = sample_sets(Path(args.data) / args.log, args.every)
    with tempfile.TemporaryDirectory() as folder:
        sides = {"baseline": load_revision(args.baseline, Path(folder),
                                           "loopclosure/matchers/pair_kernel.py"),
                 "now": pair_kernel}
        same = all(np.array_equal(a, b) for make in (tables, counted)
                   for a, b in zip(make(sides["baseline"], sets), make(sides["now"], sets),
                                   strict=True))
        best = {name: np.inf for name in sides}
        for _ in range(args.repeat):
            for name, module in sides.items():
                start = time.process_time()
                tables(module, sets)
                best[name] = min(best[name], time.process_time() - start)
    print(f"{len(sets)} scans of {args.log}: histograms (table and counting) "
          f"{'identical' if same else 'DIFFER'}; table path CPU best of {args.repeat}: "
          f"{best['baseline']:.3f} s ({args.baseline}) -> {best['now']:.3f} s (now), "
          f"ratio {best['baseline'] / best['now']:.3f}")


if __name__ == "__main__":
    main()
