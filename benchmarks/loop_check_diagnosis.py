"""Why appearance-only loop detection misses revisits: retrieval or the geometric check?

Run from the repository root::

    python benchmarks/loop_check_diagnosis.py ../shared/data/carmen-corrected/*.log.gz \
        [--relations FILE] [--csv DIR] [--what-if]

Each log is mapped as ``loopclosure bench loops`` maps it (the loop searches off; a
corrected log with the drifting odometry of seed 0 and its own corrected poses as the
reference, or the reference fitted to ``--relations`` for a raw log).  Then every
keyframe with a revisit (an eligible older keyframe within 2 m in the reference)
asks the place database, as the pipeline's global search does
(`loopclosure.loop_detector.LoopClosureDetector.query_places`, then `places`: the
best ``loops.global_verify`` distinct places), and **every** one of those places is
checked on its own (`verify_places`, no pose prior), not only until the pipeline's
budget of accepted loops is spent.  A check is *correct* when its relative pose
agrees with the reference within 0.2 m and 2 degrees.

Per log it prints the query funnel: revisits; a true place among the database's
matches; among the places checked; a correct check accepted; a wrong one accepted
(and one more than 0.5 m off).  Then, pooled over the logs, the rule that rejected
each correct check (the first rule that failed, `loopclosure.geometric_check`) and,
with ``--what-if``, the correct and wrong checks each threshold of the acceptance rule
would accept at other values (re-applied to the recorded figures; the distance and
the agreement rules are left out, so the counts are of single checks).

``--csv DIR`` writes every check (log, query, match, truth, verdict, fitness,
consistency, margin, degeneracy, rms, matched length, errors, and the query's pose in the
map that the check implies: the match's map pose composed with the check's relative pose)
to ``DIR/<log>.csv``, outside the repository.
"""

from __future__ import annotations

import argparse
import csv
import re
import sys
from collections import Counter
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from data import se2  # noqa: E402
from evaluation.loop_bench import Tolerances, mapped_input  # noqa: E402
from evaluation.loop_bench_input import LoopSource  # noqa: E402
from slam.config import PipelineConfig  # noqa: E402

FIELDS = ("fitness", "inlier_ratio", "rms", "degeneracy", "margin", "consistency",
          "matched_length", "axis_length", "axis_hold", "pinned_length", "cross_hold")


def checks_of(path: str, relations: str | None, tol: Tolerances) -> tuple[list[dict], Counter]:
    """Every check of every revisit query of the log at `path` (module docstring)."""
    source = LoopSource(path, relations=relations, reference_from_log=relations is None,
                        odometry_noise=None if relations else 0, folder=str(Path.cwd()))
    mapper, result, ref = mapped_input(source, PipelineConfig())
    det = mapper.detector
    poses = np.array([result.keyframe_poses[kf.id] for kf in result.keyframes], float)
    keys = np.array(sorted(det.database.keys), dtype=np.intp)
    covered = np.isfinite(ref).all(axis=1)
    rows: list[dict] = []
    funnel: Counter = Counter()
    for k in range(len(result.keyframes)):
        if k not in det.database or not covered[k]:
            continue
        older = keys[keys < k]
        cand = older[det.eligible(k)[older] & covered[older]]
        if len(cand) == 0:
            continue
        near = np.hypot(*(ref[cand, :2] - ref[k, :2]).T) <= tol.max_distance
        if not near.any():
            continue
        true = set(cand[near].tolist())
        matches = det.query_places(k, cand)
        places = det.places(matches, poses)
        pts = mapper.query_submaps.get(k)
        checked = [c for p in places for c in det.verify_places(k, [p], poses, pts)]
        good = bad = far = False
        for c in checked:
            err = se2.between(se2.between(ref[c.match], ref[k]), np.asarray(c.relative))
            err_m, err_deg = float(np.hypot(err[0], err[1])), abs(float(np.degrees(err[2])))
            correct = err_m <= tol.trans_tol and err_deg <= tol.rot_tol_deg
            good |= c.accepted and correct
            bad |= c.accepted and not correct
            far |= c.accepted and err_m > 0.5
            v = c.verification
            implied = se2.compose(poses[c.match], np.asarray(c.relative))  # query, map frame
            rows.append(dict(log=Path(path).name, query=k, match=int(c.match),
                             implied_x=round(float(implied[0]), 3),
                             implied_y=round(float(implied[1]), 3),
                             implied_deg=round(float(np.degrees(implied[2])), 2),
                             near=int(c.match) in true, correct=correct, accepted=c.accepted,
                             reason=c.reason, err_m=round(err_m, 4), err_deg=round(err_deg, 3),
                             **{f: round(float(getattr(v, f)), 4) for f in FIELDS}))
        funnel["revisits"] += 1
        funnel["true place matched"] += any(int(m.key) in true for m in matches)
        funnel["true place checked"] += any(int(p.key) in true for p in places)
        funnel["correct accepted"] += good
        funnel["wrong accepted"] += bad
        funnel["wrong > 0.5 m accepted"] += far
    return rows, funnel


