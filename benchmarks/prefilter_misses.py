"""Benchmark: what the prefilter's misses are, and the recall@K of descriptor variants.

Run from the repository root::

    python benchmarks/prefilter_misses.py LOG[:RELATIONS] ... --cache DIR
        [--variant NAME:KEY=VALUE,KEY=VALUE ...] [--misses CSV]

Each log is mapped as ``loopclosure bench loops`` maps it (`evaluation.loop_bench`;
a corrected log takes its logged poses as the reference and the drifting odometry of
seed 0), once: DIR keeps every keyframe's 360-degree virtual scan (its own view as
the loop detector described it, and its wide view, re-rendered from the map of its
last ``loops.wide_keyframes`` keyframes, which the loop searches being off leaves as
it was), the revisit queries and, per query, its nearest true place's distance,
heading difference and submap overlap (`evaluation.loop_bench_misses`).

For the default pair histogram and each variant (``NAME:`` then
`PairHistogramConfig` fields, e.g. ``r8:max_range=8.0``) every keyframe's two views
are described again and each revisit query orders the eligible stored keyframes as
``bench loops``'s prefilter row does (the own and the wide view interleaved by rank,
`evaluation.loop_bench_queries.interleaved_order`).  Further variant fields:
``cloud_radius=R`` (the histogram of the submap's points within R [m], no virtual
scan, `cloud_vector`; with ``combo_weight=W`` concatenated to the default's, weight W),
``union_radius=R`` (the surfaces visible from the origin or from free viewpoints on
a ring of R, `union_vector`; ``union_count`` viewpoints), ``vp_radius=R`` (offset
viewpoints of `loopclosure.viewpoints`, ``union_count`` of them, on the stored side,
``vp_mode=0``, the query's, 1, or both, 2; ``vp_margin`` multiplies their
distances; ``vp_min_area=A`` leaves out a viewpoint whose polygon's area is below A
times the keyframe's own polygon's; ``vp_mode=3``: no minimum, every keyframe's own
vector replaced by the mean of it, weight ``vp_self`` (1), and its viewpoints'
(`smoothed`, unit length unless ``vp_unit=0``; ``vp_wide=1``: the wide view's too,
from viewpoints of its wide map)).  Printed per variant: recall@1/10/50, recall@10
per bin of distance, heading difference and overlap, the recall of each view's K best together (2K
places, as the loop detector verifies), and of other orders of the two views
(`combined_orders`); for the default, the misses (no true place among the first 10)
split by where the true place ranks in each view alone.  ``--misses CSV`` writes one row per miss of
the default: query, nearest true place, its distance [m], heading difference
[deg], overlap, and the first true place's rank in the own view, the wide view and
the interleaved order (0-based).
"""

from __future__ import annotations

import argparse
import csv
import pickle
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from evaluation.loop_bench import mapped_input  # noqa: E402
from evaluation.loop_bench_input import LoopSource  # noqa: E402
from evaluation.loop_bench_misses import (  # noqa: E402
    DISTANCE_BINS,
    HEADING_BINS,
    OVERLAP_BINS,
    nearest_place,
    revisit_queries,
    submap_overlap,
)
from evaluation.loop_bench_queries import interleaved_order  # noqa: E402
from loopclosure.matchers.pair_histogram import (  # noqa: E402
    PairHistogramConfig,
    PairHistogramMatcher,
)
from loopclosure.polygon import DegeneratePolygonError, polygon_from_scan  # noqa: E402
from loopclosure.virtual_scan import virtual_scan  # noqa: E402
from slam.config import PipelineConfig  # noqa: E402
from slam.config_io import apply_overrides  # noqa: E402

KS = (1, 10, 50)
BIG = 10**9


