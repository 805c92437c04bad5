"""The prior-free geometric check, old (multi-start ICP) vs new (correlative), on the same pairs.

Two steps::

    python benchmarks/prior_free_check.py collect LOG [--relations FILE] --out PAIRS.pkl
    python benchmarks/prior_free_check.py compare PAIRS.pkl [PAIRS.pkl ...]
        [--set KEY=VALUE] [--variant NAME:KEY=VALUE,...]

``collect`` runs `loopclosure bench loops`'s protocol (`evaluation.loop_bench`, the
default pipeline, every keyframe a query with no pose prior; a corrected log takes
its logged poses as the reference with the drifting odometry of seed 0) and records
every check with no prior it makes (each checked place of a query, and the re-check
at a nearer keyframe): the query submap, the candidate's submap, the heading
hypotheses and translation the detector passes to `verify`, the fused score of the
query's match, and the reference relative pose.  The file stays outside the repository (data is
never copied in).

``compare`` re-runs the check on every recorded pair with ``method="icp"`` (the
multi-start ICP check) and ``method="correlative"`` (`loopclosure.correlative`
first), both with the same configuration otherwise, in this one process, and prints
per log and in total: CPU seconds per check (``time.process_time``) and their ratio,
accepted / correct / false accepts, how many of those false accepts are reference
artefacts (ICP started at the reference pose converges to the check's pose, within
5 cm and 0.5 deg), the recall at 100% precision of the accepted
proposals ranked by fused score over the queries with a revisit (the bench's
``final`` row, restricted to the recorded queries), and how many verdicts differ from
the first variant's.  Correct = the reference puts the two keyframes within 2 m and
the checked relative pose agrees within 0.2 m / 2 deg.  ``--variant`` replaces the two
methods by named configurations (e.g. ``--variant numpy:compiled_icp=false
--variant compiled:``: the check's ICP by numpy or by the compiled kernel).
"""

from __future__ import annotations

import argparse
import dataclasses
import pickle
import sys
import time
from pathlib import Path

import numpy as np

from data import se2


def collect(log: Path, relations: Path | None, out: Path, max_queries: int | None) -> None:
    import loopclosure.candidate_checks as cc
    import loopclosure.loop_detector as ld
    from evaluation.cli_loops import _relations_fn, _trajectory_fn
    from evaluation.loop_bench import run_loop_bench
    from evaluation.slam_input import load_input
    from evaluation.slam_reference import logged_reference
    from slam.config import PipelineConfig

    data = load_input(log, odometry_noise=None if relations else 0)
    ref_fn = (_relations_fn(data, relations) if relations
              else _trajectory_fn(data, logged_reference(data)))
    records: list[dict] = []
    real_verify = cc.verify
    real_check = ld.LoopClosureDetector._check_global
    real_target = ld.LoopClosureDetector._target
    context: dict = {}
    target_keys: dict[int, int] = {}

    def check_global(self, key, m, query_points, *args, **kwargs):
        context.update(query=int(key), score=float(m.score))
        return real_check(self, key, m, query_points, *args, **kwargs)

    def target(self, key):
        t = real_target(self, key)
        target_keys[id(t)] = int(key)
        return t

    def recording(query_points, candidate, **kw):
        result = real_verify(query_points, candidate, **kw)
        if kw.get("prior") is None and "query" in context:  # a check with no prior
            records.append({
                "query_points": np.asarray(query_points, float),
                "target_points": np.asarray(candidate.points, float),
                "headings": np.asarray(kw.get("headings"), float),
                "translation": np.asarray(kw.get("translation"), float),
                "max_distance": kw.get("max_distance"),
                "query": context["query"], "match": target_keys[id(candidate)],
                "score": context["score"],
            })
        return result

    cc.verify = recording
    ld.LoopClosureDetector._check_global = check_global
    ld.LoopClosureDetector._target = target
    try:
        bench = run_loop_bench(str(log), data.scans, PipelineConfig(), ref_fn,
                               stages=["fused"], max_queries=max_queries)
    finally:
        cc.verify = real_verify
        ld.LoopClosureDetector._check_global = real_check
        ld.LoopClosureDetector._target = real_target
    ref = bench.reference
    revisit = dict(zip(bench.query_keys.tolist(), bench.has_revisit.tolist(), strict=True))
    pairs = []
    for rec in records:
        k, m = rec["query"], rec["match"]
        if np.isnan(ref[m]).any() or np.isnan(ref[k]).any():
            continue
        rec.update(has_revisit=bool(revisit.get(k, False)),
                   truth=se2.between(ref[m], ref[k]),
                   place_ok=bool(np.hypot(*(ref[m, :2] - ref[k, :2])) <= 2.0))
        pairs.append(rec)
    out.parent.mkdir(parents=True, exist_ok=True)
    with open(out, "wb") as f:
        pickle.dump({"name": log.name, "queries": len(bench.query_keys),
                     "revisits": bench.revisits, "pairs": pairs}, f)
    print(f"{log.name}: {len(pairs)} pairs, {bench.revisits} revisits -> {out}")


def _recall_p100(score, correct, accepted, revisits):
    s = np.where(accepted, score, -np.inf)
    order = np.argsort(-s, kind="stable")
    best = 0.0
    tp = fp = 0
    for i in order:
        if not np.isfinite(s[i]):
            break
        tp += bool(correct[i])
        fp += not correct[i]
        if fp == 0:
            best = tp / max(revisits, 1)
    return best