def rule(reason: str) -> str:
    """The rule a verdict names, its figures dropped."""
    return re.sub(r"\s+", " ", re.sub(r"[\d.()<>]+", "", reason)).strip()


def accepts(rows: list[dict], **cfg: float) -> np.ndarray:
    """The acceptance rule of the correlative check (`loopclosure.geometric_check`)
    re-applied to recorded checks, with some thresholds changed (`cfg`)."""
    from loopclosure.geometric_check import GeometricCheckConfig

    c = GeometricCheckConfig()
    for name, value in cfg.items():
        setattr(c, name, value)
    f = {k: np.array([r[k] for r in rows], float) for k in FIELDS}
    partial = (f["fitness"] < c.min_fitness) | (f["inlier_ratio"] < c.min_inlier_ratio)
    held = c.pinned_degenerate & (np.nan_to_num(f["pinned_length"], nan=-1.0)
                                  >= c.min_matched_length)
    # pinned_cross, where the check recorded its cross slide: kept along > across
    crossed = np.isfinite(f["cross_hold"])
    held &= ~(c.pinned_cross & crossed) | (f["axis_hold"] > f["cross_hold"])
    return ((f["matched_length"] >= c.min_matched_length)
            & (f["consistency"] >= c.min_consistency)
            & (f["rms"] <= c.max_rms) & ((f["degeneracy"] >= c.min_degeneracy) | held)
            & ~(partial & (f["degeneracy"] < c.min_degeneracy_partial) & ~held)
            & ~(c.pinned_required & (f["degeneracy"] < c.min_degeneracy_partial)
                & ~(np.nan_to_num(f["pinned_length"], nan=-1.0) >= c.min_matched_length))
            & (f["margin"] >= c.min_fitness_margin))


WHAT_IF = {
    "min_consistency": (0.96, 0.94, 0.92, 0.90, 0.88, 0.85),
    "min_fitness_margin": (0.15, 0.1, 0.05, 0.0),
    "min_matched_length": (8.0, 4.0, 2.0, 1.0),
    "min_degeneracy_partial": (0.15, 0.1, 0.05, 0.04),
    "pinned_degenerate": (False, True),
    "pinned_required": (False, True),
    "pinned_degenerate+pinned_required": (True,),
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("logs", nargs="+")
    ap.add_argument("--relations", help="reference relations of a raw log (one log)")
    ap.add_argument("--csv", type=Path, help="write every check to DIR/<log>.csv")
    ap.add_argument("--what-if", action="store_true", help="other thresholds, pooled")
    args = ap.parse_args()
    if args.relations and len(args.logs) != 1:
        ap.error("--relations goes with one log")
    tol = Tolerances()
    every: list[dict] = []
    heads = ("revisits", "true place matched", "true place checked", "correct accepted",
             "wrong accepted", "wrong > 0.5 m accepted")
    print("log".ljust(34) + "".join(h.rjust(24) for h in heads))
    for path in args.logs:
        rows, funnel = checks_of(path, args.relations, tol)
        every += rows
        n = max(funnel["revisits"], 1)
        cells = [f"{funnel[h]} ({funnel[h] / n:.2f})" if h != "revisits" else str(funnel[h])
                 for h in heads]
        print(Path(path).name.ljust(34) + "".join(c.rjust(24) for c in cells), flush=True)
        if args.csv and rows:
            args.csv.mkdir(parents=True, exist_ok=True)
            with open(args.csv / f"{Path(path).name}.csv", "w", newline="") as out:
                w = csv.DictWriter(out, fieldnames=list(rows[0]))
                w.writeheader()
                w.writerows(rows)
    rejected = Counter(rule(r["reason"]) for r in every if r["correct"] and not r["accepted"])
    print(f"\ncorrect checks rejected, by rule ({sum(rejected.values())} of "
          f"{sum(r['correct'] for r in every)} correct checks):")
    for name, count in rejected.most_common():
        print(f"  {count:6d}  {name}")
    if not args.what_if or not every:
        return
    correct = np.array([r["correct"] for r in every])
    off = np.array([r["err_m"] for r in every]) > 0.5
    print("\nwhat if (single checks, pooled): threshold value -> correct / wrong / wrong > 0.5 m "
          "accepted")
    for name, values in WHAT_IF.items():
        for value in values:
            ok = accepts(every, **{n: value for n in name.split("+")})
            print(f"  {name} = {value:<5}  {int((ok & correct).sum()):6d} "
                  f"{int((ok & ~correct).sum()):6d} {int((ok & off).sum()):6d}")


if __name__ == "__main__":
    main()