def mapped(spec: str, config: PipelineConfig, cache: Path) -> dict:
    """The per-log data of the study (module docstring), from `cache` if there."""
    log, _, relations = spec.partition(":")
    name = Path(log).name.split(".")[0]
    path = cache / f"{name}.pkl"
    if path.exists():
        with open(path, "rb") as f:
            return pickle.load(f)
    source = LoopSource(str(Path(log).resolve()),
                        relations=str(Path(relations).resolve()) if relations else None,
                        reference_from_log=not relations,
                        odometry_noise=None if relations else 0, folder=str(Path.cwd()))
    mapper, _, ref = mapped_input(source, config)
    det = mapper.detector
    db = det.database
    loops = config.loops
    keys = np.array(db.keys, dtype=np.intp)
    own = {int(k): det.place_scan(int(k)) for k in keys}
    wide_keys = sorted({int(w) for k in keys if (w := det.wide_key(int(k))) is not None})
    trailing = det._trailing_map
    wide, wide_maps = {}, {}
    for w in wide_keys:
        pts = np.asarray(trailing(w, loops.wide_keyframes), float).reshape(-1, 2)
        wide[w] = virtual_scan(pts, loops.virtual_beams, loops.virtual_range)
        wide_maps[w] = pts.astype(np.float32)
    queries = []
    for k, rows, _, near in revisit_queries(det, ref):
        nk, dist, dth = nearest_place(ref, k, keys[rows[near]])
        q_pts = _described_submap(mapper, k)
        overlap = submap_overlap(q_pts, mapper.submap(nk), ref[k], ref[nk])
        queries.append(dict(k=int(k), rows=rows, near=near, asked=det.wide_key(int(k)),
                            nearest=int(nk), dist=dist, dtheta=dth, overlap=overlap))
    submaps = {int(k): _described_submap(mapper, int(k)).astype(np.float32) for k in keys}
    data = dict(name=name, keys=keys, own=own, wide=wide, queries=queries, ref=ref,
                submaps=submaps, wide_maps=wide_maps)
    cache.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as f:
        pickle.dump(data, f)
    return data


def _described_submap(mapper, key: int) -> np.ndarray:
    """Keyframe `key`'s submap as it was when it was described (its past neighbours)."""
    n = mapper.config.submap_neighbours()
    return mapper._local_points(key, max(mapper._span(key)[0], key - n), key)


def polygons_of(scans: dict, config: PipelineConfig) -> dict:
    """The polygon of every scan that makes one (`config.loops.polygon`)."""
    out = {}
    for k, scan in scans.items():
        try:
            out[k] = polygon_from_scan(scan, config.loops.polygon)
        except DegeneratePolygonError:
            continue
    return out


def describe_all(scans: dict, config: PipelineConfig, matcher: PairHistogramMatcher
                 ) -> dict[int, np.ndarray]:
    """Pair-histogram vector of every scan that makes a polygon."""
    return {k: np.asarray(matcher.describe(poly), float)
            for k, poly in polygons_of(scans, config).items()}


def cloud_vector(pts: np.ndarray, radius: float, cfg: PairHistogramConfig,
                 neighbours: int = 7) -> np.ndarray | None:
    """Pair histogram of a point cloud without a viewpoint: the points within
    `radius` [m] of the origin, on a `cfg.step` voxel grid, each with the normal of
    its `neighbours` nearest cells (smallest principal axis) and weight `cfg.step`."""
    from scipy.spatial import cKDTree

    from loopclosure.fast_icp import voxel_downsample_fast

    p = np.asarray(pts, float).reshape(-1, 2)
    p = p[np.hypot(p[:, 0], p[:, 1]) < radius]
    if len(p) < neighbours:
        return None
    v = np.asarray(voxel_downsample_fast(p, cfg.step), float)
    if len(v) < neighbours:
        return None
    _, idx = cKDTree(v).query(v, k=neighbours)
    nb = v[idx] - v[idx].mean(axis=1, keepdims=True)  # (n, k, 2)
    cxx, cyy = (nb[..., 0] ** 2).sum(1), (nb[..., 1] ** 2).sum(1)
    cxy = (nb[..., 0] * nb[..., 1]).sum(1)
    theta = 0.5 * np.arctan2(2 * cxy, cxx - cyy)  # the main axis
    nrm = np.column_stack([-np.sin(theta), np.cos(theta)])
    return _root_histogram(v, nrm, np.full(len(v), cfg.step), cfg)


