"""``bench loops``' final row with the free-space test about the keyframe (default) and
about each scan's own origin (``loops.check.free_space_origins = scans``), one process.

Run from the repository root::

    python benchmarks/scan_origins_bench.py LOG [--relations FILE] [--bar B ...]
        [--max-queries N] [--npz PREFIX] [--no-default] [--variant CAP:WINDOW:BAR ...]
        [--confirm WINDOW:BAR ...] [--either BAR [--fallback]]

The log is mapped once as ``loopclosure bench loops LOG --reference-from-log
--odometry-noise 0 --stages fused`` maps it (``--relations FILE``: the relations-fitted
reference instead), with the option on so that the keyframe store keeps every
keyframe's scan free space (mapping runs no loop check).  Then every query is run
(`evaluation.loop_bench_queries.query_all`) first with the default
``free_space_origins = keyframe``, then with ``scans`` at each ``--bar`` (the check's
``min_consistency``; default: the config's), then with the margin across each scan's
surface (``free_space_surface_cap``, `loopclosure.free_space` (1'')) and beside its
returns (``free_space_return_window``, (4)) at each ``--variant CAP:WINDOW:BAR``, then
with the confirmed free space (``free_space_confirm``, (5): (1) and the scans' model with
returns window WINDOW) at each ``--confirm WINDOW:BAR`` (``--either BAR``: or (1) at
BAR, ``free_space_either``; ``--fallback``: a fit only (5) passes is accepted only for a
query none of whose places (1) passes, ``free_space_fallback``).
Prints per pass R@100P / R@99P / AP of the final row, accepted / correct detections
and the accepted ones more than 1 m or 5 degrees from the reference (a wrong place,
not a tolerance case), CPU ms per query (the whole query: cascade and checks) and the
memory of the kept free space; the peak RSS at the end.
"""

from __future__ import annotations

import argparse
import resource
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from data import se2  # noqa: E402
from evaluation.loop_bench import _query_plan, mapped_input  # noqa: E402
from evaluation.loop_bench_input import LoopSource  # noqa: E402
from evaluation.loop_bench_queries import query_all  # noqa: E402
from evaluation.loop_bench_truth import (  # noqa: E402
    average_precision,
    pose_correct,
    pr_curve,
    recall_at_precision,
)
from loopclosure.free_space import SCAN_FREE_SPACE  # noqa: E402
from slam.config import PipelineConfig  # noqa: E402


def loop_source(log: str, relations: str | None) -> LoopSource:
    """`log` as ``bench loops`` reads it: against `relations` when given, else its
    logged poses as the reference and the drifting odometry of seed 0."""
    if relations:
        return LoopSource(log, relations=relations, folder=str(Path.cwd()))
    return LoopSource(log, reference_from_log=True, odometry_noise=0, folder=str(Path.cwd()))


