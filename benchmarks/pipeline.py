"""Benchmark: the SLAM pipeline's speed and accuracy under configuration variants, in one run.

Run from the repository root::

    python benchmarks/pipeline.py [--data DIR] [--limit N] [--logs intel,seattle,...] \
        [--variant NAME:key=value,key=value ...]

Every variant maps the same scans of each log with `slam.pipeline.Mapper` and the
defaults of `slam.config.PipelineConfig` changed by its ``key=value`` overrides (the
syntax of ``loopclosure run --set``; a comma not followed by ``key=`` belongs to the
value, so tuples pass: ``icp2d.covariance_floor=0.005,0.005,0.006``).
The scans are read once, before any timing.
For each log and variant the script prints wall-clock seconds and the CPU seconds of
the mapper's process, seconds per stage (odometry, keyframes, loop detection, iSAM2
updates, final GNC; the stages a worker process ran overlap the others), loop
counts (with the candidates from a prior rejected without ICP: ``screened`` by the
coarse screen, ``bounded`` by the overlap bound), peak resident memory [MB] of the
mapper's process during the variant (``peak_mb``; the scans read before it included)
and of its front-end worker (``worker_peak_mb``, a forked child: the pages it shares
with the mapper are counted in both),
and the error:

- ``intel`` (``carmen/intel.clf.bz2``, the first `--limit` scans, all with
  ``--limit 0``): the relations metric (Kümmerle et al. 2009) of the per-scan
  trajectory against ``carmen/intel.relations``, all relations whose both stamps were
  mapped and the short ones (under 1 s apart);
- a GMapping-corrected log (``freiburg-101``, ``seattle``, ``intel-corrected``,
  ``orebro``, ``belgioioso``, ``freiburg-campus``; whole): the ATE [m] against the
  logged poses, mapped from the simulator's drifting wheel odometry (seed `--seed`,
  0 by default) as ``loopclosure bench slam LOG --odometry-noise SEED
  --reference-from-log`` does;
- a simulated run ``sim-<world>-<beams>`` (``sim-box-361``, ``sim-surface-181``, ...;
  `data.sim.simulate_run`, seed 3, two laps at 0.5 m/s and 5 Hz, a 180-degree laser
  of that many beams, 1 cm range noise, 1 % dropout, 30 m range: the lasers of
  ``benchmarks/front_end_precision.py``): the ATE [m] against the exact ground truth,
  and the local precision of every scan's pose, the mean translation [m] and
  rotation [deg] error of consecutive scans' relative poses (``consec_*``), also
  for the refined scans with ``--refine``.

Then, per log, the ratio of each variant's times to the first variant's.  The peak
is reset before each variant (Linux ``/proc/self/clear_refs``; elsewhere it is the
process's peak so far, which only grows from one variant to the next).

Without ``--variant`` it compares the three loop searches (``loops.search`` =
``pose``, the default ``both``, ``appearance``).
"""

from __future__ import annotations

import argparse
import re
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from data import se2
from data.carmen import CarmenLog
from data.relations import read_relations
from data.sim import MotionConfig, simulate_run
from data.types import Trajectory
from evaluation.relations_metric import relations_metric
from evaluation.slam_input import evaluation_stamps, load_input
from evaluation.slam_reference import logged_reference, trajectory_at_stamps
from evaluation.trajectory_error import trajectory_errors
from slam.config import PipelineConfig
from slam.config_io import apply_overrides
from slam.memory import peak_rss_since_reset_mb, release_free_memory, reset_peak_rss
from slam.pipeline import Mapper
from slam.refine_scans import refine_scan_poses

CORRECTED = ("freiburg-101", "seattle", "intel-corrected", "orebro", "belgioioso",
             "freiburg-campus")

SHORT_S = 1.0
SIM_PREFIX = "sim-"

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


def consecutive(poses: np.ndarray, truth: np.ndarray, prefix: str) -> dict[str, float]:
    """Mean translation [m] and rotation [deg] error of consecutive relative poses."""
    err = se2.between(se2.between(truth[:-1], truth[1:]), se2.between(poses[:-1], poses[1:]))
    return {f"{prefix}trans_m": float(np.mean(np.hypot(err[:, 0], err[:, 1]))),
            f"{prefix}rot_deg": float(np.degrees(np.mean(np.abs(se2.wrap_angle(err[:, 2])))))}


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


def map_scans(scans: list, result) -> list[int]:
    """Positions in `scans` of the mapper's keyframes (the maps of `refine_scan_poses`)."""
    position = {s.index: i for i, s in enumerate(scans)}
    return sorted(position[k.scan_index] for k in result.keyframes)


