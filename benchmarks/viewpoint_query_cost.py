"""Benchmark: a place query's CPU time with offset viewpoints against without, in one process.

Run from the repository root::

    python benchmarks/viewpoint_query_cost.py [--scans N] [--sizes 2000,10000]
        [--queries Q] [--viewpoints V] [--repeat R]

The measurement of `place_query_scaling.measure` (Intel places, the default
`PlaceDatabaseConfig`, `PlaceDatabase.query` without headings, CPU ms per query) for
three configurations, R times each, interleaved in this one process so that the
machine's load falls on all of them alike: no viewpoints; V stored viewpoints per
entry (``loops.viewpoints.count=V``, the stored side only); V stored viewpoints and V
on the query's side (``loops.database.query_viewpoints=true``: the smallest distance
over every pair of a query description and a stored one).  Printed per size: the best
of the R runs of each and its ratio to the configuration without viewpoints.
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
    "stored": dict(query_viewpoints=False),
    "stored+query": dict(query_viewpoints=True),
}


def main(configs: dict[str, dict] = CONFIGS, doc: str = __doc__) -> None:
    """Time every configuration of `configs` (the first is the one the ratios divide
    by), interleaved, and print the best of each per database size."""
    ap = argparse.ArgumentParser(description=doc.split("\n")[0])
    ap.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data")
    ap.add_argument("--scans", type=int, default=1000)
    ap.add_argument("--sizes", default="2000,10000")
    ap.add_argument("--queries", type=int, default=50)
    ap.add_argument("--viewpoints", type=int, default=4)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    sizes = [int(s) for s in args.sizes.split(",")]
    best: dict[str, dict[int, float]] = {name: {} for name in configs}
    for r in range(args.repeat):
        names = list(configs) if r % 2 == 0 else list(configs)[::-1]
        for name in names:
            kw = {"viewpoints": args.viewpoints, **configs[name]}
            got = measure(args.data, args.scans, sizes, args.queries, verbose=False, **kw)
            for m, ms in got.items():
                best[name][m] = min(best[name].get(m, float("inf")), ms)
            print(f"run {r} {name}: " + ", ".join(f"{m} {ms:.2f} ms" for m, ms in got.items()),
                  flush=True)
    for m in sizes:
        base = best[next(iter(configs))][m]
        print(f"database {m:6d} entries, best of {args.repeat}: " + "; ".join(
            f"{name} {best[name][m]:.2f} ms (x{best[name][m] / base:.2f})" for name in configs))


if __name__ == "__main__":
    main()
