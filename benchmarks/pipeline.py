"""Benchmark: the SLAM pipeline's speed and accuracy under configuration variants, in one run.

Run from the repository root::

    python benchmarks/pipeline.py [--data DIR] [--limit N] \
        [--variant NAME:key=value,key=value ...]

Every variant maps the same first `--limit` scans of the Intel log
(``carmen/intel.clf.bz2``; all of it with ``--limit 0``) with `slam.pipeline.Mapper`
and the defaults of `slam.config.PipelineConfig` changed by its ``key=value``
overrides (the syntax of ``loopclosure run --set``).  The scans are read once,
before any timing.  For each variant the script prints wall-clock seconds per stage
(odometry, keyframes, loop detection, iSAM2 updates, final GNC), loop counts, and
the relations metric (Kümmerle et al. 2009) of the per-scan trajectory against
``carmen/intel.relations`` (relations whose both stamps were mapped), and then the
ratio of each variant's times to the first variant's.

Without ``--variant`` it compares the three loop searches (``loops.search`` =
``pose``, the default ``both``, ``appearance``).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from data.carmen import CarmenLog
from data.relations import read_relations
from data.types import Trajectory
from evaluation.relations_metric import relations_metric
from slam.config import PipelineConfig
from slam.config_io import apply_overrides
from slam.pipeline import Mapper
from slam.refine_scans import refine_scan_poses

SHORT_S = 1.0

DEFAULT_VARIANTS = (
    "pose:loops.search=pose",
    "defaults:",
    "appearance:loops.search=appearance",
)


def scan_points(scan) -> np.ndarray:
    """``(N, 2)`` valid end points of a scan in its sensor frame [m]."""
    ok = scan.valid
    return np.column_stack([scan.ranges[ok] * np.cos(scan.angles[ok]),
                            scan.ranges[ok] * np.sin(scan.angles[ok])])


def score(stamps: np.ndarray, poses: np.ndarray, relations: list, prefix: str) -> dict:
    """Relations error of per-scan poses: all relations and the short ones."""
    order = np.argsort(stamps, kind="stable")
    traj = Trajectory.from_xytheta(stamps[order], poses[order])
    lo, hi = stamps.min(), stamps.max()
    inside = [r for r in relations if lo <= min(r.t1, r.t2) and max(r.t1, r.t2) <= hi]
    short = [r for r in inside if abs(r.t2 - r.t1) < SHORT_S]
    row: dict[str, float] = {}
    if inside:
        metric = relations_metric(traj, inside)
        row[f"{prefix}trans_m"] = metric.trans_abs_mean
        row[f"{prefix}rot_deg"] = metric.rot_abs_mean_deg
    if short:
        metric = relations_metric(traj, short)
        row[f"{prefix}short_trans_m"] = metric.trans_abs_mean
        row[f"{prefix}short_rot_deg"] = metric.rot_abs_mean_deg
    return row


def run_variant(scans: list, overrides: list[str], relations: list,
                refine: bool = False) -> dict[str, float]:
    """Map `scans` with the overridden defaults; timings, loop counts and relations error."""
    cfg = apply_overrides(PipelineConfig(), overrides)
    start = time.perf_counter()
    cpu = time.process_time()
    result = Mapper(cfg).run(scans)
    wall = time.perf_counter() - start
    row: dict[str, float] = {"wall_s": wall, "cpu_s": time.process_time() - cpu}
    row.update({f"{k}_s": v for k, v in result.timings.items()})
    row["keyframes"] = len(result.keyframes)
    row["candidates"] = len(result.loops)
    row["appearance_candidates"] = sum(e.candidate.source == "appearance" for e in result.loops)
    row["prior_free_checks"] = sum(not e.candidate.prior for e in result.loops)
    row["accepted"] = len(result.accepted_loops)
    row["accepted_appearance"] = sum(
        e.candidate.source == "appearance" for e in result.accepted_loops
    )
    row["gnc_rejected"] = sum(e.rejected_by_gnc for e in result.loops)
    stamps = result.scan_stamps
    row.update(score(stamps, result.scan_poses, relations, "rel_"))
    if refine and len(stamps) == len(scans):
        start = time.perf_counter()
        position = {s.index: i for i, s in enumerate(scans)}
        map_scans = sorted(position[k.scan_index] for k in result.keyframes)
        refined = refine_scan_poses([scan_points(s) for s in scans], result.scan_poses,
                                    map_scans)
        row["refine_s"] = time.perf_counter() - start
        row.update(score(stamps, refined.poses, relations, "refined_"))
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=Path(__file__).resolve().parents[2]
                        / "shared" / "data")
    parser.add_argument("--limit", type=int, default=4000, help="scans (0: the whole log)")
    parser.add_argument("--refine", action="store_true",
                        help="also score the scans refined by slam.refine_scans")
    parser.add_argument("--variant", action="append", default=None,
                        help="NAME:key=value,key=value (repeatable)")
    args = parser.parse_args()
    log = args.data / "carmen" / "intel.clf.bz2"
    if not log.exists():
        sys.exit(f"{log} not found: pass --data with the shared data folder")
    scans = []
    for scan in CarmenLog(log):
        scans.append(scan)
        if args.limit and len(scans) >= args.limit:
            break
    relations = read_relations(args.data / "carmen" / "intel.relations")
    print(f"Intel, {len(scans)} scans")
    rows: dict[str, dict[str, float]] = {}
    for spec in args.variant or DEFAULT_VARIANTS:
        name, _, sets = spec.partition(":")
        overrides = [s for s in sets.split(",") if s]
        rows[name] = run_variant(scans, overrides, relations, args.refine)
        r = rows[name]
        print(f"\n{name} ({', '.join(overrides) or 'defaults'})")
        print("  " + "  ".join(f"{k} {v:.4g}" for k, v in r.items()))
    first = next(iter(rows.values()))
    print("\ntime ratios against the first variant (lower is faster)")
    keys = [k for k in first if k.endswith("_s") and first[k] > 0]
    print(f"{'variant':<20}" + "".join(f"{k:>22}" for k in keys))
    for name, r in rows.items():
        print(f"{name:<20}" + "".join(f"{r[k] / first[k]:>22.3f}" for k in keys))


if __name__ == "__main__":
    main()
