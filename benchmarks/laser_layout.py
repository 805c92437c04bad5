"""Does the beam layout or the range scale of a log explain its short relations' error?

Run from the repository root::

    python benchmarks/laser_layout.py [--log LOG] [--relations FILE] [--limit N]
        [--layout NAME:START_DEG:STEP_DEG ...] [--scale S ...] [--set key=value ...]

The ``icp2d`` front end (the default `Icp2dConfig`, or ``--set`` overrides in the
syntax of ``loopclosure run --set``, keys under ``icp2d.``) maps the log's scans,
in file order with their wheel odometry, once per variant: each ``--layout``
re-bears every scan's beams (beam ``i`` at ``START + i * STEP`` degrees), each
``--scale`` multiplies every range (a diagnosis: no laser's ranges are wrong by a
percent), each ``--config`` changes the front end's settings instead.  The variant
``reader`` keeps the reader's bearings; the row ``wheel
odometry`` scores the scans' own odometry poses (when every scan has one).

Per variant, on the reference relations whose scans are less than 1 s apart
(`SHORT_S`): the relations metric's mean translation [m] and rotation [deg] errors
(Kümmerle et al. 2009, `evaluation.relations_metric`), and ``along``: the median
over the relations longer than `MIN_ALONG_M` of ``(t_est - t_ref) . t_ref /
|t_ref|^2`` (``t`` the relation's translation in the frame of its first scan), the
relative length error of the estimated motion along the reference's; ``vs
reader``: the mean translation [m] and rotation [deg] between the variant's and
the ``reader`` variant's relative poses of the same relations (how much the
estimate moves when only the front end changes, no reference involved).  A layout
that removes a shared length error without raising the metric's error is the
log's; one that only trades one for the other is not evidence.  ``--breakdown``
also prints each variant's errors by tercile of the reference relation's turn rate
[deg/s], speed [m/s] and length [m] (a motion-dependent error, the laser's sweep
during motion, grows with the first two) and the translation error split along and
across the reference's translation (mean and standard deviation [m]): a shared
length error is the along mean, the scatter the standard deviations.

Nothing is written; the shared data is read in place.
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from data.carmen import CarmenLog  # noqa: E402
from data.relations import read_relations  # noqa: E402
from data.types import Scan, Trajectory  # noqa: E402
from evaluation.relations_metric import lookup, relations_metric  # noqa: E402
from slam.config import PipelineConfig  # noqa: E402
from slam.config_io import apply_overrides  # noqa: E402
from slam.odometry.icp2d import Icp2dConfig, Icp2dOdometry  # noqa: E402

DEFAULT_DATA = ROOT.parent / "shared" / "data"
SHORT_S = 1.0
MIN_ALONG_M = 0.05


def along_error(estimate: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """``(t_est - t_ref) . t_ref / |t_ref|^2`` of ``(K, 4, 4)`` relative poses; NaN below
    `MIN_ALONG_M` of reference translation."""
    t_ref, t_est = reference[:, :2, 3], estimate[:, :2, 3]
    length2 = np.einsum("ij,ij->i", t_ref, t_ref)
    out = np.einsum("ij,ij->i", t_est - t_ref, t_ref) / np.maximum(length2, 1e-12)
    out[length2 < MIN_ALONG_M**2] = np.nan
    return out


def relayout(scan: Scan, start_deg: float | None, step_deg: float | None,
             scale: float) -> Scan:
    """`scan` with beam ``i`` at ``start + i * step`` degrees (None: as read) and its
    ranges times `scale` (invalid readings kept invalid)."""
    angles = scan.angles
    if start_deg is not None and step_deg is not None:
        angles = np.radians(start_deg + step_deg * np.arange(len(scan.ranges)))
    ranges = scan.ranges
    if scale != 1.0:
        valid = scan.valid
        ranges = ranges.copy()
        ranges[valid] *= scale
    return dataclasses.replace(scan, angles=angles, ranges=ranges)


def along_across(estimate: np.ndarray, reference: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Translation error ``t_est - t_ref`` [m] of ``(K, 4, 4)`` relative poses split along
    ``t_ref`` and across it (positive to its left); NaN below `MIN_ALONG_M`."""
    t_ref, d = reference[:, :2, 3], estimate[:, :2, 3] - reference[:, :2, 3]
    length = np.hypot(t_ref[:, 0], t_ref[:, 1])
    u = t_ref / np.maximum(length, 1e-12)[:, None]
    along = np.where(length >= MIN_ALONG_M, u[:, 0] * d[:, 0] + u[:, 1] * d[:, 1], np.nan)
    across = np.where(length >= MIN_ALONG_M, u[:, 0] * d[:, 1] - u[:, 1] * d[:, 0], np.nan)
    return along, across


def pairs(poses: np.ndarray, stamps: np.ndarray, relations):
    """Matched ``(estimate, reference, dt)``: ``(K, 4, 4)`` relative poses and ``(K,)``
    ``|t2 - t1|`` [s] of the relations whose stamps the trajectory holds (1 ms)."""
    traj = Trajectory.from_xytheta(stamps, poses)
    i1 = lookup(traj.stamps, np.array([r.t1 for r in relations]), 1e-3)
    i2 = lookup(traj.stamps, np.array([r.t2 for r in relations]), 1e-3)
    ok = (i1 >= 0) & (i2 >= 0)
    est = np.linalg.inv(traj.poses[i1[ok]]) @ traj.poses[i2[ok]]
    kept = [r for r, k in zip(relations, ok, strict=True) if k]
    return (est, np.stack([r.delta for r in kept]),
            np.array([abs(r.t2 - r.t1) for r in kept]))


