"""Benchmark: what ranks above the true place when the prefilter misses a revisit.

Run from the repository root::

    python benchmarks/prefilter_rivals.py LOG[:RELATIONS] ... --cache DIR [--weight 0.1]
        [--near-radius 6] [--combo STAGE:W ...]

Reads (or makes) the cache of `benchmarks/prefilter_misses.py` (every keyframe's own
and wide virtual scans and the revisit queries of a log mapped as ``loopclosure bench
loops`` maps it) and describes every scan by four prefilter vectors: the pair
histogram (``pairs``, the default stage), the pair histogram of the surfaces within
``--near-radius`` (6 m) of the sensor (``pairs-near``,
`PairHistogramConfig.max_range`), the near+far FFT (``fft-near``) and the ring
projection (``ring``).  Each view's distance is normalised by the median distance
of 256 random pairs of its keyframes (as `benchmarks/fft_near_prefilter.py`).  For
each revisit query the stored keyframes are ordered as ``bench loops``'s prefilter
row orders them (own and wide view interleaved by rank) and, for a miss (no true
place among the first 10), printed:

* the rivals (the wrong places ranked above the first true place): how many, how far
  from the query at the reference poses [m] (share within 2-4 m, 4-10 m, beyond
  10 m), and whether they are one place (the spread of their positions);
* the first true place's rank in the own view by each vector alone, and the share of
  the own view's rivals that each other vector still puts ahead of the true place
  (which stage's distance is closest to the true one; whether the near field or the
  whole view puts the rivals ahead);
* recall@1/10/50 of ``p = d_pairs + W d_STAGE`` for each ``--combo STAGE:W``;
* for ``p = d_pairs + w d_fft-near`` (``--weight``): the queries whose first true
  place falls from within 50 to 50 or beyond, and the rivals that the near field
  moved ahead (their distance from the query, their ``fft-near`` rank, the true
  place's ``fft-near`` rank).
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

from fft_near_prefilter import describe, distances, matrix, scale  # noqa: E402
from prefilter_misses import describe_all, mapped  # noqa: E402

from evaluation.loop_bench_queries import interleaved_order  # noqa: E402
from loopclosure.matchers.pair_histogram import (  # noqa: E402
    PairHistogramConfig,
    PairHistogramMatcher,
)
from loopclosure.place_config import NEAR_FFT, NEAR_PAIRS, PlaceDatabaseConfig  # noqa: E402
from slam.config import PipelineConfig  # noqa: E402

BIG = 10**9
STAGES = ("pairs", NEAR_PAIRS, NEAR_FFT, "ring")
K, EXTRA = 10, 5


def view_vectors(data: dict, config: PipelineConfig, db: PlaceDatabaseConfig) -> dict:
    """Per view ("own", "wide"): its sorted keys and, per stage of `STAGES`, the
    matrix of vectors, which keys have one, and the view's scale."""
    near = PairHistogramMatcher(PairHistogramConfig(max_range=db.pairs_near_radius))
    out = {}
    for view in ("own", "wide"):
        vk = data["keys"] if view == "own" else np.array(sorted(data["wide"]), np.intp)
        per = {}
        for stage in STAGES:
            vecs = (describe_all(data[view], config, near) if stage == NEAR_PAIRS
                    else describe(data[view], config, stage, db))
            m, has = matrix(vecs, vk)
            per[stage] = (m, has, scale(m, has) if has.sum() > 1 else 1.0)
        out[view] = (vk, per)
    return out


def first_true(order: np.ndarray, near: np.ndarray, finite: np.ndarray) -> int:
    hit = np.flatnonzero(near[order] & finite[order])
    return int(hit[0]) if len(hit) else BIG


