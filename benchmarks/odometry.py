"""Benchmark: accuracy and speed of the odometry front ends, in one run.

Run from the repository root::

    python benchmarks/odometry.py [--data DIR] [--front icp2d,kiss-icp,wheel]
                                  [--corrected freiburg-101,seattle] [--limit N]

Intel (``carmen/intel.clf.bz2`` with ``carmen/intel.relations``): every front end
processes the whole log (file order, wheel odometry in the scans) once; the script
prints wall-clock and CPU seconds of the front end alone (the log is read before
timing starts), milliseconds per scan, and the relations metric (Kümmerle et al.
2009, `evaluation.relations_metric`) of the odometry trajectory alone, without loop
closure: mean absolute translational [m] and rotational [deg] error over all
relations, and over the local ones (stamps less than 5 s apart) and the long ones
(the loop relations, where drift shows).  Duplicate stamps keep their first scan;
the trajectory is sorted by stamp (the log's stamps run backwards at times).

GMapping-corrected logs (``carmen-corrected/<name>-corrected.log.gz``): their pose
fields are corrected poses, the reference.  They serve two tests of the defaults on
other buildings, ATE (`evaluation.trajectory_error`, SE(2) alignment) against the
corrected poses, scans matched by index (these logs' stamps can all be 0):

* ``synthetic odometry``: the simulator's drifting wheel-odometry model
  (`data.sim.motion.wheel_odometry`, default `OdometryNoise`, seed 0) applied to the
  corrected poses; the front ends get it as ``scan.odom``.
* ``no odometry``: ``scan.odom`` removed (constant-velocity prediction).  These logs
  hold one scan per metre or so with turns of 20-80 degrees between scans, so this
  is a stress test of the registration's basin, not a normal operating point.

Nothing here is cached or written; the data is read from the shared folder only.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from data.carmen import CarmenLog  # noqa: E402
from data.relations import read_relations  # noqa: E402
from data.sim.motion import OdometryNoise, wheel_odometry  # noqa: E402
from data.types import Scan, Trajectory  # noqa: E402
from evaluation.relations_metric import relations_metric  # noqa: E402
from evaluation.trajectory_error import trajectory_errors  # noqa: E402
from slam.odometry import FRONT_ENDS, make_odometry  # noqa: E402

DEFAULT_DATA = ROOT.parent / "shared" / "data"
INTEL = Path("carmen") / "intel.clf.bz2"
RELATIONS = Path("carmen") / "intel.relations"
CORRECTED = ("freiburg-101", "seattle", "belgioioso", "orebro", "intel")
LOCAL_S = 5.0


def run_front(name: str, scans: list[Scan]) -> tuple[np.ndarray, np.ndarray, float, float, dict]:
    """Poses ``(N, 3)``, stamps, wall and CPU seconds, and status counts of one front end."""
    odo = make_odometry(name)
    wall0, cpu0 = time.perf_counter(), time.process_time()
    estimates = [odo.process(s) for s in scans]
    wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
    statuses: dict[str, int] = {}
    for e in estimates:
        statuses[e.status] = statuses.get(e.status, 0) + 1
    poses = np.array([e.pose for e in estimates])
    stamps = np.array([e.stamp for e in estimates])
    return poses, stamps, wall, cpu, statuses


def trajectory_by_stamp(stamps: np.ndarray, poses: np.ndarray) -> Trajectory:
    """Sorted by stamp, first scan of each duplicate stamp."""
    order = np.argsort(stamps, kind="stable")
    uniq, first = np.unique(stamps[order], return_index=True)
    return Trajectory.from_xytheta(uniq, poses[order][first])


def bench_intel(data: Path, fronts: list[str], limit: int | None) -> None:
    log, rel_path = data / INTEL, data / RELATIONS
    if not log.exists() or not rel_path.exists():
        print(f"skipped Intel: {log} or {rel_path} not found")
        return
    t0 = time.perf_counter()
    scans = list(CarmenLog(log))[:limit]
    read_s = time.perf_counter() - t0
    stamps = np.array([s.stamp for s in scans])
    relations = [r for r in read_relations(rel_path)
                 if min(r.t1, r.t2) >= stamps.min() and max(r.t1, r.t2) <= stamps.max()]
    gap = np.array([abs(r.t2 - r.t1) for r in relations])
    local = gap < LOCAL_S
    print(f"Intel: {len(scans)} scans read in {read_s:.1f} s; {len(relations)} relations "
          f"({local.sum()} local < {LOCAL_S:g} s apart, {(~local).sum()} long)")
    header = (f"{'front end':<10} {'wall s':>7} {'cpu s':>7} {'ms/scan':>8} "
              f"{'trans m':>8} {'rot deg':>8} {'local m':>8} {'local deg':>9} "
              f"{'long m':>7} {'long deg':>8}  statuses")
    print(header)
    print("-" * len(header))
    walls: dict[str, float] = {}
    for name in fronts:
        poses, st, wall, cpu, statuses = run_front(name, scans)
        walls[name] = wall
        m = relations_metric(trajectory_by_stamp(st, poses), relations)
        te, re = m.trans_errors, m.rot_errors_deg
        if m.relations_used == len(relations):
            loc = f"{te[local].mean():8.4f} {re[local].mean():9.3f}"
            lng = f"{te[~local].mean():7.3f} {re[~local].mean():8.2f}" if (~local).any() else ""
        else:
            loc, lng = f"{'-':>8} {'-':>9}", f"{'-':>7} {'-':>8}"
        print(f"{name:<10} {wall:7.1f} {cpu:7.1f} {1000 * wall / len(scans):8.2f} "
              f"{m.trans_abs_mean:8.4f} {m.rot_abs_mean_deg:8.3f} {loc} {lng}  {statuses}",
              flush=True)
    if "wheel" in walls:
        ratios = ", ".join(f"{k} {v / walls['wheel']:.0f}x" for k, v in walls.items()
                           if k != "wheel")
        print(f"wall time relative to wheel (reading odometry only): {ratios}")
    print("For scale: Cartographer with loop closure 0.0229 m / 0.453 deg "
          "(Hess et al. 2016, Table II), 179 s for the log (Table V).")


def bench_corrected(data: Path, names: list[str], fronts: list[str]) -> None:
    rows = []
    for name in names:
        path = data / "carmen-corrected" / f"{name}-corrected.log.gz"
        if not path.exists():
            print(f"skipped {name}: {path} not found")
            continue
        scans = list(CarmenLog(path))
        ref = np.array([s.odom for s in scans])
        index = np.arange(len(scans), dtype=float)
        reference = Trajectory.from_xytheta(index, ref)
        synthetic = wheel_odometry(ref, OdometryNoise(), np.random.default_rng(0))
        modes = {
            "synthetic odometry": [dataclasses.replace(s, odom=o, stamp=i)
                                   for i, (s, o) in enumerate(zip(scans, synthetic, strict=True))],
            "no odometry": [dataclasses.replace(s, odom=None, stamp=i)
                            for i, s in enumerate(scans)],
        }
        odo_ate = trajectory_errors(Trajectory.from_xytheta(index, synthetic), reference)
        rows.append((name, "synthetic odometry", "(odometry itself)", odo_ate.ate_rmse, 0.0, 0))
        for mode, mode_scans in modes.items():
            for front in fronts:
                if front == "wheel":
                    continue
                poses, _, wall, _, _ = run_front(front, mode_scans)
                err = trajectory_errors(Trajectory.from_xytheta(index, poses), reference)
                rows.append((name, mode, front, err.ate_rmse, wall, len(scans)))
    if rows:
        print("\nGMapping-corrected logs: ATE RMSE [m] against the corrected poses")
        print(f"{'log':<14} {'mode':<20} {'front end':<18} {'ATE m':>8} {'ms/scan':>8}")
        for name, mode, front, ate_rmse, wall, n in rows:
            ms = f"{1000 * wall / n:8.1f}" if n else f"{'':>8}"
            print(f"{name:<14} {mode:<20} {front:<18} {ate_rmse:8.3f} {ms}", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA, help="shared data folder")
    parser.add_argument("--front", default=",".join(FRONT_ENDS),
                        help="comma-separated front ends (default: all)")
    parser.add_argument("--corrected", default=",".join(CORRECTED),
                        help="corrected logs to run ('' for none)")
    parser.add_argument("--limit", type=int, default=None, help="first N Intel scans only")
    args = parser.parse_args()
    fronts = [f.strip() for f in args.front.split(",") if f.strip()]
    if not args.data.is_dir():
        print(f"skipped: shared data folder {args.data} not found")
        return
    bench_intel(args.data, fronts, args.limit)
    names = [n.strip() for n in args.corrected.split(",") if n.strip()]
    if names:
        bench_corrected(args.data, names, fronts)


if __name__ == "__main__":
    main()
