"""Benchmark: the near+far FFT stage beside the pair histogram in the prefilter row.

Run from the repository root::

    python benchmarks/fft_near_prefilter.py LOG[:RELATIONS] ... --cache DIR
        [--weights 0,0.25,0.5,1] [--near-radius 6] [--far-weight 0.05]

Reads (or makes) the cache of `benchmarks/prefilter_misses.py` (every keyframe's own
and wide virtual scans and the revisit queries of a log mapped as ``loopclosure bench
loops`` maps it), describes every scan by the pair histogram and by the ``fft-near``
stage (`loopclosure.place_config.stage_matcher`), and orders each revisit query's
eligible keyframes as ``bench loops``'s prefilter row does (the own and the wide view
interleaved by rank, `evaluation.loop_bench_queries.interleaved_order`), each view by

    p(j) = d_pairs(q, j) / scale_pairs + w d_near(q, j) / scale_near     (unitless)

(scale: the median distance of 256 random pairs of the view's keyframes, seed 0),
for every weight w of ``--weights`` (w = 0: the default prefilter), and by the two
stages' lists interleaved by rank (``rank``: four lists, the first 4K rows hold every
list's K best).  Printed per log and variant: recall@1/10/50 of the revisit queries.
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

from prefilter_misses import mapped, polygons_of  # noqa: E402

from evaluation.loop_bench_queries import interleaved_order  # noqa: E402
from loopclosure.place_config import NEAR_FFT, PlaceDatabaseConfig, stage_matcher  # noqa: E402
from slam.config import PipelineConfig  # noqa: E402

KS = (1, 10, 50)


def describe(scans: dict, config: PipelineConfig, stage: str, db: PlaceDatabaseConfig
             ) -> dict[int, np.ndarray]:
    """The prefilter vector of `stage` of every scan that makes a polygon."""
    matcher = stage_matcher(stage, db)
    out = {}
    for k, poly in polygons_of(scans, config).items():
        d = matcher.describe(poly)
        out[k] = np.asarray(getattr(d, "amplitudes", d), float)
    return out


def matrix(vectors: dict, keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(M, D)`` vectors of `keys` (zeros where none) and which keys have one."""
    dim = len(next(iter(vectors.values())))
    has = np.array([int(k) in vectors for k in keys])
    return np.array([vectors.get(int(k), np.zeros(dim)) for k in keys]), has


def scale(m: np.ndarray, has: np.ndarray) -> float:
    """Median distance of 256 random pairs of the rows that have a vector."""
    rows = np.flatnonzero(has)
    rng = np.random.default_rng(0)
    a, b = rng.choice(rows, 256), rng.choice(rows, 256)
    keep = a != b
    return float(np.median(np.linalg.norm(m[a[keep]] - m[b[keep]], axis=1)))


def distances(views: dict, keys: np.ndarray, q: dict) -> dict[tuple[str, str], np.ndarray]:
    """Normalised distance of query `q` to its eligible rows, per (view, stage): `views`
    maps a view to its keys and, per stage, (vectors, has-vector mask, scale)."""
    rows = q["rows"]
    out = {}
    for view, (vk, per) in views.items():
        asked = q["k"] if view == "own" else q["asked"]
        for stage, (m, has, s) in per.items():
            d = np.full(len(rows), np.inf)
            qi = np.searchsorted(vk, asked) if asked is not None else -1
            if 0 <= qi < len(vk) and vk[qi] == asked and has[qi]:
                at = np.searchsorted(vk, keys[rows])
                ok = (at < len(vk)) & (vk[np.minimum(at, len(vk) - 1)] == keys[rows])
                ok[ok] &= has[at[ok]]
                d[ok] = np.linalg.norm(m[at[ok]] - m[qi], axis=1) / s
            out[view, stage] = d
    return out


def first_hits(data: dict, config: PipelineConfig, db: PlaceDatabaseConfig,
               weights: list[float]) -> dict[str, np.ndarray]:
    """Per variant, the 0-based rank of each revisit query's first true place."""
    keys = data["keys"]
    views = {}
    for view in ("own", "wide"):
        vk = keys if view == "own" else np.array(sorted(data["wide"]), np.intp)
        per = {}
        for stage in ("pairs", NEAR_FFT):
            m, has = matrix(describe(data[view], config, stage, db), vk)
            per[stage] = (m, has, scale(m, has) if has.sum() > 1 else 1.0)
        views[view] = (vk, per)
    big = 10**9
    out: dict[str, list[int]] = {}
    for q in data["queries"]:
        near = q["near"]
        dist = distances(views, keys, q)
        with np.errstate(invalid="ignore"):  # 0 x inf: a view without the keyframe
            variants = {f"w={w:g}": [dist[v, "pairs"] + w * dist[v, NEAR_FFT]
                                     for v in ("own", "wide")] for w in weights}
        variants["near alone"] = [dist[v, NEAR_FFT] for v in ("own", "wide")]
        variants["rank"] = [dist[v, s] for v in ("own", "wide") for s in ("pairs", NEAR_FFT)]
        for name, per_view in variants.items():
            per_view = [np.where(np.isnan(d), np.inf, d) for d in per_view]
            order = interleaved_order(per_view)[0]
            finite = np.isfinite(np.min(np.vstack(per_view), axis=0))[order]
            hit = np.flatnonzero(near[order] & finite)
            out.setdefault(name, []).append(int(hit[0]) if len(hit) else big)
    return {n: np.array(v) for n, v in out.items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("logs", nargs="+", help="LOG or LOG:RELATIONS")
    ap.add_argument("--cache", type=Path, required=True)
    ap.add_argument("--weights", default="0,0.25,0.5,1")
    ap.add_argument("--near-radius", type=float, default=6.0)
    ap.add_argument("--far-weight", type=float, default=0.05)
    args = ap.parse_args()
    config = PipelineConfig()
    db = PlaceDatabaseConfig(fft_near_radius=args.near_radius, fft_far_weight=args.far_weight)
    weights = [float(w) for w in args.weights.split(",")]
    for spec in args.logs:
        t = time.perf_counter()
        data = mapped(spec, config, args.cache)
        hits = first_hits(data, config, db, weights)
        print(f"{data['name']}: {len(data['queries'])} revisits "
              f"({time.perf_counter() - t:.0f} s)", flush=True)
        for name, r in hits.items():
            rec = "/".join(f"{np.mean(r < k):.3f}" for k in KS)
            print(f"  {name:12s} recall@1/10/50 {rec}", flush=True)


if __name__ == "__main__":
    main()