def run_pass(mapper, result, ref, max_queries, label, npz):
    det = mapper.detector
    covered = np.isfinite(ref).all(axis=1)
    poses = np.array([result.keyframe_poses[kf.id] for kf in result.keyframes], float)
    start = time.process_time()
    raw = query_all(mapper, ref, covered, poses, ["fused"],
                    _query_plan(len(ref), max_queries), 10**9, 2.0, lambda *_: None)
    cpu = time.process_time() - start
    q = np.asarray(raw.keys)
    match = np.asarray(raw.final_match)
    acc = np.asarray(raw.accepted) & (match >= 0)
    ok = np.zeros(len(q), bool)
    ok[acc] = pose_correct(ref[q[acc]], ref[match[acc]], np.asarray(raw.relative)[acc])
    rel = np.asarray(raw.relative, float).reshape(-1, 3)
    err = np.full((len(q), 2), np.nan)  # accepted: the fit's distance from the reference
    for i in np.flatnonzero(acc & np.isfinite(ref[match.clip(0)]).all(axis=1)):
        off = se2.between(se2.between(ref[match[i]], ref[q[i]]), rel[i])
        err[i] = np.hypot(off[0], off[1]), abs(np.degrees(off[2]))
    gross = int(np.sum(acc & ~ok & ((err[:, 0] > 1.0) | (err[:, 1] > 5.0))))
    revisits = int(np.sum(raw.revisit))
    curve = pr_curve(np.asarray(raw.final_score), ok, revisits)
    if npz:
        np.savez(f"{npz}-{label}.npz", keys=q, match=match, score=np.asarray(raw.final_score),
                 accepted=acc, relative=np.asarray(raw.relative), correct=ok,
                 reason=np.asarray(raw.reason), error=err)
    kept = sum(t.derived[SCAN_FREE_SPACE].nbytes for _, t in det._targets.values()
               if SCAN_FREE_SPACE in t.derived)
    print(f"  {label}: R@100P {recall_at_precision(curve, 1.0):.3f} "
          f"R@99P {recall_at_precision(curve, 0.99):.3f} AP {average_precision(curve):.3f} "
          f"accepted {int(acc.sum())} correct {int(ok.sum())} wrong beyond 1 m / 5 deg "
          f"{gross} revisits {revisits} "
          f"queries {len(q)} cpu ms/query {1000 * cpu / max(len(q), 1):.1f} "
          f"cached-target free space {kept / 1e6:.1f} MB", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("log")
    ap.add_argument("--relations")
    ap.add_argument("--bar", type=float, action="append")
    ap.add_argument("--max-queries", type=int)
    ap.add_argument("--npz", help="save each pass's final records to PREFIX-LABEL.npz")
    ap.add_argument("--variant", action="append", metavar="CAP:WINDOW:BAR",
                    help="also a pass with the margin across each scan's surface "
                         "(``loops.check.free_space_surface_cap = CAP``) and its returns "
                         "(``free_space_return_window = WINDOW``) at bar BAR; repeatable")
    ap.add_argument("--confirm", action="append", metavar="WINDOW:BAR",
                    help="also a pass with the confirmed free space (1) and (1'), "
                         "(``free_space_confirm``, `loopclosure.free_space` (5)), the "
                         "scans' returns window WINDOW, at bar BAR; repeatable")
    ap.add_argument("--either", type=float, default=0.0, metavar="BAR",
                    help="with --confirm: a fit failing the pass's bar under (5) passes "
                         "when (1) reaches BAR (``free_space_either``)")
    ap.add_argument("--fallback", action="store_true",
                    help="with --either: a fit only (5) passes is accepted only for a "
                         "query none of whose places (1) passes (``free_space_fallback``)")
    ap.add_argument("--no-default", action="store_true")
    ap.add_argument("--default-only", action="store_true",
                    help="the default alone, mapped without the option (its memory)")
    ap.add_argument("--rule-pairs", type=int, metavar="STEP",
                    help="also the front-end pairs of `consistency_bar_rule.py` (every "
                         "STEP-th keyframe) on this mapping")
    args = ap.parse_args()
    cfg = PipelineConfig()
    default_bar = cfg.loops.check.min_consistency
    if not args.default_only:  # the store keeps the scans' free space
        cfg.loops.check.free_space_origins = "scans"
    source = loop_source(args.log, args.relations)
    mapper, result, ref = mapped_input(source, cfg)
    det = mapper.detector
    kept = sum(r.nbytes for r in det._scan_ranges)
    print(f"{Path(args.log).name}: {len(ref)} keyframes, scans' free ranges kept "
          f"{kept / 1e6:.1f} MB", flush=True)
    check = det.config.check
    if args.rule_pairs:
        from consistency_bar_rule import matched_bar, pairs_in

        one, per = pairs_in(mapper, args.rule_pairs)
        print(f"  front-end pairs {len(one)}: below {default_bar} with (1) "
              f"{np.mean(one < default_bar):.3f}; matched bar of (1') "
              f"{matched_bar(one, per, default_bar):.3f}", flush=True)
        if args.npz:
            np.savez(f"{args.npz}-rule-pairs.npz", keyframe=one, scans=per)
    if not args.no_default:
        check.free_space_origins, check.min_consistency = "keyframe", default_bar
        det.release_caches()
        run_pass(mapper, result, ref, args.max_queries, f"keyframe-{default_bar}", args.npz)
    for bar in [] if args.default_only else args.bar or (
            [] if args.variant or args.confirm else [default_bar]):
        check.free_space_origins, check.min_consistency = "scans", bar
        det.release_caches()
        run_pass(mapper, result, ref, args.max_queries, f"scans-{bar}", args.npz)
    for variant in [] if args.default_only else args.variant or []:
        cap, window, bar = (float(v) for v in variant.split(":"))
        check.free_space_origins, check.min_consistency = "scans", bar
        check.free_space_surface_cap, check.free_space_return_window = cap, int(window)
        det.release_caches()
        run_pass(mapper, result, ref, args.max_queries, f"surface{cap:g}-w{int(window)}-{bar}",
                 args.npz)
    check.free_space_surface_cap, check.free_space_return_window = 1.0, 0
    for variant in [] if args.default_only else args.confirm or []:
        window, bar = variant.split(":")
        check.free_space_origins, check.min_consistency = "scans", float(bar)
        check.free_space_return_window, check.free_space_confirm = int(window), True
        check.free_space_either = args.either
        check.free_space_fallback = args.fallback
        det.release_caches()
        run_pass(mapper, result, ref, args.max_queries,
                 f"confirm-w{int(window)}-{bar}" + (f"-or-{args.either}" if args.either else "")
                 + ("-fallback" if args.fallback else ""), args.npz)
    check.free_space_return_window, check.free_space_confirm = 0, False
    check.free_space_either, check.free_space_fallback = 0.0, False
    print(f"  peak RSS {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB")


if __name__ == "__main__":
    main()
