"""Benchmark: the place database's query time against its size, in one run.

Run from the repository root::

    python benchmarks/place_query_scaling.py [--data DIR] [--scans N]
        [--sizes 1000,2500,5000,10000] [--queries Q]

Every 5th of the Intel log's scans (``carmen/intel.clf.bz2``), up to N of them, is
made a place (`loopclosure.polygon.polygon_from_scan`) and described once with the
default `PlaceDatabaseConfig` (the pipeline's stages: surface-pair prefilter, FLIRT,
logistic fusion).  For every size M the database holds M entries: the described
places in turn, repeated as often as needed (a repeat costs the query what a new
place would: one more row of the prefilter's matrix, one more candidate for the
verifier).  Q queries (places of the same log) then run `PlaceDatabase.query` as the
loop detector's global search does (no headings), and the script prints CPU ms per
query for every size and its ratio to the smallest, and the CPU ms of describing one
place (once per keyframe, whatever the size).  The geometric check of the
candidates that follows a query checks at most `loops.global_places` places whatever
the database's size, so it is not part of this figure (`bench loops` reports the
whole query, check included).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from data.carmen import CarmenLog
from loopclosure.place_config import PlaceDatabaseConfig
from loopclosure.place_database import PlaceDatabase
from loopclosure.polygon import DegeneratePolygonError, polygon_from_scan


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    root = Path(__file__).resolve().parents[1]
    parser.add_argument("--data", type=Path, default=root.parent / "shared" / "data")
    parser.add_argument("--scans", type=int, default=2000, help="places described")
    parser.add_argument("--sizes", default="1000,2500,5000,10000")
    parser.add_argument("--queries", type=int, default=100)
    args = parser.parse_args()
    sizes = [int(s) for s in args.sizes.split(",")]

    log = args.data / "carmen" / "intel.clf.bz2"
    scans = [s for i, s in enumerate(CarmenLog(log)) if i % 5 == 0]
    polygons = []
    for scan in scans:
        try:
            polygons.append(polygon_from_scan(scan))
        except DegeneratePolygonError:
            continue
        if len(polygons) == args.scans + args.queries:
            break
    places, queries = polygons[: args.scans], polygons[args.scans:]
    probe = PlaceDatabase(PlaceDatabaseConfig())
    described = [probe.describe(p) for p in places]
    start = time.process_time()
    asked = [probe.describe(p) for p in queries]
    describe_ms = 1e3 * (time.process_time() - start) / max(len(queries), 1)
    print(f"{len(described)} places, {len(asked)} queries; stages "
          f"{', '.join(probe.config.stages)}; describing a place: {describe_ms:.2f} ms CPU")

    base = None
    for m in sizes:
        db = PlaceDatabase(PlaceDatabaseConfig())
        for key in range(m):
            db.add_descriptors(key, described[key % len(described)], stamp=float(key))
        db.query(asked[0], headings=False)  # warm-up: scales, stacks, compiled kernels
        start = time.process_time()
        for q in asked:
            db.query(q, headings=False)
        ms = 1e3 * (time.process_time() - start) / len(asked)
        base = ms if base is None else base
        print(f"database {m:6d} entries: {ms:7.2f} ms CPU per query  (ratio {ms / base:.2f})")


if __name__ == "__main__":
    main()
