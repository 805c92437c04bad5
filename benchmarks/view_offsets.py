"""Benchmark: the prefilter's recall of revisits with the database keyframes described
from offset viewpoints too, by the distance to the nearest true place.

Run from the repository root::

    python benchmarks/view_offsets.py LOG[:RELATIONS] ... [--cache DIR]
        [--radius R ...] [--count N] [--clearance C] [--set KEY=VALUE ...]

Each log is mapped as ``loopclosure bench loops`` maps it (`evaluation.loop_bench`;
a corrected log takes its logged poses as the reference, odometry of seed 0), once:
with `--cache` the keyframes' submaps, descriptors and revisit queries are kept in
DIR and reused.  For every keyframe with a revisit (an eligible older keyframe within
2 m by the reference), the pair-histogram distance to every eligible stored keyframe
is taken from the keyframe's own description (``own``) and, for each setting of
(`radius`, `count`), as the smallest over a stored keyframe's own description and
those of the viewpoints of `loopclosure.viewpoints` (``ring R xN``); each is also
interleaved by rank with the wide view (`evaluation.loop_bench_queries.interleaved_order`,
as ``bench loops`` merges the views).  With ``--symmetric`` each setting is also
taken with the query described from its own viewpoints (``sym``: the smallest over
every pair of a query and a stored description,
`PlaceDatabaseConfig.query_viewpoints`); with ``--full`` also with the viewpoints
rendered from the complete submaps (neighbours on both sides, the keyframe's origin
one of them; radius 0: the origin alone).  It prints recall@1/10/50 over all revisits and
recall@10 per bin of the nearest true place's distance, and the seconds the offset
descriptions took per keyframe.
"""

from __future__ import annotations

import argparse
import itertools
import pickle
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from evaluation.loop_bench import mapped_input  # noqa: E402
from evaluation.loop_bench_input import LoopSource  # noqa: E402
from evaluation.loop_bench_misses import DISTANCE_BINS, revisit_queries  # noqa: E402
from evaluation.loop_bench_queries import interleaved_order  # noqa: E402
from loopclosure.polygon import DegeneratePolygonError, polygon_from_scan  # noqa: E402
from loopclosure.viewpoints import ViewpointConfig, viewpoint_scans  # noqa: E402
from loopclosure.virtual_scan import virtual_scan  # noqa: E402
from slam.config import PipelineConfig  # noqa: E402
from slam.config_io import apply_overrides  # noqa: E402

KS = (1, 10, 50)


def _mapped(spec: str, config: PipelineConfig, cache: Path | None) -> dict:
    """The per-log data the study needs (module docstring), from the cache if there."""
    log, _, relations = spec.partition(":")
    name = Path(log).name.split(".")[0]
    path = None if cache is None else cache / f"{name}.pkl"
    if path is not None and path.exists():
        with open(path, "rb") as f:
            data = pickle.load(f)
        if "full_submaps" in data:
            return data
    source = LoopSource(str(Path(log).resolve()),
                        relations=str(Path(relations).resolve()) if relations else None,
                        reference_from_log=not relations,
                        odometry_noise=None if relations else 0, folder=str(Path.cwd()))
    mapper, _, ref = mapped_input(source, config)
    det, db, wide = mapper.detector, mapper.detector.database, mapper.detector.wide_database
    keys = np.array(db.keys, dtype=np.intp)
    own = np.array([np.asarray(db.descriptors(int(k))["pairs"], float) for k in keys])
    wide_keys = np.array(wide.keys, dtype=np.intp) if wide is not None else keys[:0]
    wide_vec = np.array([np.asarray(wide.descriptors(int(k))["pairs"], float)
                         for k in wide_keys]) if len(wide_keys) else np.zeros((0, 1))
    queries = [(k, rows, true, det.wide_key(k)) for k, rows, true, _ in
               revisit_queries(det, ref)]
    data = {"name": name, "keys": keys, "own": own, "wide_keys": wide_keys,
            "wide": wide_vec, "queries": queries,
            "submaps": {int(k): _described_submap(mapper, int(k)) for k in keys},
            "full_submaps": {int(k): mapper.submap(int(k)) for k in keys},
            "ref": ref}
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        with open(path, "wb") as f:
            pickle.dump(data, f)
    return data


def _described_submap(mapper, key: int) -> np.ndarray:
    """Keyframe `key`'s submap as it was when it was described (the newest keyframe:
    its past neighbours only; the front end's worker described it in its own copy)."""
    n = mapper.config.submap_neighbours()
    return mapper._local_points(key, max(mapper._span(key)[0], key - n), key)


def offset_vectors(data: dict, config: PipelineConfig, vp: ViewpointConfig,
                   full: bool = False) -> tuple[np.ndarray, np.ndarray, float]:
    """``(V, D)`` pair-histogram vectors of every keyframe's offset viewpoints, the
    row of `data["keys"]` each belongs to, and the seconds per keyframe.  `full`: the
    viewpoints see the keyframe's complete submap (its neighbours on both sides, as
    it is once the later ones exist), and the keyframe's origin is one of them."""
    from loopclosure.matchers import get_matcher

    loops = config.loops
    pairs = get_matcher("pairs")
    vecs, owner = [], []
    start = time.perf_counter()
    for row, k in enumerate(data["keys"].tolist()):
        pts = data["full_submaps" if full else "submaps"][k]
        own_scan = virtual_scan(pts, loops.virtual_beams, loops.virtual_range)
        scans = viewpoint_scans(pts, own_scan, vp, loops.virtual_beams, loops.virtual_range)
        for scan in ([own_scan] if full else []) + scans:
            try:
                poly = polygon_from_scan(scan, loops.polygon)
            except DegeneratePolygonError:
                continue
            vecs.append(np.asarray(pairs.describe(poly), float))
            owner.append(row)
    sec = (time.perf_counter() - start) / max(1, len(data["keys"]))
    dim = data["own"].shape[1]
    return (np.array(vecs).reshape(-1, dim), np.array(owner, np.intp), sec)


