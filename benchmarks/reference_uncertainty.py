"""How sure is the relations reference of the detections it calls wrong?

Run from the repository root, after ``loopclosure bench loops LOG --relations FILE
--out DIR``::

    python benchmarks/reference_uncertainty.py LOG --relations FILE --queries DIR/queries.csv

``bench loops`` judges a detection after the geometric check correct when the
reference puts its two keyframes within 2 m and the check's relative pose agrees
with the reference's within 0.2 m / 2 degrees.  With a relations reference
(`evaluation.slam_reference`), the relative pose of two passes that no relation joins
directly is a chain of relations, each good to its own few millimetres and a quarter
degree: its error grows along the chain.  This script maps the log as the benchmark
does (the same keyframes and front-end odometry), rebuilds the reference's pose graph
and, for every accepted detection the benchmark called wrong (and for the correct
ones, for comparison), the standard deviations of the reference's own relative pose
between the two keyframes from the graph's marginal covariance
(`evaluation.slam_reference.relative_sigmas`).

It prints each wrong detection (rank by score, keyframes, error, the reference's
sigmas, error over sigma), the sigmas of the correct detections, and recall at 100%
precision twice: as the benchmark counts it, and with the wrong detections whose
errors lie within the tolerance plus three of the reference's sigmas set aside as
unverifiable (neither correct nor wrong).  The second figure is a diagnosis of the
reference, not a replacement of the benchmark's.
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from evaluation.loop_bench import Tolerances, mapped_input  # noqa: E402
from evaluation.loop_bench_input import LoopSource  # noqa: E402
from evaluation.loop_bench_truth import pr_curve, recall_at_precision  # noqa: E402
from evaluation.slam_reference import (  # noqa: E402
    reference_graph,
    relations_in_range,
    relations_reference,
    relative_sigmas,
)
from slam.config import PipelineConfig  # noqa: E402

SIGMAS = 3.0
"""Sigmas of the reference's own uncertainty added to the tolerance (unverifiable)."""


def _detections(path: Path) -> list[dict]:
    """The accepted detections of a ``bench loops`` queries.csv, best score first."""
    with path.open() as f:
        rows = [r for r in csv.DictReader(f) if r["final_score"] not in ("", "nan")]
    rows.sort(key=lambda r: -float(r["final_score"]))
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("log")
    ap.add_argument("--relations", required=True)
    ap.add_argument("--queries", required=True, help="queries.csv of `bench loops --out`")
    args = ap.parse_args()
    tol = Tolerances()

    from data.relations import read_relations

    source = LoopSource(args.log, relations=args.relations, folder=str(Path.cwd()))
    _mapper, result, ref = mapped_input(source, PipelineConfig())
    scans = source.open().scans
    stamps = np.array([s.stamp for s in scans], float)
    kf_scan = np.array([k.scan_index for k in result.keyframes], np.intp)
    rels = relations_in_range(read_relations(args.relations), stamps)
    odometry = np.asarray(result.odometry_poses, float)
    built = reference_graph(stamps, rels, kf_scan, odometry)
    solved = relations_reference(stamps, rels, kf_scan, odometry)
    if built is None:
        sys.exit("no relation joins two scans of the log")

    rows = _detections(Path(args.queries))
    with Path(args.queries).open() as f:
        listed = {int(r["keyframe"]): int(r["scan_index"]) for r in csv.DictReader(f)}
    mismatch = [k for k, s in listed.items() if k < len(kf_scan) and kf_scan[k] != s]
    if mismatch:
        sys.exit(f"{len(mismatch)} keyframes differ from the benchmark's mapping "
                 f"(first: {mismatch[0]}): run both with the same code and config")
    correct = np.array([r["final_correct"] == "1" for r in rows])
    pairs = np.array([[kf_scan[int(r["final_match"])], kf_scan[int(r["keyframe"])]]
                      for r in rows], np.intp).reshape(-1, 2)
    covered = np.isin(pairs, built.nodes).all(axis=1)
    sig = np.full((len(rows), 3), np.nan)
    if covered.any():
        sig[covered] = relative_sigmas(built, solved.node_poses, pairs[covered])
    err_m = np.array([float(r["error_m"]) for r in rows])
    err_deg = np.array([float(r["error_deg"]) for r in rows])
    sig_m = np.hypot(sig[:, 0], sig[:, 1])
    sig_deg = np.degrees(sig[:, 2])
    dist = np.hypot(*(ref[[int(r["final_match"]) for r in rows], :2]
                      - ref[[int(r["keyframe"]) for r in rows], :2]).T)
    within = (~correct & covered & (err_m <= tol.trans_tol + SIGMAS * sig_m)
              & (err_deg <= tol.rot_tol_deg + SIGMAS * sig_deg)
              & (dist <= tol.max_distance + SIGMAS * sig_m))

    print(f"{args.log}: {len(rows)} accepted detections, {int(correct.sum())} correct, "
          f"{int((~correct).sum())} wrong, {int(within.sum())} of them within the "
          f"tolerance + {SIGMAS:g} sigma of the reference")
    print("rank  query  match  place [m]  error [m]  error [deg]  ref sigma [m]  "
          "ref sigma [deg]  verdict")
    for i in np.flatnonzero(~correct):
        r = rows[i]
        print(f"{i:4d}  {r['keyframe']:>5}  {r['final_match']:>5}  {dist[i]:9.2f}  "
              f"{err_m[i]:9.3f}  {err_deg[i]:11.2f}  {sig_m[i]:13.3f}  {sig_deg[i]:15.2f}  "
              f"{'unverifiable' if within[i] else 'wrong'}")
    ok = correct & covered
    if ok.any():
        print(f"correct detections: reference sigma median {np.median(sig_m[ok]):.3f} m / "
              f"{np.median(sig_deg[ok]):.2f} deg, 90th percentile "
              f"{np.percentile(sig_m[ok], 90):.3f} m / {np.percentile(sig_deg[ok], 90):.2f} deg")
    with Path(args.queries).open() as f:
        revisits = sum(r["revisit"] == "1" for r in csv.DictReader(f))
    scores = np.array([float(r["final_score"]) for r in rows])
    strict = recall_at_precision(pr_curve(scores, correct, revisits), 1.0)
    keep = ~within
    aware = recall_at_precision(pr_curve(scores[keep], correct[keep], revisits), 1.0)
    print(f"recall at 100% precision: {strict:.3f} as the benchmark counts; {aware:.3f} with "
          f"the {int(within.sum())} detections the reference cannot judge set aside")


if __name__ == "__main__":
    main()
