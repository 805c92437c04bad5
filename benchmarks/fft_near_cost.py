"""Benchmark: what the ``fft-near`` prefilter stage costs beside the pair histogram.

Run from the repository root::

    python benchmarks/fft_near_cost.py [--keyframes 2000] [--repeat 5]

In one process, interleaved, best of ``--repeat`` (CPU time, `time.process_time`):
describing one polygon by the pair histogram and by the ``fft-near`` stage, and one
`PlaceDatabase.candidates` query (prefilter screening, shortlist, FLIRT over K) over a
database of ``--keyframes`` keyframes with the prefilter ``pairs`` and ``pairs,
fft-near`` (the polygons of the simulated Box world, repeated).  Printed: microseconds
a description, milliseconds a query, and the ratios.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from data.sim import place_dataset  # noqa: E402
from loopclosure.place_config import PlaceDatabaseConfig, stage_matcher  # noqa: E402
from loopclosure.place_database import PlaceDatabase  # noqa: E402
from loopclosure.polygon import polygon_from_scan  # noqa: E402


def best(fn, repeat: int) -> float:
    """Smallest CPU seconds of `repeat` calls of `fn`."""
    out = []
    for _ in range(repeat):
        t = time.process_time()
        fn()
        out.append(time.process_time() - t)
    return min(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--keyframes", type=int, default=2000)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    polygons = [polygon_from_scan(s) for _, s in place_dataset("box", places=11,
                                                                 scans_per_place=21)]
    cfg = PlaceDatabaseConfig()
    matchers = {s: stage_matcher(s, cfg) for s in ("pairs", "fft-near")}
    sample = polygons[:40]
    desc = {s: best(lambda m=m: [m.describe(p) for p in sample], args.repeat) / len(sample)
            for s, m in matchers.items()}
    dbs = {}
    for name, prefilter in (("pairs", ("pairs",)), ("pairs,fft-near", ("pairs", "fft-near"))):
        db = PlaceDatabase(prefilter=prefilter, grid_headings=0, n_headings=0)
        for i in range(args.keyframes):
            db.add(i, polygons[i % len(polygons)])
        dbs[name] = (db, db.describe(polygons[7]))
    query = {name: [] for name in dbs}
    for _ in range(args.repeat):  # interleaved
        for name, (db, q) in dbs.items():
            query[name].append(best(lambda db=db, q=q: db.candidates(q), 1))
    print(f"describe: pairs {1e6 * desc['pairs']:.0f} us, fft-near "
          f"{1e6 * desc['fft-near']:.0f} us (+{100 * desc['fft-near'] / desc['pairs']:.0f}%)")
    a, b = (1e3 * min(query[n]) for n in dbs)
    print(f"query over {args.keyframes}: pairs {a:.2f} ms, pairs,fft-near {b:.2f} ms "
          f"(ratio {b / a:.2f})")


if __name__ == "__main__":
    main()