def _dist(q: np.ndarray, m: np.ndarray) -> np.ndarray:
    return np.sqrt(np.maximum(((m - q) ** 2).sum(axis=1), 0.0))


def study(data: dict, variants: dict[str, tuple[np.ndarray, np.ndarray]],
          symmetric: bool = False) -> dict:
    """Per view name, per query: rank (0-based) of the first true place (big: none)."""
    keys, own, ref = data["keys"], data["own"], data["ref"]
    wide_keys, wide = data["wide_keys"], data["wide"]
    out: dict[str, list[int]] = {}
    nearest = []
    for k, rows, true, asked in data["queries"]:
        near = true <= 2.0
        nearest.append(float(true[near].min()))
        q = own[np.searchsorted(keys, k)]
        d_own = _dist(q, own[rows])
        other = np.full(len(rows), np.inf)
        if asked is not None and len(wide_keys) and asked in set(wide_keys.tolist()):
            wq = wide[np.searchsorted(wide_keys, asked)]
            w_rows = np.flatnonzero(np.isin(wide_keys, keys[rows]))
            at = np.searchsorted(keys[rows], wide_keys[w_rows])
            other[at] = _dist(wq, wide[w_rows])
        views = {"own": d_own}
        row_k = np.searchsorted(keys, k)
        for name, (vecs, owner) in variants.items():
            d_all = _dist(q, vecs)
            best = np.full(len(keys), np.inf)
            np.minimum.at(best, owner, d_all)
            views[name] = np.minimum(d_own, best[rows])
            if symmetric:  # the query described from its own viewpoints too
                sym = views[name].copy()
                for qv in vecs[owner == row_k]:
                    d_all = _dist(qv, vecs)
                    best = np.full(len(keys), np.inf)
                    np.minimum.at(best, owner, d_all)
                    sym = np.minimum(sym, np.minimum(_dist(qv, own[rows]), best[rows]))
                views["sym " + name] = sym
        for name, d in views.items():
            for label, order in ((name, np.argsort(d, kind="stable")),
                                 (name + " +wide", interleaved_order([d, other])[0])):
                hit = np.flatnonzero(near[order])
                out.setdefault(label, []).append(int(hit[0]) if len(hit) else 10**9)
    del ref
    return {"rank": {n: np.array(r) for n, r in out.items()}, "nearest": np.array(nearest)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("logs", nargs="+", help="LOG or LOG:RELATIONS")
    ap.add_argument("--cache", type=Path)
    ap.add_argument("--radius", action="append", default=[],
                    help="ring radii of one setting, comma-separated [m] (repeatable)")
    ap.add_argument("--count", type=int, default=6)
    ap.add_argument("--full", action="store_true",
                    help="also each setting from the complete submaps, origin included")
    ap.add_argument("--symmetric", action="store_true",
                    help="also each setting with the query described from its viewpoints")
    ap.add_argument("--clearance", type=float, default=ViewpointConfig().clearance)
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    args = ap.parse_args()
    config = apply_overrides(PipelineConfig(), args.set)
    for spec in args.logs:
        data = _mapped(spec, config, args.cache)
        variants = {}
        for r in args.radius or ["1"]:
            radii = tuple(float(x) for x in r.split(","))
            for full in (False, True) if args.full else (False,):
                if r == "0" and not full:
                    continue
                vp = ViewpointConfig(radii=radii if r != "0" else (),
                                     count=args.count, clearance=args.clearance)
                vecs, owner, sec = offset_vectors(data, config, vp, full)
                name = f"{'full ' if full else ''}ring{r}x{args.count}"
                variants[name] = (vecs, owner)
                print(f"{data['name']} {name}: {len(vecs) / len(data['keys']):.2f} "
                      f"viewpoints a keyframe, {1e3 * sec:.1f} ms a keyframe", flush=True)
        res = study(data, variants, args.symmetric)
        nearest = res["nearest"]
        print(f"{data['name']}: {len(nearest)} revisits, {len(data['keys'])} keyframes")
        for name, rank in res["rank"].items():
            line = "  ".join(f"R@{k} {np.mean(rank < k):.3f}" for k in KS)
            bins = []
            for lo, hi in itertools.pairwise(DISTANCE_BINS):
                sel = (nearest >= lo) & (nearest < hi if hi < DISTANCE_BINS[-1]
                                          else nearest <= hi)
                bins.append(f"{lo:g}-{hi:g}:{np.mean(rank[sel] < 10):.2f}({int(sel.sum())})")
            print(f"  {name:22s} {line}   R@10 by distance {' '.join(bins)}")


if __name__ == "__main__":
    main()