def run_variant(scans: list, overrides: list[str], relations: list | None,
                refine: bool = False, reference: Trajectory | None = None,
                truth: bool = False) -> dict[str, float]:
    """Map `scans` with the overridden defaults; timings, loop counts, peak memory and
    the relations error (with `relations`) or the ATE against `reference` (and, when
    it is the exact `truth` of every scan, the consecutive-scan errors)."""
    cfg = apply_overrides(PipelineConfig(), overrides)
    release_free_memory()
    reset = reset_peak_rss()
    start = time.perf_counter()
    cpu = time.process_time()
    result = Mapper(cfg).run(scans)
    wall = time.perf_counter() - start
    row: dict[str, float] = {"wall_s": wall, "cpu_s": time.process_time() - cpu}
    row["peak_mb"] = peak_rss_since_reset_mb(reset)
    row["worker_peak_mb"] = result.worker_peak_rss_mb
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
    # Candidates from a prior rejected without ICP: by the coarse screen at the prior,
    # and by the overlap bound (`loopclosure.geometric_check`).
    row["screened"] = sum(e.candidate.reason.startswith("no overlap at the prior")
                          for e in result.loops)
    row["bounded"] = sum(e.candidate.reason.startswith("no fit within reach")
                         for e in result.loops)
    stamps = result.scan_stamps
    if reference is not None:
        estimate = trajectory_at_stamps(evaluation_stamps(stamps)[0], result.scan_poses)
        row["ate_m"] = trajectory_errors(estimate, reference).ate_rmse
        if truth:
            row.update(consecutive(np.asarray(result.scan_poses), reference.xytheta(),
                                   "consec_"))
            if refine:
                refined = refine_scan_poses([scan_points(s) for s in scans],
                                            result.scan_poses, map_scans(scans, result))
                row.update(consecutive(refined.poses, reference.xytheta(), "refined_consec_"))
        return row
    row.update(score(stamps, result.scan_poses, relations or [], "rel_"))
    if refine and len(stamps) == len(scans):
        start = time.perf_counter()
        refined = refine_scan_poses([scan_points(s) for s in scans], result.scan_poses,
                                    map_scans(scans, result))
        row["refine_s"] = time.perf_counter() - start
        row.update(score(stamps, refined.poses, relations, "refined_"))
    return row


def load_log(data: Path, name: str, limit: int,
             seed: int = 0) -> tuple[list, list | None, Trajectory | None]:
    """Scans of log `name` with its relations (Intel) or its reference (corrected logs,
    simulated runs); `seed`: of a corrected log's synthetic wheel odometry."""
    if name.startswith(SIM_PREFIX):
        world, _, beams = name.removeprefix(SIM_PREFIX).partition("-")
        if not beams.isdigit():
            sys.exit(f"unknown log {name!r}: sim-<world>-<beams>, e.g. sim-box-361")
        run = simulate_run(world, seed=3, fov_deg=180.0, beams=int(beams), max_range=30.0,
                           noise_sigma=0.01, dropout=0.01,
                           motion=MotionConfig(speed=0.5, rate_hz=5.0, laps=2.0))
        return run.scans, None, run.ground_truth
    if name == "intel":
        log = data / "carmen" / "intel.clf.bz2"
        if not log.exists():
            sys.exit(f"{log} not found: pass --data with the shared data folder")
        scans = []
        for scan in CarmenLog(log):
            scans.append(scan)
            if limit and len(scans) >= limit:
                break
        return scans, read_relations(data / "carmen" / "intel.relations"), None
    if name not in CORRECTED:
        sys.exit(f"unknown log {name!r}: intel, sim-<world>-<beams> or one of "
                 f"{', '.join(CORRECTED)}")
    log = data / "carmen-corrected" / f"{name.removesuffix('-corrected')}-corrected.log.gz"
    if not log.exists():
        sys.exit(f"{log} not found: pass --data with the shared data folder")
    loaded = load_input(log, odometry_noise=seed)
    return loaded.scans, None, logged_reference(loaded)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=Path(__file__).resolve().parents[2]
                        / "shared" / "data")
    parser.add_argument("--limit", type=int, default=4000,
                        help="Intel scans (0: the whole log)")
    parser.add_argument("--logs", default="intel",
                        help=f"comma-separated: intel, sim-box-361 (sim-<world>-<beams>), "
                        f"{', '.join(CORRECTED)}")
    parser.add_argument("--seed", type=int, default=0,
                        help="seed of the corrected logs' synthetic wheel odometry")
    parser.add_argument("--refine", action="store_true",
                        help="also score the scans refined by slam.refine_scans (Intel, sim)")
    parser.add_argument("--variant", action="append", default=None,
                        help="NAME:key=value,key=value (repeatable)")
    args = parser.parse_args()
    for log in [n.strip() for n in args.logs.split(",") if n.strip()]:
        scans, relations, reference = load_log(args.data, log, args.limit, args.seed)
        print(f"\n== {log}, {len(scans)} scans, seed {args.seed}")
        rows: dict[str, dict[str, float]] = {}
        for spec in args.variant or DEFAULT_VARIANTS:
            name, _, sets = spec.partition(":")
            overrides = [s for s in re.split(r",(?=[\w.]+=)", sets) if s]
            rows[name] = run_variant(scans, overrides, relations, args.refine, reference,
                                     truth=log.startswith(SIM_PREFIX))
            r = rows[name]
            print(f"\n{name} ({', '.join(overrides) or 'defaults'})")
            print("  " + "  ".join(f"{k} {v:.4g}" for k, v in r.items()))
        first = next(iter(rows.values()))
        print(f"\n{log}: time ratios against the first variant (lower is faster)")
        keys = [k for k in first if k.endswith("_s") and first[k] > 0]
        print(f"{'variant':<20}" + "".join(f"{k:>22}" for k in keys))
        for name, r in rows.items():
            print(f"{name:<20}" + "".join(f"{r[k] / first[k]:>22.3f}" if k in r else f"{'-':>22}"
                                          for k in keys))


if __name__ == "__main__":
    main()
