"""``bench loops``' final row with the free-space test's rays cast from each scan's own origin.

Run from the repository root::

    python benchmarks/multi_origin_consistency.py LOG [--bar B] [--max-queries N] [--npz F]

The log is mapped and queried as ``loopclosure bench loops LOG --reference-from-log
--odometry-noise 0 --stages fused`` does, with `loopclosure.prior_free`'s consistency
replaced (in this process only) by the ``multi`` model of `consistency_diagnosis.py`: the
same hits, a conflict being a point in the free space of any scan of the other submap,
each scan's free space about its own sensor origin (the keyframes of the submap at
their front-end poses).  `--bar` sets ``loops.check.min_consistency`` (default: the
config's).  Prints the final row's R@100P / R@99P and the accepted / correct detections.
A check whose submaps the script cannot name (the longer check's, off by default) keeps
today's model.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from consistency_diagnosis import scans_of, union_free  # noqa: E402

from data import se2  # noqa: E402
from evaluation.loop_bench import _query_plan, mapped_input  # noqa: E402
from evaluation.loop_bench_input import LoopSource  # noqa: E402
from evaluation.loop_bench_queries import query_all  # noqa: E402
from evaluation.loop_bench_truth import pose_correct, pr_curve, recall_at_precision  # noqa: E402
from loopclosure import geometric_check, prior_free  # noqa: E402
from loopclosure.free_space import Consistency  # noqa: E402
from slam.config import PipelineConfig  # noqa: E402

_original = prior_free.consistency
_current: dict = {"query": None, "candidate": None}


def multi_consistency(query, candidate, pose, tolerance=0.1, margin=0.3, *, q_scans,
                      c_scans) -> Consistency:
    """`loopclosure.free_space.consistency` (2) with the conflicts of the ``multi``
    model: a point that is no hit conflicts when it lies in the free space of any of
    the other submap's scans (`consistency_diagnosis.union_free`)."""
    t = np.asarray(pose, dtype=float).reshape(3)
    hits = conflicts = 0
    for moved, other, scans in ((se2.transform_points(t, query.points), candidate, c_scans),
                                (se2.transform_points(se2.inverse(t), candidate.points),
                                 query, q_scans)):
        if len(moved) == 0 or other.tree is None:
            continue
        d, _ = other.tree.query(moved, k=1, distance_upper_bound=tolerance)
        hit = np.isfinite(d)
        hits += int(hit.sum())
        conflicts += int((~hit & union_free(scans, moved, margin)).sum())
    total = len(query.points) + len(candidate.points)
    return Consistency(hits / (hits + conflicts) if hits + conflicts else 0.0,
                       conflicts / total if total else 0.0, hits, conflicts)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("log")
    ap.add_argument("--bar", type=float)
    ap.add_argument("--max-queries", type=int)
    ap.add_argument("--npz", help="save the final row's records (keys, match, score, "
                    "accepted, relative, correct) here")
    args = ap.parse_args()
    cfg = PipelineConfig()
    if args.bar is not None:
        cfg.loops.check.min_consistency = args.bar
    source = LoopSource(args.log, reference_from_log=True, odometry_noise=0,
                        folder=str(Path.cwd()))
    mapper, result, ref = mapped_input(source, cfg)
    det = mapper.detector
    s = cfg.loops.check.search
    nb = cfg.submap_neighbours()
    last = len(mapper.keyframes.keyframes) - 1
    names: dict[int, int] = {}
    scans: dict[tuple, list] = {}
    target_of, verify_places = det._target, det.verify_places
    match_prior_free = geometric_check.match_prior_free

    def scans_at(key: int, hi: int) -> list:
        if (key, hi) not in scans:
            scans[(key, hi)] = scans_of(mapper, key, max(0, key - nb), hi, s.free_bins)
        return scans[(key, hi)]

    def named_target(key):
        t = target_of(key)
        names[id(t)] = key
        return t

    def verifying(key, *a, **kw):
        _current["query"] = key
        return verify_places(key, *a, **kw)

    def matching(query_points, candidate, **kw):
        _current["candidate"] = names.get(id(candidate))
        try:
            return match_prior_free(query_points, candidate, **kw)
        finally:
            _current["candidate"] = None

    def consistency(query, candidate, pose, tolerance=0.1, margin=0.3):
        k, m = _current["query"], _current["candidate"]
        if k is None or m is None:
            return _original(query, candidate, pose, tolerance, margin)
        return multi_consistency(query, candidate, pose, tolerance, margin,
                                 q_scans=scans_at(k, k), c_scans=scans_at(m, min(last, m + nb)))

    det._target, det.verify_places = named_target, verifying
    geometric_check.match_prior_free = matching
    prior_free.consistency = consistency
    covered = np.isfinite(ref).all(axis=1)
    poses = np.array([result.keyframe_poses[kf.id] for kf in result.keyframes], float)
    raw = query_all(mapper, ref, covered, poses, ["fused"], _query_plan(len(ref), args.max_queries),
                    10**9, 2.0, lambda *_: None)
    q = np.asarray(raw.keys)
    match = np.asarray(raw.final_match)
    acc = np.asarray(raw.accepted) & (match >= 0)
    ok = np.zeros(len(q), bool)
    ok[acc] = pose_correct(ref[q[acc]], ref[match[acc]], np.asarray(raw.relative)[acc])
    if args.npz:
        np.savez(args.npz, keys=q, match=match, score=np.asarray(raw.final_score),
                 accepted=acc, relative=np.asarray(raw.relative), correct=ok)
    curve = pr_curve(np.asarray(raw.final_score), ok, int(np.sum(raw.revisit)))
    print(f"{Path(args.log).name} multi-origin free space, bar "
          f"{cfg.loops.check.min_consistency}: R@100P {recall_at_precision(curve, 1.0):.3f} "
          f"R@99P {recall_at_precision(curve, 0.99):.3f} accepted {int(acc.sum())} "
          f"correct {int(ok.sum())} revisits {int(np.sum(raw.revisit))}")


if __name__ == "__main__":
    main()