def study(data: dict, views: dict, weight: float, combos: list[tuple[str, float]] = ()
          ) -> dict:
    keys, ref = data["keys"], data["ref"]
    acc: dict[str, list] = {n: [] for n in (
        "rank", "rank_w", "n_rivals", "riv_dist", "riv_spread", "own_rank", "ahead",
        "lost", "lost_riv_dist", "lost_riv_near_rank", "lost_true_near_rank",
        "lost_true_pairs_rank", "lost_n_new", "all_true_near_rank", "query_dist",
        "lost_dist", "lost_overlap")}
    extras: dict[str, list[bool]] = {}
    for q in data["queries"]:
        rows, near = q["rows"], q["near"]
        if not near.any():
            continue
        d = distances(views, keys, q)
        with np.errstate(invalid="ignore"):
            comb = {v: np.where(np.isnan(x := d[v, "pairs"] + weight * d[v, NEAR_FFT]),
                                np.inf, x) for v in ("own", "wide")}
        base = [d["own", "pairs"], d["wide", "pairs"]]
        fin = np.isfinite(np.min(np.vstack(base), axis=0))
        order = interleaved_order(base)[0]
        r0 = first_true(order, near, fin)
        order_w = interleaved_order([comb["own"], comb["wide"]])[0]
        fin_w = np.isfinite(np.min(np.vstack([comb["own"], comb["wide"]]), axis=0))
        rw = first_true(order_w, near, fin_w)
        acc["rank"].append(r0)
        acc["rank_w"].append(rw)
        own_ranks = {}
        for st in STAGES:
            x = d["own", st]
            o = np.argsort(x, kind="stable")
            own_ranks[st] = first_true(o, near, np.isfinite(x))
        acc["all_true_near_rank"].append(own_ranks[NEAR_FFT])
        for st, w in combos:
            with np.errstate(invalid="ignore"):
                per = [np.where(np.isnan(x := d[v, "pairs"] + w * d[v, st]), np.inf, x)
                       for v in ("own", "wide")]
            o = interleaved_order(per)[0]
            acc.setdefault(f"pairs + {w:g} {st}", []).append(
                first_true(o, near, np.isfinite(np.min(np.vstack(per), axis=0))))
        for name, hit in extra_hits(d, order, near, fin).items():
            extras.setdefault(name, []).append(hit)
        qpos = ref[q["k"], :2]
        acc["query_dist"].append(q["dist"])
        if r0 >= 10:
            riv = order[:min(r0, 50)]
            riv = riv[~near[riv]]
            pos = ref[keys[rows[riv]], :2]
            acc["n_rivals"].append(r0)
            acc["riv_dist"].append(np.hypot(*(pos - qpos).T))
            acc["riv_spread"].append(float(np.median(np.hypot(*(pos - np.median(pos, 0)).T))))
            acc["own_rank"].append(own_ranks)
            # the own view's rivals (pairs) and the share each stage keeps ahead
            xo = d["own", "pairs"]
            t = np.flatnonzero(near & np.isfinite(xo))
            if len(t):
                tbest = {st: np.min(d["own", st][t]) for st in STAGES}
                rv = np.flatnonzero(~near & (xo < tbest["pairs"]))
                acc["ahead"].append({st: float(np.mean(d["own", st][rv] < tbest[st]))
                                     if len(rv) else np.nan for st in STAGES})
        if r0 < 50 <= rw:
            new = order_w[:50]
            new = new[~near[new] & ~np.isin(new, order[:r0])]
            pos = ref[keys[rows[new]], :2]
            acc["lost"].append(q["k"])
            acc["lost_riv_dist"].append(np.hypot(*(pos - qpos).T))
            xn = d["own", NEAR_FFT]
            onear = np.argsort(xn, kind="stable")
            rank_of = np.empty(len(onear), np.intp)
            rank_of[onear] = np.arange(len(onear))
            acc["lost_riv_near_rank"].append(rank_of[new])
            acc["lost_true_near_rank"].append(own_ranks[NEAR_FFT])
            acc["lost_true_pairs_rank"].append(own_ranks["pairs"])
            acc["lost_n_new"].append(len(new))
            acc["lost_dist"].append(q["dist"])
            acc["lost_overlap"].append(q["overlap"])
    acc["extras"] = {n: np.array(v) for n, v in extras.items()}
    return acc


def extra_hits(d: dict, order: np.ndarray, near: np.ndarray, fin: np.ndarray
               ) -> dict[str, bool]:
    """Whether a true place is among the pair histogram's first `K` (interleaved
    order) joined by the first `EXTRA` of another stage's interleaved order not
    among them; ``pairs`` : the pair histogram's own first K + EXTRA."""
    out = {"pairs": bool(near[order[:K + EXTRA]].any())}
    head = order[:K]
    for st in STAGES[1:]:
        per = [d["own", st], d["wide", st]]
        o = interleaved_order(per)[0]
        ok = np.isfinite(np.min(np.vstack(per), axis=0))[o]
        o = o[ok & ~np.isin(o, head)][:EXTRA]
        out[st] = bool(near[head].any() or near[o].any())
    return out


def _pct(x: np.ndarray, lo: float, hi: float) -> str:
    return f"{np.mean((x >= lo) & (x < hi)):.2f}"


