"""Benchmark: the place database's recall of revisits from other viewpoints of the query.

Run from the repository root::

    python benchmarks/trail_retrieval.py LOG [--relations FILE] [--radius 1.0,1.5]
        [--last 1,3,5] [--offset 1.0]

The log is mapped as ``loopclosure bench loops`` maps it (`evaluation.loop_bench`,
the loop searches off; a corrected log takes its logged poses as the reference and
the drifting odometry of seed 0).  For every keyframe with a revisit (an eligible
older keyframe within 2 m by the reference) the prefilter's distance to every
eligible stored keyframe is taken, as ``bench loops``' ``prefilter`` row takes it
(the smaller of the keyframe's own and wide views), and then the smallest of that
and the distance of other descriptions of the query's place:

- ``trail R``: the keyframes among the last 10 whose position (the front end's
  poses) lies within R [m] of the query's, each by its own description
  (`LoopClosureDetector.with_trail` joins their answers so);
- ``last N``: the last N keyframes whatever their distance;
- ``moved D``: the query's submap cast again as a virtual scan from 4 viewpoints D
  [m] ahead, behind, left and right of it (those inside the place's free space),
  described anew (their ms per description printed).

It prints recall@1 and recall@10 (a true place among the K smallest distances) over
all revisits and by the distance of the nearest true place (0-1, 1-1.5, 1.5-2 m).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from evaluation.loop_bench import mapped_input  # noqa: E402
from evaluation.loop_bench_input import LoopSource  # noqa: E402
from evaluation.loop_bench_misses import revisit_queries  # noqa: E402
from loopclosure.polygon import DegeneratePolygonError, polygon_from_scan  # noqa: E402
from loopclosure.virtual_scan import virtual_scan  # noqa: E402
from slam.config import PipelineConfig  # noqa: E402

BINS = ((0.0, 1.0), (1.0, 1.5), (1.5, 2.0 + 1e-9))
DIRECTIONS = np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]])


def _moved(det, db, pts, place, rows, offset: float, clock: list[float]) -> np.ndarray:
    """Smallest prefilter distance over the query described from the moved viewpoints."""
    cfg = det.config
    best = np.full(len(rows), np.inf)
    ranges = np.where(place.valid, place.ranges, np.inf)
    for d in DIRECTIONS * offset:
        beam = np.argmin(np.abs(np.angle(np.exp(1j * (place.angles - np.arctan2(d[1], d[0]))))))
        if not ranges[beam] > offset + 0.5:  # the viewpoint must lie in the free space
            continue
        start = time.process_time()
        try:
            polygon = polygon_from_scan(virtual_scan(pts - d, cfg.virtual_beams,
                                                     cfg.virtual_range), cfg.polygon)
        except DegeneratePolygonError:
            continue
        q = db.describe(polygon)
        clock[0] += time.process_time() - start
        clock[1] += 1
        best = np.minimum(best, db.prefilter_distances(q, rows)[0])
    return best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("log")
    ap.add_argument("--relations")
    ap.add_argument("--radius", default="1.0,1.5")
    ap.add_argument("--last", default="1,3,5")
    ap.add_argument("--offset", type=float, default=1.0)
    args = ap.parse_args()
    radii = [float(r) for r in args.radius.split(",") if r]
    lasts = [int(n) for n in args.last.split(",") if n]
    source = LoopSource(args.log, relations=args.relations,
                        reference_from_log=args.relations is None,
                        odometry_noise=None if args.relations else 0, folder=str(Path.cwd()))
    mapper, result, ref = mapped_input(source, PipelineConfig())
    det, db, wide = mapper.detector, mapper.detector.database, mapper.detector.wide_database
    keys = np.array(db.keys, dtype=np.intp)  # rows in key order
    wide_keys = np.array(wide.keys, dtype=np.intp) if wide is not None else keys[:0]
    xy = np.array([result.keyframe_poses[kf.id] for kf in result.keyframes], float)[:, :2]
    names = (["own"] + [f"trail {r:g} m" for r in radii] + [f"last {n}" for n in lasts]
             + [f"moved {args.offset:g} m"])
    hits = {name: {1: [], 10: []} for name in names}
    nearest: list[float] = []
    clock = [0.0, 0]
    for k, rows, true, near in revisit_queries(det, ref):
        own = db.prefilter_distances(db.descriptors(k), rows)[0].copy()
        asked = det.wide_key(k)
        if asked is not None and asked in wide:
            w_rows = np.flatnonzero(np.isin(wide_keys, keys[rows]))
            at = np.searchsorted(keys[rows], wide_keys[w_rows])
            np.minimum.at(own, at, wide.prefilter_distances(wide.descriptors(asked), w_rows)[0])
        behind = [t for t in range(k - 1, max(k - 10, 0) - 1, -1) if t in db]
        other = {t: db.prefilter_distances(db.descriptors(t), rows)[0] for t in behind}
        views = {"own": own}
        for r in radii:
            views[f"trail {r:g} m"] = np.min(
                [own] + [other[t] for t in behind if np.hypot(*(xy[t] - xy[k])) <= r], axis=0)
        for n in lasts:
            views[f"last {n}"] = np.min([own] + [other[t] for t in behind[:n]], axis=0)
        views[f"moved {args.offset:g} m"] = np.minimum(own, _moved(
            det, db, mapper.query_submaps[k], det.place_scan(k), rows, args.offset, clock))
        for name, d in views.items():
            order = np.argsort(d, kind="stable")
            for kk in (1, 10):
                hits[name][kk].append(bool(near[order[:kk]].any()))
        nearest.append(float(true[near].min()))
    dist = np.array(nearest)
    print(f"{Path(args.log).name}: {len(dist)} revisits; describing a moved viewpoint "
          f"{1e3 * clock[0] / max(clock[1], 1):.1f} ms CPU ({clock[1]} views)")
    for kk in (1, 10):
        print(f"recall@{kk}: " + "  ".join(
            f"{name} {np.mean(hits[name][kk]):.3f}" for name in names))
        for lo, hi in BINS:
            m = (dist >= lo) & (dist < hi)
            print(f"  {lo:g}-{min(hi, 2.0):g} m ({int(m.sum())}): " + "  ".join(
                f"{name} {np.asarray(hits[name][kk])[m].mean():.3f}" for name in names))


if __name__ == "__main__":
    main()
