"""How accurate the accepted prior-free fits are, split along the fit's weak and strong axes.

Run from the repository root::

    python benchmarks/fit_accuracy.py LOG [--max-queries N] [--cache FILE.npz] \
        [--csv OUT.csv] [--set KEY=VALUE ...] [--longer L] \
        [--variants more_iter,scan,scan_scan,longer_match,longer_both,dense]

The log is mapped as ``loopclosure bench loops LOG --reference-from-log
--odometry-noise 0 --stages fused`` maps it (`evaluation.loop_bench.mapped_input`) and
every planned keyframe queries its database as the benchmark does
(`evaluation.loop_bench_queries.query_all`, fused row and the final check), recording
the final check of each query.  For every accepted final fit (query ``k`` in match
``m``'s frame, ``T``) the reference's relative pose ``R = between(ref[m], ref[k])``
gives the error ``R[:2] - T[:2]`` (match frame [m]) split along the fit's degenerate
axis (``along``, the unit direction of its least translational information) and across
it (``across``), and the heading error ``R[2] - T[2]`` [deg].

Each variant then refines every accepted fit from ``T`` by point-to-line ICP
(`loopclosure.registration.register`, gate 0.3 m, up to 60 iterations) and reports
the same figures and the R@100P / R@99P of the final row with the refined poses
(the same detections and scores; only the poses' correctness changes):

- ``more_iter``: the check's own source (query submap at ``source_voxel``) and target,
  run to convergence (the check's ICP stops after ``search.icp_iterations``);
- ``scan``: only the query keyframe's own scan against the match's submap;
- ``scan_scan``: the query keyframe's own scan against the match keyframe's own scan
  (no front-end pose places either: a check of the submaps' own geometry);
- ``longer_match``: the query submap against the match's keyframes ``m - L .. m + L``;
- ``longer_both``: the query's keyframes ``k - L .. k`` against the match's
  ``m - L .. m + L`` (L = ``--longer``, keyframes);
- ``dense``: the query submap at half ``source_voxel``.

The query records (the slow part) are cached in ``--cache`` (keep it outside the
repository: it is derived from the data).  Nothing here changes a verdict.
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
from evaluation.loop_bench import _query_plan, mapped_input  # noqa: E402
from evaluation.loop_bench_input import LoopSource  # noqa: E402
from evaluation.loop_bench_queries import query_all  # noqa: E402
from evaluation.loop_bench_truth import pr_curve, recall_at_precision  # noqa: E402
from loopclosure.registration import (  # noqa: E402
    RegistrationTarget,
    register,
    voxel_downsample,
)
from slam.config import PipelineConfig  # noqa: E402
from slam.config_io import apply_overrides  # noqa: E402

VARIANTS = ("more_iter", "scan", "scan_scan", "longer_match", "longer_both", "dense")


def split_error(reference: np.ndarray, fitted: np.ndarray, axis: np.ndarray
                ) -> tuple[float, float, float]:
    """``(along, across, heading)``: the reference's relative pose minus the fit's, its
    translation (match frame [m]) on the unit `axis` and on its left perpendicular,
    and the heading difference [deg] wrapped to (-180, 180]."""
    d = np.asarray(reference, float)[:2] - np.asarray(fitted, float)[:2]
    a = np.asarray(axis, float).reshape(2)
    n = np.array([-a[1], a[0]])
    turn = float(np.degrees(se2.wrap_angle(reference[2] - fitted[2])))
    return float(d @ a), float(d @ n), turn


def _records(args, cfg):
    """Map, query, and keep each query's final check (cached in ``args.cache``)."""
    source = LoopSource(args.log, reference_from_log=True, odometry_noise=0,
                        folder=str(Path.cwd()))
    mapper, result, ref = mapped_input(source, cfg)
    if args.cache and Path(args.cache).exists():
        return mapper, ref, dict(np.load(args.cache))
    det = mapper.detector
    seen: dict[int, list] = {}
    original = det.verify_places

    def recording(key, *a, **kw):
        out = original(key, *a, **kw)
        seen[key] = out
        return out

    det.verify_places = recording
    covered = np.isfinite(ref).all(axis=1)
    poses = np.array([result.keyframe_poses[kf.id] for kf in result.keyframes], float)
    plan = _query_plan(len(ref), args.max_queries)
    raw = query_all(mapper, ref, covered, poses, ["fused"], plan, 10**9, 2.0,
                    lambda *_: None)
    det.verify_places = original
    n = len(raw.keys)
    axes = np.zeros((n, 2))
    for i, k in enumerate(raw.keys):
        for c in seen.get(k, []):
            if c.accepted and c.match == raw.final_match[i] and np.allclose(
                    c.relative, raw.relative[i]):
                axes[i] = c.verification.degenerate_axis
    rec = dict(keys=np.asarray(raw.keys), revisit=np.asarray(raw.revisit),
               accepted=np.asarray(raw.accepted), match=np.asarray(raw.final_match),
               score=np.asarray(raw.final_score), relative=np.asarray(raw.relative),
               axis=axes, degeneracy=np.asarray(raw.figures)[:, 4])
    if args.cache:
        np.savez(args.cache, **rec)
    return mapper, ref, rec


