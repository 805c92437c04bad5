"""Would a final refinement by the query keyframe's own scan make the check's pose more precise?

Run from the repository root, after ``loopclosure bench loops LOG ... --out DIR``::

    python benchmarks/own_scan_refinement.py LOG --queries DIR/queries.csv [--relations FILE]

The query's submap spans the keyframes behind it; where the front end bent that span
the check fits the bent submap.  The query's own scan cannot be bent.  For every
final detection of ``queries.csv`` whose two keyframes the reference puts within 2 m,
the check is run again (`loopclosure.geometric_check.verify`, from the reference's
heading: the same search and ICP as the benchmark's) and, when accepted, the query
keyframe's own scan is registered onto the candidate's submap by point-to-line ICP
from the check's pose.  Counted against the reference (0.2 m / 2 degrees): the
checks' poses, the refined poses, and the refined pose taken only when the scan fits
better (higher fitness) than the submap did; and the detections whose verdict the
last rule flips.
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from data import se2  # noqa: E402
from evaluation.loop_bench import mapped_input  # noqa: E402
from evaluation.loop_bench_input import LoopSource  # noqa: E402
from loopclosure.geometric_check import verify  # noqa: E402
from loopclosure.registration import IcpConfig, RegistrationTarget, register  # noqa: E402
from slam.config import PipelineConfig  # noqa: E402

REFINE = IcpConfig(max_correspondence_distance=0.3, max_iterations=60)


def within(err: np.ndarray, trans_tol: float = 0.2, rot_tol_deg: float = 2.0) -> bool:
    """A relative-pose error ``(3,)`` within the benchmark's tolerances."""
    return bool(np.hypot(err[0], err[1]) <= trans_tol and abs(np.degrees(err[2])) <= rot_tol_deg)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("log")
    ap.add_argument("--queries", type=Path, required=True)
    ap.add_argument("--relations")
    args = ap.parse_args()
    source = LoopSource(args.log, relations=args.relations,
                        reference_from_log=args.relations is None,
                        odometry_noise=None if args.relations else 0, folder=str(Path.cwd()))
    mapper, result, ref = mapped_input(source, PipelineConfig())
    det = mapper.detector
    rows = [r for r in csv.DictReader(open(args.queries)) if r["final_match"] != ""]
    counts = dict(checked=0, check=0, scan=0, scan_if_better=0)
    flips = []
    for r in rows:
        q, m = int(r["keyframe"]), int(r["final_match"])
        if not np.hypot(*(ref[q, :2] - ref[m, :2])) <= 2.0:
            continue
        ref_rel = se2.between(ref[m], ref[q])
        v = verify(np.asarray(mapper.query_submaps[q], float), det._target(m),
                   headings=[float(ref_rel[2])], translation=ref_rel[:2],
                   max_distance=det.config.max_distance, config=det.config.check)
        if not v.accepted:
            continue
        target = RegistrationTarget(det._submap_points(m), REFINE)
        s = register(np.asarray(result.keyframes[q].points, float), target, v.relative,
                     config=REFINE)
        e_check = se2.between(ref_rel, v.relative)
        e_scan = se2.between(ref_rel, s.pose)
        e_rule = e_scan if (s.ok and s.fitness > v.fitness) else e_check
        counts["checked"] += 1
        counts["check"] += within(e_check)
        counts["scan"] += within(e_scan)
        counts["scan_if_better"] += within(e_rule)
        if within(e_check) != within(e_rule):
            flips.append(f"{q}->{m} heading error {np.degrees(e_check[2]):+.2f} -> "
                         f"{np.degrees(e_rule[2]):+.2f} deg (fitness {v.fitness:.2f} submap, "
                         f"{s.fitness:.2f} scan)")
    print(f"{Path(args.log).name}: correct of {counts['checked']} accepted re-checks: check "
          f"{counts['check']}, own scan {counts['scan']}, own scan when it fits better "
          f"{counts['scan_if_better']}")
    for f in flips:
        print("  flips:", f)


if __name__ == "__main__":
    main()