def report(name: str, acc: dict, weight: float) -> None:
    r0, rw = np.array(acc["rank"]), np.array(acc["rank_w"])
    print(f"{name}: {len(r0)} revisits, recall@1/10/50 pairs "
          f"{np.mean(r0 < 1):.3f}/{np.mean(r0 < 10):.3f}/{np.mean(r0 < 50):.3f}, "
          f"+{weight:g} fft-near {np.mean(rw < 1):.3f}/{np.mean(rw < 10):.3f}/"
          f"{np.mean(rw < 50):.3f}", flush=True)
    n = len(acc["n_rivals"])
    if n:
        rd = np.concatenate(acc["riv_dist"])
        print(f"  misses {n}: rivals ahead (first 50) at the reference: distance median "
              f"{np.median(rd):.1f} m; 2-4 m {_pct(rd, 2, 4)}, 4-10 m {_pct(rd, 4, 10)}, "
              f">=10 m {_pct(rd, 10, np.inf)}; per miss, median spread of the rivals "
              f"{np.median(acc['riv_spread']):.1f} m")
        per_miss_near = np.array([np.mean(x < 4) for x in acc["riv_dist"]])
        print(f"  misses whose rivals are mostly (>half) within 4 m: "
              f"{np.mean(per_miss_near > 0.5):.2f}")
        for st in STAGES:
            rk = np.array([o[st] for o in acc["own_rank"]])
            ah = np.array([a[st] for a in acc["ahead"]])
            print(f"  own view by {st:8s}: true place rank median {np.median(rk):.0f}, "
                  f"within 10 {np.mean(rk < 10):.2f}, within 50 {np.mean(rk < 50):.2f}; "
                  f"pairs' rivals kept ahead {np.nanmean(ah):.2f}")
    lost = len(acc["lost"])
    gained = int(np.sum((rw < 50) & (r0 >= 50)))
    print(f"  @50 with fft-near: lost {lost}, gained {gained}")
    if lost:
        ld = np.concatenate(acc["lost_riv_dist"])
        lr = np.concatenate(acc["lost_riv_near_rank"])
        print(f"    new rivals: {np.median(acc['lost_n_new']):.0f} a query; distance median "
              f"{np.median(ld):.1f} m, 2-4 m {_pct(ld, 2, 4)}, 4-10 m {_pct(ld, 4, 10)}, "
              f">=10 m {_pct(ld, 10, np.inf)}; their fft-near own rank median "
              f"{np.median(lr):.0f}")
        tn = np.array(acc["lost_true_near_rank"])
        tp = np.array(acc["lost_true_pairs_rank"])
        an = np.array(acc["all_true_near_rank"])
        print(f"    true place's own rank: pairs median {np.median(tp):.0f}, fft-near "
              f"median {np.median(tn):.0f} (all revisits: fft-near median "
              f"{np.median(an):.0f})")
        print(f"    lost queries: {acc['lost']}; their nearest true place: distance median "
              f"{np.median(acc['lost_dist']):.2f} m, overlap median "
              f"{np.nanmedian(acc['lost_overlap']):.2f}")
    for name, r in acc.items():
        if name.startswith("pairs + "):
            r = np.array(r)
            print(f"  {name}: recall@1/10/50 {np.mean(r < 1):.3f}/{np.mean(r < 10):.3f}/"
                  f"{np.mean(r < 50):.3f}")
    print(f"  first {K} of pairs + {EXTRA} extras: " + ", ".join(
        f"{n} {np.mean(h):.3f}" for n, h in acc["extras"].items()))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("logs", nargs="+", help="LOG or LOG:RELATIONS")
    ap.add_argument("--cache", type=Path, required=True)
    ap.add_argument("--weight", type=float, default=0.1)
    ap.add_argument("--near-radius", type=float, default=6.0,
                    help="R of the pairs-near stage [m]")
    ap.add_argument("--combo", action="append", default=[], metavar="STAGE:W",
                    help="also rank by p = d_pairs + W d_STAGE (repeatable)")
    args = ap.parse_args()
    config = PipelineConfig()
    db = PlaceDatabaseConfig(pairs_near_radius=args.near_radius)
    for spec in args.logs:
        t = time.perf_counter()
        data = mapped(spec, config, args.cache)
        views = view_vectors(data, config, db)
        combos = [(c.rpartition(":")[0], float(c.rpartition(":")[2])) for c in args.combo]
        acc = study(data, views, args.weight, combos)
        report(f"{data['name']} ({time.perf_counter() - t:.0f} s)", acc, args.weight)


if __name__ == "__main__":
    main()
