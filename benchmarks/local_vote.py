"""Benchmark: a keypoint-pair vote (`loopclosure.place_vote`) beside the prefilter.

Run from the repository root::

    python benchmarks/local_vote.py LOG[:RELATIONS] ... --cache DIR
        [--variant NAME:FIELD=VALUE,...] [--split 7]

Each log is mapped as ``loopclosure bench loops`` maps it, once, with the cache of
`benchmarks/prefilter_misses.py` (same DIR, same files).  Every stored keyframe's own
view (and its wide view, where it has one) is described by FLIRT interest points
(`loopclosure.matchers.flirt`, the loop detector's verifier, default parameters) and
stored in a `PairVoteIndex` per view.  Each revisit query orders the eligible stored
keyframes

- ``default``: as ``bench loops``'s prefilter row (own and wide pair-histogram
  distances interleaved by rank, `prefilter_misses.ranks`);
- ``vote``: by the pair vote of its own view's keypoints (with ``--query-wide``
  also its wide view's, the larger score kept), own and wide indexes interleaved by
  rank (ties by the default order);
- ``fused N``: the default order's first N rows, then the vote's best rows not among
  them, then the rest in the default order (10 - N of the first 10 from the vote);
- ``fused own N``: the same with the own index's vote alone (a query's own view
  against the stored own views, as one database would vote);
- ``interleave3``: own, wide and vote lists interleaved by rank;
- ``either@10``: a true place among the default's first 10 or the vote's (20 rows).

Printed per log and variant (``NAME:`` then `PairVoteConfig` fields): recall@1/10/50
of each order and recall@10 per distance / overlap bin, and CPU ms per vote query.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from prefilter_misses import (  # noqa: E402
    BIG,
    KS,
    _binned,
    describe_all,
    mapped,
    polygons_of,
    wide_distance,
    wide_matrix,
)

from evaluation.loop_bench_misses import DISTANCE_BINS, OVERLAP_BINS  # noqa: E402
from evaluation.loop_bench_queries import interleaved_order  # noqa: E402
from loopclosure.matchers.flirt import FlirtConfig, FlirtMatcher  # noqa: E402
from loopclosure.matchers.pair_histogram import PairHistogramMatcher  # noqa: E402
from loopclosure.place_vote import PairVoteConfig, PairVoteIndex  # noqa: E402
from slam.config import PipelineConfig  # noqa: E402
from slam.config_io import apply_overrides  # noqa: E402


def keypoints(scans: dict, config: PipelineConfig, step: float | None = None,
              max_range: float | None = None, max_features: int = 40
              ) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """FLIRT interest points (positions [m], normal angles [rad]) of every scan.
    `step` [m]: the polygon's boundary sampled every `step` metres (``n_samples`` =
    perimeter / step, 64 .. 4096) instead of 256 samples whatever its perimeter;
    `max_range` [m]: points farther from the sensor dropped."""
    flirt = FlirtMatcher(FlirtConfig(max_features=max_features))
    out = {}
    for k, poly in polygons_of(scans, config).items():
        m = flirt
        if step is not None:
            v = np.asarray(poly.vertices, float)
            per = float(np.hypot(*(np.roll(v, -1, axis=0) - v).T).sum())
            n = int(np.clip(round(per / step), 64, 4096))
            m = FlirtMatcher(FlirtConfig(n_samples=n, max_features=max_features))
        f = m.describe(poly)
        p, o = np.asarray(f.points, float), np.asarray(f.orientations, float)
        # label: concave (1) or convex (0), plus 2 x the scale's octave above 0.3 m (0..2)
        octave = np.clip(np.floor(np.log2(np.maximum(f.scales, 1e-9) / 0.3)), 0, 2)
        lab = (np.asarray(f.responses) < 0).astype(np.int64) + 2 * octave.astype(np.int64)
        if max_range is not None:
            keep = np.hypot(p[:, 0], p[:, 1]) <= max_range
            p, o, lab = p[keep], o[keep], lab[keep]
        out[k] = (p, o, lab)
    return out


def repeatability(data: dict, kp: dict, radius: float = 0.5) -> tuple[float, float]:
    """Median over revisit queries of the share of the query's keypoints with a
    keypoint of its nearest true place within `radius` [m] once that place's are
    moved into the query's frame by the reference poses; and the median count."""
    ref = np.asarray(data["ref"], float)
    share, count = [], []
    for q in data["queries"]:
        k, j = q["k"], q["nearest"]
        if k not in kp or j not in kp or not len(kp[k][0]) or not len(kp[j][0]):
            continue
        a, b = ref[k], ref[j]
        cb, sb = np.cos(b[2]), np.sin(b[2])
        w = kp[j][0] @ np.array([[cb, sb], [-sb, cb]]) + b[:2]  # world
        ca, sa = np.cos(a[2]), np.sin(a[2])
        local = (w - a[:2]) @ np.array([[ca, -sa], [sa, ca]])
        d = np.hypot(*(kp[k][0][:, None, :] - local[None]).transpose(2, 0, 1))
        hit = d.min(axis=1) <= radius
        share.append(hit.mean())
        count.append(hit.sum())
    return float(np.median(share)), float(np.median(count))


