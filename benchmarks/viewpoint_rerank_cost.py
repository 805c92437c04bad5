"""Benchmark: a place query's CPU time with viewpoints re-ranking a pool against the
full screen over every pair of descriptions and against no viewpoints, in one process.

Run from the repository root::

    python benchmarks/viewpoint_rerank_cost.py [--scans N] [--sizes 2000,10000]
        [--queries Q] [--viewpoints V] [--repeat R]

The measurement of `place_query_scaling.measure` (Intel places, the default
`PlaceDatabaseConfig`, `PlaceDatabase.query` without headings, CPU ms per query) for
four configurations, R times each, interleaved in this one process so that the
machine's load falls on all of them alike: no viewpoints; V stored viewpoints per
entry and V on the query's side screened over every pair (``viewpoint_order="min"``,
``query_viewpoints``); the same viewpoints ranking only the pool of the own
descriptions' smallest distances again (``viewpoint_order="rerank"``, the pool
of 128 and of 256).  Printed per
size: the best of the R runs of each and its ratio to the one without viewpoints.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from place_query_scaling import measure  # noqa: E402

CONFIGS = {
    "none": dict(viewpoints=0),
    "both min": dict(query_viewpoints=True, viewpoint_order="min"),
    "both rerank": dict(query_viewpoints=True, viewpoint_order="rerank"),
    "both rerank 256": dict(query_viewpoints=True, viewpoint_order="rerank", viewpoint_pool=256),
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data")
    ap.add_argument("--scans", type=int, default=1000)
    ap.add_argument("--sizes", default="2000,10000")
    ap.add_argument("--queries", type=int, default=50)
    ap.add_argument("--viewpoints", type=int, default=4)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    sizes = [int(s) for s in args.sizes.split(",")]
    best: dict[str, dict[int, float]] = {name: {} for name in CONFIGS}
    for r in range(args.repeat):
        names = list(CONFIGS) if r % 2 == 0 else list(CONFIGS)[::-1]
        for name in names:
            kw = {"viewpoints": args.viewpoints, **CONFIGS[name]}
            got = measure(args.data, args.scans, sizes, args.queries, verbose=False, **kw)
            for m, ms in got.items():
                best[name][m] = min(best[name].get(m, float("inf")), ms)
            print(f"run {r} {name}: " + ", ".join(f"{m} {ms:.2f} ms" for m, ms in got.items()),
                  flush=True)
    for m in sizes:
        base = best["none"][m]
        print(f"database {m:6d} entries, best of {args.repeat}: " + "; ".join(
            f"{name} {best[name][m]:.2f} ms (x{best[name][m] / base:.2f})" for name in CONFIGS))


if __name__ == "__main__":
    main()
