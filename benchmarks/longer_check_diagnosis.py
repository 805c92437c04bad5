"""Where the longer check's wrong fits come from: the longer submaps' length, the
front end's drift over them, or the acceptance rules.

Run from the repository root::

    python benchmarks/longer_check_diagnosis.py LOG [--relations FILE] \
        [--keyframes 10,30] [--paths 5,10,20] [--csv FILE]

The log is mapped as ``loopclosure bench loops`` maps it (`evaluation.loop_bench.
mapped_input`: a corrected log with the drifting odometry of seed 0 and its own
corrected poses as the reference, or the reference fitted to ``--relations``).  Every
keyframe with a revisit (an eligible older keyframe within 2 m in the reference)
asks the place database for its places, as `benchmarks/loop_check_diagnosis.py`
does, and each place is checked on its own with the longer check off.  Every check
rejected for its degeneracy alone (`loopclosure.longer_check.is_degenerate`) is then
re-checked (`loopclosure.longer_check.recheck_longer`) on longer submaps of each
length asked for (a count of keyframes, or a path length in metres chosen by
`loopclosure.longer_check.trailing_count` on the map's keyframe poses), built twice:

- ``odom``: as the pipeline builds them (`slam.pipeline.Mapper.trailing_map`: the
  keyframes placed by the front end's poses);
- ``ref``: the same keyframes' scans placed by the reference poses (no drift).

A re-check accepted by ``odom`` and wrong (more than 0.2 m or 2 degrees from the
reference) but correct by ``ref`` is the front end's drift; wrong by both, the
submaps themselves (look-alike places) or the acceptance rules.  For each it
prints the trailing path [m] of query and candidate and the drift over it: the
front end's pose of the trailing map's oldest keyframe relative to its newest,
against the reference's [m, deg].  ``--csv`` writes one row per re-check.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.rows_csv import write_rows  # noqa: E402
from data import se2  # noqa: E402
from evaluation.loop_bench import Tolerances, mapped_input  # noqa: E402
from evaluation.loop_bench_input import LoopSource  # noqa: E402
from loopclosure.fast_icp import voxel_downsample_fast  # noqa: E402
from loopclosure.longer_check import (  # noqa: E402
    departure,
    is_degenerate,
    joined,
    judged,
    longer_fit,
    trailing_count,
)
from slam.config import PipelineConfig  # noqa: E402

FIGURES = ("fitness", "inlier_ratio", "rms", "degeneracy", "margin", "consistency",
           "matched_length")


def reference_trailing(mapper, ref: np.ndarray, key: int, n: int) -> np.ndarray:
    """`Mapper.trailing_map(key, n)` with the scans placed by the reference poses."""
    first = max(mapper._span(key)[0], key - n)
    parts = [se2.transform_points(se2.between(ref[key], ref[j]), mapper._keyframe(j).points)
             for j in range(first, key + 1) if np.isfinite(ref[j]).all()]
    pts = np.vstack(parts) if parts else np.zeros((0, 2))
    pts = pts[np.hypot(pts[:, 0], pts[:, 1]) <= mapper.config.submap.max_range]
    return voxel_downsample_fast(pts, mapper.config.submap.voxel)


def drift(mapper, ref: np.ndarray, key: int, n: int) -> tuple[float, float, float]:
    """Trailing path [m] of `key`'s n keyframes, and the front end's error of the oldest
    one's pose relative to `key` against the reference's [m], [deg]."""
    first = max(mapper._span(key)[0], key - n)
    odom = [mapper._keyframe(j).odom_pose for j in range(first, key + 1)]
    path = float(np.hypot(*np.diff(np.array(odom)[:, :2], axis=0).T).sum())
    if not (np.isfinite(ref[first]).all() and np.isfinite(ref[key]).all()):
        return path, float("nan"), float("nan")
    err = se2.between(se2.between(odom[-1], odom[0]), se2.between(ref[key], ref[first]))
    return path, float(np.hypot(err[0], err[1])), abs(float(np.degrees(err[2])))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("log")
    ap.add_argument("--relations")
    ap.add_argument("--keyframes", default="10,30")
    ap.add_argument("--paths", default="5,10,20")
    ap.add_argument("--csv")
    ap.add_argument("--queries", default="", help="only these keyframes (comma-separated)")
    args = ap.parse_args()
    tol = Tolerances()
    source = LoopSource(args.log, relations=args.relations,
                        reference_from_log=args.relations is None,
                        odometry_noise=None if args.relations else 0, folder=str(Path.cwd()))
    mapper, result, ref = mapped_input(source, PipelineConfig())
    det = mapper.detector
    check = det.config.check
    poses = np.array([result.keyframe_poses[kf.id] for kf in result.keyframes], float)
    steps = np.hypot(*np.diff(poses[:, :2], axis=0).T)
    print(f"{Path(args.log).name}: {len(poses)} keyframes, median step "
          f"{np.median(steps):.2f} m")
    variants = ([("kf", int(v)) for v in args.keyframes.split(",") if v]
                + [("m", float(v)) for v in args.paths.split(",") if v])
    keys = np.array(sorted(det.database.keys), dtype=np.intp)
    covered = np.isfinite(ref).all(axis=1)
    rows = []
    only = {int(q) for q in args.queries.split(",") if q}
    for k in range(len(poses)):
        if only and k not in only:
            continue
        if k not in det.database or not covered[k]:
            continue
        older = keys[keys < k]
        cand = older[det.eligible(k)[older] & covered[older]]
        if len(cand) == 0 or not (np.hypot(*(ref[cand, :2] - ref[k, :2]).T)
                                  <= tol.max_distance).any():
            continue
        places = det.places(det.query_places(k, cand), poses)
        pts = mapper.query_submaps.get(k)
        for c in (c for p in places for c in det.verify_places(k, [p], poses, pts)):
            first = c.verification
            if first is None or not is_degenerate(first):
                continue
            j = int(c.match)
            truth = se2.between(ref[j], ref[k])
            for kind, value in variants:
                cfg = (dataclasses.replace(check, longer_keyframes=int(value), longer_path_m=0.0)
                       if kind == "kf" else dataclasses.replace(check, longer_path_m=value))
                nq, nc = trailing_count(poses, k, cfg), trailing_count(poses, j, cfg)
                for built in ("odom", "ref"):
                    if built == "odom":
                        q = joined(pts, mapper.trailing_map(k, nq))
                        t = joined(mapper.submap(j), mapper.trailing_map(j, nc))
                    else:
                        q = joined(pts, reference_trailing(mapper, ref, k, nq))
                        t = joined(mapper.submap(j), reference_trailing(mapper, ref, j, nc))
                    whole = longer_fit(first, q, t, max_distance=det.config.max_distance,
                                       config=cfg)
                    second = judged(first, whole, cfg)
                    _, across, turn = departure(first, whole)
                    werr = se2.between(truth, whole.relative)
                    err = se2.between(truth, second.relative)
                    em, ed = float(np.hypot(err[0], err[1])), abs(float(np.degrees(err[2])))
                    pq, dq, aq = drift(mapper, ref, k, nq)
                    pc, dc, ac = drift(mapper, ref, j, nc)
                    rows.append(dict(query=k, match=j, variant=f"{value:g}{kind}", built=built,
                                     nq=nq, nc=nc, accepted=second.accepted,
                                     correct=em <= tol.trans_tol and ed <= tol.rot_tol_deg,
                                     err_m=round(em, 3), err_deg=round(ed, 2),
                                     along=round(float((second.relative[:2] - truth[:2])
                                                       @ first.degenerate_axis), 3),
                                     whole_err_m=round(float(np.hypot(werr[0], werr[1])), 3),
                                     whole_err_deg=round(abs(float(np.degrees(werr[2]))), 2),
                                     first_err_deg=round(abs(float(np.degrees(
                                         se2.between(truth, first.relative)[2]))), 2),
                                     across=round(across, 3), turn=round(turn, 2),
                                     first_cov=";".join(f"{v:.3g}" for v in
                                                        first.covariance.ravel()),
                                     cov=";".join(f"{v:.3g}" for v in whole.covariance.ravel()),
                                     axis=";".join(f"{v:.3f}" for v in first.degenerate_axis),
                                     x=round(float(second.relative[0]), 3),
                                     y=round(float(second.relative[1]), 3),
                                     path_q=round(pq, 1), path_c=round(pc, 1),
                                     drift_q_m=round(dq, 3), drift_q_deg=round(aq, 2),
                                     drift_c_m=round(dc, 3), drift_c_deg=round(ac, 2),
                                     **{f"first_{f}": round(float(getattr(first, f)), 3)
                                        for f in FIGURES},
                                     **{f: round(float(getattr(second, f)), 3)
                                        for f in FIGURES},
                                     reason=second.reason))
    print(f"{len({(r['query'], r['match']) for r in rows})} degenerate checks re-checked")
    print(f"{'variant':>8} {'built':>5} {'correct':>8} {'wrong':>6} {'path m':>7}")
    for v in dict.fromkeys(r["variant"] for r in rows):
        for built in ("odom", "ref"):
            sel = [r for r in rows if r["variant"] == v and r["built"] == built]
            acc = [r for r in sel if r["accepted"]]
            print(f"{v:>8} {built:>5} {sum(r['correct'] for r in acc):>8} "
                  f"{sum(not r['correct'] for r in acc):>6} "
                  f"{np.median([r['path_q'] for r in sel]) if sel else 0:>7.1f}")
        for r in rows:
            if r["variant"] == v and r["built"] == "odom" and r["accepted"] and not r["correct"]:
                other = next(o for o in rows if o["variant"] == v and o["built"] == "ref"
                             and o["query"] == r["query"] and o["match"] == r["match"])
                print(f"    wrong {r['query']}->{r['match']}: {r['err_m']} m {r['err_deg']} deg;"
                      f" paths {r['path_q']}/{r['path_c']} m, drift {r['drift_q_m']} m "
                      f"{r['drift_q_deg']} deg / {r['drift_c_m']} m {r['drift_c_deg']} deg; "
                      f"ref-built: {'accepted' if other['accepted'] else 'rejected'} "
                      f"{other['err_m']} m {other['err_deg']} deg")
    if args.csv:
        write_rows(args.csv, rows)


if __name__ == "__main__":
    main()
