"""Benchmark: ways of fusing a keyframe's offset viewpoints into the prefilter's order.

Run from the repository root::

    python benchmarks/view_fusion.py LOG[:RELATIONS] ... --cache DIR
        [--radius 1.5] [--count 4] [--knn 10] [--explain]

DIR is `benchmarks/prefilter_misses.py`'s cache (each keyframe's own and wide virtual
scans, its submap, the revisit queries).  Every keyframe is described by the default
pair histogram from its own origin and from the free offset viewpoints of one ring
(`loopclosure.viewpoints`, `prefilter_misses.viewpoint_stack`).  For every revisit
query the own view's distance to each eligible stored keyframe is then one of:

``own``
    d0: the own descriptions' distance (today's default).
``query min`` / ``stored min``
    the smallest over the query's viewpoints (or the stored keyframe's) and d0:
    the existing options ``query_viewpoints`` / ``stored_viewpoints``.
``query min, scaled`` / ``stored min, scaled``
    the same minimum after each viewpoint description's distances are divided by
    that description's scale and multiplied by the own description's scale, the
    scale being the mean of its `knn` smallest distances to the own descriptions
    of the database (for a stored viewpoint: of the keyframes older than its
    owner, as they stood when it was added).  A description that is near to
    every place (a viewpoint that sees little) takes no place ahead of a place
    the own description is near to: a correction of hubness (the cross-domain
    similarity local scaling of Conneau et al., ICLR 2018, as a ratio).
``three lists``
    the own view's d0, the query-viewpoint minimum and the wide view interleaved by
    rank (`evaluation.loop_bench_queries.interleaved_order`), so the own
    description's best places keep their places among the first.

Each is interleaved with the wide view as ``bench loops``'s prefilter row does
(recall@1/10/50 printed).  ``--explain`` prints, for every query a variant loses
against ``own`` at @10, the true place's rank and which description put the places
ahead of it there, with each description's scale.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import prefilter_misses as pm  # noqa: E402

from evaluation.loop_bench_queries import interleaved_order  # noqa: E402
from loopclosure.matchers.pair_histogram import PairHistogramMatcher  # noqa: E402
from slam.config import PipelineConfig  # noqa: E402

KS = (1, 10, 50)


def knn_scale(d: np.ndarray, knn: int) -> float:
    """Mean of the `knn` smallest finite entries of `d` (nan when none)."""
    f = d[np.isfinite(d)]
    if not len(f):
        return float("nan")
    return float(np.mean(np.partition(f, min(knn, len(f)) - 1)[:knn]))


def stored_factors(keys: np.ndarray, own_m: np.ndarray, has_own: np.ndarray,
                   vecs: np.ndarray, owner: np.ndarray, knn: int) -> np.ndarray:
    """Per stored viewpoint: (own description's scale) / (its scale), both over the
    own descriptions of the keyframes older than its owner (1 with fewer than
    `knn` of them)."""
    out = np.ones(len(vecs))
    for i, (v, o) in enumerate(zip(vecs, owner, strict=True)):
        older = np.flatnonzero(has_own & (keys < keys[o]))
        if len(older) < knn or not has_own[o]:
            continue
        s_v = knn_scale(np.linalg.norm(own_m[older] - v, axis=1), knn)
        s_o = knn_scale(np.linalg.norm(own_m[older] - own_m[o], axis=1), knn)
        if s_v > 0:
            out[i] = s_o / s_v
    return out


def grids_of(scans: dict, config: PipelineConfig) -> dict[int, np.ndarray]:
    """Dilated polar occupancy grid of every scan that makes a polygon, as the place
    database stores it (`loopclosure.place_grids.polar_grid`)."""
    from loopclosure.grid_rerank import dilate_polar
    from loopclosure.place_grids import polar_grid, unpack_grid

    cfg = config.loops.database
    return {k: dilate_polar(unpack_grid(polar_grid(poly, cfg), cfg))
            for k, poly in pm.polygons_of(scans, config).items()}


def first_hit(order: np.ndarray, near: np.ndarray, finite: np.ndarray) -> int:
    hit = np.flatnonzero(near[order] & finite[order])
    return int(hit[0]) if len(hit) else pm.BIG


def study(data: dict, config: PipelineConfig, radius: float, count: int, knn: int,
          explain: bool, grid: bool = False) -> dict[str, np.ndarray]:
    matcher = PairHistogramMatcher()
    own = pm.describe_all(data["own"], config, matcher)
    wide = pm.describe_all(data["wide"], config, matcher)
    vecs, owner = pm.viewpoint_stack(data, config, matcher, radius, count)
    keys = data["keys"]
    dim = matcher.config.dim
    own_m = np.array([own.get(int(k), np.zeros(dim)) for k in keys])
    has_own = np.array([int(k) in own for k in keys])
    factors = stored_factors(keys, own_m, has_own, vecs, owner, knn)
    grid_own = grids_of(data["own"], config) if grid else None
    grid_wide = grids_of(data["wide"], config) if grid else None
    wide_keys, wide_m = pm.wide_matrix(wide)
    out: dict[str, list[int]] = {}
    for q in data["queries"]:
        k, rows, near = q["k"], q["rows"], q["near"]
        if k not in own:
            for name in out:
                out[name].append(pm.BIG)
            continue
        d0 = np.linalg.norm(own_m[rows] - own[k], axis=1)
        d0[~has_own[rows]] = np.inf
        s0 = knn_scale(d0, knn)
        qrow = int(np.searchsorted(keys, k))
        qv = vecs[owner == qrow]
        dq = np.array([np.linalg.norm(own_m[rows] - v, axis=1) for v in qv]).reshape(-1, len(rows))
        dq[:, ~has_own[rows]] = np.inf
        q_scale = np.array([s0 / knn_scale(d, knn) for d in dq]).reshape(-1, 1)
        stored_raw = np.full(len(keys), np.inf)
        stored_scaled = np.full(len(keys), np.inf)
        if len(vecs):
            dv = np.linalg.norm(vecs - own[k], axis=1)
            np.minimum.at(stored_raw, owner, dv)
            np.minimum.at(stored_scaled, owner, dv * factors)
        asked = q["asked"]
        other = pm.wide_distance(wide, wide_keys, wide_m, keys[rows], asked)
        qmin = np.minimum(d0, dq.min(axis=0)) if len(dq) else d0
        qmin_s = np.minimum(d0, (dq * q_scale).min(axis=0)) if len(dq) else d0
        smin = np.minimum(d0, stored_raw[rows])
        smin_s = np.minimum(d0, stored_scaled[rows])
        variants = {
            "own": [d0, other], "query min": [qmin, other],
            "query min, scaled": [qmin_s, other], "stored min": [smin, other],
            "stored min, scaled": [smin_s, other], "three lists": [d0, qmin, other],
            "both min, scaled": [np.minimum(qmin_s, smin_s), other],
            "three lists, stored": [d0, smin, other],
            "four lists": [d0, qmin, smin, other],
            "three lists, both min": [d0, np.minimum(qmin, smin), other],
        }
        finite = np.isfinite(np.min(np.vstack([d0, other]), axis=0))
        for name, per in variants.items():
            order = interleaved_order(per)[0]
            out.setdefault(name, []).append(first_hit(order, near, finite))
        if grid:
            for name, per in (("three lists, grid re-rank", [d0, qmin, other]),
                              ("own, grid re-rank", [d0, other])):
                order = interleaved_order(per)[0]
                out.setdefault(name, []).append(first_hit(
                    _grid_rerank(order, per, k, asked, keys[rows], grid_own, grid_wide),
                    near, finite))
        if explain:
            r0 = out["own"][-1]
            for name in ("query min", "query min, scaled", "stored min",
                         "stored min, scaled"):
                r = out[name][-1]
                if (r0 < 10) != (r < 10):
                    _explain(name, q, d0, dq, q_scale, smin, smin_s, other, r0, r, keys,
                             rows, near)
    return {n: np.array(v) for n, v in out.items()}


def _grid_rerank(order, per, k, asked, row_keys, grid_own, grid_wide, pool=10):
    """The union of each list's `pool` best re-ranked by the polar grids' similarity
    (the larger of the own grids' and the wide grids'), then the rest of `order`."""
    from loopclosure.grid_rerank import dilated_similarity

    ranks = np.full((len(per), len(order)), pm.BIG)
    for i, d in enumerate(per):
        f = np.flatnonzero(np.isfinite(d))
        ranks[i, f[np.argsort(d[f], kind="stable")]] = np.arange(len(f))
    union = np.flatnonzero(ranks.min(axis=0) < pool)
    c = np.zeros(len(union))
    for mine, grids in ((k, grid_own), (asked, grid_wide)):
        if mine is None or mine not in grids:
            continue
        have = [j for j, kk in enumerate(row_keys[union].tolist()) if kk in grids]
        if not have:
            continue
        g = np.stack([grids[int(row_keys[union[j]])] for j in have])
        sim = dilated_similarity(grids[mine], g, np.count_nonzero(g, axis=(1, 2)))
        c[have] = np.maximum(c[have], sim)
    top = union[np.argsort(-c, kind="stable")]
    rest = order[~np.isin(order, top)]
    return np.concatenate([top, rest])


def _explain(name, q, d0, dq, q_scale, smin, smin_s, other, r0, r, keys, rows, near):
    """Which description put the places ahead of the true place (`--explain`)."""
    print(f"    {name}: query {q['k']} (nearest {q['nearest']} {q['dist']:.2f} m "
          f"{q['dtheta']:.0f} deg overlap {q['overlap']:.2f}) rank {r0} -> {r}")
    true = np.flatnonzero(near)
    t = true[np.argmin(d0[true])]
    print(f"      true place {keys[rows[t]]}: d0 {d0[t]:.4f}, query viewpoints "
          + " ".join(f"{x:.4f}" for x in dq[:, t])
          + f", stored min {smin[t]:.4f} (scaled {smin_s[t]:.4f})")
    print("      query viewpoint scale factors (own scale / theirs): "
          + " ".join(f"{x:.3f}" for x in q_scale.ravel()))
    if name.startswith("query"):
        best = np.minimum(d0, dq.min(axis=0)) if len(dq) else d0
        ahead = np.flatnonzero((best < best[t]) & ~near)
        src = np.argmin(np.vstack([d0, dq]), axis=0)[ahead]
        print(f"      {len(ahead)} wrong places below the true place's {best[t]:.4f}; "
              f"taken by description (0 = own) {np.bincount(src).tolist()}; their d0 "
              f"median {np.median(d0[ahead]) if len(ahead) else float('nan'):.4f}")
    else:
        ahead = np.flatnonzero((smin < smin[t]) & ~near)
        print(f"      {len(ahead)} wrong places below the true place's {smin[t]:.4f} "
              f"({int((smin[ahead] < d0[ahead]).sum())} by a stored viewpoint); their d0 "
              f"median {np.median(d0[ahead]) if len(ahead) else float('nan'):.4f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("logs", nargs="+", help="LOG or LOG:RELATIONS")
    ap.add_argument("--cache", type=Path, required=True)
    ap.add_argument("--radius", type=float, default=1.5)
    ap.add_argument("--count", type=int, default=4)
    ap.add_argument("--knn", type=int, default=10)
    ap.add_argument("--explain", action="store_true")
    ap.add_argument("--grid", action="store_true",
                    help="also re-rank each list's 10 best by the polar grids' similarity")
    args = ap.parse_args()
    config = PipelineConfig()
    for spec in args.logs:
        t = time.perf_counter()
        data = pm.mapped(spec, config, args.cache)
        print(f"{data['name']}: {len(data['queries'])} revisits", flush=True)
        r = study(data, config, args.radius, args.count, args.knn, args.explain, args.grid)
        for name, ranks in r.items():
            print(f"  {name:20s} " + " / ".join(f"{np.mean(ranks < k):.3f}" for k in KS),
                  flush=True)
        print(f"  ({time.perf_counter() - t:.0f} s)", flush=True)


if __name__ == "__main__":
    main()