def vote_index(keys: np.ndarray, kp: dict, cfg: PairVoteConfig) -> tuple[PairVoteIndex,
                                                                          np.ndarray]:
    """Index of the keyframes of `keys` that have keypoints, and each index row's
    position in `keys`."""
    index = PairVoteIndex(cfg)
    at = []
    for pos, k in enumerate(keys.tolist()):
        if k in kp:
            p, o, lab = kp[k]
            index.add(p, o, lab % cfg.n_labels)
            at.append(pos)
    return index, np.array(at, np.intp)


def first_hit(order: np.ndarray, near: np.ndarray) -> int:
    hit = np.flatnonzero(near[order])
    return int(hit[0]) if len(hit) else BIG


def fused(default: np.ndarray, vote_order: np.ndarray, n: int, k: int = 10) -> np.ndarray:
    """First `n` of `default`, then the vote's best not among them up to `k`, then the
    rest of `default`."""
    head = default[:n]
    extra = vote_order[: 4 * k][~np.isin(vote_order[: 4 * k], head)][: k - n]
    first = np.concatenate([head, extra]).astype(np.intp)
    return np.concatenate([first, default[~np.isin(default, first)]]).astype(np.intp)


def run_log(data: dict, config: PipelineConfig, kp_own: dict, kp_wide: dict,
            cfg: PairVoteConfig, splits: list[int], query_wide: bool = False
            ) -> dict[str, np.ndarray]:
    keys = data["keys"]
    matcher = PairHistogramMatcher()
    own = describe_all(data["own"], config, matcher)
    wide = describe_all(data["wide"], config, matcher)
    dim = matcher.config.dim
    own_m = np.array([own.get(int(k), np.zeros(dim)) for k in keys])
    has_own = np.array([int(k) in own for k in keys])
    wide_keys, wide_m = wide_matrix(wide)
    idx_own, at_own = vote_index(keys, kp_own, cfg)
    wkeys = np.array(sorted(kp_wide), np.intp)
    idx_wide, at_w = vote_index(wkeys, kp_wide, cfg)
    wide_pos = np.searchsorted(keys, wkeys[at_w])  # position in keys of each wide row
    out: dict[str, list] = {}
    clock = 0.0
    skipped = 0
    for q in data["queries"]:
        k, rows, near = q["k"], q["rows"], q["near"]
        if k not in own:
            skipped += 1
            continue
        d_own = np.linalg.norm(own_m[rows] - own[k], axis=1)
        d_own[~has_own[rows]] = np.inf
        d_wide = wide_distance(wide, wide_keys, wide_m, keys[rows], q["asked"])
        default = interleaved_order([d_own, d_wide])[0]
        pos_rows = np.full(len(keys), -1)
        pos_rows[rows] = np.arange(len(rows))
        v_own = np.full(len(rows), -np.inf)
        v_wide = np.full(len(rows), -np.inf)
        if k in kp_own:
            t0 = time.process_time()
            p, o, lab = kp_own[k]
            lab = lab % cfg.n_labels
            s = idx_own.scores(p, o, lab)
            sw = idx_wide.scores(p, o, lab) if len(idx_wide) else np.zeros(0)
            clock += time.process_time() - t0
            asked = q["asked"]
            if query_wide and asked in kp_wide:  # the query's wide view votes too
                pw, ow, lw = kp_wide[asked]
                s = np.maximum(s, idx_own.scores(pw, ow, lw % cfg.n_labels))
                if len(idx_wide):
                    sw = np.maximum(sw, idx_wide.scores(pw, ow, lw % cfg.n_labels))
            p = pos_rows[at_own]
            ok = p >= 0
            v_own[p[ok]] = s[ok]
            if len(sw):
                p = pos_rows[wide_pos]
                ok = p >= 0
                v_wide[p[ok]] = sw[ok]
        # distances for the interleave: negative votes; zero votes do not rank
        dv_own = np.where(v_own > 0, -v_own, np.inf)
        dv_wide = np.where(v_wide > 0, -v_wide, np.inf)
        rank_default = np.empty(len(rows))
        rank_default[default] = np.arange(len(rows))
        vote_order = interleaved_order([dv_own, dv_wide])[0]
        n_voted = int(np.isfinite(np.minimum(dv_own, dv_wide)).sum())
        voted = np.zeros(len(rows), bool)
        voted[vote_order[:n_voted]] = True
        vote_full = np.concatenate([vote_order[:n_voted], default[~voted[default]]]
                                   ).astype(np.intp)
        orders = {"default": default, "vote": vote_full,
                  "vote own": np.lexsort((rank_default, -np.where(v_own > 0, v_own, 0)))}
        own_voted = np.flatnonzero(v_own > 0)
        own_vote = own_voted[np.lexsort((rank_default[own_voted], -v_own[own_voted]))]
        for n in splits:
            orders[f"fused {n}"] = fused(default, vote_full[:n_voted], n)
            orders[f"fused own {n}"] = fused(default, own_vote, n)
        orders["interleave3"] = interleaved_order([d_own, d_wide,
                                                   np.minimum(dv_own, dv_wide)])[0]
        for name, order in orders.items():
            out.setdefault(name, []).append(first_hit(order, near))
        out.setdefault("either@10", []).append(
            0 if min(out["default"][-1], out["vote"][-1]) < 10 else BIG)
    n_q = max(1, sum(1 for q in data["queries"] if q["k"] in kp_own))
    res = {n: np.array(v + [BIG] * skipped) for n, v in out.items()}
    res["_ms"] = np.array([1000 * clock / n_q])
    return res