def score(poses: np.ndarray, stamps: np.ndarray, relations) -> tuple[float, float, float]:
    """Short relations' mean translation [m], rotation [deg] and median along error."""
    m = relations_metric(Trajectory.from_xytheta(stamps, poses), relations)
    est, ref, _ = pairs(poses, stamps, relations)
    return m.trans_abs_mean, m.rot_abs_mean_deg, float(np.nanmedian(along_error(est, ref)))


def breakdown(poses: np.ndarray, stamps: np.ndarray, relations) -> None:
    """Print the errors by tercile of the reference's turn rate, speed and length, and
    the translation error's along/across mean and standard deviation [m]."""
    est, ref, dt = pairs(poses, stamps, relations)
    err = est @ np.linalg.inv(ref)
    trans = np.hypot(err[:, 0, 3], err[:, 1, 3])
    rot = np.degrees(np.arctan2(err[:, 1, 0], err[:, 0, 0]))
    length = np.hypot(ref[:, 0, 3], ref[:, 1, 3])
    turn = np.degrees(np.abs(np.arctan2(ref[:, 1, 0], ref[:, 0, 0])))
    dt = np.maximum(dt, 1e-6)
    for what, x in (("turn rate deg/s", turn / dt), ("speed m/s", length / dt),
                    ("length m", length)):
        edges = np.quantile(x, [0.0, 1 / 3, 2 / 3, 1.0])
        for lo, hi in itertools.pairwise(edges):
            m = (x >= lo) & (x <= hi)
            print(f"  {what} {lo:8.3f}..{hi:8.3f}: {m.sum():4d} relations, trans "
                  f"{trans[m].mean():.4f} m, rot {np.abs(rot[m]).mean():.3f} deg")
    along, across = along_across(est, ref)
    print(f"  along {np.nanmean(along):+.4f} +- {np.nanstd(along):.4f} m, across "
          f"{np.nanmean(across):+.4f} +- {np.nanstd(across):.4f} m, rotation "
          f"{rot.mean():+.4f} +- {rot.std():.4f} deg")


def run(scans: list[Scan], config: Icp2dConfig) -> tuple[np.ndarray, np.ndarray]:
    odo = Icp2dOdometry(config)
    est = [odo.process(s) for s in scans]
    return np.array([e.pose for e in est]), np.array([e.stamp for e in est])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--log", type=Path, default=DEFAULT_DATA / "carmen" / "intel.clf.bz2")
    parser.add_argument("--relations", type=Path,
                        default=DEFAULT_DATA / "carmen" / "intel.relations")
    parser.add_argument("--limit", type=int, default=None, help="first N scans only")
    parser.add_argument("--layout", action="append", default=[],
                        help="NAME:START_DEG:STEP_DEG (repeatable)")
    parser.add_argument("--scale", action="append", type=float, default=[],
                        help="range scale (repeatable)")
    parser.add_argument("--set", action="append", default=[], help="key=value (icp2d.*)")
    parser.add_argument("--config", action="append", default=[],
                        help="NAME:key=value,key=value: another front-end setting, the "
                        "reader's bearings (repeatable)")
    parser.add_argument("--breakdown", action="store_true",
                        help="errors by turn rate, speed and length; along/across split")
    args = parser.parse_args()
    scans = list(CarmenLog(args.log))[: args.limit]
    stamps = np.array([s.stamp for s in scans])
    short = [r for r in read_relations(args.relations)
             if abs(r.t2 - r.t1) < SHORT_S
             and min(r.t1, r.t2) >= stamps.min() and max(r.t1, r.t2) <= stamps.max()]
    a = np.degrees(scans[0].angles)
    print(f"{args.log.name}: {len(scans)} scans of {len(a)} beams, reader's bearings "
          f"{a[0]:+.3f}..{a[-1]:+.3f} deg step {a[1] - a[0]:.4f}; {len(short)} relations "
          f"< {SHORT_S:g} s")
    config = apply_overrides(PipelineConfig(), args.set).icp2d
    variants = [("reader", None, None, 1.0, config)]
    for spec in args.layout:
        name, start, step = spec.split(":")
        variants.append((name, float(start), float(step), 1.0, config))
    variants += [(f"range x{s:g}", None, None, s, config) for s in args.scale]
    for spec in args.config:
        name, _, sets = spec.partition(":")
        other = apply_overrides(PipelineConfig(), args.set + sets.split(",")).icp2d
        variants.append((name, None, None, 1.0, other))
    print(f"{'variant':<16} {'trans m':>8} {'rot deg':>8} {'along':>8} {'vs reader m':>11} "
          f"{'deg':>7}")
    if all(s.odom is not None for s in scans):
        te, re, al = score(np.array([s.odom for s in scans]), stamps, short)
        print(f"{'wheel odometry':<16} {te:8.5f} {re:8.4f} {al:+8.2%}", flush=True)
    first = None
    for name, start, step, scale, cfg in variants:
        moved = [relayout(s, start, step, scale) for s in scans]
        poses, st = run(moved, cfg)
        te, re, al = score(poses, st, short)
        est = pairs(poses, st, short)[0]
        first = est if first is None else first
        apart = first @ np.linalg.inv(est)
        print(f"{name:<16} {te:8.5f} {re:8.4f} {al:+8.2%} "
              f"{np.hypot(apart[:, 0, 3], apart[:, 1, 3]).mean():11.5f} "
              f"{np.degrees(np.abs(np.arctan2(apart[:, 1, 0], apart[:, 0, 0]))).mean():7.4f}",
              flush=True)
        if args.breakdown:
            breakdown(poses, st, short)


if __name__ == "__main__":
    main()