def union_vector(pts: np.ndarray, own_scan, radius: float, count: int,
                 cfg: PairHistogramConfig, polygon_cfg) -> np.ndarray | None:
    """Pair histogram of the surfaces visible from the origin or from any free
    viewpoint on a ring of `radius` [m] (`loopclosure.viewpoints`): every view's
    surface samples in the keyframe frame: the origin's all, another view's those
    farther than `cfg.step` from every sample already taken."""
    from loopclosure.matchers.pair_histogram import surface_samples
    from loopclosure.viewpoints import ViewpointConfig, viewpoint_scans

    scans = [own_scan]
    if radius > 0 and pts is not None:
        scans += viewpoint_scans(pts, own_scan, ViewpointConfig(radii=(radius,), count=count))
    P, N, W = [], [], []
    for sc in scans:
        try:
            poly = polygon_from_scan(sc, polygon_cfg)
        except DegeneratePolygonError:
            continue
        o = np.asarray(sc.odom[:2], float) if sc.odom is not None else np.zeros(2)
        p, n, w = surface_samples(np.asarray(poly.vertices, float), step=cfg.step,
                                  max_edge=cfg.max_edge, max_range=cfg.max_range)
        P.append(p + o)
        N.append(n)
        W.append(w)
    if not P:
        return None
    from scipy.spatial import cKDTree

    p, n, w = P[0], N[0], W[0]
    for pe, ne, we in zip(P[1:], N[1:], W[1:], strict=True):
        if not len(pe):
            continue
        new = (cKDTree(p).query(pe, distance_upper_bound=cfg.step)[0] > cfg.step
               if len(p) else np.ones(len(pe), bool))
        p, n, w = np.vstack([p, pe[new]]), np.vstack([n, ne[new]]), np.concatenate([w, we[new]])
    return _root_histogram(p, n, w, cfg)