def scaling(kp: dict, cfg: PairVoteConfig, sizes: list[int], n_queries: int = 50
            ) -> dict[int, float]:
    """Best-of-3 CPU ms of one `PairVoteIndex.scores` query at each database size, the
    database made of the log's keyframes' keypoints cycled to the size (as many
    postings per key as a log of that many keyframes like these), the index built
    before timing; queries: `n_queries` keyframes evenly spread."""
    items = list(kp.values())
    qs = [items[i] for i in np.linspace(0, len(items) - 1, n_queries).astype(int)]
    out = {}
    for size in sizes:
        index = PairVoteIndex(cfg)
        for i in range(size):
            p, o, lab = items[i % len(items)]
            index.add(p, o, lab % cfg.n_labels)
        index.scores(*qs[0][:2], qs[0][2] % cfg.n_labels)  # builds the sorted index
        best = np.inf
        for _ in range(3):
            t0 = time.process_time()
            for p, o, lab in qs:
                index.scores(p, o, lab % cfg.n_labels)
            best = min(best, (time.process_time() - t0) / len(qs))
        out[size] = 1000 * best
    return out


def report(data: dict, name: str, res: dict) -> None:
    qs = data["queries"]
    dist = np.array([q["dist"] for q in qs])
    ov = np.array([q["overlap"] for q in qs])
    print(f"  {name}: vote {res['_ms'][0]:.2f} ms per query (own + wide index, CPU)")
    for order, r in res.items():
        if order.startswith("_"):
            continue
        print(f"    {order:12s} " + " ".join(f"@{k} {np.mean(r < k):.3f}" for k in KS)
              + f" | @10 by distance {_binned(r, dist, DISTANCE_BINS)}"
              + f" | by overlap {_binned(r, ov, OVERLAP_BINS)}", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("logs", nargs="+", help="LOG or LOG:RELATIONS")
    ap.add_argument("--cache", type=Path, required=True)
    ap.add_argument("--variant", action="append", default=[])
    ap.add_argument("--split", default="5,7,8")
    ap.add_argument("--step", type=float, help="keypoints: boundary step [m]")
    ap.add_argument("--max-range", type=float, help="keypoints: farthest kept [m]")
    ap.add_argument("--max-features", type=int, default=40)
    ap.add_argument("--repeat-only", action="store_true")
    ap.add_argument("--variants-only", action="store_true",
                    help="skip the default PairVoteConfig")
    ap.add_argument("--query-wide", action="store_true",
                    help="the query's wide view's keypoints vote too (the larger score)")
    ap.add_argument("--scaling", default="", help="database sizes to time, e.g. 1000,10000")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    args = ap.parse_args()
    config = apply_overrides(PipelineConfig(), args.set)
    variants = {"default": PairVoteConfig()}
    for v in args.variant:
        name, _, rest = v.partition(":")
        kv = {a: b for a, b in (item.split("=") for item in rest.split(",") if item)}
        ints = ("neighbours", "n_labels", "length_slack")
        over = {a: (b == "1") if a == "normalise" else int(b) if a in ints else float(b)
                for a, b in kv.items()}
        variants[name] = replace(PairVoteConfig(), **over)
    if args.variants_only and args.variant:
        del variants["default"]
    splits = [int(s) for s in args.split.split(",") if s]
    for spec in args.logs:
        data = mapped(spec, config, args.cache)
        t = time.perf_counter()
        kp_own = keypoints(data["own"], config, args.step, args.max_range, args.max_features)
        kp_wide = keypoints(data["wide"], config, args.step, args.max_range,
                            args.max_features)
        print(f"{data['name']}: {len(data['keys'])} keyframes, {len(data['queries'])} revisits;"
              f" keypoints {time.perf_counter() - t:.0f} s, median "
              f"{np.median([len(v[0]) for v in kp_own.values()]):.0f} per keyframe; "
              "repeatable at 0.5 m (median share, count) %.2f, %.0f"
              % repeatability(data, kp_own), flush=True)
        if args.repeat_only:
            continue
        for vname, cfg in variants.items():
            if args.scaling:
                ms = scaling(kp_own, cfg, [int(x) for x in args.scaling.split(",")])
                print(f"  {vname}: CPU ms per vote query (own index only) at size "
                      + ", ".join(f"{n}: {t:.2f}" for n, t in ms.items()), flush=True)
                continue
            report(data, vname, run_log(data, config, kp_own, kp_wide, cfg, splits,
                                        args.query_wide))


if __name__ == "__main__":
    main()
