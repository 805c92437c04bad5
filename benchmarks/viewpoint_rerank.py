"""Benchmark: prefilter recall@1/10/50 of offset viewpoints ranked by the smallest
distance over every pair of descriptions, against the viewpoints re-ranking a pool
with each query description rank-normalised (``viewpoint_order="rerank"``), offline.

Run from the repository root::

    python benchmarks/viewpoint_rerank.py LOG[:RELATIONS] ... --cache DIR
        [--radius 1.0] [--count 4] [--pools 128] [--ranks 30] [--side] [--full-rank]
        [--queries K,K]

The logs are mapped and cached as `prefilter_misses.py` does (the same DIR); every
keyframe's own and wide view and its free offset viewpoints on one ring (`--radius`
[m], `--count`; `loopclosure.viewpoints`) are described once by the default pair
histogram and kept in ``DIR/views-R-N/``.  Per revisit query, one matrix of the
distances of its descriptions (own, then its viewpoints) to every stored description
(own, then viewpoints) gives every variant; the own view is interleaved with the
wide view by rank as ``bench loops`` does (`interleaved_order`).  Variants:
``default`` (own descriptions only), ``min`` (smallest over every pair:
``viewpoint_order="min"`` with ``query_viewpoints``), ``min-P`` (that, only within
the own descriptions' P nearest), ``rerank-P-R`` (`loopclosure.place_views.
rank_normalised` over the pool of the own descriptions' P nearest, rank R: the
database's ``"rerank"``), and with ``--full-rank`` ``norm-R`` (rank-normalised over
every eligible keyframe, no pool).  ``--side`` keeps only the viewpoints beside the
path (offset mostly along the keyframe's y axis); ``--no-cross`` compares the
query's viewpoints with the stored own descriptions only (the query's own
description still with the stored viewpoints: no pair of two viewpoints; the
database's ``viewpoint_cross=false``).  ``--queries`` prints, per
variant, the rank of the first true place of those query keyframes and the queries
whose recall@10 a variant changes against the default.
"""

from __future__ import annotations

import argparse
import pickle
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import prefilter_misses as pm  # noqa: E402

from evaluation.loop_bench_queries import interleaved_order  # noqa: E402
from loopclosure.matchers.pair_histogram import (  # noqa: E402
    PairHistogramConfig,
    PairHistogramMatcher,
)
from loopclosure.place_views import rank_normalised  # noqa: E402
from loopclosure.polygon import DegeneratePolygonError, polygon_from_scan  # noqa: E402
from loopclosure.viewpoints import ViewpointConfig, viewpoint_scans  # noqa: E402
from slam.config import PipelineConfig  # noqa: E402

KS = (1, 10, 50)


def described(data: dict, config: PipelineConfig, cache: Path, radius: float, count: int
              ) -> dict:
    """Own, wide and viewpoint vectors of every keyframe of `data` (cached): ``own``
    and ``wide`` (key -> vector), ``vecs`` ``(V, D)``, ``owner`` (row of
    ``data["keys"]`` of each viewpoint), ``offs`` ``(V, 2)`` its offset [m]."""
    path = cache / f"views-{radius:g}-{count}" / f"{data['name']}.pkl"
    if path.exists():
        with open(path, "rb") as f:
            return pickle.load(f)
    m = PairHistogramMatcher(PairHistogramConfig())
    vp = ViewpointConfig(radii=(radius,), count=count)
    vecs, owner, offs = [], [], []
    for row, k in enumerate(data["keys"].tolist()):
        for sc in viewpoint_scans(data["submaps"][k], data["own"][k], vp):
            try:
                poly = polygon_from_scan(sc, config.loops.polygon)
            except DegeneratePolygonError:
                continue
            vecs.append(np.asarray(m.describe(poly), float))
            owner.append(row)
            offs.append(sc.odom[:2])
    out = dict(own=pm.describe_all(data["own"], config, m),
               wide=pm.describe_all(data["wide"], config, m),
               vecs=np.array(vecs).reshape(-1, m.config.dim), owner=np.array(owner, np.intp),
               offs=np.array(offs, float).reshape(-1, 2))
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as f:
        pickle.dump(out, f)
    return out


def per_key_min(values: np.ndarray, owner: np.ndarray, n: int) -> np.ndarray:
    """``(n,)`` smallest of `values` per owner row (inf: none)."""
    best = np.full(n, np.inf)
    np.minimum.at(best, owner, values)
    return best


