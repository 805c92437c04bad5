"""Benchmark: what a second prefilter stage beside the pair histogram costs.

Run from the repository root::

    python benchmarks/near_stage_cost.py [--stage pairs-near] [--weight 0.25]
        [--keyframes 2000,10000] [--repeat 5]

In one process, interleaved, best of ``--repeat`` (CPU time, `time.process_time`):
describing one polygon by the pair histogram and by ``--stage`` (its
`loopclosure.place_config.stage_matcher`), a whole `PlaceDatabase.describe` with the
prefilter ``pairs`` and ``pairs,STAGE``, and one `PlaceDatabase.candidates` query
(prefilter screening, shortlist, FLIRT over K, the default grids' extras) over a
database of each ``--keyframes`` size with both prefilters (the polygons of the
simulated Box world, repeated).  Printed: microseconds a description, milliseconds a
query, and the ratios.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fft_near_cost import best  # noqa: E402

from data.sim import place_dataset  # noqa: E402
from loopclosure.place_config import PlaceDatabaseConfig, stage_matcher  # noqa: E402
from loopclosure.place_database import PlaceDatabase  # noqa: E402
from loopclosure.polygon import polygon_from_scan  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--stage", default="pairs-near")
    ap.add_argument("--weight", type=float, default=0.25)
    ap.add_argument("--keyframes", default="2000,10000")
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    polygons = [polygon_from_scan(s) for _, s in place_dataset("box", places=11,
                                                                 scans_per_place=21)]
    cfg = PlaceDatabaseConfig()
    matchers = {s: stage_matcher(s, cfg) for s in ("pairs", args.stage)}
    sample = polygons[:40]
    desc = {s: best(lambda m=m: [m.describe(p) for p in sample], args.repeat) / len(sample)
            for s, m in matchers.items()}
    print(f"describe: pairs {1e6 * desc['pairs']:.0f} us, {args.stage} "
          f"{1e6 * desc[args.stage]:.0f} us", flush=True)
    two = ("pairs", args.stage)
    setups = {"pairs": dict(prefilter=("pairs",)),
              ",".join(two): dict(prefilter=two, prefilter_weights=(1.0, args.weight))}
    whole = {}
    for name, kw in setups.items():
        db = PlaceDatabase(**kw)
        whole[name] = best(lambda db=db: [db.describe(p) for p in sample], args.repeat)
    a, b = (1e3 * whole[n] / len(sample) for n in setups)
    print(f"PlaceDatabase.describe: {a:.2f} ms -> {b:.2f} ms (ratio {b / a:.2f})", flush=True)
    for size in (int(x) for x in args.keyframes.split(",")):
        dbs = {}
        for name, kw in setups.items():
            db = PlaceDatabase(**kw)
            for i in range(size):
                db.add(i, polygons[i % len(polygons)])
            dbs[name] = (db, [db.describe(p) for p in polygons[:5]])
        query = {name: [] for name in dbs}
        for _ in range(args.repeat):  # interleaved
            for name, (db, qs) in dbs.items():
                query[name].append(best(lambda db=db, qs=qs: [db.candidates(q) for q in qs],
                                        1) / len(qs))
        a, b = (1e3 * min(query[n]) for n in dbs)
        print(f"query over {size}: pairs {a:.2f} ms, {','.join(two)} {b:.2f} ms "
              f"(ratio {b / a:.2f})", flush=True)


if __name__ == "__main__":
    main()