def _root_histogram(p: np.ndarray, n: np.ndarray, w: np.ndarray,
                    cfg: PairHistogramConfig) -> np.ndarray | None:
    """Square root of the normalised pair histogram of samples `p` [m], unit normals
    `n` and lengths `w` [m] (every stride-th sample, weight times stride, beyond
    `cfg.max_samples`); None for an empty histogram."""
    from loopclosure.matchers.pair_kernel import pair_histogram_compiled

    if len(p) > cfg.max_samples:
        stride = -(-len(p) // cfg.max_samples)
        p, n, w = p[::stride], n[::stride], w[::stride] * stride
    hist = pair_histogram_compiled(p, n, w, max_distance=cfg.max_distance,
                                   n_distance=cfg.n_distance, n_angle=cfg.n_angle).ravel()
    total = hist.sum()
    return np.sqrt(hist / total) if total > 0 else None


def describe_unions(scans: dict, clouds: dict, radius: float, count: int,
                    cfg: PairHistogramConfig, polygon_cfg) -> dict:
    out = {}
    for k, sc in scans.items():
        d = union_vector(clouds.get(k), sc, radius, count, cfg, polygon_cfg)
        if d is not None:
            out[k] = d
    return out


def describe_clouds(clouds: dict, radius: float, cfg: PairHistogramConfig) -> dict:
    out = {}
    for k, pts in clouds.items():
        d = cloud_vector(pts, radius, cfg)
        if d is not None:
            out[k] = d
    return out


def combined_orders(d_own: np.ndarray, d_wide: np.ndarray) -> dict[str, np.ndarray]:
    """Other ways of ordering the rows of two views than the interleave by rank:
    ``rrf`` (reciprocal rank fusion, constant 60), ``rank sum`` (Borda; a row one
    view lacks takes that view's last rank), ``ratio min`` (the smaller of each
    view's distance over that view's median distance for this query), ``ratio sum``."""
    per = np.vstack([d_own, d_wide])
    n = per.shape[1]
    ranks = np.full(per.shape, float(n))
    ratio = np.full(per.shape, np.inf)
    for v, d in enumerate(per):
        fin = np.flatnonzero(np.isfinite(d))
        if len(fin):
            ranks[v, fin[np.argsort(d[fin], kind="stable")]] = np.arange(len(fin))
            ratio[v, fin] = d[fin] / max(np.median(d[fin]), 1e-12)
    has_wide = np.isfinite(d_wide).any()
    if not has_wide:
        ranks, ratio = ranks[:1], ratio[:1]
    rrf = -(1.0 / (60.0 + ranks)).sum(axis=0)
    rsum = ranks.sum(axis=0)
    rmin = ratio.min(axis=0)
    rs = np.where(np.isfinite(ratio), ratio, 2.0).sum(axis=0)
    return {"rrf": np.argsort(rrf, kind="stable"), "rank sum": np.argsort(rsum, kind="stable"),
            "ratio min": np.argsort(rmin, kind="stable"),
            "ratio sum": np.argsort(rs, kind="stable")}


def viewpoint_stack(data: dict, config: PipelineConfig, matcher: PairHistogramMatcher,
                    radius: float, count: int, min_area: float = 0.0
                    ) -> tuple[np.ndarray, np.ndarray]:
    """``(V, D)`` pair-histogram vectors of every keyframe's free offset viewpoints
    (`loopclosure.viewpoints`, one ring) and the row of `data["keys"]` of each; a
    viewpoint whose polygon's area is below `min_area` times the keyframe's own
    polygon's is left out."""
    from loopclosure.viewpoints import ViewpointConfig, viewpoint_scans

    vp = ViewpointConfig(radii=(radius,), count=count)
    vecs, owner = [], []
    for row, k in enumerate(data["keys"].tolist()):
        own_area = 0.0
        if min_area > 0:
            try:
                own_area = polygon_from_scan(data["own"][k], config.loops.polygon).area
            except DegeneratePolygonError:
                continue
        for sc in viewpoint_scans(data["submaps"][k], data["own"][k], vp):
            try:
                poly = polygon_from_scan(sc, config.loops.polygon)
            except DegeneratePolygonError:
                continue
            if poly.area < min_area * own_area:
                continue
            vecs.append(np.asarray(matcher.describe(poly), float))
            owner.append(row)
    return np.array(vecs).reshape(-1, matcher.config.dim), np.array(owner, np.intp)


def smoothed(own: dict, keys: np.ndarray, views: tuple[np.ndarray, np.ndarray],
             self_weight: float = 1.0, unit: bool = True) -> dict[int, np.ndarray]:
    """Every keyframe's own vector replaced by the weighted mean of it (weight
    `self_weight`) and its viewpoints' vectors (`viewpoint_stack`, weight 1 each),
    rescaled to unit length when `unit`: one vector per keyframe that varies less
    with the viewpoint's translation."""
    vecs, owner = views
    out = {}
    for row, k in enumerate(keys.tolist()):
        if k not in own:
            continue
        mine = vecs[owner == row]
        v = (self_weight * own[k] + mine.sum(axis=0)) / (self_weight + len(mine))
        n = np.linalg.norm(v)
        out[k] = v / n if unit and n > 0 else v
    return out


def wide_matrix(wide: dict) -> tuple[np.ndarray, np.ndarray | None]:
    """The wide view's keys (sorted) and their vectors stacked row by row (None: none)."""
    wide_keys = np.array(sorted(wide), np.intp)
    return wide_keys, (np.array([wide[int(k)] for k in wide_keys]) if len(wide_keys)
                       else None)


def wide_distance(wide: dict, wide_keys: np.ndarray, wide_m: np.ndarray | None,
                  row_keys: np.ndarray, asked: int | None) -> np.ndarray:
    """Distance of the query's wide vector ``wide[asked]`` to every sorted `row_keys`
    keyframe's (`wide_matrix`); ``inf`` where either has none."""
    other = np.full(len(row_keys), np.inf)
    if wide_m is not None and asked is not None and asked in wide:
        w_rows = np.flatnonzero(np.isin(wide_keys, row_keys))
        at = np.searchsorted(row_keys, wide_keys[w_rows])
        other[at] = np.linalg.norm(wide_m[w_rows] - wide[asked], axis=1)
    return other


def _min_over(q: np.ndarray, vecs: np.ndarray, owner: np.ndarray, n: int) -> np.ndarray:
    best = np.full(n, np.inf)
    if len(vecs):
        np.minimum.at(best, owner, np.linalg.norm(vecs - q, axis=1))
    return best


def ranks(data: dict, own: dict, wide: dict, views: tuple | None = None,
          mode: str = "stored", margin: float = 1.0) -> dict[str, np.ndarray]:
    """Per query: 0-based rank of the first true place in the own view, the wide
    view and their interleaved order (`BIG`: none).  `views` (`viewpoint_stack`):
    the own view's distance is the smallest over the stored keyframe's viewpoints
    (`mode` "stored"), over the query's (``query``), or over both (``both``); a
    viewpoint's distance is multiplied by `margin` first."""
    keys = data["keys"]
    dim = len(next(iter(own.values())))
    own_m = np.array([own.get(int(k), np.zeros(dim)) for k in keys])
    has_own = np.array([int(k) in own for k in keys])
    wide_keys, wide_m = wide_matrix(wide)
    out = {"own": [], "wide": [], "both": []}
    for q in data["queries"]:
        k, rows, near = q["k"], q["rows"], q["near"]
        if k not in own:
            for v in out.values():
                v.append(BIG)
            continue
        d_own = np.linalg.norm(own_m[rows] - own[k], axis=1)
        if views is not None:
            vecs, owner = views
            qrow = int(np.searchsorted(keys, k))
            if mode in ("stored", "both"):
                d_own = np.minimum(d_own, margin * _min_over(own[k], vecs, owner,
                                                             len(keys))[rows])
            if mode in ("query", "both"):
                for qv in vecs[owner == qrow]:
                    d_own = np.minimum(d_own, margin * np.linalg.norm(own_m[rows] - qv, axis=1))
                    if mode == "both":
                        d_own = np.minimum(d_own, margin * _min_over(qv, vecs, owner,
                                                                     len(keys))[rows])
        d_own[~has_own[rows]] = np.inf
        other = wide_distance(wide, wide_keys, wide_m, keys[rows], q["asked"])
        for name, per in (("own", [d_own]), ("wide", [other]), ("both", [d_own, other])):
            order = interleaved_order(per)[0]
            finite = np.isfinite(np.min(np.vstack(per), axis=0))[order]
            hit = np.flatnonzero(near[order] & finite)
            out[name].append(int(hit[0]) if len(hit) else BIG)
        for name, order in combined_orders(d_own, other).items():
            hit = np.flatnonzero(near[order])
            out.setdefault(name, []).append(int(hit[0]) if len(hit) else BIG)
    return {n: np.array(v) for n, v in out.items()}


def _binned(r: np.ndarray, values: np.ndarray, edges) -> str:
    parts = []
    for i in range(len(edges) - 1):
        lo, hi = edges[i], edges[i + 1]
        sel = (values >= lo) & ((values <= hi) if i == len(edges) - 2 else (values < hi))
        if sel.any():
            parts.append(f"{lo:g}-{hi:g} {np.mean(r[sel] < 10):.3f} ({int(sel.sum())})")
    return ", ".join(parts)


def report(name: str, data: dict, r: dict[str, np.ndarray]) -> None:
    qs = data["queries"]
    dist = np.array([q["dist"] for q in qs])
    dth = np.array([q["dtheta"] for q in qs])
    ov = np.array([q["overlap"] for q in qs])
    both = r["both"]
    print(f"  {name}: recall@K " + " ".join(f"@{k} {np.mean(both < k):.3f}" for k in KS)
          + "  (own alone @10 " f"{np.mean(r['own'] < 10):.3f}, wide alone @10 "
          f"{np.mean(r['wide'] < 10):.3f})", flush=True)
    print(f"    by distance [m]: {_binned(both, dist, DISTANCE_BINS)}")
    print(f"    by heading [deg]: {_binned(both, dth, HEADING_BINS)}")
    print(f"    by overlap: {_binned(both, ov, OVERLAP_BINS)}")
    per_view = np.minimum(r["own"], r["wide"])
    print("    each view's K best (2K places): " + " ".join(
        f"@{k} {np.mean(per_view < k):.3f}" for k in KS))
    for name in ("rrf", "rank sum", "ratio min", "ratio sum"):
        if name in r:
            print(f"    views combined by {name}: " + " ".join(
                f"@{k} {np.mean(r[name] < k):.3f}" for k in KS))


def miss_table(data: dict, r: dict[str, np.ndarray]) -> None:
    """Where the misses' true places rank in each view, and their geometry."""
    qs = data["queries"]
    miss = r["both"] >= 10
    n = int(miss.sum())
    print(f"  misses: {n} of {len(qs)} revisits")
    if not n:
        return
    own, wide = r["own"][miss], r["wide"][miss]
    for label, sel in (("own 10-49", (own >= 10) & (own < 50)),
                       ("own 50-199", (own >= 50) & (own < 200)),
                       ("own >= 200 or none", own >= 200),
                       ("wide 10-49", (wide >= 10) & (wide < 50)),
                       ("wide >= 50 or none", wide >= 50),
                       ("both views >= 50", (own >= 50) & (wide >= 50))):
        print(f"    true place {label}: {int(sel.sum())} ({sel.mean():.2f})")
    dist = np.array([q["dist"] for q in qs])[miss]
    dth = np.array([q["dtheta"] for q in qs])[miss]
    ov = np.array([q["overlap"] for q in qs])[miss]
    print(f"    nearest true place: distance median {np.median(dist):.2f} m, >1 m "
          f"{np.mean(dist > 1):.2f}; heading >90 deg {np.mean(dth > 90):.2f}; overlap "
          f"median {np.nanmedian(ov):.2f}, <0.5 {np.mean(ov < 0.5):.2f}, >=0.7 "
          f"{np.mean(ov >= 0.7):.2f}")
    near_hi = (dist <= 1.0) & (ov >= 0.7)
    print(f"    within 1 m and overlap >= 0.7 (the descriptor's fault): {int(near_hi.sum())}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("logs", nargs="+", help="LOG or LOG:RELATIONS")
    ap.add_argument("--cache", type=Path, required=True)
    ap.add_argument("--variant", action="append", default=[],
                    help="NAME:FIELD=VALUE,... of PairHistogramConfig (repeatable)")
    ap.add_argument("--misses", type=Path, help="CSV of the default's misses")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    args = ap.parse_args()
    config = apply_overrides(PipelineConfig(), args.set)
    variants = {"default": {}}
    for v in args.variant:
        name, _, rest = v.partition(":")
        kv = dict(item.split("=") for item in rest.split(",") if item)
        variants[name] = {k: float(x) if k in ("cloud_radius", "union_radius", "union_count",
                                           "combo_weight", "vp_radius", "vp_mode",
                                           "vp_margin", "vp_min_area", "vp_self", "vp_unit",
                                           "vp_wide") else
                          type(getattr(PairHistogramConfig(), k))(float(x) if "." in x
                                                                  else int(x))
                          for k, x in kv.items()}
    rows = []
    for spec in args.logs:
        t = time.perf_counter()
        data = mapped(spec, config, args.cache)
        print(f"{data['name']}: {len(data['keys'])} keyframes, {len(data['queries'])} "
              f"revisits, {len(data['wide'])} wide views ({time.perf_counter() - t:.0f} s)",
              flush=True)
        for vname, over in variants.items():
            over = dict(over)
            radius = over.pop("cloud_radius", None)
            union = over.pop("union_radius", None)
            combo = over.pop("combo_weight", None)
            count = int(over.pop("union_count", 4))
            vp = over.pop("vp_radius", None)
            vp_mode = {0: "stored", 1: "query", 2: "both", 3: "smooth"}[int(over.pop("vp_mode", 0))]
            margin = float(over.pop("vp_margin", 1.0))
            min_area = float(over.pop("vp_min_area", 0.0))
            vp_self = float(over.pop("vp_self", 1.0))
            vp_unit = bool(over.pop("vp_unit", 1.0))
            vp_wide = bool(over.pop("vp_wide", 0.0))
            matcher = PairHistogramMatcher(replace(PairHistogramConfig(), **over))
            t = time.perf_counter()
            views = None
            if vp is not None:
                views = viewpoint_stack(data, config, matcher, vp, count, min_area)
            if union is not None:
                own = describe_unions(data["own"], data["submaps"], union, count,
                                      matcher.config, config.loops.polygon)
                wide = describe_unions(data["wide"], data["wide_maps"], union, count,
                                       matcher.config, config.loops.polygon)
            elif radius is None:
                own = describe_all(data["own"], config, matcher)
                wide = describe_all(data["wide"], config, matcher)
            else:
                own = describe_clouds(data["submaps"], radius, matcher.config)
                wide = describe_clouds(data["wide_maps"], radius, matcher.config)
                if combo is not None:  # both descriptors, the cloud's weighted
                    own_s = describe_all(data["own"], config, matcher)
                    wide_s = describe_all(data["wide"], config, matcher)
                    z = np.zeros(matcher.config.dim)
                    own = {k: np.concatenate([v, combo * own.get(k, z)])
                           for k, v in own_s.items()}
                    wide = {k: np.concatenate([v, combo * wide.get(k, z)])
                            for k, v in wide_s.items()}
            if vp is not None and vp_mode == "smooth":
                own = smoothed(own, data["keys"], views, vp_self, vp_unit)
                if vp_wide:
                    wkeys = np.array(sorted(wide), np.intp)
                    wdata = dict(keys=wkeys, submaps=data["wide_maps"], own=data["wide"])
                    wide = smoothed(wide, wkeys, viewpoint_stack(wdata, config, matcher, vp,
                                                                 count, min_area),
                                    vp_self, vp_unit)
                views = None
            r = ranks(data, own, wide, views, vp_mode if vp is not None else "stored", margin)
            report(f"{vname} ({time.perf_counter() - t:.0f} s)", data, r)
            if vname == "default":
                miss_table(data, r)
                for q, ro, rw, rb in zip(data["queries"], r["own"], r["wide"], r["both"],
                                         strict=True):
                    if rb >= 10:
                        rows.append([data["name"], q["k"], q["nearest"], f"{q['dist']:.2f}",
                                     f"{q['dtheta']:.1f}", f"{q['overlap']:.3f}",
                                     *(int(x) if x < BIG else -1 for x in (ro, rw, rb))])
    if args.misses:
        with open(args.misses, "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["log", "query", "nearest", "nearest_m", "dtheta_deg", "overlap",
                        "rank_own", "rank_wide", "rank_interleaved"])
            w.writerows(rows)


if __name__ == "__main__":
    main()