def _recall(score, correct, revisits):
    curve = pr_curve(score, correct, revisits)
    return recall_at_precision(curve, 1.0), recall_at_precision(curve, 0.99)


def _refine(variant: str, mapper, k: int, m: int, start: np.ndarray, cfg, longer: int,
            targets: dict) -> np.ndarray:
    check = cfg.loops.check
    icp = dataclasses.replace(check.icp, max_correspondence_distance=check.search.icp_gate,
                              max_iterations=60)
    query = mapper.query_submaps[k]
    if variant in ("longer_match", "longer_both"):
        tkey = ("long", m)
        if tkey not in targets:
            lo, hi = max(0, m - longer), min(len(mapper.keyframes.keyframes) - 1, m + longer)
            targets[tkey] = RegistrationTarget(mapper._local_points(m, lo, hi), check.icp)
        target = targets[tkey]
    elif variant == "scan_scan":
        tkey = ("scan", m)
        if tkey not in targets:
            targets[tkey] = RegistrationTarget(
                voxel_downsample(mapper._keyframe(m).points, cfg.submap.voxel), check.icp)
        target = targets[tkey]
    else:
        if m not in targets:
            targets[m] = RegistrationTarget(mapper.submap(m), check.icp)
        target = targets[m]
    if variant in ("scan", "scan_scan"):
        source = voxel_downsample(mapper._keyframe(k).points, check.source_voxel)
    elif variant == "longer_both":
        source = voxel_downsample(mapper._local_points(k, max(0, k - longer), k),
                                  check.source_voxel)
    elif variant == "dense":
        source = voxel_downsample(query, 0.5 * check.source_voxel)
    else:
        source = voxel_downsample(query, check.source_voxel)
    r = register(source, target, start, config=icp)
    return np.asarray(r.pose, float) if r.ok else np.asarray(start, float)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("log")
    ap.add_argument("--max-queries", type=int)
    ap.add_argument("--cache")
    ap.add_argument("--csv")
    ap.add_argument("--variants", default=",".join(VARIANTS))
    ap.add_argument("--longer", type=int, default=30)
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="a config override, as the CLI's --set")
    args = ap.parse_args()
    cfg = apply_overrides(PipelineConfig(), args.set)
    mapper, ref, rec = _records(args, cfg)
    keys, match, rel, axes = rec["keys"], rec["match"], rec["relative"], rec["axis"]
    acc = rec["accepted"] & (match >= 0)
    revisits = int(rec["revisit"].sum())
    variants = [v for v in args.variants.split(",") if v]
    rows, correct = [], {v: np.zeros(len(keys), bool) for v in ("check", *variants)}
    errs = {v: [] for v in ("check", *variants)}
    targets: dict = {}
    for i in np.flatnonzero(acc):
        k, m = int(keys[i]), int(match[i])
        truth = se2.between(ref[m], ref[k])
        place = float(np.hypot(*(ref[m, :2] - ref[k, :2]))) <= 2.0
        poses = {"check": rel[i]}
        for v in variants:
            poses[v] = _refine(v, mapper, k, m, rel[i], cfg, args.longer, targets)
        row = dict(query=k, match=m, score=round(float(rec["score"][i]), 4),
                   degeneracy=round(float(rec["degeneracy"][i]), 4))
        for v, p in poses.items():
            along, across, turn = split_error(truth, p, axes[i])
            ok = place and np.hypot(along, across) <= 0.2 and abs(turn) <= 2.0
            correct[v][i] = ok
            errs[v].append((along, across, turn))
            row.update({f"{v}_along": round(along, 3), f"{v}_across": round(across, 3),
                        f"{v}_deg": round(turn, 2), f"{v}_ok": int(ok)})
        rows.append(row)
    print(f"{Path(args.log).name}: {len(keys)} queries, {revisits} revisits, "
          f"{int(acc.sum())} accepted")
    print("variant      R@100P  R@99P  correct  |along| med/p90  |across| med/p90  "
          "|deg| med/p90")
    for v in ("check", *variants):
        e = np.abs(np.asarray(errs[v]).reshape(-1, 3))
        r100, r99 = _recall(rec["score"], correct[v], revisits)
        med = np.median(e, axis=0) if len(e) else np.full(3, np.nan)
        p90 = np.percentile(e, 90, axis=0) if len(e) else np.full(3, np.nan)
        print(f"{v:12s} {r100:.3f}   {r99:.3f}  {int(correct[v].sum()):5d}    "
              f"{med[0]:.3f}/{p90[0]:.3f}       {med[1]:.3f}/{p90[1]:.3f}      "
              f"{med[2]:.2f}/{p90[2]:.2f}")
    if args.csv:
        write_rows(args.csv, rows)


if __name__ == "__main__":
    main()
