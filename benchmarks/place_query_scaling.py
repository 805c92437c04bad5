"""Benchmark: the place database's query time against its size, in one run.

Run from the repository root::

    python benchmarks/place_query_scaling.py [--data DIR] [--scans N]
        [--sizes 1000,2500,5000,10000] [--queries Q] [--viewpoints V [--query-viewpoints]
        [--no-stored-viewpoints] [--viewpoint-order min|interleave]] [--baseline REV [--repeat R]]

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

With ``--viewpoints V`` every entry also carries V offset viewpoints
(`loopclosure.place_views`: the prefilter vectors of V other described places stand
in for them; the cost is the same), and with ``--query-viewpoints`` every query
carries V of its own and the database compares them too
(`PlaceDatabaseConfig.query_viewpoints`); ``--no-stored-viewpoints`` then leaves the
entries' viewpoints unscreened (`PlaceDatabaseConfig.stored_viewpoints`: the
viewpoints on the query's side only), and ``--viewpoint-order interleave`` ranks by
the own description's list and the viewpoints' smallest interleaved
(`PlaceDatabaseConfig.viewpoint_order`).

With ``--baseline REV`` the same measurement runs R times (default 3) in fresh
processes with the code of revision REV (``git archive``) and with the working tree,
alternately, and the script prints per size the median CPU ms of each and their
ratio (baseline / now): a speed change measured in one sitting.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def measure(data: Path, n_scans: int, sizes: list[int], n_queries: int,
            verbose: bool = True, viewpoints: int = 0,
            query_viewpoints: bool = False, stored_viewpoints: bool = True,
            viewpoint_order: str = "min", viewpoint_pool: int = 128) -> dict[int, float]:
    """CPU ms per query for every database size (module docstring), with the code
    on ``sys.path``."""
    import numpy as np

    from data.carmen import CarmenLog
    from loopclosure.place_config import PlaceDatabaseConfig
    from loopclosure.place_database import PlaceDatabase
    from loopclosure.polygon import DegeneratePolygonError, polygon_from_scan

    log = data / "carmen" / "intel.clf.bz2"
    scans = [s for i, s in enumerate(CarmenLog(log)) if i % 5 == 0]
    polygons = []
    for scan in scans:
        try:
            polygons.append(polygon_from_scan(scan))
        except DegeneratePolygonError:
            continue
        if len(polygons) == n_scans + n_queries:
            break
    places, queries = polygons[:n_scans], polygons[n_scans:]
    probe = PlaceDatabase(PlaceDatabaseConfig())
    described = [probe.describe(p) for p in places]
    start = time.process_time()
    asked = [probe.describe(p) for p in queries]
    describe_ms = 1e3 * (time.process_time() - start) / max(len(queries), 1)
    if verbose:
        print(f"{len(described)} places, {len(asked)} queries; stages "
              f"{', '.join(probe.config.stages)}; describing a place: {describe_ms:.2f} ms CPU")
    n = len(described)

    def with_views(desc: dict, at: int) -> dict:
        if viewpoints == 0:
            return desc
        from loopclosure.place_views import VIEWPOINTS

        stand_in = [described[(at + 1 + i) % n]["pairs"] for i in range(viewpoints)]
        return {**desc, VIEWPOINTS: {"pairs": np.stack([np.asarray(v) for v in stand_in])}}

    if query_viewpoints:
        asked = [with_views(q, i) for i, q in enumerate(asked)]
    out: dict[int, float] = {}
    for m in sizes:
        db = PlaceDatabase(PlaceDatabaseConfig(query_viewpoints=query_viewpoints,
                                               stored_viewpoints=stored_viewpoints,
                                               viewpoint_order=viewpoint_order,
                                               viewpoint_pool=viewpoint_pool))
        for key in range(m):
            db.add_descriptors(key, with_views(described[key % n], key), stamp=float(key))
        db.query(asked[0], headings=False)  # warm-up: scales, stacks, compiled kernels
        start = time.process_time()
        for q in asked:
            db.query(q, headings=False)
        out[m] = 1e3 * (time.process_time() - start) / len(asked)
        if verbose:
            print(f"database {m:6d} entries: {out[m]:7.2f} ms CPU per query  "
                  f"(ratio {out[m] / out[sizes[0]]:.2f})")
    return out


def against_baseline(args: argparse.Namespace, sizes: list[int]) -> None:
    """The measurement with REV's code and the working tree's, alternately."""
    with tempfile.TemporaryDirectory() as tmp:
        base = Path(tmp) / "baseline"
        base.mkdir()
        archive = subprocess.run(["git", "archive", args.baseline], cwd=ROOT, check=True,
                                 capture_output=True).stdout
        subprocess.run(["tar", "-x", "-C", str(base)], input=archive, check=True)
        runs: dict[str, list[dict]] = {"baseline": [], "now": []}
        order = [("baseline", base), ("now", ROOT)]
        for r in range(args.repeat):
            for label, code in order if r % 2 == 0 else order[::-1]:
                done = subprocess.run(
                    [sys.executable, __file__, "--worker", str(code), "--data", str(args.data),
                     "--scans", str(args.scans), "--sizes", args.sizes,
                     "--queries", str(args.queries)],
                    check=True, capture_output=True, text=True, cwd=code)
                runs[label].append({int(k): v for k, v in json.loads(done.stdout).items()})
        for m in sizes:
            old = statistics.median(x[m] for x in runs["baseline"])
            new = statistics.median(x[m] for x in runs["now"])
            print(f"database {m:6d} entries: {old:7.2f} ms ({args.baseline}) -> {new:7.2f} ms "
                  f"(now) CPU per query, ratio {old / new:.2f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data")
    parser.add_argument("--scans", type=int, default=2000, help="places described")
    parser.add_argument("--sizes", default="1000,2500,5000,10000")
    parser.add_argument("--queries", type=int, default=100)
    parser.add_argument("--viewpoints", type=int, default=0)
    parser.add_argument("--query-viewpoints", action="store_true")
    parser.add_argument("--no-stored-viewpoints", action="store_true",
                        help="the stored keyframes' viewpoints are not screened")
    parser.add_argument("--viewpoint-order", default="min", choices=("min", "interleave"))
    parser.add_argument("--baseline", help="a revision to compare with (git archive)")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--worker", help=argparse.SUPPRESS)
    args = parser.parse_args()
    sizes = [int(s) for s in args.sizes.split(",")]
    if args.worker:
        sys.path.insert(0, args.worker)
        print(json.dumps(measure(args.data, args.scans, sizes, args.queries, verbose=False)))
        return
    sys.path.insert(0, str(ROOT))
    if args.baseline:
        against_baseline(args, sizes)
        return
    measure(args.data, args.scans, sizes, args.queries, viewpoints=args.viewpoints,
            query_viewpoints=args.query_viewpoints,
            stored_viewpoints=not args.no_stored_viewpoints,
            viewpoint_order=args.viewpoint_order)


if __name__ == "__main__":
    main()
