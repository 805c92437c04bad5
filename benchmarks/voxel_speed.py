"""`loopclosure.fast_icp.voxel_downsample_fast` against its previous kernel, in one run.

Run from the repository root::

    python benchmarks/voxel_speed.py

The previous kernel (reproduced here: numpy's stable argsort of the cell keys,
computed with numpy, then one compiled pass) and the current one (one compiled
pass that finds the cells by hashing) voxelise the same clouds at 5 cm: walls with
1 cm noise seen twice (the shape of a front-end scan, a local map, a submap), of 180
to 40,000 points.  It prints CPU microseconds per call (``time.process_time``, the
best of 5 repetitions), their ratio, and whether the outputs are bit-identical
(they must be: same cells, same summation order, same output order).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numba
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


@numba.njit(cache=True)
def _previous_kernel(pts, key, order):
    n = len(key)
    sums = np.zeros((n, 2))
    counts = np.zeros(n)
    group_at = np.full(n, -1, dtype=np.int64)
    g = -1
    for t in range(n):
        i = order[t]
        if t == 0 or key[i] != key[order[t - 1]]:
            g += 1
            group_at[i] = g
        sums[g, 0] += pts[i, 0]
        sums[g, 1] += pts[i, 1]
        counts[g] += 1.0
    out = np.empty((g + 1, 2))
    row = 0
    for i in range(n):
        h = group_at[i]
        if h >= 0:
            out[row, 0] = sums[h, 0] / counts[h]
            out[row, 1] = sums[h, 1] / counts[h]
            row += 1
    return out


def previous(points: np.ndarray, voxel: float) -> np.ndarray:
    pts = np.ascontiguousarray(np.asarray(points, dtype=float).reshape(-1, 2))
    cells = np.floor(pts / voxel).astype(np.int64)
    key = (cells[:, 0] << 32) ^ (cells[:, 1] & 0xFFFFFFFF)
    return _previous_kernel(pts, key, np.argsort(key, kind="stable"))


def walls(n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` points on 12 random wall segments in a 30 m square, 1 cm noise, seen twice."""
    ends = rng.uniform(-15, 15, (12, 2, 2))
    seg = rng.integers(0, 12, n // 2)
    t = rng.uniform(0, 1, n // 2)[:, None]
    pts = ends[seg, 0] + t * (ends[seg, 1] - ends[seg, 0])
    pts = np.vstack([pts, pts]) + rng.normal(0, 0.01, (2 * len(pts), 2))
    return pts[rng.permutation(len(pts))]


def main() -> None:
    from loopclosure.fast_icp import voxel_downsample_fast

    rng = np.random.default_rng(0)
    print(f"{'points':>7s} {'previous us':>12s} {'current us':>11s} {'ratio':>6s} identical")
    for n in (180, 360, 2000, 10000, 40000):
        pts = walls(n, rng)
        same = np.array_equal(previous(pts, 0.05), voxel_downsample_fast(pts, 0.05))
        reps = max(1, 100_000 // n)
        best = {}
        for name, fn in (("previous", previous), ("current", voxel_downsample_fast)):
            times = []
            for _ in range(5):
                start = time.process_time()
                for _ in range(reps):
                    fn(pts, 0.05)
                times.append((time.process_time() - start) / reps)
            best[name] = min(times)
        print(f"{len(pts):7d} {1e6 * best['previous']:12.0f} {1e6 * best['current']:11.0f} "
              f"{best['current'] / best['previous']:6.2f} {same}")


if __name__ == "__main__":
    main()
