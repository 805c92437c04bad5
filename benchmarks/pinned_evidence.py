"""What tells a true degenerate prior-free fit from a wrong one: the slide profiles.

Run from the repository root::

    python benchmarks/pinned_evidence.py LOG [--relations FILE] --queries Q1,Q2,... \
        [--csv OUT.csv]

The log is mapped as ``loopclosure bench loops`` maps it (`evaluation.loop_bench.mapped_input`),
then each listed query keyframe asks the place database and checks its places as the
pipeline's global search does (`verify_places`, ``loops.check.pinned_degenerate`` on),
every place on its own.  For each check whose fit lies below a degeneracy bar (the
checks `loopclosure.prior_free.axis_profile` profiles) the script records, besides the
check's own figures, the hits of the free-space test (`loopclosure.free_space` (2)):

- ``weak_P`` for the fit slid P [m] along its degenerate axis, P in -0.5..0.5 by 0.1 and +-0.05;
- ``err_along``: the reference's relative pose minus the check's along that axis [m];
- ``strong_m``/``strong_p``: slid 0.5 m either way along the perpendicular (strong) axis;
- ``hits``: at the fit.

and the check's correctness against the reference (0.2 m, 2 degrees).  Nothing here
changes a verdict.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.rows_csv import write_rows  # noqa: E402
from data import se2  # noqa: E402
from evaluation.loop_bench import mapped_input  # noqa: E402
from evaluation.loop_bench_input import LoopSource  # noqa: E402
from loopclosure import prior_free  # noqa: E402
from loopclosure.free_space import consistency  # noqa: E402
from slam.config import PipelineConfig  # noqa: E402

SHIFTS = np.round(np.concatenate([np.arange(-0.5, 0.51, 0.1), [-0.05, 0.05]]), 2)
RECORD: list[dict] = []
_original = prior_free.axis_profile


def _recording(query, candidate, pose, axis, shift, tolerance, margin):
    """`prior_free.axis_profile`, recording the wider profiles of the same fit."""
    t = np.asarray(pose, float).reshape(3)
    a = np.asarray(axis, float).reshape(2)
    n = np.array([-a[1], a[0]])
    rec = {"pose": t.copy(), "ax": float(a[0]), "ay": float(a[1])}
    for s in SHIFTS:
        m = t.copy()
        m[:2] += s * a
        rec[f"weak_{s:+.2f}"] = consistency(query, candidate, m, tolerance, margin).hits
    for name, s in (("strong_m", -shift), ("strong_p", shift)):
        m = t.copy()
        m[:2] += s * n
        rec[name] = consistency(query, candidate, m, tolerance, margin).hits
    RECORD.append(rec)
    return _original(query, candidate, pose, axis, shift, tolerance, margin)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("log")
    ap.add_argument("--relations")
    ap.add_argument("--queries", required=True, help="comma-separated keyframe ids")
    ap.add_argument("--csv")
    args = ap.parse_args()
    prior_free.axis_profile = _recording
    cfg = PipelineConfig()
    cfg.loops.check.pinned_degenerate = True
    source = LoopSource(args.log, relations=args.relations,
                        reference_from_log=args.relations is None,
                        odometry_noise=None if args.relations else 0, folder=str(Path.cwd()))
    mapper, result, ref = mapped_input(source, cfg)
    det = mapper.detector
    poses = np.array([result.keyframe_poses[kf.id] for kf in result.keyframes], float)
    keys = np.array(sorted(det.database.keys), dtype=np.intp)
    covered = np.isfinite(ref).all(axis=1)
    rows = []
    for k in (int(q) for q in args.queries.split(",")):
        older = keys[keys < k]
        cand = older[det.eligible(k)[older] & covered[older]]
        if len(cand) == 0:
            continue
        places = det.places(det.query_places(k, cand), poses)
        pts = mapper.query_submaps.get(k)
        for p in places:
            RECORD.clear()
            for c in det.verify_places(k, [p], poses, pts):
                v = c.verification
                if not np.isfinite(v.pinned_length):
                    continue
                rec = next((r for r in RECORD if np.allclose(r["pose"], c.relative)), None)
                if rec is None:
                    continue
                err = se2.between(se2.between(ref[c.match], ref[k]), np.asarray(c.relative))
                err_m, err_deg = float(np.hypot(err[0], err[1])), abs(float(np.degrees(err[2])))
                # the reference's relative pose minus the check's, candidate frame
                truth = se2.between(ref[c.match], ref[k])
                d_xy = truth[:2] - np.asarray(c.relative)[:2]
                row = dict(err_along=round(float(d_xy @ [rec["ax"], rec["ay"]]), 3),
                           query=k, match=int(c.match), accepted=int(c.accepted),
                           correct=int(err_m <= 0.2 and err_deg <= 2.0),
                           err_m=round(err_m, 3), err_deg=round(err_deg, 2),
                           reason=c.reason[:40],
                           fitness=round(v.fitness, 4), consistency=round(v.consistency, 4),
                           degeneracy=round(v.degeneracy, 4),
                           matched=round(v.matched_length, 2),
                           pinned=round(v.pinned_length, 2), hold=round(v.axis_hold, 3))
                row.update({kk: vv for kk, vv in rec.items() if kk != "pose"})
                rows.append(row)
                print(row, flush=True)
    if args.csv:
        write_rows(args.csv, rows)


if __name__ == "__main__":
    main()