def _run(pairs, cfg):
    from loopclosure.geometric_check import verify
    from loopclosure.registration import RegistrationTarget

    out = []
    cpu = 0.0
    for p in pairs:
        target = RegistrationTarget(p["target_points"], cfg.icp)  # cached by the detector
        t = time.process_time()
        r = verify(p["query_points"], target, headings=p["headings"],
                   translation=p["translation"], max_distance=p["max_distance"], config=cfg)
        cpu += time.process_time() - t
        out.append(r)
    return out, cpu


def _judge(pairs, results):
    correct = []
    for p, r in zip(pairs, results, strict=True):
        d = se2.between(p["truth"], r.relative)
        ok = (p["place_ok"] and np.hypot(d[0], d[1]) <= 0.2
              and abs(np.degrees(se2.wrap_angle(d[2]))) <= 2.0)
        correct.append(bool(ok))
    return np.array(correct)


def _reference_agrees(pair: dict, result, cfg) -> bool:
    """ICP started at the reference pose converges to the check's pose (within 5 cm and
    0.5 deg): the data support the check, the reference disagrees with it."""
    from loopclosure.registration import RegistrationTarget, register, voxel_downsample

    target = RegistrationTarget(pair["target_points"], cfg.icp)
    src = voxel_downsample(pair["query_points"], cfg.source_voxel)
    d = se2.between(register(src, target, pair["truth"], config=cfg.icp).pose,
                    result.relative)
    return bool(np.hypot(d[0], d[1]) <= 0.05 and abs(np.degrees(se2.wrap_angle(d[2]))) <= 0.5)


def _with(cfg, overrides: list[str]):
    """`cfg` with ``key=value`` overrides (numbers, booleans, strings)."""
    for o in overrides:
        k, v = o.split("=", 1)
        old = getattr(cfg, k)
        if isinstance(old, bool):
            value = v.lower() in ("1", "true")
        elif isinstance(old, (int, float)):
            value = type(old)(float(v))
        else:
            value = v
        cfg = dataclasses.replace(cfg, **{k: value})
    return cfg


def compare(files: list[Path], overrides: list[str], variants: list[str]) -> None:
    from loopclosure.geometric_check import GeometricCheckConfig

    base = _with(GeometricCheckConfig(), overrides)
    if variants:
        methods = {}
        for v in variants:
            name, _, sets = v.partition(":")
            methods[name] = _with(base, [x for x in sets.split(",") if x])
    else:
        methods = {"icp": dataclasses.replace(base, method="icp"),
                   "correlative": dataclasses.replace(base, method="correlative")}
    first = next(iter(methods))
    totals = {m: [0.0, 0] for m in methods}
    print(f"{'log':24s} {'method':12s} {'pairs':>5s} {'ms/chk':>7s} {'acc':>4s} {'ok':>4s} "
          f"{'false':>5s} {'refArt':>6s} {'R@P100':>6s} {'differ':>6s}")
    for f in files:
        with open(f, "rb") as fh:
            doc = pickle.load(fh)
        pairs = doc["pairs"]
        score = np.array([p["score"] for p in pairs])
        reference = None
        for name, cfg in methods.items():
            res, cpu = _run(pairs, cfg)
            correct = _judge(pairs, res)
            acc = np.array([r.accepted for r in res])
            reference = acc if reference is None else reference
            totals[name][0] += cpu
            totals[name][1] += len(pairs)
            r100 = _recall_p100(score, correct & acc, acc, doc["revisits"])
            artefacts = sum(_reference_agrees(pairs[i], res[i], cfg)
                            for i in np.flatnonzero(acc & ~correct))
            print(f"{doc['name'][:24]:24s} {name:12s} {len(pairs):5d} "
                  f"{1e3 * cpu / max(len(pairs), 1):7.1f} {acc.sum():4d} "
                  f"{(acc & correct).sum():4d} {(acc & ~correct).sum():5d} {artefacts:6d} "
                  f"{r100:6.3f} {(acc != reference).sum():6d}")
            sys.stdout.flush()
    ms = {m: 1e3 * c / max(n, 1) for m, (c, n) in totals.items()}
    print("CPU per check: " + ", ".join(
        f"{m} {v:.1f} ms ({ms[first] / max(v, 1e-9):.2f}x of {first}'s speed)"
        for m, v in ms.items()))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    c = sub.add_parser("collect")
    c.add_argument("log", type=Path)
    c.add_argument("--relations", type=Path)
    c.add_argument("--out", type=Path, required=True)
    c.add_argument("--max-queries", type=int)
    m = sub.add_parser("compare")
    m.add_argument("pairs", type=Path, nargs="+")
    m.add_argument("--set", action="append", default=[], help="GeometricCheckConfig key=value")
    m.add_argument("--variant", action="append", default=[],
                   help="NAME:KEY=VALUE[,KEY=VALUE] (GeometricCheckConfig); several replace "
                        "the default icp / correlative pair, the first is the reference")
    a = ap.parse_args()
    if a.cmd == "collect":
        collect(a.log, a.relations, a.out, a.max_queries)
    else:
        compare(a.pairs, a.set, a.variant)


if __name__ == "__main__":
    main()
