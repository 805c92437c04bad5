"""Every whole-circle re-check of `loops.circle_fallback`, judged against the reference.

Run from the repository root::

    python benchmarks/circle_fallback.py LOG [--relations FILE] [--fallback N]

The log runs through ``loopclosure bench loops``'s protocol (`evaluation.loop_bench`,
the ``fused`` row and the final check; a corrected log takes its logged poses as the
reference with the drifting odometry of seed 0, a raw log the reference fitted to
``--relations``) with ``loops.circle_fallback = N`` (default 13: every place a query
checks).  Each re-check the detector makes (`LoopClosureDetector._circle_fallback`)
is recorded: the query, the place, its position among the places the query checked
(0: the first), the verdict of its check from the heading hypotheses, and the
re-check's verdict and relative pose.  A re-check is *correct* when the reference
puts the two keyframes within 2 m and its relative pose agrees with the reference
within 0.2 m and 2 degrees.

Prints the bench's final row (recall at 100% / 99% precision, top-1 recall, ms per
query), the re-checks made, accepted, correct and wrong, each accepted one, and how
far down the checked places the true places re-checked lay.
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import loopclosure.candidate_checks as cc  # noqa: E402
import loopclosure.loop_detector as ld  # noqa: E402
from data import se2  # noqa: E402
from evaluation.loop_bench import loop_benchmark, parse_stages  # noqa: E402
from evaluation.loop_bench_input import LoopSource  # noqa: E402
from evaluation.loop_bench_report import json_document  # noqa: E402
from slam.config import PipelineConfig  # noqa: E402
from slam.config_io import apply_overrides  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("log")
    ap.add_argument("--relations")
    ap.add_argument("--fallback", type=int, default=13)
    args = ap.parse_args()
    cfg = apply_overrides(PipelineConfig(), [f"loops.circle_fallback={args.fallback}"])
    records: list[dict] = []
    state: dict = {"on": False}
    real_fallback = ld.LoopClosureDetector._circle_fallback
    real_verify = cc.verify
    real_target = ld.LoopClosureDetector._target
    target_keys: dict[int, int] = {}

    def fallback(self, key, matches, out, query_points, poses, budget):
        state.update(on=True, key=key, first={int(c.match): c.reason for c in out},
                     order=[int(c.match) for c in out])
        try:
            return real_fallback(self, key, matches, out, query_points, poses, budget)
        finally:
            state["on"] = False

    def target(self, key):
        t = real_target(self, key)
        target_keys[id(t)] = int(key)
        return t

    def verify(query_points, candidate, **kw):
        result = real_verify(query_points, candidate, **kw)
        if state["on"] and kw.get("headings", 0) is None:
            match = target_keys[id(candidate)]
            records.append({
                "query": state["key"], "match": match, "rank": state["order"].index(match),
                "first": state["first"][match], "accepted": result.accepted,
                "reason": result.reason, "relative": np.asarray(result.relative, float)})
        return result

    ld.LoopClosureDetector._circle_fallback = fallback
    ld.LoopClosureDetector._target = target
    cc.verify = verify
    source = LoopSource(args.log, relations=args.relations,
                        reference_from_log=args.relations is None,
                        odometry_noise=None if args.relations else 0, folder=str(Path.cwd()))
    try:
        bench = loop_benchmark(source.open(), cfg, stages=parse_stages("fused", cfg),
                               source=source)
    finally:
        ld.LoopClosureDetector._circle_fallback = real_fallback
        ld.LoopClosureDetector._target = real_target
        cc.verify = real_verify
    ref = bench.reference
    for r in records:
        k, m = r["query"], r["match"]
        if np.isnan(ref[[k, m]]).any():
            r["place_ok"] = r["pose_ok"] = None
            continue
        truth = se2.between(ref[m], ref[k])
        d = se2.between(truth, r["relative"])
        r["place_ok"] = bool(np.hypot(*(ref[m, :2] - ref[k, :2])) <= 2.0)
        r["pose_ok"] = bool(r["place_ok"] and np.hypot(d[0], d[1]) <= 0.2
                            and abs(np.degrees(d[2])) <= 2.0)
        r["error"] = (float(np.hypot(d[0], d[1])), float(np.degrees(d[2])))
    final = json_document(bench)["final"]
    print(f"{Path(args.log).name}: circle_fallback {args.fallback}; final R@100P "
          f"{final['recall_at_p100']:.3f}, R@99P {final['recall_at_p99']:.3f}, top-1 "
          f"{final['top1_recall']:.3f}, {final['ms_per_query']:.1f} ms per query")
    accepted = [r for r in records if r["accepted"]]
    print(f"re-checks {len(records)} ({len(records) / max(len(bench.query_keys), 1):.2f} "
          f"per query), accepted {len(accepted)}: correct "
          f"{sum(bool(r['pose_ok']) for r in accepted)}, wrong "
          f"{sum(r['pose_ok'] is False for r in accepted)}")
    for r in accepted:
        print(f"  query {r['query']} place {r['match']} (checked {r['rank'] + 1}th) "
              f"correct {r['pose_ok']} error {r.get('error')}; from the hypotheses: "
              f"{r['first']}")
    print("true places re-checked, by position among the checked places:",
          sorted(Counter(r["rank"] for r in records if r["place_ok"]).items()))


if __name__ == "__main__":
    main()