def variants(pools: list[int], ranks: list[int], full_rank: bool) -> dict:
    """name -> f(P, d0, rows) giving the own view's order key per stored row: ``P``
    ``(A, n)`` per query description the smallest distance over each keyframe's
    descriptions, ``d0`` the own-own distances, ``rows`` the eligible rows."""
    def pool_of(d0, rows, size):
        return rows[np.argsort(d0[rows], kind="stable")[:size]]

    def default(P, d0, rows):
        return d0

    def plain_min(P, d0, rows):
        return P.min(axis=0)

    def min_pool(size):
        def f(P, d0, rows):
            pool = pool_of(d0, rows, size)
            out = d0.copy()
            out[pool] = P[:, pool].min(axis=0)
            return out
        return f

    def rerank(size, rank):
        def f(P, d0, rows):
            pool = pool_of(d0, rows, size)
            out = d0.copy()
            out[pool] = rank_normalised(P[:, pool], rank)[0]
            return out
        return f

    def norm(rank):
        def f(P, d0, rows):
            out = np.full(len(d0), np.inf)
            out[rows] = rank_normalised(P[:, rows], rank)[0]
            return out
        return f

    out = {"default": default, "min": plain_min}
    for p in pools:
        out[f"min-{p}"] = min_pool(p)
        for r in ranks:
            out[f"rerank-{p}-{r}"] = rerank(p, r)
    if full_rank:
        for r in ranks:
            out[f"norm-{r}"] = norm(r)
    return out


def ranks_of(data: dict, d: dict, fns: dict, side: bool, own_only: bool = False
             ) -> dict[str, np.ndarray]:
    """Per variant and revisit query, the 0-based interleaved rank of the first true
    place (`pm.BIG`: none); `own_only`: the query's viewpoints are compared with the
    stored own descriptions only (no pair of two viewpoints)."""
    keys = data["keys"]
    own, wide = d["own"], d["wide"]
    vecs, owner = d["vecs"], d["owner"]
    if side:
        keep = np.abs(d["offs"][:, 1]) > np.abs(d["offs"][:, 0])
        vecs, owner = vecs[keep], owner[keep]
    dim = len(next(iter(own.values())))
    has_own = np.array([int(k) in own for k in keys])
    own_m = np.array([own.get(int(k), np.zeros(dim)) for k in keys])
    stored = np.vstack([own_m, vecs])
    s_owner = np.concatenate([np.arange(len(keys)), owner])
    s_sq = (stored ** 2).sum(axis=1)
    wide_keys, wide_m = pm.wide_matrix(wide)
    out: dict[str, list[int]] = {name: [] for name in fns}
    for q in data["queries"]:
        k, rows, near = q["k"], q["rows"], q["near"]
        if k not in own:
            for v in out.values():
                v.append(pm.BIG)
            continue
        qrow = int(np.searchsorted(keys, k))
        Q = np.vstack([own[k][None], vecs[owner == qrow]])
        D = np.sqrt(np.maximum((Q ** 2).sum(1)[:, None] + s_sq[None] - 2 * Q @ stored.T, 0))
        P = np.array([per_key_min(D[a] if a == 0 or not own_only else D[a, : len(keys)],
                                  s_owner if a == 0 or not own_only else s_owner[: len(keys)],
                                  len(keys)) for a in range(len(Q))])
        d0 = D[0, : len(keys)].copy()
        d0[~has_own] = np.inf
        P[:, ~has_own] = np.inf
        other = pm.wide_distance(wide, wide_keys, wide_m, keys[rows], q["asked"])
        for name, fn in fns.items():
            d_own = fn(P, d0, rows)[rows]
            per = [d_own, other]
            order = interleaved_order(per)[0]
            finite = np.isfinite(np.min(np.vstack(per), axis=0))[order]
            hit = np.flatnonzero(near[order] & finite)
            out[name].append(int(hit[0]) if len(hit) else pm.BIG)
    return {n: np.array(v) for n, v in out.items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("logs", nargs="+", help="LOG or LOG:RELATIONS")
    ap.add_argument("--cache", type=Path, required=True)
    ap.add_argument("--radius", type=float, default=1.0)
    ap.add_argument("--count", type=int, default=4)
    ap.add_argument("--pools", default="128")
    ap.add_argument("--ranks", default="30")
    ap.add_argument("--side", action="store_true")
    ap.add_argument("--full-rank", action="store_true")
    ap.add_argument("--no-cross", action="store_true",
                    help="query viewpoints against stored own descriptions only")
    ap.add_argument("--queries", default="")
    args = ap.parse_args()
    config = PipelineConfig()
    fns = variants([int(p) for p in args.pools.split(",")],
                   [int(r) for r in args.ranks.split(",")], args.full_rank)
    watch = [int(k) for k in args.queries.split(",") if k]
    for spec in args.logs:
        t = time.perf_counter()
        data = pm.mapped(spec, config, args.cache)
        d = described(data, config, args.cache, args.radius, args.count)
        r = ranks_of(data, d, fns, args.side, args.no_cross)
        ks = np.array([q["k"] for q in data["queries"]])
        print(f"{data['name']}: {len(ks)} revisits, {len(d['vecs'])} viewpoints "
              f"({time.perf_counter() - t:.0f} s)", flush=True)
        for name, x in r.items():
            line = f"  {name:16s} " + " ".join(f"@{k} {np.mean(x < k):.3f}" for k in KS)
            if name != "default":
                lost = ks[(r["default"] < 10) & (x >= 10)].tolist()
                won = ks[(r["default"] >= 10) & (x < 10)].tolist()
                line += f"   @10 lost {lost} won {len(won)}"
            for k in watch:
                if k in ks:
                    line += f"   query {k}: rank {int(x[ks == k][0])}"
            print(line, flush=True)


if __name__ == "__main__":
    main()
